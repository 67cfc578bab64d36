"""The indirect multi-start (``method="indirect"`` / ``"multiple-shooting"`` without cones): the
candidates in order, a smoothing path or a switch-time Newton each, the best verified extremal
kept (``solvers.api`` documents the order and the stopping rule)."""

from __future__ import annotations

import math
import time
from typing import Optional, Tuple

import numpy as np

from .attitude_bvp import AttitudeBVP
from .guesses import Guess, eigenaxis_guess, perturbed, structure_templates, symmetric_images
from .indirect import Attempt, per_axis_from_guess, pnorm_from_guess, solution_fields, solve_structure
from .shooting import newton_shoot
from .eigenaxis import eigenaxis_time
from .eigenaxis_answer import FINE_GATE, fine_eigenaxis_time
from .solution import (STATUS_BUDGET_EXHAUSTED, STATUS_MESSAGES, STATUS_NOT_CONVERGED, STATUS_SUCCESS,
                       STATUS_VERIFICATION_FAILED, STATUS_WORSE_THAN_BASELINE, SlewSolution)
from .switch_time import Structure
from .verify import DENSE_STEPS, sensor_reversed, verify

# a structure template's switch-time Newton stops when 10 iterations have not brought its residual
# below 0.1 of the first: on 100 random slews (seeds 1 and 2 of bench_solver, where the rule was
# chosen), 24 of 1,077 template attempts converged, none of them that slowly, and the failures
# spent 44 % of their iterations past that point (about 40 % of the classical route's time went to
# failing templates). On held-out seeds 4 and 5 (a review, 50 slews) it cut 4 of 423 stalled
# templates that would have converged, all to local extremals 15-95 % slower: no answer changed
TEMPLATE_STALL = (10, 0.1)

# After the first verified extremal reached along the smoothing path of a built-in candidate
# (the eigenaxis guess and its variants), each later candidate's attempt stops after
# max(2 × the propagations of that first attempt, 200) propagations (solve's ``candidate_cap``).
# On 200 random per-axis slews (bench_solver seeds 1 and 2, all 16 candidates of each traced:
# runs/s22/cand_trace.py, policy_sim.py, not in the repository) the paths that ran longer ended
# in slower local extremals or failed: simulated, this rule returned the same verified answers
# as the uncapped multi-start on all 159 it verifies, with the median from 0.94 to 0.66 s (a cap
# of 0.5× lost 4 answers, by up to 58 %); A/B on seeds 3 and 4: identical verified answers.
CANDIDATE_CAP = (2.0, 200.0)


def checked_cap(cap) -> Tuple[float, float]:
    """``candidate_cap`` as a ``(multiple, floor)`` pair of floats, or a ``ValueError``."""
    bad = ValueError(f"candidate_cap: must be None or a pair (multiple, floor) of numbers >= 0, got {cap!r}")
    if isinstance(cap, (str, bytes, dict, bool)):
        raise bad
    try:
        items = list(cap)
    except TypeError:
        raise bad from None
    if len(items) != 2 or any(isinstance(v, (bool, np.bool_)) for v in items):
        raise bad
    try:
        mult, floor = (float(v) for v in items)
    except (TypeError, ValueError):
        raise bad from None
    if not (mult >= 0 and floor >= 0):        # rejects NaN too
        raise bad
    return mult, floor


def _structure_from_guess(g: Guess, bvp) -> Optional[Structure]:
    if g.switch_times is None:
        return None
    ev = sorted((float(t) / bvp.tau, i) for i in range(3) for t in g.switch_times[i])
    if g.u_first is not None:
        s0 = np.where(g.u_first == 0, 1.0, g.u_first)
    else:
        z, _ = g.to_nondim(bvp)
        y0, _ = bvp.initial(z)
        s0 = bvp.initial_signs(y0)
    return Structure(np.asarray(s0, float), np.array([e[1] for e in ev], dtype=np.int64),
                     np.array([e[0] for e in ev]))


