"""``SlewVectorEnv``: N copies of ``SlewEnv`` stepped in one compiled call.

Semantics are Gymnasium 1.x's (``AutoresetMode.NEXT_STEP``): the step after a
copy terminates or is truncated resets that copy and returns its first
observation with reward 0 and ``terminated = truncated = False``. With the same
seeds, problems and actions, the batch returns exactly what
``gymnasium.make_vec("slew_env/Slew-v0", vectorization_mode="sync")`` returns:

- ``reset(seed=s)`` seeds copy ``i`` with ``s + i`` (a list gives one seed per
  copy), as ``SyncVectorEnv`` does;
- each copy owns a generator and a pool of pre-drawn uniform blocks, consumed
  block by block exactly as ``SlewEnv.reset`` draws them, so the compiled step
  can reset finished copies without returning to Python;
- copies are truncated after ``max_episode_steps`` steps, as ``TimeLimit`` does.

``options={"problems": [p0, p1, ...]}`` poses one ``SlewProblem`` / dict per copy
(``None`` entries draw from the distribution); ``options={"problem": p}`` poses
the same problem in every copy; ``options={"reset_mask": mask}`` resets only
the masked copies. Infos are a dict of arrays with ``_key`` masks, every key
present for every copy (the same keys as ``SlewEnv``'s info).

``step(actions)`` takes real numbers of shape ``(num_envs, 3)``, one action per
copy (an action is not broadcast to every copy); any other shape or dtype (text,
booleans, complex numbers) raises ``ValueError`` naming ``actions``. A copy that
terminated is not stepped again: its next step is the autoreset above.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numba import njit

from .core import env_kernels as _k
from .core import task as _t
from .env import (DEFAULT_MAX_EPISODE_STEPS, as_actions, check_max_cones, check_options, check_render_mode,
                  check_seed, make_config, observation_bounds, problem_to_task, resolve_distribution)
from .checks import whole
from .tasks import BLOCK, MAX_BLOCKS, unplaceable_message

_INFO_KEYS = (("is_success", _k.R_SUCCESS, True), ("violation", _k.R_VIOLATION, True),
              ("min_cone_margin", _k.R_MIN_MARGIN, False), ("attitude_error", _k.R_ATT_ERR, False),
              ("rate_error", _k.R_RATE_ERR, False), ("time", _k.R_TIME, False))


@njit(cache=True)
def _retry_reset(i, tasks, sts, cfg, dist, pool, pool_pos, obs, outs):
    return _k.reset_from_pool(i, tasks, sts, cfg, dist, pool, pool_pos, obs, outs)


# bounds on the batch's size (numpy's MemoryError for 1e12 copies named no argument)
MAX_COPIES = 1 << 20
MAX_POOL_BLOCKS = 1024
MAX_POOL_BYTES = 4 * 2 ** 30


class SlewVectorEnv(VectorEnv):
    """A batch of ``num_envs`` ``SlewEnv`` copies (same arguments, see ``SlewEnv``).

    Extra arguments: ``num_envs``; ``max_episode_steps`` (default 400; ``None``
    never truncates); ``parallel`` (default False; True or False, nothing else):
    step the copies on numba threads; ``pool_blocks`` (default 4): uniform blocks
    pre-drawn per copy (memory ``num_envs × pool_blocks × 256 × 8`` bytes).

    ``parallel`` is off by default. On 2 idle cores it speeds up large batches
    (about 1.8x at 1024 copies), but when another process or the learner's own
    threads hold a core, every threaded call waits for a descheduled thread and
    a step becomes 5 to 15 times slower than the serial one, which is what
    happens during training on a small machine; at a load of 1.2 it was 123
    times slower at 64 copies (8,000 against 982,810 env-steps/s) and 9.5 times
    at 1024 (``benchmarks/bench_env.py``, session 34). Results are identical
    either way.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20,
                "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, max_episode_steps: Optional[int] = DEFAULT_MAX_EPISODE_STEPS,
                 task_distribution="full-attitude", max_cones: int = 4, control_dt: float = 0.05,
                 substeps: int = 4, success_bonus: float = 10.0, violation_penalty: float = 10.0,
                 terminate_on_violation: bool = True, shaping: float = 1.0, att_tol_deg: float = 1.0,
                 rate_tol: float = 0.02, render_mode: Optional[str] = None,
                 parallel: bool = False, pool_blocks: int = 4):
        n = whole("num_envs", num_envs, 1, MAX_COPIES)
        check_render_mode(render_mode, self.metadata["render_modes"])
        pool_blocks = whole("pool_blocks", pool_blocks, 1, MAX_POOL_BLOCKS)
        if n * pool_blocks * BLOCK * 8 > MAX_POOL_BYTES:
            raise ValueError(f"num_envs, pool_blocks: {n} copies × {pool_blocks} blocks of pre-drawn uniforms take "
                             f"{n * pool_blocks * BLOCK * 8 / 2 ** 30:.3g} GiB, more than the "
                             f"{MAX_POOL_BYTES / 2 ** 30:g} GiB allowed; use fewer")
        if not isinstance(parallel, (bool, np.bool_)):
            raise ValueError(f"parallel: must be True or False, got {parallel!r:.80}")
        self.max_cones = check_max_cones(max_cones)
        self.task_distribution = resolve_distribution(task_distribution, self.max_cones)
        self._cfg = make_config(control_dt, substeps, success_bonus, violation_penalty,
                                terminate_on_violation, shaping, att_tol_deg, rate_tol,
                                max_episode_steps)
        self.num_envs = n
        self.render_mode = render_mode
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self._dist = self.task_distribution.to_array()
        self.control_dt = float(control_dt)

        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)
        low, high = observation_bounds(self.max_cones)
        self.single_observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, n)
        self.observation_space = batch_space(self.single_observation_space, n)

        self._tasks = np.zeros((n, _t.task_length(self.max_cones)))
        self._sts = np.zeros((n, _k.state_length(self.max_cones)))
        self._obs = np.zeros((n, _k.obs_length(self.max_cones)), dtype=np.float32)
        self._outs = np.zeros((n, _k.OUT_LENGTH))
        self._actions = np.zeros((n, 3))
        self._pending = np.zeros(n, dtype=np.bool_)
        self._pool = np.empty((n, pool_blocks, BLOCK))
        self._pool_pos = np.full(n, pool_blocks, dtype=np.int64)
        self._rngs: list = [None] * n
        self._has_reset = False
        self.parallel = bool(parallel)
        self._step_kernel = _k.vec_step_parallel if self.parallel else _k.vec_step

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed=None, options: Optional[dict] = None):
        n = self.num_envs
        # Validate everything before touching any copy, so a bad call changes nothing.
        which, given = self._parse_options(options)
        if isinstance(seed, (list, tuple, np.ndarray)):
            seeds = list(seed.tolist() if isinstance(seed, np.ndarray) else seed)
            if len(seeds) != n:
                raise ValueError(f"seed: expected {n} seeds (one per copy), got {len(seeds)}")
            checked = []
            for s in seeds:
                try:
                    checked.append(check_seed(s))
                except ValueError:
                    raise ValueError(f"seed: a list of seeds must hold whole numbers >= 0 or None, "
                                     f"got {s!r:.80} in {seed!r:.80}") from None
            seeds = checked
        else:
            try:
                seed = check_seed(seed)
            except ValueError:
                raise ValueError(f"seed: expected None, a whole number >= 0 or a list of {n} of them "
                                 f"(one per copy), got {seed!r:.80}") from None
            seeds = [None] * n if seed is None else [seed + i for i in range(n)]
            super().reset(seed=seed)
        for i, s in enumerate(seeds):
            if s is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(s)
                self._refill(i)
        for i, task in given.items():
            self._tasks[i] = task

        _k.vec_reset(which, self._tasks, self._sts, self._cfg, self._dist, self._pool,
                     self._pool_pos, self._obs, self._outs, self._pending)
        self._service()
        self._has_reset = True
        return self._obs.copy(), self._infos()

    def step(self, actions):
        if not self._has_reset:
            # as the single environment says it (gymnasium's ResetNeeded; a RuntimeError before)
            raise ResetNeeded("call reset() before step()")
        if not (type(actions) is np.ndarray and actions.shape == self._actions.shape
                and actions.dtype.kind in "fiu"):
            actions = as_actions("actions", actions, self._actions.shape)
        np.copyto(self._actions, actions)
        if self._step_kernel(self._tasks, self._sts, self._actions, self._cfg, self._dist,
                             self._pool, self._pool_pos, self._obs, self._outs, self._pending):
            self._service()
        o = self._outs
        return (self._obs.copy(), o[:, _k.R_REWARD].copy(), o[:, _k.R_TERMINATED] > 0.5,
                o[:, _k.R_TRUNCATED] > 0.5, self._infos())

    def render(self):
        """One frame per copy showing its current attitude (no history is kept in the batch)."""
        if self.render_mode is None:
            return None
        from .rendering import SlewRenderer
        from .core.quaternion import qrotate
        renderer = SlewRenderer(fps=self.metadata["render_fps"])
        frames = []
        for i in range(self.num_envs):
            task, x = self._tasks[i], self._sts[i, :7]
            s = np.asarray(qrotate(x[:4].copy(), task[_t.T_SENSOR:_t.T_SENSOR + 3].copy()))
            T = task[_t.T_TUNIT]
            frames.append(renderer.draw(task, {
                "time": np.array([self._sts[i, _k.S_TIME]]),
                "attitude_error": np.array([self._outs[i, _k.R_ATT_ERR]]),
                "sensor": s[None, :], "rates": (x[4:7] * T)[None, :],
                "torque": (self._outs[i, _k.R_TORQUE:_k.R_TORQUE + 3]
                           / task[_t.T_UMAX:_t.T_UMAX + 3])[None, :]}))
        return tuple(frames)

    # ------------------------------------------------------------------ internals
    def _parse_options(self, options):
        """``which`` per copy (0 keep, 1 draw, 2 pose the given task) and the given tasks."""
        n = self.num_envs
        which = np.ones(n, dtype=np.int8)
        given = {}
        options = check_options(options, ("problems", "problem", "reset_mask"))
        problems = options.get("problems")
        if options.get("problem") is not None:
            if problems is not None:
                raise ValueError("options: give 'problem' or 'problems', not both")
            problems = [options["problem"]] * n
        if problems is not None:
            if not isinstance(problems, (list, tuple)):
                raise ValueError(f"problems: expected a list of {n} entries (a SlewProblem, a dict or None "
                                 f"per copy), got {problems!r:.80}")
            if len(problems) != n:
                raise ValueError(f"problems: expected {n} entries (one per copy), got {len(problems)}")
            for i, p in enumerate(problems):
                if p is not None:
                    try:
                        given[i] = problem_to_task(p, self.max_cones)[1]
                    except ValueError as e:     # (which copy's problem: the field alone did not say)
                        if "problem" in options:     # (one problem for every copy: no index to name)
                            raise
                        raise ValueError(f"problems[{i}]: {e}") from None
                    which[i] = 2
        if options.get("reset_mask") is not None:
            mask = self._mask(options["reset_mask"])
            if mask.shape != (n,):
                raise ValueError(f"reset_mask: expected shape ({n},), got {mask.shape}")
            if not self._has_reset and not mask.all():
                raise ValueError("reset_mask: the first reset must reset every copy")
            which[~mask] = 0
            given = {i: t for i, t in given.items() if mask[i]}
        return which, given

    def _mask(self, value):
        """``reset_mask`` as a bool array: booleans (or 0/1), not text or other numbers."""
        bad = ValueError(f"reset_mask: expected {self.num_envs} booleans (one per copy), got {value!r:.80}")
        if value is None or isinstance(value, (str, bytes, dict, set)):
            raise bad
        try:
            arr = np.asarray(value)
        except (TypeError, ValueError):
            raise bad from None
        if arr.dtype.kind == "O":
            if not all(isinstance(v, (bool, np.bool_)) for v in arr.ravel()):
                raise bad
            arr = arr.astype(bool)
        if arr.dtype.kind in "iu" and np.all((arr == 0) | (arr == 1)):
            arr = arr.astype(bool)
        if arr.dtype.kind != "b":
            raise bad
        return arr

    def _refill(self, i):
        self._rngs[i].random(out=self._pool[i])
        self._pool_pos[i] = 0

    def _service(self):
        """Refill empty pools and finish resets that ran out of pre-drawn blocks."""
        n_blocks = self._pool.shape[1]
        for i in np.flatnonzero(self._pending | (self._pool_pos >= n_blocks)):
            refills = 0
            while True:
                if self._pool_pos[i] >= n_blocks:
                    if refills * n_blocks >= MAX_BLOCKS:
                        raise RuntimeError(unplaceable_message(MAX_BLOCKS, BLOCK))
                    self._refill(i)
                    refills += 1
                if not self._pending[i]:
                    break
                if _retry_reset(i, self._tasks, self._sts, self._cfg, self._dist, self._pool,
                                self._pool_pos, self._obs, self._outs):
                    self._pending[i] = False

    def _infos(self) -> dict:
        o = self._outs
        n = self.num_envs
        infos = {}
        for key, col, is_bool in _INFO_KEYS:
            infos[key] = o[:, col] > 0.5 if is_bool else o[:, col].copy()
            infos["_" + key] = np.ones(n, dtype=np.bool_)
        return infos

    @property
    def tasks(self) -> np.ndarray:
        """Copy of the current problems, one row per copy (layout of ``slew_env.core.task``)."""
        return self._tasks.copy()

    @property
    def states(self) -> np.ndarray:
        """Copy of the physical states ``[q, ω]``, one row per copy."""
        return self._sts[:, _k.S_X:_k.S_X + 7].copy()
