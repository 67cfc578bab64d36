"""The learned cone route's Newton settings and candidate order (session 31): the switch-time
Newton gives up on a guess that makes no progress (``LEARNED_STALL``), iterates at a coarse
integrator tolerance first (``LEARNED_COARSE_RTOL``) but declares convergence only at the
problem's, and the candidates with touches are tried in order of their starting residual."""
import math

import numpy as np
import pytest

import solvers.cone_touch as ct
from solvers import solve, cone_routes
from solvers.cone_touch import _structure_of, solve_touch_guess, starting_residuals
from solvers.guesses import Guess

from reference_cases import TOUCH
from test_cone_touch import _answer_guess, rough_answer_guess


@pytest.fixture(scope="module")
def touch_answer():
    sol = solve(TOUCH, method="indirect")
    assert sol.success and sol.exact, sol.message
    return sol


def _newton_parts(guess):
    bvp = ct._touch_bvp(TOUCH)
    tp, z, T0, tc, nu = ct._touch_unknowns(bvp, guess)
    return bvp, tp, z, _structure_of(guess, bvp.tau), T0, tc, nu


def test_the_coarse_phase_converges_to_the_same_extremal_at_the_problems_tolerance(touch_answer):
    bvp, tp, z, st, T0, tc, nu = _newton_parts(rough_answer_guess(touch_answer, 10.0, 0.02, 0.03, 1.3, seed=3))
    fine = (bvp.rtol, bvp.atol)
    x0, ok0, nit0, _, rn0, t0 = ct.structured_newton(tp, z, st, T0, tc, nu)
    evals = []
    real = ct._structured_residual
    ct._structured_residual = lambda tp_, *a: evals.append((tp_.bvp.rtol, a[-1])) or real(tp_, *a)
    try:
        x1, ok1, nit1, _, rn1, t1 = ct.structured_newton(tp, z, st, T0, tc, nu, coarse_rtol=1e-8)
    finally:
        ct._structured_residual = real
    assert ok0 and ok1 and rn1 < 1e-11
    assert (bvp.rtol, bvp.atol) == fine                         # restored
    # most evaluations coarse; the last ones, which decide convergence, at the problem's tolerance
    assert evals[0][0] == 1e-8 and evals[-1][0] == fine[0]
    assert sum(r == 1e-8 for r, _ in evals) > sum(r == fine[0] for r, _ in evals)
    assert np.allclose(x1, x0, rtol=0, atol=1e-9) and np.allclose(t1, t0, rtol=0, atol=1e-9)


def test_a_coarse_iterate_is_never_declared_converged(touch_answer):
    """With a tolerance looser than the hand-over residual (1e-3 against 1e3 · 1e-8), the coarse
    iterates reach it first; convergence is still declared on a residual evaluated at the
    problem's integrator tolerance."""
    bvp, tp, z, st, T0, tc, nu = _newton_parts(rough_answer_guess(touch_answer, 10.0, 0.02, 0.03, 1.3, seed=3))
    fine = (bvp.rtol, bvp.atol)
    evals = []
    real = ct._structured_residual
    ct._structured_residual = lambda tp_, *a: evals.append(tp_.bvp.rtol) or real(tp_, *a)
    try:
        x, ok, nit, _, rn, _ = ct.structured_newton(tp, z, st, T0, tc, nu, tol=1e-3, coarse_rtol=1e-8)
    finally:
        ct._structured_residual = real
    assert ok and rn < 1e-3 and evals[-1] == fine[0] and evals[0] == 1e-8
    # with too few iterations to hand over and converge, no success on a coarse residual
    bvp2, tp2, z2, st2, T2, tc2, nu2 = _newton_parts(rough_answer_guess(touch_answer, 10.0, 0.02, 0.03, 1.3, seed=3))
    _, ok2, _, _, rn2, _ = ct.structured_newton(tp2, z2, st2, T2, tc2, nu2, max_iter=2, coarse_rtol=1e-8)
    assert not ok2 and (bvp2.rtol, bvp2.atol) == (1e-12, 1e-13)


