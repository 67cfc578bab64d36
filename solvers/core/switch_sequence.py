"""Compiled steps of a fixed bang-bang switching sequence, for switch-time shooting.

``advance_columns`` flies one arc with the signs held fixed, carrying only the sensitivity
columns already non-zero (those of ``z`` and of the switches passed so far: an early arc carries
6 columns instead of 14), and ``switch_event`` applies a switch: its switching function, the
function's gradient, and the jump of the switch instant's column. The event loop of switch-time
shooting, with or without touches of keep-out cones, is ``touch_sequence.touch_sequence_flow``
(``solvers.switch_time._residual`` calls it with no touches); it replaced the loop that ran arc by
arc in Python (a transition matrix per arc, then ``Φ @ G``), whose overhead per arc was larger
than the arc's integration. The step sizes depend on the state alone (the error norm ignores the
sensitivities), so the arcs take the same steps as before. ``sequence_end`` and
``sequence_samples`` are the forward passes of the switch-time optimisers (end state, sampled
states, and their derivatives in the switch instants).
"""
import numpy as np
from numba import njit

from .attitude_flow import FLOW_OK, MODE_BANG, NY, ext_rhs, flow
from .state_arc import state_arc


@njit(cache=True)
def no_step_budget():
    """The step budget of a call that has none (``steps_left``: a 1-element array of the steps the
    calls sharing it may still take, decremented as they go)."""
    return np.full(1, 1 << 62, np.int64)


@njit(cache=True)
def _fixed_arc(Y0, dt, m, signs, J, umax, mode, p, eps, rtol, atol, pen, steps_left):
    """One arc of fixed ``signs`` over ``dt`` of ``[y, Φ]`` (``m`` sensitivity columns, row-major),
    as ``AttitudeBVP.arc`` runs it: ``(Y(dt), ok)``, ``ok`` False if it fails, is not finite or
    needs more steps than ``steps_left[0]`` (which it decrements by the steps it took)."""
    cap = min(200000, steps_left[0])
    if cap <= 0:
        return Y0.copy(), False
    Y, _, _, _, steps, status = flow(Y0, dt, m, J, umax, mode, p, eps, signs, rtol, atol, min(0.05, dt), cap, 0,
                                     np.empty(0), np.empty((0, NY)), np.empty((0, 3)), np.empty(1),
                                     np.empty(1, dtype=np.int64), pen, False, np.inf)
    steps_left[0] -= steps
    if status != FLOW_OK:
        return Y, False
    for i in range(Y.shape[0]):
        if not np.isfinite(Y[i]):
            return Y, False
    return Y, True


@njit(cache=True)
def _zero_costates(y):
    for i in range(7, NY):
        if y[i] != 0.0:
            return False
    return True


@njit(cache=True)
def _arc_transition(y, dt, m, signs, J, umax, mode, p, eps, rtol, atol, pen, steps_left):
    """One arc of fixed ``signs`` over ``dt`` from the augmented state ``y``, with the state's
    7×7 transition matrix when ``m`` is 7 (zeros when 0): ``(y(dt), Φ, ok)``. With zero
    costates and no cone penalty the costates stay zero, and the state flows alone
    (``state_arc``: the same steps and states, half the work with ``Φ``)."""
    if mode == MODE_BANG and pen.shape[0] == 0 and _zero_costates(y):
        x, Phi, ok = state_arc(y, dt, umax * signs, J, rtol, atol, m > 0, steps_left)
        out = np.zeros(NY)
        out[:7] = x
        return out, Phi, ok
    Y0 = np.zeros(NY + NY * m)
    Y0[:NY] = y
    for c in range(m):
        Y0[NY + c * m + c] = 1.0
    Y, ok = _fixed_arc(Y0, dt, m, signs, J, umax, mode, p, eps, rtol, atol, pen, steps_left)
    Phi = np.zeros((7, 7))
    for i in range(m):
        for c in range(m):
            Phi[i, c] = Y[NY + i * m + c]
    return Y[:NY].copy(), Phi, ok


@njit(cache=True)
def _finite_times(times, T):
    """Whether ``T`` and every switch instant are finite (an iterate may not be)."""
    if not np.isfinite(T):
        return False
    for j in range(times.shape[0]):
        if not np.isfinite(times[j]):
            return False
    return True


