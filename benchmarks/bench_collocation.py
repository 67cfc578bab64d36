"""Benchmark: direct collocation on N seeded random rest-to-rest full-attitude slews.

Half the problems have a symmetric body (J = 1, 1, 1), half a random one (J_i in
[0.3, 1]); attitudes uniform at random (the same generator as bench_solver.py). Each is
solved by ``solve_collocation`` and by the indirect solver ``solvers.solve``. Prints the
collocation success rate and statuses, median / 95th-percentile wall time, and on the
problems both solved, the relative final-time difference (collocation - indirect) /
indirect: median, spread, and how often it exceeds the collocation's own ``tf_tol``
(a different local optimum).

    python benchmarks/bench_collocation.py [--n 40] [--seed 0] [--norm inf|2] [--intervals 60]
"""
import argparse
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import solvers  # noqa: E402
from solvers.collocation import solve_collocation  # noqa: E402
from bench_solver import random_problems  # noqa: E402  (the same problem set)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--norm", default="inf")
    ap.add_argument("--intervals", type=int, default=60)
    args = ap.parse_args(argv)
    probs = random_problems(args.n, args.seed, args.norm)
    # warm up: numba caches of the indirect solver, CasADi NLP builds of both grids
    solve_collocation(probs[0], n_intervals=args.intervals)
    solvers.solve(probs[0])
    rows = []
    for k, p in enumerate(probs):
        c = solve_collocation(p, n_intervals=args.intervals)
        d = solvers.solve(p)
        rows.append((p, c, d))
        print(f"\r{k + 1}/{len(probs)} solved, collocation {sum(r[1].success for r in rows)} ok, "
              f"indirect {sum(r[2].success for r in rows)} ok", end="", file=sys.stderr)
    print(file=sys.stderr)
    col = [r[1] for r in rows]
    ok = [s for s in col if s.success]
    wall = np.array([s.wall_time for s in col])
    statuses = {}
    for s in col:
        statuses[s.status] = statuses.get(s.status, 0) + 1
    both = [(p, c, d) for p, c, d in rows if c.success and d.success]
    rel = np.array([(c.tf - d.tf) / d.tf for _, c, d in both]) if both else np.array([np.nan])
    beyond = [(p, c, d) for p, c, d in both if abs(c.tf - d.tf) > c.tf_tol]
    slower = sum(1 for _, c, d in beyond if c.tf > d.tf)
    faster = len(beyond) - slower
    ind_only = sum(1 for _, c, d in rows if d.success and not c.success)
    col_only = sum(1 for _, c, d in rows if c.success and not d.success)
    sym = [s for s in col if np.allclose(s.problem.inertia, s.problem.inertia[0])]
    nit = np.array([s.nit for s in ok]) if ok else np.array([np.nan])

    print(f"direct collocation (Hermite-Simpson, N={args.intervals}, CasADi {__import__('casadi').__version__} "
          f"+ IPOPT), {len(probs)} random rest-to-rest slews, norm={args.norm}, seed={args.seed}")
    print(f"  success             : {len(ok)}/{len(col)} ({100.0 * len(ok) / len(col):.1f} %); "
          f"symmetric bodies {sum(s.success for s in sym)}/{len(sym)}; statuses {dict(sorted(statuses.items()))}")
    print(f"  wall time           : median {np.median(wall):.3f} s, p95 {np.percentile(wall, 95):.3f} s, "
          f"max {wall.max():.3f} s (all problems)")
    print(f"  IPOPT iterations    : median {np.median(nit):.0f}, p95 {np.percentile(nit, 95):.0f} "
          f"(all starts and grids, successes)")
    ind_wall = np.array([r[2].wall_time for r in rows])
    print(f"  indirect solver     : {sum(r[2].success for r in rows)}/{len(rows)} succeeded; wall median "
          f"{np.median(ind_wall):.3f} s, p95 {np.percentile(ind_wall, 95):.3f} s")
    print(f"  tf vs indirect      : {len(both)} problems solved by both; (tf_col - tf_ind)/tf_ind median "
          f"{np.median(rel):+.2e}, min {rel.min():+.2e}, max {rel.max():+.2e}")
    med_tol = np.median([c.tf_tol / c.tf for _, c, _ in both]) if both else math.nan
    print(f"  tf_tol (relative)   : median {med_tol:.1e}; |difference| > tf_tol on {len(beyond)} "
          f"({slower} collocation slower, {faster} faster: different local optima)")
    print(f"  only one succeeded  : indirect only {ind_only}, collocation only {col_only}")
    for p, c, d in beyond[:5]:
        print(f"    J={np.round(p.inertia, 3).tolist()} colloc {c.tf:.6f} ± {c.tf_tol:.1e} "
              f"vs indirect {d.tf:.6f}")
    for p, c, d in rows:
        if not c.success:
            print(f"    collocation failed (status {c.status}): {c.message[:160]}")


if __name__ == "__main__":
    main()
