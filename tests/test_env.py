"""SlewEnv: physics, reward, constraints, success, reproducibility, API checks."""
import importlib
import math
import warnings

import gymnasium as gym
import numpy as np
import pytest

import slew_env
from slew_env import SlewEnv, SlewProblem
from slew_env.core import dynamics, quaternion as Q
from slew_env.core import env_kernels as K

ENV_ID = "slew_env/Slew-v0"


def make(**kw):
    return SlewEnv(**kw)


def spin_problem(cone_azimuth, half_angle, w=1.0, rate_max=None):
    """Symmetric body spinning about z at rate w; sensor x sweeps the equator."""
    return SlewProblem(
        inertia=[1.0, 1.0, 1.0], torque_max=1.0, omega0=[0.0, 0.0, w],
        sensor_target=[math.cos(2.5), math.sin(2.5), 0.0],
        cones=[{"axis": [math.cos(cone_azimuth), math.sin(cone_azimuth), 0.0], "half_angle": half_angle}],
        rate_max=rate_max)


# ---------------------------------------------------------------- registration
def test_registered_on_import_idempotently():
    spec = gym.spec(ENV_ID)
    assert spec.entry_point == "slew_env.env:SlewEnv"
    assert spec.vector_entry_point == "slew_env.vector_env:SlewVectorEnv"
    assert spec.max_episode_steps == 400
    importlib.reload(slew_env)  # a second registration would warn / override
    slew_env._register()
    assert gym.spec(ENV_ID) is spec


def test_make_uses_time_limit_for_truncation():
    env = gym.make(ENV_ID, max_episode_steps=5)
    env.reset(seed=0)
    for k in range(5):
        _, _, terminated, truncated, _ = env.step(np.zeros(3, dtype=np.float32))
        assert not terminated
        assert truncated == (k == 4)
    # the raw environment never truncates by itself
    raw = SlewEnv()
    raw.reset(seed=0)
    for _ in range(500):
        assert raw.step(np.zeros(3))[3] is False


# ---------------------------------------------------------------- physics
def test_constant_torque_on_symmetric_body_gives_linear_rate():
    J, umax = 2.0, 0.5
    prob = SlewProblem(inertia=[J, J, J], torque_max=umax, qf=Q.qfrom_axis_angle(np.array([0, 0, 1.0]), 3.0))
    env = make(control_dt=0.05, substeps=4, shaping=0.0)
    env.reset(options={"problem": prob})
    a = np.array([1.0, -0.5, 0.25], dtype=np.float32)
    u = umax * a.astype(float)
    T = math.sqrt(J / umax)
    for k in range(1, 21):
        _, _, _, _, info = env.step(a)
        t = k * 0.05 * T
        assert info["time"] == pytest.approx(t, rel=1e-14)
        np.testing.assert_allclose(env.state[4:], u * t / J, rtol=1e-13, atol=1e-16)
    # ω keeps its direction n, so the body turns about n by ½|u|t²/J.
    n = u / np.linalg.norm(u)
    q = Q.qfrom_axis_angle(n, 0.5 * np.linalg.norm(u) * t * t / J)
    np.testing.assert_allclose(env.state[:4], q, atol=1e-9)


@pytest.mark.parametrize("norm", ["inf", 2.0])
def test_step_is_dynamics_propagate_bit_for_bit(norm):
    prob = SlewProblem(inertia=[0.9, 0.55, 0.4], torque_max=[1.0, 0.8, 0.6], torque_norm=norm,
                       q0=Q.qfrom_uniform(0.2, 0.7, 0.4), omega0=[0.1, -0.2, 0.05],
                       qf=Q.qfrom_uniform(0.9, 0.1, 0.3))
    env = make(control_dt=0.07, substeps=5)
    env.reset(options={"problem": prob})
    a = np.array([0.9, -0.7, 0.8])
    x = np.concatenate([prob.q0, prob.omega0])
    u = dynamics.torque_from_action(a, prob.torque_max, 0.0 if norm == "inf" else norm)
    for _ in range(3):
        env.step(a)
        x = dynamics.propagate(x, u, prob.inertia, 0.07 * prob.time_unit, 5)[-1]
        assert np.array_equal(env.state, x)


