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
# the same body about an axis off its principal axes: its eigenaxis profile has a gyroscopic term
GYRO = SlewProblem([1.0, 0.8, 0.6], q0=[1.0, 0.0, 0.0, 0.0],
                   qf=[math.cos(0.6), *(math.sin(0.6) * np.array([1.0, 1.0, 1.0]) / math.sqrt(3.0))])


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

    def slow_warm(prob, method, warm_start, options, split=False, table_reserve=False):
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


@pytest.fixture(scope="module")
def held_out_singular():
    """A held-out full-attitude problem (seed 20261122, index 28) that the shipped singular table
    answers: most of its nearest tabled problems are singular."""
    from training.generate import GenerationSpec, problem_for
    p = problem_for(GenerationSpec("full-attitude", seed=20261122), 28)
    assert warm_routes._table_may_answer(p)
    return p


def _learned_budget(monkeypatch, prob, total, table_reserve=True, **opts):
    """The budget ``try_warm_start`` gives the default model's candidates under ``total``."""
    from solvers.solution import SlewSolution
    seen = []

    def fake(p, g, opts, budget, method="indirect", with_candidates=True):
        seen.append(budget)
        return SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "stopped", 0, 0, 0.0, problem=p)
    monkeypatch.setattr(multistart, "guess_alone", fake)
    warm_routes.try_warm_start(prob, "auto", "default", dict({"time_budget": total}, **opts), split=True,
                               table_reserve=table_reserve)
    return seen[0]


def test_a_short_budget_keeps_the_singular_tables_time(monkeypatch, held_out_singular):
    """Where the singular table would answer, a budget the learned candidates could use to its end
    keeps ``TABLE_RESERVE`` for the table (their Newton cannot converge on a singular problem; an
    outside replay had seen 0.05 s budgets end 8-10 ms late, the table's answer after them)."""
    reserve = warm_routes.TABLE_RESERVE
    assert _learned_budget(monkeypatch, held_out_singular, 0.05) == pytest.approx(0.05 - reserve)
    # a budget below twice the reserve: the candidates keep a quarter of it
    assert _learned_budget(monkeypatch, held_out_singular, 0.016) == pytest.approx(0.004)
    # a long budget leaves the table its time anyway: the candidates' own cap
    assert _learned_budget(monkeypatch, held_out_singular, 20.0) == warm_routes.WARM_BUDGET
    # a problem the table does not answer: the whole short budget
    assert not warm_routes._table_may_answer(FULL)
    assert _learned_budget(monkeypatch, FULL, 0.05) == pytest.approx(0.05)
    # no table to come (not auto, or singular_table=False): nothing kept; a warm_budget below
    # what the reserve leaves stays the user's
    assert _learned_budget(monkeypatch, held_out_singular, 0.05, table_reserve=False) == pytest.approx(0.05)
    assert _learned_budget(monkeypatch, held_out_singular, 0.016, warm_budget=0.001) == pytest.approx(0.001)


def test_the_reserve_is_asked_for_only_where_the_table_can_run(monkeypatch, held_out_singular):
    seen = []

    def spy(prob, method, warm_start, options, split=False, table_reserve=False):
        seen.append((method, table_reserve))
        raise RuntimeError("stop")
    monkeypatch.setattr(warm_routes, "try_warm_start", spy)
    for kw in ({}, {"singular_table": False}, {"method": "indirect"}):
        with pytest.raises(RuntimeError, match="stop"):
            solvers.solve(held_out_singular, time_budget=0.05, **kw)
    assert seen == [("auto", True), ("auto", False), ("indirect", False)]


def test_no_table_route_starts_with_less_than_its_minimum_left(monkeypatch):
    """The learned stage left less than ``TABLE_MIN_LEFT``: the singular table (whose first
    sequence takes ~9 ms) is not started, and the answer says the budget was spent."""
    from solvers.solution import SlewSolution

    def slow_warm(prob, method, warm_start, options, split=False, table_reserve=False):
        time.sleep(options["time_budget"] - 0.5 * warm_routes.TABLE_MIN_LEFT)
        failed = SlewSolution(False, STATUS_BUDGET_EXHAUSTED, "candidates stopped", 1, 1, 0.03, problem=prob)
        return failed, {"covered": True, "succeeded": False}, None

    def no_table(*a, **k):
        raise AssertionError("the table started with too little time left")
    monkeypatch.setattr(warm_routes, "try_warm_start", slow_warm)
    monkeypatch.setattr(warm_routes, "singular_table_route", no_table)
    monkeypatch.setattr(auto_route, "solve_auto", no_table)
    sol = solvers.solve(FULL, time_budget=0.05)
    assert not sol.success and sol.status == STATUS_BUDGET_EXHAUSTED
    assert "no time left for the default route" in sol.route


