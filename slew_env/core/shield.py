"""Compiled keep-out-cone safety filter on the environment's observation.

The filter changes an action only as much as needed to keep the sensor out of every
cone, using nothing but the observation of ``env_kernels`` (so a policy that sees
the observation can carry the filter with it on board). It is a control barrier
function with a braking term, on the nondimensional dynamics of the observation
(time unit ``T``, rates ``ω̃ = ω·T``, inertia ``J̃ = J/J_max``, torque ``ũ = u/max u_max``):

    dω̃/dτ = J̃⁻¹ (ũ − ω̃ × J̃ ω̃),   ũ_i = ũ_max,i · v_i,   v the normalised action.

For a cone with body-frame axis ``c`` and half-angle ``α``, and the sensor ``b``,
``h = cos(α + δ) − b·c`` is ≥ 0 outside the cone enlarged by the margin ``δ``.
In the body frame ``ċ = c × ω``, so

    ḣ = −ω̃·(b × c),    ḧ = G·v + a₀,   G = −ũ_max ⊙ J̃⁻¹(b × c),
    a₀ = (b × c)·J̃⁻¹(ω̃ × J̃ω̃) − ω̃·(b × (c × ω̃)).

``h`` has relative degree two, and the torque is bounded, so a plain exponential
barrier can ask for more deceleration than the actuators have. The filter keeps
instead ``h_b = h − max(0, −ḣ)² / (2β)`` ≥ 0: the margin left after braking at ``β``,
a fraction ``brake`` of the largest ``G·v`` the box allows. Its condition
``ḣ_b + λ h_b ≥ 0`` is linear in ``v``. When the sensor does not approach the cone
the classical second-order condition ``ḧ + 2λḣ + λ²h ≥ 0`` is used instead.

The action kept is the point of the box closest to the policy's action that meets
every cone's condition: a small quadratic programme solved in its dual by cyclic
bisection on the multipliers (``v(μ) = clip(v_nom + Σ μ_k G_k)``). Where the box
cannot meet a condition (the policy drove in too fast), the largest multiplier is
used: the strongest push away the box allows. The conditions are checked on the
action as the environment flies it (for a p-norm bound, scaled onto the p-ball); a
filtered action lies in the cube inscribed in the p-ball, so the environment's
scaling never applies to it. An action that meets every condition is returned as
the environment would fly it (for actions inside the bound: unchanged).

Where two cones nearly meet (a narrow gap, or the sharp notch where two overlapping cones
cross), the free region narrows to a tip no action can hold: the two conditions point
nearly opposite ways and the box cannot meet both. Such tips are filled by virtual cones,
bridges (``pair_bridges``), held like the others.

The conditions hold in continuous time and are checked at control instants, with
the torque held over the step; the margin absorbs what happens in between. The
defaults (margin 0.5°, λ = 20) were tuned for the environment's control step of
0.05 T. At 0.1 T a PD law through the filter entered a cone on 19 of 100 tasks with the
defaults, on none with a 1° margin and ``brake`` 0.3; at 0.2 T on 23–29 with every setting
tried.
"""
import math

import numpy as np
from numba import njit

from . import env_kernels as _k

# params layout
P_MARGIN = 0       # δ: margin added to every cone (rad)
P_LAMBDA = 1       # λ: barrier rate (per time unit T)
P_BRAKE = 2        # β as a fraction of the box's largest G·v
P_SWEEPS = 3       # dual sweeps over the cones
P_GAP = 4          # gaps between two cones narrower than this (rad) are closed by a bridge
PARAMS_LENGTH = 5

# out layout (diagnostics of the last call)
F_ACTIVE = 0       # number of cone conditions that changed the action
F_FEASIBLE = 1     # 1 if every condition is met by the returned action
F_MIN_SLACK = 2    # smallest G·v − d over the cones considered (inf if none)
OUT_LENGTH = 3

MAX_CONES = 16
_MU_MAX = 1e6
_BISECT = 40


def make_params(margin_rad, barrier_rate, brake, sweeps, gap_rad=0.0):
    p = np.zeros(PARAMS_LENGTH)
    p[P_GAP] = gap_rad
    p[P_MARGIN] = margin_rad
    p[P_LAMBDA] = barrier_rate
    p[P_BRAKE] = brake
    p[P_SWEEPS] = sweeps
    return p


