"""Compiled flow of the time-optimal attitude extremals (state + costate + sensitivities).

Augmented state ``y = [q (4), ω (3), λq (4), λω (3)]`` (14), in the solver's
nondimensional units (``J`` scaled by ``J_max``, torque by ``u_max``).

Pontryagin for ``H = λqᵀ ½ q⊗[0,ω] + λωᵀ J⁻¹(u + f(ω))``, ``f(ω) = -ω × Jω``::

    λ̇q = ½ λq ⊗ [0, ω]
    λ̇ω = -½ Im(q* ⊗ λq) - (∂f/∂ω)ᵀ J⁻¹ λω

Control laws (``mode``), on ``σ_i = umax_i · (J⁻¹λω)_i``:

* ``MODE_BANG`` (per-axis bound, exact): ``u_i = umax_i · s_i`` with the arc's
  sign vector ``s`` held fixed between switches; a switch is an event
  ``S_i = (J⁻¹λω)_i = 0``, located to ~1e-13 by Newton on the step length,
  after which ``s_i`` flips and the sensitivities get the jump correction
  ``Φ⁺ = Φ⁻ + (f⁻ - f⁺) ∂t_s/∂y0``.
* ``MODE_PNORM`` (``‖u/umax‖_p ≤ 1``): the closed form of seed report eq. 35,
  ``v_i = -sgn σ_i |σ_i|^{1/(p-1)} / (Σ|σ_j|^{p/(p-1)})^{1/p}``.
* ``MODE_TANH`` (smoothing homotopy towards the bang-bang law):
  ``v_i = -tanh(σ_i / ε)``. Never returned as an answer.

The integrator is Dormand–Prince 8(5,3) (the coefficients scipy's DOP853 uses)
with error control on ``y`` only; the sensitivity matrix ``Φ = ∂y/∂(inputs)``
(``m`` columns, ``m`` may be 0) rides along on the same steps.
"""
import math

import numpy as np
from numba import njit
from scipy.integrate._ivp import dop853_coefficients as _dop

from slew_env.core.dynamics import state_rhs_scalar
from .cone_penalty import penalty_jac_into, penalty_rhs_into

NY = 14
MODE_BANG = 0
MODE_PNORM = 1
MODE_TANH = 2

# Flow status codes
FLOW_OK = 0
FLOW_MAX_STEPS = 1
FLOW_STEP_UNDERFLOW = 2
FLOW_NONFINITE = 3
FLOW_TOO_MANY_SWITCHES = 4

_NS = 12
_A = np.ascontiguousarray(_dop.A[:_NS, :_NS])
_B = np.ascontiguousarray(_dop.B)
_C = np.ascontiguousarray(_dop.C[:_NS])
_E3 = np.ascontiguousarray(_dop.E3)
_E5 = np.ascontiguousarray(_dop.E5)


@njit(cache=True)
def control(y, J, umax, mode, p, eps, signs):
    """Torque ``u`` (3,) and ``du/dλω`` (3x3) for the augmented state ``y``."""
    u = np.zeros(3)
    dudl = np.zeros((3, 3))
    if mode == MODE_BANG:
        for i in range(3):
            u[i] = umax[i] * signs[i]
        return u, dudl
    sig = np.empty(3)
    for i in range(3):
        sig[i] = umax[i] * y[11 + i] / J[i]
    dvds = np.zeros((3, 3))
    v = np.zeros(3)
    if mode == MODE_TANH:
        for i in range(3):
            th = np.tanh(sig[i] / eps)
            v[i] = -th
            dvds[i, i] = -(1.0 - th * th) / eps
    else:
        r = 1.0 / (p - 1.0)
        ssum = 0.0
        for i in range(3):
            ssum += abs(sig[i]) ** (r + 1.0)
        if ssum == 0.0:
            return u, dudl
        nrm = ssum ** (1.0 / p)
        a = np.empty(3)
        for i in range(3):
            a[i] = np.sign(sig[i]) * abs(sig[i]) ** r
            v[i] = -a[i] / nrm
        for i in range(3):
            for k in range(3):
                dvds[i, k] = r * a[i] * a[k] / (nrm * ssum)
            if sig[i] != 0.0:
                dvds[i, i] -= r * abs(sig[i]) ** (r - 1.0) / nrm
    for i in range(3):
        u[i] = umax[i] * v[i]
        for k in range(3):
            dudl[i, k] = umax[i] * dvds[i, k] * umax[k] / J[k]
    return u, dudl


