"""Benchmark: solvers.solve on N seeded random rest-to-rest slews (classical guesses by default).

Prints convergence rate, median / 95th-percentile wall time, Newton iterations, and the
floor — one propagation of the converged extremal with its sensitivities (6 columns) —
with the ratio of the median solve time to that floor. Also the final-time gain over
the eigenaxis slew.

    python benchmarks/bench_solver.py [--n 100] [--seed 0] [--norm inf|2] [--method indirect]
                                      [--warm-start none|default|MODEL.npz]

``--warm-start none`` (default): the classical guesses only; ``default``: the shipped learned
model first (then the classical route if its guess fails).
"""
import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import solvers  # noqa: E402
from slew_env import SlewProblem  # noqa: E402
from slew_env.core import qfrom_uniform  # noqa: E402
from solvers.attitude_bvp import AttitudeBVP  # noqa: E402
from solvers.guesses import Guess  # noqa: E402


def random_problems(n, seed, norm):
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        J = [1.0, 1.0, 1.0] if k % 2 == 0 else rng.uniform(0.3, 1.0, 3)
        out.append(SlewProblem(J, torque_norm=norm, q0=qfrom_uniform(*rng.random(3)),
                               qf=qfrom_uniform(*rng.random(3))))
    return out


def floor_time(sol, repeats=20):
    """Wall time of one propagation of the converged extremal with 6 sensitivity columns."""
    prob = sol.problem
    bvp = AttitudeBVP(prob)
    if math.isinf(prob.torque_norm):
        bvp.set_mode("bang")
    else:
        bvp.set_mode("pnorm", p=prob.torque_norm)
    z, T = Guess(sol.costate0, sol.tf).to_nondim(bvp)
    y0, dy0 = bvp.initial(z)
    bvp.flow(y0, T, dy0)
    t0 = time.perf_counter()
    for _ in range(repeats):
        bvp.flow(y0, T, dy0)
    return (time.perf_counter() - t0) / repeats


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--norm", default="inf")
    ap.add_argument("--method", default="indirect")
    ap.add_argument("--warm-start", default="none")
    args = ap.parse_args(argv)
    ws = None if args.warm_start == "none" else args.warm_start
    probs = random_problems(args.n, args.seed, args.norm)
    solvers.solve(probs[0], method=args.method, warm_start=ws)   # compile / warm the numba cache
    rows = []
    t_all = time.perf_counter()
    for k, p in enumerate(probs):
        s = solvers.solve(p, method=args.method, warm_start=ws)
        rows.append(s)
        print(f"\r{k + 1}/{len(probs)} solved, {sum(r.success for r in rows)} converged", end="", file=sys.stderr)
    print(file=sys.stderr)
    total = time.perf_counter() - t_all
    ok = [s for s in rows if s.success]
    wall = np.array([s.wall_time for s in rows])
    wall_ok = np.array([s.wall_time for s in ok]) if ok else np.array([np.nan])
    nit = np.array([s.nit for s in ok]) if ok else np.array([np.nan])
    # the floor is one propagation of an extremal from its costates: exact answers only
    exact = [s for s in ok if s.exact]
    floors = np.array([floor_time(s) for s in exact[:30]]) if exact else np.array([np.nan])
    gain = np.array([1 - s.tf / s.baseline_tf for s in ok]) if ok else np.array([np.nan])
    sym = [s for s in rows if np.allclose(s.problem.inertia, s.problem.inertia[0])]
    asym = [s for s in rows if not np.allclose(s.problem.inertia, s.problem.inertia[0])]
    statuses = {}
    for s in rows:
        statuses[s.status] = statuses.get(s.status, 0) + 1
    print(f"solver benchmark: {args.n} random rest-to-rest slews, seed {args.seed}, "
          f"torque_norm {args.norm}, method {args.method}, warm start {args.warm_start}")
    if ws is not None:
        won = sum(1 for s in rows if s.warm_start.get("succeeded"))
        print(f"  learned guess won            {won}/{len(rows)}")
    print(f"  convergence (verified)       {len(ok)}/{len(rows)} = {100 * len(ok) / len(rows):.1f} %"
          f"   (symmetric {sum(s.success for s in sym)}/{len(sym)}, asymmetric {sum(s.success for s in asym)}/{len(asym)})")
    print(f"  statuses                     {dict(sorted(statuses.items()))}")
    by_method = {}
    for s in ok:
        by_method[s.method] = by_method.get(s.method, 0) + 1
    print(f"  verified answers by method   {dict(sorted(by_method.items()))}"
          "   (indirect: exact bang-bang extremal; collocation: approximate, own tolerances; switch-time: bang-bang, optimised switch times, not an extremal)")
    print(f"  wall time, all   median {1e3 * np.median(wall):9.1f} ms   p95 {1e3 * np.percentile(wall, 95):9.1f} ms")
    print(f"  wall time, conv. median {1e3 * np.median(wall_ok):9.1f} ms   p95 {1e3 * np.percentile(wall_ok, 95):9.1f} ms")
    print(f"  Newton iterations (conv.)    median {np.median(nit):.0f}   p95 {np.percentile(nit, 95):.0f}")
    print(f"  candidates tried (conv.)     median {np.median([s.n_candidates for s in ok]) if ok else float('nan'):.0f}")
    print(f"  floor: one propagation with sensitivities   median {1e3 * np.median(floors):.3f} ms")
    print(f"  median solve / floor         {np.median(wall_ok) / np.median(floors):.0f}x")
    print(f"  tf gain over eigenaxis slew  median {100 * np.median(gain):.2f} %   min {100 * np.min(gain):.2f} %   "
          f"max {100 * np.max(gain):.2f} %")
    print(f"  total {total:.1f} s")


if __name__ == "__main__":
    main()
