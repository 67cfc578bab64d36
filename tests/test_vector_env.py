"""SlewVectorEnv: Gymnasium vector semantics, equality with N single environments."""
import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import slew_env
from slew_env import SlewEnv, SlewProblem, SlewVectorEnv

ENV_ID = "slew_env/Slew-v0"
REPO = Path(__file__).resolve().parents[1]
# Cones so tight that about one sampling block in ten fails, so the vector env's
# refill-and-retry path runs often.
TIGHT = {"family": "pointing-cones", "n_cones": (4, 4), "cone_half_angle_deg": (26, 30),
         "angle_deg": (60, 66), "path_cone_prob": 1.0, "max_cone_tries": 5}


def assert_same_step(a, b):
    for x, y in zip(a[:4], b[:4]):
        assert np.array_equal(x, y), (x, y)
    assert set(a[4]) == set(b[4])
    for key in a[4]:
        assert a[4][key].dtype == b[4][key].dtype, key
        assert np.array_equal(a[4][key], b[4][key]), key


def test_make_vec_uses_the_batched_env():
    env = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode="vector_entry_point")
    assert isinstance(env.unwrapped, SlewVectorEnv)
    assert env.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert env.single_observation_space == SlewEnv().observation_space
    assert env.single_action_space == SlewEnv().action_space
    obs, infos = env.reset(seed=0)
    assert obs.shape == (3, 51) and obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    obs, rew, term, trunc, infos = env.step(env.action_space.sample())
    assert rew.shape == term.shape == trunc.shape == (3,)
    assert term.dtype == trunc.dtype == np.bool_
    for key in ("is_success", "violation", "min_cone_margin", "attitude_error", "rate_error", "time"):
        assert infos[key].shape == (3,) and infos["_" + key].all()
    assert gym.make_vec(ENV_ID, num_envs=2).unwrapped.__class__ is SlewVectorEnv  # the default mode


@pytest.mark.parametrize("kwargs", [
    {"task_distribution": "full-attitude"},
    {"task_distribution": "pointing-cones"},
    {"task_distribution": TIGHT, "terminate_on_violation": False},
])
def test_batched_env_equals_sync_vector_env(kwargs, monkeypatch):
    """Same seeds and actions: identical to SyncVectorEnv of single envs with TimeLimit, bit for bit."""
    retries = []
    retry = slew_env.vector_env._retry_reset
    monkeypatch.setattr(slew_env.vector_env, "_retry_reset", lambda *a: retries.append(1) or retry(*a))
    n = 5
    batched = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point",
                           max_episode_steps=12, pool_blocks=1, **kwargs)
    sync = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="sync", max_episode_steps=12, **kwargs)
    ra, rb = batched.reset(seed=42), sync.reset(seed=42)
    assert np.array_equal(ra[0], rb[0])
    rng = np.random.default_rng(0)
    dones = 0
    for _ in range(60):
        actions = rng.uniform(-1, 1, (n, 3)).astype(np.float32)
        a, b = batched.step(actions), sync.step(actions)
        assert_same_step(a, b)
        dones += int(np.sum(a[2] | a[3]))
    assert dones >= 2 * n  # several autoresets happened
    if kwargs["task_distribution"] is TIGHT:
        assert retries  # some reset ran out of pre-drawn blocks and was finished from Python
    # a later reset without a seed continues each copy's generator in both
    assert np.array_equal(batched.reset()[0], sync.reset()[0])


def test_batched_env_equals_single_envs_with_given_problems():
    probs = [SlewEnv(task_distribution="pointing-cones").task_distribution.sample(s) for s in range(4)]
    probs[1] = {"inertia": [1, 2, 3], "torque_max": [0.5, 1, 1], "torque_norm": 2, "qf": [0, 0, 1, 0]}
    vec = SlewVectorEnv(num_envs=4, terminate_on_violation=False)
    singles = [SlewEnv(terminate_on_violation=False) for _ in range(4)]
    obs, _ = vec.reset(options={"problems": probs})
    for i, env in enumerate(singles):
        assert np.array_equal(obs[i], env.reset(options={"problem": probs[i]})[0])
    rng = np.random.default_rng(3)
    for _ in range(50):
        act = rng.uniform(-1.2, 1.2, (4, 3))
        obs, rew, term, _, infos = vec.step(act)
        for i, env in enumerate(singles):
            o, r, t, _, info = env.step(act[i])
            assert np.array_equal(obs[i], o) and rew[i] == r and term[i] == t
            assert infos["attitude_error"][i] == info["attitude_error"]
            assert infos["min_cone_margin"][i] == info["min_cone_margin"]
        assert not term.any()


