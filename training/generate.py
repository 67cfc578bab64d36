"""Dataset generation: draw slews from a task family, solve each, append records to a dataset file.

Problem ``i`` of a run is ``problem_for(spec, i)``: the family's ``TaskDistribution`` sampled
with ``np.random.default_rng([seed, i])``. The set
of problems therefore depends only on (family, overrides, seed, index), never on worker
scheduling, and a restarted run regenerates exactly the same problems.

Each problem is solved by a pluggable *solve function* (``solve_fn(problem, **options)``
returning a ``SlewSolution``-like object or its ``to_dict()``). The default,
``solve_default``, is ``solvers.solve`` (``method="auto"``: collocation, then the exact
indirect refinement). A record is a success only if the solver reported ``success=True``
with status 0, a finite ``tf`` and every verification check passed; anything else,
including a ``ValueError`` (a problem the route does not support), is a failure record
carrying the reason. ``exact`` says whether a success is an exact extremal (its switch
times and costates reproduce the trajectory) or an approximate collocation answer (the
(near-)singular problems, and keep-out cones today): train on what fits the purpose.

Backends: ``"local"`` (a ``concurrent.futures.ProcessPoolExecutor``, spawned workers; one
worker runs in-process) and ``"ray"`` (the same task function as Ray remote tasks). In
both, the parent process writes each record as it completes (``training.dataset``).

    from training.generate import GenerationSpec, generate
    spec = GenerationSpec("full-attitude", seed=0, n=1000, solve_options={"time_budget": 10})
    summary = generate(spec, "data/a.jsonl", workers=8)
"""
from __future__ import annotations

import dataclasses
import functools
import importlib
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from .dataset import DatasetWriter, clean_json, make_meta

# failure statuses of the generator (the solver's own statuses 1-4 are kept as they are)
STATUS_REJECTED = -1         # the solve route raised ValueError (unsupported or invalid problem)
STATUS_INTERNAL_ERROR = -2   # sampling or the solve route raised anything else
STATUS_UNVERIFIED = -3       # the route claimed success but the record's checks failed
GENERATOR_STATUS_MESSAGES = {
    STATUS_REJECTED: "The solve route rejected the problem (ValueError).",
    STATUS_INTERNAL_ERROR: "Internal error while sampling or solving.",
    STATUS_UNVERIFIED: "Claimed success without a complete, passed verification.",
}


class UnsampleableError(ValueError):
    """The family with its overrides gives no problem at all (``slew generate`` names --family-options)."""

    reason = ""     # the sampler's own words, without the overrides


DEFAULT_SOLVE_FN = "training.generate:solve_default"
WARM_SOLVE_FN = "training.generate:solve_warm"
# the most problems one run generates: its indices and the missing ones are lists in memory (a
# typo of 1e9 asked for ~36 GB); more data come from more seeds
MAX_N = 1_000_000

RECORD_FIELDS = ("index", "family", "seed", "problem", "success", "status", "message", "tf", "tf_tol",
                 "costate0", "switch_times", "u_first", "nit", "nfev", "wall_time_s", "n_candidates",
                 "candidates_tf", "method", "route", "guess", "baseline_tf", "verification", "exact",
                 "solve_fn", "solve_options", "solver_version", "solver_commit")


