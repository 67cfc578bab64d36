"""Smoke tests of ``slew train-rl``: PPO and SAC train a few thousand steps, save, reload, evaluate, resume.

Budget: the whole file well under two minutes on two cores.
"""
import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

from training.rl.train import find_checkpoint_files, load_config, train  # noqa: E402

PPO_CFG = {
    "n_envs": 2, "n_timesteps": 4096, "policy": "MlpPolicy",
    "policy_kwargs": {"net_arch": {"pi": [32, 32], "vf": [32, 32]}, "activation_fn": "tanh", "log_std_init": -1.0},
    "hyperparameters": {"learning_rate": 0.000123, "n_steps": 256, "batch_size": 128, "n_epochs": 2,
                        "gamma": 0.987},
    "normalize": {"norm_obs": True, "norm_reward": False, "clip_obs": 10.0},
    "env_kwargs": {"control_dt": 0.05, "shaping": 1.0, "max_episode_steps": 100},
    "eval": {"eval_freq": 2048, "n_eval_episodes": 2},
    "checkpoint": {"save_freq": 2048},
}
SAC_CFG = {
    "n_envs": 1, "n_timesteps": 2000, "policy": "MlpPolicy", "policy_kwargs": {"net_arch": [32, 32]},
    "hyperparameters": {"learning_rate": 0.000456, "buffer_size": 5000, "learning_starts": 300, "batch_size": 64,
                        "train_freq": 1, "gradient_steps": 1, "gamma": 0.98},
    "normalize": {"norm_obs": True, "norm_reward": False},
    "env_kwargs": {"max_episode_steps": 100},
    "eval": {"eval_freq": 1000, "n_eval_episodes": 2},
    "checkpoint": {"save_freq": 1000},
}


def _write_cfg(tmp_path, algo, entry):
    path = tmp_path / f"{algo}.yaml"
    path.write_text(yaml.safe_dump({"full-attitude": entry}))
    return path


def _few_episodes(run_dir, n=3):
    """Reload the saved policy (with VecNormalize) and fly it on n held-out problems."""
    from slew_env import SlewEnv
    from training.rl.evaluate import heldout_problems, load_policy, rollout

    model, vn, cfg = load_policy(run_dir)
    assert vn is not None and vn.training is False and vn.norm_reward is False
    env = SlewEnv(control_dt=cfg["env_kwargs"].get("control_dt", 0.05))
    results = [rollout(model, vn, env, p, max_steps=60) for p in heldout_problems("full-attitude", n, 5)]
    assert len(results) == n
    for r in results:
        assert r["steps"] >= 1 and np.isfinite(r["time"]) and isinstance(r["success"], bool)
    return model, vn


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ppo")
    cfg = _write_cfg(tmp, "ppo", PPO_CFG)
    out = tmp / "run"
    info = train("ppo", "full-attitude", config=cfg, seed=3, out=out)
    return tmp, out, info


def test_ppo_trains_saves_reloads_and_evaluates(ppo_run):
    _, out, info = ppo_run
    assert info["num_timesteps"] >= 4096
    for f in ("model.zip", "vecnormalize.pkl", "config.yaml", "train_info.json", "eval/evaluations.npz",
              "best/best_model.zip", "best/vecnormalize.pkl"):
        assert (out / f).exists(), f
    ck = sorted((out / "checkpoints").glob("rl_model_*_steps.zip"))
    vns = sorted((out / "checkpoints").glob("rl_model_vecnormalize_*_steps.pkl"))
    assert ck and len(vns) == len(ck)
    ti = json.loads((out / "train_info.json").read_text())
    assert ti["seed"] == 3 and ti["wall_time_s"] > 0 and ti["versions"]["stable_baselines3"]
    resolved = yaml.safe_load((out / "config.yaml").read_text())
    assert resolved["algo"] == "ppo" and resolved["seed"] == 3 and resolved["hyperparameters"]["n_steps"] == 256
    try:
        import tensorboard  # noqa: F401
        assert any((out / "tb").rglob("events.out.tfevents*"))
    except ImportError:
        pass
    model, vn = _few_episodes(out)
    # the config file's entries reached the model
    assert model.n_steps == 256 and model.batch_size == 128 and model.n_epochs == 2
    assert model.gamma == pytest.approx(0.987)
    assert model.learning_rate == pytest.approx(0.000123)
    assert model.policy.log_std.detach().numpy() == pytest.approx(-1.0, abs=0.2)
    # the evaluation statistics are the training statistics, frozen
    from stable_baselines3.common.vec_env import VecNormalize
    saved = VecNormalize.load(str(out / "vecnormalize.pkl"), vn.venv)
    np.testing.assert_array_equal(saved.obs_rms.mean, vn.obs_rms.mean)
    assert vn.obs_rms.count > 4096


def test_resume_without_out_goes_on_in_the_run_directory(ppo_run):
    # a user's report: without --out a resumed run went to runs/ppo-full-attitude-seedN, leaving
    # the run's own train_info.json at its old count and writing no previous_runs
    import shutil
    tmp, out, info = ppo_run
    run = tmp / "own_dir_copy"
    shutil.copytree(out, run)
    info2 = train("ppo", "full-attitude", resume=run, timesteps=256)
    assert Path(info2["out"]) == run
    saved = json.loads((run / "train_info.json").read_text())
    assert saved["num_timesteps"] == info2["num_timesteps"] > info["num_timesteps"]
    assert saved["previous_runs"][0]["num_timesteps"] == info["num_timesteps"]


