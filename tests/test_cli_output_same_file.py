"""``slew solve`` outputs onto its inputs: refused before solving, naming the option.

A fuzz run (s42, violation 2): ``slew solve --batch problems.jsonl -o problems.jsonl`` replaced the
problems by the solutions (the text of an invalid line was lost for good), and ``-o p.json`` onto
the problem itself was accepted. Other existing outputs are still overwritten, as ``--help`` and
the README say."""
import json
import os

import pytest

from cli_stubs import one_line, stub_solve
from training.cli import main

PROBLEM = {"inertia": [1, 1, 1], "torque_max": 1.0, "qf": [0.5, 0.5, 0.5, 0.5]}


@pytest.fixture
def files(tmp_path):
    problem = tmp_path / "p.json"
    problem.write_text(json.dumps(PROBLEM))
    batch = tmp_path / "problems.jsonl"
    batch.write_text(json.dumps(PROBLEM) + '\n{"inertia": [1, 1, 1], "qf": [0, 1,\n' + json.dumps(PROBLEM) + "\n")
    model = tmp_path / "model.npz"
    model.write_bytes(b"not read before the refusal")
    os.link(batch, tmp_path / "hardlink.jsonl")
    os.symlink(problem, tmp_path / "symlink.json")
    return tmp_path


@pytest.mark.parametrize("argv, needle", [
    (["--batch", "problems.jsonl", "-o", "problems.jsonl"], "-o: 'problems.jsonl' is the input file 'problems.jsonl' (--batch)"),
    (["--batch", "problems.jsonl", "-o", "problems.jsonl", "--resume"], "-o: 'problems.jsonl' is the input file"),
    (["--batch", "problems.jsonl", "-o", "hardlink.jsonl"], "-o: 'hardlink.jsonl' is the input file 'problems.jsonl'"),
    (["p.json", "-o", "p.json"], "-o: 'p.json' is the input file 'p.json' (PROBLEM.json)"),
    (["p.json", "-o", "symlink.json"], "-o: 'symlink.json' is the input file 'p.json'"),
    (["p.json", "--plot", "p.json"], "--plot: 'p.json' is the input file 'p.json' (PROBLEM.json)"),
    (["p.json", "-o", "model.npz", "--warm-start", "model.npz"], "-o: 'model.npz' is the input file 'model.npz' (--warm-start)"),
    (["p.json", "-o", "out.json", "--plot", "out.json"], "--plot: 'out.json' is the -o file too"),
])
def test_an_output_onto_an_input_is_refused_before_solving(files, capsys, argv, needle):
    before = {p.name: p.read_bytes() for p in files.iterdir() if not p.is_symlink()}
    calls = []
    cwd = os.getcwd()
    os.chdir(files)
    try:
        with stub_solve(calls):
            code = main(["solve", "--no-progress", "--repeat", "0"] + argv)
    finally:
        os.chdir(cwd)
    line = one_line(capsys.readouterr().err)
    assert code == 2 and calls == []
    assert line.startswith("slew solve: error: ") and needle in line, line
    assert "would destroy it" in line or "would replace the solution" in line
    assert {p.name: p.read_bytes() for p in files.iterdir() if not p.is_symlink()} == before


def test_another_existing_output_is_overwritten_as_documented(files, capsys):
    notes = files / "notes.txt"
    notes.write_text("PRECIOUS NOTES")
    with stub_solve([]):
        assert main(["solve", str(files / "p.json"), "-o", str(notes), "--repeat", "0"]) == 1
    assert json.loads(notes.read_text())["status"] == 1
    out = files / "sols.jsonl"
    out.write_text("OLD RESULTS\n")
    with stub_solve([]):
        assert main(["solve", "--batch", str(files / "problems.jsonl"), "-o", str(out), "--no-progress"]) == 1
    assert [json.loads(line)["line"] for line in out.read_text().splitlines()] == [1, 2, 3]
    capsys.readouterr()
    with pytest.raises(SystemExit):
        main(["solve", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "An existing file is overwritten (batch: unless --resume)" in help_text
    assert "an input file (the problem, the batch, the model) is refused" in help_text
