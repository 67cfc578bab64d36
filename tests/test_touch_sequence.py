"""The compiled touch-point sequence flow (``core.touch_sequence``) against the arc-by-arc Python
loop it replaced, and the cone's ``[h, ḣ]`` gradient against finite differences."""
import numpy as np
import pytest

from solvers.cone_touch import TouchBVP, TouchProblem, _structured_residual
from solvers.core.touch_sequence import touch_residual
from solvers.switch_time import Structure

from python_sequence_flows import _touch_residual
from python_sequence_flows import touch_residual as python_touch_residual
from reference_cases import TOUCH


def _touch_problem(prob, cone_ids, torque):
    bvp = TouchBVP(prob.replace(torque_max=torque))
    bvp.sensor = np.asarray(prob.sensor_axis, float)
    return TouchProblem(bvp, cone_ids)


def _cases(n_cases=16, seed=5):
    """Random iterates: pointing and full-attitude targets, 0-3 touches on cones in any order,
    switches and touches interleaved (a switch and a touch at the same instant, events beyond T)."""
    rng = np.random.default_rng(seed)
    full = TOUCH.replace(sensor_target=None, qf=TOUCH.q0)       # a full-attitude target off every cone
    for k in range(n_cases):
        prob = full if k % 3 == 2 else TOUCH
        K = int(rng.integers(0, 4))
        tp = _touch_problem(prob, list(rng.permutation(3)[:K]), rng.uniform(0.3, 2.0, 3))
        n = int(rng.integers(0, 9))
        T = float(rng.uniform(1.0, 4.0))
        times = rng.uniform(0.0, 1.1 * T, n)
        tc = np.sort(rng.uniform(0.05 * T, 1.05 * T, K))
        if n and K:
            tc[0] = times[0]                            # a tie: the switch runs first
        nu = rng.uniform(0.0, 2.0, K)
        z = rng.normal(size=6)
        z /= np.linalg.norm(z) * rng.uniform(0.9, 1.1)
        st = Structure(rng.choice([-1.0, 1.0], 3), rng.integers(0, 3, n), times)
        yield tp, z, times, T, tc, nu, st


@pytest.mark.parametrize("want_jac", [True, False])
def test_the_compiled_touch_flow_matches_the_python_loop(want_jac):
    seen_K = set()
    for tp, z, times, T, tc, nu, st in _cases():
        seen_K.add(tp.K)
        r, Jm = _structured_residual(tp, z, times, T, tc, nu, st, want_jac)
        r0, J0 = python_touch_residual(tp, z, times, T, tc, nu, st, want_jac)
        assert r.shape == r0.shape == (1 + st.n + 2 * tp.K + 6,)
        assert np.allclose(r, r0, rtol=1e-11, atol=1e-12), np.max(np.abs(r - r0))
        if want_jac:
            assert Jm.shape == J0.shape == (r.shape[0], 6 + st.n + 1 + 2 * tp.K)
            assert np.allclose(Jm, J0, rtol=1e-10, atol=1e-11), np.max(np.abs(Jm - J0))
        else:
            assert Jm is None
    assert seen_K == {0, 1, 2, 3}


def test_a_non_finite_instant_is_a_failed_evaluation_not_an_exception():
    tp, z, times, T, tc, nu, st = next(c for c in _cases() if c[0].K and c[6].n)
    assert _structured_residual(tp, z, times, T, np.full_like(tc, np.nan), nu, st, True) == (None, None)
    bad = times.copy()
    bad[0] = np.inf
    assert _structured_residual(tp, z, bad, T, tc, nu, st, True) == (None, None)


def test_cone_residual_gradient_matches_the_python_one_and_finite_differences():
    rng = np.random.default_rng(2)
    tp = _touch_problem(TOUCH, [0, 1, 2], np.ones(3))
    for k in range(3):
        y = rng.normal(size=14)
        y[:4] /= np.linalg.norm(y[:4])
        r, g = touch_residual(y, tp.Ms[k], tp.cos_a_array[k])
        r0, g0 = _touch_residual(y, tp.M[k], tp.cos_a[k])
        assert np.allclose(r, r0, rtol=1e-14, atol=1e-15) and np.allclose(g, g0, rtol=1e-13, atol=1e-15)
        for i in range(14):
            e = np.zeros(14)
            e[i] = 1e-6
            fd = (touch_residual(y + e, tp.Ms[k], tp.cos_a_array[k])[0]
                  - touch_residual(y - e, tp.Ms[k], tp.cos_a_array[k])[0]) / 2e-6
            assert np.allclose(g[:, i], fd, atol=1e-8), (k, i)
