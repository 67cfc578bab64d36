"""Load the compiled kernels a kind of problem uses before a solve's clock starts.

numba compiles a kernel at its first call in a process, or loads it from its on-disk cache
(``cache=True``; tens of seconds on a fresh install, which compiles them). Inside a solve that
time would count against its ``time_budget`` and cut the solve short. ``solve`` therefore calls
``ensure_kernels`` before it starts its clock: the first solve of each kind of problem in a
process solves small representative problems of that kind first, without a budget, so that every
kernel its routes call is loaded, and the shipped model files with them. A time budget then
holds from the first solve on. Measured (a review, 2026-11-24): 0.2–1.1 s a kind without cones
and 0.8–1.8 s with cones once numba's cache exists; every kind (``load_kernels()``) 7.7–7.9 s,
79 s on a fresh install. Since session 35 every kind also plans the eigenaxis slew, and a kind
with cones solves a second problem whose path clears its cone: 1.25 s for pointing slews, 2.1 s
with cones, 10.3 s for every kind (2026-11-25; the slow tests had found pointing kinds loading
kernels inside their budget). One thread loads; another that needs a kind meanwhile waits for it.

The kinds are the combinations of the torque bound (per-axis or p-norm), the target
(full attitude or pointing only) and whether the problem has keep-out cones: the kernels'
argument types differ between them, not between problems of one kind.
``tests/test_kernel_loading.py`` checks, in a new process, that after loading, the routes of
each kind (``auto`` with and without the shipped models, ``indirect``, ``multiple-shooting``,
the eigenaxis fallback, ``method="eigenaxis"``) load no further kernel.
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np

from slew_env import Cone, SlewProblem

_LOADED: dict = {}          # kind -> seconds spent loading it in this process
_LOADING: dict = {}         # kind -> the thread loading it (its own solves inside do not load again)
_ERRORS: dict = {}          # kind -> what a representative solve raised (the loading goes on)
_LOCK = threading.RLock()


def problem_kind(problem: SlewProblem) -> tuple:
    """``(bound, target, cones)``: ``"per-axis"`` or ``"p-norm"``, ``"full"`` or ``"pointing"``,
    ``True`` where the problem has keep-out cones."""
    bound = "per-axis" if math.isinf(problem.torque_norm) else "p-norm"
    target = "pointing" if problem.sensor_target is not None else "full"
    return bound, target, bool(problem.cones)


def _representatives(kind: tuple) -> list:
    """Small problems of ``kind`` whose solves take the kind's routes quickly once loaded."""
    bound, target, cones = kind
    p = math.inf if bound == "per-axis" else 2.0
    inertia = [1.0, 0.8, 0.6]
    if target == "full":
        half = 0.6
        base = SlewProblem(inertia, torque_norm=p, q0=[1.0, 0.0, 0.0, 0.0],
                           qf=[math.cos(half), math.sin(half) * 0.6, math.sin(half) * 0.8, 0.0])
        if not cones:     # a symmetric body's eigenaxis baseline takes other kernels
            return [base, base.replace(inertia=[1.0, 1.0, 1.0])]
    else:
        base = SlewProblem(inertia, torque_norm=p, q0=[1.0, 0.0, 0.0, 0.0], sensor_target=[0.3, 0.5, 0.81])
    if cones:
        # the sensor (body x) starts on the far side of a cone from its target: the path touches it;
        # and a cone opposite the path, which it clears: the routes of inactive cones (the exact
        # solver without them), the eigenaxis baseline and fallback where the path clears them
        axis = np.array([0.55, 0.25, 0.45])
        away = -(base.start_direction + base.target_direction)
        return [base.replace(cones=[Cone(axis / np.linalg.norm(axis), 0.3)]),
                base.replace(cones=[Cone(away / np.linalg.norm(away), 0.3)])]
    return [base]


def _load_kind(kind: tuple) -> None:
    from .api import solve
    from .collocation import load_replay_kernels
    for prob in _representatives(kind):
        # the default route (the learned guess where a shipped model covers the kind); the
        # eigenaxis slew (``auto``'s baseline and the fallback, for every kind since session 35:
        # pointing targets, and cones where its path clears them). Loading is
        # an optimisation: a representative solve that raises (a damaged model file, a patched
        # route in a test) must not fail the user's solve; what it did not load loads later
        for kw in ({}, {"method": "eigenaxis"}):
            try:
                solve(prob, **kw)
            except Exception as e:      # noqa: BLE001 - see above
                _ERRORS.setdefault(kind, []).append(f"{kw or 'default'}: {type(e).__name__}: {e}"[:300])
    if kind[1] == "pointing" and kind[2]:
        # the pointing-cones network's guesses (warm_start="pointing-cones", the challenger's
        # candidates): the default route reads only its predicted tf, and a first guess made
        # inside a route compiled a kernel signature there (the slow kernel-loading test)
        try:
            _load_cone_network(_representatives(kind)[0])
        except Exception as e:          # noqa: BLE001 - as above
            _ERRORS.setdefault(kind, []).append(f"cone network: {type(e).__name__}: {e}"[:300])
    if kind[2]:
        from .cone_penalty import load_kernels as load_penalty_kernels
        from .switch_time_cones import load_kernels as load_switch_time_cone_kernels
        load_penalty_kernels()
        load_switch_time_cone_kernels()
    # collocation's replay of its control and its costate estimates (``auto``'s route where the
    # learned guess fails, the default route with cones): they run after its NLP, which is not
    # worth solving here
    load_replay_kernels()


