"""The eigenaxis slew of a pointing target and of a problem with keep-out cones
(``method="eigenaxis"`` and ``fallback="eigenaxis"``): flown to the reference attitude, verified
only where its path clears every cone, else round the cones through waypoints (a GNC review: a
50 ms budget left pointing slews with nothing to fly)."""
import math
import time

import numpy as np
import pytest

import solvers
from slew_env import SlewProblem
from solvers import multistart
from solvers.api import _eigenaxis_fallback
from solvers.eigenaxis import eigenaxis_time, reference_problem
from solvers.solution import STATUS_BUDGET_EXHAUSTED, SlewSolution

J = [0.6, 0.8, 1.0]
SENSOR = np.array([1.0, 0.0, 0.0])
TARGET = np.array([0.3, 0.8, -0.52])
TARGET = TARGET / np.linalg.norm(TARGET)


def _rotate(axis, angle, v):
    """Rodrigues' formula (the test's own rotation, not the package's quaternions)."""
    return v * math.cos(angle) + np.cross(axis, v) * math.sin(angle) + axis * (axis @ v) * (1 - math.cos(angle))


def _exact_margin(cone_axis, half_angle):
    """Clearance of the sensor's path from the start (q0 = identity: the sensor along +x) to
    TARGET by the smallest rotation, on 200,001 points of the arc: the great circle between them."""
    axis = np.cross(SENSOR, TARGET)
    axis /= np.linalg.norm(axis)
    angle = math.acos(float(SENSOR @ TARGET))
    th = np.linspace(0.0, angle, 200_001)
    path = (np.outer(np.cos(th), SENSOR) + np.outer(np.sin(th), np.cross(axis, SENSOR)))
    return float(np.min(np.arccos(np.clip(path @ cone_axis, -1, 1)))) - half_angle


def _pointing(**kw):
    return SlewProblem(J, sensor_axis=SENSOR, sensor_target=TARGET, **kw)


def test_a_pointing_target_is_reached_at_the_reference_attitude():
    p = _pointing()
    sol = solvers.solve(p, method="eigenaxis")
    assert sol.success and sol.method == "eigenaxis" and not sol.exact
    assert sol.problem.sensor_target is not None            # the answer is to the pointing problem
    # the time of the eigenaxis slew to the reference attitude, and the baseline all pointing answers carry
    assert sol.tf == pytest.approx(eigenaxis_time(reference_problem(p), n_grid=16000), rel=1e-9)
    assert sol.baseline_tf == sol.tf
    assert sol.tf == pytest.approx(solvers.solve(p).baseline_tf, rel=1e-3)
    # the sensor ends on the target (the package's replay), and the samples' last attitude is there too
    assert sol.verification["boundary_attitude_error"]["value"] < 1e-8
    qT = sol.q[-1] / np.linalg.norm(sol.q[-1])
    s_end = _rotate(qT[1:] / np.linalg.norm(qT[1:]), 2 * math.atan2(np.linalg.norm(qT[1:]), qT[0]), SENSOR)
    assert float(np.linalg.norm(s_end - TARGET)) < 1e-7
    assert "reference attitude" in sol.message


def test_a_cone_off_the_path_is_certified_clear():
    axis = np.array([0.0, 0.2, 1.0]) / math.hypot(0.2, 1.0)
    half = math.radians(20.0)
    exact = _exact_margin(axis, half)
    assert exact > 0.3      # (the problem: the arc passes well clear of the cone)
    sol = solvers.solve(_pointing(cones=[{"axis": axis, "half_angle": half}]), method="eigenaxis")
    assert sol.success
    cert = sol.verification["cone_clearance"]["value"]
    # certified: a lower bound of the exact margin, and close to it
    assert exact - 1e-5 <= cert <= exact + 1e-9
    assert sol.tf == pytest.approx(solvers.solve(_pointing(), method="eigenaxis").tf, rel=1e-12)
    assert math.isfinite(sol.baseline_tf)


def test_a_path_into_a_cone_fails_its_clearance_and_says_so():
    from solvers.eigenaxis_answer import eigenaxis_answer
    mid = SENSOR + TARGET
    axis = mid / np.linalg.norm(mid)          # the cone sits on the arc's midpoint
    half = math.radians(10.0)
    assert _exact_margin(axis, half) == pytest.approx(-half, abs=1e-9)
    p = _pointing(cones=[{"axis": axis, "half_angle": half}])
    sol = eigenaxis_answer(p)                 # the direct slew
    assert not sol.success and sol.status == 2
    check = sol.verification["cone_clearance"]
    assert not check["passed"] and check["value"] <= -half + 1e-9
    assert "cone_clearance" in sol.message and "keep-out cone" in sol.message
    assert math.isnan(sol.baseline_tf)
    # method="eigenaxis" flies round the cone through a waypoint instead (tests/test_waypoint_slew.py)
    around = solvers.solve(p, method="eigenaxis")
    assert around.success and "waypoint" in around.route and around.tf > sol.tf
    assert "direct eigenaxis path enters a keep-out cone" in around.message


