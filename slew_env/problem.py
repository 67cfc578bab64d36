"""The one description of a slew: ``SlewProblem`` and ``Cone``.

Every part of the project (environment, solvers, datasets, CLI) takes a
``SlewProblem``. It is validated once, on construction, with ``ValueError``s that
name the field and the reason; compiled code downstream trusts it.

JSON / dict field names (see README, "Problem format")::

    inertia, torque_max, torque_norm, q0, omega0, qf, sensor_axis,
    sensor_target, omegaf, cones: [{axis, half_angle | half_angle_deg}], rate_max, rate_norm_max
"""
from __future__ import annotations

import json
import math
import os
import sys
import warnings
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .checks import has_bool, has_text
from .core import quaternion as _q
from .core import task as _t
from .core.cones import angle_between

# A unit quaternion given with a norm error up to QUAT_SILENT_TOL is normalised
# silently; up to QUAT_REJECT_TOL it is normalised with a warning; beyond, rejected.
QUAT_SILENT_TOL = 1e-6
QUAT_REJECT_TOL = 1e-3
# A start or target sensor direction may sit on a cone boundary (R4 starts there),
# but not inside it by more than this (rad).
CONE_FEASIBILITY_TOL = 1e-9

# The range of problems the solvers are built for (beyond it the numerics break down: a p-norm
# control law close to p = 1 underflows, huge p overflows; a body whose axes differ by more
# than MAX_AXIS_SPREAD in J_i / u_max_i, or rates beyond MAX_RATE_TAU in units of
# τ = sqrt(J_max / u_max), make the propagation stiff, seconds past any time budget). Such
# problems are refused by name rather than crash or overrun inside compiled code.
P_MIN, P_MAX = 1.05, 100.0
MAX_AXIS_SPREAD = 1e3
MAX_RATE_TAU = 100.0

# A vector whose norm is within this of 1 is already unit to rounding and is kept
# bit for bit, so that normalising is idempotent: ``from_dict(p.to_dict()) == p``
# (dividing a unit vector by its computed norm again can move it by an ulp).
_UNIT_ROUNDING_TOL = 8.0 * np.finfo(float).eps

FIELDS = ("inertia", "torque_max", "torque_norm", "q0", "omega0", "qf", "sensor_axis",
          "sensor_target", "omegaf", "cones", "rate_max", "rate_norm_max")
# accepted on input besides FIELDS (``to_dict`` writes the field itself): the rate limits in deg/s
INPUT_ONLY_FIELDS = ("rate_max_deg", "rate_norm_max_deg")


def _vector(name, value, length, *, positive=False, allow_scalar=False, unit=False):
    """Validate a finite float vector of ``length`` entries (scalar broadcast if allowed)."""
    if has_bool(value):
        raise ValueError(f"{name}: expected numbers, got a boolean in {value!r}")
    if has_text(value):
        raise ValueError(f"{name}: expected numbers, got text in {value!r:.120} (write numbers "
                         "without quotes)")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}: expected {length} finite numbers, got {value!r:.120}") from None
    if arr.ndim == 0 and allow_scalar:
        arr = np.full(length, float(arr))
    if arr.shape != (length,):
        what = f"a number or {length} numbers" if allow_scalar else f"{length} numbers"
        raise ValueError(f"{name}: expected {what}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: all entries must be finite, got {arr.tolist()}")
    if positive and np.any(arr <= 0.0):
        raise ValueError(f"{name}: all entries must be positive, got {arr.tolist()}")
    if unit:
        with np.errstate(over="ignore"):
            n = float(np.linalg.norm(arr))
        if not math.isfinite(n):
            # the norm of finite entries near the float limit overflows: scale them first (a
            # direction is a direction whatever its length)
            arr = arr / float(np.max(np.abs(arr)))
            n = float(np.linalg.norm(arr))
        if n < 1e-12:
            raise ValueError(f"{name}: zero-length axis cannot be normalised")
        arr = _normalised(arr, n)
    return arr.copy()


def _number(name, value, what="a number"):
    """``value`` as a float: ``ValueError`` naming ``name`` for booleans, text, non-numbers
    and integers too large for a float."""
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name}: expected {what}, got {value!r}")
    if has_text(value):
        raise ValueError(f"{name}: expected {what}, got text {value!r:.120} (write numbers "
                         "without quotes)")
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}: expected {what}, got {value!r:.120}") from None


