"""``slew generate`` / ``training.generate``: runs, resume after SIGKILL, Ray backend, failure records."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from slew_env.core.dynamics import propagate
from slew_env.core.quaternion import qerror_angle
from training.cli import main
from training.dataset import DatasetMismatchError, load, read_meta, to_arrays
from training.generate import (STATUS_INTERNAL_ERROR, STATUS_REJECTED, STATUS_UNVERIFIED, GenerationSpec,
                               generate, problem_for, solve_task)

ROOT = Path(__file__).resolve().parent.parent
FAST = {"max_candidates": 4, "time_budget": 10.0}   # budget only bites on a loaded machine


def _replay_error(rec):
    """Independent check of a success record: fly the stored bang-bang control (switch times,
    first signs, torque bound) with fixed-step RK4 and measure the miss at the stored tf."""
    p = rec["problem"]
    J = np.array(p["inertia"])
    umax = np.array(p["torque_max"])
    u_first = np.array(rec["u_first"])
    events = sorted((t, i) for i in range(3) for t in rec["switch_times"][i])
    x = np.concatenate([p["q0"], p["omega0"]])
    sign = u_first.copy()
    t = 0.0
    for te, axis in events + [(rec["tf"], None)]:
        if te > t:
            x = propagate(x, umax * sign, J, te - t, max(4, int(400 * (te - t) / rec["tf"])))[-1]
            t = te
        if axis is not None:
            sign[axis] = -sign[axis]
    att = float(qerror_angle(x[:4], np.array(p["qf"])))
    rate = float(np.abs(x[4:] - np.array(p["omegaf"])).max())
    return att, rate


def _check_dataset(path, spec):
    """Every index 0..n-1 exactly once, each record's problem the one of its index, successes verified."""
    raw = [ln for ln in Path(path).read_text().split("\n")]
    assert raw[-1] == ""                                     # ends with a newline, no partial line
    lines = raw[1:-1]
    idx = [json.loads(ln)["index"] for ln in lines]
    assert sorted(idx) == list(range(spec.n))                # complete, no duplicates
    recs = load(path)
    assert [r["index"] for r in recs] == list(range(spec.n))
    for r in recs:
        assert r["family"] == spec.family and r["seed"] == spec.seed
        assert r["problem"] == problem_for(spec, r["index"]).to_dict()
        assert "t" not in r and "q" not in r                 # no dense samples
        assert r["solver_version"] is not None or r["solver_commit"] is not None
        if r["success"]:
            assert r["status"] == 0
            assert r["verification"] and all(c["passed"] for c in r["verification"].values())
            assert r["tf"] > 0 and r["tf"] <= r["baseline_tf"] * (1 + 1e-6)
            assert len(r["costate0"]) == 7 and len(r["switch_times"]) == 3
            assert r["exact"] == (r["method"] in ("indirect", "multiple-shooting"))
            if r["exact"]:   # an exact extremal: its switch times alone reproduce it
                att, rate = _replay_error(r)
                assert att < 1e-6 and rate < 1e-6, (r["index"], att, rate)
        else:
            assert r["message"]
    return recs


def test_problems_depend_only_on_family_seed_index():
    spec = GenerationSpec("full-attitude", seed=5, n=10)
    a = [problem_for(spec, i).to_dict() for i in (7, 2, 9)]
    b = [problem_for(GenerationSpec("full-attitude", seed=5, n=3), i).to_dict() for i in (7, 2, 9)]
    assert a == b
    assert problem_for(spec, 2) != problem_for(spec, 3)
    assert problem_for(spec, 2) != problem_for(GenerationSpec("full-attitude", seed=6), 2)
    # the full-attitude family mixes symmetric and asymmetric bodies
    inertias = [problem_for(spec, i).inertia for i in range(10)]
    assert any(np.allclose(J, 1.0) for J in inertias)
    assert any(not np.allclose(J, J[0]) for J in inertias)
    only_asym = GenerationSpec("full-attitude", seed=5, overrides={"symmetric_prob": 0.0})
    assert not any(np.allclose(problem_for(only_asym, i).inertia, 1.0) for i in range(10))
    pc = problem_for(GenerationSpec("pointing-cones", seed=0), 0)
    assert pc.is_pointing and 1 <= len(pc.cones) <= 3


