"""``solvers.solve``: method dispatch, multi-start over candidates, verification.

Methods:

* ``"indirect"`` — single shooting. Per-axis bound: exact bang-bang extremal by the
  switch-time solver (structure from the guess, or from a smoothing continuation),
  then event-driven re-propagation. p-norm bound: shooting on the closed-form control,
  with norm continuation from p = 2 as fallback.
* ``"multiple-shooting"`` — the same routes with every shooting stage done on
  ``segments`` segments (default 4); the per-axis answer is polished by event-driven
  multiple shooting.
* ``"indirect"`` / ``"multiple-shooting"`` with keep-out cones — single shooting (``segments`` is
  not used; ``route`` says so and ``method`` is ``"indirect"``), seeded by collocation
  (or the given guess's costates): cones inactive on the collocation answer give the exact
  extremal of the problem without cones, with a certified clearance; a path that touches cones
  at isolated instants gives the exact extremal with costate jumps there
  (``solvers.cone_touch``, also tried by ``"auto"``); a path that rides a cone (or whose touch
  refinement fails) goes to the penalty homotopy (``solvers.cone_penalty``): the verified
  extremal of a penalised, smoothed problem that clears every cone at every instant, an
  approximation of the constrained optimum (its tf gap to collocation's is reported).
* ``"collocation"`` — direct collocation (Hermite–Simpson, IPOPT; ``solvers.collocation``):
  approximate, with costate estimates; handles keep-out cones and pointing-only targets.
* ``"auto"`` (default) — a given guess first (warm start); then collocation and the exact
  indirect refinement from its costates and switching structure; when the refinement cannot
  be certified (a singular arc, a path riding a cone), a bang-bang slew with optimised switch
  times (``solvers.switch_time_opt``, ``solvers.switch_time_cones``), else the collocation
  answer itself; the classical indirect multi-start if collocation fails (see
  ``auto_route.solve_auto``). ``route`` records the path taken.

Defaults of the indirect multi-start: per-axis 16 candidates at most and at least 8 before
stopping early, p-norm 8 and 3; a 20 s time budget. See ``solve``.

Several extremals can exist (mirror images of the 180° slew; a worse local optimum of
R5 at 29.135 s). The indirect multi-start tries candidates in order — the given guess and its own
candidates, the eigenaxis guess, its images under the problem's symmetries, the
per-axis switching-structure templates, the long-way eigenaxis, then seeded
perturbations — and returns the best verified one.
It stops when ``max_candidates`` have been tried; or, once ``min_candidates`` have
been tried, when ``enough`` (2 or more) have converged and the best final time was reached by at
least two of them, or with ``enough=1`` at the first verified extremal not slower than the
eigenaxis slew; or when the ``time_budget`` runs out. After the first verified extremal
reached along a built-in candidate's smoothing path, each later per-axis candidate's attempt
stops at ``candidate_cap`` (``multistart.CANDIDATE_CAP``). ``SlewSolution.n_candidates`` says
how many it tried. A multi-start is no proof of global optimality: on random problems the
collocation-first route of ``"auto"`` found a faster extremal than the classical multi-start
in about 1 case in 13.
"""
from __future__ import annotations

import math
import time

import numpy as np

from slew_env import SlewProblem
from slew_env.checks import is_integer, is_real
from .deadline import propagation_deadline
from .blas_threads import single_threaded_blas
from .kernel_loading import ensure_kernels
from .guesses import Guess
from .eigenaxis import baseline_time
from . import waypoint_slew
from .eigenaxis_answer import N_GRID, _not_compared, eigenaxis_answer, eigenaxis_inapplicable, no_slower_than_eigenaxis
from .solution import STATUS_BUDGET_EXHAUSTED, SlewSolution
from .switch_time_opt import switch_time_applies
from . import auto_route, cone_routes, multistart, stage_budget, warm_routes

METHODS = ("auto", "indirect", "multiple-shooting", "collocation", "eigenaxis")
_OPTIONS = {"cone_challenge", "collocation", "segments", "max_candidates", "min_candidates", "enough", "candidate_cap", "seed", "time_budget", "tols", "n_dense",
            "eps_min", "rtol", "atol", "warm_budget", "singular_table", "local_optimum_check", "fallback"}
FALLBACKS = (None, "eigenaxis")

# s: kept out of the route's time budget for planning the eigenaxis fallback (12-24 ms measured),
# at most this share of the budget
FALLBACK_RESERVE = 0.025
FALLBACK_RESERVE_SHARE = 0.5

# angle steps of the fallback's profile for a p-norm bound with a gyroscopic term (the planner's
# default, 4,000, takes 20-100 ms; 1,000 steps 12-18 ms, at most 1.1e-4 slower on 80 random problems: 40 bodies, p = 1.5 and 2)
FALLBACK_GRID_PNORM_GYRO = 1000

