"""The eigenaxis baseline planner against closed forms and its own constraints."""
import math

import numpy as np
import pytest

from slew_env import SlewProblem
from slew_env.core import qfrom_axis_angle
from solvers import eigenaxis_slew


def _prob(J, axis, angle, **kw):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return SlewProblem(J, qf=qfrom_axis_angle(axis, angle), **kw)


def test_symmetric_two_norm_closed_form():
    e = eigenaxis_slew(_prob([2, 2, 2], [1, 2, 3], 2.0, torque_max=0.5, torque_norm=2))
    assert e.tf == pytest.approx(2 * math.sqrt(2.0 * 2 / 0.5), rel=1e-9)


def test_symmetric_per_axis_uses_the_cube_corner_of_the_bound():
    n = np.array([1.0, 2.0, 3.0]) / math.sqrt(14)
    e = eigenaxis_slew(_prob([1, 1, 1], n, 1.5))
    acc = 1.0 / np.max(np.abs(n))
    assert e.tf == pytest.approx(2 * math.sqrt(1.5 / acc), rel=1e-9)


def test_principal_axis_of_asymmetric_body_has_no_gyroscopic_torque():
    # R5: 150° about body x of diag(5621, 4547, 2364) with 50 N·m
    e = eigenaxis_slew(SlewProblem([5621, 4547, 2364], torque_max=50,
                                   qf=[math.cos(math.radians(75)), math.sin(math.radians(75)), 0, 0]))
    assert e.tf == pytest.approx(2 * math.sqrt(math.radians(150) * 5621 / 50), rel=1e-9)


def test_asymmetric_off_axis_respects_bounds_including_gyroscopic_torque():
    prob = _prob([1.0, 0.6, 0.3], [1, 1, 1], 2.5, torque_max=[1.0, 0.8, 0.5])
    e = eigenaxis_slew(prob)
    assert e.theta[-1] == pytest.approx(2.5)
    ratio = np.max(np.abs(e.u) / prob.torque_max)
    assert ratio <= 1 + 1e-6
    assert ratio > 0.999       # the bound is active: this is the fastest eigenaxis slew
    assert e.rate[0] == 0 and e.rate[-1] == 0
    # gyroscopic part present and sizeable at peak rate
    J = prob.inertia
    c = np.cross(e.axis, J * e.axis)
    assert np.linalg.norm(c) * np.max(e.rate) ** 2 > 0.05
    # slower than ignoring the gyroscopic torque
    acc0 = 1.0 / np.max(np.abs(J * e.axis) / prob.torque_max)
    assert e.tf > 2 * math.sqrt(2.5 / acc0)


def test_rate_limit_creates_a_coast_arc():
    prob = _prob([1, 1, 1], [0, 0, 1], 3.0, rate_max=0.8)
    e = eigenaxis_slew(prob)
    assert np.max(e.rate) == pytest.approx(0.8, rel=1e-6)
    # accelerate to 0.8 (time 0.8, angle 0.32), coast, decelerate: closed form
    assert e.tf == pytest.approx(2 * 0.8 + (3.0 - 2 * 0.32) / 0.8, rel=1e-6)


def test_eigenaxis_rejects_pointing_targets():
    with pytest.raises(ValueError, match="sensor_target"):
        eigenaxis_slew(SlewProblem([1, 1, 1], sensor_target=[0, 1, 0]))


def test_eigenaxis_slew_refuses_cones_unless_asked_for_a_reference_time():
    # a GNC review: the eigenaxis slew of a full-attitude problem with a Sun cone flew the sensor
    # 39° into the cone without a word, where solve(method="eigenaxis") refuses the problem
    from slew_env import Cone
    prob = SlewProblem([1, 1, 1], qf=[math.cos(0.6), 0, 0, math.sin(0.6)],
                       cones=[Cone([0.0, 0.0, 1.0], half_angle_deg=20.0)])
    with pytest.raises(ValueError, match="^cones: the eigenaxis slew ignores keep-out cones"):
        eigenaxis_slew(prob)
    free = SlewProblem([1, 1, 1], qf=[math.cos(0.6), 0, 0, math.sin(0.6)])
    assert eigenaxis_slew(prob, ignore_cones=True).tf == eigenaxis_slew(free).tf


