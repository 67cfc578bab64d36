"""Exact extremals that touch a keep-out cone at an isolated instant (solvers.cone_touch):
the junction's Jacobian, and a touch problem solved exactly and replayed from its switch times."""
import math

import numpy as np
import pytest

from slew_env.core.quaternion import qrotate
from solvers import solve
from solvers.clearance import certified_min_margin, margins
from solvers.cone_touch import TouchBVP, TouchProblem, _structured_residual, find_touches, solve_touch_guess
from solvers.guesses import Guess
from solvers.switch_time import Structure
from solvers.core.cone_penalty import cone_matrix
from solvers.verify import replay_path

from reference_cases import TOUCH


def test_touch_problem_jacobian_matches_finite_differences():
    bvp = TouchBVP(TOUCH)
    bvp.sensor = np.array([1.0, 0.0, 0.0])
    tp = TouchProblem(bvp, [0])
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(size=6), [2.0, 0.9, 0.4]])
    x[:6] /= np.linalg.norm(x[:6])
    R, Jm, _ = tp.segments(x)
    for j in range(x.shape[0]):
        e = np.zeros_like(x)
        e[j] = 1e-7
        fd = (tp.segments(x + e, False)[0] - tp.segments(x - e, False)[0]) / 2e-7
        assert np.allclose(Jm[:, j], fd, atol=1e-6), j


@pytest.fixture(scope="module")
def touch_solutions():
    col = solve(TOUCH, method="collocation")
    return col, solve(TOUCH, method="indirect"), solve(TOUCH)


def test_collocation_answer_touches_once(touch_solutions):
    col, sol, _ = touch_solutions
    touches = find_touches(TOUCH, col)
    assert [c for c, _ in touches] == [0]
    # at the exact extremal's touch instant, to within about an interval of the mesh
    t_exact = sol.verification["touch_multipliers"]["times"][0]
    assert abs(col.t[touches[0][1]] - t_exact) < 1.5 * col.tf / 80


def test_touch_extremal_is_exact_and_not_slower_than_collocation(touch_solutions):
    col, sol, _ = touch_solutions
    assert sol.success and sol.exact and "touch-point junctions (1)" in sol.route, sol.message
    assert sol.tf <= col.tf * (1 + 1e-9)
    assert sol.tf == pytest.approx(col.tf, rel=1e-3)
    v = sol.verification
    for k in ("boundary_attitude_error", "roll_transversality", "switching_law", "replay"):
        assert v[k]["passed"] and v[k]["value"] <= 1e-8, k
    assert v["hamiltonian_drift"]["value"] <= 1e-9   # H is continuous across the costate jump
    assert v["touch_multipliers"]["value"] > 0.0


def test_multiple_shooting_with_cones_says_it_shoots_singly(touch_solutions):
    _, single, _ = touch_solutions
    ms = solve(TOUCH, method="multiple-shooting", segments=6)
    assert ms.success and ms.method == "indirect"
    assert ms.route.startswith("multiple-shooting asked; with cones the route shoots singly → ")
    assert ms.tf == pytest.approx(single.tf, rel=1e-9)


def test_touch_extremal_replays_from_its_switch_times(touch_solutions):
    """Independent of the costates: the switch times alone (fixed-step RK4) reach the target,
    touch the cone (margin ~0 at one instant) and never enter it."""
    _, sol, _ = touch_solutions
    t, x = replay_path(TOUCH.inertia, TOUCH.torque_max, TOUCH.q0, TOUCH.omega0, sol.switch_times, sol.u_first,
                       sol.tf, steps_per_tf=20000)
    s_end = qrotate(x[-1, 0:4], TOUCH.sensor_axis)
    assert math.acos(min(1.0, float(s_end @ TOUCH.sensor_target))) < 1e-8
    assert np.linalg.norm(x[-1, 4:7]) < 1e-8
    sample, certified = certified_min_margin(TOUCH, t, x[:, 0:4], x[:, 4:7])
    assert certified >= -1e-6
    assert 0.0 <= sample + 1e-9 and sample < 1e-6          # it does touch
    interior = margins(TOUCH, x[:, 0:4])
    k = int(np.argmin(interior))
    assert 0.2 * len(t) < k < 0.8 * len(t)                  # at an interior instant


