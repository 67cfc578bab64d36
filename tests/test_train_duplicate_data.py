"""``slew train`` refuses the same problems given twice, which put copies of validation rows in
the training split (review s35, finding 12: ``--data a5.jsonl a5.jsonl`` trained on 54 "exact
solutions", 3 of the 5 validation rows also in training)."""
import json
import os
import shutil

import pytest

from training.cli import main

DATA = os.path.join(os.path.dirname(__file__), "data", "full-attitude-small.jsonl")


def _train(tmp_path, *data):
    return main(["train", "--data", *map(str, data), "--out", str(tmp_path / "run"), "--epochs", "1", "--no-progress"])


def test_the_same_file_twice_is_refused(tmp_path, capsys):
    code = _train(tmp_path, DATA, DATA)
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert f"--data: {DATA} is given twice" in err
    assert not (tmp_path / "run").exists()


def test_a_copy_of_a_file_is_refused_naming_both(tmp_path, capsys):
    copy = tmp_path / "copy.jsonl"
    shutil.copyfile(DATA, copy)
    code = _train(tmp_path, DATA, copy)
    err = capsys.readouterr().err
    assert code == 2 and f"--data: {DATA} and {copy} hold the same problems (family full-attitude, seed 100" in err


def test_files_of_other_seeds_are_accepted(tmp_path):
    pytest.importorskip("torch")
    lines = open(DATA).read().splitlines(keepends=True)
    head = json.loads(lines[0])
    head["_meta"]["seed"] = 101
    other = tmp_path / "seed101.jsonl"
    other.write_text(json.dumps(head) + "\n" + "".join(lines[1:]))
    assert _train(tmp_path, DATA, other) == 0
