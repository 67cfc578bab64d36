"""Self-verification of an extremal before it may be reported as ``success=True``.

Checks (each a dict ``{value, tol, passed}`` in ``SlewSolution.verification``):

* ``boundary_attitude_error`` — angle (rad) of ``qf* ⊗ q(tf)``; for a pointing-only
  target, the angle between the sensor's direction and the target. Per-axis bound with a
  solved switch structure: at the end of the arcs between the solved (returned) switch
  instants; otherwise from the event-driven propagation of the returned costates;
* ``roll_transversality`` — pointing-only targets: ``|μ(tf)·s| / |μ(tf)|``, the relative
  attitude costate about the free boresight at ``tf`` (transversality, must be ≤ tol);
* ``boundary_rate_error`` — ``‖ω(tf) - ωf‖`` (problem units);
* ``hamiltonian_drift`` — ``max |H(t) - H(0)| / |H(0)|`` along the dense samples;
* ``normality`` — ``H < 0`` (a normal extremal, ``λ0 > 0``); value is ``H(0)`` in the
  ``|z| = 1`` scale;
* ``switching_law`` — per-axis bound: ``u_i = -u_max,i sign(S_i)`` holds at every
  sample (value: worst ``sign(u_i)·S_i / max|S_i|``, must be ≤ tol); p-norm bound: the
  switching vector never vanishes (value: ``min ‖σ‖ / max ‖σ‖``);
* ``switch_structure`` — per-axis: the event-driven propagation of the returned costates
  switches on the same axes at the same instants as the switch-time solution, to 1e-9 of
  ``tf`` divided by each switch's conditioning (``switch_deviation``: a switching function
  that crosses zero slowly fixes its zero less precisely);
* ``rate_limit`` — ``max |ω_i| / rate_max_i`` and ``max ‖ω‖ / rate_norm_max``, the larger (only
  when the problem has a rate limit), at the dense samples and between them (``_rates_between``:
  the intervals that could reach the limit integrated again);
* ``replay`` — an independent re-propagation with a different integrator: for the
  per-axis bound, the returned switch times and first-arc signs alone, integrated by
  the environment's fixed-step RK4 (``slew_env.core.propagate``); for a p-norm bound,
  the state–costate system by a compiled Dormand–Prince 5(4) with its own step control
  (``core.costate_replay``; scipy's Radau until 2026-11-23). Value: the worse of the
  attitude (rad) and nondimensional rate errors at ``tf`` (infinite if the replay fails).
"""
from __future__ import annotations

import math

import numpy as np

from .core import attitude_flow as af
from .core.control_replay import replay_bang_bang_path
from .core.costate_replay import REPLAY_OK, replay_pnorm_end
from .switch_time import propagate_sequence

# the p-norm replay's step cap (a 5(4) pair at rtol 1e-11 takes hundreds to a few thousand)
PNORM_REPLAY_STEPS = 1_000_000

# The dense record of an extremal caps its steps at T / DENSE_STEPS (every accepted step and both
# sides of every switch are sampled). The event-driven propagation that records it tests each
# step for a switching function that crosses zero twice inside it (a cubic through the step's
# ends), so the cap sets the density of the samples, not whether a switch is found: at T / 100
# the records of 300 held-out solves gave the same answers as at T / 400, in a quarter of the
# time (1.3 → 0.35 ms a record).
DENSE_STEPS = 100

DEFAULT_TOLS = {
    "boundary_attitude_error": 1e-8,
    "boundary_rate_error": 1e-8,      # nondimensional (ω·τ); the reported value is physical
    "hamiltonian_drift": 1e-7,
    "normality": 0.0,
    "switching_law": 1e-9,
    "switch_structure": 1e-9,
    "rate_limit": 1.0 + 1e-9,
    "replay": 1e-7,
    "roll_transversality": 1e-8,
}


def make_check(value, tol, passed):
    return {"value": float(value), "tol": float(tol), "passed": bool(passed)}


def failure_text(checks):
    """``""`` when every check passed, else which failed first and by how much."""
    failed = [k for k, c in checks.items() if not c["passed"]]
    if not failed:
        return ""
    c = checks[failed[0]]
    v, tol = float(c["value"]), float(c["tol"])
    # enough digits to tell the value from its tolerance (a rate ratio of 1.0003 against 1.0001)
    digits = 3
    while digits < 12 and f"{v:.{digits}g}" == f"{tol:.{digits}g}":
        digits += 1
    text = f"verification failed: {failed[0]} = {v:.{digits}g} (tolerance {tol:.{digits}g})"
    if c.get("note"):
        text += f": {c['note']}"
    if len(failed) > 1:
        text += f"; also failed: {', '.join(failed[1:])}"
    return text


