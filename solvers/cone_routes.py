"""``solve`` with keep-out cones: the learned cone route, the refinements of a collocation answer
(inactive cones, touch points, the bang-bang switch-time answer), the indirect cone route with
its penalty homotopy, and ``auto``'s pointing-cones challenger."""

from __future__ import annotations

import itertools
import math
import time
from typing import Optional

import numpy as np

from .solution import STATUS_NOT_CONVERGED, STATUS_VERIFICATION_FAILED, SlewSolution
from .verify import make_check
from . import auto_route, multistart, stage_budget, warm_routes

# a cone model's candidate either converges in tens of milliseconds or not at all (90 % of the
# converged ones within 60 ms): each gets a short cap, and all of them a budget that costs
# little before the collocation route
CONE_WARM_BUDGET = 0.2

# s: below this time budget ``auto`` with cones tries the shipped pointing-cones warm start before
# its collocation route, not after it: collocation's starts and 80-interval solve take 0.3-0.5 s
# (bench_budget, 10 seed-5 problems: none finished in 0.2 s, all in 0.5 s), so under a shorter
# budget the route ends without an answer and the learned guess's verified extremal (70 % of
# held-out problems, 21 ms median, session 40; a slower local extremal on 4 in 10 of those) is the
# best on offer
CONE_LEARNED_FIRST_BELOW = 0.4
# ... and there the learned candidates get at most this share of the budget, the tabled
# solutions' sequences (``cone_sequences_route``) what is left after them, where that share is at
# least ``CONE_SEQUENCE_MIN_SHARE_S`` (a sequence's optimisation takes 40-150 ms; with less, the
# learned candidates get it all): 91 % of the learned answers on 1,000 held-out problems came
# within 0.1 s (runs/s39/eval_b_final)
CONE_SHORT_LEARNED_SHARE = 0.5
CONE_SEQUENCE_MIN_SHARE_S = 0.06


def short_learned_budget(budget) -> float:
    """The learned candidates' part of a short time ``budget`` (``CONE_SHORT_LEARNED_SHARE``)."""
    rest = (1.0 - CONE_SHORT_LEARNED_SHARE) * float(budget)
    return float(budget) - rest if rest >= CONE_SEQUENCE_MIN_SHARE_S else float(budget)

# auto's cone challenger (``cone_challenger``) runs where the route's answer is slower than this
# multiple of the pointing-cones network's predicted tf ("gated", the default), always, or never.
# On 600 problems (seeds 5, 6, 7; runs/s27/challenger_*.json) it won 3 times: 45 % faster (the
# answer 1.77 x the prediction), 1.1 % (1.0087 x) and 3e-7 (0.988 x); the gate challenges 45 % of
# the answers and keeps the first two
CONE_CHALLENGE_GATE = 1.0
CONE_CHALLENGE_MODES = ("gated", "always", "never")
CONE_CANDIDATE_CAP = 0.06
# under a short budget, after the first verified answer the learned candidates go on until this
# many times its time, the fastest answer kept (solve_learned_cones' ``more``). Held-out problems
# 0-149 at 0.3 s (runs/s41/more_ab.py, each problem with 1, 2 and 3, alternating): answers at
# auto's 74, 82, 90; more than 1 % slower than auto's 37, 30, 25; median time 42, 82, 124 ms
CONE_SHORT_SEARCH_MORE = 3.0

# a cone warm start whose candidates are cheap to make (``RANKS_CANDIDATES``: the shipped one) has
# those with touches tried in order of their starting residual (``ranked_by_starting_residual``),
# not in the model's order; the residuals may take this share of the warm start's budget (the
# shipped model's: 1.1 ms a problem, median, 1.3 ms p95, runs/s31/review/r_upfront_cost.py)
CONE_RANK_CANDIDATES = True
CONE_RANK_SHARE = 0.1

# s: auto's bang-bang switch-time optimisation (``auto_route.BANG_BANG_BUDGET``) with keep-out cones
# or a pointing target (its pulse rounds in turn, each with what is left): on 90 seed-100 cone
# problems 1 s left 11 answers to collocation that 4 s verified; on Melton's BP2 the round without
# pulses takes ~1 s and the one with 4 pairs, the answer, ~1.2 s
CONE_BANG_BANG_BUDGET = 3.0


def network_predicted_tf(model, prob) -> Optional[float]:
    """The pointing-cones network's predicted final time for ``prob`` (its ``tf`` guess, ``None``
    if it does not cover the problem or fails); ``model`` is the ensemble or the network."""
    net = getattr(model, "network", model)
    try:
        if hasattr(net, "predicted_tf"):    # (a cone network: no guess made for it)
            tf = net.predicted_tf(prob)
        else:
            g, why = net.guess_or_reason(prob)
            tf = None if why or g is None else float(g.tf)
    except Exception:   # noqa: BLE001 - no prediction: the challenge runs
        return None
    return tf if tf is not None and tf > 0.0 and math.isfinite(tf) else None


def beats(new, old) -> bool:
    """Whether a challenger's verified answer ``new`` replaces ``auto``'s answer ``old``: ``old``
    failed, or ``new`` is faster, or, where ``old`` is approximate, ``new`` is exact and as fast within
    ``old``'s own accuracy (an approximate answer's tf is only known to its ``tf_tol``)."""
    tol = old.tf_tol if old.success and math.isfinite(old.tf_tol) else 0.0
    return (not old.success or new.tf < old.tf * (1.0 - 1e-9)
            or (new.exact and not old.exact and new.tf <= old.tf + tol))