def test_with_an_answer_in_hand_no_sequence_starts_that_would_end_past_the_budget(monkeypatch):
    """``bang_bang_from_sequences``: once a sequence has given a verified answer, the next starts
    only if the time left is at least what a sequence has taken so far."""
    from types import SimpleNamespace
    from solvers import switch_time_opt
    started = []
    clock = [0.0]       # (a clock of its own: a sleep on a busy machine could overshoot by 10 ms)

    def fake_optimise(problem, signs0, axes, times, T, time_budget=1.0, max_iter=300, bvp=None):
        started.append(time_budget)
        clock[0] += 0.02
        return SimpleNamespace(success=True, T=T * (1.0 - 0.01 * len(started)), nit=1, nfev=1, kkt=1.0)
    monkeypatch.setattr(switch_time_opt, "time", SimpleNamespace(perf_counter=lambda: clock[0]))

    def fake_answer(problem, bvp, r, *a):
        return SimpleNamespace(tf=r.T, route="", guess="", n_candidates=0, nit=0, nfev=0, wall_time=0.0), None
    monkeypatch.setattr(switch_time_opt, "optimise_switch_times", fake_optimise)
    monkeypatch.setattr(switch_time_opt, "_answer", fake_answer)
    seq = ([1.0, 1.0, 1.0], [np.array([0.3, 0.9]), np.array([0.5, 1.0]), np.array([0.7, 1.1])], 1.5)
    ans, _, _ = switch_time_opt.bang_bang_from_sequences(FULL, [seq] * 5, time_budget=0.05)
    # 0.02 s a sequence: the third would start with ~0.01 s left, less than the 0.02 s one takes
    assert len(started) == 2 and ans.n_candidates == 2
    # without an answer (every sequence fails) the next still starts while time is left
    started.clear()
    monkeypatch.setattr(switch_time_opt, "_answer", lambda *a: (None, None))
    ans, _, _ = switch_time_opt.bang_bang_from_sequences(FULL, [seq] * 5, time_budget=0.05)
    assert ans is None and len(started) == 3


def test_the_eigenaxis_comparison_under_a_budget_fits_the_time_left(monkeypatch):
    from solvers.eigenaxis_answer import N_GRID_PNORM_GYRO
    """``auto``'s "never slower than the eigenaxis slew" plans that slew on as many steps as the
    time left pays for (a p-norm profile on the full grid had taken 32 ms after a 0.3 s budget was
    spent); without a budget, on the default grid."""
    seen = []
    real = api.no_slower_than_eigenaxis

    def spy(prob, sol, t0, n_grid=None):
        seen.append(n_grid)
        return real(prob, sol, t0, n_grid=n_grid)
    monkeypatch.setattr(api, "no_slower_than_eigenaxis", spy)
    p = GYRO.replace(torque_norm=4.0)
    solvers.solve(p, time_budget=0.3, warm_start=None)
    assert seen[-1] is not None and api.FALLBACK_GRID_FLOOR["pnorm-gyro"] <= seen[-1] < N_GRID_PNORM_GYRO
    # with time to spare, the grid of method="eigenaxis" itself; without a budget, the default
    solvers.solve(p, warm_start=None, time_budget=20.0)
    assert seen[-1] == N_GRID_PNORM_GYRO
    solvers.solve(p, warm_start=None)
    assert seen[-1] is None


def test_a_coarse_eigenaxis_comparison_replaces_an_answer_no_faster_than_it():
    """``no_slower_than_eigenaxis`` with ``n_grid``: the comparison slew is the one planned on those
    steps, verified by its replay, and replaces an approximate answer that is not faster."""
    from solvers.eigenaxis_answer import eigenaxis_answer, no_slower_than_eigenaxis
    from solvers.solution import SlewSolution
    p = GYRO.replace(torque_norm=4.0)
    coarse = eigenaxis_answer(p, n_grid=40)
    fine = eigenaxis_answer(p)
    assert coarse.success and coarse.tf > fine.tf
    approx = SlewSolution(True, STATUS_SUCCESS, "collocation", 1, 1, 0.1, method="collocation", problem=p,
                          tf=coarse.tf * 1.001, baseline_tf=fine.tf)
    out = no_slower_than_eigenaxis(p, approx, time.perf_counter(), n_grid=40)
    assert out.method == "eigenaxis" and out.tf == pytest.approx(coarse.tf, rel=1e-12)
    # faster than the coarse slew: kept
    approx.tf = coarse.tf * 0.999
    assert no_slower_than_eigenaxis(p, approx, time.perf_counter(), n_grid=40) is approx
