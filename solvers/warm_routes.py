"""``solve``'s learned warm start: the model's candidates (a cone model's through
``cone_routes.solve_learned_cones``), the checks of its answer (the eigenaxis baseline, the
collocation challenge of a likely local optimum), and the shortcuts after a full-attitude guess
fails (the singular table, the nearest tabled sequences)."""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Optional, Tuple

from .guesses import Guess
from .solution import SlewSolution
from .verify import make_check
from . import auto_route, cone_routes, eigenaxis_answer, multistart, stage_budget

WARM_BUDGET = 1.0   # s: the learned guess's candidates (its continuation candidate rarely needs more)

# auto: a warm-start extremal this much slower than the model's predicted final time is
# challenged by the collocation route (``challenge_learned_answer``), and so is one near a half turn
LOCAL_OPTIMUM_MARGIN = 0.015
HALF_TURN_MARGIN_DEG = 10.0
CHALLENGE_MIN_BUDGET = 1.0   # s: the collocation route takes 0.3-1 s; with less left, no challenge

# s: the singular table's switch-time optimisations (all its sequences); then, only when the
# answer's sequence is a KKT point, the exact solver from its KKT costates (its own budget)
SINGULAR_TABLE_BUDGET = 0.3
SINGULAR_KKT_BUDGET = 0.1

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
# (``neighbour_sequences_route``)
NEIGHBOUR_SEQUENCES = 8
NEIGHBOUR_SEQUENCE_BUDGET = 0.6
NEIGHBOUR_KKT_BUDGET = 0.1

# s: the singular table and the nearest sequences start only with this much of the time budget
# left: each optimises at least its first sequence (about 9 ms), and the default route after them
# needs far more. With less, ``solve`` reports the budget spent by the learned stage (a 0.05 s
# budget had ended 8-10 ms late where the learned candidates used it all, an outside replay, session 42)
TABLE_MIN_LEFT = 0.01
# s: under a budget that the learned candidates would otherwise use to the end, what they leave
# for the singular table where its neighbours say it answers (``_table_may_answer``)
TABLE_RESERVE = 0.015


def _singular_query(prob):
    """``(table, share, sequences)`` of the shipped singular table for ``prob``, or ``None`` where
    no table ships or it does not cover the problem; a damaged table raises (``OSError``,
    ``ValueError``, ``IndexError``)."""
    from . import warmstart
    table = warmstart.default_singular_table()
    if table is None or table.covers(prob):
        return None
    share, sequences = table.query(prob)
    return table, share, sequences


def _table_answers(table, share) -> bool:
    """Whether the table optimises sequences at this ``share`` of singular neighbours (its vote,
    or the uncertain tier's lower share)."""
    return share >= min(table.vote, SINGULAR_UNCERTAIN_SHARE)


def _table_may_answer(prob) -> bool:
    """Whether ``singular_table_route`` would optimise sequences for ``prob``; ``False`` where the
    table is missing, damaged or does not cover the problem."""
    try:
        q = _singular_query(prob)
    except (OSError, ValueError, IndexError):
        return False
    return q is not None and _table_answers(q[0], q[1])


def challenge_learned_answer(prob, warm, info, col_opts, options, t0) -> SlewSolution:
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
                 and not prob.has_rate_limit and math.degrees(prob.slew_angle) > 180.0 - HALF_TURN_MARGIN_DEG)
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
        ch = auto_route.solve_auto(prob, None, col_opts, rest)
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
        return replace_answer(ch, warm, info)
    warm.nit += ch.nit
    warm.nfev += ch.nfev
    seen = f"{ch.tf:.9g}" + ("" if ch.exact else f" ({ch.method})") if ch.success else "no answer"
    warm.route = f"{warm.route} (checked, {reason}: the collocation route gave {seen}, not faster)"
    if ch.success and ch.exact:
        warm.candidates_tf = sorted(set(warm.candidates_tf or []) | {round(ch.tf, 9)})
    return warm


