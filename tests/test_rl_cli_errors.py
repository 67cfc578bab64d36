"""Bad input to ``slew train-rl`` / ``evaluate-rl`` / ``env-demo``: one line naming the option, key or
file, exit 2, before anything runs, and nothing left behind (outside fuzz, session 42, violations 1,
7, 8 and 11: raw tracebacks from SB3, gymnasium, PyYAML and pickle; a re-run into the same
``--out`` overwrote the earlier run; failed starts left empty run directories; ``--threads 0``
and friends accepted without a word; env-demo's path errors only after the episode)."""
import json
import os
import shutil

import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

from rl_tiny import tiny_config  # noqa: E402
from training.cli import main  # noqa: E402
from training.rl.train import find_checkpoint_files, train  # noqa: E402


def _train_rl(cfg, *extra):
    return main(["train-rl", "--algo", "ppo", "--family", "full-attitude", "--config", str(cfg), *extra])


def _one_error_line(capsys, command="train-rl"):
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert "Traceback" not in err and len(lines) == 1, err
    assert lines[0].startswith(f"slew {command}: error: "), err
    return lines[0]


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A finished tiny run with checkpoints at 64 and 128 steps (and model.zip at 128)."""
    tmp = tmp_path_factory.mktemp("tiny")
    cfg = tiny_config(tmp, checkpoint={"save_freq": 64})
    train("ppo", "full-attitude", config=cfg, seed=3, out=tmp / "run")
    return tmp / "run"


@pytest.mark.parametrize("extra, needle", [
    (["--set", "hyperparameters.learning_rate=abc"], "hyperparameters.learning_rate: expected a finite number, got 'abc'"),
    (["--set", "hyperparameters.learning_rate=lin_abc"], "hyperparameters.learning_rate: expected a number or lin_"),
    (["--set", "hyperparameters.bogus_param=1"], "hyperparameters.bogus_param: not a PPO argument"),
    (["--set", "hyperparameters.n_steps=1.5"], "hyperparameters.n_steps: expected an integer, got 1.5"),
    (["--set", "hyperparameters.normalize_advantage=1"], "hyperparameters.normalize_advantage: expected true or false"),
    (["--set", "env_kwargs.bogus=1"], "env_kwargs.bogus: not a Slew-v0 argument"),
    (["--set", "env_kwargs.control_dt=-1"], "env_kwargs: control_dt: must be a positive finite number"),
    (["--set", "normalize.clip_obs=nan"], "normalize.clip_obs: expected a finite number, got 'nan'"),
    (["--set", "normalize.clip_obs=.inf"], "normalize.clip_obs: expected a finite number, got inf"),
    (["--set", "normalize.bogus=1"], "normalize.bogus: not a VecNormalize argument"),
    (["--set", "checkpoint.save_freq=-1"], "checkpoint.save_freq: must be >= 1, got -1 (set checkpoint: null"),
    (["--set", "eval.eval_freq=0"], "eval.eval_freq: must be >= 1, got 0 (set eval: null"),
    (["--set", "eval.n_eval_episodes=0"], "eval.n_eval_episodes: must be >= 1, got 0"),
    (["--set", "n_envs=two"], "n_envs: expected a finite integer, got 'two'"),
    (["--set", "policy=Bogus"], "policy / policy_kwargs / hyperparameters: Policy Bogus unknown"),
    (["--seed", "-1"], "--seed: must be between 0 and 2**32 - 1, got -1"),
    (["--solver-workers", "0"], "--solver-workers: must be >= 1, got 0"),
])
def test_train_rl_refuses_bad_settings_by_name_and_leaves_no_directory(tmp_path, capsys, extra, needle):
    cfg = tiny_config(tmp_path, eval={"eval_freq": 64, "n_eval_episodes": 2}, checkpoint={"save_freq": 64})
    out = tmp_path / "new" / "run"
    code = _train_rl(cfg, "--out", str(out), *extra)
    line = _one_error_line(capsys)
    assert code == 2 and needle in line, line
    assert not (tmp_path / "new").exists()       # had been created (with tb/, config.yaml) before the checks


def test_train_rl_corrupt_config_file_is_one_line_naming_it(tmp_path, capsys):
    bad = tmp_path / "corrupt.yaml"
    bad.write_text("full-attitude: [unclosed\n")
    assert _train_rl(bad, "--out", str(tmp_path / "run")) == 2
    line = _one_error_line(capsys)
    assert f"--config: {bad}: not a valid YAML file" in line and "line 2" in line
    assert not (tmp_path / "run").exists()


def test_a_start_that_fails_after_creating_the_directory_removes_it(tmp_path):
    """Also a Ctrl-C in the last steps before training: only what the start created goes."""
    from training.rl import train as tr
    cfg = tiny_config(tmp_path)
    with pytest.MonkeyPatch.context() as mp:
        for exc in (RuntimeError("boom"), KeyboardInterrupt()):
            def fail(*a, exc=exc, **k):
                raise exc
            mp.setattr(tr, "_callbacks", fail)
            with pytest.raises(type(exc)):
                train("ppo", "full-attitude", config=cfg, out=tmp_path / "a" / "b" / "run")
            # the run directory goes; its parents stay (they may hold other runs by then)
            assert not (tmp_path / "a" / "b" / "run").exists() and (tmp_path / "a" / "b").is_dir()
        keep = tmp_path / "existing"
        keep.mkdir()
        (keep / "notes.txt").write_text("mine")
        with pytest.raises(KeyboardInterrupt):
            train("ppo", "full-attitude", config=cfg, out=keep / "run")
        assert sorted(p.name for p in keep.iterdir()) == ["notes.txt"]


def test_a_new_run_into_a_run_directory_is_refused_and_the_run_kept(tiny_run, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    code = _train_rl(tiny_config(tmp_path), "--seed", "5", "--out", str(run))
    line = _one_error_line(capsys)
    assert code == 2 and line.startswith(f"slew train-rl: error: --out: {run} already holds a run (model.zip")
    assert f"--resume {run}" in line and "another --out" in line
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before
    # and --resume RUN_DIR continues it, as the message says
    assert main(["train-rl", "--algo", "ppo", "--family", "full-attitude", "--resume", str(run),
                 "--timesteps", "64"]) == 0
    info = json.loads((run / "train_info.json").read_text())
    assert info["num_timesteps"] == 192 and info["steps_before"] == 128 and info["previous_runs"]


def test_the_default_out_of_a_rerun_is_refused_too(tmp_path, capsys):
    cfg = tiny_config(tmp_path)
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(tmp_path)
        assert _train_rl(cfg, "--timesteps", "64") == 0
        model = (tmp_path / "runs" / "ppo-full-attitude-seed0" / "model.zip").read_bytes()
        capsys.readouterr()
        assert _train_rl(cfg, "--timesteps", "64") == 2
    line = _one_error_line(capsys)
    assert "--out (default runs/ppo-full-attitude-seed0): runs/ppo-full-attitude-seed0 already holds a run" in line
    assert (tmp_path / "runs" / "ppo-full-attitude-seed0" / "model.zip").read_bytes() == model


def test_resume_of_a_run_directory_takes_its_newest_model(tiny_run, tmp_path):
    from training.rl.train import newest_in_run
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    ck = run / "checkpoints"
    assert newest_in_run(run) == run / "model.zip"                     # 128 steps, as the last checkpoint
    shutil.copy(ck / "rl_model_64_steps.zip", run / "model.zip")      # a model.zip older than a checkpoint
    t128 = (ck / "rl_model_128_steps.zip").stat().st_mtime
    os.utime(run / "model.zip", (t128 - 10, t128 - 10))
    assert newest_in_run(run) == ck / "rl_model_128_steps.zip"
    # the most recent, not the most steps: a run resumed in place from an older checkpoint leaves
    # the abandoned line's later checkpoints behind (a review: its 256-step one was taken over the
    # model.zip just trained)
    os.utime(run / "model.zip", (t128 + 10, t128 + 10))
    assert newest_in_run(run) == run / "model.zip"
    os.utime(run / "model.zip", (t128 - 10, t128 - 10))
    (run / "model.zip").unlink()                                      # killed before its end: no model.zip
    files = find_checkpoint_files(run)
    assert files[0] == ck / "rl_model_128_steps.zip" and files[1] == ck / "rl_model_vecnormalize_128_steps.pkl"
    assert files[3] == run
    info = train("ppo", "full-attitude", resume=run, timesteps=64)   # had failed: "no checkpoint run/model.zip"
    assert info["steps_before"] == 128 and info["num_timesteps"] == 192 and info["out"] == str(run)
    shutil.rmtree(ck)
    with pytest.raises(FileNotFoundError, match="holds no model.zip and no checkpoints"):
        find_checkpoint_files(tmp_path)


def test_a_failed_start_removes_only_its_own_run_directory(tmp_path):
    # a review: check_out returned the first missing parent, and a failed start into
    # runs/sweep/a removed runs/sweep, with the run training into runs/sweep/b
    from training.rl.train import check_out
    out = tmp_path / "sweep" / "a"
    assert check_out(out, fresh=True, given=True) == out
    out.mkdir(parents=True)
    assert check_out(out, fresh=True, given=True) is None


def test_old_runs_that_switched_evaluation_off_with_zero_still_resume(tiny_run, tmp_path):
    import yaml
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    cfg = yaml.safe_load((run / "config.yaml").read_text())
    cfg["eval"], cfg["checkpoint"] = {"eval_freq": 0}, {"save_freq": 0}     # as train-rl wrote them before
    (run / "config.yaml").write_text(yaml.safe_dump(cfg))
    info = train("ppo", "full-attitude", resume=run, timesteps=64)
    assert info["num_timesteps"] == 192 and not (run / "eval").exists()


# --------------------------------------------------------------------------- evaluate-rl
def _policy_copy(tiny_run, tmp_path, broken):
    d = tmp_path / "policy"
    d.mkdir()
    for name in ("model.zip", "vecnormalize.pkl", "config.yaml"):
        shutil.copy(tiny_run / name, d / name)
    (d / broken).write_bytes(b": : [xx")
    return d


@pytest.mark.parametrize("broken, needle", [
    ("vecnormalize.pkl", "vecnormalize.pkl: not VecNormalize statistics"),
    ("config.yaml", "config.yaml: not a valid YAML file"),
])
def test_evaluate_rl_names_a_corrupt_file_of_the_policy(tiny_run, tmp_path, capsys, broken, needle):
    d = _policy_copy(tiny_run, tmp_path, broken)
    line = _refused_evaluation(d, tmp_path, capsys)
    assert f"{d / broken}" in line and needle in line, line


def _refused_evaluation(policy, tmp_path, capsys, *extra):
    """``evaluate-rl`` on one problem, refused: its one error line; neither the report
    directory nor the solutions file was made."""
    code = main(["evaluate-rl", str(policy), "--n", "1", "--no-progress", "--out", str(tmp_path / "ev"),
                 "--solutions", str(tmp_path / "sol.jsonl"), *extra])
    line = _one_error_line(capsys, "evaluate-rl")
    assert code == 2, line
    assert not (tmp_path / "ev").exists() and not (tmp_path / "sol.jsonl").exists()
    return line


@pytest.mark.parametrize("extra, needle", [
    (["--threads", "0"], "--threads: must be >= 1, got 0"),
    (["--plot-k", "-1"], "--plot-k: must be >= 0, got -1"),
    (["--solver-workers", "0"], "--solver-workers: must be >= 1, got 0"),
    (["--solve-options", "{bad"], "--solve-options: not valid JSON"),
    # content that parses but that no solve accepts: refused before the report directory is made
    (["--solve-options", '{"time_budgt": 5}'], "unknown option(s) ['time_budgt']"),
    (["--solve-options", '{"time_budget": -1}'], "time_budget: must be a positive number"),
])
def test_evaluate_rl_refuses_bad_counts(tiny_run, tmp_path, capsys, extra, needle):
    line = _refused_evaluation(tiny_run, tmp_path, capsys, *extra)
    assert needle in line, line


def test_evaluate_rl_help_says_an_existing_report_is_replaced(capsys):
    with pytest.raises(SystemExit):
        main(["evaluate-rl", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "report.md, results.json and overlay.png already there are replaced" in text


# --------------------------------------------------------------------------- env-demo
@pytest.mark.parametrize("where", ["missing/f.png", "a_dir.png", "x" * 300 + ".png", ".png"])
def test_env_demo_checks_out_before_the_episode(tmp_path, capsys, where):
    (tmp_path / "a_dir.png").mkdir()
    out = tmp_path / where
    code = main(["env-demo", "--steps", "2", "--out", str(out)])
    captured = capsys.readouterr()
    assert code == 2 and captured.out == ""            # the episode (which prints the problem) never ran
    line = _one_error_line(type("C", (), {"readouterr": lambda self: captured})(), "env-demo")
    assert line.startswith("slew env-demo: error: --out: "), line


def test_env_demo_check_leaves_an_existing_frame_and_no_empty_file(tmp_path, capsys):
    old = tmp_path / "old.png"
    old.write_bytes(b"not touched by a failed run")
    assert main(["env-demo", "--steps", "2", "--family", "", "--out", str(old)]) == 2
    assert "--family: " in capsys.readouterr().err
    assert old.read_bytes() == b"not touched by a failed run"
    new = tmp_path / "new.png"
    assert main(["env-demo", "--steps", "2", "--family", "", "--out", str(new)]) == 2
    assert not new.exists()                       # the write test's empty file is removed again
