"""Random rest-to-rest slews: the per-axis optimum is never slower than the eigenaxis slew,
and for a symmetric body the 2-norm optimum is the eigenaxis slew."""
import math

import numpy as np
import pytest

import solvers
from slew_env import SlewProblem
from slew_env.core import qfrom_uniform


def _random_problems(n, seed):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        J = [1.0, 1.0, 1.0] if k % 2 == 0 else rng.uniform(0.3, 1.0, 3)
        out.append(SlewProblem(J, q0=qfrom_uniform(*rng.random(3)), qf=qfrom_uniform(*rng.random(3))))
    return out


def _check_per_axis(problems, method="indirect"):
    failures = []
    for prob in problems:
        sol = solvers.solve(prob, method=method)
        eig = solvers.eigenaxis_slew(prob)
        assert sol.baseline_tf == pytest.approx(eig.tf, rel=2e-3)
        if not sol.success:
            # an extremal slower than the eigenaxis slew is never reported as a success
            failures.append(sol.message)
            continue
        assert sol.tf <= eig.tf * (1 + 1e-9), (prob, sol.tf, eig.tf)
        assert all(c["passed"] for c in sol.verification.values())
        if sol.method != "collocation":   # exact extremal; collocation has its own tolerances
            assert sol.verification["boundary_attitude_error"]["value"] < 1e-8
    return failures


def test_per_axis_never_slower_than_eigenaxis_small_sample():
    failures = _check_per_axis(_random_problems(8, seed=11))
    # about a third of these slews have a (near-)singular axis, which the bang-bang
    # solvers report as not converged (README, "Known limitations"); the rate is
    # measured by benchmarks/bench_solver.py
    assert len(failures) <= 5, failures
    for msg in failures:   # every failure says why
        assert "singular" in msg or "converged" in msg or "slower than the eigenaxis" in msg, msg


def test_auto_route_solves_the_small_sample():
    # collocation then exact refinement: everything converges, exact where the optimum is
    # bang-bang, the verified collocation answer where it is not (a singular arc)
    problems = _random_problems(8, seed=11)
    failures = _check_per_axis(problems, method="auto")
    assert failures == []


@pytest.mark.slow
def test_per_axis_never_slower_than_eigenaxis_200():
    failures = _check_per_axis(_random_problems(200, seed=2024))
    # every converged answer beats the eigenaxis slew (checked inside); the convergence
    # floor guards against regressions of the classical route (measured ~65-70 %)
    assert len(failures) <= 70, failures


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_symmetric_two_norm_equals_eigenaxis(seed):
    rng = np.random.default_rng(seed)
    j = rng.uniform(0.5, 3.0)
    prob = SlewProblem([j, j, j], torque_max=rng.uniform(0.2, 2.0), torque_norm=2,
                       q0=qfrom_uniform(*rng.random(3)), qf=qfrom_uniform(*rng.random(3)))
    sol = solvers.solve(prob)
    assert sol.success, sol.message
    eig = solvers.eigenaxis_slew(prob)
    assert sol.tf == pytest.approx(eig.tf, rel=1e-8)
    assert sol.tf == pytest.approx(2 * math.sqrt(prob.slew_angle * j / prob.torque_max[0]), rel=1e-8)
