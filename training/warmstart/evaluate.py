"""``slew evaluate``: how good is a warm-start model, against the classical guesses?

On held-out problems drawn from a task family with a fresh seed, every guess is given to
the indirect solver **alone** (no fallback) and we record whether it converged to a
verified extremal, the Newton iterations, the wall time and the final time:

* ``learned`` — the model (its candidates: predicted structure, propagated structure,
  costates alone);
* ``learned+table`` — the shipped model (full-attitude family, all its candidates, as in
  ``learned``), then, where it fails, the shipped singular table
  (``solvers.warmstart.singular_table``: the near singular answers' sequences, switch times
  optimised); converged = a verified answer, an exact extremal or a switch-time slew (counted
  apart), still with no collocation or classical fallback: where only 1 or 2 of the 5 nearest
  tabled problems are singular, the table's answer without the collocation check for an exact
  extremal that ``solve()`` adds there; where fewer than that are singular, the switching
  sequences of the nearest tabled solutions, optimised, then the exact solver from their KKT
  costates (``solvers.warm_routes.neighbour_sequences_route``; ``solve()`` runs the collocation route
  as well when that gives no extremal). (``solve()`` consults the table before the model's
  continuation candidate, so its times differ a little.) For the pointing-cones family (a
  model with a table of solutions: the shipped one), where the model's candidates fail, the
  switching sequences of its 4 nearest tabled solutions, optimised with the cones imposed
  (``solvers.cone_routes.cone_sequences_route``, within 0.5 s), then the exact extremal at the
  fastest verified one (0.15 s more): a verified bang-bang slew, or that extremal (counted as
  exact). ``solve()`` runs the same route under a time budget below 0.4 s, in what the learned
  candidates leave of it (far less time than here);
* ``nearest-neighbour`` — the solutions of the k nearest problems of the training data
  (the data-driven baseline), built from the same dataset files;
* ``eigenaxis`` — the analytic eigenaxis costates with the smoothing continuation;
* ``random`` — random unit costates, ``tf`` within ±30 % of the eigenaxis guess's,
  with the smoothing continuation;
* ``collocation`` — direct collocation (time only, on a subsample);
* ``auto`` — ``solvers.solve`` without a model (pointing-cones family only, on the subsample:
  collocation, then the exact refinements), the reference for the final-time gap there.

The final-time gap of a guess is ``tf / tf_best - 1`` with ``tf_best`` the fastest
verified exact extremal any guess found for that problem. The slow baselines
(eigenaxis, random, collocation) run on the first ``baseline_n`` problems.
Writes ``report.md`` (the table), ``results.jsonl`` (one line per problem and guess) and
``evaluation.png``.
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

GUESSES = ("learned", "learned+table", "nearest-neighbour", "eigenaxis", "random", "collocation", "auto")
_W = {}


SHIPPED = ("default", "pointing-cones")


def _model(model_path):
    """A model file (a network alone, or a table), or a shipped warm start by name, as ``solve``
    uses it: ``"default"`` (the full-attitude network, then its neighbour table) or
    ``"pointing-cones"`` (its neighbour table, then the network)."""
    from solvers import warmstart
    if not model_path or model_path == "default":
        return warmstart.default_warm_start()
    if model_path in SHIPPED:
        return warmstart.resolve(model_path)
    return warmstart.load_model(model_path)


def _init(model_path, nn_path, family=None, seed=0):
    from solvers import warmstart
    from solvers.kernel_loading import ensure_kernels
    _W["model"] = _model(model_path)
    _W["nn"] = warmstart.load_model(nn_path) if nn_path else None
    if family is not None:
        # the guesses are timed by calling the routes directly, not through solve(), which would
        # load the compiled kernels before its clock: a worker's first problem would load them
        # inside its warm budget (0.2 s with cones) and fail for it
        from training.generate import GenerationSpec, problem_for
        ensure_kernels(problem_for(GenerationSpec(family, seed=seed), 0))


def _run_one(args):
    """Every guess of ``args`` on one problem, with one BLAS thread, as inside ``solvers.solve``
    (these routes are called directly)."""
    from solvers.blas_threads import single_threaded_blas
    with single_threaded_blas():
        return _run_guesses(*args)


def _run_guesses(family, seed, index, guesses, budget, warm_budget):
    from solvers import Guess
    from solvers.multistart import solve_indirect
    from solvers.warm_routes import try_warm_start
    from solvers.warmstart.features import canonical_form, solution_from_canonical
    from training.generate import GenerationSpec, problem_for
    prob = problem_for(GenerationSpec(family, seed=seed), index)
    out = []
    for name in guesses:
        t0 = time.perf_counter()
        try:
            if name == "learned+table":
                out.append(_with_table(prob, out))
                continue
            if name in ("learned", "nearest-neighbour"):
                model = _W["model"] if name == "learned" else _W["nn"]
                sol, info, _ = try_warm_start(prob, "indirect", model, {"warm_budget": warm_budget})
                if sol is None and info.get("covered") is False:
                    out.append({"index": index, "guess": name, "covered": False, "reason": info.get("reason")})
                    continue
                if sol is None:     # the model raised: a failure of that guess, not a coverage gap
                    out.append({"index": index, "guess": name, "covered": True, "success": False, "exact": False,
                                "tf": None, "nit": 0, "wall_time_s": time.perf_counter() - t0, "won": "",
                                "message": info.get("error", "no guess")[:200]})
                    continue
            elif name == "eigenaxis":
                sol = solve_indirect(prob, "indirect", None, max_candidates=1, min_candidates=1, time_budget=budget)
            elif name == "random":
                rng = np.random.default_rng([seed, index, 7])
                cf = canonical_form(prob)
                z = rng.normal(size=6)
                z /= np.linalg.norm(z)
                c0, tf, _, _ = solution_from_canonical(prob, cf, z, cf.T_eig * rng.uniform(0.7, 1.3))
                sol = solve_indirect(prob, "indirect", Guess(c0, tf, source="random"), max_candidates=1,
                                      min_candidates=1, time_budget=budget)
            elif name == "auto":
                from solvers import solve
                sol = solve(prob, warm_start=None)
            else:
                from solvers.collocation import solve_collocation
                sol = solve_collocation(prob)
            wall = time.perf_counter() - t0
            exact = bool(sol.success) and name != "collocation" and bool(getattr(sol, "exact", True))
            out.append({"index": index, "guess": name, "covered": True, "success": bool(sol.success),
                        "exact": exact, "tf": float(sol.tf) if sol.success else None,
                        "nit": int(sol.nit), "wall_time_s": wall, "won": sol.guess,
                        "message": "" if sol.success else sol.message[:200]})
        except ValueError as e:
            out.append({"index": index, "guess": name, "covered": False, "reason": str(e)[:200]})
    return out


def _with_table(prob, out):
    """The ``learned+table`` record: the ``learned`` record of this problem (run just before)
    if it converged, else the table's route after it, its time added: the singular table's
    (full-attitude), or the sequences of the model's nearest tabled solutions with the cones
    imposed (pointing-cones, ``solvers.cone_routes.cone_sequences_route``)."""
    from solvers.cone_routes import cone_sequences_route
    from solvers.warm_routes import neighbour_sequences_route, singular_table_route, table_votes_bang_bang
    learned = next(r for r in out if r["guess"] == "learned")
    rec = dict(learned, guess="learned+table")
    if not learned.get("covered") or learned.get("success"):
        return rec
    t0 = time.perf_counter()
    info = {}
    if prob.cones:
        sol, (nit, _) = cone_sequences_route(prob, {}, info, model=_W["model"])
    else:
        sol, (nit, _) = singular_table_route(prob, {}, info, exact_check=False)   # the table's answers: no collocation
        if sol is None and table_votes_bang_bang(info):
            sol, (nit_nb, _) = neighbour_sequences_route(prob, {}, info)   # the neighbours' sequences
            nit += nit_nb
    rec["wall_time_s"] = learned["wall_time_s"] + time.perf_counter() - t0
    if sol is not None:
        rec.update(success=True, exact=bool(sol.exact), tf=float(sol.tf), nit=learned["nit"] + int(sol.nit),
                   won=sol.guess, message="")
    else:
        rec["nit"] = learned["nit"] + nit
    return rec


def inference_time(model, family, seed, n=200):
    """Median seconds per problem of the model's whole call as ``solve`` makes it
    (``guess_or_reason``: the coverage checks, the canonical form, the network or the table's
    first neighbour, the guess object; deferred candidates are made only when a solver reaches
    them, so not here). This is what a solve records in ``warm_start["inference_s"]``."""
    if hasattr(model, "guess_or_reason"):
        def infer(p):
            model.guess_or_reason(p)
    else:
        def infer(p):
            model.guess(p)
    return _median_time(infer, model, family, seed, n)


def network_time(model, family, seed, n=200):
    """Median seconds per problem of the canonical form and the network alone (with the
    pointing-cones ensemble, the table's nearest query too): the part of the inference that
    earlier evaluations reported."""
    from solvers.warmstart.cone_features import cone_canonical_form
    from solvers.warmstart.cone_model import ConeWarmStartModel
    from solvers.warmstart.features import canonical_form
    from solvers.warmstart.attitude_ensemble import AttitudeEnsembleWarmStart
    from solvers.warmstart.cone_ensemble import ConeEnsembleWarmStart
    if isinstance(model, AttitudeEnsembleWarmStart):
        def infer(p):
            cf = canonical_form(p)
            model.network.predict_canonical(cf.x, cf.T_eig)
    elif isinstance(model, ConeEnsembleWarmStart):
        def infer(p):
            cf = cone_canonical_form(p)
            model.table.nearest(cf.x, model.n_neighbours)
            model.network.predict_canonical(cf.x, cf.T_ref)
    elif isinstance(model, ConeWarmStartModel):
        def infer(p):
            cf = cone_canonical_form(p)
            model.predict_canonical(cf.x, cf.T_ref)
    elif hasattr(model, "predict_canonical"):
        def infer(p):
            cf = canonical_form(p)
            model.predict_canonical(cf.x, cf.T_eig)
    else:       # a model of another kind: no separate network stage
        return math.nan
    return _median_time(infer, model, family, seed, n)


def table_query_time(model, family, seed, n=200):
    """Median seconds of the ensemble table's nearest query (canonical form included)."""
    from solvers.warmstart.features import canonical_form

    def query(p):
        cf = canonical_form(p)
        model.table.nearest(cf.x, model.n_neighbours)
    return _median_time(query, model, family, seed, n)


def _median_time(fn, model, family, seed, n):
    """Median seconds of ``fn(problem)`` over the first ``n`` problems of the family that
    ``model`` covers, after one warm-up pass (first calls load compiled code, the CPU clocks up);
    NaN if it covers none."""
    from training.generate import GenerationSpec, problem_for
    probs = [problem_for(GenerationSpec(family, seed=seed), i) for i in range(n)]
    probs = [p for p in probs if model.covers(p) is None]
    if not probs:
        return math.nan
    for p in probs:
        fn(p)
    ts = []
    for p in probs:
        t0 = time.perf_counter()
        fn(p)
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def build_nn(data_paths, out_path, max_switches=5, k=3, family="full-attitude"):
    if family == "pointing-cones":
        from .cone_data import nearest_table
    else:
        from .data import nearest_table
    nearest_table(data_paths, max_switches, k).save(out_path)
    return out_path


def evaluate(family="full-attitude", n=1000, seed=20261122, model_path=None, train_data=None, out="runs/evaluate",
             baseline_n=100, workers=None, budget=5.0, progress_bar=True, warm_budget=None) -> dict:
    """See the module docstring. ``budget``: seconds per classical guess (eigenaxis, random);
    ``warm_budget``: seconds for a model's candidates (default: ``solvers.solve``'s, 1 s, or
    0.2 s for the pointing-cones family, each candidate capped at ``solvers.cone_routes.CONE_CANDIDATE_CAP``)."""
    from solvers.cone_routes import CONE_WARM_BUDGET
    from solvers.warm_routes import WARM_BUDGET
    if warm_budget is None:
        warm_budget = CONE_WARM_BUDGET if family == "pointing-cones" else WARM_BUDGET
    warm_budget = float(warm_budget)
    from solvers import warmstart
    check_train_data(train_data, family)
    model = _model(model_path)
    n_covered = check_coverage(model, model_path, family, n, seed)
    overlap = held_out_in_training(family, seed, train_data, model)
    if overlap:
        print(f"slew evaluate: warning: the held-out problems (--family {family}, --seed {seed}) are the training "
              f"problems of {', '.join(overlap)} (same family, seed and distribution); give another --seed",
              file=sys.stderr)
    os.makedirs(out, exist_ok=True)
    nn_path = None
    if full_attitude_table(train_data, family):
        nn_path = full_attitude_table(train_data, family)      # the lookup as it is
    elif train_data:
        nn_path = build_nn(train_data, os.path.join(out, "nearest.nn.npz"), family=family)
    t_inference = inference_time(model, family, seed)   # before the pool: a quiet process
    t_network = network_time(model, family, seed)
    jobs = []
    # the singular table goes with the shipped full-attitude model; a pointing-cones model's own
    # table of solutions gives the sequences (the shipped one, or an ensemble's file)
    from solvers.warmstart.cone_ensemble import ConeEnsembleWarmStart
    from solvers.warmstart.cone_nearest import ConeNearestNeighbourModel
    table = ((family == "full-attitude" and model_path in (None, "", "default")
              and warmstart.default_singular_table() is not None)
             or (family == "pointing-cones" and isinstance(model, (ConeEnsembleWarmStart, ConeNearestNeighbourModel))))
    for i in range(n):
        g = ["learned"] + (["learned+table"] if table else []) + (["nearest-neighbour"] if nn_path else [])
        if i < baseline_n:
            # with cones the classical guesses do not apply; the model-free solve() is the
            # reference (its exact answers set the best final time)
            g += ["collocation", "auto"] if family == "pointing-cones" else ["eigenaxis", "random", "collocation"]
        jobs.append((family, seed, i, tuple(g), budget, warm_budget))
    workers = workers or os.cpu_count() or 1
    rows = []
    bar = None
    if progress_bar:
        from tqdm import tqdm
        bar = tqdm(total=n, desc="slew evaluate", unit="problem")
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers, initializer=_init, initargs=(model_path, nn_path, family, seed)) as ex:
        for res in ex.map(_run_one, jobs, chunksize=4):
            rows += res
            if bar is not None:
                bar.update(1)
                bar.set_postfix(rate=f"{len(set(r['index'] for r in rows)) / (time.perf_counter() - t0):.1f}/s")
    if bar is not None:
        bar.close()
    with open(os.path.join(out, "results.jsonl"), "w") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")
    summary = summarise(rows)
    summary["inference_s_median"] = t_inference
    summary["inference_measures"] = ("the model's whole call as solve makes it: coverage, canonical form, "
                                     "network or first neighbour, the guess object; deferred candidates not made")
    summary["network_s_median"] = t_network
    from solvers.warmstart.attitude_ensemble import AttitudeEnsembleWarmStart
    from solvers.warmstart.cone_ensemble import ConeEnsembleWarmStart
    if isinstance(model, AttitudeEnsembleWarmStart):
        summary["network_measures"] = "canonical form + network"
        summary["table_query_s_median"] = table_query_time(model, family, seed)
    elif isinstance(model, ConeEnsembleWarmStart):
        summary["network_measures"] = "canonical form, network and the table's nearest query"
    else:
        summary["network_measures"] = "canonical form + network"
    summary.update(family=family, n=n, seed=seed, model_covers=n_covered, held_out_in_training=overlap,
                   baseline_n=min(baseline_n, n), budget_s=budget, warm_budget_s=warm_budget,
                   model=getattr(model, "path", None) or getattr(model, "name", None) or model_path
                   or warmstart.DEFAULT_MODEL_FILE,
                   train_data=[os.fspath(p) for p in (train_data or [])], workers=workers)
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    with open(os.path.join(out, "report.md"), "w") as f:
        f.write(markdown(summary))
    plot(rows, os.path.join(out, "evaluation.png"))
    return summary


