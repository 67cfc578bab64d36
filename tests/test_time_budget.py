"""solve's ``time_budget`` holds for the whole solve: stages get what is left of it, not a floor
of their own (collocation used to get at least 1 s, the touch refinement 1.5 s, whatever the
caller's budget), and ``method="collocation"`` takes it from solve's options."""
import math
import time
from pathlib import Path

import numpy as np
import pytest

import solvers
from slew_env import SlewProblem
from solvers import api, auto_route, cone_routes, multistart, stage_budget, warm_routes, collocation_guesses, collocation_nlp
from solvers.collocation import solve_collocation
from solvers.solution import STATUS_BUDGET_EXHAUSTED, STATUS_SUCCESS
from reference_cases import TOUCH

R3_FILE = Path(__file__).resolve().parent.parent / "examples" / "r3_seed_report_per_axis.json"

FULL = SlewProblem([1.0, 0.8, 0.6], q0=[1.0, 0.0, 0.0, 0.0], qf=[math.cos(0.6), math.sin(0.6), 0.0, 0.0])


@pytest.fixture(scope="module")
def touch_col():
    # (builds the NLP templates of this problem, so the budgeted solves below time solving)
    return solve_collocation(TOUCH)


def test_collocation_method_takes_solves_time_budget(monkeypatch):
    seen = {}

    def fake(problem, **kw):
        seen.update(kw)
        raise RuntimeError("stop")
    monkeypatch.setattr(solvers.collocation, "solve_collocation", fake)
    with pytest.raises(RuntimeError):
        solvers.solve(FULL, method="collocation", time_budget=0.25, tols={"boundary_rate_error": 1e-7})
    assert seen["time_budget"] == 0.25 and seen["tols"] == {"boundary_rate_error": 1e-7}
    # the collocation dict's own value wins
    with pytest.raises(RuntimeError):
        solvers.solve(FULL, method="collocation", time_budget=0.25, collocation={"time_budget": 3.0})
    assert seen["time_budget"] == 3.0


def test_collocation_with_its_budget_spent_says_so(touch_col):
    sol = solvers.solve(TOUCH, method="collocation", time_budget=1e-3)
    assert not sol.success and sol.status == STATUS_BUDGET_EXHAUSTED
    assert "budget" in sol.message.lower()
    # nothing converged: no eigenaxis slew is planned for the comparison
    assert math.isnan(sol.baseline_tf)
    # and it says what ran out where, not an empty route and a message ending "IPOPT: "
    assert sol.route.startswith("Hermite–Simpson: ")
    assert not sol.message.rstrip().endswith("IPOPT:")


def test_indirect_with_its_budget_spent_has_a_route():
    moving = FULL.replace(omega0=[0.05, 0.0, 0.0])
    sol = solvers.solve(moving, method="indirect", warm_start=None, time_budget=1e-3)
    assert not sol.success and sol.status == STATUS_BUDGET_EXHAUSTED
    assert sol.route.startswith("indirect: no candidate converged")


def test_auto_with_cones_keeps_a_short_budget(touch_col):
    solvers.solve(TOUCH, warm_start=None)      # warm caches (the refinement's kernels)
    t0 = time.perf_counter()
    sol = solvers.solve(TOUCH, warm_start=None, time_budget=0.02)
    wall = time.perf_counter() - t0
    assert not sol.success and sol.status == STATUS_BUDGET_EXHAUSTED
    # the old floors gave collocation at least 1 s here; the IPOPT callback stops it at once
    assert wall < 0.6


def test_stages_get_what_is_left(monkeypatch):
    budgets = []
    real = solvers.collocation.solve_collocation

    def spy(problem, **kw):
        budgets.append(kw["time_budget"])
        return real(problem, **kw)
    monkeypatch.setattr(solvers.collocation, "solve_collocation", spy)
    solvers.solve(TOUCH, warm_start=None, time_budget=0.3)
    assert budgets and budgets[0] <= 0.3
    assert stage_budget.left(0.3, 0.5) == stage_budget.MIN_STAGE_BUDGET and stage_budget.left(1.0, 0.25) == 0.75