def test_resume_continues_the_timestep_count(ppo_run):
    tmp, out, info = ppo_run
    first = sorted((out / "checkpoints").glob("rl_model_*_steps.zip"),
                   key=lambda p: int(re.search(r"_(\d+)_steps", p.name).group(1)))[0]
    steps0 = int(re.search(r"_(\d+)_steps", first.name).group(1))
    model_path, vn_path, _, run_dir = find_checkpoint_files(first)
    assert vn_path is not None and vn_path.name == f"rl_model_vecnormalize_{steps0}_steps.pkl"
    assert run_dir == out
    out2 = tmp / "resumed"
    info2 = train("ppo", "full-attitude", resume=first, timesteps=512, out=out2)
    assert info2["steps_before"] == steps0
    assert info2["num_timesteps"] >= steps0 + 512
    assert info2["num_timesteps"] - steps0 < 4096          # continued, not restarted from 0 + a full run
    assert info2["seed"] == 3                               # the resumed run's seed
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
    from training.rl.bc import _env_for
    m = PPO.load(str(out2 / "model.zip"), device="cpu")
    assert m.num_timesteps == info2["num_timesteps"] and m.n_steps == 256
    venv = DummyVecEnv([lambda: _env_for({})])
    before = VecNormalize.load(str(vn_path), venv)
    after = VecNormalize.load(str(out2 / "vecnormalize.pkl"), venv)
    assert after.obs_rms.count > before.obs_rms.count      # statistics loaded, then updated


def test_sac_trains_saves_reloads_and_evaluates(tmp_path):
    cfg = _write_cfg(tmp_path, "sac", SAC_CFG)
    out = tmp_path / "sac"
    from training.cli import main
    rc = main(["train-rl", "--algo", "sac", "--family", "full-attitude", "--config", str(cfg), "--seed", "1",
               "--out", str(out), "--progress-bar"])
    assert rc == 0
    info = json.loads((out / "train_info.json").read_text())
    assert info["num_timesteps"] >= 2000 and info["algo"] == "sac"
    assert (out / "vecnormalize.pkl").exists() and (out / "eval" / "evaluations.npz").exists()
    assert list((out / "checkpoints").glob("rl_model_vecnormalize_*_steps.pkl"))
    model, _ = _few_episodes(out)
    assert model.learning_rate == pytest.approx(0.000456)
    assert model.batch_size == 64 and model.learning_starts == 300 and model.buffer_size == 5000


def test_config_files_and_overrides():
    for algo in ("ppo", "sac"):
        for fam in ("full-attitude", "pointing-cones"):
            cfg = load_config(algo, fam)
            assert cfg["n_envs"] >= 1 and cfg["hyperparameters"] and "env_kwargs" in cfg
    with pytest.raises(ValueError, match="no entry"):
        load_config("ppo", "nope")
    from training.rl.train import apply_overrides
    cfg = apply_overrides(load_config("ppo", "full-attitude"), ["hyperparameters.gamma=0.9", "env_kwargs.shaping=0"])
    assert cfg["hyperparameters"]["gamma"] == 0.9 and cfg["env_kwargs"]["shaping"] == 0


def test_subproc_vec_env(tmp_path):
    """SubprocVecEnv workers register Slew-v0 themselves (env id "slew_env:slew_env/Slew-v0")."""
    cfg = dict(PPO_CFG, n_timesteps=512, eval=None, checkpoint=None)
    info = train("ppo", "full-attitude", config=_write_cfg(tmp_path, "ppo", cfg), out=tmp_path / "run",
                 vec_env="subproc")
    assert info["vec_env"] == "subproc" and info["num_timesteps"] >= 512


def test_ppo_on_cones_with_filter_capture_and_features_trains_reloads_and_evaluates(tmp_path):
    """The pointing-cones recipe's parts (ConeShield, CaptureHandover, HighGainFeatures) survive
    training, saving and reloading, and evaluate-rl flies the network through them."""
    from training.rl.evaluate import evaluate, load_policy
    from training.rl.features import HighGainFeatures

    entry = dict(PPO_CFG, n_timesteps=1024, eval=None, checkpoint=None)
    entry["policy_kwargs"] = dict(PPO_CFG["policy_kwargs"], features_extractor_class="high_gain")
    entry["shield"] = {"margin_deg": 0.5}
    entry["capture"] = {"deg": 1.0}
    path = tmp_path / "ppo.yaml"
    path.write_text(yaml.safe_dump({"pointing-cones": entry}))
    train("ppo", "pointing-cones", config=path, seed=1, out=tmp_path / "run")
    model, vn, cfg = load_policy(tmp_path / "run")
    assert isinstance(model.policy.features_extractor, HighGainFeatures)
    res = evaluate(tmp_path / "run", n=2, out=tmp_path / "ev", plot_k=0, solutions=tmp_path / "sol.jsonl",
                   progress=False, max_steps=40)
    assert res["shield"]["margin_deg"] == 0.5 and res["capture"]["deg"] == 1.0
    assert res["summary"]["n"] == 2 and res["summary"]["solver_ok"] == 2
    off = evaluate(tmp_path / "run", n=2, out=tmp_path / "ev-off", plot_k=0, solutions=tmp_path / "sol.jsonl",
                   progress=False, max_steps=40, shield="off", capture="off")
    assert off["shield"] is None and off["capture"] is None
    assert all(e["shield_steps"] == 0 and e["captured_steps"] == 0 for e in off["episodes"])
