"""Compiled clearance margins of keep-out cones along a sampled path, and their certified bound.

The arithmetic of ``solvers.clearance.cone_margins`` and ``cone_clearances`` (whose docstrings
give the bounds), one sample at a time: on the 8,000-sample replay that certifies every touch
answer, the numpy version took 2.2 ms, most of it in temporaries (``runs/s31/succ_parts.py``).
"""
import math

import numpy as np
from numba import njit


# error_model="numpy": a zero quaternion row gives NaN margins (a check that fails), not a
# ZeroDivisionError out of a verification
@njit(cache=True, error_model="numpy")
def path_margins(q, s, axes, half):
    """``(n, n_cones)`` clearance margins ``angle(R(q_i) s, a_k) - α_k`` (atan2 form), with
    ``q`` (n, 4) not necessarily unit and ``s`` the body sensor axis as given."""
    n, nc = q.shape[0], axes.shape[0]
    out = np.empty((n, nc))
    s0, s1, s2 = s[0], s[1], s[2]
    for i in range(n):
        nq = math.sqrt(q[i, 0] ** 2 + q[i, 1] ** 2 + q[i, 2] ** 2 + q[i, 3] ** 2)
        w, r0, r1, r2 = q[i, 0] / nq, q[i, 1] / nq, q[i, 2] / nq, q[i, 3] / nq
        # d = s + 2 (w (r × s) + r × (r × s))
        c0 = r1 * s2 - r2 * s1
        c1 = r2 * s0 - r0 * s2
        c2 = r0 * s1 - r1 * s0
        d0 = s0 + 2.0 * (w * c0 + (r1 * c2 - r2 * c1))
        d1 = s1 + 2.0 * (w * c1 + (r2 * c0 - r0 * c2))
        d2 = s2 + 2.0 * (w * c2 + (r0 * c1 - r1 * c0))
        for k in range(nc):
            a0, a1, a2 = axes[k, 0], axes[k, 1], axes[k, 2]
            x0 = d1 * a2 - d2 * a1
            x1 = d2 * a0 - d0 * a2
            x2 = d0 * a1 - d1 * a0
            out[i, k] = math.atan2(math.sqrt(x0 * x0 + x1 * x1 + x2 * x2), d0 * a0 + d1 * a1 + d2 * a2) - half[k]
    return out


@njit(cache=True, error_model="numpy")
def certified_bounds(t, mar, wn, half, amax):
    """Per cone ``[sample minimum, certified minimum, margin at t0, margin at tN]`` (n_cones, 4)
    from the margins ``mar`` (n, n_cones), the rates' norms ``wn`` (n) and the bound ``amax`` on
    ``|ω̇|`` (``clearance.cone_clearances``)."""
    n, nc = mar.shape
    out = np.empty((nc, 4))
    # a NaN anywhere (a path that is not finite) makes every minimum NaN, as numpy's would be,
    # so that no check passes on it
    bad = not (amax == amax)
    for i in range(n):
        if not (t[i] == t[i] and wn[i] == wn[i]):
            bad = True
        for k in range(nc):
            if not (mar[i, k] == mar[i, k]):
                bad = True
    if bad:
        out[:, :] = np.nan
        return out
    for k in range(nc):
        smin = mar[0, k]
        cert = np.inf
        for i in range(n - 1):
            m0, m1 = mar[i, k], mar[i + 1, k]
            if m1 < smin:
                smin = m1
            dt = t[i + 1] - t[i]
            W = max(wn[i], wn[i + 1]) + amax * dt
            lo_end = min(m0, m1)
            first = min(0.5 * (m0 + m1) - 0.5 * W * dt, lo_end)
            th0, th1 = m0 + half[k], m1 + half[k]
            th_lo = min(th0, th1) - W * dt
            th_hi = max(th0, th1) + W * dt
            s_low = 0.0
            if th_lo > 0.0 and th_hi < math.pi:
                s_low = min(math.sin(min(max(th_lo, 0.0), math.pi)), math.sin(min(max(th_hi, 0.0), math.pi)))
            best = first
            if s_low > 1e-6:
                B = (amax + 2.0 * W * W) / s_low
                second = lo_end - B * dt * dt / 8.0
                if second > best:
                    best = second
            if best < cert:
                cert = best
        out[k, 0] = smin
        out[k, 1] = cert
        out[k, 2] = mar[0, k]
        out[k, 3] = mar[n - 1, k]
    return out
