"""Canonical form of a pointing-only slew with keep-out cones (family (b) of ``slew generate``).

A rest-to-rest pointing slew is fixed by where the target direction and the cone axes lie
in the *start body frame*, the inertia, the torque bound and the sensor axis. The canonical
form removes what does not change the answer:

* **units** — inertia ``J / J_max``, bound ``u_max / max(u_max)``, time in
  ``τ = sqrt(J_max / u_max)`` (the solver's nondimensional units);
* **the inertial frame** — target ``d`` and cone axes ``a_k`` are expressed in the start body
  frame (``R(q0)ᵀ d``), so the start attitude is the identity;
* **the labelling of the body axes, and mirror images** — a signed axis permutation ``A``
  takes the sensor axis to ``+x``. Besides the rotations of the cube, ``A`` may be a
  reflection: the mirror image of a slew (inertial and body frames reflected together,
  ``R → A R Aᵀ``) is a slew of the same body under the same box bound in the same time, with
  polar vectors (target, cone axes) mapped by ``A`` and axial ones (rates, torques, the
  costates) by ``det(A) A``. Of the eight ``A`` with ``A s = +x``, the one with
  ``J'_y ≥ J'_z``, then the target's ``y`` component ``≥ 0``, then its ``z`` component
  ``≥ 0`` is taken, so the target lies in one quadrant. The sensor must therefore lie along a
  body axis (the family's default ``[1, 0, 0]`` does);
* **the order of the cones** — slots sorted by how much each cone blocks the great circle
  from the sensor to the target (its margin to that arc, most blocking first); unused slots
  are zero.

Features (``CONE_FEATURE_NAMES``, 24): ``d'`` (3), ``J'`` (3), ``u'`` (3), then per cone slot
``a'`` (3), ``α`` (rad) and a presence flag. Solutions map with
``det(A) A``: ``z' = det(A) A z`` for the nondimensional costates ``z = [μ, λω(0)]`` (gauge
``λq(0) = q(0) ⊗ [0, μ]``, unit norm); the touch-point multipliers of ``solvers.cone_touch``
in the same normalisation (``ν / |z_raw|``), touch instants nondimensional.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import cached_property
from typing import Optional

import numpy as np

from slew_env import SlewProblem
from slew_env.core.quaternion import qconj, qmul
from ..core import warmstart_kernels as _k

MAX_CONES = 3
CONE_SLOT = ("ax", "ay", "az", "half_angle", "present")
CONE_FEATURE_NAMES = ("d1", "d2", "d3", "J1", "J2", "J3", "u1", "u2", "u3") + tuple(
    f"cone{k}_{n}" for k in range(MAX_CONES) for n in CONE_SLOT)
N_CONE_FEATURES = len(CONE_FEATURE_NAMES)


def _signed_permutations():
    """The 48 signed axis permutations (rotations and reflections of the cube)."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            A = np.zeros((3, 3))
            for i, j in enumerate(perm):
                A[i, j] = signs[i]
            out.append(A)
    return out


_CUBE = _signed_permutations()


@dataclass(frozen=True)
class ConeCanonicalForm:
    """A pointing problem in canonical axes. ``A`` maps body vectors to canonical ones."""
    A: np.ndarray           # (3, 3) signed permutation, a rotation or a reflection
    x: np.ndarray           # features (N_CONE_FEATURES,)
    tau: float              # time unit sqrt(J_max / u_max)
    T_ref: float            # nondimensional time of the eigenaxis pointing slew (cones ignored)
    slots: tuple            # slots[k] = index of the problem cone in canonical slot k

    # (the form is immutable; these are read for every candidate mapped back.
    # ``form_of_supported`` fills them from its candidates' tables: 5 µs a problem less)
    @cached_property
    def axial(self) -> np.ndarray:
        """The map of axial body vectors (rates, torques, costates): ``det(A) A`` (for a signed
        permutation, det is the product of its signs times the permutation's parity)."""
        return _axial(self.A, self.order)

    @cached_property
    def order(self) -> list:
        """Canonical axis ``i`` is body axis ``order[i]``."""
        return [int(i) for i in self.order_array]

    @cached_property
    def order_array(self) -> np.ndarray:
        return np.abs(self.A).argmax(axis=1)

    @cached_property
    def slots_array(self) -> np.ndarray:
        return np.array(self.slots, dtype=np.int64)


