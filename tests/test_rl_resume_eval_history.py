"""Resuming ``train-rl`` into its run directory keeps the evaluation history and the ``best/`` guard.

Before: the resumed run's fresh ``EvalCallback`` rewrote ``eval/evaluations.npz`` with its own
evaluations only, and its best mean reward started at -inf, so its first evaluation, however
poor, replaced ``best/best_model.zip``.
"""
import shutil

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

from rl_tiny import tiny_config  # noqa: E402
from training.rl.train import train  # noqa: E402

KEYS = ("timesteps", "results", "ep_lengths", "successes")     # all that EvalCallback saves


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("first")
    cfg = tiny_config(tmp, eval={"eval_freq": 64, "n_eval_episodes": 2})
    train("ppo", "full-attitude", config=cfg, seed=2, out=tmp / "run")
    return tmp / "run"


def _copy_with_scores(first_run, tmp_path, score):
    """A copy of the run whose earlier evaluations all scored ``score`` (the file as EvalCallback wrote it
    otherwise); returns (run dir, the earlier arrays, the bytes of best/best_model.zip)."""
    run = tmp_path / "run"
    shutil.copytree(first_run, run)
    path = run / "eval" / "evaluations.npz"
    with np.load(path) as f:
        old = {k: f[k] for k in f.files}
    assert set(old) == set(KEYS) and list(old["timesteps"]) == [64, 128]
    old["results"] = np.full_like(old["results"], score)
    np.savez(path, **old)
    return run, old, (run / "best" / "best_model.zip").read_bytes()


def _evaluations(run):
    with np.load(run / "eval" / "evaluations.npz") as f:
        return {k: f[k] for k in f.files}


def test_resume_in_place_appends_to_the_evaluations_and_keeps_a_better_best(first_run, tmp_path):
    run, old, best = _copy_with_scores(first_run, tmp_path, 1000.0)   # a best no tiny policy can beat
    vn_best = (run / "best" / "vecnormalize.pkl").read_bytes()
    train("ppo", "full-attitude", resume=run, timesteps=128)
    new = _evaluations(run)
    assert set(new) == set(KEYS)
    assert list(new["timesteps"]) == [64, 128, 192, 256]             # was [192, 256]: the history erased
    for k in ("results", "ep_lengths", "successes"):
        assert len(new[k]) == 4
        np.testing.assert_array_equal(new[k][:2], old[k])
    assert (new["results"][2:] < 100).all()
    assert (run / "best" / "best_model.zip").read_bytes() == best     # was replaced by a poorer evaluation
    assert (run / "best" / "vecnormalize.pkl").read_bytes() == vn_best


def test_a_better_evaluation_after_resume_still_replaces_best(first_run, tmp_path):
    run, _, best = _copy_with_scores(first_run, tmp_path, -1000.0)
    train("ppo", "full-attitude", resume=run, timesteps=64)
    assert list(_evaluations(run)["timesteps"]) == [64, 128, 192]
    assert (run / "best" / "best_model.zip").read_bytes() != best


def test_other_n_eval_episodes_keeps_the_earlier_file_beside_and_the_guard(first_run, tmp_path):
    run, old, best = _copy_with_scores(first_run, tmp_path, 1000.0)
    with pytest.warns(UserWarning, match="n_eval_episodes=3"):
        train("ppo", "full-attitude", resume=run, timesteps=64, overrides=["eval.n_eval_episodes=3"])
    kept = np.load(run / "eval" / "evaluations_until_128_steps.npz")
    np.testing.assert_array_equal(kept["results"], old["results"])
    new = _evaluations(run)
    assert list(new["timesteps"]) == [192] and new["results"].shape == (1, 3)
    assert (run / "best" / "best_model.zip").read_bytes() == best


def test_resume_into_a_new_directory_starts_its_own_evaluations(first_run, tmp_path):
    out = tmp_path / "elsewhere"
    train("ppo", "full-attitude", resume=first_run / "model.zip", timesteps=64, out=out)
    assert list(_evaluations(out)["timesteps"]) == [192]
    assert (out / "best" / "best_model.zip").exists()
    assert list(_evaluations(first_run)["timesteps"]) == [64, 128]     # the run it continues is untouched


def test_resume_from_an_older_checkpoint_keeps_the_later_evaluations_beside(tmp_path):
    # a review: resuming into the run from a checkpoint before its last evaluation appended the new
    # evaluations after the later ones (timesteps out of order)
    cfg = tiny_config(tmp_path, eval={"eval_freq": 64, "n_eval_episodes": 2}, checkpoint={"save_freq": 64})
    run = tmp_path / "run"
    train("ppo", "full-attitude", config=cfg, seed=2, out=run)
    old = _evaluations(run)
    assert list(old["timesteps"]) == [64, 128]
    early = run / "checkpoints" / "rl_model_64_steps.zip"
    assert early.exists(), sorted(p.name for p in (run / "checkpoints").iterdir())
    with pytest.warns(UserWarning, match="resumed from 64 steps, before 1 of the run's evaluations"):
        train("ppo", "full-attitude", resume=early, timesteps=64, out=run)
    new = _evaluations(run)
    assert list(new["timesteps"]) == [64, 128]                     # the checkpoint's 64, then its own 128
    assert set(new) == set(KEYS) and all(len(new[k]) == 2 for k in KEYS)
    np.testing.assert_array_equal(new["results"][0], old["results"][0])
    kept = np.load(run / "eval" / "evaluations_beyond_64_steps.npz")
    assert set(kept.files) == set(KEYS) and list(kept["timesteps"]) == [128]
    np.testing.assert_array_equal(kept["results"], old["results"][1:])