@njit(cache=True)
def ext_rhs(y, u, J):
    """Time derivative of the augmented state for a given torque.

    The state part is the shared rigid-body dynamics (``slew_env.core.dynamics``);
    ``λ̇q = ½ λq ⊗ [0, ω]`` is the same right multiplication as ``q̇``.
    """
    f = np.empty(NY)
    ext_rhs_into(y, u[0], u[1], u[2], J, f)
    return f


@njit(cache=True)
def ext_rhs_into(y, u0, u1, u2, J, f):
    """``ext_rhs`` written into ``f`` (no allocation: the integrator's inner loop)."""
    q0, q1, q2, q3 = y[0], y[1], y[2], y[3]
    w0, w1, w2 = y[4], y[5], y[6]
    l0, l1, l2, l3 = y[7], y[8], y[9], y[10]
    c0 = J[2] - J[1]
    c1 = J[0] - J[2]
    c2 = J[1] - J[0]
    f[0], f[1], f[2], f[3], f[4], f[5], f[6] = state_rhs_scalar(
        q0, q1, q2, q3, w0, w1, w2, u0, u1, u2, J[0], J[1], J[2])
    f[7], f[8], f[9], f[10], _, _, _ = state_rhs_scalar(
        l0, l1, l2, l3, w0, w1, w2, 0.0, 0.0, 0.0, J[0], J[1], J[2])
    # Im(q* ⊗ λq) = q0 lv - l0 qv - qv × lv
    im0 = q0 * l1 - l0 * q1 - (q2 * l3 - q3 * l2)
    im1 = q0 * l2 - l0 * q2 - (q3 * l1 - q1 * l3)
    im2 = q0 * l3 - l0 * q3 - (q1 * l2 - q2 * l1)
    a0 = y[11] / J[0]
    a1 = y[12] / J[1]
    a2 = y[13] / J[2]
    # (∂f/∂ω)ᵀ a with f = -ω × Jω
    g0 = -c1 * w2 * a1 - c2 * w1 * a2
    g1 = -c0 * w2 * a0 - c2 * w0 * a2
    g2 = -c0 * w1 * a0 - c1 * w0 * a1
    f[11] = -0.5 * im0 - g0
    f[12] = -0.5 * im1 - g1
    f[13] = -0.5 * im2 - g2


@njit(cache=True)
def ext_jac(y, J, dudl):
    """``∂ẏ/∂y`` (14x14) for a torque whose dependence on λω is ``dudl``."""
    A = np.zeros((NY, NY))
    ext_jac_into(y, J, dudl, A)
    return A