def cone_unsupported_reason(problem: SlewProblem) -> Optional[str]:
    """Why ``problem`` has no pointing-cones canonical form (``None`` if it has one)."""
    if problem.qf is not None:
        return "qf: the pointing-cones form is for pointing-only targets (sensor_target)"
    if not problem.is_rest_to_rest:
        return "omega0, omegaf: the canonical form is defined for rest-to-rest slews"
    if len(problem.cones) > MAX_CONES:
        return f"cones: at most {MAX_CONES} keep-out cones, got {len(problem.cones)}"
    if _sensor_key(problem.sensor_axis) is None:
        return "sensor_axis: the canonical form needs the sensor along a body axis"
    return None


def _sensor_key(sensor_axis):
    """``(axis, positive)`` of a sensor along a body axis, else None (plain floats: this runs
    for every guess; remembered for the last few sensor axes seen, by their bytes, since a
    warm start asks twice a problem and a mission has one or two sensors)."""
    if isinstance(sensor_axis, np.ndarray) and sensor_axis.dtype == np.float64:
        b = sensor_axis.tobytes()
        key = _SENSOR_KEYS.get(b, _UNKNOWN)
        if key is _UNKNOWN:
            key = _sensor_key_of([float(v) for v in sensor_axis])
            if len(_SENSOR_KEYS) >= 16:
                _SENSOR_KEYS.clear()
            _SENSOR_KEYS[b] = key
        return key
    return _sensor_key_of([float(v) for v in sensor_axis])


_SENSOR_KEYS = {}
_UNKNOWN = object()


def _sensor_key_of(s):
    n = math.sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])
    i = max(range(3), key=lambda k: abs(s[k]))
    if abs(s[i]) / n < 1.0 - 1e-12:
        return None
    return i, s[i] > 0


def _candidates(s):
    """The signed permutations ``A`` with ``A s = +x``, as arrays ``(A (m, 3, 3), perm (m, 3),
    signs (m, 3))`` with ``(A v)_i = signs[i] v[perm[i]]`` (``warmstart_kernels.cone_canonical``),
    and each one's ``axial`` map (m, 3, 3) (``ConeCanonicalForm.axial``: made once here, not for
    every problem)."""
    As = [A for A in _CUBE if (A @ s)[0] > 0.5]
    perm = np.array([[int(np.argmax(np.abs(A[i]))) for i in range(3)] for A in As], dtype=np.int64)
    signs = np.array([[A[i, pm[i]] for i in range(3)] for A, pm in zip(As, perm)])
    axial = np.array([_axial(A, pm) for A, pm in zip(As, perm)])
    return np.array(As), perm, signs, axial


def _axial(A, order):
    """``det(A) A`` for a signed permutation ``A`` whose canonical axis ``i`` is body axis
    ``order[i]`` (det: the product of its signs times the permutation's parity)."""
    o = [int(i) for i in order]
    det = A[0, o[0]] * A[1, o[1]] * A[2, o[2]]
    even = (o[0], o[1], o[2]) in ((0, 1, 2), (1, 2, 0), (2, 0, 1))
    return (det if even else -det) * A


_CANDIDATES = {}


def cone_canonical_form(problem) -> ConeCanonicalForm:
    """The canonical form of a pointing-only ``problem`` (``ValueError`` when it has none)."""
    if not isinstance(problem, SlewProblem):
        problem = SlewProblem.from_dict(problem)
    why = cone_unsupported_reason(problem)
    if why:
        raise ValueError(why)
    return form_of_supported(problem)


def form_of_supported(problem: SlewProblem) -> ConeCanonicalForm:
    """``cone_canonical_form`` of a ``problem`` whose caller has just found
    ``cone_unsupported_reason(problem)`` to be ``None`` (the check is not made twice)."""
    key_s = _sensor_key(problem.sensor_axis)
    if key_s not in _CANDIDATES:
        s = np.asarray(problem.sensor_axis, float)
        _CANDIDATES[key_s] = _candidates(s / np.linalg.norm(s))
    axes = np.array([c.axis for c in problem.cones], dtype=np.float64).reshape(-1, 3)
    half = np.array([c.half_angle for c in problem.cones], dtype=np.float64)
    cA, cperm, csg, caxial = _CANDIDATES[key_s]
    # compiled (solvers.core.warmstart_kernels.cone_canonical): the target and cone axes in the
    # start body frame; A the candidate with the largest (J'_y - J'_z, d'_y, d'_z) to 9
    # decimals; the cones sorted by their margin to the arc from the sensor to the target; the
    # features; the eigenaxis pointing time; the time unit sqrt(J_max / u_max)
    A, x, T_ref, slots, best, tau = _k.cone_canonical(
        np.ascontiguousarray(problem.q0, dtype=np.float64), np.ascontiguousarray(problem.sensor_target, dtype=np.float64),
        np.ascontiguousarray(problem.inertia, dtype=np.float64), np.ascontiguousarray(problem.torque_max, dtype=np.float64),
        cA, cperm, csg, axes, half)
    cf = ConeCanonicalForm(A, x, tau, T_ref, tuple(slots.tolist()))
    # the derived maps from the chosen candidate's tables (copies: the tables are shared)
    order = cperm[best].copy()
    cf.__dict__.update(order_array=order, order=order.tolist(), axial=caxial[best].copy(), slots_array=slots)
    return cf


