"""Initial trajectories for ``solvers.collocation``: the eigenaxis slew and its perturbations,
detours around the cones it crosses, and a given guess or solution sampled on the mesh."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List

import numpy as np

from slew_env import SlewProblem
from slew_env.core.quaternion import qfrom_two_vectors, qmul, qrotate
from .clearance import margins
from .guesses import Guess
from .solution import SlewSolution
from . import collocation_nlp


# ----------------------------------------------------------------------------- helpers
def _qexp_body(q0, n, theta):
    """``q0 ⊗ [cos θ/2, n sin θ/2]`` for arrays of ``theta``."""
    q0 = np.array(q0, dtype=float)    # writable, whatever the caller's: one kernel signature
    th = np.asarray(theta, dtype=float)
    d = np.stack([np.cos(0.5 * th), n[0] * np.sin(0.5 * th), n[1] * np.sin(0.5 * th),
                  n[2] * np.sin(0.5 * th)], axis=-1)
    return np.array([qmul(q0, di) for di in d.reshape(-1, 4)]).reshape(d.shape)


# ----------------------------------------------------------------------------- guesses
@dataclass
class TrajGuess:
    """A guess as functions of time (nondimensional); sampled onto any grid."""
    T: float
    t: np.ndarray
    q: np.ndarray
    w: np.ndarray
    u: np.ndarray
    source: str

    def sample(self, nlp: collocation_nlp.NLP):
        tk, tm = nlp.times(1.0)
        tk = tk * self.T
        tm = tm * self.T

        def interp(arr, tt):
            return np.stack([np.interp(tt, self.t, arr[:, i]) for i in range(arr.shape[1])], axis=-1)
        X = np.hstack([interp(self.q, tk), interp(self.w, tk)])
        Xm = np.hstack([interp(self.q, tm), interp(self.w, tm)])
        X[0] = nlp.sc.x0
        U = interp(self.u, tk)
        Um = interp(self.u, tm)
        return nlp.pack(self.T, X, Xm, U, Um)


def _trapezoid_path(sc: collocation_nlp.Scaled, q_start, q_end, source):
    """Rest-to-rest rotation about the eigenaxis with the largest constant acceleration the
    bound allows at rest (gyroscopic torque ignored), coasting at the rate limit if any."""
    from .guesses import eigenaxis_acceleration
    d = np.asarray(qmul(np.array([q_start[0], -q_start[1], -q_start[2], -q_start[3]]), q_end))
    if d[0] < 0:
        d = -d
    v = float(np.linalg.norm(d[1:]))
    n = d[1:] / v if v > 1e-15 else np.array([1.0, 0.0, 0.0])
    th = 2.0 * math.atan2(v, d[0])
    acc = eigenaxis_acceleration(sc.J, sc.U, sc.p, n)
    wmax = math.inf if sc.rate is None else float(np.min(sc.rate[np.abs(n) > 1e-12] / np.abs(n[np.abs(n) > 1e-12])))
    if sc.rate_norm is not None:     # (n is a unit vector: the rate's norm is the angle's rate)
        wmax = min(wmax, sc.rate_norm)
    t1 = math.sqrt(max(th, 1e-12) / acc)
    if acc * t1 > wmax:      # trapezoid: accelerate to wmax, coast, decelerate
        t1 = wmax / acc
        tc = (th - acc * t1 * t1) / wmax
    else:
        tc = 0.0
    T = 2 * t1 + tc
    t = np.linspace(0.0, T, 201)
    a1, a2 = t1, t1 + tc
    rate = np.where(t < a1, acc * t, np.where(t < a2, acc * t1, np.maximum(0.0, acc * (T - t))))
    theta = np.where(t < a1, 0.5 * acc * t * t,
                     np.where(t < a2, 0.5 * acc * t1 * t1 + acc * t1 * (t - a1),
                              th - 0.5 * acc * np.maximum(0.0, T - t) ** 2))
    ua = np.where(t < a1, acc, np.where(t < a2, 0.0, -acc))
    q = _qexp_body(q_start, n, theta)
    return TrajGuess(T, t, q, rate[:, None] * n[None, :], ua[:, None] * (sc.J * n)[None, :], source)


def _eigen_path(sc: collocation_nlp.Scaled, q_start, q_end, source):
    """Rest-to-rest eigenaxis slew q_start → q_end within the bounds, nondimensional: the
    fastest one (``solvers.eigenaxis_slew``) for a per-axis bound; for a p-norm bound,
    whose ``eigenaxis_slew`` is slow (a scalar minimisation per grid point), the
    constant-acceleration trapezoid."""
    from .eigenaxis import eigenaxis_slew
    prob = sc.prob
    if not math.isinf(sc.p):
        return _trapezoid_path(sc, q_start, q_end, source)
    sub = SlewProblem(prob.inertia, prob.torque_max, prob.torque_norm, q0=q_start, qf=q_end,
                      rate_max=prob.rate_max, rate_norm_max=prob.rate_norm_max)
    es = eigenaxis_slew(sub, n_grid=400)
    if es.tf <= 0.0:
        t = np.array([0.0, 1.0])
        q = np.array([q_start, q_start])
        return TrajGuess(1.0, t, q, np.zeros((2, 3)), np.zeros((2, 3)), source)
    t = es.t / sc.tau
    q = _qexp_body(q_start, es.axis, es.theta)
    w = es.rate[:, None] * es.axis[None, :] * sc.tau
    u = es.u / sc.umax0
    return TrajGuess(float(t[-1]), t, q, w, u, source)


def _concat(a: TrajGuess, b: TrajGuess, source):
    t = np.concatenate([a.t, a.T + b.t[1:]])
    return TrajGuess(a.T + b.T, t, np.vstack([a.q, b.q[1:]]), np.vstack([a.w, b.w[1:]]),
                     np.vstack([a.u, b.u[1:]]), source)


def _with_rates(sc: collocation_nlp.Scaled, g: TrajGuess):
    """Blend the boundary rates into a rest-to-rest path guess (a guess only)."""
    if not (np.any(sc.x0[4:7]) or np.any(sc.wf)):
        return g
    T = g.T
    dw = sc.wf - sc.x0[4:7]
    # time to change the rate at the available acceleration, as a floor on T
    T_rate = float(np.max(np.abs(dw) * sc.J / sc.U))
    if T < T_rate:
        scale = T_rate / max(T, 1e-12)
        g = TrajGuess(T_rate, g.t * scale, g.q, g.w / scale, g.u / scale ** 2, g.source)
        T = T_rate
    s = g.t / T
    w = g.w + (1.0 - s)[:, None] * sc.x0[4:7][None, :] + s[:, None] * sc.wf[None, :]
    u = g.u + (dw * sc.J / T)[None, :]
    return TrajGuess(T, g.t, g.q, w, np.clip(u, -sc.U, sc.U), g.source + "+rates")


def _final_attitude_guess(prob, q_from):
    """Target attitude for a guess: ``qf``, or the shortest sensor rotation from ``q_from``."""
    if prob.qf is not None:
        qf = prob.qf.copy()
        if float(qf @ q_from) < 0:
            qf = -qf
        return qf
    s = np.asarray(qrotate(q_from, prob.sensor_axis))
    r = np.asarray(qfrom_two_vectors(s, prob.sensor_target))
    return np.asarray(qmul(r, q_from))


def _path_min_margin(prob, q):
    return float(margins(prob, q).min()) if prob.cones else math.inf


def _detour_guesses(sc: collocation_nlp.Scaled, straight: TrajGuess, clearance=math.radians(5.0)):
    """Around the worst-crossed cone, through a way-point just outside it (both sides)."""
    prob = sc.prob
    d = np.array([qrotate(qi / np.linalg.norm(qi), prob.sensor_axis) for qi in straight.q])
    worst, wk, wc = math.inf, 0, None
    for c in prob.cones:
        ang = np.arccos(np.clip(d @ c.axis, -1, 1)) - c.half_angle
        k = int(np.argmin(ang))
        if ang[k] < worst:
            worst, wk, wc = float(ang[k]), k, c
    if wc is None or worst >= 0.0:
        return []
    a = wc.axis
    s0, s1 = prob.start_direction, prob.target_direction
    # the deepest point of the straight path, pushed away from the cone axis (or, if it
    # passes through the axis, sideways), and the opposite side of the cone
    pm = d[wk] - (d[wk] @ a) * a
    if np.linalg.norm(pm) < 1e-9:
        pm = np.cross(a, s1 - s0)
    pm /= np.linalg.norm(pm)
    out = []
    for side in (1.0, -1.0):
        direction = pm if side > 0 else -pm
        beta = wc.half_angle + clearance
        wpt = math.cos(beta) * a + math.sin(beta) * direction
        wpt /= np.linalg.norm(wpt)
        qa = np.asarray(qmul(qfrom_two_vectors(s0, wpt), prob.q0))
        leg1 = _eigen_path(sc, prob.q0, qa, "detour")
        qb = _final_attitude_guess(prob, qa)
        leg2 = _eigen_path(sc, qa, qb, "detour")
        out.append(_concat(leg1, leg2, f"detour({'+' if side > 0 else '-'})"))
    return out


def propagate_guess(sc: collocation_nlp.Scaled, guess: Guess, n=400):
    """A ``solvers.Guess`` as a trajectory: bang-bang from its switch times, else the
    extremal of its costates (PMP control law), by fixed-step RK4 (compiled:
    ``core.control_replay.guess_path``)."""
    from .core import attitude_flow as af
    from .core.control_replay import guess_path
    T = guess.tf / sc.tau
    t = np.linspace(0.0, T, n + 1)
    by_switches = guess.switch_times is not None and guess.u_first is not None
    if by_switches:
        sw = [np.asarray(s, dtype=float).ravel() / sc.tau for s in guess.switch_times]
        sw_t = np.concatenate(sw) if sum(x.size for x in sw) else np.zeros(0)
        sw_axis = np.concatenate([np.full(x.size, i, dtype=np.int64) for i, x in enumerate(sw)])
        u_first = np.asarray(guess.u_first, dtype=float)
        u0 = np.where(u_first == 0, 1.0, u_first)
        src = "guess(switch times)"
    else:
        sw_t, sw_axis, u0 = np.zeros(0), np.zeros(0, dtype=np.int64), np.ones(3)
        src = "guess(costates)"
    mode = af.MODE_BANG if math.isinf(sc.p) else af.MODE_PNORM
    pp = 0.0 if math.isinf(sc.p) else float(sc.p)
    y = np.concatenate([sc.x0, guess.costate0[:4] / sc.tau, guess.costate0[4:] / sc.tau ** 2]).astype(float)
    Y, Uu = guess_path(y, t, np.asarray(sc.J, dtype=float), np.asarray(sc.U, dtype=float), mode, pp, sw_t,
                       sw_axis, u0, bool(by_switches))
    return TrajGuess(T, t, Y[:, 0:4], Y[:, 4:7], Uu, src)


def _solution_guess(sc: collocation_nlp.Scaled, sol: SlewSolution):
    if sol.t is None or len(sol.t) < 2 or not math.isfinite(sol.tf):
        raise ValueError("guess: the given SlewSolution has no trajectory to start from")
    t = np.asarray(sol.t) / sc.tau
    return TrajGuess(float(sol.tf) / sc.tau, t, np.asarray(sol.q), np.asarray(sol.omega) * sc.tau,
                     np.asarray(sol.u) / sc.umax0, f"solution({sol.method or 'given'})")


def _perturbed(sc: collocation_nlp.Scaled, g: TrajGuess, rng, amp=0.2):
    """``g`` with a smooth random torque and rate perturbation (breaks the symmetry of an
    eigenaxis guess about a principal axis, which IPOPT would otherwise never leave)."""
    s = g.t / g.T
    du = np.zeros_like(g.u)
    for i in range(3):
        c = rng.normal(size=3)
        du[:, i] = sum(c[j] * np.sin((j + 1) * np.pi * s) for j in range(3))
    du *= amp * sc.U / max(1.0, float(np.max(np.abs(du))))
    # rates: the integral of the torque perturbation, brought back to zero at the end
    dt = np.diff(g.t)
    dw = np.concatenate([np.zeros((1, 3)), np.cumsum(0.5 * (du[1:] + du[:-1]) * dt[:, None], axis=0)]) / sc.J
    dw -= s[:, None] * dw[-1][None, :]
    u = g.u + du
    if math.isinf(sc.p):
        u = np.clip(u, -sc.U, sc.U)
    return TrajGuess(g.T, g.t, g.q, g.w + dw, u, g.source + "+perturbed")


def initial_guesses(sc: collocation_nlp.Scaled, guess=None, n_starts=None, seed=0, extra_starts=()) -> List[TrajGuess]:
    """The starts: the given guess or the eigenaxis guess, seeded perturbations of it up to
    ``n_starts`` (default 4 without a guess, 1 with one), then cone detours when the
    eigenaxis path crosses a cone, then ``extra_starts`` (``solvers.Guess``es, propagated)."""
    prob = sc.prob
    if isinstance(guess, SlewSolution):
        base, n_default = _solution_guess(sc, guess), 1
    elif isinstance(guess, Guess):
        base, n_default = propagate_guess(sc, guess), 1
    else:
        qf = _final_attitude_guess(prob, prob.q0)
        base, n_default = _with_rates(sc, _eigen_path(sc, prob.q0, qf, "eigenaxis")), 4
    n = n_default if n_starts is None else int(n_starts)
    out = [base]
    rng = np.random.default_rng(seed)
    amps = (0.2, 0.5)
    while len(out) < n:
        out.append(_perturbed(sc, base, rng, amps[(len(out) - 1) % 2]))
    if guess is None and prob.cones and _path_min_margin(prob, base.q) < 0.0:
        out += [_with_rates(sc, g) for g in _detour_guesses(sc, base)]
        if _through_a_cone_axis(prob, base.q) and len(out) > 1:
            # the straight path runs (nearly) through a cone's axis: which way round is a
            # tie that holds IPOPT (measured: 200+ iterations without convergence); the
            # perturbed copies and the detours break it
            out = out[1:]
    for g in extra_starts or ():
        try:
            tg = propagate_guess(sc, g)
        except (ValueError, FloatingPointError, ArithmeticError):
            continue        # a start that cannot be propagated is no start (the others run)
        if not (np.all(np.isfinite(tg.q)) and np.all(np.isfinite(tg.w)) and np.isfinite(tg.T) and tg.T > 0):
            continue
        tg.source = f"{g.source} (propagated)"
        out.append(tg)
    return out


def _through_a_cone_axis(prob, q):
    d = np.array([qrotate(qi / np.linalg.norm(qi), prob.sensor_axis) for qi in q])
    for c in prob.cones:
        if float(np.min(np.arccos(np.clip(d @ c.axis, -1, 1)))) < 0.25 * c.half_angle:
            return True
    return False