def test_touch_refinement_stops_at_the_callers_deadline(touch_col):
    sol = cone_routes.refine_touching_cones(TOUCH, touch_col, {}, budget=1e-9)
    assert not sol.success
    assert "time budget ran out" in sol.message
    full = cone_routes.refine_touching_cones(TOUCH, touch_col, {})
    assert full.success and full.status == STATUS_SUCCESS


def test_auto_starts_no_multi_start_once_the_budget_is_spent(monkeypatch):
    """Collocation stopped by the budget: the classical multi-start (whose first candidate always
    runs) is not started past it."""
    solvers.solve(FULL, warm_start=None, method="collocation")     # the NLP templates, built
    called = []
    monkeypatch.setattr(multistart, "solve_indirect", lambda *a, **k: called.append(1))
    sol = solvers.solve(FULL, warm_start=None, time_budget=1e-3)
    assert not called
    assert not sol.success and sol.status == STATUS_BUDGET_EXHAUSTED
    assert "no time left for the indirect multi-start" in sol.route
    assert sol.message.startswith("Time budget exhausted")


def test_auto_runs_no_route_after_the_learned_stage_spent_the_budget(monkeypatch):
    """The learned candidates used the whole budget: the default route (collocation, whose NLP
    build is not interruptible) does not start; the answer says the budget ran out."""
    from solvers.solution import SlewSolution

    def slow_warm(prob, method, warm_start, options, split=False):
        time.sleep(0.03)
        failed = SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "candidates stopped", 1, 1, 0.03, problem=prob)
        return failed, {"covered": True, "succeeded": False}, None
    monkeypatch.setattr(warm_routes, "try_warm_start", slow_warm)
    monkeypatch.setattr(warm_routes, "singular_table_route", lambda *a, **k: (None, (0, 0)))
    monkeypatch.setattr(warm_routes, "table_votes_bang_bang", lambda info: False)

    def no_route(*a, **k):
        raise AssertionError("the route ran past the budget")
    monkeypatch.setattr(auto_route, "solve_auto", no_route)
    sol = solvers.solve(FULL, time_budget=0.02)
    assert not sol.success and sol.status == STATUS_BUDGET_EXHAUSTED
    assert "no time left for the default route" in sol.route


def test_auto_starts_no_collocation_once_the_indirect_stage_spent_the_budget(monkeypatch):
    """p-norm (p ≤ 2) auto: the indirect multi-start first; if it fails having used the budget,
    collocation (whose NLP build is not interruptible: 0.3-0.5 s the first time) is not started."""
    from solvers.solution import STATUS_BUDGET_EXHAUSTED, SlewSolution
    prob = SlewProblem([0.5, 0.8, 1.0], torque_norm=2.0, q0=[1, 0, 0, 0], qf=[0.0, 1.0, 0.0, 0.0])

    def slow_failure(p, method, guess, **options):
        time.sleep(options["time_budget"] * 1.01)
        return SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 3, 40, 0.0,
                            method="indirect", problem=p, route="stub")

    def no_collocation(*a, **k):
        raise AssertionError("collocation started after the budget was spent")

    solvers.load_kernels(prob)      # (its representative solves must not meet the stubs)
    monkeypatch.setattr(multistart, "solve_indirect", slow_failure)
    monkeypatch.setattr("solvers.collocation.solve_collocation", no_collocation)
    sol = solvers.solve(prob, warm_start=None, time_budget=0.05)
    assert not sol.success and sol.status == STATUS_BUDGET_EXHAUSTED
    assert "no time left for the collocation route" in sol.route and "used the whole time budget" in sol.message
    assert sol.nit == 3 and sol.nfev == 40


