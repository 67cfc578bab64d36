"""The per-candidate propagation cap of the per-axis multi-start (``candidate_cap``)."""
import math

import numpy as np
import pytest

import solvers
from slew_env import SlewProblem
from slew_env.core import qfrom_uniform
from solvers.attitude_bvp import AttitudeBVP
from solvers.guesses import eigenaxis_guess
from solvers.homotopy import continue_path, set_tanh
from solvers.indirect import per_axis_from_guess


def _problem(seed=3):
    rng = np.random.default_rng(seed)
    return SlewProblem(rng.uniform(0.3, 1.0, 3), q0=qfrom_uniform(*rng.random(3)), qf=qfrom_uniform(*rng.random(3)))


def _bvp(seed=3):
    bvp = AttitudeBVP(_problem(seed))
    z, T = eigenaxis_guess(bvp).to_nondim(bvp)
    return bvp, z, T


def test_path_stops_when_its_budget_says_so():
    bvp, z, T = _bvp()
    full = continue_path(bvp, z, T, 0.3, 1e-3, set_param=set_tanh)
    assert full.success and full.nfev > 40
    seen = []

    def exhausted(nfev):
        seen.append(nfev)
        return "out of propagations" if nfev > 20 else None

    cut = continue_path(bvp, z, T, 0.3, 1e-3, set_param=set_tanh, exhausted=exhausted)
    assert not cut.success and cut.message.startswith("out of propagations (continuation at")
    # checked before each step with the path's own count so far, which only grows
    assert seen == sorted(seen) and seen[-1] > 20 and all(n <= 20 for n in seen[:-1])
    assert cut.nfev == seen[-1] < full.nfev


def test_capped_attempt_fails_with_the_cap_in_its_message():
    bvp, z, T = _bvp()
    free = per_axis_from_guess(bvp, z, T)
    assert free.success and free.nfev > 60
    capped = per_axis_from_guess(bvp, z, T, max_nfev=30)
    assert not capped.success
    assert "stopped at its cap of 30 propagations" in capped.message
    # the cap is checked between Newton solves: one solve (at most 25 iterations, each a
    # propagation, plus the line search's) may overrun it
    assert 30 < capped.nfev < 30 + 80 < free.nfev
    # an ample cap changes nothing
    same = per_axis_from_guess(bvp, z, T, max_nfev=10 * free.nfev)
    assert same.success and same.T == free.T and same.nfev == free.nfev


def _bench_problems(monkeypatch, n, seed):
    import os
    monkeypatch.syspath_prepend(os.path.join(os.path.dirname(__file__), "..", "benchmarks"))
    from bench_solver import random_problems
    return random_problems(n, seed, math.inf)


def test_default_cap_returns_the_uncapped_answer_with_fewer_propagations(monkeypatch):
    # bench_solver seed 1, problem 3: the long-way candidate's path runs ~3x longer than the
    # eigenaxis candidate's and ends in a slower extremal (2.7367 s against 1.76519 s)
    p = _bench_problems(monkeypatch, 4, 1)[3]
    capped = solvers.solve(p, method="indirect", warm_start=None)
    free = solvers.solve(p, method="indirect", warm_start=None, candidate_cap=None)
    assert capped.success and free.success
    assert capped.tf == pytest.approx(free.tf, rel=1e-9)
    assert capped.tf == pytest.approx(1.76519, abs=1e-5)
    assert capped.nfev < 0.8 * free.nfev     # 6,988 against 9,303 propagations


ALL = dict(max_candidates=16, min_candidates=16, enough=99)    # every candidate runs (templates: no path)


def test_tiny_cap_keeps_the_first_verified_answer():
    p = _problem()
    first = solvers.solve(p, method="indirect", warm_start=None, max_candidates=1)
    tiny = solvers.solve(p, method="indirect", warm_start=None, candidate_cap=[0, 0], **ALL)
    free = solvers.solve(p, method="indirect", warm_start=None, candidate_cap=None, **ALL)
    assert first.success and tiny.success and tiny.n_candidates == free.n_candidates == 16
    assert tiny.tf <= first.tf * (1 + 1e-9)
    # every later path stops at its first check: far fewer propagations than uncapped
    assert tiny.nfev < free.nfev
    assert tiny.nfev - first.nfev < 0.5 * (free.nfev - first.nfev)
    # a numpy pair is accepted too
    arr = solvers.solve(p, method="indirect", warm_start=None, candidate_cap=np.array([0.0, 0.0]), **ALL)
    assert arr.tf == tiny.tf and arr.nfev == tiny.nfev


BAD_CAPS = [0.5, (2.0,), (2.0, 200, 1), (-1.0, 100), (2.0, -1), ("a", 1), (float("nan"), 100), "25", b"25",
            {2: 0, 200: 1}, (True, 200), (2.0, None)]


@pytest.mark.parametrize("bad", BAD_CAPS)
def test_bad_candidate_cap_is_a_clear_error(bad):
    with pytest.raises(ValueError, match="candidate_cap: must be None or a pair"):
        solvers.solve(_problem(), method="indirect", warm_start=None, candidate_cap=bad)


@pytest.mark.parametrize("method", ["eigenaxis", "collocation", "auto"])
def test_bad_candidate_cap_is_caught_whatever_the_route(method):
    with pytest.raises(ValueError, match="candidate_cap"):
        solvers.solve(_problem(), method=method, candidate_cap="garbage")


def test_a_template_answer_does_not_set_the_cap(monkeypatch):
    # bench_solver seed 3, problem 34: the first verified extremal comes from a structure
    # template's switch-time Newton (11 propagations, 3.25294 s); capping the paths after it
    # at 200 propagations stopped the long-way path (661) that finds the optimum, 3.08081 s
    p = _bench_problems(monkeypatch, 35, 3)[34]
    sol = solvers.solve(p, method="indirect", warm_start=None)
    assert sol.success and sol.tf == pytest.approx(3.080808962427157, rel=1e-9)


def test_multiple_shooting_takes_the_cap_and_keeps_the_answer(monkeypatch):
    # the reference is the path's cost before the multiple-shooting polish
    p = _bench_problems(monkeypatch, 4, 1)[3]
    capped = solvers.solve(p, method="multiple-shooting", warm_start=None)
    free = solvers.solve(p, method="multiple-shooting", warm_start=None, candidate_cap=None)
    assert capped.success and free.success and capped.method == "multiple-shooting"
    assert capped.tf == pytest.approx(free.tf, rel=1e-9)
    assert capped.nfev < free.nfev
