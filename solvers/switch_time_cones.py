"""Bang-bang switch-time optimisation with keep-out cones and pointing-only targets.

Where a slew's optimal path rides a keep-out cone's boundary (or has a singular arc), no
exact bang-bang extremal exists, and ``auto``'s answer was collocation's piecewise quadratic
control: its switch times, flown as a bang-bang control, miss the target, and its own control
misses it by its discretisation error. This module gives those problems (per-axis bound) a
bang-bang answer that reaches the target exactly and keeps out of the cones at every instant:

    minimise  tf   over the switch instants t_1 … t_n and tf,
    subject to     the boundary conditions (6 for a full attitude; 5 for a pointing target:
                   the sensor on the target (2) and the rates (3), the roll left free),
                   each cone's clearance margin ≥ δ at the sample instants s_m · tf
                   (δ = ``SAMPLE_MARGIN``, 5e-7 rad, ramped down near an end that sits
                   closer to a cone: ``keep_off``),
                   each axis's switches in order, 0 ≤ t_k ≤ tf,

for a fixed switching sequence (``switch_time_opt.sequence_from_samples``: collocation's sign
changes, with zero-width pulse pairs on the axes whose torque is interior, where the path
rides a cone). The states at the samples and their derivatives in the unknowns come from one
compiled pass (``core.switch_sequence.sequence_samples``: forward transition matrices, with
the jump ``f⁻ - f⁺`` at each switch), so the gradients are exact.

The margin is constrained only at samples, so the answer is found by exchange: after each
SLSQP solve, the local minima of the margin on a dense pass (4,000 instants) that come within
``NEAR`` of a cone are added as samples (a cluster of ``CLUSTER`` one dense step apart), until no
dense instant is inside a cone by more than ``DENSE_TOL``. The verification does not rely on the samples: the
clearance is certified at every instant on an independent RK4 replay of the switch times
(``clearance.certified_replay``, ≥ ``CLEARANCE_TOL``).

A bang-bang path can only approximate a boundary arc (a control that holds the sensor on the
cone is interior on some axis): the answer is feasible and exact to the last digit, and its
``tf`` an upper bound on the optimal time. ``auto`` takes it when it is within the collocation
answer's accuracy of it (``bang_bang_cone_answer``).
"""
from __future__ import annotations

import math
import time

import numpy as np

from .attitude_bvp import AttitudeBVP, step_budget
from .core.attitude_flow import MODE_BANG
from .core.cone_penalty import cone_matrix, sampled_margins
from .clearance import cone_margins
from .core.switch_sequence import sequence_samples
from .switch_time import propagate_sequence
from .verify import replay_path
from .switch_time_opt import (SwitchTimeOptResult, _start_state, checked_sequence, evaluated_sequence,
                              order_constraints)

BASE_SAMPLES = 64       # evenly spaced sample instants (fractions of tf) in the first round
DENSE_SAMPLES = 4000    # the dense pass that finds the margin's minima between samples
NEAR = 2e-3             # rad: a local minimum of the margin below this becomes a sample
FAR = 0.1               # rad: samples farther than this from every cone are dropped for the round
SAMPLE_MARGIN = 5e-7    # rad: the margin the samples keep from the cones
END_RAMP = 0.02         # share of tf over which the samples' margin ramps up from an end on a cone's edge
DENSE_TOL = 1e-9        # rad: the dense pass's deepest point inside a cone that ends the exchange
CLUSTER = 5             # samples around each near minimum of the margin
POLISH_MARGIN = 1e-9    # rad: the margin the polish gives a violated sample
EXCHANGE_ROUNDS = 5


def _pointing_rows(bvp):
    """Rows of ``bvp.terminal`` that constrain the state: all 6 for a full attitude; for a
    pointing target the 2 pointing and 3 rate rows (row 2, the roll transversality, is a
    costate condition of extremals)."""
    return np.array([0, 1, 3, 4, 5]) if bvp.pointing else np.arange(6)


