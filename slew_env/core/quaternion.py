"""Quaternion algebra on plain arrays (scalar-first, Hamilton product).

Conventions (shared/CONVENTIONS.md): ``q`` rotates body to inertial,
``v_i = q ⊗ [0, v_b] ⊗ q*`` and ``q̇ = ½ q ⊗ [0, ω]`` with body rates ``ω``.
All functions are numba-compiled and allocate only their small outputs, so they
can be called from other compiled loops (environment kernels, shooting solvers).
"""
import numpy as np
from numba import njit


@njit(cache=True)
def qmul(p, q):
    """Hamilton product ``p ⊗ q``."""
    out = np.empty(4)
    out[0] = p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3]
    out[1] = p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2]
    out[2] = p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1]
    out[3] = p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0]
    return out


@njit(cache=True)
def qconj(q):
    out = np.empty(4)
    out[0] = q[0]
    out[1] = -q[1]
    out[2] = -q[2]
    out[3] = -q[3]
    return out


@njit(cache=True)
def qnormalize(q):
    n = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return q / n


@njit(cache=True)
def qrotate(q, v):
    """Body vector ``v`` expressed in the inertial frame: ``q ⊗ [0, v] ⊗ q*``."""
    # Rodrigues form of the sandwich product: v + 2 w (r × v) + 2 r × (r × v)
    w = q[0]
    r0, r1, r2 = q[1], q[2], q[3]
    c0 = r1 * v[2] - r2 * v[1]
    c1 = r2 * v[0] - r0 * v[2]
    c2 = r0 * v[1] - r1 * v[0]
    out = np.empty(3)
    out[0] = v[0] + 2.0 * (w * c0 + r1 * c2 - r2 * c1)
    out[1] = v[1] + 2.0 * (w * c1 + r2 * c0 - r0 * c2)
    out[2] = v[2] + 2.0 * (w * c2 + r0 * c1 - r1 * c0)
    return out


@njit(cache=True)
def qrotate_inv(q, v):
    """Inertial vector ``v`` expressed in the body frame: ``q* ⊗ [0, v] ⊗ q``."""
    return qrotate(qconj(q), v)


@njit(cache=True)
def qfrom_axis_angle(axis, angle):
    """Rotation by ``angle`` (rad) about the unit vector ``axis``."""
    s = np.sin(0.5 * angle)
    out = np.empty(4)
    out[0] = np.cos(0.5 * angle)
    out[1] = s * axis[0]
    out[2] = s * axis[1]
    out[3] = s * axis[2]
    return out


@njit(cache=True)
def qangle(q):
    """Rotation angle of ``q`` in [0, π], the same for ``q`` and ``-q``."""
    v = np.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return 2.0 * np.arctan2(v, abs(q[0]))


@njit(cache=True)
def qerror_angle(q, qf):
    """Angle of the error rotation ``qf* ⊗ q`` (rad, in [0, π])."""
    return qangle(qmul(qconj(qf), q))


@njit(cache=True)
def qaxis_angle(q0, qf):
    """Axis ``n`` (unit, in the body axes of ``q0``) and angle ``θ`` in [0, π] of the rotation
    ``q0* ⊗ qf`` taking ``q0`` to ``qf``; ``([1, 0, 0], 0)`` when they are the same attitude."""
    d = qmul(qconj(q0), qf)
    if d[0] < 0.0:
        d = -d
    v = np.sqrt(d[1] * d[1] + d[2] * d[2] + d[3] * d[3])
    n = np.empty(3)
    if v < 1e-15:
        n[0], n[1], n[2] = 1.0, 0.0, 0.0
        return n, 0.0
    n[0], n[1], n[2] = d[1] / v, d[2] / v, d[3] / v
    return n, 2.0 * np.arctan2(v, d[0])


@njit(cache=True)
def qcanonical(q):
    """``q`` or ``-q``, whichever has a non-negative scalar part."""
    if q[0] < 0.0:
        return -q
    return q.copy()


@njit(cache=True)
def qfrom_two_vectors(a, b):
    """Shortest rotation taking unit vector ``a`` onto unit vector ``b``.

    For antiparallel vectors the axis is any unit vector orthogonal to ``a``
    (chosen deterministically).

    Accurate up to exactly antiparallel inputs: ``[1 + a·b, a × b]`` is evaluated as
    ``[|s|²/2, a × s]`` with ``s = a + b`` (for unit vectors these are equal), which
    does not cancel catastrophically as ``b → -a``.
    """
    s0 = a[0] + b[0]
    s1 = a[1] + b[1]
    s2 = a[2] + b[2]
    ss = s0 * s0 + s1 * s1 + s2 * s2
    out = np.empty(4)
    if ss < 1e-30:
        # antiparallel to rounding (|a + b| < 1e-15): rotate by π about the
        # coordinate axis least aligned with a, made orthogonal to a
        ax = np.zeros(3)
        i = 0
        if abs(a[1]) < abs(a[i]):
            i = 1
        if abs(a[2]) < abs(a[i]):
            i = 2
        ax[i] = 1.0
        c0 = a[1] * ax[2] - a[2] * ax[1]
        c1 = a[2] * ax[0] - a[0] * ax[2]
        c2 = a[0] * ax[1] - a[1] * ax[0]
        n = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        out[0] = 0.0
        out[1] = c0 / n
        out[2] = c1 / n
        out[3] = c2 / n
        return out
    # a × b = a × (a + b); 1 + a·b = |a + b|² / 2 for unit a, b
    out[0] = 0.5 * ss
    out[1] = a[1] * s2 - a[2] * s1
    out[2] = a[2] * s0 - a[0] * s2
    out[3] = a[0] * s1 - a[1] * s0
    return qnormalize(out)


@njit(cache=True)
def qfrom_uniform(u1, u2, u3):
    """Uniformly distributed random rotation from three uniforms in [0, 1) (Shoemake)."""
    out = np.empty(4)
    a = np.sqrt(1.0 - u1)
    b = np.sqrt(u1)
    out[0] = b * np.cos(2.0 * np.pi * u3)
    out[1] = a * np.sin(2.0 * np.pi * u2)
    out[2] = a * np.cos(2.0 * np.pi * u2)
    out[3] = b * np.sin(2.0 * np.pi * u3)
    return out


def quat_from_euler321(roll, pitch, yaw):
    """Quaternion (body to inertial) of the aerospace 3-2-1 sequence, angles in rad.

    Yaw ψ about z, then pitch θ about y, then roll φ about x.
    """
    cr, sr = np.cos(0.5 * roll), np.sin(0.5 * roll)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    return np.array([
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    ])


def quat_from_euler321_deg(roll_deg, pitch_deg, yaw_deg):
    return quat_from_euler321(np.radians(roll_deg), np.radians(pitch_deg), np.radians(yaw_deg))
