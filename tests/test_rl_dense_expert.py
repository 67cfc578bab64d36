"""Dense collocation experts with inflated cones (``training.rl.dense_expert``) and cloning from them."""
import math

import numpy as np
import pytest
import yaml

from slew_env import SlewEnv, SlewProblem
from slew_env.core.quaternion import qrotate
from training.rl.dense_expert import (control_of, dagger, inflate_cones, load_records, min_margin_deg,
                                      record_pairs, solve_range)
from training.rl.evaluate import heldout_problems


def _sensor(q, s):
    return np.asarray(qrotate(np.asarray(q, float).copy(), np.asarray(s, float).copy()))


def test_inflation_grows_cones_but_keeps_start_and_target_outside():
    for prob in heldout_problems("pointing-cones", 20, 3):
        d, infl = inflate_cones(prob, 2.5)
        big = SlewProblem.from_dict(d)          # valid: start and target outside every inflated cone
        ends = [_sensor(prob.q0, prob.sensor_axis), np.asarray(prob.target_direction)]
        for c0, c1, extra in zip(prob.cones, big.cones, infl):
            assert 0.0 <= extra <= 2.5
            assert c1.half_angle == pytest.approx(c0.half_angle + math.radians(extra), abs=1e-12)
            room = min(math.degrees(math.acos(np.clip(e @ np.asarray(c0.axis), -1, 1)) - c0.half_angle)
                       for e in ends)
            # full margin where there is room for it, else up to the endpoint slack
            assert extra == pytest.approx(min(2.5, room - 0.25), abs=1e-9) or (extra == 0.0 and room <= 0.25)


def test_control_model_is_the_collocation_quadratic_and_zero_after_tf():
    t = np.linspace(0.0, 1.0, 5)                      # two intervals: nodes 0, 0.5, 1; midpoints .25, .75
    u = np.array([[0.0, 1, -1], [1.0, 1, -1], [0.0, 1, -1], [0.5, -1, 1], [0.0, -1, 1]])
    rec = {"t": t.tolist(), "u": u.tolist(), "tf": 1.0}
    f = control_of(rec)
    np.testing.assert_allclose(f(t[:-1]), u[:-1], atol=1e-12)     # interpolates node and midpoint values
    # the quadratic through (0, 0), (.25, 1), (.5, 0) on the first interval is 16 t (0.5 - t)
    assert f(0.125)[0, 0] == pytest.approx(0.75)
    np.testing.assert_array_equal(f(np.array([1.0, 1.5])), 0.0)


@pytest.fixture(scope="module")
def dense_records(tmp_path_factory):
    path = tmp_path_factory.mktemp("dense") / "d.jsonl"
    recs = solve_range("pointing-cones", 1, 2, path, margin_deg=2.0, progress=False)
    assert [r["index"] for r in recs] == [0, 1]
    return path, recs


def test_dense_answers_clear_the_true_cones_by_the_margin(dense_records):
    path, recs = dense_records
    for r in recs:
        assert r["success"], r.get("message")
        assert len(r["t"]) == len(r["q"]) == len(r["omega"]) == len(r["u"])
        assert r["t"][0] == 0.0 and r["t"][-1] == pytest.approx(r["tf"])
        prob = SlewProblem.from_dict(r["problem"])
        assert r["min_margin_deg"] == pytest.approx(min_margin_deg(prob, np.asarray(r["q"])))
        # the inflated problem's path keeps (almost) its inflation from the true cones at the samples
        assert r["min_margin_deg"] > min(r["inflation_deg"]) - 0.05
    # resumable: asking again solves nothing and returns the same records
    again = solve_range("pointing-cones", 1, 2, path, margin_deg=2.0, progress=False)
    assert [a["tf"] for a in again] == [r["tf"] for r in recs]


def test_pairs_are_the_environment_observation_and_the_step_averaged_control(dense_records):
    _, recs = dense_records
    r = recs[0]
    prob = SlewProblem.from_dict(r["problem"])
    obs, act = record_pairs(r, n_sub=16, n_rest=3)
    assert obs.shape == (len(r["t"]) + 3, 51) and act.shape == (len(r["t"]) + 3, 3)
    env = SlewEnv(task_distribution="pointing-cones")
    o0, _ = env.reset(options={"problem": prob})
    np.testing.assert_allclose(obs[0], o0, atol=1e-5)             # the state at t = 0 is the start
    dt = 0.05 * prob.time_unit
    ts = (np.arange(16) + 0.5) / 16 * dt
    np.testing.assert_allclose(act[0], control_of(r)(ts).mean(axis=0) / np.asarray(prob.torque_max), atol=1e-6)
    assert np.all(np.abs(act) <= 1.0)
    np.testing.assert_array_equal(act[-3:], 0.0)                  # at rest on the target: no torque
    assert obs[-1][4:7].tolist() == [0.0, 0.0, 0.0]
    # flying the expert's averaged control reaches the neighbourhood of the target without a violation
    u_of = control_of(r)
    n = int(math.ceil(r["tf"] / dt))
    for k in range(n):
        _, _, term, _, info = env.step((u_of(k * dt + ts).mean(axis=0) / np.asarray(prob.torque_max)).astype(np.float32))
        assert not info["violation"]
        if term:
            break
    assert info["attitude_error"] < math.radians(3.0)


