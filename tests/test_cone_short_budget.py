"""``auto`` with keep-out cones under a time budget shorter than its collocation route takes
(``cone_routes.CONE_LEARNED_FIRST_BELOW``): the shipped pointing-cones warm start first (at most
``CONE_SHORT_LEARNED_SHARE`` of the budget), then the switching sequences of its nearest tabled
solutions (``cone_routes.cone_sequences_route``), then the route in what is left (before, the
route ran out of time and only the fallback answered)."""
import math

import numpy as np
import pytest

import solvers
from slew_env import SlewProblem
from solvers import auto_route, cone_routes, warm_routes
from solvers.solution import STATUS_BUDGET_EXHAUSTED, SlewSolution


def _problem():
    target = np.array([math.cos(math.radians(100)), math.sin(math.radians(100)), 0.0])
    mid = np.array([math.cos(math.radians(50)), math.sin(math.radians(50)), 0.0])
    return SlewProblem([0.8, 0.9, 1.0], [1.0, 1.0, 1.0], sensor_target=target, sensor_axis=[1.0, 0.0, 0.0],
                       cones=[{"axis": mid, "half_angle_deg": 15.0}])


@pytest.fixture
def calls(monkeypatch):
    """Stubs for the learned stage and the route, recording the order they are called in."""
    seen = []

    def warm(prob, method, warm_start, options, split=False):
        seen.append(("warm", warm_start, options.get("time_budget"), options.get("warm_budget")))
        ok = SlewSolution(True, 0, "stub learned answer", 3, 9, 0.0, method="indirect", problem=prob,
                          route="learned stub", tf=2.5)
        failed = SlewSolution(False, 1, "stub learned failure", 4, 40, 0.0, method="indirect", problem=prob,
                              route="learned stub")
        return (ok if seen[-1][1] == "pointing-cones" and calls_ok["warm"] else failed), \
            {"model": "stub", "covered": True, "succeeded": calls_ok["warm"]}, None

    def sequences(prob, options, info, **kw):
        seen.append(("sequences", options.get("time_budget")))
        info["neighbour_sequences"] = {"used": calls_ok["sequences"]}
        if not calls_ok["sequences"]:
            return None, (5, 50)
        return SlewSolution(True, 0, "stub sequences answer", 7, 70, 0.0, method="switch-time", problem=prob,
                            route="sequences stub", tf=2.6), (0, 0)

    def route(prob, guess, col_opts, options, **kw):
        seen.append(("route", options.get("time_budget")))
        return SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 0, 0, 0.0,
                            method="collocation", problem=prob, route="route stub")

    calls_ok = {"warm": True, "sequences": False}
    monkeypatch.setattr(warm_routes, "try_warm_start", warm)
    monkeypatch.setattr(cone_routes, "cone_sequences_route", sequences)
    monkeypatch.setattr(auto_route, "solve_auto", route)
    monkeypatch.setattr(cone_routes, "cone_challenger", lambda prob, sol, *a, **k: sol)
    return seen, calls_ok


def test_a_short_budget_tries_the_learned_cone_guess_first(calls):
    seen, _ = calls
    sol = solvers.solve(_problem(), time_budget=0.2)
    assert sol.success and sol.message == "stub learned answer"
    # the learned candidates get half of the budget; the route never ran
    assert seen == [("warm", "pointing-cones", 0.2, 0.1)]
    assert "under the collocation route's 0.4 s" in sol.route


def test_where_the_learned_guess_fails_the_sequences_then_the_route_get_what_is_left(calls):
    seen, ok = calls
    ok["warm"] = False
    sol = solvers.solve(_problem(), time_budget=0.3, fallback="eigenaxis")
    assert [c[0] for c in seen] == ["warm", "sequences", "route"]
    # the fallback kept 2 × 25 ms (a one-waypoint slew round the cone); the learned candidates half
    # of the rest, the sequences what is left after them, the route what is left after those
    assert seen[0][2] == pytest.approx(0.25, rel=1e-9) and seen[0][3] == pytest.approx(0.125, rel=1e-9)
    assert 0.0 < seen[1][1] < 0.25 and seen[2][1] <= seen[1][1]
    assert sol.success and sol.method == "eigenaxis" and "waypoint" in sol.route
    assert sol.warm_start["model"] == "stub" and not sol.warm_start["succeeded"]
    assert sol.warm_start["neighbour_sequences"] == {"used": False}
    # in the order they ran: the learned candidates, the sequences, the route
    assert sol.route.index("learned guess failed (stub learned failure)") < sol.route.index(
        "the tabled solutions' sequences gave nothing") < sol.route.index("route stub")
    assert (sol.nit, sol.nfev) >= (4 + 5, 40 + 50)


