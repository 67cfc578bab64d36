"""The costates of a bang-bang path fitted on the path alone (``solvers.touch_costates``): on an
exact extremal they are its own, touch multipliers included; they seed the exact solver at a
switch-time answer."""
import json
import os

import numpy as np
import pytest

from slew_env import SlewProblem
from solvers import solve
from solvers.touch_costates import touch_costates, touch_guess

from reference_cases import TOUCH

EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "examples")


def test_the_fit_on_a_touch_extremal_gives_back_its_costates_and_multiplier():
    """The reference touch case: ``auto``'s exact extremal touches cone 0 once. Fitted from its
    switch instants, ``tf`` and touch instant alone, the costates (gauge and scale of
    ``costate0``) and the multiplier are the extremal's own."""
    sol = solve(TOUCH)
    assert sol.success and sol.exact
    tm = sol.verification["touch_multipliers"]
    touches = [(c, t, 0.0) for c, t in zip(tm["cones"], tm["times"])]
    costate0, nu, info = touch_costates(TOUCH, sol.switch_times, sol.u_first, sol.tf, touches)
    np.testing.assert_allclose(costate0, sol.costate0, atol=1e-9)
    np.testing.assert_allclose(nu, tm["multipliers"], rtol=1e-9)
    assert info["unknowns"] == 7 + len(touches) and info["residual"] < 1e-12 and info["nfev"] > 0


def test_the_fit_on_a_full_attitude_extremal_gives_back_its_costates():
    """Without cones or touches (R3, per-axis bound: the seed report's 2.35402 s slew) the
    fit is the bang-bang extremal's KKT costates: its ``costate0``."""
    prob = SlewProblem.from_dict(json.load(open(os.path.join(EXAMPLES, "r3_seed_report_per_axis.json"))))
    sol = solve(prob)
    assert sol.success and sol.exact and sol.tf == pytest.approx(2.35402, rel=1e-5)
    costate0, nu, info = touch_costates(prob, sol.switch_times, sol.u_first, sol.tf, [])
    np.testing.assert_allclose(costate0, sol.costate0, atol=1e-9)
    assert nu.shape == (0,) and info["rows"] == info["unknowns"] == 7      # (5 switches)


def test_too_few_switches_fix_no_costates_and_a_negative_multiplier_gives_no_guess(monkeypatch):
    from solvers import touch_costates as tc
    sol = solve(TOUCH)
    tm = sol.verification["touch_multipliers"]
    touches = [(c, t, 0.0) for c, t in zip(tm["cones"], tm["times"])]
    # one switch an axis and the touch: 3 + 2 (+1 roll) conditions for 8 unknowns
    one = [np.array([0.5 * sol.tf]) for _ in range(3)]
    c0, nu, info = touch_costates(TOUCH, one, sol.u_first, sol.tf, touches)
    assert c0 is None and nu is None and "do not fix the costates" in info["reason"] and info["nfev"] > 0
    g, info = touch_guess(TOUCH, sol, touches)
    assert g.touches[0][0] == 0 and g.touches[0][2] == pytest.approx(tm["multipliers"][0], rel=1e-9)
    assert g.source == "the switch-time answer's own fitted" and info["residual"] < 1e-12
    # a fit that asks for a pull into the cone (a negative multiplier) is no touch extremal's
    real = tc.touch_costates
    monkeypatch.setattr(tc, "touch_costates", lambda *a: (lambda c0, nu, i: (c0, -nu, i))(*real(*a)))
    g, info = touch_guess(TOUCH, sol, touches)
    assert g is None and info["negative_multiplier"] and info["reason"] == "a fitted touch multiplier is negative"


def test_a_switch_at_the_start_is_the_first_arcs_control():
    """A switch-time answer may keep an instant at 0 (its instants are held in [0, tf]): the
    propagation flips that axis there, and so does the fit's H(0) row. The touch extremal's path
    written with a switch at 0 on axis 0 and the opposite first sign is the same path, and its
    fitted costates are the extremal's (a review found them 4.8e-3 off)."""
    sol = solve(TOUCH)
    tm = sol.verification["touch_multipliers"]
    touches = [(c, t, 0.0) for c, t in zip(tm["cones"], tm["times"])]
    sw = [np.asarray(x, float) for x in sol.switch_times]
    sw[0] = np.concatenate([[0.0], sw[0]])
    uf = np.array(sol.u_first, float)
    uf[0] = -uf[0]
    costate0, nu, info = touch_costates(TOUCH, sw, uf, sol.tf, touches)
    np.testing.assert_allclose(costate0, sol.costate0, atol=1e-9)
    np.testing.assert_allclose(nu, tm["multipliers"], rtol=1e-9)


def test_auto_turns_a_touching_switch_time_answer_into_its_extremal(monkeypatch):
    """``bench_cones``' seed 0 problem 11: collocation's touch refinement fails and the
    switch-time answer (1.37338435) touches cone 0 once; from the costates fitted on its path the
    touch-point solver certifies the extremal at 1.373383674 (it had been the answer's `exact`
    false before)."""
    from slew_env import TaskDistribution
    from solvers import cone_routes
    p = TaskDistribution.family("pointing-cones").sample(np.random.default_rng([0, 11]))
    sol = solve(p)
    assert sol.success and sol.exact and sol.method == "indirect"
    assert sol.tf == pytest.approx(1.373383673811002, rel=1e-9)
    assert "bang-bang switch-time optimisation" in sol.route and "own fitted costates" in sol.route
    tm = sol.verification["touch_multipliers"]
    assert tm["cones"] == [0] and tm["multipliers"][0] > 0.0
    # without the fitted costates it stays the switch-time answer
    monkeypatch.setattr(cone_routes, "exact_from_own_costates", lambda *a, **k: (None, None))
    bang = solve(p)
    assert bang.success and not bang.exact and bang.method == "switch-time" and bang.tf > sol.tf
