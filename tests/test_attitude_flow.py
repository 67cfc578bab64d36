"""The compiled extremal flow: Jacobian, switch location, jump-corrected sensitivities."""
import numpy as np
import pytest

from solvers.core import attitude_flow as af

NO_PENALTY = np.zeros(0)

J = np.array([1.0, 0.8, 0.4])
UMAX = np.array([1.0, 0.7, 0.9])


@pytest.mark.parametrize("mode,p,eps", [(af.MODE_BANG, 0.0, 1.0), (af.MODE_PNORM, 2.0, 1.0),
                                         (af.MODE_PNORM, 3.5, 1.0), (af.MODE_TANH, 0.0, 0.3)])
def test_jacobian_matches_finite_differences(mode, p, eps):
    rng = np.random.default_rng(3)
    signs = np.array([1.0, -1.0, 1.0])
    for _ in range(5):
        y = rng.normal(size=14)
        _, d = af.control(y, J, UMAX, mode, p, eps, signs)
        A = af.ext_jac(y, J, d)
        h = 1e-6
        fd = np.empty((14, 14))
        for k in range(14):
            e = np.zeros(14)
            e[k] = h
            up, _ = af.control(y + e, J, UMAX, mode, p, eps, signs)
            um, _ = af.control(y - e, J, UMAX, mode, p, eps, signs)
            fd[:, k] = (af.ext_rhs(y + e, up, J) - af.ext_rhs(y - e, um, J)) / (2 * h)
        np.testing.assert_allclose(A, fd, atol=1e-8)


def test_pnorm_control_is_eq35_and_on_the_ball():
    y = np.zeros(14)
    y[11:14] = [0.3, -0.2, 0.5]
    for p in (1.5, 2.0, 4.0):
        u, _ = af.control(y, J, UMAX, af.MODE_PNORM, p, 1.0, np.ones(3))
        v = u / UMAX
        assert np.sum(np.abs(v) ** p) ** (1 / p) == pytest.approx(1.0, abs=1e-14)
        sig = UMAX * y[11:14] / J
        # minimises σ·v over the ball: compare with the Hölder bound -‖σ‖_q, 1/p + 1/q = 1
        q = p / (p - 1)
        assert float(sig @ v) == pytest.approx(-np.sum(np.abs(sig) ** q) ** (1 / q), rel=1e-12)


def _run(y0, m, tf=3.0):
    Y0 = np.zeros(14 + 14 * m)
    Y0[:14] = y0
    if m:
        Y0[14:] = np.eye(14)[:, :m].ravel()
    signs = -np.sign(y0[11:] / J)
    sw_t = np.zeros(50)
    sw_a = np.zeros(50, dtype=np.int64)
    out = af.flow(Y0, tf, m, J, UMAX, af.MODE_BANG, 0.0, 1.0, signs, 1e-12, 1e-13, 0.05, 100000, 40,
                  np.zeros(0), np.zeros((0, 14)), np.zeros((0, 3)), sw_t, sw_a, NO_PENALTY)
    return out, sw_t, sw_a


def _y0():
    y0 = np.zeros(14)
    y0[0] = 1.0
    y0[7:11] = [0.0, 0.3, -0.5, 0.6]
    y0[11:14] = [0.2, -0.4, 0.1]
    return y0


def test_switches_are_located_on_the_switching_functions():
    (Y, s_end, _, n_sw, steps, status), sw_t, sw_a = _run(_y0(), 0)
    assert status == af.FLOW_OK
    assert n_sw >= 2
    # re-propagate to each switch instant: the axis's switching function vanishes there
    for k in range(n_sw):
        (Yk, *_), _, _ = _run(_y0(), 0, tf=sw_t[k])
        assert abs(Yk[11 + sw_a[k]] / J[sw_a[k]]) < 1e-12


def test_sensitivities_with_switch_jumps_match_finite_differences():
    y0 = _y0()
    (Y, *_), _, _ = _run(y0, 14)
    Phi = Y[14:].reshape(14, 14)
    h = 1e-7
    fd = np.empty((14, 14))
    for k in range(14):
        e = np.zeros(14)
        e[k] = h
        fd[:, k] = (_run(y0 + e, 0)[0][0] - _run(y0 - e, 0)[0][0]) / (2 * h)
    assert np.max(np.abs(Phi - fd)) < 1e-6 * max(1.0, np.max(np.abs(Phi)))
    # without the jump correction the sensitivities are visibly wrong: the test can fail
    assert np.max(np.abs(Phi)) > 1.0


