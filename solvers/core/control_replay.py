"""Re-propagation of a collocation answer's control model (compiled).

The collocation control is, on each interval ``[t_k, t_k+1]``, the quadratic through the
node, midpoint and node controls, clipped to the torque bound. ``replay_quadratic_control``
integrates the rigid body under it with classical RK4, ``samples × substeps`` steps an
interval (the control is smooth inside an interval, so RK4 keeps its fourth order), and
returns the state at ``samples`` evenly spaced instants of each interval. It is the
verification's independent re-propagation: it shares nothing with the NLP's
Hermite–Simpson scheme but the dynamics.
"""
import math

import numpy as np
from numba import njit

from slew_env.core.dynamics import rk4_step_inplace, state_rhs_scalar

from .attitude_flow import MODE_BANG, control, ext_rhs


@njit(cache=True)
def quadratic_control(s, Uk, Um, Uk1, Ulim, p):
    """The interval's control at fraction ``s`` ∈ [0, 1], clipped to the bound (per-axis
    box for ``p = inf``, else the p-norm ball scaled by ``Ulim``)."""
    l0 = 2.0 * (s - 0.5) * (s - 1.0)
    l1 = -4.0 * s * (s - 1.0)
    l2 = 2.0 * s * (s - 0.5)
    u0 = l0 * Uk[0] + l1 * Um[0] + l2 * Uk1[0]
    u1 = l0 * Uk[1] + l1 * Um[1] + l2 * Uk1[1]
    u2 = l0 * Uk[2] + l1 * Um[2] + l2 * Uk1[2]
    if math.isinf(p):
        u0 = min(max(u0, -Ulim[0]), Ulim[0])
        u1 = min(max(u1, -Ulim[1]), Ulim[1])
        u2 = min(max(u2, -Ulim[2]), Ulim[2])
    else:
        n = (abs(u0 / Ulim[0]) ** p + abs(u1 / Ulim[1]) ** p + abs(u2 / Ulim[2]) ** p) ** (1.0 / p)
        if n > 1.0:
            u0 /= n
            u1 /= n
            u2 /= n
    return u0, u1, u2