def test_the_stall_rule_stops_a_guess_that_makes_no_progress(touch_answer):
    # a guess far off (costates 60° away, the final time +40 %): 40 iterations, then a failure
    g = rough_answer_guess(touch_answer, 60.0, 0.4, 0.3, 3.0, seed=0)
    bvp, tp, z, st, T0, tc, nu = _newton_parts(g)
    _, ok_free, nit_free, _, rn_free, _ = ct.structured_newton(tp, z, st, T0, tc, nu)
    assert not ok_free and nit_free == 40
    _, ok, nit, _, rn, _ = ct.structured_newton(tp, z, st, T0, tc, nu, stall=(8, 0.1))
    assert not ok and nit == 8 and rn > 0.1
    # its cost: another guess as far off would have converged after 15 iterations (the rule was
    # chosen on held-out problems, where it lost none of the candidates that converged)
    g = rough_answer_guess(touch_answer, 60.0, 0.4, 0.3, 3.0, seed=1)
    bvp, tp, z, st, T0, tc, nu = _newton_parts(g)
    assert ct.structured_newton(tp, z, st, T0, tc, nu)[1]
    assert not ct.structured_newton(tp, z, st, T0, tc, nu, stall=(8, 0.1))[1]
    # a guess that converges as learned guesses do: its residual is below 0.1 long before
    bvp, tp, z, st, T0, tc, nu = _newton_parts(rough_answer_guess(touch_answer, 10.0, 0.02, 0.03, 1.3, seed=3))
    _, ok, _, _, rn, _ = ct.structured_newton(tp, z, st, T0, tc, nu, stall=(8, 0.1))
    assert ok and rn < 1e-11


def test_the_learned_route_uses_the_settings_and_the_collocation_route_does_not(touch_answer, monkeypatch):
    seen = []
    real = ct._switch_time_solve
    monkeypatch.setattr(ct, "_switch_time_solve", lambda *a, **k: seen.append(k) or real(*a, **k))
    g = rough_answer_guess(touch_answer, 10.0, 0.02, 0.03, 1.3, seed=3)
    out = solve_touch_guess(TOUCH, g, smoothing=False)
    assert out.success and out.tf == pytest.approx(touch_answer.tf, rel=1e-9)
    assert seen[0] == {"stall": ct.LEARNED_STALL, "coarse_rtol": ct.LEARNED_COARSE_RTOL}
    seen.clear()
    solve_touch_guess(TOUCH, g, smoothing=True)
    assert seen and all(k == {} for k in seen)


def test_starting_residuals_rank_the_candidates_with_touches(touch_answer):
    exact = _answer_guess(touch_answer, source="exact")
    rough = rough_answer_guess(touch_answer, 20.0, 0.05, 0.05, 1.5, seed=2, source="rough")
    no_touch = Guess(touch_answer.costate0, touch_answer.tf, source="no-touch")
    r = starting_residuals(TOUCH, [rough, exact, no_touch])
    assert r[1] < 1e-9 < r[0] < math.inf and r[2] == math.inf
    # the rough one first in the model's order: the exact one takes its place; the one without
    # touches keeps its own
    order = cone_routes.ranked_by_starting_residual(TOUCH, [rough, no_touch, exact])
    assert [c.source for c in order] == ["exact", "no-touch", "rough"]
    # ties (and guesses that cannot be evaluated) keep their order
    wrong = Guess(touch_answer.costate0, touch_answer.tf, source="no-structure", touches=exact.touches)
    order = cone_routes.ranked_by_starting_residual(TOUCH, [wrong, rough, exact])
    assert [c.source for c in order] == ["exact", "rough", "no-structure"]


def test_a_problem_without_a_per_axis_bound_keeps_the_models_order(touch_answer):
    exact = _answer_guess(touch_answer, source="exact")
    rough = rough_answer_guess(touch_answer, 20.0, 0.05, 0.05, 1.5, seed=2, source="rough")
    p2 = TOUCH.replace(torque_norm=2.0)
    assert starting_residuals(p2, [rough, exact]) == [math.inf, math.inf]
    assert [c.source for c in cone_routes.ranked_by_starting_residual(p2, [rough, exact])] == ["rough", "exact"]


