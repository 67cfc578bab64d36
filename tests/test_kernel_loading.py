"""The compiled kernels are loaded before a solve's clock starts (``solvers.kernel_loading``): a
time budget holds from the first solve of a process, and no route of a loaded kind loads a
kernel inside its budget. Each check runs in a new process, where nothing is loaded yet."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

import solvers
from slew_env import Cone, SlewProblem
from solvers.kernel_loading import problem_kind

ROOT = Path(__file__).resolve().parent.parent
R3_FILE = ROOT / "examples" / "r3_seed_report_per_axis.json"

# prints, as JSON, the numba signatures that the solves after ``load_kernels`` added
_NEW_SIGNATURES = """
import importlib, json, math, pkgutil, sys
sys.path.insert(0, {tests!r})
from numba.core.registry import CPUDispatcher
import numpy as np
import slew_env, solvers
from slew_env import SlewProblem
from reference_cases import TOUCH, melton
kernels = {{}}
for pkg in (slew_env, solvers):
    for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
        mod = importlib.import_module(m.name)
        kernels.update({{f"{{m.name}}.{{k}}": v for k, v in vars(mod).items() if isinstance(v, CPUDispatcher)}})
def signatures():
    return {{k: set(map(str, v.signatures)) for k, v in kernels.items()}}
problems = {problems}
solvers.load_kernels(problems)
before = signatures()
for p in problems:
    routes = [dict(), dict(time_budget=0.03, fallback="eigenaxis")]
    if not (p.cones and math.isfinite(p.torque_norm)):    # (the indirect route with cones: per-axis only)
        routes += [dict(method="indirect", warm_start=None, time_budget=3.0),
                   dict(method="multiple-shooting", warm_start=None, time_budget=3.0)]
    if p.cones:
        routes.append(dict(warm_start="pointing-cones"))
    elif p.sensor_target is None and not np.any(p.omega0):
        routes.append(dict(method="eigenaxis"))
    for kw in routes:
        solvers.solve(p, **kw)
