"""``slew solve`` errors name the file and the option at fault (a fuzz run, s42, violation 12):
``--plot FIG.png`` with ``FIG-sensor.png`` a directory was reported as "cannot write 'FIG.png'"
(which had been written), and ``-o /dev/full`` as a bare "[Errno 28] No space left on device"."""
import json
import os

import pytest

from cli_stubs import one_line, stub_solve
from training.cli import main

POINTING = {"inertia": [1, 2, 3], "sensor_target": [0, 1, 0]}
FULL = {"inertia": [1, 1, 1], "torque_max": 1.0, "qf": [0.5, 0.5, 0.5, 0.5]}


def _one_line(err):
    line = one_line(err)
    assert line.startswith("slew solve: error: ")
    return line


def test_plot_names_the_sensor_figure_that_cannot_be_written_before_solving(tmp_path, capsys):
    problem = tmp_path / "pt.json"
    problem.write_text(json.dumps(POINTING))
    (tmp_path / "figs-sensor.png").mkdir()
    calls = []
    with stub_solve(calls):
        code = main(["solve", str(problem), "--repeat", "0", "--plot", str(tmp_path / "figs.png")])
    line = _one_line(capsys.readouterr().err)
    assert code == 2 and calls == []
    assert "figs-sensor.png" in line and "is a directory" in line and "--plot" in line
    assert "'" + str(tmp_path / "figs.png") + "'" not in line
    assert not (tmp_path / "figs.png").exists()          # nothing half done


def test_a_full_attitude_problem_needs_no_sensor_figure(tmp_path, capsys):
    # only pointing and cone problems draw FIG-sensor.png: a directory of that name does not matter
    problem = tmp_path / "p.json"
    problem.write_text(json.dumps(FULL))
    (tmp_path / "figs-sensor.png").mkdir()
    calls = []
    with stub_solve(calls):
        code = main(["solve", str(problem), "--repeat", "0", "--plot", str(tmp_path / "figs.png")])
    assert code == 1 and len(calls) == 1                  # solved (the stub fails), no figure error
    assert "error" not in capsys.readouterr().err


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
@pytest.mark.parametrize("batch, size", [(False, 10), (False, 100_000), (True, 10)])
def test_a_write_error_on_the_output_names_o_and_the_path(tmp_path, capsys, batch, size):
    # (a small solution fails when the file is closed; a large one already in the write, as a
    # solution with its dense samples does)
    problem = tmp_path / "p.json"
    problem.write_text(json.dumps(FULL) + ("\n" if batch else ""))
    argv = (["--batch", str(problem), "--no-progress"] if batch else [str(problem), "--repeat", "0"])
    with stub_solve([], message="x" * size):
        code = main(["solve"] + argv + ["-o", "/dev/full"])
    line = _one_line(capsys.readouterr().err.replace("\r", "\n"))
    assert code == 2
    assert "-o: cannot write to '/dev/full': No space left on device" in line


def test_a_sampled_answer_prints_no_switches_or_first_arc_signs(tmp_path, capsys):
    """An eigenaxis answer's control is its samples: no "0 in all" switch list and no meaningless
    u_first [+1, +1, +1] (an outside check, session 43); a bang-bang answer keeps both lines."""
    prob = tmp_path / "p.json"
    prob.write_text(json.dumps({"inertia": [1, 0.8, 0.6], "qf": [0.9, 0.3, 0.3, 0.1]}))
    assert main(["solve", str(prob), "--method", "eigenaxis", "--repeat", "0"]) == 0
    out = capsys.readouterr().out
    assert "switches      none listed: the control is the record's samples (linear-samples)" in out
    assert "u_first" not in out
    assert main(["solve", str(prob), "--method", "indirect", "--warm-start", "none", "--repeat", "0"]) == 0
    out = capsys.readouterr().out
    assert "switches      5 in all" in out and "u_first       [" in out


def test_a_collocation_answer_keeps_its_approximate_switch_list(tmp_path, capsys):
    """Its record lists the sampled torque's sign changes and u_first: the printout says what they
    are rather than "none listed" (a review of session 43)."""
    prob = tmp_path / "p.json"
    prob.write_text(json.dumps({"inertia": [1, 0.8, 0.6], "qf": [0.9, 0.3, 0.3, 0.1]}))
    assert main(["solve", str(prob), "--method", "collocation", "--repeat", "0"]) == 0
    out = capsys.readouterr().out
    assert "switches      5 in all" in out and "the sampled torque's sign changes" in out
    assert "u_first       [" in out
