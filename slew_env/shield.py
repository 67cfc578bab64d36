"""``ConeShield``: a keep-out-cone safety filter for any policy flying ``SlewEnv``.

A control barrier function on the observation (``slew_env.core.shield``) moves the
policy's action only as much as needed to keep the sensor out of the cones, each
enlarged by ``margin_deg``. It needs no more than the observation, so the filter
that trained with a policy can fly with it. Use it as a wrapper::

    env = ConeShield(gym.make("slew_env/Slew-v0", task_distribution="pointing-cones"))

or on raw observations and actions (one or a batch)::

    shield = ConeShieldFilter(max_cones=4)
    safe_action = shield(obs, action)

``info["shield_active"]`` is the number of cone conditions that changed the action of
the step, ``info["shield_feasible"]`` whether the torque box could meet them all (a
policy that drove in too fast gets the strongest push away instead).
"""
from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np

from .checks import is_real
from .core import env_kernels as _k
from .core import shield as _s
from .env import as_actions


class ConeShieldFilter:
    """The filter as a function of (raw observation, action); see ``slew_env.core.shield``.

    ==================  ========  ===================================================
    Argument            Default   Meaning
    ==================  ========  ===================================================
    ``max_cones``       4         cone slots of the observation
    ``margin_deg``      0.5       every cone enlarged by this (deg), at most half the
                                  target's clearance from that cone
    ``barrier_rate``    20.0      λ, per time unit T: how fast the margin may be used
    ``brake``           0.6       braking deceleration assumed, as a fraction of the
                                  largest the torque box gives away from the cone
    ``sweeps``          20        dual sweeps over the cones (several near at once)
    ``gap_deg``         1.0       a gap between two cones narrower than this (deg),
                                  and the sharp notch where two cones cross, are
                                  filled by bridge cones (``core.shield.pair_bridges``):
                                  no action holds their tips; 0: never
    ==================  ========  ===================================================
    """

    def __init__(self, max_cones: int = 4, margin_deg: float = 0.5, barrier_rate: float = 20.0,
                 brake: float = 0.6, sweeps: int = 20, gap_deg: float = 1.0):
        def positive(name, x, upper=math.inf):
            try:
                if not is_real(x):
                    raise TypeError
                x = float(x)
            except (TypeError, ValueError):
                raise ValueError(f"{name}: must be a finite number in (0, {upper}], got {x!r}") from None
            if not (math.isfinite(x) and 0.0 < x <= upper):
                raise ValueError(f"{name}: must be a finite number in (0, {upper}], got {x!r}")
            return x

        def whole(name, x, lo, hi):
            try:       # (not text or a boolean: "0.5" and True had been read as numbers)
                ok = is_real(x) and float(x) == int(x) and lo <= int(x) <= hi
            except (TypeError, ValueError, OverflowError):
                ok = False
            if not ok:
                raise ValueError(f"{name}: must be a whole number in [{lo}, {hi}], got {x!r}")
            return int(x)

        def angle(name, x):
            try:
                v = float(x) if is_real(x) else math.nan
            except (TypeError, ValueError):
                v = math.nan
            if not (math.isfinite(v) and 0.0 <= v < 90.0):
                raise ValueError(f"{name}: must be a finite number in [0, 90), got {x!r}")
            return v

        self.max_cones = whole("max_cones", max_cones, 0, _s.MAX_CONES)
        margin = angle("margin_deg", margin_deg)
        self.sweeps = whole("sweeps", sweeps, 1, 10_000)
        self.margin_deg = margin
        self.barrier_rate = positive("barrier_rate", barrier_rate)
        self.brake = positive("brake", brake, 1.0)
        gap = angle("gap_deg", gap_deg)
        self.gap_deg = gap
        self._params = _s.make_params(math.radians(margin), self.barrier_rate, self.brake, self.sweeps,
                                      math.radians(gap))
        self._len = _k.obs_length(self.max_cones)
        self.last = np.zeros(_s.OUT_LENGTH)

    def config(self) -> dict:
        return {"margin_deg": self.margin_deg, "barrier_rate": self.barrier_rate, "brake": self.brake,
                "sweeps": self.sweeps, "gap_deg": self.gap_deg}

    def __call__(self, obs, action) -> np.ndarray:
        """Filtered action(s): ``obs`` (L,) or (N, L) raw observations, ``action`` (3,) or (N, 3)."""
        o = np.asarray(obs, dtype=np.float64)
        a = np.asarray(action, dtype=np.float64)
        single = o.ndim == 1
        o2 = o.reshape(1, -1) if single else o
        a2 = a.reshape(1, -1) if a.ndim == 1 else a
        if o2.ndim != 2 or o2.shape[1] != self._len:
            raise ValueError(f"obs: expected shape ({self._len},) or (N, {self._len}) for max_cones="
                             f"{self.max_cones}, got {o.shape}")
        if not np.isfinite(o2).all():
            bad = np.argwhere(~np.isfinite(o2))[0]
            raise ValueError(f"obs: not finite at {tuple(int(i) for i in bad) if not single else int(bad[1])}; "
                             "the filter needs a finite observation")
        if a2.ndim != 2 or a2.shape != (o2.shape[0], 3):
            raise ValueError(f"action: expected shape (3,) or ({o2.shape[0]}, 3), got {a.shape}")
        v = np.empty((o2.shape[0], 3))
        out = np.empty((o2.shape[0], _s.OUT_LENGTH))
        _s.shield_batch(np.ascontiguousarray(o2), np.ascontiguousarray(a2), self._params, self.max_cones, v, out)
        self.last = out[0] if single else out
        return v[0] if single else v


class ObservingActionWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """A ``SlewEnv`` wrapper whose action depends on the current (raw) observation.

    Subclasses implement ``act(obs, action) -> (action sent on, dict of info entries)``;
    the action arrives as a float64 array of shape (3,), and pass their constructor's
    arguments (all but ``env``) to this ``__init__``: Gymnasium records them in ``env.spec``
    (``RecordConstructorArgs``), so ``env.spec.make()`` and Gymnasium's ``check_env``, which
    re-create the wrapped environment from its spec, can rebuild the wrapper. ``name`` names
    the wrapper in the error raised when the inner environment is not a ``SlewEnv``.
    """

    name = "this wrapper"

    def __init__(self, env: gym.Env, **constructor_args):
        gym.utils.RecordConstructorArgs.__init__(self, **constructor_args)
        gym.Wrapper.__init__(self, env)
        if getattr(env.unwrapped, "max_cones", None) is None:
            raise ValueError(f"env: {self.name} wraps a slew_env SlewEnv (it reads its observation)")
        self._obs = None

    def act(self, obs, action):
        raise NotImplementedError

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._obs = obs
        return obs, info

    def step(self, action):
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        # (the environment's own check: text, booleans and complex numbers refused by name, as the
        # unwrapped environment refuses them; numpy alone had read "1" as 1 and dropped 5j)
        arr = np.asarray(as_actions("action", action, (3,)), dtype=np.float64)
        sent, extra = self.act(self._obs, arr)
        obs, reward, terminated, truncated, info = self.env.step(sent)
        self._obs = obs
        info.update(extra)
        return obs, reward, terminated, truncated, info


