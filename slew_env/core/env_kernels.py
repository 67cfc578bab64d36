"""Compiled kernels of the Gymnasium environment (one copy and a batch).

``SlewEnv`` and ``SlewVectorEnv`` both step through ``step_env``/``reset_env``,
so a batch of N copies is bit-for-bit N single environments.

Per-copy arrays (float64 unless noted):

- ``task``: the flat problem layout of ``slew_env.core.task``.
- ``st``: mutable state, layout ``S_*`` below (``state_length(max_cones)``).
- ``cfg``: environment settings shared by all copies, layout ``C_*``.
- ``obs`` (float32): observation, layout ``OB_*`` (``obs_length(max_cones)``).
- ``out``: step results, layout ``R_*``.

The integrator is classical RK4 with the quaternion renormalised after every
sub-step. It is written here on scalars instead of calling
``dynamics.rk4_step``: that function allocates about a dozen temporary arrays per
call, which is most of the cost of a step and rules out 10⁶ steps/s. The
arithmetic is the same expression for expression, and the tests check that a
step equals ``dynamics.propagate`` bit for bit.
"""
import math

import numpy as np
from numba import njit, prange

from . import task as _t
# one allocation-free RK4 step shared with everything else that steps the body
from .dynamics import rk4_step_inplace as rk4_substep, torque_from_action
from .sampling import sample_task

# rad: the most an RK4 sub-step may turn the body (its rate times the step) before it is split,
# into at most MAX_SUBSTEP_SPLIT pieces (``step_env``)
MAX_SUBSTEP_ANGLE = 0.5
MAX_SUBSTEP_SPLIT = 4096

# --- st: per-copy state ------------------------------------------------------------
S_X = 0          # 7: [q0..q3, ω1..ω3]
S_TIME = 7       # physical time since reset
S_PHI = 8        # shaping potential of the current state
S_STEPS = 9      # control steps since reset (vector env's time limit)
S_DONE = 10      # 1 when the last step ended the episode (vector env's autoreset)
S_COSLIM = 11    # max_cones: cos(α_k − tol); the sensor violates cone k when s·a_k exceeds it
# then max_cones of scratch: largest s·a_k over the sub-steps of the current step


def state_length(max_cones):
    return S_COSLIM + 2 * max_cones


# --- cfg: settings -------------------------------------------------------------------
C_DT = 0           # control step in time units sqrt(J_max/u_max)
C_SUBSTEPS = 1     # RK4 sub-steps per control step
C_BONUS = 2        # success bonus
C_PENALTY = 3      # violation penalty
C_TERMINATE = 4    # 1: a violation ends the episode
C_SHAPING = 5      # weight of the potential-based shaping term
C_ATT_TOL = 6      # success: attitude / pointing error below this (rad)
C_RATE_TOL = 7     # success: ‖ω − ωf‖·T below this
C_MAX_STEPS = 8    # vector env: truncate after this many steps (0: never)
C_VIOL_TOL = 9     # a cone is violated when the margin is below −tol (rad)
CFG_LENGTH = 10

# --- out: step results -----------------------------------------------------------------
R_REWARD = 0
R_TERMINATED = 1
R_TRUNCATED = 2
R_SUCCESS = 3
R_VIOLATION = 4
R_MIN_MARGIN = 5   # smallest cone margin (rad) over this step's sub-steps, inf without cones
R_ATT_ERR = 6      # attitude error angle (full) or pointing error angle (rad)
R_RATE_ERR = 7     # ‖ω − ωf‖·T
R_TIME = 8         # physical time since reset
R_TORQUE = 9       # 3: applied torque (physical)
OUT_LENGTH = 12

# --- obs ------------------------------------------------------------------------------------
OB_DQ = 0           # 4: error quaternion, body frame, scalar >= 0
OB_W = 4            # 3: ω·T
OB_WF = 7           # 3: ωf·T
OB_TARGET = 10      # 3: target sensor direction, body frame
OB_SENSOR = 13      # 3: sensor axis, body frame
OB_J = 16           # 3: J / J_max
OB_UMAX = 19        # 3: u_max / max(u_max)
OB_POINTING = 22    # 1 for a pointing-only target
OB_INV_P = 23       # 1/p of the torque bound, 0 per-axis
OB_RATE_LIMIT = 24  # 3: r / (1 + r) with r = rate_max·T; 1 without a rate limit
OB_CONES = 27       # per slot: axis body frame (3), half-angle, margin, mask
OB_CONE_STRIDE = 6


