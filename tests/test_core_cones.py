"""Keep-out cone geometry of slew_env.core.cones (margin = angle(s_i, a) - α, rad)."""
import math

import numpy as np
import pytest

from slew_env.core import cones as C
from slew_env.core import quaternion as Q


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("eps", [1e-3, 1e-6, 1e-9, 1e-12, 1e-15])
def test_angle_between_accurate_near_zero_and_pi(eps):
    a = unit([0.3, -0.4, 0.5])
    perp = unit(np.cross(a, [1.0, 0.0, 0.0]))
    near = math.cos(eps) * a + math.sin(eps) * perp
    far = -math.cos(eps) * a + math.sin(eps) * perp
    # arccos(a·b) would give 0 or ~1.5e-8 here; atan2 keeps the relative accuracy
    assert C.angle_between(a, near) == pytest.approx(eps, rel=1e-6)
    assert C.angle_between(a, far) == pytest.approx(math.pi - eps, rel=1e-15, abs=1e-15)
    # (near π the spacing of doubles is 4.4e-16, so only absolute accuracy is possible)
    assert math.pi - C.angle_between(a, far) == pytest.approx(eps, rel=1e-6, abs=1e-15)


def test_angle_between_exact_cases_and_symmetry():
    x, y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    assert C.angle_between(x, x) == 0.0
    assert C.angle_between(x, -x) == pytest.approx(math.pi, abs=1e-15)
    assert C.angle_between(x, y) == pytest.approx(math.pi / 2, abs=1e-15)
    rng = np.random.default_rng(3)
    for _ in range(50):
        a, b = unit(rng.normal(size=3)), unit(rng.normal(size=3))
        assert C.angle_between(a, b) == pytest.approx(math.acos(np.clip(a @ b, -1, 1)), abs=1e-12)
        assert C.angle_between(a, b) == pytest.approx(C.angle_between(b, a), abs=1e-15)


def _cones():
    axes = np.array([unit([0, 0, 1]), unit([1, 1, 0]), unit([-1, 0, 0]), [9.0, 9.0, 9.0]])
    half = np.array([math.radians(30), math.radians(10), math.radians(45), 1.0])
    return axes, half


def test_cone_margins_values_and_sign():
    axes, half = _cones()
    # sensor inside cone 0 (10° off its axis): margin -20°
    s = unit([math.sin(math.radians(10)), 0.0, math.cos(math.radians(10))])
    m = C.cone_margins_inertial(s, axes, half, 3)
    assert m.shape == (3,)
    assert m[0] == pytest.approx(math.radians(10 - 30), abs=1e-14)
    assert m[0] < 0.0
    assert m[1] > 0.0 and m[2] > 0.0
    for k in range(3):
        assert m[k] == pytest.approx(C.angle_between(s, axes[k]) - half[k], abs=0)
    # clear of all: positive
    s = unit([0.0, -1.0, 0.0])
    assert np.all(C.cone_margins_inertial(s, axes, half, 3) > 0.0)
    # on the boundary: zero
    s = unit([math.sin(math.radians(30)), 0.0, math.cos(math.radians(30))])
    assert C.cone_margins_inertial(s, axes, half, 1)[0] == pytest.approx(0.0, abs=1e-15)


def test_cone_margins_use_attitude_body_to_inertial():
    axes, half = _cones()
    sensor_b = np.array([1.0, 0.0, 0.0])
    # -90° about y takes body x to inertial +z: straight down cone 0's axis
    q = Q.qfrom_axis_angle(np.array([0.0, 1.0, 0.0]), -math.pi / 2)
    m = C.cone_margins(q, sensor_b, axes, half, 3)
    assert m[0] == pytest.approx(-math.radians(30), abs=1e-14)
    # the inverse attitude points it to -z instead: 180° from the axis
    m_inv = C.cone_margins(Q.qconj(q), sensor_b, axes, half, 3)
    assert m_inv[0] == pytest.approx(math.pi - math.radians(30), abs=1e-14)
    rng = np.random.default_rng(4)
    for _ in range(20):
        q = unit(rng.normal(size=4))
        np.testing.assert_allclose(C.cone_margins(q, sensor_b, axes, half, 3),
                                   C.cone_margins_inertial(Q.qrotate(q, sensor_b), axes, half, 3),
                                   atol=0)


def test_min_cone_margin():
    axes, half = _cones()
    sensor_b = unit([0.2, 0.3, -0.9])
    rng = np.random.default_rng(5)
    for _ in range(50):
        q = unit(rng.normal(size=4))
        all_m = C.cone_margins(q, sensor_b, axes, half, 3)
        assert C.min_cone_margin(q, sensor_b, axes, half, 3) == all_m.min()
        # only the first n_cones count (the 4th row is padding with a bogus axis)
        assert C.min_cone_margin(q, sensor_b, axes, half, 2) == all_m[:2].min()


def test_min_cone_margin_without_cones_is_inf():
    q = np.array([1.0, 0.0, 0.0, 0.0])
    s = np.array([1.0, 0.0, 0.0])
    m = C.min_cone_margin(q, s, np.zeros((0, 3)), np.zeros(0), 0)
    assert m == math.inf
    axes, half = _cones()
    assert C.min_cone_margin(q, s, axes, half, 0) == math.inf     # padded, none in use
    assert C.cone_margins(q, s, axes, half, 0).shape == (0,)
