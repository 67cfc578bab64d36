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


@pytest.mark.slow
def test_no_route_of_any_loaded_kind_loads_a_kernel():
    new = _new_signatures(
        "[SlewProblem([1.0, 0.8, 0.6], qf=[0.6, 0.48, 0.64, 0.0], torque_norm=p, cones=c)"
        " for p in (math.inf, 1.5, 2.0) for c in ([], [{'axis': [0.2, 0.9, 0.3], 'half_angle': 0.2}])]"
        " + [SlewProblem([1.0, 0.8, 0.6], sensor_target=[0.3, 0.5, 0.81], torque_norm=p, cones=c)"
        " for p in (math.inf, 2.0) for c in ([], [{'axis': [0.2, 0.9, 0.3], 'half_angle': 0.2}])]")
    assert new == {}


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
