"""Indirect route for keep-out cones that the optimal path touches or rides: a penalty
homotopy on a smoothed extremal.

When the optimal sensor path rides a cone boundary (Melton's R4 does for about half the
slew) the constrained optimum is not a bang-bang extremal: on a boundary arc one torque
component is interior, fixed by ``d²c/dt² = 0`` (the cone constraint has order 2). This
module solves, by multiple shooting, the Pontryagin conditions of a nearby problem that
has no state constraint, and follows it towards the constrained optimum:

    minimise  tf + ∫ [ P(q) + ε Σᵢ φ(uᵢ / umaxᵢ) ] dt,

* ``P`` the exterior penalty of the cones (``core.cone_penalty``: ``½ w Σ max(0, h)²`` on a
  constraint tightened by a back-off ``δ``), which becomes the state constraint as
  ``w → ∞``;
* ``φ(v) = v atanh v + ½ ln(1 - v²)`` a convex control cost whose minimiser is the
  smoothed law ``vᵢ = -tanh(σᵢ / ε)`` (the flow's ``MODE_TANH``), so an interior torque on a
  boundary arc is an ordinary smooth control, and ``ε → 0`` gives back bang-bang arcs off
  the boundary.

The costate scale is fixed by ``λ0 = 1`` and the free final time by ``H ≡ 0`` (imposed at
``t = 0``, where it costs no propagation); everything else is ``AttitudeBVP``'s: the gauge
``λq(0) = q0 ⊗ [0, μ]``, the full-attitude or pointing residuals with the roll
transversality.

The answer is the exact extremal of that regularised problem, propagated and checked
(boundary residuals, ``H`` constant, the smoothed control law, a certified clearance of
every cone at every instant, an independent replay), not the constrained optimum itself:
its final time is above the optimum by a small amount that the route reports next to the
collocation answer's (``SlewSolution.verification['regularisation']``).
"""
from __future__ import annotations

import math
import time

import numpy as np

from scipy.integrate import solve_ivp

from slew_env import Cone
from slew_env.core.dynamics import propagate
from slew_env.core.quaternion import qmul
from .attitude_bvp import AttitudeBVP, NY
from .clearance import CLEARANCE_TOL, certified_min_margin, cone_clearances
from .core import attitude_flow as af
from .core import cone_penalty as cp
from .core.control_replay import replay_quadratic_control
from .shooting import STATUS_DEADLINE, newton_shoot
from .solution import (STATUS_BUDGET_EXHAUSTED, STATUS_MESSAGES, STATUS_NOT_CONVERGED, STATUS_SUCCESS,
                       STATUS_VERIFICATION_FAILED, SlewSolution)
from .verify import DEFAULT_TOLS, boundary_checks, failure_text, make_check, rate_limit_check

# (ε, w) stages of the homotopy from the collocation costates; each one is solved by
# multiple shooting from the previous answer. w = 1e5 leaves the path about 4e-4 rad inside
# a ridden boundary before the back-off; ε = 5e-3 is within 0.1 % of the bang-bang limit
# on Melton's cases. Smaller values need more segments (the flow gets stiff).
STAGES = ((1e-2, 1e4), (1e-2, 1e5), (5e-3, 1e5))
SEGMENTS = 32
CLEARANCE_AIM = 2e-7         # rad: the back-off aims this far outside the cone
ENDPOINT_SLACK = 1e-7        # rad: the certified bound's own slack beside a boundary end point
MAX_BACKOFF_ROUNDS = 8
MAX_GAP = 3e-3               # relative tf above the seed's (collocation) answer
CONTROL_REPLAY_TOL = 1e-5    # rad and nondimensional rate: the sampled control, replayed
PATH_RTOL = 1e-8
ANSWER_RTOL = 1e-10
CERTIFY_STEPS = 8000         # samples for the certified clearance; every RETURN_EVERY-th is returned
# the returned control is linear between the returned samples: with every 4th, flown as returned,
# it strayed 1.8e-6 rad from the penalised path and entered a cone that path cleared (the
# session-31 audit); every 2nd strays a quarter of that
RETURN_EVERY = 2


