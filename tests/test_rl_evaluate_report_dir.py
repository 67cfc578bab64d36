"""``evaluate-rl`` without ``--out``: one report per checkpoint, named after it.

Two checkpoints of a run both wrote ``checkpoints/eval-<family>-seed<S>/``, the second over the
first. A run directory (its ``model.zip``, its ``best/best_model.zip``) keeps ``eval-<family>-seed<S>``.
"""
import json
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

from rl_tiny import tiny_config  # noqa: E402
from training.rl import SHIPPED_POLICIES  # noqa: E402
from training.rl.evaluate import default_report_dir, evaluate  # noqa: E402
from training.rl.train import train  # noqa: E402


def refuse(problem, **options):
    """A solve route that answers nothing (the rollouts are what this test is about)."""
    raise ValueError("not solved in this test")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ckpt")
    train("ppo", "full-attitude", config=tiny_config(tmp, checkpoint={"save_freq": 64}), seed=1, out=tmp / "run")
    return tmp / "run"


def test_two_checkpoints_without_out_get_a_report_each(run, tmp_path):
    ck = run / "checkpoints"
    reports = []
    for steps in (128, 64):
        res = evaluate(ck / f"rl_model_{steps}_steps.zip", n=1, seed=7, plot_k=0, progress=False,
                       solutions=tmp_path / "sol.jsonl", solve_fn=f"{__name__}:refuse")
        reports.append(Path(res["out"]))
    assert reports == [ck / "eval-rl_model_128_steps-full-attitude-seed7",
                       ck / "eval-rl_model_64_steps-full-attitude-seed7"]
    for steps, rep in zip((128, 64), reports):        # the first report is still there, and its own
        res = json.loads((rep / "results.json").read_text())
        assert res["policy"].endswith(f"rl_model_{steps}_steps.zip")


def test_a_run_directory_keeps_its_report_name(run):
    assert default_report_dir(run, "full-attitude", 100) == run / "eval-full-attitude-seed100"
    assert default_report_dir(run / "model.zip", "full-attitude", 100) == run / "eval-full-attitude-seed100"
    best = run / "best" / "best_model.zip"
    assert default_report_dir(best, "pointing-cones", 3) == run / "best" / "eval-pointing-cones-seed3"
    assert default_report_dir("shipped", "full-attitude", 100) == \
        Path("runs") / f"eval-{SHIPPED_POLICIES['full-attitude'].name}-full-attitude-seed100"
