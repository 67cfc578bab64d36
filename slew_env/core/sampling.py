"""Compiled task sampler: a random slew problem from a buffer of uniforms.

The sampler never calls a random generator itself. The caller draws a block of
uniforms ``u`` in [0, 1) (from ``env.np_random``) and passes it in, so that
seeded resets are reproducible and the vector environment can reset finished
copies inside its compiled step from pre-drawn blocks.

``sample_task(dist, u, task)`` writes one problem into ``task`` (the flat layout
of ``slew_env.core.task``) and returns how many uniforms it used, or ``-1`` when
the block ran out before a valid task was found (cone rejections). On ``-1`` the
caller must draw a fresh block and call again from scratch: a task is never
completed with made-up numbers. ``TOO_MANY_CONES`` (-2) means ``dist`` allows
more cones than ``task`` has slots, a caller error. ``slew_env.tasks.TaskDistribution`` documents
the parameters held in ``dist`` and wraps this in Python.

Distribution (uniforms used in this fixed order, per attempt):

1. inertia (3): ``fixed`` copies ``D_INERTIA``; ``symmetric`` is ``(1, 1, 1)``;
   ``asymmetric`` draws each ``J_i`` uniform in ``[ratio_min, ratio_max]``.
2. start attitude (3): uniform on SO(3) (Shoemake, ``qfrom_uniform``); rest.
3. target (4): pointing-only with probability ``pointing_prob``; slew angle θ
   uniform in ``[angle_min, angle_max]``. Full target: ``qf = q0 ⊗ R(n, θ)``
   about a uniform random body axis ``n``. Pointing: the sensor target is the
   start sensor direction turned by θ towards a uniform random perpendicular.
4. cone count (1): uniform integer in ``[n_min, n_max]``.
5. per cone and attempt (5): the first cone, and each further cone with
   probability ``path_prob``, is placed *across the short path*: its axis is a
   point of the great-circle arc from the start to the target sensor direction,
   moved sideways by at most ``path_offset`` × half-angle, so the arc passes
   through the cone. Other cones have uniform random axes. A cone is kept only
   if both the start and target sensor directions clear it by ``clearance``;
   after ``max_tries`` rejections of one cone the whole task is redrawn.
"""
import numpy as np
from numba import njit

from . import task as _t
from .quaternion import qfrom_uniform, qfrom_axis_angle, qmul, qrotate
from .cones import angle_between, perpendicular_basis

# --- layout of the ``dist`` parameter array -----------------------------------
D_ANGLE_MIN = 0       # slew angle range (rad)
D_ANGLE_MAX = 1
D_POINTING_PROB = 2   # probability of a pointing-only target
D_INERTIA_MODE = 3    # INERTIA_FIXED / INERTIA_SYMMETRIC / INERTIA_ASYMMETRIC
D_INERTIA = 4         # 3: inertia used by the fixed mode
D_RATIO_MIN = 7       # asymmetric mode: each J_i uniform in [ratio_min, ratio_max]
D_RATIO_MAX = 8
D_UMAX = 9            # 3: torque bound
D_PNORM = 12          # p of the torque bound, 0 = per-axis
D_SENSOR = 13         # 3: body sensor axis (unit)
D_NCONES_MIN = 16
D_NCONES_MAX = 17
D_HALF_MIN = 18       # cone half-angle range (rad)
D_HALF_MAX = 19
D_CLEARANCE = 20      # start/target sensor directions clear every cone by this (rad)
D_PATH_PROB = 21      # probability that a cone after the first lies across the path
D_PATH_OFFSET = 22    # sideways offset of a path cone, as a fraction of its half-angle
D_MAX_TRIES = 23      # attempts per cone before the task is redrawn
D_SYMMETRIC_PROB = 24  # asymmetric mode: probability of a symmetric body (1, 1, 1) instead
DIST_LENGTH = 25

INERTIA_FIXED = 0
INERTIA_SYMMETRIC = 1
INERTIA_ASYMMETRIC = 2

# Uniforms per attempt of each stage (fixed, so a task's draws are easy to audit).
_N_HEAD = 11
_N_CONE = 5
# Returned when ``dist`` asks for more cones than ``task`` has slots (a caller bug).
TOO_MANY_CONES = -2


@njit(cache=True)
def _uniform_axis(u1, u2):
    z = 2.0 * u1 - 1.0
    r = np.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * u2
    out = np.empty(3)
    out[0] = r * np.cos(phi)
    out[1] = r * np.sin(phi)
    out[2] = z
    return out


@njit(cache=True)
def _normalized(v):
    return v / np.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)