# --------------------------------------------------------------------------- problems
@dataclass(frozen=True)
class GenerationSpec:
    """What a run generates. Everything that fixes the problems is in the file's metadata.

    ``family``: a ``slew_env.tasks.FAMILIES`` name; ``overrides``: ``TaskDistribution``
    fields changed from the family's (e.g. ``symmetric_prob``, the share of symmetric
    bodies); ``n``: indices ``0 .. n-1``; ``solve_fn``: ``"module:function"`` of the
    solve route; ``solve_options``: keyword options passed to it.
    """
    family: str
    seed: int = 0
    n: int = 0
    overrides: dict = field(default_factory=dict)
    solve_fn: str = DEFAULT_SOLVE_FN
    solve_options: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"seed: expected a non-negative integer, got {self.seed!r}")
        if not isinstance(self.n, (int, np.integer)) or self.n < 0:
            raise ValueError(f"n: expected a non-negative integer, got {self.n!r}")
        if self.n > MAX_N:
            raise ValueError(f"n: at most {MAX_N:,} problems a run (got {self.n:,}); generate more with other seeds")
        if ":" not in self.solve_fn:
            raise ValueError(f"solve_fn: expected 'module:function', got {self.solve_fn!r}")
        self.distribution()   # validates family and overrides now, with the TaskDistribution's errors
        if self.overrides:
            # overrides can be valid field by field and still leave no problem to draw (50 cones
            # that cannot all be placed): every index would become a sampling failure record, kept
            # for good by a resumed run (a fuzz run: exit 0 with a dataset of rejections). Index 0
            # is drawn now, as the run would; the families themselves are known to sample
            try:
                problem_for(self, 0)
            except (RuntimeError, ValueError) as e:
                err = UnsampleableError(f"overrides {json.dumps(self.overrides, default=str)}: no problem can "
                                        f"be drawn from this distribution: {e}")
                err.reason = str(e)
                raise err from None
        if self.solve_fn in (DEFAULT_SOLVE_FN, WARM_SOLVE_FN):
            # bad options would otherwise become a rejection record at every index, kept for
            # good by a resumed run (a fuzz run: exit 0 with a dataset of rejections)
            try:
                check_route_options(self.solve_fn, self.solve_options)
            except ValueError as e:
                raise ValueError(f"solve_options: {e}") from None

    def distribution(self):
        from slew_env.tasks import TaskDistribution
        return TaskDistribution.family(self.family, **self.overrides)

    def distribution_dict(self) -> dict:
        """The parameters that fix the problems (stored in the metadata, checked on resume)."""
        return json.loads(json.dumps(dataclasses.asdict(self.distribution()), default=str))

    def meta(self, **extra) -> dict:
        return make_meta(self.family, int(self.seed), self.distribution_dict(), n=int(self.n),
                         overrides=self.overrides, seeding="np.random.default_rng([seed, index])",
                         solve_fn=self.solve_fn, solve_options=self.solve_options, **extra)


def check_route_options(solve_fn: str, options: dict) -> None:
    """The checks the built-in routes make of their options before any problem (``ValueError``
    naming the first bad one): ``solve_default``'s are ``solvers.solve``'s; ``solve_warm``'s are
    ``model`` (it must load), ``fallback`` (a boolean) and the options of the route it runs
    (``auto`` with the fallback, else ``indirect``: an unknown key, e.g. a typo, is refused, not
    ignored)."""
    import solvers
    from solvers.warmstart import resolve
    opts = dict(options)
    opts.pop("guess", None)          # (a solvers.Guess: only from Python, checked by solve)
    if solve_fn == WARM_SOLVE_FN:
        fallback = opts.pop("fallback", False)
        if not isinstance(fallback, bool):
            raise ValueError(f"fallback: expected true or false, got {fallback!r}")
        if "warm_start" in opts:
            raise ValueError("warm_start: solve_warm takes its model as 'model'")
        if not fallback and "method" in opts:
            raise ValueError("method: without the fallback solve_warm runs the indirect solver from the model's "
                             "guess; 'method' applies with \"fallback\": true")
        models = [("model", opts.pop("model", None) or "default")]
        method = opts.pop("method", "auto") if fallback else "indirect"
    else:
        method = opts.pop("method", "auto")
        models = [("warm_start", opts.pop("warm_start"))] if opts.get("warm_start") is not None else []
    for key, model in models:
        # a model that does not load would make every record a rejection, kept for good
        try:
            resolve(model)
        except (OSError, ValueError) as e:
            raise ValueError(f"{key}: {e}") from None
    opts.pop("warm_start", None)
    solvers.check_options(method, **opts)


def problem_for(spec: GenerationSpec, index: int):
    """Problem ``index`` of ``spec`` (a ``SlewProblem``); depends only on family, overrides, seed, index."""
    return spec.distribution().sample(np.random.default_rng([int(spec.seed), int(index)]))


