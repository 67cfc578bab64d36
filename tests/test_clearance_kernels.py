"""The compiled clearance margins and certified bounds (``solvers.core.clearance_kernels``)
against the numpy formulas they replaced, and the bound's meaning on a replayed path."""
import math

import numpy as np
import pytest

from slew_env import Cone, SlewProblem
from solvers.clearance import certified_min_margin, cone_clearances, cone_margins
from solvers.verify import replay_path


def _margins_numpy(problem, q):
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, r = q[:, :1], q[:, 1:4]
    v = np.asarray(problem.sensor_axis, float)[None, :]
    c = np.cross(r, v)
    d = v + 2.0 * (w * c + np.cross(r, c))
    return np.stack([np.arctan2(np.linalg.norm(np.cross(d, k.axis), axis=1), d @ k.axis) - k.half_angle
                     for k in problem.cones], axis=1)


def _clearances_numpy(problem, t, q, omega):
    mar = _margins_numpy(problem, q)
    w = np.linalg.norm(omega, axis=1)
    J = problem.inertia
    amax = float(np.linalg.norm(problem.torque_max / J)) + 1.1 * float(w.max()) ** 2 * float(J.max() / J.min())
    dt = np.diff(t)
    W = np.maximum(w[:-1], w[1:]) + amax * dt
    out = []
    for k, c in enumerate(problem.cones):
        m = mar[:, k]
        theta = m + c.half_angle
        lo_end = np.minimum(m[:-1], m[1:])
        first = np.minimum(0.5 * (m[:-1] + m[1:]) - 0.5 * W * dt, lo_end)
        th_lo = np.minimum(theta[:-1], theta[1:]) - W * dt
        th_hi = np.maximum(theta[:-1], theta[1:]) + W * dt
        inside = (th_lo > 0.0) & (th_hi < np.pi)
        s_low = np.where(inside, np.minimum(np.sin(np.clip(th_lo, 0.0, np.pi)), np.sin(np.clip(th_hi, 0.0, np.pi))),
                         0.0)
        ok = s_low > 1e-6
        B = (amax + 2.0 * W ** 2) / np.where(ok, s_low, 1.0)
        second = np.where(ok, lo_end - B * dt ** 2 / 8.0, -np.inf)
        out.append((float(m.min()), float(np.max([first, second], axis=0).min()), float(m[0]), float(m[-1])))
    return out


def _problem():
    a1 = np.array([0.55, 0.25, 0.45])
    a2 = np.array([-0.2, 0.9, 0.1])
    return SlewProblem([1.0, 0.8, 0.6], torque_max=[1.0, 0.7, 0.9], q0=[1.0, 0.0, 0.0, 0.0],
                       sensor_axis=[1.0, 0.0, 0.0], sensor_target=[0.3, 0.5, 0.81],
                       cones=[Cone(a1 / np.linalg.norm(a1), 0.3), Cone(a2 / np.linalg.norm(a2), 0.15)])


def _path(problem, n=2000, seed=0):
    rng = np.random.default_rng(seed)
    sw = [np.sort(rng.uniform(0.0, 2.5, 3)) for _ in range(3)]
    return replay_path(problem.inertia, problem.torque_max, problem.q0, problem.omega0, sw, np.array([1.0, -1.0, 1.0]),
                       2.5, steps_per_tf=n)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_margins_and_bounds_equal_the_numpy_formulas(seed):
    p = _problem()
    t, x = _path(p, seed=seed)
    q = x[:, 0:4] * 1.7          # not unit: the margins normalise
    assert np.allclose(cone_margins(p, q), _margins_numpy(p, q), rtol=0, atol=1e-13)
    got, want = cone_clearances(p, t, q, x[:, 4:7]), _clearances_numpy(p, t, q, x[:, 4:7])
    assert len(got) == 2
    for g, w in zip(got, want):
        assert g == pytest.approx(w, rel=0, abs=1e-12)


def test_the_certified_bound_is_below_every_instant_between_the_samples():
    """The bound from 200 samples lies below the margin on a 50x finer replay of the same path,
    and is within the bound's own slack of its minimum."""
    p = _problem()
    t, x = _path(p, n=200, seed=1)
    tf, xf = _path(p, n=10000, seed=1)
    fine = cone_margins(p, xf[:, 0:4]).min(axis=0)
    for k, (smin, cert, m0, mN) in enumerate(cone_clearances(p, t, x[:, 0:4], x[:, 4:7])):
        assert cert <= fine[k] + 1e-12 and cert <= smin
        assert fine[k] - cert < 0.05


def test_a_path_that_is_not_finite_certifies_nothing():
    p = _problem()
    t, x = _path(p, seed=0)
    x = x.copy()
    x[700, 0] = np.nan
    sample, cert = certified_min_margin(p, t, x[:, 0:4], x[:, 4:7])
    assert math.isnan(sample) and math.isnan(cert)
    x[700, 0] = 1.0
    w = x[:, 4:7].copy()
    w[5, 1] = np.nan
    assert all(math.isnan(v) for v in cone_clearances(p, t, x[:, 0:4], w)[0])


def test_a_zero_quaternion_gives_nan_margins_and_mismatched_arrays_are_refused():
    p = _problem()
    t, x = _path(p, n=200, seed=0)
    q = x[:, 0:4].copy()
    q[50] = 0.0
    assert np.isnan(cone_margins(p, q)[50]).all()
    assert math.isnan(certified_min_margin(p, t, q, x[:, 4:7])[1])
    with pytest.raises(ValueError, match="one row per sample"):
        cone_clearances(p, t[:-5], x[:, 0:4], x[:, 4:7])
    with pytest.raises(ValueError, match="one row per sample"):
        cone_clearances(p, t, x[:, 0:4], x[:-1, 4:7])
