"""CaptureHandover: the PD law flies the last degree instead of the policy."""
import math

import numpy as np
import pytest

from slew_env import SlewEnv
from slew_env.core import env_kernels as K
from slew_env.shield import ConeShield
from training.rl.capture import CaptureHandover, braking_action, check, error_angle, pd_action
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
    assert capture_kwargs({"capture": True}) == {"deg": 1.0, "kp": 5.0, "damping": 0.8, "law": "pd",
                                                  "brake": 0.9, "aim_deg": 0.8}
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
    with pytest.raises(ValueError, match="capture.law"):
        check({"law": "bang"})
    with pytest.raises(ValueError, match="capture.brake"):
        check({"law": "braking", "brake": 1.2})
    with pytest.raises(ValueError, match="capture.aim_deg"):
        check({"law": "braking", "deg": 1.0, "aim_deg": 1.0})
    with pytest.raises(ValueError, match="capture.aim_deg"):
        check({"aim_deg": -0.1})
    assert check({"law": "braking", "deg": 10, "aim_deg": 0})["aim_deg"] == 0.0
    with pytest.raises(ValueError, match="env"):
        import gymnasium as gym
        CaptureHandover(gym.make("Pendulum-v1"))
    env = CaptureHandover(SlewEnv())
    with pytest.raises(Exception, match="reset"):
        env.step(np.zeros(3))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(2))


def _obs_with_error(deg, axis, w=(0.0, 0.0, 0.0), J=(0.5, 0.8, 1.0), umax=(1.0, 1.0, 0.5), inv_p=0.0):
    obs = np.zeros(K.obs_length(4))
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    half = math.radians(deg) / 2
    obs[K.OB_DQ:K.OB_DQ + 4] = [math.cos(half), *(math.sin(half) * axis)]
    obs[K.OB_W:K.OB_W + 3] = w
    obs[K.OB_J:K.OB_J + 3] = J
    obs[K.OB_UMAX:K.OB_UMAX + 3] = umax
    obs[K.OB_INV_P] = inv_p
    obs[K.OB_RATE_LIMIT:K.OB_RATE_LIMIT + 3] = 1.0        # no rate limit
    return obs


def test_braking_law_tracks_the_braking_curve_of_the_error_axis():
    # 6° to go about body z at rest; per-axis bound: the largest acceleration about z is u_z/J_z = 0.5
    obs = _obs_with_error(6.0, [0, 0, 1])
    s, beta, dt, d = 0.5, 0.9, 0.05, math.radians(6.0 - 0.8)
    c = beta * s * dt
    speed = math.sqrt(c * c + 2 * beta * s * d) - c
    want = np.clip(0.8 * np.array([0.5, 0.8, 1.0]) * np.array([0, 0, speed]) / (np.array([1, 1, 0.5]) * dt), -1, 1)
    np.testing.assert_allclose(braking_action(obs, beta, math.radians(0.8), 0.8, dt), want, atol=1e-12)
    # the same axis already at the curve's rate: no torque about it
    at = _obs_with_error(6.0, [0, 0, 1], w=(0.0, 0.0, speed))
    np.testing.assert_allclose(braking_action(at, beta, math.radians(0.8), 0.8, dt), 0.0, atol=1e-12)
    # inside the aim angle the law is the rate loop alone
    inside = _obs_with_error(0.5, [1, 0, 0], w=(0.01, 0.0, 0.0))
    np.testing.assert_allclose(braking_action(inside, beta, math.radians(0.8), 0.8, dt),
                               [-0.8 * 0.5 * 0.01 / dt, 0, 0], atol=1e-12)


def test_braking_law_uses_the_bounds_own_norm():
    # axis (1, 1, 0)/√2, J = 1, u_max = 1: per axis the acceleration about it is √2, with a 2-norm bound 1
    e = [1.0, 1.0, 0.0]
    for inv_p, s in ((0.0, math.sqrt(2.0)), (0.5, 1.0)):
        obs = _obs_with_error(20.0, e, J=(1, 1, 1), umax=(1, 1, 1), inv_p=inv_p)
        c = 0.5 * s * 1e-3
        speed = math.sqrt(c * c + 2 * 0.5 * s * math.radians(20.0)) - c
        a = braking_action(obs, 0.5, 0.0, 1e-3, 1e-3)     # damping = dt: the action is the rate asked for
        np.testing.assert_allclose(a, speed * np.array(e) / math.sqrt(2.0), rtol=1e-12)
    batch = np.stack([_obs_with_error(20.0, e, J=(1, 1, 1), umax=(1, 1, 1), inv_p=ip) for ip in (0.0, 0.5)])
    np.testing.assert_allclose(braking_action(batch, 0.5, 0.0, 1e-3, 1e-3)[1],
                               braking_action(batch[1], 0.5, 0.0, 1e-3, 1e-3), rtol=1e-15)