@njit(cache=True)
def _clip_box(x, s):
    if x > s:
        return s
    if x < -s:
        return -s
    return x


@njit(cache=True)
def _v_of(vnom, G, mu, n, s, v):
    for i in range(3):
        acc = vnom[i]
        for k in range(n):
            acc += mu[k] * G[k, i]
        v[i] = _clip_box(acc, s)


@njit(cache=True)
def _dot_row(G, k, v):
    return G[k, 0] * v[0] + G[k, 1] * v[1] + G[k, 2] * v[2]


@njit(cache=True)
def cone_barrier_terms(obs, k, delta):
    """``(h, ḣ, G0, G1, G2, a0)`` of cone slot ``k`` enlarged by ``delta``: ``ḧ = G·v + a0``."""
    o = _k.OB_CONES + _k.OB_CONE_STRIDE * k
    return axis_barrier_terms(obs, obs[o], obs[o + 1], obs[o + 2], obs[o + 3], delta)


@njit(cache=True)
def axis_barrier_terms(obs, c0, c1, c2, alpha, delta):
    """``cone_barrier_terms`` of the cone of body-frame axis ``c`` and half-angle ``alpha``."""
    b0 = obs[_k.OB_SENSOR]; b1 = obs[_k.OB_SENSOR + 1]; b2 = obs[_k.OB_SENSOR + 2]
    w0 = obs[_k.OB_W]; w1 = obs[_k.OB_W + 1]; w2 = obs[_k.OB_W + 2]
    J0 = obs[_k.OB_J]; J1 = obs[_k.OB_J + 1]; J2 = obs[_k.OB_J + 2]
    # gyroscopic term J̃⁻¹(ω̃ × J̃ω̃)
    Jw0 = J0 * w0; Jw1 = J1 * w1; Jw2 = J2 * w2
    g0 = (w1 * Jw2 - w2 * Jw1) / J0
    g1 = (w2 * Jw0 - w0 * Jw2) / J1
    g2 = (w0 * Jw1 - w1 * Jw0) / J2
    p = b0 * c0 + b1 * c1 + b2 * c2
    h = math.cos(min(alpha + delta, math.pi)) - p
    x0 = b1 * c2 - b2 * c1        # b × c
    x1 = b2 * c0 - b0 * c2
    x2 = b0 * c1 - b1 * c0
    hd = -(w0 * x0 + w1 * x1 + w2 * x2)
    y0 = c1 * w2 - c2 * w1         # c × ω
    y1 = c2 * w0 - c0 * w2
    y2 = c0 * w1 - c1 * w0
    z0 = b1 * y2 - b2 * y1         # b × (c × ω)
    z1 = b2 * y0 - b0 * y2
    z2 = b0 * y1 - b1 * y0
    a0 = x0 * g0 + x1 * g1 + x2 * g2 - (w0 * z0 + w1 * z1 + w2 * z2)
    G0 = -obs[_k.OB_UMAX] * x0 / J0
    G1 = -obs[_k.OB_UMAX + 1] * x1 / J1
    G2 = -obs[_k.OB_UMAX + 2] * x2 / J2
    return h, hd, G0, G1, G2, a0


@njit(cache=True)
def _bridge_fits(obs, m0, m1, m2, r, gap, B, n):
    """Append the bridge (axis ``m``, radius ``r``) to ``B`` unless it would hold the target
    (``r`` shrinks to keep it out; dropped if that leaves it narrower than ``gap``) or the
    sensor is already in it; returns the new count."""
    tm = _k._angle(obs[_k.OB_TARGET], obs[_k.OB_TARGET + 1], obs[_k.OB_TARGET + 2], m0, m1, m2)
    r = min(r, tm - gap)
    if r < gap:
        return n
    bm = _k._angle(obs[_k.OB_SENSOR], obs[_k.OB_SENSOR + 1], obs[_k.OB_SENSOR + 2], m0, m1, m2)
    if bm <= r:
        return n
    B[n, 0] = m0; B[n, 1] = m1; B[n, 2] = m2; B[n, 3] = r
    return n + 1