def test_parallel_and_serial_kernels_agree():
    kw = dict(num_envs=70, task_distribution="pointing-cones", max_episode_steps=15)
    par, ser = SlewVectorEnv(parallel=True, **kw), SlewVectorEnv(parallel=False, **kw)
    assert np.array_equal(par.reset(seed=1)[0], ser.reset(seed=1)[0])
    rng = np.random.default_rng(1)
    for _ in range(40):
        act = rng.uniform(-1, 1, (70, 3)).astype(np.float32)
        assert_same_step(par.step(act), ser.step(act))


def test_async_make_vec_matches_batched():
    kw = dict(task_distribution="pointing-cones", max_episode_steps=8)
    batched = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", **kw)
    asyn = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="async", **kw)
    try:
        assert np.array_equal(batched.reset(seed=5)[0], asyn.reset(seed=5)[0])
        rng = np.random.default_rng(2)
        for _ in range(20):
            act = rng.uniform(-1, 1, (2, 3)).astype(np.float32)
            assert_same_step(batched.step(act), asyn.step(act))
    finally:
        asyn.close()


def test_reset_options_problem_mask_and_errors():
    vec = SlewVectorEnv(num_envs=3)
    prob = SlewProblem(inertia=[1, 1, 1], qf=[0, 1, 0, 0])
    obs, _ = vec.reset(seed=0, options={"problem": prob})
    assert all(np.array_equal(vec.tasks[i], prob.to_task_array(4)) for i in range(3))
    assert np.array_equal(obs[0], obs[2])
    vec.step(np.ones((3, 3)))
    before = vec.states
    obs2, _ = vec.reset(options={"reset_mask": [False, True, False]})
    after = vec.states
    assert np.array_equal(before[0], after[0]) and not np.array_equal(before[1], after[1])
    five = [{"axis": [0, 0, 1], "half_angle_deg": 5}] * 5
    tasks, states = vec.tasks, vec.states
    with pytest.raises(ValueError, match="cones"):
        vec.reset(options={"problems": [prob.replace(qf=[0, 0, 1, 0]),
                                        {"inertia": [1, 1, 1], "qf": [1, 0, 0, 0], "cones": five}, None]})
    assert np.array_equal(vec.tasks, tasks) and np.array_equal(vec.states, states)  # nothing changed
    with pytest.raises(ValueError, match="problems"):
        vec.reset(options={"problems": [prob]})
    with pytest.raises(ValueError, match="seed"):
        vec.reset(seed=[1, 2])


def test_seeded_batched_rollouts_reproducible():
    def run():
        vec = SlewVectorEnv(num_envs=8, task_distribution="pointing-cones", max_episode_steps=10)
        out = [vec.reset(seed=[3, 1, 4, 1, 5, 9, 2, 6])[0]]
        rng = np.random.default_rng(0)
        for _ in range(30):
            out.extend(vec.step(rng.uniform(-1, 1, (8, 3)))[:4])
        return out
    a, b = run(), run()
    assert all(np.array_equal(x, y) for x, y in zip(a, b))


SB3_SCRIPT = textwrap.dedent("""
    import numpy as np
    import slew_env  # registers slew_env/Slew-v0; spawned workers import it again
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    if __name__ == "__main__":
        for method in ("spawn",):
            venv = make_vec_env("slew_env/Slew-v0", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv,
                                vec_env_kwargs={"start_method": method},
                                env_kwargs={"task_distribution": "pointing-cones"})
            obs = venv.reset()
            assert obs.shape == (2, 51), obs.shape
            for _ in range(5):
                obs, rew, done, infos = venv.step(np.zeros((2, 3), dtype=np.float32))
            assert "is_success" in infos[0]
            venv.close()
        print("ok")
""")


def test_sb3_subproc_vec_env_in_spawned_workers(tmp_path):
    script = tmp_path / "sb3_subproc.py"
    script.write_text(SB3_SCRIPT)
    res = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                         timeout=240, env={**__import__("os").environ, "PYTHONPATH": str(REPO)})
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip().endswith("ok")


