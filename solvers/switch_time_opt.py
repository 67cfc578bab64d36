"""Bang-bang switch-time optimisation: the fastest bang-bang slew with a given switching sequence.

Some per-axis slews (about 12 % of the held-out full-attitude problems) have no bang-bang
optimum: one axis's switching function vanishes over an interval (an order-2 singular arc,
whose junctions chatter). No finite list of switch times is an extremal there, and the answer
``auto`` had was collocation's piecewise quadratic control, with its discretisation error at the
target. This module gives those problems a bang-bang answer that reaches the target *exactly*:

    minimise  tf   over the switch instants t_1 … t_n and tf,
    subject to     the boundary conditions (6, full-attitude target),
                   each axis's switches in order, 0 ≤ t_k ≤ tf,

for a fixed switching sequence (the sign of each axis's first arc and the axis of each switch),
taken from the collocation answer, with zero-width pulse pairs added on the interior axes
(``sequence_from_samples``). The states are propagated arc by arc with their 7×7 transition
matrices (the compiled DOP853 flow), so the gradients are exact:
``∂x(tf)/∂t_k = Φ(tf, t_k) (f(x_k, u_k⁻) - f(x_k, u_k⁺))`` and ``∂x(tf)/∂tf = f(x(tf), u)``.
SLSQP finds the optimum; a minimum-norm Newton polish brings the boundary residual to rounding.

The optimum of this finite problem is feasible and exact to the last digit, but it is a
*restriction* of the original problem: where the optimal control is singular it is an upper
bound on the optimal time (a finer sequence gets closer). Its KKT multipliers give costates
(``λ(tf) = -νᵀ ∂r/∂x``, carried back by the transition matrices; on a bang-bang optimum they are
its extremal's costates), from which ``auto`` tries the exact solver first.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .attitude_bvp import NY, AttitudeBVP
from .solution import bang_bang_control
from .switch_time import propagate_sequence
from .core.attitude_flow import FLOW_OK

@dataclass
class SwitchTimeOptResult:
    success: bool
    message: str
    T: float                    # nondimensional final time
    times: np.ndarray           # (n,) switch instants (nondimensional), in the sequence's order
    axes: np.ndarray            # (n,) axis of each switch
    signs0: np.ndarray          # (3,) sign of each axis's first arc
    residual: float             # boundary residual norm at the answer
    nit: int
    nfev: int
    z: np.ndarray = field(default_factory=lambda: np.full(6, np.nan))   # costates from the KKT multipliers
    kkt: float = math.nan       # residual of the stationarity condition (0 at a KKT point)
    converged: bool = False     # SLSQP reached a KKT point (else: its iteration limit, still feasible)

    def switch_times(self):
        """Per-axis sorted switch instants (nondimensional)."""
        return [np.sort(self.times[self.axes == i]) for i in range(3)]


def switch_time_applies(problem) -> bool:
    """Full-attitude target, per-axis bound, no cones: what switch-time optimisation covers."""
    return not problem.cones and problem.qf is not None and math.isinf(problem.torque_norm)


def optimise_switch_times(problem, signs0, axes, times, T, *, time_budget=1.0, max_iter=300,
                          bvp=None) -> SwitchTimeOptResult:
    """The fastest bang-bang slew of ``problem`` (per-axis bound, full-attitude target, no cones)
    with the switching sequence ``(signs0, axes)``, from the nondimensional instants ``times``
    and final time ``T`` (module docstring). A rate limit is not a constraint here: the caller
    checks it on the answer (``bang_bang_answer`` does, on its replay)."""
    from scipy.optimize import minimize
    bvp = bvp if bvp is not None else AttitudeBVP(problem)
    if bvp.pointing:
        raise ValueError("sensor_target: switch-time optimisation needs a full-attitude target (qf)")
    if not math.isinf(bvp.problem.torque_norm):
        raise ValueError("torque_norm: switch-time optimisation is for the per-axis bound")
    if bvp.problem.cones:
        raise ValueError(f"cones: switch-time optimisation does not impose keep-out cones "
                         f"({len(bvp.problem.cones)} given)")
    signs0, axes, times = checked_sequence(signs0, axes, times, T)
    bvp.set_mode("bang")
    n = axes.shape[0]
    y0 = _start_state(bvp)
    t_start = time.perf_counter()
    stats = {"nfev": 0, "nit": 0}
    cache = {}

    def evaluate(v, jac=False):
        """``(y(T), r, J_r, D7, M, nfev)`` at ``v`` (``propagate_sequence``); without ``jac``
        the last four but ``nfev`` are ``None``: SLSQP's line search needs the residual alone,
        and the arcs without transition matrices take the same steps at a fraction of the cost."""
        key = v.tobytes()
        hit = cache.get(key)
        if hit is None or (jac and hit[2] is None):
            if time.perf_counter() - t_start > time_budget:
                raise TimeoutError
            out = propagate_sequence(bvp, v[:n], axes, signs0, float(v[n]), y0, jac)
            if out is None:
                raise FloatingPointError("propagation failed")
            stats["nfev"] += out[-1]
            hit = out if jac else (out[0], out[1], None, None, None, out[2])
            cache.clear()
            cache[key] = hit
        return hit

    A = order_constraints(axes)
    e_T = np.zeros(n + 1)
    e_T[n] = 1.0
    v0 = np.concatenate([np.clip(np.asarray(times, float), 0.0, T), [T]])
    cons = [{"type": "eq", "fun": lambda v: evaluate(v)[1], "jac": lambda v: evaluate(v, True)[2]}]
    if A.shape[0]:
        cons.append({"type": "ineq", "fun": lambda v: A @ v, "jac": lambda v: A})
    fail = None
    try:
        # tf within a factor 2 of the start's: SLSQP's iterates can otherwise run tf towards 0
        # with every switch clipped past it (seen on a J = I slew over 168°)
        res = minimize(lambda v: v[n], v0, jac=lambda v: e_T, constraints=cons, method="SLSQP",
                       bounds=[(0.0, 2.0 * T)] * n + [(0.5 * T, 2.0 * T)],
                       options={"maxiter": max_iter, "ftol": 1e-13})
        v = res.x
        stats["nit"] = int(res.nit)
        # at the iteration limit the iterate is kept: the polish below makes it feasible, and a
        # feasible sequence is an answer (its tf an upper bound) whether or not it is stationary
        converged = bool(res.success)
        note = "a KKT point" if converged else f"SLSQP stopped ({res.message})"
    except TimeoutError:
        return SwitchTimeOptResult(False, f"time budget ({time_budget:g} s) exhausted", T, np.asarray(times, float),
                                   axes, signs0, math.inf, stats["nit"], stats["nfev"])
    except FloatingPointError as e:
        return SwitchTimeOptResult(False, str(e), T, np.asarray(times, float), axes, signs0, math.inf,
                                   stats["nit"], stats["nfev"])
    # polish the boundary conditions: minimum-norm Newton steps (the residual is exact, the
    # steps are tiny, the inequalities stay as SLSQP left them)
    try:
        for _ in range(8):
            _, r, Jr, *_ = evaluate(v, True)
            rn = float(np.linalg.norm(r))
            if rn < 1e-14:
                break
            vt = v - np.linalg.lstsq(Jr, r, rcond=None)[0]
            if not float(np.linalg.norm(evaluate(vt)[1])) < rn:
                break           # not converging: SLSQP ended far from feasible; fail below
            v = vt
        y, r, Jr, D7, M, _ = evaluate(v, True)
    except (TimeoutError, FloatingPointError) as e:
        return SwitchTimeOptResult(False, f"polish: {type(e).__name__} {e}", float(v[n]), v[:n].copy(), axes, signs0,
                                   math.inf, stats["nit"], stats["nfev"])
    resid = float(np.linalg.norm(r))
    if fail is None and not (resid < 1e-10):
        fail = f"boundary residual {resid:.2e} after the polish"
    times_kept, axes_kept, signs0 = evaluated_sequence(v, axes, signs0)
    z, kkt = kkt_costates(bvp, v, A, Jr, D7, M)
    ok = fail is None
    return SwitchTimeOptResult(ok, note if ok else fail, float(v[n]), times_kept, axes_kept, signs0,
                               resid, stats["nit"], stats["nfev"], z, kkt, converged)


def kkt_costates(bvp, v, A, Jr, D7, M):
    """``(z, kkt residual)`` of a switch-time iterate ``v = [times, T]`` whose state constraints
    are the boundary conditions alone (no active cone): ``J_r`` the residual's Jacobian in ``v``,
    ``D7 = ∂r/∂x(T)``, ``M`` the state transition over ``[0, T]`` (``propagate_sequence``; rows of a
    pointing target's roll transversality left out by the caller), ``A`` the order constraints.
    KKT: ``e_T = J_rᵀ ν + A_actᵀ μ`` by least squares, with the active inequalities (zero-width
    pulses, instants at 0 or T); its residual measures stationarity. ``z`` (unit norm, NaN if
    zero) is the solver's parameters ``[μ, λω(0)]`` of the costates ``λ(tf) = -D7ᵀ ν`` carried
    back to ``t = 0``: on a bang-bang optimum, its extremal's."""
    n = v.shape[0] - 1
    e_T = np.zeros(n + 1)
    e_T[n] = 1.0
    act = A[np.abs(A @ v) <= 1e-10 * max(1.0, float(v[n]))] if A.shape[0] else np.zeros((0, n + 1))
    K = np.hstack([Jr.T, act.T])
    mult, *_ = np.linalg.lstsq(K, e_T, rcond=None)
    nu = mult[:Jr.shape[0]]
    kkt = float(np.linalg.norm(K @ mult - e_T))
    # the state's costate at tf, λ(tf) = -νᵀ ∂r/∂x (the sign of the solver's convention: on R3
    # the exact extremal's costates come back to rounding), carried back to t = 0
    lam_T = -(D7.T @ nu)
    lam_0 = M.T @ lam_T
    mu = _quat_left_conj(bvp.q0, lam_0[0:4])
    z = np.concatenate([mu, lam_0[4:7]])
    nz = float(np.linalg.norm(z))
    return (z / nz if nz > 0 else np.full(6, np.nan)), kkt


def checked_sequence(signs0, axes, times, T):
    """``(signs0, axes, times)`` as float, int64 and float arrays, or a ``ValueError`` naming the
    argument: 3 signs ±1, one axis (0, 1 or 2) per finite switch instant, a positive ``T``."""
    axes = np.asarray(axes).ravel()
    times = np.asarray(times, dtype=float).ravel()
    signs0 = np.asarray(signs0, dtype=float).ravel()
    if signs0.shape != (3,) or not np.all(np.abs(signs0) == 1.0):
        raise ValueError(f"signs0: expected the 3 signs (±1) of the first arcs, got {signs0.tolist()}")
    if axes.shape != times.shape:
        raise ValueError(f"axes, times: one axis per switch instant, got {axes.size} axes and {times.size} times")
    if axes.size and not (np.issubdtype(axes.dtype, np.integer) and np.all((axes >= 0) & (axes <= 2))):
        raise ValueError(f"axes: switch axes must be 0, 1 or 2, got {axes.tolist()}")
    if not (math.isfinite(float(T)) and float(T) > 0.0) or not np.all(np.isfinite(times)):
        raise ValueError(f"T, times: need a positive final time and finite switch instants, got T={T}")
    return signs0, axes.astype(np.int64), times


def evaluated_sequence(v, axes, signs0):
    """``(times, axes, signs0)`` of the control that ``[times, T] = v`` evaluates. An axis's
    control depends only on the set of its flip instants: switches that a polish left out of
    order by rounding describe the same control, and the forward pass sorts them. One at or
    past ``T`` is no switch; one at or before 0 flips the first arc's sign."""
    n = axes.shape[0]
    keep = v[:n] < v[n]
    early = v[:n] <= 0.0
    signs0 = np.array(signs0, dtype=float)
    for a in axes[keep & early]:
        signs0[int(a)] = -signs0[int(a)]
    keep &= ~early
    return v[:n][keep].copy(), axes[keep].copy(), signs0


def order_constraints(axes):
    """``A`` with ``A @ [times, T] ≥ 0``: each axis's switches in order, ``0 ≤ t_k ≤ T``."""
    n = axes.shape[0]
    rows = []
    for a in range(3):
        idx = np.flatnonzero(axes == a)
        for i0, i1 in zip(idx, idx[1:]):
            row = np.zeros(n + 1)
            row[i1], row[i0] = 1.0, -1.0
            rows.append(row)
    for j in range(n):
        row = np.zeros(n + 1)
        row[j] = 1.0
        rows.append(row)
        row = np.zeros(n + 1)
        row[n], row[j] = 1.0, -1.0
        rows.append(row)
    return np.array(rows) if rows else np.zeros((0, n + 1))


def _start_state(bvp):
    """The augmented start state with zero costates (the state's flow does not use them)."""
    y0 = np.zeros(NY)
    y0[0:4], y0[4:7] = bvp.q0, bvp.w0
    return y0


def _quat_left_conj(q0, lq):
    """``Im(q0* ⊗ λq)``: the costate of the attitude in the solver's parameters ``μ``."""
    from slew_env.core.quaternion import qconj, qmul
    return qmul(qconj(q0), lq)[1:4]


def sequence_from_samples(t, u, umax, switch_times, u_first, min_unknowns=7, extra_pairs=0, interior=0.98,
                          singular_share=0.1):
    """A switching sequence ``(signs0, axes, times)`` for ``optimise_switch_times`` from a
    collocation answer: its zero crossings (``switch_times``, ``u_first``), plus zero-width pulse
    pairs: round robin over the axes, most interior first (the share of samples with
    ``|u| < interior·umax``), until there are at least ``min_unknowns`` unknowns (switches + tf),
    then ``extra_pairs`` more on the axes interior on over ``singular_share`` of the samples (a
    singular arc wants many; 0: every axis with an interior sample). An axis's pulses sit at
    evenly spaced quantiles of its interior samples' times."""
    signs0 = np.where(np.asarray(u_first, float) < 0, -1.0, 1.0)
    axes = [a for a in range(3) for _ in switch_times[a]]
    times = [float(s) for a in range(3) for s in switch_times[a]]
    t = np.asarray(t, float)
    v = np.abs(np.asarray(u, float)) / np.asarray(umax, float)[None, :]
    frac = np.mean(v < interior, axis=0)
    order = [int(a) for a in np.argsort(-frac, kind="stable")]
    pulses = [0, 0, 0]
    k = 0
    while len(times) + 2 * sum(pulses) + 1 < min_unknowns:
        pulses[order[k % 3]] += 1
        k += 1
    singular = [a for a in order if frac[a] > singular_share] or order[:1]
    for j in range(int(extra_pairs)):
        pulses[singular[j % len(singular)]] += 1
    for a in range(3):
        if not pulses[a]:
            continue
        inside = t[v[:, a] < interior]
        if inside.size == 0:                # no interior sample: the axis's least saturated ones
            inside = np.sort(t[np.argsort(v[:, a], kind="stable")[:max(1, pulses[a])]])
        for j in range(pulses[a]):
            tc = float(np.quantile(inside, (j + 0.5) / pulses[a]))
            axes += [a, a]
            times += [tc, tc]
    o = np.argsort(times, kind="stable")
    return signs0, np.asarray(axes, dtype=np.int64)[o], np.asarray(times, float)[o]


# A singular arc shows in a collocation answer as a long run of consecutive samples where one
# axis's torque is interior (|u| < 0.98 u_max); a switch gives a run of 2-7 samples. On 400
# held-out full-attitude problems (collocation's defaults), the longest run was at most 0.058 tf
# on all 352 with a bang-bang optimum and above 0.06 tf on 37 of the 48 singular ones.
SINGULAR_RUN = 0.06
SINGULAR_RUN_SAMPLES = 8


def interior_run(t, u, umax, interior=0.98):
    """``(axis, start, length, samples)``: the longest run of consecutive samples ``t`` on which
    one axis's torque ``u`` is interior (``|u_i| < interior · umax_i``); ``length`` in the
    units of ``t``, from the run's first sample to the first sample after it (to its own last
    sample for a run that ends the record). ``axis`` is -1 when no run has a positive length."""
    t = np.asarray(t, float)
    inside = np.abs(np.asarray(u, float)) < interior * np.asarray(umax, float)[None, :]
    best = (-1, math.nan, 0.0, 0)
    for a in range(inside.shape[1]):
        k = 0
        while k < t.shape[0]:
            if not inside[k, a]:
                k += 1
                continue
            j = k
            while j < t.shape[0] and inside[j, a]:
                j += 1
            length = float(t[min(j, t.shape[0] - 1)] - t[k])
            if length > best[2]:
                best = (a, float(t[k]), length, j - k)
            k = j
    return best


# a rate at this share of its limit or more counts as riding it (``singular_arc_evidence``)
RATE_LIMIT_ACTIVE = 0.99


def singular_arc_evidence(problem, col):
    """A sentence naming the singular arc that a collocation answer ``col`` shows (a run of
    interior torque on one axis over at least ``SINGULAR_RUN`` of tf and ``SINGULAR_RUN_SAMPLES``
    samples), or ``None``. Where it names one, ``auto`` skips the exact refinement (no bang-bang
    extremal is near) and goes to the switch-time answer, whose KKT costates still go to the exact
    solver (a bang-bang optimum that only looks singular is certified there)."""
    if not col.success or col.t is None or len(col.t) < 2 or col.u is None:
        return None
    a, start, length, n = interior_run(col.t, col.u, problem.torque_max)
    if a < 0 or n < SINGULAR_RUN_SAMPLES or not length >= SINGULAR_RUN * float(col.tf):
        return None
    what = "a singular arc"
    if problem.has_rate_limit and col.omega is not None:
        # interior torque where the rate rides its limit is the coast of a state-constrained arc,
        # not a singular arc (neither has an exact bang-bang answer here)
        t = np.asarray(col.t, float)
        run = (t >= start) & (t <= start + length)
        w = np.asarray(col.omega, float)[run]
        at_limit = problem.rate_limit_ratios(w) >= RATE_LIMIT_ACTIVE
        if at_limit.size and np.mean(at_limit) >= 0.5:
            what = (f"the rate limit is active (the rate within {1 - RATE_LIMIT_ACTIVE:.0%} of it on "
                    f"{np.mean(at_limit):.0%} of those samples): a rate-limited coast, a state-constrained arc")
    return (f"collocation's torque on axis {a + 1} is interior over {length / col.tf:.0%} of tf "
            f"(from t = {start:.4g}, {n} samples): {what}")


# SLSQP iterations for auto's bang-bang answer: on held-out singular problems 20 iterations
# already reach within ~1e-5 (relative) of the 300-iteration tf, below collocation's
SLSQP_ITERATIONS = 60
# extra pulse pairs of the successive rounds (a long singular arc needs several: held-out
# problem 180, J = I over 168°, beat collocation's tf only from 4 extra pairs on)
PULSE_ROUNDS = (0, 4, 8)
# ... and where none of them is verified, one more round with this many extra pairs over every axis
# whose torque is interior anywhere: the replay audit's full-attitude problem 106 (session 31;
# tests/test_switch_time_opt.py) has its torque interior on 5 % of x's samples and 2.5 % of z's,
# and with pulses on x alone no round became feasible (the boundary residual stayed at 9e-3);
# with pulses on z too the first round ends at a KKT point faster than collocation's answer
FALLBACK_PULSES = 4


def bang_bang_answer(problem, col, time_budget=0.5, tols=None):
    """``(answer, kkt_guess)``: a verified bang-bang answer from a collocation answer ``col`` of a
    full-attitude, per-axis problem without cones, and a ``Guess`` for the exact solver from its
    KKT costates (``None`` when they give no normal costate); ``(None, None)`` when it does not
    apply or is not at least as fast as ``col`` (within ``col.tf_tol``).

    The switch times are optimised (``optimise_switch_times``) on the collocation answer's
    sequence; the answer is verified like an indirect one where that applies: the boundary
    errors at the end of the DOP853 propagation, an independent replay of the switch times
    with the environment's RK4, and the rate limit along the replay. It is not an extremal
    (no Hamiltonian or switching-law check): ``method="switch-time"``, ``exact`` is False,
    ``costate0`` and the dense costates come from the KKT multipliers, carried along the arcs
    (in the scale ``H(0) = -1``; where they give no normal costate, ``costate0`` is
    collocation's estimate and the dense costates are NaN). Their switching functions show
    where the optimum leaves the bang-bang law (a singular arc)."""
    t0 = time.perf_counter()
    if not col.success or not switch_time_applies(problem) or col.switch_times is None or len(col.t) < 2:
        return None, None
    return answer_from_collocation(problem, col, AttitudeBVP(problem), optimise_switch_times, time_budget, tols,
                                   SLSQP_ITERATIONS, t0)


def answer_from_collocation(problem, col, bvp, optimise, time_budget, tols, max_iter, t0, pulse_rounds=None,
                            stop_at_kkt_only=False):
    """``(answer, kkt_guess)`` of ``bang_bang_answer`` with the optimiser ``optimise`` (this
    module's, or ``switch_time_cones``' with the cones imposed) and the extra pulse pairs of
    each round (default ``PULSE_ROUNDS``), ``(None, None)`` when nothing is verified or it is
    slower than ``col`` beyond ``col.tf_tol``. Each round gets the time left; the rounds stop when
    one gains less than 1e-6 of tf, with ``stop_at_kkt_only`` only when that round ended at a KKT
    point (an optimiser that returns its best feasible iterate when its time runs out says
    nothing about what more pulses would gain)."""
    tau = bvp.tau
    sw = [np.asarray(s, float) / tau for s in col.switch_times]
    # more pulse pairs approximate a singular arc better: rounds with more, the fastest kept,
    # until a round gains less than 1e-6 (relative) or the time is spent
    r = None
    seen = set()

    def round_of(extra, share):
        """One round's optimised sequence; ``None`` when no time is left or the sequence is one
        an earlier round tried."""
        left = time_budget - (time.perf_counter() - t0)
        if left <= 0.0:
            return None
        signs0, axes, times = sequence_from_samples(np.asarray(col.t) / tau, col.u, problem.torque_max, sw,
                                                    col.u_first, extra_pairs=extra, singular_share=share)
        key = (signs0.tobytes(), axes.tobytes(), times.tobytes())
        if key in seen:
            return None
        seen.add(key)
        return optimise(problem, signs0, axes, times, col.tf / tau, time_budget=left, max_iter=max_iter, bvp=bvp)

    for extra in PULSE_ROUNDS if pulse_rounds is None else pulse_rounds:
        if time.perf_counter() - t0 >= time_budget:
            break
        ri = round_of(extra, 0.1)
        if ri is None or not ri.success:
            continue
        if r is not None and ri.T > r.T * (1.0 - 1e-6):
            r = ri if ri.T < r.T else r
            if ri.converged or not stop_at_kkt_only:
                break
            continue
        r = ri
    if r is None:
        # nothing verified: pulses on every axis whose torque is interior anywhere (FALLBACK_PULSES)
        ri = round_of(FALLBACK_PULSES, 0.0)
        r = ri if ri is not None and ri.success else None
    if r is None:
        return None, None
    col_tol = float(col.tf_tol) if col.tf_tol == col.tf_tol else 0.0
    if not r.T * tau <= col.tf + col_tol:
        return None, None
    tf = r.T * tau
    # tf_tol: how far below tf the optimum may be, as far as collocation tells: down to its lower
    # bracket, and never less than half collocation's tolerance, since that end is an estimate
    # too (N against N / 2 intervals): an answer at or below it would otherwise claim a
    # certainty nothing measured (1e-10 · tf), and a slightly looser collocation would make it
    # jump from there to the whole tolerance
    lower = col.tf - col_tol
    comparison = f"against collocation's {col.tf:.9g} ± {col_tol:.1g}"
    answer, kkt_guess = _answer(problem, bvp, r, tols, "collocation's sequence", f" vs collocation's {col.tf:.9g} "
                                f"± {col_tol:.1g}", comparison, lambda att: max(
                                    tf - lower, 0.5 * col_tol, tf * max(1e-10, 10.0 * att)),
                                np.array(col.costate0, float), t0)
    if answer is not None:
        answer.nit += int(col.nit)
        answer.nfev += int(col.nfev)
        answer.guess, answer.n_candidates = col.guess, col.n_candidates
        answer.candidates_tf, answer.baseline_tf = list(col.candidates_tf or []), col.baseline_tf
    return answer, kkt_guess


def bang_bang_from_sequences(problem, sequences, time_budget=0.2, tols=None, tf_rel_tol=math.nan, source="table",
                             max_iter=None, kkt_tol=None, give_up_residual=math.inf, numbered=True):
    """``(answer, kkt_guess, (nit, nfev))`` like ``bang_bang_answer``, from given switching
    sequences instead of a collocation answer: ``sequences`` holds ``(u_first, switch_times,
    tf)`` in the problem's units (per-axis lists of instants, for instance a near problem's
    answer). Each is optimised in turn (``max_iter`` SLSQP iterations, default that of the
    problem's optimiser) and verified, until the time is spent; the fastest verified answer is
    kept. ``(nit, nfev)`` counts the work on all of them. There is no collocation answer to
    compare with, so ``tf_tol`` is ``tf_rel_tol · tf`` (an estimate measured by the caller on
    held-out problems) or NaN. ``costate0`` is the KKT multipliers' costates, an estimate where
    the iterate is not a KKT point (the dense costates are then NaN). The KKT guess is given only
    when the answer is a KKT point of its sequence (residual at most ``KKT_TOL``): after a few
    iterations on a singular problem it is not, and the exact solver from it would fail, at tens
    of milliseconds; ``kkt_tol`` (default ``KKT_TOL``) sets that residual (``math.inf``: the guess
    always, for a caller that expects a bang-bang optimum, where an iterate near it leads the
    exact solver there). ``(None, None, (nit, nfev))`` when nothing is verified or neither
    ``switch_time_applies`` nor ``switch_time_cones.switch_time_cones_applies`` holds.

    Keep-out cones and pointing targets: the sequences are optimised with the cones imposed
    (``switch_time_cones.optimise_switch_times_cones``, which stops a sequence after a round
    whose boundary residual stays above ``give_up_residual``), and the clearance is certified
    on the replay; their KKT costates (and guess) exist only where the path keeps clear of every
    cone (``switch_time_cones._costates_where_clear``), else ``costate0`` is NaN. ``numbered``
    (default): the route numbers the sequence and counts those tried (a caller that passes one
    sequence at a time says so itself)."""
    from .switch_time_cones import SLSQP_ITERATIONS as CONE_ITERATIONS
    from .switch_time_cones import optimise_switch_times_cones, switch_time_cones_applies
    t0 = time.perf_counter()
    cones = switch_time_cones_applies(problem)
    if not (cones or switch_time_applies(problem)):
        return None, None, (0, 0)
    if cones:
        bvp = AttitudeBVP(problem.replace(cones=()))
        max_iter = CONE_ITERATIONS if max_iter is None else max_iter

        def optimise(*args, **kw):
            return optimise_switch_times_cones(*args, give_up_residual=give_up_residual, **kw)
    else:
        bvp = AttitudeBVP(problem)
        max_iter = SLSQP_ITERATIONS if max_iter is None else max_iter
        optimise = optimise_switch_times
    tau = bvp.tau
    best = None
    tried = nit = nfev = 0
    for u_first, switch_times, tf in sequences:
        elapsed = time.perf_counter() - t0
        left = time_budget - elapsed
        if left <= 0.0 and tried:
            break
        if best is not None and left < elapsed / tried:
            # with an answer in hand, a sequence that would likely end past the budget is not
            # started (one takes about as long as those before it: 5-10 ms at 10 iterations)
            break
        tried += 1
        signs0 = np.where(np.asarray(u_first, float) < 0, -1.0, 1.0)
        axes = np.array([a for a in range(3) for _ in switch_times[a]], dtype=np.int64)
        times = np.array([float(x) for a in range(3) for x in switch_times[a]]) / tau
        # at least the 6 boundary conditions' worth of unknowns: zero-width pulse pairs at mid
        # time, on the x, y, z axes in turn, until there are (a neighbour's singular sequence
        # has more than enough; this is for a short bang-bang one)
        extra_axes, extra_times, a = [], [], 0
        while axes.size + len(extra_axes) + 1 < 7:
            extra_axes += [a % 3, a % 3]
            extra_times += [0.5 * tf / tau] * 2
            a += 1
        axes = np.concatenate([axes, np.array(extra_axes, dtype=np.int64)])
        times = np.concatenate([times, extra_times])
        o = np.argsort(times, kind="stable")
        r = optimise(problem, signs0, axes[o], times[o], tf / tau, time_budget=max(left, 0.01), max_iter=max_iter,
                     bvp=bvp)
        nit += r.nit
        nfev += r.nfev
        if not r.success or (best is not None and not r.T < best[0].T):
            continue
        T = r.T * tau
        comparison = (f"not compared with collocation (tf_tol {tf_rel_tol:.1g} of tf, measured on held-out problems)"
                      if tf_rel_tol == tf_rel_tol else "not compared with collocation (tf_tol not estimated)")
        what = f"the sequence of {source} {tried}" if numbered else f"the sequence of {source}"
        answer, kkt_guess = _answer(problem, bvp, r, tols, what, "", comparison,
                                    lambda att, T=T: max(T * tf_rel_tol, T * 10.0 * att) if tf_rel_tol == tf_rel_tol
                                    else math.nan, None, t0)
        if answer is not None:
            best = (r, answer, kkt_guess if r.kkt <= (KKT_TOL if kkt_tol is None else kkt_tol) else None)
    if best is None:
        return None, None, (nit, nfev)
    r, answer, kkt_guess = best
    if numbered:
        answer.route += f"; {tried} sequence(s) tried"
    answer.guess, answer.n_candidates = source, tried
    answer.nit, answer.nfev = nit, nfev
    answer.wall_time = time.perf_counter() - t0
    return answer, kkt_guess, (nit, nfev)


def _answer(problem, bvp, r, tols, what, route_tail, comparison, tf_tol_of, fallback_costate0, t0):
    """The verified ``SlewSolution`` of an optimised sequence ``r`` and its KKT guess, or
    ``(None, None)`` if a check fails: boundary errors at the end of the DOP853 arcs, an RK4
    replay of the switch times, the rate limit. ``what`` names the sequence in the route (with
    ``route_tail`` after it), ``comparison`` ends the message; ``tf_tol_of(attitude/rate miss)``
    gives its ``tf_tol``; ``fallback_costate0`` is reported when the iterate is not a KKT point (``None``:
    the multipliers' costates all the same, an estimate, or NaN when they give no normal costate)."""
    from .clearance import CLEARANCE_TOL, certified_replay
    from .guesses import Guess
    from .solution import STATUS_SUCCESS, SlewSolution
    from .verify import (DEFAULT_TOLS, boundary_checks, end_error, failure_text, make_check, rate_limit_check,
                         replay_path)
    tols = dict(DEFAULT_TOLS, **(tols or {}))
    tau = bvp.tau
    sw_nd, signs0 = _without_end_switches([_drop_null_pulses(x, r.T) for x in r.switch_times()], r.signs0, r.T)
    ax = np.concatenate([np.full(len(x), a, dtype=np.int64) for a, x in enumerate(sw_nd)])
    end = propagate_sequence(bvp, np.concatenate(sw_nd), ax, signs0, r.T, _start_state(bvp), False)
    if end is None:
        return None, None
    checks = boundary_checks(bvp, end[0], tols)
    # (a pointing target's roll transversality is a costate condition of extremals: not checked
    # on a bang-bang answer, whose costates are not an extremal's)
    checks.pop("roll_transversality", None)
    att = checks["boundary_attitude_error"]["value"]
    t_nd, x = replay_path(bvp.J, bvp.umax, bvp.q0, bvp.w0, sw_nd, signs0, r.T)
    rep = end_error(bvp, x[-1])
    checks["replay"] = make_check(rep, tols["replay"], rep <= tols["replay"])
    checks.update(rate_limit_check(bvp, x, tols, t_nd, sw_nd, signs0))
    if problem.cones:
        # certified at every instant on an RK4 replay of the switch times (finer where needed)
        cert = certified_replay(problem, [s * bvp.tau for s in sw_nd], signs0, r.T * bvp.tau)[2]
        checks["cone_clearance"] = make_check(cert, CLEARANCE_TOL, cert >= CLEARANCE_TOL)
    if failure_text(checks):
        return None, None
    tf = r.T * tau
    switch_times = [s * tau for s in sw_nd]
    # costates: the KKT multipliers' (scaled to H(0) = -1) when SLSQP's iterate is stationary
    # (their residual below KKT_TOL), else the fallback estimate and no dense costates
    c = math.nan
    kkt_costate0 = None
    if np.all(np.isfinite(r.z)):
        yz, _ = bvp.initial(r.z)
        H0 = bvp.hamiltonian(yz, signs0)
        if H0 < 0.0:
            kkt_costate0 = np.concatenate([-tau * yz[7:11] / H0, -tau ** 2 * yz[11:14] / H0])
            c = -1.0 / H0 if r.kkt <= KKT_TOL else math.nan
    u_first = signs0.copy()
    control = bang_bang_control(switch_times, u_first, problem.torque_max)
    rec = _dense_record(bvp, sw_nd, signs0, r.T, r.z if c == c else np.full(6, np.nan))
    if rec is None:
        return None, None
    t_rec, Y = rec
    t = t_rec * tau
    u = control(t)          # at a switch instant, the sample of the arc after it
    if c == c:
        costate = np.hstack([c * tau * Y[:, 7:11], c * tau ** 2 * Y[:, 11:14]])
        costate0 = kkt_costate0
    else:
        costate = np.full((t.shape[0], 7), np.nan)
        costate0 = fallback_costate0 if fallback_costate0 is not None else (
            kkt_costate0 if kkt_costate0 is not None else np.full(7, np.nan))
    n = int(ax.shape[0])
    how = "a KKT point of the sequence" if r.converged else f"after {r.nit} SLSQP iterations"
    route = (f"bang-bang switch-time optimisation of {what} ({n} switches, {how}; KKT residual {r.kkt:.1e}; "
             f"boundary residual {r.residual:.1e}): tf {tf:.9g}{route_tail}")
    message = (f"{STATUS_MESSAGES_SUCCESS_BANG} {n} switches; it reaches the target to {max(att, rep):.1e} and "
               f"takes {tf:.9g}, {comparison}.")
    answer = SlewSolution(True, STATUS_SUCCESS, message, nit=r.nit, nfev=r.nfev,
                          wall_time=time.perf_counter() - t0, tf=tf, tf_tol=tf_tol_of(max(att, rep)),
                          costate0=costate0, switch_times=switch_times,
                          u_first=u_first, t=t, q=Y[:, 0:4].copy(), omega=Y[:, 4:7] / tau, u=u,
                          costate=costate, method="switch-time", route=route,
                          baseline_tf=math.nan, verification=checks, problem=problem, _control=control)
    # the KKT costates as a guess for the exact solver even when they are not reported (a
    # non-stationary iterate's multipliers can still lead to the extremal)
    kkt_guess = None
    if kkt_costate0 is not None:
        kkt_guess = Guess(kkt_costate0, tf, switch_times, u_first, source="switch-time optimisation")
    return answer, kkt_guess


STATUS_MESSAGES_SUCCESS_BANG = ("Verified bang-bang slew with optimised switch times (not an extremal: the "
                                "optimum has a singular arc, rides a keep-out cone or was not refined exactly, "
                                "so tf is an upper bound on the optimal time, which tf_tol estimates).")
# KKT residual below which the multipliers are reported as costates
KKT_TOL = 1e-6


def _without_end_switches(sw, signs0, T):
    """``(switches, first-arc signs)`` without switches within ``1e-12 T`` of the ends: one at the
    start flips that axis's first arc, one at the end changes nothing. (An optimised sequence can
    keep an arc of rounding length there: at 1.1e-19 tf on an outside check of units, session 43,
    and the exact solver, given one switch too many, then failed where in other units it certified
    the same slew's extremal.)"""
    signs = np.array(signs0, float)
    out = []
    for a, times in enumerate(sw):
        times = [float(t) for t in times]
        while times and times[0] <= 1e-12 * T:
            times.pop(0)
            signs[a] = -signs[a]
        while times and times[-1] >= T * (1.0 - 1e-12):
            times.pop()
        out.append(np.asarray(times, float))
    return out, signs


def _drop_null_pulses(times, T):
    """An axis's sorted switch instants without the zero-width pulses (two consecutive
    switches at the same instant flip the torque twice: no effect on the control)."""
    out = []
    for t in times:
        if out and t - out[-1] <= 1e-12 * T:
            out.pop()
        else:
            out.append(float(t))
    return np.asarray(out, float)


def _dense_record(bvp, sw_nd, signs0, T, z, n_steps=100):
    """``(t, Y)``, or ``None`` if a propagation fails: the bang-bang slew with the switches
    ``sw_nd`` (per axis) sampled at every DOP853 step (capped at ``T / n_steps``, the default
    dense density of the indirect answers) and once at every switch, the state with the
    costates of ``z`` (the KKT multipliers') carried along the same arcs (zeros without)."""
    events = sorted((float(t), a) for a in range(3) for t in sw_nd[a])
    y = bvp.initial(z)[0] if np.all(np.isfinite(z)) else _start_state(bvp)
    signs = np.array(signs0, float)
    ts, Ys, t0 = [np.zeros(1)], [y[None, :].copy()], 0.0
    for t1, a in events + [(T, -1)]:
        # (two axes switching at one instant leave an arc of rounding length: nothing to sample)
        if t1 - t0 > 1e-12 * T:
            cap = 4 * n_steps + 8
            out = bvp._run(y, t1 - t0, None, signs0=signs, record=cap, detect=False, hmax=T / n_steps)
            n_rec, status, rt, rY = out[2], out[5], out[6], out[7]
            if status != FLOW_OK or n_rec < 2 or n_rec >= cap:     # failed, or samples dropped
                return None
            ts.append(t0 + rt[1:n_rec])
            Ys.append(rY[1:n_rec].copy())
            y = out[0][:NY].copy()
        t0 = max(t0, t1)
        if a >= 0:
            signs[a] = -signs[a]
    return np.concatenate(ts), np.vstack(Ys)