def _positive_scalar(name, value) -> float:
    """One finite positive number (``ValueError`` naming ``name`` otherwise)."""
    x = _number(name, value, "one positive number")
    if not (math.isfinite(x) and x > 0.0):
        raise ValueError(f"{name}: expected one finite positive number, got {x!r}")
    return x


def _normalised(arr, n):
    """``arr / n``, or ``arr`` itself when it is already unit to rounding (idempotent)."""
    if abs(n - 1.0) <= _UNIT_ROUNDING_TOL:
        return arr.copy()
    return arr / n


def _caller_stacklevel():
    """``stacklevel`` for ``warnings.warn`` pointing at the first frame outside this module."""
    here = os.path.normcase(os.path.abspath(__file__))
    f = sys._getframe(1)
    level = 1
    while f is not None and os.path.normcase(os.path.abspath(f.f_code.co_filename)) == here:
        f = f.f_back
        level += 1
    return level


def _unit_quaternion(name, value):
    q = _vector(name, value, 4)
    n = float(np.linalg.norm(q))
    err = abs(n - 1.0)
    if err > QUAT_REJECT_TOL:
        raise ValueError(
            f"{name}: not a unit quaternion (norm {n:.6g}, off by {err:.3g} > {QUAT_REJECT_TOL:g}); "
            "give a unit quaternion [q0, q1, q2, q3], scalar first")
    if err > QUAT_SILENT_TOL:
        warnings.warn(f"{name}: quaternion norm {n:.9g} is off by {err:.3g} "
                      f"(> {QUAT_SILENT_TOL:g}, <= {QUAT_REJECT_TOL:g}); normalised",
                      UserWarning, stacklevel=_caller_stacklevel())
    return _normalised(q, n)


def _torque_norm(value):
    if isinstance(value, str):
        v = value.strip().lower()
        if v in ("inf", "infinity", "∞", "max", "per-axis"):
            return math.inf
        try:
            value = float(v)
        except ValueError:
            raise ValueError(f"torque_norm: expected 'inf' or a number p > 1, got {value!r}") from None
    p = _number("torque_norm", value, "'inf' or a number p > 1")
    if math.isnan(p):
        raise ValueError("torque_norm: must be 'inf' or a number p > 1, got nan")
    if math.isinf(p) and p > 0:
        return math.inf
    if not p > 1.0:
        raise ValueError(f"torque_norm: p must be > 1 (p = 1 has no unique optimal control), got {p:g}")
    if p < P_MIN:
        # the control law's exponent 1/(p - 1) underflows the torque direction to zero
        raise ValueError(f"torque_norm: p = {p:g} is too close to 1 for the solvers (the control law "
                         f"|S|^(1/(p-1)) underflows); give {P_MIN:g} ≤ p ≤ {P_MAX:g}, or 'inf'")
    if p > P_MAX:
        raise ValueError(f"torque_norm: p = {p:g} is beyond what the solvers handle ({P_MIN:g} ≤ p ≤ {P_MAX:g}); "
                         "for a bound close to the per-axis one give 'inf', its limit as p grows")
    return p


