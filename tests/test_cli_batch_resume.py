"""``slew solve --batch`` interrupted and continued: every finished record survives a signal, and
``--resume`` solves only the input lines without a record, with no duplicate.

A fuzz run (s42, violation 1): SIGINT or SIGTERM after 19 of 40 problems dropped all 19, since
the output was written atomically at the very end; nothing could continue the batch."""
import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from training.cli import main

ROOT = Path(__file__).resolve().parent.parent
N = 40


def _problems(n=N):
    # rest-to-rest slews of asymmetric bodies with a rate limit (the fuzz run's): each takes a
    # good part of the tiny budget, so a signal lands while many lines are left
    base = {"inertia": [1, 1, 1], "torque_max": 1.0, "qf": [0.5, 0.5, 0.5, 0.5], "rate_max": 0.8}
    return [dict(base, inertia=[1, 1 + 0.05 * k, 1 + 0.1 * k]) for k in range(n)]


def _write_batch(path, problems):
    path.write_text("".join(json.dumps(p) + "\n" for p in problems))


def _records(path):
    raw = path.read_bytes()
    assert raw == b"" or raw.endswith(b"\n"), "a partial last line"
    return [json.loads(line) for line in raw.decode().splitlines()]


@contextlib.contextmanager
def _stub_solve_line(fn):
    """``training.cli_solve.solve_line`` replaced for an in-process run (not the ``monkeypatch``
    fixture: this project's loads every kind of compiled kernel first, which these stubs never use)."""
    import training.cli_solve as cs
    old = cs.solve_line
    cs.solve_line = fn
    try:
        yield
    finally:
        cs.solve_line = old


def _recording_stub(calls):
    def solve_line(lineno, text, method, opts, dense):
        calls.append(lineno)
        return json.dumps({"line": lineno, "success": True, "status": 0, "stub": True})
    return solve_line


@pytest.mark.parametrize("sig, workers, group", [(signal.SIGINT, 2, True),     # Ctrl-C: the whole group
                                                 (signal.SIGTERM, 1, False)])  # a scheduler: the parent
