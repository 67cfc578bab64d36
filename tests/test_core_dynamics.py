"""Rigid-body dynamics of slew_env.core.dynamics against closed forms.

Euler's equations J ω̇ = -ω × (J ω) + u, kinematics q̇ = ½ q ⊗ [0, ω] (body rates),
RK4 integration (CONVENTIONS.md).
"""
import math

import numpy as np
import pytest

from slew_env.core import dynamics as D
from slew_env.core import quaternion as Q

E = np.eye(3)


def state(q, w):
    return np.concatenate([np.asarray(q, dtype=float), np.asarray(w, dtype=float)])


def inertial_momentum(x, J):
    """Angular momentum in the inertial frame: q ⊗ (J ω) ⊗ q*."""
    return Q.qrotate(x[:4], J * x[4:])


# ---------------------------------------------------------------- Euler's equations
def test_euler_rate_matches_numpy():
    rng = np.random.default_rng(1)
    for _ in range(100):
        J = rng.uniform(0.1, 10.0, 3)
        w = rng.normal(size=3) * 3
        u = rng.normal(size=3)
        expected = np.linalg.solve(np.diag(J), u - np.cross(w, J * w))
        np.testing.assert_allclose(D.euler_rate(J, w, u), expected, rtol=1e-12, atol=1e-13)


def test_euler_rate_gyroscopic_sign_by_hand():
    """J = diag(1, 2, 3), ω = (1, 1, 0), u = 0: ω × Jω = (0, 0, 1) so ω̇3 = -1/3."""
    out = D.euler_rate(np.array([1.0, 2.0, 3.0]), np.array([1.0, 1.0, 0.0]), np.zeros(3))
    np.testing.assert_allclose(out, [0.0, 0.0, -1.0 / 3.0], atol=1e-15)
    out = D.euler_rate(np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 1.0]), np.zeros(3))
    np.testing.assert_allclose(out, [-1.0, 0.0, 0.0], atol=1e-15)   # ω×Jω = (3-2, 0, 0)
    out = D.euler_rate(np.array([1.0, 2.0, 3.0]), np.array([1.0, 0.0, 1.0]), np.zeros(3))
    np.testing.assert_allclose(out, [0.0, 1.0, 0.0], atol=1e-15)    # ω×Jω = (0, 1-3, 0)


def test_state_rhs_is_kinematics_plus_euler():
    rng = np.random.default_rng(2)
    for _ in range(50):
        J = rng.uniform(0.1, 10.0, 3)
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w, u = rng.normal(size=3), rng.normal(size=3)
        xd = D.state_rhs(state(q, w), u, J)
        assert xd.shape == (D.STATE_DIM,) == (7,)
        np.testing.assert_allclose(xd[:4], 0.5 * Q.qmul(q, np.concatenate([[0.0], w])), atol=1e-15)
        np.testing.assert_allclose(xd[4:], D.euler_rate(J, w, u), atol=0)
        assert abs(xd[:4] @ q) < 1e-15          # stays tangent to the unit sphere


def test_kinetic_energy():
    assert D.kinetic_energy(np.array([1.0, 2.0, 3.0]), np.array([1.0, -2.0, 0.5])) == pytest.approx(
        0.5 * (1 + 8 + 0.75), rel=1e-15)


# ---------------------------------------------------------------- closed-form motions
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_torque_free_principal_spin(axis):
    """ω = w e_i constant, q(t) = q0 ⊗ [cos(wt/2), sin(wt/2) e_i] (body-rate kinematics)."""
    J = np.array([1.0, 2.5, 4.0])                 # asymmetric: 1 is also the unstable axis
    w = 1.3
    q0 = Q.quat_from_euler321(0.3, -0.4, 1.1)
    x0 = state(q0, w * E[axis])
    T, n = 4.0, 2000
    traj = D.propagate(x0, np.zeros(3), J, T, n)
    assert traj.shape == (n + 1, 7)
    np.testing.assert_array_equal(traj[0], x0)
    np.testing.assert_allclose(traj[:, 4:], np.tile(w * E[axis], (n + 1, 1)), atol=1e-15)
    t = np.linspace(0.0, T, n + 1)
    for k in range(0, n + 1, 100):
        rel = np.concatenate([[math.cos(w * t[k] / 2)], math.sin(w * t[k] / 2) * E[axis]])
        np.testing.assert_allclose(traj[k, :4], Q.qmul(q0, rel), atol=1e-10)
    # and from the identity the closed form itself
    traj = D.propagate(state([1, 0, 0, 0], w * E[axis]), np.zeros(3), J, T, n)
    np.testing.assert_allclose(traj[-1, :4], np.concatenate([[math.cos(w * T / 2)],
                                                             math.sin(w * T / 2) * E[axis]]), atol=1e-10)