def test_no_cone_free_route_once_the_budget_is_spent(monkeypatch):
    """Collocation with the cones failed and used the budget: the problem without its cones is not
    started (its route begins with an NLP build: 0.3 s the first time)."""
    from solvers.solution import SlewSolution

    def no_route(*a, **k):
        raise AssertionError("a route started after the budget was spent")

    monkeypatch.setattr(auto_route, "solve_auto", no_route)
    monkeypatch.setattr(multistart, "solve_indirect", no_route)
    failed = SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "Time budget exhausted.", 0, 0, 0.0,
                          method="collocation", problem=TOUCH, route="stub")
    assert cone_routes.clear_without_cones(TOUCH, failed, {}, {}, 0.0) is None
    assert cone_routes.clear_without_cones(TOUCH, failed, {}, {}, -0.01, exact_only=True) is None


def test_no_nlp_is_built_that_the_budget_cannot_pay_for():
    """Building an NLP (CasADi) is not interruptible: one not yet built in the process is not
    started when the budget left is shorter than its estimated build time."""
    prob = FULL.replace(cones=[{"axis": [0.0, 0.0, 1.0], "half_angle": 0.2}] * 2, q0=[1, 0, 0, 0])
    key_n = 37       # a mesh no other test uses: its NLP is not in the cache
    assert collocation_nlp.build_estimate(key_n, 2) > 0.1
    t0 = time.perf_counter()
    sol = solve_collocation(prob, n_intervals=key_n, coarse=False, time_budget=0.05)
    assert time.perf_counter() - t0 < 0.05 + 0.05
    assert not sol.success and sol.status == STATUS_BUDGET_EXHAUSTED
    assert sol.route == "Hermite–Simpson: no time to build the NLP"
    assert "N=37" in sol.message and "2 cone(s)" in sol.message
    assert not any(k[0] == key_n for k in collocation_nlp._CACHE)
    # with the time, the same NLP is built and solved
    assert solve_collocation(prob, n_intervals=key_n, coarse=False, time_budget=60.0).success
    assert any(k[0] == key_n for k in collocation_nlp._CACHE)


def test_solve_builds_the_nlps_of_the_mesh_it_is_given_before_its_clock():
    """A cone problem's collocation NLPs are built before the clock: those of the default mesh, or
    of the ``n_intervals`` given in the ``collocation`` options (the coarse grid of the starts,
    the mesh, the N / 2 comparison)."""
    from solvers import collocation
    prob = TOUCH.replace(cones=list(TOUCH.cones)[:2])
    assert collocation.prebuild_nlps(prob, 44) >= 0.0
    sizes = {k[0] for k in collocation_nlp._CACHE if k[2] == 2 and k[1]}
    assert {10, 44, 22} <= sizes
    sol = solvers.solve(prob, time_budget=30.0, collocation={"n_intervals": 46})
    assert {10, 46, 23} <= {k[0] for k in collocation_nlp._CACHE if k[2] == 2 and k[1]}
    assert sol.success


