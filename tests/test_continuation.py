"""Homotopy paths (smoothing and norm continuation): the time budget inside a path, and the
stall criterion of the smoothing path's Newton solves."""
import math
import time

import numpy as np
import pytest

import solvers.shooting as shooting
from slew_env import SlewProblem
from slew_env.core import qfrom_uniform
from solvers.attitude_bvp import AttitudeBVP
from solvers.guesses import eigenaxis_guess
from solvers.homotopy import continue_path, set_pnorm, set_tanh
from solvers.indirect import SMOOTHING_STALL, per_axis_from_guess, pnorm_from_guess


def _bvp(p_norm=math.inf, seed=3):
    rng = np.random.default_rng(seed)
    prob = SlewProblem(rng.uniform(0.3, 1.0, 3), torque_norm=p_norm, q0=qfrom_uniform(*rng.random(3)),
                       qf=qfrom_uniform(*rng.random(3)))
    bvp = AttitudeBVP(prob)
    z, T = eigenaxis_guess(bvp).to_nondim(bvp)
    return bvp, z, T


def test_path_past_its_deadline_stops_at_once():
    bvp, z, T = _bvp()
    full = continue_path(bvp, z, T, 0.3, 1e-3, set_param=set_tanh)
    assert full.success and len(full.points) > 2 and full.nit > 0
    # the deadline is checked in the Newton iterations too: not even the path's start is solved
    cut = continue_path(bvp, z, T, 0.3, 1e-3, set_param=set_tanh, deadline=time.perf_counter() - 1.0)
    assert not cut.success and "time budget ran out" in cut.message
    assert cut.points == [] and cut.nit == 0 and cut.nfev == 1


def test_norm_continuation_keeps_the_deadline():
    bvp, z, T = _bvp(p_norm=1.05)
    late = pnorm_from_guess(bvp, z, T, 1.05, deadline=time.perf_counter() - 1.0)
    free = pnorm_from_guess(bvp, z, T, 1.05)
    # from the eigenaxis guess the direct shooting fails at p = 1.05: the continuation decides
    assert free.route == "norm continuation from p=2" and free.success
    assert not late.success and late.nfev < free.nfev


def test_smoothing_path_solves_are_stall_limited(monkeypatch):
    """Every Newton solve of the per-axis smoothing path carries the stall criterion, and the
    path still reaches the extremal."""
    seen = []
    real = shooting.newton_shoot

    def spy(*a, **k):
        seen.append(k.get("stall"))
        return real(*a, **k)

    import solvers.homotopy as homotopy
    monkeypatch.setattr(homotopy, "newton_shoot", spy)
    bvp, z, T = _bvp()
    a = per_axis_from_guess(bvp, z, T)
    assert a.success
    assert seen and all(s == SMOOTHING_STALL for s in seen)
    # the norm continuation does not use it
    seen.clear()
    bvp2, z2, T2 = _bvp(p_norm=1.5)
    bvp2.set_mode("pnorm", p=1.5)
    continue_path(bvp2, z2, T2, 2.0, 1.5, set_param=set_pnorm, factor=1.5)
    assert seen and all(s is None for s in seen)


@pytest.mark.parametrize("bad", [(0, 0.5, 1e-5), (3, 0.0, 1e-5), (3, 1.5, 1e-5), (3, 0.5, -1.0), (3, 0.5),
                                 (2.5, 0.5, 1e-5), (3, float("nan"), 1e-5)])
def test_bad_stall_criterion_is_a_clear_error(bad):
    bvp, z, T = _bvp()
    with pytest.raises(ValueError, match="stall"):
        shooting.newton_shoot(bvp, z, T, stall=bad)


def test_newton_and_switch_time_solves_stop_at_their_deadline():
    from solvers.indirect import solve_structure
    from solvers.switch_time import Structure
    bvp, z, T = _bvp()
    bvp.set_mode("tanh", eps=0.3)
    late = shooting.newton_shoot(bvp, z, T, max_step=0.5, deadline=time.perf_counter() - 1.0)
    assert not late.success and late.status == shooting.STATUS_DEADLINE and late.nit == 0
    assert "time budget" in late.message
    assert shooting.newton_shoot(bvp, z, T, max_step=0.5).nit > 0
    st = Structure(np.ones(3), np.arange(3), np.full(3, 0.5 * T))
    cut = solve_structure(bvp, z, T, st, deadline=time.perf_counter() - 1.0)
    assert not cut.success and "time budget ran out" in cut.message and cut.nit == 0
    assert solve_structure(bvp, z, T, st).nit > 0