@njit(cache=True)
def sample_task(dist, u, task):
    """Write a random problem into ``task``; return the uniforms used or -1 if ``u`` ran out."""
    n_u = u.shape[0]
    max_cones = (task.shape[0] - _t.T_CONES) // _t.CONE_STRIDE
    sensor = _normalized(dist[D_SENSOR:D_SENSOR + 3])
    clearance = dist[D_CLEARANCE]
    if int(dist[D_NCONES_MAX]) > max_cones:
        return TOO_MANY_CONES
    pos = 0
    while True:
        if pos + _N_HEAD > n_u:
            return -1
        task[:] = 0.0

        J = np.empty(3)
        mode = int(dist[D_INERTIA_MODE])
        p_sym = dist[D_SYMMETRIC_PROB]
        if mode == INERTIA_ASYMMETRIC and u[pos] < p_sym:
            mode = INERTIA_SYMMETRIC
        for i in range(3):
            if mode == INERTIA_FIXED:
                J[i] = dist[D_INERTIA + i]
            elif mode == INERTIA_SYMMETRIC:
                J[i] = 1.0
            else:
                ui = u[pos + i]
                if i == 0 and p_sym > 0.0:
                    # the same uniform chose the body: given u ≥ p it is uniform on [p, 1)
                    ui = (ui - p_sym) / (1.0 - p_sym)
                J[i] = dist[D_RATIO_MIN] + (dist[D_RATIO_MAX] - dist[D_RATIO_MIN]) * ui
        pos += 3
        q0 = qfrom_uniform(u[pos], u[pos + 1], u[pos + 2])
        pos += 3
        pointing = u[pos] < dist[D_POINTING_PROB]
        theta = dist[D_ANGLE_MIN] + (dist[D_ANGLE_MAX] - dist[D_ANGLE_MIN]) * u[pos + 1]
        ua, ub = u[pos + 2], u[pos + 3]
        pos += 4
        span = int(dist[D_NCONES_MAX]) - int(dist[D_NCONES_MIN]) + 1
        n_cones = int(dist[D_NCONES_MIN]) + min(int(u[pos] * span), span - 1)
        pos += 1

        start = qrotate(q0, sensor)
        if pointing:
            e1, e2 = perpendicular_basis(start)
            psi = 2.0 * np.pi * ua
            m = np.cos(psi) * e1 + np.sin(psi) * e2
            target = _normalized(np.cos(theta) * start + np.sin(theta) * m)
            qf = np.array([1.0, 0.0, 0.0, 0.0])
        else:
            qf = qmul(q0, qfrom_axis_angle(_uniform_axis(ua, ub), theta))
            target = qrotate(qf, sensor)

        # Frame of the start→target great circle: p(d) = cos d·start + sin d·e.
        arc = angle_between(start, target)
        e = target - np.dot(start, target) * start
        ne = np.sqrt(e[0] ** 2 + e[1] ** 2 + e[2] ** 2)
        if ne < 1e-9:  # (anti)parallel: every great circle through start is a short path
            e, _ = perpendicular_basis(start)
        else:
            e = e / ne
        normal = np.cross(start, e)

        placed = 0
        ran_out = False
        while placed < n_cones:
            ok = False
            for _ in range(int(dist[D_MAX_TRIES])):
                if pos + _N_CONE > n_u:
                    ran_out = True
                    break
                uf, ua_, ud, uo, upsi = u[pos], u[pos + 1], u[pos + 2], u[pos + 3], u[pos + 4]
                pos += _N_CONE
                on_path = placed == 0 or uf < dist[D_PATH_PROB]
                if on_path:
                    hi = min(dist[D_HALF_MAX], 0.5 * arc - clearance)
                    if hi < dist[D_HALF_MIN]:
                        break  # arc too short to hold a cone between start and target
                    alpha = dist[D_HALF_MIN] + (hi - dist[D_HALF_MIN]) * ua_
                    lo_d = alpha + clearance
                    d = lo_d + (arc - 2.0 * lo_d) * ud
                    p = np.cos(d) * start + np.sin(d) * e
                    tangent = -np.sin(d) * start + np.cos(d) * e
                    psi = 2.0 * np.pi * upsi
                    w = np.cos(psi) * tangent + np.sin(psi) * normal
                    delta = dist[D_PATH_OFFSET] * alpha * uo
                    axis = _normalized(np.cos(delta) * p + np.sin(delta) * w)
                else:
                    alpha = dist[D_HALF_MIN] + (dist[D_HALF_MAX] - dist[D_HALF_MIN]) * ua_
                    axis = _uniform_axis(ud, uo)
                if (angle_between(start, axis) - alpha >= clearance
                        and angle_between(target, axis) - alpha >= clearance):
                    o = _t.T_CONES + _t.CONE_STRIDE * placed
                    task[o:o + 3] = axis
                    task[o + 3] = alpha
                    placed += 1
                    ok = True
                    break
            if ran_out:
                return -1
            if not ok:
                break
        if placed < n_cones:
            continue  # redraw the whole task: these cones do not fit this geometry

        task[_t.T_J:_t.T_J + 3] = J
        task[_t.T_UMAX:_t.T_UMAX + 3] = dist[D_UMAX:D_UMAX + 3]
        task[_t.T_PNORM] = dist[D_PNORM]
        task[_t.T_Q0:_t.T_Q0 + 4] = q0
        task[_t.T_QF:_t.T_QF + 4] = qf
        task[_t.T_POINTING] = 1.0 if pointing else 0.0
        task[_t.T_SENSOR:_t.T_SENSOR + 3] = sensor
        task[_t.T_TARGET:_t.T_TARGET + 3] = target
        for i in range(3):
            task[_t.T_RATEMAX + i] = np.inf
        task[_t.T_TUNIT] = np.sqrt(J.max() / dist[D_UMAX:D_UMAX + 3].max())
        task[_t.T_NCONES] = placed
        return pos
