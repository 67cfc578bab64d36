"""Every rest-to-rest answer carries the eigenaxis baseline (``SlewSolution.baseline_tf``)."""
import math

import numpy as np
import pytest

import solvers
from slew_env import Cone, SlewProblem
from slew_env.core.quaternion import qrotate
from solvers.eigenaxis import baseline_time, eigenaxis_time, reference_attitude


def _pointing(**kw):
    return SlewProblem([40.0, 55.0, 70.0], torque_max=0.1, sensor_axis=[0, 0, 1],
                       sensor_target=[math.sin(1.2), 0.0, math.cos(1.2)], **kw)


def test_the_reference_attitude_points_the_sensor_by_the_smallest_rotation():
    p = _pointing()
    qf = reference_attitude(p)
    np.testing.assert_allclose(qrotate(qf, p.sensor_axis), p.sensor_target, atol=1e-15)
    # the smallest rotation: its angle is the angle between the start and target directions
    assert 2.0 * math.acos(min(1.0, abs(float(qf @ p.q0)))) == pytest.approx(1.2, rel=1e-12)
    full = SlewProblem([1, 1, 1], qf=[0.0, 1.0, 0.0, 0.0])
    assert reference_attitude(full).tolist() == [0.0, 1.0, 0.0, 0.0]


def test_a_pointing_answer_of_collocation_carries_its_baseline():
    # a GNC review: baseline_tf was null for pointing answers of collocation (here with a rate
    # limit, collocation's route)
    p = _pointing(rate_max_deg=2.0)
    sol = solvers.solve(p)
    assert sol.success and sol.method == "collocation"
    ref = p.replace(qf=reference_attitude(p), sensor_target=None)
    assert sol.baseline_tf == pytest.approx(eigenaxis_time(ref, n_grid=1000), rel=1e-12)
    assert sol.tf < sol.baseline_tf


def test_with_cones_only_an_eigenaxis_path_that_clears_them_is_a_baseline():
    free = _pointing()
    across = free.replace(cones=[Cone([math.sin(0.6), 0.0, math.cos(0.6)], half_angle_deg=10.0)])
    away = free.replace(cones=[Cone([0.0, 1.0, 0.0], half_angle_deg=10.0)])
    assert math.isnan(baseline_time(across))
    assert baseline_time(away) == baseline_time(free) > 0.0
    assert math.isnan(baseline_time(free.replace(omega0=[0.001, 0.0, 0.0])))     # not at rest