@njit(cache=True)
def ext_jac_into(y, J, dudl, A):
    """``ext_jac`` into ``A``. Writes the same entries on every call, so an ``A`` that
    started as zeros can be reused (the integrator's work array)."""
    q0, q1, q2, q3 = y[0], y[1], y[2], y[3]
    w0, w1, w2 = y[4], y[5], y[6]
    l0, l1, l2, l3 = y[7], y[8], y[9], y[10]
    c0 = J[2] - J[1]
    c1 = J[0] - J[2]
    c2 = J[1] - J[0]
    # right multiplication by [0, ω]: ½ Q̄(w), shared by q̇ and λ̇q
    for off in (0, 7):
        A[off + 0, off + 1] = -0.5 * w0
        A[off + 0, off + 2] = -0.5 * w1
        A[off + 0, off + 3] = -0.5 * w2
        A[off + 1, off + 0] = 0.5 * w0
        A[off + 1, off + 2] = 0.5 * w2
        A[off + 1, off + 3] = -0.5 * w1
        A[off + 2, off + 0] = 0.5 * w1
        A[off + 2, off + 1] = -0.5 * w2
        A[off + 2, off + 3] = 0.5 * w0
        A[off + 3, off + 0] = 0.5 * w2
        A[off + 3, off + 1] = 0.5 * w1
        A[off + 3, off + 2] = -0.5 * w0
    # ∂(½ x ⊗ [0,ω])/∂ω for x = q (rows 0..3) and x = λq (rows 7..10)
    for off, x0, x1, x2, x3 in ((0, q0, q1, q2, q3), (7, l0, l1, l2, l3)):
        A[off + 0, 4] = -0.5 * x1
        A[off + 0, 5] = -0.5 * x2
        A[off + 0, 6] = -0.5 * x3
        A[off + 1, 4] = 0.5 * x0
        A[off + 1, 5] = -0.5 * x3
        A[off + 1, 6] = 0.5 * x2
        A[off + 2, 4] = 0.5 * x3
        A[off + 2, 5] = 0.5 * x0
        A[off + 2, 6] = -0.5 * x1
        A[off + 3, 4] = -0.5 * x2
        A[off + 3, 5] = 0.5 * x1
        A[off + 3, 6] = 0.5 * x0
    # ω̇ = J⁻¹ (u + f(ω))
    A[4, 5] = -c0 * w2 / J[0]
    A[4, 6] = -c0 * w1 / J[0]
    A[5, 4] = -c1 * w2 / J[1]
    A[5, 6] = -c1 * w0 / J[1]
    A[6, 4] = -c2 * w1 / J[2]
    A[6, 5] = -c2 * w0 / J[2]
    for i in range(3):
        for k in range(3):
            A[4 + i, 11 + k] = dudl[i, k] / J[i]
    # λ̇ω = -½ Im(q* ⊗ λq) - (∂f/∂ω)ᵀ J⁻¹ λω
    # ∂Im/∂q0 = lv ; ∂Im/∂qv = -l0 I + [lv]x ; ∂Im/∂l0 = -qv ; ∂Im/∂lv = q0 I - [qv]x
    A[11, 0] = -0.5 * l1
    A[12, 0] = -0.5 * l2
    A[13, 0] = -0.5 * l3
    A[11, 1] = 0.5 * l0
    A[11, 2] = 0.5 * l3
    A[11, 3] = -0.5 * l2
    A[12, 1] = -0.5 * l3
    A[12, 2] = 0.5 * l0
    A[12, 3] = 0.5 * l1
    A[13, 1] = 0.5 * l2
    A[13, 2] = -0.5 * l1
    A[13, 3] = 0.5 * l0
    A[11, 7] = 0.5 * q1
    A[12, 7] = 0.5 * q2
    A[13, 7] = 0.5 * q3
    A[11, 8] = -0.5 * q0
    A[11, 9] = -0.5 * q3
    A[11, 10] = 0.5 * q2
    A[12, 8] = 0.5 * q3
    A[12, 9] = -0.5 * q0
    A[12, 10] = -0.5 * q1
    A[13, 8] = -0.5 * q2
    A[13, 9] = 0.5 * q1
    A[13, 10] = -0.5 * q0
    a0 = y[11] / J[0]
    a1 = y[12] / J[1]
    a2 = y[13] / J[2]
    A[11, 5] = c2 * a2
    A[11, 6] = c1 * a1
    A[12, 4] = c2 * a2
    A[12, 6] = c0 * a0
    A[13, 4] = c1 * a1
    A[13, 5] = c0 * a0
    # -(∂f/∂ω)ᵀ J⁻¹ : (∂f/∂ω)[i,k] from f0=-c0 w1 w2, f1=-c1 w2 w0, f2=-c2 w0 w1
    A[11, 12] = c1 * w2 / J[1]
    A[11, 13] = c2 * w1 / J[2]
    A[12, 11] = c0 * w2 / J[0]
    A[12, 13] = c2 * w0 / J[2]
    A[13, 11] = c0 * w1 / J[0]
    A[13, 12] = c1 * w0 / J[1]