def test_spec_validation():
    with pytest.raises(ValueError, match="unknown family"):
        GenerationSpec("nope")
    with pytest.raises(ValueError, match="seed"):
        GenerationSpec("full-attitude", seed=-1)
    with pytest.raises(ValueError, match="angle_deg"):
        GenerationSpec("full-attitude", overrides={"angle_deg": [10, 200]})
    with pytest.raises(ValueError, match="solve_fn"):
        GenerationSpec("full-attitude", solve_fn="no_colon")


def test_small_local_run_two_workers(tmp_path):
    spec = GenerationSpec("full-attitude", seed=0, n=6, solve_options=FAST)
    out = tmp_path / "a.jsonl"
    s = generate(spec, out, workers=2, progress=False)
    assert s.complete and s.written == 6 and s.done_before == 0
    recs = _check_dataset(out, spec)
    assert s.successes == sum(r["success"] for r in recs) >= 3
    meta = read_meta(out)
    assert meta["family"] == "full-attitude" and meta["seed"] == 0 and meta["n"] == 6
    assert meta["solve_options"] == FAST
    arr = to_arrays(recs)
    assert arr["success"].sum() == s.successes and arr["costate0"].shape == (6, 7)
    assert np.all(np.isfinite(arr["tf"][arr["success"]]))
    # a second run has nothing left to do
    s2 = generate(spec, out, workers=2, progress=False)
    assert s2.written == 0 and s2.done_before == 6 and s2.complete


def test_pointing_cones_records_failures_with_reason(tmp_path, capsys):
    # options the cone route refuses (single shooting): every record is a failure with that reason
    out = tmp_path / "c.jsonl"
    code = main(["generate", "--family", "pointing-cones", "--n", "4", "--seed", "1", "-o", str(out),
                 "--workers", "1", "--no-progress", "--max-candidates", "2",
                 "--solve-options", '{"method": "indirect", "segments": 1}'])
    assert code == 0
    recs = load(out)
    assert [r["index"] for r in recs] == [0, 1, 2, 3]
    for r in recs:
        assert r["success"] is False and r["status"] == STATUS_REJECTED and r["exact"] is None
        assert "segments" in r["message"] and "multiple shooting" in r["message"]
        assert r["problem"]["sensor_target"] is not None and 1 <= len(r["problem"]["cones"]) <= 3
    assert "4 failed" in capsys.readouterr().out
    # same file, other family: refused with a clear one-line error
    code = main(["generate", "--family", "full-attitude", "--n", "4", "--seed", "1", "-o", str(out)])
    assert code == 2
    assert "refusing to append" in capsys.readouterr().err
    with pytest.raises(DatasetMismatchError):
        generate(GenerationSpec("pointing-cones", seed=2, n=4), out, workers=1, progress=False)


def test_pointing_cones_default_route_records_touch_extremals(tmp_path):
    """Seed 1: both paths touch cones (problem 0 twice, problem 1 once): exact extremals with
    their touch multipliers (collocation answers before the switch-time touch formulation)."""
    out = tmp_path / "c2.jsonl"
    code = main(["generate", "--family", "pointing-cones", "--n", "2", "--seed", "1", "-o", str(out),
                 "--workers", "1", "--no-progress"])
    assert code == 0
    recs = sorted(load(out), key=lambda r: r["index"])
    for r in recs:
        assert r["success"] is True and r["verification"]["cone_clearance"]["value"] >= -1e-6
        assert r["exact"] is (r["method"] == "indirect")
    assert [r["exact"] for r in recs] == [True, True]
    for r, k in zip(recs, (2, 1)):
        tm = r["verification"]["touch_multipliers"]
        assert len(tm["times"]) == len(tm["multipliers"]) == len(tm["costate_jumps"]) == k
        assert min(tm["multipliers"]) >= 0.0


# --- pluggable routes (module-level so they could also run in a pool) ------------------------------
def _stub_unverified(problem, **options):
    return {"success": True, "status": 0, "message": "trust me", "tf": 1.0, "costate0": [0.0] * 7,
            "verification": {}}


def _stub_crash(problem, **options):
    raise RuntimeError("boom")


def test_pluggable_solve_fn_and_failure_kinds():
    spec = GenerationSpec("full-attitude", seed=0, n=1)
    r = solve_task(spec, 0, _stub_unverified)
    assert r["success"] is False and r["status"] == STATUS_UNVERIFIED
    assert "no verification checks" in r["message"] and r["solve_fn"].endswith("_stub_unverified")
    r = solve_task(spec, 0, _stub_crash)
    assert r["success"] is False and r["status"] == STATUS_INTERNAL_ERROR and "boom" in r["message"]
    assert r["problem"] == problem_for(spec, 0).to_dict()
    r = solve_task(GenerationSpec("full-attitude", seed=0, solve_fn="tests.test_generate:_stub_crash"), 0)
    assert r["status"] == STATUS_INTERNAL_ERROR and r["solve_fn"] == "tests.test_generate:_stub_crash"
    with pytest.raises(ValueError, match="cannot import"):
        generate(GenerationSpec("full-attitude", n=1, solve_fn="nowhere:fn"), "/nonexistent/x.jsonl")


