"""Exact bang-bang extremals whose path touches a keep-out cone at isolated instants.

A cone keeps the sensor out: ``h(q) = qᵀMq - cos α ≤ 0`` (``M`` from
``core.cone_penalty.cone_matrix``: ``qᵀMq = a · R(q) s``). When the optimal path touches the
boundary at an instant ``t_c`` without riding it, the necessary conditions are those of an
interior-point constraint:

* the path is tangent to the boundary there: ``h(q(t_c)) = 0`` and ``ḣ(t_c) = 2 (Mq)·q̇ = 0``;
* the attitude costate jumps along the constraint gradient,
  ``λq(t_c⁺) = λq(t_c⁻) - ν ∂h/∂q = λq(t_c⁻) - 2 ν M q`` with a multiplier ``ν ≥ 0``
  (the limit of the exterior penalty of ``solvers.cone_penalty``: ``ν = ∫ w h⁺ dt``);
  ``λω`` and the state are continuous, and so is ``H`` (the jump changes it by ``-ν ḣ = 0``).

With ``K`` touches, the unknowns are ``z = [μ, λω(0)]`` (normalised, as in ``AttitudeBVP``),
``T``, the touch instants ``t_1 < … < t_K`` and the multipliers ``ν_k``; the residuals are the
normalisation, the six boundary conditions, and ``h = ḣ = 0`` at each touch: ``7 + 2K``
equations. Newton's method on them uses the event-driven bang-bang flow with its
jump-corrected sensitivities on each segment between touches, chained through the jump maps.
The guess (instants, multipliers, costates) comes from a collocation answer.

The answer is an exact bang-bang extremal: between touches the control is
``u_i = -umax_i sign(S_i)`` with switches located on the switching functions, so the path is
reproduced by its switch times alone, and the clearance is certified on that replay.
"""
from __future__ import annotations

import math
import time

import numpy as np

from .attitude_bvp import AttitudeBVP, NY, Trajectory, flow_failure, step_budget
from .clearance import CLEARANCE_TOL, certified_replay, cone_margins
from .core import attitude_flow as af
from .core.cone_penalty import cone_matrix
from .core.touch_sequence import touch_residual, touch_sequence_flow
from .solution import STATUS_NOT_CONVERGED, STATUS_SUCCESS, STATUS_VERIFICATION_FAILED, SlewSolution
from .indirect import solution_fields
from .guesses import Guess
from .switch_time import Structure, structure_from_trajectory
from .verify import DEFAULT_TOLS, extremal_checks, failure_text, make_check, rate_limit_check

NEAR_MARGIN = 1e-3        # rad: a local minimum of the margin below this is a contact
ARC_MARGIN = 1e-4         # rad: a contact that stays this close over 5 % of tf is a boundary arc
SMOOTHING_PATH = (2e-2, 1e-2, 5e-3, 2e-3, 1e-3)
STRUCTURE_REPAIRS = 3     # re-solves of the switch-time problem with the structure its answer shows
# A learned candidate's switch-time Newton gives up when, after this many iterations, its residual
# has not once come below this (``structured_newton``'s ``stall``). On 100 held-out problems
# (runs/s31/cand_trace.py, trace_an2.py) every candidate that converged had its residual below
# 0.1 within 6 Jacobian evaluations, while the failing ones spent 33 ms each, a median, and most
# of it with the residual above 0.1: the next candidate can use that time
LEARNED_STALL = (8, 0.1)
# ... and it iterates with the integrator at this tolerance until its residual is below 1e3 times
# it, then at the problem's (1e-12): a residual with its Jacobian costs 0.49 ms instead of
# 0.77 ms (runs/s31/rtol_cost.py, 40 held-out problems), and its error, 3e-9, is far below the
# residuals of the iterations it serves
LEARNED_COARSE_RTOL = 1e-8
NEWTON_TOL = 1e-11        # the event-driven Newton's residual (max norm) of a converged extremal


class TouchBVP(AttitudeBVP):
    """``AttitudeBVP`` (bang-bang) that accepts cones: they enter through the touch junctions."""
    handles_cones = True


def touch_jump(M, nu, y, G=None, nu_col=None):
    """The costate jump of a touch, ``λq⁺ = λq⁻ - 2 ν M q``: ``(y⁺, G⁺, Jmap)``. With the
    sensitivity ``G = dy/dx`` (``None``: not carried), ``G⁺ = Jmap G`` plus ``-2Mq`` in the
    multiplier's column ``nu_col``; ``Jmap = ∂y⁺/∂y⁻``."""
    Mq = M @ y[0:4]
    y_plus = y.copy()
    y_plus[7:11] -= 2.0 * nu * Mq
    if G is None:
        return y_plus, None, None
    Jmap = np.eye(NY)
    Jmap[7:11, 0:4] -= 2.0 * nu * M
    G_plus = Jmap @ G
    G_plus[7:11, nu_col] -= 2.0 * Mq
    return y_plus, G_plus, Jmap