# ---------------------------------------------------------------- arguments checked by name
@pytest.mark.parametrize("kw, match", [
    # a fuzz run: bool() took text, None, NaN and 2 as booleans ("no" switched threads on)
    ({"parallel": "no"}, r"^parallel: must be True or False, got 'no'"),
    ({"parallel": "false"}, r"^parallel: must be True or False, got 'false'"),
    ({"parallel": None}, r"^parallel: must be True or False, got None"),
    ({"parallel": float("nan")}, r"^parallel: must be True or False, got nan"),
    ({"parallel": 2}, r"^parallel: must be True or False, got 2"),
    # int()/float() raised their own TypeError, or named no argument
    ({"num_envs": None}, r"^num_envs: must be a whole number >= 1, got None"),
    ({"num_envs": float("nan")}, r"^num_envs: must be a whole number >= 1, got nan"),
    ({"num_envs": float("inf")}, r"^num_envs: must be a whole number >= 1, got inf"),
    ({"num_envs": "2"}, r"^num_envs: must be a whole number >= 1, got '2'"),
    ({"num_envs": 2.5}, r"^num_envs: must be a whole number >= 1, got 2.5"),
    ({"num_envs": True}, r"^num_envs: must be a whole number >= 1, got True"),
    ({"pool_blocks": None}, r"^pool_blocks: must be a whole number >= 1, got None"),
    ({"pool_blocks": float("inf")}, r"^pool_blocks: must be a whole number >= 1, got inf"),
    ({"pool_blocks": "4"}, r"^pool_blocks: must be a whole number >= 1, got '4'"),
    ({"control_dt": None}, r"^control_dt: must be a positive finite number, got None"),
    ({"control_dt": "0.05"}, r"^control_dt: must be a positive finite number, got '0.05'"),
    ({"max_episode_steps": "10"}, r"^max_episode_steps: must be a whole number >= 1, got '10'"),
    ({"max_episode_steps": 1.5}, r"^max_episode_steps: must be a whole number >= 1, got 1.5"),
    ({"render_mode": ["rgb_array"]}, r"^render_mode: expected one of"),
    ({"task_distribution": {"family": "pointing-cones", "path_offset": "0.2"}}, r"^path_offset: "),
])
def test_constructor_arguments_are_checked_by_name(kw, match):
    with pytest.raises(ValueError, match=match):
        SlewVectorEnv(**{"num_envs": 2, **kw})


def test_good_constructor_arguments_are_kept():
    vec = SlewVectorEnv(num_envs=np.int64(2), parallel=np.bool_(False), pool_blocks=2.0, max_episode_steps=7.0)
    assert vec.num_envs == 2 and type(vec.num_envs) is int and vec.parallel is False
    assert vec.max_episode_steps == 7 and type(vec.max_episode_steps) is int
    assert SlewVectorEnv(num_envs=1, parallel=True).parallel is True


@pytest.fixture(scope="module")
def vec3():
    vec = SlewVectorEnv(num_envs=3)
    vec.reset(seed=0)
    return vec


def test_step_before_reset_asks_for_a_reset():
    import gymnasium as gym
    vec = SlewVectorEnv(num_envs=2)
    with pytest.raises(gym.error.ResetNeeded, match="call reset"):
        vec.step(np.zeros((2, 3)))
    vec.reset(seed=1)
    obs, *_ = vec.step(np.zeros((2, 3)))
    assert obs.shape[0] == 2


@pytest.mark.parametrize("actions", [
    # a fuzz run: (3, 1) and (3,) were broadcast to (3, 3) silently, other shapes gave numpy's
    # broadcast message, text/None/complex numpy's own TypeError (complex a warning)
    np.array([[1.0], [0.0], [-1.0]]), np.zeros(3), np.zeros((1, 3)), np.zeros((3, 4)), np.zeros((2, 3)),
    np.zeros((3, 3, 1)), 0.5, "abc", None, {"a": 1}, np.zeros((3, 3)) + 1j, [[1j, 0, 0]] * 3,
    np.full((3, 3), "1"), [["1", 0, 0]] * 3, np.ones((3, 3), dtype=bool), [[True, 0.5, 0]] * 3,
    [[None, 0, 0]] * 3, [[1, 0, 0], [1, 0], [1]],
])
def test_actions_of_the_wrong_shape_or_type_are_refused_by_name(vec3, actions):
    before = vec3.states
    with pytest.raises(ValueError, match=r"^actions: expected real numbers of shape \(3, 3\), got"):
        vec3.step(actions)
    assert np.array_equal(vec3.states, before)


def test_actions_of_real_numbers_in_any_container_are_equal():
    ref = np.array([[1.0, 0.0, -1.0], [0.5, 0.5, 0.0], [0.0, 0.0, 1.0]])
    results = []
    for actions in (ref, ref.tolist(), ref.astype(np.float32), (ref * 2).astype(np.int64) / 2,
                    np.array([[1, 0, -1], [0, 0, 0], [0, 0, 1]]), ref.astype(object)):
        vec = SlewVectorEnv(num_envs=3)
        vec.reset(seed=9)
        results.append((vec.step(actions)[0], np.asarray(actions, dtype=float)))
    for obs, act in results:
        if np.array_equal(act, ref):
            assert np.array_equal(obs, results[0][0])
    assert not np.array_equal(results[4][0], results[0][0])   # the integer actions differ