def test_rk4_substep_matches_dynamics_rk4_step_bit_for_bit():
    rng = np.random.default_rng(5)
    for _ in range(200):
        x = rng.normal(size=7)
        u, J, h = rng.normal(size=3), rng.uniform(0.1, 2.0, 3), rng.uniform(1e-3, 0.5)
        ref = dynamics.rk4_step(x, u, J, h)
        ref[:4] = ref[:4] / np.sqrt(ref[0] ** 2 + ref[1] ** 2 + ref[2] ** 2 + ref[3] ** 2)
        y = x.copy()
        K.rk4_substep(y, u[0], u[1], u[2], J[0], J[1], J[2], h)
        assert np.array_equal(y, ref)


def test_nan_and_out_of_box_actions_are_saturated_not_propagated():
    env_a, env_b = make(), make()
    env_a.reset(seed=1)
    env_b.reset(seed=1)
    for _ in range(5):
        obs_a, r_a, *_ = env_a.step(np.array([np.nan, 0.5, np.inf]))
        obs_b, r_b, *_ = env_b.step(np.array([0.0, 0.5, 1.0]))
        assert np.all(np.isfinite(env_a.state))
        assert np.array_equal(obs_a, obs_b) and r_a == r_b


def test_action_of_wrong_shape_raises():
    env = make()
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(np.zeros(4))


def test_step_before_reset_raises():
    with pytest.raises(gym.error.ResetNeeded):
        make().step(np.zeros(3))


def _drifting_onto_target():
    # at rest on the target but for a tiny rate: the first step succeeds
    return {"inertia": [1, 1, 1], "qf": [1, 0, 0, 0], "omega0": [0, 0, 0.001]}


@pytest.mark.parametrize("wrapped", [False, True])
def test_step_after_success_raises_reset_needed(wrapped):
    # a fuzz run: after terminated=True, step() integrated on and paid success_bonus on every call
    env = gym.make(ENV_ID) if wrapped else make()
    env.reset(options={"problem": _drifting_onto_target()})
    _, reward, terminated, _, info = env.step(np.zeros(3))
    assert terminated and info["is_success"] and reward > 9.0
    for _ in range(2):
        with pytest.raises(gym.error.ResetNeeded, match="terminated"):
            env.step(np.zeros(3))
    env.reset(options={"problem": _drifting_onto_target()})   # a reset starts a new episode
    assert env.step(np.zeros(3))[2]
    env.reset(seed=0)
    _, reward, terminated, _, _ = env.step(np.zeros(3))
    assert not terminated and reward < 0.0
    assert not env.step(np.zeros(3))[2]   # steps go on while the episode is not over


def test_step_after_violation_raises_reset_needed_only_when_terminating():
    prob = spin_problem(cone_azimuth=0.3, half_angle=0.1)
    env = make(shaping=0.0)
    env.reset(options={"problem": prob})
    for _ in range(200):
        _, reward, terminated, _, info = env.step(np.zeros(3))
        if terminated:
            break
    assert terminated and info["violation"] and reward < -9.0
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(3))
    # without terminate_on_violation the episode goes on through the cone
    env = make(shaping=0.0, terminate_on_violation=False)
    env.reset(options={"problem": prob})
    violations = 0
    for _ in range(200):
        _, _, terminated, _, info = env.step(np.zeros(3))
        assert not terminated
        violations += info["violation"]
    assert violations > 0


@pytest.mark.parametrize("action", [
    # a fuzz run: text was parsed as numbers, complex lost its imaginary part with a warning,
    # other non-numbers raised numpy's own errors naming no argument
    np.array(["1", "0", "0"]), ["1", 0, 0], "abc", b"abc", {"a": 1}, None, {1, 2, 3},
    [1j, 0, 0], np.array([1j, 0, 0]), np.array([True, False, True]), [True, 0.5, 0],
    [None, 0, 0], np.array([None, 0, 0]), [[1, 0], [0]], np.zeros((1, 3)), np.zeros(4), 1.0,
])
def test_action_that_is_not_three_real_numbers_is_refused_by_name(action):
    env = make()
    env.reset(seed=0)
    before = env.state
    with pytest.raises(ValueError, match=r"^action: expected real numbers of shape \(3,\), got"):
        env.step(action)
    assert np.array_equal(env.state, before)


