"""The costates of a bang-bang path that touches keep-out cones, from the path alone.

A switch-time answer (``switch_time_cones``: switch instants and ``tf`` optimised with the cones
imposed on samples) whose path touches a cone at isolated instants is near a touch-point
extremal (``cone_touch``) when its switching sequence is that extremal's. The exact solver needs
that extremal's costates and touch multipliers; a switch-time answer has neither (its KKT
multipliers belong to the sampled constraints, ``switch_time_cones._costates_where_clear``).

Along the answer's path the control is a known function of time, so the costate equation
``λ̇ = -(∂f/∂x)ᵀ λ`` is linear, with the transition ``Φ(t)⁻ᵀ`` (``Φ(t)`` the 7×7 state
transition over ``[0, t]``, ``switch_time.propagate_sequence``), and each touch at ``t_c`` on
cone ``c`` makes ``λq`` jump by ``-2 ν_c M_c q(t_c)`` (``cone_touch.touch_jump``)::

    λ(t) = Φ(t)⁻ᵀ [λ(0) - 2 Σ_{t_c < t} ν_c Φ(t_c)ᵀ g_c],   g_c = [M_c q(t_c), 0, 0, 0]

Every condition an extremal's costates meet on this path is linear in ``(λ(0), ν)``:

* each switching function vanishes at its axis's switch instants,
  ``(J⁻¹ λω(t_k))_{a_k} = 0``;
* the scale ``H(0) = λ(0) · f(x(0), u(0⁺)) = -1``;
* the gauge ``λq(0) · q(0) = 0``;
* for a pointing target, the free roll's transversality ``λq(tf) · (q(tf) ⊗ [0, s]) = 0``.

With ``n`` switches and ``K`` touches that is ``n + 2`` (``n + 3``) equations in ``7 + K``
unknowns, solved by least squares. Where the answer's sequence is the extremal's, they are its
costates and multipliers up to the answer's distance from it; the exact solver starts there.
On 40 held-out problems whose short-budget answer was a touching switch-time slew
(``runs/s41/lsq_try.py``), the exact solver converged from them on 6, all at ``auto``'s answer,
where the neighbours' costates had converged on none.
"""
from __future__ import annotations

import math
from typing import Optional, Tuple

import numpy as np

from slew_env.core.quaternion import qconj, qmul
from .attitude_bvp import NY, AttitudeBVP
from .core.cone_penalty import cone_matrix
from .guesses import Guess, costate_from_nondim
from .switch_time import propagate_sequence

# a system whose smallest singular value is below this times its largest does not fix the
# costates (too few switches for the touches): no guess
RANK_TOL = 1e-10


