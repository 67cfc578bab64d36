"""Eigenaxis slews through waypoints: a flyable slew around keep-out cones.

Where the eigenaxis path of a rest-to-rest slew takes the sensor into a keep-out cone, what
spacecraft fly today is a waypoint slew: rest-to-rest eigenaxis rotations through one or two
intermediate attitudes chosen so that the sensor stays out of the cones. This module plans such a
slew and returns it as a verified ``SlewSolution`` (``method="eigenaxis"``). It is not time-optimal
(the body stops at every waypoint); it is the fallback for cone problems under a hard budget, and
what ``method="eigenaxis"`` returns where the direct slew would enter a cone.

**The legs.** A leg to a waypoint is the smallest rotation that takes the sensor onto the
waypoint's direction ``w``: about the inertial axis ``s × w``, which is perpendicular to the
sensor, so the sensor moves along the great-circle arc from ``s`` to ``w``. The last leg is the
smallest rotation onto the target direction (a pointing target: again a great-circle arc), or the
eigenaxis rotation to ``qf`` (a full attitude: the sensor moves on a small circle, sampled). Each
leg is flown on the eigenaxis profile of ``eigenaxis_answer.EigenaxisLeg`` (the fastest within the
torque bound and the rate limit about its axis).

**The planner.** Candidate directions lie on two rings around each cone (its half-angle plus
``RING_OFFSETS``), ``N_AZIMUTH`` to a ring. A plan is kept where every leg's sensor path, sampled
every ``1/ARC_SAMPLES`` rad, keeps ``PLAN_CLEARANCE`` from every cone; plans are ranked by
an estimate of their time (each leg bang-bang at the acceleration the bound allows at rest), the
best ``PROFILE_TIMED`` are timed on their legs' eigenaxis profiles (``eigenaxis.axis_time``,
``PLAN_GRID`` steps: the gyroscopic term and the rate limit) and the fastest is flown. One waypoint is tried first; two (every pair of candidates, the shortest
``TWO_WAYPOINT_TIMED`` by sensor angle timed) only where no single waypoint clears the cones.
Planning takes about 2–10 ms.

**Verification** (as for ``eigenaxis_answer``): the legs' controls replayed one after another
from the start state (each leg's replay starts where the previous one ended, not at the planned
waypoint), the end attitude and rate within 1e-8 of the target, the torque bound at both ends of
every profile step, the rate limit, and the keep-out clearance certified between the dense
samples of the whole path (``clearance.certified_min_margin``).
"""
from __future__ import annotations

import functools
import json
import math
import time
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from slew_env import SlewProblem
from slew_env.core.cones import angle_between, perpendicular_basis
from slew_env.core.quaternion import qaxis_angle, qfrom_two_vectors, qmul, qrotate, qrotate_inv
from .clearance import sensor_directions
from .eigenaxis import axis_time, eigenaxis_path
from .guesses import eigenaxis_acceleration
from .solution import STATUS_SUCCESS, STATUS_VERIFICATION_FAILED, STATUS_MESSAGES, SlewSolution
from .verify import failure_text

# rad beyond each cone's half-angle: the rings the candidate waypoint directions lie on
RING_OFFSETS = (0.03, 0.12)
N_AZIMUTH = 36
# the planning margin of every leg's sampled sensor path (the answer's clearance is then certified
# between its dense samples, as for any answer)
PLAN_CLEARANCE = 0.01
# samples of a leg's sensor path per radian of its angle (at least 16): the path moves at most
# 1/ARC_SAMPLES rad between them, so it sags at most ~(1/ARC_SAMPLES)²/8 rad below their margin
ARC_SAMPLES = 30
PLAN_GRID = 120
# two-waypoint plans timed (the shortest by the sensor's total angle), where one waypoint is not enough
TWO_WAYPOINT_TIMED = 24
# plans timed on the eigenaxis profile, the best by the rest-to-rest estimate (``timed``)
PROFILE_TIMED = 4
# a leg longer than this (rad) is no smallest rotation to plan with (near antipodal directions)
MAX_LEG_ANGLE = math.radians(179.0)


