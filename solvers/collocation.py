"""Direct collocation (``method="collocation"``): Hermite–Simpson + IPOPT (CasADi).

``solve_collocation(problem, ...) -> SlewSolution`` — free final time, per-axis or p-norm
torque bound, rate limits, full-attitude or pointing-only targets, any number of
keep-out cones. Same result type as the indirect solver (``method="collocation"``).

Transcription
-------------
*Separated* Hermite–Simpson (Betts, *Practical Methods for Optimal Control*, §4.6) on
``N`` intervals of a fixed mesh in normalised time ``s = t / T`` (uniform unless a mesh is
given): states ``x = [q (4), ω (3)]`` and controls ``u (3)`` at the ``N + 1`` nodes and at the
``N`` interval midpoints, plus the final time ``T``. Per interval ``k`` (length
``h_k = T Δs_k``), two defects::

    Simpson   x_{k+1} - x_k - h_k/6 (f_k + 4 f_m + f_{k+1})       = 0
    Hermite   x_m - (x_k + x_{k+1})/2 - h_k/8 (f_k - f_{k+1})      = 0

(together the 3-stage Lobatto IIIA scheme, order 4 on smooth arcs). Dynamics as in
CONVENTIONS: ``q̇ = ½ q ⊗ [0, ω]``, ``J ω̇ = -ω × Jω + u``. Objective: ``min T``.
The control model of an interval is the quadratic through its node, midpoint and node
controls; the state model the cubic Hermite interpolant. (LGR is not implemented.)

Units: as the indirect solver, nondimensional — inertia ``J / J_max``, torque
``u / u_max`` (``u_max`` the largest per-axis bound), time ``t / τ`` with
``τ = sqrt(J_max / u_max)``; everything is reported in the problem's units.

Constraints
-----------
* start state fixed (variable bounds); final rate ``ω(T) = ωf`` (bounds);
* full-attitude target: ``Im(qf* ⊗ q(T)) = 0`` — three *linear* equations whose solution
  set is the line through ``±qf``: either sign of the quaternion is accepted, with no
  sign choice and no non-smooth function;
* pointing-only target: the homogeneous sensor direction ``d(q) = q ⊗ [0, s_b] ⊗ q*``
  (degree 2 in ``q``) at ``T`` satisfies ``e1·d = e2·d = 0`` (``e1, e2`` orthonormal and
  orthogonal to the target) and ``target·d ≥ 0``; the roll about the sensor is free;
* per-axis torque bound: box bounds ``|u_i| ≤ u_max,i`` on node and midpoint controls,
  **and** on the middle Bernstein coefficient ``2 u_m - (u_k + u_k+1)/2`` of each interval's
  quadratic: the quadratic is a convex combination of its three Bernstein coefficients,
  so it stays within the bound *between* the samples too. Without this the quadratic
  overshoots the bound by up to 25 % across a switch; clipping it then makes the flown
  control differ from the collocated one and the re-propagation missed R3's target by
  2e-3 rad; with it the miss is 3e-7 rad (and ``tf`` is higher by about 1e-4, relative);
* p-norm bound ``‖u / u_max‖_p ≤ 1`` at the samples and on the Bernstein coefficients
  (convex, so the whole quadratic is inside the ball): ``Σ v_i² ≤ 1`` for ``p = 2``, and
  ``Σ (v_i² + δ)^{p/2} ≤ 1`` with ``δ = 1e-10`` otherwise (``v_i = u_i / u_max,i``). ``δ`` makes
  the constraint twice differentiable at ``v_i = 0``; it is *conservative* (the feasible
  set lies inside the true ball, by at most ``3 δ^{p/2}`` in ``Σ|v_i|^p``);
* rate limit: box bounds ``|ω_i| ≤ rate_max,i`` on node and midpoint rates, and on the two
  inner Bernstein coefficients ``ω_k + h ω̇_k/3``, ``ω_k+1 - h ω̇_k+1/3`` of each interval's
  cubic rate (same argument: the cubic stays within the limit between the samples); a limit on
  the rate's norm, ``‖ω‖² ≤ rate_norm_max²`` (in units of the limit) at the interior nodes and
  on both inner coefficients (the ball is convex: the cubic stays inside it);
* keep-out cones: ``a·d(q) - cos(α + δ_c r) |q|² ≤ 0`` (homogeneous in ``q``) at the interior
  nodes and all midpoints (the end points are fixed by the start and the target, which
  ``SlewProblem`` checks and which may lie on a cone boundary, as in R4). ``δ_c`` is a
  back-off (0 at first), ramped in over the first and last two intervals by ``r``: the
  path can sag into a cone *between* the points (R4: by 2e-5 rad at N = 60), so after
  the solve the re-propagated path is checked and, while its interior margin is
  negative, the NLP is re-solved (warm) with ``δ_c`` increased by 1.5 times the violation
  (at most 4 times; ``route`` says the back-off used; R4 needs 1e-5 – 3e-5 rad, which
  costs about 1e-5 relative in ``tf``).

Quaternion norm: **not** enforced by a constraint. The start is a unit quaternion and
the kinematics preserve the norm; the scheme does so up to its truncation error (the
drift is reported, ``quaternion_norm_drift``, typically 1e-7 – 1e-5). ``|q|² = 1`` at every
node would duplicate what the defects already determine (a nearly dependent constraint,
bad for IPOPT). Cone and pointing constraints are homogeneous in ``q``, so the drift does
not affect them. Reported quaternions are normalised.

Starts, grids, budget
---------------------
Starts: the fastest eigenaxis slew within the bounds (``solvers.eigenaxis_slew``; for a
pointing target, to the attitude reached by the shortest rotation of the sensor; with
boundary rates, that path with the rates blended in), plus ``n_starts - 1`` (default 3)
seeded smooth perturbations of it — without them IPOPT never leaves the eigenaxis slew
about a principal axis (R5), a stationary point held by symmetry — plus, when the
eigenaxis path crosses a cone, two detours around the worst-crossed cone through a
way-point 5° outside it. A given ``SlewSolution`` (its samples) or ``solvers.Guess``
(propagated: bang-bang from its switch times, else the extremal of its costates)
replaces the eigenaxis guess (one start by default).

Every start is solved on a coarse grid of ``N / 2`` intervals (``N / 8`` with keep-out
cones: it picks the basin, faster and better; ``COARSE_DIVISOR_CONES``); the best one (and a
second within 0.2 % of it, mirror images excepted) is refined on ``N`` from its interpolated
solution; ``tf_tol = |tf(N) - tf(N/2)|`` (conservative: R3 measured 1.3e-4 relative error
against ``tf_tol`` 3e-4; with cones the ``N / 2`` answer is solved from the ``N`` one). The local optima seen on the coarse grid are listed in the
message (R5: 28.65 and 34.32, sometimes 29.4). IPOPT is stopped at the ``time_budget``
deadline (an iteration callback); if that happens before the refinement, the coarse
answer is returned with status 3.

Costates (covector mapping)
---------------------------
From the multipliers of the defect constraints. With IPOPT's Lagrangian
``T + νᵀ g_Simpson + μᵀ g_Hermite + ...``, stationarity with respect to a node state
``x_k`` splits into the part from the interval on its left (``L_k``) and on its right
(``R_k``); ``λ(t_k⁺) ≈ R_k`` and ``λ(t_k⁻) ≈ -L_k`` (they differ across an active cone
constraint, where the costate jumps). Reported node costates are ``(R_k - L_k) / 2``
(``R_0`` at the start, ``-L_N`` at the end), midpoint costates the mean of the two
neighbouring nodes'. Signs follow CONVENTIONS (``u_i = -u_max,i sign((J⁻¹λω)_i)``). The
gauge is fixed by projecting ``λq(t)`` orthogonal to ``q(t)`` (so ``λq(0)·q(0) = 0``; ``λq·q``
is a constant of the motion, so this is one gauge for all t), and the scale by ``H ≡ -1``
(division by minus the median of ``H`` over the samples; ``max |H + 1|`` afterwards is the
diagnostic ``hamiltonian_spread``). Units: ``λq`` times ``τ``, ``λω`` times ``τ²``, as the
indirect solver reports them. Measured accuracy: ``COSTATE_ACCURACY``.

Verification (``SlewSolution.verification``; each ``{value, tol, passed}``)
--------------------------------------------------------------------------
An independent re-propagation (classical RK4, 96 steps an interval, compiled:
``core.control_replay``; it agrees with scipy's DOP853 at ``rtol = 1e-10`` to ~3e-11) of the
returned control — the piecewise quadratic
above (clipped to the bound, a no-op to IPOPT's 1e-8 bound relaxation) — from the start
state. Checks:

* ``boundary_attitude_error`` — rad: angle of ``qf* ⊗ q(tf)`` (full attitude) or between the
  sensor and the target (pointing) at the end of the re-propagation;
* ``boundary_rate_error`` — ``‖ω(tf) - ωf‖`` of the re-propagation (problem units; the
  tolerance is nondimensional, divided by ``τ``);
* ``max_defect`` — largest residual of the NLP's equality constraints (nondimensional);
* ``cone_clearance`` — smallest clearance margin (rad) at the collocation points and on
  the re-propagated path (a certified lower bound at every instant, from 96 samples per
  interval, ``solvers.clearance``); must be ≥ -1e-6;
* ``rate_limit`` — ``max |ω_i| / rate_max,i`` and ``max ‖ω‖ / rate_norm_max`` on the same samples
  (with a rate limit), at most
  1 + 1e-9: the NLP keeps the limit at its points, and where the replayed path exceeds it
  between them (~1e-5 relative along an arc that rides the limit) the NLP is solved again with
  the limit scaled down by 1.5 times the excess (a back-off, up to 4 rounds);
* ``torque_bound`` — largest ``|u_i| / u_max,i`` (per-axis) or ``‖u / u_max‖_p`` of the NLP's
  controls;
* ``quaternion_norm_drift`` — ``max ||q| - 1|`` over the collocation points;
* ``hamiltonian_spread`` — diagnostic of the costate estimate, never fails.

Collocation is approximate, so the boundary tolerances are looser than the indirect
solver's 1e-8: ``1e-4`` rad and ``1e-4`` (nondimensional rate) at N = 60, scaled by
``(60 / N)²``, never below 1e-6 (measured: 3e-7 on R3, 2e-6 on R5, 5e-7 on R4 at N = 60).
When the default mesh misses them (a very unequal inertia: J = [1, 5, 10] over 180° misses by
1.7e-4 rad at N = 60), or the replay still exceeds an active rate limit after the back-off
below, the mesh is refined to 2N and 4N with the N = 60 tolerances kept.

Status: ``success`` only when IPOPT reports ``Solve_Succeeded`` (or
``Solved_To_Acceptable_Level``, constraints within 1e-6: degenerate NLPs with singular arcs
stop there) on the final grid and every check passes (else 1, not converged; 2, a check
failed; 3, budget). A rest-to-rest full-attitude answer without cones that is slower than the
eigenaxis slew (beyond ``tf_tol``) is a local optimum: status 4, never success. For a
per-axis bound, one no faster than it (within 0.1 %) is taken for the symmetric stationary
point (status 4) unless at least two symmetry-breaking (perturbed) starts converged and
agree: small slews are within 0.1 % of the eigenaxis slew.

Per-axis bound: ``switch_times`` are the zero crossings of the collocated torque between
clearly saturated samples (``|u_i| ≥ 0.5 u_max,i``), by linear interpolation: approximate,
to a fraction of an interval (R3, N = 60: within 3e-3 of the indirect ones), and a
singular or chattering arc (R4 BP2, axis 3) shows as extra switches; they do *not*
reproduce the trajectory on their own — ``control(t)`` does. p-norm: empty lists.
``u_first`` is the sign of each axis's first saturated sample.

Not covered: a cone set that blocks every path is rejected before solving
(``cone_passability.cones_block_every_path``: exact for up to three cones narrower than a
hemisphere; otherwise an optimistic grid test: gaps narrower than 0.5° count as open and are
left to IPOPT, which then reports infeasibility or converges); starts or targets inside a cone
are rejected by ``SlewProblem`` itself.
"""
from __future__ import annotations