@pytest.mark.parametrize("action", [
    [1, 0, -1], (1.0, 0.0, -1.0), np.array([1, 0, -1], dtype=np.int64), np.array([1, 0, -1], dtype=np.float32),
    np.array([1, 0, -1], dtype=object), [np.float32(1), np.int8(0), -1.0],
])
def test_actions_of_real_numbers_in_any_container_are_equal(action):
    a, b = make(), make()
    a.reset(seed=4)
    b.reset(seed=4)
    assert np.array_equal(a.step(action)[0], b.step(np.array([1.0, 0.0, -1.0]))[0])


@pytest.mark.parametrize("kw, match", [
    ({"seed": 1.5}, r"^seed: expected None or a whole number >= 0, got 1.5"),
    ({"seed": "1"}, r"^seed: expected None or a whole number >= 0, got '1'"),
    ({"seed": True}, r"^seed: expected None or a whole number >= 0, got True"),
    ({"seed": -1}, r"^seed: expected None or a whole number >= 0, got -1"),
    ({"options": [1]}, r"^options: expected None or a dict, got \[1\]"),
    ({"options": "problem"}, r"^options: expected None or a dict, got 'problem'"),
    ({"options": {"problems": []}}, r"^options: unknown key\(s\) \['problems'\]"),
    ({"options": {"problem": 3}}, r"^problem: expected a SlewProblem or a dict"),
])
def test_reset_arguments_are_checked_by_name(kw, match):
    env = make()
    with pytest.raises(ValueError, match=match):
        env.reset(**kw)
    assert np.array_equal(env.reset(seed=np.int64(5))[0], make().reset(seed=5)[0])


# ---------------------------------------------------------------- observation
def test_full_target_error_quaternion_completes_the_slew():
    env = make()
    env.reset(seed=3)
    for _ in range(10):
        obs, *_ = env.step(env.action_space.sample())
    prob = env.problem
    dq = obs[K.OB_DQ:K.OB_DQ + 4].astype(float)
    assert dq[0] >= 0.0
    q_reached = Q.qmul(env.state[:4], dq)  # q ⊗ (q* ⊗ qf) = ±qf
    assert min(np.abs(q_reached - prob.qf).max(), np.abs(q_reached + prob.qf).max()) < 1e-6
    np.testing.assert_allclose(obs[K.OB_TARGET:K.OB_TARGET + 3],
                               Q.qrotate_inv(env.state[:4], prob.target_direction), atol=1e-6)


def test_pointing_error_quaternion_turns_sensor_onto_target():
    env = make(task_distribution="pointing-cones")
    env.reset(seed=4)
    for _ in range(10):
        obs, _, _, _, info = env.step(env.action_space.sample())
    prob = env.problem
    dq = obs[K.OB_DQ:K.OB_DQ + 4].astype(float)
    s_b, t_b = prob.sensor_axis, Q.qrotate_inv(env.state[:4], prob.sensor_target)
    np.testing.assert_allclose(Q.qrotate(dq / np.linalg.norm(dq), s_b), t_b, atol=1e-6)
    assert info["attitude_error"] == pytest.approx(
        float(np.arccos(np.clip(s_b @ t_b, -1, 1))), abs=1e-7)
    n = len(prob.cones)
    for k in range(env.max_cones):
        slot = obs[K.OB_CONES + 6 * k:K.OB_CONES + 6 * k + 6]
        if k < n:
            cone = prob.cones[k]
            np.testing.assert_allclose(slot[:3], Q.qrotate_inv(env.state[:4], cone.axis), atol=1e-6)
            assert slot[3] == pytest.approx(cone.half_angle, abs=1e-6)
            s_i = Q.qrotate(env.state[:4], s_b)
            assert slot[4] == pytest.approx(cone.margin(s_i), abs=1e-6)
            assert slot[5] == 1.0
        else:
            assert not slot.any()


@pytest.mark.parametrize("family", ["full-attitude", "pointing-cones"])
def test_error_quaternion_is_the_core_quaternion_function(family):
    env = make(task_distribution=family)
    env.reset(seed=8)
    for _ in range(5):
        obs, *_ = env.step(env.action_space.sample())
    q, prob = env.state[:4], env.problem
    if prob.is_pointing:
        ref = Q.qfrom_two_vectors(prob.sensor_axis, Q.qrotate_inv(q, prob.sensor_target))
    else:
        ref = Q.qcanonical(Q.qmul(Q.qconj(q), prob.qf))
    assert np.array_equal(obs[:4], ref.astype(np.float32))


