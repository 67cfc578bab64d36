"""Homotopy paths towards the exact extremal: smoothing (tanh) and norm (p) continuation.

Both are paths, never answers: the per-axis answer always comes from the exact
bang-bang solvers (``switch_time`` then event-driven verification).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .shooting import STATUS_DEADLINE, newton_shoot
from .switch_time import Structure, structure_from_trajectory


@dataclass
class PathPoint:
    param: float
    z: np.ndarray
    T: float


@dataclass
class PathResult:
    success: bool
    points: list
    nit: int
    nfev: int
    message: str = ""


def continue_path(bvp, z, T, start, stop, *, set_param, factor=3.0, min_factor=1.05, tol=1e-8,
                  max_newton=25, max_steps=60, on_point=None, path_rtol=1e-9, stall=None, deadline=math.inf,
                  exhausted=None):
    """Follow a one-parameter family from ``start`` to ``stop`` (geometric steps).

    ``set_param(bvp, value)`` configures the problem; a failed step is retried with a
    smaller factor (down to ``min_factor``). ``on_point(point) -> bool`` may stop the
    path early (returns True to stop); it runs at the problem's own tolerance, while
    the path itself is integrated at ``path_rtol``. ``stall``: the Newton solves' stall
    criterion (``newton_shoot``): a step whose Newton stalls is retried shorter at once.
    ``deadline`` (``time.perf_counter()`` value): checked before each step and each Newton
    iteration; past it the path stops and fails (its points so far are returned). ``exhausted(nfev) -> str | None``: a
    further budget, checked before each step and after each Newton solve (before ``on_point``)
    with the path's propagations so far; a text stops the path, which fails with that text as
    its message.
    """
    # the path's points are stepping stones: integrate them more loosely than answers
    saved_tol = (bvp.rtol, bvp.atol)
    bvp.rtol, bvp.atol = max(bvp.rtol, path_rtol), max(bvp.atol, path_rtol)
    try:
        return _continue(bvp, z, T, start, stop, set_param, factor, min_factor, tol, max_newton,
                         max_steps, on_point, saved_tol, stall, deadline, exhausted)
    finally:
        bvp.rtol, bvp.atol = saved_tol


def _continue(bvp, z, T, start, stop, set_param, factor, min_factor, tol, max_newton, max_steps,
              on_point, answer_tol, stall=None, deadline=math.inf, exhausted=None):
    def visit(point):
        # on_point may solve for an answer: give it the answer tolerance meanwhile
        if on_point is None:
            return False
        loose = (bvp.rtol, bvp.atol)
        bvp.rtol, bvp.atol = answer_tol
        try:
            return on_point(point)
        finally:
            bvp.rtol, bvp.atol = loose

    def out_of_budget():
        # the caller's further budget (``exhausted``), as the path's failure, or None
        why = exhausted(nfev) if exhausted is not None else None
        return PathResult(False, points, nit, nfev, f"{why} (continuation at {cur:g})") if why else None

    points = []
    nit = nfev = 0
    cur = start
    set_param(bvp, cur)
    r = newton_shoot(bvp, z, T, max_step=0.5, tol=tol, max_iter=max_newton, stall=stall, deadline=deadline)
    nit += r.nit
    nfev += r.nfev
    if not r.success:
        return PathResult(False, points, nit, nfev, f"no solution at the start of the path ({r.message})")
    z, T = r.p, r.T
    points.append(PathPoint(cur, z, T))
    stop_ = out_of_budget()
    if stop_ is not None:
        return stop_
    if visit(points[-1]):
        return PathResult(True, points, nit, nfev, "stopped early")
    f = factor
    down = stop < start
    steps = 0
    while (cur > stop * 1.0000001) if down else (cur < stop * 0.9999999):
        steps += 1
        if steps > max_steps:
            return PathResult(False, points, nit, nfev, "too many continuation steps")
        if time.perf_counter() > deadline:
            return PathResult(False, points, nit, nfev, f"time budget exhausted (continuation at {cur:g})")
        stop_ = out_of_budget()
        if stop_ is not None:
            return stop_
        nxt = max(cur / f, stop) if down else min(cur * f, stop)
        set_param(bvp, nxt)
        r = newton_shoot(bvp, z, T, max_step=0.5, tol=tol, max_iter=max_newton, stall=stall, deadline=deadline)
        nit += r.nit
        nfev += r.nfev
        if r.success and r.T > 0:
            cur, z, T = nxt, r.p, r.T
            points.append(PathPoint(cur, z, T))
            stop_ = out_of_budget()
            if stop_ is not None:
                return stop_
            if visit(points[-1]):
                return PathResult(True, points, nit, nfev, "stopped early")
            f = min(factor, f * 1.5)
        elif r.status == STATUS_DEADLINE:
            return PathResult(False, points, nit, nfev, f"time budget exhausted (continuation at {cur:g})")
        else:
            f = math.sqrt(f)
            if f < min_factor:
                return PathResult(False, points, nit, nfev, f"continuation stalled at {cur:g}")
    return PathResult(True, points, nit, nfev, "reached the end of the path")


def set_tanh(bvp, eps):
    bvp.set_mode("tanh", eps=eps)


def set_pnorm(bvp, p):
    bvp.set_mode("pnorm", p=p)


def structure_candidates(bvp, z, T, *, n_samples=800, small=0.15, graze=0.1):
    """Bang-bang structures suggested by a smoothed extremal ``(z, T)`` (current mode).

    In order: the sign changes only; then with an extra switch near the start or end
    for axes whose switching function is small there (a short first or last arc that
    smoothing hides); then with switch pairs at interior grazes.
    """
    tr = bvp.record(z, T, hmax=T / n_samples)
    S = tr.y[:, 11:14] / bvp.J
    base = structure_from_trajectory(tr.t, S, graze=0.0)
    out = [base]
    amax = np.max(np.abs(S), axis=0)
    amax[amax == 0] = 1.0
    w = 0.02 * T
    extra_times, extra_axes, flips = [], [], np.ones(3)
    for i in range(3):
        if abs(S[0, i]) < small * amax[i]:
            flips[i] = -1.0
            extra_times.append(w)
            extra_axes.append(i)
        if abs(S[-1, i]) < small * amax[i]:
            extra_times.append(T - w)
            extra_axes.append(i)
    if extra_times:
        times = np.concatenate([base.times, extra_times])
        axes = np.concatenate([base.axes, np.asarray(extra_axes, dtype=np.int64)])
        o = np.argsort(times, kind="stable")
        out.append(Structure(base.signs0 * flips, axes[o], times[o]))
    g = structure_from_trajectory(tr.t, S, graze=graze)
    if g.n != base.n:
        out.append(g)
    return out