def cone_challenger(prob, sol, options, t0, gated=True) -> SlewSolution:
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
        predicted = network_predicted_tf(model, prob)
        if predicted is not None and sol.tf <= CONE_CHALLENGE_GATE * predicted:
            sol.warm_start = {"model": getattr(model, "name", type(model).__name__), "covered": True,
                              "role": "challenger", "challenged": False, "won": False, "predicted_tf": predicted,
                              "reason": f"the answer's tf {sol.tf:.9g} is not above the network's predicted "
                                        f"{predicted:.9g} (cone_challenge='gated')"}
            sol.wall_time = time.perf_counter() - t0
            return sol
    try:
        ch, info, _ = warm_routes.try_warm_start(prob, "auto", "pointing-cones", dict(options, warm_budget=budget))
    except Exception as e:   # noqa: BLE001 - the verified answer stands; the failure is recorded
        ch, info = None, {"model": getattr(model, "name", type(model).__name__), "covered": True,
                          "succeeded": False, "error": f"{type(e).__name__}: {e}"[:300]}
    info = dict(info, role="challenger", **({"won": False, "challenged": True} if info.get("covered") else {}))
    if ch is None or not ch.success:
        sol.warm_start = info
        sol.wall_time = time.perf_counter() - t0
        return sol
    info["tf"] = float(ch.tf)
    faster = ch.exact and beats(ch, sol)
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
    ch = warm_routes.replace_answer(ch, sol, info)
    ch.wall_time = time.perf_counter() - t0
    return ch


def cone_neighbour_starts(prob) -> list:
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


def solve_learned_cones(prob, g, options, budget, cap=None, errors=None, rank=False, more=1.0) -> SlewSolution:
    """A guess for a problem with keep-out cones, tried candidate by candidate: with
    ``touches``, the touch-point extremal (``cone_touch.solve_touch_guess``, switch-time
    formulation first when the guess has a structure); without, the extremal of the problem
    without cones, accepted only if its path clears every cone (certified). A deferred
    candidate that cannot be made (a model's error) is skipped, and its error added to
    ``errors`` (a list) where given. With ``rank`` (a model whose candidates are cheap to make,
    ``RANKS_CANDIDATES``; and ``CONE_RANK_CANDIDATES``) every candidate is made first and those
    with touches are tried in order of their starting residual (``ranked_by_starting_residual``,
    within ``CONE_RANK_SHARE`` of the budget): a candidate that cannot be made is then reported
    even where an earlier one converges. ``more`` > 1: after the first verified answer, at
    ``t₁`` s, the next candidates are tried until ``more · t₁`` (and the budget), and the fastest
    verified answer is kept (another candidate often reaches a faster local extremal); those
    whose path passes some cone on another side than the first answer's go first
    (``CONE_OTHER_SIDES_FIRST``)."""
    from .cone_touch import solve_touch_guess
    t0 = time.perf_counter()
    tried, last = 0, None
    nit = nfev = 0
    skipped = [] if errors is None else errors
    cands = g.iter_all(errors=skipped)
    if rank and CONE_RANK_CANDIDATES:
        cands = ranked_by_starting_residual(prob, list(cands), deadline=t0 + CONE_RANK_SHARE * budget)
    best, t_first, after, verified_tf = None, None, 0, set()
    queue = iter(cands)
    while True:
        cand = next(queue, None)
        if cand is None:
            break
        left = min(budget - (time.perf_counter() - t0), CONE_CANDIDATE_CAP if cap is None else cap)
        if best is not None:
            # the search after the first answer: within more · t₁ and the budget, each attempt
            # with a hard deadline, none started with less than a converging attempt takes
            now = time.perf_counter() - t0
            left = min(left, more * t_first - now, budget - CONE_SEARCH_RESERVE - now)
            if left < CONE_SEARCH_MIN_LEFT:
                break
        if left <= 0.0:
            break
        tried += 1
        after += best is not None
        try:
            if cand.touches:
                sol = solve_touch_guess(prob, cand, tols=options.get("tols"), time_budget=left, smoothing=False,
                                        **({"deadline": time.perf_counter() + left} if best is not None else {}))
            else:
                sol = multistart.guess_alone(prob.replace(cones=[]), cand, options, left, with_candidates=False)
                if sol.success and not certify_clear(prob, sol):
                    sol.success, sol.status = False, STATUS_VERIFICATION_FAILED
                    sol.message = (f"the extremal without cones enters a cone (certified clearance "
                                   f"{sol.verification['cone_clearance']['value']:.3g} rad)")
                sol.problem = prob
        except Exception as e:      # noqa: BLE001 - after a verified answer, a bad candidate is skipped
            if best is None:
                raise
            skipped.append(f"candidate {tried}: {type(e).__name__}: {e}"[:300])
            continue
        nit, nfev = nit + sol.nit, nfev + sol.nfev
        last = sol
        if sol.success:
            verified_tf.add(round(float(sol.tf), 9))
            if best is None:
                best, t_first = sol, time.perf_counter() - t0
                if more > 1.0 and CONE_OTHER_SIDES_FIRST and isinstance(cands, list):
                    # (a ranked list: its candidates are made already; the reordering's replays
                    # take 2-4 ms, within what the search may spend)
                    queue = iter(other_sides_first(prob, sol, list(queue),
                                                   deadline=t0 + min(budget - CONE_SEARCH_RESERVE, more * t_first)))
            elif sol.tf < best.tf * (1.0 - 1e-9):
                best = sol
            if not more > 1.0:
                break
    if best is not None:
        if after:
            best.route += f"; {after} more candidate(s) tried after the first verified answer, the fastest kept"
        best.candidates_tf = sorted(verified_tf | {round(float(t), 9) for t in (best.candidates_tf or [])})
        last = best
    if last is None:
        why = f"no candidate could be made ({'; '.join(skipped)[:300]})" if skipped else "no time left for the guess"
        return SlewSolution(False, STATUS_NOT_CONVERGED, why, 0, 0,
                            time.perf_counter() - t0, method="indirect", problem=prob, route="learned guess: no time")
    last.nit, last.nfev, last.n_candidates = nit, nfev, tried
    last.wall_time = time.perf_counter() - t0
    return last


