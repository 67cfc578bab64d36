"""Canonical form of a full-attitude slew: the features a warm-start model sees.

A rest-to-rest, full-attitude slew without cones is fixed, up to symmetry, by the
relative rotation in the start body frame, the inertia and the torque bound. The
canonical form removes what does not change the answer:

* **units** — inertia ``J / J_max``, bound ``u_max / max(u_max)``, time in
  ``τ = sqrt(J_max / u_max)`` (the solver's nondimensional units);
* **the inertial frame** — only ``q0* ⊗ qf`` matters: the eigenaxis ``n`` (start body
  axes) and the angle ``θ ∈ [0, π]``;
* **the labelling of the body axes** — a proper signed axis permutation ``A``
  (``det A = +1``, one of the 24 rotations of the cube) relabels the body axes without
  changing the physics (Euler's equations are covariant under rotations, the per-axis
  bound is permuted). ``A`` is chosen so that ``|n'_1| ≥ |n'_2| ≥ |n'_3|`` and
  ``n'_1, n'_2 ≥ 0`` (``n' = A n``; the sign of ``n'_3`` is then fixed by ``det A = +1``).
  For a symmetric body with equal bounds every such relabelling maps the problem onto
  itself, so all of its images share one canonical form; for an asymmetric body the
  permuted inertia and bound are features.

Features (``FEATURE_NAMES``): ``n'`` (3), ``θ/π``, ``J'`` (3, ``J/J_max`` in canonical
order), ``u'`` (3, ``u_max/max u_max``), ``1/p`` (0 for the per-axis bound).

Solutions map with the same ``A``: body vectors (``μ``, ``λω``, the torque signs)
transform as ``v' = A v``; the switch times of canonical axis ``i`` are those of body
axis ``order[i]``. Costates are the solver's nondimensional unknowns ``z = [μ, λω(0)]``
in the gauge ``λq(0) = q(0) ⊗ [0, μ]`` with ``|z| = 1`` (``solvers.attitude_bvp``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from slew_env import SlewProblem
from slew_env.core.quaternion import qconj, qmul
from ..core import warmstart_kernels as _k

FEATURE_NAMES = ("n1", "n2", "n3", "theta_over_pi", "J1", "J2", "J3", "u1", "u2", "u3", "inv_p")
N_FEATURES = len(FEATURE_NAMES)


@dataclass(frozen=True)
class CanonicalForm:
    """A problem in canonical axes. ``A`` maps body vectors to canonical ones."""
    A: np.ndarray           # (3, 3) proper signed permutation
    order: tuple            # canonical axis i is body axis order[i]
    x: np.ndarray           # features (N_FEATURES,)
    tau: float              # time unit sqrt(J_max / u_max) of the problem
    T_eig: float            # nondimensional time of the eigenaxis guess (the reference for tf)


def unsupported_reason(problem: SlewProblem) -> Optional[str]:
    """Why ``problem`` has no canonical form (``None`` if it has one)."""
    if problem.qf is None:
        return "sensor_target: pointing-only targets have no full-attitude canonical form"
    if problem.cones:
        return "cones: keep-out cones are not part of the full-attitude canonical form"
    if not problem.is_rest_to_rest:
        return "omega0, omegaf: the canonical form is defined for rest-to-rest slews"
    return None


def canonical_form(problem) -> CanonicalForm:
    """The canonical form of a rest-to-rest full-attitude ``problem`` (``ValueError`` otherwise)."""
    if not isinstance(problem, SlewProblem):
        problem = SlewProblem.from_dict(problem)
    why = unsupported_reason(problem)
    if why:
        raise ValueError(why)
    # compiled (solvers.core.warmstart_kernels.attitude_canonical): the eigenaxis n and angle θ
    # of q0* ⊗ qf; A sorts the axes by decreasing |n_i| (ties in axis order) with n'_1, n'_2 ≥ 0
    # and det A = +1; x = [A n, θ/π, J', u', 1/p]; T_eig from the largest constant acceleration
    A, order_arr, x, T_eig = _k.attitude_canonical(
        np.ascontiguousarray(problem.q0, dtype=np.float64), np.ascontiguousarray(problem.qf, dtype=np.float64),
        np.ascontiguousarray(problem.inertia, dtype=np.float64),
        np.ascontiguousarray(problem.torque_max, dtype=np.float64), float(problem.torque_norm))
    order = (int(order_arr[0]), int(order_arr[1]), int(order_arr[2]))
    Jmax = float(problem.inertia.max())
    umax = float(problem.torque_max.max())
    return CanonicalForm(A, order, x, math.sqrt(Jmax / umax), T_eig)


def features(problem) -> np.ndarray:
    return canonical_form(problem).x


# --------------------------------------------------------------------------- solutions
def solution_to_canonical(problem, cf: CanonicalForm, costate0, tf, switch_times, u_first):
    """A solution in problem units → canonical nondimensional ``(z', T, switch_times', u_first')``.

    ``switch_times'`` are nondimensional, per canonical axis; ``z'`` has unit norm.
    """
    problem = SlewProblem.from_dict(problem)
    c = np.asarray(costate0, float)
    mu = qmul(qconj(problem.q0), c[:4])[1:4] / cf.tau
    lw = c[4:7] / cf.tau ** 2
    z = np.concatenate([cf.A @ mu, cf.A @ lw])
    nz = np.linalg.norm(z)
    if not nz > 0:
        raise ValueError("costate0: zero in the solver's gauge")
    sw = [np.asarray(switch_times[j], float) / cf.tau for j in cf.order]
    uf = cf.A @ np.asarray(u_first, float)
    return z / nz, float(tf) / cf.tau, sw, uf


def solution_from_canonical(problem, cf: CanonicalForm, z, T, switch_times=None, u_first=None):
    """Canonical nondimensional ``(z', T, switch_times', u_first')`` → problem units:
    ``(costate0, tf, switch_times, u_first)`` as a ``solvers.Guess`` takes them."""
    problem = SlewProblem.from_dict(problem)
    z = np.asarray(z, float)
    mu = cf.A.T @ z[:3]
    lw = cf.A.T @ z[3:6]
    lq = qmul(problem.q0, np.array([0.0, mu[0], mu[1], mu[2]])) * cf.tau
    costate0 = np.concatenate([lq, lw * cf.tau ** 2])
    sw = None
    if switch_times is not None:
        sw = [None] * 3
        for i, j in enumerate(cf.order):
            sw[j] = np.asarray(switch_times[i], float) * cf.tau
    uf = None if u_first is None else cf.A.T @ np.asarray(u_first, float)
    return costate0, float(T) * cf.tau, sw, uf


def canonical_problem(cf: CanonicalForm, torque_norm="inf") -> SlewProblem:
    """The canonical problem itself (identity start, nondimensional units)."""
    n = cf.x[0:3]
    th = cf.x[3] * math.pi
    qf = np.concatenate([[math.cos(th / 2)], math.sin(th / 2) * n])
    return SlewProblem(inertia=cf.x[4:7], torque_max=cf.x[7:10], torque_norm=torque_norm, qf=qf)
