"""The tiny PPO entry the ``train-rl`` tests train (one copy, 64-step rollouts, 30-step episodes)."""
import copy

import yaml

TINY_PPO = {"n_envs": 1, "n_timesteps": 128, "policy": "MlpPolicy",
            "policy_kwargs": {"net_arch": {"pi": [16], "vf": [16]}},
            "hyperparameters": {"n_steps": 64, "batch_size": 64, "n_epochs": 1},
            "normalize": {"norm_obs": True, "norm_reward": False}, "env_kwargs": {"max_episode_steps": 30},
            "eval": None, "checkpoint": None}


def tiny_config(directory, **changes):
    """``directory/ppo.yaml`` with ``TINY_PPO`` (top-level keys replaced by ``changes``) as its
    ``full-attitude`` entry; returns its path."""
    entry = copy.deepcopy(TINY_PPO)
    entry.update(copy.deepcopy(changes))
    path = directory / "ppo.yaml"
    path.write_text(yaml.safe_dump({"full-attitude": entry}))
    return path