def _candidates(bvp, guess, max_candidates, seed, per_axis, unusable=None, guess_only=False):
    """Yields ``(z, T, structure, source)`` in the order they are tried.

    ``unusable``: ``None`` (a guess that cannot be put in the solver's gauge, such as zero
    costates, is a ``ValueError``: the user's bad input), or a list to which such candidates
    are added as ``"source: reason"`` and skipped, each using up its slot (a model's guesses:
    one degenerate candidate must not stop the solve). ``guess_only``: the guess and its
    candidates, nothing after them (a deferred candidate that gives nothing leaves its slot
    empty rather than to a classical candidate).

    Order: the user's guess and its candidates; the eigenaxis guess (smoothing
    continuation); per-axis only, the structure templates around it (cheap: one
    switch-time Newton each); the long-way eigenaxis; images of the eigenaxis guess
    under the problem's symmetries; seeded perturbations of the eigenaxis guess.
    """
    seen = []

    def fresh(z, st):
        key = (np.round(z, 6).tobytes(), None if st is None else (st.axes.tobytes(), st.signs0.tobytes()))
        if key in seen:
            return False
        seen.append(key)
        return True

    count = 0
    if guess is not None:
        for g in guess.iter_all(errors=unusable):
            if count >= max_candidates:
                break       # (deferred candidates past the limit are never computed)
            try:
                z, T = g.to_nondim(bvp)
                st = _structure_from_guess(g, bvp)
            except Exception as e:      # noqa: BLE001 - a model's candidate: any failure skips it
                if unusable is None:
                    raise
                unusable.append(f"{g.source}: unusable guess ({e})")
                count += 1
                continue
            if fresh(z, st):
                yield z, T, st, g.source
                count += 1
    if count >= max_candidates or guess_only:
        return
    rng = np.random.default_rng(seed)
    g = eigenaxis_guess(bvp)
    z0, T0 = g.to_nondim(bvp)
    if count < max_candidates and fresh(z0, None):
        yield z0, T0, None, g.source
        count += 1
    if per_axis:
        for zt, Tt, (s0, ax, tt), name in structure_templates(bvp, z0, T0, rng):
            if count >= max_candidates:
                return
            st = Structure(s0, ax, tt)
            if fresh(zt, st):
                yield zt, Tt, st, name
                count += 1
    gl = eigenaxis_guess(bvp, long_way=True)
    zl, Tl = gl.to_nondim(bvp)
    extra = [(zl, Tl, gl.source)] + [(zi, Ti, "eigenaxis-image") for zi, Ti in symmetric_images(bvp, z0, T0)]
    for z, T, src in extra:
        if count >= max_candidates:
            return
        if fresh(z, None):
            yield z, T, None, src
            count += 1
    k = 0
    while count < max_candidates and k < 10 * max_candidates:
        scale = (0.2, 0.4, 0.6)[k % 3]
        zp, Tp = perturbed(z0, T0, rng, scale)
        k += 1
        if fresh(zp, None):
            yield zp, Tp, None, f"eigenaxis-perturbed({scale:g})"
            count += 1


def _polish_multiple(bvp, a: Attempt, segments):
    """Event-driven multiple shooting from an exact switch-time answer (consistency polish)."""
    bvp.set_mode("bang")
    r = newton_shoot(bvp, a.z, a.T, segments=segments, tol=1e-11, max_step=0.1)
    if r.success and abs(r.T - a.T) < 1e-8 * a.T:
        a.z, a.T = r.p, r.T
        a.trajectory = None   # recorded for the previous (z, T)
        a.route += f" + event-driven multiple shooting ({segments} segments)"
    a.nit += r.nit
    a.nfev += r.nfev
    return a


def guess_alone(prob, guess, options, budget, method="indirect", with_candidates=True) -> SlewSolution:
    """``guess`` (and its candidates, unless not ``with_candidates``) alone by the indirect
    route, no classical candidates, within ``budget`` s: the first verified extremal that is not
    slower than the eigenaxis slew wins (a warm start's candidates, best first)."""
    n = 1 + len(guess.candidates) if with_candidates else 1
    # model_guess: a candidate the solver cannot use is a failed candidate, not an error
    opts = dict(options, max_candidates=n, min_candidates=1, enough=1, time_budget=budget, model_guess=True,
                guess_only=True)
    return solve_indirect(prob, method, guess, first_verified=True, **opts)