# --------------------------------------------------------------------------- solver version
@functools.lru_cache(maxsize=None)
def solver_version() -> tuple:
    """``(package version, git describe of the source tree or None)`` of the code that solves."""
    try:
        from importlib.metadata import version
        pkg = version("slewopt")
    except Exception:
        pkg = None
    commit = None
    try:
        import solvers
        root = os.path.dirname(os.path.dirname(os.path.abspath(solvers.__file__)))
        if os.path.exists(os.path.join(root, ".git")):
            out = subprocess.run(["git", "describe", "--always", "--dirty", "--tags"], cwd=root,
                                 capture_output=True, text=True, timeout=10)
            if out.returncode == 0 and out.stdout.strip():
                commit = out.stdout.strip()
    except Exception:
        commit = None
    return pkg, commit


# --------------------------------------------------------------------------- solve routes
def solve_default(problem, **options):
    """The most robust route available today: ``solvers.solve`` (``method="auto"``:
    collocation, exact indirect refinement, classical multi-start), without a learned warm
    start unless ``warm_start`` is given, so that a dataset never depends on a model."""
    import solvers
    options.setdefault("warm_start", None)
    return solvers.solve(problem, **options)


def solve_warm(problem, model=None, fallback=False, **options):
    """The fast route for bulk data: the warm-start ``model`` (a model file; default the
    shipped one) by the indirect solver. ``fallback=False``: a problem the guess does not
    solve becomes a failure record (no classical route), so the data are biased towards
    problems the model already solves; mix with data from ``solve_default``."""
    import solvers
    from solvers.warm_routes import try_warm_start
    from slew_env import SlewProblem
    prob = SlewProblem.from_dict(problem)
    if fallback:
        return solvers.solve(prob, warm_start=model or "default", **options)
    from solvers.blas_threads import single_threaded_blas
    from solvers.kernel_loading import ensure_kernels
    ensure_kernels(prob)              # as solvers.solve does before its clock (once a process)
    with single_threaded_blas():      # as inside solvers.solve
        sol, info, _ = try_warm_start(prob, "indirect", model or "default", options)
    if sol is None and info.get("covered") is False:
        raise ValueError(f"warm start: the model does not cover this problem ({info.get('reason')})")
    if sol is None:
        raise RuntimeError(f"warm start: the model raised {info.get('error')}")
    return sol


@functools.lru_cache(maxsize=None)
def resolve_solve_fn(path: str) -> Callable:
    """``"module:function"`` -> the callable."""
    mod, _, name = path.partition(":")
    try:
        fn = getattr(importlib.import_module(mod), name)
    except (ImportError, AttributeError) as e:
        raise ValueError(f"solve_fn: cannot import {path!r}: {e}") from None
    if not callable(fn):
        raise ValueError(f"solve_fn: {path!r} is not callable")
    return fn


def _verified(d: dict) -> Optional[str]:
    """None if a solution dict is a verified success, else the reason it is not."""
    if d.get("success") is not True or d.get("status") != 0:
        return "not a success"
    tf = d.get("tf")
    if tf is None or not (isinstance(tf, (int, float)) and math.isfinite(tf) and tf > 0):
        return f"final time {tf!r} is not a positive finite number"
    checks = d.get("verification") or {}
    if not checks:
        return "no verification checks reported"
    failed = [k for k, c in checks.items() if not (isinstance(c, dict) and c.get("passed") is True)]
    if failed:
        return f"verification checks failed: {', '.join(failed)}"
    c0 = d.get("costate0")
    if c0 is None or len(c0) != 7 or any(v is None for v in c0):
        return "costate0 missing or not finite"
    return None


