"""``slew solve``: time-optimal slew of a problem JSON file, or of a JSONL batch.

Single problem::

    slew solve PROBLEM.json [-o SOLUTION.json] [--method auto|indirect|multiple-shooting|collocation|eigenaxis]
               [--segments N] [--max-candidates N] [--seed S] [--plot FIG.png] [--no-dense]
               [--time-budget S] [--fallback eigenaxis]

prints a short summary and, with ``-o``, writes the solution JSON
(``SlewSolution.to_dict``: success, status, message, tf, costate0, switch_times,
u_first, nit, nfev, wall_time_s, kernel_load_time_s, method, route, guess, n_candidates, candidates_tf,
control_law, verification, problem, and the dense samples t, q, omega, u, costate unless
``--no-dense``, which keeps t and u only where they are the control: README, 'Solution format'). ``-o -`` writes the JSON to stdout (the summary then goes to stderr).
Exit code: 0 on success, 1 when the solver reports ``success=False`` (the solution is
still written), 2 on bad input. ``--time-budget S`` holds for the whole solve; with
``--fallback eigenaxis`` a rest-to-rest problem that gets no verified time-optimal answer
within it gets the eigenaxis slew (``method: "eigenaxis"``, success, its route and message
saying it is the fallback; a pointing target at its reference attitude, and with keep-out cones
where its path enters one, eigenaxis legs through waypoints round them).

Batch::

    slew solve --batch PROBLEMS.jsonl -o SOLUTIONS.jsonl [--workers N] [--dense] [...]

One problem per line (blank lines skipped), one solution per line, each with a ``"line"``
key (1-based line number in the input), written as soon as its problem is solved: in the
order of the input with one worker, in the order the problems finish with ``--workers N > 1``
(a process pool of spawned workers; each pays the import of ``solvers`` once). A line that
does not validate gives ``{"line": k, "success": false, "status": -1, "message": "..."}`` and
the batch goes on (an unexpected exception in the solver gives the same record with status -2
and a message starting "internal error"). Dense samples are left out unless ``--dense``.
Ctrl-C or SIGTERM stops the batch after the problem(s) in hand (a second Ctrl-C at once, the
solves it cuts not recorded); every finished record stays in the file (written one whole line
at a time, as ``slew generate`` writes: ``training.batch_output``), and the same command with
``--resume`` solves only the input lines that have no record in it yet.
Exit code: 0 when every line was solved, 1 otherwise, 130 on Ctrl-C and 143 on SIGTERM,
2 on bad options or an unreadable batch file.

An existing output file is overwritten (batch: unless ``--resume``); an output that is one of
the inputs (the problem or batch file, the warm-start model) is refused before solving. A
single solution is written atomically (a temporary file renamed over the target when
complete), so an interrupted run never leaves half of it.
"""
from __future__ import annotations

import json
import math
import os
import signal
import sys
import tempfile
import threading
import time

METHOD_CHOICES = ("auto", "indirect", "multiple-shooting", "collocation", "eigenaxis")  # == solvers.METHODS (tested; not imported: fast --help)
CONE_CHALLENGE_CHOICES = ("gated", "always", "never")   # == solvers.cone_routes.CONE_CHALLENGE_MODES (tested; as above)
BAD_LINE_STATUS = -1        # batch record of a line that does not validate (ValueError)
INTERNAL_ERROR_STATUS = -2  # batch record of a line on which the solver raised anything else


