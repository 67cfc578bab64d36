"""The compiled re-propagation of collocation controls against scipy's DOP853."""
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from slew_env.core.dynamics import state_rhs
from solvers.core.control_replay import quadratic_control, replay_quadratic_control


def _reference(x0, tk, U, Um, Ulim, p, J, samples):
    x = x0.copy()
    out = [x.copy()]
    for k in range(len(tk) - 1):
        a, b = tk[k], tk[k + 1]

        def rhs(t, y, k=k, a=a, b=b):
            return state_rhs(y, np.array(quadratic_control((t - a) / (b - a), U[k], Um[k], U[k + 1], Ulim, p)), J)
        r = solve_ivp(rhs, (a, b), x, method="DOP853", rtol=1e-12, atol=1e-13, dense_output=True)
        out.extend(r.sol(np.linspace(a, b, samples + 1)[1:]).T)
        x = r.y[:, -1].copy()
    return np.array(out)


def _case(p, amp):
    rng = np.random.default_rng(3)
    N = 12
    J = np.array([0.6, 0.8, 1.0])
    Ulim = np.array([1.0, 0.7, 0.9])
    tk = np.concatenate([[0.0], np.cumsum(rng.uniform(0.05, 0.2, N))])
    U = rng.uniform(-amp, amp, (N + 1, 3)) * Ulim
    Um = rng.uniform(-amp, amp, (N, 3)) * Ulim
    if not math.isinf(p):       # inside the ball: no clipping at amp < 1 / sqrt(3)
        U, Um = U / math.sqrt(3.0), Um / math.sqrt(3.0)
    q = rng.normal(size=4)
    x0 = np.concatenate([q / np.linalg.norm(q), rng.normal(scale=0.3, size=3)])
    return x0, tk, U, Um, Ulim, p, J


@pytest.mark.parametrize("p", [math.inf, 2.0])
def test_replay_matches_dop853(p):
    # controls within the bound, as collocation returns them (IPOPT's bound relaxation is
    # ~1e-8): smooth on each interval, where RK4 keeps its fourth order
    x0, tk, U, Um, Ulim, p, J = _case(p, 0.95)
    N = len(tk) - 1
    t, X, n = replay_quadratic_control(x0, tk, U, Um, Ulim, p, J, 96, 1)
    assert t.shape == (N * 96 + 1,) and X.shape == (N * 96 + 1, 7) and n == 4 * N * 96
    assert t[0] == tk[0] and t[-1] == tk[-1]
    assert np.abs(X - _reference(x0, tk, U, Um, Ulim, p, J, 96)).max() < 1e-10


@pytest.mark.parametrize("p", [math.inf, 2.0])
def test_replay_of_a_clipped_control_converges(p):
    # controls well beyond the bound: the clipped control has kinks inside intervals, where
    # RK4 drops to second order (an adaptive DOP853 reference is no more accurate there);
    # substeps converge
    x0, tk, U, Um, Ulim, p, J = _case(p, 1.3 * (1.0 if math.isinf(p) else math.sqrt(3.0)))
    X = {m: replay_quadratic_control(x0, tk, U, Um, Ulim, p, J, 96, m)[1] for m in (1, 8, 64)}
    e1, e8 = np.abs(X[1] - X[64]).max(), np.abs(X[8] - X[64]).max()
    assert e8 < e1 / 20 and e1 < 1e-5


def test_quadratic_control_is_clipped_to_the_bound():
    Ulim = np.array([1.0, 2.0, 0.5])
    Uk, Um, Uk1 = np.array([2.0, -3.0, 0.1]), np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0])
    np.testing.assert_allclose(quadratic_control(0.0, Uk, Um, Uk1, Ulim, math.inf), [1.0, -2.0, 0.1])
    u = np.array(quadratic_control(0.0, Uk, Um, Uk1, Ulim, 2.0))
    assert np.linalg.norm(u / Ulim) == pytest.approx(1.0)
    np.testing.assert_allclose(u / np.linalg.norm(u), Uk / np.linalg.norm(Uk))
