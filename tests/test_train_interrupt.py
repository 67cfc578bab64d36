"""Ctrl-C during ``slew train``: exit 130 and one line, ``log.csv`` of the epochs done and a
checkpoint of the last finished one, which ``--resume`` continues as if nothing had happened
(review s35, finding 13: a traceback, no log.csv, up to 49 epochs lost)."""
import os
import signal
import subprocess
import sys
import time

import pytest

pytest.importorskip("torch")

from solvers.warmstart import WarmStartModel        # noqa: E402
from training.cli import main                       # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "tests", "data", "full-attitude-small.jsonl")


def test_ctrl_c_keeps_the_epochs_done_and_resume_continues(tmp_path, monkeypatch, capsys):
    from training.warmstart import train as tr
    whole = tmp_path / "whole"
    assert main(["train", "--data", DATA, "--out", str(whole), "--epochs", "4", "--no-progress"]) == 0
    real, calls = tr._losses, []

    def interrupt_in_epoch_3(*a, **k):
        calls.append(1)
        if len(calls) == 5:        # one training batch and one validation call an epoch
            raise KeyboardInterrupt
        return real(*a, **k)
    monkeypatch.setattr(tr, "_losses", interrupt_in_epoch_3)
    run = tmp_path / "run"
    capsys.readouterr()
    try:
        code = main(["train", "--data", DATA, "--out", str(run), "--epochs", "4", "--no-progress"])
    except KeyboardInterrupt:
        code = "KeyboardInterrupt"
    err = capsys.readouterr().err
    assert code == 130 and err.strip().splitlines() == [
        f"slew train: interrupted after epoch 2 of 4: {run / 'log.csv'} and "
        f"{run / 'checkpoints' / 'epoch_0002.pt'} kept; --resume continues"]
    assert len((run / "log.csv").read_text().splitlines()) == 3
    assert os.listdir(run / "checkpoints") == ["epoch_0002.pt"] and not (run / "model.npz").exists()
    monkeypatch.setattr(tr, "_losses", real)
    assert main(["train", "--data", DATA, "--out", str(run), "--epochs", "4", "--resume", "--no-progress"]) == 0
    sha = [WarmStartModel.load(d / "model.npz").card["sha256"] for d in (whole, run)]
    assert sha[0] == sha[1]
    assert (run / "log.csv").read_text() == (whole / "log.csv").read_text()


def test_a_real_sigint_exits_130_with_one_line(tmp_path):
    """The signal itself, as a terminal sends it, in the middle of a long run."""
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text("family: full-attitude\nmax_switches: 5\nhidden: [16]\nepochs: 1000000\nbatch_size: 16\n"
                   "learning_rate: 1.0e-3\ncheckpoint_every: 1000000\n"
                   "domain: {torque_norm: inf, angle_deg: [10.0, 180.0], inertia_ratio: [0.4, 1.0], "
                   "torque_ratio_min: 1.0, cones: false, target: full-attitude}\n")
    run = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-m", "training.cli", "train", "--data", DATA, "--config", str(cfg),
                          "--out", str(run), "--no-progress"], cwd=ROOT, env=dict(os.environ, PYTHONPATH=ROOT),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         # as from a terminal: a test run started in the background (``cmd &`` in a
                         # shell without job control) hands its children SIGINT ignored
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.time() + 120
        while not (run / "config.yaml").exists() and time.time() < deadline:   # written as the epochs start
            time.sleep(0.1)
        time.sleep(1.5)
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and "slew train: interrupted after epoch" in err
    n = int(err.split("after epoch ")[1].split()[0])
    assert n >= 1 and len((run / "log.csv").read_text().splitlines()) == n + 1
    assert os.listdir(run / "checkpoints") == [f"epoch_{n:04d}.pt"]