@dataclass
class WaypointPlan:
    """Attitudes at rest the slew passes through (start, waypoints, end), the sensor's direction
    at each, and the planned time (the legs' eigenaxis times on ``PLAN_GRID`` steps)."""
    attitudes: List[np.ndarray]
    directions: List[np.ndarray]
    tf_planned: float
    n_candidates: int = 0
    legs_tf: List[float] = field(default_factory=list)

    @property
    def n_waypoints(self) -> int:
        return len(self.attitudes) - 2


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _arc_points(a, b, n):
    """``n`` points of the great-circle arc from unit ``a`` to unit ``b`` (ends included)."""
    th = float(np.arccos(np.clip(a @ b, -1.0, 1.0)))
    if th < 1e-12:
        return np.repeat(a[None, :], n, axis=0)
    tau = np.linspace(0.0, 1.0, n)[:, None]
    return (np.sin((1.0 - tau) * th) * a + np.sin(tau * th) * b) / math.sin(th)


class _Cones:
    def __init__(self, problem):
        self.axes = np.array([_unit(c.axis) for c in problem.cones])
        self.half = np.array([c.half_angle for c in problem.cones])

    def margin(self, d) -> float:
        """Smallest margin (rad) of the unit directions ``d`` (rows) to every cone."""
        if not len(self.half):
            return math.inf
        ang = np.arccos(np.clip(np.asarray(d, float) @ self.axes.T, -1.0, 1.0))
        return float(np.min(ang - self.half[None, :]))

    def arc_margin(self, a, b) -> float:
        th = float(np.arccos(np.clip(a @ b, -1.0, 1.0)))
        return self.margin(_arc_points(a, b, max(16, int(math.ceil(th * ARC_SAMPLES)) + 1)))


def _candidates(problem, cones: _Cones) -> np.ndarray:
    out = []
    phi = np.linspace(0.0, 2.0 * math.pi, N_AZIMUTH, endpoint=False)
    for c, alpha in zip(cones.axes, cones.half):
        e1, e2 = perpendicular_basis(c)
        for off in RING_OFFSETS:
            r = alpha + off
            if r >= math.pi - 1e-6:
                continue
            ring = (math.cos(r) * c[None, :] + math.sin(r) * (np.cos(phi)[:, None] * e1[None, :]
                                                                + np.sin(phi)[:, None] * e2[None, :]))
            out.append(ring)
    if not out:
        return np.zeros((0, 3))
    w = np.vstack(out)
    # only directions outside every cone by the planning margin
    ang = np.arccos(np.clip(w @ cones.axes.T, -1.0, 1.0))
    return w[np.min(ang - cones.half[None, :], axis=1) >= PLAN_CLEARANCE]


def _arc_margins(cones: _Cones, a, B) -> np.ndarray:
    """Sampled margin of the great-circle arcs from each row of ``a`` (or the one vector ``a``) to
    the matching row of ``B``, all at once (every arc sampled as finely as the longest needs)."""
    A = np.broadcast_to(np.asarray(a, float), B.shape)
    cos = np.clip(np.einsum("ij,ij->i", A, B), -1.0, 1.0)
    th = np.arccos(cos)
    m = max(16, int(math.ceil(float(th.max(initial=0.0)) * ARC_SAMPLES)) + 1)
    tau = np.linspace(0.0, 1.0, m)[None, :, None]
    sin = np.sin(th)[:, None, None]
    safe = np.where(sin > 1e-12, sin, 1.0)
    pts = np.where(sin > 1e-12, (np.sin((1.0 - tau) * th[:, None, None]) * A[:, None, :]
                                 + np.sin(tau * th[:, None, None]) * B[:, None, :]) / safe, A[:, None, :])
    # the nearest sample to each cone's axis (largest cosine), then its angle
    near = np.max(pts @ cones.axes.T, axis=1)          # (arcs, cones)
    return np.min(np.arccos(np.clip(near, -1.0, 1.0)) - cones.half[None, :], axis=1)


