"""Bang-bang extremals with a fixed switching structure (switch-time shooting).

Event-driven shooting on the bang-bang law has a Newton matrix that is rank
deficient whenever the iterate has fewer switches than boundary conditions: the
states then depend on the costates only through the switch times. Here the
structure (sign of each axis's first arc and the axis of each switch, in order)
is fixed, and the unknowns are the costates ``z``, the switch instants and ``tf``::

    unknowns  z (6), t_1 … t_n (switch instants, any order), tf
    residuals |z|² - 1,  S_{a_k}(t_k) = 0,  boundary conditions (6)

which is square and smooth. The structure comes from a smoothed extremal
(crossings, plus a pair of switches wherever a switching function grazes zero).
The answer is then checked by event-driven propagation: the same switches must
appear at the same instants and no others.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .attitude_bvp import NY, step_budget
from .core.switch_sequence import sequence_end
from .core.touch_sequence import touch_sequence_flow


@dataclass
class Structure:
    signs0: np.ndarray          # (3,) sign of each axis's first arc
    axes: np.ndarray            # (n,) axis of each switch, in time order
    times: np.ndarray           # (n,) switch instants (a guess, or the answer)

    @property
    def n(self):
        return int(self.axes.shape[0])

    def same_sequence(self, signs0, axes) -> bool:
        """Whether first signs ``signs0`` and switch axes ``axes`` (in time order) are this
        structure's (the instants aside)."""
        return (self.n == len(axes) and np.array_equal(self.axes, axes)
                and np.array_equal(self.signs0, signs0))


@dataclass
class SwitchTimeResult:
    success: bool
    message: str
    z: np.ndarray
    durations: np.ndarray
    structure: Structure
    residual_norm: float
    nit: int
    nfev: int
    history: list = field(default_factory=list)
    jacobian: object = None     # the last Jacobian, in the result's switch order

    @property
    def T(self):
        return float(np.sum(self.durations))


# no touches: the touch instants, multipliers and cones' cosines, and the cone matrices
_NO_TOUCH = np.zeros(0)
_NO_CONES = np.zeros((0, 4, 4))


def _residual(bvp, z, times, T, st, want_jac):
    """Residual and Jacobian in the unknowns ``x = [z (6), switch times (n), T]``.

    Switch times are absolute and sorted at each evaluation, so switches on
    different axes may change order freely (the control is separable by axis). The arcs
    and switches run in one compiled call (``core.touch_sequence.touch_sequence_flow``, no touches).
    """
    n = st.n
    nx = 6 + n + 1
    y, dy0 = bvp.initial(z)
    G = np.zeros((NY, nx))
    G[:, :6] = dy0
    r = np.empty(1 + n + 6)
    Jm = np.zeros((1 + n + 6, nx)) if want_jac else None
    S_jac = Jm[1:1 + n] if want_jac else np.zeros((n, nx))
    rp, drp = bvp.param_residual(z)
    r[0] = rp[0]
    if want_jac:
        Jm[0, :6] = drp[0]
    y, ok = touch_sequence_flow(y, G, np.ascontiguousarray(times, dtype=float),
                                np.ascontiguousarray(st.axes, dtype=np.int64), float(T), _NO_TOUCH, _NO_TOUCH,
                                _NO_CONES, _NO_TOUCH, np.asarray(st.signs0, dtype=float), bvp.J, bvp.umax, bvp.mode,
                                bvp.p, bvp.eps, bvp.rtol, bvp.atol, bvp.pen, bool(want_jac), r[1:1 + n], S_jac,
                                _NO_TOUCH, np.zeros((0, nx)), step_budget(nx if want_jac else 0))
    if not ok:
        return None, None
    rt, dry, drT = bvp.terminal(y, T)
    r[1 + n:] = rt
    if want_jac:
        Jm[1 + n:] = dry @ G
        Jm[1 + n:, -1] += drT
    if not np.all(np.isfinite(r)):
        return None, None
    return r, Jm