after = signatures()
print(json.dumps({{k: sorted(after[k] - before[k]) for k in kernels if after[k] - before[k]}}))
"""


def _new_signatures(problems: str) -> dict:
    code = _NEW_SIGNATURES.format(tests=str(ROOT / "tests"), problems=problems)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1200, cwd=str(ROOT))
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_no_route_of_a_loaded_kind_loads_a_kernel():
    # per-axis full attitude (symmetric and asymmetric bodies, rest to rest, moving, rate limit),
    # p-norm, and pointing with cones: every route after loading, no kernel loaded inside it
    new = _new_signatures(
        "[SlewProblem([1, 1, 1], qf=[0.5, 0.5, -0.5, 0.5]), SlewProblem([1.0, 0.8, 0.6], qf=[0.6, 0.48, 0.64, 0.0]),"
        " SlewProblem([1.0, 0.8, 0.6], qf=[0.6, 0.48, 0.64, 0.0], omega0=[0.05, 0, 0]),"
        " SlewProblem([1.0, 0.8, 0.6], qf=[0.6, 0.48, 0.64, 0.0], rate_max=0.8),"
        " SlewProblem([1.0, 0.8, 0.6], qf=[0.6, 0.48, 0.64, 0.0], torque_norm=3.0),"
        " TOUCH, melton(40, 90)]")
    assert new == {}


_CONE = "[{'axis': [0.2, 0.9, 0.3], 'half_angle': 0.2}]"
_KINDS = {   # one process each: a kind loaded beside another could borrow its kernels
    "per-axis full": "SlewProblem([1.0, 0.8, 0.6], qf=[0.6, 0.48, 0.64, 0.0])",
    "per-axis full cones": f"SlewProblem([1.0, 0.8, 0.6], qf=[0.6, 0.48, 0.64, 0.0], cones={_CONE})",
    "p-norm full": "SlewProblem([1.0, 0.8, 0.6], qf=[0.6, 0.48, 0.64, 0.0], torque_norm=1.5)",
    "p-norm full cones": f"SlewProblem([1.0, 0.8, 0.6], qf=[0.6, 0.48, 0.64, 0.0], torque_norm=2.0, cones={_CONE})",
    "per-axis pointing": "SlewProblem([1.0, 0.8, 0.6], sensor_target=[0.3, 0.5, 0.81])",
    "per-axis pointing cones": f"SlewProblem([1.0, 0.8, 0.6], sensor_target=[0.3, 0.5, 0.81], cones={_CONE})",
    "p-norm pointing": "SlewProblem([1.0, 0.8, 0.6], sensor_target=[0.3, 0.5, 0.81], torque_norm=2.0)",
    "p-norm pointing cones": f"SlewProblem([1.0, 0.8, 0.6], sensor_target=[0.3, 0.5, 0.81], torque_norm=2.0, cones={_CONE})",
}


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(_KINDS))
def test_no_route_of_a_kind_loaded_alone_loads_a_kernel(kind):
    assert _new_signatures(f"[{_KINDS[kind]}]") == {}


def test_the_first_solve_of_a_process_keeps_its_budget():
    """The kernels are loaded before the clock: a 1 µs budget cuts the first candidate of the
    process's first solve (before, a process's first candidate ran past its deadline), and the
    loading is reported, in that solve only."""
    code = ("import json, solvers; from slew_env import SlewProblem; "
            f"p = SlewProblem.from_dict(json.loads(open({str(R3_FILE)!r}).read())); "
            "a = solvers.solve(p, method='indirect', warm_start=None, time_budget=1e-6); "
            "b = solvers.solve(p, method='indirect', warm_start=None); "
            "print(json.dumps([a.status, a.n_candidates, a.kernel_load_time, b.success, b.tf, b.kernel_load_time, "
            "a.to_dict(dense=False)['kernel_load_time_s']]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1200, cwd=str(ROOT))
    assert out.returncode == 0, out.stderr[-3000:]
    status, n_cand, load_a, ok_b, tf_b, load_b, load_json = json.loads(out.stdout.strip().splitlines()[-1])
    assert status == solvers.solution.STATUS_BUDGET_EXHAUSTED and n_cand == 1
    assert load_a > 0 and load_json == load_a
    assert ok_b and tf_b == pytest.approx(2.354017849, rel=1e-8) and load_b == 0.0


def test_problem_kinds():
    full = SlewProblem([1, 2, 3], qf=[0, 1, 0, 0])
    assert problem_kind(full) == ("per-axis", "full", False)
    assert problem_kind(full.replace(torque_norm=2.0)) == ("p-norm", "full", False)
    pointing = SlewProblem([1, 2, 3], sensor_target=[0, 1, 0], cones=[Cone([0, 0, 1], 0.2)])
    assert problem_kind(pointing) == ("per-axis", "pointing", True)


def test_load_kernels_checks_its_input():
    with pytest.raises(ValueError, match="problems"):
        solvers.load_kernels("full-attitude")
    with pytest.raises(ValueError, match="inertia"):
        solvers.load_kernels([{"inertia": [1, -1, 1], "qf": [0, 1, 0, 0]}])
    # warm_start as solve checks it (a review: these had built no NLPs and said nothing)
    p = {"inertia": [1, 1, 1], "qf": [0, 1, 0, 0]}
    with pytest.raises(ValueError, match="warm_start: 'none' is no model name"):
        solvers.load_kernels([p], warm_start="none")
    with pytest.raises(ValueError, match="warm_start: expected"):
        solvers.load_kernels([p], warm_start=42)
    with pytest.raises(ValueError, match="file not found"):
        solvers.load_kernels([p], warm_start="/no/such/model.npz")


def test_evaluation_workers_load_their_familys_kernels():
    """``slew evaluate`` times the guesses by calling the routes directly (not through ``solve``):
    its workers load the family's kernels when they start, so that a worker's first problem does
    not load them inside its warm budget."""
    code = ("import training.warmstart.evaluate as ev; from solvers import kernel_loading as k; "
            "print(sorted(k._LOADED)); ev._init(None, None, 'pointing-cones', 5); print(sorted(k._LOADED))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1200, cwd=str(ROOT))
    assert out.returncode == 0, out.stderr[-3000:]
    before, after = out.stdout.strip().splitlines()[-2:]
    assert before == "[]" and "('per-axis', 'pointing', True)" in after


def test_a_second_thread_waits_for_the_loading(monkeypatch):
    """While one thread loads a kind, another that needs it waits until the loading is done
    (it used to see the kind as loaded at once and solve with its kernels still loading)."""
    import threading
    import time
    from solvers import kernel_loading as kl
    kind = ("per-axis", "a test's kind", False)
    monkeypatch.setattr(kl, "problem_kind", lambda p: kind)
    finished = []

    def slow_load(k):
        time.sleep(0.3)
        finished.append(time.perf_counter())
    monkeypatch.setattr(kl, "_load_kind", slow_load)
    got = {}

    def run(name):
        got[name] = (kl.ensure_kernels(None), time.perf_counter())
    a, b = threading.Thread(target=run, args=("a",)), threading.Thread(target=run, args=("b",))
    try:
        a.start()
        time.sleep(0.05)
        b.start()
        a.join()
        b.join()
        assert got["a"][0] >= 0.3 and 0.2 <= got["b"][0] < 0.3     # (b's loading time: its wait)
        assert got["b"][1] >= finished[0] and len(finished) == 1
    finally:
        kl._LOADED.pop(kind, None)


def test_a_representative_solve_that_raises_does_not_fail_the_users_solve(monkeypatch):
    """Loading is an optimisation: a representative solve that raises (here a patched route) is
    recorded, and the user's own solve runs (its kernels then load inside it)."""
    from solvers import kernel_loading as kl
    kind = ("per-axis", "another test's kind", False)
    monkeypatch.setattr(kl, "problem_kind", lambda p: kind)

    def broken(*a, **k):
        raise RuntimeError("a damaged model file")
    monkeypatch.setattr("solvers.api.solve", broken)
    try:
        assert kl.ensure_kernels(SlewProblem([1, 1, 1], qf=[0, 1, 0, 0])) >= 0.0
        assert kind in kl._LOADED and "a damaged model file" in kl._ERRORS[kind][0]
    finally:
        kl._LOADED.pop(kind, None)
        kl._ERRORS.pop(kind, None)