import inspect
import math
import time
from dataclasses import dataclass
from typing import Optional

import numpy as np

from slew_env import SlewProblem
from slew_env.checks import is_integer, is_real
from slew_env.core.dynamics import state_rhs
from slew_env.core.quaternion import qerror_angle, qrotate
from slew_env.core.cones import angle_between
from .clearance import CLEARANCE_TOL, cone_clearances, margins
from .guesses import Guess
from .verify import failure_text, make_check
from .solution import (STATUS_BUDGET_EXHAUSTED, STATUS_MESSAGES, STATUS_NOT_CONVERGED, STATUS_SUCCESS,
                       STATUS_VERIFICATION_FAILED, STATUS_WORSE_THAN_BASELINE, SlewSolution)
from . import collocation_guesses, collocation_nlp, cone_passability

TRANSCRIPTIONS = ("hermite-simpson",)

# Tolerances of the verification checks (see the module docstring). The boundary
# tolerances are for N = 60 and scale with (60 / N)².
DEFAULT_TOLS = {
    "boundary_attitude_error": 1e-4,   # rad, at N = 60
    "boundary_rate_error": 1e-4,       # nondimensional (ω τ), at N = 60
    "max_defect": 1e-6,                # nondimensional
    "cone_clearance": CLEARANCE_TOL,   # rad (minimum allowed margin), -1e-6
    "rate_limit": 1.0 + 1e-9,          # max |ω_i| / rate_max_i on the re-propagated path (back-off: stage 3b)
    "torque_bound": 1.0 + 1e-6,        # NLP controls, in units of the bound
    "quaternion_norm_drift": 1e-4,
}

# Measured accuracy of the costate estimate against the indirect solver's extremal:
# relative error ‖λ_colloc - λ_indirect‖ / ‖λ_indirect‖ of costate0, and the median / max
# of the same along the samples (nondimensional costates; tests/test_collocation.py
# checks R3). Bang-bang (per-axis) costates converge slowly and irregularly, because
# the switches fall inside intervals; p-norm ones like h².
COSTATE_ACCURACY = {
    "R3 per-axis, N=30": {"costate0": 5.8e-3, "median": 6.1e-3, "max": 6.7e-3},
    "R3 per-axis, N=60": {"costate0": 5.8e-3, "median": 6.0e-3, "max": 6.3e-3},
    "R3 per-axis, N=120": {"costate0": 1.3e-3, "median": 1.3e-3, "max": 1.4e-3},
    "R3 p=2, N=60": {"costate0": 7.8e-5, "median": 1.3e-4, "max": 2.4e-4},
    "R3 p=2, N=120": {"costate0": 2.0e-5, "median": 3.2e-5, "max": 5.8e-5},
    "R5 per-axis, N=60": {"costate0": 1.1e-2, "median": 1.3e-2, "max": 1.4e-2},
    "R5 per-axis, N=120": {"costate0": 2.6e-3, "median": 3.1e-3, "max": 3.6e-3},
}

# IPOPT iterations allowed to one start on the coarse grid (a start that needs more is
# not worth refining; converged coarse solves take 20-200)
_COARSE_MAX_ITER = 200

# re-propagation samples per interval: dense enough for the certified clearance's
# second-order bound to stay within 1e-7 rad of the sampled margin
_SAMPLES_PER_INTERVAL = 96


# ----------------------------------------------------------------------------- post-processing
def _interp_control(U, Um, tk, sc: collocation_nlp.Scaled):
    """The collocation control model, ``u(t)``: on each interval the quadratic through the
    node, midpoint and node controls. The Bernstein constraint keeps it within the bound;
    it is clipped anyway (by at most IPOPT's bound relaxation, ~1e-8)."""
    per_axis = math.isinf(sc.p)

    def clip(v):
        if per_axis:
            return np.clip(v, -sc.U, sc.U)
        r = np.abs(v / sc.U)
        n = np.sum(r ** sc.p, axis=-1) ** (1.0 / sc.p)
        scale = np.where(n > 1.0, 1.0 / np.where(n > 0, n, 1.0), 1.0)
        return v * scale[..., None]

    def u_of(t):
        t = np.asarray(t, dtype=float)
        scalar = t.ndim == 0
        tt = np.atleast_1d(t)
        k = np.clip(np.searchsorted(tk, tt, side="right") - 1, 0, len(tk) - 2)
        s = (tt - tk[k]) / (tk[k + 1] - tk[k])
        l0 = 2.0 * (s - 0.5) * (s - 1.0)
        l1 = -4.0 * s * (s - 1.0)
        l2 = 2.0 * s * (s - 0.5)
        v = clip(l0[:, None] * U[k] + l1[:, None] * Um[k] + l2[:, None] * U[k + 1])
        return v[0] if scalar else v
    return u_of


@dataclass
class _Replay:
    t: Optional[np.ndarray]
    x: Optional[np.ndarray]
    nfev: int
    message: str
    u_of: object


def load_replay_kernels() -> None:
    """Call the kernels of ``_replay`` and ``_project_and_scale`` once on a one-interval
    trajectory, with the argument types they get there, so that they are loaded before a solve's
    clock starts (``kernel_loading``)."""
    from .core.control_replay import replay_quadratic_control
    x0 = np.array([1.0, 0, 0, 0, 0, 0, 0])
    U, J = np.zeros((2, 3)), np.ones(3)
    replay_quadratic_control(x0, np.array([0.0, 1.0]), U, np.zeros((1, 3)), np.ones(3), math.inf, J, 1, 1)
    state_rhs(x0, U[0], J)


