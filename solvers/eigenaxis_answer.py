"""The eigenaxis slew as a ``SlewSolution``: the baseline planner in the solvers' result format.

``solve(problem, method="eigenaxis")`` returns it; ``method="auto"`` returns it when the best
answer it found is an approximate one slower than the eigenaxis slew (small slews, where the
time-optimal slew and the eigenaxis slew agree to first order and collocation cannot tell them
apart within its accuracy).

The answer is the phase-plane profile of ``eigenaxis.eigenaxis_slew``: on each of its
``n_grid`` angle steps (split where the speed reaches the rate limit inside one) the
acceleration ``θ̈_k`` is constant, so the rate is linear in time,
``θ̇(t) = θ̇_k + θ̈_k (t - t_k)``, and the torque is ``u = θ̈_k J n + θ̇² (n × J n)`` — affine in
``θ̇²`` between the step's ends, where the sweep keeps it within the bound, so within the bound
throughout. ``control(t)`` is that torque, and ``tf`` the profile's exact duration. The
verification replays the control (RK4, ``core.control_replay``) and checks the boundary
(1e-8, as for exact answers), the torque bound at every step's ends and the rate limit.
A pointing target is flown to its reference attitude (the smallest rotation that takes the
sensor onto the target); keep-out cones are not avoided but checked: the answer is verified
where the path clears them (``cone_clearance``, certified between samples) and fails otherwise
(``solve(method="eigenaxis")`` then flies round them through waypoints: ``waypoint_slew``).
It is not an extremal of the time-optimal problem: ``exact`` is ``False``, ``costate0`` is NaN
and ``switch_times`` are empty (the torque is not bang-bang per axis).
"""
from __future__ import annotations

import math
import time

import numpy as np

from slew_env import SlewProblem
from slew_env.core.cones import angle_between
from slew_env.core.quaternion import qerror_angle, qrotate
from slew_env.checks import is_integer
from .attitude_bvp import AttitudeBVP
from .eigenaxis import (BASELINE_CLEARANCE, _checked, _phase_plane, eigenaxis_path, eigenaxis_slew, eigenaxis_time,
                        reference_problem)
from .solution import STATUS_SUCCESS, STATUS_VERIFICATION_FAILED, STATUS_MESSAGES, STATUS_WORSE_THAN_BASELINE, SlewSolution
from .verify import failure_text, make_check

BOUNDARY_TOL = 1e-8
N_GRID = 16000     # per-axis (compiled sweep, ~20 ms): within ~4e-8 of the continuous profile
# a p-norm bound with a gyroscopic term: each grid point finds its acceleration interval by
# golden section and bisection (compiled, ~0.3 s for 4000 steps; within ~1e-5 of the
# continuous profile with an active rate limit)
N_GRID_PNORM_GYRO = 4000
N_DENSE = 2000
# the verification's RK4 replay takes at least this many steps in all
REPLAY_MIN_STEPS = 4000
# relative margin below the grid eigenaxis time (n_grid = 1000) under which an answer is faster
# than the eigenaxis slew without planning that slew: on 1,200 problems the grid time was at most
# 1.8e-5 above the slew's (``eigenaxis_answer``); a session-32 audit found up to 4.8e-4 above the
# continuous profile on strongly asymmetric bodies (J = [0.1, 0.5, 1]), still inside it
GRID_MARGIN = 1e-3


# the same for the multi-start's gate, by bound: the 1,000-step grid lies above the fine one by up to
# 3.8e-4 per-axis and 9.9e-5 under a 2-norm bound (6 random slews of J = [0.3, 0.6, 1] each,
# session 32); the fine grid costs 13 and 25-34 ms there (the seconds below, with a margin), and is
# computed only when an answer falls within the margin and the solve has that much time left.
# (Under a 2-norm bound a nearly symmetric body's optimum lies within 1e-5 of its eigenaxis slew:
# 2 of bench_budget's 10 p-norm slews pay the 25 ms, runs/s32/bench_budget2.txt)
FINE_GATE = {"per-axis": (GRID_MARGIN, 0.02), "p-norm": (1.5e-4, 0.05)}