# ... and those that pass some cone on another side than that first answer go first
# (``other_sides_first``): held-out problems 0-299 at 0.3 s (runs/s41/sides_ab.py, with and
# without, alternating), 8 faster answers (by 2e-4 to 7 %), none slower, the same time
CONE_OTHER_SIDES_FIRST = True
# s: no candidate of the search after the first answer starts with less left (a converging
# attempt takes 8 ms or more; a review found 1 ms attempts ending 0.3-1.5 ms late)
CONE_SEARCH_MIN_LEFT = 0.008
# s: and it ends this long before the learned stage's budget, which may be the whole solve's:
# what follows an answer (its baseline, the records) took 2-4 ms past a 0.1 s budget (a review)
CONE_SEARCH_RESERVE = 0.006


def cone_windings(prob, directions) -> np.ndarray:
    """The angle (rad) the sensor's path (inertial ``directions``, (n, 3)) turns about each cone's
    axis: paths between the same ends that pass a cone on different sides differ by about 2π."""
    from slew_env.core.cones import perpendicular_basis
    out = np.empty(len(prob.cones))
    for k, c in enumerate(prob.cones):
        e1, e2 = perpendicular_basis(np.asarray(c.axis, float))
        phi = np.unwrap(np.arctan2(directions @ e2, directions @ e1))
        out[k] = phi[-1] - phi[0]
    return out


def other_sides_first(prob, first, cands, deadline=math.inf) -> list:
    """``cands`` with those whose switch times, flown alone (an RK4 replay of 400 steps), pass
    some cone on another side than the answer ``first`` moved to the front (their order kept);
    candidates without switch times in the middle, and those not reached by ``deadline``
    (``time.perf_counter()``) at the end, in their order."""
    from .clearance import sensor_directions
    from .verify import replay_path
    q = getattr(first, "q", None)
    if q is None or len(q) < 2 or not prob.cones:
        return cands        # (no dense path to compare with: the order stays)
    ref = cone_windings(prob, sensor_directions(np.asarray(q, float), prob.sensor_axis))
    other, unknown, same = [], [], []
    for k, c in enumerate(cands):
        if time.perf_counter() > deadline:
            return other + unknown + same + list(cands[k:])
        if c.switch_times is None or c.u_first is None:
            unknown.append(c)
            continue
        try:
            _, x = replay_path(prob.inertia, prob.torque_max, prob.q0, prob.omega0, c.switch_times, c.u_first, c.tf, 400)
            w = cone_windings(prob, sensor_directions(x[:, 0:4], prob.sensor_axis))
        except (ValueError, FloatingPointError, TypeError):
            unknown.append(c)
            continue
        (other if np.any(np.abs(w - ref) > math.pi) else same).append(c)
    return other + unknown + same


def ranked_by_starting_residual(prob, cands, deadline=math.inf) -> list:
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


def refine_inactive_cones(prob, col, options, budget_left, label="auto"):
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
    ref, accepted = auto_route.refine_collocation(prob.replace(cones=[]), col, options, 1, min(2.0, stage_budget.left(budget_left, 0.0)))
    if not accepted or not certify_clear(prob, ref):
        return None
    ref.route = (f"{label}: collocation ({col.wall_time:.3g} s; cones inactive, clearance {cc['value']:.3g} rad) → "
                 f"indirect refinement without cones: {ref.route}; certified clearance "
                 f"{ref.verification['cone_clearance']['value']:.3g} rad")
    ref._cone_free = True
    return ref


def certify_clear(prob, sol):
    """Record on ``sol`` (an answer of ``prob`` without its cones) the certified clearance of
    its path from the cones of ``prob`` (``cone_clearance``) and rebind it to ``prob``;
    ``True`` if the path clears every cone at every instant."""
    from .clearance import CLEARANCE_TOL, answer_clearance
    from .eigenaxis import BASELINE_CLEARANCE, eigenaxis_path_margin
    certified = answer_clearance(prob, sol)
    sol.verification["cone_clearance"] = make_check(certified, CLEARANCE_TOL, certified >= CLEARANCE_TOL)
    sol.problem = prob
    # the baseline of the problem without cones is prob's only where the eigenaxis path keeps its
    # distance from them (``eigenaxis.baseline_time``)
    # (only where there is a baseline to drop: this runs on every converged learned candidate)
    if math.isfinite(sol.baseline_tf) and eigenaxis_path_margin(prob) < BASELINE_CLEARANCE:
        sol.baseline_tf = math.nan
    return certified >= CLEARANCE_TOL