def _replay(sc: collocation_nlp.Scaled, run: collocation_nlp.Run, samples=_SAMPLES_PER_INTERVAL) -> _Replay:
    """Independent re-propagation of the interpolated control from the start state: RK4,
    ``samples`` steps an interval, where the control is smooth (``core.control_replay``;
    it agrees with scipy's DOP853 at rtol 1e-10 to ~3e-11)."""
    from .core.control_replay import replay_quadratic_control
    T, X, Xm, U, Um = run.nlp.unpack(run.w)
    tk, _ = run.nlp.times(T)
    u_of = _interp_control(U, Um, tk, sc)
    t, x, nf = replay_quadratic_control(np.asarray(sc.x0, float), np.asarray(tk, float), np.asarray(U, float),
                                        np.asarray(Um, float), np.asarray(sc.U, float), float(sc.p),
                                        np.asarray(sc.J, float), int(samples), 1)
    if not np.all(np.isfinite(x)):
        return _Replay(None, None, int(nf), "the re-propagated state is not finite", u_of)
    return _Replay(t, x, int(nf), "", u_of)


def _switches(t, u, U):
    """Approximate switch times per axis and first-arc signs from sampled torques: zero
    crossings between clearly saturated samples (``|u_i| ≥ 0.5 u_max,i``)."""
    sw, first = [], np.zeros(3)
    for i in range(3):
        v = u[:, i] / U[i]
        sat = np.nonzero(np.abs(v) >= 0.5)[0]
        if sat.size == 0:
            sw.append(np.zeros(0))
            first[i] = float(np.sign(v[0])) if v[0] != 0 else 1.0
            continue
        first[i] = float(np.sign(v[sat[0]]))
        times = []
        for a, b in zip(sat[:-1], sat[1:]):
            if np.sign(v[a]) != np.sign(v[b]):
                seg = v[a:b + 1]
                j = a + int(np.nonzero(np.sign(seg[:-1]) != np.sign(seg[1:]))[0][-1])
                if v[j + 1] == v[j]:
                    times.append(0.5 * (t[j] + t[j + 1]))
                else:
                    times.append(t[j] + (t[j + 1] - t[j]) * v[j] / (v[j] - v[j + 1]))
        sw.append(np.array(times))
    return sw, first


def _costates(run: collocation_nlp.Run):
    """Covector mapping: costates (nondimensional, CONVENTIONS sign, unscaled) at the
    nodes and midpoints, from the defect multipliers."""
    nlp = run.nlp
    T, X, Xm, U, Um = nlp.unpack(run.w)
    N = nlp.N
    nu = run.lam_g[nlp.ig_simpson]
    mu = run.lam_g[nlp.ig_hermite]
    h = T * nlp.mesh
    Jrep = np.tile(nlp.sc.J[:, None], (1, N))
    dk, dk1 = nlp.tpl.dL(X[:N].T, Xm.T, X[1:].T, U[:N].T, Um.T, U[1:].T, h[None, :], Jrep, nu.T, mu.T)
    R = np.asarray(dk).T        # ∂/∂x_k of interval k's terms  (k = 0..N-1)
    L = np.asarray(dk1).T       # ∂/∂x_k+1 of interval k's terms
    lam = np.empty((N + 1, 7))
    lam[0] = R[0]
    lam[N] = -L[N - 1]
    lam[1:N] = 0.5 * (R[1:N] - L[0:N - 1])
    return lam, 0.5 * (lam[:-1] + lam[1:])


def _project_and_scale(sc, xx, uu, lam):
    """Gauge ``λq ⊥ q`` at every sample, then the scale ``H ≡ -1`` (by the median);
    returns the costates and ``max |H + 1|`` after scaling."""
    lam = lam.copy()
    q = xx[:, 0:4]
    lam[:, 0:4] -= (np.sum(lam[:, 0:4] * q, axis=1) / np.sum(q * q, axis=1))[:, None] * q
    H = np.array([float(lam[k] @ state_rhs(xx[k], uu[k], sc.J)) for k in range(xx.shape[0])])
    Hm = float(np.median(H))
    if Hm == 0.0 or not math.isfinite(Hm):
        return lam, math.inf
    c = -1.0 / Hm
    return lam * c, float(np.max(np.abs(H * c + 1.0)))


def _tf_tol(T, tau, Tc, miss_tol):
    """``tf_tol``: the change of ``T`` from the comparison grid's ``Tc`` (never below 1e-10
    relative), or, without one (NaN), ``miss_tol`` (the re-propagation's boundary miss)."""
    return max(abs(T - Tc) * tau, T * tau * 1e-10) if math.isfinite(Tc) else miss_tol


def _post(sc: collocation_nlp.Scaled, run: collocation_nlp.Run, Tc, tols, rep: _Replay):
    """SlewSolution fields and the verification checks of a solved run."""
    prob = sc.prob
    nlp = run.nlp
    N = nlp.N
    T, X, Xm, U, Um = nlp.unpack(run.w)
    tk, tm = nlp.times(T)
    tau = sc.tau
    n_all = 2 * N + 1
    t_all = np.empty(n_all)
    t_all[0::2], t_all[1::2] = tk, tm
    x_all = np.empty((n_all, 7))
    x_all[0::2], x_all[1::2] = X, Xm
    u_all = np.empty((n_all, 3))
    u_all[0::2], u_all[1::2] = U, Um
    norms = np.linalg.norm(x_all[:, 0:4], axis=1)
    drift = float(np.max(np.abs(norms - 1.0)))
    lam, lam_m = _costates(run)
    lam_all = np.empty((n_all, 7))
    lam_all[0::2], lam_all[1::2] = lam, lam_m
    lam_all, H_spread = _project_and_scale(sc, x_all, u_all, lam_all)
    costate = np.hstack([lam_all[:, 0:4] * tau, lam_all[:, 4:7] * tau ** 2])
    # ---- checks
    checks = {}
    scale2 = (60.0 / N) ** 2
    tol_att = max(1e-6, tols["boundary_attitude_error"] * scale2)
    tol_rate = max(1e-6, tols["boundary_rate_error"] * scale2)
    if rep.x is None:
        checks["propagation"] = make_check(1.0, 0.0, False)
        att = rate = math.inf
    else:
        xT = rep.x[-1]
        qT = xT[0:4] / np.linalg.norm(xT[0:4])
        if prob.qf is not None:
            att = float(qerror_angle(qT, prob.qf))
        else:
            att = float(angle_between(np.asarray(qrotate(qT, prob.sensor_axis)), prob.sensor_target))
        rate = float(np.linalg.norm(xT[4:7] - sc.wf))
    checks["boundary_attitude_error"] = make_check(att, tol_att, att <= tol_att)
    checks["boundary_rate_error"] = make_check(rate / tau, tol_rate / tau, rate <= tol_rate)
    gval = nlp.g(run.w, run.delta)
    max_def = float(np.max(np.abs(gval[:nlp.n_eq])))
    checks["max_defect"] = make_check(max_def, tols["max_defect"], max_def <= tols["max_defect"])
    if prob.cones:
        m = float(np.min(margins(prob, x_all[:, 0:4])))
        if rep.x is not None:
            # at every instant of the re-propagated path, not only at its samples
            m = min(m, _certified_clearance(prob, tau, rep.t, rep.x))
        else:
            m = -math.inf
        checks["cone_clearance"] = make_check(m, tols["cone_clearance"], m >= tols["cone_clearance"])
    if prob.has_rate_limit:
        worst = max(sc.rate_ratio(x_all[:, 4:7]), sc.rate_ratio(rep.x[:, 4:7])) if rep.x is not None else math.inf
        checks["rate_limit"] = make_check(worst, tols["rate_limit"], worst <= tols["rate_limit"])
    if math.isinf(sc.p):
        tb = float(np.max(np.abs(u_all) / sc.U))
    else:
        tb = float(np.max(np.sum(np.abs(u_all / sc.U) ** sc.p, axis=1) ** (1.0 / sc.p)))
    checks["torque_bound"] = make_check(tb, tols["torque_bound"], tb <= tols["torque_bound"])
    checks["quaternion_norm_drift"] = make_check(drift, tols["quaternion_norm_drift"],
                                             drift <= tols["quaternion_norm_drift"])
    # diagnostic only (never fails): how far the costate estimate is from H ≡ -1
    checks["hamiltonian_spread"] = make_check(H_spread, math.inf, True)
    # ---- tf tolerance: the change from the coarse grid, or else the boundary miss of the
    # re-propagation as a relative time (an order of magnitude only)
    miss_tol = max(T * tau * max(att, rate) if math.isfinite(att) else math.inf, T * tau * 1e-10)
    tf_tol = _tf_tol(T, tau, Tc, miss_tol)
    if math.isinf(sc.p):
        sw, first = _switches(t_all, u_all, sc.U)
        sw = [s * tau for s in sw]
    else:
        sw = [np.zeros(0)] * 3
        first = np.sign(u_all[0])
    u_of = rep.u_of

    def control(tq):
        return u_of(np.asarray(tq, dtype=float) / tau) * sc.umax0
    return dict(tf=T * tau, tf_tol=tf_tol, costate0=costate[0].copy(), switch_times=sw, u_first=first,
                t=t_all * tau, q=x_all[:, 0:4] / norms[:, None], omega=x_all[:, 4:7] / tau,
                u=u_all * sc.umax0, costate=costate, _control=control, guess=run.source,
                verification=checks), checks