def optimise_switch_times_cones(problem, signs0, axes, times, T, *, time_budget=1.0, max_iter=40,
                                bvp=None, give_up_residual=math.inf) -> SwitchTimeOptResult:
    """The fastest bang-bang slew of ``problem`` (per-axis bound; full-attitude or pointing
    target; keep-out cones imposed) with the switching sequence ``(signs0, axes)``, from the
    nondimensional instants ``times`` and final time ``T`` (module docstring). A rate limit is
    not a constraint here (the caller checks it on the replay). ``z`` of the result: the KKT
    costates of the boundary rows where the answer's path keeps clear of every cone
    (``_costates_where_clear``), else NaN (with active cone constraints the multipliers are not
    an extremal's costates).
    ``give_up_residual``: the rounds stop after one whose polished boundary residual is still
    above it (a sequence that cannot reach the target, such as a far neighbour's: its further
    rounds would only spend the next sequence's time)."""
    from scipy.optimize import minimize
    if not math.isinf(problem.torque_norm):
        raise ValueError("torque_norm: switch-time optimisation is for the per-axis bound")
    bvp = bvp if bvp is not None else AttitudeBVP(problem.replace(cones=()))
    bvp.set_mode("bang")
    signs0, axes, times = checked_sequence(signs0, axes, times, T)
    n = axes.shape[0]
    rows = _pointing_rows(bvp)
    cones = list(problem.cones)
    s_b = np.asarray(problem.sensor_axis, float)
    Ms = np.array([cone_matrix(c.axis, s_b) for c in cones]).reshape(len(cones), 4, 4)
    half = np.array([c.half_angle for c in cones], dtype=float)
    y0 = _start_state(bvp)
    ends = np.array([np.concatenate([bvp.q0, np.zeros(3)]), np.concatenate([bvp.qf, np.zeros(3)])])
    end_margins = _margins(ends, (Ms, half)) if cones else np.zeros((2, 0))
    # the dense pass's acceptance: a start or target may sit on a cone's edge (within the
    # problem's own tolerance), and that instant is then no worse than it
    accept = min(-DENSE_TOL, float(end_margins.min(initial=0.0)) - DENSE_TOL)
    args = (bvp.J, bvp.umax, bvp.mode, bvp.p, bvp.eps, bvp.rtol, bvp.atol, bvp.pen)
    t_start = time.perf_counter()
    deadline = t_start + time_budget
    stats = {"nfev": 0, "nit": 0}
    # sample instants are for the cones' margins: without cones none (each sample splits an arc:
    # 64 samples made a pointing slew's arcs about 4 times as many)
    fracs = (np.arange(BASE_SAMPLES) + 0.5) / BASE_SAMPLES if cones else np.zeros(0)
    cache = {}

    def evaluate(v, jac=False):
        """``(r, J_r, g, J_g, y(T))`` at ``v``: the boundary residual, the samples' margins
        beyond what they keep off (``keep_off``) and, with ``jac``, their Jacobians (else
        ``None``). Values alone skip the transition matrices (5-7× cheaper): SLSQP's line
        search needs only them."""
        key = v.tobytes()
        hit = cache.get(key)
        if hit is None or (jac and hit[1] is None):
            if time.perf_counter() - t_start > time_budget:
                raise TimeoutError
            X, dX, yT, dx, nfev, ok = sequence_samples(y0, np.ascontiguousarray(v[:n]), axes, float(v[n]), signs0,
                                                       fracs, *args, jac, step_budget(7 if jac else 0))
            stats["nfev"] += nfev
            if not ok:
                raise FloatingPointError("propagation failed")
            r, D, _ = bvp.terminal(yT, float(v[n]))
            g, Jg = sampled_margins(X, dX, Ms, half)
            cache.clear()
            cache[key] = hit = (r[rows], D[rows, :7] @ dx if jac else None, g - keep_off(fracs, end_margins).ravel(),
                                Jg if jac else None, yT)
        return hit

    A = order_constraints(axes)
    e_T = np.zeros(n + 1)
    e_T[n] = 1.0
    v = np.concatenate([np.clip(times, 0.0, T), [T]])
    cons = [{"type": "eq", "fun": lambda v: evaluate(v)[0], "jac": lambda v: evaluate(v, True)[1]},
            {"type": "ineq", "fun": lambda v: evaluate(v)[2], "jac": lambda v: evaluate(v, True)[3]}]
    if A.shape[0]:
        cons.append({"type": "ineq", "fun": lambda v: A @ v, "jac": lambda v: A})
    best = None             # (v, note, converged, samples): the fastest feasible iterate so far
    why = "no feasible iterate"
    rnd = 0
    try:
        if cones:
            # the start's own near contacts are sampled from the first round on
            add, _ = _new_samples(y0, v, n, axes, signs0, args, (Ms, half), fracs, deadline)
            fracs = np.unique(np.concatenate([fracs, add]))
        # rounds: SLSQP, the feasibility polish, the dense pass; a feasible iterate is kept,
        # and the next round starts from it (more samples where it entered a cone, or more
        # iterations where SLSQP stopped at its limit) until a KKT point or the last round
        for rnd in range(1, EXCHANGE_ROUNDS + 1):
            if cones:
                fracs = _near_samples(evaluate, v, fracs, end_margins, len(cones))
                cache.clear()
            res = minimize(lambda v: v[n], v, jac=lambda v: e_T, constraints=cons, method="SLSQP",
                           bounds=[(0.0, 2.0 * T)] * n + [(0.5 * T, 2.0 * T)],
                           options={"maxiter": max_iter, "ftol": 1e-13})
            v = res.x
            stats["nit"] += int(res.nit)
            v = _polish(evaluate, v)
            resid = float(np.linalg.norm(evaluate(v)[0]))
            add, worst = (_new_samples(y0, v, n, axes, signs0, args, (Ms, half), fracs, deadline) if cones
                          else (np.zeros(0), math.inf))
            stats["nfev"] += DENSE_SAMPLES if cones else 0
            feasible = resid < 1e-10 and worst >= accept
            if not resid < 1e-10:
                why = f"boundary residual {resid:.2e} after the polish"
                if not resid <= give_up_residual:
                    break
            elif not feasible:
                why = f"the path enters a cone by {-worst:.1e} rad between samples"
            gain = math.inf if best is None else best[0][n] - v[n]
            if feasible and gain > 0.0:
                best = (v.copy(), "a KKT point" if res.success else f"SLSQP stopped ({res.message})",
                        bool(res.success), fracs.size, resid)
            # done at a feasible KKT point, when a further round gains less than 1e-7 of tf, or
            # when SLSQP converged to an infeasible point that gives no new sample (at its
            # iteration limit, the next round goes on from where it stopped)
            if feasible and (res.success or gain < 1e-7 * v[n]) or (not feasible and add.size == 0 and res.success):
                break
            if add.size:
                fracs = np.unique(np.concatenate([fracs, add]))
                cache.clear()
    except TimeoutError:
        why = f"time budget ({time_budget:g} s) exhausted"
    except FloatingPointError as e:
        why = str(e)
    if best is None:
        return SwitchTimeOptResult(False, f"{why} (after {rnd} round(s))", float(v[n]), v[:n].copy(), axes, signs0,
                                   math.inf, stats["nit"], stats["nfev"])
    v, note, converged, n_samples, resid = best
    note += f"; {n_samples} samples, {rnd} round(s)"
    z, kkt = _costates_where_clear(bvp, problem, v, axes, signs0, y0, A, rows, stats)
    times_kept, axes_kept, signs0 = evaluated_sequence(v, axes, signs0)
    return SwitchTimeOptResult(True, note, float(v[n]), times_kept, axes_kept, signs0, resid, stats["nit"],
                               stats["nfev"], z, kkt, converged)


