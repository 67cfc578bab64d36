"""Compiled arc of the rigid-body state alone under a fixed torque, with its 7×7 transition matrix.

A bang-bang control given by its switch instants needs no costates: between switches the torque
is a constant, and the state ``x = [q, ω]`` (7) flows on its own. ``attitude_flow.flow`` carries
the 14-dimensional augmented state and a 14-row sensitivity block; when the costates are zero
and no cone penalty acts they stay zero, so half of that work is spent on zeros. This arc
integrates the 7 state components and, if asked, ``Φ = ∂x(dt)/∂x(0)`` (7×7), with the same
Dormand–Prince 8(5,3) steps: the error norm is the augmented flow's with zero costates (their
terms vanish, the normalisation by 14 stays), so both take the same steps and give the same
states, at about half the cost with the transition matrix. (With ``atol = 0``, which no caller
uses, the augmented flow's zero costates make its norm 0/0 and it fails, where this one does not.)
"""
import numpy as np
from numba import njit

from slew_env.core.dynamics import state_rhs_scalar
from .attitude_flow import (NY, _NS, dop853_solution, dop853_stage_input, err_norm, ext_jac_into,
                            sensitivity_rate_into)

NX = 7


@njit(cache=True)
def _rhs_into(Y, m, u, J, out, A, y, dz):
    """Derivative of ``[x, Φ]`` (Φ row-major 7 × m) under the torque ``u``, written into ``out``.
    Work arrays, all zeros on the first call: ``A`` (14×14; its state block is ``∂ẋ/∂x``),
    ``y`` (14: the augmented state with zero costates) and ``dz`` (3×3: a torque that does not
    depend on the costates)."""
    out[0], out[1], out[2], out[3], out[4], out[5], out[6] = state_rhs_scalar(
        Y[0], Y[1], Y[2], Y[3], Y[4], Y[5], Y[6], u[0], u[1], u[2], J[0], J[1], J[2])
    if m == 0:
        return
    for i in range(NX):
        y[i] = Y[i]
    ext_jac_into(y, J, dz, A)
    sensitivity_rate_into(A, Y, NX, m, out)


@njit(cache=True)
def _step(Y, h, m, u, J, K0, A, y, dz):
    """One DOP853 step; returns ``(Y_new, K)`` with the 13 stage derivatives in ``K``."""
    n = Y.shape[0]
    K = np.empty((13, n))
    Ys = np.empty(n)
    K[0] = K0
    for s in range(1, _NS):
        dop853_stage_input(Y, K, s, h, Ys)
        _rhs_into(Ys, m, u, J, K[s], A, y, dz)
    Ynew = dop853_solution(Y, K, h)
    _rhs_into(Ynew, m, u, J, K[12], A, y, dz)
    return Ynew, K


@njit(cache=True)
def state_arc(x0, dt, u, J, rtol, atol, want_phi, steps_left=None):
    """The state ``x0`` (7) flown over ``dt`` (> 0) under the constant torque ``u`` (3), with
    ``Φ`` (7×7; zeros without ``want_phi``). Steps as ``attitude_flow.flow`` with
    ``h0 = min(0.05, dt)`` and at most 200,000 steps, and at most ``steps_left[0]`` (a 1-element
    int64 array, decremented by the steps taken; ``None``: no such bound). Returns
    ``(x(dt), Φ, ok)``; ``ok`` is False if the steps run out or underflow or the result is not
    finite."""
    cap = 200000 if steps_left is None else min(200000, steps_left[0])
    m = NX if want_phi else 0
    Y = np.zeros(NX + NX * m)
    Y[:NX] = x0[:NX]
    for c in range(m):
        Y[NX + c * m + c] = 1.0
    A = np.zeros((NY, NY))
    y = np.zeros(NY)
    dz = np.zeros((3, 3))
    K0 = np.empty(Y.shape[0])
    _rhs_into(Y, m, u, J, K0, A, y, dz)
    t = 0.0
    h = min(0.05, dt)
    steps = 0
    ok = True
    while t < dt:
        if steps >= cap:
            ok = False
            break
        last = False
        if t + h >= dt:
            h = dt - t
            last = True
        if h < 1e-14 * max(1.0, dt):
            if not last:
                ok = False
            break
        Ynew, K = _step(Y, h, m, u, J, K0, A, y, dz)
        steps += 1
        err = err_norm(Y, Ynew, K, h, rtol, atol, NX)
        if not (err == err) or not np.isfinite(Ynew[0]):
            h *= 0.25
            if h < 1e-14:
                ok = False
                break
            continue
        if err > 1.0:
            h *= max(0.2, 0.9 * err ** (-1.0 / 8.0))
            continue
        t = dt if last else t + h
        Y = Ynew
        K0 = K[12]
        fac = 0.9 * err ** (-1.0 / 8.0) if err > 0.0 else 10.0
        h *= min(10.0, max(0.2, fac))
    if steps_left is not None:
        steps_left[0] -= steps
    Phi = np.zeros((NX, NX))
    for i in range(m):
        for c in range(m):
            Phi[i, c] = Y[NX + i * m + c]
    for i in range(Y.shape[0]):
        if not np.isfinite(Y[i]):
            ok = False
    return Y[:NX].copy(), Phi, ok
