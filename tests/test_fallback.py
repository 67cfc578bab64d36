"""``fallback="eigenaxis"``: a flyable answer where the time-optimal route gives no verified one."""
import json
import time
from pathlib import Path

import numpy as np
import pytest

import solvers
from slew_env import SlewProblem
from solvers import Guess, multistart
from solvers.eigenaxis_answer import eigenaxis_answer
from training.cli import main

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
R3 = EXAMPLES / "r3_seed_report_per_axis.json"


def _r3():
    return SlewProblem.from_dict(json.loads(R3.read_text()))


def _bad_guess():
    """A guess that cannot converge: costates away from any extremal, tf a third of the optimum."""
    return Guess(costate0=np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]), tf=0.8)


def test_a_failed_route_returns_the_eigenaxis_slew():
    prob = _r3()
    failed = solvers.solve(prob, method="indirect", guess=_bad_guess(), max_candidates=1, warm_start=None)
    assert not failed.success
    # the failure says that a flyable answer is offered (a GNC review had to find the option)
    assert failed.message.endswith("No verified answer: fallback='eigenaxis' would return the eigenaxis slew "
                                   "(solvers.eigenaxis_slew; its time is baseline_tf where the budget left time to "
                                   "plan it), checked by its own replay, not time-optimal.")
    sol = solvers.solve(prob, method="indirect", guess=_bad_guess(), max_candidates=1, warm_start=None,
                        fallback="eigenaxis")
    eig = eigenaxis_answer(prob)
    assert sol.success and sol.method == "eigenaxis" and not sol.exact
    assert "fallback" in sol.route and "fallback" in sol.message
    assert sol.tf == pytest.approx(eig.tf, rel=1e-12)
    # the eigenaxis slew of R3 is 6.8 % slower than its time-optimal 2.35402
    assert sol.tf == pytest.approx(2.5136, rel=1e-3)
    assert sol.verification and all(c["passed"] for c in sol.verification.values())
    # the failed route's work is counted
    assert sol.nfev >= failed.nfev


def test_a_verified_answer_is_not_replaced():
    sol = solvers.solve(_r3(), fallback="eigenaxis")
    assert sol.success and sol.method == "indirect"
    assert sol.tf == pytest.approx(2.3540178, rel=1e-7)


def test_where_the_fallback_does_not_apply_or_fails_the_failure_says_so(monkeypatch):
    import time
    from solvers import waypoint_slew
    from solvers.api import _eigenaxis_fallback
    from solvers.solution import STATUS_BUDGET_EXHAUSTED, SlewSolution
    # the eigenaxis path from +x to +y crosses a cone about their bisector; with no waypoint slew
    # around it (none planned here: tests/test_waypoint_slew.py flies the one there is), the direct
    # slew is tried and fails its clearance check
    monkeypatch.setattr(waypoint_slew, "fallback_plan", lambda prob: None)
    cones = SlewProblem([1.0, 1.0, 1.0], sensor_target=[0.0, 1.0, 0.0],
                        cones=[{"axis": [0.7071, 0.7071, 0.0], "half_angle_deg": 10.0}])
    moving = _r3().replace(omega0=[0.01, 0.0, 0.0])
    for prob, why in ((moving, "does not apply: non-zero rates"),
                      (cones, "failed: A candidate converged but failed its own verification")):
        failed = SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 0, 0, 0.0,
                              method="indirect", problem=prob, route="test")
        out = _eigenaxis_fallback(prob, failed, time.perf_counter())
        assert out is failed and not out.success
        assert f"fallback 'eigenaxis' {why}" in out.message
    assert "cone_clearance = -0.175" in out.message


def test_bad_fallback_values_name_the_option():
    with pytest.raises(ValueError, match="fallback"):
        solvers.solve(_r3(), fallback="slerp")
    with pytest.raises(ValueError, match="fallback"):
        solvers.solve(_r3(), fallback=True)
    with pytest.raises(ValueError, match="fallback: applies"):
        solvers.solve(_r3(), method="collocation", fallback="eigenaxis")


def test_cli_time_budget_and_fallback(tmp_path, capsys):
    out = tmp_path / "sol.json"
    code = main(["solve", str(R3), "-o", str(out), "--method", "indirect", "--warm-start", "none",
                 "--time-budget", "30", "--fallback", "eigenaxis", "--repeat", "0"])
    assert code == 0
    assert json.loads(out.read_text())["method"] == "indirect"      # solved: no fallback needed
    for argv, needle in ((["--time-budget", "-1"], "--time-budget"),
                         (["--method", "collocation", "--fallback", "eigenaxis"], "--fallback")):
        code = main(["solve", str(R3), "--repeat", "0"] + argv)
        err = capsys.readouterr().err
        assert code == 2 and needle in err and "Traceback" not in err