def test_hamiltonian_is_conserved_across_switches():
    y0 = _y0()
    rec_t = np.zeros(2000)
    rec_Y = np.zeros((2000, 14))
    rec_s = np.zeros((2000, 3))
    signs = -np.sign(y0[11:] / J)
    _, _, n_rec, n_sw, _, status = af.flow(y0.copy(), 3.0, 0, J, UMAX, af.MODE_BANG, 0.0, 1.0, signs, 1e-12,
                                           1e-13, 0.05, 100000, 40, rec_t, rec_Y, rec_s,
                                           np.zeros(50), np.zeros(50, dtype=np.int64), NO_PENALTY)
    H = [af.hamiltonian(rec_Y[k], J, UMAX, af.MODE_BANG, 0.0, 1.0, rec_s[k]) for k in range(n_rec)]
    assert n_sw >= 2
    assert np.max(np.abs(np.array(H) - H[0])) < 1e-10


# a pointing-cones extremal whose first axis has a pulse (two switches 0.039 T apart) shorter
# than the adaptive step: the end-of-step sign check alone misses both switches
PULSE_Y0 = np.array([0.10972301988678053, -0.914365579306258, 0.3839374322092109, -0.06699622702402173, 0.0, 0.0, 0.0,
                     -0.2484589234190229, 0.26902235105902833, 0.6196956218529638, -0.5272251443292697,
                     -0.0008089043019391267, 0.3486400130060751, 0.2869766688292576])
PULSE_J = np.array([1.0, 0.7183438267246143, 0.5428235650429168])


def _pulse_flow(m, hmax=np.inf, rtol=1e-10):
    Y0 = np.zeros(14 + 14 * m)
    Y0[:14] = PULSE_Y0
    if m:
        Y0[14:] = np.eye(14)[:, :m].ravel()
    sw_t = np.zeros(50)
    sw_a = np.zeros(50, dtype=np.int64)
    out = af.flow(Y0, 0.6997750876550235, m, PULSE_J, np.ones(3), af.MODE_BANG, 0.0, 1.0, np.array([1.0, -1.0, -1.0]),
                  rtol, rtol, 0.05, 100000, 40, np.zeros(0), np.zeros((0, 14)), np.zeros((0, 3)), sw_t, sw_a,
                  NO_PENALTY, True, hmax)
    return out, sw_t[:out[3]], sw_a[:out[3]]


def test_a_pulse_shorter_than_the_step_is_found():
    (Y, s_end, _, n_sw, _, status), sw_t, sw_a = _pulse_flow(0)
    (Y_ref, s_ref, _, n_ref, _, _), t_ref, a_ref = _pulse_flow(0, hmax=1e-3)   # steps far shorter than the pulse
    assert status == af.FLOW_OK
    assert n_sw == n_ref == 2 and list(sw_a) == list(a_ref) == [0, 0]
    np.testing.assert_allclose(sw_t, t_ref, atol=1e-11)
    assert 0.03 < sw_t[1] - sw_t[0] < 0.1
    np.testing.assert_array_equal(s_end, s_ref)
    np.testing.assert_allclose(Y[:14], Y_ref[:14], atol=1e-8)


def test_pulse_sensitivities_match_finite_differences():
    (Y, *_), _, _ = _pulse_flow(14)
    Phi = Y[14:].reshape(14, 14)
    h = 1e-7
    fd = np.empty((14, 14))
    for k in range(14):
        PULSE_Y0[k] += h
        plus = _pulse_flow(0)[0][0].copy()
        PULSE_Y0[k] -= 2 * h
        minus = _pulse_flow(0)[0][0].copy()
        PULSE_Y0[k] += h
        fd[:, k] = (plus - minus) / (2 * h)
    assert np.max(np.abs(Phi - fd)) < 1e-5 * max(1.0, np.max(np.abs(Phi)))