@njit(cache=True)
def sensitivity_rate_into(A, Y, n, m, out):
    """``Φ̇ = A Φ`` for the ``n × m`` sensitivity block stored row-major after the ``n`` state
    components of ``Y``, written at the same place in ``out``. ``A`` (at least ``n × n``) is
    about half zeros, which are skipped; a BLAS call costs more than it saves at this size."""
    for i in range(n):
        base = n + i * m
        for c in range(m):
            out[base + c] = 0.0
        for k in range(n):
            a = A[i, k]
            if a != 0.0:
                kb = n + k * m
                for c in range(m):
                    out[base + c] += a * Y[kb + c]


@njit(cache=True)
def full_rhs_into(Y, m, J, umax, mode, p, eps, signs, pen, out, A):
    """Derivative of ``[y, Φ]`` (Φ row-major 14 x m), written into ``out``; ``A`` is a
    14x14 work array that started as zeros (see ``ext_jac_into``). ``pen`` is a packed
    keep-out-cone penalty (``cone_penalty.pack``; empty: none)."""
    y = Y[:NY]
    if mode == MODE_BANG and m == 0:   # a bang-bang arc without sensitivities: no allocation
        ext_rhs_into(y, umax[0] * signs[0], umax[1] * signs[1], umax[2] * signs[2], J, out)
        if pen.shape[0] > 0:
            penalty_rhs_into(y, pen, out)
        return
    u, dudl = control(y, J, umax, mode, p, eps, signs)
    ext_rhs_into(y, u[0], u[1], u[2], J, out)
    if pen.shape[0] > 0:
        penalty_rhs_into(y, pen, out)
    if m > 0:
        ext_jac_into(y, J, dudl, A)
        if pen.shape[0] > 0:
            penalty_jac_into(y, pen, A)
        sensitivity_rate_into(A, Y, NY, m, out)


@njit(cache=True)
def full_rhs(Y, m, J, umax, mode, p, eps, signs, pen):
    """Derivative of ``[y, Φ]`` (Φ row-major 14 x m)."""
    out = np.empty(NY + NY * m)
    full_rhs_into(Y, m, J, umax, mode, p, eps, signs, pen, out, np.zeros((NY, NY)))
    return out


@njit(cache=True)
def dop853_stage_input(Y, K, s, h, Ys):
    """``Ys = Y + h Σ_j A[s, j] K[j]``: the input of stage ``s`` (``K`` holds the stages before)."""
    for i in range(Y.shape[0]):
        acc = 0.0
        for j in range(s):
            a = _A[s, j]
            if a != 0.0:
                acc += a * K[j, i]
        Ys[i] = Y[i] + h * acc


@njit(cache=True)
def dop853_solution(Y, K, h):
    """The 8th-order solution ``Y + h Σ_j B[j] K[j]`` of a step with the stages ``K``."""
    Ynew = np.empty(Y.shape[0])
    for i in range(Y.shape[0]):
        acc = 0.0
        for j in range(_NS):
            acc += _B[j] * K[j, i]
        Ynew[i] = Y[i] + h * acc
    return Ynew


@njit(cache=True)
def _dop853_step(Y, h, m, J, umax, mode, p, eps, signs, pen, K0):
    """One DOP853 step; returns ``(Y_new, K)`` with the 13 stage derivatives in ``K``."""
    n = Y.shape[0]
    K = np.empty((13, n))
    Ys = np.empty(n)
    A = np.zeros((NY, NY))
    K[0] = K0
    for s in range(1, _NS):
        dop853_stage_input(Y, K, s, h, Ys)
        full_rhs_into(Ys, m, J, umax, mode, p, eps, signs, pen, K[s], A)
    Ynew = dop853_solution(Y, K, h)
    full_rhs_into(Ynew, m, J, umax, mode, p, eps, signs, pen, K[12], A)
    return Ynew, K


@njit(cache=True)
def err_norm(Y, Ynew, K, h, rtol, atol, n):
    """DOP853's error norm over the first ``n`` components, normalised by ``NY``: the augmented
    state's (``n = NY``), or the state's alone (``n = 7``), which is the augmented state's when
    its costates are zero (their error terms vanish)."""
    e5 = 0.0
    e3 = 0.0
    for i in range(n):
        sc = atol + rtol * max(abs(Y[i]), abs(Ynew[i]))
        a5 = 0.0
        a3 = 0.0
        for j in range(13):
            a5 += _E5[j] * K[j, i]
            a3 += _E3[j] * K[j, i]
        e5 += (a5 / sc) ** 2
        e3 += (a3 / sc) ** 2
    if e5 == 0.0 and e3 == 0.0:
        return 0.0
    den = e5 + 0.01 * e3
    return abs(h) * e5 / np.sqrt(den * NY)