def _events(times, tc):
    """Switches ``(t, 0, j)`` and touches ``(t, 1, k)`` in time order, then the end ``(T, 2, -1)``
    is appended by the caller."""
    return sorted([(float(t), 0, j) for j, t in enumerate(times)] + [(float(t), 1, k) for k, t in enumerate(tc)])


class TouchProblem:
    """The touch-point boundary-value problem of ``bvp`` with touches on ``cones[k]``."""

    def __init__(self, bvp, cone_ids):
        self.bvp = bvp
        self.K = len(cone_ids)
        s = bvp.sensor
        # stacked for the compiled flow (``core.touch_sequence``); ``M`` and ``cos_a``, per touch,
        # are views of the same data
        self.Ms = np.array([cone_matrix(bvp.problem.cones[c].axis, s) for c in cone_ids], dtype=float).reshape(
            self.K, 4, 4)
        self.cos_a_array = np.array([math.cos(bvp.problem.cones[c].half_angle) for c in cone_ids], dtype=float)
        self.M = list(self.Ms)
        self.cos_a = self.cos_a_array.tolist()
        self.cone_ids = list(cone_ids)

    def unpack(self, x):
        K = self.K
        return x[0:6], x[6], x[7:7 + K], x[7 + K:7 + 2 * K]

    def segments(self, x, want_jac=True):
        """Propagate through the touches: ``(R, Jac, pieces)`` or ``(None, None, message)``."""
        bvp, K = self.bvp, self.K
        z, T, tc, nu = self.unpack(x)
        bounds = np.concatenate([[0.0], tc, [T]])
        if not np.all(np.diff(bounds) > 0.0):
            return None, None, "touch instants out of order"
        n = x.shape[0]
        y, dy = bvp.initial(z)
        D = np.zeros((NY, n))          # dy/dx of the current segment's start
        D[:, 0:6] = dy
        signs = bvp.initial_signs(y)
        R = [np.array([float(z @ z) - 1.0])]
        Jr = [np.zeros((1, n))]
        Jr[0][0, 0:6] = 2.0 * z
        pieces = []
        for k in range(K + 1):
            dur = bounds[k + 1] - bounds[k]
            Y, s_end, _, n_sw, steps, status, *_ = bvp._run(y, dur, np.eye(NY) if want_jac else None,
                                                            signs0=signs)
            if status != af.FLOW_OK or not np.all(np.isfinite(Y)):
                return None, None, f"segment {k}: {flow_failure(status)}"
            ye = Y[:NY].copy()
            u, _ = af.control(ye, bvp.J, bvp.umax, bvp.mode, bvp.p, bvp.eps, s_end)
            fe = af.ext_rhs(ye, u, bvp.J)
            pieces.append((y.copy(), dur, signs.copy()))
            if want_jac:
                Phi = Y[NY:].reshape(NY, NY)
                De = Phi @ D
                # the segment ends at bounds[k+1] and starts at bounds[k]
                col_end = 7 + k if k < K else 6
                De[:, col_end] += fe
                if k > 0:
                    De[:, 7 + k - 1] -= fe
            if k < K:
                r, g = touch_residual(ye, self.M[k], self.cos_a[k])
                R.append(r)
                if want_jac:
                    Jr.append(g @ De)
                y, D_plus, _ = touch_jump(self.M[k], nu[k], ye, De if want_jac else None, 7 + K + k)
                if want_jac:
                    D = D_plus
                signs = s_end.copy()
            else:
                r, dry, drT = bvp.terminal(ye, T)
                R.append(r)
                if want_jac:
                    Jr.append(dry @ De)
        Rv = np.concatenate(R)
        if not np.all(np.isfinite(Rv)):
            return None, None, "non-finite residual"
        return Rv, (np.vstack(Jr) if want_jac else None), pieces


def _structured_residual(tp, z, times, T, tc, nu, st, want_jac):
    """Residual and Jacobian of the touch problem with a fixed bang-bang structure ``st``
    (``solvers.switch_time.Structure``), in ``x = [z (6), switch instants (n), T, touch
    instants (K), multipliers (K)]``:

        |z|² - 1,   S_{a_j}(t_j) = 0 (n),   h = ḣ = 0 at each touch (2K),   boundary (6)

    Square and smooth: the arcs have fixed controls, the switch instants are unknowns (as
    in ``switch_time``), and each touch applies the jump ``λq⁺ = λq⁻ - 2νMq``. The
    sensitivity ``G = dy(t)/dx`` at the running time ``t`` picks up ``f⁻ - f⁺`` in the
    column of each event's instant (the state after it, moved later). The arcs and events
    run in one compiled call (``core.touch_sequence.touch_sequence_flow``)."""
    bvp, K, n = tp.bvp, tp.K, st.n
    nx = 6 + n + 1 + 2 * K
    y, dy0 = bvp.initial(z)
    G = np.zeros((NY, nx))
    G[:, :6] = dy0
    nr = 1 + n + 2 * K + 6
    r = np.empty(nr)
    Jm = np.zeros((nr, nx)) if want_jac else None
    S_jac = Jm[1:1 + n] if want_jac else np.zeros((n, nx))
    H_jac = Jm[1 + n:1 + n + 2 * K] if want_jac else np.zeros((2 * K, nx))
    rp, drp = bvp.param_residual(z)
    r[0] = rp[0]
    if want_jac:
        Jm[0, :6] = drp[0]
    y, ok = touch_sequence_flow(y, G, np.ascontiguousarray(times, dtype=float),
                                np.ascontiguousarray(st.axes, dtype=np.int64), float(T),
                                np.ascontiguousarray(tc, dtype=float), np.ascontiguousarray(nu, dtype=float),
                                tp.Ms, tp.cos_a_array, np.asarray(st.signs0, dtype=float), bvp.J, bvp.umax,
                                bvp.mode, bvp.p, bvp.eps, bvp.rtol, bvp.atol, bvp.pen, bool(want_jac),
                                r[1:1 + n], S_jac, r[1 + n:1 + n + 2 * K], H_jac, step_budget(nx if want_jac else 0))
    if not ok:
        return None, None
    rt, dry, drT = bvp.terminal(y, T)
    r[1 + n + 2 * K:] = rt
    if want_jac:
        Jm[1 + n + 2 * K:] = dry @ G
        Jm[1 + n + 2 * K:, 6 + n] += drT
    if not np.all(np.isfinite(r)):
        return None, None
    return r, Jm