def test_routes_that_begin_with_collocation_have_their_nlps_built_before_the_clock(monkeypatch):
    """``auto`` on a full-attitude problem that no warm start covers (here a rate limit) begins
    with collocation: its NLPs are built before the clock, as for pointing and cone problems.
    A problem the shipped model covers, a p-norm bound with p ≤ 2 (indirect first) and the
    indirect method do not build them."""
    full = SlewProblem(inertia=[1.0, 0.8, 0.6], torque_max=1.0, q0=[1, 0, 0, 0],
                       qf=[math.cos(0.6), math.sin(0.6) * 0.6, math.sin(0.6) * 0.8, 0.0])
    rated = full.replace(rate_max=0.5)
    assert api._begins_with_collocation(rated, "auto", None, "default")
    assert api._begins_with_collocation(full, "auto", None, None)
    assert api._begins_with_collocation(full, "collocation", None, "default")
    assert not api._begins_with_collocation(full, "auto", None, "default")          # the learned guess first
    assert not api._begins_with_collocation(full.replace(torque_norm=2.0), "auto", None, None)
    assert not api._begins_with_collocation(rated, "indirect", None, None)
    assert not api._begins_with_collocation(rated, "eigenaxis", None, None)
    assert not api._begins_with_collocation(full, "auto", solvers.Guess(np.ones(7), 2.0), None)
    cones = rated.replace(rate_max=None, cones=[{"axis": [0.0, 0.0, 1.0], "half_angle": 0.2}])
    assert api._begins_with_collocation(cones, "indirect", None, None)
    assert not api._begins_with_collocation(cones.replace(torque_norm=2.0), "indirect", None, None)   # refused

    class Broken:        # a user model whose coverage test fails: the classical route (collocation)
        def covers(self, p):
            raise RuntimeError("no")

        def guess(self, p):
            raise RuntimeError("no")
    assert api._begins_with_collocation(full, "auto", None, Broken())
    # load_kernels takes the same NLPs at start-up
    from solvers import collocation as col
    seen = []
    monkeypatch.setattr(col, "prebuild_nlps", lambda p, *a, **k: seen.append(p) or 0.0)
    solvers.load_kernels([full, rated])
    assert seen == [rated]
    monkeypatch.undo()
    built = []
    monkeypatch.setattr(api, "_prebuild_nlps", lambda prob, col_opts: built.append(prob) or 0.0)
    solvers.solve(full, time_budget=5.0)
    assert not built
    sol = solvers.solve(rated, time_budget=5.0)
    assert built == [rated] and sol.success
    # for real: the mesh given is built, the rate-limited structure's warm-started solver too
    monkeypatch.undo()
    sol = solvers.solve(rated, collocation={"n_intervals": 43}, time_budget=20.0)
    keys = [k for k in collocation_nlp._CACHE if k[0] == 43 and k[4] and not k[1]]
    assert keys and collocation_nlp._CACHE[keys[0]]._warm is not None
    assert sol.kernel_load_time > 0.0 and sol.success


def test_the_warm_started_solver_is_not_built_without_the_time_for_it():
    """A back-off round re-solves an answer warm-started; that IPOPT solver is built at its first
    use (0.1-1.3 s, not interruptible): not when the budget left cannot pay for it (the cold
    solver then runs from the same point), and built when it can."""
    sc = collocation_nlp.Scaled.of(TOUCH)
    nlp = collocation_nlp.NLP(sc, np.full(12, 1.0 / 12), 1e-7, 200, False)    # a mesh no other test uses
    g = collocation_guesses.initial_guesses(sc)[0]
    run = nlp.solve(g.sample(nlp), time.perf_counter() + 30.0, g.source)
    assert run.lam_x is not None and nlp.tpl._warm is None
    nlp.solve(run.w, time.perf_counter() + 1e-3, run.source, warm=run)
    assert nlp.tpl._warm is None
    again = nlp.solve(run.w, time.perf_counter() + 30.0, run.source, warm=run)
    assert nlp.tpl._warm is not None and again.success


# axes' acceleration bounds 1,000 apart: one propagation with sensitivities takes 20,000+ steps
STIFF = SlewProblem([0.1, 1.0, 100.0], torque_max=1.0,
                    qf=[0.6830127018922193, -0.1830127018922193, -0.06162841671621933, 0.7044160264027586])


def _stiff_flow(bvp):
    y0, d = bvp.initial(np.array([0.3, -0.2, 0.1, 0.5, 0.4, -0.6]))
    return bvp.flow(y0, 0.6, d)


def test_a_propagation_stops_at_the_solves_deadline():
    from solvers.attitude_bvp import MIN_STEPS, AttitudeBVP, step_allowance
    from solvers.deadline import propagation_deadline
    bvp = AttitudeBVP(STIFF, mode="tanh", eps=0.05)
    free = _stiff_flow(bvp)
    assert free.ok and free.n_steps > 10 * MIN_STEPS
    with propagation_deadline(time.perf_counter() - 1.0):
        cut = _stiff_flow(bvp)
        # an answer's recorded trajectory is not cut
        assert step_allowance(0, record=100)[1] is False
        # a nested, later deadline does not extend the earlier one
        with propagation_deadline(time.perf_counter() + 100.0):
            assert step_allowance(6) == (MIN_STEPS, True)
    assert not cut.ok and cut.n_steps == MIN_STEPS
    assert cut.message == "the time budget ran out during a propagation"
    # outside the block, no cap again
    assert step_allowance(6)[1] is False and _stiff_flow(bvp).n_steps == free.n_steps