def _log_cosh(x):
    ax = np.abs(x)
    return ax + np.log1p(np.exp(-2.0 * ax)) - math.log(2.0)


def load_kernels() -> None:
    """Call the penalty's kernels once, with the argument types this module gives them, so that
    they are loaded before a solve's clock starts (``kernel_loading``): the route runs only after
    the touch-point solver failed, which no quick representative solve reaches."""
    y = np.zeros(NY)
    y[0] = 1.0
    pen = cp.pack([Cone([0.0, 0.0, 1.0], 0.1)], np.array([1.0, 0.0, 0.0]), 1.0, 0.0)
    cp.penalty_value(y, pen)
    cp.penalty_rhs_into(y, pen, np.zeros(NY))
    ones = np.ones(3)
    af.hamiltonian(y, ones, ones.copy(), af.MODE_TANH, 0.0, 0.1, ones.copy())
    u = af.control_batch(np.tile(y, (2, 1)), ones, ones, af.MODE_TANH, 0.0, 0.1, np.ones((2, 3)))
    inertia = np.ones(3)
    inertia.flags.writeable = False      # as a SlewProblem's arrays
    propagate(np.array([1.0, 0, 0, 0, 0, 0, 0]), u[0].copy(), inertia, 0.1, 2)


class ConePenaltyBVP(AttitudeBVP):
    """``AttitudeBVP`` with the cones as an exterior penalty and the tanh control law.

    Unknowns ``z = [μ (3), λω(0) (3)]`` at the physical scale ``λ0 = 1`` (no
    normalisation), plus the final time; ``param_residual`` is ``H(0) = 0``.
    """
    handles_cones = True

    def __init__(self, problem, eps=0.05, weight=1e3, backoff=0.0, rtol=1e-10, atol=1e-11):
        if not problem.cones:
            raise ValueError("cones: the penalty route needs at least one keep-out cone")
        if not math.isinf(problem.torque_norm):
            raise ValueError(f"torque_norm: the cone penalty route handles the per-axis bound ('inf') "
                             f"only, got p = {problem.torque_norm:g}")
        super().__init__(problem, mode="tanh", eps=eps, rtol=rtol, atol=atol)
        self.sensor = np.asarray(problem.sensor_axis, float) / np.linalg.norm(problem.sensor_axis)
        self.set_penalty(weight, backoff)

    def set_penalty(self, weight=None, backoff=None, eps=None):
        """Penalty weight ``w``, back-off ``δ`` (cosine units; scalar or one per cone), ``ε``."""
        if weight is not None:
            self.weight = float(weight)
        if backoff is not None:
            self.backoff = np.broadcast_to(np.asarray(backoff, float), (len(self.problem.cones),)).copy()
        if eps is not None:
            self.eps = float(eps)
        self.pen = cp.pack(self.problem.cones, self.sensor, self.weight, self.backoff)

    # ----------------------------------------------------------------- H ≡ 0
    def running_cost(self, y):
        """``1 + P(q) + ε Σ φ(vᵢ)`` at ``y`` (the Lagrangian with ``λ0 = 1``)."""
        x = self.umax * y[11:14] / self.J / self.eps
        phi = x * np.tanh(x) - _log_cosh(x)
        return 1.0 + cp.penalty_value(y, self.pen) + self.eps * float(np.sum(phi))

    def full_hamiltonian(self, y):
        return self.running_cost(y) + af.hamiltonian(y, self.J, self.umax, self.mode, self.p, self.eps,
                                                     np.ones(3))

    def param_residual(self, z):
        y0, d = self.initial(z)
        u, _ = af.control(y0, self.J, self.umax, self.mode, self.p, self.eps, np.ones(3))
        f = af.ext_rhs(y0, u, self.J)
        # envelope theorem: u minimises H, so dH/dλ = ẏ_state (q̇ for λq, ω̇ for λω)
        grad = np.concatenate([f[0:4], f[4:7]]) @ d[np.r_[7:11, 11:14]]
        return np.array([self.full_hamiltonian(y0)]), grad[None, :]

    def hamiltonian_along(self, Y):
        return np.array([self.full_hamiltonian(y) for y in Y])