# where less time is left than the default profile takes, the fallback's grid shrinks to what
# fits (planning time measured 2026-11-24: without a p-norm gyroscopic term 0.9 ms + 1.0 µs a
# step, with one 3 ms + 10 µs a step; the costs below are 1.5× that), down to these floors
# (per-axis 1,000 steps: at most 3.4e-4 slower than 16,000 on two samples of random bodies, 40
# and a review's; p-norm with a gyroscopic term, 250 steps: at most 6.1e-4 slower than 4,000; a
# p-norm profile without one is exact on any grid). Below a few milliseconds the floors take
# longer than what is left: 0.8-1.8 ms late (per-axis) at budgets of 0.1-1 ms. Re-measured
# 2026-12-07 with the record check and the unit scaling that the planner has since gained, on a
# loaded machine (runs/s43/fb_cost.py, 30 problems a row, per leg): per-axis 1,000 steps median
# 1.4 ms, max 3.0 ms (the model: 3.0 ms); 16,000 steps median 9.9, max 22.6 ms (25.5 ms);
# with cones 1.9 / 2.0 ms and 13.2 / 13.8 ms; p = 2 with a gyroscopic term, 1,000 steps, median
# 11.5, max 13.7 ms (19.5 ms): the costs still cover them
FALLBACK_STEP_COST = {"no-gyro": (1.5e-3, 1.5e-6), "pnorm-gyro": (4.5e-3, 1.5e-5)}
FALLBACK_GRID_FLOOR = {"no-gyro": 1000, "pnorm-gyro": 250}


def solve(problem, method="auto", guess=None, warm_start="default", **options) -> SlewSolution:
    """Time-optimal slew of ``problem`` (``SlewProblem`` or dict).

    ``method``: ``"auto"`` (default), ``"indirect"``, ``"multiple-shooting"``,
    ``"collocation"`` (see the module docstring) or ``"eigenaxis"`` (the baseline planner's slew:
    ``eigenaxis_answer``; with keep-out cones where its path enters one, rest-to-rest eigenaxis
    legs through one or two waypoints round them, ``waypoint_slew``). ``guess``: a ``solvers.Guess``.

    ``warm_start``: where the first guess comes from when ``guess`` is not given
    (indirect routes and ``"auto"``): ``"default"`` (the shipped full-attitude model, for the
    problems in its family; with keep-out cones and ``method="auto"``, the 2 nearest tabled
    solutions of the shipped pointing-cones warm start join collocation's starts, and the warm
    start challenges the default route's answer afterwards, replacing it only with a faster
    verified extremal: ``cone_challenge``, below; under a ``time_budget`` shorter than
    ``cone_routes.CONE_LEARNED_FIRST_BELOW``, 0.4 s, which the collocation route does not fit in, that
    warm start goes first instead, within half the budget (all of it where the other half is
    under 60 ms, ``cone_routes.short_learned_budget``), and where it finds no extremal the
    switching sequences of its nearest tabled solutions are optimised with the cones imposed,
    ``cone_routes.cone_sequences_route``: a verified bang-bang slew, ``method="switch-time"``, or
    the exact extremal at it where one is found), ``"pointing-cones"`` (that warm start as the first
    guess: opt-in, faster but often a slower local extremal, see ``docs/WARMSTART.md``), a model object (``solvers.warmstart.WarmStartModel``,
    ``NearestNeighbourModel`` or anything with ``covers(problem)`` — ``None`` or ``True``: it
    covers the problem; a text saying why not, or ``False``: it does not — and ``guess(problem)``),
    a model file path, or ``None``. The learned candidates are tried alone first (the first
    verified extremal that is not slower than the eigenaxis slew wins); if none is
    verified, the classical route runs as if there were no model. ``SlewSolution.warm_start``
    records what happened and ``guess`` which candidate won.

    Options of the indirect routes: ``segments`` (multiple shooting, default 4; the cone
    penalty route of an indirect solve with active cones: default 32, at least 2),
    ``max_candidates`` (default 16 per-axis, 8 p-norm), ``min_candidates`` (tried before
    stopping early, default 8 per-axis, 3 p-norm), ``enough`` (converged candidates before
    stopping early, default 2: the best final time reached by two of them; 1: the first verified
    extremal not slower than the eigenaxis slew, once ``min_candidates`` were tried), ``candidate_cap`` (per-axis: after the first verified extremal reached along a
    built-in candidate's smoothing path, each later candidate's attempt stops after
    ``max(multiple × the first attempt's propagations, floor)`` propagations;
    default ``(2, 200)``, ``None`` for no cap), ``seed`` (for the perturbed candidates, default 0),
    ``time_budget`` (s, default 20; ``method="collocation"``: 60, as ``solve_collocation``) is
    the whole solve's: every stage gets what is left of it and stops at its next check (between
    Newton iterations, continuation steps, candidates and IPOPT iterations), the answer then
    being the best verified one so far or status 3, budget exhausted. The first candidate of a
    multi-start always starts (its iterations check the deadline). The compiled kernels (and, where the
    route begins with collocation, its NLPs: ``_begins_with_collocation``) are loaded before the clock starts
    (``kernel_load_time``); an NLP the budget left cannot pay for is not built
    (``benchmarks/bench_budget.py`` and ``bench_first_solve.py`` measure the overshoot). ``warm_budget`` (s, for the learned guess's candidates,
    default 1; 0.2 with keep-out cones), ``tols`` (verification tolerances, see
    ``solvers.verify``), ``n_dense`` (the dense record's steps are capped at ``tf / n_dense``; default 100, samples at
    every step and both sides of every switch), ``eps_min`` (end of the
    smoothing path, default 1e-3), ``rtol``/``atol`` (integrator). ``collocation``: a dict
    of options for ``solvers.collocation.solve_collocation`` (``method="collocation"`` and
    the collocation stage of ``"auto"``). ``singular_table`` (default True): ``auto`` with the
    default model, when its guess fails and the shipped singular table finds the problem among
    singular ones, answers with the near singular answers' sequences, optimised (tens of
    milliseconds, no collocation; ``warm_routes.singular_table_route``); where the table's vote is
    uncertain (1 or 2 of the 5 nearest singular), the same, then a collocation check for an exact
    extremal (a few tenths of a second); where it votes bang-bang (fewer singular), the 8 nearest
    tabled solutions' switching sequences, optimised, then the exact solver from their KKT
    costates (``warm_routes.neighbour_sequences_route``: an extremal in tenths of a second without
    collocation; a bang-bang answer that is not one must beat the collocation route's answer,
    which then runs too); False: the collocation route instead.
    ``fallback`` (default None): ``"eigenaxis"`` returns, where the route ends without a verified
    answer (the ``time_budget`` ran out, or nothing converged), the eigenaxis slew of a
    rest-to-rest problem (``method="eigenaxis"``, verified by its replay, not time-optimal;
    12–24 ms for a per-axis bound; a pointing target at its reference attitude; with keep-out
    cones where its path enters one, the slew through waypoints round them, ``waypoint_slew``):
    a flyable answer for on-board use under a hard budget. With a ``time_budget``, the route gets
    that budget less the fallback's planning time (``FALLBACK_RESERVE``, 25 ms a leg of the slew;
    at most half the budget), so that either answer
    is there within the budget, up to the route's own overshoot (one Newton iteration or IPOPT
    iteration); where less is left than its default profile takes, the fallback plans on fewer
    angle steps (``_fallback_grid``), down to a floor that is late below a few milliseconds of
    budget (docs/SOLVER.md, "Short budgets with the fallback"). The budget's clock starts after the compiled kernels of
    the problem's kind are loaded (``kernel_loading``; the first solve of each kind in a process, reported as
    ``kernel_load_time``; ``solvers.load_kernels`` does it at start-up), and collocation builds
    no NLP the budget left cannot pay for (``collocation_nlp.NoTimeToBuild``). For a p-norm bound with
    a gyroscopic term the fallback's profile has at most 1,000 angle steps
    (``FALLBACK_GRID_PNORM_GYRO``; at most 1.1e-4 slower than ``method="eigenaxis"``'s 4,000).
    The route's message says why the fallback was needed.
    ``local_optimum_check`` (default True): ``auto`` runs the collocation route as well when the
    learned guess's extremal is likely a local optimum (more than 1.5 % above the model's
    predicted time, or a slew within 10° of a half turn; ``warm_routes.challenge_learned_answer``) and keeps
    the faster answer; False: the learned answer at once (milliseconds, for on-board use).
    ``cone_challenge`` (``auto`` with cones and the default warm start): ``"gated"`` (default) runs
    the pointing-cones warm start after the route only where the answer is slower than the
    network's predicted final time (``cone_routes.CONE_CHALLENGE_GATE``; about 0.1 s where it runs, on 45 % of
    random cone problems), ``"always"``, or ``"never"``.

    A verified extremal slower than the eigenaxis slew of the same problem (the
    baseline, ``SlewSolution.baseline_tf``) is a local optimum: it is returned with
    ``success=False`` and status 4, never as the answer.
    """
    with single_threaded_blas():
        return _solve(problem, method, guess, warm_start, **options)


