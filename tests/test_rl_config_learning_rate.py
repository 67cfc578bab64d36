"""``config.yaml`` after behaviour cloning records the learning rate the RL phase runs with.

``bc.rl_learning_rate`` replaces the model's learning rate after cloning; the run's
``config.yaml`` kept the configured ``hyperparameters.learning_rate`` (3e-4 where 1e-4 ran).
"""
import shutil
from pathlib import Path

import pytest
import yaml

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

from training.rl.train import train  # noqa: E402

# problems 0 and 1 of seed 100, already solved: the cloning reads them and solves nothing
DATA = Path(__file__).resolve().parent / "data" / "full-attitude-small.jsonl"
TINY = {"n_envs": 1, "n_timesteps": 0, "policy": "MlpPolicy",
        "policy_kwargs": {"net_arch": {"pi": [16], "vf": [16]}},
        "hyperparameters": {"learning_rate": 3.0e-4, "n_steps": 64, "batch_size": 64, "n_epochs": 1},
        "normalize": {"norm_obs": True, "norm_reward": False},
        "env_kwargs": {"max_episode_steps": 50}, "eval": None, "checkpoint": None,
        "bc": {"epochs": 2, "value_pretrain": False, "rl_learning_rate": 7.0e-5}}


def _clone_then_train(tmp_path, entry, timesteps):
    """(saved config.yaml, saved model) of a run that clones 2 expert problems, then trains."""
    from stable_baselines3 import PPO

    cfg = tmp_path / "ppo.yaml"
    cfg.write_text(yaml.safe_dump({"full-attitude": entry}))
    data = tmp_path / "experts.jsonl"
    shutil.copy(DATA, data)
    out = tmp_path / "run"
    train("ppo", "full-attitude", config=cfg, timesteps=timesteps, out=out, bc_pretrain=2, bc_seed=100,
          expert_data=data)
    return yaml.safe_load((out / "config.yaml").read_text()), PPO.load(str(out / "model.zip"), device="cpu")


def test_config_yaml_records_the_learning_rate_set_by_cloning(tmp_path):
    saved, model = _clone_then_train(tmp_path, TINY, 64)
    assert model.learning_rate == 7.0e-5
    assert model.policy.optimizer.param_groups[0]["lr"] == 7.0e-5
    assert saved["hyperparameters"]["learning_rate"] == 7.0e-5      # was 3e-4, the configured value
    assert saved["bc"]["rl_learning_rate"] == 7.0e-5
    assert saved["hyperparameters"]["n_steps"] == 64                 # the rest as configured


def test_without_rl_learning_rate_the_configured_one_stays(tmp_path):
    saved, model = _clone_then_train(tmp_path, dict(TINY, bc={"epochs": 2, "value_pretrain": False}), 0)
    assert saved["hyperparameters"]["learning_rate"] == 3.0e-4 == model.learning_rate


def test_a_hyperparameter_set_on_resume_is_the_one_that_runs(tmp_path):
    # config.yaml recorded a --set hyperparameters.X given on resume, but SB3's load kept the
    # saved value, so the record and the run disagreed (an RL review)
    from stable_baselines3 import PPO
    from rl_tiny import tiny_config

    out = tmp_path / "run"
    train("ppo", "full-attitude", config=tiny_config(tmp_path), timesteps=64, out=out)
    train("ppo", "full-attitude", resume=str(out), timesteps=64,
          overrides=["hyperparameters.learning_rate=2.5e-5", "hyperparameters.ent_coef=0.01"])
    saved = yaml.safe_load((out / "config.yaml").read_text())
    model = PPO.load(str(out / "model.zip"), device="cpu")
    assert saved["hyperparameters"]["learning_rate"] == 2.5e-5 == model.learning_rate
    assert model.policy.optimizer.param_groups[0]["lr"] == 2.5e-5
    assert saved["hyperparameters"]["ent_coef"] == 0.01 == model.ent_coef
    assert model.n_steps == 64 and model.num_timesteps == 128        # the rest as saved


def test_a_gamma_set_on_resume_reaches_the_reward_normalisation(tmp_path):
    # VecNormalize.load kept the saved discount: the agent ran with the new gamma while its
    # rewards were scaled with returns discounted by the old one
    import pickle

    from stable_baselines3 import PPO
    from rl_tiny import tiny_config

    def saved_normalisation():
        with open(out / "vecnormalize.pkl", "rb") as f:
            return pickle.load(f)          # (VecNormalize.load needs an env to wrap)

    out = tmp_path / "run"
    train("ppo", "full-attitude", config=tiny_config(tmp_path, normalize={"norm_obs": True, "norm_reward": True}),
          timesteps=64, out=out)
    first = saved_normalisation()
    assert first.gamma == 0.99 and first.clip_reward == 10.0        # SB3's defaults, as configured
    train("ppo", "full-attitude", resume=str(out), timesteps=64,
          overrides=["hyperparameters.gamma=0.9", "normalize.clip_reward=3.0"])
    vn = saved_normalisation()
    assert PPO.load(str(out / "model.zip"), device="cpu").gamma == 0.9
    assert vn.gamma == 0.9 and vn.clip_reward == 3.0
    assert vn.norm_reward and vn.norm_obs
    assert vn.obs_rms.count > first.obs_rms.count                    # the statistics went on from the file
