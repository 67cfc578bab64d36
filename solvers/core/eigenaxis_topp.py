"""Phase-plane sweeps of the eigenaxis baseline for the per-axis bound (compiled).

The eigenaxis slew is computed on every indirect solve (it gates local optima), so its
forward/backward integration of ``s = θ̇²`` runs here, on plain arrays. Same algorithm as
the Python fallback in ``solvers.eigenaxis`` (used for p-norm bounds): on each grid
interval the acceleration is constant and feasible at both ends, so the sampled torques
never exceed the bound.
"""
import math

import numpy as np
from numba import njit


@njit(cache=True)
def accel_interval(a, c, U, s):
    """Feasible ``θ̈`` at speed ``s`` for the per-axis bound: ``(lo, hi, ok)``."""
    lo = -math.inf
    hi = math.inf
    for i in range(3):
        if abs(a[i]) < 1e-15:
            if abs(c[i] * s) > U[i]:
                return 0.0, 0.0, False
            continue
        b1 = (-U[i] - c[i] * s) / a[i]
        b2 = (U[i] - c[i] * s) / a[i]
        lo = max(lo, min(b1, b2))
        hi = min(hi, max(b1, b2))
    if lo > hi:
        return 0.0, 0.0, False
    return lo, hi, True


@njit(cache=True)
def _amax(a, c, U, s, s_max):
    lo, hi, ok = accel_interval(a, c, U, min(s, s_max))
    return hi if ok else 0.0


@njit(cache=True)
def _amin(a, c, U, s, s_max):
    lo, hi, ok = accel_interval(a, c, U, min(s, s_max))
    return lo if ok else 0.0


@njit(cache=True)
def sweep_per_axis(a, c, U, s_max, th, n_grid):
    """Forward (max acceleration) and backward (max deceleration) profiles of ``s`` on
    ``n_grid`` equal steps of ``θ`` in ``[0, th]``; the profile is ``min(fwd, bwd)``."""
    dth = th / n_grid
    fwd = np.zeros(n_grid + 1)
    bwd = np.zeros(n_grid + 1)
    for k in range(n_grid):
        s = fwd[k]
        acc = _amax(a, c, U, s, s_max)
        for _ in range(3):
            acc = min(acc, _amax(a, c, U, min(s + 2.0 * dth * acc, s_max), s_max))
        fwd[k + 1] = min(s + 2.0 * dth * max(acc, 0.0), s_max)
    for k in range(n_grid, 0, -1):
        s = bwd[k]
        dec = _amin(a, c, U, s, s_max)
        for _ in range(3):
            dec = max(dec, _amin(a, c, U, min(s - 2.0 * dth * dec, s_max), s_max))
        bwd[k - 1] = min(s - 2.0 * dth * min(dec, 0.0), s_max)
    return fwd, bwd


@njit(cache=True)
def max_speed(a, c, U):
    """Largest ``s = θ̇²`` with a non-empty acceleration interval (the maximum-velocity
    curve of the per-axis bound); ``inf`` when the gyroscopic term never limits it."""
    hi = 1.0
    while True:
        lo_, hi_, ok = accel_interval(a, c, U, hi)
        if not ok or hi >= 1e12:
            break
        hi *= 2.0
    if hi >= 1e12:
        return math.inf
    lo = 0.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo_, hi_, ok = accel_interval(a, c, U, mid)
        if ok:
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True)
def profile_time(fwd, bwd, th, n_grid):
    """Duration of the phase-plane profile ``min(fwd, bwd)`` (piecewise-constant acceleration)."""
    dth = th / n_grid
    total = 0.0
    prev = math.sqrt(max(min(fwd[0], bwd[0]), 0.0))
    for k in range(1, n_grid + 1):
        r = math.sqrt(max(min(fwd[k], bwd[k]), 0.0))
        den = prev + r
        if den > 0.0:
            total += 2.0 * dth / den
        prev = r
    return total
