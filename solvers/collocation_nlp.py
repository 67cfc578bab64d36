"""The Hermite–Simpson NLP of ``solvers.collocation`` (its module docstring has the transcription):
one CasADi/IPOPT template a structure (intervals, target kind, cones, norm, options), cached,
and bound to a problem and a mesh by its parameters and bounds."""

from __future__ import annotations

import copy
import math
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Optional

import numpy as np

from slew_env import SlewProblem
from slew_env.core.cones import perpendicular_basis

# IPOPT statuses taken as converged: "acceptable" is a solve that met the (looser) acceptable
# tolerances, with constraints to 1e-6; the independent replay then decides
CONVERGED_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
_P_SMOOTH_DELTA = 1e-10


@dataclass
class Scaled:
    """The problem in nondimensional units."""
    prob: SlewProblem
    tau: float
    umax0: float
    J: np.ndarray
    U: np.ndarray
    x0: np.ndarray
    wf: np.ndarray
    rate: Optional[np.ndarray]
    p: float
    rate_norm: Optional[float] = None     # the limit on the rate's norm (nondimensional)

    @classmethod
    def of(cls, prob):
        Jmax = float(prob.inertia.max())
        umax0 = float(prob.torque_max.max())
        tau = math.sqrt(Jmax / umax0)
        rate = None if prob.rate_max is None else prob.rate_max * tau
        rate_norm = None if prob.rate_norm_max is None else prob.rate_norm_max * tau
        return cls(prob, tau, umax0, prob.inertia / Jmax, prob.torque_max / umax0,
                   np.concatenate([prob.q0, prob.omega0 * tau]), prob.omegaf * tau, rate, prob.torque_norm,
                   rate_norm)

    def rate_ratio(self, w) -> float:
        """The largest ``|ω_i| / rate_i`` and ``‖ω‖ / rate_norm`` over the rows of the
        nondimensional rates ``w`` (``SlewProblem.rate_limit_ratio`` in these units); 0 without
        a limit."""
        w = np.asarray(w, dtype=float).reshape(-1, 3)
        worst = 0.0
        if not np.all(np.isfinite(w)):
            return math.inf        # (max(0.0, nan) is 0.0: a NaN rate would have passed the check)
        if self.rate is not None:
            worst = float(np.max(np.max(np.abs(w), axis=0) / self.rate))
        if self.rate_norm is not None:
            worst = max(worst, float(np.max(np.linalg.norm(w, axis=1))) / self.rate_norm)
        return worst

    @property
    def rate_kind(self) -> tuple:
        """``(per-axis limit, norm limit)``: which rate constraints the NLP has (part of its structure)."""
        return (self.rate is not None, self.rate_norm is not None)


# ----------------------------------------------------------------------------- the NLP
# Built NLPs are cached by structure (interval count, target kind, number of cones, norm,
# IPOPT options): inertia, bounds, targets, cones and the mesh are NLP parameters or
# variable / constraint bounds, so one build serves every problem of the same shape.
_CACHE: "OrderedDict[tuple, _Template]" = OrderedDict()
_CACHE_SIZE = 32   # (cone problems alone use 3 grids × 1-3 cones, and a full-attitude solve 2 more)


class _Deadline:
    """IPOPT iteration callback that stops the solve at a wall-clock deadline."""

    def __init__(self, ca, nx, ng, npar):
        deadline = self

        class CB(ca.Callback):
            def __init__(self):
                ca.Callback.__init__(self)
                self.construct("colloc_deadline", {})

            def get_n_in(self):
                return ca.nlpsol_n_out()

            def get_n_out(self):
                return 1

            def get_name_in(self, i):
                return ca.nlpsol_out(i)

            def get_name_out(self, i):
                return "ret"

            def get_sparsity_in(self, i):
                n = ca.nlpsol_out(i)
                if n == "f":
                    return ca.Sparsity.scalar()
                if n in ("x", "lam_x"):
                    return ca.Sparsity.dense(nx)
                if n in ("g", "lam_g"):
                    return ca.Sparsity.dense(ng)
                return ca.Sparsity.dense(npar)

            def eval(self, arg):
                return [1 if time.perf_counter() > deadline.at else 0]
        self.at = math.inf
        self.cb = CB()


