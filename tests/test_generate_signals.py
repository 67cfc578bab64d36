"""``slew generate`` stopped by a signal: the solve in progress is not recorded (a restart solves
it again), the exit code says which signal, and no pool worker outlives its parent.

An outside review found Ctrl-C with ``--workers 1`` swallowed by CasADi/IPOPT or numba: the
interrupted solve became a failure record, never retried, and the run ended with exit 0."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from training.dataset import load
from training.generate import GenerationSpec, generate

ROOT = Path(__file__).resolve().parent.parent
TESTS = Path(__file__).resolve().parent


def _swallowing(sig, at_index):
    """A solve route that, at ``at_index``, receives ``sig`` and swallows the KeyboardInterrupt
    as CasADi and numba do, returning a failure; the others fail at once (no solve needed)."""
    def solve(problem, index_box=[0], **options):
        i = index_box[0]
        index_box[0] += 1
        if i == at_index:
            try:
                os.kill(os.getpid(), sig)
                time.sleep(5.0)              # (the handler raises inside the sleep)
            except KeyboardInterrupt:
                return {"success": False, "status": 1, "message": "IPOPT: NonIpopt_Exception_Thrown"}
        return {"success": False, "status": 1, "message": "no candidate converged"}
    return solve


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_swallowed_interrupt_stops_the_run_without_recording_that_solve(tmp_path, sig):
    out = tmp_path / "d.jsonl"
    spec = GenerationSpec("full-attitude", seed=0, n=6)
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    s = generate(spec, out, workers=1, progress=False, solve_fn=_swallowing(sig, 2))
    assert s.interrupted and s.signal == sig
    assert [r["index"] for r in load(out)] == [0, 1]          # index 2's cut-short solve is not kept
    assert s.missing == [2, 3, 4, 5]
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before   # put back


def _cli(out, workers, *extra):
    return [sys.executable, "-m", "training.cli", "generate", "--family", "full-attitude", "--n", "8",
            "-o", str(out), "--workers", str(workers), "--no-progress", "--solve-fn", "gen_sleepy:solve",
            "--solve-options", '{"sleep": 60}', *extra]


def _env():
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(TESTS), os.environ.get("PYTHONPATH", "")]))


def _children(pid):
    """Processes whose parent is ``pid`` (Linux /proc)."""
    kids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if int((d / "stat").read_text().split(")")[-1].split()[1]) == pid:
                    kids.append(int(d.name))
            except (OSError, ValueError, IndexError):
                pass
    return kids


def _alive(pid):
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().split(")")[-1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc")
@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGKILL, -signal.SIGKILL)])
def test_pool_workers_end_with_their_parent(tmp_path, sig, code):
    proc = subprocess.Popen(_cli(tmp_path / "d.jsonl", 2), cwd=ROOT, env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline = time.time() + 60
        workers = []
        while len(workers) < 2 and proc.poll() is None and time.time() < deadline:
            time.sleep(0.2)
            workers = [k for k in _children(proc.pid)
                       if b"spawn_main" in (Path("/proc") / str(k) / "cmdline").read_bytes()]
        assert len(workers) == 2, proc.communicate(timeout=5)
        time.sleep(1.0)                       # (the workers are past their initializer)
        os.kill(proc.pid, sig)                # the parent alone, as a scheduler or the OOM killer does
        proc.wait(timeout=30)
        assert proc.returncode == code
        deadline = time.time() + 15
        while any(_alive(w) for w in workers) and time.time() < deadline:
            time.sleep(0.1)
        assert not any(_alive(w) for w in workers), "pool workers outlived their parent"
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def test_the_handlers_are_set_again_where_ray_replaced_them():
    # ray.init sets its own SIGTERM handler: a SIGTERM then ended a Ray run with exit 1, no summary
    from training.generate import _StopSignals
    before = signal.getsignal(signal.SIGTERM)
    with _StopSignals() as stop:
        signal.signal(signal.SIGTERM, lambda s, f: None)       # what ray.init does
        stop.rearm()
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1.0)
        assert stop.signum == signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) == before


def test_a_record_whose_fsync_a_signal_cut_counts_as_written(tmp_path, monkeypatch):
    import training.dataset as ds
    from training.dataset import DatasetWriter
    with DatasetWriter(tmp_path / "d.jsonl", ds.make_meta("full-attitude", 0, {})) as w:
        def interrupted(fd):
            raise KeyboardInterrupt
        monkeypatch.setattr(ds.os, "fsync", interrupted)
        with pytest.raises(KeyboardInterrupt):
            w.append({"index": 0, "success": True})
        assert w.done == {0: True}                          # it is in the file
    monkeypatch.undo()
    assert [r["index"] for r in load(tmp_path / "d.jsonl")] == [0]


@pytest.mark.parametrize("reraise", [True, False])
def test_a_deferred_interrupt_is_raised_after_the_block_or_dropped(reraise):
    from training.interrupts import interrupt_deferred
    done = []
    try:
        with interrupt_deferred(reraise=reraise):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.2)
            done.append(True)                              # the block was not cut
    except KeyboardInterrupt:
        assert reraise
    else:
        assert not reraise
    assert done == [True]