@njit(cache=True)
def pair_bridges(obs, j, k, gap, delta, B):
    """Bridges that close the sharp free corners between cone slots ``j`` and ``k``, written to
    the rows of ``B`` (axis, radius); returns how many (0–2).

    Where two cones nearly meet, the free region between them narrows to a tip: a narrow
    gap, or the notch where two overlapping cones cross at a sharp angle. At the tip both
    conditions hold at once at nearly opposite directions and the box cannot meet them,
    so a sensor driven in is lost (seen at gaps of 0.1° and 0.6°, and at notches of
    29°–44° with ``brake`` 0.5). A bridge is a virtual cone that fills the tip up to where
    the free corner is ``W = 2·(gap + delta)`` wide:

    - a gap ``g`` (axis angle less both half-angles) with ``|g| < gap``: centred on the gap
      point (on the great circle from ``c_j`` to ``c_k``); two circles of half-angles
      ``α_j``, ``α_k`` part from their common tangent as ``d²·cot α/2``, so the width at ``d``
      is ``g + κd²``, ``κ = (cot α_j + cot α_k)/2``, and ``r = √((W − g)/κ)``;
    - cones that overlap by more (``g ≤ −gap``): one bridge on each crossing point of their
      rims, where the free corner's opening angle is ``θ``: ``r = (W/2)/tan(θ/2)`` (the
      corner's chord width; the sum of the two clearances there is somewhat less), kept only
      if at least ``gap`` (none where ``tan(θ/2) > (gap + delta)/gap``: above about 110° with
      the defaults).

    A bridge is at most half the smaller cone's half-angle plus ``gap`` wide; none joins a cone
    lying inside the other.

    A bridge never holds the target (it shrinks to keep the target ``gap`` outside, and is
    dropped if that leaves it narrower than ``gap``) nor a sensor already inside it.
    """
    oj = _k.OB_CONES + _k.OB_CONE_STRIDE * j
    ok_ = _k.OB_CONES + _k.OB_CONE_STRIDE * k
    cj0 = obs[oj]; cj1 = obs[oj + 1]; cj2 = obs[oj + 2]; aj = obs[oj + 3]
    ck0 = obs[ok_]; ck1 = obs[ok_ + 1]; ck2 = obs[ok_ + 2]; ak = obs[ok_ + 3]
    D = _k._angle(cj0, cj1, cj2, ck0, ck1, ck2)
    g = D - aj - ak
    if g >= gap or D < 1e-9 or math.pi - D < 1e-9:
        return 0
    if D + min(aj, ak) <= max(aj, ak):
        return 0          # one cone inside the other: no free corner between them
    W = 2.0 * (gap + delta)
    # a bridge no wider than half the smaller cone (and the threshold): it fills a tip, it does
    # not stand in for a cone
    cap = 0.5 * min(aj, ak) + gap
    cjk = cj0 * ck0 + cj1 * ck1 + cj2 * ck2
    if g > -gap:
        u0 = ck0 - cjk * cj0; u1 = ck1 - cjk * cj1; u2 = ck2 - cjk * cj2
        un = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
        if un < 1e-12:
            return 0      # (axes not of unit length in a crafted observation)
        u0 /= un; u1 /= un; u2 /= un
        phi = aj + 0.5 * g
        cp = math.cos(phi); sp = math.sin(phi)
        kappa = 0.5 * (1.0 / math.tan(max(aj, 1e-6)) + 1.0 / math.tan(max(ak, 1e-6)))
        r = min(math.sqrt((W - g) / kappa), cap) if kappa > 1e-6 else cap
        return _bridge_fits(obs, cp * cj0 + sp * u0, cp * cj1 + sp * u1, cp * cj2 + sp * u2, r, gap, B, 0)
    # the rims cross at x = a·c_j + b·c_k ± t·n, n = c_j × c_k / |c_j × c_k|
    s2 = 1.0 - cjk * cjk
    ca = math.cos(aj); ck_ = math.cos(ak)
    a = (ca - ck_ * cjk) / s2
    b = (ck_ - ca * cjk) / s2
    t2 = 1.0 - (a * a + b * b + 2.0 * a * b * cjk)
    if t2 <= 1e-12:
        return 0          # one cone inside the other: no crossing
    n0 = cj1 * ck2 - cj2 * ck1; n1 = cj2 * ck0 - cj0 * ck2; n2 = cj0 * ck1 - cj1 * ck0
    nn = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if nn < 1e-12:
        return 0
    t = math.sqrt(t2) / nn
    n = 0
    for sign in (1.0, -1.0):
        x0 = a * cj0 + b * ck0 + sign * t * n0
        x1 = a * cj1 + b * ck1 + sign * t * n1
        x2 = a * cj2 + b * ck2 + sign * t * n2
        # the rims' normals in the tangent plane at x; the free corner opens at π − their angle
        pj = x0 * cj0 + x1 * cj1 + x2 * cj2
        pk = x0 * ck0 + x1 * ck1 + x2 * ck2
        e0 = cj0 - pj * x0; e1 = cj1 - pj * x1; e2 = cj2 - pj * x2
        f0 = ck0 - pk * x0; f1 = ck1 - pk * x1; f2 = ck2 - pk * x2
        en = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        fn = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
        if en < 1e-12 or fn < 1e-12:
            continue
        theta = math.pi - math.acos(min(1.0, max(-1.0, (e0 * f0 + e1 * f1 + e2 * f2) / (en * fn))))
        half = math.tan(0.5 * theta)
        if half <= 0.0:
            continue
        r = min(0.5 * W / half, cap)
        if r < gap:
            continue
        n = _bridge_fits(obs, x0, x1, x2, r, gap, B, n)
    return n