def solve_switch_times(bvp, z0, structure: Structure, T0, *, tol=1e-12, max_iter=30,
                       max_step=0.3, coarse_rtol=1e-9, deadline=math.inf, stall=None):
    """Newton on (costates, switch times, final time) for a fixed bang-bang structure.

    Iterates first at the integrator tolerance ``coarse_rtol`` to a residual of about
    ``1e3 · coarse_rtol`` (most iterations, cheap), then at the problem's own tolerance
    to ``tol``. ``deadline`` (``time.perf_counter()`` time): checked before each iteration.
    ``stall``: ``(k, ratio)``, stop (as failed) once ``k`` iterations have not brought the
    residual below ``ratio`` times the first one (``multistart.TEMPLATE_STALL``).
    """
    if coarse_rtol is not None and coarse_rtol > bvp.rtol:
        fine = (bvp.rtol, bvp.atol)
        bvp.rtol, bvp.atol = coarse_rtol, coarse_rtol
        try:
            first = _solve_switch_times(bvp, z0, structure, T0, tol=1e3 * coarse_rtol, max_iter=max_iter,
                                        max_step=max_step, deadline=deadline, stall=stall)
        finally:
            bvp.rtol, bvp.atol = fine
        if not first.success:
            return first
        # at the problem's tolerance the coarse Jacobian is still accurate to ~coarse_rtol, so
        # chord steps (residuals only, no sensitivities) converge in one or two iterations;
        # full Newton if they do not
        again = _chord(bvp, first, tol) if first.jacobian is not None else None
        if again is None or not again.success:
            again = _solve_switch_times(bvp, first.z, first.structure, first.T, tol=tol, max_iter=max_iter,
                                        max_step=max_step, deadline=deadline)
        again.nit += first.nit
        again.nfev += first.nfev
        return again
    return _solve_switch_times(bvp, z0, structure, T0, tol=tol, max_iter=max_iter, max_step=max_step,
                               deadline=deadline, stall=stall)


def _solve_switch_times(bvp, z0, structure: Structure, T0, *, tol, max_iter, max_step, deadline=math.inf,
                        stall=None):
    st = structure
    n = st.n
    x = np.concatenate([np.asarray(z0, float), np.asarray(st.times, float), [float(T0)]])
    nfev = 0

    def split(x):
        return x[:6], x[6:6 + n], float(x[-1])

    r, Jm = _residual(bvp, *split(x), st, True)
    nfev += 1
    if r is None:
        return SwitchTimeResult(False, "propagation failed at the guess", x[:6], x[6:], st, np.inf, 0, nfev)
    hist = []
    nit = 0
    phi = float(r @ r)
    msg = "maximum iterations reached"
    ok = False
    scale = np.concatenate([np.ones(6), np.full(n + 1, max(float(T0), 1e-3))])
    while True:
        rn = float(np.max(np.abs(r)))
        hist.append(rn)
        if rn < tol:
            ok, msg = True, "converged"
            break
        if nit >= max_iter:
            break
        if time.perf_counter() > deadline:
            msg = "the time budget ran out"
            break
        if stall is not None and nit == stall[0] and rn > stall[1] * hist[0]:
            msg = f"stalled (residual {rn / hist[0]:.2g} of the first after {nit} iterations)"
            break
        nit += 1
        dx = np.linalg.lstsq(Jm, -r, rcond=1e-13)[0]
        big = float(np.max(np.abs(dx) / scale))
        if big > max_step:
            dx *= max_step / big
        accepted = False
        alpha = 1.0
        Jt = None
        while alpha > 1e-8:
            xt = x + alpha * dx
            zt, tt, Tt = split(xt)
            if np.all(tt >= 0.0) and np.all(tt <= Tt) and Tt > 0.0:
                # the full step is usually accepted: evaluate its Jacobian with it
                rt, Jt = _residual(bvp, zt, tt, Tt, st, alpha == 1.0)
                nfev += 1
                if rt is not None and float(rt @ rt) < (1 - 1e-4 * alpha) * phi:
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            msg = "line search failed"
            break
        x = xt
        if Jt is not None:
            r, Jm = rt, Jt
        else:
            r, Jm = _residual(bvp, *split(x), st, True)
            nfev += 1
        if r is None:
            msg = "propagation failed"
            break
        phi = float(r @ r)
    z, times, T = split(x)
    order = np.argsort(times, kind="stable")
    res_st = Structure(st.signs0.copy(), st.axes[order].copy(), times[order].copy())
    d = np.diff(np.concatenate([[0.0], times[order], [T]]))
    jac = None
    if Jm is not None:   # rows and columns in the sorted switch order of res_st
        ro = np.concatenate([[0], 1 + order, np.arange(1 + n, 1 + n + 6)])
        co = np.concatenate([np.arange(6), 6 + order, [6 + n]])
        jac = Jm[np.ix_(ro, co)]
    return SwitchTimeResult(ok, msg, z, d, res_st, float(np.max(np.abs(r))) if r is not None else np.inf,
                            nit, nfev, hist, jac)


