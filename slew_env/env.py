"""``SlewEnv``: time-optimal rigid-body slews as a Gymnasium environment."""
from __future__ import annotations

import math
from typing import Optional

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .core import env_kernels as _k
from .core import task as _t
from .core.quaternion import qrotate
from .problem import SlewProblem
from .checks import is_finite, is_integer, is_real, whole
from .tasks import TaskDistribution, draw_task

from . import DEFAULT_MAX_EPISODE_STEPS, ENV_ID  # noqa: F401 (re-exported)
# A cone counts as violated when the sensor is inside it by more than this (rad):
# the same tolerance SlewProblem allows for a start on a cone boundary.
VIOLATION_TOL = 1e-9


def observation_bounds(max_cones: int):
    """(low, high) float32 arrays of the observation box for ``max_cones`` slots."""
    n = _k.obs_length(max_cones)
    low = np.zeros(n, dtype=np.float32)
    high = np.zeros(n, dtype=np.float32)

    def put(start, length, lo, hi):
        low[start:start + length] = lo
        high[start:start + length] = hi

    put(_k.OB_DQ, 4, -1.0, 1.0)
    low[_k.OB_DQ] = 0.0
    put(_k.OB_W, 3, -_k.RATE_OBS_MAX, _k.RATE_OBS_MAX)
    put(_k.OB_WF, 3, -_k.RATE_OBS_MAX, _k.RATE_OBS_MAX)
    put(_k.OB_TARGET, 3, -1.0, 1.0)
    put(_k.OB_SENSOR, 3, -1.0, 1.0)
    put(_k.OB_J, 3, 0.0, 1.0)
    put(_k.OB_UMAX, 3, 0.0, 1.0)
    put(_k.OB_POINTING, 1, 0.0, 1.0)
    put(_k.OB_INV_P, 1, 0.0, 1.0)
    put(_k.OB_RATE_LIMIT, 3, 0.0, 1.0)
    for k in range(max_cones):
        o = _k.OB_CONES + _k.OB_CONE_STRIDE * k
        put(o, 3, -1.0, 1.0)
        put(o + 3, 1, 0.0, np.pi)
        put(o + 4, 1, -np.pi, np.pi)
        put(o + 5, 1, 0.0, 1.0)
    return low, high


def as_actions(name, value, shape) -> np.ndarray:
    """``value`` as an array of real numbers of ``shape``, or a ``ValueError`` naming ``name``.

    Text, booleans, complex numbers, ``None`` and other non-numbers are refused (numpy would
    parse ``"1"`` as 1, take ``True`` as 1 and drop an imaginary part). NaN and inf pass: the
    kernels saturate them. Arrays of a real dtype are checked by dtype only (no per-element loop).
    """
    expected = f"real numbers of shape {shape}"
    if isinstance(value, np.ndarray):
        arr = value
    else:
        if value is None or isinstance(value, (str, bytes, dict, set)):
            raise ValueError(f"{name}: expected {expected}, got {value!r:.80}")
        try:
            arr = np.asarray(value)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{name}: expected {expected}, got {value!r:.80}") from None
        if isinstance(value, (list, tuple)) and arr.dtype.kind in "fiu":
            # numpy reads [True, 0.5, 0] as floats: look at the entries of a (small) list
            flat = np.asarray(value, dtype=object).ravel()
            if not all(is_real(v) or isinstance(v, np.ndarray) and v.dtype.kind in "fiu" for v in flat):
                raise ValueError(f"{name}: expected {expected}, got {value!r:.80}")
    if arr.dtype.kind == "O" and all(is_real(v) for v in arr.ravel()):
        arr = arr.astype(np.float64)
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"{name}: expected {expected}, got an array of dtype {arr.dtype} {value!r:.80}")
    if arr.shape != shape:
        raise ValueError(f"{name}: expected {expected}, got shape {arr.shape}")
    return arr


def check_render_mode(render_mode, modes) -> None:
    """``render_mode``: ``None`` or one of ``modes``; a ``ValueError`` naming it otherwise."""
    if render_mode is not None and not (isinstance(render_mode, str) and render_mode in modes):
        raise ValueError(f"render_mode: expected one of {modes} or None, got {render_mode!r:.80}")


def check_seed(seed):
    """``seed`` (``None`` or a whole number >= 0) as an int or ``None``; ``ValueError`` naming ``seed``."""
    if seed is None:
        return None
    if not (is_integer(seed) and seed >= 0):
        raise ValueError(f"seed: expected None or a whole number >= 0, got {seed!r:.80}")
    return int(seed)