def touch_costates(problem, switch_times, u_first, tf, touches) -> Tuple[Optional[np.ndarray], Optional[np.ndarray], dict]:
    """``(costate0, nu, info)`` of the bang-bang path ``(switch_times, u_first, tf)`` (problem
    units) of ``problem`` (per-axis bound, with cones) touching its cones at ``touches``
    (``[(cone, instant, ·)]``, instants in problem units): ``costate0`` in the package's gauge
    and scale (``H = -1``), ``nu`` the touch multipliers in the scale of ``costate0`` (what
    ``Guess.touches`` holds), ``info`` the least-squares fit (``rows``, ``unknowns``, ``residual``,
    ``condition``) and the propagations it took (``nfev``). ``(None, None, info)`` with
    ``info["reason"]`` where the conditions do not fix them (rank) or a propagation fails."""
    bvp = AttitudeBVP(problem.replace(cones=()))
    bvp.set_mode("bang")
    tau = bvp.tau
    T = float(tf) / tau
    axes = np.array([a for a in range(3) for _ in switch_times[a]], dtype=np.int64)
    times = np.array([float(x) for a in range(3) for x in switch_times[a]], dtype=float) / tau
    o = np.argsort(times, kind="stable")
    axes, times = axes[o], times[o]
    signs0 = np.where(np.asarray(u_first, float) < 0, -1.0, 1.0)
    # the control on the first arc: a switch at (or, clipped, before) 0 flips its axis there, as
    # the propagation does (switch-time answers keep their instants in [0, tf])
    signs_start = signs0.copy()
    for a, t in zip(axes, times):
        if t <= 0.0:
            signs_start[a] = -signs_start[a]
    y0 = np.zeros(NY)
    y0[0:4], y0[4:7] = bvp.q0, bvp.w0
    s_b = np.asarray(problem.sensor_axis, float) / np.linalg.norm(problem.sensor_axis)
    K = len(touches)
    tc = [float(t) / tau for _, t, _ in touches]
    info = {"nfev": 0}

    def transition(t):
        """``(y(t), Φ(t))``: the path's state and 7×7 transition over ``[0, t]``."""
        before = times < t
        out = propagate_sequence(bvp, times[before], axes[before], signs0, t, y0, True)
        if out is None:
            raise FloatingPointError
        info["nfev"] += int(out[5])
        return out[0], out[4]

    try:
        G = []          # Φ(t_c)ᵀ g_c
        for (c, _, _), t in zip(touches, tc):
            y, M = transition(t)
            g = np.zeros(7)
            g[0:4] = cone_matrix(problem.cones[c].axis, s_b) @ y[0:4]
            G.append(M.T @ g)

        def costate_map(t):
            """``(y(t), L)``: ``λ(t) = L [λ(0), ν]``, ``L`` (7, 7 + K)."""
            y, M = transition(t)
            Minv_T = np.linalg.inv(M).T
            L = np.zeros((7, 7 + K))
            L[:, :7] = Minv_T
            for k in range(K):
                if tc[k] < t:
                    L[:, 7 + k] = -2.0 * (Minv_T @ G[k])
            return y, L

        rows, rhs = [], []
        Jinv = 1.0 / np.asarray(bvp.J, float)
        for a, t in zip(axes, times):
            if not 0.0 < t < T:
                continue        # (an instant at an end switches nothing inside)
            _, L = costate_map(t)
            rows.append(Jinv[a] * L[4 + a])
            rhs.append(0.0)
        # H(0) = λ(0) · f(x(0), u(0⁺)) = -1
        w0 = np.asarray(bvp.w0, float)
        Jv = np.asarray(bvp.J, float)
        u0 = signs_start * np.asarray(bvp.umax, float)
        f0 = np.concatenate([0.5 * qmul(bvp.q0, np.concatenate([[0.0], w0])),
                             (u0 - np.cross(w0, Jv * w0)) * Jinv])
        rows.append(np.concatenate([f0, np.zeros(K)]))
        rhs.append(-1.0)
        rows.append(np.concatenate([bvp.q0, np.zeros(3 + K)]))      # the gauge
        rhs.append(0.0)
        if problem.qf is None:
            yT, LT = costate_map(T)
            roll = qmul(yT[0:4], np.concatenate([[0.0], s_b]))
            rows.append(roll @ LT[0:4])
            rhs.append(0.0)
    except (FloatingPointError, np.linalg.LinAlgError):
        return None, None, dict(info, reason="a propagation along its path failed")
    A, b = np.array(rows), np.array(rhs)
    x, _, rank, sv = np.linalg.lstsq(A, b, rcond=None)
    info.update(rows=int(A.shape[0]), unknowns=7 + K)
    if not (np.all(np.isfinite(x)) and rank == 7 + K and sv[-1] > RANK_TOL * sv[0]):
        return None, None, dict(info, reason=f"its {A.shape[0] - 2 - (problem.qf is None)} switches and "
                                             f"{K} touch(es) do not fix the costates")
    lam0, nu = x[:7], x[7:]
    info.update(residual=float(np.linalg.norm(A @ x - b)), condition=float(sv[0] / sv[-1]))
    # problem units (``guesses.costate_from_nondim``): λq scales with τ, λω with τ², ν with τ
    # (λq's jump); λq(0) enters through its parameters μ, in the gauge λq(0)·q(0) = 0
    mu = qmul(qconj(bvp.q0), lam0[0:4])[1:4]
    costate0 = costate_from_nondim(bvp, np.concatenate([mu, lam0[4:7]]))
    if not math.isfinite(float(np.linalg.norm(costate0))) or not np.any(costate0):
        return None, None, dict(info, reason="the fitted costates are zero or not finite")
    return costate0, nu * tau, info


def touch_guess(problem, sol, touches, source="the switch-time answer's own fitted"):
    """``(guess, info)``: a ``Guess`` for ``cone_touch.solve_touch_guess`` at the bang-bang
    answer ``sol`` (its instants, ``tf``, first signs) with ``touches`` and the costates and
    multipliers of ``touch_costates``, and that fit's ``info`` (its ``nfev`` to be counted by the
    caller); ``(None, info)`` with ``info["reason"]`` where there is none."""
    costate0, nu, info = touch_costates(problem, sol.switch_times, sol.u_first, sol.tf, touches)
    if costate0 is None:
        return None, info
    if np.any(nu < 0.0):
        # a touch that pulls the path into the cone: not a touch extremal with this sequence
        return None, dict(info, negative_multiplier=True, reason="a fitted touch multiplier is negative")
    g = Guess(costate0, sol.tf, [np.asarray(x, float) for x in sol.switch_times], sol.u_first, source=source,
              touches=[(c, t, float(n)) for (c, t, _), n in zip(touches, nu)])
    return g, info