def full_attitude_table(train_data, family):
    """The one ``--train-data`` file when it is a full-attitude solution table (``NAME.nn.npz``,
    such as the shipped ``full-attitude.nn.npz``): it is the nearest-neighbour lookup itself, used
    as it is (the dataset files it was built from are large and not shipped). ``None`` otherwise.
    A table given with other files is refused: it cannot be merged with them. A full-attitude
    table names no data files, so the check that the held-out problems are not training problems
    rests on the model's card (the shipped model's names the same data as its table)."""
    from .table_data import is_table
    if family != "full-attitude":
        return None
    from solvers.warmstart import load_model
    from solvers.warmstart.nearest import NearestNeighbourModel
    found = None
    for path in train_data or []:
        if not is_table(path):
            continue
        try:
            table = load_model(path)
        except (OSError, ValueError) as e:
            raise ValueError(f"--train-data: {path}: {e}") from None
        if isinstance(table, NearestNeighbourModel):
            found = path
            break
        # (another kind of table: check_train_data names its family)
    if found is not None and len(train_data) > 1:
        raise ValueError(f"--train-data: {found}: a full-attitude solution table is the lookup itself and "
                         f"cannot be merged with other files; give the table alone, or the dataset files")
    return None if found is None else os.fspath(found)


def check_train_data(train_data, family) -> None:
    """``--train-data`` files are datasets of the held-out family (another family's records have
    no canonical form of this one: the error named neither the option nor the file); a
    pointing-cones solution table (``NAME.nn.npz``) is taken as its solutions, and a full-attitude
    one (alone) as the lookup itself (``full_attitude_table``)."""
    from .data import data_meta
    if full_attitude_table(train_data, family) is not None:
        return
    for path in train_data or []:
        try:
            meta = data_meta(path)
        except ValueError as e:
            raise ValueError(f"--train-data: {str(e).removeprefix('--data: ')}") from None
        if meta.get("family") != family:
            raise ValueError(f"--train-data: {path}: family {meta.get('family')!r}, not the held-out problems' "
                             f"--family {family!r}")


