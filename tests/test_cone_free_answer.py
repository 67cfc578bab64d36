"""``auto`` with keep-out cones that the cone-free optimum already clears, where collocation with
the cones fails (its mesh cuts through a cone that grazes the path): the answer of the problem
without its cones, its clearance certified on an RK4 replay of its switch times
(``cone_routes.clear_without_cones``, ``clearance.answer_clearance``), in a share of the budget
that collocation leaves for it (``auto_route.cone_free_reserve``). The session-43 adversarial
repro F2: a 0.3° cone whose boundary passes 1e-7 rad outside the cone-free path had ended in
status 2 after 20 s."""
import time

import numpy as np
import pytest

import solvers
from slew_env import SlewProblem
from solvers import auto_route, clearance, cone_routes
from solvers.solution import SlewSolution

# the repro (runs/s43/adversarial/repro_F2_tangent_cone_fails.json): its cone-free answer is a
# bang-bang switch-time slew (a singular arc), tf 1.5628476
INERTIA = [1.0, 0.7183438267246143, 0.5428235650429168]
TARGET = [0.16021416297716448, -0.818128926665578, 0.5522648652001644]
CONE_AXIS = [0.9675520543071086, -0.20579588761689818, 0.14659834530466953]
HALF_ANGLE = 0.005235887755982971


def _problem(half_angle=HALF_ANGLE, axis=CONE_AXIS):
    return SlewProblem(INERTIA, [1.0, 1.0, 1.0], sensor_target=TARGET, sensor_axis=[1.0, 0.0, 0.0],
                       cones=[{"axis": axis, "half_angle": half_angle}])


@pytest.fixture(scope="module")
def free_answer():
    return solvers.solve(_problem().replace(cones=[]))


def test_switch_time_answer_clearance_comes_from_its_replay(free_answer):
    prob = _problem()
    assert free_answer.success and free_answer.method == "switch-time" and not free_answer.exact
    assert free_answer.tf == pytest.approx(1.5628476, rel=1e-6)
    # its ~100 dense samples bound the clearance between them far too low ...
    dense = clearance.certified_min_margin(prob, free_answer.t, free_answer.q, free_answer.omega)[1]
    assert dense < -1e-3
    # ... where the replay of its switch times certifies the path clear within the tolerance
    replay = clearance.certified_replay(prob, free_answer.switch_times, free_answer.u_first, free_answer.tf)[2]
    assert clearance.answer_clearance(prob, free_answer) == replay
    assert clearance.CLEARANCE_TOL <= replay < 1e-6


def _failed_collocation(prob):
    return SlewSolution(False, 2, "stub: collocation's mesh cut through a cone", 10, 20, 0.0,
                        method="collocation", problem=prob, route="stub collocation")


def test_clear_without_cones_answers_with_the_cone_free_slew():
    prob = _problem()
    ans = cone_routes.clear_without_cones(prob, _failed_collocation(prob), {}, {}, 5.0)
    assert ans is not None and ans.success and ans.problem is prob
    assert ans.tf == pytest.approx(1.5628476, rel=1e-6)
    check = ans.verification["cone_clearance"]
    assert check["passed"] and check["value"] >= clearance.CLEARANCE_TOL
    assert "the problem without cones, whose path clears them" in ans.route


def test_clear_without_cones_repairs_a_path_that_enters_a_cone():
    prob = _problem(half_angle=HALF_ANGLE + 1e-3)     # the same cone 1e-3 rad wider: the path enters it
    col = _failed_collocation(prob)
    # not returned as it is: its switching sequence is optimised with the cone imposed
    ans = cone_routes.clear_without_cones(prob, col, {}, {}, 5.0)
    assert ans is not None and ans.success and ans.method == "switch-time"
    assert "whose path enters a cone" in ans.route
    assert clearance.certified_replay(prob, ans.switch_times, ans.u_first, ans.tf)[2] >= clearance.CLEARANCE_TOL
    assert ans.tf > 1.5628476      # a detour round the wider cone costs time
    # the indirect route's call (exact answers only) gets nothing, and no time gives nothing
    assert cone_routes.clear_without_cones(prob, col, {}, {}, 5.0, exact_only=True) is None
    assert cone_routes.clear_without_cones(_problem(), col, {}, {}, 0.0) is None


def test_cone_free_reserve():
    assert auto_route.cone_free_reserve(20.0) == pytest.approx(5.0)
    assert auto_route.cone_free_reserve(10.0) == pytest.approx(2.5)
    assert auto_route.cone_free_reserve(100.0) == pytest.approx(auto_route.CONE_FREE_RESERVE_MAX)
    # short budgets keep all of it for collocation
    assert auto_route.cone_free_reserve(auto_route.CONE_FREE_RESERVE_FROM - 0.1) == 0.0
    assert auto_route.cone_free_reserve(0.3) == 0.0