# ----------------------------------------------------------------------------- the solver
def _regrid(run: collocation_nlp.Run, nlp_new: collocation_nlp.NLP):
    """Interpolate a solved run onto another mesh (a warm start)."""
    T, X, Xm, U, Um = run.nlp.unpack(run.w)
    tk, tm = run.nlp.times(T)
    t = np.concatenate([tk, tm])
    o = np.argsort(t, kind="stable")
    xs = np.vstack([X, Xm])[o]
    us = np.vstack([U, Um])[o]
    return collocation_guesses.TrajGuess(T, t[o], xs[:, 0:4], xs[:, 4:7], us, run.source).sample(nlp_new)


def _coarse_mesh(mesh, Nc):
    """A mesh of ``Nc`` intervals with the same end points (merging neighbours)."""
    N = mesh.shape[0]
    if N % Nc == 0:
        return mesh.reshape(Nc, -1).sum(axis=1)
    edges = np.concatenate([[0.0], np.cumsum(mesh)])
    sel = np.round(np.linspace(0, N, Nc + 1)).astype(int)
    return np.diff(edges[sel])


def _certified_clearance(prob, tau, t, x):
    """Certified minimum margin (rad, every instant) of a re-propagated path ``x = [q, ω]`` in
    nondimensional units (``solvers.clearance.cone_clearances``)."""
    per = cone_clearances(prob, t * tau, x[:, 0:4], x[:, 4:7] / tau)
    return min(p[1] for p in per) if per else math.inf


def _back_off(sc, best, rep, deadline, failures, solve_round, excess, rounds=4):
    """Re-solve ``best`` while its replay ``rep`` shows a positive ``excess(run, rep)`` (a
    constraint kept at the collocation points but not between them), each round by
    ``solve_round(run, excess, warm) -> (run, label)`` from the last answer: ``(best, rep, nit,
    nfev)``. A round starts from the answer's primal-dual point (``warm``); one that fails, leaves
    the answer's basin or makes no progress (its replay's excess not below the last) is tried
    again cold; if that fails too, it is recorded in ``failures`` and the last good answer kept."""
    nit = nfev = 0
    if not best.success or rep.x is None:
        return best, rep, nit, nfev
    for _ in range(rounds):
        e = excess(best, rep)
        if not e > 0.0 or time.perf_counter() > deadline:
            break
        first_why = None
        # warm first: a back-off moves the constraints by about 1e-5, and IPOPT restarted from
        # the answer's primal-dual point needs 1-5 iterations where a cold start needs 9-52
        # (12 pointing-cones problems, seed 0, N = 80: 15-43 ms against 75-373 ms, the same T
        # within 1e-6). A cold start also pushes the variables off their bounds (the bang-bang
        # torques sit on them) and can leave the basin (seed 0 problem 35 with starts on 40
        # intervals: cold +5.5 %, warm within 1e-6); it is the repair when the warm start fails.
        # A warm start can also accept its starting point as it is (0 iterations on a rate
        # back-off of 1e-8: only the states are moved inside the bounds, the replay is unchanged;
        # session 27's review, full-attitude seed 5 problem 29): no progress is a failure too
        # (where the warm-started solver cannot be built in the time left, the "warm" round would be
        # the cold one, solved twice on failure: the cold round alone)
        nlp = getattr(best, "nlp", None)
        modes = (True, False) if nlp is None or nlp.warm_ready(deadline) else (False,)
        for warm in modes:
            r, label = solve_round(best, e, warm)
            nit += r.nit
            nfev += r.nfev
            # a back-off moves the answer by about its own size; a larger move is a jump to
            # another local optimum (seen: +36 % for a 3.4e-5 rad cone back-off), not a repair
            tag = ", warm" if warm else ", cold"
            rep_r = None
            if not r.success:
                why = f"{best.source} ({label}{tag}): {r.status}"
            elif abs(r.T - best.T) > max(1e-3, 10.0 * e) * best.T:
                why = (f"{best.source} ({label}{tag}): left the answer's basin "
                       f"(T {best.T:.6g} → {r.T:.6g})")
            else:
                why = None
                rep_r = _replay(sc, r)
                nfev += rep_r.nfev
                if warm and rep_r.x is not None:
                    e_r = excess(r, rep_r)
                    if e_r > 0.0 and not e_r < e:
                        why = f"{best.source} ({label}{tag}): no progress (excess {e:.3g} → {e_r:.3g})"
            if why is None:
                if first_why is not None:
                    failures.append(f"{first_why}; repaired: the cold restart stayed in the basin")
                break
            if not warm:
                failures += [w for w in (first_why, why) if w is not None]
                break
            if time.perf_counter() > deadline:
                failures.append(why)
                break
            first_why = why
        if why is not None:
            break
        best, rep = r, rep_r
    return best, rep, nit, nfev


def _interior_clearance(prob, rep: _Replay, run: collocation_nlp.Run, tau):
    """Certified smallest margin of the re-propagated path away from the first and last
    interval (there the start and the target fix the path; a back-off cannot help)."""
    tk, _ = run.nlp.times(run.T)
    sel = (rep.t >= tk[1]) & (rep.t <= tk[-2])
    if np.count_nonzero(sel) < 2:
        return math.inf
    return _certified_clearance(prob, tau, rep.t[sel], rep.x[sel])


# intervals by default: 60, and 80 with keep-out cones (chosen with starts on N / 2). With cones the NLP has many local
# optima and which one IPOPT reaches depends on the mesh (the constraints sit at the nodes and
# midpoints). Measured on 60 random pointing-cones problems against the best of 60, 80 and 120
# intervals: mean gap 0.91 % (60), 0.39 % (80), 0.19 % (120); worst 34 %, 6.6 %, 9 %; median
# time 0.80 s, 0.79 s, 1.87 s (benchmarks/RESULTS.md).
DEFAULT_INTERVALS = 60
DEFAULT_INTERVALS_CONES = 80

# the starts' grid, with keep-out cones: N / 8 intervals (10 for the default 80), not N / 2. It
# picks the basin, and with fewer cone points IPOPT reaches the better ones more often: on 300
# seeded pointing-cones problems, against the best of N/2, N/4 and N/8, the mean tf gap was
# 1.7e-3 (N/2), 6.9e-4 (N/4), 6.0e-4 (N/8), with 13, 5 and 5 answers more than 1 % slower, and
# `auto` took 0.9, 0.6 and 0.5 s (median; runs/s15/coarse_probe.py). On 150 problems of another
# seed, after the choice: 4.7e-3, 1.3e-3, 1.3e-3 and 9, 7, 4; exact extremals 126, 123, 120 (most
# of those lost are faster answers riding a cone)
COARSE_DIVISOR_CONES = 8
MAX_INTERVALS = 5000     # about 80,000 NLP variables; 10**6 exhausted memory in CasADi


def check_scalar_options(**opts) -> None:
    """``solve_collocation``'s scalar options given in ``opts``, each a ``ValueError`` naming it
    (``solve`` checks its ``collocation`` dict with this whatever the route, before any NLP
    is built: a negative ``tol`` reached IPOPT, a text ``seed`` numpy)."""
    for k, v in opts.items():
        if k == "transcription" and v not in TRANSCRIPTIONS:
            raise ValueError(f"transcription: unknown transcription {v!r}; choose one of {', '.join(TRANSCRIPTIONS)}")
        if k == "tol" and not (is_real(v) and math.isfinite(v) and v > 0):
            raise ValueError(f"tol: must be a positive number, got {v!r:.80}")
        if k == "max_iter" and not (is_integer(v) and v >= 1):
            raise ValueError(f"max_iter: must be a positive integer, got {v!r:.80}")
        if k == "time_budget" and not (is_real(v) and v > 0 and not math.isnan(v)):
            raise ValueError(f"time_budget: must be a positive number of seconds, got {v!r:.80}")
        if k == "n_starts" and v is not None and not (is_integer(v) and v >= 1):
            raise ValueError(f"n_starts: must be a positive integer, got {v!r:.80}")
        if k == "seed" and not (is_integer(v) and 0 <= v < 2 ** 63):
            raise ValueError(f"seed: must be an integer ≥ 0, got {v!r:.80}")
        if k in ("verbose", "coarse", "defer_tf_tol") and not isinstance(v, (bool, np.bool_)):
            # bool("no") is True: text or numbers here are refused, not guessed at
            raise ValueError(f"{k}: must be True or False, got {v!r:.80}")