@pytest.mark.parametrize("kw, match", [
    ({"seed": 1.5}, r"^seed: expected None, a whole number >= 0 or a list of 3 of them"),
    ({"seed": "12"}, r"^seed: expected None, a whole number >= 0 or a list of 3 of them"),
    ({"seed": True}, r"^seed: expected None, a whole number >= 0 or a list of 3 of them"),
    ({"seed": -1}, r"^seed: expected None, a whole number >= 0 or a list of 3 of them"),
    ({"seed": [1, 2, 1.5]}, r"^seed: a list of seeds must hold whole numbers >= 0 or None, got 1.5"),
    ({"seed": [1, 2, "3"]}, r"^seed: a list of seeds must hold whole numbers >= 0 or None, got '3'"),
    ({"seed": [1, 2]}, r"^seed: expected 3 seeds \(one per copy\), got 2"),
    ({"options": [1]}, r"^options: expected None or a dict, got \[1\]"),
    ({"options": "problems"}, r"^options: expected None or a dict, got 'problems'"),
    ({"options": {"problme": None}}, r"^options: unknown key\(s\) \['problme'\]"),
    ({"options": {"problems": 3}}, r"^problems: expected a list of 3 entries"),
    ({"options": {"problems": "abc"}}, r"^problems: expected a list of 3 entries"),
    ({"options": {"problems": [3, None, None]}}, r"^problems\[0\]: problem: expected a SlewProblem or a dict"),
    ({"options": {"problem": "abc"}}, r"^problem: expected a SlewProblem or a dict"),
    ({"options": {"reset_mask": "abc"}}, r"^reset_mask: expected 3 booleans"),
    ({"options": {"reset_mask": ["false", "true", "true"]}}, r"^reset_mask: expected 3 booleans"),
    ({"options": {"reset_mask": [0.5, 1, 1]}}, r"^reset_mask: expected 3 booleans"),
    ({"options": {"reset_mask": [None, True, True]}}, r"^reset_mask: expected 3 booleans"),
    ({"options": {"reset_mask": [True, True]}}, r"^reset_mask: expected shape \(3,\)"),
])
def test_reset_arguments_are_checked_by_name(vec3, kw, match):
    tasks, states = vec3.tasks, vec3.states
    with pytest.raises(ValueError, match=match):
        vec3.reset(**kw)
    assert np.array_equal(vec3.tasks, tasks) and np.array_equal(vec3.states, states)


def test_reset_accepts_the_documented_seed_forms():
    a, b = SlewVectorEnv(num_envs=3), SlewVectorEnv(num_envs=3)
    assert np.array_equal(a.reset(seed=np.int64(4))[0], b.reset(seed=[4, 5, 6])[0])
    assert np.array_equal(a.reset(seed=np.array([7, 8, 9]))[0], b.reset(seed=(7, np.int32(8), 9))[0])
    a.reset(seed=[1, None, 3])
    for mask in ([1, 0, 1], np.array([True, False, True]), [np.bool_(True), False, True]):
        before = a.states
        after = a.reset(options={"reset_mask": mask}) and a.states
        assert np.array_equal(after[1], before[1])
        assert not np.array_equal(after[0], before[0]) and not np.array_equal(after[2], before[2])


def test_a_terminated_copy_is_autoreset_not_stepped_on():
    # SlewEnv raises ResetNeeded after termination; the batch keeps Gymnasium's next-step
    # autoreset: reward 0, not terminated, a new task (the bonus is never paid twice)
    drift = {"inertia": [1, 1, 1], "qf": [1, 0, 0, 0], "omega0": [0, 0, 0.001]}
    vec = SlewVectorEnv(num_envs=2)
    vec.reset(seed=0, options={"problems": [drift, None]})
    _, rew, term, _, infos = vec.step(np.zeros((2, 3)))
    assert term.tolist() == [True, False] and infos["is_success"][0] and rew[0] > 9.0
    obs, rew, term, trunc, infos = vec.step(np.zeros((2, 3)))
    assert rew[0] == 0.0 and not term[0] and not trunc[0] and infos["time"][0] == 0.0
    assert not np.array_equal(vec.tasks[0], SlewProblem.from_dict(drift).to_task_array(4))
    assert vec.step(np.zeros((2, 3)))[1][0] < 0.0