def fine_eigenaxis_time(prob) -> float:
    """The eigenaxis slew's time of ``prob`` on the planner's fine grid (``N_GRID`` steps per-axis,
    within ~4e-8 of the continuous profile; ``N_GRID_PNORM_GYRO`` for a p-norm bound), for
    deciding whether an answer near the 1,000-step grid time (``FINE_GATE``) is faster."""
    from .eigenaxis import eigenaxis_time
    return eigenaxis_time(prob, n_grid=N_GRID if math.isinf(prob.torque_norm) else N_GRID_PNORM_GYRO)


def eigenaxis_inapplicable(prob):
    """Why the eigenaxis slew is not an answer to ``prob`` (it needs a problem at rest at both
    ends), or ``None``: where ``solve``'s eigenaxis fallback and ``method="eigenaxis"`` do not
    apply. (With cones it applies where its path clears them: ``eigenaxis_answer`` checks.)"""
    return None if prob.is_rest_to_rest else "non-zero rates"


def _not_compared(prob):
    """Why ``auto`` does not compare its answer to ``prob`` with the eigenaxis slew
    (``no_slower_than_eigenaxis``), or ``None``: it does for full-attitude targets without cones."""
    if prob.cones:
        return "keep-out cones"
    if prob.qf is None:
        return "a pointing target"
    return eigenaxis_inapplicable(prob)


