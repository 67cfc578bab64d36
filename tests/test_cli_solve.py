"""``slew solve``: single problem, batch, error handling (in-process via training.cli.main)."""
import json
from pathlib import Path

import pytest

from training.cli import main

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
R3 = EXAMPLES / "r3_seed_report_per_axis.json"
BATCH = EXAMPLES / "batch_small.jsonl"
R3_TF = 2.3540178          # REFERENCE_CASES.md R3, per-axis, indirect shooting
REQUIRED = {"success", "status", "message", "tf", "costate0", "switch_times", "u_first", "nit", "nfev",
            "wall_time_s", "method", "verification"}
DENSE = {"t", "q", "omega", "u", "costate"}


def _one_line_error(err):
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("slew solve: error: ")
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="module")
def r3_run(tmp_path_factory):
    """One in-process ``slew solve`` of R3 (per-axis) with -o and --plot, shared by the tests."""
    d = tmp_path_factory.mktemp("r3")
    out, fig = d / "r3.json", d / "r3.png"
    code = main(["solve", str(R3), "-o", str(out), "--plot", str(fig)])
    return code, out, fig


def test_single_exit_code_and_json(r3_run):
    code, out, _ = r3_run
    assert code == 0
    sol = json.loads(out.read_text())
    assert REQUIRED <= set(sol)
    assert DENSE <= set(sol)
    assert sol["success"] is True and sol["status"] == 0
    assert abs(sol["tf"] - R3_TF) <= 1e-6 * R3_TF
    assert len(sol["switch_times"]) == 3
    assert sum(len(s) for s in sol["switch_times"]) == 5
    assert sorted(len(s) for s in sol["switch_times"]) == [1, 2, 2]
    assert len(sol["costate0"]) == 7 and len(sol["u_first"]) == 3
    assert all(c["passed"] for c in sol["verification"].values())
    n = len(sol["t"])
    assert n > 100 and len(sol["q"]) == n and len(sol["costate"]) == n and len(sol["costate"][0]) == 7
    assert sol["problem"]["inertia"] == [1.0, 1.0, 1.0]
    # no temp file left next to the output
    assert sorted(p.name for p in out.parent.iterdir()) == ["r3.json", "r3.png"]


def test_single_plot_is_a_png(r3_run):
    _, _, fig = r3_run
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_summary_and_stdout_output_without_dense(capsys):
    code = main(["solve", str(R3), "-o", "-", "--no-dense", "--max-candidates", "1"])
    cap = capsys.readouterr()
    sol = json.loads(cap.out)                   # stdout holds only the JSON
    assert REQUIRED <= set(sol) and not (DENSE & set(sol))
    assert code == (0 if sol["success"] else 1)
    for word in ("success", "tf", "switches", "u_first", "nit / nfev", "wall time", "route", "guess",
                 "candidates", "baseline", "verification", "replay"):
        assert word in cap.err
    # how the answer's control is defined, as its record says
    assert sol["control_law"] == "bang-bang" and "control       bang-bang: ±torque_max" in cap.err


def test_solver_failure_exits_1_and_still_writes(tmp_path, monkeypatch, capsys):
    import solvers
    from solvers import SlewSolution

    def failing_solve(problem, method="auto", guess=None, **options):
        return SlewSolution(False, 1, "No candidate converged. (stub)", nit=3, nfev=7, wall_time=0.01,
                            method="indirect", problem=problem)

    monkeypatch.setattr(solvers, "solve", failing_solve)
    out, fig = tmp_path / "fail.json", tmp_path / "fail.png"
    code = main(["solve", str(R3), "-o", str(out), "--plot", str(fig)])
    assert code == 1
    sol = json.loads(out.read_text())
    assert sol["success"] is False and sol["status"] == 1 and sol["tf"] is None
    assert not fig.exists()
    assert "figure        not written" in capsys.readouterr().out