def test_a_verified_sequences_answer_ends_the_solve(calls):
    seen, ok = calls
    ok.update(warm=False, sequences=True)
    sol = solvers.solve(_problem(), time_budget=0.3, fallback="eigenaxis")
    assert [c[0] for c in seen] == ["warm", "sequences"]        # no route
    assert sol.success and sol.method == "switch-time" and sol.message == "stub sequences answer"
    assert sol.route.startswith("time budget 0.25 s, under the collocation route's 0.4 s: learned guess failed "
                                "(stub learned failure) → sequences stub")
    assert (sol.nit, sol.nfev) == (7 + 4, 70 + 40)      # the learned candidates' work is counted
    assert sol.warm_start["neighbour_sequences"] == {"used": True}


def test_a_users_warm_budget_holds_under_a_short_budget(calls):
    seen, ok = calls
    solvers.solve(_problem(), time_budget=0.3, warm_budget=0.05)
    assert seen[0][3] == 0.05


def test_a_budget_the_route_fits_in_keeps_the_route_first(calls):
    seen, _ = calls
    solvers.solve(_problem(), time_budget=cone_routes.CONE_LEARNED_FIRST_BELOW)
    assert seen[0][0] == "route"
    seen.clear()
    solvers.solve(_problem())                  # no budget: the default route, as before
    assert seen[0][0] == "route"


def test_a_budget_too_short_for_a_sequence_goes_to_the_learned_candidates_whole(calls):
    """Half of a 0.1 s budget (less the fallback's 25 ms a leg) would leave the sequences less than
    ``CONE_SEQUENCE_MIN_SHARE_S``, less than one optimisation takes: the learned candidates may use
    it all, as before the sequences existed (the sequences get what they leave: here the stub's
    failure at once leaves nearly all of it)."""
    seen, ok = calls
    ok["warm"] = False
    solvers.solve(_problem(), time_budget=0.1, fallback="eigenaxis")
    assert seen[0][0] == "warm" and seen[0][3] == pytest.approx(0.05, rel=1e-9) == seen[0][2]
    assert seen[1][0] == "sequences" and seen[1][1] <= 0.05
    assert cone_routes.short_learned_budget(0.25) == pytest.approx(0.125)
    assert cone_routes.short_learned_budget(0.1) == 0.1


def test_the_learned_candidates_go_on_after_the_first_answer_and_keep_the_fastest():
    """Held-out problem 149: the first candidate that converges gives 1.5622 s; the later ones
    reach faster local extremals. With ``more`` the search goes on after the first answer and
    keeps the fastest (every candidate here: not timed), its work and the others' counted."""
    from solvers import cone_routes
    from solvers.warmstart import default_cone_model
    from training.generate import GenerationSpec, problem_for
    from slew_env import SlewProblem
    p = SlewProblem.from_dict(problem_for(GenerationSpec("pointing-cones", seed=20261122), 149))
    model = default_cone_model()
    first = cone_routes.solve_learned_cones(p, model.guess(p), {}, 20.0, cap=5.0, rank=True)
    best = cone_routes.solve_learned_cones(p, model.guess(p), {}, 20.0, cap=5.0, rank=True, more=1e9)
    assert first.success and best.success and best.exact
    assert best.tf < first.tf * (1.0 - 0.05)
    assert "more candidate(s) tried after the first verified answer, the fastest kept" in best.route
    assert best.n_candidates > first.n_candidates and best.nit > first.nit
    assert "tried after the first" not in first.route


def test_windings_tell_the_side_a_path_passes_a_cone():
    """Two sensor paths from +x to +y past a cone about their midpoint, one over it (+z) and one
    under it (-z): the angles they turn about the cone's axis differ by 2π; a path the other way
    round the same side turns by the same angle."""
    from solvers.cone_routes import cone_windings
    from slew_env import Cone, SlewProblem
    p = SlewProblem([1, 1, 1], sensor_target=[0, 1, 0], cones=[Cone([1, 1, 0], half_angle_deg=10)])
    t = np.linspace(0.0, 0.5 * np.pi, 200)
    over = np.stack([np.cos(t), np.sin(t), 0.5 * np.sin(2 * t)], 1)
    under = over * np.array([1.0, 1.0, -1.0])
    over /= np.linalg.norm(over, axis=1)[:, None]
    under /= np.linalg.norm(under, axis=1)[:, None]
    w_over, w_under = cone_windings(p, over)[0], cone_windings(p, under)[0]
    assert abs(abs(w_over - w_under) - 2 * np.pi) < 0.05
    assert abs(abs(w_over) - np.pi) < 0.05 and abs(abs(w_under) - np.pi) < 0.05


