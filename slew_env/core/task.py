"""Flat float64 layout of a slew problem, for compiled kernels.

A ``SlewProblem`` is packed into one 1-D array so that numba kernels (one
environment, a batch of environments, a shooting solver) read it without Python
objects. ``T_PNORM`` holds ``p`` for a p-norm bound and ``0`` for the per-axis
(∞-norm) bound. ``T_RATEMAX`` holds ``inf`` on axes without a rate limit.
``T_TARGET`` is the inertial sensor direction at the target (for a full-attitude
target it is ``qf`` applied to the sensor axis). ``T_TUNIT`` is the time unit
``sqrt(J_max / u_max)`` used to make observations and rewards scale-free.
"""
T_J = 0           # 3: principal inertia
T_UMAX = 3        # 3: torque bound per axis
T_PNORM = 6       # 1: p of the p-norm bound, 0 for the per-axis bound
T_Q0 = 7          # 4: start attitude
T_W0 = 11         # 3: start body rate
T_QF = 14         # 4: target attitude (identity when pointing-only)
T_POINTING = 18   # 1: 1.0 when the target is pointing-only (roll free)
T_SENSOR = 19     # 3: body sensor axis
T_TARGET = 22     # 3: inertial sensor direction at the target
T_WF = 25         # 3: target body rate
T_RATEMAX = 28    # 3: per-axis rate limit (inf = none)
T_TUNIT = 31      # 1: time unit sqrt(J_max / u_max)
T_NCONES = 32     # 1: number of cones in use
T_CONES = 33      # 4 per cone: inertial axis (3), half-angle (rad)
CONE_STRIDE = 4


def task_length(max_cones):
    return T_CONES + CONE_STRIDE * max_cones


def max_cones_of(length):
    return (length - T_CONES) // CONE_STRIDE
