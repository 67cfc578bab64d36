"""Boundary residuals of a pointing-only target, compiled (called at every shooting step).

With the sensor ``s`` (body), the target direction ``d`` (inertial) and ``E`` (2 x 3) an
orthonormal basis of the plane perpendicular to ``s``:

* pointing (2): ``E d_b`` with ``d_b = R(q)ᵀ d = (q0² - v·v) d + 2 v (v·d) - 2 q0 (v × d)``
  (zero when the sensor points at the target, ``d_b = s``, and also at the antipode
  ``d_b = -s``); or, with ``stereographic``, ``2 E d_b / (1 + s·d_b)``, the stereographic
  projection of ``d_b`` from ``-s``: ``2 tan(θ/2)`` for a sensor ``θ`` off the target, zero only
  at ``d_b = s`` and without bound towards the antipode. The two agree to second order near
  the target;
* roll transversality (1): ``Im(q* ⊗ λq) · s``, the costate conjugate to the free roll about
  the sensor axis, with ``Im(q* ⊗ λq) = q0 λv - λ0 v - v × λv``;
* the final rate (3): ``ω - ω_f``.

Each with its gradient in the augmented state ``y = [q, ω, λq, λω]`` (6 x 14).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@njit(cache=True)
def pointing_terminal(y, d, sb, E, wf, stereographic=False):
    """``(r (6), D (6, 14))``: pointing, roll transversality and rate residuals (module docstring)."""
    q0 = y[0]
    v = y[1:4].copy()
    l0 = y[7]
    lv = y[8:11].copy()
    vd = v[0] * d[0] + v[1] * d[1] + v[2] * d[2]
    vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    vxd = _cross(v, d)
    db = (q0 * q0 - vv) * d + 2.0 * v * vd - 2.0 * q0 * vxd
    ddb = np.empty((3, 4))
    ddb[:, 0] = 2.0 * q0 * d - 2.0 * vxd
    for j in range(3):
        ej = np.zeros(3)
        ej[j] = 1.0
        ddb[:, 1 + j] = -2.0 * v[j] * d + 2.0 * ej * vd + 2.0 * v * d[j] - 2.0 * q0 * _cross(ej, d)
    r = np.empty(6)
    D = np.zeros((6, 14))
    if stereographic:
        # the floor on 1 + s·d_b only keeps the exact antipode finite
        den = max(1.0 + sb[0] * db[0] + sb[1] * db[1] + sb[2] * db[2], 1e-12)
        edb = E @ db
        r[0:2] = 2.0 * edb / den
        D[0:2, 0:4] = 2.0 * (E @ ddb) / den - 2.0 * np.outer(edb, sb @ ddb) / (den * den)
    else:
        r[0:2] = E @ db
        D[0:2, 0:4] = E @ ddb
    im = q0 * lv - l0 * v - _cross(v, lv)
    r[2] = im[0] * sb[0] + im[1] * sb[1] + im[2] * sb[2]
    D[2, 0] = lv[0] * sb[0] + lv[1] * sb[1] + lv[2] * sb[2]
    D[2, 1:4] = -l0 * sb - _cross(lv, sb)
    D[2, 7] = -(v[0] * sb[0] + v[1] * sb[1] + v[2] * sb[2])
    D[2, 8:11] = q0 * sb - _cross(sb, v)
    for i in range(3):
        r[3 + i] = y[4 + i] - wf[i]
        D[3 + i, 4 + i] = 1.0
    return r, D