@njit(cache=True)
def advance_columns(y, G, active, n_active, dt, signs, J, umax, mode, p, eps, rtol, atol, pen, want_jac,
                    steps_left):
    """One arc of fixed ``signs`` over ``dt`` from ``y``, carrying the sensitivity columns
    ``active[:n_active]`` of ``G`` (updated in place; the others are zero and stay so), or none
    without ``want_jac``: ``(y(dt), ok)``, ``(y, False)`` if the arc fails (``steps_left``:
    ``_fixed_arc``'s)."""
    m = n_active if want_jac else 0
    Y0 = np.empty(NY + NY * m)
    Y0[:NY] = y
    for i in range(NY):
        for c in range(m):
            Y0[NY + i * m + c] = G[i, active[c]]
    Y, ok = _fixed_arc(Y0, dt, m, signs, J, umax, mode, p, eps, rtol, atol, pen, steps_left)
    if not ok:
        return y, False
    for i in range(NY):
        for c in range(m):
            G[i, active[c]] = Y[NY + i * m + c]
    return Y[:NY].copy(), True


@njit(cache=True)
def switch_event(y, G, signs, a, j, J, umax, want_jac, S_res, S_jac, active, n_active):
    """Switch ``j`` of axis ``a`` at the running state ``y``, its instant the unknown in column
    ``6 + j``: ``S_res[j]`` the switching function ``λω_a / J_a`` just before it, with its
    gradient in ``S_jac[j]`` and the jump ``f⁻ - f⁺`` in ``G``'s column, which becomes active;
    flips ``signs[a]``. Returns the new number of active columns."""
    S_res[j] = y[11 + a] / J[a]
    if want_jac:
        f = ext_rhs(y, umax * signs, J)
        for c in range(G.shape[1]):
            S_jac[j, c] = G[11 + a, c] / J[a]
        S_jac[j, 6 + j] += f[11 + a] / J[a]
        # moving the switch later keeps the old torque on axis a for longer
        G[4 + a, 6 + j] += 2.0 * signs[a] * umax[a] / J[a]
        active[n_active] = 6 + j
        n_active += 1
    signs[a] = -signs[a]
    return n_active


@njit(cache=True)
def sequence_end(y0, times, axes, T, signs0, J, umax, mode, p, eps, rtol, atol, pen, want_jac, steps_left=None):
    """The end of a bang-bang control with switches at fixed instants, and the end state's
    derivatives in ``[times, T]`` (``solvers.switch_time.propagate_sequence``'s arcs in one
    compiled call). An instant at or after ``T`` does not flip (beyond the horizon); one before
    0 flips at 0; either way its derivative is zero.

    Returns ``(y(T), dx, M, nfev, ok)``: with ``want_jac``, ``dx`` (7, n + 1) holds
    ``∂x(T)/∂t_k = Φ(T, t_k)(f⁻ - f⁺)`` (switch ``k`` in the caller's order) and ``∂x(T)/∂T``,
    accumulated backwards over the arcs' 7×7 transition matrices, and ``M`` is the transition
    matrix over ``[0, T]``; without, both are zeros. ``ok`` is False if an arc fails, also for
    want of steps: ``steps_left`` (a 1-element int64 array, decremented) bounds the steps of all
    the arcs together (the solve's deadline, ``attitude_bvp.step_budget``); ``None``: no bound.
    """
    sl = no_step_budget() if steps_left is None else steps_left
    n = times.shape[0]
    m = 7 if want_jac else 0
    dx = np.zeros((7, n + 1))
    M = np.zeros((7, 7))
    if not _finite_times(times, T):
        return y0.copy(), dx, M, 0, False
    order = np.argsort(times, kind="mergesort")
    mats = np.zeros((n + 1, 7, 7))
    jumps = np.zeros((n, 7))
    signs = signs0.copy()
    y = y0.copy()
    t = 0.0
    nfev = 0
    for kk in range(n + 1):
        raw = T if kk == n else times[order[kk]]
        tk = min(max(raw, 0.0), T)
        if tk > t:
            y, Phi, ok = _arc_transition(y, tk - t, m, signs, J, umax, mode, p, eps, rtol, atol, pen, sl)
            nfev += 1
            if not ok:
                return y, dx, M, nfev, False
            if want_jac:
                mats[kk] = Phi
            t = tk
        elif want_jac:
            for i in range(7):
                mats[kk, i, i] = 1.0
        if kk == n:
            break
        a = axes[order[kk]]
        if raw >= T:
            continue
        if want_jac and raw > 0.0:
            # f⁻ - f⁺ differs only in ω̇_a (as in ``switch_event``)
            jumps[kk, 4 + a] = 2.0 * signs[a] * umax[a] / J[a]
        signs[a] = -signs[a]
    if want_jac:
        G = np.eye(7)
        # Φ(T, t_k) = M_last … M_{k+1}: accumulated backwards
        for j in range(n - 1, -1, -1):
            G = G @ mats[j + 1]
            dx[:, order[j]] = G @ jumps[j]
        f = ext_rhs(y, umax * signs, J)
        for i in range(7):
            dx[i, n] = f[i]
        M = G @ mats[0]
    return y, dx, M, nfev, True