# s: where the answer without cones enters a cone, its switching sequence optimised with the cones
# imposed (``switch_time_opt.bang_bang_from_sequences``) gets at most this (``clear_without_cones``):
# a cone 1.1e-6 to 1e-5 rad inside the cone-free path had ended in status 2 after 15-20 s, though a
# slew 3.4e-7 slower clears it (runs/s44/adv/REPORT.md finding 2)
CONE_FREE_REPAIR_BUDGET = 1.0


def clear_without_cones(prob, col, options, col_opts, budget_left, exact_only=False, label="auto", why=None):
    """When collocation fails on a cone problem: the answer of the problem without its cones,
    if its path clears every cone at every instant (certified), else ``None`` (also with no time
    left, ``budget_left ≤ 0``). A cone far from
    the path can still upset the NLP; the unconstrained optimum that is feasible is the
    constrained optimum. Unless ``exact_only``, where that path enters a cone, its switching
    sequence is optimised with the cones imposed (``CONE_FREE_REPAIR_BUDGET``; a cone that only
    clips it needs a small detour, which collocation's mesh can miss): that verified bang-bang
    slew, or the touch-point extremal at it (``exact_from_own_costates``), is returned instead.
    ``why``: the route's account of the collocation that failed. The answer returned counts its
    own work only (the caller adds ``col``'s); where none is, the attempt's work is added to
    ``col``."""
    if budget_left <= 0.0:      # no time left: the route it would take starts with an NLP build
        return None
    t0 = time.perf_counter()
    free_prob = prob.replace(cones=[])
    opts = dict(options, time_budget=stage_budget.left(budget_left, 0.0))
    free = (multistart.solve_indirect(free_prob, "indirect", None, **opts) if exact_only
            else auto_route.solve_auto(free_prob, None, col_opts, opts))
    why = why or f"collocation with the cones failed ({col.message[:120]})"
    out = None
    if free.success and not (exact_only and not free.exact):
        if certify_clear(prob, free):
            free.route = (f"{label}: {why} → the problem without cones, "
                          f"whose path clears them (certified {free.verification['cone_clearance']['value']:.3g} rad): "
                          f"{free.route}")
            free._cone_free = True
            out = free
        elif not exact_only:
            left = min(CONE_FREE_REPAIR_BUDGET, budget_left - (time.perf_counter() - t0))
            out = _repaired_free_answer(prob, free, options, left, f"{label}: {why}")
    if out is None:         # (the attempt's work is the caller's answer's)
        col.nit += free.nit
        col.nfev += free.nfev
    return out


def _repaired_free_answer(prob, free, options, left, prefix) -> Optional[SlewSolution]:
    """The switching sequence of ``free`` (an answer of ``prob`` without its cones, whose path
    enters one) optimised with the cones imposed within ``left`` s, and the touch-point extremal at
    it where one is certified; ``None`` if nothing is verified (or ``free`` has no switch list)."""
    from .switch_time_cones import switch_time_cones_applies
    from .switch_time_opt import bang_bang_from_sequences
    t0 = time.perf_counter()
    if left <= 0.05 or not (free.exact or free.method == "switch-time") or not switch_time_cones_applies(prob):
        return None
    entered = free.verification["cone_clearance"]["value"]
    seq = (np.asarray(free.u_first, float), [np.asarray(s, float) for s in free.switch_times], float(free.tf))
    bang, _, (nit, nfev) = bang_bang_from_sequences(prob, [seq], time_budget=left, tols=options.get("tols"),
                                                    source="the answer without cones", numbered=False)
    if bang is None:
        free.nit += nit
        free.nfev += nfev
        return None
    bang.nit += free.nit        # (its own work is counted in it already)
    bang.nfev += free.nfev
    bang.route = (f"{prefix} → the problem without cones, whose path enters a cone (certified {entered:.3g} rad) "
                  f"→ its switching sequence with the cones imposed: {bang.route}")
    # (within what is left of ``left``: the touch solve's own minimum keeps it from starting late)
    ex, _ = exact_from_own_costates(prob, bang, options,
                                    min(OWN_COSTATES_BUDGET, left - (time.perf_counter() - t0)))
    return ex if ex is not None else bang


# auto with cones: the problem without its cones challenges the answer (``cone_free_challenger``)
# where the eigenaxis slew's sensor path clears every cone, within this budget (s) and only with at
# least ``CONE_FREE_CHALLENGE_MIN_LEFT`` s of the solve's left. Collocation can settle on a local
# extremal that touches a cone the cone-free optimum clears: of an adversarial check's 95 answers
# with a valid cone-free optimum, 30 were over 1e-4 slower (up to 16 %), 19 of them where the
# eigenaxis path clears the cones (runs/s44/eig_gate_adv.py). On 300 held-out pointing-cones problems, whose cones lie
# across the path, that path clears them on none (runs/s44/eig_gate.py): they pay nothing
CONE_FREE_CHALLENGE_BUDGET = 2.0
CONE_FREE_CHALLENGE_MIN_LEFT = 0.3