def held_out_in_training(family, seed, train_data=None, model=None) -> list:
    """The ``--train-data`` files, and the data files the model's card records (``slew train``
    records them since session 35), whose problems are the held-out ones: the same family, seed
    and distribution draw the same problems, index by index."""
    from training.generate import GenerationSpec
    from .data import data_meta
    dist = GenerationSpec(family, seed=seed).distribution_dict()

    def same(fam, s, d):
        # on the fields both state: a file written before a field was added still counts
        return (fam == family and s == int(seed) and isinstance(d, dict)
                and all(d[k] == dist[k] for k in d.keys() & dist.keys()))
    def named(files, where):
        # a table's entry names the data files of its own card (``sources``), checked in turn
        out = []
        for d in files or []:
            if same(d.get("family"), d.get("seed"), d.get("distribution")):
                out.append(f"{d.get('file')} ({where})")
            out += named(d.get("sources"), f"behind {d.get('file')}, {where}")
        return out
    hits = []
    for path in [] if full_attitude_table(train_data, family) else train_data or []:
        meta = data_meta(path)      # (a solution table: the data files its card names)
        if same(meta.get("family"), meta.get("seed"), meta.get("distribution")):
            hits.append(os.fspath(path))
        hits += named(meta.get("sources"), f"in {os.fspath(path)}")
    # the model's card, or for an ensemble (the shipped warm starts) its network's
    card = getattr(model, "card", None) or getattr(getattr(model, "network", None), "card", None) or {}
    hits += named((card.get("training") or {}).get("data_files"), "in the model's card")
    return hits


