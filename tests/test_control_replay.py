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


def _python_bang_bang_path(J, umax, q0, w0, switch_times, u_first, tf, steps_per_tf=1000):
    """``solvers.verify.replay_path`` as it ran before it was compiled (the reference)."""
    from slew_env.core.dynamics import propagate
    events = sorted((float(t), i) for i in range(3) for t in switch_times[i])
    signs = np.array(u_first, dtype=float)
    x = np.concatenate([q0, w0]).astype(float)
    ts, xs = [np.zeros(1)], [x[None, :]]
    t_prev = 0.0
    h_nom = tf / steps_per_tf
    for t_next, axis in events + [(tf, -1)]:
        dt = t_next - t_prev
        if dt > 0:
            n = max(1, int(math.ceil(dt / h_nom)))
            traj = propagate(x, umax * signs, J, dt, n)
            ts.append(t_prev + np.linspace(0.0, dt, n + 1)[1:])
            xs.append(traj[1:])
            x = traj[-1]
        if axis >= 0:
            signs[axis] = -signs[axis]
        t_prev = max(t_prev, t_next)
    return np.concatenate(ts), np.vstack(xs)


def test_the_compiled_bang_bang_replay_is_the_python_loop_bit_for_bit():
    from solvers.verify import replay_path
    rng = np.random.default_rng(5)
    for k in range(40):
        J = rng.uniform(0.2, 3.0, 3)
        umax = rng.uniform(0.1, 2.0, 3)
        q0 = rng.normal(size=4)
        q0 /= np.linalg.norm(q0)
        w0 = rng.normal(size=3) * (k % 2)
        tf = float(rng.uniform(0.05, 5.0))
        # any number of switches per axis, ties across axes, one at 0, and one past tf
        sw = [np.sort(rng.uniform(0.0, tf, rng.integers(0, 5))) for _ in range(3)]
        if k % 5 == 1 and sw[0].size and sw[1].size:
            sw[1][0] = sw[0][0]
        if k % 7 == 2:
            sw[2] = np.concatenate([[0.0], sw[2]])
        if k % 9 == 3:
            sw[0] = np.concatenate([sw[0], [1.1 * tf]])
        u_first = rng.choice([-1.0, 1.0], 3)
        steps = int(rng.choice([7, 100, 1000]))
        t, x = replay_path(J, umax, q0, w0, sw, u_first, tf, steps)
        t0, x0 = _python_bang_bang_path(J, umax, q0, w0, sw, u_first, tf, steps)
        assert np.array_equal(t, t0) and np.array_equal(x, x0, equal_nan=True)   # a coarse replay may blow up: alike
    # no switches at all: one arc of constant torque
    t, x = replay_path(np.ones(3), np.ones(3), np.array([1.0, 0, 0, 0]), np.zeros(3), [[], [], []], [1, 1, 1], 2.0, 10)
    assert t.shape == (11,) and t[-1] == 2.0 and np.allclose(x[-1, 4:7], 2.0)


def _python_propagate_guess(sc, guess, n=400):
    """``solvers.collocation_guesses.propagate_guess`` as it ran before it was compiled (reference)."""
    from solvers.core import attitude_flow as af
    T = guess.tf / sc.tau
    prob = sc.prob
    t = np.linspace(0.0, T, n + 1)
    h = T / n
    if guess.switch_times is not None and guess.u_first is not None:
        sw = [np.asarray(s) / sc.tau for s in guess.switch_times]
        u0 = np.where(guess.u_first == 0, 1.0, guess.u_first)

        def uf(tt, y):
            flips = np.array([np.searchsorted(sw[i], tt, side="right") for i in range(3)])
            return sc.U * u0 * np.where(flips % 2 == 0, 1.0, -1.0)
        src = "guess(switch times)"
    else:
        mode = af.MODE_BANG if math.isinf(sc.p) else af.MODE_PNORM
        pp = 0.0 if math.isinf(sc.p) else sc.p

        def uf(tt, y):
            if mode == af.MODE_BANG:
                S = y[11:14] / sc.J
                return -sc.U * np.where(S >= 0, 1.0, -1.0)
            return af.control(y, sc.J, sc.U, mode, pp, 1e-2, np.ones(3))[0]
        src = "guess(costates)"
    y = np.concatenate([sc.x0, guess.costate0[:4] / sc.tau, guess.costate0[4:] / sc.tau ** 2])
    Y = np.empty((n + 1, 14))
    Uu = np.empty((n + 1, 3))
    Y[0] = y
    for k in range(n):
        tt = t[k]
        uk = uf(tt, y)
        Uu[k] = uk
        k1 = af.ext_rhs(y, uk, sc.J)
        k2 = af.ext_rhs(y + 0.5 * h * k1, uf(tt + 0.5 * h, y + 0.5 * h * k1), sc.J)
        k3 = af.ext_rhs(y + 0.5 * h * k2, uf(tt + 0.5 * h, y + 0.5 * h * k2), sc.J)
        k4 = af.ext_rhs(y + h * k3, uf(tt + h, y + h * k3), sc.J)
        y = y + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        y[0:4] /= np.linalg.norm(y[0:4])
        Y[k + 1] = y
    Uu[n] = uf(t[n], y)
    return T, t, Y, Uu