@njit(cache=True)
def _rk4_step(x, y, h, ua, um, ub, J):
    """One classical RK4 step of ``x`` in place (``y``: scratch) under a control that takes the
    values ``ua``, ``um``, ``ub`` at the step's start, middle and end."""
    k1 = state_rhs_scalar(x[0], x[1], x[2], x[3], x[4], x[5], x[6], ua[0], ua[1], ua[2], J[0], J[1], J[2])
    for i in range(7):
        y[i] = x[i] + 0.5 * h * k1[i]
    k2 = state_rhs_scalar(y[0], y[1], y[2], y[3], y[4], y[5], y[6], um[0], um[1], um[2], J[0], J[1], J[2])
    for i in range(7):
        y[i] = x[i] + 0.5 * h * k2[i]
    k3 = state_rhs_scalar(y[0], y[1], y[2], y[3], y[4], y[5], y[6], um[0], um[1], um[2], J[0], J[1], J[2])
    for i in range(7):
        y[i] = x[i] + h * k3[i]
    k4 = state_rhs_scalar(y[0], y[1], y[2], y[3], y[4], y[5], y[6], ub[0], ub[1], ub[2], J[0], J[1], J[2])
    for i in range(7):
        x[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@njit(cache=True)
def replay_quadratic_control(x0, tk, U, Um, Ulim, p, J, samples, substeps):
    """``(t, X, n_rhs)``: ``t`` (N·samples + 1,), ``X`` (N·samples + 1, 7) from ``x0`` at
    ``tk[0]`` over the ``N = len(tk) - 1`` intervals; ``U`` (N + 1, 3) node controls, ``Um``
    (N, 3) midpoint controls."""
    N = tk.shape[0] - 1
    t = np.empty(N * samples + 1)
    X = np.empty((N * samples + 1, 7))
    x = x0.copy()
    y = np.empty(7)
    t[0] = tk[0]
    X[0] = x
    row = 1
    n = 0
    for k in range(N):
        a, b = tk[k], tk[k + 1]
        L = b - a
        m = samples * substeps
        dh = 1.0 / m
        for j in range(m):
            s = j * dh
            _rk4_step(x, y, L * dh, quadratic_control(s, U[k], Um[k], U[k + 1], Ulim, p),
                      quadratic_control(s + 0.5 * dh, U[k], Um[k], U[k + 1], Ulim, p),
                      quadratic_control(s + dh, U[k], Um[k], U[k + 1], Ulim, p), J)
            n += 4
            if (j + 1) % substeps == 0:
                t[row] = a + (j + 1) * dh * L
                X[row] = x
                row += 1
        t[row - 1] = b
    return t, X, n


@njit(cache=True)
def _eigen_torque(k, tau, rate, acc, a, c):
    r = rate[k] + acc[k] * tau
    return (acc[k] * a[0] + r * r * c[0], acc[k] * a[1] + r * r * c[1], acc[k] * a[2] + r * r * c[2])


@njit(cache=True)
def replay_eigenaxis_profile(x0, t, rate, acc, a, c, J, substeps):
    """Final state under the eigenaxis profile's torque: on ``[t_k, t_k+1)`` the rotation rate is
    ``θ̇(t) = rate_k + acc_k (t - t_k)`` and the torque ``u = acc_k a + θ̇² c`` (``a = J n``,
    ``c = n × J n``); RK4, ``substeps`` steps an interval (the torque is smooth inside)."""
    x = x0.copy()
    y = np.empty(7)
    for k in range(t.shape[0] - 1):
        L = t[k + 1] - t[k]
        if not L > 0.0:
            continue
        h = L / substeps
        for j in range(substeps):
            s = j * h
            _rk4_step(x, y, h, _eigen_torque(k, s, rate, acc, a, c), _eigen_torque(k, s + 0.5 * h, rate, acc, a, c),
                      _eigen_torque(k, s + h, rate, acc, a, c), J)
    return x


@njit(cache=True)
def replay_bang_bang_path(x0, umax, J, ev_t, ev_axis, signs0, tf, steps_per_tf):
    """``(t, x)``: the environment's RK4 (``slew_env.core.dynamics``) under a bang-bang torque,
    every step sampled, in one compiled call (``solvers.verify.replay_path``'s loop).

    ``ev_t``/``ev_axis``: the switches sorted by instant, then axis; each arc between them
    (and the last one, to ``tf``) takes ``max(1, ceil(dt / (tf / steps_per_tf)))`` equal steps,
    the quaternion renormalised after each, as ``dynamics.propagate`` does (bit for bit); instants as
    ``np.linspace`` gives them (the arc's end exactly).
    """
    n_ev = ev_t.shape[0]
    h_nom = tf / steps_per_tf
    # each arc's start and length (an arc that does not go forward takes no steps), then its steps
    starts = np.empty(n_ev + 1)
    lengths = np.empty(n_ev + 1)
    steps = np.zeros(n_ev + 1, dtype=np.int64)
    t_prev = 0.0
    for k in range(n_ev + 1):
        t_next = ev_t[k] if k < n_ev else tf
        starts[k], lengths[k] = t_prev, t_next - t_prev
        if lengths[k] > 0.0:
            steps[k] = max(1, int(math.ceil(lengths[k] / h_nom)))
        t_prev = max(t_prev, t_next)
    ts = np.empty(1 + steps.sum())
    xs = np.empty((ts.shape[0], 7))
    ts[0] = 0.0
    xs[0] = x0
    x = x0.copy()
    signs = signs0.copy()
    i = 0
    for k in range(n_ev + 1):
        n, dt = steps[k], lengths[k]
        u0, u1, u2 = umax[0] * signs[0], umax[1] * signs[1], umax[2] * signs[2]
        for s in range(n):
            # rk4_step then the renormalisation, as propagate does, without allocating
            rk4_step_inplace(x, u0, u1, u2, J[0], J[1], J[2], dt / n)
            i += 1
            xs[i] = x
            ts[i] = starts[k] + dt if s == n - 1 else starts[k] + (s + 1) * (dt / n)
        if k < n_ev:
            signs[ev_axis[k]] = -signs[ev_axis[k]]
    return ts, xs


@njit(cache=True)
def _guess_torque(tt, y, J, U, mode, p, sw_t, sw_axis, u0, by_switches, out):
    """A guess's torque at ``tt``: bang-bang from its switch instants (``u0`` the first signs;
    an axis flips at each of its instants at or before ``tt``), else the control law of its
    costates (bang: ``-U sign(S)`` with ``S ≥ 0`` taken as positive; p-norm: the closed form)."""
    if by_switches:
        for i in range(3):
            flips = 0
            for k in range(sw_t.shape[0]):
                if sw_axis[k] == i and sw_t[k] <= tt:
                    flips += 1
            out[i] = U[i] * u0[i] * (1.0 if flips % 2 == 0 else -1.0)
    elif mode == MODE_BANG:
        for i in range(3):
            out[i] = -U[i] * (1.0 if y[11 + i] / J[i] >= 0.0 else -1.0)
    else:
        u, _ = control(y, J, U, mode, p, 1e-2, np.ones(3))
        for i in range(3):
            out[i] = u[i]


@njit(cache=True)
def guess_path(y0, t, J, U, mode, p, sw_t, sw_axis, u0, by_switches):
    """``(Y, Uu)``: the augmented state ``y0`` (14,) under a guess's torque (``_guess_torque``)
    by classical RK4 on the even grid ``t``, the quaternion renormalised after every step, and
    the torque at every grid point (the collocation NLP's starting trajectory)."""
    n = t.shape[0] - 1
    h = t[1] - t[0] if n > 0 else 0.0
    Y = np.empty((n + 1, 14))
    Uu = np.empty((n + 1, 3))
    y = y0.copy()
    Y[0] = y
    u = np.empty(3)
    for k in range(n):
        tt = t[k]
        _guess_torque(tt, y, J, U, mode, p, sw_t, sw_axis, u0, by_switches, u)
        Uu[k] = u
        k1 = ext_rhs(y, u, J)
        y2 = y + 0.5 * h * k1
        _guess_torque(tt + 0.5 * h, y2, J, U, mode, p, sw_t, sw_axis, u0, by_switches, u)
        k2 = ext_rhs(y2, u, J)
        y3 = y + 0.5 * h * k2
        _guess_torque(tt + 0.5 * h, y3, J, U, mode, p, sw_t, sw_axis, u0, by_switches, u)
        k3 = ext_rhs(y3, u, J)
        y4 = y + h * k3
        _guess_torque(tt + h, y4, J, U, mode, p, sw_t, sw_axis, u0, by_switches, u)
        k4 = ext_rhs(y4, u, J)
        y = y + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        nq = np.sqrt(y[0] ** 2 + y[1] ** 2 + y[2] ** 2 + y[3] ** 2)
        for i in range(4):
            y[i] /= nq
        Y[k + 1] = y
    _guess_torque(t[n], y, J, U, mode, p, sw_t, sw_axis, u0, by_switches, u)
    Uu[n] = u
    return Y, Uu
