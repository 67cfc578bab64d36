"""``training.rl.bc.solution_actions``: a solver's answer flown through ``Slew-v0``.

The recipe of docs/RL.md ("Flying the solver's answer in the environment"): the problem from
``env.unwrapped.problem``, each action the step's mean of ``u(t) / u_max``, the torque cut off
at ``tf`` (``SlewSolution.control`` goes on past it).
"""
import math

import gymnasium as gym
import numpy as np
import pytest

import slew_env  # noqa: F401  (registers Slew-v0)
from slew_env import ENV_ID
from training.rl.bc import solution_actions


@pytest.fixture(scope="module")
def posed():
    import solvers

    env = gym.make(ENV_ID, task_distribution="full-attitude")
    env.reset(seed=3)
    with pytest.raises(AttributeError):
        env.problem                                      # gymnasium 1.x wrappers do not forward it
    prob = env.unwrapped.problem
    assert env.get_wrapper_attr("problem") == prob
    sol = solvers.solve(prob)
    assert sol.success and sol.problem == prob
    return env, prob, sol


def test_the_actions_fly_the_answer_to_the_target(posed):
    env, prob, sol = posed
    actions = solution_actions(sol, env.unwrapped.control_dt)
    dt = env.unwrapped.control_dt * prob.time_unit
    assert actions.shape == (math.ceil(sol.tf / dt - 1e-9), 3) and actions.dtype == np.float32
    assert np.abs(actions).max() <= 1.0
    env.reset(options={"problem": prob})
    for k, a in enumerate(actions):
        obs, reward, terminated, truncated, info = env.step(a)
        if terminated or truncated:
            break
    assert info["is_success"] and not info["violation"]
    assert k >= len(actions) - 2                          # at tf, within the 1° / 0.02 tolerance


def test_each_action_is_the_step_average_and_the_torque_stops_at_tf(posed):
    env, prob, sol = posed
    n_sub = 16
    actions = solution_actions(sol, 0.05, n_sub=n_sub)
    dt, umax = 0.05 * prob.time_unit, np.asarray(prob.torque_max)
    assert np.abs(sol.control(sol.tf + 0.5 * dt)).min() > 0      # the solution's law goes on past tf
    for k in (0, len(actions) // 2, len(actions) - 1):
        t = k * dt + (np.arange(n_sub) + 0.5) / n_sub * dt
        u = np.array([sol.control(x) if x <= sol.tf else np.zeros(3) for x in t])
        np.testing.assert_allclose(actions[k], u.mean(axis=0) / umax, atol=1e-7)
    last = (len(actions) - 1) * dt + (np.arange(n_sub) + 0.5) / n_sub * dt
    assert (last > sol.tf).any()                          # the last step runs past tf: cut there