def check_options(options, keys) -> dict:
    """``options`` (``None`` or a dict with keys among ``keys``) as a dict."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise ValueError(f"options: expected None or a dict, got {options!r:.80}")
    unknown = [k for k in options if k not in keys]
    if unknown:
        raise ValueError(f"options: unknown key(s) {unknown!r:.120}; use "
                         + " or ".join(repr(k) for k in keys))
    return dict(options)


# the longest control step (time units T) and the most RK4 sub-steps a step may ask for
MAX_CONTROL_DT = 10.0
MAX_SUBSTEPS = 10_000


def make_config(control_dt, substeps, success_bonus, violation_penalty, terminate_on_violation,
                shaping, att_tol_deg, rate_tol, max_episode_steps=None) -> np.ndarray:
    """Validate the environment arguments and pack them for the kernels."""
    def positive(name, v):
        if not (is_finite(v) and v > 0.0):
            raise ValueError(f"{name}: must be a positive finite number, got {v!r:.80}")
        return float(v)

    def nonneg(name, v):
        if not (is_finite(v) and v >= 0.0):
            raise ValueError(f"{name}: must be a finite number >= 0, got {v!r:.80}")
        return float(v)

    if not (isinstance(terminate_on_violation, (bool, np.bool_))
            or (is_real(terminate_on_violation) and terminate_on_violation in (0, 1))):
        raise ValueError(f"terminate_on_violation: must be True or False, got {terminate_on_violation!r:.80}")
    cfg = np.zeros(_k.CFG_LENGTH)
    cfg[_k.C_DT] = positive("control_dt", control_dt)
    if cfg[_k.C_DT] > MAX_CONTROL_DT:
        raise ValueError(f"control_dt: at most {MAX_CONTROL_DT:g} time units T (a slew takes a few), "
                         f"got {control_dt!r:.80}")
    # (each sub-step is compiled work that no signal interrupts: 1e12 of them had run for hours)
    cfg[_k.C_SUBSTEPS] = whole("substeps", substeps, 1, MAX_SUBSTEPS)
    cfg[_k.C_BONUS] = nonneg("success_bonus", success_bonus)
    cfg[_k.C_PENALTY] = nonneg("violation_penalty", violation_penalty)
    cfg[_k.C_TERMINATE] = 1.0 if terminate_on_violation else 0.0
    cfg[_k.C_SHAPING] = nonneg("shaping", shaping)
    cfg[_k.C_ATT_TOL] = math.radians(positive("att_tol_deg", att_tol_deg))
    cfg[_k.C_RATE_TOL] = positive("rate_tol", rate_tol)
    if max_episode_steps is not None:
        cfg[_k.C_MAX_STEPS] = whole("max_episode_steps", max_episode_steps, 1)
    cfg[_k.C_VIOL_TOL] = VIOLATION_TOL
    return cfg


def resolve_distribution(task_distribution, max_cones):
    dist = TaskDistribution.resolve(task_distribution)
    if dist.max_cones > max_cones:
        raise ValueError(f"max_cones: task distribution {dist.name!r} draws up to {dist.max_cones} "
                         f"cones but max_cones={max_cones}")
    return dist


# cone slots an environment may observe (each adds 6 numbers to the observation; 1e12 had asked
# numpy for the memory and failed with a MemoryError naming no argument)
MAX_CONE_SLOTS = 64


def check_max_cones(max_cones):
    return whole("max_cones", max_cones, 0, MAX_CONE_SLOTS)


def problem_to_task(problem, max_cones: int) -> tuple[SlewProblem, np.ndarray]:
    """Validate a ``SlewProblem`` or dict and pack it with ``max_cones`` slots."""
    prob = SlewProblem.from_dict(problem)
    if len(prob.cones) > max_cones:
        raise ValueError(f"cones: the problem has {len(prob.cones)} cones but this environment "
                         f"observes at most max_cones={max_cones}; make it with a larger max_cones")
    return prob, prob.to_task_array(max_cones)


class SlewEnv(gym.Env):
    """Time-optimal slew of a rigid spacecraft, with keep-out cones on a body sensor.

    A rigid body with principal inertia ``J`` and a bounded torque must turn from
    rest at ``q0`` to rest at a target (a full attitude ``qf`` or, pointing-only,
    a sensor direction) as fast as possible, without the sensor entering any
    keep-out cone and without exceeding a per-axis rate limit. Conventions
    (scalar-first quaternions, body→inertial, Euler's equations) are those of
    ``shared/CONVENTIONS.md``. ``T = sqrt(J_max / u_max)`` is the problem's time
    unit; times, rates and rewards below are made scale-free with it.

    **Action space** — ``Box(-1, 1, (3,), float32)``: normalised torque ``a``.

    ====  =====================================================================
    Num   Action
    ====  =====================================================================
    0-2   torque on body axis i as a fraction of ``u_max,i``
    ====  =====================================================================

    The torque is ``u_i = u_max,i · v_i`` with ``v`` = ``a`` clipped to [-1, 1]
    and, for a p-norm bound, scaled radially onto the unit p-ball when outside
    it (``dynamics.torque_from_action``). It is held for the whole control step.
    Out-of-range values are saturated, not rejected; a NaN component gives zero
    torque on that axis, so no action can put NaN into the state. An action of
    the wrong shape, or not of real numbers (text, booleans, complex numbers,
    ``None``), raises ``ValueError`` naming ``action``.

    **Observation space** — ``Box(float32)`` of length ``27 + 6·max_cones``
    (51 for the default ``max_cones=4``). Body frame = current body axes.

    =======  ===================================================  ==========  =========
    Index    Observation                                          Min         Max
    =======  ===================================================  ==========  =========
    0-3      error quaternion ``q* ⊗ qf`` (scalar first, scalar   -1 (0)      1
             >= 0): the rotation still to go, body frame. For a
             pointing target: the shortest rotation taking the
             sensor onto the target direction, body frame
    4-6      body rate ``ω · T`` (clipped, see below)             -1e4        1e4
    7-9      target body rate ``ωf · T`` (clipped)                -1e4        1e4
    10-12    target sensor direction, body frame                  -1          1
    13-15    sensor axis, body frame                              -1          1
    16-18    inertia ``J / J_max``                                0           1
    19-21    torque bound ``u_max / max(u_max)``                  0           1
    22       1 if the target is pointing-only (roll free)         0           1
    23       ``1/p`` of the torque bound, 0 for per-axis          0           1
    24-26    rate limit ``r/(1+r)``, ``r = rate_max,i · T``;      0           1
             1 without a rate limit
    27+6k    cone slot k: axis, body frame (3)                    -1          1
    30+6k    cone slot k: half-angle (rad)                        0           π
    31+6k    cone slot k: current margin, angle(sensor, axis)     -π          π
             − half-angle (rad); negative inside
    32+6k    cone slot k: mask, 1 present, 0 absent               0           1
    =======  ===================================================  ==========  =========

    Absent cone slots are all zero. Every observation lies inside the space.
    All bounds are finite because Gymnasium's checker warns on infinite ones: the
    rates are clipped at ±1e4, which no episode from rest approaches (``|ω|·T``
    grows by at most ``√3·(J_max/J_min)·t/T``, under 90 in 400 steps for the
    provided distributions), and the rate limit is squashed so that "none" is 1.

    **Reward** — time-optimal: a cost per unit (nondimensional) time, plus terms.

    ======================================  =================================================
    Term                                    Value per step
    ======================================  =================================================
    time                                    ``-control_dt`` (the time elapsed, in units T;
                                            less on a step cut short by a violation)
    success                                 ``+success_bonus`` on the step that succeeds
    violation, ``terminate_on_violation``   ``-violation_penalty`` once, and the episode ends
    violation, otherwise                    ``-violation_penalty × control_dt × (sub-steps in
                                            violation / substeps)``: the penalty per unit
                                            time spent in violation
    shaping (``shaping`` weight)            ``shaping · (Φ(s') − Φ(s))``,
                                            ``Φ = −(error angle + ‖ω − ωf‖·T)``, and
                                            ``Φ = 0`` for a terminal ``s'``
    ======================================  =================================================

    The shaping term is potential-based with a zero terminal potential, so over an
    episode it adds ``−Φ(s0)`` (a constant of the start) plus, if truncated, the
    last potential; it does not change which policy is optimal for the undiscounted
    return. It is ``Φ(s') − Φ(s)``, not ``γΦ(s') − Φ(s)``: a learner discounting with
    γ < 1 also pays ``(1 − γ)·|Φ|`` per step (docs/RL.md, "The reward as the learner
    sees it").
    ``shaping=0`` gives the pure time-optimal reward.

    **Constraints** — a violation is the sensor inside a cone by more than 1e-9
    rad, or ``|ω_i| > rate_max,i``. Both are checked after every RK4 sub-step,
    not only at control instants. With ``terminate_on_violation`` the step stops
    at the first violating sub-step and the observation is that state.

    **Starting state** — ``reset(seed=..., options={"problem": p})`` poses the
    given ``SlewProblem`` or dict (validated by ``SlewProblem.from_dict``; more
    cones than ``max_cones`` raises ``ValueError`` naming ``cones``). Without a
    problem, a task is drawn with ``self.np_random`` from ``task_distribution``
    (see ``slew_env.tasks.TaskDistribution``). The body starts at ``q0, ω0``.

    **Episode end**

    - terminated: success — error angle (full target: the angle of
      ``qf* ⊗ q``; pointing: the angle between sensor and target) below
      ``att_tol_deg`` and ``‖ω − ωf‖·T < rate_tol`` at a control instant;
    - terminated: a violation, when ``terminate_on_violation`` is true;
    - truncated: only by the ``TimeLimit`` wrapper (``max_episode_steps=400``
      in the registration of ``slew_env/Slew-v0``).

    A terminated episode is over: ``step()`` then raises
    ``gymnasium.error.ResetNeeded`` until ``reset()`` (as it does before the first
    reset), rather than integrating on and paying the bonus or penalty again.

    ``info`` keys: ``is_success``, ``violation`` (any sub-step of this step),
    ``min_cone_margin`` (smallest margin over this step's sub-steps, rad;
    ``inf`` without cones), ``attitude_error`` (rad), ``rate_error``
    (``‖ω − ωf‖·T``), ``time`` (physical, since reset).

    **Arguments**

    ==========================  ================  ==============================================
    Argument                    Default           Meaning
    ==========================  ================  ==============================================
    ``task_distribution``       "full-attitude"   family name, ``TaskDistribution`` or dict
    ``max_cones``               4                 cone slots in the observation (at most 64)
    ``control_dt``              0.05              control step, in time units T (at most 10)
    ``substeps``                4                 RK4 sub-steps per control step (at most 10,000; one
                                                  that would turn the body more than 0.5 rad is
                                                  split, so a fast spin stays finite)
    ``success_bonus``           10.0              reward on success
    ``violation_penalty``       10.0              see Reward
    ``terminate_on_violation``  True              a violation ends the episode
    ``shaping``                 1.0               weight of the shaping term (0: none)
    ``att_tol_deg``             1.0               success tolerance on the error angle (deg)
    ``rate_tol``                0.02              success tolerance on ``‖ω − ωf‖·T``
    ``render_mode``             None              ``"rgb_array"`` or ``"human"``
    ==========================  ================  ==============================================

    Rendering draws the sensor's path on the unit sphere with the cones, the
    start and the target, and the time histories of the error angle, the rates
    and the torques (``slew_env.rendering``).

    ``slew_env.shield.ConeShield(env)`` filters any policy's actions so that the
    sensor stays out of the cones (a control barrier function on the observation).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 20}

    def __init__(self, task_distribution="full-attitude", max_cones: int = 4,
                 control_dt: float = 0.05, substeps: int = 4, success_bonus: float = 10.0,
                 violation_penalty: float = 10.0, terminate_on_violation: bool = True,
                 shaping: float = 1.0, att_tol_deg: float = 1.0, rate_tol: float = 0.02,
                 render_mode: Optional[str] = None):
        check_render_mode(render_mode, self.metadata["render_modes"])
        self.render_mode = render_mode
        self.max_cones = check_max_cones(max_cones)
        self.task_distribution = resolve_distribution(task_distribution, self.max_cones)
        self._dist = self.task_distribution.to_array()
        self._cfg = make_config(control_dt, substeps, success_bonus, violation_penalty,
                                terminate_on_violation, shaping, att_tol_deg, rate_tol)
        self.control_dt = float(control_dt)
        self.att_tol_deg = float(att_tol_deg)     # success tolerance (deg), read by wrappers such as CaptureHandover
        self.substeps = int(substeps)
        self.terminate_on_violation = bool(terminate_on_violation)

        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        low, high = observation_bounds(self.max_cones)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

        self._task = np.zeros(_t.task_length(self.max_cones))
        self._st = np.zeros(_k.state_length(self.max_cones))
        self._obs = np.zeros(_k.obs_length(self.max_cones), dtype=np.float32)
        self._out = np.zeros(_k.OUT_LENGTH)
        self._act = np.zeros(3)
        self._problem: Optional[SlewProblem] = None
        self._has_reset = False
        self._terminated = False
        self._history = None
        self._renderer = None

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        seed = check_seed(seed)
        problem = check_options(options, ("problem",)).get("problem")
        super().reset(seed=seed)
        if problem is not None:
            self._problem, self._task[:] = problem_to_task(problem, self.max_cones)
        else:
            draw_task(self.np_random, self._dist, self._task)
            self._problem = None
        _k.reset_env(self._task, self._st, self._cfg, self._obs, self._out)
        self._has_reset = True
        self._terminated = False
        if self.render_mode is not None:
            self._history = _History()
            self._history.record(self._task, self._st, self._out)
            if self.render_mode == "human":
                self.render()
        return self._obs.copy(), self._info()

    def step(self, action):
        if not self._has_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        if self._terminated:
            raise gym.error.ResetNeeded("step() after the episode terminated (success, or a violation with "
                                        "terminate_on_violation); call reset() first")
        act = self._act
        if type(action) is np.ndarray and action.shape == (3,) and action.dtype.kind in "fiu":
            act[:] = action
        else:
            act[:] = as_actions("action", action, (3,))
        _k.step_env(self._task, self._st, act, self._cfg, self._obs, self._out)
        reward, terminated, _, success, violation, margin, att, rate_err, time = \
            self._out[:_k.R_TORQUE].tolist()
        info = {"is_success": success > 0.5, "violation": violation > 0.5,
                "min_cone_margin": margin, "attitude_error": att, "rate_error": rate_err,
                "time": time}
        if self._history is not None:
            self._history.record(self._task, self._st, self._out)
            if self.render_mode == "human":
                self.render()
        self._terminated = terminated > 0.5
        return self._obs.copy(), reward, self._terminated, False, info

    def _info(self) -> dict:
        o = self._out
        return {"is_success": bool(o[_k.R_SUCCESS] > 0.5), "violation": bool(o[_k.R_VIOLATION] > 0.5),
                "min_cone_margin": float(o[_k.R_MIN_MARGIN]), "attitude_error": float(o[_k.R_ATT_ERR]),
                "rate_error": float(o[_k.R_RATE_ERR]), "time": float(o[_k.R_TIME])}

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; make the environment with "
                            'render_mode="rgb_array" or "human"')
            return None
        if not self._has_reset:
            raise gym.error.ResetNeeded("call reset() before render()")
        from .rendering import SlewRenderer
        if self._renderer is None:
            self._renderer = SlewRenderer(fps=self.metadata["render_fps"])
        frame = self._renderer.draw(self._task, self._history.arrays())
        if self.render_mode == "human":
            self._renderer.show(frame)
            return None
        return frame

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ------------------------------------------------------------------ introspection
    @property
    def problem(self) -> SlewProblem:
        """The slew of the current episode."""
        if self._problem is None:
            if not self._has_reset:
                raise gym.error.ResetNeeded("no problem posed yet; call reset()")
            self._problem = SlewProblem.from_task_array(self._task)
        return self._problem

    @property
    def state(self) -> np.ndarray:
        """Copy of the physical state ``[q0, q1, q2, q3, ω1, ω2, ω3]``."""
        return self._st[_k.S_X:_k.S_X + 7].copy()

    @property
    def last_torque(self) -> np.ndarray:
        """Copy of the torque applied during the last step (physical units; zeros after reset)."""
        return self._out[_k.R_TORQUE:_k.R_TORQUE + 3].copy()

    @property
    def time(self) -> float:
        """Physical time since reset."""
        return float(self._st[_k.S_TIME])

    @property
    def task_array(self) -> np.ndarray:
        """Copy of the current problem in the flat layout of ``slew_env.core.task``."""
        return self._task.copy()


class _History:
    """Per-step record for rendering (kept only when a render mode is set)."""

    def __init__(self):
        self.rows = []

    def record(self, task, st, out):
        x = st[_k.S_X:_k.S_X + 7]
        T = task[_t.T_TUNIT]
        s_i = np.asarray(qrotate(x[:4].copy(), task[_t.T_SENSOR:_t.T_SENSOR + 3].copy()))
        u_norm = out[_k.R_TORQUE:_k.R_TORQUE + 3] / task[_t.T_UMAX:_t.T_UMAX + 3]
        self.rows.append(np.concatenate(([st[_k.S_TIME], out[_k.R_ATT_ERR]], s_i, x[4:7] * T, u_norm)))

    def arrays(self) -> dict:
        a = np.array(self.rows)
        return {"time": a[:, 0], "attitude_error": a[:, 1], "sensor": a[:, 2:5],
                "rates": a[:, 5:8], "torque": a[:, 8:11]}