# ω·T is clipped to ±RATE_OBS_MAX so the observation box can be finite (the Gymnasium
# checker warns on infinite bounds). No episode from rest comes near it: |Jω| grows by at
# most |u|·t, so |ω|·T by at most √3·(J_max/J_min)·t/T, under 90 in 400 steps of the
# provided distributions.
RATE_OBS_MAX = 1.0e4


def obs_length(max_cones):
    return OB_CONES + OB_CONE_STRIDE * max_cones


@njit(cache=True)
def _max_cones(task):
    return (task.shape[0] - _t.T_CONES) // _t.CONE_STRIDE


# --- scalar geometry (no heap allocation in the inner loops) ----------------------------------
@njit(cache=True)
def _rot(q0, q1, q2, q3, v0, v1, v2):
    """q ⊗ [0, v] ⊗ q*, the Rodrigues form of ``quaternion.qrotate``."""
    c0 = q2 * v2 - q3 * v1
    c1 = q3 * v0 - q1 * v2
    c2 = q1 * v1 - q2 * v0
    return (v0 + 2.0 * (q0 * c0 + q2 * c2 - q3 * c1),
            v1 + 2.0 * (q0 * c1 + q3 * c0 - q1 * c2),
            v2 + 2.0 * (q0 * c2 + q1 * c1 - q2 * c0))


@njit(cache=True)
def _angle(a0, a1, a2, b0, b1, b2):
    """Angle between unit vectors (atan2 form, as ``cones.angle_between``)."""
    c0 = a1 * b2 - a2 * b1
    c1 = a2 * b0 - a0 * b2
    c2 = a0 * b1 - a1 * b0
    return np.arctan2(np.sqrt(c0 * c0 + c1 * c1 + c2 * c2), a0 * b0 + a1 * b1 + a2 * b2)