@pytest.mark.parametrize("J, axis, rate_max", [
    ([1, 1, 1], [1, 2, 3], None),                      # symmetric body: bang-bang
    ([2, 2, 2], [1, -1, 0.5], 0.05),                   # symmetric body, rate cap: bang-coast-bang
    ([5621, 4547, 2364], [1, 0, 0], None),             # principal axis of an asymmetric body
    ([3, 2, 1], [0, 1, 0], [0.01, 0.02, 0.03]),        # principal axis, rate cap
])
def test_baseline_time_without_gyroscopic_term_is_the_closed_form(J, axis, rate_max):
    # the solver's gate (eigenaxis_time) takes the closed form when n × Jn = 0; it must agree
    # with the planner's own profile, and never be slower than a fine grid (conservative)
    from solvers.eigenaxis import eigenaxis_time, _phase_plane
    import solvers.core.eigenaxis_topp as topp
    prob = _prob(J, axis, 2.2, torque_max=[1.0, 0.7, 0.4], rate_max=rate_max)
    n, th, a, c, s_max = _phase_plane(prob)
    assert not np.any(c)
    fwd, bwd, fa, bd = topp.sweep(a, c, np.asarray(prob.torque_max, float), math.inf, float(s_max), float(th), 200000)
    _, s, steps = topp.capped_nodes(fwd, bwd, fa, bd, float(th), 200000, math.inf)    # the grid alone
    fine = topp.nodes_time(steps, s)
    T = eigenaxis_time(prob, n_grid=1000)
    assert T == pytest.approx(fine, rel=1e-8) and T <= fine * (1 + 1e-14)
    # the planner's profile splits the grid step where the rate cap starts: the closed form too
    assert eigenaxis_slew(prob).tf == pytest.approx(T, rel=1e-12)


def test_a_tight_rate_limit_is_exact_in_the_baseline_and_the_eigenaxis_answer():
    # a GNC review: 150° about a principal axis of a symmetric body at 0.1 deg/s took 1503.0 s on
    # the 1,000-step grid against θ/ω + ω/α = 1500.8727 s (the acceleration covers 0.3 % of a step)
    from solvers import solve
    from solvers.eigenaxis import eigenaxis_time
    th, w, J, u = math.radians(150.0), math.radians(0.1), 50.0, 0.1
    prob = SlewProblem([J, J, J], torque_max=u, qf=[math.cos(th / 2), 0, 0, math.sin(th / 2)], rate_max=w)
    exact = th / w + w / (u / J)
    assert exact == pytest.approx(1500.8727, abs=1e-4)
    for n_grid in (1000, 4000):
        assert eigenaxis_slew(prob, n_grid=n_grid).tf == pytest.approx(exact, rel=1e-12)
    assert eigenaxis_time(prob, n_grid=1000) == pytest.approx(exact, rel=1e-12)
    eig = solve(prob, method="eigenaxis")
    assert eig.success and eig.tf == pytest.approx(exact, rel=1e-12), eig.message
    assert eig.verification["rate_limit"]["value"] <= 1 + 1e-9
    # an asymmetric body off its principal axes (a gyroscopic term): the 1,000-step profile is
    # within 1e-6 of a 64-times finer one (it was 1.4e-3 above it before the split)
    prob = SlewProblem([40.0, 55.0, 70.0], torque_max=0.1, rate_max=math.radians(0.1),
                       qf=[math.cos(th / 2), *(math.sin(th / 2) * np.array([1.0, 2.0, 3.0]) / math.sqrt(14.0))])
    coarse, fine = eigenaxis_time(prob, n_grid=1000), eigenaxis_time(prob, n_grid=64000)
    assert fine <= coarse <= fine * (1 + 1e-6)


