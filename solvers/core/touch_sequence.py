"""Compiled flow of a fixed bang-bang switching sequence, with touch-point junctions on cones.

``touch_sequence_flow`` is the loop of ``solvers.cone_touch._structured_residual`` in one
compiled call, and, with no touches, of the switch-time Newton's ``solvers.switch_time._residual``: the arcs between switches and touches with the signs held fixed, the switching
functions at the switches, ``[h, ḣ]`` at each touch (the path tangent to the cone there) and the
costate jump ``λq⁺ = λq⁻ - 2 ν M q`` after it, with the sensitivity ``G = dy/dx`` to the unknowns

    x = [z (6), switch instants (n), T, touch instants (K), multipliers (K)]

carried through every arc and event. In Python each arc cost a call into the integrator with a
full 14-column transition matrix, then ``Φ @ G``, and the per-event bookkeeping was about a
third of a learned cone candidate's time. Here only the columns already non-zero ride along an
arc (those of ``z``, and of the switches and touches passed so far; the arc and switch steps are
``switch_sequence``'s); the step sizes depend on the state alone, so the arcs take the same steps
as the Python loop's.
"""
import numpy as np
from numba import njit

from .attitude_flow import NY, ext_rhs
from .switch_sequence import _finite_times, advance_columns, no_step_budget, switch_event


@njit(cache=True)
def _mat4_vec(M, v):
    """``M v`` for a 4×4 ``M`` and the first 4 entries of ``v`` (a loop: no BLAS call)."""
    out = np.zeros(4)
    for i in range(4):
        for l in range(4):
            out[i] += M[i, l] * v[l]
    return out


@njit(cache=True)
def touch_residual(y, M, cos_a):
    """``[h, ḣ]`` of the cone ``h(q) = qᵀMq - cos α`` at the augmented state ``y``, and their
    gradient (2, NY): ``ḣ = 2 (Mq)·q̇`` with ``q̇ = ½ q ⊗ (0, ω)``."""
    q0, q1, q2, q3 = y[0], y[1], y[2], y[3]
    w1, w2, w3 = y[4], y[5], y[6]
    qd = np.empty(4)
    qd[0] = 0.5 * (-q1 * w1 - q2 * w2 - q3 * w3)
    qd[1] = 0.5 * (q0 * w1 + q2 * w3 - q3 * w2)
    qd[2] = 0.5 * (q0 * w2 + q3 * w1 - q1 * w3)
    qd[3] = 0.5 * (q0 * w3 + q1 * w2 - q2 * w1)
    Mq = _mat4_vec(M, y)
    Mqd = _mat4_vec(M, qd)
    h = 0.0
    hd = 0.0
    for i in range(4):
        h += y[i] * Mq[i]
        hd += 2.0 * Mq[i] * qd[i]
    r = np.empty(2)
    r[0] = h - cos_a
    r[1] = hd
    g = np.zeros((2, NY))
    m0, m1, m2, m3 = Mq[0], Mq[1], Mq[2], Mq[3]
    for i in range(4):
        g[0, i] = 2.0 * Mq[i]
    # ∂q̇/∂q = ½ R((0, ω)) (x ⊗ p = R(p) x); its transpose applied to Mq
    g[1, 0] = 2.0 * Mqd[0] + (w1 * m1 + w2 * m2 + w3 * m3)
    g[1, 1] = 2.0 * Mqd[1] + (-w1 * m0 - w3 * m2 + w2 * m3)
    g[1, 2] = 2.0 * Mqd[2] + (-w2 * m0 + w3 * m1 - w1 * m3)
    g[1, 3] = 2.0 * Mqd[3] + (-w3 * m0 - w2 * m1 + w1 * m2)
    # ∂q̇/∂ω = ½ (columns 1-3 of the left matrix Q(q), q ⊗ p = Q(q) p); transposed onto Mq
    g[1, 4] = -q1 * m0 + q0 * m1 + q3 * m2 - q2 * m3
    g[1, 5] = -q2 * m0 - q3 * m1 + q0 * m2 + q1 * m3
    g[1, 6] = -q3 * m0 + q2 * m1 - q1 * m2 + q0 * m3
    return r, g