def _to_direction(q, s_b, w):
    """The attitude at rest after the smallest rotation from ``q`` that points the sensor at ``w``,
    with that rotation's body axis and angle."""
    s = np.asarray(qrotate(q, s_b))
    w = np.ascontiguousarray(w, float)
    k = np.array([s[1] * w[2] - s[2] * w[1], s[2] * w[0] - s[0] * w[2], s[0] * w[1] - s[1] * w[0]])
    th = float(angle_between(s, w))
    qn = np.asarray(qmul(qfrom_two_vectors(s, w), q))
    qn = qn / np.linalg.norm(qn)
    if th < 1e-12:
        return qn, np.array([1.0, 0.0, 0.0]), 0.0
    return qn, _unit(np.asarray(qrotate_inv(q, k / np.linalg.norm(k)))), th


def _last_leg(problem, cones: _Cones, q, s_b):
    """``(end attitude, body axis, angle, sampled clearance)`` of the last leg from ``q``."""
    if problem.qf is None:
        d = _unit(problem.sensor_target)
        s = np.asarray(qrotate(q, s_b))
        qe, n, th = _to_direction(q, s_b, d)
        return qe, n, th, cones.arc_margin(s, d)
    qf = np.asarray(problem.qf, float)
    n, th = qaxis_angle(np.ascontiguousarray(q, float), np.ascontiguousarray(qf, float))
    m = max(16, int(math.ceil(th * ARC_SAMPLES)) + 1)
    qs = eigenaxis_path(np.asarray(q, float), np.asarray(n, float), np.linspace(0.0, th, m))
    d = sensor_directions(qs, s_b)
    return qf, np.asarray(n, float), float(th), cones.margin(d)


# plans timed, the shortest by the sensor's total angle first (an eigenaxis leg's time grows with
# its angle, and with the body's axis: a few shortest ones contain the fastest)
ONE_WAYPOINT_TIMED = 10
# full-attitude targets: last legs sampled (a small circle each) before the timed ones are found
LAST_LEGS_SAMPLED = 60