def test_pointing_error_quaternion_near_antiparallel():
    # sensor x, target within 1e-9 rad of -x: the rotation is π about an axis ⟂ x
    t = np.array([-1.0, 1e-9, 0.0])
    prob = SlewProblem(inertia=[1, 1, 1], sensor_target=t / np.linalg.norm(t))
    obs, info = make().reset(options={"problem": prob})
    np.testing.assert_allclose(obs[:4], [0.0, 0.0, 0.0, 1.0], atol=1e-7)
    assert info["attitude_error"] == pytest.approx(math.pi - 1e-9, abs=1e-15)


@pytest.mark.parametrize("family", ["full-attitude", "pointing-cones"])
def test_observations_stay_in_space_over_random_rollouts(family):
    env = make(task_distribution=family, terminate_on_violation=False)
    env.action_space.seed(0)
    env.reset(seed=0)
    for k in range(1500):
        obs, reward, terminated, _, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs), (k, obs)
        assert np.isfinite(reward)
        if terminated or k % 150 == 149:
            obs, _ = env.reset()
            assert env.observation_space.contains(obs)


# ---------------------------------------------------------------- reward
def test_reward_per_step_is_minus_control_dt_without_shaping():
    env = make(control_dt=0.04, shaping=0.0)
    env.reset(seed=2)
    for _ in range(100):
        _, reward, terminated, _, _ = env.step(env.action_space.sample())
        assert reward == -0.04
        assert not terminated


def test_shaping_is_the_potential_difference():
    env = make(shaping=0.5)
    _, info = env.reset(seed=2)
    phi = -(info["attitude_error"] + info["rate_error"])
    for _ in range(20):
        _, reward, _, _, info = env.step(env.action_space.sample())
        phi_next = -(info["attitude_error"] + info["rate_error"])
        assert reward == pytest.approx(-0.05 + 0.5 * (phi_next - phi), abs=1e-12)
        phi = phi_next


# ---------------------------------------------------------------- constraints
def test_cone_violation_between_control_instants_is_caught():
    # The sensor moves 0.4 rad per control step along the equator; the cone (centre
    # 0.6 rad, half-angle 0.08) lies between the control instants at 0.4 and 0.8
    # rad, both clear by 0.12 rad; only the sub-step at 0.6 rad is inside.
    prob = spin_problem(cone_azimuth=0.6, half_angle=0.08)
    env = make(control_dt=0.4, substeps=4, shaping=0.0)
    env.reset(options={"problem": prob})
    _, reward, terminated, _, info = env.step(np.zeros(3))
    assert not info["violation"] and not terminated and reward == -0.4
    assert info["min_cone_margin"] == pytest.approx(0.12, abs=1e-6)  # at 0.4 rad
    _, reward, terminated, _, info = env.step(np.zeros(3))
    assert info["violation"] and terminated and not info["is_success"]
    # stopped at the violating sub-step (2 of 4): time 0.6, cost 0.2, penalty 10
    assert info["time"] == pytest.approx(0.6, abs=1e-12)
    assert reward == pytest.approx(-0.2 - 10.0, abs=1e-12)
    assert info["min_cone_margin"] == pytest.approx(-0.08, abs=1e-6)
    # the control instants themselves are clear: a check only there would miss it
    clear = make(control_dt=0.4, substeps=4)
    clear.reset(options={"problem": prob.replace(cones=[])})
    for _ in range(2):
        clear.step(np.zeros(3))
        assert prob.cones[0].margin(Q.qrotate(clear.state[:4], prob.sensor_axis)) > 0.11


def test_violation_only_penalised_when_not_terminating():
    prob = spin_problem(cone_azimuth=0.6, half_angle=0.08)
    env = make(control_dt=0.4, substeps=4, shaping=0.0, terminate_on_violation=False,
               violation_penalty=10.0)
    env.reset(options={"problem": prob})
    env.step(np.zeros(3))
    _, reward, terminated, _, info = env.step(np.zeros(3))
    # one sub-step of four inside: 10 × 0.4 × 1/4
    assert info["violation"] and not terminated
    assert reward == pytest.approx(-0.4 - 1.0, abs=1e-12)
    assert info["time"] == pytest.approx(0.8, abs=1e-12)
    _, reward, _, _, info = env.step(np.zeros(3))
    assert not info["violation"] and reward == -0.4