def test_braking_law_flies_in_from_8_degrees_near_the_bang_bang_time():
    """At rest 8° off the target, the braking law succeeds within 1.3× the bang-bang rest-to-rest
    time about the error axis (to the aim angle); the PD law takes over 5× as long."""
    times = {}
    for law in ("pd", "braking"):
        env = CaptureHandover(SlewEnv(task_distribution="pointing-cones"), deg=10.0, law=law)
        env.reset(seed=4)
        o, _ = env.reset(options={"problem": _near_target(env.unwrapped.problem, 8.0)})
        axis = o[K.OB_DQ + 1:K.OB_DQ + 4] / np.linalg.norm(o[K.OB_DQ + 1:K.OB_DQ + 4])
        s = 1.0 / np.max(np.abs(o[K.OB_J:K.OB_J + 3] * axis / o[K.OB_UMAX:K.OB_UMAX + 3]))
        for _ in range(400):
            o, _, term, trunc, info = env.step(np.ones(3))      # the policy's action is ignored throughout
            assert info["captured"] or info["is_success"]
            if term or trunc:
                break
        assert info["is_success"]
        times[law] = info["time"] / env.unwrapped.problem.time_unit
    bang = 2.0 * math.sqrt(math.radians(8.0 - 0.8) / s)
    assert bang < times["braking"] < 1.3 * bang
    assert times["pd"] > 5 * times["braking"]


def test_braking_law_tracks_the_rate_relative_to_a_spinning_target_and_any_p():
    # a target spinning at ωf: at the curve's rate relative to it, no torque
    obs = _obs_with_error(6.0, [0, 0, 1], w=(0.3, 0.0, 0.0))
    obs[K.OB_WF:K.OB_WF + 3] = [0.3, 0.0, 0.0]
    ref = _obs_with_error(6.0, [0, 0, 1])
    np.testing.assert_allclose(braking_action(obs, 0.9, 0.0, 0.8, 0.05), braking_action(ref, 0.9, 0.0, 0.8, 0.05),
                               atol=1e-15)
    # p = 1.5 on an asymmetric axis: s = 1 / ‖J e / u_max‖_1.5
    e = np.array([0.2, -0.5, 0.7])
    e /= np.linalg.norm(e)
    J, um = np.array([0.5, 0.8, 1.0]), np.array([1.0, 0.7, 0.5])
    s = 1.0 / np.sum(np.abs(J * e / um) ** 1.5) ** (1 / 1.5)
    obs = _obs_with_error(20.0, e, J=J, umax=um, inv_p=1 / 1.5)
    speed = math.sqrt((0.5 * s * 1e-3) ** 2 + 2 * 0.5 * s * math.radians(20.0)) - 0.5 * s * 1e-3
    np.testing.assert_allclose(braking_action(obs, 0.5, 0.0, 1e-3, 1e-3), speed * e * J / um, rtol=1e-12)


def test_braking_law_keeps_to_a_rate_limit():
    """15° from a full target with a rate limit of 0.15/T: the curve is capped, no rate violation."""
    env = CaptureHandover(SlewEnv(task_distribution="full-attitude"), deg=20.0, law="braking")
    env.reset(seed=3)
    p = env.unwrapped.problem.to_dict()
    T = env.unwrapped.problem.time_unit
    half = math.radians(15.0) / 2
    turn = np.array([math.cos(half), *(-math.sin(half) * np.array([0.6, 0.0, 0.8]))])
    from slew_env.core.quaternion import qmul
    p.update(omega0=[0, 0, 0], omegaf=[0, 0, 0], torque_norm="inf", rate_max=0.15 / T,
             q0=list(qmul(np.asarray(p["qf"], float), turn)))
    env.reset(options={"problem": p})
    peak = 0.0
    for _ in range(400):
        _, _, term, trunc, info = env.step(np.zeros(3))
        assert not info["violation"]
        peak = max(peak, float(np.max(np.abs(env.unwrapped.state[4:7]))) * T)
        if term or trunc:
            break
    assert info["is_success"]
    assert 0.12 < peak <= 0.15          # it does use the allowed rate


def test_braking_law_needs_an_aim_inside_the_success_tolerance():
    with pytest.raises(ValueError, match="capture.aim_deg.*att_tol_deg"):
        CaptureHandover(SlewEnv(att_tol_deg=0.5), deg=10.0, law="braking", aim_deg=0.8)
    CaptureHandover(SlewEnv(att_tol_deg=0.5), deg=10.0, law="braking", aim_deg=0.4)
    CaptureHandover(SlewEnv(att_tol_deg=0.5), deg=10.0, law="pd")       # the PD law has no aim
    with pytest.raises(ValueError, match="capture.law"):
        check({"law": np.array(["braking"])})
    with pytest.raises(ValueError, match="capture.brake"):
        check({"brake": True})
    with pytest.raises(ValueError, match=r"capture.aim_deg.*\(the default\)"):
        check({"law": "braking", "deg": 0.5})