def check_coverage(model, model_path, family, n, seed) -> int:
    """How many of the ``n`` held-out problems ``model`` covers; none is an error (every guess
    but the baselines would be skipped, and the report would still look like an evaluation)."""
    from training.generate import GenerationSpec, problem_for
    spec = GenerationSpec(family, seed=seed)
    first, covered = None, 0
    for i in range(n):
        why = model.covers(problem_for(spec, i))
        covered += not why
        first = first or why
    if not covered:
        raise ValueError(f"--model: {model_path or 'default'} covers none of the {n} held-out --family {family} "
                         f"problems (problem 0: {first})")
    return covered


def summarise(rows) -> dict:
    """Per-guess statistics. The final-time gap compares each guess with the fastest exact
    extremal any guess found, on the problems where every guess ran (the baseline subset),
    so that a guess is never compared only with itself."""
    best = {}
    for r in rows:
        if r.get("exact") and r.get("tf") is not None:
            best[r["index"]] = min(best.get(r["index"], math.inf), r["tf"])
    ran = {}
    for r in rows:
        ran.setdefault(r["index"], set()).add(r["guess"])
    width = max((len(v) for v in ran.values()), default=0)
    # with one guess a problem, each would be "at best" against itself: no gap is measured
    full = {i for i, v in ran.items() if len(v) == width} if width >= 2 else set()
    out = {"gap_problems": len(full)}
    for g in GUESSES:
        rs = [r for r in rows if r["guess"] == g and r.get("covered")]
        if not rs:
            continue
        ok = [r for r in rs if r["success"]]
        gaps = [r["tf"] / best[r["index"]] - 1.0 for r in ok
                if r["index"] in best and r["index"] in full and r.get("exact")]
        wall = np.array([r["wall_time_s"] for r in rs])
        wall_ok = np.array([r["wall_time_s"] for r in ok]) if ok else np.array([np.nan])
        out[g] = {
            "n": len(rs), "converged": len(ok), "rate": len(ok) / len(rs), "exact": sum(1 for r in ok if r.get("exact")),
            "nit_median": float(np.median([r["nit"] for r in ok])) if ok else math.nan,
            "nit_mean": float(np.mean([r["nit"] for r in ok])) if ok else math.nan,
            "time_median_s": float(np.median(wall)), "time_p95_s": float(np.percentile(wall, 95)),
            "time_median_converged_s": float(np.median(wall_ok)),
            "gap_median": float(np.median(gaps)) if gaps else math.nan,
            "gap_p95": float(np.percentile(gaps, 95)) if gaps else math.nan,
            "share_at_best": float(np.mean(np.array(gaps) <= 1e-6)) if gaps else math.nan,
            "not_covered": sum(1 for r in rows if r["guess"] == g and not r.get("covered")),
        }
    # guesses that ran and rejected every problem (never those that did not run)
    out["not_applicable"] = [g for g in GUESSES if g not in out and any(r["guess"] == g for r in rows)]
    # the same problems for the eigenaxis comparison of iterations
    if "learned" in out and "eigenaxis" in out:
        sub = {r["index"] for r in rows if r["guess"] == "eigenaxis"}
        both = [(a, b) for a in rows for b in rows if a["index"] == b["index"] and a["index"] in sub
                and a["guess"] == "learned" and b["guess"] == "eigenaxis" and a.get("success") and b.get("success")]
        if both:
            out["nit_ratio_eigenaxis_over_learned"] = float(np.mean([b["nit"] for _, b in both]) /
                                                            max(np.mean([a["nit"] for a, _ in both]), 1e-9))
            out["time_ratio_eigenaxis_over_learned"] = float(np.median([b["wall_time_s"] / a["wall_time_s"] for a, b in both]))
    return out


