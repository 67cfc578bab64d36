"""``slew train --resume`` resumes only checkpoints of the same run: same config, epochs, seed
and data (paths and content); otherwise it refuses, naming what differs (review s35, findings
3, 4 and 13)."""
import os
import shutil

import pytest

pytest.importorskip("torch")

from solvers.warmstart import WarmStartModel        # noqa: E402
from training.cli import main                       # noqa: E402
from training.warmstart.train import DEFAULT_CONFIG, train          # noqa: E402

DATA = os.path.join(os.path.dirname(__file__), "data", "full-attitude-small.jsonl")
TINY = {"hidden": [16], "checkpoint_every": 1}


def _sha(summary):
    return WarmStartModel.load(summary["model"]).card["sha256"]


def test_a_stale_checkpoint_of_another_run_is_not_resumed(tmp_path):
    """A 3-epoch run, then a fresh 2-epoch run with another seed into the same directory: its
    --resume takes its own last checkpoint, not the older run's later one."""
    out = tmp_path / "run"
    train([DATA], out, seed=0, epochs=3, progress_bar=False, overrides=TINY)
    fresh = _sha(train([DATA], out, seed=1, epochs=2, progress_bar=False, overrides=TINY))
    assert sorted(os.listdir(out / "checkpoints")) == ["epoch_0001.pt", "epoch_0002.pt", "epoch_0003.pt"]
    assert _sha(train([DATA], out, seed=1, epochs=2, resume=True, progress_bar=False, overrides=TINY)) == fresh


def test_resume_still_continues_its_own_run(tmp_path):
    whole = _sha(train([DATA], tmp_path / "a", seed=2, epochs=3, progress_bar=False, overrides=TINY))
    train([DATA], tmp_path / "b", seed=2, epochs=3, progress_bar=False, overrides=TINY)
    os.remove(tmp_path / "b" / "checkpoints" / "epoch_0003.pt")
    # checkpoint_every only says when to save: another value resumes
    again = train([DATA], tmp_path / "b", seed=2, epochs=3, resume=True, progress_bar=False,
                  overrides=dict(TINY, checkpoint_every=5))
    assert _sha(again) == whole


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished 3-epoch run (seed 0) and a second data file."""
    root = tmp_path_factory.mktemp("resume")
    lines = open(DATA).read().splitlines(keepends=True)
    other = root / "other.jsonl"
    other.write_text("".join(lines[:-5]))
    assert main(["train", "--data", DATA, "--out", str(root / "run"), "--epochs", "3", "--no-progress"]) == 0
    return root, other


@pytest.mark.parametrize("change, needle", [
    (["--seed", "7"], "--seed (0; now 7)"),
    (["--epochs", "5"], "--epochs (a 3-epoch run; now 5)"),
    (["--epochs", "2"], "--epochs (a 3-epoch run, already at epoch 3, beyond; now 2)"),
    (["--data", "OTHER"], "--data (full-attitude-small.jsonl; now other.jsonl)"),
    (["--config", "WIDER"], "--config (hidden)"),      # the state_dict of another shape: no traceback
])
def test_resume_into_another_run_is_refused_naming_what_differs(finished, tmp_path, capsys, change, needle):
    root, other = finished
    run = tmp_path / "run"
    shutil.copytree(root / "run", run)
    before = sorted(os.listdir(run / "checkpoints")), (run / "model.npz").read_bytes(), (run / "config.yaml").read_text()
    args = {"--data": DATA, "--seed": "0", "--epochs": "3"}
    wider = tmp_path / "wider.yaml"
    wider.write_text(open(DEFAULT_CONFIG).read().replace("hidden: [256, 256, 256]", "hidden: [32]"))
    subst = {"OTHER": str(other), "WIDER": str(wider)}
    args.update(dict(zip(change[::2], [subst.get(v, v) for v in change[1::2]])))
    argv = ["train", "--out", str(run), "--resume", "--no-progress"] + [x for kv in args.items() for x in kv]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert "--resume: no checkpoint in" in err and needle in err, err
    # nothing of the run was touched
    assert before == (sorted(os.listdir(run / "checkpoints")), (run / "model.npz").read_bytes(),
                      (run / "config.yaml").read_text())


def test_resume_notices_data_whose_content_changed(finished, tmp_path, capsys):
    root, _ = finished
    data = tmp_path / "data.jsonl"
    shutil.copyfile(DATA, data)
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "run"), "--epochs", "2", "--no-progress"]) == 0
    lines = data.read_text().splitlines(keepends=True)
    data.write_text("".join(lines[:-1]))           # the same path, other records
    code = main(["train", "--data", str(data), "--out", str(tmp_path / "run"), "--epochs", "2", "--resume",
                 "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "--data (the content of data.jsonl changed since)" in err, err


def test_a_finished_run_resumes_to_the_same_model(finished, tmp_path):
    root, _ = finished
    run = tmp_path / "run"
    shutil.copytree(root / "run", run)
    sha = WarmStartModel.load(run / "model.npz").card["sha256"]
    assert main(["train", "--data", DATA, "--out", str(run), "--epochs", "3", "--resume", "--no-progress"]) == 0
    assert WarmStartModel.load(run / "model.npz").card["sha256"] == sha


def test_a_checkpoint_without_an_identity_is_not_resumed(tmp_path, capsys):
    """A checkpoint written before checkpoints recorded their run cannot be told from another
    run's: refused, saying so."""
    import torch
    run = tmp_path / "run"
    train([DATA], run, seed=0, epochs=1, progress_bar=False, overrides=TINY)
    path = run / "checkpoints" / "epoch_0001.pt"
    st = torch.load(path, weights_only=False)
    del st["identity"]
    torch.save(st, path)
    code = main(["train", "--data", DATA, "--out", str(run), "--epochs", "1", "--resume", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "(epoch_0001.pt) was written before checkpoints recorded their run" in err