def singular_table_route(prob, options, info, col_opts=None, exact_check=True):
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
    t0 = time.perf_counter()
    try:
        q = _singular_query(prob)
    except (OSError, ValueError, IndexError) as e:   # a damaged shipped file: the route without it
        info["singular_table"] = {"error": f"{type(e).__name__}: {e}"[:300]}
        return None, (0, 0)
    if q is None:
        return None, (0, 0)
    table, share, sequences = q
    rec = info["singular_table"] = {"share": share, "vote": table.vote, "used": False}
    if not _table_answers(table, share):
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
    ex = multistart.exact_from_kkt(prob, bang, kkt_guess, options,
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
    eigenaxis slew (``eigenaxis_answer.eigenaxis_unless_faster``: the grid time, or the slew itself when near it);
    if so its ``baseline_tf`` and ``eigenaxis_baseline`` check are set."""
    baseline, eig = eigenaxis_answer.eigenaxis_unless_faster(prob, answer.tf)
    if eig is not None:
        if not (eig.success and answer.tf < eig.tf):
            return False
        baseline = eig.tf
    answer.baseline_tf = baseline
    answer.verification["eigenaxis_baseline"] = make_check(answer.tf / baseline - 1.0, 0.0, True)
    return True


def neighbour_sequences_route(prob, options, info) -> Tuple[Optional[SlewSolution], Tuple[int, int]]:
    """``(answer or None, (nit, nfev) spent)``: ``auto`` after the default model's candidates
    failed and the singular table voted bang-bang (``table_votes_bang_bang``). The switching
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
        left = budget + NEIGHBOUR_KKT_BUDGET - (time.perf_counter() - t0)
        ex = multistart.exact_from_kkt(prob, bang, kkt_guess, options, min(NEIGHBOUR_KKT_BUDGET, left), prefix)
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


def faster_verified(route_answer, bang) -> SlewSolution:
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


def table_votes_bang_bang(info) -> bool:
    """Whether ``singular_table_route`` ran and found fewer than ``SINGULAR_UNCERTAIN_SHARE`` of
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
        col = solve_collocation(prob, **dict({"time_budget": stage_budget.left(budget, 0.2)}, **col_opts))
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
        ref, accepted = auto_route.refine_collocation(prob, col, options, 2, min(auto_route.REFINE_CAP_AFTER_WARM, left))
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


def split_continuation(g: Guess):
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


def try_warm_start(prob, method, warm_start, options, split=False, table_reserve=False):
    """Try the model's guess alone; returns ``(solution or None, info, later)``: ``later`` is
    ``None`` unless ``split``, then the guess's continuation candidates, not tried here
    (``split_continuation``). ``table_reserve``: the singular table may run after it (``auto``
    with the table on): under a short budget the candidates leave it ``TABLE_RESERVE``."""
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
        g, later = split_continuation(g)
    t_guess = time.perf_counter() - t0
    t_inf = t_guess if t_inf is None else t_inf
    # a model may load the solver's compiled code first (once per process), so that its
    # candidates' time caps measure solving, not loading; not counted in the solve's time
    t_warm = model.warm_up(cone_routes.warm_up_solve) if prob.cones and hasattr(model, "warm_up") else 0.0
    t0 += t_warm
    ind_method = "multiple-shooting" if method == "multiple-shooting" else "indirect"
    total = float(options.get("time_budget", 20.0))
    budget = min(float(options.get("warm_budget", cone_routes.CONE_WARM_BUDGET if prob.cones else WARM_BUDGET)), total)
    opts = {k: v for k, v in options.items() if k not in ("warm_budget", "_cone_search_more")}
    skipped = []
    if prob.cones:
        sol = cone_routes.solve_learned_cones(prob, g, opts, budget, errors=skipped,
                                              rank=bool(getattr(model, "RANKS_CANDIDATES", False)),
                                              more=float(options.get("_cone_search_more", 1.0)))
    else:
        if (table_reserve and isinstance(warm_start, str) and warm_start == "default"
                and total - budget < TABLE_RESERVE and _table_may_answer(prob)):
            # a short budget that the candidates could use up on a problem the singular table
            # answers (their Newton cannot converge on a singular one): the table's time is kept
            budget = min(budget, max(total - TABLE_RESERVE, 0.25 * total))
        sol = multistart.guess_alone(prob, g, opts, budget, method=ind_method)
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


def replace_answer(new, old, info) -> SlewSolution:
    """``new``, a challenger's faster answer, replaces ``old`` (the two challengers of ``auto``:
    ``challenge_learned_answer``, ``cone_routes.cone_challenger``): the work of both is counted, the
    final times both saw are in ``candidates_tf``, and the warm start's record goes with it."""
    new.nit += old.nit
    new.nfev += old.nfev
    seen = set(new.candidates_tf or []) | set(old.candidates_tf or []) | {round(new.tf, 9)}
    if old.success:
        seen.add(round(old.tf, 9))
    new.candidates_tf = sorted(seen)
    new.warm_start = info
    return new