# --- observation --------------------------------------------------------------------------------
@njit(cache=True)
def write_obs(task, x, obs):
    """Fill ``obs`` for state ``x``; return (attitude-or-pointing error angle, ‖ω − ωf‖·T)."""
    q0, q1, q2, q3 = x[0], x[1], x[2], x[3]
    T = task[_t.T_TUNIT]
    s0, s1, s2 = task[_t.T_SENSOR], task[_t.T_SENSOR + 1], task[_t.T_SENSOR + 2]
    tb0, tb1, tb2 = _rot(q0, -q1, -q2, -q3, task[_t.T_TARGET], task[_t.T_TARGET + 1],
                         task[_t.T_TARGET + 2])
    if task[_t.T_POINTING] > 0.5:
        # Shortest rotation taking the sensor onto the target: quaternion.qfrom_two_vectors,
        # [|s + t|²/2, s × (s + t)] normalised, which stays accurate as t → −s.
        p0, p1, p2 = s0 + tb0, s1 + tb1, s2 + tb2
        pp = p0 * p0 + p1 * p1 + p2 * p2
        if pp < 1e-30:
            # antiparallel: π about the coordinate axis least aligned with the sensor
            i = 0
            if abs(s1) < abs(s0):
                i = 1
            if abs(s2) < abs((s0, s1, s2)[i]):
                i = 2
            e0, e1, e2 = (1.0 if i == 0 else 0.0), (1.0 if i == 1 else 0.0), (1.0 if i == 2 else 0.0)
            c0, c1, c2 = s1 * e2 - s2 * e1, s2 * e0 - s0 * e2, s0 * e1 - s1 * e0
            n = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            d0, d1, d2, d3 = 0.0, c0 / n, c1 / n, c2 / n
        else:
            d0 = 0.5 * pp
            d1 = s1 * p2 - s2 * p1
            d2 = s2 * p0 - s0 * p2
            d3 = s0 * p1 - s1 * p0
            n = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2 + d3 * d3)
            d0, d1, d2, d3 = d0 / n, d1 / n, d2 / n, d3 / n
        att = _angle(s0, s1, s2, tb0, tb1, tb2)
    else:
        # δq = q* ⊗ qf: the rotation still to go, in the body frame.
        f0, f1, f2, f3 = (task[_t.T_QF], task[_t.T_QF + 1], task[_t.T_QF + 2], task[_t.T_QF + 3])
        d0 = q0 * f0 + q1 * f1 + q2 * f2 + q3 * f3
        d1 = q0 * f1 - q1 * f0 - q2 * f3 + q3 * f2
        d2 = q0 * f2 + q1 * f3 - q2 * f0 - q3 * f1
        d3 = q0 * f3 - q1 * f2 + q2 * f1 - q3 * f0
        if d0 < 0.0:
            d0, d1, d2, d3 = -d0, -d1, -d2, -d3
        att = 2.0 * np.arctan2(np.sqrt(d1 * d1 + d2 * d2 + d3 * d3), d0)
    obs[OB_DQ] = d0
    obs[OB_DQ + 1] = d1
    obs[OB_DQ + 2] = d2
    obs[OB_DQ + 3] = d3

    e2sum = 0.0
    for i in range(3):
        w = x[4 + i]
        wf = task[_t.T_WF + i]
        obs[OB_W + i] = min(max(w * T, -RATE_OBS_MAX), RATE_OBS_MAX)
        obs[OB_WF + i] = min(max(wf * T, -RATE_OBS_MAX), RATE_OBS_MAX)
        e2sum += (w - wf) * (w - wf)
    rate_err = np.sqrt(e2sum) * T

    obs[OB_TARGET] = tb0
    obs[OB_TARGET + 1] = tb1
    obs[OB_TARGET + 2] = tb2
    obs[OB_SENSOR] = s0
    obs[OB_SENSOR + 1] = s1
    obs[OB_SENSOR + 2] = s2
    jmax = max(task[_t.T_J], max(task[_t.T_J + 1], task[_t.T_J + 2]))
    umax = max(task[_t.T_UMAX], max(task[_t.T_UMAX + 1], task[_t.T_UMAX + 2]))
    for i in range(3):
        obs[OB_J + i] = task[_t.T_J + i] / jmax
        obs[OB_UMAX + i] = task[_t.T_UMAX + i] / umax
        r = task[_t.T_RATEMAX + i] * T
        # Squashed so that "no limit" (inf) is the finite value 1.
        obs[OB_RATE_LIMIT + i] = 1.0 if np.isinf(r) else r / (1.0 + r)
    obs[OB_POINTING] = task[_t.T_POINTING]
    p = task[_t.T_PNORM]
    obs[OB_INV_P] = 0.0 if p <= 0.0 else 1.0 / p

    si0, si1, si2 = _rot(q0, q1, q2, q3, s0, s1, s2)
    nc = int(task[_t.T_NCONES])
    n_slots = (obs.shape[0] - OB_CONES) // OB_CONE_STRIDE
    for k in range(n_slots):
        o = OB_CONES + OB_CONE_STRIDE * k
        if k < nc:
            c = _t.T_CONES + _t.CONE_STRIDE * k
            a0, a1, a2, alpha = task[c], task[c + 1], task[c + 2], task[c + 3]
            ab0, ab1, ab2 = _rot(q0, -q1, -q2, -q3, a0, a1, a2)
            obs[o] = ab0
            obs[o + 1] = ab1
            obs[o + 2] = ab2
            obs[o + 3] = alpha
            obs[o + 4] = _angle(si0, si1, si2, a0, a1, a2) - alpha
            obs[o + 5] = 1.0
        else:
            for j in range(OB_CONE_STRIDE):
                obs[o + j] = 0.0
    return att, rate_err


@njit(cache=True)
def min_margin_now(task, x):
    """Smallest cone margin (rad) of the sensor at state ``x``; inf without cones."""
    s0, s1, s2 = _rot(x[0], x[1], x[2], x[3], task[_t.T_SENSOR], task[_t.T_SENSOR + 1],
                      task[_t.T_SENSOR + 2])
    m = np.inf
    for k in range(int(task[_t.T_NCONES])):
        c = _t.T_CONES + _t.CONE_STRIDE * k
        mk = _angle(s0, s1, s2, task[c], task[c + 1], task[c + 2]) - task[c + 3]
        if mk < m:
            m = mk
    return m


# --- one copy -----------------------------------------------------------------------------------
@njit(cache=True)
def is_success(att, rate_err, cfg):
    """Error angle and ‖ω − ωf‖·T both inside their tolerances."""
    return att < cfg[C_ATT_TOL] and rate_err < cfg[C_RATE_TOL]