def _chord(bvp, first: SwitchTimeResult, tol, max_iter=4):
    """Chord iterations from a converged coarse result, with its Jacobian kept fixed."""
    st = first.structure
    n = st.n
    x = np.concatenate([first.z, st.times, [first.T]])
    J = first.jacobian
    nfev = 0
    hist = []
    for it in range(max_iter + 1):
        r, _ = _residual(bvp, x[:6], x[6:6 + n], float(x[-1]), st, False)
        nfev += 1
        if r is None:
            return None
        rn = float(np.max(np.abs(r)))
        hist.append(rn)
        if rn < tol:
            times = x[6:6 + n]
            order = np.argsort(times, kind="stable")
            res_st = Structure(st.signs0.copy(), st.axes[order].copy(), times[order].copy())
            d = np.diff(np.concatenate([[0.0], times[order], [x[-1]]]))
            return SwitchTimeResult(True, "converged", x[:6].copy(), d, res_st, rn, it, nfev, hist, None)
        if it == max_iter or (len(hist) > 1 and rn > 0.5 * hist[-2]):
            return None
        x = x + np.linalg.lstsq(J, -r, rcond=1e-13)[0]
        tt, Tt = x[6:6 + n], float(x[-1])
        if not (Tt > 0.0 and np.all(tt >= 0.0) and np.all(tt <= Tt)):
            return None     # a switch left [0, T]: full Newton with its line search instead
    return None


def structure_from_trajectory(t, S, graze=0.0):
    """Switching structure read off sampled switching functions ``S`` (n, 3).

    Sign changes become switches (instants by linear interpolation). With
    ``graze > 0``, a local minimum of ``|S_i|`` below ``graze · max|S_i|`` that is not
    a crossing becomes a pair of switches around the minimum: the bang-bang
    extremal near a smoothed one often has a short arc there.
    """
    events = []
    for i in range(3):
        s = S[:, i]
        amax = float(np.max(np.abs(s))) or 1.0
        for k in range(len(t) - 1):
            if s[k] == 0.0 and k > 0:
                continue
            if s[k] * s[k + 1] < 0.0 or (s[k + 1] == 0.0 and k + 2 < len(t) and s[k] * s[k + 2] < 0):
                tk = t[k] + (t[k + 1] - t[k]) * s[k] / (s[k] - s[k + 1]) if s[k] != s[k + 1] else t[k]
                events.append((tk, i))
        if graze > 0.0:
            a = np.abs(s)
            for k in range(1, len(t) - 1):
                if a[k] <= a[k - 1] and a[k] < a[k + 1] and a[k] < graze * amax and s[k - 1] * s[k + 1] > 0:
                    w = max(1e-4 * (t[-1] - t[0]), 0.5 * (t[k + 1] - t[k - 1]) * 0.1)
                    events.append((t[k] - w, i))
                    events.append((t[k] + w, i))
    events.sort()
    s0 = S[0]
    signs0 = np.array([-np.sign(v) if v != 0 else 1.0 for v in s0])
    if events:
        times = np.array([e[0] for e in events])
        axes = np.array([e[1] for e in events], dtype=np.int64)
    else:
        times = np.zeros(0)
        axes = np.zeros(0, dtype=np.int64)
    return Structure(signs0, axes, times)


def propagate_sequence(bvp, times, axes, signs0, T, y0, want_jac):
    """A bang-bang control with its switches at fixed instants (``times``, ``axes``, first signs
    ``signs0``), propagated from the augmented state ``y0`` over ``[0, T]``, or ``None`` if a
    propagation fails. Returns ``(y(T), r, nfev)``, ``r`` the boundary residual (6); with
    ``want_jac``, ``(y(T), r, J_r, D7, M, nfev)``: ``J_r`` the residual's Jacobian in
    ``[times, T]`` (exact: ``∂x(T)/∂t_k = Φ(T, t_k)(f⁻ - f⁺)``, accumulated backwards over the
    arcs' 7×7 transition matrices), ``D7 = ∂r/∂x(T)`` and ``M`` the state transition matrix over
    ``[0, T]``. The arcs run in one compiled call (``core.switch_sequence.sequence_end``); a
    time that is not finite fails like a propagation."""
    y, dx, M_total, nfev, ok = sequence_end(
        np.asarray(y0, dtype=float), np.ascontiguousarray(times, dtype=float), np.ascontiguousarray(axes, dtype=np.int64),
        float(T), np.asarray(signs0, dtype=float), bvp.J, bvp.umax, bvp.mode, bvp.p, bvp.eps, bvp.rtol, bvp.atol,
        bvp.pen, bool(want_jac), step_budget(7 if want_jac else 0))
    if not ok:
        return None
    r, D, _ = bvp.terminal(y, T)
    if not want_jac:
        return y, r, nfev
    D7 = D[:, :7]
    return y, r, D7 @ dx, D7, M_total, nfev