def _segment_paths(bvp, z, T, nodes, steps):
    """Dense record of each multiple-shooting segment from its own start."""
    M = len(nodes) + 1
    y0, _ = bvp.initial(z)
    starts = [y0] + list(nodes)
    out = []
    for k in range(M):
        Y, s_end, n_rec, _, _, status, rt, rY, *_ = bvp._run(starts[k], T / M, None, signs0=np.ones(3),
                                                             record=steps // M + 64, hmax=T / steps)
        out.append((rt[:n_rec] + k * T / M, rY[:n_rec].copy(), status == af.FLOW_OK and n_rec > 1 and
                    abs(rt[n_rec - 1] - T / M) < 1e-12 * max(1.0, T)))
    return out


def _independent_replay(bvp, starts, T):
    """Each segment re-propagated by scipy's DOP853 (a different integrator and right-hand
    side call path); the largest relative difference of the segment ends."""
    M = len(starts)
    J, um, eps, pen = bvp.J, bvp.umax, bvp.eps, bvp.pen
    s1 = np.ones(3)

    def rhs(t, y):
        u, _ = af.control(y, J, um, af.MODE_TANH, 0.0, eps, s1)
        f = af.ext_rhs(y, u, J)
        cp.penalty_rhs_into(y, pen, f)
        return f
    ends = []
    for k in range(M):
        sol = solve_ivp(rhs, (0.0, T / M), starts[k], method="DOP853", rtol=1e-11, atol=1e-12)
        ends.append(sol.y[:, -1] if sol.success else np.full(NY, np.nan))
    return ends


def solve_penalised(problem, seed, *, segments=SEGMENTS, stages=STAGES, time_budget=20.0, tols=None):
    """The penalised extremal of a cone problem near the answer ``seed`` (a ``SlewSolution``
    with dense states and costate estimates, normally collocation's): a ``SlewSolution``.

    Runs the ``(ε, w)`` stages, then moves the back-off out until the certified clearance
    of every cone is at least ``CLEARANCE_AIM`` (or ``CLEARANCE_TOL`` after
    ``MAX_BACKOFF_ROUNDS``), then verifies. ``success`` needs every check, including the
    final time no more than ``MAX_GAP`` above the seed's (``regularisation``).
    """
    t_start = time.perf_counter()
    deadline = t_start + float(time_budget)
    M = int(segments)
    if M < 2:
        raise ValueError(f"segments: the penalty route uses multiple shooting, needs ≥ 2, got {segments}")
    tols = dict(DEFAULT_TOLS, **(tols or {}))
    bvp = ConePenaltyBVP(problem, eps=stages[0][0], weight=stages[0][1])
    tau = bvp.tau
    z = costate_from_solution(bvp, seed)
    T = float(seed.tf) / tau
    nodes = nodes_from_solution(bvp, seed, M)
    nit = nfev = 0
    log = []
    reached = None

    def shoot(eps, w, backoff, z, T, nodes, final=False):
        nonlocal nit, nfev
        bvp.set_penalty(weight=w, eps=eps, backoff=backoff)
        # the stages are stepping stones: integrated loosely; the answer at the verified
        # tolerance (the stiff penalty puts the residual's noise floor near 1e-9 there)
        bvp.rtol, bvp.atol = (ANSWER_RTOL, ANSWER_RTOL * 0.1) if final else (PATH_RTOL, PATH_RTOL * 0.1)
        r = newton_shoot(bvp, z, T, segments=M, nodes0=nodes, tol=3e-9 if final else 1e-7, max_iter=40,
                         max_step=0.5, linear_solver="lu", deadline=deadline)
        nit += r.nit
        nfev += r.nfev
        outcome = "ok" if r.success else "cut by the time budget" if r.status == STATUS_DEADLINE else "failed"
        log.append(f"ε={eps:g} w={w:g}: {outcome} ({r.nit} it)")
        return r

    backoff = np.zeros(len(problem.cones))
    prev = None
    for eps, w in stages:
        if time.perf_counter() > deadline:
            log.append("the time budget ran out")
            break
        r = shoot(eps, w, backoff, z, T, nodes)
        if not r.success and prev is not None:
            # one intermediate stage (geometric mean) before giving up on this one
            mid = (math.sqrt(prev[0] * eps), math.sqrt(prev[1] * w))
            rm = shoot(*mid, backoff, z, T, nodes)
            if rm.success:
                z, T, nodes, reached = rm.p, rm.T, rm.nodes, mid
                r = shoot(eps, w, backoff, z, T, nodes)
        if not r.success:
            break
        z, T, nodes, reached, prev = r.p, r.T, r.nodes, (eps, w), (eps, w)
    def failed(status, text):
        lead = f"{STATUS_MESSAGES[status]} " if status == STATUS_BUDGET_EXHAUSTED else ""
        return SlewSolution(False, status, f"{lead}Penalty homotopy: {text}", nit, nfev, time.perf_counter() - t_start,
                            method="indirect", route="cone penalty homotopy: " + "; ".join(log), guess="collocation",
                            problem=problem)

    def out_of_time(where):
        # a stage's iterate is not an answer until the final polish and the verification have
        # run: none after the deadline (the certified clearance alone takes 0.05-0.1 s)
        return failed(STATUS_BUDGET_EXHAUSTED, f"the time budget ran out {where} (stages: {'; '.join(log)}).")

    if reached is None:
        status = STATUS_BUDGET_EXHAUSTED if time.perf_counter() > deadline else STATUS_NOT_CONVERGED
        return failed(status, "no stage converged from the seed's costates (" + "; ".join(log) + ").")
    eps, w = reached
    sins = np.array([math.sin(c.half_angle) for c in problem.cones])
    for _ in range(MAX_BACKOFF_ROUNDS):
        if time.perf_counter() > deadline:
            break
        clear = _clearances(bvp, problem, z, T, nodes)
        if clear is None:
            break
        cert = np.array([c[1] for c in clear])
        # a path that starts or ends on a cone boundary (R4) cannot clear it by more there
        aim = np.minimum(CLEARANCE_AIM, np.array([min(c[2], c[3]) for c in clear]))
        short = cert < aim - ENDPOINT_SLACK
        if not np.any(short) or time.perf_counter() > deadline:
            break
        need = np.where(short, aim + CLEARANCE_AIM - cert, 0.0)
        for frac in (1.0, 0.5, 0.25):   # a large move of the boundary arc may need smaller steps
            trial = backoff + frac * need * sins
            r = shoot(eps, w, trial, z, T, nodes)
            if r.success:
                break
        if not r.success:
            bvp.set_penalty(backoff=backoff)
            break
        backoff, z, T, nodes = trial, r.p, r.T, r.nodes
    if time.perf_counter() > deadline:
        return out_of_time(f"after the stage ε={eps:g}, w={w:g}, before the final polish")
    r = shoot(eps, w, backoff, z, T, nodes, final=True)
    if r.success:
        z, T, nodes = r.p, r.T, r.nodes
    elif r.status == STATUS_DEADLINE:
        return out_of_time("in the final polish")
    else:
        log.append("final polish failed: the answer is the last stage's")
    if time.perf_counter() > deadline:
        return out_of_time("before the verification")
    sol = _verified_solution(bvp, problem, seed, z, T, nodes, tols)
    sol.nit, sol.nfev = nit, nfev
    back_rad = [f"{b / s:.3g}" for b, s in zip(backoff, sins)]
    sol.route = (f"cone penalty homotopy from {seed.method} costates ({'; '.join(log)}); ε={eps:g}, w={w:g}, "
                 f"back-off {', '.join(back_rad)} rad; {M} segments")
    sol.wall_time = time.perf_counter() - t_start
    return sol


def _clearances(bvp, problem, z, T, nodes, steps=CERTIFY_STEPS):
    paths = _segment_paths(bvp, z, T, nodes, steps)
    if not all(p[2] for p in paths):
        return None
    t = np.concatenate([p[0] for p in paths]) * bvp.tau
    Y = np.vstack([p[1] for p in paths])
    return cone_clearances(problem, t, Y[:, 0:4], Y[:, 4:7] / bvp.tau)


def _verified_solution(bvp, problem, seed, z, T, nodes, tols):
    tau = bvp.tau
    umax0 = float(problem.torque_max.max())
    M = len(nodes) + 1
    paths = _segment_paths(bvp, z, T, nodes, CERTIFY_STEPS)
    checks = {}
    if not all(p[2] for p in paths):
        checks["propagation"] = make_check(1.0, 0.0, False)
        return SlewSolution(False, STATUS_VERIFICATION_FAILED, "verification failed: propagation", 0, 0, 0.0,
                            method="indirect", guess="collocation", verification=checks, problem=problem)
    y0, _ = bvp.initial(z)
    starts = [y0] + list(nodes)
    ends = [p[1][-1] for p in paths]
    # continuity of the multiple-shooting nodes
    scale = np.maximum(np.abs(np.array(nodes)), 1.0) if nodes else np.ones((0, NY))
    defect = max([float(np.max(np.abs(ends[k] - nodes[k]) / scale[k])) for k in range(M - 1)] or [0.0])
    checks["node_continuity"] = make_check(defect, 1e-7, defect <= 1e-7)
    checks.update(boundary_checks(bvp, ends[-1], tols))
    t_nd = np.concatenate([p[0] for p in paths])
    Y = np.vstack([p[1] for p in paths])
    # H ≡ 0 with λ0 = 1: the free-final-time condition, held along the whole path
    Hs = bvp.hamiltonian_along(Y[::8])
    hdev = float(np.max(np.abs(Hs)))
    checks["hamiltonian_drift"] = make_check(hdev, tols["hamiltonian_drift"], hdev <= tols["hamiltonian_drift"])
    rep_ends = _independent_replay(bvp, starts, T)
    rep = max(float(np.max(np.abs(rep_ends[k] - ends[k]) / np.maximum(np.abs(ends[k]), 1.0))) for k in range(M))
    rep = rep if rep == rep else math.inf
    checks["replay"] = make_check(rep, 1e-7, rep <= 1e-7)
    t = t_nd * tau
    omega = Y[:, 4:7] / tau
    per = cone_clearances(problem, t, Y[:, 0:4], omega)
    cert = min(c[1] for c in per)
    checks["cone_clearance"] = make_check(cert, CLEARANCE_TOL, cert >= CLEARANCE_TOL)
    checks.update(rate_limit_check(bvp, Y, tols))
    # what a user can replay without the penalised flow: the returned torque samples (linear
    # in between, as control(t)), integrated by the environment's RK4; the smooth control is
    # only sampled, so this is looser than the trajectory's own boundary errors
    keep = slice(None, None, RETURN_EVERY)
    t_out, Y_out = t[keep], Y[keep]
    if t_out[-1] != t[-1]:
        t_out, Y_out = np.append(t_out, t[-1]), np.vstack([Y_out, Y[-1:]])
    u = af.control_batch(np.ascontiguousarray(Y_out), bvp.J, bvp.umax, bvp.mode, bvp.p, bvp.eps,
                         np.ones((Y_out.shape[0], 3))) * umax0
    # the returned control exactly as ``control(t)`` gives it (linear between the samples: the
    # quadratic through the two ends and their mean), RK4 with 4 steps an interval; its path is
    # what a user flies, so its clearance is certified too (where the penalised flow's own path
    # cleared a cone, certified +2.5e-7 rad, this one entered it by 1.7e-6: runs/s31/replay, the audit)
    t_fl, X_fl, _ = replay_quadratic_control(np.concatenate([problem.q0, problem.omega0]), np.ascontiguousarray(t_out),
                                             np.ascontiguousarray(u), np.ascontiguousarray(0.5 * (u[:-1] + u[1:])),
                                             np.array(problem.torque_max, float), math.inf,
                                             np.array(problem.inertia, float), 2, 2)
    x = X_fl[-1]
    crep = max(bvp.attitude_error(x[0:4] / np.linalg.norm(x[0:4])), float(np.linalg.norm(x[4:7] * tau - bvp.wf)))
    crep = crep if crep == crep else math.inf
    checks["control_replay"] = make_check(crep, CONTROL_REPLAY_TOL, crep <= CONTROL_REPLAY_TOL)
    cert_fl = certified_min_margin(problem, t_fl, X_fl[:, 0:4], X_fl[:, 4:7])[1]
    cert_fl = cert_fl if cert_fl == cert_fl else -math.inf
    checks["control_clearance"] = make_check(cert_fl, CLEARANCE_TOL, cert_fl >= CLEARANCE_TOL)
    gap = (T * tau - float(seed.tf)) / float(seed.tf)
    # the multiple-shooting nodes (problem units): the 1e-8 boundary errors hold for the
    # trajectory through them; a single propagation from costate0 amplifies 1e-9 into ~1e-6
    nodes_y = [np.concatenate([y[0:4], y[4:7] / tau, tau * y[7:11], tau ** 2 * y[11:14]]).tolist()
               for y in starts]
    checks["regularisation"] = dict(make_check(gap, MAX_GAP, gap <= MAX_GAP), eps=bvp.eps, weight=bvp.weight,
                                    backoff=bvp.backoff.tolist(), seed_tf=float(seed.tf),
                                    nodes_t=[k * T * tau / M for k in range(M)], nodes_y=nodes_y)
    text = failure_text(checks)
    costate = np.hstack([tau * Y_out[:, 7:11], tau ** 2 * Y_out[:, 11:14]])

    def control(tq):
        tq = np.asarray(tq, dtype=float)
        return np.stack([np.interp(tq, t_out, u[:, i]) for i in range(3)], axis=-1)
    tf = T * tau
    if text:
        status, msg = STATUS_VERIFICATION_FAILED, f"Penalised extremal found but {text}."
    else:
        status = STATUS_SUCCESS
        msg = (f"Verified penalised extremal (ε = {bvp.eps:g}, w = {bvp.weight:g}): it keeps out of every cone at "
               f"every instant, flown by its returned control too (certified clearance {min(cert, cert_fl):.2g} rad, "
               f"tolerance {CLEARANCE_TOL:g}), and its tf is {100 * gap:+.3f} % from the collocation answer; "
               f"an approximation of the constrained optimum, not its exact extremal.")
    return SlewSolution(
        not text, status, msg, 0, 0, 0.0, tf=tf, tf_tol=max(abs(gap) * tf, float(seed.tf_tol) if seed.tf_tol == seed.tf_tol
                                                         else 0.0),
        costate0=np.concatenate([tau * y0[7:11], tau ** 2 * y0[11:14]]), switch_times=[np.zeros(0)] * 3,
        u_first=np.sign(u[0]), t=t_out, q=Y_out[:, 0:4].copy(), omega=Y_out[:, 4:7] / tau, u=u, costate=costate,
        method="indirect", guess=f"{seed.method} costates", n_candidates=1, candidates_tf=[tf], verification=checks,
        problem=problem, _control=control)


def costate_from_solution(bvp, sol):
    """``z`` (``μ``, ``λω(0)``; nondimensional, ``λ0 = 1``) from a ``SlewSolution``'s costate0."""
    lq = np.asarray(sol.costate0[0:4], float) / bvp.tau
    lw = np.asarray(sol.costate0[4:7], float) / bvp.tau ** 2
    q0c = bvp.q0 * np.array([1.0, -1.0, -1.0, -1.0])
    mu = qmul(q0c, lq)[1:4]
    return np.concatenate([mu, lw])


def nodes_from_solution(bvp, sol, M):
    """Multiple-shooting nodes (augmented states at ``k T / M``) from a dense solution."""
    t = np.asarray(sol.t, float) / bvp.tau
    T = float(sol.tf) / bvp.tau
    cols = [sol.q, sol.omega * bvp.tau, sol.costate[:, 0:4] / bvp.tau, sol.costate[:, 4:7] / bvp.tau ** 2]
    Y = np.hstack(cols)
    nodes = []
    for k in range(1, M):
        tk = k * T / M
        y = np.array([np.interp(tk, t, Y[:, i]) for i in range(NY)])
        y[0:4] /= np.linalg.norm(y[0:4])
        nodes.append(y)
    return nodes
