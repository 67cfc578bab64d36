"""CaptureHandover: the PD law flies the last degree instead of the policy."""
import math

import numpy as np
import pytest

from slew_env import SlewEnv
from slew_env.core import env_kernels as K
from slew_env.shield import ConeShield
from training.rl.capture import CaptureHandover, check, error_angle, pd_action
from training.rl.evaluate import resolve_capture
from training.rl.train import capture_kwargs, wrap_controller


def test_capture_law_is_error_feedback_and_a_deadbeat_rate_loop():
    obs = np.zeros(K.obs_length(4))
    half = math.radians(2.0) / 2               # 2° still to go about body z, spinning at 0.01 about x
    obs[K.OB_DQ:K.OB_DQ + 4] = [math.cos(half), 0.0, 0.0, math.sin(half)]
    obs[K.OB_W:K.OB_W + 3] = [0.01, 0.0, 0.0]
    obs[K.OB_J:K.OB_J + 3] = [0.5, 0.8, 1.0]
    obs[K.OB_UMAX:K.OB_UMAX + 3] = [1.0, 1.0, 0.5]
    # rate term: damping · J ω / (u_max dt) = 0.8 · 0.5 · 0.01 / 0.05 on x
    np.testing.assert_allclose(pd_action(obs, 5.0, 0.8, 0.05), [-0.08, 0.0, 5.0 * math.radians(2.0)], atol=1e-12)
    assert error_angle(obs) == pytest.approx(math.radians(2.0))
    assert np.all(np.abs(pd_action(np.tile(obs, (4, 1)) * 50, 50.0, 1.0, 0.05)) <= 1.0)


def test_rate_loop_removes_the_damping_fraction_of_a_roll_in_one_step():
    env = CaptureHandover(SlewEnv(task_distribution="pointing-cones"), deg=1.0, damping=0.8)
    env.reset(seed=1)
    p = env.unwrapped.problem.to_dict()
    tgt = np.asarray(env.unwrapped.problem.target_direction)
    sensor = np.asarray(env.unwrapped.problem.sensor_axis)
    axis = np.cross(sensor, tgt)
    axis /= np.linalg.norm(axis)
    ang = math.acos(np.clip(sensor @ tgt, -1, 1))       # start on the target, rolling about the sensor
    p["q0"] = [math.cos(ang / 2), *(math.sin(ang / 2) * axis)]
    T = env.unwrapped.problem.time_unit
    p["omega0"] = list(0.03 / T * sensor)
    o, _ = env.reset(options={"problem": p})
    w0 = o[K.OB_W:K.OB_W + 3] @ o[K.OB_SENSOR:K.OB_SENSOR + 3]
    o, *_ = env.step(np.ones(3))
    w1 = o[K.OB_W:K.OB_W + 3] @ o[K.OB_SENSOR:K.OB_SENSOR + 3]
    assert w1 == pytest.approx(0.2 * w0, rel=1e-3)


def _near_target(problem, off_deg):
    """The problem as a dict, started at rest ``off_deg`` short of the target along the shortest arc."""
    p = problem.to_dict()
    tgt = np.asarray(problem.target_direction)
    sensor = np.asarray(problem.sensor_axis)
    axis = np.cross(sensor, tgt)
    axis /= np.linalg.norm(axis)
    ang = math.acos(np.clip(sensor @ tgt, -1, 1)) - math.radians(off_deg)
    p["q0"] = [math.cos(ang / 2), *(math.sin(ang / 2) * axis)]
    return p


class _Chatter:
    """Full torque, alternating sign: reaches nothing, never rests."""

    def __init__(self):
        self.k = 0

    def __call__(self):
        self.k += 1
        return np.full(3, (-1.0) ** self.k)


def test_policy_actions_pass_outside_and_the_pd_law_flies_inside():
    env = CaptureHandover(SlewEnv(task_distribution="pointing-cones"), deg=1.0)
    base = SlewEnv(task_distribution="pointing-cones")
    o, _ = env.reset(seed=3)
    ob, _ = base.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(5):                         # far from the target: the action goes through unchanged
        a = rng.uniform(-1, 1, 3)
        o, r, *_ , info = env.step(a)
        ob, rb, *_ = base.step(a)
        np.testing.assert_array_equal(o, ob)
        assert not info["captured"]
    # start 0.5° off the target, turning: the PD law takes over whatever the policy says, and settles
    p = _near_target(env.unwrapped.problem, 0.5)
    p["omega0"] = [0.02, -0.01, 0.015]
    chatter = _Chatter()
    env.reset(options={"problem": p})
    for steps in range(1, 200):
        _, _, term, _, info = env.step(chatter())
        assert info["captured"]
        if term:
            break
    assert info["is_success"] and steps < 20
    # the same chattering policy without the handover never succeeds
    bare = SlewEnv(task_distribution="pointing-cones")
    bare.reset(options={"problem": p})
    for _ in range(200):
        _, _, term, _, info = bare.step(chatter())
        assert not info["is_success"]


def test_capture_damps_the_rate_error_not_the_rate():
    """A target that spins: on target at the target's rate, the capture law leaves it so."""
    env = CaptureHandover(SlewEnv(task_distribution="pointing-cones"))
    env.reset(seed=2)
    p = _near_target(env.unwrapped.problem, 0.5)
    spin = list(0.05 / env.unwrapped.problem.time_unit * np.asarray(env.unwrapped.problem.sensor_axis))
    p["omega0"] = spin
    p["omegaf"] = spin
    env.reset(options={"problem": p})
    for steps in range(1, 20):
        _, _, term, _, info = env.step(np.ones(3))
        assert info["captured"]
        if term:
            break
    assert info["is_success"] and steps <= 3


def test_configuration_and_evaluation_flags():
    assert capture_kwargs({"capture": None}) is None
    assert capture_kwargs({"capture": True}) == {"deg": 1.0, "kp": 5.0, "damping": 0.8}
    env = wrap_controller(SlewEnv(task_distribution="pointing-cones"), shield={}, capture=check({}))
    assert isinstance(env, CaptureHandover) and isinstance(env.env, ConeShield)
    cfg = {"capture": {"deg": 2.0}}
    assert resolve_capture("policy", cfg)["deg"] == 2.0
    assert resolve_capture("off", cfg) is None
    assert resolve_capture("on", {"capture": None}) == check({})
    with pytest.raises(ValueError, match="--capture"):
        resolve_capture("sometimes", cfg)


def test_bad_capture_arguments_name_the_field():
    with pytest.raises(ValueError, match="capture: unknown"):
        capture_kwargs({"capture": {"gain": 1}})
    with pytest.raises(ValueError, match="capture.deg"):
        check({"deg": 0})
    with pytest.raises(ValueError, match="capture.kp"):
        check({"kp": "fast"})
    with pytest.raises(ValueError, match="capture.damping"):
        check({"damping": 1.5})
    with pytest.raises(ValueError, match="env"):
        import gymnasium as gym
        CaptureHandover(gym.make("Pendulum-v1"))
    env = CaptureHandover(SlewEnv())
    with pytest.raises(Exception, match="reset"):
        env.step(np.zeros(3))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(2))