def solve_task(spec: GenerationSpec, index: int, solve_fn: Optional[Callable] = None) -> dict:
    """Record of problem ``index``: sample, solve, check. Never raises (a failure is a record).

    ``solve_fn``: a callable used instead of ``spec.solve_fn`` (in-process use; with a
    process pool it must be picklable, i.e. a module-level function).
    """
    t0 = time.perf_counter()
    pkg, commit = solver_version()
    rec = {k: None for k in RECORD_FIELDS}
    rec.update(index=int(index), family=spec.family, seed=int(spec.seed), solve_fn=spec.solve_fn,
               solve_options=spec.solve_options, solver_version=pkg, solver_commit=commit)
    stage = "sampling"
    try:
        prob = problem_for(spec, index)
        rec["problem"] = prob.to_dict()
        stage = "solving"
        fn = solve_fn if solve_fn is not None else resolve_solve_fn(spec.solve_fn)
        if solve_fn is not None:
            rec["solve_fn"] = f"{getattr(fn, '__module__', '?')}:{getattr(fn, '__qualname__', repr(fn))}"
        sol = fn(prob, **spec.solve_options)
        d = sol if isinstance(sol, dict) else sol.to_dict(dense=False)
        d = clean_json(d)
        for k in ("success", "status", "message", "tf", "tf_tol", "costate0", "switch_times", "u_first", "nit",
                  "nfev", "wall_time_s", "n_candidates", "candidates_tf", "method", "route", "guess",
                  "baseline_tf", "verification"):
            if k in d:
                rec[k] = d[k]
        if rec["success"] is True:
            why = _verified(rec)
            if why is not None:
                rec.update(success=False, status=STATUS_UNVERIFIED,
                           message=f"{GENERATOR_STATUS_MESSAGES[STATUS_UNVERIFIED]} {why}. "
                                   f"Solver said: {rec['message']}")
        else:
            rec["success"] = False
        # an exact extremal comes from the indirect routes; collocation answers are approximate
        from solvers.solution import is_exact
        rec["exact"] = is_exact(rec["success"], rec.get("method"), rec.get("verification"))
    except ValueError as e:
        rec.update(success=False, status=STATUS_REJECTED, message=f"{stage}: {e}")
    except Exception as e:   # a bug in a route must cost one record, not the run
        rec.update(success=False, status=STATUS_INTERNAL_ERROR,
                   message=f"{stage}: internal error: {type(e).__name__}: {e}")
    if rec["wall_time_s"] is None:
        rec["wall_time_s"] = time.perf_counter() - t0
    return clean_json(rec)


# --------------------------------------------------------------------------- the run
@dataclass
class Summary:
    path: str
    n: int
    done_before: int = 0        # records already in the file when the run started
    written: int = 0            # records written by this run
    successes: int = 0          # successes among indices 0..n-1 (whole file)
    failures: int = 0
    missing: list = field(default_factory=list)   # indices < n not in the file at the end
    wall_time_s: float = 0.0
    truncated_bytes: int = 0    # partial last line cut away on open
    interrupted: bool = False
    signal: Optional[int] = None  # the signal that stopped the run (SIGINT, SIGTERM), if one did
    route_note: str = ""         # how this run's route differs from the one the file began with
    lost: list = field(default_factory=list)      # indices whose worker died (not recorded)
    status_counts: dict = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        return not self.missing


class _Progress:
    """tqdm bar; postfix: solves per second (this run) and success rate (whole dataset)."""

    def __init__(self, total, initial, ok, enabled, desc):
        from tqdm import tqdm
        self.bar = tqdm(total=total, initial=initial, unit="solve", desc=desc, file=sys.stderr,
                        disable=not enabled, dynamic_ncols=True, smoothing=0.1)
        self.t0 = time.perf_counter()
        self.count = 0
        self.done = initial
        self.ok = ok

    def update(self, success):
        self.count += 1
        self.done += 1
        self.ok += bool(success)
        dt = max(time.perf_counter() - self.t0, 1e-9)
        self.bar.set_postfix_str(f"{self.count / dt:.2f} solves/s, ok {100.0 * self.ok / max(self.done, 1):.1f}%",
                                 refresh=False)
        self.bar.update(1)

    def close(self):
        self.bar.close()


class _StopSignals:
    """SIGINT and SIGTERM in the parent of a run: a flag, and ``KeyboardInterrupt``.

    A solve in this process runs inside CasADi/IPOPT and numba, which can swallow the
    ``KeyboardInterrupt`` (IPOPT reports ``NonIpopt_Exception_Thrown``, numba a ``SystemError``):
    the solve then ends as a failure record that a restart never retries, and the run went on
    with exit 0. The flag says that the record of a solve in progress is not kept and the run
    stops (a restart solves that index again). SIGTERM (``timeout``, a scheduler) takes the same
    path, so that the pool is shut down rather than left running. Only in the main thread (where
    signal handlers live); elsewhere a no-op."""

    def __init__(self):
        self.signum = None
        self._old = {}

    @property
    def hit(self) -> bool:
        return self.signum is not None

    def _handler(self, signum, frame):
        self.signum = signum
        raise KeyboardInterrupt

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._old = {sig: signal.getsignal(sig) for sig in self.SIGNALS}
            self.rearm()
        return self

    def rearm(self):
        """Set the handlers (again, where something replaced them: ``ray.init`` sets its own
        SIGTERM handler, and a SIGTERM then ended the run with exit 1 and no summary)."""
        if self._old:
            for sig in self.SIGNALS:
                signal.signal(sig, self._handler)

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)
        return False