def plan_waypoints(problem) -> Optional[WaypointPlan]:
    """The fastest waypoint slew of a rest-to-rest ``problem`` with keep-out cones found by the
    planner (module docstring), or ``None`` where no plan with one or two waypoints clears the
    cones. The direct slew (no waypoint) is not a plan here: the caller flies it where it clears."""
    problem = problem if isinstance(problem, SlewProblem) else SlewProblem.from_dict(problem)
    if not problem.is_rest_to_rest:
        raise ValueError("omega0, omegaf: a waypoint slew is planned rest to rest")
    if not problem.cones:
        return None
    cones = _Cones(problem)
    s_b = _unit(problem.sensor_axis)
    q0 = _unit(problem.q0)
    s0 = np.asarray(qrotate(q0, s_b))
    pointing = problem.qf is None
    d_end = _unit(problem.sensor_target) if pointing else np.asarray(qrotate(_unit(problem.qf), s_b))
    W = _candidates(problem, cones)
    if not len(W):
        return None
    th1 = np.arccos(np.clip(W @ s0, -1.0, 1.0))
    th3 = np.arccos(np.clip(W @ d_end, -1.0, 1.0))
    ok1 = (th1 <= MAX_LEG_ANGLE) & (_arc_margins(cones, s0, W) >= PLAN_CLEARANCE)
    # a pointing target's last leg is a great-circle arc too; a full attitude's is checked per plan
    ok3 = (th3 <= MAX_LEG_ANGLE) & (_arc_margins(cones, d_end, W) >= PLAN_CLEARANCE) if pointing \
        else np.ones(len(W), bool)
    n_tried = 0
    plans = []        # (planned time, attitudes, directions, legs' times)

    J, U, p = np.asarray(problem.inertia, float), np.asarray(problem.torque_max, float), float(problem.torque_norm)

    def timed(n, th):
        # a first estimate: bang-bang at the acceleration the bound allows at rest (no gyroscopic
        # term, no rate limit); the best few plans by it are timed on the profile below
        return 2.0 * math.sqrt(th / eigenaxis_acceleration(J, U, p, n)) if th > 0.0 else 0.0

    def last(q):
        nonlocal n_tried
        n_tried += 1
        qe, n3, t3, m3 = _last_leg(problem, cones, q, s_b)
        return None if (t3 > MAX_LEG_ANGLE or m3 < PLAN_CLEARANCE) else (qe, n3, t3)

    # one waypoint, the shortest by the sensor's angle first
    sampled = 0
    for i in np.argsort(th1 + th3):
        if len(plans) >= ONE_WAYPOINT_TIMED or (not pointing and sampled >= LAST_LEGS_SAMPLED):
            break
        if not (ok1[i] and ok3[i]):
            continue
        q1, n1, a1 = _to_direction(q0, s_b, W[i])
        sampled += 1
        end = last(q1)
        if end is None:
            continue
        qe, n2, a2 = end
        t1, t2 = timed(n1, a1), timed(n2, a2)
        plans.append((t1 + t2, [q0, q1, qe], [s0, W[i], np.asarray(qrotate(qe, s_b))], [t1, t2]))
    if not plans:
        # two waypoints: pairs (i, j) with clear outer arcs, the shortest by total angle first,
        # their middle arcs checked in that order
        cos = np.clip(W @ W.T, -1.0, 1.0)
        th2 = np.arccos(cos)
        total = th1[:, None] + th2 + th3[None, :]
        valid = ok1[:, None] & ok3[None, :] & (th2 <= MAX_LEG_ANGLE) & (th2 > 1e-9)
        order = np.argsort(np.where(valid, total, np.inf), axis=None)[:int(valid.sum())]
        # the middle arcs in chunks of the ranked pairs (all at once would sample thousands)
        for k0 in range(0, order.size, 512):
            if len(plans) >= TWO_WAYPOINT_TIMED:
                break
            ii, jj = np.divmod(order[k0:k0 + 512], len(W))
            clear = _arc_margins(cones, W[ii], W[jj]) >= PLAN_CLEARANCE
            for i, j in zip(ii[clear], jj[clear]):
                if len(plans) >= TWO_WAYPOINT_TIMED:
                    break
                q1, n1, a1 = _to_direction(q0, s_b, W[i])
                q2, n2, a2 = _to_direction(q1, s_b, W[j])
                end = last(q2)
                if end is None:
                    continue
                qe, n3, a3 = end
                ts = [timed(n1, a1), timed(n2, a2), timed(n3, a3)]
                plans.append((sum(ts), [q0, q1, q2, qe], [s0, W[i], W[j], np.asarray(qrotate(qe, s_b))], ts))
    if not plans:
        return None
    # the best few by the estimate, timed on the eigenaxis profile (gyroscopic term and rate limit)
    timed_plans = []
    for _, att, dirs, _ in sorted(plans, key=lambda r: r[0])[:PROFILE_TIMED]:
        ts = []
        for qa, qb in zip(att[:-1], att[1:]):
            n, th = qaxis_angle(np.ascontiguousarray(qa, float), np.ascontiguousarray(qb, float))
            ts.append(axis_time(problem, n, th, n_grid=PLAN_GRID) if th > 0.0 else 0.0)
        timed_plans.append((sum(ts), att, dirs, ts))
    best = min(timed_plans, key=lambda r: r[0])
    return WaypointPlan(best[1], best[2], float(best[0]), n_tried, list(best[3]))


# the direct eigenaxis path's 721 samples (``eigenaxis.EIGENAXIS_PATH_SAMPLES``) are at most π/720 rad apart: between two samples it sags
# at most ~(π/720)²/8 ≈ 2.4e-6 rad below them, so a sampled margin above this clears every instant
DIRECT_CLEARANCE = 1e-5