def dense_record(bvp, z, T, n=DENSE_STEPS):
    return bvp.record(z, T, hmax=T / n)


def replay_path(J, umax, q0, w0, switch_times, u_first, tf, steps_per_tf=1000):
    """``(t, x)``, ``x = [q, ω]``, from switch times and first-arc signs alone: fixed-step RK4
    of the environment, about ``steps_per_tf`` steps over ``tf``, every step sampled
    (``core.control_replay.replay_bang_bang_path``)."""
    events = sorted((float(t), i) for i in range(3) for t in switch_times[i])
    ev_t = np.array([e[0] for e in events], dtype=float)
    ev_axis = np.array([e[1] for e in events], dtype=np.int64)
    x0 = np.concatenate([q0, w0]).astype(float)
    return replay_bang_bang_path(x0, np.asarray(umax, dtype=float), np.asarray(J, dtype=float), ev_t, ev_axis,
                                 np.array(u_first, dtype=float), float(tf), float(steps_per_tf))


def replay_bang_bang(J, umax, q0, w0, switch_times, u_first, tf, steps_per_tf=1000):
    """State at ``tf`` from switch times and first-arc signs alone (``replay_path``'s last)."""
    return replay_path(J, umax, q0, w0, switch_times, u_first, tf, steps_per_tf)[1][-1]


def end_error(bvp, x):
    """The worse of the attitude error (rad) and the nondimensional rate error of the state
    ``x = [q, ω, …]`` (nondimensional) against the target: the replay check's value."""
    return max(bvp.attitude_error(x[0:4]), float(np.linalg.norm(x[4:7] - bvp.wf)))


SENSOR_REVERSED = "the sensor ends pointing away from the target"


def sensor_reversed(checks):
    """Did a pointing target's extremal end with the sensor on the target's antipode (more than
    90° off; ``boundary_checks``' note)? ``False`` for empty checks (no extremal to check)."""
    return checks.get("boundary_attitude_error", {}).get("note") == SENSOR_REVERSED


def boundary_checks(bvp, yT, tols):
    """``boundary_attitude_error``, ``boundary_rate_error`` and, for a pointing target,
    ``roll_transversality`` at the final augmented state ``yT`` (nondimensional)."""
    checks = {}
    att = bvp.attitude_error(yT[0:4])
    rate_nd = float(np.linalg.norm(yT[4:7] - bvp.wf))
    checks["boundary_attitude_error"] = make_check(att, tols["boundary_attitude_error"],
                                                   att <= tols["boundary_attitude_error"])
    if bvp.pointing and att > 0.5 * math.pi:
        # the pointing residual (the sensor parallel to the target) is also zero with the sensor
        # reversed, where a Newton iteration can end: say so, an angle of 3.14 alone does not
        checks["boundary_attitude_error"]["note"] = SENSOR_REVERSED
    checks["boundary_rate_error"] = make_check(rate_nd / bvp.tau, tols["boundary_rate_error"] / bvp.tau,
                                               rate_nd <= tols["boundary_rate_error"])
    if bvp.pointing:
        tv = bvp.roll_transversality(yT)
        checks["roll_transversality"] = make_check(tv, tols["roll_transversality"], tv <= tols["roll_transversality"])
    return checks


def extremal_checks(bvp, tr, tols):
    """The checks of a recorded extremal ``tr`` (a ``Trajectory``) that do not depend on how
    it was found: ``boundary_checks`` at its end, ``hamiltonian_drift``, ``normality`` and,
    for the per-axis bound, ``switching_law`` at every sample."""
    checks = boundary_checks(bvp, tr.y[-1], tols)
    H = af.hamiltonian_batch(tr.y, bvp.J, bvp.umax, bvp.mode, bvp.p, bvp.eps, tr.signs)
    H0 = H[0]
    drift = float(np.max(np.abs(H - H0)) / max(abs(H0), 1e-300))
    checks["hamiltonian_drift"] = make_check(drift, tols["hamiltonian_drift"], drift <= tols["hamiltonian_drift"])
    checks["normality"] = make_check(H0, 0.0, H0 < 0.0)
    if bvp.mode == af.MODE_BANG:
        S = tr.y[:, 11:14] / bvp.J
        amax = np.max(np.abs(S), axis=0)
        amax[amax == 0] = 1.0
        worst = float(np.max(tr.signs * S / amax))
        checks["switching_law"] = make_check(worst, tols["switching_law"], worst <= tols["switching_law"])
    return checks