def test_rate_limit_checked_at_substeps():
    prob = SlewProblem(inertia=[1.0, 1.0, 1.0], torque_max=1.0, qf=[0, 0, 0, 1.0], rate_max=0.25)
    env = make(control_dt=0.4, substeps=4, shaping=0.0)
    env.reset(options={"problem": prob})
    _, reward, terminated, _, info = env.step(np.array([0.0, 0.0, 1.0]))
    # ω3 = t reaches 0.3 > 0.25 at the third sub-step
    assert info["violation"] and terminated
    assert info["time"] == pytest.approx(0.3, abs=1e-12)
    assert reward == pytest.approx(-0.3 - 10.0, abs=1e-12)
    assert env.state[6] == pytest.approx(0.3, abs=1e-12)


# ---------------------------------------------------------------- success
def _near_target(angle_deg, omega0=(0.0, 0.0, 0.0)):
    return SlewProblem(inertia=[1, 1, 1], torque_max=1.0, omega0=omega0,
                       qf=Q.qfrom_axis_angle(np.array([0, 1.0, 0]), math.radians(angle_deg)))


def test_success_tolerances():
    env = make(shaping=0.0)
    env.reset(options={"problem": _near_target(0.5)})
    _, reward, terminated, _, info = env.step(np.zeros(3))
    assert info["is_success"] and terminated and reward == pytest.approx(10.0 - 0.05, abs=1e-12)
    env.reset(options={"problem": _near_target(1.5)})
    _, _, terminated, _, info = env.step(np.zeros(3))
    assert not info["is_success"] and not terminated
    # attitude inside the tolerance but ‖ω‖·T = 0.05 > 0.02
    env.reset(options={"problem": _near_target(0.0, omega0=(0.0, 0.0, 0.05))})
    _, _, terminated, _, info = env.step(np.zeros(3))
    assert info["attitude_error"] < math.radians(1) and not info["is_success"] and not terminated


def test_pointing_success_ignores_roll():
    prob = SlewProblem(inertia=[1, 1, 1], torque_max=1.0, q0=Q.qfrom_axis_angle(np.array([1.0, 0, 0]), 2.0),
                       sensor_target=[math.cos(0.01), math.sin(0.01), 0.0])
    env = make()
    env.reset(options={"problem": prob})
    _, _, terminated, _, info = env.step(np.zeros(3))
    assert info["is_success"] and terminated
    assert info["attitude_error"] == pytest.approx(0.01, abs=1e-9)


def test_feedback_controller_reaches_success():
    prob = SlewProblem(inertia=[1, 1, 1], torque_max=1.0,
                       qf=Q.qfrom_axis_angle(np.array([1.0, 2.0, 2.0]) / 3.0, math.radians(90)))
    env = make(shaping=0.0)
    obs, _ = env.reset(options={"problem": prob})
    total = 0.0
    for k in range(400):
        dq, w = obs[0:4].astype(float), obs[4:7].astype(float)
        obs, reward, terminated, _, info = env.step(np.clip(4.0 * dq[1:] - 3.0 * w, -1, 1))
        total += reward
        if terminated:
            break
    assert info["is_success"]
    assert total == pytest.approx(10.0 - 0.05 * (k + 1), abs=1e-9)


# ---------------------------------------------------------------- reset
def test_too_many_cones_raise_value_error_naming_cones():
    cones = [{"axis": [0, 0, 1], "half_angle_deg": 5}] * 5
    prob = {"inertia": [1, 1, 1], "qf": [1, 0, 0, 0], "cones": cones}
    env = make(max_cones=4)
    with pytest.raises(ValueError, match="cones"):
        env.reset(options={"problem": prob})
    make(max_cones=5).reset(options={"problem": prob})


def test_reset_with_problem_dict_and_invalid_problem():
    d = {"inertia": [3, 2, 1], "torque_max": 0.5, "qf": [0, 1, 0, 0],
         "cones": [{"axis": [0, 1, 0], "half_angle_deg": 20}]}
    env = make()
    obs, info = env.reset(options={"problem": d})
    assert env.problem == SlewProblem.from_dict(d)
    assert obs[K.OB_CONES + 5] == 1.0 and obs[K.OB_CONES + 11] == 0.0
    assert info["time"] == 0.0 and not info["is_success"]
    with pytest.raises(ValueError, match="inertia"):
        env.reset(options={"problem": {"inertia": [1, -1, 1], "qf": [1, 0, 0, 0]}})
    with pytest.raises(ValueError, match="options"):
        env.reset(options={"problme": d})