def _worker_init(parent_pid):
    """A pool worker ends with its parent: killed (SIGKILL, SIGTERM) parents had left their
    workers solving, ~290 MB each, for good (Linux: ``PR_SET_PDEATHSIG``)."""
    try:
        import ctypes
        ctypes.CDLL(None).prctl(1, int(signal.SIGTERM))    # PR_SET_PDEATHSIG = 1
    except Exception:      # not Linux: the workers end when their current task does
        pass
    if os.getppid() != parent_pid:      # the parent died before the call above
        os._exit(1)


def usable_cores() -> int:
    """The cores this process may run on (the local pool's default size)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def generate(spec: GenerationSpec, path, workers: Optional[int] = None, backend: str = "local",
             address: Optional[str] = None, progress: bool = True, fsync: bool = True,
             solve_fn: Optional[Callable] = None, window: Optional[int] = None) -> Summary:
    """Generate (or continue) the dataset ``path`` for ``spec``: indices ``0 .. spec.n-1``.

    Indices already in the file (success or failure) are skipped. ``workers``: local pool
    size (default: the usable cores; 1 runs in this process), or the CPUs of a local Ray
    instance. ``backend``: ``"local"`` or ``"ray"`` (``address``: a running cluster, e.g.
    ``"auto"`` or ``"ray://head:10001"``; none starts a local instance unless Ray is already
    initialised). ``solve_fn``: a callable overriding ``spec.solve_fn`` (must be picklable
    for the pool and Ray). Returns a ``Summary``.
    """
    if backend not in ("local", "ray"):
        raise ValueError(f"backend: expected 'local' or 'ray', got {backend!r}")
    if workers is not None and workers < 1:
        raise ValueError(f"workers: must be a positive integer, got {workers}")
    if address is not None and backend != "ray":
        raise ValueError("address: only with backend 'ray'")
    if solve_fn is None:
        resolve_solve_fn(spec.solve_fn)   # fail now on a bad path, not in every worker
    pkg, commit = solver_version()
    meta = spec.meta(created_by={"solver_version": pkg, "solver_commit": commit})
    t_start = time.perf_counter()
    summary = Summary(path=str(path), n=int(spec.n))
    with DatasetWriter(path, meta, fsync=fsync) as writer:
        summary.truncated_bytes = writer.truncated_bytes
        todo = [i for i in range(spec.n) if i not in writer.done]
        summary.done_before = len(writer.done)
        done_in_range = spec.n - len(todo)
        ok_in_range = sum(1 for i, s in writer.done.items() if s and i < spec.n)
        bar = _Progress(spec.n, done_in_range, ok_in_range, progress and spec.n > 0,
                        desc=f"slew generate {spec.family}")

        summary.route_note = _route_note(writer.meta, spec, solve_fn)

        def write(rec):
            if stop.hit:     # a solve the signal cut short: not kept (a restart solves it again)
                raise KeyboardInterrupt
            writer.append(rec)
            summary.written += 1
            bar.update(rec.get("success") is True)

        stop = _StopSignals()
        try:
            with stop:
                if todo:
                    if backend == "ray":
                        _run_ray(spec, todo, write, workers, address, solve_fn, window, summary, stop.rearm)
                    elif (workers or usable_cores()) == 1 or len(todo) == 1:
                        for i in todo:
                            write(solve_task(spec, i, solve_fn))
                    else:
                        _run_local(spec, todo, write, workers or usable_cores(), solve_fn, window, summary)
        except KeyboardInterrupt:
            summary.interrupted = True
            summary.signal = stop.signum if stop.hit else int(signal.SIGINT)
        finally:
            bar.close()
        done = writer.done
    summary.missing = [i for i in range(spec.n) if i not in done]
    summary.successes = sum(1 for i in range(spec.n) if done.get(i) is True)
    summary.failures = sum(1 for i in range(spec.n) if done.get(i) is False)
    summary.wall_time_s = time.perf_counter() - t_start
    return summary


def _route_note(meta, spec, solve_fn) -> str:
    """What differs between the route the file began with (its metadata) and this run's: each
    record names its own ``solve_fn`` and ``solve_options``; a continuation may change them (the
    shipped data's seed 14 did), but should say so."""
    if solve_fn is not None or not isinstance(meta, dict):
        return ""
    diffs = []
    for key, now in (("solve_fn", spec.solve_fn), ("solve_options", clean_json(spec.solve_options))):
        if key in meta and meta[key] != now:
            diffs.append(f"{key} {json.dumps(now)} (the file began with {json.dumps(meta[key])})")
    return "; ".join(diffs)


def _run_local(spec, todo, write, workers, solve_fn, window, summary, max_pool_restarts=3):
    """Process pool (spawned workers), a bounded window of tasks in flight, records written as they complete.

    A worker that dies (killed, or a crash in compiled code) breaks the pool: the indices in
    flight are put back and a new pool is started, at most ``max_pool_restarts`` times; after
    that the run stops and the indices not done stay missing (``Summary.lost``), to be retried
    by the next run.
    """
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    window = window or 4 * workers
    ctx = multiprocessing.get_context("spawn")
    queue = list(reversed(todo))          # pop() takes the lowest index first
    restarts = 0
    while queue:
        ex = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                                 initargs=(os.getpid(),))
        pending = {}
        lost = []
        try:
            while queue or pending:
                while queue and len(pending) < window and not lost:
                    i = queue.pop()
                    pending[ex.submit(solve_task, spec, i, solve_fn)] = i
                if not pending:
                    break
                finished, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in finished:
                    i = pending.pop(fut)
                    try:
                        rec = fut.result()
                    except BrokenProcessPool:
                        lost.append(i)
                        continue
                    write(rec)
        except BaseException:
            # (an interrupt: the solves in flight are not recorded, so their workers are ended
            # now; left alone, the interpreter's exit would wait for each to finish its solve)
            for proc in list((getattr(ex, "_processes", None) or {}).values()):
                proc.terminate()
            ex.shutdown(wait=False, cancel_futures=True)
            raise
        ex.shutdown(wait=not lost, cancel_futures=bool(lost))
        if not lost:
            return
        restarts += 1
        if restarts > max_pool_restarts:
            summary.lost.extend(sorted(lost))
            return
        queue.extend(sorted(lost, reverse=True))