# RK4 sub-steps of an interval between samples whose rates may peak above the limit inside it: at
# least this many, and enough that no step turns the rates by more than RATE_REFINE_TURN rad (fast
# spinning bodies), at most RATE_REFINE_MAX_STEPS
RATE_REFINE_STEPS = 32
RATE_REFINE_TURN = 0.02
RATE_REFINE_MAX_STEPS = 2000


def _rates_between(bvp, t, Y, slopes, f):
    """The largest rate-limit ratio between the samples ``(t, Y)`` (nondimensional times and
    states whose columns 4:7 are the rates, or the rates alone): a rate can peak inside an arc,
    where Euler's equations turn it round (large rates at the ends), between two samples that both
    pass. Every interval whose samples, plus half its length times 1.5 the path's largest rate
    derivative (``slopes``, per sample), reach the limit is integrated again, all at once: RK4 of
    ``f(ks, Ys)`` (the derivatives of the states ``Ys`` on the intervals ``ks``) in steps that turn
    the rates by at most ``RATE_REFINE_TURN`` rad (at least ``RATE_REFINE_STEPS``), then the peak's
    instant taken from a parabola through the largest step and its neighbours (at an interval's
    end too) and the ratio integrated there (no interpolation's overshoot). A review measured it
    against scipy's DOP853 on 120 fast-spinning paths: within 2e-12."""
    prob, tau = bvp.problem, bvp.tau
    t = np.asarray(t, float)
    Y = np.asarray(Y, float)
    cols = slice(4, 7) if Y.shape[1] > 3 else slice(0, 3)
    ratios = prob.rate_limit_ratios(Y[:, cols] / tau)
    limits = []
    if prob.rate_max is not None:
        limits.append(float(np.min(prob.rate_max)))
    if prob.rate_norm_max is not None:
        limits.append(float(prob.rate_norm_max))
    L = min(limits) * tau                 # the smallest limit, nondimensional
    h = np.diff(t)
    rise = 1.5 * float(np.max(slopes)) * 0.5 * h / L
    worst = float(np.max(ratios))
    ks = np.nonzero((np.maximum(ratios[:-1], ratios[1:]) + rise > 1.0 - 1e-3) & (h > 0.0))[0]
    if ks.size == 0:
        return worst
    spin = float(np.max(np.linalg.norm(Y[:, cols], axis=1))) / float(np.min(bvp.J))   # bounds the turning rate
    n = int(min(RATE_REFINE_MAX_STEPS, max(RATE_REFINE_STEPS, math.ceil(float(np.max(h[ks])) * spin / RATE_REFINE_TURN))))
    dt = (h[ks] / n)[:, None]
    m = ks.size
    Ys = np.empty((n + 1, m, Y.shape[1]))
    Ys[0] = Y[ks]
    R = np.empty((n + 1, m))
    R[0] = prob.rate_limit_ratios(Ys[0][:, cols] / tau)

    def rk4(kk, y, step):
        """One RK4 step of the intervals ``kk`` from their states ``y`` (a step a row)."""
        k1 = f(kk, y)
        k2 = f(kk, y + 0.5 * step * k1)
        k3 = f(kk, y + 0.5 * step * k2)
        k4 = f(kk, y + step * k3)
        return y + step / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    for s in range(n):
        Ys[s + 1] = rk4(ks, Ys[s], dt)
        R[s + 1] = prob.rate_limit_ratios(Ys[s + 1][:, cols] / tau)
    worst = max(worst, float(np.max(R)))
    cols_m = np.arange(m)
    c0 = np.clip(np.argmax(R, axis=0), 1, n - 1)          # the three steps round the largest
    a, b, c = R[c0 - 1, cols_m], R[c0, cols_m], R[c0 + 1, cols_m]
    den = a - 2.0 * b + c
    top = den < 0.0
    if np.any(top):
        x = np.clip(c0[top] + 0.5 * (a[top] - c[top]) / den[top], 0.0, float(n))     # the vertex, in steps
        i = np.minimum(np.floor(x).astype(np.int64), n - 1)
        sel = np.nonzero(top)[0]
        # from the step before the vertex to it, each interval by its own fraction of a step
        yv = rk4(ks[sel], Ys[i, sel], ((x - i) * dt[sel, 0])[:, None])
        worst = max(worst, float(np.max(prob.rate_limit_ratios(yv[:, cols] / tau))))
    return worst