@njit(cache=True)
def step_reward(cfg, n_done, n_viol, success, terminated, phi, phi_next):
    """Reward of a step that ran ``n_done`` sub-steps, ``n_viol`` of them in violation.

    Time cost ``control_dt`` (pro rata when the step was cut short), the success
    bonus, the violation penalty (once if violations terminate, else per unit
    time in violation) and the shaping term ``shaping·(Φ' − Φ)``.
    """
    n_sub = cfg[C_SUBSTEPS]
    reward = -cfg[C_DT] if n_done == n_sub else -cfg[C_DT] * n_done / n_sub
    if n_viol > 0:
        if cfg[C_TERMINATE] > 0.5:
            reward -= cfg[C_PENALTY]
        else:
            reward -= cfg[C_PENALTY] * cfg[C_DT] * n_viol / n_sub
    if success:
        reward += cfg[C_BONUS]
    # Terminal states have potential 0 (Ng et al.), so shaping cannot change which policy is optimal.
    if terminated:
        phi_next = 0.0
    return reward + cfg[C_SHAPING] * (phi_next - phi)


@njit(cache=True)
def reset_env(task, st, cfg, obs, out):
    """Pose ``task``: start state, observation, and reset results in ``out``."""
    st[:] = 0.0
    for i in range(4):
        st[S_X + i] = task[_t.T_Q0 + i]
    for i in range(3):
        st[S_X + 4 + i] = task[_t.T_W0 + i]
    for k in range(int(task[_t.T_NCONES])):
        st[S_COSLIM + k] = np.cos(task[_t.T_CONES + _t.CONE_STRIDE * k + 3] - cfg[C_VIOL_TOL])
    att, rate_err = write_obs(task, st, obs)
    st[S_PHI] = -(att + rate_err)
    out[:] = 0.0
    out[R_MIN_MARGIN] = min_margin_now(task, st)
    out[R_ATT_ERR] = att
    out[R_RATE_ERR] = rate_err


@njit(cache=True)
def step_env(task, st, action, cfg, obs, out):
    """Advance one control step under ``action`` (normalised, clipped) and score it."""
    u = torque_from_action(action, task[_t.T_UMAX:_t.T_UMAX + 3], task[_t.T_PNORM])
    u0, u1, u2 = u[0], u[1], u[2]
    J0, J1, J2 = task[_t.T_J], task[_t.T_J + 1], task[_t.T_J + 2]
    rm0, rm1, rm2 = task[_t.T_RATEMAX], task[_t.T_RATEMAX + 1], task[_t.T_RATEMAX + 2]
    s0, s1, s2 = task[_t.T_SENSOR], task[_t.T_SENSOR + 1], task[_t.T_SENSOR + 2]
    n_sub = int(cfg[C_SUBSTEPS])
    dt = cfg[C_DT] * task[_t.T_TUNIT]
    h = dt / n_sub
    terminate_on_violation = cfg[C_TERMINATE] > 0.5
    nc = int(task[_t.T_NCONES])
    scratch = S_COSLIM + _max_cones(task)
    for k in range(nc):
        st[scratch + k] = -2.0
    x = st[S_X:S_X + 7]

    n_done = 0
    n_viol = 0
    for _ in range(n_sub):
        # a body spun fast (a long episode at full torque, a long control_dt) would turn more than
        # MAX_SUBSTEP_ANGLE in one RK4 step, where RK4 diverges (NaN observations after ~4,000
        # saturated steps, an outside fuzz): the sub-step is split, which leaves every ordinary
        # step (|ω|·h ≈ 0.25 at the end of a 400-step episode at full torque) as it was
        w = math.sqrt(x[4] * x[4] + x[5] * x[5] + x[6] * x[6])
        m = int(min(math.ceil(w * h / MAX_SUBSTEP_ANGLE), MAX_SUBSTEP_SPLIT)) if w * h > MAX_SUBSTEP_ANGLE else 1
        for _ in range(m):
            rk4_substep(x, u0, u1, u2, J0, J1, J2, h / m)
        n_done += 1
        # The constraint holds at every sub-step, not only at control instants.
        bad = abs(x[4]) > rm0 or abs(x[5]) > rm1 or abs(x[6]) > rm2
        if nc > 0:
            si0, si1, si2 = _rot(x[0], x[1], x[2], x[3], s0, s1, s2)
            for k in range(nc):
                c = _t.T_CONES + _t.CONE_STRIDE * k
                dot = si0 * task[c] + si1 * task[c + 1] + si2 * task[c + 2]
                if dot > st[scratch + k]:
                    st[scratch + k] = dot
                if dot > st[S_COSLIM + k]:
                    bad = True
        if bad:
            n_viol += 1
            if terminate_on_violation:
                break  # the episode ends here, at the state that violated
    st[S_TIME] += dt if n_done == n_sub else n_done * h

    min_margin = np.inf
    for k in range(nc):
        m = np.arccos(min(st[scratch + k], 1.0)) - task[_t.T_CONES + _t.CONE_STRIDE * k + 3]
        if m < min_margin:
            min_margin = m

    att, rate_err = write_obs(task, st, obs)
    violation = n_viol > 0
    ended_by_violation = violation and terminate_on_violation
    success = (not ended_by_violation) and is_success(att, rate_err, cfg)
    terminated = success or ended_by_violation
    phi = -(att + rate_err)
    reward = step_reward(cfg, n_done, n_viol, success, terminated, st[S_PHI], phi)
    st[S_PHI] = phi

    out[R_REWARD] = reward
    out[R_TERMINATED] = 1.0 if terminated else 0.0
    out[R_TRUNCATED] = 0.0
    out[R_SUCCESS] = 1.0 if success else 0.0
    out[R_VIOLATION] = 1.0 if violation else 0.0
    out[R_MIN_MARGIN] = min_margin
    out[R_ATT_ERR] = att
    out[R_RATE_ERR] = rate_err
    out[R_TIME] = st[S_TIME]
    out[R_TORQUE] = u0
    out[R_TORQUE + 1] = u1
    out[R_TORQUE + 2] = u2