def _check_intervals(N, in_list=False) -> int:
    """``N`` as an int, or ``ValueError`` naming ``n_intervals``."""
    if not is_integer(N):
        raise ValueError(f"n_intervals: expected {'integers ≥ 2 in the list' if in_list else 'an integer ≥ 2'}, "
                         f"got {N!r}")
    if N < 2:
        raise ValueError(f"n_intervals: must be at least 2, got {N}")
    if N > MAX_INTERVALS:
        raise ValueError(f"n_intervals: at most {MAX_INTERVALS:,} (an NLP of {N:,} intervals would not fit in "
                         f"memory), got {N:,}")
    return int(N)


def _best_of_meshes(prob, meshes, t_start, **kw) -> SlewSolution:
    """``solve_collocation`` on each mesh in ``meshes``, the fastest verified answer."""
    if not meshes:
        raise ValueError("n_intervals: an empty list of meshes")
    if kw.get("mesh") is not None:
        raise ValueError("mesh: a custom mesh fixes N; give one n_intervals with it, not a list")
    for N in meshes:
        _check_intervals(N, in_list=True)
    budget = kw.pop("time_budget")
    sols = []
    for N in meshes:
        left = budget - (time.perf_counter() - t_start)
        if sols and left <= 0.0:
            break
        sols.append(solve_collocation(prob, n_intervals=N, time_budget=max(left, 1e-3), **kw))
    ok = [x for x in sols if x.success]
    best = min(ok, key=lambda x: x.tf) if ok else sols[-1]
    best.nit = sum(x.nit for x in sols)
    best.nfev = sum(x.nfev for x in sols)
    best.wall_time = time.perf_counter() - t_start
    best.candidates_tf = sorted({round(float(t), 9) for x in sols for t in (x.candidates_tf or [])})
    tried = ", ".join(f"N={x_N}: " + (f"{x.tf:.6g}" if x.success else "failed") for x_N, x in zip(meshes, sols))
    best.route = f"best of meshes ({tried}): {best.route}"
    return best


# checks that a finer mesh can repair: the replay's miss of the target, and what happens
# between the collocation points
_MESH_CHECKS = {"boundary_attitude_error", "boundary_rate_error", "roll_transversality", "quaternion_norm_drift",
                "cone_clearance", "rate_limit"}
MESH_REFINEMENTS = 2     # default mesh only: N → 2N → 4N while the replay misses


def _mesh_limited(sol) -> bool:
    failed = {k for k, c in (sol.verification or {}).items() if not c.get("passed", True)}
    return sol.status == STATUS_VERIFICATION_FAILED and bool(failed) and failed <= _MESH_CHECKS


# where the comparison solve that measures tf_tol gave nothing (no time to run it or to build its
# NLP, or an answer in another basin), tf_tol is the replay's boundary miss, which can be far
# smaller than the discretisation error (seen: 5.8e-7 and 7.1e-7 against 3.5e-4 and 2.3e-4)
TF_TOL_ESTIMATE_NOTE = (" tf_tol is the replay's boundary-miss estimate: the comparison solve that measures the "
                        "discretisation error gave nothing (no time for it, or an answer in another basin), and "
                        "the estimate may understate that error.")


def settle_tf_tol(sol, budget: float = 5.0):
    """Run the ``N / 2`` comparison solve that ``defer_tf_tol`` skipped and set ``sol.tf_tol``
    (its work added to ``nit``, ``nfev`` and ``wall_time``); nothing if none is pending."""
    pending = getattr(sol, "_tf_tol_pending", None)
    if pending is None:
        return sol
    t0 = time.perf_counter()
    sol._tf_tol_pending = None
    sol.tf_tol, n1, n2, measured = pending(float(budget))
    if not measured:
        sol.message += TF_TOL_ESTIMATE_NOTE
    sol.nit += n1
    sol.nfev += n2
    sol.wall_time += time.perf_counter() - t0
    return sol


def solve_collocation(problem, *, n_intervals: Optional[int] = None, transcription: str = "hermite-simpson",
                      guess=None, tol: float = 1e-8, max_iter: int = 3000, time_budget: float = 60.0,
                      verbose: bool = False, n_starts: Optional[int] = None, seed: int = 0,
                      coarse: bool = True, mesh=None, tols: Optional[dict] = None,
                      extra_starts=(), defer_tf_tol: bool = False, _before_refinement=None,
                      _refinement_extra: float = 0.0) -> SlewSolution:
    """Time-optimal slew of ``problem`` by Hermite–Simpson direct collocation and IPOPT.

    Parameters
    ----------
    problem : SlewProblem or dict
    n_intervals : int ≥ 2, or a list of them, optional
        Collocation intervals ``N`` (``N + 1`` nodes and ``N`` midpoints). Default 60, and 80
        for a problem with keep-out cones (``DEFAULT_INTERVALS_CONES``: the mesh changes which
        local optimum IPOPT reaches there, and 80 does better than 60 at the same cost). With
        the default, an answer whose replay fails only on what a finer mesh repairs (the
        boundary miss, the clearance between points) is solved again on 2N, then 4N
        (``MESH_REFINEMENTS``), from itself, held to the default mesh's tolerances; then on
        meshes whose intervals where the control or the rates change fast are split in 8
        (``LOCAL_ROUNDS`` rounds). With a rate limit that every axis reaches within a quarter of
        an interval (short acceleration arcs in a long coast) the local refinement goes first. A
        list solves on each mesh in turn (one time budget for all) and returns the fastest
        verified answer: with cones, ``[80, 120]`` reached the best of 60, 80 and 120 intervals
        on all of 60 test problems, at about 3x the time of 80 alone.
    transcription : ``"hermite-simpson"``
        The only transcription implemented (separated form; module docstring).
    guess : None, SlewSolution or solvers.Guess
        None: the eigenaxis slew (and its perturbations, and cone detours when it crosses
        a cone). A ``SlewSolution``: its dense samples. A ``Guess``: propagated (bang-bang
        from its switch times, else the extremal of its costates).
    tol : float
        IPOPT ``tol`` (``constr_viol_tol`` is ``min(tol, 1e-8)``).
    max_iter : int
        IPOPT iteration limit of each solve.
    time_budget : float
        Seconds for the whole call; IPOPT is stopped at the deadline.
    verbose : bool
        IPOPT's iteration output.
    n_starts : int, optional
        Initial guesses tried (default 4 without a guess: the eigenaxis guess and three
        seeded smooth perturbations of it, which break the symmetry that holds IPOPT on the
        eigenaxis slew about a principal axis; 1 with a guess). Cone detours come on top.
    seed : int
        Seed of the perturbations.
    coarse : bool
        Solve every start on ``max(2, N // 2)`` intervals first (with keep-out cones on ``N // 8``,
        at least ``min(10, N // 2)``: ``COARSE_DIVISOR_CONES``), refine the best (and a second
        one within 0.2 % of it) on ``N``; ``tf_tol = |tf(N) - tf(N/2)|`` (with cones from an
        ``N / 2`` solve started from the answer). Without it
        every start is solved on ``N`` and ``tf_tol`` is a rough estimate from the boundary
        miss of the re-propagation.
    mesh : optional, ``N`` positive interval fractions (normalised to sum 1). Uniform by default.
    tols : dict, optional
        Overrides of ``DEFAULT_TOLS`` (the verification tolerances).
    extra_starts : sequence of ``solvers.Guess``, optional
        More starts, each propagated (bang-bang from its switch times, else the extremal of its
        costates) and solved with the others on the coarse grid; one whose propagation fails or
        is not finite is skipped. ``auto`` gives the nearest solutions of the shipped
        pointing-cones table here (``cone_routes.CONE_NEIGHBOUR_STARTS``).
    defer_tf_tol : bool
        With cones, skip the ``N / 2`` solve that measures ``tf_tol`` (about a fifth of the
        call's time): the answer's ``tf_tol`` is NaN until ``settle_tf_tol(answer)`` runs that
        solve. For a caller that usually replaces the answer by an exact extremal (``auto``'s
        refinements, whose tolerance on ``tf_tol`` has a floor of 1e-3 relative) and settles it
        only when it needs the value or returns the answer.
    _before_refinement : callable, optional
        For ``auto`` (not a ``solve`` option): called with the default mesh's answer where its
        replay fails only on what a finer mesh repairs, before any finer mesh is built; an
        answer it returns is returned as it is, and the finer meshes are not solved (``None``:
        they are; the time it took comes out of ``time_budget``, and ``_refinement_extra`` s are
        added to it: ``auto``'s reserve for the attempt the hook has made).

    Returns a ``SlewSolution`` (``method="collocation"``); see the module docstring for
    the fields, the checks and the statuses.
    """
    t_start = time.perf_counter()
    if extra_starts is None:
        extra_starts = ()
    if (isinstance(extra_starts, (str, bytes, Guess)) or not hasattr(extra_starts, "__iter__")
            or not all(isinstance(g, Guess) for g in extra_starts)):
        raise ValueError(f"extra_starts: expected a sequence of solvers.Guess, got {extra_starts!r:.80}")
    kw = dict(transcription=transcription, tol=tol, max_iter=max_iter, verbose=verbose, seed=seed, coarse=coarse,
              tols=tols)
    evidence = {}
    sol = _solve_collocation_mesh(problem, n_intervals=n_intervals, guess=guess, time_budget=time_budget,
                                  n_starts=n_starts, mesh=mesh, evidence=evidence, extra_starts=extra_starts,
                                  defer_tf_tol=defer_tf_tol, **kw)
    if n_intervals is not None or mesh is not None or not _mesh_limited(sol):
        return sol
    if _before_refinement is not None:
        other = _before_refinement(sol)
        if other is not None:
            return other
        time_budget += float(_refinement_extra)
    # the default mesh is too coarse for this problem (fast axes of a very unequal inertia,
    # say): the replay of its control misses. Solve again on a finer mesh from this answer:
    # uniform (N → 2N → 4N), then refined only where the control or the rates change fast; with a
    # rate limit the local refinement first (a tight limit's short acceleration arcs in a long
    # coast: 90° at 0.1 deg/s, whose 1.2 s arcs the uniform meshes of 13, 6.5 and 3.2 s could
    # not follow, converged on 158 intervals refined at the ends; ``_short_rate_arcs``)
    prob = sol.problem
    N = DEFAULT_INTERVALS_CONES if prob.cones else DEFAULT_INTERVALS
    first = sol
    base = dict(DEFAULT_TOLS, **(tols or {}))

    def held(n):
        # the default mesh's boundary tolerances on n intervals (they scale with (N / n)²: a
        # problem that needs the finer mesh converges like the default one would, not better)
        return dict(base, **{c: base[c] * (n / N) ** 2 for c in ("boundary_attitude_error", "boundary_rate_error")})

    def attempt(n, mesh, guess, left, what):
        """The solve on ``n`` intervals (``mesh``: their fractions, or uniform), from ``guess``,
        its route and message saying ``what`` was refined and why."""
        out = _solve_collocation_mesh(prob, n_intervals=n, guess=guess, time_budget=left, n_starts=1, mesh=mesh,
                                      evidence=evidence, **dict(kw, tols=held(n)))
        note = (f"{what}, with the boundary tolerances of N={N} (at N={N} the replay failed: "
                f"{failure_text(first.verification)[:160]})")
        out.route = f"{out.route}; {note}"
        out.message = f"{out.message} {note[0].upper()}{note[1:]}."
        out.wall_time = time.perf_counter() - t_start
        return out

    def uniform(sol):
        """``(answer to return or None, the last mesh-limited answer)``."""
        for k in range(1, MESH_REFINEMENTS + 1):
            left = time_budget - (time.perf_counter() - t_start)
            if left < 2.0:      # building a finer NLP alone takes up to a few seconds
                break
            finer = attempt(N * 2 ** k, None, sol, left, f"mesh refined to N={N * 2 ** k}")
            if finer.success:
                return finer, sol
            if not _mesh_limited(finer):
                # the finer mesh failed for another reason (time, IPOPT): the default mesh's answer,
                # whose only fault is its accuracy, is the more useful one to return
                first.message = (f"{first.message} A finer mesh (N={N * 2 ** k}) did not help: "
                                 f"{finer.message[:200]}")
                first.wall_time = time.perf_counter() - t_start
                return first, sol
            sol = finer
        return None, sol

    def local(sol):
        """``(verified answer or None, the last mesh-limited answer)``: rounds of
        ``_local_edges`` from the default mesh's answer, then from each refined one."""
        edges, last = np.linspace(0.0, 1.0, N + 1), first
        for k in range(LOCAL_ROUNDS):
            left = time_budget - (time.perf_counter() - t_start)
            edges = _local_edges(last, edges) if left >= 2.0 else None
            if edges is None or edges.size - 1 > LOCAL_MAX_INTERVALS:
                break       # (a control that changes fast everywhere: no local refinement to make)
            n_loc = edges.size - 1
            fine = attempt(n_loc, list(np.diff(edges)), last, left,
                           f"mesh refined where the control or the rates change fast ({n_loc} intervals, round {k + 1})")
            if fine.success:
                return fine, sol
            if not _mesh_limited(fine):
                break
            sol = last = fine
        return None, sol

    for refine in ((local, uniform) if _short_rate_arcs(prob, first.tf / N) else (uniform, local)):
        answer, sol = refine(sol)
        if answer is not None:
            return answer
    sol.wall_time = time.perf_counter() - t_start
    return sol


