"""``slew generate``: a dataset of solved slews from a task family (``docs/DATASET.md``).

::

    slew generate --family full-attitude --n 1000 --seed 0 -o data/a.jsonl
                  [--workers N] [--backend local|ray] [--address ADDR]
                  [--time-budget S] [--max-candidates N] [--solve-options JSON]
                  [--family-options JSON] [--solve-fn MODULE:FUNCTION]
                  [--no-progress] [--no-fsync]

Problem ``i`` is the family's task distribution sampled with
``np.random.default_rng([seed, i])``; each is solved (by default ``solvers.solve`` with
``method="auto"``: collocation first, then the exact refinement; no learned warm start) and
appended to the JSON Lines file ``-o`` as soon as it completes. Running the
same command again continues an interrupted (even SIGKILLed) run: indices already in the
file are skipped; a partial last line (no newline after it) is cut away, while a line that ends
with its newline but does not parse, even the last, is refused as corruption. A file generated
with another family, seed or distribution is refused, and so is an existing file that is not a
dataset, and ``--family-options`` under which no problem can be drawn.

Exit code: 0 when every index ``0 .. n-1`` is in the file (failure records included),
1 when some are missing (a worker died, or the run did not finish: run the command again),
130 on Ctrl-C and 143 on SIGTERM (the solve in progress is not recorded; run the command
again), 2 on bad options or a file that cannot be continued.
"""
from __future__ import annotations

import json
import os
import sys

FAMILY_CHOICES = ("full-attitude", "pointing-cones")   # == slew_env.tasks.FAMILIES (not imported: fast --help)


def add_arguments(p):
    p.add_argument("--family", required=True, metavar="NAME",
                   help=f"task family: {' | '.join(FAMILY_CHOICES)} (see docs/DATASET.md)")
    p.add_argument("--n", type=int, required=True, metavar="N", help="number of problems (indices 0 .. N-1)")
    p.add_argument("--seed", type=int, default=0, metavar="S", help="dataset seed (default 0)")
    p.add_argument("-o", "--output", required=True, metavar="FILE.jsonl",
                   help="dataset file (JSON lines); created, or continued if it exists")
    p.add_argument("--workers", type=int, metavar="N",
                   help="worker processes (local) or CPUs of a local Ray instance (default: all cores)")
    p.add_argument("--backend", default="local", choices=("local", "ray"),
                   help="local process pool (default) or Ray remote tasks")
    p.add_argument("--address", metavar="ADDR",
                   help="Ray cluster address (ray.init(address=...)); default: start a local instance")
    p.add_argument("--time-budget", type=float, metavar="S",
                   help="solver time budget per problem, seconds (default: the solver's, 20)")
    p.add_argument("--max-candidates", type=int, metavar="N",
                   help="most candidate guesses per problem (default: the solver's)")
    p.add_argument("--solve-options", metavar="JSON", default=None,
                   help="more solver options as a JSON object, e.g. '{\"min_candidates\": 2}'")
    p.add_argument("--family-options", metavar="JSON", default=None,
                   help="TaskDistribution fields changed from the family's, as a JSON object, "
                        "e.g. '{\"n_cones\": [1, 1]}'")
    p.add_argument("--solve-fn", default=None, metavar="MODULE:FUNCTION",
                   help="solve route, a function (problem, **options) -> SlewSolution "
                        "(default training.generate:solve_default = solvers.solve)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-fsync", action="store_true",
                   help="do not fsync after each record (still safe against a killed process, "
                        "not against a power cut)")


def _json_object(text, flag):
    if text is None:
        return {}
    try:
        d = json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{flag}: not valid JSON ({e})") from None
    if not isinstance(d, dict):
        raise ValueError(f"{flag}: expected a JSON object, got {type(d).__name__}")
    return d