class _Template:
    """Separated Hermite–Simpson NLP of one structure, with its IPOPT solver."""

    def __init__(self, N, pointing, n_cones, p, rate, tol, max_iter, verbose):
        import casadi as ca
        self.N, self.pointing, self.n_cones, self.p = N, pointing, n_cones, p
        SX = ca.SX
        # ---- parameters
        nt = 9 if pointing else 4
        P = SX.sym("P", 3 + 3 + nt + 3 + 4 * n_cones + 1 + N + 1)
        o = 0
        Jp = P[o:o + 3]; o += 3
        Up = P[o:o + 3]; o += 3
        tdat = P[o:o + nt]; o += nt
        sb = P[o:o + 3]; o += 3
        cone_p = [P[o + 4 * c:o + 4 * c + 4] for c in range(n_cones)]; o += 4 * n_cones
        delta = P[o]; o += 1
        mesh = P[o:o + N]; o += N
        rnorm = P[o]; o += 1          # the limit on the rate's norm (used with one)
        self.n_par = int(P.shape[0])
        self.i_par = dict(J=0, U=3, tdat=6, sb=6 + nt, cones=6 + nt + 3, delta=6 + nt + 3 + 4 * n_cones,
                          mesh=6 + nt + 3 + 4 * n_cones + 1, rnorm=6 + nt + 3 + 4 * n_cones + 1 + N)
        # ---- dynamics
        x = SX.sym("x", 7)
        u = SX.sym("u", 3)
        J = SX.sym("J", 3)
        q0, q1, q2, q3 = x[0], x[1], x[2], x[3]
        w0, w1, w2 = x[4], x[5], x[6]
        fx = ca.vertcat(0.5 * (-q1 * w0 - q2 * w1 - q3 * w2),
                        0.5 * (q0 * w0 + q2 * w2 - q3 * w1),
                        0.5 * (q0 * w1 - q1 * w2 + q3 * w0),
                        0.5 * (q0 * w2 + q1 * w1 - q2 * w0),
                        (u[0] - (J[2] - J[1]) * w1 * w2) / J[0],
                        (u[1] - (J[0] - J[2]) * w2 * w0) / J[1],
                        (u[2] - (J[1] - J[0]) * w0 * w1) / J[2])
        f = ca.Function("f", [x, u, J], [fx])
        # one interval: Simpson and Hermite defects
        xk, xm, xk1 = SX.sym("xk", 7), SX.sym("xm", 7), SX.sym("xk1", 7)
        uk, um, uk1 = SX.sym("uk", 3), SX.sym("um", 3), SX.sym("uk1", 3)
        h = SX.sym("h")
        fk, fm, fk1 = f(xk, uk, J), f(xm, um, J), f(xk1, uk1, J)
        simpson = xk1 - xk - h / 6.0 * (fk + 4.0 * fm + fk1)
        hermite = xm - 0.5 * (xk + xk1) - h / 8.0 * (fk - fk1)
        D = ca.Function("D", [xk, xm, xk1, uk, um, uk1, h, J], [simpson, hermite])
        nu, mu = SX.sym("nu", 7), SX.sym("mu", 7)
        Lint = ca.dot(nu, simpson) + ca.dot(mu, hermite)
        # d/dx_k and d/dx_k+1 of one interval's part of the Lagrangian (covector mapping)
        self.dL = ca.Function("dL", [xk, xm, xk1, uk, um, uk1, h, J, nu, mu],
                              [ca.gradient(Lint, xk), ca.gradient(Lint, xk1)]).map(N)
        # homogeneous sensor direction q ⊗ [0, s] ⊗ q* (degree 2 in q)
        qs = SX.sym("q", 4)
        s_ = SX.sym("s", 3)
        a0, a1, a2, a3 = qs[0], qs[1], qs[2], qs[3]
        dv = ca.vertcat(
            (a0 * a0 + a1 * a1 - a2 * a2 - a3 * a3) * s_[0] + 2 * (a1 * a2 - a0 * a3) * s_[1]
            + 2 * (a1 * a3 + a0 * a2) * s_[2],
            2 * (a1 * a2 + a0 * a3) * s_[0] + (a0 * a0 - a1 * a1 + a2 * a2 - a3 * a3) * s_[1]
            + 2 * (a2 * a3 - a0 * a1) * s_[2],
            2 * (a1 * a3 - a0 * a2) * s_[0] + 2 * (a2 * a3 + a0 * a1) * s_[1]
            + (a0 * a0 - a1 * a1 - a2 * a2 + a3 * a3) * s_[2])
        dvec = ca.Function("d", [qs, s_], [dv])
        # ---- variables
        T = SX.sym("T")
        X = SX.sym("X", 7, N + 1)
        Xm = SX.sym("Xm", 7, N)
        Uk = SX.sym("U", 3, N + 1)
        Um = SX.sym("Um", 3, N)
        w = ca.vertcat(T, ca.vec(X), ca.vec(Xm), ca.vec(Uk), ca.vec(Um))
        nx = int(w.shape[0])
        self.nx = nx
        off = 1
        self.iX = off + np.arange(7 * (N + 1)).reshape(N + 1, 7); off += 7 * (N + 1)
        self.iXm = off + np.arange(7 * N).reshape(N, 7); off += 7 * N
        self.iU = off + np.arange(3 * (N + 1)).reshape(N + 1, 3); off += 3 * (N + 1)
        self.iUm = off + np.arange(3 * N).reshape(N, 3); off += 3 * N
        # ---- constraints (layout recorded for the bounds and the multipliers)
        g = []
        self.layout = {}

        def add(name, expr):
            start = sum(int(e.numel()) for e in g)
            g.append(ca.vec(expr))
            self.layout[name] = (start, start + int(expr.numel()))
        Jrep = ca.repmat(Jp, 1, N)
        S_, H_ = D.map(N)(X[:, :N], Xm, X[:, 1:], Uk[:, :N], Um, Uk[:, 1:], T * mesh.T, Jrep)
        add("simpson", S_)
        add("hermite", H_)
        qN = X[0:4, N]
        if pointing:
            e1, e2, tgt = tdat[0:3], tdat[3:6], tdat[6:9]
            dN = dvec(qN, sb)
            add("terminal", ca.vertcat(ca.dot(e1, dN), ca.dot(e2, dN)))
            add("terminal_sign", ca.dot(tgt, dN))
        else:
            qf = tdat
            # Im(qf* ⊗ q): linear in q, zero on the line through ±qf
            r = ca.vertcat(qf[0] * qN[1] - qf[1] * qN[0] - qf[2] * qN[3] + qf[3] * qN[2],
                           qf[0] * qN[2] - qf[2] * qN[0] - qf[3] * qN[1] + qf[1] * qN[3],
                           qf[0] * qN[3] - qf[3] * qN[0] - qf[1] * qN[2] + qf[2] * qN[1])
            add("terminal", r)
        self.n_eq = self.layout["terminal"][1]
        # torque bound between samples: Bernstein middle coefficient of each interval's
        # quadratic control, b = 2 u_m - (u_k + u_k+1)/2 (see the module docstring)
        Bm = 2.0 * Um - 0.5 * (Uk[:, :N] + Uk[:, 1:])
        if math.isinf(p):
            add("bernstein", Bm)
        else:
            v = SX.sym("v", 3)
            if p == 2.0:
                ball = ca.sumsqr(v / Up)
            else:
                z = v / Up
                ball = ca.sum1((z * z + _P_SMOOTH_DELTA) ** (p / 2.0))
            Ball = ca.Function("ball", [v, P], [ball])
            allU = ca.horzcat(Uk, Um, Bm)
            add("ball", Ball.map(allU.shape[1])(allU, ca.repmat(P, 1, allU.shape[1])))
        # rate limit between samples: on each interval the scheme's rate is the cubic
        # Hermite interpolant of (ω_k, ω̇_k, ω_k+1, ω̇_k+1), whose Bernstein coefficients are
        # ω_k, ω_k + h ω̇_k / 3, ω_k+1 - h ω̇_k+1 / 3, ω_k+1: bounding the inner two (the outer
        # ones are the node values, box-bounded) keeps the whole cubic within the limit
        box, norm = rate
        if box or norm:
            hh = SX.sym("hh")
            wd_k = f(xk, uk, J)[4:7]
            wd_k1 = f(xk1, uk1, J)[4:7]
            RB = ca.Function("rb", [xk, xk1, uk, uk1, hh, J],
                             [ca.vertcat(xk[4:7] + hh / 3.0 * wd_k, xk1[4:7] - hh / 3.0 * wd_k1)])
            rb = RB.map(N)(X[:, :N], X[:, 1:], Uk[:, :N], Uk[:, 1:], T * mesh.T, Jrep)
            if box:
                add("rate_bernstein", rb)
            if norm:
                # the norm limit: a cubic lies in the convex hull of its Bernstein coefficients and
                # the ball is convex, so ‖·‖ ≤ r at the interior nodes and at both inner
                # coefficients of every interval holds along the whole cubic (the ends are fixed;
                # the midpoints lie on the cubic); in units of r, so that IPOPT's feasibility
                # tolerance is relative to the limit
                W = ca.horzcat(X[4:7, 1:N], rb[0:3, :], rb[3:6, :]) / rnorm
                add("rate_norm", ca.sum1(W * W))
        # keep-out cones at interior nodes and all midpoints (the ends are fixed by the
        # start and the target and may sit on a boundary); back-off δ ramps up over the
        # first and last two intervals
        ramp_n = np.array([min(1.0, min(k, N - k) / 2.0) for k in range(1, N)])
        ramp_m = np.array([min(1.0, min(k + 0.5, N - k - 0.5) / 2.0) for k in range(N)])
        ramp = np.concatenate([ramp_n, ramp_m])
        Qc = ca.horzcat(X[0:4, 1:N], Xm[0:4, :])
        qc = SX.sym("qc", 4)
        ax = SX.sym("ax", 3)
        al = SX.sym("al")
        rw = SX.sym("rw")
        cexpr = ca.dot(ax, dvec(qc, sb)) - ca.cos(al + rw * delta) * ca.sumsqr(qc)
        Cf = ca.Function("cone", [qc, ax, al, rw, P], [cexpr]).map(2 * N - 1)
        for c in range(n_cones):
            add(f"cone{c}", Cf(Qc, ca.repmat(cone_p[c][0:3], 1, 2 * N - 1),
                              ca.repmat(cone_p[c][3], 1, 2 * N - 1), ca.DM(ramp).T,
                              ca.repmat(P, 1, 2 * N - 1)))
        gall = ca.vertcat(*g)
        self.ng = int(gall.shape[0])
        self.geval = ca.Function("g", [w, P], [gall])
        self.deadline = _Deadline(ca, nx, self.ng, self.n_par)
        opts = {"ipopt.tol": tol, "ipopt.max_iter": int(max_iter), "ipopt.print_level": 5 if verbose else 0,
                "print_time": bool(verbose), "ipopt.sb": "yes", "ipopt.constr_viol_tol": min(1e-8, tol),
                "ipopt.mu_strategy": "adaptive", "iteration_callback": self.deadline.cb,
                # an "acceptable" stop (degenerate NLPs: singular arcs, where a slack axis's
                # torque is not unique) must still be feasible; the replay verifies it
                "ipopt.acceptable_constr_viol_tol": 1e-6}
        self.solver = ca.nlpsol("colloc", "ipopt", {"x": w, "p": P, "f": T, "g": gall}, opts)
        self._nlp_dict, self._opts = {"x": w, "p": P, "f": T, "g": gall}, opts
        self._warm = None

    @property
    def warm_solver(self):
        """The same NLP with IPOPT started from a given primal-dual point (built when first
        needed). A back-off re-solves an answer with its constraints moved by about 1e-5: the
        cold start pushes the variables off their bounds (the bang-bang torques all sit on
        them) and out of the answer's basin, into another local optimum (seen: +5.5 %)."""
        if self._warm is None:
            import casadi as ca
            opts = dict(self._opts, **{"ipopt.warm_start_init_point": "yes", "ipopt.mu_init": 1e-7,
                                       "ipopt.warm_start_bound_push": 1e-9, "ipopt.warm_start_bound_frac": 1e-9,
                                       "ipopt.warm_start_slack_bound_push": 1e-9,
                                       "ipopt.warm_start_slack_bound_frac": 1e-9,
                                       "ipopt.warm_start_mult_bound_push": 1e-9})
            self._warm = ca.nlpsol("colloc_warm", "ipopt", self._nlp_dict, opts)
        return self._warm