def test_auto_answers_the_grazing_cone_repro():
    # collocation's default mesh enters the cone between its points; the finer meshes had taken
    # the whole 20 s budget and failed. The cone-free answer is tried before them
    prob = _problem()
    s = solvers.solve(prob)
    assert s.success and s.status == 0, s.message
    assert s.tf == pytest.approx(1.5628476, rel=1e-6)
    assert "default mesh enters a cone between its points" in s.route and "tried before finer meshes" in s.route
    assert "the problem without cones, whose path clears them" in s.route
    assert "mesh refined" not in s.route
    assert s.verification["cone_clearance"]["value"] >= clearance.CLEARANCE_TOL
    assert np.all(np.isfinite(s.q))


def test_collocation_calls_the_hook_before_finer_meshes():
    from solvers.collocation import solve_collocation
    prob = _problem()
    seen = []
    sentinel = SlewSolution(True, 0, "the hook's answer", 0, 0, 0.0, method="switch-time", problem=prob)

    def hook(first):
        seen.append(first)
        return sentinel
    assert solve_collocation(prob, _before_refinement=hook) is sentinel
    first, = seen
    assert not first.success and not first.verification["cone_clearance"]["passed"]
    # a hook with nothing to give: collocation goes on with its own answer (finer meshes, where
    # the budget leaves 2 s for one: not timed here)
    seen.clear()
    own = solve_collocation(prob, time_budget=3.0, _before_refinement=lambda f: seen.append(f))
    assert len(seen) == 1 and own is not sentinel and own.method == "collocation"


def test_the_hook_is_not_a_solve_option():
    from solvers import collocation
    assert "_before_refinement" not in collocation.SOLVE_OPTIONS
    with pytest.raises(ValueError, match="_before_refinement"):
        solvers.solve(_problem(), method="collocation", collocation={"_before_refinement": print})


# a session-44 adversarial repro: a 0.26 deg cone 1e-7 rad outside the path of this switch-time slew
# (singular, 23 switches), which the replay bounded at -1.3e-6 with 32,000 steps and refused
G8_PROBLEM = dict(inertia=[1.0, 1.0, 1.0], torque_max=[0.874, 0.656, 0.725],
                  qf=[-0.5630759640061589, 0.035698626545042446, -0.571355333850986, -0.5960068366230044],
                  sensor_axis=[1.0, 0.0, 0.0],
                  cones=[{"axis": [0.556913549262932, 0.562070041118623, -0.6114937183032002],
                          "half_angle": 0.004615850014835142}])
G8_ANSWER = dict(tf=2.8192550800529874, u_first=[-1.0, 1.0, 1.0], switch_times=[
    [0.32749941175710495, 0.7140534271035787, 0.7245140959284571, 0.7425325324031996, 0.8709457506776581,
     1.007242128671905, 1.1580772091275182, 1.312380219174751, 1.4699186751176798, 1.6258929620924838,
     1.765200508575437, 1.8621999533086457, 1.9179102221239934, 1.9869675917865797, 2.0921337668798206,
     2.196640067910889, 2.258526357126936, 2.2982897136160396, 2.3499190782341213, 2.411558205645642,
     2.6327392661914826], [1.4096275400264944], [1.4096275400264926]])


def test_certified_replay_refines_to_a_third_level_on_a_grazing_path():
    prob = SlewProblem(**G8_PROBLEM)
    a = G8_ANSWER
    coarse = [clearance.certified_replay(prob, a["switch_times"], a["u_first"], a["tf"], steps=(n,))[2]
              for n in (8000, 32000)]
    assert all(c < clearance.CLEARANCE_TOL for c in coarse)       # both refuse it ...
    assert len(clearance.REPLAY_STEPS) == 3
    t, x, cert = clearance.certified_replay(prob, a["switch_times"], a["u_first"], a["tf"])
    assert cert >= clearance.CLEARANCE_TOL and cert < 1e-7        # ... the third level certifies it
    assert t.size > clearance.REPLAY_STEPS[1] + 1      # (the third level's path)


def test_auto_repairs_a_cone_free_path_that_clips_the_cone():
    # the F2 cone 1.5e-6 rad wider: the cone-free path enters it by about 1.4e-6 (beyond the
    # tolerance); its switching sequence with the cone imposed clears it, as fast to 1e-7
    prob = _problem(half_angle=HALF_ANGLE + 1.6e-6)
    s = solvers.solve(prob)
    assert s.success and s.status == 0, s.message
    assert "whose path enters a cone" in s.route and "its switching sequence with the cones imposed" in s.route
    assert s.tf == pytest.approx(1.5628476, rel=1e-6)
    cert = clearance.certified_replay(prob, s.switch_times, s.u_first, s.tf)[2]
    assert cert >= clearance.CLEARANCE_TOL
    assert s.verification["cone_clearance"]["passed"]