def add_arguments(p):
    p.add_argument("problem", nargs="?", metavar="PROBLEM.json",
                   help="problem JSON file (see README, 'Problem format')")
    p.add_argument("--batch", metavar="PROBLEMS.jsonl",
                   help="solve every problem of a JSON-lines file (one problem per line) instead")
    p.add_argument("-o", "--output", metavar="FILE",
                   help="write the solution JSON here (batch: JSON lines, one record written as each problem is "
                        "solved; required); '-' for stdout. An existing file is overwritten (batch: unless "
                        "--resume); an input file (the problem, the batch, the model) is refused")
    p.add_argument("--resume", action="store_true",
                   help="batch: continue an interrupted batch: keep the records already in -o and solve only the "
                        "input lines that have none (each record names its input line)")
    p.add_argument("--method", default="auto", metavar="METHOD",
                   help=f"solver: {' | '.join(METHOD_CHOICES)} (default auto)")
    p.add_argument("--segments", type=int, metavar="N",
                   help="shooting segments (default: 4 for multiple-shooting, 1 otherwise)")
    p.add_argument("--max-candidates", type=int, metavar="N",
                   help="most candidate guesses to try (default: the solver's)")
    p.add_argument("--seed", type=int, metavar="S", help="seed of the perturbed candidates (default: the solver's, 0)")
    p.add_argument("--plot", metavar="FIG.png", help="save a figure of the solution (single problem only)")
    dense = p.add_mutually_exclusive_group()
    dense.add_argument("--no-dense", dest="dense", action="store_false", default=None,
                       help="leave the dense samples t, q, omega, u, costate out of the JSON")
    dense.add_argument("--dense", dest="dense", action="store_true", default=None,
                       help="batch: include the dense samples (left out by default)")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="batch: worker processes (default 1)")
    p.add_argument("--no-progress", action="store_true", help="batch: no progress bar")
    p.add_argument("--warm-start", default="default", metavar="MODEL",
                   help="learned warm start: 'default' (the shipped full-attitude model; with cones, auto starts "
                        "collocation from the pointing-cones table's nearest solutions too, and may try that warm "
                        "start after its route, keeping a faster answer: --cone-challenge), 'pointing-cones' "
                        "(that warm start as the first guess, opt-in), 'none', or a model file "
                        "(.npz from 'slew train', .nn.npz nearest-neighbour table)")
    p.add_argument("--no-local-optimum-check", dest="local_optimum_check", action="store_false", default=True,
                   help="auto: return the learned guess's extremal at once, without running the collocation route "
                        "where it may be a local optimum (well above the predicted time, or near a half turn)")
    p.add_argument("--cone-challenge", choices=CONE_CHALLENGE_CHOICES, default=None,
                   help="auto with cones: run the pointing-cones warm start after the route where the answer is "
                        "slower than the network's predicted time (gated, the default), always, or never")
    p.add_argument("--time-budget", type=float, metavar="S",
                   help="seconds for the whole solve (default: the solver's, 20; collocation 60; "
                        "--method eigenaxis: profiles coarse enough to fit, down to a floor)")
    p.add_argument("--fallback", choices=("eigenaxis",), default=None,
                   help="where no verified time-optimal answer comes within the budget, return the eigenaxis slew "
                        "(rest to rest; a pointing target at its reference attitude; with cones directly where its "
                        "path clears them, else through waypoints round them; verified, not time-optimal)")
    p.add_argument("--repeat", type=int, default=3, metavar="N",
                   help="single problem: solve N more times and report the median time of a repeated solve "
                        "(the first call in a process also loads compiled code; default 3, 0 to skip)")