def _fixed_structure_switching(tp, x, times, st, per_arc=24):
    """``(t, S)``: the switching functions ``S_i = λω_i / J_i`` sampled along the path of the
    fixed structure ``st`` with switch instants ``times`` (``x`` as ``TouchProblem`` takes it),
    with the costate jump at each touch; ``None`` if the propagation fails."""
    bvp = tp.bvp
    z, T, tc, nu = tp.unpack(x)
    y, _ = bvp.initial(z)
    signs = st.signs0.astype(float).copy()
    ts, Ss = [np.zeros(1)], [(y[11:14] / bvp.J)[None, :]]
    t_prev = 0.0
    for t_next, kind, j in _events(times, tc) + [(T, 2, -1)]:
        dt = t_next - t_prev
        if dt > 0.0:
            Y, _, n_rec, _, _, status, rt, rY, *_ = bvp._run(y, dt, None, signs0=signs, record=20 * per_arc,
                                                             detect=False, hmax=dt / per_arc)
            if status != af.FLOW_OK:
                return None
            ts.append(rt[1:n_rec] + t_prev)
            Ss.append(rY[1:n_rec, 11:14] / bvp.J)
            y = Y[:NY].copy()
        t_prev = max(t_prev, t_next)
        if kind == 0:
            a = int(st.axes[j])
            signs[a] = -signs[a]
        elif kind == 1:
            y = touch_jump(tp.M[j], nu[j], y)[0]
    return np.concatenate(ts), np.vstack(Ss)


def repaired_structure(tp, x, times, st):
    """The structure the switching functions of a fixed-structure solution actually have (their
    sign changes along its path), or ``None`` if it is ``st`` itself: a wrong guess of the
    structure (a switch missing where a switching function crosses zero, or one too many)
    shows up as a mismatch, and the next solve starts from the corrected one."""
    path = _fixed_structure_switching(tp, x, times, st)
    if path is None:
        return None
    new = structure_from_trajectory(*path)
    same = (np.array_equal(new.signs0, st.signs0) and new.n == st.n
            and np.array_equal(new.axes, st.axes[np.argsort(times, kind="stable")]))
    return None if same else new


def structured_newton(tp, z0, st, T0, tc0, nu0, tol=1e-11, max_iter=40, max_step=0.3, deadline=math.inf,
                      stall=None, coarse_rtol=None):
    """Newton with a line search on ``_structured_residual``: ``(x, converged, nit, nfev,
    residual, switch instants)`` with ``x = [z, T, touch instants, multipliers]`` as
    ``TouchProblem`` takes it (the event-driven Newton then checks the structure).
    ``stall = (k, r)``: give up after ``k`` iterations if the residual (max norm) has not yet
    come below ``r`` (``LEARNED_STALL``). ``coarse_rtol``: iterate with the integrator at this
    tolerance until the residual is below ``1e3 · coarse_rtol``, then at the problem's own
    (``LEARNED_COARSE_RTOL``); convergence is only ever declared at the problem's."""
    bvp = tp.bvp
    fine = (bvp.rtol, bvp.atol)
    if coarse_rtol is None or not coarse_rtol > fine[0]:
        return _structured_newton(tp, z0, st, T0, tc0, nu0, tol, max_iter, max_step, deadline, stall, None)
    try:
        bvp.rtol, bvp.atol = coarse_rtol, coarse_rtol * fine[1] / fine[0]
        return _structured_newton(tp, z0, st, T0, tc0, nu0, tol, max_iter, max_step, deadline, stall,
                                  (1e3 * coarse_rtol, fine))
    finally:
        bvp.rtol, bvp.atol = fine


