"""The rate limit holds between the dense samples too (an outside adversarial check, session 43):
with large start rates a rate can peak inside an arc, where Euler's equations turn it round, and an
exact extremal whose samples at t = 0.0187 and 0.0370 passed (ratio 0.9999999999) peaked at
t = 0.0276, 0.214 % over the limit (scipy's DOP853 and Radau agree)."""
import numpy as np
import pytest

import solvers
from slew_env import SlewProblem
from solvers import Guess

# runs/s43/adversarial/repro_F0_rate_limit_between_samples_seed31.json and the answer auto gave it
F0 = SlewProblem(inertia=[1.0, 0.29594224984475603, 0.46986171044240455],
                 qf=[0.8747677051964231, 0.28300535656359493, 0.37338241522522214, -0.12359207944798087],
                 omega0=[-4.344881024792871, -5.170868704393943, -0.5625622958380763],
                 rate_max=[1000.0, 5.266780228583561, 1000.0])
F0_ANSWER = Guess(np.array([0.0, -0.09003679196318076, -0.3209821073258194, 0.2987331620660741,
                            -0.936255794942656, 0.003184677525131953, -0.040626512503685853]), 3.691806598218831,
                  [np.array([]), np.array([0.08071408290724302, 0.5410185308331225, 1.1591612772372604,
                                           1.9927950840896744, 2.306953260208203, 3.5633962752044623]),
                   np.array([0.05748452260097784, 0.49295866906142877, 0.9748201935920937, 1.620786127256433])],
                  np.array([1.0, -1.0, 1.0]), source="the answer that broke the limit")


def test_an_extremal_over_the_limit_between_its_samples_fails_its_check():
    s = solvers.solve(F0, method="indirect", guess=F0_ANSWER, warm_start=None, max_candidates=1, min_candidates=1)
    assert not s.success and s.status == 2
    check = s.verification["rate_limit"]
    assert not check["passed"] and check["value"] == pytest.approx(1.0021419668, rel=1e-7)   # DOP853's peak
    assert "rate_limit" in s.message


def test_auto_answers_it_within_the_limit():
    from scipy.integrate import solve_ivp
    s = solvers.solve(F0)
    assert s.success, s.message
    J = np.asarray(F0.inertia)
    r = solve_ivp(lambda t, w: (s.control(t) - np.cross(w, J * w)) / J, (0.0, s.tf), np.asarray(F0.omega0, float),
                  method="DOP853", rtol=1e-10, atol=1e-12, t_eval=np.linspace(0.0, s.tf, 20001), max_step=s.tf / 2000)
    assert F0.rate_limit_ratio(r.y.T) <= 1.0 + 1e-6


def test_far_from_the_limit_the_check_is_the_samples_maximum(monkeypatch):
    from solvers import verify
    calls = []
    real = verify._bang_rates_between
    monkeypatch.setattr(verify, "_bang_rates_between", lambda *a: calls.append(real(*a)) or calls[-1])
    p = SlewProblem([1, 1, 1], qf=[0, 0, 0, 1], rate_max=10.0)        # R1 peaks at about 1.6
    s = solvers.solve(p, method="indirect", warm_start=None, max_candidates=1, min_candidates=1)
    assert s.success and s.verification["rate_limit"]["value"] < 0.2
    assert calls and max(calls) == pytest.approx(s.verification["rate_limit"]["value"])


def test_a_pnorm_extremal_is_checked_between_its_samples_too():
    """A 2-norm extremal whose largest sampled rate is set as the limit (plus 1e-5): its rate peaks
    2.5e-5 above that between two samples, so the answer fails the check (the state and costates
    integrated again, the p-norm law)."""
    qf = np.array([0.87, 0.28, 0.37, -0.12])
    free = SlewProblem([1, 0.6, 0.45], torque_norm=2, qf=qf / np.linalg.norm(qf), omega0=[-3.0, -3.5, -0.5])
    s = solvers.solve(free, method="indirect", warm_start=None)
    assert s.success
    peak = float(np.max(np.abs(s.omega[:, 1])))
    limited = free.replace(rate_max=[100.0, peak * (1 + 1e-5), 100.0])
    s2 = solvers.solve(limited, method="indirect", warm_start=None)
    assert not s2.success and s2.verification["rate_limit"]["value"] == pytest.approx(1.000025, abs=5e-6)