def test_a_signal_keeps_every_finished_record_and_resume_continues(tmp_path, sig, workers, group):
    problems = _problems()
    src, out = tmp_path / "batch.jsonl", tmp_path / "out.jsonl"
    _write_batch(src, problems)
    out.write_text("PREVIOUS RESULTS\n")          # without --resume an existing file is overwritten
    cmd = [sys.executable, "-m", "training.cli", "solve", "--batch", str(src), "-o", str(out),
           "--time-budget", "0.3", "--no-progress", "--workers", str(workers)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        deadline = time.time() + 60
        seen = 0
        while time.time() < deadline and proc.poll() is None:
            raw = out.read_bytes()
            seen = 0 if raw.startswith(b"PREVIOUS") else raw.count(b"\n")
            if seen >= 2:
                break
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()
        (os.killpg if group else os.kill)(proc.pid, sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + sig, err
    kept = _records(out)
    lines = [r["line"] for r in kept]
    assert 2 <= len(kept) < N and len(set(lines)) == len(lines), lines
    # it stops after the problems in hand (one a worker), not after a queue of others (the
    # bound leaves room for a record racing the signal)
    assert len(kept) <= seen + workers + 1, (seen, len(kept))
    assert "stopping after the problem(s) in hand" in err
    for r in kept:                                  # each record is its own line's answer
        assert r["problem"]["inertia"] == [float(v) for v in problems[r["line"] - 1]["inertia"]]
        assert isinstance(r["success"], bool) and "tf" in r
    assert f"interrupted ({signal.Signals(sig).name}): {len(kept)} of {N} record(s) in {out}" in err
    assert f"--resume to solve the {N - len(kept)} line(s) left" in err and "Traceback" not in err
    if workers == 1:
        assert lines == list(range(1, len(kept) + 1))    # one worker: input order

    # the same command with --resume solves exactly the lines left, once each, and appends them
    # (a file in the pool's completion order too; one worker here: the stub lives in this process)
    before = out.read_bytes()
    calls = []
    with _stub_solve_line(_recording_stub(calls)):
        code = main(cmd[3:] + ["--resume", "--workers", "1"])
    assert code == (0 if all(r["success"] for r in kept) else 1)    # the exit code covers the whole file
    assert calls == sorted(set(range(1, N + 1)) - set(lines))
    assert out.read_bytes().startswith(before)
    assert sorted(r["line"] for r in _records(out)) == list(range(1, N + 1))


def test_resume_cuts_a_partial_last_line_and_solves_that_line_again(tmp_path, capsys):
    src, out = tmp_path / "b.jsonl", tmp_path / "o.jsonl"
    _write_batch(src, _problems(4))
    with _stub_solve_line(_recording_stub([])):
        assert main(["solve", "--batch", str(src), "-o", str(out), "--no-progress"]) == 0
    full = out.read_bytes().split(b"\n")
    torn = b"\n".join(full[:2]) + b"\n" + full[2][:15]        # killed while writing line 3's record
    out.write_bytes(torn)
    calls = []
    with _stub_solve_line(_recording_stub(calls)):
        assert main(["solve", "--batch", str(src), "-o", str(out), "--no-progress", "--resume"]) == 0
    assert calls == [3, 4]
    assert [r["line"] for r in _records(out)] == [1, 2, 3, 4]
    cap = capsys.readouterr()
    assert "cut away a partial last line (15 bytes)" in cap.err
    assert "4 problem(s): 4 solved, 0 not solved, 0 invalid (2 already in" in cap.out


def test_a_complete_batch_resumed_solves_nothing_and_keeps_the_exit_code(tmp_path, capsys):
    src, out = tmp_path / "b.jsonl", tmp_path / "o.jsonl"
    src.write_text(json.dumps(_problems(1)[0]) + "\n\n{bad json\n")
    with _stub_solve_line(lambda k, *a: json.dumps({"line": k, "success": False, "status": -1, "message": "x"})
                          if k == 3 else json.dumps({"line": k, "success": True})):
        assert main(["solve", "--batch", str(src), "-o", str(out), "--no-progress"]) == 1
    before = out.read_bytes()
    calls = []
    with _stub_solve_line(_recording_stub(calls)):
        assert main(["solve", "--batch", str(src), "-o", str(out), "--no-progress", "--resume"]) == 1
    assert calls == [] and out.read_bytes() == before
    assert "2 problem(s): 1 solved, 0 not solved, 1 invalid (2 already in" in capsys.readouterr().out


def test_resume_into_a_missing_file_starts_it(tmp_path):
    src, out = tmp_path / "b.jsonl", tmp_path / "new.jsonl"
    _write_batch(src, _problems(2))
    calls = []
    with _stub_solve_line(_recording_stub(calls)):
        assert main(["solve", "--batch", str(src), "-o", str(out), "--no-progress", "--resume"]) == 0
    assert calls == [1, 2] and [r["line"] for r in _records(out)] == [1, 2]


@pytest.mark.parametrize("content, needle", [
    (b'{"line": 1, "success": true}\n{"line": 2, "succ\n', "line 2 is not valid JSON"),   # complete: not cut
    (b'{"line": 1, "success": true}\n{"line": 9, "success": true}\n', "record of input line 9, which holds no"),
    (b'{"line": 1, "success": true}\n{"line": 1, "success": true}\n', "input line 1 has two records"),
    (b'{"line": 1, "success": true}\n{"index": 2}\n', "line 2 is not a record of 'slew solve --batch'"),
    # a record of another batch's problem under this batch's line 1 (a review: it was kept as done)
    (json.dumps({"line": 1, "success": True, "problem": dict(_problems(1)[0], inertia=[9, 9, 9])}).encode() + b"\n",
     "line 1 is the record of another problem than input line 1"),
    (b"PRECIOUS NOTES\n", "not the output of 'slew solve --batch'"),
    (b"PRECIOUS NOTES", "not the output of 'slew solve --batch'"),                       # no newline either
    (b'{"line": 1, "success": true}\nnotes', "are not the beginning of a record; refusing to cut them"),
])
def test_resume_refuses_a_file_it_cannot_continue_and_leaves_it(tmp_path, capsys, content, needle):
    src, out = tmp_path / "b.jsonl", tmp_path / "o.jsonl"
    _write_batch(src, _problems(3))
    out.write_bytes(content)
    calls = []
    with _stub_solve_line(_recording_stub(calls)):
        code = main(["solve", "--batch", str(src), "-o", str(out), "--no-progress", "--resume"])
    err = capsys.readouterr().err
    assert code == 2 and calls == [] and out.read_bytes() == content
    line = err.strip()
    assert "\n" not in line and line.startswith("slew solve: error: -o: ") and needle in line, err


def test_resume_keeps_a_record_of_the_same_problem_written_differently(tmp_path, capsys):
    # the record's problem is the solver's reading of the line (rate_max as three numbers, every
    # field spelled out): the same problem, kept as done
    from slew_env import SlewProblem
    src, out = tmp_path / "b.jsonl", tmp_path / "o.jsonl"
    _write_batch(src, _problems(2))
    rec = {"line": 1, "success": True, "problem": SlewProblem.from_dict(_problems(2)[0]).to_dict()}
    out.write_text(json.dumps(rec) + "\n")
    calls = []
    with _stub_solve_line(_recording_stub(calls)):
        assert main(["solve", "--batch", str(src), "-o", str(out), "--no-progress", "--resume"]) == 0
    assert calls == [2] and [r["line"] for r in _records(out)] == [1, 2]


@pytest.mark.parametrize("argv, needle", [
    (["-o", "-", "--resume"], "--resume: needs -o FILE"),
    (["-o", "/dev/null", "--resume"], "is not a regular file"),
])
def test_resume_needs_a_file_it_can_read_back(tmp_path, capsys, argv, needle):
    src = tmp_path / "b.jsonl"
    _write_batch(src, _problems(1))
    if argv[1] == "/dev/null" and not os.path.exists("/dev/null"):
        pytest.skip("no /dev/null")
    assert main(["solve", "--batch", str(src), "--no-progress"] + argv) == 2
    assert needle in capsys.readouterr().err


def test_resume_is_only_for_a_batch(capsys):
    example = ROOT / "examples" / "r3_seed_report_per_axis.json"
    assert main(["solve", str(example), "--resume"]) == 2
    assert "--resume: only with --batch" in capsys.readouterr().err


def test_a_second_ctrl_c_during_a_solve_is_not_recorded(tmp_path, capsys):
    # the route may swallow the KeyboardInterrupt and end as a failure (IPOPT, numba): that
    # failure must not become the line's record, or a resume would never solve it
    src, out = tmp_path / "b.jsonl", tmp_path / "o.jsonl"
    _write_batch(src, _problems(3))

    def solve_line(lineno, text, method, opts, dense):
        if lineno == 2:
            os.kill(os.getpid(), signal.SIGINT)          # first: stop after this problem
            try:
                os.kill(os.getpid(), signal.SIGINT)      # second: now
                time.sleep(5.0)
            except KeyboardInterrupt:
                return json.dumps({"line": lineno, "success": False, "status": -2, "message": "swallowed"})
        return json.dumps({"line": lineno, "success": True})

    with _stub_solve_line(solve_line):
        assert main(["solve", "--batch", str(src), "-o", str(out), "--no-progress"]) == 130
    assert [r["line"] for r in _records(out)] == [1]
    assert "1 of 3 record(s)" in capsys.readouterr().err


def test_a_second_run_on_the_same_output_is_refused_and_empties_nothing(tmp_path, capsys):
    # the output is locked as a dataset is: a second batch (with or without --resume) must neither
    # interleave its records nor empty the file of the run in progress
    from training.dataset import lock_exclusive
    src, out = tmp_path / "b.jsonl", tmp_path / "o.jsonl"
    _write_batch(src, _problems(2))
    out.write_text(json.dumps({"line": 1, "success": True}) + "\n")
    before = out.read_bytes()
    fd = os.open(out, os.O_RDWR | os.O_APPEND)
    try:
        lock_exclusive(fd, out)                     # the run in progress
        for extra in ([], ["--resume"]):
            calls = []
            with _stub_solve_line(_recording_stub(calls)):
                assert main(["solve", "--batch", str(src), "-o", str(out), "--no-progress"] + extra) == 2
            assert calls == [] and out.read_bytes() == before
            assert "-o: " in capsys.readouterr().err
    finally:
        os.close(fd)
