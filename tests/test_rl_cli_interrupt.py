"""Ctrl-C / SIGTERM during ``slew train-rl``: the run stops at the next step, saves the model, its
VecNormalize statistics and train_info.json there, says so in one line with the command that
continues it, and exits 130 / 143; ``--resume RUN_DIR`` then goes on from that step (outside fuzz,
session 42, violation 5: a 19-frame traceback, nothing saved since the last checkpoint, and
``--resume RUN_DIR`` refused with "no checkpoint RUN_DIR/model.zip").

Each case runs a real process sent a real signal: about 6 s here."""
import json
import os
import signal
import subprocess
import sys
import time

import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

from rl_tiny import tiny_config  # noqa: E402
from training.cli import main  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGET = 10 ** 7          # far more steps than a test runs: only the signal ends it


@pytest.mark.parametrize("sig, code, vec", [(signal.SIGINT, 130, "dummy"), (signal.SIGTERM, 143, "dummy"),
                                            # to the whole group, subprocess workers included (timeout,
                                            # scancel; a review: the killed workers left nothing saved)
                                            (signal.SIGTERM, 143, "subproc")])
def test_a_signal_saves_the_run_where_it_stopped_and_resume_continues(tmp_path, sig, code, vec):
    cfg = tiny_config(tmp_path, checkpoint={"save_freq": 10 ** 6})      # no checkpoint in time: all from the stop
    run = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "training.cli", "train-rl", "--algo", "ppo", "--family",
                          "full-attitude", "--config", str(cfg), "--timesteps", str(TARGET), "--out", str(run),
                          "--vec-env", vec],
                         cwd=ROOT, env=dict(os.environ, PYTHONPATH=ROOT), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=vec == "subproc",
                         # as from a terminal: a test run started in the background (``cmd &`` in a
                         # shell without job control) hands its children SIGINT ignored
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.time() + 25
        while not (run / "config.yaml").exists() and time.time() < deadline:   # written just before learn()
            time.sleep(0.05)
        time.sleep(1.0)
        if vec == "subproc":
            os.killpg(p.pid, sig)
        else:
            p.send_signal(sig)
        out, err = p.communicate(timeout=20)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == code, err
    lines = err.strip().splitlines()
    assert "Traceback" not in err and lines, err
    info = json.loads((run / "train_info.json").read_text())
    steps = info["num_timesteps"]
    assert 0 < steps < TARGET and info["interrupted"] == {"signal": sig.name, "target_timesteps": TARGET}
    assert lines[-1] == (f"slew train-rl: interrupted ({sig.name}) at step {steps}: model.zip, vecnormalize.pkl "
                         f"and train_info.json saved in {run}; continue with: slew train-rl --algo ppo --family "
                         f"full-attitude --resume {run} --timesteps {TARGET - steps}"), err
    assert [ln for ln in lines if ln.startswith("slew train-rl")] == [lines[-1]]
    assert (run / "model.zip").exists() and (run / "vecnormalize.pkl").exists()
    assert not list(run.glob("checkpoints/rl_model_*"))     # so what resume finds is what the stop saved

    # the documented form: the run directory (its model.zip, the newest)
    assert main(["train-rl", "--algo", "ppo", "--family", "full-attitude", "--resume", str(run),
                 "--timesteps", "64"]) == 0
    info2 = json.loads((run / "train_info.json").read_text())
    assert info2["steps_before"] == steps and info2["num_timesteps"] == steps + 64
    assert "interrupted" not in info2 and info2["previous_runs"][0]["interrupted"]["signal"] == sig.name


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_second_signal_that_will_not_wait_exits_as_that_signal(monkeypatch, capsys, sig, code):
    """The second signal cuts the wait for the step (not the save) and the exit status says which
    signal it was (a second SIGTERM had exited 130, as if Ctrl-C; session 42's note)."""
    from training.rl import train as train_mod

    stop = train_mod._SignalStop()
    stop._handle(sig, None)                       # the first only asks learn() to stop
    assert stop.signum == sig
    with pytest.raises(train_mod.SignalInterrupt) as e:
        stop._handle(sig, None)
    assert e.value.signum == sig and isinstance(e.value, KeyboardInterrupt)
    stop.hold()
    stop._handle(sig, None)                       # not during the save

    def second_signal(*a, **k):
        raise train_mod.SignalInterrupt(sig)
    monkeypatch.setattr(train_mod, "train", second_signal)
    assert main(["train-rl", "--algo", "ppo", "--family", "full-attitude", "--timesteps", "64"]) == code
    assert "interrupted before the model was saved" in capsys.readouterr().err
