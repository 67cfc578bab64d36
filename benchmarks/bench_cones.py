"""Benchmark: pointing-only slews with 1–3 keep-out cones across the short path.

Draws N problems from the environment's ``pointing-cones`` family (seeded) and solves each
with ``method="collocation"``, ``"indirect"`` and ``"auto"``; prints, per method, the
verified success rate (and how many answers are exact extremals: ``auto`` and ``indirect``
refine problems whose cones are inactive; how many are the ``indirect`` route's penalised
extremals, for active cones, and how many ``auto``'s bang-bang switch-time slews, where the path
rides a cone), median / 95th-percentile wall time, median final time, the worst
cone clearance of the verified answers, and the ratio of each method's time to
collocation's on the same problems.

    python benchmarks/bench_cones.py [--n 40] [--seed 0] [--no-cones] [--warm-start default|none|MODEL.npz]

``--no-cones``: the same family's pointing-only slews without cones (the indirect route's
roll transversality; ``auto`` refines collocation to exact extremals). ``--warm-start``: the
learned guess tried first by ``auto`` and ``indirect`` (``pointing-cones``, a model file), or
``default``: the shipped models as ``solve`` uses them (with cones, ``auto`` tries the
pointing-cones warm start after its default route and keeps a faster answer), or ``none``.
"""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import solvers  # noqa: E402
from slew_env import TaskDistribution  # noqa: E402

METHODS = ("collocation", "indirect", "auto")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-cones", action="store_true")
    ap.add_argument("--warm-start", default="default",
                    help="default (the shipped models: the pointing-cones one for these problems), none, or MODEL.npz")
    args = ap.parse_args(argv)
    ws = None if args.warm_start == "none" else args.warm_start
    dist = TaskDistribution.family("pointing-cones", **({"n_cones": (0, 0)} if args.no_cones else {}))
    probs = [dist.sample(np.random.default_rng([args.seed, i])) for i in range(args.n)]
    solvers.solve(probs[0], method="collocation")      # warm caches
    solvers.solve(probs[0], warm_start=ws)
    rows = {m: [] for m in METHODS}
    for k, p in enumerate(probs):
        for m in METHODS:
            t0 = time.perf_counter()
            try:
                s = solvers.solve(p, method=m, warm_start=ws)
                rows[m].append((s.success, time.perf_counter() - t0, s.tf,
                                s.verification.get("cone_clearance", {}).get("value", np.nan), "",
                                s.exact, "penalty homotopy" in s.route,
                                bool(s.warm_start.get("won") if s.warm_start.get("role") == "challenger"
                                     else s.warm_start.get("succeeded")), s.method == "switch-time"))
            except ValueError as e:   # the indirect route declines cones (clear error)
                rows[m].append((False, time.perf_counter() - t0, np.nan, np.nan, str(e)[:60], False, False, False,
                                False))
        print(f"\r{k + 1}/{len(probs)}", end="", file=sys.stderr)
    print(file=sys.stderr)
    ncones = [len(p.cones) for p in probs]
    won = sum(1 for k in range(len(probs)) if rows["auto"][k][7])
    print(f"pointing-cones benchmark{' (cones removed)' if args.no_cones else ''}: {args.n} problems (seed {args.seed}), "
          f"warm start {args.warm_start} (auto: the learned guess, first or as a challenger, gave the answer on "
          f"{won}/{len(probs)}), cones per problem "
          f"{ {int(c): int(n) for c, n in zip(*np.unique(ncones, return_counts=True))} }")
    col_t = np.array([r[1] for r in rows["collocation"]])
    for m in METHODS:
        r = rows[m]
        ok = np.array([x[0] for x in r])
        t = np.array([x[1] for x in r])
        tf = np.array([x[2] for x in r])
        clr = np.array([x[3] for x in r])
        exact = int(sum(x[5] for x in r))
        pen = int(sum(x[0] and x[6] for x in r))
        bang = int(sum(x[0] and x[8] for x in r))
        line = (f"  {m:12s} verified {ok.sum():3d}/{len(r)} = {100 * ok.mean():5.1f} % ({exact} exact extremals"
                + (f", {pen} penalised" if pen else "") + (f", {bang} switch-time" if bang else "") + ")")
        if ok.any():
            line += (f"   wall median {1e3 * np.median(t[ok]):7.1f} ms  p95 {1e3 * np.percentile(t[ok], 95):7.1f} ms"
                     f"   tf median {np.median(tf[ok]):.5f}"
                     + (f"   min clearance {np.nanmin(clr[ok]):.2e} rad" if np.isfinite(clr[ok]).any() else "")
                     + f"   time / collocation (median) {np.median(t[ok] / col_t[ok]):.2f}")
        else:
            reasons = {x[4] for x in r if x[4]}
            line += f"   ({'; '.join(sorted(reasons))[:120]})"
        print(line)


if __name__ == "__main__":
    main()