def _structured_newton(tp, z0, st, T0, tc0, nu0, tol, max_iter, max_step, deadline, stall, refine):
    """``structured_newton``'s iterations; ``refine = (residual, (rtol, atol))``: the integrator
    is at a coarse tolerance, and goes to ``(rtol, atol)`` once the residual is below ``residual``."""
    n, K = st.n, tp.K
    x = np.concatenate([np.asarray(z0, float), np.asarray(st.times, float), [float(T0)],
                        np.asarray(tc0, float), np.asarray(nu0, float)])

    def split(x):
        return x[:6], x[6:6 + n], float(x[6 + n]), x[7 + n:7 + n + K], x[7 + n + K:]

    def inside(x):
        # touches keep their order: the event-driven problem pairs instants with cones in order
        _, tt, T, tc, _ = split(x)
        return (T > 0.0 and np.all(tt >= 0.0) and np.all(tt <= T) and np.all(tc > 0.0) and np.all(tc < T)
                and np.all(np.diff(tc) > 0.0))

    def pack(x):
        z, tt, T, tc, nu = split(x)
        return np.concatenate([z, [T], tc, nu]), tt.copy()

    r, Jm = _structured_residual(tp, *split(x), st, True)
    nfev = 1
    if r is None:
        return pack(x)[0], False, 0, nfev, math.inf, pack(x)[1]
    scale = np.concatenate([np.ones(6), np.full(n + 1 + K, max(float(T0), 1e-3)), np.maximum(np.abs(nu0), 1.0)])
    phi = float(r @ r)
    best = math.inf
    for it in range(max_iter):
        rn = float(np.max(np.abs(r)))
        if refine is not None and rn < refine[0]:
            # close enough for the problem's tolerance: the residual and Jacobian again with it
            tp.bvp.rtol, tp.bvp.atol = refine[1]
            refine = None
            r, Jm = _structured_residual(tp, *split(x), st, True)
            nfev += 1
            if r is None:
                return pack(x)[0], False, it, nfev, math.inf, pack(x)[1]
            phi = float(r @ r)
            rn = float(np.max(np.abs(r)))
        if rn < tol and refine is None:
            return pack(x)[0], True, it, nfev, rn, pack(x)[1]
        best = min(best, rn)
        if time.perf_counter() > deadline or (stall is not None and it >= stall[0] and best > stall[1]):
            return pack(x)[0], False, it, nfev, rn, pack(x)[1]
        dx = np.linalg.lstsq(Jm, -r, rcond=1e-13)[0]
        big = float(np.max(np.abs(dx) / scale))
        if big > max_step:
            dx *= max_step / big
        # the full step's trial carries the Jacobian (kept if the step is taken); shorter trials
        # fly the state alone and the Jacobian follows if one is taken. On the learned cone route
        # a third of the accepted steps are full steps, and as many full steps are rejected, but
        # flying every trial without the Jacobian measured no faster (60 problems, twice). An
        # accepted trial whose Jacobian cannot be had (sensitivities overflowing) is rejected
        alpha, accepted = 1.0, False
        while alpha > 1e-6:
            xt = x + alpha * dx
            if inside(xt):
                rt, Jt = _structured_residual(tp, *split(xt), st, alpha == 1.0)
                nfev += 1
                if rt is not None and float(rt @ rt) < (1.0 - 1e-4 * alpha) * phi:
                    if Jt is None:
                        rt, Jt = _structured_residual(tp, *split(xt), st, True)
                        nfev += 1
                    if rt is not None:
                        accepted = True
                        break
            alpha *= 0.5
        if not accepted:
            return pack(x)[0], False, it, nfev, rn, pack(x)[1]
        x, r, Jm = xt, rt, Jt
        phi = float(r @ r)
    rn = float(np.max(np.abs(r)))
    return pack(x)[0], rn < tol and refine is None, max_iter, nfev, rn, pack(x)[1]


def newton(tp, x0, tol=NEWTON_TOL, max_iter=30, max_step=0.3, deadline=math.inf):
    """Damped Newton on the touch-point problem: ``(x, converged, nit, nfev, residual)``."""
    x = np.asarray(x0, float).copy()
    R, Jm, msg = tp.segments(x)
    nfev = 1
    if R is None:
        return x, False, 0, nfev, math.inf
    scale = np.maximum(np.abs(x), 1.0)
    for it in range(max_iter):
        rn = float(np.max(np.abs(R)))
        if rn < tol:
            return x, True, it, nfev, rn
        if time.perf_counter() > deadline:
            return x, False, it, nfev, rn
        # minimum-norm least squares: a bang-bang Jacobian is rank-deficient when the iterate
        # has fewer switches than conditions (see shooting.newton_shoot)
        dx = np.linalg.lstsq(Jm, -R, rcond=1e-10)[0]
        big = float(np.max(np.abs(dx) / scale))
        if big > max_step:
            dx *= max_step / big
        phi = float(R @ R)
        alpha = 1.0
        xt = None
        while alpha > 1e-3:
            xt = x + alpha * dx
            Rt, _, _ = tp.segments(xt, want_jac=False)
            nfev += 1
            if Rt is not None and float(Rt @ Rt) < (1.0 - 1e-4 * alpha) * phi:
                break
            alpha *= 0.5
            xt = None
        if xt is None:
            # the bang-bang residual is only piecewise smooth (a switch may appear or vanish
            # near the guess): Levenberg–Marquardt steps, shorter and turned towards the gradient
            JtJ, g = Jm.T @ Jm, Jm.T @ R
            lam0 = float(np.trace(JtJ)) / JtJ.shape[0]
            for lam in lam0 * np.array([1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0]):
                step = np.linalg.solve(JtJ + lam * np.diag(np.maximum(np.diag(JtJ), 1e-12)), -g)
                cand = x + step
                Rt, _, _ = tp.segments(cand, want_jac=False)
                nfev += 1
                if Rt is not None and float(Rt @ Rt) < phi:
                    xt = cand
                    break
            if xt is None:
                return x, False, it, nfev, rn
        x = xt
        R, Jm, msg = tp.segments(x)
        nfev += 1
        if R is None:
            return x, False, it + 1, nfev, math.inf
    rn = float(np.max(np.abs(R)))
    return x, rn < tol, max_iter, nfev, rn


