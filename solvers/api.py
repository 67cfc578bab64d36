"""``solvers.solve``: method dispatch, multi-start over candidates, verification.

Methods:

* ``"indirect"`` — single shooting. Per-axis bound: exact bang-bang extremal by the
  switch-time solver (structure from the guess, or from a smoothing continuation),
  then event-driven re-propagation. p-norm bound: shooting on the closed-form control,
  with norm continuation from p = 2 as fallback.
* ``"multiple-shooting"`` — the same routes with every shooting stage done on
  ``segments`` segments (default 4); the per-axis answer is polished by event-driven
  multiple shooting.
* ``"indirect"`` / ``"multiple-shooting"`` with keep-out cones — seeded by collocation
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
  ``_solve_auto``). ``route`` records the path taken.

Defaults of the indirect multi-start: per-axis 16 candidates at most and at least 8 before
stopping early, p-norm 8 and 3; a 20 s time budget. See ``solve``.

Several extremals can exist (mirror images of the 180° slew; a worse local optimum of
R5 at 29.135 s). The indirect multi-start tries candidates in order — the given guess and its own
candidates, the eigenaxis guess, its images under the problem's symmetries, the
per-axis switching-structure templates, the long-way eigenaxis, then seeded
perturbations — and returns the best verified one.
It stops when ``max_candidates`` have been tried; or, once ``min_candidates`` have
been tried, when ``enough`` have converged and the best final time was reached by at
least two of them; or when the ``time_budget`` runs out. After the first verified extremal
reached along a built-in candidate's smoothing path, each later per-axis candidate's attempt
stops at ``candidate_cap`` (``CANDIDATE_CAP``). ``SlewSolution.n_candidates`` says
how many it tried. A multi-start is no proof of global optimality: on random problems the
collocation-first route of ``"auto"`` found a faster extremal than the classical multi-start
in about 1 case in 13.
"""
from __future__ import annotations

import itertools
import math
import time
from dataclasses import replace
from typing import Optional, Tuple

import numpy as np

from slew_env import SlewProblem
from .attitude_bvp import AttitudeBVP
from .deadline import propagation_deadline
from .blas_threads import single_threaded_blas
from .kernel_loading import ensure_kernels
from .guesses import Guess, eigenaxis_guess, perturbed, structure_templates, symmetric_images
from .indirect import Attempt, per_axis_from_guess, pnorm_from_guess, solution_fields, solve_structure
from .shooting import newton_shoot
from .eigenaxis import eigenaxis_time
from .solution import (STATUS_BUDGET_EXHAUSTED, STATUS_MESSAGES, STATUS_NOT_CONVERGED, STATUS_SUCCESS,
                       STATUS_VERIFICATION_FAILED, STATUS_WORSE_THAN_BASELINE, SlewSolution)
from .switch_time import Structure
from .switch_time_opt import switch_time_applies
from .verify import DENSE_STEPS, make_check, verify

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
# longer than what is left: 0.8-1.8 ms late (per-axis) at budgets of 0.1-1 ms
FALLBACK_STEP_COST = {"no-gyro": (1.5e-3, 1.5e-6), "pnorm-gyro": (4.5e-3, 1.5e-5)}
FALLBACK_GRID_FLOOR = {"no-gyro": 1000, "pnorm-gyro": 250}
# a structure template's switch-time Newton stops when 10 iterations have not brought its residual
# below 0.1 of the first: on 100 random slews (seeds 1 and 2 of bench_solver, where the rule was
# chosen), 24 of 1,077 template attempts converged, none of them that slowly, and the failures
# spent 44 % of their iterations past that point (about 40 % of the classical route's time went to
# failing templates). On held-out seeds 4 and 5 (a review, 50 slews) it cut 4 of 423 stalled
# templates that would have converged, all to local extremals 15-95 % slower: no answer changed
TEMPLATE_STALL = (10, 0.1)
WARM_BUDGET = 1.0   # s: the learned guess's candidates (its continuation candidate rarely needs more)
# a cone model's candidate either converges in tens of milliseconds or not at all (90 % of the
# converged ones within 60 ms): each gets a short cap, and all of them a budget that costs
# little before the collocation route
CONE_WARM_BUDGET = 0.2
# auto's cone challenger (``_cone_challenger``) runs where the route's answer is slower than this
# multiple of the pointing-cones network's predicted tf ("gated", the default), always, or never.
# On 600 problems (seeds 5, 6, 7; runs/s27/challenger_*.json) it won 3 times: 45 % faster (the
# answer 1.77 x the prediction), 1.1 % (1.0087 x) and 3e-7 (0.988 x); the gate challenges 45 % of
# the answers and keeps the first two
CONE_CHALLENGE_GATE = 1.0
CONE_CHALLENGE_MODES = ("gated", "always", "never")
CONE_CANDIDATE_CAP = 0.06
# a cone warm start whose candidates are cheap to make (``RANKS_CANDIDATES``: the shipped one) has
# those with touches tried in order of their starting residual (``_ranked_by_starting_residual``),
# not in the model's order; the residuals may take this share of the warm start's budget (the
# shipped model's: 1.1 ms a problem, median, 1.3 ms p95, runs/s31/review/r_upfront_cost.py)
CONE_RANK_CANDIDATES = True
CONE_RANK_SHARE = 0.1
REFINE_CAP_AFTER_WARM = 0.6   # s: auto's exact refinement after collocation when the learned guess failed
# s: auto's bang-bang switch-time optimisation when no exact extremal refines a collocation
# answer (three rounds of 15-250 ms each on held-out singular problems)
BANG_BANG_BUDGET = 1.0
# s: the same with keep-out cones or a pointing target (its pulse rounds in turn, each with what is
# left): on 90 seed-100 cone problems 1 s left 11 answers to collocation that 4 s verified; on
# Melton's BP2 the round without pulses takes ~1 s and the one with 4 pairs, the answer, ~1.2 s
CONE_BANG_BANG_BUDGET = 3.0
# auto: a warm-start extremal this much slower than the model's predicted final time is
# challenged by the collocation route (``_challenge_learned_answer``), and so is one near a half turn
LOCAL_OPTIMUM_MARGIN = 0.015
HALF_TURN_MARGIN_DEG = 10.0
CHALLENGE_MIN_BUDGET = 1.0   # s: the collocation route takes 0.3-1 s; with less left, no challenge
# s: what a stage gets when the time budget is spent before it starts: it stops at its first
# check and reports the budget exhausted. (Stages used to get 0.5-1 s whatever was left, so
# that a budget of 0.05 s could take 3 s; ``benchmarks/bench_budget.py``)
MIN_STAGE_BUDGET = 1e-3
# s: the singular table's switch-time optimisations (all its sequences); then, only when the
# answer's sequence is a KKT point, the exact solver from its KKT costates (its own budget)
SINGULAR_TABLE_BUDGET = 0.3
SINGULAR_KKT_BUDGET = 0.1
# relative margin below the grid eigenaxis time (n_grid = 1000) under which an answer is faster
# than the eigenaxis slew without planning that slew: on 1,200 problems the grid time was at most
# 1.8e-5 above the slew's (``eigenaxis_answer``)
EIGENAXIS_GRID_MARGIN = 1e-3
# SLSQP iterations on each of the nearest singular answers' sequences; the fastest verified answer
# is kept. On the 101 singular held-out problems the table routes (the learned guess failed, ≥ 60 %
# of the 5 nearest singular; runs/s13/combo.py), against the collocation route's answer: the nearest sequence alone, 10
# iterations: tf a median 5e-6 and at most 4.3e-4 above, 13 without an answer; the best of the 3
# nearest: a median 3e-6, at most 1.8e-4, 1 without (20 iterations: twice the time for 2e-6)
SINGULAR_TABLE_ITERATIONS = 10
# where only 1 or 2 of the 5 nearest tabled problems are singular, the learned guess having failed
# (its candidates failed on 120 singular and 7 bang-bang held-out problems), the table still answers:
# 40 iterations a sequence (the best of 3 within 0.6 s) get within 3e-5 of the collocation route's
# answer, at a sixth of its time (runs/s15/vote_probe.py, lost_probe.py)
SINGULAR_UNCERTAIN_SHARE = 0.2
SINGULAR_UNCERTAIN_ITERATIONS = 40
SINGULAR_UNCERTAIN_BUDGET = 0.6
# where the singular table votes bang-bang and the learned candidates failed (7 of 1,000 held-out
# problems, 5 of them with an exact extremal), the switching sequences of the 8 nearest tabled
# solutions, their switch times optimised, then the exact solver from the KKT costates of each
# (``_neighbour_sequences_route``)
NEIGHBOUR_SEQUENCES = 8
NEIGHBOUR_SEQUENCE_BUDGET = 0.6
NEIGHBOUR_KKT_BUDGET = 0.1
# s: auto's indirect multi-start before collocation for a p-norm bound with p ≤ 2
# (``_pnorm_indirect_first``; it takes 0.1-0.4 s there, the collocation route 0.4-16 s)
PNORM_INDIRECT_BUDGET = 2.0
PNORM_INDIRECT_MIN_INERTIA_RATIO = 0.3   # the measured range (``_pnorm_indirect_first``)


# After the first verified extremal reached along the smoothing path of a built-in candidate
# (the eigenaxis guess and its variants), each later candidate's attempt stops after
# max(2 × the propagations of that first attempt, 200) propagations (solve's ``candidate_cap``).
# On 200 random per-axis slews (bench_solver seeds 1 and 2, all 16 candidates of each traced:
# runs/s22/cand_trace.py, policy_sim.py, not in the repository) the paths that ran longer ended
# in slower local extremals or failed: simulated, this rule returned the same verified answers
# as the uncapped multi-start on all 159 it verifies, with the median from 0.94 to 0.66 s (a cap
# of 0.5× lost 4 answers, by up to 58 %); A/B on seeds 3 and 4: identical verified answers.
CANDIDATE_CAP = (2.0, 200.0)


def _checked_cap(cap) -> Tuple[float, float]:
    """``candidate_cap`` as a ``(multiple, floor)`` pair of floats, or a ``ValueError``."""
    bad = ValueError(f"candidate_cap: must be None or a pair (multiple, floor) of numbers >= 0, got {cap!r}")
    if isinstance(cap, (str, bytes, dict, bool)):
        raise bad
    try:
        items = list(cap)
    except TypeError:
        raise bad from None
    if len(items) != 2 or any(isinstance(v, (bool, np.bool_)) for v in items):
        raise bad
    try:
        mult, floor = (float(v) for v in items)
    except (TypeError, ValueError):
        raise bad from None
    if not (mult >= 0 and floor >= 0):        # rejects NaN too
        raise bad
    return mult, floor


def _left(budget, spent) -> float:
    """Seconds left of ``budget`` after ``spent``, at least ``MIN_STAGE_BUDGET``."""
    return max(MIN_STAGE_BUDGET, float(budget) - float(spent))


def _structure_from_guess(g: Guess, bvp) -> Optional[Structure]:
    if g.switch_times is None:
        return None
    ev = sorted((float(t) / bvp.tau, i) for i in range(3) for t in g.switch_times[i])
    if g.u_first is not None:
        s0 = np.where(g.u_first == 0, 1.0, g.u_first)
    else:
        z, _ = g.to_nondim(bvp)
        y0, _ = bvp.initial(z)
        s0 = bvp.initial_signs(y0)
    return Structure(np.asarray(s0, float), np.array([e[1] for e in ev], dtype=np.int64),
                     np.array([e[0] for e in ev]))


