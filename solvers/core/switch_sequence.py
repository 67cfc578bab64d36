"""Compiled flow of a fixed bang-bang switching sequence, for switch-time shooting.

``sequence_flow`` integrates the extremal's arcs between given switch instants (any order:
sorted here, stably) with the signs held fixed on each arc, and carries the sensitivity
``G = dy/dx`` to the shooting unknowns ``x = [z (6), t_1 … t_n, T]`` through every arc and
switch, with the switching functions at the switches and their gradients. It is the loop
``solvers.switch_time._residual`` ran arc by arc in Python (a transition matrix per arc, then
``Φ @ G``), in one compiled call: the Python overhead per arc was larger than the arc's
integration. Only the columns already non-zero ride along: those of ``z`` and of the switches
passed so far (the others, and ``T``'s, are zero until their switch or the end), so an early
arc carries 6 columns instead of 14. The step sizes depend on the state alone (the error norm
ignores the sensitivities), so the arcs take the same steps as before.
"""
import numpy as np
from numba import njit

from .attitude_flow import FLOW_OK, NY, ext_rhs, flow


@njit(cache=True)
def sequence_flow(y0, G, times, axes, T, signs0, J, umax, mode, p, eps, rtol, atol, pen, want_jac,
                  S_res, S_jac):
    """Arcs of ``y0`` (NY,) over ``[0, T]`` with switches of axes ``axes`` at ``times``.

    ``G`` (NY, 6 + n + 1): on entry, columns 0-5 hold ``dy0/dz`` and the rest zeros; on
    return (with ``want_jac``), ``dy(T)/dx`` with switch ``j``'s column at ``6 + j`` (the
    caller's order) and ``T``'s last. ``S_res[j]`` is the switching function
    ``λω_a / J_a`` of switch ``j`` just before it; ``S_jac[j]`` its gradient in ``x``.
    Returns ``(y(T), ok)``; ``ok`` is False if an arc fails or a time is not finite.
    """
    n = times.shape[0]
    nx = 6 + n + 1
    y = y0.copy()
    signs = signs0.copy()
    if not np.isfinite(T):
        return y, False
    for j in range(n):
        if not np.isfinite(times[j]):
            return y, False
    order = np.argsort(times, kind="mergesort")      # stable, as np.argsort(kind="stable")
    active = np.empty(nx, dtype=np.int64)
    for c in range(6):
        active[c] = c
    n_active = 6
    no_t = np.empty(0)
    no_Y = np.empty((0, NY))
    no_s = np.empty((0, 3))
    sw_t = np.empty(1)
    sw_a = np.empty(1, dtype=np.int64)
    t_prev = 0.0
    for k in range(n + 1):
        t_next = T if k == n else times[order[k]]
        dt = t_next - t_prev
        if dt > 0.0:
            m = n_active if want_jac else 0
            Y0 = np.empty(NY + NY * m)
            Y0[:NY] = y
            for i in range(NY):
                for c in range(m):
                    Y0[NY + i * m + c] = G[i, active[c]]
            Y, _, _, _, _, status = flow(Y0, dt, m, J, umax, mode, p, eps, signs, rtol, atol, min(0.05, dt),
                                         200000, 0, no_t, no_Y, no_s, sw_t, sw_a, pen, False, np.inf)
            if status != FLOW_OK:
                return y, False
            for i in range(Y.shape[0]):
                if not np.isfinite(Y[i]):
                    return y, False
            y = Y[:NY].copy()
            for i in range(NY):
                for c in range(m):
                    G[i, active[c]] = Y[NY + i * m + c]
        if t_next > t_prev:
            t_prev = t_next
        if k == n:
            break
        j = order[k]
        a = axes[j]
        S_res[j] = y[11 + a] / J[a]
        if want_jac:
            f = ext_rhs(y, umax * signs, J)
            for c in range(nx):
                S_jac[j, c] = G[11 + a, c] / J[a]
            S_jac[j, 6 + j] += f[11 + a] / J[a]
            # moving the switch later keeps the old torque on axis a for longer
            G[4 + a, 6 + j] += 2.0 * signs[a] * umax[a] / J[a]
            active[n_active] = 6 + j
            n_active += 1
        signs[a] = -signs[a]
    if want_jac:
        f = ext_rhs(y, umax * signs, J)
        for i in range(NY):
            G[i, nx - 1] += f[i]
    return y, True