def _run_ray(spec, todo, write, workers, address, solve_fn, window, summary, rearm=lambda: None):
    """Ray remote tasks running ``solve_task``; the driver writes records as they complete."""
    try:
        import ray
    except ImportError:
        raise ValueError("backend 'ray': Ray is not installed; pip install 'slewopt[cluster]' "
                         "(or pip install 'ray[default]')") from None
    started = False
    if not ray.is_initialized():
        kw = {"address": address} if address else {}
        if not address and workers:
            kw["num_cpus"] = workers
        ray.init(**kw, log_to_driver=False)
        started = True
        rearm()
    pending = {}
    try:
        task = ray.remote(num_cpus=1, max_retries=2)(solve_task)
        cpus = int(ray.cluster_resources().get("CPU", workers or 1))
        window = window or 4 * max(cpus, 1)
        queue = list(reversed(todo))
        spec_ref = ray.put(spec)
        while queue or pending:
            while queue and len(pending) < window:
                i = queue.pop()
                pending[task.remote(spec_ref, i, solve_fn)] = i
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                i = pending.pop(ref)
                try:
                    rec = ray.get(ref)
                except Exception:   # worker or node lost after Ray's retries: not recorded
                    summary.lost.append(i)
                    continue
                write(rec)
    except BaseException:
        for ref in list(pending):
            try:
                ray.cancel(ref, force=True)
            except Exception:
                pass
        raise
    finally:
        if started:
            ray.shutdown()