# --- a batch of copies --------------------------------------------------------------------------
@njit(cache=True)
def reset_from_pool(i, tasks, sts, cfg, dist, pool, pool_pos, obs, outs):
    """Draw a task for copy ``i`` from its pre-drawn uniform blocks and reset it.

    Blocks are used in order, one per attempt, like ``tasks.draw_task`` does
    with fresh blocks. Returns False when the blocks ran out (the caller refills
    and calls again), never a task from a partial draw.
    """
    n_blocks = pool.shape[1]
    while pool_pos[i] < n_blocks:
        b = pool_pos[i]
        pool_pos[i] = b + 1
        if sample_task(dist, pool[i, b], tasks[i]) >= 0:
            reset_env(tasks[i], sts[i], cfg, obs[i], outs[i])
            return True
    return False


@njit(cache=True)
def _vec_step_one(i, tasks, sts, actions, cfg, dist, pool, pool_pos, obs, outs, pending):
    st = sts[i]
    if st[S_DONE] > 0.5:
        # Gymnasium's next-step autoreset: this step only resets, reward 0, not done.
        if not reset_from_pool(i, tasks, sts, cfg, dist, pool, pool_pos, obs, outs):
            pending[i] = True
            outs[i, :] = 0.0
        return
    step_env(tasks[i], st, actions[i], cfg, obs[i], outs[i])
    st[S_STEPS] += 1.0
    max_steps = cfg[C_MAX_STEPS]
    truncated = max_steps > 0.0 and st[S_STEPS] >= max_steps
    outs[i, R_TRUNCATED] = 1.0 if truncated else 0.0
    if truncated or outs[i, R_TERMINATED] > 0.5:
        st[S_DONE] = 1.0


@njit(cache=True)
def vec_step(tasks, sts, actions, cfg, dist, pool, pool_pos, obs, outs, pending):
    """Step every copy; returns how many copies need Python (empty pool or pending reset)."""
    n_blocks = pool.shape[1]
    attention = 0
    for i in range(tasks.shape[0]):
        _vec_step_one(i, tasks, sts, actions, cfg, dist, pool, pool_pos, obs, outs, pending)
        if pending[i] or pool_pos[i] >= n_blocks:
            attention += 1
    return attention


@njit(cache=True, parallel=True)
def vec_step_parallel(tasks, sts, actions, cfg, dist, pool, pool_pos, obs, outs, pending):
    """``vec_step`` over threads; copies are independent, so results are identical."""
    n_blocks = pool.shape[1]
    attention = 0
    for i in prange(tasks.shape[0]):
        _vec_step_one(i, tasks, sts, actions, cfg, dist, pool, pool_pos, obs, outs, pending)
        if pending[i] or pool_pos[i] >= n_blocks:
            attention += 1
    return attention


@njit(cache=True)
def vec_reset(which, tasks, sts, cfg, dist, pool, pool_pos, obs, outs, pending):
    """Reset copies with ``which[i]``: 1 draws a task from the pool, 2 poses ``tasks[i]`` as given."""
    for i in range(tasks.shape[0]):
        if which[i] == 2:
            reset_env(tasks[i], sts[i], cfg, obs[i], outs[i])
        elif which[i] == 1:
            if not reset_from_pool(i, tasks, sts, cfg, dist, pool, pool_pos, obs, outs):
                pending[i] = True
