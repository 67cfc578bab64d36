"""Eigenaxis slews through waypoints round keep-out cones (``solvers.waypoint_slew``): what
``method="eigenaxis"`` and ``fallback="eigenaxis"`` fly where the direct eigenaxis path enters a
cone. Each answer is replayed here by scipy's DOP853 from its control alone, with the test's own
rotation algebra."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

import solvers
from slew_env import SlewProblem
from solvers import waypoint_slew
from solvers.solution import STATUS_BUDGET_EXHAUSTED, SlewSolution

SENSOR = np.array([1.0, 0.0, 0.0])


def _rot(q):
    """scipy rotation of a scalar-first quaternion (body to inertial)."""
    q = np.asarray(q, float)
    return Rotation.from_quat([q[1], q[2], q[3], q[0]])


def _replay(sol, problem):
    """Fly ``sol.control`` from the start state with DOP853 between the breakpoints (instants the
    dense record holds twice: leg ends and acceleration switches); the end state and the smallest
    cone margin on 20,000 points of the flown path."""
    J = np.asarray(problem.inertia, float)

    def rhs(t, x):
        q, w = x[:4], x[4:]
        u = np.asarray(sol.control(np.array([t])))[0]
        dq = 0.5 * np.array([-q[1] * w[0] - q[2] * w[1] - q[3] * w[2],
                             q[0] * w[0] + q[2] * w[2] - q[3] * w[1],
                             q[0] * w[1] - q[1] * w[2] + q[3] * w[0],
                             q[0] * w[2] + q[1] * w[1] - q[2] * w[0]])
        return np.concatenate([dq, (u - np.cross(w, J * w)) / J])

    t = np.asarray(sol.t)
    breaks = np.unique(t[1:][np.diff(t) == 0.0])
    edges = np.concatenate([[0.0], breaks[(breaks > 0) & (breaks < sol.tf)], [sol.tf]])
    x = np.concatenate([problem.q0, np.zeros(3)])
    worst = math.inf
    axes = np.array([c.axis for c in problem.cones])
    half = np.array([c.half_angle for c in problem.cones])
    for a, b in zip(edges[:-1], edges[1:]):
        # (the control is evaluated just inside each piece: at a breakpoint it is the next piece's)
        r = solve_ivp(rhs, (a, b), x, method="DOP853", rtol=1e-12, atol=1e-13, dense_output=True)
        x = r.y[:, -1]
        tt = np.linspace(a, b, max(2, int(20_000 * (b - a) / sol.tf)))
        qs = r.sol(tt)[:4].T
        qs = qs / np.linalg.norm(qs, axis=1, keepdims=True)
        dirs = Rotation.from_quat(qs[:, [1, 2, 3, 0]]).apply(np.array(problem.sensor_axis, float))
        worst = min(worst, float(np.min(np.arccos(np.clip(dirs @ axes.T, -1, 1)) - half[None, :])))
    return x, worst


def _blocked_pointing(**kw):
    """Sensor +x to a target 100° away, a 15° cone on the great circle between them."""
    target = np.array([math.cos(math.radians(100)), math.sin(math.radians(100)), 0.0])
    mid = np.array([math.cos(math.radians(50)), math.sin(math.radians(50)), 0.0])
    args = dict(inertia=[1.0, 1.0, 1.0], torque_max=[1.0, 1.0, 1.0], sensor_target=target,
                sensor_axis=SENSOR, cones=[{"axis": mid, "half_angle_deg": 15.0}])
    args.update(kw)
    return SlewProblem(**args)


def _leg_time_symmetric(qa, qb):
    """Rest-to-rest eigenaxis time of J = 1, |u_i| ≤ 1 from qa to qb: the angle θ about the body
    axis n at the acceleration 1 / max|n_i|, bang-bang (no gyroscopic term for a symmetric body)."""
    rv = (_rot(qa).inv() * _rot(qb)).as_rotvec()
    th = float(np.linalg.norm(rv))
    return 2.0 * math.sqrt(th * float(np.max(np.abs(rv / th))))


def test_a_blocked_pointing_slew_goes_round_the_cone_through_one_waypoint():
    p = _blocked_pointing()
    assert not waypoint_slew.direct_path_clear(p)
    plan = waypoint_slew.plan_waypoints(p)
    assert plan is not None and plan.n_waypoints == 1
    # the waypoint's direction lies outside the cone by the planning margin
    w = plan.directions[1]
    axis = np.array([math.cos(math.radians(50)), math.sin(math.radians(50)), 0.0])
    assert math.acos(float(w @ axis)) - math.radians(15.0) >= waypoint_slew.PLAN_CLEARANCE - 1e-12
    sol = solvers.solve(p, method="eigenaxis")
    assert sol.success and sol.status == 0 and "through 1 waypoint" in sol.route
    assert sol.verification["boundary_attitude_error"]["value"] < 1e-8
    assert sol.verification["cone_clearance"]["value"] > 0.0
    # the time is the two legs' bang-bang times, by the test's own formula on the plan's attitudes
    expected = sum(_leg_time_symmetric(a, b) for a, b in zip(plan.attitudes[:-1], plan.attitudes[1:]))
    assert sol.tf == pytest.approx(expected, rel=1e-9)
    # the direct path (through the cone) would be faster: 2 sqrt(θ / a) about the rotation's axis
    assert sol.tf > 2.0 * math.sqrt(math.radians(100.0) * 1.0)
    # flown from its control alone, the sensor ends on the target at rest, and stays out of the cone
    x, worst = _replay(sol, p)
    end = _rot(x[:4] / np.linalg.norm(x[:4])).apply(SENSOR)
    assert math.acos(min(1.0, float(end @ p.sensor_target))) < 1e-7
    assert np.linalg.norm(x[4:]) < 1e-7
    assert worst > 0.0


def test_a_full_attitude_target_behind_a_cone():
    # qf: a 100° turn about z; its eigenaxis path takes the sensor (+x) through the cone
    qf = [math.cos(math.radians(50)), 0.0, 0.0, math.sin(math.radians(50))]
    # (a symmetric body: its legs are bang-bang, which DOP853 flies piece by piece)
    p = _blocked_pointing(sensor_target=None, qf=qf, torque_max=[0.6, 1.0, 0.8])
    assert not waypoint_slew.direct_path_clear(p)
    sol = solvers.solve(p, method="eigenaxis")
    assert sol.success and "waypoint" in sol.route
    x, worst = _replay(sol, p)
    err = (_rot(qf).inv() * _rot(x[:4] / np.linalg.norm(x[:4]))).magnitude()
    assert err < 1e-7 and np.linalg.norm(x[4:]) < 1e-7 and worst > 0.0


def test_two_waypoints_where_one_does_not_clear_the_cones():
    # a family problem (pointing-cones, seed 1, index 0): three cones in a cluster
    p = SlewProblem.from_dict({
        "inertia": [0.707092974820154, 0.9702782177955612, 0.48649576763178026], "torque_max": [1.0, 1.0, 1.0],
        "q0": [-0.8631306867035866, 0.20971962606658023, -0.08583840227572907, 0.45128135880827047],
        "sensor_axis": [1.0, 0.0, 0.0], "sensor_target": [0.6896199430527163, 0.6597262044467577, 0.29863969814852687],
        "cones": [{"axis": [0.9442023180894279, 0.12773274757146033, 0.3035890770637122], "half_angle": 0.2896310072226663},
                  {"axis": [0.909969714444537, -0.38301595548478773, 0.15891474644539116], "half_angle": 0.3152459026204266},
                  {"axis": [0.9419149569868746, 0.30270514290252665, 0.1454847423779393], "half_angle": 0.34389652529526604}]})
    plan = waypoint_slew.plan_waypoints(p)
    assert plan is not None and plan.n_waypoints == 2
    sol = waypoint_slew.waypoint_answer(p, plan=plan)
    assert sol.success and "through 2 waypoints" in sol.route
    assert sol.tf == pytest.approx(plan.tf_planned, rel=1e-3)        # the planner's 120-step grid
    x, worst = _replay(sol, p)
    end = _rot(x[:4] / np.linalg.norm(x[:4])).apply(np.array(p.sensor_axis, float))
    assert math.acos(min(1.0, float(end @ p.sensor_target))) < 1e-7 and worst > 0.0


def test_the_fallback_flies_the_waypoint_slew_under_a_short_budget(monkeypatch):
    import solvers.api as api

    def route(prob, method, guess, warm_start, options, *rest):
        # the route ran out of time (stubbed: with cones it begins with collocation)
        sol = SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 0, 0, 0.0,
                           method="auto", problem=prob, route="stub")
        return api._eigenaxis_fallback(prob, sol, 0.0, 0.05, math.inf)

    monkeypatch.setattr(api, "_dispatch", route)
    p = _blocked_pointing()
    sol = solvers.solve(p, time_budget=0.1, fallback="eigenaxis")
    assert sol.success and sol.method == "eigenaxis"
    assert "fallback: eigenaxis slew through 1 waypoint" in sol.route
    assert "Time budget exhausted" in sol.message
    assert sol.tf == pytest.approx(solvers.solve(p, method="eigenaxis").tf, rel=1e-6)


def test_the_fallback_goes_round_the_cones_where_the_direct_slew_fails_its_clearance(monkeypatch):
    """The planner took the direct path for clear (its samples), but the flown slew's certified
    clearance fails: the fallback flies waypoints instead of giving up (the direct path here goes
    right through the cone; the sampled check is stubbed to have missed it)."""
    import solvers.api as api
    monkeypatch.setattr(waypoint_slew, "direct_path_clear", lambda problem: True)
    waypoint_slew._fallback_plan_cached.cache_clear()
    p = _blocked_pointing(torque_max=[0.9, 1.0, 1.0])
    assert waypoint_slew.fallback_plan(p) == "direct"
    failed = SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 0, 0, 0.0,
                          method="auto", problem=p, route="stub")
    sol = api._eigenaxis_fallback(p, failed, 0.0, 0.05, math.inf)
    waypoint_slew._fallback_plan_cached.cache_clear()
    assert sol.success and "fallback: eigenaxis slew through 1 waypoint" in sol.route
    assert sol.verification["cone_clearance"]["value"] > 0.0
    x, worst = _replay(sol, p)
    end = _rot(x[:4] / np.linalg.norm(x[:4])).apply(SENSOR)
    assert math.acos(min(1.0, float(end @ p.sensor_target))) < 1e-7 and worst > 0.0


def test_a_failed_solve_says_the_fallback_would_go_round_the_cones(monkeypatch):
    from solvers import cone_routes

    def route(prob, guess, col_opts, options):
        return SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 0, 0, 0.0,
                            method="indirect", problem=prob, route="stub")

    monkeypatch.setattr(cone_routes, "solve_indirect_cones", route)
    sol = solvers.solve(_blocked_pointing(), method="indirect", time_budget=0.1)
    assert not sol.success and "through waypoints around the keep-out cones" in sol.message


def test_a_clear_direct_path_is_flown_directly():
    # the cone off the great circle by 0.3 rad: no waypoint needed
    p = _blocked_pointing(cones=[{"axis": [math.cos(math.radians(50)) * math.cos(0.56),
                                           math.sin(math.radians(50)) * math.cos(0.56), math.sin(0.56)],
                                  "half_angle": 0.26}])
    assert waypoint_slew.direct_path_clear(p)
    assert waypoint_slew.fallback_plan(p) == "direct"
    sol = solvers.solve(p, method="eigenaxis")
    assert sol.success and "waypoint" not in sol.route


def test_bad_input_to_the_planner():
    with pytest.raises(ValueError, match="omega0, omegaf"):
        waypoint_slew.plan_waypoints(_blocked_pointing(omega0=[0.01, 0.0, 0.0]))
    assert waypoint_slew.plan_waypoints(_blocked_pointing(cones=[])) is None


def test_no_plan_gives_a_failure_that_says_so(monkeypatch):
    monkeypatch.setattr(waypoint_slew, "plan_waypoints", lambda p: None)
    sol = solvers.solve(_blocked_pointing(), method="eigenaxis")
    assert not sol.success and "keep-out cone" in sol.message


def test_a_plan_flown_on_the_problem_without_its_cones():
    # (the waypoint answer's checks run the cone check only where there are cones)
    p = _blocked_pointing()
    plan = waypoint_slew.plan_waypoints(p)
    ans = waypoint_slew.waypoint_answer(p.replace(cones=[]), plan=plan)
    assert ans.success and "cone_clearance" not in ans.verification
    assert "keep-out cone (certified" not in ans.message
    with_cones = waypoint_slew.waypoint_answer(p, plan=plan)
    assert with_cones.success and with_cones.verification["cone_clearance"]["passed"]
    assert with_cones.tf == pytest.approx(ans.tf, rel=1e-12)