def test_batch(tmp_path, capsys):
    out = tmp_path / "sols.jsonl"
    code = main(["solve", "--batch", str(BATCH), "-o", str(out)])
    cap = capsys.readouterr()
    assert code == 1                            # one line of the batch is invalid
    recs = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(recs) == 3
    assert [r["line"] for r in recs] == [1, 2, 3]
    assert recs[0]["success"] and abs(recs[0]["tf"] - 3.24310) < 1e-4          # R1
    assert recs[1]["success"] and abs(recs[1]["tf"] - R3_TF) <= 1e-6 * R3_TF    # R3 per-axis
    assert not (DENSE & set(recs[0]))          # no dense samples in batch by default
    bad = recs[2]
    assert bad["success"] is False and bad["status"] == -1
    assert "inertia" in bad["message"]
    assert "3 problem(s): 2 solved, 0 not solved, 1 invalid" in cap.out
    assert "problem" in cap.err                 # tqdm bar on stderr


def test_batch_with_workers_numbers_every_line_and_skips_blank_lines(tmp_path):
    lines = BATCH.read_text().splitlines()
    src = tmp_path / "mixed.jsonl"
    src.write_text("{not json\n\n" + lines[2] + "\n   \n" + lines[1] + "\n")
    out = tmp_path / "mixed_out.jsonl"
    code = main(["solve", "--batch", str(src), "-o", str(out), "--workers", "2", "--dense", "--no-progress"])
    assert code == 1
    # with workers, records are written as they complete (each names its input line)
    recs = sorted((json.loads(line) for line in out.read_text().splitlines()), key=lambda r: r["line"])
    assert [r["line"] for r in recs] == [1, 3, 5]
    assert recs[0]["status"] == -1 and "JSON" in recs[0]["message"]
    assert recs[1]["status"] == -1 and "inertia" in recs[1]["message"]
    assert recs[2]["success"] and abs(recs[2]["tf"] - R3_TF) <= 1e-6 * R3_TF
    assert DENSE <= set(recs[2])


def test_batch_interrupted_keeps_the_finished_records(tmp_path, monkeypatch, capsys):
    # a fuzz run (s42): the whole-file atomic writer dropped every finished record on Ctrl-C
    import training.cli_solve as cs
    calls = []

    def interrupted(lineno, text, method, opts, dense):
        calls.append(lineno)
        if len(calls) > 1:
            raise KeyboardInterrupt
        return json.dumps({"line": lineno, "success": True})

    monkeypatch.setattr(cs, "solve_line", interrupted)
    out = tmp_path / "kept.jsonl"
    code = main(["solve", "--batch", str(BATCH), "-o", str(out), "--no-progress"])
    assert code == 130
    assert out.read_text() == json.dumps({"line": 1, "success": True}) + "\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.jsonl"]      # no temp file
    assert "1 of 3 record(s) in" in capsys.readouterr().err


def test_a_signal_mid_batch_stops_between_problems(tmp_path, monkeypatch):
    """A fuzz run: Ctrl-C raised inside a solve was swallowed by IPOPT (the batch ran to its end,
    exit 0) or came out of compiled code as a SystemError written down as a failed problem.
    Now SIGINT and SIGTERM only ask the batch to stop; it stops before the next problem, and the
    record of the problem in hand is kept."""
    import os
    import signal
    import training.cli_solve as cs
    calls = []

    def signalled(lineno, text, method, opts, dense):
        calls.append(lineno)
        os.kill(os.getpid(), signal.SIGTERM if len(calls) == 1 else signal.SIGINT)
        return json.dumps({"line": lineno, "success": True})   # the solve in hand completes

    monkeypatch.setattr(cs, "solve_line", signalled)
    out = tmp_path / "kept.jsonl"
    # the handler the batch must give back (SIG_IGN, not Python's, when pytest itself runs in
    # the background of a shell without job control)
    before = signal.getsignal(signal.SIGINT)
    code = main(["solve", "--batch", str(BATCH), "-o", str(out), "--no-progress"])
    assert code == 143 and calls == [1]
    assert [json.loads(line)["line"] for line in out.read_text().splitlines()] == [1]
    assert signal.getsignal(signal.SIGINT) is before


