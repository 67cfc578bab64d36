"""A shooting engine that knows nothing about attitudes.

It solves two-point (or multi-point) boundary-value problems of the form::

    y(0) = initial(p),   y' = F(y) on M segments of a free total duration T,
    param_residual(p) = 0,   junction_k(y(t_k⁻), y_k) = 0,   terminal(y(T), T) = 0

with unknowns ``Z = [p, y_1 … y_{M-1}, T]`` (single shooting when ``M = 1``),
by Newton's method with a backtracking line search and a step cap, using the
sensitivities that the problem's ``flow`` returns (variational equations).

A problem object supplies (see ``ShootingProblem``):

* ``n_y``, ``n_p``: sizes of the propagated vector and of the free initial parameters;
* ``initial(p) -> (y0, dy0/dp)``;
* ``param_residual(p) -> (r, dr/dp)`` (e.g. a costate normalisation);
* ``flow(y0, duration, Phi0) -> Flow`` with ``Flow.y``, ``Flow.Phi`` (``∂y(end)/∂(what Phi0
  differentiates)``, or ``None`` when ``Phi0`` is ``None``), ``Flow.f`` (``ẏ`` at the end),
  ``Flow.ok`` and ``Flow.message``;
* ``terminal(y, T) -> (r, dr/dy, dr/dT)``;
* optionally ``junction(k, y_left, y_right) -> (r, dr/dy_left, dr/dy_right)``; the default is
  continuity ``y_left - y_right``;
* optionally ``segment_fractions(M)``: how ``T`` is split (default equal parts).

The engine records iterations and function evaluations in a ``ShootingResult``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Optional, Protocol

import numpy as np

from . import deadline as solve_deadline


class Flow(Protocol):
    y: np.ndarray
    Phi: Optional[np.ndarray]
    f: np.ndarray
    ok: bool
    message: str


class ShootingProblem(Protocol):
    n_y: int
    n_p: int

    def initial(self, p): ...
    def param_residual(self, p): ...
    def flow(self, y0, duration, Phi0): ...
    def terminal(self, y, T): ...


@dataclass
class ShootingResult:
    success: bool
    status: int
    message: str
    p: np.ndarray
    T: float
    nodes: list
    residual_norm: float
    nit: int
    nfev: int
    history: list = field(default_factory=list)


STATUS_CONVERGED = 0
STATUS_MAX_ITER = 1
STATUS_LINE_SEARCH = 2
STATUS_FLOW_FAILED = 3
STATUS_NONFINITE = 4
STATUS_BAD_DURATION = 5
STATUS_STALLED = 6
STATUS_DEADLINE = 7

MESSAGES = {
    STATUS_CONVERGED: "Newton converged: residual below tolerance.",
    STATUS_MAX_ITER: "Maximum number of Newton iterations reached.",
    STATUS_LINE_SEARCH: "Line search failed to reduce the residual (Newton stalled).",
    STATUS_FLOW_FAILED: "Propagation failed at the initial guess.",
    STATUS_NONFINITE: "Non-finite residual or Jacobian.",
    STATUS_BAD_DURATION: "The duration became non-positive.",
    STATUS_STALLED: "Stalled: the residual stopped decreasing (the stall criterion given).",
    STATUS_DEADLINE: "The time budget ran out (the deadline given).",
}


def _fractions(problem, M):
    if hasattr(problem, "segment_fractions"):
        return np.asarray(problem.segment_fractions(M), dtype=float)
    return np.full(M, 1.0 / M)


def _junction(problem, k, yl, yr):
    if hasattr(problem, "junction"):
        return problem.junction(k, yl, yr)
    n = yl.shape[0]
    return yl - yr, np.eye(n), -np.eye(n)


class _Counter:
    def __init__(self):
        self.nfev = 0


def _evaluate(problem, Z, M, want_jac, counter):
    """Residual vector and (optionally) Jacobian at ``Z``."""
    n_p, n_y = problem.n_p, problem.n_y
    p = Z[:n_p]
    T = Z[-1]
    if not (T > 0.0) or not np.all(np.isfinite(Z)):
        return None, None, "non-positive or non-finite duration"
    fr = _fractions(problem, M)
    n_z = Z.shape[0]
    rows_r = []
    rows_J = []
    rp, drp = problem.param_residual(p)
    rows_r.append(np.atleast_1d(rp))
    if want_jac:
        Jp = np.zeros((np.atleast_1d(rp).shape[0], n_z))
        Jp[:, :n_p] = np.atleast_2d(drp)
        rows_J.append(Jp)
    y0, dy0dp = problem.initial(p)
    for k in range(M):
        if k == 0:
            ys = y0
            col0, ncol = 0, n_p
            Phi0 = dy0dp if want_jac else None
        else:
            o = n_p + (k - 1) * n_y
            ys = Z[o:o + n_y]
            col0, ncol = o, n_y
            Phi0 = np.eye(n_y) if want_jac else None
        dur = fr[k] * T
        fl = problem.flow(ys, dur, Phi0)
        counter.nfev += 1
        if not fl.ok:
            return None, None, fl.message
        if k < M - 1:
            o2 = n_p + k * n_y
            r, dl, dr = _junction(problem, k, fl.y, Z[o2:o2 + n_y])
            rows_r.append(r)
            if want_jac:
                Jk = np.zeros((r.shape[0], n_z))
                Jk[:, col0:col0 + ncol] = dl @ fl.Phi
                Jk[:, o2:o2 + n_y] += dr
                Jk[:, -1] = dl @ fl.f * fr[k]
                rows_J.append(Jk)
        else:
            r, dry, drT = problem.terminal(fl.y, T)
            rows_r.append(r)
            if want_jac:
                Jk = np.zeros((r.shape[0], n_z))
                Jk[:, col0:col0 + ncol] = dry @ fl.Phi
                Jk[:, -1] = dry @ fl.f * fr[k] + drT
                rows_J.append(Jk)
    R = np.concatenate(rows_r)
    if not np.all(np.isfinite(R)):
        return None, None, "non-finite residual"
    Jm = np.vstack(rows_J) if want_jac else None
    return R, Jm, ""


def initial_nodes(problem, p, T, M):
    """Interior nodes of a multiple-shooting guess, by propagating the single-shooting guess."""
    nodes = []
    fr = _fractions(problem, M)
    y, _ = problem.initial(p)
    for k in range(M - 1):
        fl = problem.flow(y, fr[k] * T, None)
        if not fl.ok:
            return None
        y = fl.y
        nodes.append(y.copy())
    return nodes


# seconds per column³ of ``np.linalg.lstsq`` (one BLAS thread: 3e-10 measured at 700-1,400
# columns, more below), learnt from the solves this process has timed; below
# ``_LSTSQ_TIMED_FROM`` columns a solve takes a few ms at most and is neither predicted nor timed
_LSTSQ_RATE = [6e-10]
_LSTSQ_TIMED_FROM = 200


def _lstsq_seconds(shape) -> float:
    """Predicted time of a least-squares solve of a ``shape`` matrix (0 for small ones)."""
    n = min(shape)
    return 0.0 if n < _LSTSQ_TIMED_FROM else _LSTSQ_RATE[0] * float(n) ** 3


def _learn_lstsq(shape, seconds) -> None:
    n = min(shape)
    if n >= _LSTSQ_TIMED_FROM:
        # held within a factor 2 a time, so that one slow call beside another job cannot
        # make every later many-segment solve give up
        _LSTSQ_RATE[0] = min(2.0 * _LSTSQ_RATE[0], max(0.5 * _LSTSQ_RATE[0], seconds / float(n) ** 3))


def newton_shoot(problem, p0, T0, *, segments=1, nodes0=None, tol=1e-11, max_iter=40,
                 max_step=None, min_alpha=1e-6, scale=None, linear_solver="lstsq", stall=None,
                 deadline=math.inf) -> ShootingResult:
    """Solve the BVP by damped Newton from ``(p0, T0)``.

    ``linear_solver``: ``"lstsq"`` (minimum-norm least squares, SVD: right for the
    rank-deficient Jacobians of bang-bang problems) or ``"lu"`` (an LU solve of the square
    system, falling back to least squares when it is singular: about fifty times faster on
    the few-hundred-unknown systems of many-segment multiple shooting).

    ``max_step`` caps the Newton step (inf-norm, relative to the unknowns' scale ``scale``)
    so a poor guess cannot throw the iterate far away. Converged when the residual's
    inf-norm is below ``tol``.

    ``stall``: ``(k, factor, floor)`` stops the iteration (``STATUS_STALLED``) once, after at
    least ``k`` iterations, the residual is above ``floor`` and more than ``factor`` times its
    value ``k`` iterations before: a damped Newton that has stopped making progress on a
    rank-deficient problem is usually held by a non-zero local minimum of the residual, and a
    continuation step would rather retry with a shorter step than spend its iteration limit.

    ``deadline`` (``time.perf_counter()`` time): checked before each iteration; past it the
    iteration stops (``STATUS_DEADLINE``).
    """
    if linear_solver not in ("lstsq", "lu"):
        raise ValueError(f"linear_solver: expected 'lstsq' or 'lu', got {linear_solver!r}")
    if stall is not None:
        ok = (isinstance(stall, (tuple, list)) and len(stall) == 3 and isinstance(stall[0], (int, np.integer))
              and not isinstance(stall[0], bool) and stall[0] >= 1
              and all(isinstance(v, (int, float)) and math.isfinite(v) for v in stall[1:])
              and 0.0 < stall[1] < 1.0 and stall[2] >= 0.0)
        if not ok:
            raise ValueError(f"stall: expected (k ≥ 1 iterations, factor in (0, 1), floor ≥ 0), got {stall!r}")
    counter = _Counter()
    M = int(segments)
    if M < 1:
        raise ValueError(f"segments: must be a positive integer, got {segments}")
    p0 = np.asarray(p0, dtype=float)
    if nodes0 is None and M > 1:
        nodes0 = initial_nodes(problem, p0, T0, M)
        counter.nfev += M - 1
        if nodes0 is None:
            return ShootingResult(False, STATUS_FLOW_FAILED, MESSAGES[STATUS_FLOW_FAILED], p0, T0, [],
                                  math.inf, 0, counter.nfev)
    Z = np.concatenate([p0] + [np.asarray(n, float) for n in (nodes0 or [])] + [[float(T0)]])
    if scale is None:
        scale = np.maximum(np.abs(Z), 1.0)
    R, Jm, msg = _evaluate(problem, Z, M, True, counter)
    if R is None:
        return ShootingResult(False, STATUS_FLOW_FAILED, f"{MESSAGES[STATUS_FLOW_FAILED]} ({msg})",
                              p0, T0, [], math.inf, 0, counter.nfev)
    history = []
    nit = 0
    phi = 0.5 * float(R @ R)
    status = STATUS_MAX_ITER
    while True:
        rn = float(np.max(np.abs(R)))
        history.append(rn)
        if rn < tol:
            status = STATUS_CONVERGED
            break
        if nit >= max_iter:
            status = STATUS_MAX_ITER
            break
        if stall is not None and nit >= stall[0] and rn > stall[1] * history[-1 - stall[0]] and rn > stall[2]:
            status = STATUS_STALLED
            break
        if not np.all(np.isfinite(Jm)):
            status = STATUS_NONFINITE
            break
        if time.perf_counter() > min(deadline, solve_deadline.current()):
            status = STATUS_DEADLINE
            break
        nit += 1
        # Minimum-norm least-squares step: the Jacobian of a bang-bang problem is
        # rank-deficient whenever the iterate has fewer switches than conditions
        # (the states then depend on the costates only through the switch times).
        dZ = None
        if linear_solver == "lu" and Jm.shape[0] == Jm.shape[1]:
            try:
                dZ = np.linalg.solve(Jm, -R)
            except np.linalg.LinAlgError:
                dZ = None
            if dZ is not None and not np.all(np.isfinite(dZ)):
                dZ = None
        if dZ is None:
            if time.perf_counter() + _lstsq_seconds(Jm.shape) > min(deadline, solve_deadline.current()):
                # the SVD of a many-segment Jacobian cannot be stopped once begun: one that the
                # time left cannot pay for is not started (300 segments ran 20 s past 2 s)
                status = STATUS_DEADLINE
                break
            t_ls = time.perf_counter()
            dZ = np.linalg.lstsq(Jm, -R, rcond=1e-12)[0]
            _learn_lstsq(Jm.shape, time.perf_counter() - t_ls)
        if max_step is not None:
            big = float(np.max(np.abs(dZ) / scale))
            if big > max_step:
                dZ *= max_step / big
        alpha = 1.0
        accepted = False
        while alpha >= min_alpha:
            if solve_deadline.passed():
                # past the solve's end each trial's propagation is cut short and fails: halving
                # the step on would only run ~20 more of them
                break
            Zt = Z + alpha * dZ
            Rt, _, _ = _evaluate(problem, Zt, M, False, counter)
            if Rt is not None:
                phit = 0.5 * float(Rt @ Rt)
                if phit <= (1.0 - 1e-4 * alpha) * phi or (phit < phi and alpha < 1.0):
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            status = STATUS_DEADLINE if solve_deadline.passed() else STATUS_LINE_SEARCH
            break
        Z = Zt
        R, Jm, msg = _evaluate(problem, Z, M, True, counter)
        if R is None:
            status = STATUS_FLOW_FAILED
            break
        phi = 0.5 * float(R @ R)
    n_p, n_y = problem.n_p, problem.n_y
    nodes = [Z[n_p + k * n_y:n_p + (k + 1) * n_y].copy() for k in range(M - 1)]
    rn = float(np.max(np.abs(R))) if R is not None else math.inf
    return ShootingResult(status == STATUS_CONVERGED, status, MESSAGES[status], Z[:n_p].copy(), float(Z[-1]),
                          nodes, rn, nit, counter.nfev, history)
