"""The environment's arguments, bodies and long episodes at the edges of what it integrates (an
outside fuzz, session 42): NaN observations from an accepted control_dt or body, a long saturated
episode that blew the integrator up, arguments that hung or ran out of memory without naming
themselves, and a shield that passed text on as actions."""
import math

import gymnasium as gym
import numpy as np
import pytest

import slew_env
from slew_env import ConeShield, SlewEnv, SlewProblem, SlewVectorEnv, TaskDistribution


def _random_episode_finite(env, seed, steps=400):
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    for _ in range(steps):
        obs, r, te, tr, _ = env.step(rng.uniform(-1, 1, 3).astype(np.float32))
        if not (np.all(np.isfinite(obs)) and math.isfinite(r) and env.observation_space.contains(obs)):
            return False
        if te or tr:
            break
    return True


def test_a_long_control_step_stays_finite_and_a_too_long_one_is_refused():
    # control_dt = 2 had given NaN observations in 45 of 100 random episodes
    env = gym.make("slew_env/Slew-v0", control_dt=2.0, disable_env_checker=True)
    assert all(_random_episode_finite(env, s) for s in range(20))
    with pytest.raises(ValueError, match=r"^control_dt: at most 10 time units T"):
        gym.make("slew_env/Slew-v0", control_dt=1e6)
    with pytest.raises(ValueError, match=r"^substeps: must be a whole number <= 10000"):
        SlewEnv(substeps=10 ** 12)


def test_a_long_saturated_episode_stays_finite():
    # full torque for 5,000 steps: the rate reached ~500 / T and RK4 diverged at step ~4,186
    env = SlewEnv()        # (no time limit of its own: gym.make's TimeLimit is not there)
    env.reset(seed=3)
    a = np.ones(3, np.float32)
    for _ in range(5000):
        obs, r, te, tr, _ = env.step(a)
        assert np.all(np.isfinite(obs)) and math.isfinite(r) and env.observation_space.contains(obs)
        if te or tr:
            env.reset(seed=3)


def test_a_fast_spin_is_integrated_to_its_invariants():
    # torque-free at 58 / T: one sub-step would turn the body 0.73 rad; split into steps of at
    # most 0.5 rad (a bound for RK4's stability, not its accuracy), the inertial angular momentum
    # drifts by 1.8e-4 of itself over 10 T, and |q| stays 1
    J = np.array([1.0, 0.7, 0.45])
    p = SlewProblem(J.tolist(), qf=[0.0, 1.0, 0.0, 0.0],
                    omega0=[50.0, 0.0, 30.0], omegaf=[0.0, 0.0, 0.0])
    env = SlewEnv(terminate_on_violation=False)
    env.reset(options={"problem": p})
    from slew_env.core import qrotate

    def momentum():
        x = env._st[:7]
        return np.asarray(qrotate(x[:4], J * x[4:7])), float(np.linalg.norm(x[:4]))
    h0, _ = momentum()
    for _ in range(200):
        env.step(np.zeros(3, np.float32))
    h1, qn = momentum()
    assert np.linalg.norm(h1 - h0) <= 1e-3 * np.linalg.norm(h0)
    assert abs(qn - 1.0) < 1e-9


def test_bodies_whose_time_unit_leaves_the_floating_point_range_are_refused():
    # inertia 1e200 with torque 1e-200 had given NaN observations from the first reset
    for J, u in ((1e200, 1e-200), (1e-200, 1e200)):
        with pytest.raises(ValueError, match=r"^inertia, torque_max: the time unit sqrt\(J_max / u_max\)"):
            SlewProblem([J] * 3, torque_max=u, qf=[0.0, 1.0, 0.0, 0.0])
        with pytest.raises(ValueError, match=r"^inertia, torque_max: the time unit"):
            TaskDistribution(inertia_mode="fixed", inertia=(J,) * 3, torque_max=u)
    # far apart, but inside the range: accepted (the solvers scale them)
    SlewProblem([1e-300] * 3, torque_max=1.0, qf=[0.0, 1.0, 0.0, 0.0])


@pytest.mark.parametrize("make, kw, pattern", [
    (SlewEnv, dict(max_cones=10 ** 12), r"^max_cones: must be a whole number <= 64"),
    (SlewVectorEnv, dict(num_envs=10 ** 12), r"^num_envs: must be a whole number <= 1048576"),
    (SlewVectorEnv, dict(pool_blocks=10 ** 12), r"^pool_blocks: must be a whole number <= 1024"),
    (SlewVectorEnv, dict(num_envs=1 << 20, pool_blocks=1024), r"^num_envs, pool_blocks: .* GiB"),
])
def test_sizes_that_cannot_be_allocated_are_refused_by_name(make, kw, pattern):
    with pytest.raises(ValueError, match=pattern):
        make(**kw)


def test_the_shield_refuses_what_the_environment_refuses():
    env = ConeShield(gym.make("slew_env/Slew-v0", task_distribution="pointing-cones"))
    env.reset(seed=0)
    for bad in (["1", "0", "0"], [True, False, True], np.array([1 + 5j, 0, 0])):
        with pytest.raises(ValueError, match=r"^action: expected real numbers of shape \(3,\)"):
            env.step(bad)
    env.step([0.5, 0.0, -0.5])
    with pytest.raises(ValueError, match=r"^margin_deg: must be a finite number"):
        ConeShield(gym.make("slew_env/Slew-v0"), margin_deg="0.5")
    with pytest.raises(ValueError, match=r"^sweeps: must be a whole number"):
        ConeShield(gym.make("slew_env/Slew-v0"), sweeps=True)


def test_a_bad_problem_of_a_batch_names_its_copy():
    venv = SlewVectorEnv(num_envs=3)
    good = {"inertia": [1, 1, 1], "qf": [0.0, 1.0, 0.0, 0.0]}
    with pytest.raises(ValueError, match=r"^problems\[1\]: inertia"):
        venv.reset(options={"problems": [good, {"inertia": [1, -1, 1], "qf": [0, 1, 0, 0]}, None]})