def _count_records(path):
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return 0
    return max(0, data.count(b"\n") - 1)


def _group_alive(pgid):
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False


def test_sigkill_midway_then_restart_completes(tmp_path):
    """The issue's kill test: SIGKILL a generation run (the whole process group, pool workers
    included) once some records exist, simulate a torn last line, run the same command again,
    and check the dataset is complete, has no duplicates and loads."""
    n = 12
    out = tmp_path / "k.jsonl"
    cmd = [sys.executable, "-m", "training.cli", "generate", "--family", "full-attitude", "--n", str(n),
           "--seed", "7", "-o", str(out), "--workers", "2", "--max-candidates", "4", "--time-budget", "10",
           "--no-progress"]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.time() + 90
        while _count_records(out) < 3 and proc.poll() is None and time.time() < deadline:
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    deadline = time.time() + 10
    while _group_alive(proc.pid) and time.time() < deadline:
        time.sleep(0.05)
    assert not _group_alive(proc.pid), "pool workers survived the kill"
    killed_at = _count_records(out)
    assert 3 <= killed_at < n, killed_at
    before = out.read_bytes()
    before = before[:before.rfind(b"\n") + 1]     # the complete lines at the kill
    done_before = {r["index"] for r in load(out)}
    # a kill inside a write would leave a torn last line: add one to exercise the repair path
    missing = min(set(range(n)) - done_before)
    with open(out, "ab") as f:
        f.write(b'{"index": %d, "family": "full-attitude", "seed": 7, "problem": {"inertia": [0.5' % missing)

    res = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stderr + res.stdout
    assert "partial last line" in res.stdout
    after = out.read_bytes()
    assert after.startswith(before)               # records written before the kill are untouched
    spec = GenerationSpec("full-attitude", seed=7, n=n, solve_options=FAST)
    recs = _check_dataset(out, spec)
    assert {r["index"] for r in recs} - done_before == set(range(n)) - done_before
    assert sum(r["success"] for r in recs) >= n // 2
    assert f"{n}/{n} problems" in res.stdout


def test_ray_backend_local_instance(tmp_path):
    ray = pytest.importorskip("ray")
    spec = GenerationSpec("full-attitude", seed=3, n=4, solve_options=FAST)
    out = tmp_path / "r.jsonl"
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        s = generate(spec, out, backend="ray", progress=False)
    finally:
        ray.shutdown()
    assert s.complete and s.written == 4 and not s.lost
    recs = _check_dataset(out, spec)
    # the same problems and answers as the local backend (records carry their index)
    local = solve_task(spec, 2)
    ray_rec = next(r for r in recs if r["index"] == 2)
    assert ray_rec["problem"] == local["problem"]
    if local["success"] and ray_rec["success"]:
        assert abs(ray_rec["tf"] - local["tf"]) <= 1e-8 * local["tf"]


def test_warm_route_generation_with_the_shipped_model(tmp_path):
    """``solve_warm``: the model's guess alone; exact records say which candidate won."""
    from solvers.warmstart import DEFAULT_MODEL_FILE
    spec = GenerationSpec("full-attitude", seed=5, n=8, solve_fn="training.generate:solve_warm",
                          solve_options={"model": DEFAULT_MODEL_FILE, "time_budget": 0.5})
    out = tmp_path / "w.jsonl"
    s = generate(spec, out, workers=1, progress=False)
    assert s.complete and s.written == 8
    recs = _check_dataset(out, spec)
    ok = [r for r in recs if r["success"]]
    assert len(ok) >= 5
    assert all(r["exact"] and r["guess"].startswith("learned") and r["method"] == "indirect" for r in ok)
    for r in recs:
        if not r["success"]:
            assert r["status"] in (1, 2, 3, 4) and r["message"]


def test_solve_default_never_uses_a_model():
    from training.generate import solve_default
    p = problem_for(GenerationSpec("full-attitude", seed=5), 0)
    s = solve_default(p, time_budget=20)
    assert s.success and s.warm_start == {} and not s.guess.startswith("learned")