class NoTimeToBuild(Exception):
    """Building an NLP that is not in the cache would pass the deadline (the build, in CasADi,
    cannot be interrupted)."""


def build_estimate(N, n_cones) -> float:
    """Seconds to build an NLP of ``N`` intervals and ``n_cones`` cones, with a margin: measured
    2026-11-24, 0.055 s (N = 10) to 0.41 s (N = 120) without cones, 1.15 s with 3 cones at
    N = 120; a review's 92 builds (rate limits and p-norm bounds among them) took 0.67–1.35 times
    the formula without the margin."""
    return BUILD_MARGIN * (0.02 + 3.3e-3 * N * (1.0 + 0.6 * n_cones))


BUILD_MARGIN = 1.4


def nlp_template(N, pointing, n_cones, p, rate, tol, max_iter, verbose, deadline=math.inf) -> _Template:
    key = (N, pointing, n_cones, p, rate, tol, max_iter, verbose)
    tpl = _CACHE.get(key)
    if tpl is None:
        left, est = deadline - time.perf_counter(), build_estimate(N, n_cones)
        if left < est:
            raise NoTimeToBuild(f"building the NLP of N={N} intervals and {n_cones} cone(s), its first use in "
                                f"this process, takes about {est:.2g} s: {max(left, 0.0):.3g} s of the budget left")
        tpl = _Template(N, pointing, n_cones, p, rate, tol, max_iter, verbose)
        _CACHE[key] = tpl
        while len(_CACHE) > _CACHE_SIZE:
            _CACHE.popitem(last=False)
    else:
        _CACHE.move_to_end(key)
    return tpl


