"""``method="auto"``: collocation first, then the exact indirect refinement from its costates and
switching structure, else the bang-bang switch-time answer, else collocation's own answer
(``solvers.api`` documents the whole route)."""

from __future__ import annotations

import math
import time

import numpy as np

from .guesses import Guess
from .solution import STATUS_BUDGET_EXHAUSTED, STATUS_MESSAGES, SlewSolution
from .switch_time_opt import switch_time_applies
from . import cone_routes, multistart, stage_budget, warm_routes

REFINE_CAP_AFTER_WARM = 0.6   # s: auto's exact refinement after collocation when the learned guess failed

# s: auto's bang-bang switch-time optimisation when no exact extremal refines a collocation
# answer (three rounds of 15-250 ms each on held-out singular problems)
BANG_BANG_BUDGET = 1.0

# s: auto's indirect multi-start before collocation for a p-norm bound with p ≤ 2
# (``pnorm_indirect_first``; it takes 0.1-0.4 s there, the collocation route 0.4-16 s)
PNORM_INDIRECT_BUDGET = 2.0
PNORM_INDIRECT_MIN_INERTIA_RATIO = 0.3   # the measured range (``pnorm_indirect_first``)

# with keep-out cones, collocation leaves this share of auto's budget (at most
# ``CONE_FREE_RESERVE_MAX`` s, none under ``CONE_FREE_RESERVE_FROM`` s) to the problem without its
# cones (``cone_routes.clear_without_cones``), which runs only where collocation fails: a cone
# that grazes the path (1e-7 rad clear of it) or many cones near it can make collocation's mesh
# cut through one at every N until the budget is gone, where the cone-free answer clears them
# (the session-43 adversarial repros F2 and F2b: status 2 after 20 s before, runs/s44/f2.py)
CONE_FREE_RESERVE_SHARE = 0.25
CONE_FREE_RESERVE_MAX = 5.0
CONE_FREE_RESERVE_FROM = 8.0


# s: at most this for the problem without its cones where collocation's default mesh clips a cone
# between its points, before it builds finer meshes (``_solve_auto_route``'s ``clipped``): on 80
# held-out pointing-cones problems no default mesh did (runs/s44/mesh_refine_freq.py), and on the
# grazing-cone repros the finer meshes had taken the whole budget
CONE_FREE_FIRST_BUDGET = 3.0


def cone_free_reserve(budget) -> float:
    """s of ``budget`` that collocation with cones leaves to the problem without them."""
    budget = float(budget)
    return 0.0 if budget < CONE_FREE_RESERVE_FROM else min(CONE_FREE_RESERVE_MAX, CONE_FREE_RESERVE_SHARE * budget)


def solve_auto(prob, guess, col_opts, options, **kw) -> SlewSolution:
    """``_solve_auto_route``, and before it, for a p-norm bound with p ≤ 2 and no ``guess``, the
    indirect multi-start (``pnorm_indirect_first``): its verified answer is the answer; if it
    fails, the route runs with the rest of the time budget, and its answer's ``route`` says so."""
    if guess is not None or not pnorm_indirect_first(prob):
        return _solve_auto_route(prob, guess, col_opts, options, **kw)
    t0 = time.perf_counter()
    budget = float(options.get("time_budget", 20.0))
    ind = multistart.solve_indirect(prob, "indirect", None, **dict(options, time_budget=min(PNORM_INDIRECT_BUDGET, budget)))
    if ind.success:
        ind.route = f"auto: indirect first (p-norm bound, p ≤ 2) → {ind.route}"
        ind.wall_time = time.perf_counter() - t0
        return ind
    if budget <= time.perf_counter() - t0:
        # the indirect stage spent the budget: no route (building an NLP is not interruptible)
        sol = stage_budget.budget_spent(prob, "The indirect multi-start (p-norm bound, p ≤ 2)", 0, 0, t0,
                                        "no time left for the collocation route")
    else:
        left = stage_budget.left(budget, time.perf_counter() - t0)
        sol = _solve_auto_route(prob, guess, col_opts, dict(options, time_budget=left), **kw)
    sol.route = f"auto: indirect first (p-norm bound, p ≤ 2) failed ({ind.message[:120]}) → {sol.route}"
    sol.nit += ind.nit
    sol.nfev += ind.nfev
    sol.wall_time = time.perf_counter() - t0
    return sol


