"""Benchmark: the first solve of a process under a time budget.

Each solve runs in a new Python process, as `slew solve --time-budget B` does. ``solve`` loads
the compiled kernels of the problem's kind before its clock starts (``solvers.kernel_loading``),
so the budget bounds the solve from the first one on; this prints, per family and method, the
solve's wall time against the budget (the overshoot), the loading time reported beside it
(``kernel_load_time``), the whole call, and the statuses.

    python benchmarks/bench_first_solve.py [--n 5] [--seed 5] [--budget 0.05]
                                           [--families full-attitude,pnorm,pointing-cones]

The families are those of ``bench_budget.py`` (problem i of a family is the same in both).
"""
import argparse
import json
import os
import subprocess
import sys

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")

_CHILD = """
import json, sys, time
sys.path.insert(0, {root!r}); sys.path.insert(0, {bench!r})
from bench_budget import problems
import solvers
p = problems({family!r}, {i} + 1, {seed})[{i}]
t0 = time.perf_counter()
s = solvers.solve(p, method={method!r}, time_budget={budget!r}, **{kw!r})
call = time.perf_counter() - t0
print(json.dumps([s.success, s.status, s.wall_time, s.kernel_load_time, call]))
"""

CONFIGS = (("auto", {}), ("auto", {"warm_start": None}), ("indirect", {"warm_start": None}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=5)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--budget", type=float, default=0.05)
    ap.add_argument("--families", default="full-attitude,pnorm,pointing-cones")
    args = ap.parse_args(argv)
    print(f"budget {args.budget:g} s; one new process a solve")
    print(f"{'family':15s} {'method':9s} {'warm':8s} {'verified':>9s} {'overshoot ms: median':>21s} {'max':>7s} "
          f"{'load s: median':>15s} {'call s: median':>15s}  statuses")
    for family in args.families.split(","):
        for method, kw in CONFIGS:
            if method == "indirect" and family == "pointing-cones":
                continue
            rows = []
            for i in range(args.n):
                code = _CHILD.format(root=ROOT, bench=os.path.join(ROOT, "benchmarks"), family=family, i=i,
                                     seed=args.seed, method=method, budget=args.budget, kw=kw)
                out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
                if out.returncode != 0:
                    raise SystemExit(f"{family} {method} problem {i}: {out.stderr[-2000:]}")
                rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
            ok, status, wall, load, call = (np.array(c) for c in zip(*rows))
            over = 1e3 * (wall - args.budget)
            stats = ",".join(f"{s}:{int(np.sum(status == s))}" for s in sorted(set(status.tolist())))
            warm = "default" if "warm_start" not in kw else str(kw["warm_start"])
            print(f"{family:15s} {method:9s} {warm:8s} {int(ok.sum()):>4d}/{len(ok):<4d} {np.median(over):>21.1f} "
                  f"{over.max():>7.1f} {np.median(load):>15.3f} {np.median(call):>15.3f}  {stats}", flush=True)


if __name__ == "__main__":
    main()
