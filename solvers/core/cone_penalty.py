"""Compiled exterior penalty of keep-out cones, for the costate equations of the flow.

A cone ``k`` (inertial unit axis ``a``, half-angle ``α``) keeps the sensor (body unit
vector ``s``) out: ``a · R(q) s ≤ cos α``. For a unit quaternion that product is a
quadratic form, ``a · R(q) s = qᵀ M q`` with the symmetric 4x4::

    M₀₀ = a·s,   M₀ⱼ = Mⱼ₀ = (s × a)ⱼ,   M_vv = a sᵀ + s aᵀ - (a·s) I₃

(from ``R(q)s = (q₀² - v·v) s + 2 v (v·s) + 2 q₀ v × s``). The running cost adds
``P(q) = ½ w Σₖ max(0, hₖ)²`` with ``hₖ = qᵀMₖq - bₖ`` and ``bₖ = cos αₖ - δₖ`` (``δₖ`` a
back-off in cosine units that keeps the penalised path, which enters the penalty zone
by about ``η / w``, outside the true cone). With ``λ0 = 1`` Pontryagin gives::

    λ̇q += -∂P/∂q = -2 w Σₖ hₖ⁺ Mₖ q,
    ∂(λ̇q)/∂q  = -2 w Σₖ [hₖ⁺ Mₖ + 2 [hₖ > 0] (Mₖq)(Mₖq)ᵀ]

(a C¹ right-hand side: the variational equations need no jump correction). Packed form
(``pack``): ``[w, n, (M row-major 16, b) × n]``; an empty array means no penalty.
"""
import numpy as np
from numba import njit

_STRIDE = 17


def cone_matrix(a, s):
    """``M`` with ``qᵀ M q = a · R(q) s`` for unit ``q`` (inertial ``a``, body ``s``)."""
    a = np.asarray(a, float)
    s = np.asarray(s, float)
    M = np.empty((4, 4))
    M[0, 0] = a @ s
    c = np.cross(s, a)
    M[0, 1:] = c
    M[1:, 0] = c
    M[1:, 1:] = np.outer(a, s) + np.outer(s, a) - (a @ s) * np.eye(3)
    return M


def pack(cones, sensor, weight, backoff):
    """Packed penalty for ``cones`` (objects with unit ``axis`` and ``half_angle``) on the
    body ``sensor``; ``backoff`` (cosine units, scalar or one per cone)."""
    n = len(cones)
    back = np.broadcast_to(np.asarray(backoff, float), (n,))
    out = np.empty(2 + _STRIDE * n)
    out[0] = float(weight)
    out[1] = float(n)
    for k, c in enumerate(cones):
        a = np.asarray(c.axis, float)
        a = a / np.linalg.norm(a)
        o = 2 + _STRIDE * k
        out[o:o + 16] = cone_matrix(a, sensor).ravel()
        out[o + 16] = np.cos(c.half_angle) - back[k]
    return out


@njit(cache=True)
def _excess(y, pen, o, Mq):
    """``h = qᵀMq - b`` of the cone packed at offset ``o``; ``Mq`` is written."""
    h = 0.0
    for i in range(4):
        acc = 0.0
        for j in range(4):
            acc += pen[o + 4 * i + j] * y[j]
        Mq[i] = acc
        h += y[i] * acc
    return h - pen[o + 16]


@njit(cache=True)
def penalty_value(y, pen):
    """``P(q)`` for the augmented state ``y``."""
    if pen.shape[0] == 0:
        return 0.0
    w = pen[0]
    Mq = np.empty(4)
    total = 0.0
    for k in range(int(pen[1])):
        h = _excess(y, pen, 2 + _STRIDE * k, Mq)
        if h > 0.0:
            total += 0.5 * w * h * h
    return total


@njit(cache=True)
def penalty_rhs_into(y, pen, f):
    """Add ``-∂P/∂q`` to ``λ̇q`` (``f[7:11]``)."""
    w = pen[0]
    Mq = np.empty(4)
    for k in range(int(pen[1])):
        h = _excess(y, pen, 2 + _STRIDE * k, Mq)
        if h > 0.0:
            for i in range(4):
                f[7 + i] -= 2.0 * w * h * Mq[i]


@njit(cache=True)
def penalty_jac_into(y, pen, A):
    """Set the block ``∂(λ̇q)/∂q`` of ``A`` (rows 7..10, columns 0..3).

    Assigned, not added: ``A`` is reused between calls, and no other term of the flow
    writes this block.
    """
    w = pen[0]
    Mq = np.empty(4)
    for i in range(4):
        for j in range(4):
            A[7 + i, j] = 0.0
    for k in range(int(pen[1])):
        o = 2 + _STRIDE * k
        h = _excess(y, pen, o, Mq)
        if h > 0.0:
            for i in range(4):
                for j in range(4):
                    A[7 + i, j] -= 2.0 * w * (h * pen[o + 4 * i + j] + 2.0 * Mq[i] * Mq[j])


@njit(cache=True)
def sampled_margins(X, dX, Ms, half):
    """Clearance margins ``θ - α`` (rad; ``cos θ = qᵀMq / |q|²``) of each cone ``k`` (``Ms[k]``,
    ``half[k]``) at each sampled state ``X[m]`` (7: ``q`` first), and their gradients in the
    unknowns through ``dX[m] = ∂x/∂v`` (7, nv): ``(g (M·K,), Jg (M·K, nv))``, row ``m·K + k``."""
    M = X.shape[0]
    K = Ms.shape[0]
    nv = dX.shape[2]
    g = np.empty(M * K)
    Jg = np.zeros((M * K, nv))
    for m in range(M):
        q = X[m, 0:4]
        qq = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
        for k in range(K):
            Mq = Ms[k] @ q
            c = (q[0] * Mq[0] + q[1] * Mq[1] + q[2] * Mq[2] + q[3] * Mq[3]) / qq
            c = min(1.0, max(-1.0, c))
            s = max(np.sqrt(1.0 - c * c), 1e-12)
            row = m * K + k
            g[row] = np.arccos(c) - half[k]
            # ∂θ/∂q = -∂c/∂q / sin θ, ∂c/∂q = 2 (Mq - c q) / |q|²
            for j in range(4):
                dj = -2.0 * (Mq[j] - c * q[j]) / (qq * s)
                for col in range(nv):
                    Jg[row, col] += dj * dX[m, j, col]
    return g, Jg