def find_touches(problem, sol):
    """``[(cone index, time index)]`` of the isolated contacts of a dense answer (local minima of
    the margin below ``NEAR_MARGIN``), or ``None`` when a contact lasts (a boundary arc: the
    path stays within ``ARC_MARGIN`` over more than 5 % of the slew)."""
    t = np.asarray(sol.t, float)
    out = []
    for c, m in enumerate(cone_margins(problem, sol.q).T):
        near = m < NEAR_MARGIN
        # ignore contacts at the very ends (a start or target on the boundary needs no junction)
        near[:2] = False
        near[-2:] = False
        if not near.any():
            continue
        idx = np.flatnonzero(near)
        for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            riding = run[m[run] < ARC_MARGIN]
            if riding.size and t[riding[-1]] - t[riding[0]] > 0.05 * t[-1]:
                return None
            out.append((c, int(run[np.argmin(m[run])])))
    out.sort(key=lambda p: t[p[1]])
    return out


def _seed_name(seed):
    return "collocation" if seed.method == "collocation" else "penalised"


def solve_touch(problem, seed, *, tols=None, time_budget=5.0, deadline=math.inf):
    """The exact extremal with touch-point junctions near ``seed`` (a collocation answer, or
    the penalised extremal of ``solvers.cone_penalty``), or a ``SlewSolution`` with
    ``success=False`` saying why not. Accepted only if not slower than the seed.
    ``time_budget`` and ``deadline``: as ``solve_touch_guess``."""
    t_start = time.perf_counter()
    if not math.isinf(problem.torque_norm):
        return _fail(problem, "per-axis bound only", t_start)
    touches = find_touches(problem, seed)
    if touches is None:
        return _fail(problem, "a contact lasts (boundary arc)", t_start)
    if not touches:
        return _fail(problem, "no touch found", t_start)
    guess = touch_guess_from(problem, seed, touches)
    col_rel = max(float(seed.tf_tol) / seed.tf if seed.tf_tol == seed.tf_tol else 0.0, 1e-3)
    return solve_touch_guess(problem, guess, reference=(float(seed.tf), 2.0 * col_rel, "not_slower_than_seed"),
                             tols=tols, time_budget=time_budget, t_start=t_start, deadline=deadline)


def _fail(problem, why, t_start):
    return SlewSolution(False, STATUS_NOT_CONVERGED, why, 0, 0, time.perf_counter() - t_start, method="indirect",
                        problem=problem, route=f"touch-point junctions: {why}")


def touch_guess_from(problem, seed, touches) -> Guess:
    """A ``Guess`` with touches from a dense answer ``seed`` and its contacts ``touches``
    (``find_touches``): its costates at t = 0, the contact instants, and the multipliers from
    the seed's costate jumps across each contact, projected on the constraint gradient."""
    s = np.asarray(problem.sensor_axis, float) / np.linalg.norm(problem.sensor_axis)
    ts = np.asarray(seed.t, float)
    C = np.asarray(seed.costate, float)
    rows = []
    for c, i in touches:
        M = cone_matrix(problem.cones[c].axis, s)
        lo, hi = max(0, i - 3), min(len(ts) - 1, i + 3)
        qi = np.asarray(seed.q[i], float) / np.linalg.norm(seed.q[i])
        # both projected on the tangent space of the unit sphere: the collocation costate's
        # component along q is a free gauge, and it changes across the contact too
        jump = C[hi, 0:4] - C[lo, 0:4]
        jump = jump - (jump @ qi) * qi
        g = 2.0 * M @ qi
        g = g - (g @ qi) * qi
        rows.append((c, float(ts[i]), max(0.0, -float(jump @ g) / max(float(g @ g), 1e-12))))
    # strictly inside (0, tf): a contact sample at the end is excluded by find_touches
    return Guess(seed.costate0, seed.tf, seed.switch_times, seed.u_first, source=_seed_name(seed), touches=rows)