@njit(cache=True)
def sequence_samples(y0, times, axes, T, signs0, fracs, J, umax, mode, p, eps, rtol, atol, pen, want_jac,
                     steps_left=None):
    """The states of a bang-bang control with switches at fixed instants at the sample instants
    ``fracs · T`` (``fracs`` sorted, in [0, 1]), and their derivatives in ``[times, T]``, for
    path constraints (keep-out cones) in switch-time optimisation.

    Forward sensitivities: ``G = ∂x/∂[times, T]`` (7, n + 1) rides along the arcs
    (``G ← Φ G``); a switch ``k`` adds its jump ``f⁻ - f⁺`` to column ``k``; at a sample
    ``x(s T)`` the ``T`` column is ``s f(x)`` (the instant moves with ``T``; the switches do
    not). Switch instants are clipped to ``[0, T]`` as in ``sequence_end``. Without
    ``want_jac`` the states alone (``dX`` and ``dx`` zeros): the arcs carry no transition matrix.

    Returns ``(X (M, 7), dX (M, 7, n + 1), y(T), dx (7, n + 1), nfev, ok)``; ``steps_left``:
    ``sequence_end``'s.
    """
    sl = no_step_budget() if steps_left is None else steps_left
    n = times.shape[0]
    M = fracs.shape[0]
    X = np.zeros((M, 7))
    dX = np.zeros((M, 7, n + 1))
    dx = np.zeros((7, n + 1))
    if not _finite_times(times, T):
        return X, dX, y0.copy(), dx, 0, False
    # merged events: switches (kind 0, index j) and samples (kind 1, index m), by time
    ev_t = np.empty(n + M)
    ev_k = np.empty(n + M, dtype=np.int64)
    ev_i = np.empty(n + M, dtype=np.int64)
    for j in range(n):
        ev_t[j] = min(max(times[j], 0.0), T)
        ev_k[j] = 0
        ev_i[j] = j
    for m in range(M):
        ev_t[n + m] = fracs[m] * T
        ev_k[n + m] = 1
        ev_i[n + m] = m
    order = np.argsort(ev_t, kind="mergesort")
    G = np.zeros((7, n + 1))
    m = 7 if want_jac else 0
    signs = signs0.copy()
    y = y0.copy()
    t = 0.0
    nfev = 0
    for kk in range(n + M + 1):
        e = order[kk] if kk < n + M else -1
        tk = T if e < 0 else ev_t[e]
        if tk > t:
            y, Phi, ok = _arc_transition(y, tk - t, m, signs, J, umax, mode, p, eps, rtol, atol, pen, sl)
            nfev += 1
            if not ok:
                return X, dX, y, dx, nfev, False
            if want_jac:
                G = Phi @ G
            t = tk
        if e < 0:
            break
        if ev_k[e] == 1:
            k = ev_i[e]
            for i in range(7):
                X[k, i] = y[i]
            if want_jac:
                f = ext_rhs(y, umax * signs, J)
                for i in range(7):
                    for c in range(n):
                        dX[k, i, c] = G[i, c]
                    dX[k, i, n] = fracs[k] * f[i]
            continue
        j = ev_i[e]
        raw = times[j]
        a = axes[j]
        if raw >= T:
            continue
        if raw > 0.0:
            G[4 + a, j] += 2.0 * signs[a] * umax[a] / J[a]
        signs[a] = -signs[a]
    if want_jac:
        f = ext_rhs(y, umax * signs, J)
        for i in range(7):
            for c in range(n):
                dx[i, c] = G[i, c]
            dx[i, n] = f[i]
    return X, dX, y, dx, nfev, True