@njit(cache=True)
def switching(Y, J):
    return Y[11:14] / J


@njit(cache=True)
def flow(Y0, tf, m, J, umax, mode, p, eps, signs0, rtol, atol, h0, max_steps, max_switches,
         rec_t, rec_Y, rec_signs, sw_t, sw_axis, pen, detect=True, hmax=np.inf):
    """Integrate ``[y, Φ]`` from t=0 to ``tf`` (> 0).

    ``signs0`` is the bang-bang sign vector of the first arc (ignored by the
    smooth modes). Accepted step ends and both sides of every switch are written
    to ``rec_t`` / ``rec_Y`` / ``rec_signs`` while room remains. Switch instants
    and axes go to ``sw_t`` / ``sw_axis``. With ``detect=False`` the bang-bang
    signs stay fixed over the whole interval (one arc of a fixed switching
    structure). ``hmax`` caps the step (dense recording).

    Returns ``(Y(tf), signs at tf, n_rec, n_switches, n_steps, status)``.
    """
    Y = Y0.copy()
    signs = signs0.copy()
    t = 0.0
    K0 = full_rhs(Y, m, J, umax, mode, p, eps, signs, pen)
    h = min(h0, tf)
    n_rec = 0
    cap = rec_t.shape[0]
    if cap > 0:
        rec_t[0] = 0.0
        rec_Y[0] = Y[:NY]
        rec_signs[0] = signs
        n_rec = 1
    n_sw = 0
    steps = 0
    status = FLOW_OK
    while t < tf:
        if steps >= max_steps:
            status = FLOW_MAX_STEPS
            break
        last = False
        if h > hmax:
            h = hmax
        if t + h >= tf:
            h = tf - t
            last = True
        if h < 1e-14 * max(1.0, tf):
            if last:
                break
            status = FLOW_STEP_UNDERFLOW
            break
        Ynew, K = _dop853_step(Y, h, m, J, umax, mode, p, eps, signs, pen, K0)
        steps += 1
        err = err_norm(Y, Ynew, K, h, rtol, atol, NY)
        if not (err == err) or not np.isfinite(Ynew[0]):
            h *= 0.25
            if h < 1e-14:
                status = FLOW_NONFINITE
                break
            continue
        if err > 1.0:
            h *= max(0.2, 0.9 * err ** (-1.0 / 8.0))
            continue
        # event check: the arc's sign must stay consistent with u = -umax sign(S)
        if mode == MODE_BANG and detect:
            first_tau = h
            first_ax = -1
            for i in range(3):
                if signs[i] * (Ynew[11 + i] / J[i]) > 0.0:
                    tau = _locate_switch(Y, h, m, J, umax, signs, pen, K0, i)
                    if tau < first_tau:
                        first_tau = tau
                        first_ax = i
                else:
                    # two crossings inside one step (a short pulse) leave the end sign right:
                    # look for them on the Hermite cubic of S_i over the step
                    tc = _hidden_crossing(Y, Ynew, K0, K[12], h, J, umax, signs, pen, i)
                    if tc > 0.0:
                        tau = _locate_switch(Y, tc, m, J, umax, signs, pen, K0, i)
                        if tau < first_tau:
                            first_tau = tau
                            first_ax = i
            if first_ax >= 0:
                if first_tau < h:
                    Ynew, K = _dop853_step(Y, first_tau, m, J, umax, mode, p, eps, signs, pen, K0)
                t += first_tau
                Y = Ynew
                if cap > 0 and n_rec < cap:
                    rec_t[n_rec] = t
                    rec_Y[n_rec] = Y[:NY]
                    rec_signs[n_rec] = signs
                    n_rec += 1
                # sensitivity jump: Φ⁺ = Φ⁻ + (f⁻ - f⁺) ∂ts/∂y0, ∂ts = -∇S·Φ⁻ / Ṡ
                if m > 0:
                    k = first_ax
                    ldot = K[12][11 + k]  # λ̇ω_k is the same on both sides
                    if ldot != 0.0:
                        jump = 2.0 * signs[k] * umax[k] / J[k]
                        for c in range(m):
                            dts = -Y[NY + (11 + k) * m + c] / ldot
                            Y[NY + (4 + k) * m + c] += jump * dts
                if n_sw < sw_t.shape[0]:
                    sw_t[n_sw] = t
                    sw_axis[n_sw] = first_ax
                n_sw += 1
                signs[first_ax] = -signs[first_ax]
                if n_sw > max_switches:
                    status = FLOW_TOO_MANY_SWITCHES
                    break
                K0 = full_rhs(Y, m, J, umax, mode, p, eps, signs, pen)
                if cap > 0 and n_rec < cap:
                    rec_t[n_rec] = t
                    rec_Y[n_rec] = Y[:NY]
                    rec_signs[n_rec] = signs
                    n_rec += 1
                continue
        t = tf if last else t + h
        Y = Ynew
        K0 = K[12]
        if cap > 0 and n_rec < cap:
            rec_t[n_rec] = t
            rec_Y[n_rec] = Y[:NY]
            rec_signs[n_rec] = signs
            n_rec += 1
        fac = 0.9 * err ** (-1.0 / 8.0) if err > 0.0 else 10.0
        h *= min(10.0, max(0.2, fac))
    return Y, signs, n_rec, n_sw, steps, status