def eigenaxis_path_clear(prob) -> bool:
    """Whether the sensor of the rest-to-rest ``prob``'s eigenaxis slew (to its reference
    attitude) stays out of every cone (``eigenaxis.eigenaxis_path_margin`` > 0: a gate, not a
    certificate); ``False`` without cones or not at rest."""
    from .eigenaxis import eigenaxis_path_margin
    return bool(prob.cones) and prob.is_rest_to_rest and eigenaxis_path_margin(prob) > 0.0


def cone_free_challenger(prob, sol, options, col_opts, t0) -> SlewSolution:
    """``auto``'s answer ``sol`` to ``prob`` (with cones), or the answer of the problem without
    its cones (``clear_without_cones``: where its path clears the cones; where it clips one, its
    repaired sequence) where it ``beats`` ``sol`` (``cone_challenger``'s rule). Run only where the eigenaxis path
    clears every cone (``eigenaxis_path_clear``), ``sol`` is not already an answer or extremal of
    the problem without cones (``SlewSolution._cone_free``), and ``CONE_FREE_CHALLENGE_MIN_LEFT``
    of the budget is left; within ``CONE_FREE_CHALLENGE_BUDGET``. The route records the challenge;
    the work of both is counted and ``wall_time`` is the whole solve's."""
    if sol.success and sol._cone_free:
        return sol
    left = float(options.get("time_budget", 20.0)) - (time.perf_counter() - t0)
    if left < CONE_FREE_CHALLENGE_MIN_LEFT or not eigenaxis_path_clear(prob):
        return sol
    what = f"{sol.method} answer {sol.tf:.9g}" if sol.success else "failure"
    challenge = "the problem without cones challenged it (the eigenaxis path clears the cones)"
    free = clear_without_cones(prob, sol, options, col_opts, min(CONE_FREE_CHALLENGE_BUDGET, left),
                               why=f"the eigenaxis path clears the cones: a challenge to the route's {what}")
    if free is not None and beats(free, sol):
        out = warm_routes.replace_answer(free, sol, sol.warm_start)
        out.route += f"; it replaced the route's {what}"
    else:
        out = sol
        if free is not None:
            sol.nit += free.nit
            sol.nfev += free.nfev
        sol.route += f"; {challenge} and lost" + (f" ({free.tf:.9g})" if free is not None else "")
    out.wall_time = time.perf_counter() - t0
    return out


# the pointing-cones table's sequences route (``cone_sequences_route``): the switching sequences
# of this many nearest tabled solutions, optimised with the cones imposed, the fastest verified
# kept. On the 133 of held-out problems 0-399 where the session-39 warm start's candidates
# failed (session 40, runs/s40/st_proto.py, 2 s a problem): 132 verified (133 with 5 s a
# sequence); against solve()'s answers (collocation route) a median gap of 6.9e-5 with 4
# sequences, 1.3e-4 with 3, 7.2e-4 with the first alone (17, 17 and 36 more than 1 % slower; the
# first alone verified 110). With 0.5 s and the exact attempt after it, on a loaded machine, 130
# (runs/s40/route_eval.py)
CONE_SEQUENCES = 4
CONE_SEQUENCE_BUDGET = 0.5      # s
# a sequence whose boundary residual is still above this after a round is dropped
CONE_SEQUENCE_GIVE_UP = 1e-2
# s: under a short time budget the sequences are not started with less than this left
CONE_SEQUENCE_MIN_LEFT = 0.02
# s: the exact extremal at the sequences' answer (``exact_near_bang_bang``), beyond their budget.
# On the 133 problems above (a loaded machine, runs/s40/route_eval.py): 0.06 s gave 37 exact
# extremals (27 at solve()'s answer), 0.2 s 41 (31); 85 of the 133 have an exact optimum. With
# the session-40 table, on a quiet machine, 0.15 s: 45 with the winning neighbour's costates
# alone, 48 trying the others' after them (route_015_single/multi.jsonl)
CONE_SEQUENCE_EXACT_BUDGET = 0.15
# a touch multiplier where no neighbour's touch of that cone gives one
TOUCH_NU_GUESS = 0.05
# s: an exact attempt is not started with less than this left of its budget
CONE_EXACT_MIN_LEFT = 0.005


