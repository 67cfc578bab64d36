"""auto on a p-norm bound with p ≤ 2: the indirect multi-start first, collocation after it only
if it fails; p > 2, pointing targets, rate limits and cones keep collocation first."""
import numpy as np
import pytest

import solvers.api as api
from slew_env import SlewProblem
from slew_env.core import qfrom_uniform
from solvers import solve
from solvers.collocation import solve_collocation


def _problem(p_norm, seed=3, **kw):
    rng = np.random.default_rng(seed)
    return SlewProblem(rng.uniform(0.3, 1.0, 3), torque_norm=p_norm, q0=qfrom_uniform(*rng.random(3)),
                       qf=qfrom_uniform(*rng.random(3)), **kw)


@pytest.mark.parametrize("p_norm", [2.0, 1.5])
def test_auto_answers_a_p_norm_slew_by_the_indirect_route_first(p_norm):
    p = _problem(p_norm)
    s = solve(p)
    assert s.success and s.exact and s.method == "indirect"
    assert s.route.startswith("auto: indirect first (p-norm bound, p ≤ 2)") and "collocation" not in s.route
    col = solve_collocation(p)
    assert col.success
    # the extremal is collocation's optimum, exactly: no slower than its answer beyond its accuracy
    assert s.tf <= col.tf + max(col.tf_tol, 1e-6 * col.tf) and s.tf == pytest.approx(col.tf, rel=2e-3)
    assert s.tf < s.baseline_tf and s.verification["replay"]["passed"]


def test_other_problems_keep_collocation_first():
    assert api._pnorm_indirect_first(_problem(2.0))
    assert not api._pnorm_indirect_first(_problem(3.0))
    assert not api._pnorm_indirect_first(_problem(np.inf))
    assert not api._pnorm_indirect_first(_problem(2.0, rate_max=[0.5, 0.5, 0.5]))
    assert not api._pnorm_indirect_first(_problem(2.0).replace(omega0=[0.01, 0.0, 0.0]))
    # outside the measured inertia ratios (a review found 17.6 % and 66 % slower local optima at
    # ratios down to 0.05)
    assert not api._pnorm_indirect_first(_problem(2.0).replace(inertia=[0.1, 0.6, 1.0]))
    assert api._pnorm_indirect_first(_problem(2.0).replace(inertia=[0.3, 0.6, 1.0]))
    pointing = SlewProblem([1.0, 0.8, 0.6], torque_norm=2.0, q0=[1.0, 0.0, 0.0, 0.0], qf=None,
                           sensor_axis=[0.0, 0.0, 1.0], sensor_target=[1.0, 0.0, 0.0])
    assert not api._pnorm_indirect_first(pointing)
    s = solve(_problem(3.0))
    assert s.success and "indirect first" not in s.route and "collocation" in s.route


def test_when_the_indirect_route_fails_collocation_answers_and_says_why(monkeypatch):
    p = _problem(2.0)
    real = api._solve_indirect
    calls = []

    def failing_first(prob, method, guess, *a, **kw):
        calls.append(guess)
        if len(calls) == 1:     # the indirect-first attempt: its answer taken as a failure
            out = real(prob, method, guess, *a, **kw)
            out.success, out.status, out.message = False, 1, "No candidate converged (forced by the test)."
            return out
        return real(prob, method, guess, *a, **kw)

    monkeypatch.setattr(api, "_solve_indirect", failing_first)
    s = solve(p)
    assert s.success and calls[0] is None
    assert "indirect first" in s.route and "failed" in s.route and "collocation" in s.route
    assert s.tf == pytest.approx(solve(p, method="indirect").tf, rel=1e-8)