def test_after_the_first_answer_candidates_on_other_sides_go_first():
    """Held-out problem 109: after the first verified answer, the candidates whose switch times,
    flown alone, pass a cone on another side are tried first (8 problems in 300 got a faster
    answer within the same time, none a slower one: runs/s41/sides_ab.py). Checked here against
    windings of a finer replay, computed apart."""
    from slew_env.core.cones import perpendicular_basis
    from solvers import cone_routes
    from solvers.clearance import sensor_directions
    from solvers.verify import replay_path
    from solvers.warmstart import default_cone_model
    from training.generate import GenerationSpec, problem_for
    from slew_env import SlewProblem
    p = SlewProblem.from_dict(problem_for(GenerationSpec("pointing-cones", seed=20261122), 109))
    cands = list(default_cone_model().guess(p).iter_all())
    first = cone_routes.solve_learned_cones(p, default_cone_model().guess(p), {}, 20.0, cap=5.0, rank=True)
    assert first.success

    def windings(d):
        out = []
        for c in p.cones:
            e1, e2 = perpendicular_basis(np.asarray(c.axis, float))
            phi = np.unwrap(np.arctan2(d @ e2, d @ e1))
            out.append(phi[-1] - phi[0])
        return np.array(out)
    ref = windings(sensor_directions(np.asarray(first.q), p.sensor_axis))
    ordered = cone_routes.other_sides_first(p, first, cands)
    assert sorted(map(id, ordered)) == sorted(map(id, cands))
    other = []
    for c in ordered:
        _, x = replay_path(p.inertia, p.torque_max, p.q0, p.omega0, c.switch_times, c.u_first, c.tf, 4000)
        other.append(bool(np.any(np.abs(windings(sensor_directions(x[:, 0:4], p.sensor_axis)) - ref) > np.pi)))
    k = other.index(False)
    assert 0 < k < len(other) and not any(other[k:])      # other sides first, then the same side


def test_only_the_short_budget_branch_searches_on_and_reorders(monkeypatch):
    """``solve(p, time_budget < 0.4 s)`` asks the learned stage to search on (``more`` =
    ``CONE_SHORT_SEARCH_MORE``), and the search reorders the remaining candidates by side; the
    opt-in first guess (``warm_start="pointing-cones"``) stops at its first answer. With the
    switch off, no reordering; a first answer without a dense path keeps the order."""
    from solvers import cone_routes, solve
    from training.generate import GenerationSpec, problem_for
    from slew_env import SlewProblem
    p = SlewProblem.from_dict(problem_for(GenerationSpec("pointing-cones", seed=20261122), 109))
    seen, reordered = [], []
    real, real_osf = cone_routes.solve_learned_cones, cone_routes.other_sides_first

    def spy(*a, **k):
        seen.append(k.get("more", 1.0))
        return real(*a, **k)

    def spy_osf(*a, **k):
        reordered.append(True)
        return real_osf(*a, **k)
    monkeypatch.setattr(cone_routes, "solve_learned_cones", spy)
    monkeypatch.setattr(cone_routes, "other_sides_first", spy_osf)
    solve(p, time_budget=0.3)
    assert seen[0] == cone_routes.CONE_SHORT_SEARCH_MORE > 1.0 and reordered
    seen.clear(), reordered.clear()
    solve(p, warm_start="pointing-cones", time_budget=2.0)
    assert seen and seen[0] == 1.0 and not reordered
    seen.clear()
    monkeypatch.setattr(cone_routes, "CONE_OTHER_SIDES_FIRST", False)
    solve(p, time_budget=0.3)
    assert seen[0] > 1.0 and not reordered

    class NoPath:
        q = None
    cands = [1, 2, 3]
    assert real_osf(p, NoPath(), cands) == cands and real_osf(p, NoPath(), cands) is cands


def test_the_search_keeps_every_verified_time_and_skips_a_candidate_that_raises():
    """After the first verified answer the search keeps going: every verified final time is in
    ``candidates_tf``, and a later candidate that raises (a touch on a cone the problem lacks)
    is skipped and recorded, not fatal (a review lost the first answer to it)."""
    from solvers import cone_routes
    from solvers.guesses import Guess
    from solvers.warmstart import default_cone_model
    from training.generate import GenerationSpec, problem_for
    from slew_env import SlewProblem
    p = SlewProblem.from_dict(problem_for(GenerationSpec("pointing-cones", seed=20261122), 149))
    best = cone_routes.solve_learned_cones(p, default_cone_model().guess(p), {}, 20.0, cap=5.0, rank=True, more=1e9)
    assert round(best.tf, 9) in best.candidates_tf and round(1.5622205922845647, 9) in best.candidates_tf
    assert min(best.candidates_tf) == round(best.tf, 9)
    # a guess that converges at once (an extremal's own costates and touches), then a bad one
    tm = best.verification["touch_multipliers"]
    touches = list(zip(tm["cones"], tm["times"], tm["multipliers"]))
    g = Guess(best.costate0, best.tf, best.switch_times, best.u_first, source="its own answer", touches=touches)
    g.candidates = [Guess(best.costate0, best.tf, best.switch_times, best.u_first, source="bad",
                          touches=[(len(p.cones) + 4, 0.5 * best.tf, 1.0)])]
    # (alone, before any answer, the bad candidate raises, as it always did)
    with pytest.raises(ValueError, match="cone index"):
        cone_routes.solve_learned_cones(p, g.candidates[0], {}, 20.0, cap=5.0, more=1e9)
    errors = []
    out = cone_routes.solve_learned_cones(p, g, {}, 20.0, cap=5.0, errors=errors, more=1e9)
    assert out.success and out.tf == pytest.approx(best.tf, rel=1e-9) and out.n_candidates == 2
    assert len(errors) == 1 and "ValueError" in errors[0] and "cone index" in errors[0]