def _candidates(bvp, guess, max_candidates, seed, per_axis, unusable=None, guess_only=False):
    """Yields ``(z, T, structure, source)`` in the order they are tried.

    ``unusable``: ``None`` (a guess that cannot be put in the solver's gauge, such as zero
    costates, is a ``ValueError``: the user's bad input), or a list to which such candidates
    are added as ``"source: reason"`` and skipped, each using up its slot (a model's guesses:
    one degenerate candidate must not stop the solve). ``guess_only``: the guess and its
    candidates, nothing after them (a deferred candidate that gives nothing leaves its slot
    empty rather than to a classical candidate).

    Order: the user's guess and its candidates; the eigenaxis guess (smoothing
    continuation); per-axis only, the structure templates around it (cheap: one
    switch-time Newton each); the long-way eigenaxis; images of the eigenaxis guess
    under the problem's symmetries; seeded perturbations of the eigenaxis guess.
    """
    seen = []

    def fresh(z, st):
        key = (np.round(z, 6).tobytes(), None if st is None else (st.axes.tobytes(), st.signs0.tobytes()))
        if key in seen:
            return False
        seen.append(key)
        return True

    count = 0
    if guess is not None:
        for g in guess.iter_all(errors=unusable):
            if count >= max_candidates:
                break       # (deferred candidates past the limit are never computed)
            try:
                z, T = g.to_nondim(bvp)
                st = _structure_from_guess(g, bvp)
            except Exception as e:      # noqa: BLE001 - a model's candidate: any failure skips it
                if unusable is None:
                    raise
                unusable.append(f"{g.source}: unusable guess ({e})")
                count += 1
                continue
            if fresh(z, st):
                yield z, T, st, g.source
                count += 1
    if count >= max_candidates or guess_only:
        return
    rng = np.random.default_rng(seed)
    g = eigenaxis_guess(bvp)
    z0, T0 = g.to_nondim(bvp)
    if count < max_candidates and fresh(z0, None):
        yield z0, T0, None, g.source
        count += 1
    if per_axis:
        for zt, Tt, (s0, ax, tt), name in structure_templates(bvp, z0, T0, rng):
            if count >= max_candidates:
                return
            st = Structure(s0, ax, tt)
            if fresh(zt, st):
                yield zt, Tt, st, name
                count += 1
    gl = eigenaxis_guess(bvp, long_way=True)
    zl, Tl = gl.to_nondim(bvp)
    extra = [(zl, Tl, gl.source)] + [(zi, Ti, "eigenaxis-image") for zi, Ti in symmetric_images(bvp, z0, T0)]
    for z, T, src in extra:
        if count >= max_candidates:
            return
        if fresh(z, None):
            yield z, T, None, src
            count += 1
    k = 0
    while count < max_candidates and k < 10 * max_candidates:
        scale = (0.2, 0.4, 0.6)[k % 3]
        zp, Tp = perturbed(z0, T0, rng, scale)
        k += 1
        if fresh(zp, None):
            yield zp, Tp, None, f"eigenaxis-perturbed({scale:g})"
            count += 1


def _polish_multiple(bvp, a: Attempt, segments):
    """Event-driven multiple shooting from an exact switch-time answer (consistency polish)."""
    bvp.set_mode("bang")
    r = newton_shoot(bvp, a.z, a.T, segments=segments, tol=1e-11, max_step=0.1)
    if r.success and abs(r.T - a.T) < 1e-8 * a.T:
        a.z, a.T = r.p, r.T
        a.trajectory = None   # recorded for the previous (z, T)
        a.route += f" + event-driven multiple shooting ({segments} segments)"
    a.nit += r.nit
    a.nfev += r.nfev
    return a


def solve(problem, method="auto", guess=None, warm_start="default", **options) -> SlewSolution:
    """Time-optimal slew of ``problem`` (``SlewProblem`` or dict).

    ``method``: ``"auto"`` (default), ``"indirect"``, ``"multiple-shooting"`` or
    ``"collocation"`` (see the module docstring). ``guess``: a ``solvers.Guess``.

    ``warm_start``: where the first guess comes from when ``guess`` is not given
    (indirect routes and ``"auto"``): ``"default"`` (the shipped full-attitude model, for the
    problems in its family; with keep-out cones and ``method="auto"``, the 2 nearest tabled
    solutions of the shipped pointing-cones warm start join collocation's starts, and the warm
    start challenges the default route's answer afterwards, replacing it only with a faster
    verified extremal: ``cone_challenge``, below), ``"pointing-cones"`` (that warm start as the first
    guess: opt-in, faster but often a slower local extremal, see ``docs/WARMSTART.md``), a model object (``solvers.warmstart.WarmStartModel``,
    ``NearestNeighbourModel`` or anything with ``covers(problem)`` and ``guess(problem)``),
    a model file path, or ``None``. The learned candidates are tried alone first (the first
    verified extremal that is not slower than the eigenaxis slew wins); if none is
    verified, the classical route runs as if there were no model. ``SlewSolution.warm_start``
    records what happened and ``guess`` which candidate won.

    Options of the indirect routes: ``segments`` (multiple shooting, default 4; the cone
    penalty route of an indirect solve with active cones: default 32, at least 2),
    ``max_candidates`` (default 16 per-axis, 8 p-norm), ``min_candidates`` (tried before
    stopping early, default 8 per-axis, 3 p-norm), ``enough`` (converged candidates before
    stopping early, default 2), ``candidate_cap`` (per-axis: after the first verified extremal reached along a
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
    milliseconds, no collocation; ``_singular_table_route``); where the table's vote is
    uncertain (1 or 2 of the 5 nearest singular), the same, then a collocation check for an exact
    extremal (a few tenths of a second); where it votes bang-bang (fewer singular), the 8 nearest
    tabled solutions' switching sequences, optimised, then the exact solver from their KKT
    costates (``_neighbour_sequences_route``: an extremal in tenths of a second without
    collocation; a bang-bang answer that is not one must beat the collocation route's answer,
    which then runs too); False: the collocation route instead.
    ``fallback`` (default None): ``"eigenaxis"`` returns, where the route ends without a verified
    answer (the ``time_budget`` ran out, or nothing converged), the eigenaxis slew of a
    rest-to-rest full-attitude problem without cones (``method="eigenaxis"``, verified by its
    replay, not time-optimal; 12–24 ms for a per-axis bound): a flyable answer for on-board use
    under a hard budget. With a ``time_budget``, the route gets that budget less the fallback's
    planning time (``FALLBACK_RESERVE``, 25 ms; at most half the budget), so that either answer
    is there within the budget, up to the route's own overshoot (one Newton iteration or IPOPT
    iteration); where less is left than its default profile takes, the fallback plans on fewer
    angle steps (``_fallback_grid``), down to a floor that is late below a few milliseconds of
    budget (docs/SOLVER.md, "Short budgets with the fallback"). The budget's clock starts after the compiled kernels of
    the problem's kind are loaded (``kernel_loading``; the first solve of each kind in a process, reported as
    ``kernel_load_time``; ``solvers.load_kernels`` does it at start-up), and collocation builds
    no NLP the budget left cannot pay for (``collocation.NoTimeToBuild``). For a p-norm bound with
    a gyroscopic term the fallback's profile has at most 1,000 angle steps
    (``FALLBACK_GRID_PNORM_GYRO``; at most 1.1e-4 slower than ``method="eigenaxis"``'s 4,000).
    The route's message says why the fallback was needed.
    ``local_optimum_check`` (default True): ``auto`` runs the collocation route as well when the
    learned guess's extremal is likely a local optimum (more than 1.5 % above the model's
    predicted time, or a slew within 10° of a half turn; ``_challenge_learned_answer``) and keeps
    the faster answer; False: the learned answer at once (milliseconds, for on-board use).
    ``cone_challenge`` (``auto`` with cones and the default warm start): ``"gated"`` (default) runs
    the pointing-cones warm start after the route only where the answer is slower than the
    network's predicted final time (``CONE_CHALLENGE_GATE``; about 0.1 s where it runs, on 45 % of
    random cone problems), ``"always"``, or ``"never"``.

    A verified extremal slower than the eigenaxis slew of the same problem (the
    baseline, ``SlewSolution.baseline_tf``) is a local optimum: it is returned with
    ``success=False`` and status 4, never as the answer.
    """
    with single_threaded_blas():
        return _solve(problem, method, guess, warm_start, **options)


def _solve(problem, method, guess, warm_start, **options) -> SlewSolution:
    """``solve`` with the BLAS libraries at one thread (``blas_threads``)."""
    prob = SlewProblem.from_dict(problem)   # a SlewProblem passes through
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
        options["candidate_cap"] = _checked_cap(options["candidate_cap"])
    _check_options(options)
    use_table = options.pop("singular_table", True)
    if not isinstance(use_table, bool):
        raise ValueError(f"singular_table: expected True or False, got {use_table!r}")
    check_local = options.pop("local_optimum_check", True)
    if not isinstance(check_local, bool):
        raise ValueError(f"local_optimum_check: expected True or False, got {check_local!r}")
    cone_challenge = options.pop("cone_challenge", "gated")
    if not (isinstance(cone_challenge, str) and cone_challenge in CONE_CHALLENGE_MODES):
        raise ValueError(f"cone_challenge: expected one of {', '.join(map(repr, CONE_CHALLENGE_MODES))}, "
                         f"got {cone_challenge!r}")
    fallback = options.pop("fallback", None)
    if not (fallback is None or (isinstance(fallback, str) and fallback in FALLBACKS)):
        raise ValueError(f"fallback: expected None or 'eigenaxis', got {fallback!r}")
    if fallback is not None and method in ("collocation", "eigenaxis"):
        raise ValueError(f"fallback: applies to the 'auto', 'indirect' and 'multiple-shooting' routes, "
                         f"not method={method!r}")
    reserved = 0.0
    if fallback == "eigenaxis" and "time_budget" in options and _fallback_inapplicable(prob) is None:
        # the fallback is planned after the route: its time comes out of the route's budget, so
        # that the answer, whichever it is, is there within the budget
        budget = float(options["time_budget"])
        reserved = min(FALLBACK_RESERVE, FALLBACK_RESERVE_SHARE * budget)
        options["time_budget"] = budget - reserved
    col_opts = options.pop("collocation", None) or {}
    if not isinstance(col_opts, dict):
        raise ValueError(f"collocation: expected a dict of solve_collocation options, got {col_opts!r}")
    _check_collocation_options(col_opts)
    if method != "eigenaxis":
        # an infeasible problem is an input error, found before any loading; the grid test
        # (about 0.1 s for three mutually overlapping cones) is remembered, not repeated inside
        # the time budget
        from .collocation import check_cones_passable
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
    sol.kernel_load_time = load
    return sol


MAX_SEGMENTS = 1000          # multiple shooting's segments (each a column block of the Jacobian)
MAX_DENSE_STEPS = 1_000_000  # n_dense: steps of the dense record


def _int_option(options, key, lo, hi):
    if key in options:
        v = options[key]
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
            raise ValueError(f"{key}: expected an integer from {lo} to {hi:,}, got {v!r:.80}")


def _is_real(v) -> bool:
    """A real number, not a boolean (which Python would take as 0 or 1)."""
    return not isinstance(v, bool) and isinstance(v, (int, float, np.floating, np.integer))


def _positive_option(options, key):
    if key in options:
        v = options[key]
        if not (_is_real(v) and math.isfinite(v) and v > 0):
            raise ValueError(f"{key}: expected a positive finite number, got {v!r:.80}")