def exact_from_kkt(prob, bang, kkt_guess, options, budget, prefix) -> Optional[SlewSolution]:
    """The exact extremal from a switch-time answer's KKT costates (``kkt_guess``), if the exact
    solver certifies one no slower than ``bang`` within ``budget`` s (the optimum was bang-bang
    after all), with ``bang``'s work counted and the route through it; else ``None``, with the
    attempt's work counted in ``bang`` and its outcome in ``bang.message``."""
    if kkt_guess is None or not budget > 0.05:
        return None
    ex = guess_alone(prob, kkt_guess, options, budget)
    if ex.success and ex.tf <= bang.tf * (1.0 + 1e-9):
        ex.route = f"{prefix} → {bang.route} → exact extremal from its KKT costates: {ex.route}"
        ex.nit += bang.nit
        ex.nfev += bang.nfev
        return ex
    bang.nit += ex.nit
    bang.nfev += ex.nfev
    bang.message += f" The exact solver from its KKT costates: {ex.message[:200]}"
    return None


def refuse_zero_slew(prob) -> None:
    """``ValueError`` (naming the target's field) for a slew at rest whose target is its start."""
    if prob.is_rest_to_rest and prob.slew_angle < 1e-12:
        if prob.qf is None:
            raise ValueError("sensor_target: the sensor already points at the target (zero slew at rest); "
                             "nothing to solve")
        raise ValueError("qf: the target equals the start (zero slew at rest); nothing to solve")