class ConeShield(ObservingActionWrapper):
    """``SlewEnv`` whose actions pass through ``ConeShieldFilter`` (arguments as there)."""

    name = "ConeShield"

    def __init__(self, env: gym.Env, margin_deg: float = 0.5, barrier_rate: float = 20.0, brake: float = 0.6,
                 sweeps: int = 20, gap_deg: float = 1.0):
        super().__init__(env, margin_deg=margin_deg, barrier_rate=barrier_rate, brake=brake, sweeps=sweeps,
                         gap_deg=gap_deg)
        self.filter = ConeShieldFilter(env.unwrapped.max_cones, margin_deg, barrier_rate, brake, sweeps, gap_deg)
        _warn_control_dt(getattr(env.unwrapped, "control_dt", None), self.filter.margin_deg, self.filter.brake)

    def act(self, obs, action):
        safe = self.filter(obs, action)
        return safe, {"shield_active": int(self.filter.last[_s.F_ACTIVE]),
                      "shield_feasible": bool(self.filter.last[_s.F_FEASIBLE] > 0.5)}


class ConeShieldVector(gym.vector.VectorWrapper):
    """``SlewVectorEnv`` (or any vector of ``SlewEnv`` copies) whose batched actions pass through
    ``ConeShieldFilter``; arguments as ``ConeShield``. ``infos["shield_active"]`` and
    ``infos["shield_feasible"]`` are arrays, with Gymnasium's ``_shield_active`` /
    ``_shield_feasible`` masks: a copy that ended on the previous step is being reset
    (next-step autoreset) and its action is ignored, so it has no entry."""

    def __init__(self, env, margin_deg: float = 0.5, barrier_rate: float = 20.0, brake: float = 0.6,
                 sweeps: int = 20, gap_deg: float = 1.0):
        super().__init__(env)
        max_cones = getattr(env, "max_cones", None)
        if max_cones is None:
            max_cones = _obs_max_cones(env.single_observation_space.shape)
        self.filter = ConeShieldFilter(max_cones, margin_deg, barrier_rate, brake, sweeps, gap_deg)
        _warn_control_dt(getattr(env, "control_dt", None), self.filter.margin_deg, self.filter.brake)
        self._obs = None
        self._ended = None

    def reset(self, **kwargs):
        obs, infos = self.env.reset(**kwargs)
        self._obs = obs
        self._ended = np.zeros(len(obs), dtype=bool)
        return obs, infos

    def step(self, actions):
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        safe = self.filter(self._obs, actions)
        obs, rewards, terminations, truncations, infos = self.env.step(safe)
        self._obs = obs
        last = np.atleast_2d(self.filter.last)
        live = ~self._ended
        self._ended = np.asarray(terminations, bool) | np.asarray(truncations, bool)
        infos = dict(infos)
        infos["shield_active"] = np.where(live, last[:, _s.F_ACTIVE], 0).astype(int)
        infos["_shield_active"] = live
        infos["shield_feasible"] = np.where(live, last[:, _s.F_FEASIBLE] > 0.5, True)
        infos["_shield_feasible"] = live.copy()
        return obs, rewards, terminations, truncations, infos


def _warn_control_dt(dt, margin_deg, brake):
    # the defaults hold the cones at control steps of 0.05 T (the environment's default); a
    # longer step needs a wider margin and a gentler braking assumption (PD law, 100 tasks of
    # seed 7: at 0.1 T the defaults entered cones on 19, margin 1° and brake 0.3 on none; at
    # 0.2 T no setting tried held them, 23-29 entries)
    if dt is not None and dt > 0.05 + 1e-12 and (margin_deg < 10.0 * dt - 1e-9 or brake > 0.03 / dt + 1e-9):
        warnings.warn(f"ConeShield: control_dt={dt:g} is longer than the 0.05 the filter's defaults were tuned "
                      f"for; the sensor can slip into a cone between control instants. Use margin_deg >= "
                      f"{10.0 * dt:g} and brake <= {0.03 / dt:.3g} (at 0.1 these held 100 test flights; beyond 0.1 "
                      f"none tried did)", stacklevel=3)


def _obs_max_cones(shape) -> int:
    n = (int(shape[0]) - _k.OB_CONES) if shape else -1
    if n < 0 or n % _k.OB_CONE_STRIDE:
        raise ValueError(f"env: observations of shape {shape} are not SlewEnv observations")
    return n // _k.OB_CONE_STRIDE