def check_options(method="auto", **options) -> None:
    """The checks ``solve`` makes of ``method`` and its options before solving, without a
    problem: a ``ValueError`` naming the first bad one (``slew generate`` checks its
    ``--solve-options`` with this before it writes any record)."""
    _checked_options(method, None, dict(options))


def _checked_options(method, guess, options):
    """``(use_table, check_local, cone_challenge, fallback, col_opts)`` popped from ``options``
    after every check that does not need the problem."""
    if method not in METHODS:
        raise ValueError(f"method: unknown method {method!r}; choose one of {', '.join(METHODS)}")
    unknown = set(options) - _OPTIONS
    if unknown:
        raise ValueError(f"options: unknown option(s) {sorted(unknown)}; known: {sorted(_OPTIONS)}")
    if guess is not None and not isinstance(guess, Guess):
        raise ValueError(f"guess: expected a solvers.Guess, got {type(guess).__name__}")
    for key in ("time_budget", "warm_budget"):
        if key in options:
            v = options[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (v > 0) or not math.isfinite(v):
                raise ValueError(f"{key}: must be a positive number of seconds, got {v!r}")
    if options.get("candidate_cap") is not None:
        options["candidate_cap"] = multistart.checked_cap(options["candidate_cap"])
    _check_options(options)
    use_table = options.pop("singular_table", True)
    if not isinstance(use_table, bool):
        raise ValueError(f"singular_table: expected True or False, got {use_table!r}")
    check_local = options.pop("local_optimum_check", True)
    if not isinstance(check_local, bool):
        raise ValueError(f"local_optimum_check: expected True or False, got {check_local!r}")
    cone_challenge = options.pop("cone_challenge", "gated")
    if not (isinstance(cone_challenge, str) and cone_challenge in cone_routes.CONE_CHALLENGE_MODES):
        raise ValueError(f"cone_challenge: expected one of {', '.join(map(repr, cone_routes.CONE_CHALLENGE_MODES))}, "
                         f"got {cone_challenge!r}")
    fallback = options.pop("fallback", None)
    if not (fallback is None or (isinstance(fallback, str) and fallback in FALLBACKS)):
        raise ValueError(f"fallback: expected None or 'eigenaxis', got {fallback!r}")
    if fallback is not None and method in ("collocation", "eigenaxis"):
        raise ValueError(f"fallback: applies to the 'auto', 'indirect' and 'multiple-shooting' routes, "
                         f"not method={method!r}")
    col_opts = options.pop("collocation", None) or {}
    if not isinstance(col_opts, dict):
        raise ValueError(f"collocation: expected a dict of solve_collocation options, got {col_opts!r}")
    _check_collocation_options(col_opts)
    return use_table, check_local, cone_challenge, fallback, col_opts


def _solve(problem, method, guess, warm_start, **options) -> SlewSolution:
    """``solve`` with the BLAS libraries at one thread (``blas_threads``)."""
    prob = SlewProblem.from_dict(problem)   # a SlewProblem passes through
    use_table, check_local, cone_challenge, fallback, col_opts = _checked_options(method, guess, options)
    for k, (c, _, _) in enumerate((guess.touches or []) if guess is not None else []):
        if c >= len(prob.cones):
            raise ValueError(f"guess.touches[{k}]: cone index {c}, but the problem has {len(prob.cones)} cone(s)")
    # (every route refuses it itself, but only after the first solve of a process had loaded its
    # kind's kernels: 0.7 s for an input error)
    multistart.refuse_zero_slew(prob)
    if not prob.is_rest_to_rest and prob.slew_angle < 1e-12 and np.array_equal(prob.omega0, prob.omegaf):
        # (at rest every route refuses it itself; with a rate, collocation ended in IPOPT's
        # Restoration_Failed)
        raise ValueError(("qf" if prob.qf is not None else "sensor_target") + ", omegaf: the target state is the "
                         "start state (the same attitude and rate): tf = 0, nothing to solve")
    reserved = 0.0
    if fallback == "eigenaxis" and "time_budget" in options and _fallback_flyable(prob):
        # the fallback is planned after the route: its time comes out of the route's budget, so
        # that the answer, whichever it is, is there within the budget
        budget = float(options["time_budget"])
        # (a waypoint slew around the cones plans one profile a leg)
        reserved = min(FALLBACK_RESERVE * _fallback_legs(prob), FALLBACK_RESERVE_SHARE * budget)
        options["time_budget"] = budget - reserved
    if method != "eigenaxis":
        # an infeasible problem is an input error, found before any loading; the grid test
        # (about 0.1 s, for four or more cones in a loop of overlaps) is remembered, not
        # repeated inside the time budget
        from .cone_passability import check_cones_passable
        check_cones_passable(prob)
    # the kernels are loaded (on a fresh install, compiled) before the clock starts: the time
    # budget is for solving, and loading inside it would cut the first solve of a process short
    load = 0.0 if method == "eigenaxis" else ensure_kernels(prob)
    if _begins_with_collocation(prob, method, guess, warm_start):
        # so are the collocation NLPs of routes that begin with collocation (not interruptible)
        load += _prebuild_nlps(prob, col_opts)
    # no propagation runs past the route's budget by more than a few ms, nor a line search
    # (``solvers.deadline``); the eigenaxis fallback's reserve stays its own (it runs no capped code)
    route_budget = float(options.get("time_budget", 60.0 if method == "collocation" else 20.0))
    with propagation_deadline(time.perf_counter() + route_budget):
        sol = _dispatch(prob, method, guess, warm_start, options, col_opts, fallback, reserved,
                        check_local, use_table, cone_challenge)
    if not (isinstance(sol.baseline_tf, float) and math.isfinite(sol.baseline_tf)) and prob.is_rest_to_rest \
            and sol.status != STATUS_BUDGET_EXHAUSTED:      # (a spent budget gets nothing more)
        # the routes that did not need the eigenaxis baseline (collocation's pointing and cone
        # answers, the touch-point and switch-time routes) left it empty; every rest-to-rest
        # answer carries it (cones ignored, a pointing target's reference attitude), for the user's
        # comparison (under a millisecond)
        sol.baseline_tf = baseline_time(prob)
    sol.kernel_load_time = load
    return sol


# multiple shooting's segments, each 14 columns of a dense Jacobian whose least-squares solve
# costs ~3e-10 n³ s: 200 segments, ~6 s an iteration (1,000 held a 7,000-column SVD for minutes)
MAX_SEGMENTS = 200
# n_dense: steps of the dense record; a propagation takes at most ``attitude_bvp.MAX_STEPS``
# (200,000), and a dense record needs n_dense steps plus two rows a switch
MAX_DENSE_STEPS = 100_000


def _int_option(options, key, lo, hi):
    if key in options:
        v = options[key]
        if not is_integer(v) or not lo <= v <= hi:
            raise ValueError(f"{key}: expected an integer from {lo} to {hi:,}, got {v!r:.80}")


def _positive_option(options, key):
    if key in options:
        v = options[key]
        if not (is_real(v) and math.isfinite(v) and v > 0):
            raise ValueError(f"{key}: expected a positive finite number, got {v!r:.80}")


def _check_options(options) -> None:
    """``solve``'s numeric options, checked whatever route runs (a route that does not use one
    must not let a bad value through unnoticed): ``ValueError`` naming the option."""
    _int_option(options, "segments", 1, MAX_SEGMENTS)
    _int_option(options, "n_dense", 1, MAX_DENSE_STEPS)
    for key in ("max_candidates", "min_candidates", "enough"):
        _int_option(options, key, 1, 10_000)
    lo, hi = options.get("min_candidates"), options.get("max_candidates")
    if lo is not None and hi is not None and lo > hi:
        # a default min above a given max is capped by it; two given bounds that contradict
        # each other are a slip
        raise ValueError(f"min_candidates: {lo} is more than max_candidates ({hi})")
    if "seed" in options and options["seed"] is not None:
        _int_option(options, "seed", 0, 2 ** 63 - 1)
    for key in ("eps_min", "rtol", "atol"):
        _positive_option(options, key)
    if "tols" in options and options["tols"] is not None:
        _check_tols(options["tols"])


def _check_tols(tols) -> None:
    from . import collocation
    from .verify import DEFAULT_TOLS
    if not isinstance(tols, dict):
        raise ValueError(f"tols: expected a dict of verification tolerances, got {tols!r:.80}")
    known = set(DEFAULT_TOLS) | set(collocation.DEFAULT_TOLS)
    unknown = set(tols) - known
    if unknown:
        raise ValueError(f"tols: unknown check(s) {sorted(map(str, unknown))}; known: {sorted(known)}")
    for k, v in tols.items():
        if not is_real(v) or not (math.isfinite(v) or v == math.inf) or (
                math.isfinite(v) and v < 0.0 and k != "normality"):
            raise ValueError(f"tols[{k!r}]: expected a finite number ≥ 0, got {v!r:.80}")


def _check_collocation_options(col_opts) -> None:
    """The ``collocation`` dict: ``solve_collocation``'s keyword options only (``problem`` and
    ``guess`` come from ``solve`` itself), and its mesh checked before any NLP is built."""
    from . import collocation
    known = set(collocation.SOLVE_OPTIONS) - {"guess"}
    unknown = set(col_opts) - known
    if unknown:
        raise ValueError(f"collocation: unknown option(s) {sorted(map(str, unknown))}; known: {sorted(known)}")
    n = col_opts.get("n_intervals")
    if n is not None:
        for N in (n if isinstance(n, (list, tuple)) else [n]):
            collocation._check_intervals(N, in_list=isinstance(n, (list, tuple)))
    if col_opts.get("tols") is not None:
        _check_tols(col_opts["tols"])
    collocation.check_scalar_options(**{k: v for k, v in col_opts.items()
                                        if k not in ("n_intervals", "tols", "mesh", "extra_starts")})


def _begins_with_collocation(prob, method, guess, warm_start) -> bool:
    """Whether the route of ``method`` for ``prob`` begins with a collocation solve, whose NLPs
    ``solve`` then builds before its clock starts: collocation itself; ``auto`` and ``indirect``
    with cones (per-axis bound);
    ``auto`` for a pointing target, and for a full-attitude problem that neither a given
    ``guess``, the indirect multi-start of a p-norm bound with p ≤ 2, nor a warm start covering
    it goes before (a rate limit, unequal bounds, ``warm_start=None``, ...). Measured (a new
    process a solve, budget 0.3 s): ``auto`` without a model verified 0 of 4 full-attitude
    slews, as building its NLPs took the budget (status 3)."""
    if method == "eigenaxis":
        return False
    if method == "collocation":
        return True
    if prob.cones:
        # auto and the indirect route (which refuses a p-norm bound with cones, before any
        # solve) begin with collocation; with an opt-in cone warm start its candidates come
        # first, and collocation after them where they fail (4 in 10)
        return method == "auto" or math.isinf(prob.torque_norm)
    if method != "auto":
        return False
    if prob.is_pointing:
        return True
    if guess is not None or auto_route.pnorm_indirect_first(prob):
        return False
    from . import warmstart
    try:
        model = warmstart.resolve(warm_start, prob)
    except Exception:   # noqa: BLE001 - a model that cannot be read: the solve reports it
        return False
    if model is None:
        return True
    try:
        return bool(model.covers(prob))
    except Exception:   # noqa: BLE001 - the warm start records the error, and collocation runs
        return True


def _prebuild_nlps(prob, col_opts) -> float:
    """``collocation.prebuild_nlps`` for the mesh(es) and tolerances the ``collocation`` options
    give (seconds); options it cannot read are left to the solve, which reports them."""
    from .collocation import prebuild_nlps
    meshes = col_opts.get("n_intervals")
    meshes = meshes if isinstance(meshes, (list, tuple)) else [meshes]
    spent = 0.0
    try:
        for n in meshes:
            spent += prebuild_nlps(prob, n, tol=col_opts.get("tol", 1e-8), max_iter=col_opts.get("max_iter", 3000),
                                   coarse=col_opts.get("coarse", True), verbose=col_opts.get("verbose", False))
    except (ValueError, TypeError):
        pass
    return spent


def _dispatch(prob, method, guess, warm_start, options, col_opts, fallback, reserved, check_local,
              use_table, cone_challenge="gated") -> SlewSolution:
    """``_solve`` after its arguments were checked and the kernels loaded."""
    if method == "collocation":
        from .collocation import solve_collocation
        # solve's own time_budget and tols hold for collocation too (the ``collocation`` dict's win)
        top = {k: options[k] for k in ("time_budget", "tols") if k in options}
        return solve_collocation(prob, guess=guess, **dict(top, **col_opts))
    if method == "eigenaxis":
        if guess is not None:
            raise ValueError("guess: method='eigenaxis' plans the eigenaxis slew and takes no guess")
        # (with cones where the direct path enters one, the slew through waypoints around them)
        if "time_budget" not in options or not prob.is_rest_to_rest:
            return waypoint_slew.flyable_eigenaxis_answer(prob)
        # a budget: profiles of as many steps as fit in it (the fallback's grid, down to its floor)
        t0 = time.perf_counter()
        budget = float(options["time_budget"])
        legs = _fallback_legs(prob)
        # (up to the method's own grid, which for a p-norm bound with a gyroscopic term is finer
        # than the fallback's: a generous budget gives the answer without a budget)
        grid = _fallback_grid(prob, budget - (time.perf_counter() - t0), legs, fine=True)
        sol = waypoint_slew.flyable_eigenaxis_answer(prob, n_grid=grid)
        sol.route = f"{sol.route}; profile steps fitted to the time budget, {budget:.3g} s"
        return sol
    t0 = time.perf_counter()
    warm = None
    info = {}
    seq_failed = None       # (nit, nfev, record) of the short budget's sequences, where they found nothing
    # auto with cones and the shipped models: the default route answers, and the shipped
    # pointing-cones warm start challenges that answer afterwards (``cone_routes.cone_challenger``)
    challenge = (method == "auto" and bool(prob.cones) and guess is None and isinstance(warm_start, str)
                 and warm_start == "default")
    if challenge and "extra_starts" not in col_opts:
        starts = cone_routes.cone_neighbour_starts(prob)
        col_opts = dict(col_opts, extra_starts=starts)
        if starts and "n_starts" not in col_opts:
            col_opts["n_starts"] = cone_routes.CONE_OWN_STARTS_WITH_NEIGHBOURS
    later = None
    if challenge and float(options.get("time_budget", math.inf)) < cone_routes.CONE_LEARNED_FIRST_BELOW:
        # a budget shorter than the collocation route takes: the learned cone guess first (its
        # verified extremal, where it finds one, is the answer), then the tabled solutions'
        # sequences (a verified bang-bang slew, or the exact extremal at it); else the route runs
        # in what is left
        budget = float(options["time_budget"])
        short = f"time budget {budget:.3g} s, under the collocation route's {cone_routes.CONE_LEARNED_FIRST_BELOW:g} s"
        warm_opts = dict(options)
        warm_opts.setdefault("warm_budget", min(cone_routes.CONE_WARM_BUDGET, cone_routes.short_learned_budget(budget)))
        warm_opts["_cone_search_more"] = cone_routes.CONE_SHORT_SEARCH_MORE
        warm, info, _ = warm_routes.try_warm_start(prob, method, "pointing-cones", warm_opts)
        if warm is not None and warm.success:
            warm.route = f"{short}: {warm.route}"
            warm.wall_time = time.perf_counter() - t0
            return warm
        left = budget - (time.perf_counter() - t0)
        if info.get("covered") and left > cone_routes.CONE_SEQUENCE_MIN_LEFT:
            seq, (s_nit, s_nfev) = cone_routes.cone_sequences_route(prob, dict(options, time_budget=left), info)
            if seq is not None:
                what = f"learned guess failed ({warm.message[:160]})" if warm is not None else "no learned guess"
                seq.route = f"{short}: {what} → {seq.route}"
                seq.nit += warm.nit if warm is not None else 0
                seq.nfev += warm.nfev if warm is not None else 0
                seq.warm_start = info
                seq.wall_time = time.perf_counter() - t0
                return seq
            seq_failed = (s_nit, s_nfev, info["neighbour_sequences"])
    if guess is None and not challenge:
        # auto on a full-attitude per-axis problem: the learned candidates that carry a switching
        # structure (milliseconds) first; its continuation candidates after collocation, unless
        # collocation shows a singular arc, where they cannot converge (``auto_route.solve_auto``)
        split = method == "auto" and switch_time_applies(prob)
        warm, info, later = warm_routes.try_warm_start(prob, method, warm_start, options, split=split,
                                                       table_reserve=method == "auto" and use_table)
        if warm is not None and warm.success:
            if method == "auto" and check_local:
                warm = warm_routes.challenge_learned_answer(prob, warm, info, col_opts, options, t0)
            warm.wall_time = time.perf_counter() - t0
            return warm
    rest = {k: v for k, v in options.items() if k != "warm_budget"}
    if info:   # the time budget is for the whole solve, the warm stage included
        rest["time_budget"] = stage_budget.left(float(options.get("time_budget", 20.0)), time.perf_counter() - t0)
    if method == "auto":
        # the learned guess failed on a problem it covers: almost always a singular problem,
        # where the exact refinement after collocation does not succeed either (it succeeds
        # in well under a second when it does), so its budget is cut from 2 s
        failed_warm = bool(info.get("covered")) and not info.get("succeeded")
        sol = neighbours_bang = None
        spent_table = (0, 0)
        # (with less than ``TABLE_MIN_LEFT`` of the budget left, the table's first sequence alone
        # would end past it: the budget comes first)
        budget_left = float(options.get("time_budget", 20.0)) - (time.perf_counter() - t0)
        if (use_table and failed_warm and switch_time_applies(prob) and isinstance(warm_start, str)
                and warm_start == "default" and budget_left >= warm_routes.TABLE_MIN_LEFT):
            t_table = time.perf_counter()
            sol, spent_table = warm_routes.singular_table_route(prob, rest, info, col_opts)
            if sol is None and warm_routes.table_votes_bang_bang(info):
                sol, spent_nb = warm_routes.neighbour_sequences_route(prob, rest, info)
                spent_table = (spent_table[0] + spent_nb[0], spent_table[1] + spent_nb[1])
                if sol is not None and not sol.exact:
                    # a bang-bang answer, not an extremal, where the table expects one: the
                    # collocation route runs too, and the faster verified answer is kept
                    neighbours_bang, sol = sol, None
            if sol is None:      # its time comes out of the rest of the budget
                rest["time_budget"] = stage_budget.left(rest["time_budget"], time.perf_counter() - t_table)
        if sol is None and info and (float(options.get("time_budget", 20.0)) - (time.perf_counter() - t0)
                                     < (warm_routes.TABLE_MIN_LEFT if failed_warm else 0.0)):
            # the learned stage spent the budget: no route (building an NLP is not interruptible)
            what = ("The learned guess's candidates (and the tabled solutions' sequences, where they ran)" if prob.cones
                    else "The learned guess's candidates (and the singular table's routes, where they ran)")
            sol = stage_budget.budget_spent(prob, what, *spent_table, t0, "no time left for the default route")
            if neighbours_bang is not None:
                sol = warm_routes.faster_verified(sol, neighbours_bang)
        if sol is None:
            sol = auto_route.solve_auto(prob, guess, col_opts, rest, refine_cap=auto_route.REFINE_CAP_AFTER_WARM if failed_warm else 2.0,
                                        later=later, warm_info=info,
                                        warm_budget=float(options.get("warm_budget", warm_routes.WARM_BUDGET)))
            if neighbours_bang is not None:
                sol = warm_routes.faster_verified(sol, neighbours_bang)
            sol.nit += spent_table[0]
            sol.nfev += spent_table[1]
    elif prob.cones:
        sol = cone_routes.solve_indirect_cones(prob, guess, col_opts, rest)
        if method == "multiple-shooting":
            # the cone routes shoot over the whole slew (the touch junctions and the penalty
            # homotopy are single-shooting problems): say so rather than report "indirect" unasked
            sol.route = f"multiple-shooting asked; with cones the route shoots singly → {sol.route}"
    else:
        sol = multistart.solve_indirect(prob, method, guess, **rest)
    if method == "auto" and prob.cones and guess is None:
        sol = cone_routes.cone_free_challenger(prob, sol, options, col_opts, t0)
    if challenge and cone_challenge != "never":
        sol = cone_routes.cone_challenger(prob, sol, options, t0, gated=cone_challenge == "gated")
    if method == "auto":
        # under a budget, the eigenaxis slew it is compared with is planned on as many steps as
        # the time left pays for (the fallback's grid; a p-norm profile on the full grid had taken
        # 32 ms after a 0.3 s budget was spent, an outside replay, session 42)
        grid = (_fallback_grid(prob, t0 + float(options["time_budget"]) - time.perf_counter(), fine=True)
                if "time_budget" in options and _not_compared(prob) is None else None)
        sol = no_slower_than_eigenaxis(prob, sol, t0, n_grid=grid)
    if info:
        sol.warm_start = info
        if seq_failed is not None:      # (they ran after the learned guess: named after it)
            sol.nit += seq_failed[0]
            sol.nfev += seq_failed[1]
            rec = seq_failed[2]
            why = rec.get("error") or rec.get("skipped") or f"{rec.get('tried', 0)} tried, none verified"
            sol.route = f"the tabled solutions' sequences gave nothing ({why[:120]}) → {sol.route}"
        if warm is not None:
            sol.nit += warm.nit
            sol.nfev += warm.nfev
            what = "learned guess's structured candidates" if later is not None else "learned guess"
            sol.route = f"{what} failed ({warm.message[:160]}) → {sol.route}"
        sol.wall_time = time.perf_counter() - t0
    if fallback == "eigenaxis" and not sol.success:
        end = t0 + float(options["time_budget"]) + reserved if "time_budget" in options else math.inf
        sol = _eigenaxis_fallback(prob, sol, t0, reserved, end)
    elif not sol.success and method != "eigenaxis" and _fallback_flyable(prob):
        # a user with a slew to fly and no verified answer should learn that one is offered
        text = sol.message.rstrip()
        sol.message = (text + ("" if text.endswith((".", ")")) else ".")
                       + (" No verified answer: fallback='eigenaxis' would return the eigenaxis slew "
                          "(solvers.eigenaxis_slew; its time is baseline_tf where the budget left time to plan it), "
                          "checked by its own replay, not time-optimal." if _fallback_legs(prob) == 1 else
                          " No verified answer: fallback='eigenaxis' would return an eigenaxis slew through "
                          "waypoints around the keep-out cones, checked by its own replay, not time-optimal."))
    return sol


def _fallback_flyable(prob) -> bool:
    """Whether the eigenaxis fallback gives ``prob`` a slew to fly: a problem at rest, and with
    cones one whose eigenaxis path keeps clear of them (``baseline_time``'s rule) or for which a
    waypoint slew around them is found (``waypoint_slew.fallback_plan``; planned once, 2-25 ms,
    before the route's clock starts). Elsewhere no budget is kept for it and none is offered."""
    return eigenaxis_inapplicable(prob) is None and waypoint_slew.fallback_plan(prob) is not None


def _fallback_legs(prob) -> int:
    """Eigenaxis profiles the fallback plans for ``prob``: 1, or one a leg of its waypoint slew."""
    plan = waypoint_slew.fallback_plan(prob) if prob.is_rest_to_rest else "direct"
    return plan.n_waypoints + 1 if isinstance(plan, waypoint_slew.WaypointPlan) else 1


def _fallback_grid(prob, left=math.inf, legs=1, fine=False):
    """The fallback profile's angle steps, ``left`` seconds before the budget ends: the planner's
    default (``N_GRID``), or ``FALLBACK_GRID_PNORM_GYRO`` for a p-norm bound with a gyroscopic
    term (``fine``: ``method="eigenaxis"``'s own ``N_GRID_PNORM_GYRO``), fewer where they would not
    fit in ``left`` (``FALLBACK_STEP_COST``, not below ``FALLBACK_GRID_FLOOR``). ``legs``: profiles
    sharing ``left`` (a waypoint slew's; under a p-norm bound each is costed as one with a
    gyroscopic term, their axes being the legs')."""
    from .eigenaxis import _checked, _phase_plane, reference_problem
    from .eigenaxis_answer import N_GRID_PNORM_GYRO
    left = left / legs
    if not math.isinf(prob.torque_norm) and (legs > 1 or np.any(_phase_plane(_checked(reference_problem(prob)))[3])):
        kind, grid = "pnorm-gyro", N_GRID_PNORM_GYRO if fine else FALLBACK_GRID_PNORM_GYRO
    else:     # (a p-norm profile without a gyroscopic term is bang-coast-bang, exact on any grid)
        kind, grid = "no-gyro", N_GRID
    fixed, step = FALLBACK_STEP_COST[kind]
    fits = int((left - fixed) / step) if math.isfinite(left) else grid
    return max(FALLBACK_GRID_FLOOR[kind], min(grid, fits))


def _eigenaxis_fallback(prob, sol, t0, reserved=0.0, end=math.inf) -> SlewSolution:
    """``fallback="eigenaxis"``: where the route returned no verified answer (the time budget
    ran out, or nothing converged), the eigenaxis slew of a rest-to-rest problem (a pointing
    target at its reference attitude; with cones where its path clears them, else the slew through
    waypoints around them, ``waypoint_slew``) (``eigenaxis_answer``: what most spacecraft fly
    today, verified by its replay;
    12–24 ms for a per-axis bound, planned in the ``reserved`` seconds that ``solve`` kept out of
    the route's budget). ``sol`` unchanged, its message saying why, where the fallback does not
    apply or fails."""
    why = eigenaxis_inapplicable(prob)
    if why is not None:
        sol.message = f"{sol.message} (fallback 'eigenaxis' does not apply: {why}.)"
        return sol
    plan = waypoint_slew.fallback_plan(prob)
    try:
        if isinstance(plan, waypoint_slew.WaypointPlan):
            legs = plan.n_waypoints + 1
            eig = waypoint_slew.waypoint_answer(prob, n_grid=_fallback_grid(prob, end - time.perf_counter(), legs),
                                                plan=plan)
        else:
            eig = eigenaxis_answer(prob, n_grid=_fallback_grid(prob, end - time.perf_counter()))
            if (plan == "direct" and not eig.success and prob.cones and prob.is_rest_to_rest
                    and not eig.verification.get("cone_clearance", {}).get("passed", True)):
                # the direct path's samples cleared the cones (``direct_path_clear``) but the
                # certified margin between them did not: round the cones through waypoints
                plan = waypoint_slew.plan_waypoints(prob)
                if plan is not None:
                    wp = waypoint_slew.waypoint_answer(
                        prob, n_grid=_fallback_grid(prob, end - time.perf_counter(), plan.n_waypoints + 1), plan=plan)
                    eig = wp if wp.success else eig
    except ValueError as e:          # a zero slew: nothing to fly
        sol.message = f"{sol.message} (fallback 'eigenaxis' does not apply: {e}.)"
        return sol
    if not eig.success:
        sol.message = f"{sol.message} (fallback 'eigenaxis' failed: {eig.message[:200]})"
        return sol
    kept = f" (planned in the {1e3 * reserved:.0f} ms of the budget kept for it)" if reserved else ""
    what = "the eigenaxis slew" if eig.route.startswith("eigenaxis slew (") else eig.route
    eig.route = (f"{(sol.route or sol.method or 'the route')[:300]} → status {sol.status}, no verified "
                 f"time-optimal answer → fallback: {what}{kept}")
    eig.message = (f"{eig.message} Returned as the fallback (fallback='eigenaxis'); the time-optimal route "
                   f"ended with status {sol.status}: {sol.message}")
    eig.nit, eig.nfev = eig.nit + sol.nit, eig.nfev + sol.nfev
    eig.warm_start = sol.warm_start
    eig.wall_time = time.perf_counter() - t0
    return eig