# rad: a path whose clearance stays above this (RK4 replay, ``CLEAR_STEPS`` steps) leaves every
# cone constraint inactive, and the KKT conditions of the boundary rows alone give its costates
CLEAR_MARGIN = 1e-5
CLEAR_STEPS = 4000


def _costates_where_clear(bvp, problem, v, axes, signs0, y0, A, rows, stats):
    """``(z, kkt residual)`` of the answer ``v`` where no cone constraint is active (its path, on
    an RK4 replay, at least ``CLEAR_MARGIN`` from every cone): the boundary rows' KKT costates
    (``switch_time_opt.kkt_costates``), which on a stationary answer are its extremal's, the
    seed of the exact solver; else ``(NaN, NaN)`` (with an active cone the multipliers of the
    sampled constraints make the costates jump: no such costates are formed)."""
    from .switch_time_opt import kkt_costates
    nan = (np.full(6, np.nan), math.nan)
    n = axes.shape[0]
    T = float(v[n])
    if problem.cones:
        # (an iterate's instant past tf switches nothing)
        sw = [np.clip(v[:n][axes == i], 0.0, T) for i in range(3)]
        _, X = replay_path(bvp.J, bvp.umax, y0[0:4], y0[4:7], sw, signs0, T, CLEAR_STEPS)
        if not (np.all(np.isfinite(X)) and float(cone_margins(problem, X[:, 0:4]).min()) > CLEAR_MARGIN):
            return nan
    out = propagate_sequence(bvp, v[:n], axes, signs0, T, y0, True)
    if out is None:
        return nan
    _, _, Jr, D7, M, nfev = out
    stats["nfev"] += nfev
    return kkt_costates(bvp, v, A, Jr[rows], D7[rows], M)