def test_make_with_family_name():
    env = gym.make(ENV_ID, task_distribution="pointing-cones")
    for seed in range(10):
        env.reset(seed=seed)
        prob = env.unwrapped.problem
        assert prob.is_pointing and 1 <= len(prob.cones) <= 3


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="task_distribution"):
        make(task_distribution="nope")
    with pytest.raises(ValueError, match="max_cones"):
        make(task_distribution="pointing-cones", max_cones=2)
    with pytest.raises(ValueError, match="control_dt"):
        make(control_dt=0.0)
    with pytest.raises(ValueError, match="substeps"):
        make(substeps=0)
    with pytest.raises(ValueError, match="render_mode"):
        make(render_mode="ascii")


@pytest.mark.parametrize("key, bad, match", [
    # a fuzz run: these raised float()'s or int()'s own TypeError/OverflowError naming no
    # argument, or were read as numbers without a word ("0.1" as 0.1, True as 1)
    ("control_dt", "0.1", r"^control_dt: must be a positive finite number, got '0.1'"),
    ("control_dt", None, r"^control_dt: must be a positive finite number, got None"),
    ("control_dt", True, r"^control_dt: must be a positive finite number, got True"),
    ("control_dt", [0.1], r"^control_dt: must be a positive finite number"),
    ("substeps", float("nan"), r"^substeps: must be a whole number >= 1, got nan"),
    ("substeps", float("inf"), r"^substeps: must be a whole number >= 1, got inf"),
    ("substeps", None, r"^substeps: must be a whole number >= 1, got None"),
    ("substeps", True, r"^substeps: must be a whole number >= 1, got True"),
    ("max_cones", float("nan"), r"^max_cones: must be a whole number >= 0, got nan"),
    ("max_cones", None, r"^max_cones: must be a whole number >= 0, got None"),
    ("success_bonus", "1", r"^success_bonus: must be a finite number >= 0, got '1'"),
    ("terminate_on_violation", "no", r"^terminate_on_violation: must be True or False"),
    ("control_dt", 10 ** 400, r"^control_dt: must be a positive finite number"),
    ("substeps", 10 ** 400, r"^substeps: must be a whole number <= "),
    ("render_mode", ["human"], r"^render_mode: expected one of"),
    ("task_distribution", {"family": "full-attitude", "max_cone_tries": "5"}, r"^max_cone_tries: "),
])
def test_arguments_of_the_wrong_type_are_refused_by_name(key, bad, match):
    with pytest.raises(ValueError, match=match):
        make(**{key: bad})
    assert make(**{key: {"control_dt": 0.2, "substeps": 2, "max_cones": 3, "success_bonus": 1,
                        "terminate_on_violation": 0, "render_mode": "rgb_array",
                        "task_distribution": {"family": "full-attitude", "max_cone_tries": 5}}[key]}) is not None


# ---------------------------------------------------------------- reproducibility
def _rollout(env, seed, n=300):
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    out = [obs.tobytes(), repr(info)]
    for _ in range(n):
        obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, 3).astype(np.float32))
        out += [obs.tobytes(), r, term, trunc, repr(info)]
        if term or trunc:
            obs, info = env.reset()
            out += [obs.tobytes(), repr(info)]
    return out, env.unwrapped.task_array.tobytes()


@pytest.mark.parametrize("family", ["full-attitude", "pointing-cones"])
def test_seeded_rollouts_are_bit_for_bit_reproducible(family):
    kw = dict(task_distribution=family, max_episode_steps=40)
    a = _rollout(gym.make(ENV_ID, **kw), seed=11)
    b = _rollout(gym.make(ENV_ID, **kw), seed=11)
    c = _rollout(gym.make(ENV_ID, **kw), seed=12)
    assert a == b
    assert a[0][0] != c[0][0]


# ---------------------------------------------------------------- checkers
@pytest.fixture
def headless(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")  # check_env opens a "human" window


@pytest.mark.parametrize("family", ["full-attitude", "pointing-cones"])
def test_gymnasium_and_sb3_checkers_pass_without_warnings(family, headless):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gym.make(ENV_ID, task_distribution=family)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
        sb3_check_env(env.unwrapped, warn=True)
    env.close()