def test_costate_jumps_along_the_constraint_gradient(touch_solutions):
    _, sol, _ = touch_solutions
    tc = sol.verification["touch_multipliers"]["times"][0]
    k = int(np.searchsorted(sol.t, tc))
    # the dense record holds both sides of the touch instant
    before = [i for i in range(len(sol.t)) if abs(sol.t[i] - tc) < 1e-12]
    assert len(before) >= 2
    i0, i1 = before[0], before[-1]
    jump = sol.costate[i1, 0:4] - sol.costate[i0, 0:4]
    g = 2.0 * cone_matrix(TOUCH.cones[0].axis, TOUCH.sensor_axis) @ sol.q[i0]
    cosine = float(jump @ g) / (np.linalg.norm(jump) * np.linalg.norm(g))
    assert cosine == pytest.approx(-1.0, abs=1e-9)          # λq⁺ - λq⁻ = -ν ∂h/∂q, ν > 0
    assert np.allclose(sol.costate[i1, 4:7], sol.costate[i0, 4:7])   # λω is continuous
    # the reported jump is the one in the dense costates (what a costate replay needs)
    reported = np.asarray(sol.verification["touch_multipliers"]["costate_jumps"][0])
    assert np.allclose(reported, jump, atol=1e-9 * np.linalg.norm(jump))
    assert k > 0


def test_auto_returns_the_touch_extremal(touch_solutions):
    _, sol, auto = touch_solutions
    assert auto.success and auto.exact and "touch-point" in auto.route
    assert auto.tf == pytest.approx(sol.tf, rel=1e-10)


# ------------------------------------------------------------------ switch-time formulation
def _answer_guess(sol, **change):
    """The exact answer read back as a ``Guess`` with its structure and touches."""
    tm = sol.verification["touch_multipliers"]
    kw = dict(costate0=sol.costate0, tf=sol.tf, switch_times=sol.switch_times, u_first=sol.u_first,
              touches=list(zip(tm["cones"], tm["times"], tm["multipliers"])), source="answer")
    kw.update(change)
    return Guess(**kw)


def rough_answer_guess(sol, deg, tf_rel, t_rel, nu_factor, seed, source="answer"):
    """The exact answer made rough: costates ``deg`` degrees off, final time ``x(1 + tf_rel)``,
    switch instants randomly within ``±t_rel``, touch instants ``x(1 - t_rel)``, multipliers
    ``x nu_factor``."""
    rng = np.random.default_rng(seed)
    c = np.asarray(sol.costate0)
    v = rng.normal(size=7)
    v -= (v @ c) / (c @ c) * c
    v *= np.linalg.norm(c) * math.tan(math.radians(deg)) / np.linalg.norm(v)
    tm = sol.verification["touch_multipliers"]
    return _answer_guess(sol, costate0=c + v, tf=sol.tf * (1 + tf_rel), source=source,
                         switch_times=[np.asarray(s) * (1 + t_rel * rng.uniform(-1, 1, len(s))) for s in sol.switch_times],
                         touches=[(c_, t * (1 - t_rel), m * nu_factor)
                                  for c_, t, m in zip(tm["cones"], tm["times"], tm["multipliers"])])


def test_structured_touch_jacobian_matches_finite_differences(touch_solutions):
    _, sol, _ = touch_solutions
    bvp = TouchBVP(TOUCH)
    bvp.sensor = np.array([1.0, 0.0, 0.0])
    tp = TouchProblem(bvp, [0])
    tau = bvp.tau
    times = np.concatenate([np.asarray(s) / tau for s in sol.switch_times])
    axes = np.concatenate([np.full(len(s), i) for i, s in enumerate(sol.switch_times)]).astype(np.int64)
    st = Structure(np.asarray(sol.u_first, float), axes, times)
    n = st.n
    z, T = Guess(sol.costate0, sol.tf).to_nondim(bvp)
    rng = np.random.default_rng(1)
    x = np.concatenate([z, times, [T], [sol.verification["touch_multipliers"]["times"][0] / tau], [0.5]])
    x = x + 1e-3 * rng.normal(size=x.shape)

    def f(x, jac=True):
        return _structured_residual(tp, x[:6], x[6:6 + n], x[6 + n], x[7 + n:8 + n], x[8 + n:], st, jac)

    R, Jm = f(x)
    assert R.shape == Jm.shape[:1] == (1 + n + 2 + 6,) and Jm.shape[1] == x.shape[0]   # square
    for j in range(x.shape[0]):
        e = np.zeros_like(x)
        e[j] = 1e-7
        fd = (f(x + e, False)[0] - f(x - e, False)[0]) / 2e-7
        assert np.allclose(Jm[:, j], fd, atol=2e-6), j


def test_answer_read_back_as_a_guess_converges_at_once(touch_solutions):
    """The units of a guess's touches (instants in problem time, multipliers in the scale of
    ``costate0``) are those the solution reports: its own answer is a fixed point."""
    _, sol, _ = touch_solutions
    again = solve_touch_guess(TOUCH, _answer_guess(sol), smoothing=False)
    assert again.success, again.message
    assert again.nit <= 2
    assert again.tf == pytest.approx(sol.tf, rel=1e-10)