def test_torque_free_asymmetric_conserves_energy_and_inertial_momentum():
    J = np.array([1.0, 2.0, 3.0])
    x0 = state(Q.quat_from_euler321(0.2, 0.5, -0.7), [0.3, 1.0, -0.4])   # tumbling near axis 2
    traj = D.propagate(x0, np.zeros(3), J, 60.0, 12_000)
    # the motion is far from trivial: the rates change a lot
    assert np.ptp(traj[:, 4:], axis=0).min() > 0.3
    T0 = D.kinetic_energy(J, x0[4:])
    H0 = inertial_momentum(x0, J)
    for x in traj[::500]:
        assert D.kinetic_energy(J, x[4:]) == pytest.approx(T0, rel=1e-11)
        np.testing.assert_allclose(inertial_momentum(x, J), H0, atol=1e-10)
    np.testing.assert_allclose(np.linalg.norm(traj[:, :4], axis=1), 1.0, atol=1e-15)


@pytest.mark.parametrize("j, umax, theta_f", [(1.0, 1.0, math.pi), (2.0, 0.5, 2.0), (5621.0, 50.0, 2.618)])
def test_eigenaxis_bang_bang(j, umax, theta_f):
    """Symmetric body, u = ±umax n: θ(t) = ½(umax/j)t² then the mirror; rest at θf at
    tf = 2√(θf j/umax), and q(t) = [cos θ/2, sin θ/2 n] throughout."""
    J = np.full(3, j)
    n_axis = np.array([1.0, 2.0, -2.0]) / 3.0
    a = umax / j
    tf = 2.0 * math.sqrt(theta_f * j / umax)
    N = 1000
    first = D.propagate(state([1, 0, 0, 0], [0, 0, 0]), umax * n_axis, J, tf / 2, N)
    second = D.propagate(first[-1], -umax * n_axis, J, tf / 2, N)
    t = np.linspace(0.0, tf, 2 * N + 1)
    traj = np.vstack([first, second[1:]])
    theta = np.where(t <= tf / 2, 0.5 * a * t ** 2, theta_f - 0.5 * a * (tf - t) ** 2)
    omega = np.where(t <= tf / 2, a * t, a * (tf - t))
    q_exact = np.column_stack([np.cos(theta / 2), np.sin(theta / 2)[:, None] * n_axis])
    np.testing.assert_allclose(traj[:, :4], q_exact, atol=1e-10)
    np.testing.assert_allclose(traj[:, 4:], omega[:, None] * n_axis, atol=1e-12 * a * tf)
    assert theta[N] == pytest.approx(theta_f / 2, rel=1e-14)
    np.testing.assert_allclose(traj[-1, 4:], 0.0, atol=1e-12 * a * tf)      # at rest at tf
    assert Q.qangle(traj[-1, :4]) == pytest.approx(theta_f, abs=1e-10)


def test_propagate_time_scaling_of_physical_units():
    """Scaling J and u together leaves the motion unchanged; scaling time by c scales rates by 1/c."""
    J = np.array([1.0, 0.8, 0.4])
    u = np.array([0.3, -1.0, 0.5])
    x0 = state([1, 0, 0, 0], [0.1, 0.0, -0.2])
    ref = D.propagate(x0, u, J, 2.0, 400)
    same = D.propagate(x0, 7.0 * u, 7.0 * J, 2.0, 400)
    np.testing.assert_allclose(same, ref, atol=1e-13)
    c = 10.0   # t' = c t: J' = J, u' = u / c², ω' = ω / c
    slow = D.propagate(state([1, 0, 0, 0], x0[4:] / c), u / c ** 2, J, 2.0 * c, 400)
    np.testing.assert_allclose(slow[:, :4], ref[:, :4], atol=1e-12)
    np.testing.assert_allclose(slow[:, 4:] * c, ref[:, 4:], atol=1e-12)


# ---------------------------------------------------------------- RK4
def _rk4_solve(x0, u, J, T, n):
    x = x0.copy()
    h = T / n
    for _ in range(n):
        x = D.rk4_step(x, u, J, h)
    return x


def test_rk4_step_fourth_order_convergence():
    J = np.array([1.0, 2.0, 3.0])
    u = np.array([0.4, -0.3, 0.2])
    x0 = state(Q.quat_from_euler321(0.3, 0.2, 0.1), [1.0, -2.0, 1.5])
    T = 2.0
    ref = _rk4_solve(x0, u, J, T, 4096)
    errs = [np.linalg.norm(_rk4_solve(x0, u, J, T, n) - ref) for n in (16, 32, 64)]
    ratios = [errs[0] / errs[1], errs[1] / errs[2]]
    for r in ratios:
        assert 13.0 < r < 19.5, (errs, ratios)
    # and the local error of one step is O(h⁵): ratio ≈ 32
    exact = _rk4_solve(x0, u, J, 0.1, 256)
    e1 = np.linalg.norm(D.rk4_step(x0, u, J, 0.1) - exact)
    e2 = np.linalg.norm(D.rk4_step(x0, u, J, 0.05) - _rk4_solve(x0, u, J, 0.05, 256))
    assert 25.0 < e1 / e2 < 40.0, (e1, e2)