@pytest.mark.parametrize("budget, torque_norm, inertia, kept, n_grid", [
    (0.2, np.inf, [1.0, 1.0, 1.0], 0.025, 16000),    # FALLBACK_RESERVE; the planner's grid
    (0.03, np.inf, [1.0, 1.0, 1.0], 0.015, 16000),   # at most half the budget
    (0.2, 2.0, [1.0, 1.0, 1.0], 0.025, 16000),       # p-norm, no gyroscopic term: bang-coast-bang
    (0.2, 2.0, [0.5, 0.8, 1.0], 0.025, 1000),        # p-norm off the principal axes: a coarser grid
])
def test_the_fallback_planning_time_comes_out_of_the_routes_budget(monkeypatch, budget, torque_norm, inertia,
                                                                  kept, n_grid):
    from solvers.solution import STATUS_BUDGET_EXHAUSTED, SlewSolution
    seen = {}

    def route(prob, method, guess, **options):
        seen["time_budget"] = options["time_budget"]
        return SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 0, 0, 0.0,
                            method="indirect", problem=prob, route="stub")

    monkeypatch.setattr(multistart, "solve_indirect", route)
    prob = _r3().replace(inertia=inertia, torque_norm=torque_norm)
    sol = solvers.solve(prob, method="indirect", warm_start=None, time_budget=budget, fallback="eigenaxis")
    assert seen["time_budget"] == pytest.approx(budget - kept, rel=1e-12)
    assert sol.success and sol.method == "eigenaxis"
    assert f"planned in the {1e3 * kept:.0f} ms of the budget kept for it" in sol.route
    assert f"profile, {n_grid} steps)" in sol.message
    if n_grid < 16000:      # the coarser profile: flyable, never faster, at most 5e-5 slower
        fine = eigenaxis_answer(prob).tf
        assert fine * (1.0 - 1e-12) <= sol.tf <= fine * (1.0 + 5e-5)
    # without the fallback, or where it does not apply, the route has the whole budget
    solvers.solve(prob, method="indirect", warm_start=None, time_budget=budget)
    assert seen["time_budget"] == budget
    solvers.solve(prob.replace(omega0=[0.01, 0.0, 0.0]), method="indirect", warm_start=None, time_budget=budget,
                  fallback="eigenaxis")
    assert seen["time_budget"] == budget


@pytest.mark.parametrize("torque_norm, inertia", [(np.inf, [0.5, 0.8, 1.0]), (2.0, [0.5, 0.8, 1.0]),
                                                  (2.0, [1.0, 1.0, 1.0])])
def test_a_short_budget_gets_a_coarser_fallback_that_fits(monkeypatch, torque_norm, inertia):
    """The route used its whole budget: the 5 ms kept at a 10 ms budget cannot pay for the
    default profile (per-axis 16,000 steps, 12-20 ms), so the fallback plans on fewer steps, not
    below the floor; a coarser profile is flyable and never faster than the fine one."""
    import re
    from solvers import api
    from solvers.solution import STATUS_BUDGET_EXHAUSTED, SlewSolution

    def route(prob, method, guess, **options):
        time.sleep(options["time_budget"])
        return SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 0, 0, 0.0,
                            method="indirect", problem=prob, route="stub")

    monkeypatch.setattr(multistart, "solve_indirect", route)
    prob = _r3().replace(inertia=inertia, torque_norm=torque_norm)
    sol = solvers.solve(prob, method="indirect", warm_start=None, time_budget=0.01, fallback="eigenaxis")
    assert sol.success and sol.method == "eigenaxis"
    n = int(re.search(r"profile, (\d+) steps\)", sol.message).group(1))
    kind = "no-gyro" if np.isinf(torque_norm) or inertia == [1.0, 1.0, 1.0] else "pnorm-gyro"
    default = 16000 if kind == "no-gyro" else api.FALLBACK_GRID_PNORM_GYRO
    assert api.FALLBACK_GRID_FLOOR[kind] <= n < default
    fine = eigenaxis_answer(prob).tf
    assert fine * (1.0 - 1e-12) <= sol.tf <= fine * (1.0 + 1e-3)
    # with time to spare, the default grid
    assert api._fallback_grid(prob) == default and api._fallback_grid(prob, 1.0) == default
    assert api._fallback_grid(prob, 0.0) == api.FALLBACK_GRID_FLOOR[kind]
