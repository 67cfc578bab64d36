"""Keep-out cone clearance of a returned trajectory, certified between samples.

The clearance margin of a cone, ``angle(R(q)s, a) - α``, changes no faster than the
sensor direction moves, i.e. at most ``|ω|`` rad per unit time, and its second derivative
is bounded through ``|ω|`` and ``|ω̇|`` (``cone_clearances``). Between two samples the margin
is therefore bounded below: the certified minimum is a lower bound of the margin at every
instant, not only at grid points. A bang-bang answer is re-propagated
from its switch times alone (fixed-step RK4 of the environment,
``solvers.verify.replay_path``), so the check is also independent of the solver's integrator.
"""
from __future__ import annotations

import math

import numpy as np

from .core.clearance_kernels import certified_bounds, path_margins

# the smallest clearance margin (rad) an answer may have anywhere on its path: a start or
# target on a cone boundary (Melton's R4) leaves the certified bound a few 1e-8 below zero
CLEARANCE_TOL = -1e-6


def sensor_directions(q, sensor_b):
    """Inertial sensor direction for each row of ``q`` (n, 4)."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, r = q[:, :1], q[:, 1:4]
    v = np.asarray(sensor_b, float)[None, :]
    c = np.cross(r, v)
    return v + 2.0 * (w * c + np.cross(r, c))


def cone_margins(problem, q):
    """Clearance margin (rad) of each cone of ``problem`` for each row of ``q``: (n, n_cones),
    ``angle(sensor, axis) - half_angle`` (atan2: accurate near 0 and π; compiled,
    ``core.clearance_kernels.path_margins``)."""
    q = np.ascontiguousarray(q, dtype=float).reshape(-1, 4)
    if not problem.cones:
        return np.zeros((q.shape[0], 0))
    axes, half = _cone_arrays(problem)
    return path_margins(q, np.asarray(problem.sensor_axis, dtype=float), axes, half)


def _cone_arrays(problem):
    """The cones' axes (n_cones, 3) and half-angles, as the compiled kernels take them."""
    return (np.array([c.axis for c in problem.cones], dtype=float).reshape(-1, 3),
            np.array([c.half_angle for c in problem.cones], dtype=float))


def margins(problem, q):
    """Smallest clearance margin (rad) over the problem's cones, for each row of ``q``."""
    m = cone_margins(problem, q)
    return m.min(axis=1) if m.shape[1] else np.full(m.shape[0], np.inf)


def certified_min_margin(problem, t, q, omega):
    """``(sample minimum, certified minimum over [t0, tN])`` of the clearance margin (all
    cones; ``cone_clearances`` gives them per cone)."""
    per = cone_clearances(problem, t, q, omega)
    if not per:
        m = margins(problem, q)
        return float(m.min()), float(m.min())
    return min(p[0] for p in per), min(p[1] for p in per)


def cone_clearances(problem, t, q, omega):
    """``[(sample minimum, certified minimum, margin at t0, margin at tN)]``, one per cone.

    Per cone and per step, the better of two lower bounds that hold at every instant:

    * first order: the margin moves at most ``|ω|`` rad per unit time;
    * second order: ``θ = angle(d, a)`` has ``|θ̈| ≤ (|ω̇| + (1 + |cos θ|)|ω|²) / sin θ`` (from
      ``cos θ = d·a``, ``|ḋ| ≤ |ω|``, ``|d̈| ≤ |ω̇| + |ω|²``), so between samples it stays above
      the smaller end value minus ``B Δt² / 8``; used where ``sin θ`` is bounded away from 0
      over the step. This one is what certifies paths that ride a cone boundary.
    """
    t, q, omega = np.asarray(t, float), np.asarray(q, float), np.asarray(omega, float)
    if not (t.shape[0] == q.shape[0] == omega.shape[0]):
        raise ValueError(f"t, q, omega: one row per sample, got {t.shape[0]}, {q.shape[0]} and {omega.shape[0]}")
    if q.shape[0] < 2 or not problem.cones:
        return []
    mar = cone_margins(problem, q)
    w = np.linalg.norm(omega, axis=1)
    J = problem.inertia
    # inside a step |ω| exceeds the larger end value by at most amax·Δt, with
    # |ω̇| ≤ |u_max / J| + |ω|² J_max / J_min (Euler's equations)
    amax = float(np.linalg.norm(problem.torque_max / J)) + 1.1 * float(w.max()) ** 2 * float(J.max() / J.min())
    # per step: the first-order bound min(mean - W Δt / 2, smaller end), W = the larger end's |ω|
    # + amax Δt; the second-order one, smaller end - B Δt² / 8 with B = (amax + 2 W²) / sin θ_low,
    # where θ stays within (0, π) over the step and sin θ_low > 1e-6; the better of the two
    # (compiled: ``core.clearance_kernels.certified_bounds``)
    _, half = _cone_arrays(problem)
    b = certified_bounds(np.ascontiguousarray(t, dtype=float), mar, np.ascontiguousarray(w), half, amax)
    return [tuple(float(v) for v in row) for row in b]


# RK4 steps over tf of the certified replay: first try, then finer while the bound misses the
# tolerance and the samples clear it. The third level: small cones (0.17-0.6 deg) 1e-8 to 1e-7 rad
# outside a path were bounded at -1.3e-6 to -2.1e-6 with 32,000 steps, refused, and the solve
# ended in status 2; 128,000 steps certify them (-7.7e-8 to +5.3e-9 rad), in 20-60 ms, paid only
# on such paths (an adversarial check, runs/s44/adv/REPORT.md finding 1; runs/s44/replay_levels.py)
REPLAY_STEPS = (8000, 32000, 128000)


def certified_replay(problem, switch_times, u_first, tf, steps=REPLAY_STEPS):
    """``(t, x, certified minimum margin)`` of the path flown from switch times and first-arc
    signs alone (the environment's RK4, ``solvers.verify.replay_path``).

    The certified bound loses ``~ |θ̈| Δt² / 8`` where the path touches a cone; when a
    replay's bound misses ``CLEARANCE_TOL`` while its samples clear it, the replay is repeated
    with the next, finer step count (each tightens the bound 16x)."""
    from .verify import replay_path
    for k, n in enumerate(steps):
        t, x = replay_path(problem.inertia, problem.torque_max, problem.q0, problem.omega0, switch_times, u_first,
                           tf, steps_per_tf=n)
        sample, cert = certified_min_margin(problem, t, x[:, 0:4], x[:, 4:7])
        if cert >= CLEARANCE_TOL or sample < CLEARANCE_TOL or k == len(steps) - 1:
            return t, x, cert


def answer_clearance(problem, sol):
    """Certified minimum margin over the cones of ``problem`` along the path of ``sol``: for a
    per-axis answer flown by its switch times (an exact extremal, or a bang-bang switch-time
    answer) those switch times alone, re-propagated by the environment's RK4 (independent of the
    solver's samples, ``certified_replay``); otherwise its dense samples."""
    # (a switch-time answer's dense record is coarse, ~100 samples: the certified bound between
    # them had been 4e-3 rad low on a path that clears a cone by 1e-7, where the replay certifies
    # it to 5e-7; runs/s44/f2.py, the session-43 adversarial repro F2)
    if (sol.exact or sol.method == "switch-time") and math.isinf(problem.torque_norm):
        return certified_replay(problem, sol.switch_times, sol.u_first, sol.tf)[2]
    return certified_min_margin(problem, sol.t, sol.q, sol.omega)[1]
