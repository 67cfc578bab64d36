"""Indirect (Pontryagin) routes to one extremal from one guess.

Per-axis bound: switch-time Newton from a guess that carries a switching structure;
otherwise smoothing continuation (tanh, ε ↓) and, along the path, the bang-bang
structures it suggests are tried with the exact switch-time solver. The result is
then re-propagated with event-driven switching (no structure imposed): if the
switching law produces other switches the structure is corrected and solved again.

p-norm bound: event-free shooting on the closed-form control (single or multiple
shooting), directly and, if that fails, by norm continuation from p = 2.
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .core import attitude_flow as af
from .homotopy import continue_path, set_pnorm, set_tanh, structure_candidates
from .shooting import newton_shoot
from .solution import bang_bang_control
from .switch_time import Structure, solve_switch_times
from .verify import DENSE_STEPS


# the smoothing path's Newton solves stop when, after 10 iterations, the residual is above 1e-5
# and more than 0.9 of what it was 10 iterations before (``newton_shoot``'s ``stall``); the step
# is then retried shorter. Without it, more than half of the classical route's Newton iterations
# were spent in solves that crept to their 25-iteration limit and failed. On 40 seeded problems
# (runs/s20/ind_ab.py) this cut the evaluations by 20 % with the same answers; (6, 0.5) cut 42 %
# but changed paths enough to lose extremals: one 1.3e-4 slower, and none at all on a J = (1, 3, 5)
# slew, whose path then crawled past its 60 steps
SMOOTHING_STALL = (10, 0.9, 1e-5)


@dataclass
class Attempt:
    success: bool
    z: np.ndarray
    T: float
    structure: Optional[Structure]
    nit: int
    nfev: int
    route: str
    message: str
    residual: float = math.inf
    history: list = field(default_factory=list)
    trajectory: object = None   # the event-driven record (T / DENSE_STEPS steps) that confirmed the structure


def _event_check(bvp, z, T, structure, tol=1e-8, n_steps=DENSE_STEPS):
    """Event-driven propagation of ``(z, T)``: does it reproduce ``structure``?

    Steps are capped at ``T / n_steps`` (as in the verification) so that a switching
    function that crosses zero twice within one long step is not missed.
    """
    bvp.set_mode("bang")
    tr = bvp.record(z, T, hmax=T / n_steps)
    if not tr.ok:
        return False, None, tr
    ev = Structure(tr.signs0, tr.switch_axis.astype(np.int64), tr.switch_t)
    if structure is None:
        return False, ev, tr
    same = (structure.same_sequence(ev.signs0, ev.axes)
            and np.allclose(ev.times, structure.times, atol=tol * max(1.0, T), rtol=0))
    return same, ev, tr


def solve_structure(bvp, z, T, structure, nit=0, nfev=0, route="switch-time", max_rounds=3,
                    tol=1e-12, deadline=math.inf, stall=None):
    """Exact bang-bang solve for a structure, then correct the structure until the
    event-driven propagation reproduces it. ``deadline`` (``time.perf_counter()`` time):
    checked before each Newton iteration; ``stall``: ``solve_switch_times``'s."""
    bvp.set_mode("bang")
    st = structure
    last = None
    for _ in range(max_rounds):
        sr = solve_switch_times(bvp, z, st, T, tol=tol, deadline=deadline, stall=stall)
        nit += sr.nit
        nfev += sr.nfev
        last = sr
        if not sr.success:
            return Attempt(False, sr.z, sr.T, sr.structure, nit, nfev, route,
                           f"switch-time Newton: {sr.message} (residual {sr.residual_norm:.2e})",
                           sr.residual_norm, sr.history)
        same, ev, tr = _event_check(bvp, sr.z, sr.T, sr.structure)
        if same:
            return Attempt(True, sr.z, sr.T, sr.structure, nit, nfev, route, "converged",
                           sr.residual_norm, sr.history, trajectory=tr)
        if ev is None:
            break
        # the switching law switches elsewhere: adopt its structure and solve again
        z, T, st = sr.z, sr.T, ev
    r = last.residual_norm if last else math.inf
    return Attempt(False, z, T, st, nit, nfev, route,
                   "the switching law does not reproduce the solved switch structure", r)