def solve_indirect(prob, method, guess, first_verified=False, **options) -> SlewSolution:
    """The indirect multi-start. ``first_verified``: stop at the first verified extremal that
    is not slower than the eigenaxis slew (a warm start's candidates, best first)."""
    t_start = time.perf_counter()
    if prob.cones:
        raise ValueError("cones: keep-out cones are not supported by the indirect solvers yet "
                         f"({len(prob.cones)} given); use method='auto' or 'collocation'")
    refuse_zero_slew(prob)
    segments = int(options.get("segments", 4 if method == "multiple-shooting" else 1))
    if segments < 1:
        raise ValueError(f"segments: must be a positive integer, got {segments}")
    per_axis = math.isinf(prob.torque_norm)
    max_candidates = int(options.get("max_candidates", 16 if per_axis else 8))
    min_candidates = int(options.get("min_candidates", 8 if per_axis else 3))
    enough = int(options.get("enough", 2))
    if enough < 1:
        raise ValueError(f"enough: must be a positive integer, got {enough}")
    seed = options.get("seed", 0)
    budget = float(options.get("time_budget", 20.0))
    tols = options.get("tols")
    n_dense = int(options.get("n_dense", DENSE_STEPS))
    eps_min = float(options.get("eps_min", 1e-3))
    kw = {}
    if "rtol" in options:
        kw["rtol"] = float(options["rtol"])
    if "atol" in options:
        kw["atol"] = float(options["atol"])
    bvp = AttitudeBVP(prob, **kw)
    # the eigenaxis slew is what spacecraft fly today: an extremal slower than it is a
    # local optimum, never the answer (rest-to-rest problems only; for a pointing-only
    # target the eigenaxis slew to the reference attitude, one feasible way to point)
    baseline = math.nan
    if prob.is_rest_to_rest:
        baseline = eigenaxis_time(bvp.ref_problem, n_grid=1000) / bvp.tau
    fine_done = False

    def near_baseline(T):
        """The baseline for an extremal of time ``T``: the 1,000-step grid time, which lies above
        the continuous profile (by up to ~5e-4 on strongly asymmetric bodies), unless ``T`` is
        within the bound's margin of it (``FINE_GATE``) and the solve has the time: then the fine
        grid's, once (13-34 ms), so that an extremal between the two is not taken for faster than
        the eigenaxis slew. (Past the deadline the grid's stands, as before: a budget comes first.)"""
        nonlocal baseline, fine_done
        margin, cost = FINE_GATE["per-axis" if per_axis else "p-norm"]
        if (not fine_done and math.isfinite(baseline) and T >= baseline * (1.0 - margin)
                and deadline - time.perf_counter() > cost):
            fine_done = True
            baseline = min(baseline, fine_eigenaxis_time(bvp.ref_problem) / bvp.tau)
        return baseline
    deadline = t_start + budget
    method_used = "multiple-shooting" if method == "multiple-shooting" else "indirect"
    cap = options.get("candidate_cap", CANDIDATE_CAP)
    if cap is not None:
        cap_mult, cap_floor = checked_cap(cap)
    first_nfev = None       # propagations of the first verified built-in candidate's attempt

    nit = nfev = 0

    def attempt(z, T, st, src):
        """One candidate's Newton path from ``(z, T)``, then, if it converged, the verification of
        its extremal: ``(attempt, path_cost, ok, checks, text, trajectory)``."""
        nonlocal nit, nfev
        # structure templates, model guesses (learned, nearest-neighbour) and the KKT costates of
        # a switch-time optimisation carry a full switching structure: straight to the
        # switch-time Newton, no smoothing path
        path_cost = 0
        if per_axis and st is not None and src.startswith(("template", "learned", "nearest", "switch-time")):
            a = solve_structure(bvp, z, T, st, route=f"switch-time from {src}", deadline=deadline,
                                stall=TEMPLATE_STALL if src.startswith("template") else None)
            if a.success and segments > 1:
                a = _polish_multiple(bvp, a, segments)
        elif per_axis:
            a = per_axis_from_guess(bvp, z, T, st, eps_min=eps_min, deadline=deadline,
                                    T_accept=baseline * (1 + 1e-7) if baseline == baseline else math.inf,
                                    max_nfev=(max(cap_mult * first_nfev, cap_floor)
                                              if cap is not None and first_nfev is not None else math.inf))
            path_cost = a.nfev if a.route.startswith("tanh continuation") else 0
            if a.success and segments > 1:
                a = _polish_multiple(bvp, a, segments)
        else:
            a = pnorm_from_guess(bvp, z, T, prob.torque_norm, segments=segments, deadline=deadline)
        nit += a.nit
        nfev += a.nfev
        if not a.success:
            return a, path_cost, False, {}, a.message, None
        if per_axis:
            bvp.set_mode("bang")
        else:
            bvp.set_mode("pnorm", p=prob.torque_norm)
        # the event check's record (T / DENSE_STEPS steps) of the same (z, T) serves as the dense record
        reuse = a.trajectory if (per_axis and n_dense == DENSE_STEPS) else None
        ok, checks, text, tr = verify(bvp, a.z, a.T, a.structure, tols=tols, n_dense=n_dense, trajectory=reuse)
        nfev += 2
        return a, path_cost, ok, checks, text, tr

    tried = 0
    found = []   # (T, attempt, tr, checks, source)
    failures = []
    last_verif_fail = None
    antipodal = []      # candidates whose extremal put the sensor on the target's antipode

    def listed(unusable):
        return _candidates(bvp, guess, max_candidates, seed, per_axis,
                           unusable=unusable if options.get("model_guess") else None,
                           guess_only=bool(options.get("guess_only")))

    def candidates():
        yield from listed(failures)
        # (an extremal slower than the eigenaxis slew is no answer: status 4; the baseline is NaN
        # with rates at the ends, where every verified extremal counts)
        if (any(not (f[0] > baseline * (1 + 1e-7)) for f in found) or not antipodal
                or time.perf_counter() > deadline):
            return
        # the antipode is a root of the plain pointing residual; the stereographic one has none
        # there (``core.pointing``), so with no verified answer the candidates run again with
        # it (an outside replay: on 3 of 17 pointing slews every converged candidate ended at
        # the antipode). Only then: it changes the Newton paths, and so which local extremals
        # other slews' candidates reach.
        bvp.stereographic = True
        for z, T, st, src in listed([]):      # (unusable ones were named in the first pass)
            yield z, T, st, f"{src} (stereographic pointing residual)"

    for z, T, st, src in candidates():
        # the budget is checked between candidates, and the first one always starts; inside a
        # candidate the Newton iterations stop at the deadline (the kernels were loaded before
        # the clock started: ``kernel_loading``)
        if tried > 0 and time.perf_counter() > deadline:
            break
        if (enough <= 1 and tried >= min_candidates
                and any(not (f[0] > near_baseline(f[0]) * (1 + 1e-7)) for f in found)):
            # ``enough=1``: a verified extremal not slower than the eigenaxis slew, and
            # ``min_candidates`` tried (it had waited for a second extremal, as ``enough=2``)
            break
        tried += 1
        a, path_cost, ok, checks, text, tr = attempt(z, T, st, src)
        if sensor_reversed(checks):
            antipodal.append(src)
        if not a.success:
            failures.append(f"{src}: {a.message}")
            continue
        if not ok:
            last_verif_fail = (a, tr, checks, text, src)
            failures.append(f"{src}: {text}")
            continue
        found.append((a.T, a, tr, checks, src))
        # the reference is the cost of a built-in candidate's smoothing path (as measured:
        # a switch-time Newton from a full structure, ~10 propagations for a template, says
        # nothing about how long a path needs; a user's, a model's or collocation's guess
        # was not measured and does not set it)
        if first_nfev is None and path_cost > 0 and src.startswith("eigenaxis"):
            first_nfev = path_cost
        if first_verified and not (a.T > near_baseline(a.T) * (1 + 1e-7)):
            break
        if len(found) >= enough and tried >= min_candidates:
            Ts = sorted(f[0] for f in found)
            beats_baseline = not (Ts[0] > near_baseline(Ts[0]) * (1 + 1e-7))
            if len(Ts) >= 2 and abs(Ts[1] - Ts[0]) <= 1e-7 * Ts[0] and beats_baseline:
                break
    bvp.stereographic = False
    wall = time.perf_counter() - t_start
    if found:
        near_baseline(min(f[0] for f in found))
    common = dict(nit=nit, nfev=nfev, method=method_used, n_candidates=tried, problem=prob,
                  baseline_tf=baseline * bvp.tau)
    # the baseline comes from a grid (never too fast: the fine one near an answer) or, without a
    # gyroscopic term, its closed form: 1e-7 slack
    if found and min(f[0] for f in found) > baseline * (1 + 1e-7):
        best_T = min(f[0] for f in found)
        T, a, tr, checks, src = next(f for f in found if f[0] <= best_T * (1.0 + 1e-9))
        fields = solution_fields(bvp, a.z, a.T, a.route, tr, checks, src, prob, a.structure)
        cands = sorted({round(f[0] * bvp.tau, 9) for f in found})
        return SlewSolution(False, STATUS_WORSE_THAN_BASELINE,
                            f"{STATUS_MESSAGES[STATUS_WORSE_THAN_BASELINE]} Best extremal {T * bvp.tau:.9g} vs "
                            f"eigenaxis slew {baseline * bvp.tau:.9g}; tried {tried} candidate(s)."
                            + (f" First failure: {failures[0]}" if failures else ""),
                            wall_time=time.perf_counter() - t_start, candidates_tf=cands, **common, **fields)
    if found:
        best_T = min(f[0] for f in found)
        # among extremals with the same final time, report the first one found
        T, a, tr, checks, src = next(f for f in found if f[0] <= best_T * (1.0 + 1e-9))
        fields = solution_fields(bvp, a.z, a.T, a.route, tr, checks, src, prob, a.structure)
        cands = sorted({round(f[0] * bvp.tau, 9) for f in found})
        msg = STATUS_MESSAGES[STATUS_SUCCESS]
        if len(cands) > 1:
            msg += f" Best of {len(cands)} distinct extremals found (final times {cands})."
        return SlewSolution(True, STATUS_SUCCESS, msg, wall_time=time.perf_counter() - t_start,
                            candidates_tf=cands, **common, **fields)
    if last_verif_fail is not None:
        a, tr, checks, text, src = last_verif_fail
        fields = solution_fields(bvp, a.z, a.T, a.route, tr, checks, src, prob, a.structure)
        return SlewSolution(False, STATUS_VERIFICATION_FAILED,
                            f"{STATUS_MESSAGES[STATUS_VERIFICATION_FAILED]} {text}", wall_time=wall,
                            **common, **fields)
    status = STATUS_BUDGET_EXHAUSTED if time.perf_counter() > deadline else STATUS_NOT_CONVERGED
    detail = "; ".join(failures[:3])
    return SlewSolution(False, status, f"{STATUS_MESSAGES[status]} Tried {tried} candidate(s): {detail}",
                        wall_time=wall, route=f"{method_used}: no candidate converged ({tried} tried)", **common)