def test_batch_lines_end_at_newlines_only(tmp_path):
    # a fuzz run: str.splitlines split at a U+2028 or a form feed inside a line, and every later
    # record's "line" was one off
    lines = BATCH.read_text().splitlines()
    src = tmp_path / "sep.jsonl"
    src.write_text("{\"inertia\": [1, 2, 3], \"torque_norm\": \"inf\u2028\", \"qf\": [0, 1, 0, 0]}\r\n{bad\f}\n"
                   + lines[1] + "\n",
                   encoding="utf-8")
    out = tmp_path / "sep_out.jsonl"
    main(["solve", "--batch", str(src), "-o", str(out), "--no-progress"])
    recs = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["line"] for r in recs] == [1, 2, 3]
    assert recs[0]["success"] and recs[1]["status"] == -1 and recs[2]["success"]


def test_output_to_a_fifo_writes_into_it_and_leaves_it_a_fifo(tmp_path):
    # a fuzz run: -o /dev/null or a FIFO was replaced by a regular file (temp file + rename)
    import os
    import stat
    import threading
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(open(fifo).read()))
    reader.start()
    code = main(["solve", str(R3), "-o", str(fifo), "--repeat", "0"])
    reader.join(timeout=60)
    assert code == 0 and stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert abs(json.loads(got[0])["tf"] - R3_TF) <= 1e-6 * R3_TF


@pytest.mark.parametrize("argv, needle", [
    (["solve", "/nonexistent/problem.json"], "No such file"),
    (["solve", str(R3), "-o", "some_new_dir/"], "names a directory"),
    (["solve", "{bad}"], "cannot read"),
    (["solve", str(R3), "--method", "newton"], "unknown method 'newton'"),
    (["solve", "--batch", "/nonexistent/problems.jsonl", "-o", "x.jsonl"], "No such file"),
    (["solve", "--batch", str(BATCH)], "needs -o"),
    (["solve", str(R3), "-o", "/nonexistent/dir/sol.json"], "does not exist"),
    (["solve"], "give a problem file"),
])
def test_bad_input_exit_2_one_line(argv, needle, capsys):
    assert main(argv) == 2
    line = _one_line_error(capsys.readouterr().err)
    assert needle in line


def test_invalid_json_and_invalid_problem_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"inertia": [1, 1, 1], "qf": [0, 0, 0, 1]')
    assert main(["solve", str(bad)]) == 2
    assert "not valid JSON" in _one_line_error(capsys.readouterr().err)
    neg = tmp_path / "neg.json"
    neg.write_text(json.dumps({"inertia": [1, -2, 1], "qf": [0, 0, 0, 1]}))
    assert main(["solve", str(neg)]) == 2
    assert "inertia" in _one_line_error(capsys.readouterr().err)


def test_help_lists_solve(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "solve" in out and "JSONL batch" in out
    with pytest.raises(SystemExit):
        main(["solve", "--help"])
    out = capsys.readouterr().out
    for opt in ("--batch", "--method", "--segments", "--max-candidates", "--seed", "--plot", "--no-dense",
                "--workers", "-o"):
        assert opt in out


def test_batch_records_a_solver_crash_and_goes_on(tmp_path, monkeypatch):
    import solvers

    def crashing_solve(problem, method="auto", guess=None, **options):
        raise RuntimeError("boom")

    monkeypatch.setattr(solvers, "solve", crashing_solve)
    out = tmp_path / "crash.jsonl"
    assert main(["solve", "--batch", str(BATCH), "-o", str(out), "--no-progress"]) == 1
    recs = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["status"] for r in recs] == [-2, -2, -1]
    assert recs[0]["message"] == "internal error: RuntimeError: boom"


def test_cli_method_choices_match_the_solver():
    import solvers
    from solvers.cone_routes import CONE_CHALLENGE_MODES
    from training.cli_solve import CONE_CHALLENGE_CHOICES, METHOD_CHOICES
    assert tuple(METHOD_CHOICES) == tuple(solvers.METHODS)
    assert tuple(CONE_CHALLENGE_CHOICES) == tuple(CONE_CHALLENGE_MODES)