@pytest.mark.parametrize("p_norm", [np.inf, 2.0, 3.0])
def test_the_compiled_guess_path_is_the_python_loop(p_norm):
    from slew_env import SlewProblem
    from slew_env.core import qfrom_uniform
    from solvers import Guess
    from solvers.collocation_guesses import propagate_guess
    from solvers.collocation_nlp import Scaled
    rng = np.random.default_rng(12)
    for k in range(6):
        prob = SlewProblem(rng.uniform(0.3, 1.0, 3) * 7.0, torque_max=rng.uniform(0.2, 2.0, 3), torque_norm=p_norm,
                           q0=qfrom_uniform(*rng.random(3)), qf=qfrom_uniform(*rng.random(3)))
        sc = Scaled.of(prob)
        c0 = rng.normal(size=7)
        tf = float(rng.uniform(1.0, 6.0)) * sc.tau
        if k % 2 and math.isinf(p_norm):
            sw = [np.sort(rng.uniform(0, tf, rng.integers(0, 4))) for _ in range(3)]
            g = Guess(c0, tf, sw, np.array(rng.choice([-1.0, 1.0], 3)))
        else:
            g = Guess(c0, tf)
        new = propagate_guess(sc, g, n=int(rng.choice([7, 400])))
        T, t, Y, Uu = _python_propagate_guess(sc, g, n=new.t.size - 1)
        assert new.T == T and np.array_equal(new.t, t)
        assert np.allclose(new.q, Y[:, 0:4], rtol=0, atol=1e-12) and np.allclose(new.w, Y[:, 4:7], rtol=0, atol=1e-11)
        assert np.allclose(new.u, Uu, rtol=0, atol=1e-12)


def test_guess_path_switch_exactly_on_a_grid_point_and_a_midpoint():
    """An axis flips at every instant at or before the time asked (as ``searchsorted(side="right")``):
    a switch exactly on a grid point acts from that point's own step, one exactly at a step's
    midpoint from that step's second and third stages."""
    from solvers.core import attitude_flow as af
    from solvers.core.control_replay import guess_path
    J = np.array([1.0, 0.8, 0.6])
    U = np.array([1.0, 0.5, 0.7])
    n = 8
    t = np.linspace(0.0, 2.0, n + 1)
    h = t[1] - t[0]
    y0 = np.zeros(14)
    y0[0] = 1.0
    sw_t = np.array([t[3], t[5] + 0.5 * h])       # x on grid point 3, y at the midpoint of step 5
    sw_axis = np.array([0, 1], dtype=np.int64)
    u0 = np.array([1.0, -1.0, 1.0])
    Y, Uu = guess_path(y0, t, J, U, af.MODE_BANG, 0.0, sw_t, sw_axis, u0, True)

    def torque(tt):
        flips = np.array([np.searchsorted(np.sort(sw_t[sw_axis == i]), tt, side="right") for i in range(3)])
        return U * u0 * np.where(flips % 2 == 0, 1.0, -1.0)
    y = y0.copy()
    for k in range(n):
        tt = t[k]
        k1 = af.ext_rhs(y, torque(tt), J)
        k2 = af.ext_rhs(y + 0.5 * h * k1, torque(tt + 0.5 * h), J)
        k3 = af.ext_rhs(y + 0.5 * h * k2, torque(tt + 0.5 * h), J)
        k4 = af.ext_rhs(y + h * k3, torque(tt + h), J)
        y = y + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        y[0:4] /= np.linalg.norm(y[0:4])
        assert np.allclose(Y[k + 1], y, rtol=0, atol=1e-14)
    # the torque sampled at the grid points: x flipped from point 3 on, y from point 6 on
    assert np.array_equal(Uu[:, 0], np.where(np.arange(n + 1) >= 3, -1.0, 1.0))
    assert np.array_equal(Uu[:, 1], np.where(np.arange(n + 1) >= 6, 0.5, -0.5))
    assert np.array_equal(Uu[:, 2], np.full(n + 1, 0.7))