def cone_sequences_route(prob, options, info, model="pointing-cones", budget=CONE_SEQUENCE_BUDGET):
    """``(answer or None, (nit, nfev))``: a verified bang-bang slew of a per-axis problem with
    keep-out cones, without collocation, from the switching sequences of the
    ``CONE_SEQUENCES`` nearest solutions of a pointing-cones table (``model``: a name for
    ``warmstart.resolve``, or a model with a ``table``, or a table), their switch times and
    ``tf`` optimised with the cones imposed (``switch_time_opt.bang_bang_from_sequences``),
    within ``min(budget, options["time_budget"])``; the fastest verified one is kept: exactly
    feasible, its clearance certified on an RK4 replay, not an extremal (``method="switch-time"``,
    ``exact`` false; ``tf_tol`` NaN, no collocation answer to compare with; ``costate0`` its KKT
    costates where its path keeps clear of the cones, else NaN: with active cones the
    multipliers are not costates). Then, within ``CONE_SEQUENCE_EXACT_BUDGET`` more (never past
    ``options["time_budget"]``), the exact extremal at that answer (``exact_near_bang_bang``),
    which replaces it where found and not slower. ``info["neighbour_sequences"]`` records what
    happened. For ``auto`` under a time budget that collocation does not fit in,
    after the learned candidates failed, and for ``slew evaluate``'s ``learned+table`` row."""
    from . import warmstart
    from .switch_time_cones import switch_time_cones_applies
    from .switch_time_opt import bang_bang_from_sequences
    from .warmstart.cone_nearest import ConeNearestNeighbourModel
    t0 = time.perf_counter()
    rec = info["neighbour_sequences"] = {"used": False}
    if not (prob.cones and switch_time_cones_applies(prob)):
        rec["skipped"] = "not a per-axis problem with keep-out cones"
        return None, (0, 0)
    try:
        m = warmstart.resolve(model, prob) if isinstance(model, str) else model
        table = m if isinstance(m, ConeNearestNeighbourModel) else getattr(m, "table", None)
        if not isinstance(table, ConeNearestNeighbourModel) or table.covers(prob):
            rec["skipped"] = "no pointing-cones table covers the problem"
            return None, (0, 0)
        g = table.guess(prob, k=CONE_SEQUENCES)
    except Exception as e:   # noqa: BLE001 - a damaged file or model: no answer from it, the solve goes on
        rec["error"] = f"{type(e).__name__}: {e}"[:300]
        return None, (0, 0)
    budget = min(float(budget), float(options.get("time_budget", 20.0)))
    neighbours = [g] + list(g.candidates)
    best = None                 # (answer, its KKT guess, its neighbour)
    nit = nfev = tried = 0
    for nb in neighbours:
        left = budget - (time.perf_counter() - t0)
        if left < CONE_SEQUENCE_MIN_LEFT:       # (not one optimisation round's time)
            break
        tried += 1
        try:
            bang, kkt_guess, (n_it, n_fev) = bang_bang_from_sequences(
                prob, [(nb.u_first, nb.switch_times, nb.tf)], time_budget=left, tols=options.get("tols"),
                source=f"the {nb.source} tabled solution", give_up_residual=CONE_SEQUENCE_GIVE_UP, kkt_tol=math.inf,
                numbered=False)
        except ValueError as e:     # a tabled sequence that is not one (a damaged table row)
            rec.setdefault("errors", []).append(f"{nb.source}: {e}"[:200])
            continue
        nit, nfev = nit + n_it, nfev + n_fev
        if bang is not None and (best is None or bang.tf < best[0].tf):
            best = (bang, kkt_guess, nb)
    rec.update(sequences=len(neighbours), tried=tried)
    if best is None:
        rec["time_s"] = time.perf_counter() - t0
        return None, (nit, nfev)
    bang, kkt_guess, nb = best
    bang.nit, bang.nfev, bang.n_candidates = nit, nfev, tried
    prefix = f"the {len(neighbours)} nearest tabled solutions' sequences ({tried} tried)"
    # (beyond the sequences' own budget, never beyond the solve's)
    left = min(budget + CONE_SEQUENCE_EXACT_BUDGET, float(options.get("time_budget", 20.0))) - (
        time.perf_counter() - t0)
    # (the winning neighbour's costates first, then the others', for a touching path)
    others = [c for c in neighbours if c is not nb]
    ex, (x_nit, x_nfev), why = exact_near_bang_bang(prob, bang, kkt_guess, [nb] + others, options,
                                                    min(CONE_SEQUENCE_EXACT_BUDGET, left))
    rec["exact"] = ex is not None
    if ex is not None:
        ex.nit, ex.nfev = ex.nit + nit, ex.nfev + nfev
        ex.n_candidates = tried + 1
        ex.route = f"{prefix} → {bang.route} → {ex.route}"
        answer = ex
    else:
        # the exact attempt's work is counted, and why it gave nothing said
        bang.nit, bang.nfev = bang.nit + x_nit, bang.nfev + x_nfev
        rec["exact_reason"] = why
        bang.route = f"{prefix} → {bang.route}; no exact extremal at it ({why[:160]})"
        answer = bang
    rec.update(used=True, time_s=time.perf_counter() - t0)
    answer.wall_time = time.perf_counter() - t0
    return answer, (0, 0)