def _true_peak(J, umax, w0, sw, s0, T, axis):
    """max |ω_axis| over a bang-bang path by scipy's DOP853 on each arc, refined by a bounded search."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import minimize_scalar
    from solvers.solution import bang_bang_control
    br = np.unique(np.concatenate([np.concatenate(sw), [0.0, T]]))
    ctl = bang_bang_control(sw, s0, umax)
    w, best = np.array(w0, float), abs(w0[axis])
    for a, b in zip(br[:-1], br[1:]):
        u = ctl(0.5 * (a + b))
        r = solve_ivp(lambda t, w: (u - np.cross(w, J * w)) / J, (a, b), w, method="DOP853", rtol=1e-12, atol=1e-14,
                      dense_output=True)
        tt = np.linspace(a, b, 2001)
        R = np.abs(r.sol(tt)[axis])
        k = int(np.argmax(R))
        m = minimize_scalar(lambda x: -abs(float(r.sol(x)[axis])), bounds=(tt[max(k - 1, 0)], tt[min(k + 1, 2000)]),
                            method="bounded", options={"xatol": 1e-13})
        best = max(best, float(R[k]), -m.fun)
        w = r.y[:, -1]
    return best


def test_the_check_between_samples_agrees_with_an_independent_integration():
    """Random bang-bang paths with large start rates, sampled as the dense records are (every
    switch and T/100): the check's ratio against scipy's DOP853 peak, with the limit 1e-7 below
    the peak (must fail) and 1e-11 above it (must pass). A review found a peak in an interval's
    last sub-step reported at the sample's value (1e-6 low) and 32 fixed steps overshooting by 3e-8
    on fast-spinning bodies."""
    from scipy.integrate import solve_ivp
    from solvers.attitude_bvp import AttitudeBVP
    from solvers.solution import bang_bang_control
    from solvers.verify import DEFAULT_TOLS, rate_limit_check
    rng = np.random.default_rng(3)
    checked = 0
    for trial in range(12):
        J = np.array([1.0, rng.uniform(0.1, 1.0), rng.uniform(0.1, 1.0)])
        umax = rng.uniform(0.2, 1.0, 3)
        umax /= umax.max()
        w0 = rng.normal(size=3) * rng.uniform(1.0, 5.0)
        T = rng.uniform(1.0, 4.0)
        sw = [np.sort(rng.uniform(0.0, T, rng.integers(0, 5))) for _ in range(3)]
        s0 = rng.choice([-1.0, 1.0], 3)
        grid = np.unique(np.concatenate([np.linspace(0.0, T, 101)] + sw))
        br = np.unique(np.concatenate([np.concatenate(sw), [0.0, T]]))
        ctl = bang_bang_control(sw, s0, umax)
        w, ts, Ws = w0.copy(), [], []
        for a, b in zip(br[:-1], br[1:]):
            u = ctl(0.5 * (a + b))
            r = solve_ivp(lambda tt, w: (u - np.cross(w, J * w)) / J, (a, b), w, method="DOP853", rtol=1e-12,
                          atol=1e-14, dense_output=True)
            g = grid[(grid >= a) & (grid <= b)]
            ts.append(g)
            Ws.append(r.sol(g).T)
            w = r.y[:, -1]
        t, W = np.concatenate(ts), np.concatenate(Ws)
        Y = np.hstack([np.zeros((len(t), 4)), W])
        peak = _true_peak(J, umax, w0, sw, s0, T, 1)
        if peak <= abs(w0[1]) * (1 + 1e-6):
            continue                                  # the start is the peak: nothing between samples
        for fac, passes in ((1 - 1e-7, False), (1 + 1e-11, True)):
            p = SlewProblem(list(J), torque_max=list(umax), qf=[1, 0, 0, 0], omega0=list(w0),
                            rate_max=[1e9, peak * fac, 1e9])
            c = rate_limit_check(AttitudeBVP(p), Y, DEFAULT_TOLS, t, sw, s0)["rate_limit"]
            assert c["value"] == pytest.approx(1.0 / fac, abs=1e-8), (trial, fac)
            assert c["passed"] is passes, (trial, fac, c)
        checked += 1
    assert checked >= 6