def direct_path_clear(problem) -> bool:
    """Whether the direct eigenaxis slew of a rest-to-rest ``problem`` keeps the sensor out of
    every cone (its sampled path by ``DIRECT_CLEARANCE``; its answer then certifies it). A path that
    passes closer than ``eigenaxis.BASELINE_CLEARANCE`` is still flown, but is no baseline."""
    from .eigenaxis import eigenaxis_path_margin
    return eigenaxis_path_margin(problem) >= DIRECT_CLEARANCE


def waypoint_answer(problem, n_grid: int = None, plan: Optional[WaypointPlan] = None) -> SlewSolution:
    """The waypoint slew of ``plan`` (default: ``plan_waypoints(problem)``) as a verified
    ``SlewSolution`` (module docstring); ``n_grid``: angle steps of each leg's profile (default:
    ``eigenaxis_answer``'s). Where no plan exists, a failed solution (status 5) that says so."""
    from .eigenaxis_answer import N_GRID, N_GRID_PNORM_GYRO, EigenaxisLeg, legs_checks, recorded
    from .eigenaxis import _phase_plane
    t_start = time.perf_counter()
    target = problem if isinstance(problem, SlewProblem) else SlewProblem.from_dict(problem)
    if not target.is_rest_to_rest:
        raise ValueError("omega0, omegaf: a waypoint slew is flown rest to rest")
    if plan is None:
        plan = plan_waypoints(target)
    if plan is None:
        msg = (f"{STATUS_MESSAGES[STATUS_VERIFICATION_FAILED]} No waypoint slew found: the direct eigenaxis "
               "path enters a keep-out cone, and no plan through one or two waypoints on rings around the "
               f"cones keeps {PLAN_CLEARANCE} rad from them.")
        return SlewSolution(False, STATUS_VERIFICATION_FAILED, msg, 0, 0, time.perf_counter() - t_start,
                            method="eigenaxis", route="eigenaxis slew through waypoints: no plan found",
                            guess="eigenaxis", n_candidates=0, problem=target)
    legs, grids, offsets = [], [], [0.0]
    for qa, qb in zip(plan.attitudes[:-1], plan.attitudes[1:]):
        leg_prob = target.replace(q0=qa, qf=qb, cones=[])
        if n_grid is None:
            c = _phase_plane(leg_prob)[3]
            grid = N_GRID if math.isinf(leg_prob.torque_norm) or not np.any(c) else N_GRID_PNORM_GYRO
        else:
            grid = int(n_grid)
        legs.append(EigenaxisLeg(leg_prob, grid))
        grids.append(grid)
        offsets.append(offsets[-1] + legs[-1].tf)
    # dense samples of the whole slew (each junction twice: the end of one leg, the start of the next)
    def joined(n_dense):
        parts = [leg.samples(n_dense) for leg in legs]
        return (np.concatenate([p[0] + off for p, off in zip(parts, offsets)]), np.vstack([p[1] for p in parts]),
                np.vstack([p[2] for p in parts]), np.vstack([p[3] for p in parts]))
    (td, qd, wd, ud), record = recorded(target, joined, target.inertia)
    # verification: the legs' controls flown one after another from the start state
    x = np.concatenate([np.asarray(target.q0, float), np.zeros(3)])
    for leg in legs:
        x = leg.replay(x)
    checks = legs_checks(target, legs, x, (td, qd, wd, ud), record)
    text = failure_text(checks)
    tf = float(offsets[-1])
    ends = np.array(offsets)

    def control(tq):
        tq = np.asarray(tq, dtype=float)
        k = np.clip(np.searchsorted(ends, tq, side="right") - 1, 0, len(legs) - 1)
        out = np.empty(tq.shape + (3,))
        for i, leg in enumerate(legs):
            sel = k == i
            if np.any(sel):
                out[sel] = leg.control(tq[sel] - ends[i])
        return out

    nw = plan.n_waypoints
    dirs = "; ".join(f"[{d[0]:.4f}, {d[1]:.4f}, {d[2]:.4f}]" for d in plan.directions[1:-1])
    msg = (f"An eigenaxis slew through {nw} waypoint{'s' if nw > 1 else ''} (the sensor at {dirs}, inertial; "
           f"at rest there): {len(legs)} rest-to-rest eigenaxis legs of {', '.join(f'{leg.tf:.6g}' for leg in legs)}, "
           "replayed one after another from the start. The direct eigenaxis path enters a keep-out cone. Not a "
           "time-optimal extremal.")
    if target.qf is None:
        msg += " The last leg is the smallest rotation onto the target (roll not optimised)."
    if not text and target.cones:
        msg += f" The path clears every keep-out cone (certified margin {checks['cone_clearance']['value']:.3g} rad)."
    elif text:
        msg = f"{STATUS_MESSAGES[STATUS_VERIFICATION_FAILED]} {text}. {msg}"
    first = ud[0]
    return SlewSolution(not text, STATUS_SUCCESS if not text else STATUS_VERIFICATION_FAILED, msg, 0, 0,
                        time.perf_counter() - t_start, tf=tf, tf_tol=abs(tf - plan.tf_planned),
                        u_first=np.where(first > 0, 1.0, np.where(first < 0, -1.0, 0.0)),
                        t=td, q=qd, omega=wd, u=ud, costate=np.full((td.size, 7), np.nan),
                        method="eigenaxis",
                        route=f"eigenaxis slew through {nw} waypoint{'s' if nw > 1 else ''} "
                              f"({plan.n_candidates} plans checked; phase-plane profiles of "
                              f"{'/'.join(str(g) for g in grids)} steps)",
                        guess="eigenaxis", n_candidates=plan.n_candidates, candidates_tf=[round(tf, 9)],
                        baseline_tf=math.nan, verification=checks, problem=target, _control=control)