def test_dense_bc_pretrain_and_a_dagger_round(dense_records, tmp_path):
    pytest.importorskip("stable_baselines3")
    from training.rl.train import train

    path, _ = dense_records
    tiny = {"n_envs": 2, "n_timesteps": 0, "policy": "MlpPolicy",
            "policy_kwargs": {"net_arch": {"pi": [32, 32], "vf": [32, 32]}},
            "hyperparameters": {"n_steps": 64, "batch_size": 64, "n_epochs": 1},
            "normalize": {"norm_obs": True, "norm_reward": False},
            "env_kwargs": {"max_episode_steps": 50}, "eval": None, "checkpoint": None,
            "bc": {"expert": "dense", "margin_deg": 2.0, "epochs": 5}}
    cfg = tmp_path / "ppo.yaml"
    cfg.write_text(yaml.safe_dump({"pointing-cones": tiny}))
    info = train("ppo", "pointing-cones", config=cfg, timesteps=0, out=tmp_path / "bc", bc_pretrain=2,
                 expert_data=path)
    bc = info["bc"]
    assert bc["expert"] == "dense" and bc["n_solved"] == 2
    assert bc["train_mse_last"] < bc["train_mse_first"]
    # a DAgger round: expert answers from states the (poor) cloned policy visits, same targets and cones
    out = tmp_path / "dagger.jsonl"
    res = dagger(tmp_path / "bc", "pointing-cones", 5, 1, out, n_pick=1, margin_deg=2.0, progress=False)
    assert res["new_records"] == len(load_records(out)) <= 1
    for r in load_records(out):
        assert r["index"] == 0 and r["seed"] == 5
        base = heldout_problems("pointing-cones", 1, 5)[0]
        p = SlewProblem.from_dict(r["problem"])
        assert p.cones == base.cones and np.allclose(p.target_direction, base.target_direction)
    # DAgger records are added with bc.extra_data
    info2 = train("ppo", "pointing-cones", config=cfg, timesteps=0, out=tmp_path / "bc2", bc_pretrain=2,
                  expert_data=path, overrides=[f"bc.extra_data=[{out}]"])
    assert info2["bc"]["n_extra_records"] == res["new_records"]


def test_a_line_cut_by_a_kill_is_skipped_and_the_next_record_starts_a_new_line(tmp_path):
    from training.rl.dense_expert import _open_append

    path = tmp_path / "d.jsonl"
    path.write_text('{"index": 0, "success": false}\n{"index": 1, "succ')
    with _open_append(path) as f:
        f.write('{"index": 2, "success": false}\n')
    assert [r["index"] for r in load_records(path)] == [0, 2]


class _Law:
    """A policy stand-in: the PD law on the raw observation; ``dither`` adds ±0.6 torque on
    alternate steps, so it reaches the target but never comes to rest there."""

    def __init__(self, dither):
        self.dither = dither
        self.k = 0

    def predict(self, o, deterministic=True):
        from slew_env.core import env_kernels as K
        o = np.asarray(o, float)[0]
        dq, w = o[K.OB_DQ:K.OB_DQ + 4], o[K.OB_W:K.OB_W + 3]
        ang = 2.0 * math.atan2(np.linalg.norm(dq[1:]), dq[0])
        a = 5.0 * ang * dq[1:] / max(np.linalg.norm(dq[1:]), 1e-12) - 3.0 * w
        self.k += 1
        if self.dither:
            a = a + 0.6 * (-1) ** self.k
        return np.clip(a, -1, 1)[None], None


def test_terminal_dagger_states_are_near_the_target_of_episodes_that_failed():
    from slew_env.shield import ConeShield
    from training.rl.dense_expert import visited_states

    prob = SlewProblem(inertia=(0.6, 0.9, 1.0), torque_max=1.0, q0=[1, 0, 0, 0], sensor_axis=[1, 0, 0],
                       sensor_target=[0.0, 1.0, 0.0], cones=[{"axis": [0, 0, 1], "half_angle_deg": 20.0}])
    env = ConeShield(SlewEnv(task_distribution="pointing-cones"))
    rng = np.random.default_rng(0)
    states, outcome = visited_states(_Law(dither=True), None, env, prob, 4, rng, terminal_deg=2.0)
    assert outcome == "timeout" and len(states) == 4
    tgt = np.asarray(prob.target_direction, float)
    for x in states:
        err = math.degrees(math.acos(np.clip(_sensor(x[:4], prob.sensor_axis) @ tgt, -1, 1)))
        assert 0.0 < err <= 2.0 + 1e-9
    # on the way (the default): states more than 0.5° from the target
    states, _ = visited_states(_Law(dither=True), None, env, prob, 4, rng)
    assert all(math.degrees(math.acos(np.clip(_sensor(x[:4], prob.sensor_axis) @ tgt, -1, 1))) > 0.5
               for x in states)
    # a policy that succeeds gives no terminal states
    states, outcome = visited_states(_Law(dither=False), None, env, prob, 4, rng, terminal_deg=2.0)
    assert outcome == "success" and states == []