def solve_touch_guess(problem, guess, *, reference=None, tols=None, time_budget=5.0, smoothing=True,
                      t_start=None, deadline=math.inf):
    """Newton on the touch-point problem from ``guess`` (a ``Guess`` with ``touches``), then
    the verification of ``_verify``. ``reference``: ``(tf, relative tolerance, check name)``,
    the answer must not be slower than ``tf`` by more than the tolerance (a guard against
    converging to another, worse extremal). ``smoothing``: follow the tanh path when the
    direct Newton fails (slower; a learned guess skips it for speed). ``time_budget`` (s)
    bounds the structures tried and the smoothing path; without smoothing, every Newton solve
    too. ``deadline`` (``time.perf_counter()`` time): a hard stop for all of it, checked between
    Newton iterations (the caller's own time budget)."""
    t_start = time.perf_counter() if t_start is None else t_start
    tols = dict(DEFAULT_TOLS, **(tols or {}))
    if not math.isinf(problem.torque_norm):
        return _fail(problem, "per-axis bound only", t_start)
    if not guess.touches:
        return _fail(problem, "the guess has no touches", t_start)
    for k, (c, _, _) in enumerate(guess.touches):
        if c >= len(problem.cones):
            raise ValueError(f"guess.touches[{k}]: cone index {c}, but the problem has {len(problem.cones)} cone(s)")
    bvp = _touch_bvp(problem)
    tp, z, T0, tc, nu = _touch_unknowns(bvp, guess)
    tau = bvp.tau
    x0 = np.concatenate([z, [T0], tc, nu])
    ok, nit, nfev, rn = False, 0, 0, math.inf
    starts = [x0]
    # the switch-time formulation first: smooth in its unknowns, so a guess with the right
    # structure converges from further away than the event-driven Newton below. Its answer is
    # an extremal only if the structure was right (no switching function crosses zero where
    # the structure has no switch): the event-driven Newton starts from it, and converges at
    # once if so. Structures tried: the guess's, then the one its own costates produce
    # (event-driven propagation through the guessed touches), if different
    tried = []
    evaluated = {}      # id of a switch-time answer: (its event-driven residual, its pieces)
    soft = min(t_start + time_budget, deadline)    # the structures' and the smoothing path's limit
    over = lambda: time.perf_counter() > soft   # noqa: E731
    for st in (_structure_of(guess, tau), "propagated"):
        if over():
            break
        if st == "propagated":
            st = propagated_structure(tp, x0)
        if st is None or any(_same_structure(st, o) for o in tried):
            continue
        tried.append(st)
        xs_, n1, n2 = _switch_time_solve(tp, x0, st, soft, **({} if smoothing else _learned_newton()))
        nit, nfev = nit + n1, nfev + n2
        if xs_ is not None:
            starts.insert(len(starts) - 1, xs_)     # before the raw guess, after earlier answers
            R_ev, _, pieces_ev = tp.segments(xs_, want_jac=False)
            if R_ev is not None:
                evaluated[id(xs_)] = (float(np.max(np.abs(R_ev))), pieces_ev)
            if R_ev is not None and float(np.max(np.abs(R_ev))) < 1e-9:
                break       # the event-driven flow agrees: this structure is the extremal's
    raw_skipped = False
    pieces = None
    for xstart in starts:
        if over() and xstart is x0 and len(starts) > 1:
            break
        if xstart is x0 and tried and not smoothing:
            # without smoothing (a learned guess, which must be fast), the event-driven Newton
            # starts only from the switch-time answers: from the raw guess, on the learned cone
            # route, it converged 0 times in 166 (100 held-out problems) and took a quarter of
            # the touch solver's time, which the next candidate can use
            raw_skipped = True
            break
        if id(xstart) in evaluated and evaluated[id(xstart)][0] < NEWTON_TOL:
            # already an event-driven extremal: the Newton would stop before its first step
            x, ok, rn, pieces = xstart, True, evaluated[id(xstart)][0], evaluated[id(xstart)][1]
            break
        x, ok, n1, n2, rn = newton(tp, xstart, deadline=deadline if smoothing else soft)
        nit, nfev = nit + n1, nfev + n2
        pieces = None
        if ok:
            break
    if not ok and smoothing:
        # the smoothed control law (tanh(S/ε), a homotopy only) makes the residual smooth
        # where a switch appears or vanishes near the guess; follow ε down, then solve the
        # exact bang-bang problem from there
        xs, ok_s = x0, False
        for eps in SMOOTHING_PATH:
            if over():
                break
            bvp.set_mode("tanh", eps=eps)
            xs, ok_s, n1, n2, rs = newton(tp, xs, tol=1e-9, deadline=deadline)
            nit, nfev = nit + n1, nfev + n2
            if not ok_s:
                break
        bvp.set_mode("bang")
        if ok_s:
            x, ok, n1, n2, rn = newton(tp, xs, deadline=deadline)
            nit, nfev = nit + n1, nfev + n2
            pieces = None
    if not ok:
        why = f"Newton did not converge (residual {rn:.2g}, {nit} iterations)"
        if raw_skipped and not math.isfinite(rn):
            why = (f"the switch-time Newton converged on none of the guess's {len(tried)} structure(s) "
                   f"({nit} iterations)")
        if time.perf_counter() > deadline:
            why += "; the time budget ran out"
        sol = _fail(problem, why, t_start)
        sol.nit, sol.nfev = nit, nfev
        return sol
    sol = _verify(tp, x, problem, guess.source, reference, tols, pieces)
    sol.nit, sol.nfev = nit, nfev
    sol.wall_time = time.perf_counter() - t_start
    return sol


