"""Independent re-propagation of a p-norm extremal (compiled): Dormand–Prince 5(4).

The verification's ``replay`` check for a p-norm bound integrates the state–costate system
from the returned costates with a method other than the solver's DOP853: the 5(4) pair of
Dormand and Prince (the tableau scipy's ``RK45`` uses), with its own error control. The
p-norm control jumps where ``λω`` passes through zero (the symmetric body's eigenaxis slew
reverses its torque at mid-time); the step control finds such a jump by rejecting steps
across it. It replaced scipy's Radau through Python callbacks, which took 0.4 s a check and
90 % of a p-norm solve.
"""
import math

import numpy as np
from numba import njit
from scipy.integrate._ivp.rk import RK45

from .attitude_flow import MODE_PNORM, NY, control, ext_rhs

_A = np.ascontiguousarray(RK45.A)
_B = np.ascontiguousarray(RK45.B)
_E = np.ascontiguousarray(RK45.E)
_NS = 6

# status codes
REPLAY_OK = 0
REPLAY_MAX_STEPS = 1
REPLAY_NONFINITE = 2


@njit(cache=True)
def _pnorm_rhs(y, J, umax, p):
    u, _ = control(y, J, umax, MODE_PNORM, p, 0.0, np.ones(3))
    return ext_rhs(y, u, J)


@njit(cache=True)
def replay_pnorm_end(y0, T, J, umax, p, rtol, atol, max_steps):
    """``(y(T), status, steps)``: the augmented state ``y0`` (NY,) under the p-norm control law
    over ``[0, T]`` (nondimensional), adaptive Dormand–Prince 5(4) at ``rtol``/``atol``; a ``T``
    that is not finite and positive fails (``REPLAY_NONFINITE``) without a step."""
    y = y0.copy()
    if not (T > 0.0 and math.isfinite(T)):
        return y, REPLAY_NONFINITE, 0
    t = 0.0
    f = _pnorm_rhs(y, J, umax, p)
    K = np.empty((_NS + 1, NY))
    h = min(1e-3 * T, T)
    steps = 0
    while t < T:
        if steps >= max_steps:
            return y, REPLAY_MAX_STEPS, steps
        last = t + h >= T
        if last:
            h = T - t
        K[0] = f
        for s in range(1, _NS):
            ys = y.copy()
            for j in range(s):
                a = _A[s, j]
                if a != 0.0:
                    for i in range(NY):
                        ys[i] += h * a * K[j, i]
            K[s] = _pnorm_rhs(ys, J, umax, p)
        y_new = y.copy()
        for j in range(_NS):
            for i in range(NY):
                y_new[i] += h * _B[j] * K[j, i]
        f_new = _pnorm_rhs(y_new, J, umax, p)
        K[_NS] = f_new
        err = 0.0
        finite = True
        for i in range(NY):
            e = 0.0
            for j in range(_NS + 1):
                e += _E[j] * K[j, i]
            sc = atol + rtol * max(abs(y[i]), abs(y_new[i]))
            err += (h * e / sc) ** 2
            if not math.isfinite(y_new[i]):
                finite = False
        steps += 1
        if not finite:
            h *= 0.25
            if h < 1e-15 * T:
                return y, REPLAY_NONFINITE, steps
            continue
        err = math.sqrt(err / NY)
        if err <= 1.0:
            t = T if last else t + h
            y = y_new
            f = f_new
            h *= 10.0 if err == 0.0 else min(10.0, 0.9 * err ** -0.2)
        else:
            h *= max(0.2, 0.9 * err ** -0.2)
            if h < 1e-15 * T:
                return y, REPLAY_NONFINITE, steps
    return y, REPLAY_OK, steps