@njit(cache=True)
def touch_sequence_flow(y0, G, times, axes, T, tc, nu, Ms, cos_a, signs0, J, umax, mode, p, eps, rtol, atol,
                        pen, want_jac, S_res, S_jac, H_res, H_jac, steps_left=None):
    """Arcs of ``y0`` (NY,) over ``[0, T]`` with switches of axes ``axes`` at ``times`` and touches
    of cone ``k`` (matrix ``Ms[k]``, ``cos α = cos_a[k]``) at ``tc[k]`` with multipliers ``nu[k]``.

    ``G`` (NY, 6 + n + 1 + 2K): on entry, columns 0-5 hold ``dy0/dz`` and the rest zeros; on
    return (with ``want_jac``), ``dy(T)/dx`` in the column order of ``x`` above. ``S_res[j]``
    is the switching function ``λω_a / J_a`` of switch ``j`` just before it and ``S_jac[j]`` its
    gradient; ``H_res[2k:2k+2]`` is ``[h, ḣ]`` at touch ``k`` and ``H_jac[2k:2k+2]`` its gradient.
    Events at the same instant run switches first, each kind in index order. Instants are not
    clipped to ``[0, T]``: one before 0 acts at 0, and one past ``T`` acts where the flow has
    stopped, at the latest earlier instant (the caller keeps its iterates inside). Returns
    ``(y(T), ok)``; ``ok`` is False if an arc fails or an instant is not finite, also for want of
    steps (``steps_left``: ``switch_sequence.sequence_end``'s).
    """
    sl = no_step_budget() if steps_left is None else steps_left
    n = times.shape[0]
    K = tc.shape[0]
    nx = 6 + n + 1 + 2 * K
    c_T = 6 + n
    c_tc = 7 + n
    c_nu = 7 + n + K
    y = y0.copy()
    signs = signs0.copy()
    if not (_finite_times(times, T) and _finite_times(tc, T)):
        return y, False
    ev_t = np.empty(n + K)
    for j in range(n):
        ev_t[j] = times[j]
    for k in range(K):
        ev_t[n + k] = tc[k]
    order = np.argsort(ev_t, kind="mergesort")       # stable: switches before touches at a tie
    active = np.empty(nx, dtype=np.int64)
    for c in range(6):
        active[c] = c
    n_active = 6
    t_prev = 0.0
    for e in range(n + K + 1):
        t_next = T if e == n + K else ev_t[order[e]]
        dt = t_next - t_prev
        if dt > 0.0:
            y, ok = advance_columns(y, G, active, n_active, dt, signs, J, umax, mode, p, eps, rtol, atol, pen,
                                    want_jac, sl)
            if not ok:
                return y, False
        if t_next > t_prev:
            t_prev = t_next
        if e == n + K:
            break
        idx = order[e]
        if idx < n:
            n_active = switch_event(y, G, signs, axes[idx], idx, J, umax, want_jac, S_res, S_jac, active, n_active)
            continue
        k = idx - n
        M = Ms[k]
        r, g = touch_residual(y, M, cos_a[k])
        H_res[2 * k] = r[0]
        H_res[2 * k + 1] = r[1]
        Mq = 0.5 * g[0, 0:4]        # ∂h/∂q = 2 M q (halving is exact)
        if want_jac:
            f = ext_rhs(y, umax * signs, J)
            for row in range(2):
                for c in range(nx):
                    s = 0.0
                    for i in range(NY):
                        s += g[row, i] * G[i, c]
                    H_jac[2 * k + row, c] = s
                # the touch instant moves with the state: ∂[h, ḣ]/∂t_c = g · f⁻
                gf = 0.0
                for i in range(NY):
                    gf += g[row, i] * f[i]
                H_jac[2 * k + row, c_tc + k] += gf
            # the jump's map on G: rows 7-10 gain -2ν M (rows 0-3)
            for ci in range(n_active):
                c = active[ci]
                for i in range(4):
                    s = 0.0
                    for l in range(4):
                        s += M[i, l] * G[l, c]
                    G[7 + i, c] -= 2.0 * nu[k] * s
            for i in range(4):
                G[7 + i, c_nu + k] -= 2.0 * Mq[i]
            # the touch instant's column: the jump map applied to f⁻, minus f⁺
            Mf = _mat4_vec(M, f)
            for i in range(NY):
                G[i, c_tc + k] += f[i]
            for i in range(4):
                G[7 + i, c_tc + k] -= 2.0 * nu[k] * Mf[i]
        for i in range(4):
            y[7 + i] -= 2.0 * nu[k] * Mq[i]
        if want_jac:
            fp = ext_rhs(y, umax * signs, J)
            for i in range(NY):
                G[i, c_tc + k] -= fp[i]
            active[n_active] = c_tc + k
            active[n_active + 1] = c_nu + k
            n_active += 2
    if want_jac:
        f = ext_rhs(y, umax * signs, J)
        for i in range(NY):
            G[i, c_T] += f[i]
    return y, True