def test_load_kernels_builds_a_cone_problems_nlps_too():
    """At start-up, ``load_kernels`` also builds the collocation NLPs of a pointing or cone
    problem's default mesh and cone count, which the first solve would otherwise build."""
    from solvers import collocation_nlp
    cones = [{"axis": a, "half_angle": 0.15} for a in ([1, 0, 0], [0, 1, 0], [0, 0, 1], [0.6, 0.8, 0.0])]
    p = SlewProblem([1.0, 0.8, 0.6], sensor_target=[0.3, 0.5, 0.81], sensor_axis=[0.6, 0.0, 0.8], cones=cones)
    built = lambda: {k[0] for k in collocation_nlp._CACHE if k[1] and k[2] == 4}     # noqa: E731
    assert not built() & {10, 80, 40}
    solvers.load_kernels([p])
    assert {10, 80, 40} <= built()


def test_load_kernels_builds_the_nlps_of_the_route_the_solves_will_take(monkeypatch):
    """``solve(p, warm_start=None)`` begins a full-attitude slew with collocation, where the
    default warm start does not: ``load_kernels(..., warm_start=None)`` builds its NLPs at start-up
    (a review's first budgeted solve after a plain ``load_kernels([p])`` took 197 ms of 20)."""
    from solvers import collocation
    built = []
    monkeypatch.setattr(collocation, "prebuild_nlps", lambda p: built.append(p) or 0.0)
    p = SlewProblem([1.0, 0.8, 0.6], torque_max=1.0, qf=[0.0, 0.0, 0.6, 0.8])
    solvers.load_kernels([p])
    assert built == []                      # the shipped warm start goes first: no NLP needed
    solvers.load_kernels([p], warm_start=None)
    assert built == [p]
    solvers.load_kernels([p], method="indirect", warm_start=None)
    assert built == [p]                     # the indirect route builds none
    with pytest.raises(ValueError, match="method"):
        solvers.load_kernels([p], method="fastest")
