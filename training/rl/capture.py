"""Capture near the target: a PD law takes over from the policy within a small angle.

Spacecraft slew controllers hand over to a settling (fine-pointing) law near the target;
``CaptureHandover`` does the same for a policy flying ``SlewEnv``. When the error angle of
the observation is below ``deg``, the action sent on is

    pd(obs)_i = clip(kp · θ e_i − damping · J̃_i (ω̃_i − ω̃f_i) / (ũ_max,i · Δt), −1, 1),

``θ·e`` the rotation still to go (angle and axis of the error quaternion, body frame),
``ω̃ = ω·T`` the body rate and ``ω̃f`` the target rate, ``J̃``, ``ũ_max`` the observation's inertia and torque bound and
``Δt`` the control step: the rate term removes the fraction ``damping`` of the rate in one
step (a deadbeat rate loop, scaled per axis by the body's inertia). Elsewhere the policy's
own action goes through.

Why: the time-optimal expert's controls near the target are full-torque pulses a few
control steps long. Cloned, and after RL, the cone policies reached the target and then
chattered round it (or rolled slowly about the sensor axis with zero torque) without
ever meeting the rate tolerance of the success test (0.02): 35 of the 35 failures of one
clone, 16 of 17 of an RL policy. Within 1° of the target this law settles in a few steps:
on 150 training problems, the last degree took a median 7 % of the optimal final time
(a plain PD law with ``kd = 6``: 15 %).

``law="braking"`` is an approach law for a larger handover angle: the same deadbeat rate
loop tracks the rate of a braking curve instead of ``kp·θ·e``,

    ω̃_des = e · (√(c² + 2 β s d) − c),   d = max(θ − aim, 0),   c = β s Δt,

``s`` the largest acceleration the torque bound gives about the error axis ``e`` (per
axis: ``min_i ũ_max,i / (J̃_i |e_i|)``; a p-norm bound: ``1 / ‖J̃ e / ũ_max‖_p``), ``β``
(``brake``) the share of it the braking may use, and ``aim`` the angle it brakes to
(inside the success tolerance: a time-optimal slew need not reach the target exactly).
``c`` rounds the curve off near ``aim``, where its square root would ask for an infinite
gain from a sampled loop. A rate limit (the observation's ``OB_RATE_LIMIT``) caps the curve's
speed at 0.9 of the limit, less the target's own rate. ``aim`` must lie inside the
environment's success tolerance ``att_tol_deg``: inside ``aim`` the law only removes the
rate, so it would come to rest short of a tighter tolerance. Why: with the cone policy
flying to 10° and the 1° settling law, the body reached the success ball at speed and took
a median 0.13 time units to settle; flown along the braking curve from 10° it arrives near
rest and settles in 0.09 (60 problems of tuning seed 1; median ratio on 200 of them: 1.247 →
1.224; docs/RL.md). Its actions pass through the cone filter like the policy's.
"""
from __future__ import annotations

import math

import gymnasium as gym
import numpy as np

from slew_env.core import env_kernels as _k
from slew_env.shield import ObservingActionWrapper

KEYS = ("deg", "kp", "damping", "law", "brake", "aim_deg")
LAWS = ("pd", "braking")
DEFAULTS = {"deg": 1.0, "kp": 5.0, "damping": 0.8, "law": "pd", "brake": 0.9, "aim_deg": 0.8}


def check(kw: dict) -> dict:
    """Validated capture arguments (defaults filled in).

    ``law``: ``"pd"`` (error feedback ``kp``) or ``"braking"`` (the braking curve, ``brake``
    and ``aim_deg``); both use ``damping`` for the rate loop.
    """
    if not isinstance(kw, dict):
        raise ValueError(f"capture: expected a mapping of {', '.join(KEYS)}, got {kw!r}")
    unknown = set(kw) - set(KEYS)
    if unknown:
        raise ValueError(f"capture: unknown key(s) {sorted(unknown)}; known: {', '.join(KEYS)}")
    out = dict(DEFAULTS)
    for k, v in kw.items():
        if k == "law":
            if not isinstance(v, str) or v not in LAWS:
                raise ValueError(f"capture.law: expected one of {', '.join(LAWS)}, got {v!r}")
            out[k] = v
            continue
        try:
            if isinstance(v, bool):
                raise TypeError
            x = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"capture.{k}: expected a number, got {v!r}") from None
        bad = not math.isfinite(x) or (x < 0.0 if k == "aim_deg" else x <= 0.0)
        bad |= (k == "deg" and x >= 180.0) or (k in ("damping", "brake") and x > 1.0)
        if bad:
            limit = {"deg": " and < 180", "damping": " and <= 1", "brake": " and <= 1"}.get(k, "")
            low = ">= 0" if k == "aim_deg" else "> 0"
            raise ValueError(f"capture.{k}: must be a finite number {low}{limit}, got {v!r}")
        out[k] = x
    if out["law"] == "braking" and out["aim_deg"] >= out["deg"]:
        given = "" if "aim_deg" in kw else " (the default)"
        raise ValueError(f"capture.aim_deg: must be below capture.deg ({out['deg']:g}), "
                         f"got {out['aim_deg']!r}{given}")
    return out