@njit(cache=True)
def _hidden_crossing(Y, Ynew, K0, K1, h, J, umax, signs, pen, axis):
    """A step length ``τ`` in (0, h) at which ``S_axis`` has the wrong sign for the arc
    (``signs·S > 0``) although both ends of the step have the right one, or 0.

    Candidates are the extrema of the cubic Hermite interpolant of ``S_axis`` (values and
    derivatives at both ends); a candidate counts only if an exact DOP853 step to it confirms
    the wrong sign, so a crossing pair is never invented by the interpolant."""
    sg = signs[axis]
    s0 = sg * Y[11 + axis] / J[axis]
    s1 = sg * Ynew[11 + axis] / J[axis]
    d0 = sg * K0[11 + axis] / J[axis] * h
    d1 = sg * K1[11 + axis] / J[axis] * h
    # σS(θ) on θ ∈ [0, 1]: a θ³ + b θ² + d0 θ + s0
    a = 2.0 * s0 + d0 - 2.0 * s1 + d1
    b = -3.0 * s0 - 2.0 * d0 + 3.0 * s1 - d1
    scale = max(max(abs(s0), abs(s1)), max(abs(d0), abs(d1)))
    if not (s1 < 0.0):
        return 0.0
    if not (s0 < -1e-10 * scale):
        # the step starts on a switch (S ≈ 0 to rounding): S must leave zero to the arc's side
        # (else the crossing at the start is the switch just taken); a pulse is then a maximum
        # of the cubic after its first minimum, which the maxima-only search below finds
        if not (d0 < 0.0):
            return 0.0
    # maxima of σS on (0, 1): roots of 3a θ² + 2b θ + d0 with 6a θ + 2b < 0 (stable formula:
    # when S is nearly a parabola over the step, a is rounding noise)
    A = 3.0 * a
    B = 2.0 * b
    C = d0
    roots = np.empty(2)
    nr = 0
    if abs(A) <= 1e-12 * abs(B):
        if B != 0.0:
            roots[0] = -C / B
            nr = 1
    else:
        disc = B * B - 4.0 * A * C
        if disc >= 0.0:
            qq = -0.5 * (B + math.copysign(math.sqrt(disc), B))
            if qq != 0.0:
                roots[0] = qq / A
                roots[1] = C / qq
                nr = 2
            else:
                roots[0] = 0.0
                nr = 1
    best = 0.0
    best_v = 1e-12 * scale
    for k in range(nr):
        th = roots[k]
        if th > 0.0 and th < 1.0 and 3.0 * a * th + b < 0.0:
            v = ((a * th + b) * th + d0) * th + s0
            if v > best_v:
                best_v = v
                best = th
    if best == 0.0:
        return 0.0
    Yc = Y[:NY].copy()
    Yt, Kt = _dop853_step(Yc, best * h, 0, J, umax, MODE_BANG, 0.0, 1.0, signs, pen, K0[:NY].copy())
    if sg * Yt[11 + axis] / J[axis] > 1e-13 * scale:   # not a graze at rounding level
        return best * h
    return 0.0


