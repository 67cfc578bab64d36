"""Collocation's deferred tf_tol: with cones, ``auto`` skips the N / 2 comparison solve unless it
returns the collocation answer (or needs its tolerance); the value, once settled, is the one an
undeferred call reports."""
import json
import math

import pytest

from slew_env import SlewProblem
from solvers import solve, cone_routes, collocation_nlp
from solvers.cone_routes import rel_tol
from solvers.collocation import settle_tf_tol, solve_collocation
from reference_cases import TOUCH

# pointing-cones family, seed [0, 16]: two inactive cones, a singular arc in collocation's
# control, so ``auto`` returns the collocation answer
SINGULAR = SlewProblem.from_dict(json.loads("""{"inertia": [0.8674252065599288, 0.7431124169250392, 0.8321639004975081],
 "q0": [0.4008220135130077, 0.23868787518038095, 0.10598095647930232, 0.8781445488010419],
 "sensor_target": [0.7253570826714324, -0.6052547065847356, -0.3279082840908636],
 "cones": [{"axis": [0.19667610621452922, 0.9523108055156937, 0.23328660257790623], "half_angle": 0.4899607073654043},
           {"axis": [0.5155956269675454, 0.8545206496082496, 0.06289363119616362], "half_angle": 0.46825801621524976}]}"""))


@pytest.fixture(scope="module")
def touch_pair():
    return solve_collocation(TOUCH), solve_collocation(TOUCH, defer_tf_tol=True)


def test_deferred_answer_is_the_same_without_its_tolerance(touch_pair):
    now, later = touch_pair
    assert now.success and later.success
    assert later.tf == now.tf
    assert math.isfinite(now.tf_tol) and 0 < now.tf_tol < 1e-3 * now.tf
    assert math.isnan(later.tf_tol)
    # the N / 2 solve was skipped: less work
    assert later.nit < now.nit


def test_settled_tolerance_equals_the_undeferred_one(touch_pair):
    now, later = touch_pair
    nit = later.nit
    settle_tf_tol(later, 5.0)
    assert later.tf_tol == pytest.approx(now.tf_tol, rel=1e-9)
    assert later.nit == now.nit and later.nit > nit
    assert later._tf_tol_pending is None
    settle_tf_tol(later, 5.0)          # settled once: a second call changes nothing
    assert later.nit == now.nit


def test_no_time_left_gives_the_replay_estimate():
    sol = solve_collocation(TOUCH, defer_tf_tol=True)
    nit = sol.nit
    settle_tf_tol(sol, 0.0)
    assert math.isfinite(sol.tf_tol) and sol.tf_tol > 0
    assert sol.nit == nit
    # and says that it is that estimate, which may understate the discretisation error
    assert "boundary-miss estimate" in sol.message


def test_a_settled_tolerance_says_nothing_of_an_estimate(touch_pair):
    _, later = touch_pair
    settle_tf_tol(later, 5.0)
    assert "boundary-miss estimate" not in later.message


def test_without_cones_nothing_is_deferred():
    free = solve_collocation(TOUCH.replace(cones=[]), defer_tf_tol=True)
    assert free.success and math.isfinite(free.tf_tol) and free._tf_tol_pending is None


def test_auto_settles_the_collocation_answer_it_returns(monkeypatch):
    # by default a bang-bang switch-time answer replaces this collocation answer, compared
    # with its settled tf_tol ...
    sol = solve(SINGULAR, time_budget=120.0)     # (a fresh install compiles kernels in its first solves)
    assert sol.success and not sol.exact and sol.method == "switch-time"
    assert "against collocation's" in sol.message and "± nan" not in sol.message
    # ... and where there is none, the collocation answer itself is settled
    monkeypatch.setattr(cone_routes, "bang_bang_cones", lambda *a, **k: None)
    sol = solve(SINGULAR)
    assert sol.success and not sol.exact and sol.method == "collocation"
    assert sol._tf_tol_pending is None
    assert math.isfinite(sol.tf_tol) and 1e-6 * sol.tf < sol.tf_tol < 1e-3 * sol.tf


def test_auto_touch_extremal_unchanged():
    sol = solve(TOUCH)
    assert sol.success and sol.exact and "touch-point junctions" in sol.route
    assert sol._tf_tol_pending is None


def test_relative_tolerance_floor():
    now = type("A", (), {"tf": 2.0, "tf_tol": 1e-2})()
    assert rel_tol(now) == pytest.approx(5e-3)
    now.tf_tol = 1e-6
    assert rel_tol(now) == 1e-3
    now.tf_tol = math.nan
    assert rel_tol(now) == 1e-3


def test_a_comparison_that_gives_nothing_in_time_is_said_too():
    """The N / 2 comparison returns at once with nothing (here: its NLP is not built and the budget
    cannot pay for building it): the tolerance is the replay's estimate, and the message says so,
    although the budget had not run out."""
    sol = solve_collocation(TOUCH, defer_tf_tol=True)
    for key in [k for k in collocation_nlp._CACHE if k[0] == 40 and k[2] == len(TOUCH.cones)]:
        del collocation_nlp._CACHE[key]
    settle_tf_tol(sol, 0.05)
    assert math.isfinite(sol.tf_tol) and "boundary-miss estimate" in sol.message