def per_axis_from_guess(bvp, z, T, structure=None, *, eps_starts=(0.3, 1.0), eps_min=1e-3,
                        deadline=math.inf, T_accept=math.inf, max_nfev=math.inf):
    """One attempt at the exact per-axis extremal from one nondimensional guess.

    Along the smoothing path, a bang-bang extremal slower than ``T_accept`` (the
    eigenaxis slew, nondimensional) is kept only as a fallback and the path goes on:
    it is a local optimum, and the smaller ε points usually lead to the better one.
    The path starts at the first of ``eps_starts`` where Newton converges.
    ``max_nfev``: the attempt (the guess's switch-time solve, the path and the switch-time
    solves along it) stops once it has made more than that many propagations, checked before
    each Newton solve (one solve may overrun it), keeping an extremal it found before.
    """
    nit = nfev = 0
    path_nfev = 0       # the running path's propagations, as last reported to over_cap
    capped = False

    def over_cap(n_path):
        nonlocal path_nfev, capped
        path_nfev = n_path
        if nfev + n_path > max_nfev:
            capped = True
            return f"stopped at its cap of {max_nfev:g} propagations"
        return None

    if structure is not None:
        a = solve_structure(bvp, z, T, structure, route="switch-time (guess structure)", deadline=deadline)
        if a.success and a.T <= T_accept:
            return a
        nit, nfev = a.nit, a.nfev
    found = {}

    def try_point(pt):
        nonlocal nit, nfev
        if time.perf_counter() > deadline:
            return True
        if pt.param > 0.05 * scale:
            return False
        bvp.set_mode("tanh", eps=pt.param)
        for st in structure_candidates(bvp, pt.z, pt.T):
            if over_cap(path_nfev):
                return True
            a = solve_structure(bvp, pt.z, pt.T, st, route=f"tanh continuation to eps={pt.param:.3g} + switch-time",
                                deadline=deadline)
            nit += a.nit
            nfev += a.nfev
            if a.success:
                if "best" not in found or a.T < found["best"].T:
                    found["best"] = a
                if a.T <= T_accept:
                    return True
        bvp.set_mode("tanh", eps=pt.param)
        return False

    # ε is a width on σ = umax·S: scale the path to the size of the guess's switching
    # functions (for the eigenaxis guess |λω(0)| = (T/4)/sqrt(1 + T²/16) with |z| = 1),
    # so that a short slew with small S is smoothed as much as a long one
    sig = float(np.max(np.abs(bvp.umax * np.asarray(z[3:6]) / bvp.J)))
    scale = min(1.0, max(2.0 * sig, 1e-6))
    path = None
    for eps0 in eps_starts:
        path_nfev = 0
        if over_cap(0):         # the guess's own switch-time solve or a failed start used it up
            break
        path = continue_path(bvp, z, T, eps0 * scale, eps_min * scale, set_param=set_tanh, on_point=try_point,
                             stall=SMOOTHING_STALL, deadline=deadline,
                             exhausted=over_cap if max_nfev < math.inf else None)
        nit += path.nit
        nfev += path.nfev
        if path.points:       # the path started: do not restart it from another ε
            break
    bvp.set_mode("bang")
    if "best" in found:
        a = found["best"]
        a.nit, a.nfev = nit, nfev
        return a
    if path is None or capped:
        where = f" (eps = {path.points[-1].param:.3g})" if path is not None and path.points else ""
        return Attempt(False, z, T, None, nit, nfev, "tanh continuation",
                       f"stopped at its cap of {max_nfev:g} propagations{where}")
    if not path.success:
        return Attempt(False, z, T, None, nit, nfev, "tanh continuation", path.message)
    last = path.points[-1]
    # the diagnosis records the path (~10 ms): not past the caller's deadline
    msg = (f"no bang-bang structure near the smoothed extremal (eps = {last.param:.3g}, "
           f"tf = {last.T * bvp.tau:.9g})" + (singular_diagnosis(bvp, last.z, last.T, last.param)
                                              if time.perf_counter() <= deadline else ""))
    return Attempt(False, last.z, last.T, None, nit, nfev, "tanh continuation", msg)


def singular_diagnosis(bvp, z, T, eps, threshold=0.05):
    """Text naming the axes whose smoothed control stays unsaturated (|u_i| < 0.99 u_max)
    for more than ``threshold`` of the time: the extremal has a (near-)singular arc there,
    where the time-optimal control is not bang-bang (it may chatter)."""
    bvp.set_mode("tanh", eps=eps)
    tr = bvp.record(z, T, hmax=T / 1000)
    bvp.set_mode("bang")
    if not tr.ok or tr.t.shape[0] < 3:
        return ""
    S = tr.y[:, 11:14] / bvp.J
    unsat = np.abs(np.tanh(S * bvp.umax / eps)) < 0.99
    dt = np.diff(tr.t)
    frac = (unsat[:-1] * dt[:, None]).sum(axis=0) / T
    axes = [f"{'xyz'[i]} ({100 * frac[i]:.0f} % of the time)" for i in range(3) if frac[i] > threshold]
    if not axes:
        return ""
    return ("; the control stays unsaturated on axis " + ", ".join(axes)
            + ": a (near-)singular arc, where the time-optimal control is not bang-bang")