@dataclass(frozen=True)
class Cone:
    """Keep-out cone on the sensor axis: inertial unit ``axis`` and ``half_angle`` (rad).

    ``Cone(axis, half_angle=None, half_angle_deg=None)``: give exactly one of the two.
    """
    axis: np.ndarray
    half_angle: float

    def __init__(self, axis, half_angle=None, *, half_angle_deg=None, _field="cone"):
        if (half_angle is None) == (half_angle_deg is None):
            raise ValueError(f"{_field}: give exactly one of half_angle (rad) or half_angle_deg")
        a = _vector(f"{_field}.axis", axis, 3, unit=True)
        if half_angle_deg is not None:
            name = f"{_field}.half_angle_deg"
            deg = _number(name, half_angle_deg)
            if not math.isfinite(deg):
                raise ValueError(f"{name}: must be finite, got {deg}")
            if not 0.0 < deg < 180.0:
                raise ValueError(f"{name}: half-angle must lie in (0°, 180°), got {deg:g}°")
            ha = math.radians(deg)
        else:
            name = f"{_field}.half_angle"
            ha = _number(name, half_angle, "a number (rad)")
            if not math.isfinite(ha):
                raise ValueError(f"{name}: must be finite, got {ha}")
            if not 0.0 < ha < math.pi:
                raise ValueError(
                    f"{name}: half-angle must lie in (0, π) rad i.e. (0°, 180°), got {ha:g} rad")
        a.setflags(write=False)
        object.__setattr__(self, "axis", a)
        object.__setattr__(self, "half_angle", ha)

    @property
    def half_angle_deg(self) -> float:
        return math.degrees(self.half_angle)

    def margin(self, direction) -> float:
        """Clearance margin (rad) of an inertial unit direction: angle to the axis minus half-angle."""
        d = np.asarray(direction, dtype=float)
        return float(angle_between(d / np.linalg.norm(d), self.axis)) - self.half_angle

    def to_dict(self) -> dict:
        return {"axis": self.axis.tolist(), "half_angle": self.half_angle}

    @classmethod
    def from_dict(cls, d, _field="cone") -> "Cone":
        if isinstance(d, Cone):
            return d
        if not isinstance(d, dict):
            raise ValueError(f"{_field}: expected an object with axis and half_angle, got {d!r}")
        unknown = set(d) - {"axis", "half_angle", "half_angle_deg"}
        if unknown:
            raise ValueError(f"{_field}: unknown field(s) {sorted(unknown)}")
        if "axis" not in d:
            raise ValueError(f"{_field}.axis: missing")
        return cls(d["axis"], d.get("half_angle"), half_angle_deg=d.get("half_angle_deg"), _field=_field)

    def __eq__(self, other):
        return (isinstance(other, Cone) and np.array_equal(self.axis, other.axis)
                and self.half_angle == other.half_angle)

    def __hash__(self):
        return hash((tuple(self.axis), self.half_angle))

    def __repr__(self):
        return f"Cone(axis={self.axis.tolist()}, half_angle_deg={self.half_angle_deg:.6g})"


def check_time_unit(inertia, torque_max, fields) -> None:
    """Refuse (``ValueError`` naming ``fields``) inertia and torque bounds whose time unit
    ``sqrt(J_max / u_max)`` or its inverse is outside the floating-point range: inertia 1e200
    with torque 1e-200 had given NaN observations from the first reset (an outside fuzz)."""
    ratio = float(np.max(inertia)) / float(np.max(torque_max))
    if not (math.isfinite(ratio) and ratio > 0.0 and math.isfinite(1.0 / ratio)):
        raise ValueError(f"{fields}: the time unit sqrt(J_max / u_max) of inertia {np.max(inertia):.3g} and "
                         f"torque {np.max(torque_max):.3g} is outside the floating-point range; express them "
                         "in other units")