def test_rk4_step_is_pure_no_renormalisation():
    x0 = state([2.0, 0, 0, 0], [0, 0, 0])   # non-unit quaternion, at rest, no torque: fixed point
    np.testing.assert_array_equal(D.rk4_step(x0, np.zeros(3), np.ones(3), 0.1), x0)
    x1 = state([1.0, 0, 0, 0], [1.0, 0, 0])
    out = D.rk4_step(x1, np.zeros(3), np.ones(3), 0.5)
    # RK4 of q̇ = ½ q ⊗ [0, ω]: norm grows by the truncated series, not renormalised
    assert np.linalg.norm(out[:4]) != 1.0


def test_propagate_renormalises_and_matches_rk4():
    J = np.array([1.0, 2.0, 3.0])
    u = np.array([0.4, -0.3, 0.2])
    x0 = state([1, 0, 0, 0], [1.0, -2.0, 1.5])
    traj = D.propagate(x0, u, J, 1.0, 10)
    x = x0.copy()
    for k in range(10):
        x = D.rk4_step(x, u, J, 0.1)
        x[:4] /= np.linalg.norm(x[:4])
        np.testing.assert_allclose(traj[k + 1], x, atol=1e-15)
    x0[0] = 5.0                       # propagate does not write into its input
    assert traj[0, 0] == 1.0


# ---------------------------------------------------------------- torque from action
UNIT = np.ones(3)


def test_torque_from_action_per_axis_clipping():
    for p in (0.0, -1.0):                        # p <= 0: per-axis (∞-norm) bound
        np.testing.assert_array_equal(D.torque_from_action(np.array([2.0, -3.0, 0.5]), UNIT, p),
                                      [1.0, -1.0, 0.5])
        np.testing.assert_array_equal(D.torque_from_action(np.array([1.0, -1.0, 1.0]), UNIT, p),
                                      [1.0, -1.0, 1.0])      # corners allowed for ∞-norm


def test_torque_from_action_umax_scaling():
    umax = np.array([50.0, 20.0, 0.5])
    np.testing.assert_allclose(D.torque_from_action(np.array([0.5, -7.0, 1.0]), umax, 0.0),
                               [25.0, -20.0, 0.5], rtol=1e-15)
    # p-norm: ‖u / umax‖_p ≤ 1
    out = D.torque_from_action(np.array([1.0, 1.0, 1.0]), umax, 2.0)
    np.testing.assert_allclose(out / umax, np.full(3, 1 / math.sqrt(3)), rtol=1e-15)


def test_torque_from_action_nan_and_inf():
    out = D.torque_from_action(np.array([np.nan, 0.3, -np.inf]), np.array([2.0, 2.0, 2.0]), 0.0)
    np.testing.assert_array_equal(out, [0.0, 0.6, -2.0])
    out = D.torque_from_action(np.array([np.nan, np.nan, np.nan]), UNIT, 2.0)
    np.testing.assert_array_equal(out, [0.0, 0.0, 0.0])
    out = D.torque_from_action(np.array([np.inf, np.nan, np.inf]), UNIT, 2.0)
    np.testing.assert_allclose(out, [1 / math.sqrt(2), 0.0, 1 / math.sqrt(2)], rtol=1e-15)


@pytest.mark.parametrize("p", [1.5, 2.0, 3.0, 20.0])
def test_torque_from_action_p_norm_projection(p):
    rng = np.random.default_rng(int(p * 10))
    n_out = n_in = 0
    for _ in range(300):
        a = rng.uniform(-1.3, 1.3, 3)
        v = np.clip(a, -1.0, 1.0)
        out = D.torque_from_action(a, UNIT, p)
        norm_v = np.sum(np.abs(v) ** p) ** (1 / p)
        if norm_v > 1.0:
            n_out += 1
            assert np.sum(np.abs(out) ** p) ** (1 / p) == pytest.approx(1.0, rel=1e-12)
            np.testing.assert_allclose(out, v / norm_v, rtol=1e-12)   # radial: same direction
        else:
            n_in += 1
            np.testing.assert_array_equal(out, v)                       # untouched inside
    assert n_out > 20 and n_in > 20


def test_torque_from_action_euclidean_examples():
    np.testing.assert_allclose(D.torque_from_action(np.array([0.9, 0.9, 0.0]), UNIT, 2.0),
                               [1 / math.sqrt(2), 1 / math.sqrt(2), 0.0], rtol=1e-15)
    np.testing.assert_array_equal(D.torque_from_action(np.array([0.6, -0.8, 0.0]), UNIT, 2.0),
                                  [0.6, -0.8, 0.0])
    np.testing.assert_array_equal(D.torque_from_action(np.array([0.5, 0.5, 0.5]), UNIT, 2.0),
                                  [0.5, 0.5, 0.5])
    # the same action is inside the ∞-ball but outside the 2-ball
    a = np.array([1.0, -1.0, 0.0])
    np.testing.assert_array_equal(D.torque_from_action(a, UNIT, 0.0), a)
    np.testing.assert_allclose(np.linalg.norm(D.torque_from_action(a, UNIT, 2.0)), 1.0, rtol=1e-15)