def _check_options(options) -> None:
    """``solve``'s numeric options, checked whatever route runs (a route that does not use one
    must not let a bad value through unnoticed): ``ValueError`` naming the option."""
    _int_option(options, "segments", 1, MAX_SEGMENTS)
    _int_option(options, "n_dense", 1, MAX_DENSE_STEPS)
    for key in ("max_candidates", "min_candidates", "enough"):
        _int_option(options, key, 1, 10_000)
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
        if not _is_real(v) or not (math.isfinite(v) or v == math.inf) or (
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
    if guess is not None or _pnorm_indirect_first(prob):
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
        from .eigenaxis_answer import eigenaxis_answer
        return eigenaxis_answer(prob)
    t0 = time.perf_counter()
    warm = None
    info = {}
    # auto with cones and the shipped models: the default route answers, and the shipped
    # pointing-cones warm start challenges that answer afterwards (``_cone_challenger``)
    challenge = (method == "auto" and bool(prob.cones) and guess is None and isinstance(warm_start, str)
                 and warm_start == "default")
    if challenge and "extra_starts" not in col_opts:
        starts = _cone_neighbour_starts(prob)
        col_opts = dict(col_opts, extra_starts=starts)
        if starts and "n_starts" not in col_opts:
            col_opts["n_starts"] = CONE_OWN_STARTS_WITH_NEIGHBOURS
    later = None
    if guess is None and not challenge:
        # auto on a full-attitude per-axis problem: the learned candidates that carry a switching
        # structure (milliseconds) first; its continuation candidates after collocation, unless
        # collocation shows a singular arc, where they cannot converge (``_solve_auto``)
        split = method == "auto" and switch_time_applies(prob)
        warm, info, later = _warm_start(prob, method, warm_start, options, split=split)
        if warm is not None and warm.success:
            if method == "auto" and check_local:
                warm = _challenge_learned_answer(prob, warm, info, col_opts, options, t0)
            warm.wall_time = time.perf_counter() - t0
            return warm
    rest = {k: v for k, v in options.items() if k != "warm_budget"}
    if info:   # the time budget is for the whole solve, the warm stage included
        rest["time_budget"] = _left(float(options.get("time_budget", 20.0)), time.perf_counter() - t0)
    if method == "auto":
        # the learned guess failed on a problem it covers: almost always a singular problem,
        # where the exact refinement after collocation does not succeed either (it succeeds
        # in well under a second when it does), so its budget is cut from 2 s
        failed_warm = bool(info.get("covered")) and not info.get("succeeded")
        sol = neighbours_bang = None
        spent_table = (0, 0)
        if (use_table and failed_warm and switch_time_applies(prob) and isinstance(warm_start, str)
                and warm_start == "default"):
            t_table = time.perf_counter()
            sol, spent_table = _singular_table_route(prob, rest, info, col_opts)
            if sol is None and _table_votes_bang_bang(info):
                sol, spent_nb = _neighbour_sequences_route(prob, rest, info)
                spent_table = (spent_table[0] + spent_nb[0], spent_table[1] + spent_nb[1])
                if sol is not None and not sol.exact:
                    # a bang-bang answer, not an extremal, where the table expects one: the
                    # collocation route runs too, and the faster verified answer is kept
                    neighbours_bang, sol = sol, None
            if sol is None:      # its time comes out of the rest of the budget
                rest["time_budget"] = _left(rest["time_budget"], time.perf_counter() - t_table)
        if sol is None and info and float(options.get("time_budget", 20.0)) <= time.perf_counter() - t0:
            # the learned stage spent the budget: no route (building an NLP is not interruptible)
            sol = _budget_spent(prob, "The learned guess's candidates (and the singular table's routes, where "
                                "they ran)", *spent_table, t0, "no time left for the default route")
            if neighbours_bang is not None:
                sol = _faster_verified(sol, neighbours_bang)
        if sol is None:
            sol = _solve_auto(prob, guess, col_opts, rest, refine_cap=REFINE_CAP_AFTER_WARM if failed_warm else 2.0,
                              later=later, warm_info=info,
                              warm_budget=float(options.get("warm_budget", WARM_BUDGET)))
            if neighbours_bang is not None:
                sol = _faster_verified(sol, neighbours_bang)
            sol.nit += spent_table[0]
            sol.nfev += spent_table[1]
    elif prob.cones:
        sol = _solve_indirect_cones(prob, guess, col_opts, rest)
    else:
        sol = _solve_indirect(prob, method, guess, **rest)
    if challenge and cone_challenge != "never":
        sol = _cone_challenger(prob, sol, options, t0, gated=cone_challenge == "gated")
    if method == "auto":
        sol = _no_slower_than_eigenaxis(prob, sol, t0)
    if info:
        sol.warm_start = info
        if warm is not None:
            sol.nit += warm.nit
            sol.nfev += warm.nfev
            what = "learned guess's structured candidates" if later is not None else "learned guess"
            sol.route = f"{what} failed ({warm.message[:160]}) → {sol.route}"
        sol.wall_time = time.perf_counter() - t0
    if fallback == "eigenaxis" and not sol.success:
        end = t0 + float(options["time_budget"]) + reserved if "time_budget" in options else math.inf
        sol = _eigenaxis_fallback(prob, sol, t0, reserved, end)
    return sol


def _fallback_inapplicable(prob):
    """Why the eigenaxis slew is not an answer to ``prob`` (it needs a rest-to-rest
    full-attitude problem without cones), or ``None``: where the fallback does not apply, and
    where ``auto`` does not compare its answer with it (``_no_slower_than_eigenaxis``)."""
    if prob.cones:
        return "keep-out cones"
    if prob.qf is None:
        return "a pointing target"
    return None if prob.is_rest_to_rest else "non-zero rates"


def _fallback_grid(prob, left=math.inf):
    """The fallback profile's angle steps, ``left`` seconds before the budget ends: the planner's
    default (``N_GRID``), or ``FALLBACK_GRID_PNORM_GYRO`` for a p-norm bound with a gyroscopic
    term, fewer where they would not fit in ``left`` (``FALLBACK_STEP_COST``, not below
    ``FALLBACK_GRID_FLOOR``)."""
    from .eigenaxis import _checked, _phase_plane
    from .eigenaxis_answer import N_GRID
    if not math.isinf(prob.torque_norm) and np.any(_phase_plane(_checked(prob))[3]):
        kind, grid = "pnorm-gyro", FALLBACK_GRID_PNORM_GYRO
    else:     # (a p-norm profile without a gyroscopic term is bang-coast-bang, exact on any grid)
        kind, grid = "no-gyro", N_GRID
    fixed, step = FALLBACK_STEP_COST[kind]
    fits = int((left - fixed) / step) if math.isfinite(left) else grid
    return max(FALLBACK_GRID_FLOOR[kind], min(grid, fits))


def _eigenaxis_fallback(prob, sol, t0, reserved=0.0, end=math.inf) -> SlewSolution:
    """``fallback="eigenaxis"``: where the route returned no verified answer (the time budget
    ran out, or nothing converged), the eigenaxis slew of a rest-to-rest full-attitude problem
    without cones (``eigenaxis_answer``: what most spacecraft fly today, verified by its replay;
    12–24 ms for a per-axis bound, planned in the ``reserved`` seconds that ``solve`` kept out of
    the route's budget). ``sol`` unchanged, its message saying why, where the fallback does not
    apply or fails."""
    why = _fallback_inapplicable(prob)
    if why is not None:
        sol.message = f"{sol.message} (fallback 'eigenaxis' does not apply: {why}.)"
        return sol
    from .eigenaxis_answer import eigenaxis_answer
    try:
        eig = eigenaxis_answer(prob, n_grid=_fallback_grid(prob, end - time.perf_counter()))
    except ValueError as e:          # a zero slew: nothing to fly
        sol.message = f"{sol.message} (fallback 'eigenaxis' does not apply: {e}.)"
        return sol
    if not eig.success:
        sol.message = f"{sol.message} (fallback 'eigenaxis' failed: {eig.message[:200]})"
        return sol
    kept = f" (planned in the {1e3 * reserved:.0f} ms of the budget kept for it)" if reserved else ""
    eig.route = (f"{(sol.route or sol.method or 'the route')[:300]} → status {sol.status}, no verified "
                 f"time-optimal answer → fallback: the eigenaxis slew{kept}")
    eig.message = (f"{eig.message} Returned as the fallback (fallback='eigenaxis'); the time-optimal route "
                   f"ended with status {sol.status}: {sol.message}")
    eig.nit, eig.nfev = eig.nit + sol.nit, eig.nfev + sol.nfev
    eig.warm_start = sol.warm_start
    eig.wall_time = time.perf_counter() - t0
    return eig


def _challenge_learned_answer(prob, warm, info, col_opts, options, t0) -> SlewSolution:
    """``auto``, where the warm start's verified extremal is likely a local optimum, the
    collocation route runs too, and its answer replaces it if faster (an exact extremal; or a
    verified slew that is not one, such as a singular problem's switch-time answer, faster
    beyond its ``tf_tol``). Two signs (only for a model that predicts the optimal time,
    ``info["predicted_tf"]``):

    * the answer is more than ``LOCAL_OPTIMUM_MARGIN`` slower than that prediction (a neighbour's
      solution led to another extremal). The shipped network predicts the optimal time to 0.1 %
      (median); on 1,948 exact answers of held-out and audit problems, 10 were more than 1.5 %
      above it, and 2 of those were local optima 4.9 % and 1.2 % slower than the best known;
    * a slew within ``HALF_TURN_MARGIN_DEG`` of 180°, where the short and the long way round and
      their mirror images are nearly degenerate extremals that the network cannot tell apart: on
      123 such held-out and audit problems the warm start's answer was more than 1e-4 slower
      than the best known on 8 (up to 1.2 %), the collocation route on none.

    ``info["local_optimum_check"]`` records the check; ``local_optimum_check=False`` turns it off."""
    pred = info.get("predicted_tf")
    if not (pred and math.isfinite(pred)):
        return warm
    slow = warm.tf > pred * (1.0 + LOCAL_OPTIMUM_MARGIN)
    # (measured on per-axis rest-to-rest slews without rate limits, the shipped model's family)
    half_turn = (prob.qf is not None and prob.is_rest_to_rest and math.isinf(prob.torque_norm)
                 and prob.rate_max is None and math.degrees(prob.slew_angle) > 180.0 - HALF_TURN_MARGIN_DEG)
    if not (slow or half_turn):
        return warm
    reason = " and ".join(r for r, on in (("slower than predicted", slow), ("near a half turn", half_turn)) if on)
    rec = info["local_optimum_check"] = {"predicted_tf": float(pred), "tf": float(warm.tf), "won": False,
                                         "reason": reason}
    left = float(options.get("time_budget", 20.0)) - (time.perf_counter() - t0)
    if left < CHALLENGE_MIN_BUDGET:     # a verified answer is in hand: the budget comes first
        rec["skipped"] = f"time_budget: {max(left, 0.0):.3g} s left, the collocation route needs {CHALLENGE_MIN_BUDGET:g} s"
        return warm
    rest = {k: v for k, v in options.items() if k != "warm_budget"}
    rest["time_budget"] = left
    t_ch = time.perf_counter()
    try:
        ch = _solve_auto(prob, None, col_opts, rest)
    except Exception as e:   # noqa: BLE001 - the verified answer in hand stands; the failure is recorded
        rec.update(error=f"{type(e).__name__}: {e}"[:300], time_s=time.perf_counter() - t_ch)
        return warm
    rec.update(challenger_tf=float(ch.tf) if ch.success else None, challenger_exact=bool(ch.success and ch.exact),
               time_s=time.perf_counter() - t_ch)
    # an exact extremal that is faster; or a verified answer that is not an extremal (a singular
    # problem's switch-time answer) but faster beyond its own tf_tol: the learned extremal was a
    # local optimum, and the faster feasible slew is the better answer
    tol = ch.tf_tol if ch.success and math.isfinite(ch.tf_tol) else math.inf
    if ch.success and (ch.tf < warm.tf * (1.0 - 1e-9) if ch.exact else ch.tf + tol < warm.tf):
        rec["won"] = True
        info["succeeded"] = False      # the answer is the challenger's, not the learned guess's
        what = "a faster extremal" if ch.exact else f"a faster slew ({ch.method}, not an extremal)"
        why = (f"{warm.tf / pred - 1:.1%} above the model's predicted {pred:.9g}" if slow else
               f"a slew of {math.degrees(prob.slew_angle):.2f}°, near a half turn, where it may be a local optimum")
        ch.route = f"learned guess ({warm.guess}) gave {warm.tf:.9g}, {why} → the collocation route found {what}: {ch.route}"
        ch.message = f"{ch.message} Faster than the learned guess's extremal ({warm.tf:.9g}), a local optimum."
        return _replace_answer(ch, warm, info)
    warm.nit += ch.nit
    warm.nfev += ch.nfev
    seen = f"{ch.tf:.9g}" + ("" if ch.exact else f" ({ch.method})") if ch.success else "no answer"
    warm.route = f"{warm.route} (checked, {reason}: the collocation route gave {seen}, not faster)"
    if ch.success and ch.exact:
        warm.candidates_tf = sorted(set(warm.candidates_tf or []) | {round(ch.tf, 9)})
    return warm


def _guess_alone(prob, guess, options, budget, method="indirect", with_candidates=True) -> SlewSolution:
    """``guess`` (and its candidates, unless not ``with_candidates``) alone by the indirect
    route, no classical candidates, within ``budget`` s: the first verified extremal that is not
    slower than the eigenaxis slew wins (a warm start's candidates, best first)."""
    n = 1 + len(guess.candidates) if with_candidates else 1
    # model_guess: a candidate the solver cannot use is a failed candidate, not an error
    opts = dict(options, max_candidates=n, min_candidates=1, enough=1, time_budget=budget, model_guess=True,
                guess_only=True)
    return _solve_indirect(prob, method, guess, first_verified=True, **opts)


def _exact_from_kkt(prob, bang, kkt_guess, options, budget, prefix) -> Optional[SlewSolution]:
    """The exact extremal from a switch-time answer's KKT costates (``kkt_guess``), if the exact
    solver certifies one no slower than ``bang`` within ``budget`` s (the optimum was bang-bang
    after all), with ``bang``'s work counted and the route through it; else ``None``, with the
    attempt's work counted in ``bang`` and its outcome in ``bang.message``."""
    if kkt_guess is None or not budget > 0.05:
        return None
    ex = _guess_alone(prob, kkt_guess, options, budget)
    if ex.success and ex.tf <= bang.tf * (1.0 + 1e-9):
        ex.route = f"{prefix} → {bang.route} → exact extremal from its KKT costates: {ex.route}"
        ex.nit += bang.nit
        ex.nfev += bang.nfev
        return ex
    bang.nit += ex.nit
    bang.nfev += ex.nfev
    bang.message += f" The exact solver from its KKT costates: {ex.message[:200]}"
    return None


def _singular_table_route(prob, options, info, col_opts=None, exact_check=True):
    """``(answer or None, (nit, nfev) spent)``: ``auto`` after the default model's guess failed.
    If most of the shipped singular table's nearest problems are singular
    (``warmstart.singular_table``), the fastest bang-bang slew with the switching sequence of a
    near singular answer (no collocation), faster than the eigenaxis slew; the exact solver is
    tried from its KKT costates when its sequence is a KKT point (a bang-bang optimum is
    certified there). Where only a few are (at least ``SINGULAR_UNCERTAIN_SHARE``, below the
    table's vote), the same answer with more iterations, then collocation (``col_opts``) checks
    for an exact extremal (``_exact_after_uncertain_table``; not with ``exact_check=False``, the
    table's answers alone, as ``slew evaluate`` measures them). ``None`` when the table does not
    apply or gives no such answer; ``info["singular_table"]`` records what happened (a damaged
    table file: the error; ``uncertain`` and ``exact_check`` for the second tier)."""
    from . import warmstart
    t0 = time.perf_counter()
    try:
        table = warmstart.default_singular_table()
        if table is None or table.covers(prob):
            return None, (0, 0)
        share, sequences = table.query(prob)
    except (OSError, ValueError, IndexError) as e:   # a damaged shipped file: the route without it
        info["singular_table"] = {"error": f"{type(e).__name__}: {e}"[:300]}
        return None, (0, 0)
    rec = info["singular_table"] = {"share": share, "vote": table.vote, "used": False}
    if share < min(table.vote, SINGULAR_UNCERTAIN_SHARE):
        return None, (0, 0)
    uncertain = share < table.vote
    rec["uncertain"] = uncertain
    from .switch_time_opt import bang_bang_from_sequences
    budget = float(options.get("time_budget", 20.0))

    def optimise(max_iter, time_budget):
        return bang_bang_from_sequences(prob, sequences, time_budget=time_budget, tols=options.get("tols"),
                                        tf_rel_tol=table.tf_rel_tol, source="the singular table's neighbour",
                                        max_iter=max_iter)

    bang, kkt_guess, spent = optimise(SINGULAR_UNCERTAIN_ITERATIONS if uncertain else SINGULAR_TABLE_ITERATIONS,
                                      min(SINGULAR_UNCERTAIN_BUDGET if uncertain else SINGULAR_TABLE_BUDGET, budget))
    if bang is None and not uncertain:
        # none verified after 10 iterations a sequence (a long singular arc can need more: held-out
        # problem 790, J = I over 131°, verifies at 40): the uncertain tier's iterations, once
        left = min(SINGULAR_UNCERTAIN_BUDGET, budget - (time.perf_counter() - t0))
        if left > 0.05:
            bang, kkt_guess, again = optimise(SINGULAR_UNCERTAIN_ITERATIONS, left)
            if bang is not None:     # the answer counts both passes' work
                bang.nit += spent[0]
                bang.nfev += spent[1]
            spent = (spent[0] + again[0], spent[1] + again[1])
            rec["retried"] = True
    rec["time_s"] = time.perf_counter() - t0
    if bang is None:
        return None, spent
    # faster than the eigenaxis slew, or no answer here (the collocation route runs instead)
    faster = _faster_than_eigenaxis(prob, bang)
    rec["time_s"] = time.perf_counter() - t0
    if not faster:
        return None, spent
    prefix = f"singular table ({share:.0%} of the {table.k} nearest problems singular)"
    ex = _exact_from_kkt(prob, bang, kkt_guess, options,
                         min(SINGULAR_KKT_BUDGET, budget - (time.perf_counter() - t0)), prefix)
    if ex is not None:
        rec.update(used=True, time_s=time.perf_counter() - t0)
        return ex, (0, 0)
    if uncertain and exact_check:
        # 3 or 4 of the 5 nearest problems have a bang-bang optimum: collocation (a few tenths
        # of a second without cones) says whether this one has a singular arc; where it shows
        # none, its exact refinement is tried, and a certified extremal no slower wins
        ex = _exact_after_uncertain_table(prob, bang, col_opts or {}, options,
                                          budget - (time.perf_counter() - t0), prefix, rec)
        if ex is not None:
            rec.update(used=True, time_s=time.perf_counter() - t0)
            return ex, (0, 0)
    if uncertain:
        prefix += ", uncertain" + (f"; collocation's check for an exact extremal: {rec['exact_check'][:160]}"
                                   if rec.get("exact_check") else "")
    bang.route = f"{prefix} → {bang.route}"
    bang.wall_time = time.perf_counter() - t0
    rec.update(used=True, time_s=bang.wall_time)
    return bang, (0, 0)


def _faster_than_eigenaxis(prob, answer) -> bool:
    """Whether a bang-bang ``answer`` of a rest-to-rest full-attitude problem is faster than its
    eigenaxis slew (``_eigenaxis_unless_faster``: the grid time, or the slew itself when near it);
    if so its ``baseline_tf`` and ``eigenaxis_baseline`` check are set."""
    baseline, eig = _eigenaxis_unless_faster(prob, answer.tf)
    if eig is not None:
        if not (eig.success and answer.tf < eig.tf):
            return False
        baseline = eig.tf
    answer.baseline_tf = baseline
    answer.verification["eigenaxis_baseline"] = make_check(answer.tf / baseline - 1.0, 0.0, True)
    return True


def _neighbour_sequences_route(prob, options, info) -> Tuple[Optional[SlewSolution], Tuple[int, int]]:
    """``(answer or None, (nit, nfev) spent)``: ``auto`` after the default model's candidates
    failed and the singular table voted bang-bang (``_table_votes_bang_bang``). The switching
    sequences of the ``NEIGHBOUR_SEQUENCES`` nearest tabled solutions, in turn: the switch
    times optimised (``bang_bang_from_sequences``), then the exact solver from that answer's
    KKT costates. The neighbours' own costates failed by Newton's method; their sequences still
    lead to the extremal, since optimising switch times converges from far worse times than the
    shooting Newton. The first certified extremal (no slower than its sequence's answer) wins;
    without one, the fastest verified bang-bang answer (``method="switch-time"``, not an
    extremal), which ``solve`` compares with the collocation route's answer. ``None`` when the
    default table is missing or does not cover ``prob``, or nothing is verified within
    ``NEIGHBOUR_SEQUENCE_BUDGET``; ``info["neighbour_sequences"]`` records what happened."""
    from . import warmstart
    from .switch_time_opt import bang_bang_from_sequences
    t0 = time.perf_counter()
    rec = info["neighbour_sequences"] = {"used": False}
    try:
        table = getattr(warmstart.default_warm_start(), "table", None)
        if table is None or table.covers(prob):
            rec["skipped"] = "the default table does not cover the problem"
            return None, (0, 0)
        g = table.guess(prob, k=NEIGHBOUR_SEQUENCES)
    except (OSError, ValueError, IndexError) as e:   # a damaged shipped file: the route without it
        rec["error"] = f"{type(e).__name__}: {e}"[:300]
        return None, (0, 0)
    budget = min(NEIGHBOUR_SEQUENCE_BUDGET, float(options.get("time_budget", 20.0)))
    best = None
    nit = nfev = tried = 0
    for c in [g] + list(g.candidates):
        left = budget - (time.perf_counter() - t0)
        if left <= 0.02:
            break
        tried += 1
        bang, kkt_guess, (n_it, n_fev) = bang_bang_from_sequences(
            prob, [(c.u_first, c.switch_times, c.tf)], time_budget=left, tols=options.get("tols"),
            source=f"the {c.source} tabled solution", kkt_tol=math.inf)
        nit += n_it
        nfev += n_fev
        if bang is None:
            continue
        prefix = f"the nearest tabled solutions' sequences ({tried} tried)"
        bang.nit, bang.nfev = nit, nfev
        ex = _exact_from_kkt(prob, bang, kkt_guess, options,
                             min(NEIGHBOUR_KKT_BUDGET, budget + NEIGHBOUR_KKT_BUDGET - (time.perf_counter() - t0)),
                             prefix)
        if ex is not None and best is not None and ex.tf > best.tf * (1.0 + 1e-9):
            # an earlier sequence gave a faster verified slew: this extremal is a local optimum
            nit, nfev = ex.nit, ex.nfev
            continue
        if ex is not None:
            rec.update(used=True, tried=tried, exact=True, time_s=time.perf_counter() - t0)
            return ex, (0, 0)
        nit, nfev = bang.nit, bang.nfev      # the exact attempt's work is counted there
        if best is None or bang.tf < best.tf:
            best = bang
    rec.update(tried=tried, exact=False, time_s=time.perf_counter() - t0)
    if best is None:
        return None, (nit, nfev)
    if not _faster_than_eigenaxis(prob, best):
        rec["rejected"] = "not faster than the eigenaxis slew"
        return None, (nit, nfev)
    best.route = f"the nearest tabled solutions' sequences ({tried} tried) → {best.route}"
    best.nit, best.nfev = nit, nfev
    best.wall_time = time.perf_counter() - t0
    rec.update(used=True, time_s=best.wall_time)
    return best, (0, 0)


def _faster_verified(route_answer, bang) -> SlewSolution:
    """The collocation route's ``route_answer`` or the neighbours' verified bang-bang answer
    ``bang``, whichever is faster (an answer no slower than ``bang`` keeps its place: an exact
    extremal at the same time is the better answer); the other's work is counted in it."""
    # a certified extremal keeps its place unless the bang-bang slew is faster beyond numerical
    # noise (1e-6: a slew of the same basin cannot beat its extremal by more)
    margin = 1e-6 if route_answer.success and route_answer.exact else 1e-9
    if route_answer.success and route_answer.tf <= bang.tf * (1.0 + margin):
        route_answer.nit += bang.nit
        route_answer.nfev += bang.nfev
        return route_answer
    bang.nit += route_answer.nit
    bang.nfev += route_answer.nfev
    what = (f"{route_answer.method} answer {route_answer.tf:.9g}" if route_answer.success else
            f"no verified answer: {route_answer.message[:120]}")
    bang.route = f"{bang.route}; faster than the collocation route's ({what})"
    return bang


def _table_votes_bang_bang(info) -> bool:
    """Whether ``_singular_table_route`` ran and found fewer than ``SINGULAR_UNCERTAIN_SHARE`` of
    the nearest tabled problems singular (it then gives no answer)."""
    rec = info.get("singular_table") or {}
    return "share" in rec and rec["share"] < min(rec.get("vote", 1.0), SINGULAR_UNCERTAIN_SHARE)


def _exact_after_uncertain_table(prob, bang, col_opts, options, budget, prefix, rec) -> Optional[SlewSolution]:
    """The exact extremal that collocation's refinement certifies where the singular table's
    vote was uncertain, if it is no slower than the table's bang-bang answer ``bang``; else
    ``None``, with the check's work counted in ``bang``. ``rec["exact_check"]`` records what
    happened (an error in the check too: ``bang`` stays the answer)."""
    from .collocation import solve_collocation
    from .switch_time_opt import singular_arc_evidence
    t0 = time.perf_counter()
    if budget < CHALLENGE_MIN_BUDGET:
        rec["exact_check"] = f"skipped: {budget:.2f} s of the time budget left"
        return None
    try:
        col = solve_collocation(prob, **dict({"time_budget": _left(budget, 0.2)}, **col_opts))
        bang.nit += col.nit
        bang.nfev += col.nfev
        why = singular_arc_evidence(prob, col) if col.success else f"collocation failed: {col.message[:120]}"
        if why:
            rec["exact_check"] = why
            return None
        left = budget - (time.perf_counter() - t0)
        if left < 0.05:
            rec["exact_check"] = "no singular arc in collocation's control; no time left for the refinement"
            return None
        ref, accepted = _refine_collocation(prob, col, options, 2, min(REFINE_CAP_AFTER_WARM, left))
    except Exception as e:   # noqa: BLE001 - the table's verified answer stands
        rec["exact_check"] = f"error: {type(e).__name__}: {e}"[:300]
        return None
    if accepted and ref.tf <= bang.tf * (1.0 + 1e-9):
        rec["exact_check"] = "an exact extremal, no slower"
        ref.route = (f"{prefix}, uncertain → {bang.route} → collocation ({col.wall_time:.3g} s; no singular arc "
                     f"in its control) → indirect refinement: {ref.route}")
        # the refinement's count holds collocation's (accepted); the table's own work is in bang
        ref.nit += bang.nit - col.nit
        ref.nfev += bang.nfev - col.nfev
        return ref
    rec["exact_check"] = ("the refined extremal is slower than the table's answer" if accepted else
                          f"exact refinement not certified: {ref.message[:120]}")
    own_nit, own_nfev = (ref.nit - col.nit, ref.nfev - col.nfev) if accepted else (ref.nit, ref.nfev)
    bang.nit += own_nit
    bang.nfev += own_nfev
    return None


def _split_continuation(g: Guess):
    """``(fast, later)``: ``g`` with only the candidates that carry a switching structure (or
    are deferred: a model's deferred candidates carry one), and the others — costates alone,
    solved by smoothing continuation, up to a second each — as one guess, or ``None``. A guess
    without a structure of its own is not split."""
    if g.switch_times is None:
        return g, None
    keep = [c for c in g.candidates if not isinstance(c, Guess) or c.switch_times is not None]
    rest = [c for c in g.candidates if isinstance(c, Guess) and c.switch_times is None]
    if not rest:
        return g, None
    return replace(g, candidates=keep), replace(rest[0], candidates=rest[1:])


def _warm_start(prob, method, warm_start, options, split=False):
    """Try the model's guess alone; returns ``(solution or None, info, later)``: ``later`` is
    ``None`` unless ``split``, then the guess's continuation candidates, not tried here
    (``_split_continuation``)."""
    from . import warmstart
    model = warmstart.resolve(warm_start, prob)
    if model is None:
        return None, {}, None
    name = getattr(model, "name", type(model).__name__)
    t0 = time.perf_counter()
    try:
        if hasattr(model, "guess_or_reason"):
            g, why = model.guess_or_reason(prob)
        else:
            why = model.covers(prob)
            g = None if why else model.guess(prob)
    except Exception as e:   # noqa: BLE001 - any model failure (numerics, a user model's bug)
        # a model that cannot produce a guess must not stop the solve: the classical route
        # runs, and the error is recorded (the answer is verified either way)
        return None, {"model": name, "covered": True, "succeeded": False,
                      "error": f"{type(e).__name__}: {e}"[:300]}, None
    if why:
        return None, {"model": name, "covered": False, "reason": why}, None
    if not isinstance(g, Guess):
        raise ValueError(f"warm_start: {name}.guess() returned {type(g).__name__}, expected a solvers.Guess")
    later = None
    t_inf = getattr(g, "inference_s", getattr(model, "last_inference_s", None))
    # a model that predicts the optimal final time says so (``Guess.predicted_tf``: the shipped
    # full-attitude network); a neighbour's time or a user model's guess is not such a prediction
    predicted_tf = getattr(g, "predicted_tf", None)
    if split:
        g, later = _split_continuation(g)
    t_guess = time.perf_counter() - t0
    t_inf = t_guess if t_inf is None else t_inf
    # a model may load the solver's compiled code first (once per process), so that its
    # candidates' time caps measure solving, not loading; not counted in the solve's time
    t_warm = model.warm_up(_warm_up_solve) if prob.cones and hasattr(model, "warm_up") else 0.0
    t0 += t_warm
    ind_method = "multiple-shooting" if method == "multiple-shooting" else "indirect"
    total = float(options.get("time_budget", 20.0))
    budget = min(float(options.get("warm_budget", CONE_WARM_BUDGET if prob.cones else WARM_BUDGET)), total)
    opts = {k: v for k, v in options.items() if k != "warm_budget"}
    skipped = []
    if prob.cones:
        sol = _solve_learned_cones(prob, g, opts, budget, errors=skipped,
                                   rank=bool(getattr(model, "RANKS_CANDIDATES", False)))
    else:
        sol = _guess_alone(prob, g, opts, budget, method=ind_method)
    info = {"model": name, "covered": True, "succeeded": bool(sol.success), "candidates": sol.n_candidates,
            "inference_s": t_inf, "guess_s": t_guess, "time_s": time.perf_counter() - t0}
    if skipped:     # candidates the model could not make (the others were tried)
        info["error"] = "; ".join(skipped)[:300]
    if predicted_tf is not None:
        info["predicted_tf"] = float(predicted_tf)
    if t_warm:
        info["warm_up_s"] = t_warm
    if isinstance(warm_start, str) and warm_start in ("default", "pointing-cones"):
        why = warmstart.table_error("pointing-cones" if prob.cones else "full-attitude")
        if why:         # a damaged shipped table: the network alone gave the guess
            info["table_error"] = why
    if later is not None:
        info["deferred"] = 1 + len(later.candidates)
    sol.warm_start = info
    if sol.success:
        sol.route = f"learned guess ({name}) → {sol.route}"
    return sol, info, later


def _no_slower_than_eigenaxis(prob, sol, t0) -> SlewSolution:
    """``auto``'s answer to a rest-to-rest full-attitude problem is never slower than the
    eigenaxis slew: an approximate (collocation) answer that is not faster — small slews,
    where the two agree to first order and collocation cannot resolve the difference — is
    replaced by the eigenaxis slew itself (``eigenaxis_answer``, verified by its replay)."""
    if not sol.success or sol.exact or _fallback_inapplicable(prob) is not None:
        return sol
    # the collocation baseline is on a coarse grid (lenient by up to 0.1 % per-axis and 2 %
    # p-norm with a rate limit): compare with the eigenaxis answer itself, which is cheap for a
    # per-axis bound (compiled, ~7 ms) and planned only when the answer is not clearly faster
    # than the fine grid; for a p-norm bound only when the answer is within 3 % of that baseline
    if not math.isinf(prob.torque_norm):
        if not (sol.tf >= sol.baseline_tf * (1.0 - 0.03)):
            return sol
        from .eigenaxis_answer import eigenaxis_answer
        eig = eigenaxis_answer(prob)
    else:
        _, eig = _eigenaxis_unless_faster(prob, sol.tf)
    if eig is None or not eig.success or not eig.tf < sol.tf:
        return sol
    eig.route = (f"{sol.route[:200]} gave {sol.tf:.9g}, no faster than the eigenaxis slew "
                 f"({eig.tf:.9g}): the eigenaxis slew is the answer")
    eig.message = (f"{eig.message} The time-optimal routes found nothing faster (best {sol.tf:.9g}, approximate, "
                   f"tf_tol {sol.tf_tol:.2g}): for a slew this small the two agree to first order.")
    eig.nit, eig.nfev = sol.nit, sol.nfev
    eig.candidates_tf = sorted(set(list(sol.candidates_tf or []) + [round(eig.tf, 9)]))
    eig.warm_start = sol.warm_start
    eig.wall_time = time.perf_counter() - t0
    return eig


def _eigenaxis_unless_faster(prob, tf):
    """``(baseline, eig)`` for a rest-to-rest, full-attitude, per-axis problem and a final time
    ``tf``: if ``tf`` is below the fine-grid eigenaxis time (problem units) by the margin
    ``EIGENAXIS_GRID_MARGIN``, it is faster than the eigenaxis slew, and ``(grid time, None)``;
    else the slew itself is planned (~15 ms): ``(grid time, eigenaxis_answer)``."""
    from .eigenaxis_answer import eigenaxis_answer
    bvp = AttitudeBVP(prob)
    grid = eigenaxis_time(bvp.ref_problem, n_grid=1000)
    if tf < grid * (1.0 - EIGENAXIS_GRID_MARGIN):
        return grid, None
    return grid, eigenaxis_answer(prob)


def _warm_up_solve(problem, guess):
    """A cone model's warm-up solve: its guess through the same route as the candidates, with
    no time caps (``ConeEnsembleWarmStart.warm_up`` runs one with touches, one without)."""
    return _solve_learned_cones(problem, guess, {}, 5.0, cap=5.0)


def _network_predicted_tf(model, prob) -> Optional[float]:
    """The pointing-cones network's predicted final time for ``prob`` (its ``tf`` guess, ``None``
    if it does not cover the problem or fails); ``model`` is the ensemble or the network."""
    net = getattr(model, "network", model)
    try:
        g, why = net.guess_or_reason(prob)
    except Exception:   # noqa: BLE001 - no prediction: the challenge runs
        return None
    return None if why or g is None or not (g.tf > 0.0) else float(g.tf)


def _cone_challenger(prob, sol, options, t0, gated=True) -> SlewSolution:
    """``auto`` on a problem with cones: after the default route (collocation, then the exact
    refinements) has answered, the shipped pointing-cones warm start (``warmstart.cone_ensemble``:
    the solutions of the nearest tabled problems, then the network's guess) gets
    ``CONE_WARM_BUDGET``. Its verified extremal replaces the answer only if it is faster (or
    as fast within the answer's ``tf_tol`` and exact where the answer is not). Collocation
    reaches local optima: on 1,000 held-out problems the warm start found a faster extremal
    on 36 (23 by more than 1 %, up to 44 %); its other answers, often slower, are never used.
    ``SlewSolution.warm_start`` records the challenge (``role: "challenger"``, ``won``).

    ``gated`` (``solve``'s ``cone_challenge="gated"``, the default): only an answer slower than
    ``CONE_CHALLENGE_GATE`` times the network's predicted tf is challenged. Since the 2 nearest
    tabled solutions became collocation starts, the challenge rarely wins (3 of 600 problems), and
    it cost about 0.1 s a problem; a large win is an answer far above the prediction (45 %: 1.77
    times it). A skipped challenge is recorded (``challenged: False``, ``predicted_tf``)."""
    from . import warmstart
    left = float(options.get("time_budget", 20.0)) - (time.perf_counter() - t0)
    budget = min(float(options.get("warm_budget", CONE_WARM_BUDGET)), left)
    try:
        model = warmstart.default_cone_model() if budget > 0 else None
    except Exception as e:   # noqa: BLE001 - a damaged shipped file: the verified answer stands
        why = f"{type(e).__name__}: {e}"[:300]
        sol.warm_start = {"model": "pointing-cones (shipped)", "covered": True, "role": "challenger",
                          "challenged": False, "won": False, "error": why,
                          "reason": f"the shipped pointing-cones model could not be read ({why})"}
        return sol
    if model is None:
        return sol
    if gated and sol.success:
        predicted = _network_predicted_tf(model, prob)
        if predicted is not None and sol.tf <= CONE_CHALLENGE_GATE * predicted:
            sol.warm_start = {"model": getattr(model, "name", type(model).__name__), "covered": True,
                              "role": "challenger", "challenged": False, "won": False, "predicted_tf": predicted,
                              "reason": f"the answer's tf {sol.tf:.9g} is not above the network's predicted "
                                        f"{predicted:.9g} (cone_challenge='gated')"}
            sol.wall_time = time.perf_counter() - t0
            return sol
    try:
        ch, info, _ = _warm_start(prob, "auto", "pointing-cones", dict(options, warm_budget=budget))
    except Exception as e:   # noqa: BLE001 - the verified answer stands; the failure is recorded
        ch, info = None, {"model": getattr(model, "name", type(model).__name__), "covered": True,
                          "succeeded": False, "error": f"{type(e).__name__}: {e}"[:300]}
    info = dict(info, role="challenger", **({"won": False, "challenged": True} if info.get("covered") else {}))
    if ch is None or not ch.success:
        sol.warm_start = info
        sol.wall_time = time.perf_counter() - t0
        return sol
    info["tf"] = float(ch.tf)
    tol = sol.tf_tol if sol.success and math.isfinite(sol.tf_tol) else 0.0
    # faster; or, where the answer is approximate, exact and as fast within the answer's own
    # accuracy (the approximate answer's tf is only known to tf_tol)
    faster = ch.exact and (not sol.success or ch.tf < sol.tf * (1.0 - 1e-9)
                           or (not sol.exact and ch.tf <= sol.tf + tol))
    if not faster:
        sol.warm_start = info
        sol.wall_time = time.perf_counter() - t0
        return sol
    info["won"] = True
    was = f"{sol.tf:.9g}" if sol.success else "no answer"
    ch.route = (f"auto: the default route ({sol.route[:160]}) gave {was}; the pointing-cones warm start found a "
                f"faster extremal → {ch.route}")
    ch.message = f"{ch.message} Faster than the default route's answer ({was})."
    ch.baseline_tf = sol.baseline_tf
    ch = _replace_answer(ch, sol, info)
    ch.wall_time = time.perf_counter() - t0
    return ch


def _replace_answer(new, old, info) -> SlewSolution:
    """``new``, a challenger's faster answer, replaces ``old`` (the two challengers of ``auto``:
    ``_challenge_learned_answer``, ``_cone_challenger``): the work of both is counted, the
    final times both saw are in ``candidates_tf``, and the warm start's record goes with it."""
    new.nit += old.nit
    new.nfev += old.nfev
    seen = set(new.candidates_tf or []) | set(old.candidates_tf or []) | {round(new.tf, 9)}
    if old.success:
        seen.add(round(old.tf, 9))
    new.candidates_tf = sorted(seen)
    new.warm_start = info
    return new


def _cone_neighbour_starts(prob) -> list:
    """The first ``CONE_NEIGHBOUR_STARTS`` candidates of the shipped pointing-cones warm start
    (the nearest tabled solutions), as extra collocation starts for ``auto``; none if it does
    not cover ``prob`` or cannot be read."""
    from . import warmstart
    try:
        model = warmstart.resolve("pointing-cones", prob)
        if model is None or model.covers(prob):
            return []
        # (the later candidates are deferred: only these are computed)
        return list(itertools.islice(model.guess(prob).iter_all(), CONE_NEIGHBOUR_STARTS))
    except Exception:   # noqa: BLE001 - a damaged or missing model: the route's own starts
        return []


def _solve_learned_cones(prob, g, options, budget, cap=None, errors=None, rank=False) -> SlewSolution:
    """A guess for a problem with keep-out cones, tried candidate by candidate: with
    ``touches``, the touch-point extremal (``cone_touch.solve_touch_guess``, switch-time
    formulation first when the guess has a structure); without, the extremal of the problem
    without cones, accepted only if its path clears every cone (certified). A deferred
    candidate that cannot be made (a model's error) is skipped, and its error added to
    ``errors`` (a list) where given. With ``rank`` (a model whose candidates are cheap to make,
    ``RANKS_CANDIDATES``; and ``CONE_RANK_CANDIDATES``) every candidate is made first and those
    with touches are tried in order of their starting residual (``_ranked_by_starting_residual``,
    within ``CONE_RANK_SHARE`` of the budget): a candidate that cannot be made is then reported
    even where an earlier one converges."""
    from .cone_touch import solve_touch_guess
    t0 = time.perf_counter()
    tried, last = 0, None
    nit = nfev = 0
    skipped = [] if errors is None else errors
    cands = g.iter_all(errors=skipped)
    if rank and CONE_RANK_CANDIDATES:
        cands = _ranked_by_starting_residual(prob, list(cands), deadline=t0 + CONE_RANK_SHARE * budget)
    for cand in cands:
        left = min(budget - (time.perf_counter() - t0), CONE_CANDIDATE_CAP if cap is None else cap)
        if left <= 0.0:
            break
        tried += 1
        if cand.touches:
            sol = solve_touch_guess(prob, cand, tols=options.get("tols"), time_budget=left, smoothing=False)
        else:
            sol = _guess_alone(prob.replace(cones=[]), cand, options, left, with_candidates=False)
            if sol.success and not _certify_clear(prob, sol):
                sol.success, sol.status = False, STATUS_VERIFICATION_FAILED
                sol.message = (f"the extremal without cones enters a cone (certified clearance "
                               f"{sol.verification['cone_clearance']['value']:.3g} rad)")
            sol.problem = prob
        nit, nfev = nit + sol.nit, nfev + sol.nfev
        last = sol
        if sol.success:
            break
    if last is None:
        why = f"no candidate could be made ({'; '.join(skipped)[:300]})" if skipped else "no time left for the guess"
        return SlewSolution(False, STATUS_NOT_CONVERGED, why, 0, 0,
                            time.perf_counter() - t0, method="indirect", problem=prob, route="learned guess: no time")
    last.nit, last.nfev, last.n_candidates = nit, nfev, tried
    last.wall_time = time.perf_counter() - t0
    return last


def _ranked_by_starting_residual(prob, cands, deadline=math.inf) -> list:
    """``cands`` with those that have touches reordered by their starting residual
    (``cone_touch.starting_residuals``, lowest first; ties keep their order), each in the place
    of one that has touches; the others keep their places. On 200 held-out problems with every
    candidate run on its own (``runs/s31/all_cands.py``, ``rank_sim.py``), the nearest
    solutions' order put the first that converges at a median of 35.5 ms, this order at 30.9 ms
    (the residuals included: 2.5 ms as first written, 0.9 ms now), 131 and 130 problems
    converging, and fewer answers slower than the best candidate's (15 against 20). Residuals
    not evaluated by ``deadline``
    count as infinite (those candidates keep their order, after the others)."""
    from .cone_touch import starting_residuals
    slots = [k for k, c in enumerate(cands) if c.touches]
    if len(slots) < 2:
        return cands
    keys = dict(zip(slots, starting_residuals(prob, [cands[k] for k in slots], deadline=deadline)))
    out = list(cands)
    for k, j in zip(slots, sorted(slots, key=lambda j: keys[j])):
        out[k] = cands[j]
    return out


def _budget_spent(prob, what, nit, nfev, t0, route) -> SlewSolution:
    """Status 3 where a stage of ``auto`` has used the whole time budget (``what``: the stage,
    the subject of a sentence): the next stage is not started, as building an NLP is not
    interruptible."""
    return SlewSolution(False, STATUS_BUDGET_EXHAUSTED,
                        f"{STATUS_MESSAGES[STATUS_BUDGET_EXHAUSTED]} {what} used the whole time budget.",
                        nit, nfev, time.perf_counter() - t0, method="indirect", problem=prob, route=route)


def _solve_auto(prob, guess, col_opts, options, **kw) -> SlewSolution:
    """``_solve_auto_route``, and before it, for a p-norm bound with p ≤ 2 and no ``guess``, the
    indirect multi-start (``_pnorm_indirect_first``): its verified answer is the answer; if it
    fails, the route runs with the rest of the time budget, and its answer's ``route`` says so."""
    if guess is not None or not _pnorm_indirect_first(prob):
        return _solve_auto_route(prob, guess, col_opts, options, **kw)
    t0 = time.perf_counter()
    budget = float(options.get("time_budget", 20.0))
    ind = _solve_indirect(prob, "indirect", None, **dict(options, time_budget=min(PNORM_INDIRECT_BUDGET, budget)))
    if ind.success:
        ind.route = f"auto: indirect first (p-norm bound, p ≤ 2) → {ind.route}"
        ind.wall_time = time.perf_counter() - t0
        return ind
    if budget <= time.perf_counter() - t0:
        # the indirect stage spent the budget: no route (building an NLP is not interruptible)
        sol = _budget_spent(prob, "The indirect multi-start (p-norm bound, p ≤ 2)", 0, 0, t0,
                            "no time left for the collocation route")
    else:
        left = _left(budget, time.perf_counter() - t0)
        sol = _solve_auto_route(prob, guess, col_opts, dict(options, time_budget=left), **kw)
    sol.route = f"auto: indirect first (p-norm bound, p ≤ 2) failed ({ind.message[:120]}) → {sol.route}"
    sol.nit += ind.nit
    sol.nfev += ind.nfev
    sol.wall_time = time.perf_counter() - t0
    return sol


def _solve_auto_route(prob, guess, col_opts, options, refine_cap=2.0, later=None, warm_info=None,
                      warm_budget=WARM_BUDGET) -> SlewSolution:
    """The fastest route to a verified answer.

    1. a given ``guess`` alone, by the indirect route (a warm start) (without one, for a p-norm
       bound with p ≤ 2, ``_solve_auto`` has tried the indirect multi-start before this);
    2. direct collocation; where its control shows a singular arc (full-attitude, per-axis,
       ``switch_time_opt.singular_arc_evidence``), straight to 3b;
    3. otherwise ``later`` (the learned guess's continuation candidates, held back by
       ``solve``, within ``warm_budget`` s; ``warm_info`` is updated if one wins), then exact indirect refinement from
       collocation's costates and switching structure (the bang-bang extremal near the
       collocation answer), with the eigenaxis guess as a second candidate;
    3b. if no exact extremal is certified (a singular arc, mostly), a bang-bang slew with
       collocation's switching sequence and optimised switch times (``method="switch-time"``),
       whose KKT costates go to the exact solver first; failing that, the collocation answer
       itself, verified by its own checks and labelled as such in ``route`` and ``message``;
    4. if collocation fails, the classical indirect multi-start.
    Keep-out cones go to collocation; its answer is refined exactly when the cones are inactive
    (the extremal without cones) or touched at isolated instants (touch-point junctions);
    otherwise (a path riding a cone boundary, or a singular arc) the answer is a bang-bang slew
    with collocation's sequence and optimised switch times, the cones imposed
    (``switch_time_cones``), or, where none is verified, the collocation answer itself.
    Pointing-only targets without cones are refined like full-attitude ones (with the roll
    transversality), and get the same switch-time answer where no extremal is certified.
    """
    t0 = time.perf_counter()
    spent = lambda: time.perf_counter() - t0  # noqa: E731
    budget = float(options.get("time_budget", 20.0))
    indirect_ok = not prob.cones
    tried_guess = None
    if guess is not None and indirect_ok:
        opts = dict(options, max_candidates=1 + len(guess.candidates), min_candidates=1, guess_only=True)
        tried_guess = _solve_indirect(prob, "indirect", guess, **opts)
        if tried_guess.success:
            tried_guess.route = f"auto: given guess → {tried_guess.route}"
            tried_guess.wall_time = spent()
            return tried_guess
        if budget <= spent():
            return _budget_spent(prob, "The given guess", tried_guess.nit, tried_guess.nfev, t0,
                                 f"auto: given guess failed ({tried_guess.message[:120]}) → no time left for "
                                 "collocation")
    from .collocation import solve_collocation
    # with cones, collocation's N / 2 solve for tf_tol waits: the refinements below mostly
    # replace its answer by an exact extremal (their use of tf_tol has a 1e-3 relative floor)
    col = solve_collocation(prob, **dict({"time_budget": _left(budget, spent()), "defer_tf_tol": not indirect_ok},
                                         **col_opts))
    if not indirect_ok:
        ref = _refine_inactive_cones(prob, col, options, budget - spent()) if col.success else None
        if ref is not None:
            ref.wall_time = spent()
            return ref
        touch = _refine_touching_cones(prob, col, options, _left(budget, spent())) if col.success else None
        if touch is not None and touch.success:
            touch.route = f"auto: collocation ({col.wall_time:.3g} s) → {touch.route}"
            touch.wall_time = spent()
            return touch
        if not col.success:
            free = _clear_without_cones(prob, col, options, col_opts, budget - spent())
            if free is not None:
                free.wall_time = spent()
                return free
        settle_tf_tol(col, budget - spent())
        # a path that rides a cone (or a singular arc): a bang-bang slew with collocation's
        # sequence and optimised switch times, the cones imposed, reaches the target exactly
        # and is flown by its switch times; collocation's answer is not
        bang = _bang_bang_cones(prob, col, options, budget - spent())
        if bang is not None:
            bang.route = f"auto: collocation ({col.route}; {col.wall_time:.3g} s; no exact extremal near it) → {bang.route}"
            bang.wall_time = spent()
            return bang
        col.route = f"auto: collocation ({col.route})"
        col.wall_time = spent()
        return col
    if col.success:
        from .switch_time_opt import singular_arc_evidence
        singular = singular_arc_evidence(prob, col) if (switch_time_applies(prob)
                                                        or _pointing_singular_check(prob)) else None

        def refine(note):
            """The collocation guess, then the eigenaxis guess (exact for a symmetric 2-norm problem,
            where the λω = 0 instant makes a near guess hard to refine): ``(ref, accepted, why)``;
            an accepted ``ref`` gets its route (``note`` after collocation's time) and wall time."""
            r, ok = _refine_collocation(prob, col, options, 2,
                                        min(refine_cap, _left(budget, spent())))
            if ok:
                r.route = f"auto: collocation ({col.wall_time:.3g} s{note}) → indirect refinement: {r.route}"
                r.wall_time = spent()
            return r, ok, (r.message if not r.success else
                           f"the refined extremal ({r.tf:.9g}) is slower than the collocation answer")

        ref = None
        if singular is None:
            if later is not None and budget - spent() > 0.05:
                lg = _guess_alone(prob, later, options, min(warm_budget, budget - spent()))
                if warm_info is not None:
                    warm_info["deferred_result"] = "succeeded" if lg.success else "failed"
                if lg.success:
                    if warm_info is not None:
                        warm_info.update(succeeded=True, after_collocation=True)
                    lg.route = (f"auto: collocation ({col.wall_time:.3g} s; no singular arc in its control) → "
                                f"the learned guess's continuation candidate: {lg.route}")
                    lg.wall_time = spent()
                    return lg
                # (its work is counted in the answer's nit and nfev)
                col.nit += lg.nit
                col.nfev += lg.nfev
            ref, accepted, why = refine("")
            if accepted:
                return ref
            why = f"exact refinement not certified: {why}"
        else:
            why = f"exact refinement skipped: {singular}"
            if later is not None and warm_info is not None:
                warm_info["deferred_result"] = "skipped: a singular arc in collocation's control"
        # no exact extremal near it (a singular arc, mostly): the fastest bang-bang slew with
        # collocation's switching sequence reaches the target exactly, where collocation's own
        # control misses it by its discretisation error
        bang = kkt_guess = None
        if budget - spent() > 0.05:
            from .switch_time_opt import bang_bang_answer
            bang, kkt_guess = bang_bang_answer(prob, col, time_budget=min(BANG_BANG_BUDGET, budget - spent()),
                                               tols=options.get("tols"))
        if bang is not None:
            if ref is not None:
                bang.nit += ref.nit
                bang.nfev += ref.nfev
            prefix = f"auto: collocation ({col.wall_time:.3g} s)"
            ex = _exact_from_kkt(prob, bang, kkt_guess, options, min(BANG_BANG_BUDGET, budget - spent()), prefix)
            if ex is not None:
                ex.wall_time = spent()
                return ex
            bang.route = f"auto: collocation ({col.wall_time:.3g} s; {why[:250]}) → {bang.route}"
            bang.wall_time = spent()
            return bang
        if prob.qf is None:
            # a pointing target: the switch-time optimisation that leaves the roll free
            bang = _bang_bang_cones(prob, col, options, budget - spent())
            if bang is not None:
                bang.route = f"auto: collocation ({col.wall_time:.3g} s; {why[:250]}) → {bang.route}"
                bang.wall_time = spent()
                return bang
        if ref is None and budget - spent() > 0.05:
            # a singular arc in sight but no bang-bang answer: the exact refinement after all
            ref, accepted, why_ref = refine("; no switch-time answer")
            if accepted:
                return ref
            why += f"; no switch-time answer; exact refinement then not certified: {why_ref}"
        col.route = f"auto: collocation ({col.route}; {why[:300]})"
        col.message = (f"{col.message} Collocation answer (approximate, its own tolerances); the exact "
                       f"bang-bang refinement was not certified.")
        col.wall_time = spent()
        return col
    if budget - spent() <= 0.0:
        # the budget is spent: no multi-start (its first candidate would start: the eigenaxis
        # baseline and at least one iteration after the budget)
        col.status = STATUS_BUDGET_EXHAUSTED
        if not col.message.startswith(STATUS_MESSAGES[STATUS_BUDGET_EXHAUSTED]):
            col.message = f"{STATUS_MESSAGES[STATUS_BUDGET_EXHAUSTED]} Collocation: {col.message}"
        col.route = f"auto: collocation ({col.route}); no time left for the indirect multi-start"
        col.wall_time = spent()
        return col
    ind = _solve_indirect(prob, "indirect", guess, **dict(options, time_budget=_left(budget, spent())))
    ind.route = f"auto: collocation failed ({col.message[:200]}) → indirect multi-start: {ind.route}"
    ind.wall_time = spent()
    return ind


def _pointing_singular_check(prob) -> bool:
    """``auto`` reads collocation's control for a singular arc before the exact refinement of a
    pointing target too (per-axis bound, no cones, no rate limit). Measured on 100 random pointing
    slews (``pointing-cones`` without cones, seed 11; ``runs/s27/pointing_singular.py``): the
    evidence showed on 22 of the 26 without an exact answer (a roll-axis torque interior over
    9-84 % of tf) and on none of the 74 with one, where the futile refinement took 0.5-1.2 s."""
    return (prob.qf is None and not prob.cones and math.isinf(prob.torque_norm) and prob.rate_max is None)


def _pnorm_indirect_first(prob) -> bool:
    """``auto`` tries the indirect multi-start before collocation for a p-norm bound with
    ``p ≤ 2`` (rest-to-rest, full attitude, no cones, no rate limit: where it was measured). On
    240 seeded problems (80 each at p = 2, 1.5, 1.2, inertia ratios ≥ 0.3; ``runs/s19/pnorm_cmp.py``)
    it verified every one, never slower than the collocation route's answer (by more than 1e-10)
    and faster by up to 3 % on some at p = 1.2, in a median 111-390 ms against 0.4-16 s. Outside
    that, a review found local optima: at p = 2 with inertias down to 0.05 of the largest, answers
    17.6 % and 66 % slower than the collocation route's (two candidates agreeing on the local
    optimum), so the gate holds only for ``min J / max J ≥ PNORM_INDIRECT_MIN_INERTIA_RATIO``. At
    p = 3 it failed on 2 of 40 and returned a local optimum 2.8 % slower on 1: collocation first."""
    p = float(prob.torque_norm)
    J = np.asarray(prob.inertia, dtype=float)
    return (math.isfinite(p) and p <= 2.0 and not prob.cones and prob.rate_max is None and not prob.is_pointing
            and prob.is_rest_to_rest and float(J.min() / J.max()) >= PNORM_INDIRECT_MIN_INERTIA_RATIO)


def _refine_collocation(target, col, options, max_candidates, budget):
    """The exact extremal of ``target`` from a collocation answer's costates and switching
    structure: ``(solution, accepted)``. Accepted only if verified and not slower than the
    collocation answer (beyond its tolerance): the refined extremal must be the one
    collocation found, or a better one, not another local optimum."""
    per_axis = math.isinf(target.torque_norm)
    g = Guess(col.costate0, col.tf, col.switch_times if per_axis else None, col.u_first if per_axis else None,
              source="collocation")
    opts = dict(options, max_candidates=max_candidates, min_candidates=1, enough=1, time_budget=budget,
                model_guess=True)
    ref = _solve_indirect(target, "indirect", g, **opts)
    accepted = bool(ref.success and ref.tf <= col.tf * (1.0 + 2.0 * _rel_tol(col)))
    if ref.success and not accepted and getattr(col, "_tf_tol_pending", None) is not None:
        # slower than the floor allows: the deferred tf_tol may allow it
        settle_tf_tol(col, budget)
        accepted = bool(ref.tf <= col.tf * (1.0 + 2.0 * _rel_tol(col)))
    if accepted:
        ref.nit += col.nit
        ref.nfev += col.nfev
    return ref, accepted


# auto with cones: the 2 nearest tabled solutions of the shipped pointing-cones warm start join
# collocation's starts. On 150 seeded cone problems (seed 7) the answers more than 1e-4 slower
# than the best found went from 9 to 4 (more than 1 %: 4 to 2), the mean gap from 1.4e-3 to
# 1.1e-3, at +14 % median time; 4 neighbours did no better (runs/s15/nbr_starts.py)
CONE_NEIGHBOUR_STARTS = 2
# ... and with them, collocation's own starts drop from 4 (the eigenaxis slew and 3 perturbations
# of it) to 2: the neighbours bring the variety the perturbations were for. 100 seeded problems
# (seeds 0 and 1, runs/s29/ab_cones.py) gave the same answers and a median 9-12 % lower
# (522 -> 474 ms, 489 -> 430 ms); 1 start lost 0.3-1 % on 3 of 60
CONE_OWN_STARTS_WITH_NEIGHBOURS = 2
# a cone whose clearance on the collocation answer exceeds this (rad) is taken as inactive
INACTIVE_CONE_MARGIN = 1e-3
TOUCH_BUDGET = 1.5   # s: the touch-point refinement's smoothing path after a failed direct attempt


def _refine_inactive_cones(prob, col, options, budget_left, label="auto"):
    """Exact answer for a cone problem whose cones are all inactive, or ``None``.

    If the collocation answer stays ``INACTIVE_CONE_MARGIN`` clear of every cone, the
    constrained optimum is an extremal of the problem without cones: refine it by the
    indirect solver from the collocation costates, then accept it only if it is not slower
    than the collocation answer and its re-propagated path (switch times alone, RK4)
    clears every cone at every instant (certified lower bound, ``solvers.clearance``).
    An unconstrained extremal that is feasible and as fast as the constrained optimum is
    the constrained optimum.
    """
    per_axis = math.isinf(prob.torque_norm)
    cc = col.verification.get("cone_clearance", {})
    if not per_axis or not prob.is_rest_to_rest or not (cc.get("value", -1.0) > INACTIVE_CONE_MARGIN):
        return None
    from .switch_time_opt import singular_arc_evidence
    singular = singular_arc_evidence(prob.replace(cones=[]), col)
    if singular:
        # no bang-bang extremal near it: the refinement would spend its 2 s and fail (seen on 14
        # of 400 cone problems; on 45 with inactive cones and an exact answer no such run showed)
        col.route += f"; cones inactive (clearance {cc['value']:.3g} rad), no exact refinement: {singular}"
        return None
    ref, accepted = _refine_collocation(prob.replace(cones=[]), col, options, 1, min(2.0, _left(budget_left, 0.0)))
    if not accepted or not _certify_clear(prob, ref):
        return None
    ref.route = (f"{label}: collocation ({col.wall_time:.3g} s; cones inactive, clearance {cc['value']:.3g} rad) → "
                 f"indirect refinement without cones: {ref.route}; certified clearance "
                 f"{ref.verification['cone_clearance']['value']:.3g} rad")
    return ref


def _certify_clear(prob, sol):
    """Record on ``sol`` (an answer of ``prob`` without its cones) the certified clearance of
    its path from the cones of ``prob`` (``cone_clearance``) and rebind it to ``prob``;
    ``True`` if the path clears every cone at every instant."""
    from .clearance import CLEARANCE_TOL, answer_clearance
    certified = answer_clearance(prob, sol)
    sol.verification["cone_clearance"] = make_check(certified, CLEARANCE_TOL, certified >= CLEARANCE_TOL)
    sol.problem = prob
    return certified >= CLEARANCE_TOL


def _clear_without_cones(prob, col, options, col_opts, budget_left, exact_only=False, label="auto"):
    """When collocation fails on a cone problem: the answer of the problem without its cones,
    if its path clears every cone at every instant (certified), else ``None`` (also with no time
    left, ``budget_left ≤ 0``). A cone far from
    the path can still upset the NLP; the unconstrained optimum that is feasible is the
    constrained optimum."""
    if budget_left <= 0.0:      # no time left: the route it would take starts with an NLP build
        return None
    free_prob = prob.replace(cones=[])
    opts = dict(options, time_budget=_left(budget_left, 0.0))
    free = (_solve_indirect(free_prob, "indirect", None, **opts) if exact_only
            else _solve_auto(free_prob, None, col_opts, opts))
    if not free.success or (exact_only and not free.exact) or not _certify_clear(prob, free):
        return None
    free.route = (f"{label}: collocation with the cones failed ({col.message[:120]}) → the problem without cones, "
                  f"whose path clears them (certified {free.verification['cone_clearance']['value']:.3g} rad): "
                  f"{free.route}")
    return free


def _bang_bang_cones(prob, col, options, left):
    """``switch_time_cones.bang_bang_cone_answer`` within ``min(CONE_BANG_BANG_BUDGET, left)`` (``None``
    when less than 50 ms are left, or it gives nothing)."""
    if not col.success or left <= 0.05:
        return None
    from .switch_time_cones import bang_bang_cone_answer
    return bang_bang_cone_answer(prob, col, time_budget=min(CONE_BANG_BANG_BUDGET, left), tols=options.get("tols"))


def settle_tf_tol(sol, budget) -> None:
    """``collocation.settle_tf_tol`` (imported where used, as collocation is everywhere here)."""
    from .collocation import settle_tf_tol as settle
    settle(sol, budget)


def _rel_tol(col) -> float:
    """The relative tolerance a refinement of ``col`` may be slower by (each side): its
    ``tf_tol`` relative, at least 1e-3 (NaN, not measured or deferred: 1e-3)."""
    return max(float(col.tf_tol) / col.tf if col.tf_tol == col.tf_tol else 0.0, 1e-3)


def _refine_touching_cones(prob, col, options, budget=TOUCH_BUDGET) -> SlewSolution:
    """The exact extremal whose path touches cones at isolated instants (costate jumps there,
    ``solvers.cone_touch``), from a collocation answer; ``success=False`` if there is none
    near it (a boundary arc, or Newton fails), or if it is slower than collocation's.
    ``budget`` (s): the caller's time left, a hard stop (the smoothing path gets at most
    ``TOUCH_BUDGET`` of it)."""
    from .cone_touch import solve_touch
    deadline = time.perf_counter() + budget
    touch_budget = min(TOUCH_BUDGET, budget)
    sol = solve_touch(prob, col, tols=options.get("tols"), time_budget=touch_budget, deadline=deadline)
    slower = sol.verification.get("not_slower_than_seed", {})
    if not sol.success and getattr(col, "_tf_tol_pending", None) is not None and not slower.get("passed", True):
        # slower than the 1e-3 floor allows: the deferred tf_tol may allow more, and then the
        # touch extremal is solved again against it
        rel = _rel_tol(col)
        settle_tf_tol(col, min(TOUCH_BUDGET, deadline - time.perf_counter()))
        if _rel_tol(col) > rel and time.perf_counter() < deadline:
            sol = solve_touch(prob, col, tols=options.get("tols"), time_budget=touch_budget, deadline=deadline)
    sol.nit += col.nit
    sol.nfev += col.nfev
    return sol


def _solve_indirect_cones(prob, guess, col_opts, options) -> SlewSolution:
    """The indirect route for a problem with keep-out cones (see the module docstring)."""
    from .collocation import solve_collocation
    from .cone_penalty import SEGMENTS, solve_penalised
    t0 = time.perf_counter()
    budget = float(options.get("time_budget", 60.0))
    if not math.isinf(prob.torque_norm):
        raise ValueError(f"torque_norm: with keep-out cones the indirect route handles the per-axis bound "
                         f"('inf') only, got p = {prob.torque_norm:g}; use method='collocation' or 'auto'")
    segments = int(options.get("segments", SEGMENTS))
    if segments < 2:
        raise ValueError(f"segments: the cone penalty route uses multiple shooting, needs ≥ 2, got {segments}")
    col = solve_collocation(prob, guess=guess, **dict({"time_budget": budget, "defer_tf_tol": True},
                                                      **col_opts))
    if not col.success:
        free = _clear_without_cones(prob, col, options, col_opts, budget - (time.perf_counter() - t0),
                                    exact_only=True, label="indirect with cones")
        if free is not None:
            free.wall_time = time.perf_counter() - t0
            return free
        col.success = False
        col.method = "indirect"
        col.route = f"indirect with cones: collocation seed failed ({col.message[:200]})"
        col.wall_time = time.perf_counter() - t0
        return col
    ref = _refine_inactive_cones(prob, col, options, budget - (time.perf_counter() - t0), label="indirect with cones")
    if ref is not None:
        ref.wall_time = time.perf_counter() - t0
        return ref
    touch = _refine_touching_cones(prob, col, options, _left(budget, time.perf_counter() - t0))
    if touch.success:
        touch.route = f"indirect with cones: collocation ({col.wall_time:.3g} s) → {touch.route}"
        touch.wall_time = time.perf_counter() - t0
        return touch
    settle_tf_tol(col, budget - (time.perf_counter() - t0))   # the penalty route's tf_tol builds on it
    sol = solve_penalised(prob, col, segments=segments, tols=options.get("tols"),
                          time_budget=_left(budget, time.perf_counter() - t0))
    sol.nit += col.nit + touch.nit
    sol.nfev += col.nfev + touch.nfev
    if sol.success:
        # the penalised extremal's costates carry the touch jumps smoothed out, a better seed
        # for the exact touch refinement than collocation's
        exact = _refine_touching_cones(prob, sol, options, _left(budget, time.perf_counter() - t0))
        if exact.success:
            exact.route = f"indirect with cones: collocation ({col.wall_time:.3g} s) → {sol.route} → {exact.route}"
            exact.wall_time = time.perf_counter() - t0
            return exact
    sol.route = f"indirect with cones: collocation ({col.wall_time:.3g} s, tf {col.tf:.6g}) → {sol.route}"
    sol.wall_time = time.perf_counter() - t0
    return sol


def _solve_indirect(prob, method, guess, first_verified=False, **options) -> SlewSolution:
    """The indirect multi-start. ``first_verified``: stop at the first verified extremal that
    is not slower than the eigenaxis slew (a warm start's candidates, best first)."""
    t_start = time.perf_counter()
    if prob.cones:
        raise ValueError("cones: keep-out cones are not supported by the indirect solvers yet "
                         f"({len(prob.cones)} given); use method='auto' or 'collocation'")
    if prob.is_rest_to_rest and prob.slew_angle < 1e-12:
        if prob.qf is None:
            raise ValueError("sensor_target: the sensor already points at the target (zero slew at rest); "
                             "nothing to solve")
        raise ValueError("qf: the target equals the start (zero slew at rest); nothing to solve")
    segments = int(options.get("segments", 4 if method == "multiple-shooting" else 1))
    if segments < 1:
        raise ValueError(f"segments: must be a positive integer, got {segments}")
    per_axis = math.isinf(prob.torque_norm)
    max_candidates = int(options.get("max_candidates", 16 if per_axis else 8))
    min_candidates = int(options.get("min_candidates", 8 if per_axis else 3))
    enough = int(options.get("enough", 2))
    seed = options.get("seed", 0)
    budget = float(options.get("time_budget", 20.0))
    tols = options.get("tols")
    n_dense = int(options.get("n_dense", DENSE_STEPS))
    eps_min = float(options.get("eps_min", 1e-3))
    kw = {}
    if "rtol" in options:
        kw["rtol"] = float(options["rtol"])
    if "atol" in options:
        kw["atol"] = float(options["atol"])
    bvp = AttitudeBVP(prob, **kw)
    # the eigenaxis slew is what spacecraft fly today: an extremal slower than it is a
    # local optimum, never the answer (rest-to-rest problems only; for a pointing-only
    # target the eigenaxis slew to the reference attitude, one feasible way to point)
    baseline = math.nan
    if prob.is_rest_to_rest:
        baseline = eigenaxis_time(bvp.ref_problem, n_grid=1000) / bvp.tau
    deadline = t_start + budget
    method_used = "multiple-shooting" if method == "multiple-shooting" else "indirect"
    cap = options.get("candidate_cap", CANDIDATE_CAP)
    if cap is not None:
        cap_mult, cap_floor = _checked_cap(cap)
    first_nfev = None       # propagations of the first verified built-in candidate's attempt

    nit = nfev = 0
    tried = 0
    found = []   # (T, attempt, tr, checks, source)
    failures = []
    last_verif_fail = None
    for z, T, st, src in _candidates(bvp, guess, max_candidates, seed, per_axis,
                                     unusable=failures if options.get("model_guess") else None,
                                     guess_only=bool(options.get("guess_only"))):
        # the budget is checked between candidates, and the first one always starts; inside a
        # candidate the Newton iterations stop at the deadline (the kernels were loaded before
        # the clock started: ``kernel_loading``)
        if tried > 0 and time.perf_counter() > deadline:
            break
        tried += 1
        # structure templates, model guesses (learned, nearest-neighbour) and the KKT costates of
        # a switch-time optimisation carry a full switching structure: straight to the
        # switch-time Newton, no smoothing path
        path_cost = 0
        if per_axis and st is not None and src.startswith(("template", "learned", "nearest", "switch-time")):
            a = solve_structure(bvp, z, T, st, route=f"switch-time from {src}", deadline=deadline,
                                stall=TEMPLATE_STALL if src.startswith("template") else None)
            if a.success and segments > 1:
                a = _polish_multiple(bvp, a, segments)
        elif per_axis:
            a = per_axis_from_guess(bvp, z, T, st, eps_min=eps_min, deadline=deadline,
                                    T_accept=baseline * (1 + 1e-7) if baseline == baseline else math.inf,
                                    max_nfev=(max(cap_mult * first_nfev, cap_floor)
                                              if cap is not None and first_nfev is not None else math.inf))
            path_cost = a.nfev if a.route.startswith("tanh continuation") else 0
            if a.success and segments > 1:
                a = _polish_multiple(bvp, a, segments)
        else:
            a = pnorm_from_guess(bvp, z, T, prob.torque_norm, segments=segments, deadline=deadline)
        nit += a.nit
        nfev += a.nfev
        if not a.success:
            failures.append(f"{src}: {a.message}")
            continue
        if per_axis:
            bvp.set_mode("bang")
        else:
            bvp.set_mode("pnorm", p=prob.torque_norm)
        # the event check's record (T / DENSE_STEPS steps) of the same (z, T) serves as the dense record
        reuse = a.trajectory if (per_axis and n_dense == DENSE_STEPS) else None
        ok, checks, text, tr = verify(bvp, a.z, a.T, a.structure, tols=tols, n_dense=n_dense, trajectory=reuse)
        nfev += 2
        if not ok:
            last_verif_fail = (a, tr, checks, text, src)
            failures.append(f"{src}: {text}")
            continue
        found.append((a.T, a, tr, checks, src))
        # the reference is the cost of a built-in candidate's smoothing path (as measured:
        # a switch-time Newton from a full structure, ~10 propagations for a template, says
        # nothing about how long a path needs; a user's, a model's or collocation's guess
        # was not measured and does not set it)
        if first_nfev is None and path_cost > 0 and src.startswith("eigenaxis"):
            first_nfev = path_cost
        if first_verified and not (a.T > baseline * (1 + 1e-7)):
            break
        if len(found) >= enough and tried >= min_candidates:
            Ts = sorted(f[0] for f in found)
            beats_baseline = not (Ts[0] > baseline * (1 + 1e-7))
            if len(Ts) >= 2 and abs(Ts[1] - Ts[0]) <= 1e-7 * Ts[0] and beats_baseline:
                break
    wall = time.perf_counter() - t_start
    common = dict(nit=nit, nfev=nfev, method=method_used, n_candidates=tried, problem=prob,
                  baseline_tf=baseline * bvp.tau)
    # the baseline comes from a grid (conservative: never too fast) or, without a gyroscopic
    # term, its closed form: 1e-7 slack
    if found and min(f[0] for f in found) > baseline * (1 + 1e-7):
        best_T = min(f[0] for f in found)
        T, a, tr, checks, src = next(f for f in found if f[0] <= best_T * (1.0 + 1e-9))
        fields = solution_fields(bvp, a.z, a.T, a.route, tr, checks, src, prob, a.structure)
        cands = sorted({round(f[0] * bvp.tau, 9) for f in found})
        return SlewSolution(False, STATUS_WORSE_THAN_BASELINE,
                            f"{STATUS_MESSAGES[STATUS_WORSE_THAN_BASELINE]} Best extremal {T * bvp.tau:.9g} vs "
                            f"eigenaxis slew {baseline * bvp.tau:.9g}; tried {tried} candidate(s)."
                            + (f" First failure: {failures[0]}" if failures else ""),
                            wall_time=time.perf_counter() - t_start, candidates_tf=cands, **common, **fields)
    if found:
        best_T = min(f[0] for f in found)
        # among extremals with the same final time, report the first one found
        T, a, tr, checks, src = next(f for f in found if f[0] <= best_T * (1.0 + 1e-9))
        fields = solution_fields(bvp, a.z, a.T, a.route, tr, checks, src, prob, a.structure)
        cands = sorted({round(f[0] * bvp.tau, 9) for f in found})
        msg = STATUS_MESSAGES[STATUS_SUCCESS]
        if len(cands) > 1:
            msg += f" Best of {len(cands)} distinct extremals found (final times {cands})."
        return SlewSolution(True, STATUS_SUCCESS, msg, wall_time=time.perf_counter() - t_start,
                            candidates_tf=cands, **common, **fields)
    if last_verif_fail is not None:
        a, tr, checks, text, src = last_verif_fail
        fields = solution_fields(bvp, a.z, a.T, a.route, tr, checks, src, prob, a.structure)
        return SlewSolution(False, STATUS_VERIFICATION_FAILED,
                            f"{STATUS_MESSAGES[STATUS_VERIFICATION_FAILED]} {text}", wall_time=wall,
                            **common, **fields)
    status = STATUS_BUDGET_EXHAUSTED if time.perf_counter() > deadline else STATUS_NOT_CONVERGED
    detail = "; ".join(failures[:3])
    return SlewSolution(False, status, f"{STATUS_MESSAGES[status]} Tried {tried} candidate(s): {detail}",
                        wall_time=wall, route=f"{method_used}: no candidate converged ({tried} tried)", **common)
