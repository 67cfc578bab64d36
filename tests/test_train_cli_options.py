"""``slew train``'s options are checked before the data load and the training, and ``--export``
replaces the model, its card and its table together (review s35, finding 13)."""
import os

import pytest

from training.cli import main

DATA = os.path.join(os.path.dirname(__file__), "data", "full-attitude-small.jsonl")


@pytest.mark.parametrize("epochs", ["0", "-3"])
def test_epochs_below_one_is_refused_before_the_data_load(tmp_path, capsys, epochs):
    code = main(["train", "--data", DATA, "--out", str(tmp_path / "run"), "--epochs", epochs, "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "--epochs: must be ≥ 1" in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_the_api_refuses_epochs_below_one_by_the_config_check(tmp_path):
    from training.warmstart.train import train
    with pytest.raises(ValueError, match="epochs: must be ≥ 1"):
        train([DATA], tmp_path / "run", epochs=0, progress_bar=False)


def test_export_into_a_missing_directory_is_made_before_training(tmp_path):
    pytest.importorskip("torch")
    target = tmp_path / "new" / "dir" / "m.npz"
    assert main(["train", "--data", DATA, "--out", str(tmp_path / "run"), "--epochs", "1", "--no-progress",
                 "--export", str(target)]) == 0
    for name in ("m.npz", "m.md", "m.nn.npz"):
        assert (target.parent / name).exists(), name
    assert [f for f in os.listdir(target.parent) if f.endswith(".tmp")] == []


def test_export_onto_a_directory_is_refused_before_training(tmp_path, capsys):
    code = main(["train", "--data", DATA, "--out", str(tmp_path / "run"), "--epochs", "1", "--no-progress",
                 "--export", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and "--export:" in err and "is a directory" in err
    assert not (tmp_path / "run").exists()


def test_an_interrupted_export_leaves_the_old_files_together(tmp_path, monkeypatch):
    """Ctrl-C while the export copies: the old network, card and table stay as they were (no new
    network next to an old table), and no temporary file is left behind."""
    pytest.importorskip("torch")
    import shutil
    target = tmp_path / "models" / "m.npz"
    target.parent.mkdir()
    old = {"m.npz": b"old network", "m.md": b"old card", "m.nn.npz": b"old table"}
    for name, content in old.items():
        (target.parent / name).write_bytes(content)
    real_copy, calls = shutil.copyfile, []

    def copy_then_interrupt(src, dst, *a, **k):
        calls.append(dst)
        if len(calls) == 3:          # the third file of the export
            raise KeyboardInterrupt
        return real_copy(src, dst, *a, **k)
    monkeypatch.setattr(shutil, "copyfile", copy_then_interrupt)
    try:
        code = main(["train", "--data", DATA, "--out", str(tmp_path / "run"), "--epochs", "1", "--no-progress",
                     "--export", str(target)])
    except KeyboardInterrupt:
        code = "KeyboardInterrupt"
    assert code == 130
    assert {name: (target.parent / name).read_bytes() for name in old} == old
    assert sorted(os.listdir(target.parent)) == sorted(old)


@pytest.mark.parametrize("make, argv, needle", [
    (None, ["--config", "nope.yaml"], "--config: no such file: "),
    ("file", ["--out", "a_file"], "--out: "),
    ("notes", ["--data", "notes.txt"], "--data: "),
])
def test_other_bad_options_are_named(tmp_path, capsys, monkeypatch, make, argv, needle):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a_file").write_text("keep me")
    (tmp_path / "notes.txt").write_text("my notes\n")
    args = {"--data": DATA, "--out": "run"}
    args.update(dict(zip(argv[::2], argv[1::2])))
    code = main(["train", "--epochs", "1", "--no-progress"] + [x for kv in args.items() for x in kv])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and err.startswith(f"slew train: error: {needle}"), err
    assert (tmp_path / "a_file").read_text() == "keep me" and not (tmp_path / "run").exists()


@pytest.mark.parametrize("change, pattern", [
    ({"hidden": [2048, 2048]}, r"^config.hidden: 4,309,035 weights in all, more than the 4,194,304"),
    ({"hidden": [64] * 70}, r"^config.hidden: expected a list of at most 63 layer widths"),
    ({"hidden": [64, 0]}, r"^config.hidden: expected a list"),
    ({"max_switches": 51}, r"^config.max_switches: expected a whole number from 0 to 50"),
    ({"max_switches": "5"}, r"^config.max_switches: expected a whole number"),
])
def test_a_network_no_model_file_may_hold_is_refused_before_training(change, pattern):
    # a review: hidden [2048, 2048] trained to the end and then failed writing model.npz, whose
    # loader refuses more than MAX_WEIGHTS weights
    from training.warmstart.train import load_config
    with pytest.raises(ValueError, match=pattern):
        load_config(overrides=change)
    assert load_config()["hidden"]      # the shipped configs pass
    from training.warmstart.train import DEFAULT_CONFIG
    load_config(os.path.join(os.path.dirname(DEFAULT_CONFIG), "pointing-cones.yaml"))