LOCAL_SPLIT = 8     # parts an interval is split into where the control or the rates change fast
LOCAL_ROUNDS = 3    # rounds of that refinement (each from the answer before)
LOCAL_MAX_INTERVALS = 600   # and the most intervals it builds (its NLP cannot be interrupted)


def _short_rate_arcs(prob, h) -> bool:
    """Whether every axis reaches its rate limit from rest at full torque within a quarter of the
    default mesh's interval ``h``: arcs that 2N and 4N uniform intervals cannot follow either, so
    the local refinement goes first (elsewhere uniform refinement, the cheaper where it works,
    goes first: J = [1, 2, 3] at 0.05 rad/s needs 120 uniform intervals, 193 local ones)."""
    if not prob.has_rate_limit:
        return False
    # (the limit an axis meets alone: its own, or the norm's)
    limit = np.minimum(np.inf if prob.rate_max is None else np.asarray(prob.rate_max, float),
                       np.inf if prob.rate_norm_max is None else prob.rate_norm_max)
    t_reach = limit * np.asarray(prob.inertia, float) / np.asarray(prob.torque_max, float)
    return bool(np.max(t_reach) < 0.25 * h)


def _local_edges(sol, edges):
    """The mesh ``edges`` (fractions of ``tf``, 0 to 1) with every interval over which a torque
    component of ``sol``'s samples changes by more than a fifth of its bound, or a rate
    component by more than a fifth of its limit, and its neighbours, split in ``LOCAL_SPLIT``;
    ``None`` where no interval has such a change (or ``sol`` has no samples)."""
    t, u, w = np.asarray(sol.t, float), np.asarray(sol.u, float), np.asarray(sol.omega, float)
    if t.size < 2 or u.shape != (t.size, 3) or w.shape != (t.size, 3) or not (sol.tf > 0.0) \
            or not (np.all(np.isfinite(u)) and np.all(np.isfinite(w))):
        return None
    prob = sol.problem
    scaled = u / np.asarray(prob.torque_max, float)
    if prob.rate_max is not None:
        scaled = np.hstack([scaled, w / np.asarray(prob.rate_max, float)])
    if prob.rate_norm_max is not None:
        scaled = np.hstack([scaled, np.linalg.norm(w, axis=1, keepdims=True) / prob.rate_norm_max])
    n = edges.size - 1
    x = t / sol.tf
    k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, n - 1)
    hi = np.full((n, scaled.shape[1]), -np.inf)
    lo = np.full((n, scaled.shape[1]), np.inf)
    np.maximum.at(hi, k, scaled)
    np.minimum.at(lo, k, scaled)
    # a sample on an interval's start also ends the interval before it
    ends = np.flatnonzero((k > 0) & np.isclose(x, edges[k], rtol=0.0, atol=1e-12))
    np.maximum.at(hi, k[ends] - 1, scaled[ends])
    np.minimum.at(lo, k[ends] - 1, scaled[ends])
    change = np.where(np.isfinite(hi) & np.isfinite(lo), hi - lo, 0.0).max(axis=1) > 0.2
    if not change.any():
        return None
    hit = change.copy()
    hit[1:] |= change[:-1]
    hit[:-1] |= change[1:]
    parts = [edges[:1]]
    for j in range(n):
        m = LOCAL_SPLIT if hit[j] else 1
        parts.append(np.linspace(edges[j], edges[j + 1], m + 1)[1:])
    return np.concatenate(parts)


# solve_collocation's keyword options (``solve``'s ``collocation`` dict is checked against them)
SOLVE_OPTIONS = tuple(k for k in inspect.signature(solve_collocation).parameters if not k.startswith("_"))[1:]