@dataclass
class Run:
    T: float
    w: np.ndarray
    lam_g: np.ndarray
    status: str
    success: bool
    nit: int
    nfev: int
    nlp: "NLP"
    source: str
    delta: float = 0.0
    lam_x: Optional[np.ndarray] = None


class NLP:
    """A template bound to one problem and mesh: parameters and bounds."""

    def __init__(self, sc: Scaled, mesh, tol, max_iter, verbose, deadline=math.inf):
        prob = sc.prob
        N = int(mesh.shape[0])
        self.sc, self.N, self.mesh = sc, N, np.asarray(mesh, float)
        tpl = nlp_template(N, prob.is_pointing, len(prob.cones), float(sc.p), sc.rate_kind, float(tol),
                           int(max_iter), bool(verbose), deadline)
        self.tpl = tpl
        self.nx = tpl.nx
        self.iX, self.iXm, self.iU, self.iUm = tpl.iX, tpl.iXm, tpl.iU, tpl.iUm
        # ---- parameters
        P = np.zeros(tpl.n_par)
        ip = tpl.i_par
        P[ip["J"]:ip["J"] + 3] = sc.J
        P[ip["U"]:ip["U"] + 3] = sc.U
        if prob.is_pointing:
            e1, e2 = perpendicular_basis(np.asarray(prob.sensor_target, float))
            P[ip["tdat"]:ip["tdat"] + 9] = np.concatenate([e1, e2, prob.sensor_target])
        else:
            P[ip["tdat"]:ip["tdat"] + 4] = prob.qf
        P[ip["sb"]:ip["sb"] + 3] = prob.sensor_axis
        for c, cone in enumerate(prob.cones):
            P[ip["cones"] + 4 * c:ip["cones"] + 4 * c + 3] = cone.axis
            P[ip["cones"] + 4 * c + 3] = cone.half_angle
        P[ip["mesh"]:ip["mesh"] + N] = self.mesh
        P[ip["rnorm"]] = 1.0 if sc.rate_norm is None else sc.rate_norm
        self.P = P
        # ---- bounds
        lbx = np.full(tpl.nx, -np.inf)
        ubx = np.full(tpl.nx, np.inf)
        lbx[0] = 1e-6
        for I in (self.iX, self.iXm):
            lbx[I[:, 0:4]] = -1.5
            ubx[I[:, 0:4]] = 1.5
            if sc.rate is not None:
                lbx[I[:, 4:7]] = -sc.rate
                ubx[I[:, 4:7]] = sc.rate
        # p-norm: the ball constraint bounds the controls; the boxes just keep them finite
        ub_u = sc.U if math.isinf(sc.p) else 1.01 * sc.U
        for I in (self.iU, self.iUm):
            lbx[I] = -ub_u
            ubx[I] = ub_u
        lbx[self.iX[0]] = sc.x0
        ubx[self.iX[0]] = sc.x0
        lbx[self.iX[N, 4:7]] = sc.wf
        ubx[self.iX[N, 4:7]] = sc.wf
        self.lbx, self.ubx = lbx, ubx
        lbg = np.full(tpl.ng, -np.inf)
        ubg = np.zeros(tpl.ng)
        lay = tpl.layout
        for name in ("simpson", "hermite", "terminal"):
            a, b = lay[name]
            lbg[a:b] = 0.0
        if "terminal_sign" in lay:
            a, b = lay["terminal_sign"]
            lbg[a:b] = 0.0
            ubg[a:b] = np.inf
        if "bernstein" in lay:
            a, b = lay["bernstein"]
            lbg[a:b] = -np.tile(sc.U, N)
            ubg[a:b] = np.tile(sc.U, N)
        if "rate_bernstein" in lay:
            a, b = lay["rate_bernstein"]
            lbg[a:b] = -np.tile(sc.rate, 2 * N)
            ubg[a:b] = np.tile(sc.rate, 2 * N)
        if "ball" in lay:
            a, b = lay["ball"]
            ubg[a:b] = 1.0
        if "rate_norm" in lay:
            a, b = lay["rate_norm"]
            ubg[a:b] = 1.0
        self.lbg, self.ubg = lbg, ubg
        a, b = lay["simpson"]
        self.ig_simpson = np.arange(a, b).reshape(N, 7)
        a, b = lay["hermite"]
        self.ig_hermite = np.arange(a, b).reshape(N, 7)
        self.n_eq = tpl.n_eq

    rate_scale = 1.0     # the rate limit of the NLP, relative to the problem's (back-off)

    def with_rate_scale(self, scale) -> "NLP":
        """This NLP with the rate limit scaled by ``scale`` (< 1: a back-off)."""
        other = copy.copy(self)
        f = scale / self.rate_scale
        other.lbx, other.ubx = self.lbx.copy(), self.ubx.copy()
        other.lbg, other.ubg = self.lbg.copy(), self.ubg.copy()
        for I in (self.iX, self.iXm):
            w = I[:, 4:7]
            # the fixed start and end rates (lb = ub) stay as they are; an unlimited axis's
            # infinite bounds stay infinite (f > 0)
            free = self.lbx[w] != self.ubx[w]
            other.lbx[w] = np.where(free, self.lbx[w] * f, self.lbx[w])
            other.ubx[w] = np.where(free, self.ubx[w] * f, self.ubx[w])
        if "rate_bernstein" in self.tpl.layout:
            a, b = self.tpl.layout["rate_bernstein"]
            other.lbg[a:b] *= f
            other.ubg[a:b] *= f
        if "rate_norm" in self.tpl.layout:      # (squared norms, in units of the limit)
            a, b = self.tpl.layout["rate_norm"]
            other.ubg[a:b] *= f * f
        other.rate_scale = scale
        return other

    def params(self, delta):
        P = self.P.copy()
        P[self.tpl.i_par["delta"]] = delta
        return P

    def warm_ready(self, deadline) -> bool:
        """Whether a warm start before ``deadline`` would use the warm-started solver: it is
        built, or the time left pays for building it (else ``solve`` starts cold)."""
        return (self.tpl._warm is not None
                or deadline - time.perf_counter() > build_estimate(self.N, len(self.sc.prob.cones)))

    def solve(self, w0, deadline, source, delta=0.0, warm: Optional["Run"] = None) -> Run:
        """IPOPT from ``w0``; with ``warm`` (an answer of this NLP), from its primal-dual point."""
        tpl = self.tpl
        tpl.deadline.at = deadline
        solver = tpl.solver
        args = dict(x0=w0, p=self.params(delta), lbx=self.lbx, ubx=self.ubx, lbg=self.lbg, ubg=self.ubg)
        # (the warm-started solver is built at its first use: not when the budget left cannot pay
        # for it; the cold solver then starts from the same point)
        if warm is not None and warm.lam_x is not None and self.warm_ready(deadline):
            solver = tpl.warm_solver
            args.update(x0=warm.w, lam_x0=warm.lam_x, lam_g0=warm.lam_g)
        r = solver(**args)
        st = solver.stats()
        w = np.asarray(r["x"]).ravel()
        status = str(st.get("return_status", "unknown"))
        if status == "User_Requested_Stop" and time.perf_counter() > deadline:
            status = "Maximum_WallTime_Exceeded"
        nit = int(st.get("iter_count", 0))
        nfev = int(st.get("n_call_nlp_g", nit + 1))
        return Run(float(w[0]), w, np.asarray(r["lam_g"]).ravel(), status,
                   bool(st.get("success", False)) and status in CONVERGED_STATUSES, nit, nfev, self, source,
                   delta, np.asarray(r["lam_x"]).ravel())

    def g(self, w, delta=0.0):
        return np.asarray(self.tpl.geval(w, self.params(delta))).ravel()

    # ---- packing
    def pack(self, T, X, Xm, U, Um):
        w = np.empty(self.nx)
        w[0] = T
        w[self.iX] = X
        w[self.iXm] = Xm
        w[self.iU] = U
        w[self.iUm] = Um
        return w

    def unpack(self, w):
        w = np.asarray(w, dtype=float).ravel()
        return float(w[0]), w[self.iX], w[self.iXm], w[self.iU], w[self.iUm]

    def times(self, T):
        """Node and midpoint times (nondimensional)."""
        s = np.concatenate([[0.0], np.cumsum(self.mesh)])
        s[-1] = 1.0
        return s * T, 0.5 * (s[:-1] + s[1:]) * T