def test_the_learned_cone_route_tries_the_lowest_starting_residual_first(touch_answer, monkeypatch):
    exact = _answer_guess(touch_answer, source="exact")
    rough = rough_answer_guess(touch_answer, 20.0, 0.05, 0.05, 1.5, seed=2, source="rough")
    g = Guess(rough.costate0, rough.tf, rough.switch_times, rough.u_first, source="rough", touches=rough.touches,
              candidates=[lambda: exact])
    tried = []
    real = ct.solve_touch_guess
    monkeypatch.setattr(ct, "solve_touch_guess", lambda p, c, **k: tried.append(c.source) or real(p, c, **k))
    out = cone_routes.solve_learned_cones(TOUCH, g, {}, 1.0, rank=True)
    assert out.success and tried == ["exact"] and out.n_candidates == 1
    # a model that does not opt in (RANKS_CANDIDATES) keeps its order, and its deferred
    # candidates are made only when reached
    tried.clear()
    made = []
    g2 = Guess(rough.costate0, rough.tf, rough.switch_times, rough.u_first, source="rough", touches=rough.touches,
               candidates=[lambda: made.append(1) or exact])
    cone_routes.solve_learned_cones(TOUCH, g2, {}, 1.0)
    assert tried[0] == "rough"
    # nor with the ranking switched off
    monkeypatch.setattr(cone_routes, "CONE_RANK_CANDIDATES", False)
    tried.clear()
    cone_routes.solve_learned_cones(TOUCH, g, {}, 1.0, rank=True)
    assert tried[0] == "rough"


def test_the_ranking_keeps_to_its_share_of_the_budget(touch_answer):
    exact = _answer_guess(touch_answer, source="exact")
    rough = rough_answer_guess(touch_answer, 20.0, 0.05, 0.05, 1.5, seed=2, source="rough")
    assert starting_residuals(TOUCH, [rough, exact], deadline=0.0) == [math.inf, math.inf]
    # past its deadline the candidates keep the model's order
    assert [c.source for c in cone_routes.ranked_by_starting_residual(TOUCH, [rough, exact], deadline=0.0)] == \
        ["rough", "exact"]


def test_the_shipped_cone_warm_start_opts_in_to_the_ranking():
    from solvers.warmstart import default_cone_model
    assert default_cone_model().RANKS_CANDIDATES is True


def test_an_answer_already_converged_skips_the_event_driven_newton(touch_answer, monkeypatch):
    """The switch-time answer whose event-driven residual is below the Newton's tolerance is the
    answer (no Newton call); where it is not, the Newton runs from it."""
    calls = []
    real = ct.newton
    monkeypatch.setattr(ct, "newton", lambda tp, x, **k: calls.append(1) or real(tp, x, **k))
    g = rough_answer_guess(touch_answer, 10.0, 0.02, 0.03, 1.3, seed=3)
    a = solve_touch_guess(TOUCH, g, smoothing=False)
    assert a.success and calls == []
    monkeypatch.setattr(ct, "NEWTON_TOL", 0.0)
    b = solve_touch_guess(TOUCH, g, smoothing=False)
    assert b.success and len(calls) >= 1
    assert b.tf == pytest.approx(a.tf, rel=1e-12)


def test_a_verified_touch_answer_is_the_same_with_its_pieces_reused(touch_answer):
    """``solve_touch_guess`` hands ``_verify`` the event-driven pieces it already has: the
    verification is the one made from scratch."""
    g = _answer_guess(touch_answer)
    bvp, tp, z, st, T0, tc, nu = _newton_parts(g)
    x = np.concatenate([z, [T0], tc, nu])
    R, _, pieces = tp.segments(x, want_jac=False)
    a = ct._verify(tp, x, TOUCH, "answer", None, ct.DEFAULT_TOLS)
    b = ct._verify(tp, x, TOUCH, "answer", None, ct.DEFAULT_TOLS, pieces)
    assert a.success and b.success
    assert a.tf == b.tf and np.array_equal(a.costate0, b.costate0)
    assert {k: v["value"] for k, v in a.verification.items() if isinstance(v, dict) and "value" in v} == \
        {k: v["value"] for k, v in b.verification.items() if isinstance(v, dict) and "value" in v}
