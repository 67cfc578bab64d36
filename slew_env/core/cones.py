"""Keep-out cone geometry on plain arrays.

A cone is an inertial unit axis ``a`` and a half-angle ``α``; the sensor (a body
unit vector ``s_b``) is clear when ``angle(q ⊗ s_b ⊗ q*, a) ≥ α``. The clearance
margin is ``angle(s_i, a) - α`` in radians, negative inside the cone.
"""
import numpy as np
from numba import njit

from .quaternion import qrotate


@njit(cache=True)
def angle_between(a, b):
    """Angle between unit vectors, accurate near 0 and π (atan2 of |a×b|, a·b)."""
    c0 = a[1] * b[2] - a[2] * b[1]
    c1 = a[2] * b[0] - a[0] * b[2]
    c2 = a[0] * b[1] - a[1] * b[0]
    s = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    return np.arctan2(s, d)


@njit(cache=True)
def perpendicular_basis(s):
    """Two unit vectors completing unit ``s`` to a right-handed orthonormal basis
    (``e1 = s × x_k`` normalised, ``x_k`` the axis least aligned with ``s``; ``e2 = s × e1``)."""
    i = 0
    if abs(s[1]) < abs(s[i]):
        i = 1
    if abs(s[2]) < abs(s[i]):
        i = 2
    ax = np.zeros(3)
    ax[i] = 1.0
    e1 = np.cross(s, ax)
    e1 /= np.sqrt(e1[0] ** 2 + e1[1] ** 2 + e1[2] ** 2)
    e2 = np.cross(s, e1)
    return e1, e2


@njit(cache=True)
def cone_margins_inertial(s_i, axes, half_angles, n_cones):
    """Margins of the inertial sensor direction ``s_i`` to the first ``n_cones`` cones."""
    out = np.empty(n_cones)
    for k in range(n_cones):
        out[k] = angle_between(s_i, axes[k]) - half_angles[k]
    return out


@njit(cache=True)
def cone_margins(q, sensor_b, axes, half_angles, n_cones):
    """Margins (rad) of the sensor at attitude ``q`` to each of the first ``n_cones`` cones."""
    return cone_margins_inertial(qrotate(q, sensor_b), axes, half_angles, n_cones)


@njit(cache=True)
def min_cone_margin(q, sensor_b, axes, half_angles, n_cones):
    """Smallest margin over the cones; ``+inf`` when there are none."""
    s_i = qrotate(q, sensor_b)
    m = np.inf
    for k in range(n_cones):
        mk = angle_between(s_i, axes[k]) - half_angles[k]
        if mk < m:
            m = mk
    return m