def test_the_fallback_flies_a_pointing_slew_where_the_route_found_none(monkeypatch):
    def route(prob, method, guess, **options):
        return SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 0, 0, 0.0,
                            method="indirect", problem=prob, route="stub")

    monkeypatch.setattr(multistart, "solve_indirect", route)
    p = _pointing(cones=[{"axis": [0.0, 0.2 / math.hypot(0.2, 1.0), 1.0 / math.hypot(0.2, 1.0)],
                          "half_angle_deg": 20.0}])
    failed = solvers.solve(p.replace(cones=()), method="indirect", warm_start=None, time_budget=0.2)
    assert not failed.success and "fallback='eigenaxis' would return the eigenaxis slew" in failed.message
    plain = solvers.solve(_pointing(), method="eigenaxis")
    sol = solvers.solve(p.replace(cones=()), method="indirect", warm_start=None, time_budget=0.2,
                        fallback="eigenaxis")
    # with cones the route begins with collocation (not stubbed here): the fallback step alone
    cone_sol = _eigenaxis_fallback(p, route(p, "indirect", None), time.perf_counter())
    for s in (sol, cone_sol):
        assert s.success and s.method == "eigenaxis"
        assert "fallback: the eigenaxis slew" in s.route and "Time budget exhausted" in s.message
        assert s.tf == pytest.approx(plain.tf, rel=1e-12)
    assert cone_sol.verification["cone_clearance"]["passed"]


def _cone_at_distance(d, half):
    """A cone whose axis lies ``half + d`` from the arc's midpoint, off the arc's plane: the arc
    passes ``d`` rad from its boundary, at the midpoint."""
    mid = (SENSOR + TARGET) / np.linalg.norm(SENSOR + TARGET)
    normal = np.cross(SENSOR, TARGET) / np.linalg.norm(np.cross(SENSOR, TARGET))
    return {"axis": math.cos(half + d) * mid + math.sin(half + d) * normal, "half_angle": half}


def test_a_path_that_clears_a_cone_closely_is_flown_but_is_no_baseline():
    # the baseline rule (eigenaxis.baseline_time): only a path 0.005 rad clear of every cone; the
    # eigenaxis answer had given its tf as the baseline for any path its clearance check passed
    cone = _cone_at_distance(0.002, math.radians(15.0))
    assert _exact_margin(np.asarray(cone["axis"]), cone["half_angle"]) == pytest.approx(0.002, abs=1e-9)
    sol = solvers.solve(_pointing(cones=[cone]), method="eigenaxis")
    assert sol.success and 0.0 < sol.verification["cone_clearance"]["value"] <= 0.002
    assert math.isnan(sol.baseline_tf)


def test_the_fallback_keeps_no_time_where_the_path_enters_a_cone(monkeypatch):
    import solvers.api as api
    seen = {}

    def route(prob, method, guess, warm_start, options, *rest):
        seen["time_budget"] = options["time_budget"]
        return SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 0, 0, 0.0,
                            method="indirect", problem=prob, route="stub")

    monkeypatch.setattr(api, "_dispatch", route)
    blocked = _pointing(cones=[_cone_at_distance(-0.2, math.radians(15.0))])
    clear = _pointing(cones=[_cone_at_distance(0.3, math.radians(15.0))])
    # round the cone through one waypoint: two legs, 25 ms each kept
    solvers.solve(blocked, time_budget=0.2, fallback="eigenaxis")
    assert seen["time_budget"] == pytest.approx(0.2 - 0.05, rel=1e-12)
    from solvers import waypoint_slew
    with monkeypatch.context() as m:
        m.setattr(waypoint_slew, "fallback_plan", lambda prob: None)     # no way round
        solvers.solve(blocked, time_budget=0.2, fallback="eigenaxis")
    assert seen["time_budget"] == 0.2                  # the route keeps the whole budget
    solvers.solve(clear, time_budget=0.2, fallback="eigenaxis")
    assert seen["time_budget"] == pytest.approx(0.2 - 0.025, rel=1e-12)