@njit(cache=True)
def _locate_switch(Y, h, m, J, umax, signs, pen, K0, axis):
    """Step length τ in (0, h] at which ``S_axis`` crosses zero (Newton, bracketed).

    Each evaluation is one exact DOP853 step of length τ from the step start
    (without sensitivities), so the root is as accurate as the integrator.
    """
    Yc = Y[:NY].copy()
    K0c = K0[:NY].copy()
    lo = 0.0
    hi = h
    s_lo = Yc[11 + axis] / J[axis]
    tau = h * 0.5
    # secant start from the end points
    Yh, Kh = _dop853_step(Yc, h, 0, J, umax, MODE_BANG, 0.0, 1.0, signs, pen, K0c)
    s_hi = Yh[11 + axis] / J[axis]
    sg = signs[axis]
    if not (sg * s_lo < -1e-10 * abs(s_hi)):
        # the step starts on a switch (S ≈ 0 to rounding): the crossing wanted is the next one,
        # so the bracket starts where S is clearly on the arc's side
        th = 0.5 * h
        for _ in range(40):
            Yt, Kt = _dop853_step(Yc, th, 0, J, umax, MODE_BANG, 0.0, 1.0, signs, pen, K0c)
            st = Yt[11 + axis] / J[axis]
            if sg * st < 0.0:
                lo = th
                s_lo = st
                break
            hi = th
            s_hi = st
            th *= 0.5
    if s_hi != s_lo:
        tau = lo + (hi - lo) * s_lo / (s_lo - s_hi)
    if not (tau > lo and tau < hi):
        tau = 0.5 * (lo + hi)
    for it in range(60):
        Yt, Kt = _dop853_step(Yc, tau, 0, J, umax, MODE_BANG, 0.0, 1.0, signs, pen, K0c)
        s = Yt[11 + axis] / J[axis]
        sd = Kt[12][11 + axis] / J[axis]
        if (s > 0.0) == (s_lo > 0.0):
            lo = tau
        else:
            hi = tau
        if abs(s) < 1e-15 or hi - lo < 1e-15 * max(1.0, h):
            break
        new = tau - s / sd if sd != 0.0 else 0.5 * (lo + hi)
        if not (new > lo and new < hi):
            new = 0.5 * (lo + hi)
        if abs(new - tau) < 1e-16 * max(1.0, h):
            tau = new
            break
        tau = new
    return tau


@njit(cache=True)
def hamiltonian(y, J, umax, mode, p, eps, signs):
    """``H`` without the ``λ0`` term: ``λqᵀ q̇ + λωᵀ ω̇``."""
    u, _ = control(y, J, umax, mode, p, eps, signs)
    f = ext_rhs(y, u, J)
    h = 0.0
    for i in range(7):
        h += y[7 + i] * f[i]
    return h


@njit(cache=True)
def hamiltonian_batch(Y, J, umax, mode, p, eps, S):
    """``hamiltonian`` at every row of the recorded states ``Y`` with signs ``S``."""
    n = Y.shape[0]
    out = np.empty(n)
    for k in range(n):
        out[k] = hamiltonian(Y[k], J, umax, mode, p, eps, S[k])
    return out


@njit(cache=True)
def control_batch(Y, J, umax, mode, p, eps, S):
    """``control`` (the torque only) at every row of ``Y`` with signs ``S``."""
    n = Y.shape[0]
    out = np.empty((n, 3))
    for k in range(n):
        u, _ = control(Y[k], J, umax, mode, p, eps, S[k])
        out[k] = u
    return out
