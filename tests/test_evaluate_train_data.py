"""``slew evaluate``'s ``--train-data``: another family's file is refused naming the option and
the file, and held-out problems that are training problems (same family, seed, distribution,
from --train-data or the model's card) are warned about (review s35, findings 8 and 13)."""
import json
import os

import pytest

from training.cli import main

HERE = os.path.dirname(__file__)
DATA = os.path.join(HERE, "data", "full-attitude-small.jsonl")          # full-attitude, seed 100
CONES = os.path.join(HERE, "data", "pointing-cones-small.jsonl")


def _evaluate(tmp_path, *extra):
    return main(["evaluate", "--n", "1", "--baseline-n", "0", "--workers", "1", "--no-progress",
                 "--out", str(tmp_path / "ev"), *extra])


def test_train_data_of_another_family_is_refused_naming_the_option_and_the_file(tmp_path, capsys):
    code = _evaluate(tmp_path, "--train-data", DATA, CONES)
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert f"--train-data: {CONES}: family 'pointing-cones', not the held-out problems' --family 'full-attitude'" in err
    assert not (tmp_path / "ev").exists()


def test_train_data_that_is_not_a_dataset_is_refused(tmp_path, capsys):
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    assert _evaluate(tmp_path, "--train-data", str(notes)) == 2
    assert f"--train-data: {notes}: not a slew dataset file" in capsys.readouterr().err


def test_held_out_problems_from_the_training_seed_are_warned_about(tmp_path, capsys):
    assert _evaluate(tmp_path, "--seed", "100", "--train-data", DATA) == 0
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert err == [f"slew evaluate: warning: the held-out problems (--family full-attitude, --seed 100) are the "
                   f"training problems of {DATA} (same family, seed and distribution); give another --seed"]
    s = json.load(open(tmp_path / "ev" / "summary.json"))
    assert s["held_out_in_training"] == [DATA]
    assert "**Warning**: the held-out problems are training problems of" in open(tmp_path / "ev" / "report.md").read()
    # another seed: no warning
    assert _evaluate(tmp_path, "--seed", "101", "--train-data", DATA) == 0
    assert "warning" not in capsys.readouterr().err


def test_the_model_cards_data_are_checked_too(tmp_path, capsys):
    pytest.importorskip("torch")
    assert main(["train", "--data", DATA, "--out", str(tmp_path / "run"), "--epochs", "1", "--no-progress"]) == 0
    capsys.readouterr()
    assert _evaluate(tmp_path, "--seed", "100", "--model", str(tmp_path / "run" / "model.npz")) == 0
    assert "are the training problems of full-attitude-small.jsonl (in the model's card)" in capsys.readouterr().err
    card = json.loads(str(__import__("numpy").load(tmp_path / "run" / "model.npz")["card"]))
    assert card["training"]["data_files"][0]["seed"] == 100 and len(card["training"]["data_files"][0]["sha256"]) == 64


SHIPPED_TABLE = os.path.join(os.path.dirname(HERE), "solvers", "warmstart", "models", "full-attitude.nn.npz")


def test_the_shipped_full_attitude_table_is_the_lookup_itself(tmp_path):
    """The datasets behind the shipped table are not shipped: the table alone gives the
    nearest-neighbour row (a new user's audit, session 43: it was refused, exit 2)."""
    assert _evaluate(tmp_path, "--n", "2", "--train-data", SHIPPED_TABLE) == 0
    rows = [json.loads(line) for line in open(tmp_path / "ev" / "results.jsonl")]
    nn = [r for r in rows if r["guess"] == "nearest-neighbour"]
    learned = {r["index"]: r for r in rows if r["guess"] == "learned"}
    # held-out problems 0 and 1: the lookup converges to the learned guess's extremal
    assert len(nn) == 2 and all(r["covered"] and r["success"] and r["exact"] for r in nn)
    assert all(abs(r["tf"] - learned[r["index"]]["tf"]) < 1e-9 for r in nn)
    assert not (tmp_path / "ev" / "nearest.nn.npz").exists()     # used as it is, not rebuilt
    assert json.load(open(tmp_path / "ev" / "summary.json"))["train_data"] == [SHIPPED_TABLE]


def test_a_full_attitude_table_with_other_files_is_refused(tmp_path, capsys):
    assert _evaluate(tmp_path, "--train-data", SHIPPED_TABLE, DATA) == 2
    err = capsys.readouterr().err
    assert "cannot be merged with other files" in err and SHIPPED_TABLE in err
    assert not (tmp_path / "ev").exists()