def _solve_auto_route(prob, guess, col_opts, options, refine_cap=2.0, later=None, warm_info=None,
                      warm_budget=None) -> SlewSolution:
    """The fastest route to a verified answer.

    1. a given ``guess`` alone, by the indirect route (a warm start) (without one, for a p-norm
       bound with p ≤ 2, ``solve_auto`` has tried the indirect multi-start before this);
    2. direct collocation; where its control shows a singular arc (full-attitude, per-axis,
       ``switch_time_opt.singular_arc_evidence``), straight to 3b;
    3. otherwise ``later`` (the learned guess's continuation candidates, held back by
       ``solve``, within ``warm_budget`` s, by default ``warm_routes.WARM_BUDGET``; ``warm_info`` is
       updated if one wins), then exact indirect refinement from
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
    (``switch_time_cones``), or, where none is verified, the collocation answer itself. Where
    collocation's default mesh enters a cone between its points, or collocation fails, the answer
    of the problem without its cones is returned if its path clears them (certified;
    ``CONE_FREE_FIRST_BUDGET``, ``cone_free_reserve``).
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
        tried_guess = multistart.solve_indirect(prob, "indirect", guess, **opts)
        if tried_guess.success:
            tried_guess.route = f"auto: given guess → {tried_guess.route}"
            tried_guess.wall_time = spent()
            return tried_guess
        if budget <= spent():
            return stage_budget.budget_spent(
                prob, "The given guess", tried_guess.nit, tried_guess.nfev, t0,
                f"auto: given guess failed ({tried_guess.message[:120]}) → no time left for collocation")
    from .collocation import solve_collocation
    # with cones, collocation's N / 2 solve for tf_tol waits: the refinements below mostly
    # replace its answer by an exact extremal (their use of tf_tol has a 1e-3 relative floor)
    reserve = 0.0 if indirect_ok else cone_free_reserve(budget)
    col_budget = stage_budget.left(budget - reserve, spent())
    free_first = []         # the cone-free attempt's answer before the finer meshes (None: none)

    def clipped(first):
        # the default mesh's answer enters a cone between its points: a cone that grazes the
        # cone-free path (or many near it) can defeat every finer mesh, where the path of the
        # problem without its cones may clear them all; tried before the finer meshes, which
        # then get the reserve kept for it (``_refinement_extra``)
        if first.verification.get("cone_clearance", {}).get("passed", True):
            return None
        free = cone_routes.clear_without_cones(
            prob, first, options, col_opts, min(CONE_FREE_FIRST_BUDGET, budget - spent()),
            why=(f"collocation's default mesh enters a cone between its points "
                 f"(cone_clearance {first.verification['cone_clearance']['value']:.3g} rad), "
                 "tried before finer meshes"))
        if free is not None:        # (the default mesh's work is the answer's too)
            free.nit += first.nit
            free.nfev += first.nfev
        free_first.append(free)
        return free

    col = solve_collocation(prob, **dict({"time_budget": col_budget, "defer_tf_tol": not indirect_ok}, **col_opts),
                            _before_refinement=None if indirect_ok else clipped, _refinement_extra=reserve)
    if free_first and free_first[0] is not None and col is free_first[0]:
        col.wall_time = spent()
        return col
    if free_first:
        col.route += ("; the problem without cones was tried before the finer meshes and gave no answer clear "
                      "of the cones")
    if not indirect_ok:
        ref = cone_routes.refine_inactive_cones(prob, col, options, budget - spent()) if col.success else None
        if ref is not None:
            ref.wall_time = spent()
            return ref
        touch = cone_routes.refine_touching_cones(prob, col, options, stage_budget.left(budget, spent())) if col.success else None
        if touch is not None and touch.success:
            touch.route = f"auto: collocation ({col.wall_time:.3g} s) → {touch.route}"
            touch.wall_time = spent()
            return touch
        if not col.success and not free_first:      # (not again where it ran before the finer meshes)
            free = cone_routes.clear_without_cones(prob, col, options, col_opts, budget - spent())
            if free is not None:
                free.nit += col.nit
                free.nfev += col.nfev
                free.wall_time = spent()
                return free
        cone_routes.settle_tf_tol(col, budget - spent())
        # a path that rides a cone (or a singular arc): a bang-bang slew with collocation's
        # sequence and optimised switch times, the cones imposed, reaches the target exactly
        # and is flown by its switch times; collocation's answer is not
        bang = cone_routes.bang_bang_cones(prob, col, options, budget - spent())
        if bang is not None:
            bang.route = (f"auto: collocation ({col.route}; {col.wall_time:.3g} s; its costates reached no exact "
                          f"extremal) → {bang.route}")
            # where its path touches a cone, the touch-point extremal from the costates fitted on it
            ex, why = cone_routes.exact_from_own_costates(
                prob, bang, options, min(cone_routes.OWN_COSTATES_BUDGET, budget - spent()))
            if ex is not None:
                ex.wall_time = spent()
                return ex
            if why:
                bang.message += f" The touch-point extremal from its own fitted costates: {why[:200]}."
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
            r, ok = refine_collocation(prob, col, options, 2,
                                       min(refine_cap, stage_budget.left(budget, spent())))
            if ok:
                r.route = f"auto: collocation ({col.wall_time:.3g} s{note}) → indirect refinement: {r.route}"
                r.wall_time = spent()
            return r, ok, (r.message if not r.success else
                           f"the refined extremal ({r.tf:.9g}) is slower than the collocation answer")

        ref = None
        if singular is None:
            if later is not None and budget - spent() > 0.05:
                wb = warm_routes.WARM_BUDGET if warm_budget is None else warm_budget
                lg = multistart.guess_alone(prob, later, options, min(wb, budget - spent()))
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
            ex = multistart.exact_from_kkt(prob, bang, kkt_guess, options, min(BANG_BANG_BUDGET, budget - spent()), prefix)
            if ex is not None:
                ex.wall_time = spent()
                return ex
            bang.route = f"auto: collocation ({col.wall_time:.3g} s; {_clipped(why, 250)}) → {bang.route}"
            bang.wall_time = spent()
            return bang
        if prob.qf is None:
            # a pointing target: the switch-time optimisation that leaves the roll free
            bang = cone_routes.bang_bang_cones(prob, col, options, budget - spent())
            if bang is not None:
                bang.route = f"auto: collocation ({col.wall_time:.3g} s; {_clipped(why, 250)}) → {bang.route}"
                bang.wall_time = spent()
                return bang
        if ref is None and budget - spent() > 0.05:
            # a singular arc in sight but no bang-bang answer: the exact refinement after all
            ref, accepted, why_ref = refine("; no switch-time answer")
            if accepted:
                return ref
            why += f"; no switch-time answer; exact refinement then not certified: {why_ref}"
        col.route = f"auto: collocation ({col.route}; {_clipped(why, 500)})"
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
    ind = multistart.solve_indirect(prob, "indirect", guess, **dict(options, time_budget=stage_budget.left(budget, spent())))
    if not ind.success and _worst_excess(col) < _worst_excess(ind):
        # both failed: the record nearer to passing its checks is the more useful one (with a
        # tight rate limit the multi-start, which ignores the limit, returned an answer 71 times
        # over it where collocation had missed its target by 1.4 times its tolerance)
        col.route = (f"auto: collocation failed ({col.route}); the indirect multi-start failed too "
                     f"({ind.message[:200]}): the collocation answer, the nearer to its checks")
        col.nit += ind.nit
        col.nfev += ind.nfev
        col.wall_time = spent()
        return col
    ind.route = f"auto: collocation failed ({col.message[:200]}) → indirect multi-start: {ind.route}"
    ind.wall_time = spent()
    return ind


def _clipped(text, n) -> str:
    """``text`` in at most about ``n`` characters: its start and its end (where a later stage's
    reason is appended) with an ellipsis between, not its first ``n`` (which cut the last reason
    off mid-word)."""
    if len(text) <= n:
        return text
    head = n // 3
    return f"{text[:head]} … {text[len(text) - (n - head - 3):]}"


def _worst_excess(sol) -> float:
    """How far ``sol`` is from passing its checks: 0 where every check passed (an answer that
    failed for another reason, slower than the eigenaxis slew, say), else the largest ``value /
    tol`` of its failed checks; ``inf`` without checks to measure (no candidate verified at all,
    a spent budget, a failed check without a positive tolerance)."""
    checks = sol.verification or {}
    if not checks:
        return math.inf
    worst = 0.0
    for c in checks.values():
        if not c.get("passed", True):
            v, tol = c.get("value"), c.get("tol")
            if not (isinstance(v, (int, float)) and isinstance(tol, (int, float)) and tol > 0 and math.isfinite(v)):
                return math.inf
            worst = max(worst, v / tol)
    return worst


def _pointing_singular_check(prob) -> bool:
    """``auto`` reads collocation's control for a singular arc before the exact refinement of a
    pointing target too (per-axis bound, no cones, no rate limit). Measured on 100 random pointing
    slews (``pointing-cones`` without cones, seed 11; ``runs/s27/pointing_singular.py``): the
    evidence showed on 22 of the 26 without an exact answer (a roll-axis torque interior over
    9-84 % of tf) and on none of the 74 with one, where the futile refinement took 0.5-1.2 s."""
    return (prob.qf is None and not prob.cones and math.isinf(prob.torque_norm) and not prob.has_rate_limit)


def pnorm_indirect_first(prob) -> bool:
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
    return (math.isfinite(p) and p <= 2.0 and not prob.cones and not prob.has_rate_limit and not prob.is_pointing
            and prob.is_rest_to_rest and float(J.min() / J.max()) >= PNORM_INDIRECT_MIN_INERTIA_RATIO)


# how many verified extremals the refinement of a collocation answer waits for (its candidates:
# collocation's guess, then the eigenaxis guess): 1 for a full-attitude target stops at the first
# (collocation's own, as a rule). Each problem both ways, alternating (runs/s43/refine_ab.py,
# auto without a model): on bench_solver's seeds 1-3 (180 problems) the same answers, median time
# 256 -> 186, 305 -> 200 and 276 -> 212 ms; on 40 pointing slews one answer 0.17 % slower (the
# eigenaxis candidate's extremal was faster), so a pointing target still tries both
REFINE_ENOUGH = {"full": 1, "pointing": 2}


def refine_collocation(target, col, options, max_candidates, budget):
    """The exact extremal of ``target`` from a collocation answer's costates and switching
    structure: ``(solution, accepted)``. Accepted only if verified and not slower than the
    collocation answer (beyond its tolerance): the refined extremal must be the one
    collocation found, or a better one, not another local optimum."""
    per_axis = math.isinf(target.torque_norm)
    g = Guess(col.costate0, col.tf, col.switch_times if per_axis else None, col.u_first if per_axis else None,
              source="collocation")
    enough = REFINE_ENOUGH["pointing" if target.sensor_target is not None else "full"]
    opts = dict(options, max_candidates=max_candidates, min_candidates=1, enough=enough, time_budget=budget,
                model_guess=True)
    ref = multistart.solve_indirect(target, "indirect", g, **opts)
    accepted = bool(ref.success and ref.tf <= col.tf * (1.0 + 2.0 * cone_routes.rel_tol(col)))
    if ref.success and not accepted and getattr(col, "_tf_tol_pending", None) is not None:
        # slower than the floor allows: the deferred tf_tol may allow it
        cone_routes.settle_tf_tol(col, budget)
        accepted = bool(ref.tf <= col.tf * (1.0 + 2.0 * cone_routes.rel_tol(col)))
    if accepted:
        ref.nit += col.nit
        ref.nfev += col.nfev
    return ref, accepted
