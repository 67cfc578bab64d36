"""Phase-plane sweeps of the eigenaxis slew (compiled), for the per-axis and the p-norm bound.

The eigenaxis slew is computed on every indirect solve (it gates local optima), so its
forward/backward integration of ``s = θ̇²`` runs here, on plain arrays: on each grid
interval the acceleration is constant and feasible at both ends, so the sampled torques
never exceed the bound. For a p-norm bound the feasible accelerations at a speed are the
sublevel interval of a convex function: a point inside it by golden section, its edges by
false position.
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
def _interval(a, c, U, p, s, want_lo, want_hi):
    """Feasible ``θ̈`` at speed ``s``: the per-axis interval for ``p = inf``, else the p-norm one
    (only its ends asked for)."""
    if math.isinf(p):
        return accel_interval(a, c, U, s)
    return _pnorm_ends(a, c, U, p, s, want_lo, want_hi)


@njit(cache=True)
def _amax(a, c, U, p, s, s_max):
    lo, hi, ok = _interval(a, c, U, p, min(s, s_max), False, True)
    return hi if ok else 0.0


@njit(cache=True)
def _amin(a, c, U, p, s, s_max):
    lo, hi, ok = _interval(a, c, U, p, min(s, s_max), True, False)
    return lo if ok else 0.0


@njit(cache=True)
def sweep(a, c, U, p, s_max, th, n_grid):
    """The phase-plane sweeps under the bound ``p`` (``inf``: per axis): forward (max
    acceleration) and backward (max deceleration) profiles of ``s`` on ``n_grid`` equal steps of
    ``θ`` in ``[0, th]``; the profile is ``min(fwd, bwd)``. Also the constant acceleration each
    sweep used on each interval (``fa[k] ≥ 0`` forward, ``bd[k] ≤ 0`` backward, interval ``k``
    from ``θ_k`` to ``θ_k+1``), which ``capped_nodes`` needs: ``(fwd, bwd, fa, bd)``."""
    dth = th / n_grid
    fwd = np.zeros(n_grid + 1)
    bwd = np.zeros(n_grid + 1)
    fa = np.zeros(n_grid)
    bd = np.zeros(n_grid)
    # without a gyroscopic term the interval does not depend on the speed: found once (the
    # rounds below would stop at their first repeat anyway)
    gyro = c[0] != 0.0 or c[1] != 0.0 or c[2] != 0.0
    fixed_hi = 0.0 if gyro else _amax(a, c, U, p, 0.0, s_max)
    fixed_lo = 0.0 if gyro else _amin(a, c, U, p, 0.0, s_max)
    for k in range(n_grid):
        s = fwd[k]
        acc = _amax(a, c, U, p, s, s_max) if gyro else fixed_hi
        for _ in range(3 if gyro else 0):
            nxt = min(acc, _amax(a, c, U, p, min(s + 2.0 * dth * acc, s_max), s_max))
            if nxt == acc:      # a fixed point: further rounds repeat the same evaluation
                break
            acc = nxt
        fa[k] = max(acc, 0.0)
        fwd[k + 1] = min(s + 2.0 * dth * fa[k], s_max)
    for k in range(n_grid, 0, -1):
        s = bwd[k]
        dec = _amin(a, c, U, p, s, s_max) if gyro else fixed_lo
        for _ in range(3 if gyro else 0):
            nxt = max(dec, _amin(a, c, U, p, min(s - 2.0 * dth * dec, s_max), s_max))
            if nxt == dec:
                break
            dec = nxt
        bd[k - 1] = min(dec, 0.0)
        bwd[k - 1] = min(s - 2.0 * dth * bd[k - 1], s_max)
    return fwd, bwd, fa, bd


@njit(cache=True)
def capped_nodes(fwd, bwd, fa, bd, th, n_grid, s_cap):
    """The profile ``min(fwd, bwd)`` as nodes ``(θ, s, dθ)`` (``dθ[k]``: the angle from node
    ``k`` to ``k+1``, the grid step itself where a step is not split, so that a profile without
    added points is the grid's to the last bit): the grid, plus the points inside a grid interval
    where the profile reaches the rate cap ``s_cap`` (``inf``: none) on a sweep's line. On the
    grid alone an interval where the speed reaches the cap takes one constant acceleration from
    its start to the cap at its end, slower than accelerating fully and then coasting: under a
    tight rate limit, whose acceleration covers less than a grid step, that cost up to 0.2 % of
    the slew's time. With these points every piece has the constant acceleration it really has
    (exact for a body without gyroscopic term). The pieces' angles are computed from the sweep's
    acceleration (``d = (s_cap - s) / 2|θ̈|``), not as differences of nearby angles, so that the
    acceleration a piece implies is the sweep's to rounding however short the piece."""
    dth = th / n_grid
    theta = np.empty(3 * n_grid + 1)
    s = np.empty(3 * n_grid + 1)
    steps = np.empty(3 * n_grid)
    theta[0] = 0.0
    s[0] = min(fwd[0], bwd[0])
    m = 1
    for k in range(n_grid):
        t0 = k * dth
        t1 = th if k == n_grid - 1 else (k + 1) * dth
        d1 = math.inf       # from t0 to where the forward line reaches the cap
        d2 = math.inf       # from where the backward line leaves the cap to t1
        if s_cap < math.inf:
            if fa[k] > 0.0 and fwd[k] < s_cap < fwd[k] + 2.0 * dth * fa[k]:
                d1 = (s_cap - fwd[k]) / (2.0 * fa[k])
                if bwd[k + 1] - 2.0 * bd[k] * (dth - d1) < s_cap * (1.0 - 1e-12):
                    d1 = math.inf           # the profile is the backward line there, below the cap
            if bd[k] < 0.0 and bwd[k + 1] < s_cap < bwd[k + 1] - 2.0 * dth * bd[k]:
                d2 = (s_cap - bwd[k + 1]) / (-2.0 * bd[k])
                if fwd[k] + 2.0 * fa[k] * (dth - d2) < s_cap * (1.0 - 1e-12):
                    d2 = math.inf           # the profile is the forward line there, below the cap
        mid = dth - (d1 if d1 < math.inf else 0.0) - (d2 if d2 < math.inf else 0.0)
        if d1 < math.inf and d2 < math.inf and not mid > 1e-12 * dth:
            # both lines reach the cap at one angle: one point, the pieces to either side
            theta[m] = t0 + d1
            s[m] = s_cap
            steps[m - 1] = d1
            m += 1
            theta[m] = t1
            s[m] = min(fwd[k + 1], bwd[k + 1])
            steps[m - 1] = d2
            m += 1
            continue
        if not mid > 1e-12 * dth:       # (rounding at a piece's end: the grid step)
            d1 = math.inf
            d2 = math.inf
            mid = dth
        # the pieces: [t0, t0 + d1] where the cap is reached, the coast (``mid``: the grid step
        # less what the sweeps' lines take), [t1 - d2, t1] where it is left
        if d1 < math.inf:
            theta[m] = t0 + d1
            s[m] = s_cap
            steps[m - 1] = d1
            m += 1
        if d2 < math.inf:
            theta[m] = t1 - d2
            s[m] = s_cap
            steps[m - 1] = mid
            m += 1
        theta[m] = t1
        s[m] = min(fwd[k + 1], bwd[k + 1])
        steps[m - 1] = d2 if d2 < math.inf else mid
        m += 1
    return theta[:m].copy(), s[:m].copy(), steps[:m - 1].copy()


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
def nodes_time(steps, s):
    """Duration of the profile through the nodes ``s_k`` ``steps[k]`` apart in angle (constant
    acceleration between nodes: ``dt = 2 dθ / (θ̇_k + θ̇_k+1)``)."""
    total = 0.0
    prev = math.sqrt(max(s[0], 0.0))
    for k in range(1, s.shape[0]):
        r = math.sqrt(max(s[k], 0.0))
        den = prev + r
        if den > 0.0:
            total += 2.0 * steps[k - 1] / den
        prev = r
    return total


@njit(cache=True)
def _pnorm_of(x, a, c, U, p, s):
    """``‖(a x + c s) / U‖_p`` (scaled by its largest term: no overflow for large p)."""
    m = 0.0
    for i in range(3):
        v = abs((a[i] * x + c[i] * s) / U[i])
        if v > m:
            m = v
    if m == 0.0:
        return 0.0
    t = 0.0
    for i in range(3):
        t += (abs((a[i] * x + c[i] * s) / U[i]) / m) ** p
    return m * t ** (1.0 / p)


@njit(cache=True)
def _edge(out, inside, a, c, U, p, s, tol):
    """The sublevel set's edge between ``out`` (norm > 1) and ``inside`` (norm ≤ 1), on its
    feasible side, to ``tol``: false position with the Illinois rule (the end that has not
    moved for two steps has its value halved, so both ends close in; about a dozen norms
    where bisection took 47), a midpoint where the secant leaves the bracket."""
    f_out = _pnorm_of(out, a, c, U, p, s) - 1.0
    f_in = min(_pnorm_of(inside, a, c, U, p, s) - 1.0, 0.0)
    side = 0
    for _ in range(200):
        if abs(inside - out) <= tol or f_in == 0.0:
            break
        x = (out * f_in - inside * f_out) / (f_in - f_out)
        if not (min(out, inside) < x < max(out, inside)):
            x = 0.5 * (out + inside)
        fx = _pnorm_of(x, a, c, U, p, s) - 1.0
        if fx > 0.0:
            out, f_out = x, fx
            if side == 1:
                f_in *= 0.5
            side = 1
        else:
            inside, f_in = x, fx
            if side == -1:
                f_out *= 0.5
            side = -1
    return inside


@njit(cache=True)
def _inside_point(lo, hi, a, c, U, p, s, tol):
    """A point of ``[lo, hi]`` where the norm is ≤ 1: golden section towards the convex
    function's minimiser, stopped at the first such point (any one brackets both edges).
    ``(x, ok)``; ``ok`` False where the minimum exceeds 1 (on the maximum-velocity curve the
    interval is one point, accepted to rounding)."""
    g = 0.5 * (math.sqrt(5.0) - 1.0)
    x0, x1 = lo, hi
    xa = x1 - g * (x1 - x0)
    xb = x0 + g * (x1 - x0)
    fa = _pnorm_of(xa, a, c, U, p, s)
    if fa <= 1.0:
        return xa, True
    fb = _pnorm_of(xb, a, c, U, p, s)
    if fb <= 1.0:
        return xb, True
    for _ in range(200):
        if x1 - x0 <= tol:
            break
        if fa <= fb:
            x1, xb, fb = xb, xa, fa
            xa = x1 - g * (x1 - x0)
            fa = _pnorm_of(xa, a, c, U, p, s)
            if fa <= 1.0:
                return xa, True
        else:
            x0, xa, fa = xa, xb, fb
            xb = x0 + g * (x1 - x0)
            fb = _pnorm_of(xb, a, c, U, p, s)
            if fb <= 1.0:
                return xb, True
    xm = 0.5 * (x0 + x1)
    return xm, _pnorm_of(xm, a, c, U, p, s) <= 1.0 + 1e-12


@njit(cache=True)
def _pnorm_ends(a, c, U, p, s, want_lo, want_hi):
    """``accel_interval_pnorm``, with only the ends asked for (the other is NaN): the sweeps
    need one end at a time."""
    lo, hi, ok = accel_interval(a, c, U, s)
    if not ok:
        return 0.0, 0.0, False
    tol = 1e-14 * max(1.0, hi - lo)
    xm, ok = _inside_point(lo, hi, a, c, U, p, s, tol)
    if not ok:
        return 0.0, 0.0, False
    left = right = math.nan
    if want_lo:
        left = lo if _pnorm_of(lo, a, c, U, p, s) <= 1.0 else _edge(lo, xm, a, c, U, p, s, tol)
    if want_hi:
        right = hi if _pnorm_of(hi, a, c, U, p, s) <= 1.0 else _edge(hi, xm, a, c, U, p, s, tol)
    return left, right, True


@njit(cache=True)
def accel_interval_pnorm(a, c, U, p, s):
    """Feasible ``θ̈`` at speed ``s`` for the p-norm bound: ``(lo, hi, ok)``. The set
    ``{x : ‖(a x + c s) / U‖_p ≤ 1}`` is an interval (a convex function's sublevel set) inside
    the per-axis one: a point inside it (``_inside_point``), then each edge (``_edge``)."""
    return _pnorm_ends(a, c, U, p, s, True, True)
