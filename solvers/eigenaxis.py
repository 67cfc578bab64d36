"""The eigenaxis slew: the baseline planner most spacecraft fly today.

Rest-to-rest rotation about the fixed eigenaxis ``n`` (body axes) by the angle ``θ``
from ``q0`` to ``qf``: ``ω = θ̇ n``. For an asymmetric body the torque that keeps the
rotation on the axis includes the gyroscopic part::

    u = θ̈ J n + θ̇² (n × J n)

We return the *fastest* such slew whose torque stays within the bound (per-axis or
p-norm) and whose rates stay within ``rate_max``: time-optimal path parametrisation
along ``θ`` in the phase plane ``s = θ̇²`` (maximum acceleration forward from rest,
maximum deceleration backward from rest, under the maximum-velocity curve). For a
symmetric body and the 2-norm ball this is ``tf = 2 sqrt(θ J / u_max)`` exactly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from slew_env import SlewProblem
from slew_env.core.quaternion import qfrom_two_vectors, qmul, qrotate
from .core import eigenaxis_topp as topp
from .guesses import eigenaxis_axis_angle


@dataclass
class EigenaxisSlew:
    tf: float
    axis: np.ndarray        # body axes
    angle: float
    theta: np.ndarray       # samples of the rotation angle
    t: np.ndarray           # time at each sample
    rate: np.ndarray        # θ̇ at each sample
    u: np.ndarray           # torque on each grid interval (worse end), last row the final torque
    dtheta: Optional[np.ndarray] = None     # the angle of each piece between samples (θ̈ constant on it)
    # θ̈ on each piece, from the planner's own θ̇² (a piece a rounding error long makes it ill-conditioned
    # to recompute from ``rate``, which is in the problem's units)
    acc: Optional[np.ndarray] = None


def _phase_plane(problem: SlewProblem, axis_angle=None):
    """``(n, θ, a, c, s_max)``: eigenaxis and angle, torque per unit acceleration ``a = J n``
    and per unit speed² ``c = n × Jn``, and the largest admissible ``s = θ̇²`` (the
    maximum-velocity curve of the bound, capped by the rate limit). ``axis_angle``: ``(n, θ)``
    given (a rotation other than ``q0`` to ``qf``: the legs of a waypoint slew)."""
    n, th = eigenaxis_axis_angle(problem) if axis_angle is None else axis_angle
    J, U, p = problem.inertia, problem.torque_max, problem.torque_norm
    a = np.ascontiguousarray(J * n, float)
    c = np.cross(n, J * n)
    # rounding leaves ~1e-17 of n × Jn for a symmetric body or a principal axis
    # (compared in units of the largest inertia: the norms' squares under- or overflow beyond 1e±150)
    jm = float(np.max(J))
    if np.linalg.norm(c / jm) <= 1e-12 * np.linalg.norm(a / jm):
        c = np.zeros(3)
    c = np.ascontiguousarray(c, float)
    if math.isinf(p):
        s_mvc = topp.max_speed(a, c, np.ascontiguousarray(U, float))
    else:   # largest s with a non-empty acceleration interval, by bisection
        Uc = np.ascontiguousarray(U, float)

        def feasible(sv):   # the compiled interval (tests/test_eigenaxis_answer.py has a scipy reference)
            return topp.accel_interval_pnorm(a, c, Uc, float(p), float(sv))[2]
        hi = 1.0
        while feasible(hi) and hi < 1e12:
            hi *= 2.0
        s_mvc = math.inf
        if hi < 1e12:
            lo = 0.0
            for _ in range(100):
                mid = 0.5 * (lo + hi)
                if feasible(mid):
                    lo = mid
                else:
                    hi = mid
            s_mvc = lo
    return n, th, a, c, min(s_mvc, _rate_cap(problem, n))


def _rate_cap(problem, n) -> float:
    """The largest ``s = θ̇²`` the rate limit allows about ``n`` (``inf`` without one)."""
    s_rate = math.inf
    if problem.rate_max is not None:
        for i in range(3):
            if abs(n[i]) > 1e-15:
                s_rate = min(s_rate, (problem.rate_max[i] / abs(n[i])) ** 2)
    if problem.rate_norm_max is not None:       # ‖θ̇ n‖ = θ̇ (n a unit vector)
        s_rate = min(s_rate, problem.rate_norm_max ** 2)
    return s_rate


def _profile_nodes(problem, n, a, c, U, p, s_max, th, n_grid):
    """The sweeps' profile as nodes ``(θ, s, dθ)`` (``topp.capped_nodes``): the grid, and the points
    where the speed reaches the rate limit inside a grid interval (only where the rate limit
    is the cap: the maximum-velocity curve of the bound is not a coast)."""
    fwd, bwd, fa, bd = topp.sweep(a, c, U, float(p), float(s_max), float(th), int(n_grid))
    s_cap = float(s_max) if _rate_cap(problem, n) <= s_max else math.inf
    return topp.capped_nodes(fwd, bwd, fa, bd, float(th), int(n_grid), s_cap)


def _constant_accel_time(th, acc, s_max) -> float:
    """Rest-to-rest time over angle ``th`` at constant acceleration ``acc`` (the same
    deceleration), with the speed capped at ``sqrt(s_max)``: bang-bang, or bang-coast-bang."""
    if not acc > 0.0:
        return math.inf
    if acc * th <= s_max:              # the triangle's peak speed² is acc·th
        return 2.0 * math.sqrt(th / acc)
    w = math.sqrt(s_max)
    return th / w + w / acc


def _unit_scaled(problem: SlewProblem):
    """``(scaled, tau, umax)``: ``problem`` in the units where its largest inertia and torque bound
    are 1 (times in ``tau = sqrt(J_max / u_max)``, rates in ``1 / tau``). The planner's sweeps and
    the p-norm bisection work on absolute magnitudes: in the problem's own units they failed for
    inertias below about 1e-13 or above 1e30 (an outside fuzz, session 42: inertia 1e-15 and torque
    1e-15, a consistent choice of units, gave a slew whose torque broke its bound 3e4-fold)."""
    jmax, umax = float(np.max(problem.inertia)), float(np.max(problem.torque_max))
    tau = math.sqrt(jmax / umax)
    if jmax == 1.0 and umax == 1.0:
        return problem, 1.0, 1.0
    changes = dict(inertia=np.asarray(problem.inertia) / jmax, torque_max=np.asarray(problem.torque_max) / umax,
                   omega0=np.asarray(problem.omega0) * tau, omegaf=np.asarray(problem.omegaf) * tau)
    if problem.rate_max is not None:
        changes["rate_max"] = np.asarray(problem.rate_max) * tau
    if problem.rate_norm_max is not None:
        changes["rate_norm_max"] = float(problem.rate_norm_max) * tau
    return problem.replace(**{k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in changes.items()}), tau, umax


def _checked(problem) -> SlewProblem:
    if not isinstance(problem, SlewProblem):
        problem = SlewProblem.from_dict(problem)
    if problem.qf is None:
        raise ValueError("sensor_target: the eigenaxis slew needs a full attitude target qf")
    if not problem.is_rest_to_rest:
        raise ValueError("omega0, omegaf: the eigenaxis slew is defined rest to rest")
    return problem


def reference_attitude(problem: SlewProblem) -> np.ndarray:
    """The target attitude of ``problem``: ``qf``; for a pointing-only target, the start attitude
    turned by the smallest rotation that takes the sensor onto the target (the roll a pointing
    answer is compared at: the eigenaxis baseline's target)."""
    if problem.qf is not None:
        return np.array(problem.qf, float)
    s_b = np.asarray(problem.sensor_axis, float) / np.linalg.norm(problem.sensor_axis)
    d_i = np.asarray(problem.sensor_target, float) / np.linalg.norm(problem.sensor_target)
    qf = qmul(qfrom_two_vectors(qrotate(problem.q0, s_b), d_i), problem.q0)
    return qf / np.linalg.norm(qf)


def reference_problem(problem: SlewProblem) -> SlewProblem:
    """The rest-to-rest full-attitude problem whose eigenaxis slew is ``problem``'s: the target
    ``reference_attitude``, no keep-out cones (the callers check the path against them)."""
    return problem.replace(qf=reference_attitude(problem), sensor_target=None, cones=())


EIGENAXIS_PATH_SAMPLES = 721


def eigenaxis_path_margin(problem: SlewProblem) -> float:
    """The smallest clearance margin (rad) of the sensor from the keep-out cones along the eigenaxis
    slew of the rest-to-rest ``problem`` to its reference attitude, sampled at
    ``EIGENAXIS_PATH_SAMPLES`` angles (``inf`` without cones): not certified between the samples.
    ``baseline_time``, ``waypoint_slew.direct_path_clear`` and ``cone_routes.eigenaxis_path_clear``
    compare it with their own thresholds."""
    if not problem.cones:
        return math.inf
    from .clearance import margins
    n, th = eigenaxis_axis_angle(reference_problem(problem))
    q = eigenaxis_path(np.asarray(problem.q0, float), n, np.linspace(0.0, th, EIGENAXIS_PATH_SAMPLES))
    return float(np.min(margins(problem, q)))


def baseline_time(problem: SlewProblem, n_grid=1000) -> float:
    """The eigenaxis baseline of a rest-to-rest ``problem`` (``SlewSolution.baseline_tf``): the
    eigenaxis slew's time to its reference attitude; NaN for a problem not at rest, and where the
    eigenaxis path's sensor passes within ``BASELINE_CLEARANCE`` of a keep-out cone (a path that
    crosses a cone is no baseline to compare an answer with)."""
    if not problem.is_rest_to_rest:
        return math.nan
    if eigenaxis_path_margin(problem) < BASELINE_CLEARANCE:
        return math.nan
    return eigenaxis_time(reference_problem(problem), n_grid=n_grid)


def eigenaxis_path(q0, n, theta) -> np.ndarray:
    """The attitudes ``q0 ⊗ [cos(θ/2), sin(θ/2) n]`` of the rotation about the body axis ``n``,
    one row for each angle of ``theta`` (left multiplication is linear: one matrix product)."""
    from .attitude_bvp import quat_left_matrix     # (attitude_bvp imports this module)
    th = np.asarray(theta, float)
    return np.column_stack([np.cos(0.5 * th), np.sin(0.5 * th)[:, None] * n[None, :]]) @ quat_left_matrix(q0).T


# the sensor moves at most π / 720 rad between the 721 samples of the eigenaxis path: a sampled
# margin above this keeps the whole path clear
BASELINE_CLEARANCE = 0.005


def eigenaxis_time(problem: SlewProblem, n_grid=4000) -> float:
    """The eigenaxis slew's time (the solver's baseline gate): ``eigenaxis_slew(problem,
    n_grid).tf`` without the profile arrays, compiled end to end; without a gyroscopic term
    (``n × Jn = 0``) the exact bang-(coast-)bang closed form, which the grid (1,000 steps)
    overestimates by up to ~7e-6 where a rate cap starts (under 1e-7 without a rate limit)."""
    problem = _checked(problem)
    return axis_time(problem, *eigenaxis_axis_angle(problem), n_grid=n_grid)


def axis_time(problem: SlewProblem, n, th, n_grid=1000) -> float:
    """``eigenaxis_time`` of the rest-to-rest rotation by ``th`` about the body axis ``n`` (unit)
    under ``problem``'s inertia, torque bound and rate limit (its attitudes, rates and cones are
    not read): the planner of waypoint slews times its candidate legs with it."""
    problem, tau, _ = _unit_scaled(problem)
    n, th, a, c, s_max = _phase_plane(problem, (np.asarray(n, float), float(th)))
    if th == 0.0:
        return 0.0
    U = np.ascontiguousarray(problem.torque_max, float)
    p = float(problem.torque_norm)
    if not np.any(c):
        # no gyroscopic term (a symmetric body, or a principal axis): the feasible
        # accelerations do not depend on the rate, so the profile is bang-(coast-)bang
        acc = topp.accel_interval(a, c, U, 0.0)[1] if math.isinf(p) else topp.accel_interval_pnorm(a, c, U, p, 0.0)[1]
        return tau * _constant_accel_time(th, acc, s_max)
    _, s, steps = _profile_nodes(problem, n, a, c, U, p, s_max, th, n_grid)
    return tau * float(topp.nodes_time(steps, s))


def eigenaxis_slew(problem: SlewProblem, n_grid=4000, ignore_cones=False) -> EigenaxisSlew:
    """Fastest rest-to-rest eigenaxis slew of ``problem`` within its torque and rate bounds.
    The eigenaxis path does not avoid keep-out cones: a problem with cones is refused unless
    ``ignore_cones`` (the slew then may cross them, as a reference time)."""
    problem = _checked(problem)
    if problem.cones and not ignore_cones:
        raise ValueError("cones: the eigenaxis slew ignores keep-out cones and may cross them; use "
                         "solvers.solve(problem) for a slew that avoids them, or ignore_cones=True for the "
                         "eigenaxis slew as a reference time")
    # (planned in units where the largest inertia and torque bound are 1, ``_unit_scaled``)
    problem, tau, umax = _unit_scaled(problem)
    U, p = problem.torque_max, problem.torque_norm
    n, th, a, c, s_max = _phase_plane(problem)
    if th == 0.0:
        z = np.zeros(1)
        return EigenaxisSlew(0.0, n, 0.0, z, z, z, np.zeros((1, 3)), np.zeros(0), np.zeros(0))
    # the compiled sweeps (the baseline runs on every indirect solve, the slew on every
    # fallback), on the grid and where the speed reaches the rate limit inside a grid step
    theta, s_prof, dth = _profile_nodes(problem, n, a, c, np.ascontiguousarray(U, float), p, s_max, th, n_grid)
    s_prof = np.maximum(s_prof, 0.0)
    rate = np.sqrt(s_prof)
    # exact for piecewise-constant acceleration: dt = 2 dθ / (θ̇_k + θ̇_k+1)
    denom = rate[:-1] + rate[1:]
    dt = np.where(denom > 0, 2.0 * dth / np.where(denom > 0, denom, 1.0), 0.0)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    acc = (s_prof[1:] - s_prof[:-1]) / (2.0 * dth)      # per interval
    # torque at both ends of every interval (the larger in bound units is what matters)
    u_start = acc[:, None] * a[None, :] + s_prof[:-1, None] * c[None, :]
    u_end = acc[:, None] * a[None, :] + s_prof[1:, None] * c[None, :]
    u = np.vstack([u_start, u_end[-1:]])
    worse = np.max(np.abs(u_end) / U, axis=1) > np.max(np.abs(u_start) / U, axis=1)
    u[:-1][worse] = u_end[worse]
    t = t * tau
    return EigenaxisSlew(float(t[-1]), n, th, theta, t, rate / tau, u * umax, dth, acc / tau ** 2)