def canonical_problem(x) -> SlewProblem:
    """The problem whose canonical features are ``x``: start attitude the identity, sensor
    ``+x``, target ``d'``, inertia ``J'``, bound ``u'`` (so ``τ = 1``: its times are the
    canonical nondimensional ones), the cones of the present slots in slot order."""
    x = np.asarray(x, float)
    if x.shape != (N_CONE_FEATURES,):
        raise ValueError(f"x: expected {N_CONE_FEATURES} canonical features, got shape {x.shape}")
    from slew_env import Cone
    cones = [Cone(x[9 + 5 * k:12 + 5 * k], half_angle=float(x[12 + 5 * k]))
             for k in range(MAX_CONES) if x[13 + 5 * k] > 0.5]
    return SlewProblem(inertia=x[3:6], torque_max=x[6:9], torque_norm="inf", q0=[1.0, 0.0, 0.0, 0.0],
                       sensor_axis=[1.0, 0.0, 0.0], sensor_target=x[0:3], cones=cones)


def cone_features(problem) -> np.ndarray:
    return cone_canonical_form(problem).x


def costate_to_canonical(problem, cf: ConeCanonicalForm, costate0):
    """Costates in problem units → ``(z', |z_raw|)``: canonical unit-norm costates and the norm
    of the nondimensional costates they were scaled from (touch multipliers scale with it)."""
    c = np.asarray(costate0, float)
    mu = qmul(qconj(np.asarray(problem.q0, float)), c[:4])[1:4] / cf.tau
    lw = c[4:7] / cf.tau ** 2
    B = cf.axial
    z = np.concatenate([B @ mu, B @ lw])
    nz = float(np.linalg.norm(z))
    if not nz > 0:
        raise ValueError("costate0: zero in the solver's gauge")
    return z / nz, nz


def costate_from_canonical(problem, cf: ConeCanonicalForm, z):
    """Canonical costates ``z'`` → ``costate0`` in problem units (the same scale as ``z'``)."""
    z = np.asarray(z, float)
    B = cf.axial
    mu = B.T @ z[:3]
    lw = B.T @ z[3:6]
    lq = qmul(np.asarray(problem.q0, float), np.array([0.0, mu[0], mu[1], mu[2]])) * cf.tau
    return np.concatenate([lq, lw * cf.tau ** 2])


def solution_to_canonical(problem, cf: ConeCanonicalForm, costate0, tf, switch_times, u_first, touches=()):
    """A solution in problem units → canonical nondimensional ``(z', |z_raw|, T, switch
    instants per canonical axis, first-arc signs, touches)``; ``touches``: ``(cone, time,
    multiplier)`` as ``verification["touch_multipliers"]`` reports them, returned per canonical
    slot as ``{slot: (instant, ν)}`` with ``ν`` in the normalisation of ``z'``."""
    z, nz = costate_to_canonical(problem, cf, costate0)
    sw = [np.sort(np.asarray(switch_times[j], float)) / cf.tau for j in cf.order]
    uf = np.where(cf.axial @ np.asarray(u_first, float) >= 0, 1.0, -1.0)
    slot_of = {c: k for k, c in enumerate(cf.slots)}
    tc = {slot_of[int(c)]: (float(t) / cf.tau, float(m) / (cf.tau * nz)) for c, t, m in touches}
    return z, nz, float(tf) / cf.tau, sw, uf, tc


def solution_from_canonical(problem, cf: ConeCanonicalForm, z, T, switch_times, u_first, touches=()):
    """Canonical nondimensional ``(z', T, switch instants per canonical axis, first-arc signs,
    touches [(slot, instant, ν)])`` → problem units: ``(costate0, tf, switch_times, u_first,
    touches [(cone, time, multiplier)])`` as a ``solvers.Guess`` takes them (``costate0`` in
    the scale of the unit-norm ``z'``, so a multiplier is ``ν τ``)."""
    sw = [None] * 3
    for i, body in enumerate(cf.order):        # canonical axis i is body axis order[i]
        sw[body] = np.asarray(switch_times[i], float) * cf.tau
    touches = [(cf.slots[k], float(t) * cf.tau, float(nu) * cf.tau) for k, t, nu in touches]
    return (costate_from_canonical(problem, cf, z), float(T) * cf.tau, sw, cf.axial.T @ np.asarray(u_first, float),
            touches)