def markdown(s) -> str:
    lines = [f"# Warm-start evaluation: {s['family']}, {s['n']} held-out problems (seed {s['seed']})", "",
             f"Model: `{os.path.basename(str(s['model']))}`; slow baselines "
             f"({'collocation, auto without a model' if s['family'] == 'pointing-cones' else 'eigenaxis, random, collocation'}) on the "
             f"first {s['baseline_n']} problems; {s['workers']} worker process(es). Each guess alone, no fallback; "
             f"time budget {s.get('warm_budget_s')} s for a model's candidates, {s.get('budget_s')} s for a classical guess.", "",
             "| guess | problems | not covered | converged | Newton it. (median / mean) | median time | p95 time | median time (converged) | tf gap to best (median / p95) | at best |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for g in GUESSES:
        if g not in s or not isinstance(s[g], dict):
            continue
        r = s[g]
        conv = f"{r['converged']} ({100 * r['rate']:.1f} %)"
        if g == "collocation":
            conv = f"{r['converged']} ({100 * r['rate']:.1f} %, approximate)"
        elif g in ("auto", "learned+table"):
            conv = f"{r['converged']} ({100 * r['rate']:.1f} % verified, {r['exact']} exact)"
        nit = f"{r['nit_median']:.0f} / {r['nit_mean']:.1f}" if g != "collocation" else "–"
        gap = f"{r['gap_median']:.2e} / {r['gap_p95']:.2e}" if r['gap_median'] == r['gap_median'] else "–"
        at = f"{100 * r['share_at_best']:.1f} %" if r['share_at_best'] == r['share_at_best'] else "–"
        lines.append(f"| {g} | {r['n']} | {r.get('not_covered', 0)} | {conv} | {nit} | {1e3 * r['time_median_s']:.1f} ms | "
                     f"{1e3 * r['time_p95_s']:.1f} ms | {1e3 * r['time_median_converged_s']:.1f} ms | {gap} | {at} |")
    if s.get("held_out_in_training"):
        lines += ["", f"**Warning**: the held-out problems are training problems of "
                      f"{', '.join(s['held_out_in_training'])} (same family, seed and distribution)."]
    covers = s.get("model_covers", s["n"])
    if covers < s["n"]:
        lines += ["", f"The model covers {covers} of the {s['n']} problems ({100 * covers / s['n']:.1f} %): on the other "
                      f"{s['n'] - covers} (outside its domain) it gives no guess, and they are left out of its rows "
                      "(\"not covered\"); its rates are over the problems it covers."]
    if s.get("gap_problems", 0):
        lines += ["", f"The final-time gap is measured on the {s['gap_problems']} problems where every guess ran, "
                      "against the fastest exact extremal any of them found."]
    else:
        lines += ["", "No final-time gap is measured: only one guess ran on each problem, and a guess is not "
                      "compared with itself (`--baseline-n` runs the baselines, `solve` without a model "
                      "among them, on a subsample)."]
    if s["inference_s_median"] == s["inference_s_median"]:
        what = s.get("inference_measures", "canonical form + network")
        lines += ["", f"Inference ({what}; numba and numpy, no torch): median {1e6 * s['inference_s_median']:.1f} µs per "
                      "problem."]
        if s.get("network_s_median") == s.get("network_s_median") and s.get("network_s_median"):
            lines[-1] += (f" The {s.get('network_measures', 'canonical form + network')} alone, called stage by "
                          f"stage as earlier evaluations timed them: median {1e6 * s['network_s_median']:.1f} µs.")
        if s.get("table_query_s_median") == s.get("table_query_s_median") and s.get("table_query_s_median"):
            lines[-1] += (f" The table's query for the nearest solutions, when reached: median "
                          f"{1e6 * s['table_query_s_median']:.1f} µs.")
    else:
        lines += ["", "No inference time: the model covers none of the first problems it is timed on."]
    none = s.get("not_applicable", [])
    if none:
        lines.append(f"Not applicable to this family (the guess or route rejects every problem): {', '.join(none)}.")
    if "nit_ratio_eigenaxis_over_learned" in s:
        ratio = _two_digits(s["time_ratio_eigenaxis_over_learned"])
        lines.append(f"On the problems both solved: the eigenaxis route took {s['nit_ratio_eigenaxis_over_learned']:.1f}× the "
                     f"Newton iterations of the learned guess (mean) and {ratio}× its time (median ratio).")
    return "\n".join(lines) + "\n"


def _two_digits(x) -> str:
    """``x`` to 2 significant digits, no exponent: 1.30 → "1.3", 0.4 → "0.40", 134 → "130"
    (``:.0f`` had printed 1.30 as "1" and anything below 0.5 as "0")."""
    return np.format_float_positional(float(x), precision=2, unique=False, fractional=False, trim="k").rstrip(".")


def plot(rows, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except Exception:   # noqa: BLE001
        return
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for g in GUESSES:
        rs = [r for r in rows if r["guess"] == g and r.get("covered")]
        if not rs:
            continue
        t = np.sort([r["wall_time_s"] for r in rs if r["success"]])
        if len(t):
            ax[0].step(t * 1e3, np.arange(1, len(t) + 1) / len(rs), where="post", label=g)
        ax[1].bar(g, 100 * np.mean([r["success"] for r in rs]))
    ax[0].set_xscale("log")
    ax[0].set_xlabel("solve time [ms]")
    ax[0].set_ylabel("share converged")
    ax[0].legend()
    ax[1].set_ylabel("converged without fallback [%]")
    ax[1].tick_params(axis="x", rotation=20)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
