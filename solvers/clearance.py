"""Keep-out cone clearance of a returned trajectory, certified between samples.

The clearance margin of a cone, ``angle(R(q)s, a) - α``, changes no faster than the
sensor direction moves, i.e. at most ``|ω|`` rad per unit time. Between two samples
``k, k+1`` (spacing ``Δt``) the margin is therefore at least
``(m_k + m_{k+1})/2 - ½ max|ω| Δt``: the certified minimum is a lower bound of the
margin at every instant, not only at grid points. A bang-bang answer is re-propagated
from its switch times alone (fixed-step RK4 of the environment, ``steps`` steps over
``tf``), so the check is also independent of the solver's integrator.
"""
from __future__ import annotations

import math

import numpy as np

from slew_env.core.dynamics import propagate


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


def bang_bang_path(problem, switch_times, u_first, tf, steps=8000):
    """``(t, x)`` with ``x = [q, ω]`` re-propagated from the switch times alone (RK4)."""
    events = sorted((float(s), i) for i in range(3) for s in switch_times[i])
    signs = np.asarray(u_first, float).copy()
    x = np.concatenate([problem.q0, problem.omega0]).astype(float)
    ts, xs = [np.zeros(1)], [x[None, :]]
    t_prev = 0.0
    for t_next, axis in events + [(float(tf), -1)]:
        dt = t_next - t_prev
        if dt > 0:
            n = max(2, int(math.ceil(dt / tf * steps)))
            traj = propagate(x, problem.torque_max * signs, problem.inertia, dt, n)
            ts.append(t_prev + np.linspace(0.0, dt, n + 1)[1:])
            xs.append(traj[1:])
            x = traj[-1]
        if axis >= 0:
            signs[axis] = -signs[axis]
        t_prev = max(t_prev, t_next)
    return np.concatenate(ts), np.vstack(xs)