def test_baseline_time_of_an_asymmetric_body_off_axis_is_unchanged():
    # the sweep's fixed-point rounds stop when the acceleration stops changing: same profile
    prob = _prob([1.0, 0.6, 0.3], [1, 1, 1], 2.5, torque_max=[1.0, 0.8, 0.5])
    from solvers.eigenaxis import eigenaxis_time
    assert eigenaxis_time(prob, n_grid=4000) == pytest.approx(eigenaxis_slew(prob, n_grid=4000).tf, rel=1e-12)


@pytest.mark.parametrize("p", [1.2, 2.0, 3.0, 7.0])
def test_pnorm_feasible_interval_edges_against_a_dense_scan(p):
    """The feasible accelerations at a speed under a p-norm bound: the edges found by false
    position sit on the feasible side of the sublevel set's true edges (a dense scan of the
    norm), within 1e-12 of them."""
    from solvers.core.eigenaxis_topp import _pnorm_of, accel_interval, accel_interval_pnorm
    rng = np.random.default_rng(int(p * 10))
    checked = 0
    for _ in range(60):
        a = rng.normal(size=3)
        c = rng.normal(size=3) * 0.5
        U = rng.uniform(0.3, 1.5, 3)
        s = float(rng.uniform(0.0, 1.0))
        lo, hi, ok = accel_interval_pnorm(a, c, U, p, s)
        x = np.linspace(*accel_interval(a, c, U, s)[:2], 20001) if accel_interval(a, c, U, s)[2] else np.zeros(0)
        inside = x[[_pnorm_of(v, a, c, U, p, s) <= 1.0 for v in x]]
        if not ok:
            assert inside.size == 0
            continue
        checked += 1
        assert _pnorm_of(lo, a, c, U, p, s) <= 1.0 + 1e-12 and _pnorm_of(hi, a, c, U, p, s) <= 1.0 + 1e-12
        step = x[1] - x[0]
        assert inside.min() - step <= lo <= inside.min() + 1e-12
        assert inside.max() - 1e-12 <= hi <= inside.max() + step
        w = 1e-9 * max(1.0, hi - lo)
        if lo - w > x[0]:
            assert _pnorm_of(lo - w, a, c, U, p, s) > 1.0
        if hi + w < x[-1]:
            assert _pnorm_of(hi + w, a, c, U, p, s) > 1.0
    assert checked > 30


REF_PNORM_TIME = 2.4666369400956136   # commit eab27e4 (golden section and bisection)


def test_pnorm_baseline_time_unchanged():
    """The eigenaxis time of an asymmetric body under a 2-norm bound, as the golden-section and
    bisection sweep gave it before the false-position edges (to 1e-12)."""
    from solvers.eigenaxis import eigenaxis_time
    prob = _prob([1.0, 0.6, 0.35], [0.3, -0.5, 0.8], 2.2, torque_max=[1.0, 0.8, 0.6], torque_norm=2.0)
    assert eigenaxis_time(prob, n_grid=1000) == pytest.approx(REF_PNORM_TIME, rel=1e-12)