class SlewProblem:
    """A rigid-body slew: body, torque bound, start, target, cones, rate limit.

    Parameters
    ----------
    inertia : 3 positive numbers
        Principal moments of inertia ``J1, J2, J3`` (any consistent units).
    torque_max : number or 3 positive numbers
        Torque bound per axis (per-axis bound) or the radius of the p-norm ball.
    torque_norm : ``"inf"`` (default) or number ``P_MIN ≤ p ≤ P_MAX`` (1.05 to 100)
        ``"inf"``: ``|u_i| ≤ torque_max_i``. ``p``: ``‖u / torque_max‖_p ≤ 1``
        (with equal ``torque_max`` this is ``‖u‖_p ≤ torque_max``; 2 is the ball).
    q0 : unit quaternion, default identity
        Start attitude, scalar first, body to inertial.
    omega0 : 3 numbers, default rest
        Start body rate.
    qf : unit quaternion, optional
        Full-attitude target. Give exactly one of ``qf`` and ``sensor_target``.
    sensor_target : 3 numbers, optional
        Pointing-only target: the inertial direction the sensor must point at
        ``tf``; the rotation about the sensor axis is free.
    sensor_axis : 3 numbers, default body x ``[1, 0, 0]``
        Body-fixed sensor direction (normalised), used by cones and pointing targets.
    omegaf : 3 numbers, default rest
        Target body rate.
    cones : list of ``Cone`` or dicts, default none
        Keep-out cones on the sensor axis.
    rate_max : number or 3 positive numbers, optional
        Per-axis body-rate limit ``|ω_i| ≤ rate_max_i`` (rad per time unit).
    rate_max_deg : number or 3 positive numbers, optional
        The same limit in degrees per time unit (give one of the two; stored as ``rate_max``).
    rate_norm_max : positive number, optional
        Limit on the norm of the body rate, ``‖ω‖ ≤ rate_norm_max`` (rad per time unit): what a
        star tracker's or a gyro's rate limit usually is. Alone or with ``rate_max`` (both hold).
    rate_norm_max_deg : positive number, optional
        The same limit in degrees per time unit (stored as ``rate_norm_max``).
    """

    __slots__ = ("inertia", "torque_max", "torque_norm", "q0", "omega0", "qf", "sensor_axis",
                 "sensor_target", "omegaf", "cones", "rate_max", "rate_norm_max")

    def __init__(self, inertia, torque_max=1.0, torque_norm="inf", q0=(1.0, 0.0, 0.0, 0.0),
                 omega0=(0.0, 0.0, 0.0), qf=None, sensor_axis=(1.0, 0.0, 0.0),
                 sensor_target=None, omegaf=(0.0, 0.0, 0.0), cones=(), rate_max=None, rate_max_deg=None,
                 rate_norm_max=None, rate_norm_max_deg=None):
        self.inertia = _vector("inertia", inertia, 3, positive=True)
        self.torque_max = _vector("torque_max", torque_max, 3, positive=True, allow_scalar=True)
        self.torque_norm = _torque_norm(torque_norm)
        self.q0 = _unit_quaternion("q0", q0)
        self.omega0 = _vector("omega0", omega0, 3)
        self.omegaf = _vector("omegaf", omegaf, 3)
        check_time_unit(self.inertia, self.torque_max, "inertia, torque_max")
        accel = self.torque_max / self.inertia          # per-axis acceleration bound
        if not float(accel.max() / accel.min()) <= MAX_AXIS_SPREAD:     # (NaN too: inf / inf)
            raise ValueError(f"inertia, torque_max: the axes' acceleration bounds u_max,i / J_i differ by a factor "
                             f"{float(accel.max() / accel.min()):.3g}, beyond the {MAX_AXIS_SPREAD:g} the solvers are "
                             f"built for (inertia {self.inertia.tolist()}, torque_max {self.torque_max.tolist()})")
        tau = math.sqrt(float(self.inertia.max()) / float(self.torque_max.max()))
        for name, w in (("omega0", self.omega0), ("omegaf", self.omegaf)):
            if float(np.max(np.abs(w))) * tau > MAX_RATE_TAU:
                raise ValueError(f"{name}: rates up to {MAX_RATE_TAU:g} / τ are supported (τ = sqrt(J_max / u_max) "
                                 f"= {tau:.4g}, i.e. |ω| ≤ {MAX_RATE_TAU / tau:.4g}), got {w.tolist()}")
        self.sensor_axis = _vector("sensor_axis", sensor_axis, 3, unit=True)
        if (qf is None) == (sensor_target is None):
            raise ValueError("qf, sensor_target: give exactly one target, a full attitude qf "
                             "or a pointing-only sensor_target"
                             + (" (both were given)" if qf is not None else " (neither was given)"))
        self.qf = None if qf is None else _unit_quaternion("qf", qf)
        self.sensor_target = (None if sensor_target is None
                              else _vector("sensor_target", sensor_target, 3, unit=True))
        if cones is None:
            cones = ()
        if isinstance(cones, (dict, Cone)):
            raise ValueError("cones: expected a list of cones, got a single cone; wrap it in a list")
        if isinstance(cones, (str, bytes)) or not hasattr(cones, "__iter__"):
            raise ValueError(f"cones: expected a list of cones, got {cones!r}")
        self.cones = tuple(Cone.from_dict(c, _field=f"cones[{k}]") for k, c in enumerate(cones))
        if rate_max_deg is not None:
            if rate_max is not None:
                raise ValueError("rate_max, rate_max_deg: give the rate limit once, in rad (rate_max) or in degrees "
                                 "(rate_max_deg) per time unit")
            rate_max = np.radians(_vector("rate_max_deg", rate_max_deg, 3, positive=True, allow_scalar=True))
        if rate_max is None:
            self.rate_max = None
        else:
            self.rate_max = _vector("rate_max", rate_max, 3, positive=True, allow_scalar=True)
            for name, w in (("omega0", self.omega0), ("omegaf", self.omegaf)):
                if np.any(np.abs(w) > self.rate_max):
                    raise ValueError(f"{name}: exceeds rate_max ({w.tolist()} vs {self.rate_max.tolist()})")
        if rate_norm_max_deg is not None:
            if rate_norm_max is not None:
                raise ValueError("rate_norm_max, rate_norm_max_deg: give the limit on the rate's norm once, in rad "
                                 "(rate_norm_max) or in degrees (rate_norm_max_deg) per time unit")
            rate_norm_max = math.radians(_positive_scalar("rate_norm_max_deg", rate_norm_max_deg))
        self.rate_norm_max = None if rate_norm_max is None else _positive_scalar("rate_norm_max", rate_norm_max)
        if self.rate_norm_max is not None:
            for name, w in (("omega0", self.omega0), ("omegaf", self.omegaf)):
                if float(np.linalg.norm(w)) > self.rate_norm_max:
                    raise ValueError(f"{name}: its norm {float(np.linalg.norm(w)):.6g} exceeds rate_norm_max "
                                     f"{self.rate_norm_max:.6g}")
        for name, direction in (("q0", self.start_direction), ("qf" if self.qf is not None
                                                               else "sensor_target", self.target_direction)):
            for k, cone in enumerate(self.cones):
                m = cone.margin(direction)
                if m < -CONE_FEASIBILITY_TOL:
                    where = "start" if name == "q0" else "target"
                    raise ValueError(
                        f"{name}: infeasible, the {where} sensor direction lies inside cones[{k}] "
                        f"({math.degrees(-m):.4g}° deep; half-angle {cone.half_angle_deg:.4g}°)")
        for arr in (self.inertia, self.torque_max, self.q0, self.omega0, self.omegaf,
                    self.sensor_axis, self.qf, self.sensor_target, self.rate_max):
            if arr is not None:
                arr.setflags(write=False)

    # ------------------------------------------------------------------ geometry
    @property
    def is_pointing(self) -> bool:
        """True for a pointing-only target (roll about the sensor free)."""
        return self.qf is None

    @property
    def start_direction(self) -> np.ndarray:
        """Inertial sensor direction at the start."""
        return np.asarray(_q.qrotate(self.q0, self.sensor_axis))

    @property
    def target_direction(self) -> np.ndarray:
        """Inertial sensor direction at the target."""
        if self.qf is not None:
            return np.asarray(_q.qrotate(self.qf, self.sensor_axis))
        return self.sensor_target.copy()

    @property
    def slew_angle(self) -> float:
        """Rotation angle (rad) from start to target: the eigenaxis angle for a full
        attitude, the angle between start and target sensor directions when pointing-only."""
        if self.qf is not None:
            return float(_q.qerror_angle(self.q0, self.qf))
        return float(angle_between(self.start_direction, self.sensor_target))

    @property
    def time_unit(self) -> float:
        """``sqrt(J_max / u_max)``: the time unit of the nondimensional problem."""
        return math.sqrt(float(self.inertia.max()) / float(self.torque_max.max()))

    @property
    def p(self) -> float:
        """p of the torque bound (``inf`` for per-axis)."""
        return self.torque_norm

    @property
    def is_rest_to_rest(self) -> bool:
        return not self.omega0.any() and not self.omegaf.any()

    @property
    def has_rate_limit(self) -> bool:
        """A limit on the body rate: per axis (``rate_max``), on its norm (``rate_norm_max``), or both."""
        return self.rate_max is not None or self.rate_norm_max is not None

    def rate_limit_ratios(self, omega) -> np.ndarray:
        """``rate_limit_ratio`` of each row of ``omega`` (body rates, problem units): the larger of
        ``max_i |ω_i| / rate_max_i`` and ``‖ω‖ / rate_norm_max``; 0 without a limit, infinite for a
        row that is not finite."""
        w = np.asarray(omega, dtype=float).reshape(-1, 3)
        r = np.zeros(w.shape[0])
        if self.rate_max is not None:
            r = np.maximum(r, np.max(np.abs(w) / np.asarray(self.rate_max, float), axis=1))
        if self.rate_norm_max is not None:
            r = np.maximum(r, np.linalg.norm(w, axis=1) / self.rate_norm_max)
        # (np.maximum keeps a NaN, but a limit-free problem would give 0: a NaN rate must not pass)
        r[~np.all(np.isfinite(w), axis=1)] = math.inf
        return r

    def rate_limit_ratio(self, omega) -> float:
        """The largest ``|ω_i| / rate_max_i`` and ``‖ω‖ / rate_norm_max`` over the rows of ``omega``
        (body rates, problem units): at most 1 where the rate limits hold; 0 without a limit."""
        r = self.rate_limit_ratios(omega)
        return float(np.max(r)) if r.size else 0.0

    # ------------------------------------------------------------------ packing
    def to_task_array(self, max_cones: Optional[int] = None) -> np.ndarray:
        """Pack into the flat float64 layout of ``slew_env.core.task``."""
        n = len(self.cones)
        if max_cones is None:
            max_cones = n
        if n > max_cones:
            raise ValueError(f"cones: {n} cones given but at most {max_cones} supported here")
        if self.rate_norm_max is not None:
            raise ValueError("rate_norm_max: the environment and its task arrays hold per-axis rate limits only "
                             "(rate_max); a limit on the rate's norm is for the solvers")
        t = np.zeros(_t.task_length(max_cones))
        t[_t.T_J:_t.T_J + 3] = self.inertia
        t[_t.T_UMAX:_t.T_UMAX + 3] = self.torque_max
        t[_t.T_PNORM] = 0.0 if math.isinf(self.torque_norm) else self.torque_norm
        t[_t.T_Q0:_t.T_Q0 + 4] = self.q0
        t[_t.T_W0:_t.T_W0 + 3] = self.omega0
        t[_t.T_QF:_t.T_QF + 4] = self.qf if self.qf is not None else (1.0, 0.0, 0.0, 0.0)
        t[_t.T_POINTING] = 1.0 if self.qf is None else 0.0
        t[_t.T_SENSOR:_t.T_SENSOR + 3] = self.sensor_axis
        t[_t.T_TARGET:_t.T_TARGET + 3] = self.target_direction
        t[_t.T_WF:_t.T_WF + 3] = self.omegaf
        t[_t.T_RATEMAX:_t.T_RATEMAX + 3] = np.inf if self.rate_max is None else self.rate_max
        t[_t.T_TUNIT] = self.time_unit
        t[_t.T_NCONES] = n
        for k, c in enumerate(self.cones):
            o = _t.T_CONES + _t.CONE_STRIDE * k
            t[o:o + 3] = c.axis
            t[o + 3] = c.half_angle
        return t

    @classmethod
    def from_task_array(cls, t) -> "SlewProblem":
        """Inverse of ``to_task_array``."""
        t = np.asarray(t, dtype=float)
        if t.ndim != 1 or t.shape[0] < _t.T_CONES:
            raise ValueError(f"t: expected a task array of at least {_t.T_CONES} numbers, got shape {t.shape}")
        n = int(t[_t.T_NCONES])
        cones = []
        for k in range(n):
            o = _t.T_CONES + _t.CONE_STRIDE * k
            cones.append(Cone(t[o:o + 3], float(t[o + 3])))
        pointing = t[_t.T_POINTING] > 0.5
        rm = t[_t.T_RATEMAX:_t.T_RATEMAX + 3]
        return cls(
            inertia=t[_t.T_J:_t.T_J + 3], torque_max=t[_t.T_UMAX:_t.T_UMAX + 3],
            torque_norm="inf" if t[_t.T_PNORM] == 0.0 else float(t[_t.T_PNORM]),
            q0=t[_t.T_Q0:_t.T_Q0 + 4], omega0=t[_t.T_W0:_t.T_W0 + 3],
            qf=None if pointing else t[_t.T_QF:_t.T_QF + 4],
            sensor_axis=t[_t.T_SENSOR:_t.T_SENSOR + 3],
            sensor_target=t[_t.T_TARGET:_t.T_TARGET + 3] if pointing else None,
            omegaf=t[_t.T_WF:_t.T_WF + 3], cones=cones,
            rate_max=None if np.all(np.isinf(rm)) else rm)

    # ------------------------------------------------------------------ dict / JSON
    def to_dict(self) -> dict:
        """JSON-ready dict with the documented field names (angles in rad)."""
        return {
            "inertia": self.inertia.tolist(),
            "torque_max": self.torque_max.tolist(),
            "torque_norm": "inf" if math.isinf(self.torque_norm) else self.torque_norm,
            "q0": self.q0.tolist(),
            "omega0": self.omega0.tolist(),
            "qf": None if self.qf is None else self.qf.tolist(),
            "sensor_axis": self.sensor_axis.tolist(),
            "sensor_target": None if self.sensor_target is None else self.sensor_target.tolist(),
            "omegaf": self.omegaf.tolist(),
            "cones": [c.to_dict() for c in self.cones],
            "rate_max": None if self.rate_max is None else self.rate_max.tolist(),
            "rate_norm_max": self.rate_norm_max,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "SlewProblem":
        if isinstance(d, SlewProblem):
            return d
        if not isinstance(d, dict):
            raise ValueError(f"problem: expected a SlewProblem or a dict (JSON object), got {type(d).__name__}")
        unknown = set(d) - set(FIELDS) - set(INPUT_ONLY_FIELDS)
        if unknown:
            raise ValueError(f"problem: unknown field(s) {sorted(unknown)}; known fields are "
                             f"{list(FIELDS + INPUT_ONLY_FIELDS)}")
        if d.get("inertia") is None:
            raise ValueError("inertia: missing (3 principal moments of inertia)")
        kwargs = {k: v for k, v in d.items() if v is not None or k in ("qf", "sensor_target", "rate_max",
                                                                      "rate_norm_max")}
        return cls(**kwargs)

    def to_json(self, **kw) -> str:
        return json.dumps(self.to_dict(), **kw)

    @classmethod
    def from_json(cls, text: str) -> "SlewProblem":
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise ValueError(f"problem: not valid JSON ({e})") from None
        except RecursionError:
            raise ValueError("problem: not valid JSON (nested too deeply)") from None
        except ValueError as e:     # e.g. an integer literal beyond Python's digit limit
            raise ValueError(f"problem: not valid JSON ({e})"[:300]) from None
        return cls.from_dict(d)

    @classmethod
    def load(cls, path) -> "SlewProblem":
        try:
            with open(path, encoding="utf-8") as f:
                text = f.read()
        except FileNotFoundError:
            raise
        except (OSError, UnicodeDecodeError) as e:
            raise ValueError(f"problem: cannot read {str(path)!r} ({type(e).__name__}: {e})"[:300]) from None
        return cls.from_json(text)

    def save(self, path) -> None:
        with open(path, "w") as f:
            f.write(self.to_json(indent=2))
            f.write("\n")

    def replace(self, **changes) -> "SlewProblem":
        """A copy with some fields changed (validated again)."""
        d = self.to_dict()
        if "qf" in changes and changes["qf"] is not None:
            d["sensor_target"] = None
        if "sensor_target" in changes and changes["sensor_target"] is not None:
            d["qf"] = None
        if changes.get("rate_max_deg") is not None:
            d["rate_max"] = None
        if changes.get("rate_norm_max_deg") is not None:
            d["rate_norm_max"] = None
        d.update(changes)
        return SlewProblem.from_dict(d)

    # ------------------------------------------------------------------ misc
    def __eq__(self, other):
        return isinstance(other, SlewProblem) and self.to_dict() == other.to_dict()

    def __hash__(self):
        return hash(self.to_json(sort_keys=True))

    def __repr__(self):
        target = (f"qf={np.round(self.qf, 6).tolist()}" if self.qf is not None
                  else f"sensor_target={np.round(self.sensor_target, 6).tolist()}")
        norm = "inf" if math.isinf(self.torque_norm) else f"{self.torque_norm:g}"
        return (f"SlewProblem(inertia={self.inertia.tolist()}, torque_max={self.torque_max.tolist()}, "
                f"torque_norm={norm}, {target}, slew_angle={math.degrees(self.slew_angle):.3f}°, "
                f"cones={len(self.cones)})")