def exact_near_bang_bang(prob, bang, kkt_guess, neighbours, options, budget):
    """The exact extremal at a verified bang-bang answer ``bang`` of a cone problem (its switch
    instants and ``tf``), or ``None``: where its path keeps clear of the cones, the extremal of
    the problem without them from its KKT costates (``kkt_guess``), accepted only if its path
    clears every cone (certified); where it meets cones (margin minima below
    ``TOUCH_MARGIN_SEQUENCE`` on an RK4 replay), the touch-point extremal
    (``cone_touch.solve_touch_guess``) from those touches and the answer's instants, with the
    costates and touch multipliers fitted on its own path (``touch_costates``), then those of
    each of ``neighbours`` in turn (each attempt at most ``CONE_CANDIDATE_CAP``), until one
    converges or ``budget`` is spent. Kept only if not slower
    than ``bang`` (by 1e-6: another extremal is a slower local optimum). Returns ``(extremal or
    None, (nit, nfev) of the attempts, why there is none)``."""
    from .cone_touch import solve_touch_guess
    from .guesses import Guess
    from .touch_costates import touch_guess
    t0 = time.perf_counter()
    if budget <= 0.0:
        return None, (0, 0), "no time left"
    if kkt_guess is not None:
        ex = multistart.guess_alone(prob.replace(cones=[]), kkt_guess, options, budget, with_candidates=False)
        ex.problem = prob
        if ex.success and not certify_clear(prob, ex):
            ex.success = False
            ex.message = (f"the extremal without cones from its KKT costates enters a cone (certified clearance "
                          f"{ex.verification['cone_clearance']['value']:.3g} rad)")
        work = (int(ex.nit), int(ex.nfev))
    else:
        touches = touches_on_path(prob, bang, neighbours[0].touches)
        if not touches:
            return None, (0, 0), "its path neither keeps clear of the cones nor touches one at isolated instants"
        nit = nfev = tried = 0
        ex = None
        # first the answer's own costates and multipliers, fitted on its path (touch_costates),
        # then each neighbour's costates with the answer's instants and touches
        own, fit = touch_guess(prob, bang, touches)
        nfev += fit["nfev"]
        seeds = ([own] if own is not None else []) + list(neighbours)
        for seed in seeds:
            left = budget - (time.perf_counter() - t0)
            if left < CONE_EXACT_MIN_LEFT:      # (a converging attempt takes 8 ms or more)
                break
            tried += 1
            if seed is own:
                g = own
            else:
                g = Guess(seed.costate0, bang.tf, [np.asarray(x, float) for x in bang.switch_times], bang.u_first,
                          source=f"the switch-time answer's instants and touches, {seed.source}'s")
                g.touches = [(c, t, _first_nu(seed.touches, c, n0)) for c, t, n0 in touches]
            ex = solve_touch_guess(prob, g, tols=options.get("tols"), time_budget=min(left, CONE_CANDIDATE_CAP),
                                   smoothing=False)
            nit, nfev = nit + int(ex.nit), nfev + int(ex.nfev)
            if ex.success and ex.tf <= bang.tf * (1.0 + 1e-6):
                break           # (a slower extremal is another local optimum: the next costates)
        if ex is None:
            return None, (nit, nfev), "no time left"
        work = (nit, nfev)
        if not ex.success or ex.tf > bang.tf * (1.0 + 1e-6):
            what = (("its own fitted costates and " if own is not None else f"(no fitted costates: {fit['reason']}) ")
                    + f"{tried - (own is not None)} neighbours' costates")
            ex.message = f"{what} tried; the last: {ex.message}"
    if not ex.success:
        return None, work, ex.message
    if ex.tf > bang.tf * (1.0 + 1e-6):
        return None, work, f"the extremal found, tf {ex.tf:.9g}, is slower than the bang-bang answer"
    ex.nit, ex.nfev = work      # (every attempt's work, the failed ones' too)
    return ex, (0, 0), ""


# rad: where the margin of a bang-bang answer's path has a local minimum below this, it touches a
# cone there (its samples keep 5e-7 rad: switch_time_cones.SAMPLE_MARGIN)
TOUCH_MARGIN_SEQUENCE = 1e-5
# the RK4 steps over tf of the replay that finds them
TOUCH_REPLAY_STEPS = 4000


def touches_on_path(prob, sol, known=None) -> list:
    """``[(cone, instant, ν)]``: the local minima of each cone's margin below
    ``TOUCH_MARGIN_SEQUENCE`` on an RK4 replay of a bang-bang answer ``sol``; ``ν`` that of the
    first touch of the same cone in ``known`` (a neighbour's touches), else ``TOUCH_NU_GUESS``."""
    from .clearance import cone_margins
    from .switch_time_cones import margin_minima
    from .verify import replay_path
    t, x = replay_path(prob.inertia, prob.torque_max, prob.q0, prob.omega0, sol.switch_times, sol.u_first, sol.tf,
                       TOUCH_REPLAY_STEPS)
    m = cone_margins(prob, x[:, 0:4])
    out = [(k, float(t[i]), _first_nu(known, k, TOUCH_NU_GUESS))
           for k in range(m.shape[1]) for i in margin_minima(m[:, k], TOUCH_MARGIN_SEQUENCE)]
    return sorted(out, key=lambda c: c[1])


def _first_nu(touches, cone, default) -> float:
    """``ν`` of the first of ``touches`` (``[(cone, instant, ν)]``) on ``cone``, else ``default``."""
    return float(next((nu for c, _, nu in (touches or []) if c == cone), default))


def bang_bang_cones(prob, col, options, left):
    """``switch_time_cones.bang_bang_cone_answer`` within ``min(CONE_BANG_BANG_BUDGET, left)`` (``None``
    when less than 50 ms are left, or it gives nothing)."""
    if not col.success or left <= 0.05:
        return None
    from .switch_time_cones import bang_bang_cone_answer
    return bang_bang_cone_answer(prob, col, time_budget=min(CONE_BANG_BANG_BUDGET, left), tols=options.get("tols"))


# s: the touch-point attempt at a switch-time answer from its own fitted costates (converging
# ones took 11–13 ms on bench_cones' seed 0), and the least time left for one: its replay, fit
# and verification run outside the touch solver's deadline (13 ms on a 5 ms budget, a review)
OWN_COSTATES_BUDGET = 0.1
OWN_COSTATES_MIN_LEFT = 0.02


