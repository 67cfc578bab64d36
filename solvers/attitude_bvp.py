"""The time-optimal slew as a shooting problem (full-attitude target, no cones).

Works in nondimensional units: inertia ``J / J_max``, torque ``u / u_max``
(``u_max`` the largest per-axis bound), time ``t / τ`` with ``τ = sqrt(J_max / u_max)``.

Unknowns and gauge (CONVENTIONS.md):

* The quaternion costate has a gauge direction along ``q`` (``λq·q`` is conserved and
  ``λq ∥ q`` changes neither the state nor ``λω``). We fix ``λq(0)·q(0) = 0`` by
  writing ``λq(0) = q(0) ⊗ [0, μ]``: ``μ`` is the attitude costate in body axes,
  3 numbers. (Along an extremal ``λq(t) = q(t) ⊗ [0, μ(t)]`` with ``μ`` the body
  components of a constant inertial vector.)
* The costates are homogeneous of degree one (the control depends on directions
  only), so the scale is fixed during Newton by ``|μ|² + |λω(0)|² = 1`` and the free
  final time is the 7th unknown. For reporting the costates are rescaled so that
  ``H ≡ -1`` (the ``λ0 = 1`` normalisation); normality (``H < 0``) is verified.

Boundary residuals: ``s · Im(qf* ⊗ q(tf))`` with ``s`` the sign of the scalar part
(``q`` and ``-q`` are one attitude) and ``ω(tf) - ωf``.

Pointing-only targets (``sensor_target`` given, roll about the sensor free). The final
attitude must put the body sensor ``s`` on the inertial target ``d``: ``R(q)ᵀ d = s``, two
conditions, written ``e₁·R(q)ᵀd = 0``, ``e₂·R(q)ᵀd = 0`` with ``e₁, e₂ ⊥ s``. These also hold
at the antipode ``R(q)ᵀd = -s``, which the verification rejects; with ``stereographic = True``
they are written ``2 E R(q)ᵀd / (1 + s·R(q)ᵀd) = 0`` instead, zero only on the target's side
(``core.pointing``; the multi-start runs its candidates again this way when one reached the
antipode and none gave an answer). The third attitude condition is the transversality
condition of the free roll: the terminal set is the circle ``q ⊗ exp(φ/2 [0, s])``, whose
tangent is ``q ⊗ [0, s]``, and ``λq(tf)`` must be orthogonal to it::

    λq(tf) · (q(tf) ⊗ [0, s]) = Im(q(tf)* ⊗ λq(tf)) · s = μ(tf) · s = 0,

i.e. no costate on the rotation about the boresight at the end (the gauge component along
``q`` drops out). With ``ω(tf) = ωf`` these are again six conditions. Guesses and the
eigenaxis baseline use the reference attitude ``qf_ref``: the shortest rotation that
takes the start sensor direction onto the target, applied to ``q0``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Optional

import numpy as np

from slew_env.core.cones import perpendicular_basis
from slew_env.core.quaternion import qconj, qmul, qrotate
from .core import attitude_flow as af
from .core.pointing import pointing_terminal
from .deadline import current as _current_deadline
from .eigenaxis import reference_attitude

NY = af.NY

MAX_STEPS = 200_000
# A propagation is one compiled call that cannot look at the clock. Inside a solve with a time
# budget (``solvers.deadline.propagation_deadline``), a propagation that is not recording an answer gets only
# the steps the time left pays for, at the measured cost of a step (``_STEP_COST``), and never
# fewer than ``MIN_STEPS``: a stiff body (axes' acceleration bounds 1,000 apart) needs 20,000+
# steps of ~20 µs with sensitivities, and one such call had ended a 0.05 s solve 0.6 s late
MIN_STEPS = 200
# s a step, by the number of sensitivity columns, measured in the process as flows run; before
# the first measurement, this machine's at the time of writing (2026-11-24, DOP853 on 14 states:
# 6.5 µs, plus 2.2 µs a column; 20 µs with the 6 of a shooting Jacobian)
_STEP_COST = {}


def _step_cost(m):
    c = _STEP_COST.get(m)
    return c if c is not None else 6.5e-6 + 2.2e-6 * m


def step_allowance(m, record=0):
    """``(max_steps, capped)``: the steps a propagation with ``m`` sensitivity columns may take
    before the solve's deadline (``solvers.deadline``); a recording run (an answer's dense
    trajectory) is not capped."""
    dl = _current_deadline()
    if record or math.isinf(dl):
        return MAX_STEPS, False
    n = (dl - time.perf_counter()) / _step_cost(m)
    if n >= MAX_STEPS:
        return MAX_STEPS, False
    return max(MIN_STEPS, int(n)), True


def step_budget(m):
    """``step_allowance`` for the compiled calls that fly several arcs in one (switch-time and
    touch-point sequences, ``core.switch_sequence``, ``core.touch_sequence``): a 1-element int64
    array of the steps all their arcs together may take (the kernels decrement it), 2⁶² outside
    a solve's deadline or when it leaves ``MAX_STEPS`` or more. Always an array, so that the
    kernels run the one specialisation ``load_kernels`` compiled."""
    n, capped = step_allowance(m)
    return np.array([n if capped else 1 << 62], dtype=np.int64)


def _learn_step_cost(m, seconds, steps):
    """A moving average of the CPU time a step takes (``seconds``: this thread's CPU time, so
    that a wait for another thread is not counted), each new value held within a factor 2 of
    the current one (a descheduled call would otherwise starve the next ones of steps)."""
    if steps >= 200:        # long enough for the timer
        old = _step_cost(m)
        _STEP_COST[m] = 0.7 * old + 0.3 * min(max(seconds / steps, 0.5 * old), 2.0 * old)


def quat_left_matrix(q):
    """``Q(q)`` with ``q ⊗ p = Q(q) p``."""
    q0, q1, q2, q3 = q
    return np.array([[q0, -q1, -q2, -q3],
                     [q1, q0, -q3, q2],
                     [q2, q3, q0, -q1],
                     [q3, -q2, q1, q0]])


# a status of ``_run`` beside ``core.attitude_flow``'s: the steps the deadline left ran out
FLOW_DEADLINE = 100


def flow_failure(status) -> str:
    if status == FLOW_DEADLINE:
        return "the time budget ran out during a propagation"
    return f"propagation failed (status {status})"


@dataclass
class FlowOut:
    y: np.ndarray
    Phi: Optional[np.ndarray]
    f: np.ndarray
    ok: bool
    message: str
    signs_end: np.ndarray
    n_switches: int
    n_steps: int


@dataclass
class Trajectory:
    """Recorded extremal in nondimensional units."""
    t: np.ndarray          # (n,)
    y: np.ndarray          # (n, 14)
    signs: np.ndarray      # (n, 3) arc signs (bang-bang) at each record
    switch_t: np.ndarray   # (k,)
    switch_axis: np.ndarray  # (k,)
    signs0: np.ndarray     # (3,)
    ok: bool
    message: str


class AttitudeBVP:
    """Rest-to-rest (or rate-to-rate) full-attitude time-optimal slew, no cones.

    ``mode`` is one of ``"bang"`` (per-axis bound, exact switching), ``"pnorm"``
    (``p``-norm bound, closed-form control) or ``"tanh"`` (smoothed per-axis law with
    width ``eps``, a homotopy only).
    """
    n_y = NY
    n_p = 6
    handles_cones = False   # subclasses that put the cones in the flow say so
    pen = np.zeros(0)       # packed cone penalty of the flow (core.cone_penalty): none

    def __init__(self, problem, mode="bang", p=None, eps=1e-2, rtol=1e-12, atol=1e-13,
                 max_switches=200):
        if problem.cones and not self.handles_cones:
            raise ValueError("cones: the exact indirect solver does not handle keep-out cones "
                             "(see solvers.cone_penalty for the penalised route)")
        self.problem = problem
        Jmax = float(problem.inertia.max())
        umax = float(problem.torque_max.max())
        self.tau = math.sqrt(Jmax / umax)
        self.J = problem.inertia / Jmax
        self.umax = problem.torque_max / umax
        self.q0 = problem.q0.copy()
        self.pointing = problem.qf is None
        # the pointing residual's form (``core.pointing``): the plain one, except in the
        # multi-start's second pass after a candidate converged to the antipode
        self.stereographic = False
        if self.pointing:
            self.s_b = np.asarray(problem.sensor_axis, float) / np.linalg.norm(problem.sensor_axis)
            self.d_i = np.asarray(problem.sensor_target, float) / np.linalg.norm(problem.sensor_target)
            self.qf = reference_attitude(problem)
            # e1, e2: an orthonormal basis of the plane orthogonal to the sensor
            self._e = np.array(perpendicular_basis(self.s_b))
            self._ref_problem = None    # made when first asked for (a validated copy: 0.3 ms)
        else:
            self.qf = problem.qf.copy()
            self._ref_problem = problem
        self.w0 = problem.omega0 * self.tau
        self.wf = problem.omegaf * self.tau
        self.set_mode(mode, p, eps)
        self.rtol = rtol
        self.atol = atol
        self.max_switches = max_switches
        self._dq0 = quat_left_matrix(self.q0)[:, 1:4]   # ∂λq(0)/∂μ
        Qfc = quat_left_matrix(qconj(self.qf))
        self._dres_q = Qfc[1:4, :]                       # ∂Im(qf*⊗q)/∂q

    @property
    def ref_problem(self):
        """The full-attitude problem to the reference attitude ``qf`` (a pointing problem's
        target attitude with the roll of the shortest rotation); the problem itself otherwise."""
        if self._ref_problem is None:
            self._ref_problem = self.problem.replace(qf=self.qf, sensor_target=None)
        return self._ref_problem

    # ----------------------------------------------------------------- modes
    def set_mode(self, mode, p=None, eps=1e-2):
        if mode == "bang":
            self.mode = af.MODE_BANG
            self.p = 0.0
        elif mode == "pnorm":
            if p is None or not (p > 1.0) or math.isinf(p):
                raise ValueError(f"p: the pnorm mode needs a finite p > 1, got {p}")
            self.mode = af.MODE_PNORM
            self.p = float(p)
        elif mode == "tanh":
            self.mode = af.MODE_TANH
            self.p = 0.0
        else:
            raise ValueError(f"mode: unknown control law {mode!r}")
        self.mode_name = mode
        self.eps = float(eps)

    # ----------------------------------------------------------------- BVP pieces
    def initial(self, z):
        y0 = np.empty(NY)
        y0[0:4] = self.q0
        y0[4:7] = self.w0
        y0[7:11] = qmul(self.q0, np.array([0.0, z[0], z[1], z[2]]))
        y0[11:14] = z[3:6]
        d = np.zeros((NY, 6))
        d[7:11, 0:3] = self._dq0
        d[11:14, 3:6] = np.eye(3)
        return y0, d

    def param_residual(self, z):
        return np.array([float(z @ z) - 1.0]), 2.0 * z[None, :]

    def initial_signs(self, y):
        """Sign of each axis's first arc: ``-sign(S_i)``, ties broken by ``-sign(Ṡ_i)``."""
        S = y[11:14] / self.J
        u = np.zeros(3)
        f = af.ext_rhs(y, u, self.J)
        Sd = f[11:14] / self.J
        scale = max(float(np.max(np.abs(S))), 1e-300)
        s = np.empty(3)
        for i in range(3):
            if abs(S[i]) > 1e-13 * scale:
                s[i] = -math.copysign(1.0, S[i])
            elif Sd[i] != 0.0:
                s[i] = -math.copysign(1.0, Sd[i])
            else:
                s[i] = 1.0
        return s

    def _run(self, y0, duration, Phi0, signs0=None, record=0, detect=True, hmax=np.inf):
        m = 0 if Phi0 is None else Phi0.shape[1]
        Y0 = np.empty(NY + NY * m)
        Y0[:NY] = y0
        if m:
            Y0[NY:] = Phi0.ravel()
        signs = self.initial_signs(y0) if signs0 is None else np.asarray(signs0, float)
        rec_t = np.empty(record)
        rec_Y = np.empty((record, NY))
        rec_s = np.empty((record, 3))
        sw_t = np.empty(self.max_switches + 1)
        sw_a = np.empty(self.max_switches + 1, dtype=np.int64)
        h0 = min(0.05, duration) if duration > 0 else 0.0
        max_steps, capped = step_allowance(m, record)
        t0 = time.thread_time()
        Y, s_end, n_rec, n_sw, steps, status = af.flow(
            Y0, float(duration), m, self.J, self.umax, self.mode, self.p, self.eps, signs,
            self.rtol, self.atol, h0, max_steps, self.max_switches, rec_t, rec_Y, rec_s, sw_t, sw_a,
            self.pen, detect, hmax)
        _learn_step_cost(m, time.thread_time() - t0, steps)
        if capped and status == af.FLOW_MAX_STEPS:
            status = FLOW_DEADLINE
        return Y, s_end, n_rec, n_sw, steps, status, rec_t, rec_Y, rec_s, sw_t, sw_a, signs

    def flow(self, y0, duration, Phi0):
        if not (duration > 0.0) or not np.all(np.isfinite(y0)):
            return FlowOut(y0, None, np.zeros(NY), False, "non-positive duration or non-finite state",
                           np.zeros(3), 0, 0)
        Y, s_end, _, n_sw, steps, status, *_ = self._run(y0, duration, Phi0)
        y = Y[:NY].copy()
        ok = status == af.FLOW_OK and bool(np.all(np.isfinite(Y)))
        Phi = Y[NY:].reshape(NY, -1) if Phi0 is not None else None
        u, _ = af.control(y, self.J, self.umax, self.mode, self.p, self.eps, s_end)
        f = af.ext_rhs(y, u, self.J)
        msg = "" if ok else flow_failure(status)
        return FlowOut(y, Phi, f, ok, msg, s_end, n_sw, steps)

    def terminal(self, y, T):
        if self.pointing:
            return self._terminal_pointing(y)
        dq = qmul(qconj(self.qf), y[0:4])
        s = 1.0 if dq[0] >= 0.0 else -1.0
        r = np.empty(6)
        r[0:3] = s * dq[1:4]
        r[3:6] = y[4:7] - self.wf
        d = np.zeros((6, NY))
        d[0:3, 0:4] = s * self._dres_q
        d[3:6, 4:7] = np.eye(3)
        return r, d, np.zeros(6)

    def _terminal_pointing(self, y):
        """Pointing (2), roll transversality (1) and rate (3) residuals with their gradients
        (``core.pointing.pointing_terminal``)."""
        r, D = pointing_terminal(y, self.d_i, self.s_b, self._e, self.wf, self.stereographic)
        return r, D, np.zeros(6)

    def pointing_error(self, q):
        """Angle (rad) between the sensor's inertial direction and the target."""
        si = qrotate(q, self.s_b)
        # atan2 keeps full precision for small angles (acos near 1 resolves only ~1e-8 rad)
        return math.atan2(float(np.linalg.norm(np.cross(si, self.d_i))), float(si @ self.d_i))

    def attitude_error(self, q):
        """Boundary attitude error (rad): pointing error, or the angle of ``qf* ⊗ q``."""
        if self.pointing:
            return self.pointing_error(q)
        from slew_env.core.quaternion import qerror_angle
        return float(qerror_angle(q, self.qf))

    def roll_transversality(self, y):
        """``|μ(tf)·s| / |μ(tf)|``: the relative costate on the free roll (0 at an extremal)."""
        im = y[0] * y[8:11] - y[7] * y[1:4] - np.cross(y[1:4], y[8:11])
        return abs(float(im @ self.s_b)) / max(float(np.linalg.norm(im)), 1e-300)

    # ----------------------------------------------------------------- helpers
    def record(self, z, T, n_max=20000, hmax=np.inf):
        """Propagate the extremal from parameters ``z`` over ``T`` and record it (not ok if the
        record ran out of rows before ``T``)."""
        y0, _ = self.initial(z)
        if math.isfinite(hmax) and hmax > 0.0 and T > 0.0:
            # room for every step at the cap, both sides of each switch and the adaptive
            # steps shorter than the cap (a fixed 20,000 rows cut the record of n_dense = 30,000
            # short at two thirds of tf, with the answer still verified)
            n_max = max(n_max, int(min(T / hmax, MAX_STEPS)) * 2 + 2 * self.max_switches + 100)
        Y, s_end, n_rec, n_sw, steps, status, rt, rY, rs, swt, swa, s0 = self._run(
            y0, T, None, record=n_max, hmax=hmax)
        n_sw_kept = min(n_sw, swt.shape[0])
        ok = status == af.FLOW_OK
        msg = "" if ok else flow_failure(status)
        if ok and 0 < n_max <= n_rec and rt[n_rec - 1] < T:
            ok, msg = False, f"the dense record filled its {n_max} rows at t = {rt[n_rec - 1]:.6g} of {T:.6g}"
        return Trajectory(rt[:n_rec].copy(), rY[:n_rec].copy(), rs[:n_rec].copy(), swt[:n_sw_kept].copy(),
                          swa[:n_sw_kept].copy(), s0, ok, msg)

    def arc(self, y0, duration, signs, Phi0=None):
        """One bang-bang arc with fixed ``signs`` (no switch detection)."""
        Y, s_end, _, _, steps, status, *_ = self._run(y0, duration, Phi0, signs0=signs, detect=False)
        ok = status == af.FLOW_OK and bool(np.all(np.isfinite(Y)))
        Phi = Y[NY:].reshape(NY, -1) if Phi0 is not None else None
        return Y[:NY].copy(), Phi, ok

    def hamiltonian(self, y, signs):
        return af.hamiltonian(y, self.J, self.umax, self.mode, self.p, self.eps, signs)