def error_angle(obs) -> np.ndarray:
    """Rotation still to go (rad) of raw observation(s): the error quaternion's angle."""
    o = np.asarray(obs, dtype=np.float64)
    dq = o[..., _k.OB_DQ:_k.OB_DQ + 4]
    return 2.0 * np.arctan2(np.linalg.norm(dq[..., 1:], axis=-1), np.abs(dq[..., 0]))


def _rows(obs):
    """What both laws read of raw observation(s) ``obs``: ``(rows (N, L), whether obs was one
    row, error axis, rate error ω̃ − ω̃f (the target may spin), J̃, ũ_max)``."""
    o = np.asarray(obs, dtype=np.float64)
    single = o.ndim == 1
    o = o.reshape(1, -1) if single else o
    v = o[:, _k.OB_DQ + 1:_k.OB_DQ + 4]
    axis = v / np.maximum(np.linalg.norm(v, axis=1), 1e-12)[:, None]
    w = o[:, _k.OB_W:_k.OB_W + 3] - o[:, _k.OB_WF:_k.OB_WF + 3]
    J = o[:, _k.OB_J:_k.OB_J + 3]
    umax = np.maximum(o[:, _k.OB_UMAX:_k.OB_UMAX + 3], 1e-12)
    return o, single, axis, w, J, umax


def pd_action(obs, kp: float, damping: float, dt: float) -> np.ndarray:
    """The capture law's normalised action for raw observation(s) ``obs`` ((L,) or (N, L));
    ``dt`` the control step in time units T."""
    o, single, axis, w, J, umax = _rows(obs)
    theta = error_angle(o)
    a = np.clip(kp * theta[:, None] * axis - damping * J * w / (umax * dt), -1.0, 1.0)
    return a[0] if single else a


def braking_action(obs, brake: float, aim: float, damping: float, dt: float) -> np.ndarray:
    """The braking-curve approach law's normalised action for raw observation(s) ``obs``
    ((L,) or (N, L)); ``brake`` the share β of the deceleration about the error axis,
    ``aim`` the angle (rad) it brakes to, ``dt`` the control step in time units T."""
    o, single, axis, w, J, umax = _rows(obs)
    inv_p = o[:, _k.OB_INV_P]
    # normalised torque per unit acceleration about the axis; its norm in the bound's own
    # p-norm (the max for a per-axis bound) is the inverse of the largest acceleration
    g = np.abs(J * axis / umax)
    gmax = np.max(g, axis=1)
    p = np.where(inv_p > 0.0, 1.0 / np.maximum(inv_p, 1e-12), 1.0)
    scaled = g / np.maximum(gmax, 1e-300)[:, None]
    gn = np.where(inv_p > 0.0, gmax * np.sum(scaled ** p[:, None], axis=1) ** (1.0 / p), gmax)
    s = 1.0 / np.maximum(gn, 1e-12)
    d = np.maximum(error_angle(o) - aim, 0.0)
    c = brake * s * dt
    speed = np.sqrt(c * c + 2.0 * brake * s * d) - c
    # a rate limit r (observed as r / (1 + r), 1 without one): the curve's rate about each
    # axis stays within 0.9 r less the target's own rate
    squashed = np.clip(o[:, _k.OB_RATE_LIMIT:_k.OB_RATE_LIMIT + 3], 0.0, 1.0)
    limited = squashed < 1.0
    r = np.where(limited, squashed / np.where(limited, 1.0 - squashed, 1.0), np.inf)
    room = np.maximum(0.9 * r - np.abs(o[:, _k.OB_WF:_k.OB_WF + 3]), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        cap = np.where(limited, room / np.abs(axis), np.inf)
    speed = np.minimum(speed, np.min(cap, axis=1))
    a = np.clip(damping * J * (speed[:, None] * axis - w) / (umax * dt), -1.0, 1.0)
    return a[0] if single else a


class CaptureHandover(ObservingActionWrapper):
    """The settling law instead of the policy within ``deg`` of the target (see the module docstring).

    ``info["captured"]``: whether the settling law flew the step.
    """

    name = "CaptureHandover"

    def __init__(self, env: gym.Env, deg: float = 1.0, kp: float = 5.0, damping: float = 0.8,
                 law: str = "pd", brake: float = 0.9, aim_deg: float = 0.8):
        super().__init__(env, deg=deg, kp=kp, damping=damping, law=law, brake=brake, aim_deg=aim_deg)
        kw = check({"deg": deg, "kp": kp, "damping": damping, "law": law, "brake": brake, "aim_deg": aim_deg})
        self.deg, self.kp, self.damping = kw["deg"], kw["kp"], kw["damping"]
        self.law, self.brake, self.aim_deg = kw["law"], kw["brake"], kw["aim_deg"]
        self.dt = float(env.unwrapped.control_dt)
        self._limit = math.radians(self.deg)
        self._aim = math.radians(self.aim_deg)
        tol = float(env.unwrapped.att_tol_deg)
        if self.law == "braking" and self.aim_deg >= tol:
            raise ValueError(f"capture.aim_deg: must be below the environment's success tolerance att_tol_deg "
                             f"({tol:g}), got {self.aim_deg:g}: inside aim_deg the braking law only removes the "
                             "rate, and would come to rest outside the tolerance")

    def act(self, obs, action):
        captured = bool(error_angle(obs) < self._limit)
        if captured:
            if self.law == "braking":
                action = braking_action(obs, self.brake, self._aim, self.damping, self.dt)
            else:
                action = pd_action(obs, self.kp, self.damping, self.dt)
        return action, {"captured": captured}