def keep_off(fracs, end_margins):
    """``(M, K)``: the margin each sample keeps from each cone: ``SAMPLE_MARGIN`` (so that the
    margin between samples stays positive), ramped down near a start or target that sits closer
    to the cone than that, to half its own margin there (never below 0), over ``END_RAMP`` of tf."""
    s = np.asarray(fracs, float)[:, None]
    e0 = np.maximum(0.0, 0.5 * end_margins[0])[None, :]
    e1 = np.maximum(0.0, 0.5 * end_margins[1])[None, :]
    ramp = SAMPLE_MARGIN / END_RAMP
    return np.minimum(SAMPLE_MARGIN, np.minimum(e0 + ramp * s, e1 + ramp * (1.0 - s)))


def _polish(evaluate, v):
    """Minimum-norm Gauss-Newton steps onto the boundary conditions and the sampled cone
    constraints that SLSQP left violated (at its iteration limit an iterate need not be
    feasible): the violated samples are driven to a margin of ``POLISH_MARGIN``, the others
    are left as they are. A step is taken only if it lowers the infeasibility."""
    def infeasibility(out):
        return float(np.linalg.norm(out[0])) + float(np.maximum(0.0, -out[2]).sum())

    out = evaluate(v, True)
    for _ in range(10):
        r, Jr, g, Jg = out[0:4]
        viol = g < 0.0
        f = infeasibility(out)
        if f < 1e-14:
            break
        A = np.vstack([Jr, Jg[viol]])
        b = np.concatenate([r, g[viol] - POLISH_MARGIN])
        step = np.linalg.lstsq(A, b, rcond=None)[0]
        for frac in (1.0, 0.5, 0.25):       # backtracking: the constraints are nonlinear
            vt = v - frac * step
            try:
                ot = evaluate(vt)
            except FloatingPointError:
                continue
            if infeasibility(ot) < f:
                break
        else:
            break
        v = vt
        if infeasibility(ot) < 1e-14:
            break
        out = evaluate(v, True)
    return v


def _near_samples(evaluate, v, fracs, end_margins, K):
    """The samples of ``fracs`` within ``FAR`` of a cone at ``v`` (at least the 4 closest): a
    far sample's constraint is inactive, and it costs an arc of the sensitivity pass and a row
    of SLSQP's subproblem in every iteration. Should the path swing into a cone where no sample
    is left, the dense pass adds samples there and the round is repeated."""
    g = (evaluate(v)[2].reshape(-1, K) + keep_off(fracs, end_margins)).min(axis=1)
    near = g < FAR
    if near.sum() < 4:
        near[np.argsort(g)[:4]] = True
    return fracs[near]


