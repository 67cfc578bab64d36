"""The p-norm extremal's independent replay (compiled Dormand–Prince 5(4)) against scipy, and
the verification check built on it."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from slew_env import SlewProblem
from slew_env.core import qfrom_uniform
from solvers import Guess, solve
from solvers.attitude_bvp import AttitudeBVP
from solvers.core import attitude_flow as af
from solvers.core.costate_replay import REPLAY_MAX_STEPS, REPLAY_OK, replay_pnorm_end
from solvers.verify import verify


def _setup(p_norm, J, seed=4):
    rng = np.random.default_rng(seed)
    prob = SlewProblem(J, torque_norm=p_norm, q0=qfrom_uniform(*rng.random(3)), qf=qfrom_uniform(*rng.random(3)))
    # a generous budget: on a cold numba cache compiling takes most of the default 20 s
    sol = solve(prob, method="indirect", warm_start=None, time_budget=120.0)
    assert sol.success
    bvp = AttitudeBVP(prob)
    bvp.set_mode("pnorm", p=p_norm)
    z, T = Guess(sol.costate0, sol.tf).to_nondim(bvp)
    return prob, sol, bvp, z, T


@pytest.mark.parametrize("p_norm, J", [(3.0, [0.5, 0.8, 1.0]), (1.5, [1.0, 0.7, 0.4])])
def test_the_replay_matches_scipy_on_a_smooth_extremal(p_norm, J):
    prob, sol, bvp, z, T = _setup(p_norm, J)
    y0, _ = bvp.initial(z)
    y, status, steps = replay_pnorm_end(y0, T, bvp.J, bvp.umax, p_norm, 1e-11, 1e-12, 10 ** 6)
    assert status == REPLAY_OK and 50 < steps < 5000

    def rhs(t, x):
        return af.ext_rhs(x, af.control(x, bvp.J, bvp.umax, af.MODE_PNORM, p_norm, 0.0, np.ones(3))[0], bvp.J)
    ref = solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=1e-13, atol=1e-14).y[:, -1]
    assert np.allclose(y[:7], ref[:7], rtol=0, atol=1e-8)
    # and it reaches the target the solver found
    assert sol.verification["replay"]["passed"] and sol.verification["replay"]["value"] <= 1e-6


def test_the_replay_steps_across_the_torque_reversal_of_the_eigenaxis_slew():
    # a unit body, 2-norm bound: the eigenaxis slew, whose torque reverses at tf/2 (λω = 0
    # there): tf = 2 sqrt(theta), theta the slew angle
    prob, sol, bvp, z, T = _setup(2.0, [1.0, 1.0, 1.0], seed=9)
    theta = prob.slew_angle
    assert sol.tf == pytest.approx(2.0 * math.sqrt(theta), rel=1e-8)
    y0, _ = bvp.initial(z)
    y, status, _ = replay_pnorm_end(y0, T, bvp.J, bvp.umax, 2.0, 1e-11, 1e-12, 10 ** 6)
    assert status == REPLAY_OK
    q_err = min(np.linalg.norm(y[0:4] - prob.qf), np.linalg.norm(y[0:4] + prob.qf))
    assert q_err < 1e-8 and np.linalg.norm(y[4:7]) < 1e-8


def test_a_wrong_costate_fails_the_check_and_a_step_cap_is_reported():
    prob, sol, bvp, z, T = _setup(2.0, [0.6, 0.9, 1.0], seed=2)
    ok, checks, _, _ = verify(bvp, z, T)
    assert ok and checks["replay"]["passed"]
    z_bad = z + np.array([0.0, 0.0, 0.0, 1e-4, 0.0, 0.0])
    ok, checks, text, _ = verify(bvp, z_bad / np.linalg.norm(z_bad), T)
    assert not ok and not checks["replay"]["passed"] and checks["replay"]["value"] > 1e-6
    y0, _ = bvp.initial(z)
    _, status, steps = replay_pnorm_end(y0, T, bvp.J, bvp.umax, 2.0, 1e-11, 1e-12, 5)
    assert status == REPLAY_MAX_STEPS and steps == 5


def test_a_failed_replay_fails_the_check(monkeypatch):
    import solvers.verify as V
    from solvers.core.costate_replay import REPLAY_NONFINITE
    prob, sol, bvp, z, T = _setup(2.0, [0.6, 0.9, 1.0], seed=2)
    for bad_T in (float("nan"), 0.0, -1.0):
        _, status, steps = replay_pnorm_end(bvp.initial(z)[0], bad_T, bvp.J, bvp.umax, 2.0, 1e-11, 1e-12, 10)
        assert status == REPLAY_NONFINITE and steps == 0
    real = V.replay_pnorm_end
    monkeypatch.setattr(V, "replay_pnorm_end", lambda y0, *a: (real(y0, *a)[0], REPLAY_NONFINITE, 3))
    ok, checks, text, _ = verify(bvp, z, T)
    assert not ok and not checks["replay"]["passed"] and checks["replay"]["value"] == math.inf
    assert "replay" in text