def _load_cone_network(prob) -> None:
    """Every guess of the shipped pointing-cones network for ``prob`` (its domain aside)."""
    from . import warmstart
    from .warmstart.cone_features import cone_unsupported_reason, form_of_supported
    model = warmstart.default_cone_model()
    if model is not None and cone_unsupported_reason(prob) is None:
        model.network.guess_from_form(prob, form_of_supported(prob)).all()


def ensure_kernels(problem: SlewProblem) -> float:
    """Load (or on a fresh install compile) the kernels that solves of ``problem``'s kind use,
    once a process; returns the seconds it took (0 when they were loaded already)."""
    return _ensure_kind(problem_kind(problem))


def _ensure_kind(kind: tuple) -> float:
    """``ensure_kernels`` for ``kind``."""
    if kind in _LOADED:
        return 0.0
    # one thread loads; another that needs the same kind waits for it (the lock: the time it
    # waited is its loading time), and the loading thread's own solves inside return at once
    t_wait = time.perf_counter()
    with _LOCK:
        if _LOADING.get(kind) == threading.get_ident():
            return 0.0
        if kind in _LOADED:
            return time.perf_counter() - t_wait
        _LOADING[kind] = threading.get_ident()
        t0 = time.perf_counter()
        try:
            _load_kind(kind)
        finally:
            del _LOADING[kind]
        _LOADED[kind] = time.perf_counter() - t0
        return _LOADED[kind]


def load_kernels(problems=None, method: str = "auto", warm_start="default") -> float:
    """Load the compiled kernels before the first time-critical solve of a process.

    ``problems``: a ``SlewProblem`` (or a dict, or a list of them) whose kinds to load, and, where
    ``solve(problem)``'s route begins with collocation (pointing and cone problems, full-attitude
    ones no shipped warm start covers), the collocation NLPs of their default mesh and cone count
    (``collocation.prebuild_nlps``), and with ``auto`` and cones those of the problem without its
    cones too (``solve`` builds only the first before its clock: the cone-free stages are rare);
    ``None`` loads every kind. Returns the seconds spent.
    ``solve`` does this by itself before its clock starts, so calling it is needed only to take
    that time at start-up rather than in the first solve (0.2–1.8 s a kind once numba's cache
    exists; on a fresh install it compiles, tens of seconds a kind; the module docstring).

    ``method`` and ``warm_start``: those the later solves will pass to ``solve`` (the NLPs built
    are those of that route: ``solve(p, warm_start=None)`` begins a full-attitude slew with
    collocation, where the shipped warm start does not; a user review measured a first such solve
    under a 0.02 s budget at 197 ms after ``load_kernels([p])`` had loaded the default route)."""
    from .api import METHODS
    from . import warmstart as _ws
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"method: expected one of {list(METHODS)}, got {method!r:.60}")
    # as solve checks it (a misspelt or missing model had built no NLPs, silently): 'none' from
    # Python, a number, a missing file raise here, naming warm_start
    try:
        _ws.resolve(warm_start)
    except ValueError as e:
        msg = str(e)
        raise type(e)(msg if msg.startswith("warm_start") else f"warm_start: {msg}") from None
    if problems is None:
        kinds = [(b, t, c) for b in ("per-axis", "p-norm") for t in ("full", "pointing") for c in (False, True)]
    else:
        items = problems if isinstance(problems, (list, tuple)) else [problems]
        for p in items:
            if not isinstance(p, (SlewProblem, dict)):
                raise ValueError(f"problems: expected a SlewProblem, a problem dict or a list of them, "
                                 f"got {type(p).__name__} {p!r:.60}")
        probs = [SlewProblem.from_dict(p) for p in items]
        kinds = [problem_kind(p) for p in probs]
    total = sum(_ensure_kind(kind) for kind in dict.fromkeys(kinds))
    if problems is not None:
        from .api import _begins_with_collocation
        from .collocation import prebuild_nlps
        # the NLPs that solve(p, method=method, warm_start=warm_start) builds before its clock, and
        # for auto with cones those of the problem without them, which its rarer stages solve
        # (``cone_routes.clear_without_cones``, ``cone_free_challenger``) inside the budget
        total += sum(prebuild_nlps(p) for p in probs if _begins_with_collocation(p, method, None, warm_start))
        total += sum(prebuild_nlps(p.replace(cones=[])) for p in probs if method == "auto" and p.cones)
    return total
