"""Benchmark: how closely ``solvers.solve`` keeps its ``time_budget``.

For each problem family, method, warm start and budget, solves N seeded problems and prints
the verified success rate, the statuses, and the overshoot of the wall time over the budget
(median, 95th percentile, maximum, in ms). A solve checks its budget between Newton
iterations, continuation steps, candidates and IPOPT iterations, so a small overshoot (one such
step) is expected; a solve that ignores its budget shows here as an overshoot of seconds.

    python benchmarks/bench_budget.py [--n 10] [--seed 5] [--budgets 0.05,0.2,1.0]
                                      [--families full-attitude,pnorm,pointing-cones] [--fallback]

``--fallback``: ``fallback="eigenaxis"`` (the eigenaxis slew where the route gives no verified
answer; not with collocation; with cones directly where its path clears them, else through
waypoints round them, which the ``pointing-cones`` family's cones across the short path always
need), and the count of fallback answers in the last column.

Families: ``full-attitude`` (per-axis bound, symmetric and asymmetric inertia), ``pnorm``
(the same slews under the 2-norm bound), ``pointing-cones`` (pointing-only targets, 1-3 keep-out
cones), ``pointing`` (the same pointing slews without cones; not in the default list). Each configuration first solves one problem of each number of cones unbudgeted, so
that compiled kernels and NLP templates are built before any timing (a cold process compiles for tens of
seconds: not what a budget can bound).
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import solvers  # noqa: E402
from slew_env import TaskDistribution  # noqa: E402

CONFIGS = (("auto", "default"), ("auto", None), ("indirect", None), ("collocation", None))


def problems(family, n, seed):
    if family == "pnorm":
        dist = TaskDistribution.family("full-attitude", torque_norm=2.0)
    elif family == "pointing":
        dist = TaskDistribution.family("pointing-cones", n_cones=(0, 0))
    else:
        dist = TaskDistribution.family(family)
    return [dist.sample(np.random.default_rng([seed, i])) for i in range(n)]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--budgets", default="0.05,0.2,1.0")
    ap.add_argument("--families", default="full-attitude,pnorm,pointing-cones")
    ap.add_argument("--fallback", action="store_true", help="fallback='eigenaxis' where it applies")
    args = ap.parse_args(argv)
    budgets = [float(b) for b in args.budgets.split(",")]
    print(f"{'family':15s} {'method':12s} {'warm':8s} {'budget':>7s} {'verified':>9s} "
          f"{'overshoot ms: median':>21s} {'p95':>7s} {'max':>7s}  statuses")
    for family in args.families.split(","):
        probs = problems(family, args.n, args.seed)
        for method, ws in CONFIGS:
            if method == "indirect" and family == "pointing-cones":
                continue     # the indirect route with cones is collocation first (as auto)
            if args.fallback and method == "collocation":
                continue     # the fallback does not apply
            extra = {"fallback": "eigenaxis"} if args.fallback else {}
            # build kernels and NLP templates (one of each number of cones) before timing
            for k in sorted({len(p.cones) for p in probs}):
                solvers.solve(next(p for p in probs if len(p.cones) == k), method=method, warm_start=ws)
            for b in budgets:
                over, ok, statuses, n_fallback = [], 0, {}, 0
                for p in probs:
                    t0 = time.perf_counter()
                    s = solvers.solve(p, method=method, warm_start=ws, time_budget=b, **extra)
                    over.append(time.perf_counter() - t0 - b)
                    ok += bool(s.success)
                    statuses[s.status] = statuses.get(s.status, 0) + 1
                    n_fallback += s.method == "eigenaxis"
                over = 1e3 * np.array(over)
                print(f"{family:15s} {method:12s} {str(ws):8s} {b:7.2f} {ok:4d}/{len(probs):<4d} "
                      f"{np.median(over):21.0f} {np.percentile(over, 95):7.0f} {over.max():7.0f}  "
                      f"{dict(sorted(statuses.items()))}"
                      + (f"  fallback answers {n_fallback}" if args.fallback else ""), flush=True)


if __name__ == "__main__":
    main()