def exact_from_own_costates(prob, bang, options, budget=OWN_COSTATES_BUDGET):
    """The touch-point extremal at a verified switch-time answer ``bang`` whose path touches cones
    at isolated instants (``touches_on_path``), from the costates and multipliers fitted on that
    path (``touch_costates``), without smoothing: ``(extremal, "")`` if one is certified no slower
    than ``bang`` (by 1e-6) within ``budget`` s, with ``bang``'s work and route before its own;
    else ``(None, why)`` with the attempt's work counted in ``bang``, or ``(None, None)`` where
    no attempt is made (less than ``OWN_COSTATES_MIN_LEFT`` left, no touch on its path). On
    ``bench_cones``' 30 problems of seed 0 it turned 2 of ``auto``'s 7 switch-time answers into
    exact extremals."""
    from .cone_touch import solve_touch_guess
    from .touch_costates import touch_guess
    t0 = time.perf_counter()
    if budget < OWN_COSTATES_MIN_LEFT or not prob.cones or bang.switch_times is None:
        return None, None
    touches = touches_on_path(prob, bang)
    if not touches:
        return None, None
    g, info = touch_guess(prob, bang, touches)
    bang.nfev += info["nfev"]
    if g is None:
        return None, info["reason"]
    left = budget - (time.perf_counter() - t0)
    if left < CONE_EXACT_MIN_LEFT:
        return None, "no time left after the fit"
    ex = solve_touch_guess(prob, g, tols=options.get("tols"), time_budget=left, smoothing=False,
                           deadline=time.perf_counter() + left)
    if not ex.success or ex.tf > bang.tf * (1.0 + 1e-6):
        bang.nit += int(ex.nit)
        bang.nfev += int(ex.nfev)
        return None, (ex.message if not ex.success else f"the extremal found, tf {ex.tf:.9g}, is slower")
    ex.nit += bang.nit
    ex.nfev += bang.nfev
    ex.route = f"{bang.route} → {ex.route}"       # (touch-point junctions … from its own fitted costates)
    return ex, ""


def settle_tf_tol(sol, budget) -> None:
    """``collocation.settle_tf_tol``, for the cone refinements here and ``auto_route.refine_collocation``
    (collocation is imported where used, as throughout the routes)."""
    from .collocation import settle_tf_tol as settle
    settle(sol, budget)


def rel_tol(col) -> float:
    """The relative tolerance a refinement of ``col`` may be slower by (each side): its
    ``tf_tol`` relative, at least 1e-3 (NaN, not measured or deferred: 1e-3)."""
    return max(float(col.tf_tol) / col.tf if col.tf_tol == col.tf_tol else 0.0, 1e-3)


def refine_touching_cones(prob, col, options, budget=TOUCH_BUDGET) -> SlewSolution:
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
        rel = rel_tol(col)
        settle_tf_tol(col, min(TOUCH_BUDGET, deadline - time.perf_counter()))
        if rel_tol(col) > rel and time.perf_counter() < deadline:
            sol = solve_touch(prob, col, tols=options.get("tols"), time_budget=touch_budget, deadline=deadline)
    sol.nit += col.nit
    sol.nfev += col.nfev
    return sol


def solve_indirect_cones(prob, guess, col_opts, options) -> SlewSolution:
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
        free = clear_without_cones(prob, col, options, col_opts, budget - (time.perf_counter() - t0),
                                   exact_only=True, label="indirect with cones")
        if free is not None:
            free.wall_time = time.perf_counter() - t0
            return free
        col.success = False
        col.method = "indirect"
        col.route = f"indirect with cones: collocation seed failed ({col.message[:200]})"
        col.wall_time = time.perf_counter() - t0
        return col
    ref = refine_inactive_cones(prob, col, options, budget - (time.perf_counter() - t0), label="indirect with cones")
    if ref is not None:
        ref.wall_time = time.perf_counter() - t0
        return ref
    touch = refine_touching_cones(prob, col, options, stage_budget.left(budget, time.perf_counter() - t0))
    if touch.success:
        touch.route = f"indirect with cones: collocation ({col.wall_time:.3g} s) → {touch.route}"
        touch.wall_time = time.perf_counter() - t0
        return touch
    settle_tf_tol(col, budget - (time.perf_counter() - t0))   # the penalty route's tf_tol builds on it
    sol = solve_penalised(prob, col, segments=segments, tols=options.get("tols"),
                          time_budget=stage_budget.left(budget, time.perf_counter() - t0))
    sol.nit += col.nit + touch.nit
    sol.nfev += col.nfev + touch.nfev
    if sol.success:
        # the penalised extremal's costates carry the touch jumps smoothed out, a better seed
        # for the exact touch refinement than collocation's
        exact = refine_touching_cones(prob, sol, options, stage_budget.left(budget, time.perf_counter() - t0))
        if exact.success:
            exact.route = f"indirect with cones: collocation ({col.wall_time:.3g} s) → {sol.route} → {exact.route}"
            exact.wall_time = time.perf_counter() - t0
            return exact
    sol.route = f"indirect with cones: collocation ({col.wall_time:.3g} s, tf {col.tf:.6g}) → {sol.route}"
    sol.wall_time = time.perf_counter() - t0
    return sol


def warm_up_solve(problem, guess):
    """A cone model's warm-up solve: its guess through the same route as the candidates, with
    no time caps (``ConeEnsembleWarmStart.warm_up`` runs one with touches, one without)."""
    return solve_learned_cones(problem, guess, {}, 5.0, cap=5.0)
