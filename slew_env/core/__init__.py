"""Compiled physics shared by the environment and the solvers.

Pure functions on arrays (numba, ``cache=True``); no classes, no validation.
Inputs are trusted here: validation happens once, in ``slew_env.problem``.
"""
from .quaternion import (
    qmul, qconj, qnormalize, qrotate, qrotate_inv, qfrom_axis_angle, qangle,
    qerror_angle, qaxis_angle, qcanonical, qfrom_two_vectors, qfrom_uniform,
    quat_from_euler321, quat_from_euler321_deg,
)
from .dynamics import (
    STATE_DIM, euler_rate, state_rhs, rk4_step, propagate, torque_from_action,
    kinetic_energy,
)
from .cones import angle_between, cone_margins, cone_margins_inertial, min_cone_margin, perpendicular_basis
from . import task

__all__ = [
    "qmul", "qconj", "qnormalize", "qrotate", "qrotate_inv", "qfrom_axis_angle",
    "qangle", "qerror_angle", "qaxis_angle", "qcanonical", "qfrom_two_vectors", "qfrom_uniform",
    "quat_from_euler321", "quat_from_euler321_deg",
    "STATE_DIM", "euler_rate", "state_rhs", "rk4_step", "propagate",
    "torque_from_action", "kinetic_energy",
    "angle_between", "cone_margins", "cone_margins_inertial", "min_cone_margin", "perpendicular_basis",
    "task",
]