def _touch_bvp(problem):
    """The touch-point BVP of ``problem``, its sensor axis unit."""
    bvp = TouchBVP(problem)
    bvp.sensor = np.asarray(problem.sensor_axis, float) / np.linalg.norm(problem.sensor_axis)
    return bvp


def _touch_unknowns(bvp, guess):
    """``(tp, z, T, tc, nu)``: the touch problem on ``guess``'s cones and the guess's unknowns,
    nondimensional (the touch instants over ``tau``, the multipliers in the scale of ``z``)."""
    tp = TouchProblem(bvp, [c for c, _, _ in guess.touches])
    z, T0, nz = guess.to_nondim(bvp, with_norm=True)
    tc = np.array([t / bvp.tau for _, t, _ in guess.touches])
    nu = np.array([m / (bvp.tau * nz) for _, _, m in guess.touches])
    return tp, z, T0, tc, nu


def starting_residuals(problem, guesses, deadline=math.inf) -> list:
    """For each guess, the switch-time residual (max norm) as given, with its own structure,
    touches and multipliers: the first thing ``solve_touch_guess`` evaluates, here without the
    Jacobian and at ``LEARNED_COARSE_RTOL``. ``inf`` where a guess has no touches or no
    structure, names a cone the problem does not have, or its flow fails, and for all of them
    where the bound is not per-axis, and for those not reached by ``deadline``
    (``time.perf_counter()``). A learned route's candidates are tried in order of it
    (``solvers.cone_routes.solve_learned_cones``)."""
    out = [math.inf] * len(guesses)
    if not math.isinf(problem.torque_norm) or problem.sensor_axis is None or not problem.cones:
        return out
    bvp = _touch_bvp(problem)
    if LEARNED_COARSE_RTOL is not None and LEARNED_COARSE_RTOL > bvp.rtol:
        bvp.rtol, bvp.atol = LEARNED_COARSE_RTOL, LEARNED_COARSE_RTOL * bvp.atol / bvp.rtol
    for k, guess in enumerate(guesses):
        if time.perf_counter() > deadline:
            break
        st = _structure_of(guess, bvp.tau) if guess.touches else None
        if st is None or any(c >= len(problem.cones) for c, _, _ in guess.touches):
            continue
        try:
            tp, z, T0, tc, nu = _touch_unknowns(bvp, guess)
            r = _structured_residual(tp, z, np.asarray(st.times, float), T0, tc, nu, st, False)[0]
        except (ValueError, TypeError, IndexError, ArithmeticError):
            continue    # a guess the touch solver cannot use: it says why when the route reaches it
        if r is not None:
            out[k] = float(np.max(np.abs(r)))
    return out


def _learned_newton():
    """``structured_newton``'s options on a learned guess's route (module constants, read when used)."""
    return {"stall": LEARNED_STALL, "coarse_rtol": LEARNED_COARSE_RTOL}


def _switch_time_solve(tp, x0, st, deadline=math.inf, stall=None, coarse_rtol=None):
    """Switch-time Newton from ``x0`` with structure ``st``, repaired up to
    ``STRUCTURE_REPAIRS`` times: ``(x or None, nit, nfev)``. ``stall``, ``coarse_rtol``:
    ``structured_newton``'s."""
    nit = nfev = 0
    zs, Ts, tcs, nus = tp.unpack(x0)
    for _ in range(STRUCTURE_REPAIRS + 1):
        xs_, ok_s, n1, n2, _, times = structured_newton(tp, zs, st, Ts, tcs, nus, deadline=deadline, stall=stall,
                                                        coarse_rtol=coarse_rtol)
        nit, nfev = nit + n1, nfev + n2
        if not ok_s:
            return None, nit, nfev
        fixed = repaired_structure(tp, xs_, times, st)
        if fixed is None:
            return xs_, nit, nfev
        st = fixed
        zs, Ts, tcs, nus = tp.unpack(xs_)
    return None, nit, nfev


def _event_driven_path(bvp, pieces, record=0, hmax=np.inf):
    """The event-driven flow over the pieces between touches (``TouchProblem.segments``):
    ``(t, y, signs, switch instants, switch axes)`` (samples only with ``record``; switches in
    time order), or ``None`` if a piece fails."""
    t0, ts, ys, sg, sw_t, sw_a = 0.0, [], [], [], [], []
    for y0, dur, signs in pieces:
        Y, s_end, n_rec, n_sw, steps, status, rt, rY, rs, swt, swa, _ = bvp._run(
            y0, dur, None, signs0=signs, record=record, hmax=hmax)
        if status != af.FLOW_OK:
            return None
        ts.append(rt[:n_rec] + t0)
        ys.append(rY[:n_rec])
        sg.append(rs[:n_rec])
        sw_t.extend((swt[:n_sw] + t0).tolist())
        sw_a.extend(swa[:n_sw].tolist())
        t0 += dur
    order = np.argsort(sw_t, kind="stable")
    return (np.concatenate(ts), np.vstack(ys), np.vstack(sg), np.asarray(sw_t, float)[order],
            np.asarray(sw_a, dtype=np.int64)[order])