def _bang_rates_between(bvp, t, W, switch_times, signs0):
    """``_rates_between`` for a bang-bang path: Euler's equations alone, with the control of
    each interval's middle (the samples include the switch instants)."""
    from .solution import bang_bang_control
    J = bvp.J
    t = np.asarray(t, float)
    W = np.asarray(W, float)
    U = bang_bang_control(switch_times, signs0, bvp.umax)(0.5 * (t[:-1] + t[1:]))

    def wdot(w, u):
        return (u - np.cross(w, J * w)) / J
    slopes = np.concatenate([np.linalg.norm(wdot(W[:-1], U), axis=1), np.linalg.norm(wdot(W[1:], U), axis=1)])
    return _rates_between(bvp, t, W, slopes, lambda ks, w: wdot(w, U[ks]))


def _costate_rates_between(bvp, t, Y):
    """``_rates_between`` for a path whose control follows its costates (the p-norm law): the
    state and costates integrated together."""
    J, umax, mode, p, eps = bvp.J, bvp.umax, bvp.mode, bvp.p, bvp.eps
    ones = np.ones(3)

    def f1(y):
        return af.ext_rhs(y, af.control(y, J, umax, mode, p, eps, ones)[0], J)
    Y = np.asarray(Y, float)
    slopes = np.array([np.linalg.norm(f1(y)[4:7]) for y in Y])
    return _rates_between(bvp, t, Y, slopes, lambda ks, ys: np.array([f1(y) for y in ys]))


def rate_limit_check(bvp, Y, tols, t=None, switch_times=None, signs0=None):
    """``rate_limit`` (``max |ω_i| / rate_max_i`` and ``max ‖ω‖ / rate_norm_max``:
    ``SlewProblem.rate_limit_ratio``) over the nondimensional states ``Y`` when the problem has
    a rate limit, else nothing. With the samples' times ``t``, also between the samples: from a
    bang-bang path's ``switch_times`` and first-arc ``signs0`` (nondimensional), or without them
    from the costates in ``Y`` (the p-norm law: ``_rates_between``; an outside check found exact answers 0.21 % over the limit
    between two samples that passed, session 43)."""
    prob = bvp.problem
    if not prob.has_rate_limit:
        return {}
    W = np.asarray(Y)[:, 4:7]
    worst = prob.rate_limit_ratio(W / bvp.tau)
    if t is not None and len(t) >= 2 and math.isfinite(worst) and worst <= tols["rate_limit"]:
        # (samples that already fail need no search between them: the answer fails either way)
        worst = max(worst, _bang_rates_between(bvp, t, W, switch_times, signs0) if switch_times is not None
                    else _costate_rates_between(bvp, t, Y))
    return {"rate_limit": make_check(worst, tols["rate_limit"], worst <= tols["rate_limit"])}


# the largest conditioning factor ``switch_deviation`` grants: event-located switches always
# within 1e-7 of tf of the solved ones
MAX_SWITCH_CONDITIONING = 1e2