@njit(cache=True)
def _condition(obs, c0, c1, c2, alpha, delta0, t0, t1, t2, lam, brake, s):
    """``(usable, G0, G1, G2, d)``: the cone's condition ``G·v ≥ d`` on the action."""
    # the margin never closes the target off: at most half the target's own clearance
    ct = t0 * c0 + t1 * c1 + t2 * c2
    tgt_margin = math.acos(min(1.0, max(-1.0, ct))) - alpha
    delta = min(delta0, max(0.0, 0.5 * tgt_margin))
    h, hd, G0, G1, G2, a0 = axis_barrier_terms(obs, c0, c1, c2, alpha, delta)
    A = s * (abs(G0) + abs(G1) + abs(G2))
    if A <= 1e-12:
        return False, 0.0, 0.0, 0.0, 0.0
    if hd < 0.0:
        beta = brake * A
        hb = h - hd * hd / (2.0 * beta)
        need = beta * (1.0 - lam * hb / (-hd))
    else:
        need = -2.0 * lam * hd - lam * lam * h
    return True, G0, G1, G2, need - a0


@njit(cache=True)
def shield_action(obs, action, params, max_cones, v, out):
    """Filtered normalised action of ``action`` at observation ``obs``, written to ``v``.

    ``obs`` is a raw (not normalised) observation of ``SlewEnv`` with ``max_cones``
    slots. Returns the number of conditions that changed the action.
    """
    # the policy's action as the environment flies it (dynamics.torque_from_action):
    # saturated, NaN → 0, and for a p-norm bound scaled radially onto the unit p-ball
    inv_p = obs[_k.OB_INV_P]
    vnom = np.empty(3)
    for i in range(3):
        a = action[i]
        if a != a:
            a = 0.0
        vnom[i] = _clip_box(a, 1.0)
    if inv_p > 0.0:
        pn = 0.0
        for i in range(3):
            pn += abs(vnom[i]) ** (1.0 / inv_p)
        pn = pn ** inv_p
        if pn > 1.0:
            for i in range(3):
                vnom[i] /= pn
    for i in range(3):
        v[i] = vnom[i]
    out[F_ACTIVE] = 0.0
    out[F_FEASIBLE] = 1.0
    out[F_MIN_SLACK] = np.inf
    # an observation that is not finite cannot be filtered: say so, change nothing
    for j in range(_k.OB_CONES):
        if not np.isfinite(obs[j]):
            out[F_FEASIBLE] = 0.0
            return 0
    for k in range(min(max_cones, MAX_CONES)):
        for j in range(_k.OB_CONE_STRIDE):
            if not np.isfinite(obs[_k.OB_CONES + _k.OB_CONE_STRIDE * k + j]):
                out[F_FEASIBLE] = 0.0
                return 0

    s = 1.0 if inv_p <= 0.0 else 3.0 ** (-inv_p)
    lam = params[P_LAMBDA]
    brake = params[P_BRAKE]
    delta0 = params[P_MARGIN]

    t0 = obs[_k.OB_TARGET]; t1 = obs[_k.OB_TARGET + 1]; t2 = obs[_k.OB_TARGET + 2]
    if obs[_k.OB_J] <= 0.0 or obs[_k.OB_J + 1] <= 0.0 or obs[_k.OB_J + 2] <= 0.0:
        return 0

    n = 0
    ncon = min(max_cones, MAX_CONES)
    G = np.zeros((max(ncon * ncon, 1), 3))       # the cones and up to 2 bridges a pair
    d = np.zeros(G.shape[0])
    B = np.zeros((2, 4))
    gap = params[P_GAP]
    for k in range(ncon):
        o = _k.OB_CONES + _k.OB_CONE_STRIDE * k
        if obs[o + 5] < 0.5:
            continue
        usable, G0, G1, G2, dk = _condition(obs, obs[o], obs[o + 1], obs[o + 2], obs[o + 3], delta0,
                                            t0, t1, t2, lam, brake, s)
        if usable:
            G[n, 0] = G0; G[n, 1] = G1; G[n, 2] = G2
            d[n] = dk
            n += 1
        if gap <= 0.0:
            continue
        for j in range(k):
            if obs[_k.OB_CONES + _k.OB_CONE_STRIDE * j + 5] < 0.5:
                continue
            nb = pair_bridges(obs, j, k, gap, delta0, B)
            for i in range(nb):
                usable, G0, G1, G2, dk = _condition(obs, B[i, 0], B[i, 1], B[i, 2], B[i, 3], delta0,
                                                    t0, t1, t2, lam, brake, s)
                if usable:
                    G[n, 0] = G0; G[n, 1] = G1; G[n, 2] = G2
                    d[n] = dk
                    n += 1
    # kept even when the policy's action meets them: moving v for another cone may break one
    for k in range(n):
        slack = G[k, 0] * vnom[0] + G[k, 1] * vnom[1] + G[k, 2] * vnom[2] - d[k]
        if slack < out[F_MIN_SLACK]:
            out[F_MIN_SLACK] = slack
    if n == 0:
        return 0
    mu = np.zeros(n)
    # any condition unmet by the policy's action?
    unmet = 0
    for k in range(n):
        if _dot_row(G, k, vnom) < d[k]:
            unmet += 1
    if unmet == 0:
        return 0
    sweeps = int(params[P_SWEEPS])
    for _ in range(max(1, sweeps)):
        changed = False
        for k in range(n):
            # smallest μ_k ≥ 0 with G_k·v(μ) ≥ d_k, the others held (monotone in μ_k)
            old = mu[k]
            mu[k] = 0.0
            _v_of(vnom, G, mu, n, s, v)
            if _dot_row(G, k, v) >= d[k]:
                if old != 0.0:
                    changed = True
                continue
            lo = 0.0
            hi = 1.0
            mu[k] = hi
            _v_of(vnom, G, mu, n, s, v)
            while _dot_row(G, k, v) < d[k] and hi < _MU_MAX:
                lo = hi
                hi *= 4.0
                mu[k] = hi
                _v_of(vnom, G, mu, n, s, v)
            for _it in range(_BISECT):
                mid = 0.5 * (lo + hi)
                mu[k] = mid
                _v_of(vnom, G, mu, n, s, v)
                if _dot_row(G, k, v) >= d[k]:
                    hi = mid
                else:
                    lo = mid
            mu[k] = hi
            if abs(hi - old) > 1e-9 * (1.0 + hi):
                changed = True
        if not changed:
            break
    _v_of(vnom, G, mu, n, s, v)
    active = 0
    feasible = 1.0
    out[F_MIN_SLACK] = np.inf          # the slack of the action returned, not of the policy's
    for k in range(n):
        if mu[k] > 0.0:
            active += 1
        sl = _dot_row(G, k, v) - d[k]
        if sl < -1e-9 * (1.0 + abs(d[k])):
            feasible = 0.0
        if sl < out[F_MIN_SLACK]:
            out[F_MIN_SLACK] = sl
    out[F_ACTIVE] = active
    out[F_FEASIBLE] = feasible
    return active


@njit(cache=True)
def shield_batch(obs, actions, params, max_cones, v, out):
    """``shield_action`` row by row (``obs`` (N, L), ``actions``/``v`` (N, 3), ``out`` (N, OUT_LENGTH))."""
    for j in range(obs.shape[0]):
        shield_action(obs[j], actions[j], params, max_cones, v[j], out[j])