def test_structured_newton_converges_from_a_rough_guess(touch_solutions):
    """Costates 10° off, final time +2 %, switch and touch instants ±3 %, multiplier x1.3:
    the switch-time formulation (structure fixed) still finds the exact extremal."""
    _, sol, _ = touch_solutions
    tm = sol.verification["touch_multipliers"]
    g = rough_answer_guess(sol, 10.0, 0.02, 0.03, 1.3, seed=3)
    out = solve_touch_guess(TOUCH, g, smoothing=False)
    assert out.success, out.message
    assert out.tf == pytest.approx(sol.tf, rel=1e-9)
    assert out.verification["touch_multipliers"]["multipliers"][0] == pytest.approx(tm["multipliers"][0], rel=1e-6)


def test_guess_touches_are_validated(touch_solutions):
    _, sol, _ = touch_solutions
    with pytest.raises(ValueError, match=r"guess.touches\[0\]: needs cone index"):
        _answer_guess(sol, touches=[(0, sol.tf * 1.5, 1.0)])
    with pytest.raises(ValueError, match=r"guess.touches\[0\]: needs cone index"):
        _answer_guess(sol, touches=[(0, 0.5, -1.0)])
    with pytest.raises(ValueError, match=r"guess.touches\[0\]: expected"):
        _answer_guess(sol, touches=[(0, 0.5)])
    with pytest.raises(ValueError, match=r"guess.touches\[0\]: cone index 5, but the problem has 3"):
        solve_touch_guess(TOUCH, _answer_guess(sol, touches=[(5, 0.5, 1.0)]))


def test_structure_read_back_from_the_switching_functions(touch_solutions):
    """The exact answer's structure is consistent with its own switching functions (no repair),
    and the event-driven flow reproduces it; with a switch dropped from the structure, the read
    back puts it where the switching function still crosses zero."""
    from solvers.cone_touch import propagated_structure, repaired_structure
    _, sol, _ = touch_solutions
    bvp = TouchBVP(TOUCH)
    bvp.sensor = np.array([1.0, 0.0, 0.0])
    tp = TouchProblem(bvp, [0])
    tau = bvp.tau
    tm = sol.verification["touch_multipliers"]
    # the multiplier in the normalisation of z, as solve_touch_guess converts it
    z, T, nz = Guess(sol.costate0, sol.tf).to_nondim(bvp, with_norm=True)
    x = np.concatenate([z, [T], [tm["times"][0] / tau], [tm["multipliers"][0] / (tau * nz)]])
    times = np.concatenate([np.asarray(s) / tau for s in sol.switch_times])
    axes = np.concatenate([np.full(len(s), i) for i, s in enumerate(sol.switch_times)]).astype(np.int64)
    order = np.argsort(times)
    st = Structure(np.asarray(sol.u_first, float), axes[order], times[order])
    assert repaired_structure(tp, x, st.times, st) is None
    prop = propagated_structure(tp, x)
    assert np.array_equal(prop.axes, st.axes) and np.allclose(prop.times, st.times, atol=1e-9)
    # drop the first switch: up to it the path is unchanged, so S still crosses zero there
    dropped = Structure(st.signs0.copy(), st.axes[1:], st.times[1:])
    fixed = repaired_structure(tp, x, dropped.times, dropped)
    assert fixed is not None
    on_axis = fixed.times[fixed.axes == st.axes[0]]
    assert np.min(np.abs(on_axis - st.times[0])) < 1e-3 * T


def test_without_smoothing_the_raw_guess_gets_no_event_driven_newton(touch_solutions, monkeypatch):
    """A learned guess (``smoothing=False``) whose switch-time solves all fail: no event-driven
    Newton from the raw guess (it converged 0 times in 166 on the learned cone route), and the
    failure says what was tried; with smoothing the raw guess still gets it."""
    import solvers.cone_touch as ct
    _, sol, _ = touch_solutions
    calls = []
    monkeypatch.setattr(ct, "_switch_time_solve", lambda tp, x0, st, deadline=math.inf, **k: (None, 3, 7))
    real_newton = ct.newton
    monkeypatch.setattr(ct, "newton", lambda tp, x, **k: calls.append(x) or real_newton(tp, x, **k))
    out = solve_touch_guess(TOUCH, _answer_guess(sol), smoothing=False)
    assert not out.success and calls == []
    # the guess's own structure (its costates propagate to the same one: tried once)
    assert "converged on none of the guess's 1 structure(s)" in out.message, out.message
    solve_touch_guess(TOUCH, _answer_guess(sol), smoothing=True, time_budget=0.5)
    assert len(calls) >= 1