def pnorm_from_guess(bvp, z, T, p, *, segments=1, tol=1e-9, deadline=math.inf):
    """One attempt at the p-norm extremal: direct shooting, else continuation from p = 2
    (within ``deadline``, a ``time.perf_counter()`` value, checked between its steps and
    Newton iterations).

    The tolerance is looser than the bang-bang one because the p-norm control jumps
    where λω passes through zero (the midpoint of an eigenaxis slew), which limits the
    integrator's accuracy to about 1e-10.
    """
    bvp.set_mode("pnorm", p=p)
    r = newton_shoot(bvp, z, T, segments=segments, tol=tol, max_step=0.5, deadline=deadline)
    if r.success:
        return Attempt(True, r.p, r.T, None, r.nit, r.nfev,
                       "multiple shooting" if segments > 1 else "single shooting", "converged",
                       r.residual_norm, r.history)
    nit, nfev = r.nit, r.nfev
    if p != 2.0:
        start, stop = (2.0, p)
        path = continue_path(bvp, z, T, start, stop, set_param=set_pnorm, factor=1.5, tol=max(tol, 1e-8),
                             deadline=deadline)
        nit += path.nit
        nfev += path.nfev
        if path.success:
            last = path.points[-1]
            bvp.set_mode("pnorm", p=p)
            r = newton_shoot(bvp, last.z, last.T, segments=segments, tol=tol, max_step=0.5, deadline=deadline)
            nit += r.nit
            nfev += r.nfev
            if r.success:
                return Attempt(True, r.p, r.T, None, nit, nfev, "norm continuation from p=2", "converged",
                               r.residual_norm, r.history)
    return Attempt(False, r.p, r.T, None, nit, nfev, "shooting", r.message, r.residual_norm, r.history)


def solution_fields(bvp, z, T, route, tr, checks, guess_src, problem, structure=None):
    """``SlewSolution`` fields, in the problem's units, of the extremal ``(z, T)`` recorded as
    ``tr`` (a ``Trajectory``): costates rescaled to ``H ≡ -1``, switch times, the dense samples,
    the control and ``tf_tol`` from the boundary and replay errors in ``checks``."""
    # the answer's own control law, whatever mode the solver was left in: a later candidate's
    # p-norm continuation, stopped part-way, leaves an intermediate p, and the torque, the
    # control(t) closure and the costate scale of an earlier, verified answer were built with it
    # (session 27's independent replay: p = 1.807 for a p = 1.5 answer, ||u||_p = 1.13)
    if math.isinf(problem.torque_norm):
        bvp.set_mode("bang")
    else:
        bvp.set_mode("pnorm", p=float(problem.torque_norm))
    tau = bvp.tau
    umax0 = float(problem.torque_max.max())
    H0 = bvp.hamiltonian(tr.y[0], tr.signs[0])
    c = -1.0 / H0 if H0 < 0 else 1.0
    y0, _ = bvp.initial(z)
    costate0 = np.concatenate([c * tau * y0[7:11], c * tau ** 2 * y0[11:14]])
    t = tr.t * tau
    u_nd = af.control_batch(tr.y, bvp.J, bvp.umax, bvp.mode, bvp.p, bvp.eps, tr.signs)
    u = u_nd * umax0
    costate = np.hstack([c * tau * tr.y[:, 7:11], c * tau ** 2 * tr.y[:, 11:14]])
    if bvp.mode == af.MODE_BANG:
        # the solved switch instants when there are (the answer the boundary was checked on),
        # else the event-located ones
        same = structure is not None and structure.same_sequence(tr.signs0, tr.switch_axis)
        src_t, src_a = (structure.times, structure.axes) if same else (tr.switch_t, tr.switch_axis)
        sw = [np.sort(src_t[src_a == i]) * tau for i in range(3)]
        u_first = tr.signs0.copy()
        control = bang_bang_control(sw, u_first, problem.torque_max)
    else:
        sw = [np.zeros(0)] * 3
        u_first = np.sign(u[0])

        # the control is a smooth function of λω but may turn sharply (it reverses where λω
        # passes through zero: the 2-norm eigenaxis slew at tf/2), so it is not interpolated
        # between samples: the extremal is propagated from the last sample before t (the same
        # flow; a frozen copy, so later changes of the solver's mode cannot affect it)
        flow = copy.copy(bvp)
        ts, ys = tr.t.copy(), tr.y.copy()

        def control(tq):
            tq = np.asarray(tq, dtype=float)
            flat = np.atleast_1d(tq).ravel()
            out = np.empty((flat.size, 3))
            for n, tt in enumerate(flat):
                sq = min(max(float(tt) / tau, 0.0), float(ts[-1]))
                k = max(0, int(np.searchsorted(ts, sq, side="right")) - 1)
                y = ys[k]
                if sq > ts[k]:
                    y = flow._run(y.copy(), sq - float(ts[k]), None)[0][:af.NY]
                out[n] = af.control(y, flow.J, flow.umax, flow.mode, flow.p, flow.eps, tr.signs0)[0] * umax0
            return out.reshape(tq.shape + (3,))
    # tolerance of tf: the boundary errors and the independent replay bound how far the
    # extremal is from reaching the target; tf is known to that order (relative), and never
    # better than the integrator's 1e-10
    err = max((checks[k]["value"] for k in ("boundary_attitude_error", "replay") if k in checks),
              default=math.inf)       # neither: the dense record failed (not verified)
    tf_tol = T * tau * max(1e-10, 10.0 * err)
    return dict(tf=T * tau, tf_tol=tf_tol, costate0=costate0, switch_times=sw, u_first=u_first, t=t,
                q=tr.y[:, 0:4].copy(), omega=tr.y[:, 4:7] / tau, u=u, costate=costate,
                _control=control, route=route, guess=guess_src, verification=checks)
