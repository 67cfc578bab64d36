"""Rigid-body rotational dynamics on plain arrays.

State ``x = [q0, q1, q2, q3, ω1, ω2, ω3]`` (quaternion body→inertial, body rates).
Euler's equations in principal axes: ``J ω̇ = -ω × (J ω) + u``.
These are the dynamics the environment steps and the solvers differentiate.
"""
import numpy as np
from numba import njit

STATE_DIM = 7


@njit(cache=True)
def euler_rate(J, w, u):
    """``ω̇ = J⁻¹ (u - ω × Jω)`` for principal inertia ``J`` (3,)."""
    out = np.empty(3)
    out[0] = (u[0] - (J[2] - J[1]) * w[1] * w[2]) / J[0]
    out[1] = (u[1] - (J[0] - J[2]) * w[2] * w[0]) / J[1]
    out[2] = (u[2] - (J[1] - J[0]) * w[0] * w[1]) / J[2]
    return out


@njit(cache=True)
def state_rhs(x, u, J):
    """Time derivative of the 7-state ``[q, ω]`` under torque ``u``."""
    out = np.empty(7)
    q0, q1, q2, q3 = x[0], x[1], x[2], x[3]
    w0, w1, w2 = x[4], x[5], x[6]
    # q̇ = ½ q ⊗ [0, ω]
    out[0] = 0.5 * (-q1 * w0 - q2 * w1 - q3 * w2)
    out[1] = 0.5 * (q0 * w0 + q2 * w2 - q3 * w1)
    out[2] = 0.5 * (q0 * w1 - q1 * w2 + q3 * w0)
    out[3] = 0.5 * (q0 * w2 + q1 * w1 - q2 * w0)
    out[4] = (u[0] - (J[2] - J[1]) * w1 * w2) / J[0]
    out[5] = (u[1] - (J[0] - J[2]) * w2 * w0) / J[1]
    out[6] = (u[2] - (J[1] - J[0]) * w0 * w1) / J[2]
    return out


@njit(cache=True)
def rk4_step(x, u, J, h):
    """One classical Runge–Kutta step of length ``h`` with constant torque ``u``.

    The quaternion is not renormalised here, so that the step is a pure RK4 map
    (tests compare it with closed forms); callers that run long renormalise.
    """
    k1 = state_rhs(x, u, J)
    k2 = state_rhs(x + 0.5 * h * k1, u, J)
    k3 = state_rhs(x + 0.5 * h * k2, u, J)
    k4 = state_rhs(x + h * k3, u, J)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


@njit(cache=True)
def state_rhs_scalar(q0, q1, q2, q3, w0, w1, w2, u0, u1, u2, J0, J1, J2):
    """``state_rhs`` on scalars, same expressions (no allocation: for hot loops)."""
    return (0.5 * (-q1 * w0 - q2 * w1 - q3 * w2),
            0.5 * (q0 * w0 + q2 * w2 - q3 * w1),
            0.5 * (q0 * w1 - q1 * w2 + q3 * w0),
            0.5 * (q0 * w2 + q1 * w1 - q2 * w0),
            (u0 - (J2 - J1) * w1 * w2) / J0,
            (u1 - (J0 - J2) * w2 * w0) / J1,
            (u2 - (J1 - J0) * w0 * w1) / J2)


@njit(cache=True)
def rk4_step_inplace(x, u0, u1, u2, J0, J1, J2, h):
    """One RK4 step of ``x[0:7]`` in place, then the quaternion renormalised.

    Same arithmetic as ``rk4_step`` followed by the renormalisation of ``propagate``,
    without allocating: the environment kernels step millions of bodies a second with it.
    """
    a = 0.5 * h
    k1 = state_rhs_scalar(x[0], x[1], x[2], x[3], x[4], x[5], x[6], u0, u1, u2, J0, J1, J2)
    k2 = state_rhs_scalar(x[0] + a * k1[0], x[1] + a * k1[1], x[2] + a * k1[2], x[3] + a * k1[3],
              x[4] + a * k1[4], x[5] + a * k1[5], x[6] + a * k1[6], u0, u1, u2, J0, J1, J2)
    k3 = state_rhs_scalar(x[0] + a * k2[0], x[1] + a * k2[1], x[2] + a * k2[2], x[3] + a * k2[3],
              x[4] + a * k2[4], x[5] + a * k2[5], x[6] + a * k2[6], u0, u1, u2, J0, J1, J2)
    k4 = state_rhs_scalar(x[0] + h * k3[0], x[1] + h * k3[1], x[2] + h * k3[2], x[3] + h * k3[3],
              x[4] + h * k3[4], x[5] + h * k3[5], x[6] + h * k3[6], u0, u1, u2, J0, J1, J2)
    b = h / 6.0
    for i in range(7):
        x[i] = x[i] + b * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    n = np.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2 + x[3] ** 2)
    for i in range(4):
        x[i] = x[i] / n


@njit(cache=True)
def propagate(x0, u, J, dt, n_steps):
    """Integrate ``n_steps`` RK4 steps of ``dt / n_steps`` with constant torque.

    Returns the array of states, shape ``(n_steps + 1, 7)``, quaternion
    renormalised after every step.
    """
    h = dt / n_steps
    out = np.empty((n_steps + 1, 7))
    out[0] = x0
    x = x0.copy()
    for k in range(n_steps):
        x = rk4_step(x, u, J, h)
        n = np.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2 + x[3] ** 2)
        x[0:4] /= n
        out[k + 1] = x
    return out


@njit(cache=True)
def torque_from_action(a, umax, p):
    """Map a normalised action ``a`` (3,) to a torque within the bound.

    Each component is clipped to [-1, 1]. For a p-norm bound (``p`` finite,
    ``p > 1``; ``p <= 0`` means the per-axis ∞-norm) the clipped action is
    projected radially onto the unit p-norm ball when it lies outside it. The
    torque is ``u_i = umax_i · v_i``, so the bound is ``‖u / umax‖_p ≤ 1``
    (``umax`` equal on all axes gives the plain ``‖u‖_p ≤ umax``).
    """
    v = np.empty(3)
    for i in range(3):
        ai = a[i]
        if ai > 1.0:
            ai = 1.0
        elif ai < -1.0:
            ai = -1.0
        elif not (ai == ai):  # NaN action: no torque rather than NaN state
            ai = 0.0
        v[i] = ai
    if p > 0.0:
        s = 0.0
        for i in range(3):
            s += abs(v[i]) ** p
        n = s ** (1.0 / p)
        if n > 1.0:
            v /= n
    out = np.empty(3)
    for i in range(3):
        out[i] = umax[i] * v[i]
    return out


@njit(cache=True)
def kinetic_energy(J, w):
    return 0.5 * (J[0] * w[0] ** 2 + J[1] * w[1] ** 2 + J[2] * w[2] ** 2)