def _new_samples(y0, v, n, axes, signs0, args, cones, fracs, deadline):
    """``(new fractions, deepest margin)``: around each local minimum of a cone's margin below
    ``NEAR`` on the dense pass, a cluster of ``CLUSTER`` samples one dense step apart (the
    minimum moves as the iterate does: the cluster keeps it between samples, where the margin
    can dip below the samples' by at most ~|θ̈| h² / 8), not already sampled; and the smallest
    margin seen."""
    if time.perf_counter() > deadline:
        raise TimeoutError
    dense = np.linspace(0.0, 1.0, DENSE_SAMPLES)
    X, *_, ok = sequence_samples(y0, np.ascontiguousarray(v[:n]), axes, float(v[n]), signs0, dense, *args, False,
                                 step_budget(0))
    if not ok:
        raise FloatingPointError("propagation failed on the dense pass")
    g = _margins(X, cones)
    worst = float(g.min())
    h = dense[1] - dense[0]
    new = []
    for k in range(g.shape[1]):
        for i in margin_minima(g[:, k], NEAR):
            new.extend(dense[i] + h * np.arange(-(CLUSTER // 2), CLUSTER // 2 + 1))
    new = np.asarray(new, float)
    new = new[(new > 0.0) & (new < 1.0)]
    if new.size and fracs.size:
        new = new[np.min(np.abs(new[:, None] - fracs[None, :]), axis=1) > 1e-9]
    return new, worst


def margin_minima(m, below) -> np.ndarray:
    """Indices of the interior local minima of the sampled margin ``m`` (one cone's, along a
    path) that lie below ``below``."""
    return np.flatnonzero((m[1:-1] <= m[:-2]) & (m[1:-1] <= m[2:]) & (m[1:-1] < below)) + 1


def _margins(X, cones):
    """The clearance margins (M, K) of the sampled states ``X`` (``core.cone_penalty.sampled_margins``
    without gradients)."""
    Ms, half = cones
    g, _ = sampled_margins(X, np.zeros((X.shape[0], 7, 0)), Ms, half)
    return g.reshape(X.shape[0], -1)


SLSQP_ITERATIONS = 40    # a round's SLSQP iterations (feasible iterates are kept between rounds)
# extra zero-width pulse pairs of the successive optimisations (as switch_time_opt's; a path
# riding a cone wants them: on Melton's BP2 the round without them ends 2.3e-4 above
# collocation's tf, beyond its tf_tol, and the round with 4 pairs 1.1e-4 below it). On 20
# seed-100 problems, (4, 8) alone verified 17 and (0, 4, 8) 18, at the same times.
PULSE_ROUNDS = (0, 4, 8)


_COMPILED = []


def load_kernels():
    """Compile (or load from numba's cache) the kernels this module runs, once per process, on
    a one-switch problem: in a fresh install the compilation takes seconds, longer than the
    optimisation's budget."""
    if _COMPILED:
        return
    J = np.ones(3)
    y0 = np.zeros(14)
    y0[0] = 1.0
    X, dX, *_ = sequence_samples(y0, np.array([0.5]), np.array([0], dtype=np.int64), 1.0, np.ones(3),
                                 np.array([0.5]), J, J, MODE_BANG, 0.0, 1e-2, 1e-12, 1e-13, np.zeros(0), True,
                                 step_budget(7))
    sampled_margins(X, dX, np.eye(4)[None, :, :], np.array([0.1]))
    _COMPILED.append(True)


def rate_limit_active(problem, col) -> bool:
    """Whether collocation's answer runs at the rate limit (some ``|ω_i|`` at 98 % of
    ``rate_max_i``, or ``‖ω‖`` at 98 % of ``rate_norm_max``, or more): holding a rate limit needs
    an interior torque, which no bang-bang sequence gives, so the optimisation is not tried (its
    answer would fail the rate check)."""
    if not problem.has_rate_limit or col.omega is None or len(col.omega) == 0:
        return False
    return problem.rate_limit_ratio(col.omega) >= 0.98


def switch_time_cones_applies(problem) -> bool:
    """Per-axis bound with keep-out cones or a pointing target: what this module adds to
    ``switch_time_opt`` (full attitude, no cones)."""
    return math.isinf(problem.torque_norm) and (bool(problem.cones) or problem.qf is None)


def bang_bang_cone_answer(problem, col, time_budget=1.0, tols=None):
    """A verified bang-bang answer from a collocation answer ``col`` of a per-axis problem with
    keep-out cones or a pointing target, or ``None`` when it does not apply, nothing is
    verified, or it is slower than ``col`` beyond ``col.tf_tol``.

    The switch times of collocation's sequence (with pulse pairs on its interior axes, rounds
    of ``PULSE_ROUNDS``, the fastest kept) are optimised with the cones imposed
    (``optimise_switch_times_cones``). Verified like the other switch-time answers (boundary
    errors at the end of the DOP853 arcs, an RK4 replay of the switch times, the rate limit),
    and the cone clearance certified at every instant on that replay (``cone_clearance`` ≥
    ``CLEARANCE_TOL``). ``method="switch-time"``; ``exact`` is False; ``costate0`` is
    collocation's estimate and the dense costates are NaN (the cone constraints' multipliers
    make the KKT costates jump, so they are not reported), except where the answer's path keeps
    clear of every cone and is a KKT point of its sequence: there both are its KKT costates
    (``_costates_where_clear``), as for a full-attitude answer without cones."""
    from .switch_time_opt import answer_from_collocation
    if (not col.success or not switch_time_cones_applies(problem) or col.switch_times is None or col.t is None
            or len(col.t) < 2 or rate_limit_active(problem, col)):
        return None
    load_kernels()      # (a fresh install compiles them once: not on this step's budget)
    t0 = time.perf_counter()
    return answer_from_collocation(problem, col, AttitudeBVP(problem.replace(cones=())), optimise_switch_times_cones,
                                   time_budget, tols, SLSQP_ITERATIONS, t0, PULSE_ROUNDS, stop_at_kkt_only=True)[0]


__all__ = ["optimise_switch_times_cones", "bang_bang_cone_answer", "switch_time_cones_applies"]