# a session-44 adversarial problem: a 0.57 deg cone 1e-7 rad outside the cone-free optimum's sensor
# path (tf 1.8456930), whose eigenaxis path clears it; auto's route reached a touch-point extremal
# 0.044 % slower (1.8465007)
G84_PROBLEM = dict(inertia=[1.0, 1.0, 0.55], torque_max=[1.0, 1.0, 1.0],
                   sensor_target=[-0.18085006889672653, 0.9652232002595519, -0.18877877598066567],
                   sensor_axis=[1.0, 0.0, 0.0],
                   cones=[{"axis": [0.13033399247689625, 0.9575726886451863, -0.2570361771538428],
                           "half_angle": 0.009999899999999977}])


def test_the_cone_free_answer_challenges_where_the_eigenaxis_path_clears_the_cones():
    prob = SlewProblem(**G84_PROBLEM)
    assert cone_routes.eigenaxis_path_clear(prob)
    s = solvers.solve(prob)
    assert s.success and s.status == 0, s.message
    assert s.tf == pytest.approx(1.8456930, abs=2e-7)
    assert "the eigenaxis path clears the cones: a challenge to the route's indirect answer 1.8465" in s.route
    assert "it replaced the route's indirect answer" in s.route
    assert clearance.answer_clearance(prob, s) >= clearance.CLEARANCE_TOL
    # both final times seen, both answers' work counted
    assert round(1.8465007, 6) in {round(t, 6) for t in s.candidates_tf} and round(s.tf, 9) in s.candidates_tf
    assert s.nit > 0 and s.nfev > 0


def test_no_challenge_of_an_extremal_refined_clear_of_the_cones():
    prob = SlewProblem(**G84_PROBLEM)
    s = SlewSolution(True, 0, "stub", 1, 1, 0.0, method="indirect", problem=prob, tf=9.0, route="stub route",
                     _cone_free=True)
    assert cone_routes.cone_free_challenger(prob, s, {}, {}, time.perf_counter()) is s
    assert s.route == "stub route"


def test_no_cone_free_challenge_where_the_eigenaxis_path_crosses_a_cone():
    from training.generate import GenerationSpec, problem_for
    # held-out pointing-cones problems lie across their eigenaxis paths: no extra solve for them
    probs = [problem_for(GenerationSpec("pointing-cones", seed=20261122), i) for i in range(20)]
    assert not any(cone_routes.eigenaxis_path_clear(p) for p in probs)
    assert not cone_routes.eigenaxis_path_clear(_problem().replace(cones=[]))     # (no cones: no gate)
    # a cone on the great circle's midpoint between the sensor's start and target directions
    mid = np.array([1.0, 0.0, 0.0]) + np.array(TARGET)
    crossing = _problem(half_angle=0.2, axis=(mid / np.linalg.norm(mid)).tolist())
    assert not cone_routes.eigenaxis_path_clear(crossing)
    s = SlewSolution(True, 0, "stub", 1, 1, 0.0, method="indirect", problem=crossing, route="stub route", tf=9.0)
    assert cone_routes.cone_free_challenger(crossing, s, {}, {}, time.perf_counter()) is s
    assert s.route == "stub route"


def test_the_repair_leaves_the_exact_attempt_only_the_time_left(monkeypatch):
    # the sequence's optimisation takes all of the repair's time: the touch-point attempt after it
    # gets what is left (too little to start), not its own 0.1 s
    from solvers import switch_time_opt
    real = switch_time_opt.bang_bang_from_sequences
    budgets = []

    def slow(problem, sequences, time_budget=0.2, **kw):
        out = real(problem, sequences, time_budget=time_budget, **kw)
        time.sleep(max(0.0, time_budget))
        return out
    monkeypatch.setattr(switch_time_opt, "bang_bang_from_sequences", slow)
    real_exact = cone_routes.exact_from_own_costates
    monkeypatch.setattr(cone_routes, "exact_from_own_costates",
                        lambda prob, bang, options, budget=0.1: budgets.append(budget) or real_exact(prob, bang, options, budget))
    prob = _problem(half_angle=HALF_ANGLE + 1.6e-6)
    ans = cone_routes.clear_without_cones(prob, _failed_collocation(prob), {}, {}, 5.0)
    assert ans is not None and ans.success
    assert budgets and budgets[0] < cone_routes.OWN_COSTATES_MIN_LEFT


def test_a_lost_challenge_counts_its_time_and_says_so(monkeypatch):
    prob = SlewProblem(**G84_PROBLEM)

    def nothing(prob, col, options, col_opts, budget_left, **kw):
        time.sleep(0.2)
        col.nit += 7
        return None
    monkeypatch.setattr(cone_routes, "clear_without_cones", nothing)
    s = SlewSolution(True, 0, "stub", 1, 1, 0.01, method="indirect", problem=prob, route="stub route", tf=1.9)
    t0 = time.perf_counter()
    out = cone_routes.cone_free_challenger(prob, s, {}, {}, t0)
    assert out is s and s.wall_time >= 0.2 and s.nit == 8
    assert s.route == "stub route; the problem without cones challenged it (the eigenaxis path clears the cones) and lost"