def propagated_structure(tp, x):
    """The structure the event-driven bang-bang flow gives from ``x`` (switches located on the
    switching functions, costate jumps at the touches), or ``None`` if it fails."""
    R, _, pieces = tp.segments(x, want_jac=False)
    path = _event_driven_path(tp.bvp, pieces) if R is not None else None
    if path is None:
        return None
    return Structure(np.asarray(pieces[0][2], float).copy(), path[4], path[3])


def _same_structure(a, b):
    return np.array_equal(a.signs0, b.signs0) and np.array_equal(a.axes, b.axes)


def _structure_of(guess, tau):
    """The bang-bang structure of a guess with switch times and first-arc signs, else ``None``."""
    if guess.switch_times is None or guess.u_first is None:
        return None
    times = np.concatenate([np.asarray(s, float) / tau for s in guess.switch_times])
    axes = np.concatenate([np.full(len(s), i, dtype=np.int64) for i, s in enumerate(guess.switch_times)])
    order = np.argsort(times, kind="stable")
    return Structure(np.where(np.asarray(guess.u_first) >= 0, 1.0, -1.0), axes[order], times[order])


def _verify(tp, x, problem, source, reference, tols, pieces=None):
    """The checks of a touch extremal ``x``; ``pieces``: ``tp.segments(x)``'s, where already made."""
    bvp, K = tp.bvp, tp.K
    tau = bvp.tau
    z, T, tc, nu = tp.unpack(x)
    if pieces is None:
        R, _, pieces = tp.segments(x, want_jac=False)
        if R is None:       # the flow through the touches failed
            pieces = None
    path = _event_driven_path(bvp, pieces, record=4000, hmax=T / 1000) if pieces is not None else None
    if path is None:
        return _fail(problem, "the converged touch extremal could not be propagated for its verification",
                     time.perf_counter())
    t_all, y_all, S, sw_t, sw_a = path
    # the whole path as one record: both sides of each touch are samples at its instant
    tr = Trajectory(t_all, y_all, S, sw_t, sw_a, S[0].copy(), True, "")
    checks = extremal_checks(bvp, tr, tols)
    # touch multipliers: ν ≥ 0 (the cone pushes the path out, never pulls it in). Reported in
    # the solution's costate scale (H ≡ -1, problem units), with the jump of λq at each touch,
    # so that the costates can be replayed: λq(t⁺) = λq(t⁻) + jump
    H0 = bvp.hamiltonian(tr.y[0], tr.signs[0])
    c_scale = -1.0 / H0 if H0 < 0 else 1.0
    jumps = []
    for k in range(K):
        qk = pieces[k + 1][0][0:4]
        jumps.append((-2.0 * nu[k] * c_scale * tau * (tp.M[k] @ qk)).tolist())
    checks["touch_multipliers"] = dict(make_check(float(np.min(nu)), 0.0, bool(np.min(nu) >= 0.0)),
                                       times=(tc * tau).tolist(), cones=tp.cone_ids,
                                       multipliers=(nu * c_scale * tau).tolist(), costate_jumps=jumps)
    switch_times = [tr.switch_t[tr.switch_axis == i] * tau for i in range(3)]
    # independent replay of the switch times alone (the environment's RK4), with the
    # clearance certified on it at every instant
    t_rep, x_rep, cert = certified_replay(problem, switch_times, tr.signs0, T * tau)
    rep = max(bvp.attitude_error(x_rep[-1, 0:4]), float(np.linalg.norm(x_rep[-1, 4:7] * tau - bvp.wf)))
    checks["replay"] = make_check(rep, tols["replay"], rep <= tols["replay"])
    checks["cone_clearance"] = make_check(cert, CLEARANCE_TOL, cert >= CLEARANCE_TOL)
    checks.update(rate_limit_check(bvp, tr.y, tols, tr.t, [tr.switch_t[tr.switch_axis == i] for i in range(3)], tr.signs0))
    if reference is not None:
        ref_tf, ref_rel, name = reference
        slower = (T * tau - ref_tf) / ref_tf
        checks[name] = make_check(slower, ref_rel, slower <= ref_rel)
    text = failure_text(checks)
    msg = (f"Verified extremal found (touching the cones at {K} instant(s), costate jumps there: "
           f"verification['touch_multipliers']).") if not text else f"Touch-point extremal found but {text}."
    fields = solution_fields(bvp, z, T, f"touch-point junctions ({K}) from {source} costates", tr,
                             checks, source, problem)
    return SlewSolution(not text, STATUS_SUCCESS if not text else STATUS_VERIFICATION_FAILED, msg, 0, 0, 0.0,
                        method="indirect", n_candidates=1, candidates_tf=[fields["tf"]], problem=problem, **fields)