def switch_deviation(bvp, tr, structure, T):
    """``switch_structure``'s value: the largest gap between an event-located switch of the record
    ``tr`` and the solved one, relative to ``T`` and divided by the conditioning factor of the
    switches up to it, ``W_k = max(1, max_{j ≤ k} 0.1·max|S| / (|Ṡ_{a_j}(t_j)|·T))`` (``max|S|``
    over all axes, ``W_k`` at most ``MAX_SWITCH_CONDITIONING``).

    Why: a switching function that crosses zero slowly (a short pulse on an axis whose ``S``
    hovers near zero) fixes its zero only to ``δS / |Ṡ|``, where ``δS`` is the integration error
    of the costates, and the switches after it inherit that shift through the state, amplified.
    Two correct propagations of the same costates then put those switches up to ~1e-8 of ``T``
    apart. Measured on held-out problems: pulses with ``|Ṡ|`` ~ 1e-4, the last switch 1.8e-9 to
    8e-9 of ``T`` from the solved one, while scipy's DOP853 (rtol 1e-13) found ``S`` within 4e-14 of
    zero at every solved instant. The factor assumes ``δS`` ≤ 1e-10 of the costates' scale; the
    switches before the first slow crossing keep the plain tolerance.
    """
    S = tr.y[:, 11:14] / bvp.J
    scale = float(np.max(np.abs(S)))
    W = 1.0
    worst = 0.0
    for k in range(structure.n):
        a = int(structure.axes[k])
        i = min(int(np.searchsorted(tr.t, tr.switch_t[k])), tr.t.shape[0] - 1)
        y = tr.y[i]
        u, _ = af.control(y, bvp.J, bvp.umax, af.MODE_BANG, 0.0, 1.0, tr.signs[i])
        sdot = abs(float(af.ext_rhs(y, u, bvp.J)[11 + a] / bvp.J[a]))    # the same on both sides
        W = min(max(W, 0.1 * scale / max(sdot * T, 1e-300)), MAX_SWITCH_CONDITIONING)
        worst = max(worst, abs(float(tr.switch_t[k] - structure.times[k])) / T / W)
    return worst


def verify(bvp, z, T, structure=None, tols=None, n_dense=DENSE_STEPS, trajectory=None):
    """Run the checks; returns ``(all_passed, checks, first_failure_text, dense_trajectory)``.

    ``trajectory``: the dense record of exactly ``(z, T)`` with steps capped at ``T / n_dense``
    if the caller already has it (the solver's own event check), else it is recorded here.
    """
    tols = dict(DEFAULT_TOLS, **(tols or {}))
    checks = {}
    tr = trajectory if trajectory is not None else dense_record(bvp, z, T, n_dense)
    if not tr.ok or tr.t.shape[0] < 2:
        checks["propagation"] = make_check(1.0, 0.0, False)
        return False, checks, f"propagation failed: {tr.message}", tr
    checks.update(extremal_checks(bvp, tr, tols))
    if bvp.mode == af.MODE_BANG:
        sw = [tr.switch_t[tr.switch_axis == i] for i in range(3)]
        if structure is not None:
            ok_axes = structure.same_sequence(tr.signs0, tr.switch_axis)
            dev = switch_deviation(bvp, tr, structure, T) if ok_axes and structure.n else (
                0.0 if ok_axes else math.inf)
            checks["switch_structure"] = make_check(dev, tols["switch_structure"],
                                                ok_axes and dev <= tols["switch_structure"])
            if ok_axes:
                # the answer is the solved switch instants: the boundary is checked at the end of
                # their arcs (the event-driven record moves an ill-conditioned switch, and the end
                # state with it, by up to its located deviation: checked just above)
                end = propagate_sequence(bvp, structure.times, structure.axes, structure.signs0, T,
                                         bvp.initial(z)[0], False)
                checks.update(boundary_checks(bvp, end[0] if end is not None else np.full(tr.y.shape[1], np.nan), tols))
                sw = [structure.times[structure.axes == i] for i in range(3)]
        x = replay_bang_bang(bvp.J, bvp.umax, bvp.q0, bvp.w0, sw, tr.signs0, T)
        rep = end_error(bvp, x)
    else:
        sig = np.linalg.norm(tr.y[:, 11:14] / bvp.J * bvp.umax, axis=1)
        ratio = float(np.min(sig) / max(np.max(sig), 1e-300))
        checks["switching_law"] = make_check(ratio, 0.0, ratio > 0.0)
        y0, _ = bvp.initial(z)
        yR, status, _ = replay_pnorm_end(y0, float(T), bvp.J, bvp.umax, float(bvp.p), 1e-11, 1e-12, PNORM_REPLAY_STEPS)
        rep = end_error(bvp, yR) if status == REPLAY_OK else math.inf
        # a p-norm control is continuous except where λω = 0, where the replay's steps must
        # straddle a jump (as Radau's did when it was the replay)
        tols["replay"] = max(tols["replay"], 1e-6)
    checks["replay"] = make_check(rep, tols["replay"], rep <= tols["replay"])
    if bvp.mode == af.MODE_BANG:
        checks.update(rate_limit_check(bvp, tr.y, tols, tr.t, sw, tr.signs0))
    else:
        checks.update(rate_limit_check(bvp, tr.y, tols, tr.t))
    text = failure_text(checks)
    return not text, checks, text, tr
