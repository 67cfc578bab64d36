"""``slew evaluate``: the warm-start model against the classical guesses on held-out problems."""
from __future__ import annotations

import math
import os


def add_arguments(p):
    p.add_argument("--model", default=None,
                   help="model file (a network alone, or a .nn.npz table), or a shipped warm start by name: "
                        "default (the full-attitude network, then its neighbour table), pointing-cones (its "
                        "neighbour table, then the network); default: default")
    p.add_argument("--family", default="full-attitude", help="task family of the held-out problems")
    p.add_argument("--n", type=int, default=1000, help="held-out problems (default 1000)")
    p.add_argument("--seed", type=int, default=20261122, help="seed of the held-out problems (fresh: not a data seed)")
    p.add_argument("--train-data", nargs="*", default=None, metavar="FILE.jsonl",
                   help="the model's training data: builds the nearest-neighbour baseline from it (dataset files, "
                        "or for pointing-cones the solution table NAME.nn.npz the model was trained on; for full-attitude a "
                        "solution table alone is the lookup itself, e.g. the shipped "
                        "solvers/warmstart/models/full-attitude.nn.npz)")
    p.add_argument("--baseline-n", type=int, default=100,
                   help="problems for the slow baselines: eigenaxis, random, collocation (default 100)")
    p.add_argument("--budget", type=float, default=5.0,
                   help="time budget of a classical guess (eigenaxis, random), seconds (default 5)")
    p.add_argument("--warm-budget", type=float, default=None,
                   help="time budget of a model's candidates, seconds (default: solve()'s, 1; 0.2 with cones)")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: all cores)")
    p.add_argument("--out", "-o", default="runs/evaluate", help="output directory (report.md, results.jsonl, evaluation.png; files of those names already there are replaced)")
    p.add_argument("--no-progress", action="store_true")


def run(args) -> int:
    from training.warmstart.evaluate import evaluate
    if args.n < 1:
        raise ValueError(f"--n: must be ≥ 1, got {args.n}")
    # a fuzz run: a negative or zero budget, negative --baseline-n or --workers 0 ran and wrote
    # a report that looked valid (baselines at 0 % or "not applicable")
    for flag, v in (("--budget", args.budget), ("--warm-budget", args.warm_budget)):
        if v is not None and not (math.isfinite(v) and v > 0):
            raise ValueError(f"{flag}: must be a positive number of seconds, got {v}")
    if args.baseline_n < 0:
        raise ValueError(f"--baseline-n: must be ≥ 0, got {args.baseline_n}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers: must be ≥ 1, got {args.workers}")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ValueError(f"--out: {args.out!r} exists and is not a directory")
    for path in args.train_data or []:
        if not os.path.exists(path):
            raise FileNotFoundError(f"--train-data: no such file: {path}")
    evaluate(args.family, args.n, args.seed, args.model, args.train_data, args.out, args.baseline_n,
             args.workers, args.budget, progress_bar=not args.no_progress, warm_budget=args.warm_budget)
    with open(os.path.join(args.out, "report.md")) as f:
        print(f.read())
    return 0
