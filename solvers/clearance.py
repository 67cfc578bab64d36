"""Keep-out cone clearance of a returned trajectory, certified between samples.

The clearance margin of a cone, ``angle(R(q)s, a) - α``, changes no faster than the
sensor direction moves, i.e. at most ``|ω|`` rad per unit time. Between two samples
``k, k+1`` (spacing ``Δt``) the margin is therefore at least
``(m_k + m_{k+1})/2 - ½ max|ω| Δt``: the certified minimum is a lower bound of the
margin at every instant, not only at grid points. A bang-bang answer is re-propagated
from its switch times alone (fixed-step RK4 of the environment,
``solvers.verify.replay_path``), so the check is also independent of the solver's integrator.
"""
from __future__ import annotations

import numpy as np


def sensor_directions(q, sensor_b):
    """Inertial sensor direction for each row of ``q`` (n, 4)."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, r = q[:, :1], q[:, 1:4]
    v = np.asarray(sensor_b, float)[None, :]
    c = np.cross(r, v)
    return v + 2.0 * (w * c + np.cross(r, c))


def margins(problem, q):
    """Smallest clearance margin (rad) over the problem's cones, for each row of ``q``."""
    d = sensor_directions(q, problem.sensor_axis)
    m = np.full(q.shape[0], np.inf)
    for c in problem.cones:
        cross = np.linalg.norm(np.cross(d, c.axis), axis=1)
        m = np.minimum(m, np.arctan2(cross, d @ c.axis) - c.half_angle)
    return m


def certified_min_margin(problem, t, q, omega):
    """``(sample minimum, certified minimum over [t0, tN])`` of the clearance margin."""
    m = margins(problem, q)
    if m.shape[0] < 2:
        return float(m.min()), float(m.min())
    w = np.linalg.norm(omega, axis=1)
    J = problem.inertia
    # inside a step |ω| exceeds the larger end value by at most amax·Δt, with
    # |ω̇| ≤ |u_max / J| + |ω|² J_max / J_min (Euler's equations)
    amax = float(np.linalg.norm(problem.torque_max / J)) + 1.1 * float(w.max()) ** 2 * float(J.max() / J.min())
    dt = np.diff(t)
    lip = np.maximum(w[:-1], w[1:]) + amax * dt
    lower = 0.5 * (m[:-1] + m[1:]) - 0.5 * lip * dt
    lower = np.minimum(lower, np.minimum(m[:-1], m[1:]))
    return float(m.min()), float(lower.min())