def flyable_eigenaxis_answer(problem, n_grid: int = None) -> SlewSolution:
    """``method="eigenaxis"``'s answer: the direct eigenaxis slew (``eigenaxis_answer``), or, with
    keep-out cones where its path enters one, the waypoint slew (``waypoint_answer``)."""
    from .eigenaxis_answer import eigenaxis_answer
    target = problem if isinstance(problem, SlewProblem) else SlewProblem.from_dict(problem)
    direct = None
    if not target.cones or direct_path_clear(target):
        direct = eigenaxis_answer(target, n_grid=n_grid)
        if direct.success or not target.cones:
            return direct
    if not target.is_rest_to_rest:
        return eigenaxis_answer(target, n_grid=n_grid)     # (raises its own error)
    wp = waypoint_answer(target, n_grid=n_grid)
    if wp.success or direct is None:
        if not wp.success and direct is None:
            # say what the direct slew does too (it is the answer a user asked for)
            wp.message = f"{wp.message} The direct eigenaxis slew enters a keep-out cone."
        return wp
    return direct


@functools.lru_cache(maxsize=64)
def _fallback_plan_cached(key: str):
    problem = SlewProblem.from_dict(json.loads(key))
    if direct_path_clear(problem):
        return "direct"
    return plan_waypoints(problem)


def fallback_plan(problem):
    """What ``solve``'s eigenaxis fallback flies for a rest-to-rest ``problem``: ``"direct"`` (no
    cones, or the direct eigenaxis path clears them), a ``WaypointPlan``, or ``None`` (no plan
    found). Remembered for the last problems asked (``solve`` asks before its route, to keep the
    fallback's time out of the route's budget, and again in the fallback)."""
    problem = problem if isinstance(problem, SlewProblem) else SlewProblem.from_dict(problem)
    if not problem.cones:
        return "direct"
    return _fallback_plan_cached(json.dumps(problem.to_dict(), sort_keys=True))
