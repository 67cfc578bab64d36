"""The state-only arc (``solvers.core.state_arc``) against the augmented 14-dimensional flow it
stands in for when the costates are zero, and its transition matrix against finite differences."""
import numpy as np
import pytest

from solvers.core.attitude_flow import MODE_BANG, NY
from solvers.core.state_arc import state_arc
from solvers.core.switch_sequence import _arc_transition, _fixed_arc, no_step_budget

NO_PEN = np.empty(0)


def _random_arc(rng):
    q = rng.normal(size=4)
    x = np.concatenate([q / np.linalg.norm(q), rng.normal(size=3) * 0.6])
    J = rng.uniform(0.2, 1.0, 3)
    umax = rng.uniform(0.2, 1.0, 3)
    signs = rng.choice([-1.0, 1.0], 3)
    return x, float(rng.uniform(0.01, 4.0)), J, umax, signs


def _augmented(x, dt, J, umax, signs, m, rtol=1e-12, atol=1e-12):
    Y0 = np.zeros(NY + NY * m)
    Y0[:7] = x
    for c in range(m):
        Y0[NY + c * m + c] = 1.0
    Y, ok = _fixed_arc(Y0, dt, m, signs, J, umax, MODE_BANG, 0.0, 0.0, rtol, atol, NO_PEN, no_step_budget())
    Phi = np.array([[Y[NY + i * m + c] for c in range(m)] for i in range(min(m, 7))]).reshape(min(m, 7), m)
    return Y, Phi, ok


@pytest.mark.parametrize("want_phi", [False, True])
def test_same_steps_and_states_as_the_augmented_flow(want_phi):
    rng = np.random.default_rng(11)
    for _ in range(40):
        x, dt, J, umax, signs = _random_arc(rng)
        x1, Phi1, ok1 = state_arc(x, dt, umax * signs, J, 1e-12, 1e-12, want_phi)
        Y, Phi2, ok2 = _augmented(x, dt, J, umax, signs, 7 if want_phi else 0)
        assert ok1 and ok2
        # the same error norm on the same state components: the same steps, so the same bits
        np.testing.assert_array_equal(x1, Y[:7])
        assert np.all(Y[7:NY] == 0.0)
        if want_phi:
            np.testing.assert_array_equal(Phi1, Phi2[:7, :7])
        else:
            assert np.all(Phi1 == 0.0)


def test_transition_matrix_matches_finite_differences():
    rng = np.random.default_rng(5)
    x, dt, J, umax, signs = _random_arc(rng)
    u = umax * signs
    _, Phi, ok = state_arc(x, dt, u, J, 1e-13, 1e-13, True)
    assert ok
    h = 1e-6
    for c in range(7):
        e = np.zeros(7)
        e[c] = h
        xp, _, _ = state_arc(x + e, dt, u, J, 1e-13, 1e-13, False)
        xm, _, _ = state_arc(x - e, dt, u, J, 1e-13, 1e-13, False)
        np.testing.assert_allclose(Phi[:, c], (xp - xm) / (2 * h), atol=1e-7)


def test_arc_transition_uses_the_augmented_flow_when_costates_are_not_zero():
    """Non-zero costates must still be carried (``verify`` replays an extremal's switch times
    with its costates): the state arc would drop them."""
    rng = np.random.default_rng(2)
    x, dt, J, umax, signs = _random_arc(rng)
    y = np.zeros(NY)
    y[:7] = x
    y[7:] = rng.normal(size=7)
    y1, _, ok = _arc_transition(y, dt, 0, signs, J, umax, MODE_BANG, 0.0, 0.0, 1e-12, 1e-12, NO_PEN,
                                no_step_budget())
    Y, _, ok2 = _augmented(y[:7], dt, J, umax, signs, 0)
    assert ok and ok2
    # the state does not see the costates (only the step sizes do)
    np.testing.assert_allclose(y1[:7], Y[:7], rtol=0, atol=1e-9)
    assert np.abs(y1[7:]).max() > 1e-3                  # and the costates were propagated


def test_non_finite_start_is_reported_not_returned():
    x = np.array([1.0, 0.0, 0.0, 0.0, np.nan, 0.0, 0.0])
    _, _, ok = state_arc(x, 1.0, np.ones(3), np.ones(3), 1e-10, 1e-10, True)
    assert not ok
