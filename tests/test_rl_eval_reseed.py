"""``train-rl``'s evaluations fly the same problems each time, so ``best/`` compares like with like.

The eval environment was seeded once (seed + 10000); each ``EvalCallback`` evaluation then
drew new problems. It is now re-seeded with seed + 10000 before every evaluation.
"""
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

from rl_tiny import tiny_config  # noqa: E402
from training.rl.train import train  # noqa: E402


def test_every_evaluation_flies_the_same_problems(tmp_path):
    # learning rate 0 and no observation normalisation: the policy, hence its deterministic
    # actions on a given problem, stay the same from one evaluation to the next
    cfg = tiny_config(tmp_path, n_timesteps=256, normalize=False,
                      hyperparameters={"learning_rate": 0.0, "n_steps": 64, "batch_size": 64, "n_epochs": 1},
                      eval={"eval_freq": 64, "n_eval_episodes": 3})
    train("ppo", "full-attitude", config=cfg, seed=4, out=tmp_path / "run")
    ev = np.load(tmp_path / "run" / "eval" / "evaluations.npz")
    assert list(ev["timesteps"]) == [64, 128, 192, 256]
    # the same policy on the same problems: the same returns and lengths at every evaluation
    # (a new draw of problems at each evaluation gave different returns)
    for k in range(1, 4):
        np.testing.assert_array_equal(ev["results"][k], ev["results"][0])
        np.testing.assert_array_equal(ev["ep_lengths"][k], ev["ep_lengths"][0])
    assert len(set(np.round(ev["results"][0], 12))) == 3        # three different problems within one