def test_a_stiff_body_does_not_overrun_a_short_budget():
    # before the step allowance: 0.69 s late (two propagations of 0.28 and 0.44 s); now ~3 ms. The
    # margin is wide (a loaded machine), the overrun it guards against was not
    solvers.load_kernels([STIFF])
    sol = solvers.solve(STIFF, method="indirect", time_budget=0.05, warm_start=None)
    assert not sol.success and sol.status == STATUS_BUDGET_EXHAUSTED
    assert sol.wall_time < 0.05 + 0.25


# the compiled calls that fly several arcs (switch-time and touch-point sequences) share one
# step budget (attitude_bvp.step_budget), as single propagations have theirs (step_allowance)
def _stiff_sequence():
    from solvers.attitude_bvp import AttitudeBVP
    p = SlewProblem(inertia=[0.001, 1.0, 1.0], torque_max=[1.0, 1.0, 1.0], qf=[0.0, 1.0, 0.0, 0.0])
    y0 = np.zeros(14)
    y0[0] = 1.0
    return AttitudeBVP(p), y0


def test_sequence_kernels_stop_when_their_steps_run_out():
    from solvers.core.switch_sequence import sequence_end, sequence_samples
    from solvers.core.state_arc import state_arc
    bvp, y0 = _stiff_sequence()
    args = (np.array([2.5]), np.array([0], dtype=np.int64), 5.0, np.ones(3), bvp.J, bvp.umax, bvp.mode, bvp.p,
            bvp.eps, bvp.rtol, bvp.atol, bvp.pen)
    free = np.array([1 << 62], dtype=np.int64)
    assert sequence_end(y0, *args, True, free)[-1]
    used = (1 << 62) - int(free[0])
    assert used > 1000                                   # a stiff body: many steps
    few = np.array([300], dtype=np.int64)
    assert not sequence_end(y0, *args, True, few)[-1] and few[0] <= 0
    fracs = np.linspace(0.0, 1.0, 11)
    few = np.array([300], dtype=np.int64)
    assert not sequence_samples(y0, args[0], args[1], args[2], args[3], fracs, *args[4:], False, few)[-1]
    assert sequence_samples(y0, args[0], args[1], args[2], args[3], fracs, *args[4:], False)[-1]   # no budget
    few = np.array([300], dtype=np.int64)
    assert not state_arc(y0[:7], 5.0, bvp.umax, bvp.J, 1e-12, 1e-13, True, few)[2] and few[0] <= 0


def test_switch_time_and_touch_residuals_keep_to_the_solves_deadline():
    """Past the solve's deadline the sequences get the floor of 200 steps: the stiff body's
    5-unit sequence (thousands of steps) fails there instead of running to its end."""
    from solvers.switch_time import Structure, _residual, propagate_sequence
    from solvers.deadline import propagation_deadline
    bvp, y0 = _stiff_sequence()
    times = np.array([2.5])
    assert propagate_sequence(bvp, times, np.array([0]), np.ones(3), 5.0, y0, True) is not None
    st = Structure(np.ones(3), np.array([0], dtype=np.int64), times)
    z = np.array([0.3, 0.2, 0.1, 0.5, 0.4, 0.3])
    z /= np.linalg.norm(z)
    assert _residual(bvp, z, times, 5.0, st, True)[0] is not None
    with propagation_deadline(time.perf_counter() - 1.0):
        assert propagate_sequence(bvp, times, np.array([0]), np.ones(3), 5.0, y0, True) is None
        assert _residual(bvp, z, times, 5.0, st, True)[0] is None
