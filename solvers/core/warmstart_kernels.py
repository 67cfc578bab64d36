"""Compiled kernels of the learned warm start's inference: the network and the
full-attitude canonical form and output decoding (``solvers.warmstart``).

At these sizes (a 1×256 row through 256×256 layers, 43 outputs) numpy spends most of its
time in per-call overhead; one compiled call per stage keeps a guess's inference well under
the 100 µs a solve can spare for it. The numpy paths stay the reference: for a batch of
rows ``WarmStartModel.forward`` still multiplies matrices in numpy.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from slew_env.core.quaternion import qaxis_angle, qmul, qrotate_inv

ACT_SILU, ACT_TANH, ACT_RELU = 0, 1, 2


# tanh as a rational function (odd degree 13 over even degree 6, clamped beyond |x| = 7.9053):
# within 4.1e-7 of tanh in float32 arithmetic (largest near x = 5.83), and free of library calls, so the loop over a
# layer's 256 units vectorises (a libm call per unit took two thirds of the network's time)
_TA = (4.89352455891786e-03, 6.37261928875436e-04, 1.48572235717979e-05, 5.12229709037114e-08,
       -8.60467152213735e-11, 2.00018790482477e-13, -2.76076847742355e-16)
_TB = (4.89352518554385e-03, 2.26843463243900e-03, 1.18534705686654e-04, 1.19825839466702e-06)
_TCLAMP = 7.90531110763549805
A1, A3, A5, A7, A9, A11, A13 = (np.float32(v) for v in _TA)
B0, B2, B4, B6 = (np.float32(v) for v in _TB)
TCLAMP = np.float32(_TCLAMP)


@njit(cache=True, inline="always")
def fast_tanh(x):
    """float32 tanh within 4.1e-7 (``_TA``, ``_TB``); exactly ±1 beyond the clamp."""
    x = min(max(x, -TCLAMP), TCLAMP)
    x2 = x * x
    p = x * (A1 + x2 * (A3 + x2 * (A5 + x2 * (A7 + x2 * (A9 + x2 * (A11 + x2 * A13))))))
    q = B0 + x2 * (B2 + x2 * (B4 + x2 * B6))
    return p / q


@njit(cache=True)
def _dense(h, W, b, out):
    """``out = h W + b`` for one row (W row-major: the inner loop runs along a row)."""
    n_in, n_out = W.shape
    for j in range(n_out):
        out[j] = b[j]
    for i in range(n_in):
        hi = h[i]
        for j in range(n_out):
            out[j] += hi * W[i, j]


@njit(cache=True)
def mlp_forward(x, mean, std, weights, biases, act):
    """Raw float32 outputs of the MLP for one feature row ``x`` (float64, standardised by
    ``mean``, ``std``); ``weights``, ``biases`` tuples of C-contiguous float32 arrays, ``act``
    the hidden activation (``ACT_*``); none on the last layer."""
    h = np.empty(x.shape[0], np.float32)
    for i in range(x.shape[0]):
        h[i] = np.float32((x[i] - mean[i]) / std[i])
    last = len(weights) - 1
    for k in range(len(weights)):
        out = np.empty(weights[k].shape[1], np.float32)
        _dense(h, weights[k], biases[k], out)
        if k < last:
            for j in range(out.shape[0]):
                v = out[j]
                if act == ACT_SILU:
                    out[j] = np.float32(0.5) * v * (np.float32(1.0) + fast_tanh(np.float32(0.5) * v))
                elif act == ACT_TANH:
                    out[j] = fast_tanh(v)
                else:
                    out[j] = max(v, np.float32(0.0))
        h = out
    return h


@njit(cache=True)
def attitude_canonical(q0, qf, J, umax, p):
    """The full-attitude canonical form (``solvers.warmstart.features``): ``(A, order, x,
    T_eig)`` for a rest-to-rest slew from ``q0`` to ``qf`` with inertia ``J``, bound ``umax``
    and norm ``p`` (``inf``: per axis)."""
    n, th = qaxis_angle(q0, qf)
    # axes by decreasing |n_i|; a tie keeps the axis order (a stable sort)
    order = np.arange(3)
    for i in range(1, 3):
        j = i
        while j > 0 and abs(n[order[j]]) > abs(n[order[j - 1]]):
            order[j], order[j - 1] = order[j - 1], order[j]
            j -= 1
    even = (order[0] == 0 and order[1] == 1) or (order[0] == 1 and order[1] == 2) or \
        (order[0] == 2 and order[1] == 0)
    parity = 1.0 if even else -1.0
    s0 = 1.0 if n[order[0]] >= 0.0 else -1.0
    s1 = 1.0 if n[order[1]] >= 0.0 else -1.0
    sg = np.array([s0, s1, parity * s0 * s1])
    A = np.zeros((3, 3))
    for i in range(3):
        A[i, order[i]] = sg[i]
    Jmax = max(J[0], max(J[1], J[2]))
    umx = max(umax[0], max(umax[1], umax[2]))
    x = np.empty(11)
    for i in range(3):
        x[i] = sg[i] * n[order[i]]
        x[4 + i] = J[order[i]] / Jmax
        x[7 + i] = umax[order[i]] / umx
    x[3] = th / math.pi
    x[10] = 0.0 if math.isinf(p) else 1.0 / p
    # the eigenaxis guess's time: rest-to-rest about n' with the largest constant acceleration
    if math.isinf(p):
        amax = 0.0
        for i in range(3):
            amax = max(amax, abs(x[4 + i] * x[i]) / x[7 + i])
        acc = 1.0 / amax
    else:
        s = 0.0
        for i in range(3):
            s += (abs(x[4 + i] * x[i]) / x[7 + i]) ** p
        acc = 1.0 / s ** (1.0 / p)
    T_eig = 2.0 * math.sqrt(max(th, 1e-12) / acc)
    return A, order, x, T_eig


@njit(cache=True)
def _sort_head(a, n):
    """Sort ``a[:n]`` in place (n ≤ max_switches: an insertion sort; np.sort here cost seconds
    of compilation)."""
    for i in range(1, n):
        v = a[i]
        j = i - 1
        while j >= 0 and a[j] > v:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = v


@njit(cache=True)
def _unit_costates(out, i_z):
    """The 6 costate outputs from ``i_z`` on, scaled to unit norm (float64)."""
    z = np.empty(6)
    nz = 0.0
    for i in range(6):
        z[i] = out[i_z + i]
        nz += z[i] * z[i]
    nz = max(math.sqrt(nz), 1e-12)
    for i in range(6):
        z[i] /= nz
    return z


@njit(cache=True)
def decode_attitude(out, K, i_z, i_logT, i_uf, i_counts, i_times, T_eig):
    """The full-attitude network's outputs ``out`` decoded: ``(z', T, u_first', counts,
    count probabilities (3, K+1), switch instants (3, K): row i sorted, its first counts[i]
    used)`` (``WarmStartModel.predict_canonical``)."""
    z = _unit_costates(out, i_z)
    T = T_eig * math.exp(float(out[i_logT]))
    uf = np.empty(3)
    for i in range(3):
        uf[i] = 1.0 if out[i_uf + i] >= 0.0 else -1.0
    cp = np.empty((3, K + 1))
    counts = np.zeros(3, np.int64)
    times = np.zeros((3, K))
    for i in range(3):
        base = i_counts + i * (K + 1)
        m = float(out[base])
        best = 0
        for k in range(1, K + 1):
            if out[base + k] > out[base + best]:
                best = k
            m = max(m, float(out[base + k]))
        se = 0.0
        for k in range(K + 1):
            cp[i, k] = math.exp(float(out[base + k]) - m)
            se += cp[i, k]
        for k in range(K + 1):
            cp[i, k] /= se
        counts[i] = best
        for k in range(best):
            times[i, k] = 1.0 / (1.0 + math.exp(-float(out[i_times + i * K + k])))
        _sort_head(times[i], best)
        for k in range(best):
            times[i, k] *= T
    return z, T, uf, counts, cp, times


@njit(cache=True)
def _body_costates(q0, B, z, u, tau):
    """Canonical unit costates ``z`` (6,) and first-arc signs ``u`` (3,) → ``costate0`` in the
    problem's units (``λq(0) = q0 ⊗ [0, μ]·τ``, ``λω(0) = λω'·τ²``) and body signs (``np.sign``,
    as ``Guess`` takes them), by the axial map ``B`` (body vectors are ``B^T`` times canonical
    ones)."""
    mu = np.zeros(3)
    lw = np.zeros(3)
    uf = np.zeros(3)
    for i in range(3):
        for k in range(3):
            mu[i] += B[k, i] * z[k]
            lw[i] += B[k, i] * z[3 + k]
            uf[i] += B[k, i] * u[k]
        uf[i] = 1.0 if uf[i] > 0.0 else (-1.0 if uf[i] < 0.0 else 0.0)
    lq = qmul(q0, np.array([0.0, mu[0], mu[1], mu[2]]))
    c0 = np.empty(7)
    for i in range(4):
        c0[i] = lq[i] * tau
    for i in range(3):
        c0[4 + i] = lw[i] * (tau * tau)     # as the staged path rounds it: λω' · τ²
    return c0, uf


@njit(cache=True)
def attitude_guess(q0, qf, J, umax, p, mean, std, weights, biases, act, K, i_z, i_logT, i_uf, i_counts,
                   i_times):
    """A full-attitude network's guess in one compiled call: the canonical form, the network,
    the decoding, and the map back to the problem's axes and units (``WarmStartModel
    .guess_or_reason``; the stages are ``attitude_canonical``, ``mlp_forward``,
    ``decode_attitude`` and ``features.solution_from_canonical``). Three calls and the numpy
    map back cost 55 µs of Python overhead a guess; this one call, about 20 µs.

    Returns ``(x, costate0 (7,), tf, switch_times (3, K): row i holds body axis i's first
    counts[i], counts (3,), u_first (3,), ok)``; ``ok`` is false where the network's outputs
    are not finite (features far outside its range)."""
    A, order, x, T_eig = attitude_canonical(q0, qf, J, umax, p)
    out = mlp_forward(x, mean, std, weights, biases, act)
    z, T, uf_c, counts_c, cp, times_c = decode_attitude(out, K, i_z, i_logT, i_uf, i_counts, i_times, T_eig)
    Jmax = max(J[0], max(J[1], J[2]))
    umx = max(umax[0], max(umax[1], umax[2]))
    tau = math.sqrt(Jmax / umx)
    c0, uf = _body_costates(q0, A, z, uf_c, tau)
    sw = np.zeros((3, K))
    counts = np.zeros(3, np.int64)
    for i in range(3):
        j = order[i]
        counts[j] = counts_c[i]
        for k in range(counts_c[i]):
            sw[j, k] = times_c[i, k] * tau
    ok = math.isfinite(T) and T > 0.0
    for i in range(7):
        ok = ok and math.isfinite(c0[i])
    for i in range(3):
        for k in range(counts[i]):
            ok = ok and math.isfinite(sw[i, k])
    return x, c0, T * tau, sw, counts, uf, ok


# --------------------------------------------------------------------------- pointing with cones
@njit(cache=True)
def _round9(v):
    """``v`` to 9 decimals (the tie-breaking keys of the cone canonical form). Unlike Python's
    ``round``, which rounds the exact decimal value, this rounds ``v·1e9`` half to even: at a
    value within an ulp of a half-way point (5e-10 and the like) the other of two equally valid
    mirror forms can be chosen."""
    return np.rint(v * 1e9) / 1e9


@njit(cache=True)
def _arc_margin(a, half_angle, d):
    """Smallest angle from the cone ``(a, half_angle)`` boundary to the great circle from
    ``+x`` to ``d`` (negative when the arc enters the cone; ``cone_features._arc_margin``)."""
    c = min(1.0, max(-1.0, d[0]))
    th = math.acos(c)
    p1, p2 = d[1], d[2]
    n = math.hypot(p1, p2)
    # opposite target: every great circle is shortest; take the one through +z (deterministic)
    if n > 1e-9:
        p1, p2 = p1 / n, p2 / n
    else:
        p1, p2 = 0.0, 1.0
    ax, ap = a[0], a[1] * p1 + a[2] * p2
    phi = math.atan2(ap, ax)
    if 0.0 <= phi <= th:
        best = math.hypot(ax, ap)
    else:
        best = max(ax, ax * c + ap * math.sin(th))
    return math.acos(min(1.0, max(-1.0, best))) - half_angle


@njit(cache=True)
def cone_canonical(q0, target, J, umax, cand_A, cand_perm, cand_sg, cone_axes, half_angles):
    """The pointing-cones canonical form (``solvers.warmstart.cone_features``) of the slew from
    ``q0`` that points the sensor at ``target`` past cones with inertial axes ``cone_axes``
    (n, 3): ``(A, x, T_ref, slots, best, tau)``, ``best`` the index of ``A`` among the
    candidates, ``tau = sqrt(J_max / u_max)`` the time unit.
    ``cand_*``: the signed permutations with ``A s = +x`` for the sensor ``s``, as
    ``(A v)_i = sg[i] v[perm[i]]``."""
    n = cone_axes.shape[0]
    if n > 3:
        raise ValueError("cone_canonical: at most 3 cones (MAX_CONES)")
    d_body = qrotate_inv(q0, target)
    axes_body = np.empty((n, 3))
    for i in range(n):
        axes_body[i] = qrotate_inv(q0, cone_axes[i])
    # A: the candidate with the largest key (J'_y - J'_z, d'_y, d'_z), each to 9 decimals (a
    # tie within that goes to the next entry, then to the first candidate)
    best = 0
    k0 = k1 = k2 = -np.inf
    for c in range(cand_A.shape[0]):
        pm = cand_perm[c]
        sg = cand_sg[c]
        a0 = _round9(J[pm[1]] - J[pm[2]])
        a1 = _round9(sg[1] * d_body[pm[1]])
        a2 = _round9(sg[2] * d_body[pm[2]])
        if c == 0 or a0 > k0 or (a0 == k0 and (a1 > k1 or (a1 == k1 and a2 > k2))):
            best, k0, k1, k2 = c, a0, a1, a2
    A = cand_A[best].copy()
    d = A @ d_body
    d = d / math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    Jmax = max(J[0], max(J[1], J[2]))
    umx = max(umax[0], max(umax[1], umax[2]))
    absA = np.abs(A)
    Jn = (absA @ J) / Jmax
    un = (absA @ umax) / umx
    margins = np.empty(n)
    axes = np.empty((n, 3))
    for i in range(n):
        a = A @ axes_body[i]
        a = a / math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
        axes[i] = a
        margins[i] = _arc_margin(a, half_angles[i], d)
    # slots: most blocking first (smallest margin), ties by the problem's order
    slots = np.arange(n)
    for i in range(1, n):
        j = i
        while j > 0 and margins[slots[j]] < margins[slots[j - 1]]:
            slots[j], slots[j - 1] = slots[j - 1], slots[j]
            j -= 1
    x = np.zeros(9 + 5 * 3)
    x[0:3] = d
    x[3:6] = Jn
    x[6:9] = un
    for k in range(n):
        i = slots[k]
        x[9 + 5 * k:12 + 5 * k] = axes[i]
        x[12 + 5 * k] = half_angles[i]
        x[13 + 5 * k] = 1.0
    # eigenaxis pointing slew (cones ignored): about +x × d = (0, -d_z, d_y) through the angle
    # between them; for an opposite target, about +z
    th = math.acos(min(1.0, max(-1.0, d[0])))
    nax = math.hypot(d[1], d[2])
    ax = np.array([0.0, -d[2] / nax, d[1] / nax]) if nax > 1e-9 else np.array([0.0, 0.0, 1.0])
    amax = 0.0
    for i in range(3):
        amax = max(amax, abs(Jn[i] * ax[i]) / un[i])
    acc = 1.0 / amax                        # the per-axis bound (guesses.eigenaxis_acceleration)
    T_ref = 2.0 * math.sqrt(max(th, 1e-6) / acc)
    return A, x, T_ref, slots, best, math.sqrt(Jmax / umx)


@njit(cache=True)
def decode_cone(out, K, n_slots, i_z, i_logT, i_touch, i_tt, i_nu, i_uf, i_counts, i_times, T_ref):
    """The cone network's outputs decoded (``ConeWarmStartModel.predict_canonical``): ``(z', T,
    touch probabilities, touch instants, multipliers, first-arc signs, counts, switch instants
    (3, K): row i sorted, its first counts[i] used)``."""
    z = _unit_costates(out, i_z)
    T = T_ref * math.exp(float(out[i_logT]))
    p = np.empty(n_slots)
    tc = np.empty(n_slots)
    nu = np.empty(n_slots)
    for k in range(n_slots):
        p[k] = 1.0 / (1.0 + math.exp(-float(out[i_touch + k])))
        # strictly inside (0, T) even where the sigmoid saturates
        tc[k] = T * min(max(1.0 / (1.0 + math.exp(-float(out[i_tt + k]))), 1e-6), 1.0 - 1e-6)
        nu[k] = math.exp(min(max(float(out[i_nu + k]), -20.0), 5.0))
    uf = np.empty(3)
    for i in range(3):
        uf[i] = 1.0 if out[i_uf + i] >= 0.0 else -1.0
    counts = np.zeros(3, np.int64)
    times = np.zeros((3, K))
    for i in range(3):
        base = i_counts + i * (K + 1)
        best = 0
        for k in range(1, K + 1):
            if out[base + k] > out[base + best]:
                best = k
        counts[i] = best
        for k in range(best):
            times[i, k] = T / (1.0 + math.exp(-float(out[i_times + i * K + k])))
        _sort_head(times[i], best)
    return z, T, p, tc, nu, uf, counts, times


@njit(cache=True)
def cone_row_solution(q0, axial, order, tau, T_ref, n_cones, slots, Z, T_tab, T_ref_tab, U, F, touch, frac, log_nu,
                      j):
    """Row ``j`` of a pointing-cones table mapped to a problem (``ConeNearestNeighbourModel
    .row_guess``; the staged reference is ``cone_features.solution_from_canonical``): the
    problem's start ``q0``, its canonical form's ``axial`` map, ``order``, ``tau``, ``T_ref``
    and ``slots``. Returns ``(costate0 (7,), tf, switch_times (3, K): row i holds body axis i's
    first counts[i], sorted, counts (3,), u_first (3,), touches (m, 3): rows (cone, time,
    multiplier) in time order, ok)``; ``ok`` is false where a used entry is not finite."""
    K = F.shape[2]
    T = T_tab[j] * T_ref / T_ref_tab[j]
    c0, uf = _body_costates(q0, axial, Z[j], U[j], tau)
    sw = np.zeros((3, K))
    counts = np.zeros(3, np.int64)
    for i in range(3):                       # canonical axis i is body axis order[i]
        b = order[i]
        m = 0
        for k in range(K):
            f = F[j, i, k]
            if math.isfinite(f):
                sw[b, m] = f
                m += 1
        counts[b] = m
        _sort_head(sw[b], m)
        for k in range(m):
            sw[b, k] = (sw[b, k] * T) * tau
    touches = np.zeros((n_cones, 3))
    m = 0
    for k in range(n_cones):
        if touch[j, k] > 0.5:
            touches[m, 0] = slots[k]
            touches[m, 1] = frac[j, k] * T * tau
            touches[m, 2] = math.exp(log_nu[j, k]) * tau
            m += 1
    touches = touches[:m]
    for a in range(1, m):                    # by time (a stable insertion sort, as Guess sorts)
        b = a
        while b > 0 and touches[b, 1] < touches[b - 1, 1]:
            for c in range(3):
                touches[b, c], touches[b - 1, c] = touches[b - 1, c], touches[b, c]
            b -= 1
    tf = T * tau
    ok = math.isfinite(tf) and tf > 0.0
    for i in range(7):
        ok = ok and math.isfinite(c0[i])
    for i in range(3):
        ok = ok and math.isfinite(U[j, i])      # (a NaN sign would come out as 0, not as an error)
    for i in range(m):
        ok = ok and 0.0 < touches[i, 1] < tf and math.isfinite(touches[i, 2]) and touches[i, 2] >= 0.0
    return c0, tf, sw, counts, uf, touches, ok


@njit(cache=True, fastmath=True)
def nearest_rows(XT, x, k, idx):
    """The ``k`` rows of a table nearest to ``x`` (squared Euclidean distance), nearest first,
    into ``idx``. ``XT``: the table's standardised features, transposed (features × rows,
    float32, C order), so that the distances accumulate over a feature at a time along
    contiguous memory and the loop over rows vectorises; brute force beats a k-d tree in the
    cone table's 24 dimensions (about 30 against 65 µs for 7,674 rows). float32 distances can
    order two rows differently from float64 only when they are within about 1e-7 relative."""
    nearest_rows_kth(XT, x, k, idx)
    return idx


@njit(cache=True)
def cone_query_plan(x, scale, slot_has, slot_lacks, slot_bound):
    """The cone table's query plan for canonical features ``x`` (``cone_nearest.nearest``):
    ``(finite, code, xs, bound)``. ``xs = x / scale``; ``code`` the presence pattern of the 3
    cone slots (bit ``k`` set where slot ``k``'s flag ``x[13 + 5k]`` is above 0.5), or -1 where
    an absent slot has features other than zeros (such a query is not grouped); ``bound`` a
    lower bound of the squared standardised distance to every row of another pattern: over
    the slots where the patterns can differ, the query's own slot norm (it has the slot, some
    row lacks it) or the table's least (``slot_bound``: the row has it, the query lacks it)."""
    n = x.shape[0]
    xs = np.empty(n)
    finite = True
    for i in range(n):
        if not np.isfinite(x[i]):
            finite = False
        xs[i] = x[i] / scale[i]
    code = 0
    bound = np.inf
    for k in range(3):
        b = 9 + 5 * k
        if x[b + 4] > 0.5:
            code += 1 << k
            if slot_lacks[k]:
                v = 0.0
                for j in range(b, b + 5):
                    v += xs[j] * xs[j]
                bound = min(bound, v)
        else:
            for j in range(b, b + 5):
                if x[j] != 0.0:
                    code = -1
            if slot_has[k]:
                bound = min(bound, slot_bound[k])
        if code < 0:
            break
    return finite, code, xs, bound