def _grids(N, cones, coarse):
    """``(Nc, N_half)``: the starts' coarse grid (None without ``coarse``) and the grid of the
    ``N / 2`` comparison that gives ``tf_tol`` (None where the starts' grid gives it)."""
    Nc = None
    if coarse and N >= 4:
        Nc = max(min(10, N // 2), N // COARSE_DIVISOR_CONES) if cones else max(2, N // 2)
    # tf_tol is the change from N / 2 intervals: with a coarser starts' grid, an N / 2 solve from
    # the answer gives it
    # (not when N / 2 is barely finer than the starts' grid: then the starts' answer gives it)
    N_half = max(2, N // 2) if Nc is not None and 2 * Nc <= max(2, N // 2) else None
    return Nc, N_half


def prebuild_nlps(problem, n_intervals=None, tol=1e-8, max_iter=3000, coarse=True, verbose=False) -> float:
    """Build the NLPs that a collocation solve of ``problem`` on one mesh of ``n_intervals``
    (default: the default mesh) uses: the starts' coarse grid, the mesh (and, with cones or a rate
    limit, its warm-started solver for the back-off rounds), the ``N / 2`` comparison
    grid. Seconds spent (0 where they are built already). ``solve`` calls it before its clock
    starts for pointing targets and cones, whose default route begins with collocation: building
    an NLP cannot be interrupted (0.05–1.2 s the first time in a process)."""
    prob = SlewProblem.from_dict(problem)
    if n_intervals is None:
        n_intervals = DEFAULT_INTERVALS_CONES if prob.cones else DEFAULT_INTERVALS
    N = _check_intervals(n_intervals)
    Nc, N_half = _grids(N, bool(prob.cones), coarse)
    sc = collocation_nlp.Scaled.of(prob)
    coarse_tol, coarse_iter = max(tol, 1e-7), min(max_iter, _COARSE_MAX_ITER)
    t0 = time.perf_counter()
    for n, tl, mi in [(Nc, coarse_tol, coarse_iter), (N, tol, max_iter), (N_half, coarse_tol, coarse_iter)]:
        if n is not None:
            tpl = collocation_nlp.nlp_template(n, prob.is_pointing, len(prob.cones), float(sc.p),
                                               sc.rate_kind, float(tl), int(mi), bool(verbose))
            if n == N and (prob.cones or prob.has_rate_limit):
                tpl.warm_solver     # the back-off rounds start from the answer's primal-dual point
    return time.perf_counter() - t0


def _solve_collocation_mesh(problem, *, n_intervals, transcription, guess, tol, max_iter, time_budget, verbose,
                            n_starts, seed, coarse, mesh, tols, evidence=None, extra_starts=(),
                            defer_tf_tol=False) -> SlewSolution:
    """``solve_collocation`` on one mesh (or each mesh of a list). ``evidence``: a dict that
    carries the saddle rule's count of agreeing symmetry-breaking starts between meshes."""
    t_start = time.perf_counter()
    evidence = {} if evidence is None else evidence
    prob = SlewProblem.from_dict(problem)
    if n_intervals is None:
        n_intervals = DEFAULT_INTERVALS_CONES if prob.cones else DEFAULT_INTERVALS
    if isinstance(n_intervals, (list, tuple)):
        return _best_of_meshes(prob, list(n_intervals), t_start, transcription=transcription, guess=guess,
                               tol=tol, max_iter=max_iter, time_budget=time_budget, verbose=verbose,
                               n_starts=n_starts, seed=seed, coarse=coarse, mesh=mesh, tols=tols,
                               extra_starts=extra_starts)
    N = _check_intervals(n_intervals)
    check_scalar_options(transcription=transcription, tol=tol, max_iter=max_iter, time_budget=time_budget,
                         n_starts=n_starts, seed=seed, verbose=verbose, coarse=coarse,
                         defer_tf_tol=defer_tf_tol)
    if guess is not None and not isinstance(guess, (SlewSolution, Guess)):
        raise ValueError(f"guess: expected a SlewSolution, a solvers.Guess or None, got {type(guess).__name__}")
    tols_all = dict(DEFAULT_TOLS)
    if tols:
        unknown = set(tols) - set(DEFAULT_TOLS)
        if unknown:
            raise ValueError(f"tols: unknown check(s) {sorted(unknown)}; known: {sorted(DEFAULT_TOLS)}")
        tols_all.update(tols)
    if mesh is None:
        mesh_arr = np.full(N, 1.0 / N)
    else:
        try:
            mesh_arr = np.asarray(mesh, dtype=float).ravel()
        except (TypeError, ValueError):
            raise ValueError(f"mesh: expected {N} positive interval fractions (one per interval), got {mesh!r:.80}") from None
        if mesh_arr.shape != (N,) or not np.all(np.isfinite(mesh_arr)) or np.any(mesh_arr <= 0):
            raise ValueError(f"mesh: expected {N} positive interval fractions (one per interval)")
        mesh_arr = mesh_arr / mesh_arr.sum()
    if prob.is_rest_to_rest and prob.slew_angle < 1e-12:
        raise ValueError(("qf" if prob.qf is not None else "sensor_target")
                         + ": the target equals the start (zero slew at rest); nothing to solve")
    cone_passability.check_cones_passable(prob)
    sc = collocation_nlp.Scaled.of(prob)
    deadline = t_start + float(time_budget)
    starts = collocation_guesses.initial_guesses(sc, guess, n_starts, seed, extra_starts)

    nit = nfev = 0
    failures = []
    budget_hit = False
    Nc, N_half = _grids(N, bool(prob.cones), coarse)
    # ---- stage 1: every start (on the coarse grid when there is one)
    common = dict(method="collocation", problem=prob, n_candidates=0)
    try:
        nlp1 = collocation_nlp.NLP(sc, _coarse_mesh(mesh_arr, Nc) if Nc else mesh_arr, max(tol, 1e-7) if Nc else tol,
                    min(max_iter, _COARSE_MAX_ITER) if Nc else max_iter, verbose, deadline)
    except collocation_nlp.NoTimeToBuild as e:
        return SlewSolution(False, STATUS_BUDGET_EXHAUSTED, f"{STATUS_MESSAGES[STATUS_BUDGET_EXHAUSTED]} No start was "
                            f"solved: {e}.", nit=0, nfev=0, wall_time=time.perf_counter() - t_start,
                            route="Hermite–Simpson: no time to build the NLP", **common)
    stage1 = []
    for g in starts:
        if time.perf_counter() > deadline:
            budget_hit = True
            break
        r = nlp1.solve(g.sample(nlp1), deadline, g.source)
        nit += r.nit
        nfev += r.nfev
        stage1.append(r)
        if not r.success:
            failures.append(f"{g.source}{f' (N={Nc})' if Nc else ''}: {r.status}")
            if r.status == "Maximum_WallTime_Exceeded":
                budget_hit = True
                break
    conv1 = sorted([r for r in stage1 if r.success], key=lambda r: r.T)
    agreeing = sum(1 for r in conv1 if r.source.endswith("perturbed") and abs(r.T - conv1[0].T) <= 1e-3 * conv1[0].T)
    evidence["escaped"] = max(evidence.get("escaped", 0), agreeing)
    coarse_tf = sorted({round(r.T * sc.tau, 6) for r in conv1})
    # ---- stage 2: refine on N
    finals = []      # (run, coarse T)
    if Nc:
        try:
            nlp = collocation_nlp.NLP(sc, mesh_arr, tol, max_iter, verbose, deadline)
        except collocation_nlp.NoTimeToBuild as e:
            nlp, budget_hit = None, True
            failures.append(str(e))
        chosen = []
        for r in conv1:
            if r.T > conv1[0].T * (1 + 2e-3) or len(chosen) >= 2:
                break
            if any(abs(r.T - c.T) <= 1e-6 * c.T for c in chosen):
                continue      # a mirror image of one already chosen
            chosen.append(r)
        if not chosen and stage1 and not budget_hit:
            chosen = [None]   # nothing converged on the coarse grid: the first start on N
        for rc in (chosen if nlp is not None else []):
            if time.perf_counter() > deadline:
                budget_hit = True
                break
            w0 = _regrid(rc, nlp) if rc is not None else starts[0].sample(nlp)
            src = rc.source if rc is not None else starts[0].source
            r = nlp.solve(w0, deadline, src)
            nit += r.nit
            nfev += r.nfev
            if not r.success:
                failures.append(f"{src} (N={N}): {r.status}")
                budget_hit = budget_hit or r.status == "Maximum_WallTime_Exceeded"
            finals.append((r, rc.T if rc is not None and r.success else math.nan))
    else:
        finals = [(r, math.nan) for r in stage1]
    common = dict(method="collocation", problem=prob, n_candidates=len(stage1))
    if not finals and not conv1:
        # nothing to compare with the eigenaxis slew (planning it takes up to 0.1 s for a p-norm
        # bound, after the time budget has run out)
        status = STATUS_BUDGET_EXHAUSTED if budget_hit else STATUS_NOT_CONVERGED
        what = ("IPOPT: " + "; ".join(failures)) if failures else (
            f"No start was solved ({len(starts)} planned"
            + ("; the time budget ran out before the first)" if budget_hit else ")"))
        return SlewSolution(False, status, f"{STATUS_MESSAGES[status]} {what}", nit=nit, nfev=nfev,
                            wall_time=time.perf_counter() - t_start,
                            route="Hermite–Simpson: " + ("no start converged" if failures else
                                                          "the time budget ran out before the first start"
                                                          if budget_hit else "no start solved"),
                            **common)
    baseline = math.nan
    if prob.is_rest_to_rest and prob.qf is not None and finals:
        from .eigenaxis import baseline_time, eigenaxis_slew
        # with cones, the eigenaxis slew only where its path clears them (``baseline_time``)
        baseline = baseline_time(prob) if prob.cones else eigenaxis_slew(prob, n_grid=1000).tf
    common["baseline_tf"] = baseline
    coarse_only = False
    if not finals:
        # (conv1 is not empty here) the budget ran out before the refinement: return the coarse answer, unverified
        finals = [(conv1[0], math.nan)]
        coarse_only = True
    conv = [f for f in finals if f[0].success and not coarse_only]
    best, Tc = min(conv, key=lambda f: f[0].T) if conv else finals[0]
    # ---- stage 3: keep-out clearance between the collocation points. The constraint holds
    # at nodes and midpoints; the path can sag into a cone between them. Re-solve with the
    # cone half-angles enlarged by a back-off δ until the re-propagated path is clear.
    best0 = best
    rep = _replay(sc, best)
    nfev += rep.nfev
    if prob.cones:
        def cone_round(run, excess, warm):
            delta = run.delta + 1.5 * excess + 1e-7
            return (run.nlp.solve(run.w, deadline, run.source, delta=delta, warm=run if warm else None),
                    f"cone back-off {delta:.2g} rad")
        best, rep, n1, n2 = _back_off(sc, best, rep, deadline, failures, cone_round,
                                      lambda run, r: -_interior_clearance(prob, r, run, sc.tau))
        nit, nfev = nit + n1, nfev + n2
    # ---- stage 3b: the rate limit between the collocation points. The NLP bounds the rates at
    # the points and the Bernstein coefficients of the scheme's cubic; the replayed path can
    # still exceed the limit slightly (1e-5 relative) along an arc that rides it. Re-solve with
    # the limit scaled down by the excess until the replay keeps it.
    if prob.has_rate_limit:
        def rate_round(run, excess, warm):
            scale = max(0.5, run.nlp.rate_scale * (1.0 - 1.5 * excess) - 1e-9)
            return (run.nlp.with_rate_scale(scale).solve(run.w, deadline, run.source, delta=run.delta,
                                                         warm=run if warm else None),
                    f"rate back-off {1.0 - scale:.2g}")
        # (rounds stop within 1e-10 of the limit: the check allows 1e-9)
        best, rep, n1, n2 = _back_off(sc, best, rep, deadline, failures, rate_round,
                                      lambda run, r: sc.rate_ratio(r.x[:, 4:7]) - 1.0 - 1e-10)
        nit, nfev = nit + n1, nfev + n2
    from_coarse = math.isfinite(Tc)
    # tf_tol compares the answer with a coarser grid's answer in its basin: with cones an N / 2
    # solve from the answer (the starts' grid is too coarse to say how accurate tf is); else the
    # starts' grid again, from the answer, when the refinement (or the back-off) left the coarse
    # answer's basin
    def compare(run, dl):
        """``(T on the comparison grid or NaN, nit, nfev)``: ``run`` solved again on N / 2 (or on
        the starts' grid) from itself, before ``dl``."""
        if not (run.success and time.perf_counter() < dl):
            return math.nan, 0, 0
        try:
            nlp_cmp = nlp1 if N_half is None else collocation_nlp.NLP(
                sc, _coarse_mesh(mesh_arr, N_half), max(tol, 1e-7), min(max_iter, _COARSE_MAX_ITER), verbose, dl)
        except collocation_nlp.NoTimeToBuild:
            return math.nan, 0, 0
        r2 = nlp_cmp.solve(_regrid(run, nlp_cmp), dl, run.source, delta=run.delta)
        # (an N / 2 answer in another basin says nothing of this one's accuracy)
        ok = r2.success and (N_half is None or abs(run.T - r2.T) <= 1e-2 * run.T)
        return (r2.T if ok else math.nan), r2.nit, r2.nfev

    deferred = compared_in_vain = False
    if N_half is not None or (from_coarse and abs(best.T - Tc) > 1e-2 * best.T):
        if N_half is not None:
            Tc = math.nan
        deferred = defer_tf_tol and N_half is not None and best.success
        if not deferred:
            Tc, n1, n2 = compare(best, deadline)
            nit, nfev = nit + n1, nfev + n2
            compared_in_vain = not math.isfinite(Tc)
    fields, checks = _post(sc, best, Tc, tols_all, rep)
    if deferred:    # (Tc is NaN here: _post gave the boundary miss's estimate, kept for settle)
        miss_tol, fields["tf_tol"] = fields["tf_tol"], math.nan
    route = f"Hermite–Simpson, N={best.nlp.N}"
    if from_coarse:
        route += f", warm start from N={Nc} (best of {len(conv1)} converged start(s))"
    if best.delta > 0:
        route += f", cone back-off {best.delta:.3g} rad"
    if best.nlp.rate_scale < 1.0:
        route += f", rate limit backed off by {1.0 - best.nlp.rate_scale:.2g}"
    fields["route"] = route
    cands = sorted({round(f[0].T * sc.tau, 9) for f in conv if f[0] is not best0}
                   | ({round(best.T * sc.tau, 9)} if conv else set()))
    wall = time.perf_counter() - t_start
    kw = dict(nit=nit, nfev=nfev, wall_time=wall, candidates_tf=cands, **common, **fields)
    if Nc and len(coarse_tf) > 1:
        local = f" Local optima on the coarse grid (N={Nc}): {coarse_tf}."
    else:
        local = ""
    if coarse_only:
        return SlewSolution(False, STATUS_BUDGET_EXHAUSTED,
                            f"{STATUS_MESSAGES[STATUS_BUDGET_EXHAUSTED]} Only the coarse grid (N={Nc}) was solved; "
                            "its answer is returned, not refined on N. Runs: " + "; ".join(failures), **kw)
    if not best.success:
        status = STATUS_BUDGET_EXHAUSTED if budget_hit and not conv else STATUS_NOT_CONVERGED
        msg = f"{STATUS_MESSAGES[status]} IPOPT: {best.status}."
        if "Infeasible" in best.status and prob.cones:
            msg += " The keep-out cones (with the torque and rate limits) may leave no feasible path."
        msg += " Runs: " + "; ".join(failures)
        return SlewSolution(False, status, msg, **kw)
    text = failure_text(checks)
    if text:
        return SlewSolution(False, STATUS_VERIFICATION_FAILED,
                            f"{STATUS_MESSAGES[STATUS_VERIFICATION_FAILED]} {text}", **kw)
    if not prob.cones and math.isfinite(baseline):
        slower = fields["tf"] > baseline * (1 + 1e-6) + fields["tf_tol"]
        # per-axis bound: an answer no faster than the eigenaxis slew is, in practice, the
        # eigenaxis slew itself — a stationary point that IPOPT cannot leave when the guess
        # has the symmetry of a slew about a principal axis (R5 from its plain eigenaxis
        # guess); precession makes per-axis optima 5-20 % faster. Perturbed starts break that
        # symmetry: when at least two of them reach the best coarse answer and it does not beat
        # the eigenaxis slew by 0.1 %, the optimum is that close to it (small slews, where the
        # two agree to first order). The count (``evidence``, set after stage 1) carries over
        # to a refinement of this answer on a finer mesh
        escaped = evidence["escaped"]
        near = fields["tf"] >= baseline * (1 - 1e-3)
        saddle = math.isinf(sc.p) and near and escaped < 2
        if slower or saddle:
            what = ("slower than" if slower else "no faster than")
            return SlewSolution(False, STATUS_WORSE_THAN_BASELINE,
                                f"{STATUS_MESSAGES[STATUS_WORSE_THAN_BASELINE]} Collocation optimum "
                                f"{fields['tf']:.9g} is {what} the eigenaxis slew {baseline:.9g}"
                                + ("" if slower else " (a stationary point held by symmetry, typically; "
                                   "try more starts, n_starts)") + f".{local}", **kw)
    msg = f"Collocation NLP solved (IPOPT {best.status}) and verified by re-propagation."
    if not prob.cones and math.isfinite(baseline) and math.isinf(sc.p) and near:
        msg += (f" Within 0.1 % of the eigenaxis slew ({baseline:.9g}), as {escaped} symmetry-breaking starts "
                "agree" + (": the slew is small enough for the two to agree to first order." if not prob.has_rate_limit
                           else " (with an active rate limit the two can agree this closely)."))
    if len(cands) > 1:
        msg += f" Best of {len(cands)} refined local optima (final times {cands})."
    msg += local
    if compared_in_vain:
        msg += TF_TOL_ESTIMATE_NOTE
    if failures:
        msg += " Runs that failed: " + "; ".join(failures)
    sol = SlewSolution(True, STATUS_SUCCESS, msg, **kw)
    if deferred:
        def settle(budget):
            T_cmp, n1, n2 = compare(best, time.perf_counter() + budget)
            return _tf_tol(best.T, sc.tau, T_cmp, miss_tol), n1, n2, math.isfinite(T_cmp)
        sol._tf_tol_pending = settle
    return sol