class EigenaxisLeg:
    """One rest-to-rest eigenaxis rotation of a full-attitude problem ``prob`` (no cones), planned
    on ``n_grid`` angle steps: its phase-plane profile, control, dense samples and replay (the
    answer of ``eigenaxis_answer``, and each leg of a waypoint slew, ``waypoint_slew``)."""

    def __init__(self, prob: SlewProblem, n_grid: int):
        self.n, self.th, self.a, self.c, _ = _phase_plane(prob)
        es = eigenaxis_slew(prob, n_grid)
        self.t, self.rate = es.t, es.rate
        self.s = self.rate ** 2
        # per piece (the grid steps, split where the rate cap starts), as the planner found it
        self.acc = es.acc
        self.theta = es.theta
        self.q0 = np.asarray(prob.q0, float)
        self.J = np.asarray(prob.inertia, float)
        self.U = np.asarray(prob.torque_max, float)
        self.p = float(prob.torque_norm)
        self.tf = float(self.t[-1])
        self.peak_rate = float(np.max(np.abs(self.rate)))

    def _locate(self, tq):
        t = self.t
        tq = np.clip(np.asarray(tq, dtype=float), 0.0, t[-1])
        k = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, t.size - 2)
        return k, tq - t[k]

    def control(self, tq):
        tq = np.asarray(tq, dtype=float)
        k, tau = self._locate(tq)
        r = self.rate[k] + self.acc[k] * tau
        return self.acc[k][..., None] * self.a + (r * r)[..., None] * self.c

    def samples(self, n_dense=N_DENSE):
        """``(t, q, omega, u)``: the exact profile at ``n_dense`` uniform instants and twice at each
        breakpoint (where the acceleration jumps: from speeding up to braking, the ends of a
        coast), first with the torque before it, then after, so that the samples flown linearly
        between them are the slew (``control_law`` "linear-samples": exact without a gyroscopic term,
        else within ``RECORD_TOL`` of the target, the ``record_replay`` check)."""
        t, acc, rate = self.t, self.acc, self.rate
        # a coarse profile (a fallback's under a short budget): every piece's end is a breakpoint
        # (flown linearly across them, the samples of a 400-step profile had missed by 1e-5 rad);
        # a fine one: where the acceleration jumps by more than 1 % of its largest value
        floor = 0.0 if acc.size <= ALL_BREAKS_MAX else 1e-2 * max(float(np.max(np.abs(acc))), 1e-300)
        breaks = t[1:-1][np.abs(np.diff(acc)) > floor]
        grid = np.linspace(0.0, float(t[-1]), int(n_dense) + 1)
        if breaks.size:       # (the uniform instants within 1e-9 tf of a breakpoint: the breakpoint)
            j = np.clip(np.searchsorted(breaks, grid), 1, breaks.size)
            near = np.minimum(np.abs(grid - breaks[j - 1]), np.abs(breaks[np.minimum(j, breaks.size - 1)] - grid))
            grid = grid[near > 1e-9 * t[-1]]
        td = np.sort(np.concatenate([grid, breaks, breaks]), kind="stable")
        k, tau = self._locate(td)
        # the first of each pair of equal instants takes the step before the breakpoint (its end)
        first = np.concatenate([td[1:] == td[:-1], [False]])
        k = np.where(first, k - 1, k)
        tau = np.where(first, td - t[np.clip(k, 0, None)], tau)
        thd = self.theta[k] + rate[k] * tau + 0.5 * acc[k] * tau ** 2
        rd = rate[k] + acc[k] * tau
        qd = eigenaxis_path(self.q0, self.n, thd)
        ud = acc[k][:, None] * self.a + (rd * rd)[:, None] * self.c
        return td, qd, rd[:, None] * self.n[None, :], ud

    def replay(self, x0) -> np.ndarray:
        """The state at the end of the control flown (RK4, ``core.control_replay``) from ``x0``."""
        from .core.control_replay import replay_eigenaxis_profile
        # RK4 steps a piece: 4, or more on a coarse profile (its error, ~(steps)⁻⁴, had failed the
        # 1e-8 boundary check at n_grid ≤ 6 with 4 a piece, on a profile that is exact)
        substeps = max(4, -(-REPLAY_MIN_STEPS // (self.t.size - 1)))
        return replay_eigenaxis_profile(np.ascontiguousarray(x0, float), np.ascontiguousarray(self.t, float),
                                        np.ascontiguousarray(self.rate, float), np.ascontiguousarray(self.acc, float),
                                        np.ascontiguousarray(self.a, float), np.ascontiguousarray(self.c, float),
                                        self.J, substeps)

    def bound_ratio(self) -> float:
        """The largest torque over the bound at both ends of every step (the torque is affine in
        ``θ̇²`` between them, so this bounds the whole profile)."""
        acc, s = self.acc, self.s
        ends = np.vstack([acc[:, None] * self.a + s[:-1, None] * self.c, acc[:, None] * self.a + s[1:, None] * self.c])
        ratio = np.abs(ends) / self.U
        return float(np.max(ratio)) if math.isinf(self.p) else float(np.max(np.sum(ratio ** self.p, axis=1) ** (1.0 / self.p)))


# rad: the recorded samples, flown linearly between them as ``control_law`` "linear-samples" says,
# reach the target within this (``record_check``). The exact profile meets the boundary to 1e-8,
# but where the body has a gyroscopic term its torque is quadratic in t between the samples, and
# the small acceleration steps of a profile of more than ``ALL_BREAKS_MAX`` pieces fall between
# them: the record misses by up to ~2e-6 rad on the default profiles of 60 random bodies (per-axis
# and 2-norm bounds, session 42), and near a half turn by up to 1.25e-4 (a review: 120 slews of
# 143-180°, some with rate limits), where ``recorded`` doubles the samples; the worst then 8.2e-5
RECORD_TOL = 1e-4
# how far (relative) the flown record's rates may pass an active rate limit: the record's own
# accuracy, as RECORD_TOL for its end
RECORD_RATE_TOL = 1e-4
# profiles of at most this many pieces list every piece's end in their samples (``samples``)
ALL_BREAKS_MAX = 1000
# where the record misses by more than ``RECORD_TOL`` (a long slew riding a rate limit, near a half
# turn: 1.25e-4 at 2,000 samples, a review), the samples are doubled, at most this many times (the
# miss falls as the square of their spacing)
RECORD_MAX_DOUBLINGS = 3


def recorded(target, sample_sets, J):
    """``((td, qd, wd, ud), check)``: the dense samples of a slew, ``sample_sets(n)`` giving them
    at ``n`` uniform instants (a leg's, or every leg's joined): ``N_DENSE``, doubled while flying
    them misses the target by more than ``RECORD_TOL`` (``RECORD_MAX_DOUBLINGS`` times at most),
    and the ``record_replay`` check of those returned."""
    n = N_DENSE
    for _ in range(RECORD_MAX_DOUBLINGS + 1):
        samples = sample_sets(n)
        chk = record_check(target, samples[0], samples[3], J)
        if chk["passed"] and chk.get("rate", {}).get("passed", True):
            break
        n *= 2
    return samples, chk


def record_check(target, td, ud, J):
    """The ``record_replay`` check: the dense samples ``(td, ud)`` flown as the record defines the
    control (linear in t between them; each breakpoint listed twice), by RK4 from the start at rest,
    and the attitude error at the end (rad; for a pointing target, the sensor's angle to it), with
    the rate error in the same scale (``|Δω|·tf``)."""
    from .core.control_replay import replay_quadratic_control
    td = np.ascontiguousarray(td, float)
    ud = np.ascontiguousarray(ud, float)
    x0 = np.concatenate([np.asarray(target.q0, float), np.asarray(target.omega0, float)])
    # the quadratic through the ends and their mean is the straight line between them; one RK4
    # step an interval (its error, ~h⁵, is far below the record's own miss: DOP853 agrees to 1 %)
    _, X, _ = replay_quadratic_control(x0, td, ud, np.ascontiguousarray(0.5 * (ud[:-1] + ud[1:])),
                                       np.full(3, np.inf), math.inf, np.asarray(J, float), 1, 1)
    qT = X[-1, 0:4] / np.linalg.norm(X[-1, 0:4])
    att = (float(angle_between(np.asarray(qrotate(qT, target.sensor_axis)), target.target_direction))
           if target.qf is None else float(qerror_angle(qT, target.qf)))
    err = max(att, float(np.linalg.norm(X[-1, 4:7] - target.omegaf)) * float(td[-1]))
    # an active rate limit: the profile coasts on it, and the flown record's rates overshoot it by
    # up to ~1e-5 (an outside check, session 43): held to RECORD_RATE_TOL and reported
    chk = make_check(err, RECORD_TOL, err <= RECORD_TOL)
    chk["note"] = "the recorded samples flown linearly (control_law 'linear-samples')"
    if target.has_rate_limit:
        ratio = float(target.rate_limit_ratio(X[:, 4:7]))
        # (its own check, ``record_checks``: a failure names the ratio, not the end's miss)
        chk["rate"] = make_check(ratio, 1.0 + RECORD_RATE_TOL, ratio <= 1.0 + RECORD_RATE_TOL)
        chk["rate"]["note"] = "the rate limit on the recorded samples flown linearly"
    return chk


def record_checks(record) -> dict:
    """``record_replay`` (the end's miss) and, with a rate limit, ``record_rate_limit`` (the flown
    record's largest rate-limit ratio) from ``record_check``'s result."""
    record = dict(record)
    rate = record.pop("rate", None)
    return {"record_replay": record, **({"record_rate_limit": rate} if rate is not None else {})}


def legs_checks(target, legs, xf, samples, record, cone_note=None) -> dict:
    """The verification of a slew flown as eigenaxis ``legs`` one after another (the eigenaxis
    answer's one leg, or a waypoint slew's), for the problem ``target``: ``xf``, the state their
    controls reach, replayed from the start, against the target (1e-8; the rate's scale the peak
    rate, at least 1 / τ); the torque bound at every step's ends; the rate limit; with cones the
    clearance of the dense ``samples`` ``(t, q, omega, u)``, certified between them (failing with
    ``cone_note``, if given, as its note); and the record's own checks (``record_checks``)."""
    qT = xf[0:4] / np.linalg.norm(xf[0:4])
    att = (float(angle_between(np.asarray(qrotate(qT, target.sensor_axis)), target.target_direction))
           if target.qf is None else float(qerror_angle(qT, target.qf)))
    rate_err = float(np.linalg.norm(xf[4:7] - target.omegaf))
    # the rate's scale: the peak rate, at least 1 / τ (τ = sqrt(J_max / u_max)): unit-consistent, as
    # verify's 1e-8 / τ (a floor of 1 rad per problem time unit had let a slow body's rate miss by
    # 1 % of its scale at τ = 1e6 s: an outside check of physical units, session 43)
    w_scale = max(1.0 / target.time_unit, max(leg.peak_rate for leg in legs))
    bound = max(leg.bound_ratio() for leg in legs)
    checks = {"boundary_attitude_error": make_check(att, BOUNDARY_TOL, att <= BOUNDARY_TOL),
              "boundary_rate_error": make_check(rate_err, BOUNDARY_TOL * w_scale, rate_err <= BOUNDARY_TOL * w_scale),
              "torque_bound": make_check(bound, 1.0 + 1e-9, bound <= 1.0 + 1e-9)}
    if target.has_rate_limit:
        rl = max(target.rate_limit_ratio(leg.peak_rate * leg.n) for leg in legs)
        checks["rate_limit"] = make_check(rl, 1.0 + 1e-9, rl <= 1.0 + 1e-9)
    if target.cones:
        from .clearance import CLEARANCE_TOL, certified_min_margin
        td, qd, wd = samples[0], samples[1], samples[2]
        cert = certified_min_margin(target, td, qd, wd)[1]
        checks["cone_clearance"] = make_check(cert, CLEARANCE_TOL, cert >= CLEARANCE_TOL)
        if cert < CLEARANCE_TOL and cone_note:
            checks["cone_clearance"]["note"] = cone_note
    checks.update(record_checks(record))
    return checks


def eigenaxis_answer(problem, n_grid: int = None) -> SlewSolution:
    """The fastest eigenaxis slew of a rest-to-rest ``problem`` (module docstring);
    ``ValueError`` for a problem not at rest. ``n_grid``: angle steps of the profile (default
    ``N_GRID``, or ``N_GRID_PNORM_GYRO`` for a p-norm bound on an asymmetric body off its
    principal axes).

    A pointing target is reached at its reference attitude (``eigenaxis.reference_attitude``: the
    smallest rotation that takes the sensor onto the target; the roll is not optimised). With
    keep-out cones the answer is the same slew, verified only where its path keeps the sensor out
    of every cone: the ``cone_clearance`` check, certified between the samples as for every other
    answer (``clearance.certified_min_margin``); otherwise it fails that check and says so."""
    t_start = time.perf_counter()
    target = problem if isinstance(problem, SlewProblem) else SlewProblem.from_dict(problem)
    if not target.is_rest_to_rest:
        raise ValueError("omega0, omegaf: the eigenaxis slew is defined rest to rest")
    pointing = target.qf is None
    # the profile is planned on the full-attitude problem without cones; the checks are target's
    prob = _checked(reference_problem(target) if pointing or target.cones else target)
    n, th, a, c, _ = _phase_plane(prob)
    if th == 0.0:
        if pointing:
            raise ValueError("sensor_target: the sensor already points at the target (zero slew at rest); "
                             "nothing to solve")
        raise ValueError("qf: the target equals the start (zero slew at rest); nothing to solve")
    if n_grid is None:
        n_grid = N_GRID if math.isinf(prob.torque_norm) or not np.any(c) else N_GRID_PNORM_GYRO
    if not is_integer(n_grid) or n_grid < 2:
        raise ValueError(f"n_grid: must be an integer ≥ 2, got {n_grid!r}")
    leg = EigenaxisLeg(prob, n_grid)
    (td, qd, wd, ud), record = recorded(target, leg.samples, prob.inertia)
    # verification: replay, torque at both ends of every step, rate limit, cones
    checks = legs_checks(target, [leg], leg.replay(np.concatenate([leg.q0, np.zeros(3)])), (td, qd, wd, ud), record,
                         cone_note="the eigenaxis path takes the sensor into a keep-out cone")
    text = failure_text(checks)
    # tf is the duration of this profile exactly; tf_tol: its distance to the continuous
    # eigenaxis optimum, from a grid half as fine
    tf = leg.tf
    tf_tol = abs(tf - eigenaxis_slew(prob, max(2, n_grid // 2)).tf)
    msg = (f"The eigenaxis slew: about the body axis n = [{n[0]:.6g}, {n[1]:.6g}, {n[2]:.6g}] by "
           f"{math.degrees(th):.6g}°, the fastest within the bounds (phase-plane profile, {n_grid} steps), "
           "replayed from its control. Not a time-optimal extremal.")
    if pointing:
        msg += " The sensor reaches the target at the reference attitude (the smallest rotation; roll not optimised)."
    if target.cones and "cone_clearance" not in text:
        msg += f" Its path clears every keep-out cone (certified margin {checks['cone_clearance']['value']:.3g} rad)."
    if text:
        msg = f"{STATUS_MESSAGES[STATUS_VERIFICATION_FAILED]} {text}. {msg}"
    first = ud[0]
    return SlewSolution(not text, STATUS_SUCCESS if not text else STATUS_VERIFICATION_FAILED, msg, 0, 0,
                        time.perf_counter() - t_start, tf=tf, tf_tol=tf_tol,
                        u_first=np.where(first > 0, 1.0, np.where(first < 0, -1.0, 0.0)),
                        t=td, q=qd, omega=wd, u=ud, costate=np.full((td.size, 7), np.nan),
                        method="eigenaxis", route=f"eigenaxis slew (phase-plane profile, {n_grid} steps)",
                        guess="eigenaxis", n_candidates=1, candidates_tf=[round(tf, 9)],
                        # (with cones, as ``eigenaxis.baseline_time`` gives it: only where the path keeps
                        # BASELINE_CLEARANCE from every cone)
                        baseline_tf=tf if not target.cones or checks["cone_clearance"]["value"] >= BASELINE_CLEARANCE
                        else math.nan,
                        verification=checks, problem=target, _control=leg.control)


def eigenaxis_unless_faster(prob, tf, n_grid=None):
    """``(baseline, eig)`` for a rest-to-rest, full-attitude, per-axis problem and a final time
    ``tf``: if ``tf`` is below the fine-grid eigenaxis time (problem units) by the margin
    ``GRID_MARGIN``, it is faster than the eigenaxis slew, and ``(grid time, None)``;
    else the slew itself is planned (~15 ms; on ``n_grid`` steps if given):
    ``(grid time, eigenaxis_answer)``."""
    bvp = AttitudeBVP(prob)
    grid = eigenaxis_time(bvp.ref_problem, n_grid=1000)
    if tf < grid * (1.0 - GRID_MARGIN):
        return grid, None
    return grid, eigenaxis_answer(prob, n_grid=n_grid)


def no_slower_than_eigenaxis(prob, sol, t0, n_grid=None) -> SlewSolution:
    """``auto``'s answer to a rest-to-rest full-attitude problem is never slower than the
    eigenaxis slew: an approximate (collocation) answer that is not faster — small slews,
    where the two agree to first order and collocation cannot resolve the difference — is
    replaced by the eigenaxis slew itself (``eigenaxis_answer``, verified by its replay).
    ``n_grid``: the eigenaxis profile's steps (``solve`` under a time budget: as many as the time
    left pays for; a coarser profile is slower, so the answer is compared with a slew that is
    flown as planned, not with the finest one)."""
    if _not_compared(prob) is not None:
        return sol
    if sol.status == STATUS_WORSE_THAN_BASELINE:
        # every answer the routes found is slower than the eigenaxis slew (a slew of a few nrad,
        # where collocation cannot resolve the difference; a local optimum): the eigenaxis slew,
        # verified by its replay, is the best answer known
        eig = eigenaxis_answer(prob, n_grid=n_grid)
        if not eig.success:
            return sol
        return _as_answer(eig, sol, t0, f"{sol.route[:200]} found only slower answers ({sol.message[:200]})",
                          "The time-optimal routes found only slower answers")
    if not sol.success or sol.exact:
        return sol
    # the collocation baseline is on a coarse grid (lenient by up to 0.1 % per-axis and 2 %
    # p-norm with a rate limit): compare with the eigenaxis answer itself, which is cheap for a
    # per-axis bound (compiled, ~7 ms) and planned only when the answer is not clearly faster
    # than the fine grid; for a p-norm bound only when the answer is within 3 % of that baseline
    if not math.isinf(prob.torque_norm):
        if not (sol.tf >= sol.baseline_tf * (1.0 - 0.03)):
            return sol
        eig = eigenaxis_answer(prob, n_grid=n_grid)
    else:
        _, eig = eigenaxis_unless_faster(prob, sol.tf, n_grid=n_grid)
    if eig is None or not eig.success or not eig.tf < sol.tf:
        return sol
    return _as_answer(eig, sol, t0, f"{sol.route[:200]} gave {sol.tf:.9g}, no faster than the eigenaxis slew "
                      f"({eig.tf:.9g})", f"The time-optimal routes found nothing faster (best {sol.tf:.9g}, "
                      f"approximate, tf_tol {sol.tf_tol:.2g}): for a slew this small the two agree to first order")


def _as_answer(eig, sol, t0, route, why) -> SlewSolution:
    """The eigenaxis slew ``eig`` as ``auto``'s answer in place of ``sol``: ``route`` and ``why``
    say what the routes found; their work and final times are kept."""
    eig.route = f"{route}: the eigenaxis slew is the answer"
    eig.message = f"{eig.message} {why}."
    eig.nit, eig.nfev = sol.nit, sol.nfev
    eig.candidates_tf = sorted(set(list(sol.candidates_tf or []) + [round(eig.tf, 9)]))
    eig.warm_start = sol.warm_start
    eig.wall_time = time.perf_counter() - t0
    return eig