@njit(cache=True, fastmath=True)
def nearest_rows_kth_dims(XT, xs, dims, k, idx):
    """``nearest_rows_kth`` of the query's features ``xs[dims]`` (the table ``XT`` holds only
    those features)."""
    xq = np.empty(dims.shape[0])
    for j in range(dims.shape[0]):
        xq[j] = xs[dims[j]]
    return nearest_rows_kth(XT, xq, k, idx)


@njit(cache=True, fastmath=True)
def nearest_rows_kth(XT, x, k, idx):
    """``nearest_rows``, returning the squared distance of the ``k``-th nearest row (float32
    arithmetic; infinite if the table has fewer than ``k`` rows)."""
    d, n = XT.shape
    s = np.zeros(n, dtype=np.float32)
    for j in range(d):
        xj = np.float32(x[j])
        row = XT[j]
        for i in range(n):
            t = row[i] - xj
            s[i] += t * t
    best = np.full(k, np.inf)
    for j in range(k):
        idx[j] = -1
    worst = np.inf
    for i in range(n):
        v = s[i]
        if v < worst:
            j = k - 1
            while j > 0 and best[j - 1] > v:
                best[j] = best[j - 1]
                idx[j] = idx[j - 1]
                j -= 1
            best[j] = v
            idx[j] = i
            worst = best[k - 1]
    return worst
