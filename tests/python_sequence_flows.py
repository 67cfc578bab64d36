"""Reference loops for the compiled sequence flows: the arc-by-arc Python code they replaced
(a 14-column transition matrix per arc, then ``Φ @ G``), kept here to test them against."""
import numpy as np

from slew_env.core.quaternion import qmul
from solvers.attitude_bvp import NY, quat_left_matrix
from solvers.cone_touch import touch_jump
from solvers.core.attitude_flow import ext_rhs

_EYE = np.eye(NY)


def _right_matrix(p):
    """``R(p)`` with ``x ⊗ p = R(p) x``."""
    p0, p1, p2, p3 = p
    return np.array([[p0, -p1, -p2, -p3],
                     [p1, p0, p3, -p2],
                     [p2, -p3, p0, p1],
                     [p3, p2, -p1, p0]])


def _touch_residual(y, M, cos_a):
    """``[h, ḣ]`` at the augmented state ``y`` and their gradient (2 x 14), with numpy
    (the compiled ``core.touch_sequence.touch_residual`` is tested against it)."""
    q, w = y[0:4], y[4:7]
    Mq = M @ q
    qdot = 0.5 * qmul(q, np.array([0.0, *w]))
    h = float(q @ Mq) - cos_a
    hd = 2.0 * float(Mq @ qdot)
    g = np.zeros((2, NY))
    g[0, 0:4] = 2.0 * Mq
    dqd_dq = 0.5 * _right_matrix(np.array([0.0, *w]))
    dqd_dw = 0.5 * quat_left_matrix(q)[:, 1:4]
    g[1, 0:4] = 2.0 * (M @ qdot) + 2.0 * dqd_dq.T @ Mq
    g[1, 4:7] = 2.0 * dqd_dw.T @ Mq
    return np.array([h, hd]), g


def advance(bvp, y, G, dt, signs, want_jac):
    """One arc of fixed ``signs`` over ``dt`` (nothing if ``dt ≤ 0``): ``(y, G)`` at its end,
    or ``(None, None)`` if it fails."""
    if dt <= 0.0:
        return y, G
    y1, Phi, ok = bvp.arc(y, dt, signs, _EYE if want_jac else None)
    if not ok:
        return None, None
    return y1, (Phi @ G if want_jac else G)


def switch_event(bvp, y, G, signs, a, col, jac_row=None):
    """A switch of axis ``a``: its residual ``S_a``, its Jacobian row into ``jac_row``, the jump
    of ``G`` in the switch's column ``col``; flips ``signs[a]``."""
    res = y[11 + a] / bvp.J[a]
    if jac_row is not None:
        f = ext_rhs(y, bvp.umax * signs, bvp.J)
        jac_row[:] = G[11 + a] / bvp.J[a]
        jac_row[col] += f[11 + a] / bvp.J[a]
        G[4 + a, col] += 2.0 * signs[a] * bvp.umax[a] / bvp.J[a]
    signs[a] = -signs[a]
    return res


def switch_residual(bvp, z, times, T, st, want_jac):
    """``solvers.switch_time._residual`` as a Python loop."""
    n = st.n
    nx = 6 + n + 1
    y, dy0 = bvp.initial(z)
    G = np.zeros((NY, nx))
    G[:, :6] = dy0
    signs = st.signs0.astype(float).copy()
    r = np.empty(1 + n + 6)
    Jm = np.zeros((1 + n + 6, nx)) if want_jac else None
    rp, drp = bvp.param_residual(z)
    r[0] = rp[0]
    if want_jac:
        Jm[0, :6] = drp[0]
    order = np.argsort(times, kind="stable")
    t_prev = 0.0
    for j in list(order) + [-1]:
        t_next = T if j < 0 else float(times[j])
        y, G = advance(bvp, y, G, t_next - t_prev, signs, want_jac)
        if y is None:
            return None, None
        t_prev = max(t_prev, t_next)
        if j < 0:
            break
        r[1 + j] = switch_event(bvp, y, G, signs, int(st.axes[j]), 6 + j, Jm[1 + j] if want_jac else None)
    rt, dry, drT = bvp.terminal(y, T)
    r[1 + n:] = rt
    if want_jac:
        f = ext_rhs(y, bvp.umax * signs, bvp.J)
        G[:, -1] += f
        Jm[1 + n:] = dry @ G
        Jm[1 + n:, -1] += drT
    return r, Jm


def touch_residual(tp, z, times, T, tc, nu, st, want_jac):
    """``solvers.cone_touch._structured_residual`` as a Python loop."""
    bvp, K, n = tp.bvp, tp.K, st.n
    nx = 6 + n + 1 + 2 * K
    c_T, c_tc, c_nu = 6 + n, 7 + n, 7 + n + K
    y, dy0 = bvp.initial(z)
    G = np.zeros((NY, nx))
    G[:, :6] = dy0
    signs = st.signs0.astype(float).copy()
    nr = 1 + n + 2 * K + 6
    r = np.empty(nr)
    Jm = np.zeros((nr, nx)) if want_jac else None
    rp, drp = bvp.param_residual(z)
    r[0] = rp[0]
    if want_jac:
        Jm[0, :6] = drp[0]
    events = sorted([(float(t), 0, j) for j, t in enumerate(times)] + [(float(t), 1, k) for k, t in enumerate(tc)])
    t_prev = 0.0
    for t_next, kind, j in events + [(T, 2, -1)]:
        y, G = advance(bvp, y, G, t_next - t_prev, signs, want_jac)
        if y is None:
            return None, None
        t_prev = max(t_prev, t_next)
        if kind == 2:
            break
        if kind == 0:
            r[1 + j] = switch_event(bvp, y, G, signs, int(st.axes[j]), 6 + j, Jm[1 + j] if want_jac else None)
            continue
        rr, g = _touch_residual(y, tp.M[j], tp.cos_a[j])
        r[1 + n + 2 * j:3 + n + 2 * j] = rr
        if want_jac:
            f = ext_rhs(y, bvp.umax * signs, bvp.J)
            Jm[1 + n + 2 * j:3 + n + 2 * j] = g @ G
            Jm[1 + n + 2 * j:3 + n + 2 * j, c_tc + j] += g @ f
        y, G_plus, Jmap = touch_jump(tp.M[j], nu[j], y, G if want_jac else None, c_nu + j)
        if want_jac:
            G = G_plus
            G[:, c_tc + j] += Jmap @ f - ext_rhs(y, bvp.umax * signs, bvp.J)
    rt, dry, drT = bvp.terminal(y, T)
    r[1 + n + 2 * K:] = rt
    if want_jac:
        f = ext_rhs(y, bvp.umax * signs, bvp.J)
        G[:, c_T] += f
        Jm[1 + n + 2 * K:] = dry @ G
        Jm[1 + n + 2 * K:, c_T] += drT
    return r, Jm