def test_both_sweeps_reaching_the_rate_cap_at_one_angle_give_one_point():
    # a review: 2.23 rad at a rate cap the slew reaches exactly at its middle (a tent whose apex
    # is the cap): the point was added twice (a zero-length piece, NaN torque at n_grid=7), and a
    # piece a rounding error long gave 1.125 times the torque bound at n_grid=1000
    from solvers.eigenaxis_answer import eigenaxis_answer
    th, J = 2.23, 36.0
    prob = SlewProblem([J] * 3, torque_max=1.0, qf=[math.cos(th / 2), math.sin(th / 2), 0, 0],
                       rate_max=[0.2488864087178013, 1e3, 1e3])
    exact = 2.0 * math.sqrt(th / (1.0 / J))           # the cap is the triangle's peak
    for n_grid in (7, 8, 999, 1000, 4000):
        es = eigenaxis_slew(prob, n_grid=n_grid)
        assert np.all(es.dtheta > 0) and np.all(np.isfinite(es.u))
        assert es.tf == pytest.approx(exact, rel=1e-12)
        assert float(np.max(np.abs(es.u))) <= 1.0 + 1e-9
    for n_grid in (999, 1000, 4000):
        sol = eigenaxis_answer(prob, n_grid=n_grid)
        assert sol.success and sol.verification["torque_bound"]["value"] <= 1.0 + 1e-9, sol.message
    # random symmetric slews at rate caps: every piece's acceleration within the bound
    rng = np.random.default_rng(3)
    for _ in range(200):
        th, J, U = rng.uniform(0.2, 3.0), rng.uniform(1.0, 30.0), rng.uniform(0.2, 2.0)
        w = math.sqrt(th * U / J) * rng.uniform(0.3, 1.0)      # reached before the middle, or at it
        prob = SlewProblem([J] * 3, torque_max=U, qf=[math.cos(th / 2), math.sin(th / 2), 0, 0], rate_max=w)
        es = eigenaxis_slew(prob, n_grid=int(rng.integers(5, 4001)))
        assert np.all(es.dtheta > 0) and float(np.max(np.abs(es.u))) / U <= 1.0 + 1e-9
        assert es.tf == pytest.approx(th / w + w / (U / J) if w * w < th * U / J else 2 * math.sqrt(th * J / U),
                                      rel=1e-9)


@pytest.mark.parametrize("kw", [{}, {"torque_norm": 2.0}, {"rate_max": [0.5, 0.6, 0.7]}, {"rate_norm_max": 0.6},
                                {"torque_norm": 1.5, "rate_norm_max": 0.6}])
@pytest.mark.parametrize("kj, ku", [(1e-15, 1e-15), (1e-20, 1.0), (1.0, 1e20), (1e40, 1.0), (1e-300, 1.0),
                                    (1e200, 1e200), (4e3, 0.05)])
def test_the_planner_gives_the_same_slew_in_any_units(kw, kj, ku):
    """Inertia and torque in any consistent units: the same slew, its times scaled by
    ``sqrt(kj / ku)`` (an outside fuzz had found inertia 1e-15 with torque 1e-15 planned with a
    torque 3e4 times its bound, and inertia 1e-300 with an eigenaxis time of 0)."""
    from solvers.eigenaxis import eigenaxis_time
    from solvers.eigenaxis_answer import eigenaxis_answer
    J, U = np.array([1.0, 0.8, 0.6]), np.array([1.0, 0.7, 0.9])
    axis, angle = [1.0, 1.0, 1.0], 1.4
    tau = math.sqrt(kj / ku)
    scaled = {k: (np.asarray(v) / tau).tolist() if k.startswith("rate") else v for k, v in kw.items()}
    ref = eigenaxis_slew(_prob(J, axis, angle, torque_max=U, **kw), n_grid=400)
    p = _prob(J * kj, axis, angle, torque_max=U * ku, **scaled)
    e = eigenaxis_slew(p, n_grid=400)
    assert e.tf == pytest.approx(tau * ref.tf, rel=1e-12)
    np.testing.assert_allclose(e.t, tau * ref.t, rtol=1e-12, atol=0)
    np.testing.assert_allclose(e.u, ku * ref.u, rtol=1e-9, atol=1e-9 * ku * np.max(np.abs(ref.u)))
    assert eigenaxis_time(p, n_grid=400) == pytest.approx(tau * eigenaxis_time(_prob(J, axis, angle, torque_max=U, **kw),
                                                                             n_grid=400), rel=1e-12)
    ans = eigenaxis_answer(p, n_grid=400)
    assert ans.success and ans.tf == pytest.approx(tau * ref.tf, rel=1e-12), ans.message