# --------------------------------------------------------------------------- helpers
def _read_text(path, what):
    """File contents; any OS error becomes a one-line ValueError."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except OSError as e:
        raise ValueError(f"{what}: cannot read {str(path)!r}: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise ValueError(f"{what}: {str(path)!r} is not UTF-8 text ({e.reason})") from None


def _solve_options(args):
    if args.method not in METHOD_CHOICES:
        raise ValueError(f"--method: unknown method {args.method!r}; choose one of {', '.join(METHOD_CHOICES)}")
    opts = {}
    for name in ("segments", "max_candidates"):
        v = getattr(args, name)
        if v is not None:
            if v < 1:
                raise ValueError(f"--{name.replace('_', '-')}: must be a positive integer, got {v}")
            opts[name] = v
    if args.seed is not None:
        opts["seed"] = args.seed
    if not getattr(args, "local_optimum_check", True):
        opts["local_optimum_check"] = False
    if getattr(args, "cone_challenge", None) is not None:
        opts["cone_challenge"] = args.cone_challenge
    tb = getattr(args, "time_budget", None)
    if tb is not None:
        if not (math.isfinite(tb) and tb > 0):
            raise ValueError(f"--time-budget: must be a positive number of seconds, got {tb}")
        opts["time_budget"] = tb
    if getattr(args, "fallback", None) is not None:
        if args.method in ("collocation", "eigenaxis"):
            raise ValueError(f"--fallback: applies to the auto, indirect and multiple-shooting methods, "
                             f"not --method {args.method}")
        opts["fallback"] = args.fallback
    ws = getattr(args, "warm_start", "default")
    if ws in (None, "none", "None"):
        opts["warm_start"] = None
    elif ws == "pointing-cones":
        opts["warm_start"] = ws
    elif ws != "default":
        if not os.path.exists(ws):
            raise ValueError(f"--warm-start: model file not found: {ws}")
        opts["warm_start"] = ws
    return opts


def _check_writable(path, what):
    """Fail before solving (one line) if ``path`` cannot be created."""
    if path is None or path == "-":
        return
    if path.endswith(os.sep) or (os.altsep and path.endswith(os.altsep)):
        raise ValueError(f"{what}: {path!r} names a directory; give a file name")
    target = os.path.abspath(path)
    d = os.path.dirname(target)
    if not os.path.isdir(d):
        raise ValueError(f"{what}: directory {d!r} does not exist")
    if os.path.isdir(target):
        raise ValueError(f"{what}: {path!r} is a directory")
    if not os.access(d, os.W_OK):
        raise ValueError(f"{what}: directory {d!r} is not writable")


class AtomicWriter:
    """Text file written to ``path`` atomically (temp file in the same dir + ``os.replace``).

    ``path == "-"`` writes to stdout instead (not atomic), and so does a path that exists but
    is not a regular file (a device such as ``/dev/null``, a FIFO): replacing it would put a
    regular file in its place. Use as a context manager: the target appears only if the block
    completes; otherwise the temp file is removed.
    """

    def __init__(self, path):
        self.path = path
        self._tmp = None
        self._f = None

    def __enter__(self):
        if self.path == "-":
            self._f = sys.stdout
            return self._f
        _check_writable(self.path, "-o")
        target = os.path.abspath(self.path)
        if os.path.exists(target) and not os.path.isfile(target):
            try:
                self._f = open(target, "w", encoding="utf-8")
            except OSError as e:
                raise ValueError(f"-o: cannot write to {self.path!r}: {e.strerror or e}") from None
            self._special = True
            return self._f
        d = os.path.dirname(target)
        try:
            fd, self._tmp = tempfile.mkstemp(dir=d, prefix=f".{os.path.basename(target)}.", suffix=".tmp")
        except OSError as e:
            raise ValueError(f"-o: cannot write in {d!r}: {e.strerror or e}") from None
        # mkstemp creates 0600; give the file the usual permissions (umask applied)
        umask = os.umask(0)
        os.umask(umask)
        try:
            os.chmod(self._tmp, 0o666 & ~umask)
        except OSError:
            pass
        self._f = os.fdopen(fd, "w", encoding="utf-8")
        self._target = target
        return self._f

    def __exit__(self, exc_type, exc, tb):
        try:
            self._finish(exc_type is None)
        except OSError as e:
            raise self._error(e) from None
        if exc_type is not None and issubclass(exc_type, OSError):
            # a write in the block failed (-o /dev/full: ENOSPC): name -o and the path, not just errno
            raise self._error(exc) from None
        return False

    def _error(self, e):
        where = "stdout" if self.path == "-" else repr(self.path)
        return ValueError(f"-o: cannot write to {where}: {e.strerror or e}")

    def _finish(self, ok):
        if self.path == "-":
            sys.stdout.flush()
            return
        if getattr(self, "_special", False):
            self._f.close()
            return
        try:
            if ok:
                self._f.flush()
                os.fsync(self._f.fileno())
            try:
                self._f.close()
            except OSError:
                if ok:
                    raise
            if ok:
                os.replace(self._tmp, self._target)
                self._tmp = None
        finally:
            if self._tmp is not None and os.path.exists(self._tmp):
                os.remove(self._tmp)


def _fmt_tf(x):
    return "nan" if x is None or not math.isfinite(x) else f"{x:.10g}"


def summary_lines(sol, prob, warm=None):
    """Human summary of a ``SlewSolution`` (list of lines)."""
    L = []
    tau = prob.time_unit
    L.append(f"success       {sol.success}  (status {sol.status}) {sol.message}")
    tf_note = ("problem time units: seconds if J is in kg·m² and torque in N·m; "
               f"tf/τ = {_fmt_tf(sol.tf / tau)} with τ = sqrt(J_max/u_max) = {tau:.6g}")
    tol = getattr(sol, "tf_tol", float("nan"))
    tol_txt = f" ± {tol:.1g}" if tol == tol else ""
    L.append(f"tf            {_fmt_tf(sol.tf)}{tol_txt}  ({tf_note})")
    law = getattr(sol, "control_law", "bang-bang")
    sampled = law in ("quadratic-samples", "linear-samples") and sol.success
    if sampled and not any(len(s) for s in sol.switch_times):
        # (an eigenaxis or penalised answer: no switch list or first-arc signs define its control;
        # "0 in all" and u_first [+1, +1, +1] had been printed for it)
        L.append(f"switches      none listed: the control is the record's samples ({law})")
    elif math.isinf(prob.torque_norm):
        n = sum(len(s) for s in sol.switch_times)
        per_axis = ", ".join(f"{ax} {len(s)}" + (f" [{', '.join(f'{v:.6g}' for v in s)}]" if len(s) else "")
                             for ax, s in zip("xyz", sol.switch_times))
        note = f"  (the sampled torque's sign changes; the control is the record's samples, {law})" if sampled else ""
        L.append(f"switches      {n} in all: {per_axis}{note}")
    else:
        L.append(f"switches      none (p = {prob.torque_norm:g} norm bound: continuous control)")
    if math.isinf(prob.torque_norm) and (law == "bang-bang" or (sampled and any(len(s) for s in sol.switch_times))):
        uf = "[" + ", ".join(f"{v:+g}" for v in sol.u_first) + "]"
        L.append(f"u_first       {uf}  (sign of each axis's first arc)")
    L.append(f"nit / nfev    {sol.nit} / {sol.nfev}")
    L.append(f"wall time     {sol.wall_time:.3f} s")
    if getattr(sol, "kernel_load_time", 0.0) > 0.0:
        L.append(f"kernels       {sol.kernel_load_time:.3f} s loading them before the solve's clock started (the "
                 f"first solve of this kind of problem in the process; a fresh install compiles them)")
    ws = warm or getattr(sol, "warm_start", None) or {}
    if ws:
        if ws.get("covered") and ws.get("role") == "challenger" and ws.get("challenged") is False:
            L.append(f"warm start    {ws.get('model')}: no challenge after the route ({ws.get('reason', '')})")
        elif ws.get("covered") and ws.get("role") == "challenger":
            res = ("found a faster extremal, which is the answer" if ws.get("won") else
                   f"converged to {ws['tf']:.9g}, not faster: the route's answer stands" if ws.get("succeeded") else
                   "did not converge: the route's answer stands")
            L.append(f"warm start    {ws.get('model')}, as a challenger after the route "
                     f"(inference {1e6 * ws.get('inference_s', 0):.0f} µs): {res}")
        elif ws.get("covered"):
            lo = ws.get("local_optimum_check") or {}
            if lo.get("won"):
                why = (f"{lo['tf'] / lo['predicted_tf'] - 1:.1%} above the predicted time"
                       if lo.get("reason", "").startswith("slower") else "a slew near a half turn")
                res = (f"its guess converged to {lo['tf']:.9g} ({why}, likely a local optimum); the collocation "
                       f"route found a faster answer")
            else:
                res = ("its continuation candidate won, after collocation" if ws.get("after_collocation") else
                       "its guess won" if ws.get("succeeded") else "its guess failed, classical route used")
            L.append(f"warm start    {ws.get('model')}: inference {1e6 * ws.get('inference_s', 0):.0f} µs, {res}")
        else:
            L.append(f"warm start    {ws.get('model')}: not used ({ws.get('reason')})")
    L.append(f"method        {sol.method}")
    law = getattr(sol, "control_law", "")
    if law:
        from solvers.solution import CONTROL_LAWS
        L.append(f"control       {law}: {CONTROL_LAWS[law]}")
    L.append(f"route         {sol.route or '-'}")
    L.append(f"guess         {sol.guess or '-'}")
    cands = ", ".join(_fmt_tf(v) for v in sol.candidates_tf) or "none"
    L.append(f"candidates    {sol.n_candidates} tried; final times of converged extremals: {cands}")
    base = getattr(sol, "baseline_tf", math.nan)
    if base is not None and math.isfinite(base):
        rel = ""
        if math.isfinite(sol.tf):
            gain = 100.0 * (1.0 - sol.tf / base)
            rel = f" (tf is {abs(gain):.2f} % {'faster' if gain >= 0 else 'slower'})"
        L.append(f"baseline      eigenaxis slew tf = {_fmt_tf(base)}{rel}")
    if sol.verification:
        L.append("verification")
        w = max(len(k) for k in sol.verification)
        L.append(f"  {'check':<{w}}  {'value':>12}  {'tol':>10}  result")
        for k, c in sol.verification.items():
            L.append(f"  {k:<{w}}  {c['value']:>12.4g}  {c['tol']:>10.3g}  {'pass' if c['passed'] else 'FAIL'}")
    else:
        L.append("verification  none (no candidate converged)")
    return L


# --------------------------------------------------------------------------- single
def _run_single(args, opts):
    from slew_env import SlewProblem
    from solvers import solve

    if args.workers != 1:
        raise ValueError("--workers: only with --batch")
    if args.repeat < 0:
        raise ValueError(f"--repeat: must be ≥ 0, got {args.repeat}")
    if getattr(args, "resume", False):
        raise ValueError("--resume: only with --batch")
    text = _read_text(args.problem, "problem")
    prob = SlewProblem.from_json(text)
    dense = args.dense is not False
    sensor_png = None
    if args.plot and (prob.cones or prob.sensor_target is not None):
        # its second figure: checked before solving too, and named in its own errors (a fuzz run:
        # FIG-sensor.png a directory was reported as "cannot write 'FIG.png'", which was written)
        sensor_png = _sensor_figure_path(args.plot)
        _check_writable(sensor_png, "--plot (its sensor figure)")
    sol = solve(prob, method=args.method, **opts)
    out = sys.stderr if args.output == "-" else sys.stdout
    print(f"problem       {args.problem}: {prob!r}", file=out)
    lines = summary_lines(sol, prob)
    again = []
    if args.repeat and sol.success:
        # (the first call's kernels and model files load before its clock: kernel_load_time);
        # one repeat shows whether the rest are quick enough to be worth timing
        again.append(solve(prob, method=args.method, **opts))
        if again[0].wall_time < 1.0:
            again += [solve(prob, method=args.method, **opts) for _ in range(args.repeat - 1)]
    if again:
        import statistics
        reps = [a.wall_time for a in again]
        lines = summary_lines(sol, prob, again[-1].warm_start or None)
        k = next(i for i, ln in enumerate(lines) if ln.startswith("wall time"))
        lines[k] = (f"wall time     {sol.wall_time:.3f} s first call in this process; "
                    f"{1e3 * statistics.median(reps):.1f} ms repeated (median of {len(reps)})")
    for line in lines:
        print(line, file=out)
    if args.output:
        with AtomicWriter(args.output) as f:
            f.write(sol.to_json(dense=dense, indent=2))
            f.write("\n")
        if args.output != "-":
            what = f"with {len(sol.t)} dense samples" if dense else "without dense samples"
            print(f"solution      written to {args.output} ({what})", file=out)
    else:
        print("solution      not written (use -o SOLUTION.json)", file=out)
    if args.plot:
        from solvers.plotting import plot_sensor_path, plot_solution
        figures = [(plot_solution, args.plot, "")]
        if sensor_png is not None:
            figures.append((plot_sensor_path, sensor_png, " (sensor path, cones, clearance)"))
        for plot, path, what in figures:
            try:
                plot(sol, path)
            except ValueError as e:
                print(f"figure        not written: {e}", file=out)
                break
            except OSError as e:      # names the figure that failed, not always the main one
                raise ValueError(f"--plot: cannot write {path!r}: {e.strerror or e}") from None
            print(f"figure        written to {path}{what}", file=out)
    return 0 if sol.success else 1


def _sensor_figure_path(plot):
    """``FIG-sensor.png`` of ``--plot FIG.png``: the sensor path of pointing and cone problems."""
    root, ext = os.path.splitext(plot)
    return f"{root}-sensor{ext or '.png'}"


# --------------------------------------------------------------------------- batch
def solve_line(lineno, text, method, opts, dense):
    """One batch line -> one JSON record (string). Never raises."""
    try:
        from slew_env import SlewProblem
        from solvers import solve
        prob = SlewProblem.from_json(text)
        sol = solve(prob, method=method, **opts)
        d = {"line": lineno}
        d.update(sol.to_dict(dense=dense))
    except ValueError as e:
        d = {"line": lineno, "success": False, "status": BAD_LINE_STATUS, "message": str(e)}
    except Exception as e:   # a solver bug must not cost the rest of the batch
        d = {"line": lineno, "success": False, "status": INTERNAL_ERROR_STATUS,
             "message": f"internal error: {type(e).__name__}: {e}"}
    return json.dumps(d)


def _batch_items(path):
    """``(line number, text)`` of each non-blank line. Lines end at ``\n`` only, as in JSON
    Lines: ``str.splitlines`` would also split at U+2028, NEL or a form feed inside a line,
    and number every later line wrong."""
    text = _read_text(path, "--batch")
    return [(k, line.removesuffix("\r")) for k, line in enumerate(text.split("\n"), start=1)
            if line.strip()]


class _StopRequest:
    """While active, Ctrl-C (SIGINT) and SIGTERM only ask the batch to stop after the problem(s)
    in hand: raised inside a solve, they were swallowed by IPOPT, or came out of compiled code
    as a ``SystemError`` written down as a failed problem. A second Ctrl-C stops at once
    (``forced``): inside a solve in this process (``cuttable``) it raises ``KeyboardInterrupt``
    there; elsewhere (between records, the pool's parent) the loop sees the flag, so that the
    interrupt never lands inside a record's write."""

    def __init__(self):
        self.signal = None
        self.forced = False
        self.cuttable = False
        self._old = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.signal(s, self._handle)
        return self

    def _handle(self, signum, frame):
        if self.signal is not None:
            if signum == signal.SIGINT:
                self.forced = True
                if self.cuttable:
                    raise KeyboardInterrupt
            return
        self.signal = signum
        print("\nslew solve: stopping after the problem(s) in hand; finished records are kept "
              "(Ctrl-C again to stop now)", file=sys.stderr, flush=True)

    def __exit__(self, *exc):
        for s, h in self._old.items():
            signal.signal(s, h)
        return False


def _ignore_sigint():
    """Pool workers leave Ctrl-C to the parent, which stops the batch between problems."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class _Tally:
    """Solved / not solved / invalid counts over the records of the output (earlier runs' too)."""

    def __init__(self):
        self.ok = self.bad_input = 0

    def add(self, d):
        if d.get("success"):
            self.ok += 1
        elif d.get("status") == BAD_LINE_STATUS:
            self.bad_input += 1


def _run_batch(args, opts):
    from concurrent.futures.process import BrokenProcessPool

    from tqdm import tqdm

    from .batch_output import BatchOutput

    if args.problem:
        raise ValueError("give either PROBLEM.json or --batch PROBLEMS.jsonl, not both")
    if not args.output:
        raise ValueError("--batch: needs -o SOLUTIONS.jsonl (or -o - for stdout)")
    if args.plot:
        raise ValueError("--plot: only for a single problem, not with --batch")
    if args.workers < 1:
        raise ValueError(f"--workers: must be a positive integer, got {args.workers}")

    items = _batch_items(args.batch)
    dense = args.dense is True
    t0 = time.perf_counter()
    tally = _Tally()
    where = "stdout" if args.output == "-" else args.output
    with BatchOutput(args.output, resume=getattr(args, "resume", False), lines=dict(items)) as out:
        for d in out.done.values():
            tally.add(d)
        if out.truncated_bytes:
            print(f"{args.output}: cut away a partial last line ({out.truncated_bytes} bytes) left by an "
                  "interrupted run", file=sys.stderr)
        todo = [(k, line) for k, line in items if k not in out.done]
        bar = tqdm(total=len(items), initial=len(items) - len(todo), file=sys.stderr, unit="problem",
                   desc="slew solve", disable=args.no_progress, dynamic_ncols=True)

        def write(rec):
            out.write(rec)
            tally.add(json.loads(rec))
            bar.update(1)

        stop = _StopRequest()
        broken = None
        try:
            with stop:
                if args.workers == 1 or len(todo) <= 1:
                    _batch_serial(todo, args, opts, dense, write, stop)
                else:
                    _batch_pool(todo, args, opts, dense, write, stop)
        except KeyboardInterrupt:
            pass
        except BrokenProcessPool as e:   # a worker died (killed, a crash in compiled code)
            broken = e
        finally:
            bar.close()
    n = len(items)
    if out.count < n:      # stopped by a signal (or a dead worker) before the end
        how = (f"a worker process died ({broken})" if broken is not None and stop.signal is None else
               f"interrupted ({signal.Signals(stop.signal or signal.SIGINT).name})")
        left = n - out.count
        if out.resumable:
            hint = f"; run the same command with --resume to solve the {left} line(s) left"
        else:
            hint = f", {left} line(s) not solved ({where} cannot be resumed: use -o FILE for that)"
        print(f"slew solve: {how}: {out.count} of {n} record(s) in {where} ({out.written} written by this "
              f"run){hint}", file=sys.stderr)
        if broken is not None and stop.signal is None:
            return 1
        return 143 if stop.signal == signal.SIGTERM else 130
    n_fail = n - tally.ok - tally.bad_input
    before = f" ({len(out.done)} already in {where})" if out.done else ""
    summary_to = sys.stderr if args.output == "-" else sys.stdout
    print(f"{n} problem(s): {tally.ok} solved, {n_fail} not solved, {tally.bad_input} invalid{before}; "
          f"{time.perf_counter() - t0:.2f} s; written to {where}", file=summary_to)
    return 0 if tally.ok == n else 1


def _batch_serial(todo, args, opts, dense, write, stop):
    """In this process, in input order; stops before the next problem once a stop is asked."""
    for k, line in todo:
        if stop.signal is not None:
            return
        stop.cuttable = True
        try:
            rec = solve_line(k, line, args.method, opts, dense)
        finally:
            stop.cuttable = False
        if stop.forced:
            # a second Ctrl-C during the solve, which the route may have swallowed and ended as a
            # failure: not recorded (a --resume solves that line again)
            raise KeyboardInterrupt
        write(rec)


def _batch_pool(todo, args, opts, dense, write, stop):
    """Process pool, one problem in flight per worker, each record written as it completes (so
    in completion order: every record names its input line). Once a stop is asked, no problem
    is submitted and those being solved are waited for and written; a second Ctrl-C ends the
    workers at once, their solves not recorded."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    # no more in flight than workers: the executor marks every submitted call it has queued as
    # running, and a running call cannot be cancelled, so a larger window made a stop wait for
    # problems that had not started (a worker idles only for the parent's write and submit)
    window = args.workers
    ctx = multiprocessing.get_context("spawn")
    queue = iter(todo)
    pending = set()
    ex = ProcessPoolExecutor(max_workers=args.workers, mp_context=ctx, initializer=_ignore_sigint)
    try:
        while True:
            while stop.signal is None and len(pending) < window:
                item = next(queue, None)
                if item is None:
                    break
                pending.add(ex.submit(solve_line, *item, args.method, opts, dense))
            if stop.forced:
                raise KeyboardInterrupt
            if not pending:
                break
            # (a timeout: the loop must see a stop request while every worker is busy)
            finished, _ = wait(pending, timeout=0.25, return_when=FIRST_COMPLETED)
            for fut in finished:
                pending.discard(fut)
                write(fut.result())
    except BaseException:
        # (the solves in flight are not recorded: their workers are ended now; left alone, the
        # interpreter's exit would wait for each to finish its solve)
        for proc in list((getattr(ex, "_processes", None) or {}).values()):
            proc.terminate()
        ex.shutdown(wait=False, cancel_futures=True)
        raise
    ex.shutdown(wait=True)


# --------------------------------------------------------------------------- entry
def _same_file(a, b):
    try:
        return os.path.samefile(a, b)
    except OSError:            # (one of them does not exist yet)
        return os.path.realpath(a) == os.path.realpath(b)


def _refuse_inputs_as_outputs(args, opts):
    """An output that is one of the inputs would destroy it: refused before anything is solved or
    opened for writing (a fuzz run: ``--batch P.jsonl -o P.jsonl`` left only the solutions, and
    the text of an invalid line was lost for good)."""
    inputs = [("--batch", args.batch), ("PROBLEM.json", args.problem)]
    if isinstance(opts.get("warm_start"), str) and os.path.exists(opts["warm_start"]):
        inputs.append(("--warm-start", opts["warm_start"]))
    outputs = [(flag, path) for flag, path in (("-o", args.output), ("--plot", args.plot))
               if path and path != "-"]
    for flag, path in outputs:
        for in_flag, in_path in inputs:
            if in_path and _same_file(path, in_path):
                raise ValueError(f"{flag}: {path!r} is the input file {in_path!r} ({in_flag}); writing there "
                                 "would destroy it: give another output file")
    if len(outputs) == 2 and _same_file(args.output, args.plot):
        raise ValueError(f"--plot: {args.plot!r} is the -o file too; the figure would replace the solution")


def run(args):
    opts = _solve_options(args)
    _check_writable(args.output, "-o")
    _check_writable(args.plot, "--plot")
    _refuse_inputs_as_outputs(args, opts)
    if args.batch:
        return _run_batch(args, opts)
    if not args.problem:
        raise ValueError("give a problem file PROBLEM.json, or --batch PROBLEMS.jsonl")
    return _run_single(args, opts)