def build_spec(args):
    from .generate import DEFAULT_SOLVE_FN, GenerationSpec, UnsampleableError

    if args.family not in FAMILY_CHOICES:
        raise ValueError(f"--family: unknown family {args.family!r}; choose one of {', '.join(FAMILY_CHOICES)}")
    if args.n < 0:
        raise ValueError(f"--n: must be a non-negative integer, got {args.n}")
    if args.seed < 0:
        raise ValueError(f"--seed: must be a non-negative integer, got {args.seed}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers: must be a positive integer, got {args.workers}")
    if args.address and args.backend != "ray":
        raise ValueError("--address: only with --backend ray")
    opts = _json_object(args.solve_options, "--solve-options")
    if args.time_budget is not None:
        if not args.time_budget > 0:
            raise ValueError(f"--time-budget: must be positive, got {args.time_budget}")
        opts["time_budget"] = args.time_budget
    if args.max_candidates is not None:
        if args.max_candidates < 1:
            raise ValueError(f"--max-candidates: must be a positive integer, got {args.max_candidates}")
        opts["max_candidates"] = args.max_candidates
    overrides = _json_object(args.family_options, "--family-options")
    overrides.pop("name", None)
    try:
        return GenerationSpec(args.family, seed=args.seed, n=args.n, overrides=overrides,
                              solve_fn=args.solve_fn or DEFAULT_SOLVE_FN, solve_options=opts)
    except TypeError as e:   # an unknown TaskDistribution field
        raise ValueError(f"--family-options: {e}") from None
    except UnsampleableError as e:   # checked before the file is opened: no record is written
        raise ValueError(f"--family-options: no problem can be drawn with {json.dumps(overrides)}: "
                         f"{e.reason}") from None


def run(args):
    from .generate import generate, usable_cores

    spec = build_spec(args)
    # as train and train-rl make their --out: the README's `-o data/a.jsonl` on a fresh clone
    out_dir = os.path.dirname(os.path.abspath(args.output))
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as e:
        raise ValueError(f"-o/--output: cannot create the directory {out_dir!r}: {e.strerror or e}") from None
    cores = usable_cores()
    if args.backend == "local" and args.workers is not None and args.workers > cores:
        # wall-clock time budgets then cut solves short, and their failure records are kept
        print(f"slew generate: warning: --workers {args.workers} is more than the {cores} usable core(s); each "
              "solve gets less of a core, so time budgets cut more solves short and those failures are kept",
              file=sys.stderr)
    s = generate(spec, args.output, workers=args.workers, backend=args.backend, address=args.address,
                 progress=not args.no_progress, fsync=not args.no_fsync)
    out = sys.stdout
    if s.route_note:
        print(f"{args.output}: note: this run solved with {s.route_note}; each record names its own "
              "solve_fn and solve_options", file=out)
    if s.truncated_bytes:
        print(f"{args.output}: cut away a partial last line ({s.truncated_bytes} bytes) left by an "
              "interrupted run", file=out)
    done = spec.n - len(s.missing)
    rate = f"{s.written / s.wall_time_s:.2f} solves/s" if s.wall_time_s > 0 and s.written else "-"
    print(f"{args.output}: {done}/{spec.n} problems of {spec.family} (seed {spec.seed}): "
          f"{s.successes} verified, {s.failures} failed; {s.written} solved by this run "
          f"({s.done_before} already present) in {s.wall_time_s:.1f} s, {rate}", file=out)
    if s.failures:
        from .dataset import load
        counts = {}
        for r in load(args.output):
            if r["index"] < spec.n and r.get("success") is not True:
                key = (r.get("status"), (r.get("message") or "").split(";")[0][:100])
                counts[key] = counts.get(key, 0) + 1
        for (status, msg), k in sorted(counts.items(), key=lambda kv: -kv[1])[:5]:
            print(f"  {k} failure(s), status {status}: {msg}", file=out)
    if s.missing:
        why = "interrupted" if s.interrupted else ("worker(s) died" if s.lost else "not finished")
        head = ", ".join(str(i) for i in s.missing[:10]) + (" ..." if len(s.missing) > 10 else "")
        print(f"{len(s.missing)} index(es) missing ({why}): {head}; run the same command again to continue",
              file=sys.stderr)
        return 128 + int(s.signal or 2) if s.interrupted else 1
    return 0

