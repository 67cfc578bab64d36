"""Bang-bang switch-time optimisation: exact on a bang-bang optimum, and auto's answer to
problems with a singular arc (an exactly feasible bang-bang slew instead of collocation's)."""
import json
import math
import os

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from slew_env import Cone, SlewProblem
from solvers import Guess, solve
from solvers.attitude_bvp import AttitudeBVP
from solvers.collocation import solve_collocation
from solvers.switch_time_opt import (bang_bang_answer, interior_run, optimise_switch_times, sequence_from_samples,
                                     singular_arc_evidence)

EXAMPLES = os.path.join(os.path.dirname(__file__), os.pardir, "examples")
# held-out full-attitude problem 32 (seed 20261122): J = I; no bang-bang optimum (one axis's
# torque interior on a stretch of the collocation answer) and no exact extremal from any guess
SINGULAR = SlewProblem([1.0, 1.0, 1.0], q0=[0.09652844304608175, 0.08753364710188939, 0.9727164986420677,
                                            0.19194461070230023],
                       qf=[0.3927736518182858, 0.1982480014838032, 0.7421428665242, 0.5056189810640513])


def _qmul(a, b):
    return np.array([a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                     a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                     a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                     a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]])


def _replay(p, switch_times, u_first, tf):
    """Attitude (rad) and rate misses of the bang-bang control given by switch times alone,
    integrated here with scipy's DOP853 (independent of the package's integrators)."""
    J, U = np.asarray(p.inertia, float), np.asarray(p.torque_max, float)
    events = sorted((float(t), i) for i in range(3) for t in switch_times[i])
    s, x, t0 = np.array(u_first, float), np.concatenate([p.q0, p.omega0]), 0.0
    for t1, axis in events + [(tf, -1)]:
        if t1 > t0:
            u = U * s
            x = solve_ivp(lambda t, y: np.concatenate([0.5 * _qmul(y[:4], np.r_[0.0, y[4:]]),
                                                       (u - np.cross(y[4:], J * y[4:])) / J]),
                          (t0, t1), x, method="DOP853", rtol=1e-12, atol=1e-13).y[:, -1]
            t0 = t1
        if axis >= 0:
            s[axis] = -s[axis]
    q = x[:4] / np.linalg.norm(x[:4])
    d = _qmul(np.r_[p.qf[0], -np.asarray(p.qf[1:])], q)
    return 2 * math.atan2(np.linalg.norm(d[1:]), abs(d[0])), float(np.linalg.norm(x[4:] - p.omegaf))


def test_optimised_switch_times_recover_the_exact_bang_bang_optimum_and_its_costates():
    # R3, per-axis bound: the exact extremal is a KKT point of its own switching sequence
    p = SlewProblem.from_dict(json.load(open(os.path.join(EXAMPLES, "r3_seed_report_per_axis.json"))))
    s = solve(p, warm_start=None)
    assert s.exact and s.tf == pytest.approx(2.35402, abs=1e-5)
    bvp = AttitudeBVP(p)
    axes = np.array([a for a in range(3) for _ in s.switch_times[a]])
    times = np.concatenate(s.switch_times) / bvp.tau
    rng = np.random.default_rng(0)
    r = optimise_switch_times(p, s.u_first, axes, times * (1 + 0.03 * rng.standard_normal(times.size)),
                              1.02 * s.tf / bvp.tau)
    assert r.success and r.converged and r.residual < 1e-12
    assert r.T * bvp.tau == pytest.approx(s.tf, rel=1e-10)
    for a in range(3):
        np.testing.assert_allclose(r.switch_times()[a] * bvp.tau, s.switch_times[a], atol=1e-8)
    # the multipliers are the extremal's costates (same sign, unit norm in the solver's units)
    z_true, _ = Guess(s.costate0, s.tf).to_nondim(bvp)
    assert float(r.z @ z_true) == pytest.approx(1.0, abs=1e-8)


def test_auto_answers_a_singular_problem_with_an_exactly_feasible_bang_bang_slew():
    col = solve_collocation(SINGULAR)
    assert col.success
    # collocation's zero crossings, flown as a bang-bang control, miss the target by milliradians
    assert max(_replay(SINGULAR, col.switch_times, col.u_first, col.tf)) > 1e-4
    # (the collocation route: without the shipped singular table, test_singular_table.py)
    s = solve(SINGULAR, singular_table=False)
    assert s.success and s.method == "switch-time" and not s.exact
    assert "switch-time optimisation" in s.route and "not an extremal" in s.message
    # collocation's control shows the singular arc: the exact refinement is skipped
    assert singular_arc_evidence(SINGULAR, col) is not None
    assert "exact refinement skipped" in s.route and "a singular arc" in s.route
    assert "indirect refinement" not in s.route
    att, rate = _replay(SINGULAR, s.switch_times, s.u_first, s.tf)
    assert att < 1e-9 and rate < 1e-9
    # never slower than collocation's answer (beyond its tolerance), nor than the eigenaxis slew
    assert s.tf <= col.tf + col.tf_tol and s.tf < s.baseline_tf
    assert s.tf == pytest.approx(1.67520601, rel=1e-6) and s.tf < col.tf - 1e-4
    assert 0 < s.tf_tol < col.tf_tol
    # a bang-bang control, exact from its switch times; the KKT costates carried along the
    # arcs, in the scale H(0) = -1
    u = s.control(np.linspace(0.0, s.tf, 101))
    np.testing.assert_allclose(np.abs(u), 1.0)
    from solvers.plotting import hamiltonian_along
    H = hamiltonian_along(s)
    assert H[0] == pytest.approx(-1.0, abs=1e-9) and np.all(np.isfinite(s.costate))
    np.testing.assert_allclose(s.costate[0], s.costate0)
    d = s.to_dict()
    assert d["method"] == "switch-time" and d["exact"] is False
    json.dumps(d)
    assert s.verification["replay"]["passed"] and s.verification["boundary_attitude_error"]["value"] < 1e-9


def test_sequence_gets_pulse_pairs_until_the_unknowns_cover_the_boundary_conditions():
    t = np.linspace(0.0, 2.0, 21)
    u = np.ones((21, 3))
    u[8:12, 1] = 0.2          # axis y interior in the middle
    signs0, axes, times = sequence_from_samples(t, u, np.ones(3), [np.array([0.5]), np.array([1.5]), np.zeros(0)],
                                                [1, -1, 1])
    assert axes.size + 1 >= 7 and np.all(np.diff(times) >= 0)
    assert (axes == 1).sum() >= 3          # the interior axis got the first pulse pair
    np.testing.assert_array_equal(signs0, [1, -1, 1])


def test_switch_time_optimisation_rejects_what_it_does_not_cover():
    with pytest.raises(ValueError, match="sensor_target"):
        optimise_switch_times(SlewProblem([1, 1, 1], sensor_target=[0, 1, 0]), [1, 1, 1], [0], [0.5], 2.0)
    with pytest.raises(ValueError, match="axes"):
        optimise_switch_times(SINGULAR, [1, 1, 1], [3], [0.5], 2.0)
    with pytest.raises(ValueError, match="one axis per switch"):
        optimise_switch_times(SINGULAR, [1, 1, 1], [0, 1], [0.5], 2.0)
    with pytest.raises(ValueError, match="signs0"):
        optimise_switch_times(SINGULAR, [1, 0, 1], [0], [0.5], 2.0)
    with pytest.raises(ValueError, match="positive final time"):
        optimise_switch_times(SINGULAR, [1, 1, 1], [0], [0.5], -1.0)
    with pytest.raises(ValueError, match="cones"):
        optimise_switch_times(SINGULAR.replace(cones=[Cone([0, 0, 1], 0.2)]), [1, 1, 1], [0], [0.5], 2.0)
    with pytest.raises(ValueError, match="torque_norm"):
        optimise_switch_times(SlewProblem([1, 1, 1], qf=[0, 1, 0, 0], torque_norm=2), [1, 1, 1], [0], [0.5], 2.0)
    # no bang-bang answer for cone problems or failed collocation answers: the caller keeps its own
    col = solve_collocation(SINGULAR)
    assert bang_bang_answer(SINGULAR.replace(cones=[Cone([0, 0, 1], 0.2)]), col) == (None, None)
    col.success = False
    assert bang_bang_answer(SINGULAR, col) == (None, None)


# held-out problem 1: an asymmetric body whose optimum is bang-bang with a short pulse on axis x,
# where S_x crosses zero with |Ṡ| ~ 2e-4 (S_x stays below 0.025 while S_y, S_z reach 0.75)
PULSE = SlewProblem([0.9632585688613045, 0.5693585649475574, 0.9610770229779321],
                    q0=[-0.4685597527617647, 0.42800400729096455, 0.3680389176458581, 0.6795672762374415],
                    qf=[-0.32526004736647146, -0.5451881479544003, -0.05552228612397175, 0.7706445747948787])


def test_an_extremal_with_a_slow_switching_crossing_is_verified_as_exact():
    s = solve(PULSE)
    assert s.success and s.exact and s.method == "indirect"
    # the same time as the optimum of its switching sequence (switch-time optimisation)
    bvp = AttitudeBVP(PULSE)
    axes = np.array([a for a in range(3) for _ in s.switch_times[a]])
    r = optimise_switch_times(PULSE, s.u_first, axes, np.concatenate(s.switch_times) / bvp.tau, s.tf / bvp.tau)
    assert r.success and r.T * bvp.tau == pytest.approx(s.tf, rel=1e-9)
    att, rate = _replay(PULSE, s.switch_times, s.u_first, s.tf)
    assert att < 1e-9 and rate < 1e-9
    # the event-driven propagation of its costates puts the switches after the pulse ~2e-9 of tf
    # away from the solved ones (over the plain 1e-9): the check divides by the conditioning
    z, T = Guess(s.costate0, s.tf).to_nondim(bvp)
    bvp.set_mode("bang")
    tr = bvp.record(z, T, hmax=T / 100)
    solved = np.sort(np.concatenate(s.switch_times)) / bvp.tau
    raw = float(np.max(np.abs(tr.switch_t - solved))) / T
    assert raw > 1e-9
    assert s.verification["switch_structure"]["value"] <= 1e-9 < raw


def test_forward_jacobian_matches_finite_differences_also_for_clipped_instants():
    from solvers.switch_time import propagate_sequence as _forward
    from solvers.attitude_bvp import NY
    bvp = AttitudeBVP(SINGULAR)
    bvp.set_mode("bang")
    y0 = np.zeros(NY)
    y0[0:4], y0[4:7] = bvp.q0, bvp.w0
    axes = np.array([0, 1, 2, 0, 1, 2])
    times = np.array([0.3, 0.7, 0.9, 1.2, -0.2, 2.4])      # one before 0, one after T
    signs0, T = np.array([1.0, -1.0, 1.0]), 1.9
    _, r, Jr, *_ = _forward(bvp, times, axes, signs0, T, y0, True)
    v = np.concatenate([times, [T]])
    for j in range(v.size):
        h = 1e-6
        vp, vm = v.copy(), v.copy()
        vp[j] += h
        vm[j] -= h
        fd = (_forward(bvp, vp[:-1], axes, signs0, vp[-1], y0, False)[1]
              - _forward(bvp, vm[:-1], axes, signs0, vm[-1], y0, False)[1]) / (2 * h)
        np.testing.assert_allclose(Jr[:, j], fd, atol=1e-7)
    assert np.all(Jr[:, 4] == 0.0) and np.all(Jr[:, 5] == 0.0)       # the clipped instants


def test_switch_check_keeps_the_plain_tolerance_before_a_slow_crossing():
    from solvers.switch_time import Structure
    from solvers.verify import switch_deviation
    s = solve(PULSE)
    bvp = AttitudeBVP(PULSE)
    z, T = Guess(s.costate0, s.tf).to_nondim(bvp)
    bvp.set_mode("bang")
    tr = bvp.record(z, T, hmax=T / 100)
    times = np.sort(np.concatenate(s.switch_times)) / bvp.tau
    axes = np.array([a for t, a in sorted((t, a) for a in range(3) for t in s.switch_times[a])])
    st = Structure(np.asarray(s.u_first, float), axes, times)
    assert switch_deviation(bvp, tr, st, T) <= 1e-9
    # the first switch is well conditioned (|S'| ~ 0.02): a shift of 1e-8·T there must fail
    moved = times.copy()
    moved[0] += 1e-8 * T
    assert switch_deviation(bvp, tr, Structure(st.signs0, axes, moved), T) > 1e-9


def test_dense_record_takes_simultaneous_switches_of_two_axes():
    # two axes switching at one instant, 1e-16 apart by rounding, leave an arc of no length
    from solvers.switch_time_opt import _dense_record
    bvp = AttitudeBVP(SINGULAR)
    bvp.set_mode("bang")
    t_mid = 0.9
    rec = _dense_record(bvp, [np.array([0.4]), np.array([t_mid]), np.array([t_mid + 1e-16])],
                        np.array([1.0, 1.0, 1.0]), 1.8, np.full(6, np.nan))
    assert rec is not None
    t, Y = rec
    assert t[0] == 0.0 and t[-1] == pytest.approx(1.8) and np.all(np.diff(t) >= 0)
    # rest to rest under u = +1 then -1 on y, z: ω_y back to 0 at 1.8
    assert Y[-1, 5] == pytest.approx(0.0, abs=1e-12)


def test_interior_run_finds_the_longest_stretch_of_interior_torque():
    t = np.linspace(0.0, 1.0, 11)
    u = np.ones((11, 3))
    u[2:4, 0] = 0.5            # 2 samples, from t = 0.2 to the next bang sample at 0.4
    u[5:9, 1] = -0.1           # 4 samples, 0.5 to 0.9
    u[10, 2] = 0.0             # the last sample alone: no length
    a, start, length, n = interior_run(t, u, [1.0, 1.0, 1.0])
    assert (a, n) == (1, 4) and start == pytest.approx(0.5) and length == pytest.approx(0.4)
    assert interior_run(t, np.ones((11, 3)), [1.0, 1.0, 1.0])[0] == -1
    # the bound is per axis
    assert interior_run(t, u, [1.0, 0.05, 1.0])[0] == 0


def test_a_bang_bang_optimum_shows_no_singular_arc_in_collocation():
    p = SlewProblem.from_dict(json.load(open(os.path.join(EXAMPLES, "r3_seed_report_per_axis.json"))))
    col = solve_collocation(p)
    assert col.success and singular_arc_evidence(p, col) is None
    col_s = solve_collocation(SINGULAR)
    text = singular_arc_evidence(SINGULAR, col_s)
    assert text is not None and "interior over" in text


def test_interior_torque_while_the_rate_rides_its_limit_is_called_a_rate_limited_coast():
    """A rate-limited slew's coast has interior torque too; it is named for what it is (a user
    review had read "a singular arc" on the A1 example, whose rate rides its 1°/s limit)."""
    from types import SimpleNamespace
    t = np.linspace(0.0, 10.0, 101)
    u = np.ones((101, 3))
    u[20:80, 2] = 0.01                              # interior from t = 2 to 8
    w = np.zeros((101, 3))
    w[20:80, 2] = 0.5                               # ... with the z rate at its limit
    col = SimpleNamespace(success=True, t=t, u=u, omega=w, tf=10.0)
    limited = SlewProblem([1.0, 1.0, 1.0], torque_max=1.0, qf=[0.0, 0.0, 0.0, 1.0], rate_max=0.5)
    text = singular_arc_evidence(limited, col)
    assert "rate-limited coast" in text and "singular" not in text
    # the same control with the rate off its limit (or no limit at all) is a singular arc
    assert "a singular arc" in singular_arc_evidence(limited.replace(rate_max=1.0), col)
    assert "a singular arc" in singular_arc_evidence(limited.replace(rate_max=None), col)


# the session-31 replay audit's full-attitude problem 106 (runs/s31/replay): a 26° slew whose
# collocation torque is interior on 5 % of x's samples and 2.5 % of z's
AUDIT_106 = {"inertia": [0.530098590725567, 0.8218393595384945, 0.4410482181225713],
             "torque_max": [1.4363117930830123, 1.4941903972365447, 0.9183002429882449],
             "q0": [-0.7819504544458918, 0.6060131761949711, 0.11204884052661164, -0.09352312230987722],
             "qf": [-0.8398560955425425, 0.4615985212317799, 0.2750661242122228, -0.07685812440813151]}


def test_pulses_on_every_interior_axis_when_the_singular_ones_are_not_enough():
    """With pulse pairs only on the axis interior on over 10 % of the samples, no round of the
    switch-time optimisation was feasible and ``auto`` returned collocation's answer, whose
    switch times miss the target when flown; the fallback round puts pulses on z too."""
    p = SlewProblem.from_dict(AUDIT_106)
    col = solve(p, method="collocation")
    bvp = AttitudeBVP(p)
    args = (np.asarray(col.t) / bvp.tau, col.u, p.torque_max, [np.asarray(s) / bvp.tau for s in col.switch_times],
            col.u_first)
    _, axes, _ = sequence_from_samples(*args, extra_pairs=4)
    _, axes_all, _ = sequence_from_samples(*args, extra_pairs=4, singular_share=0.0)
    assert np.bincount(axes, minlength=3)[2] == 1 < np.bincount(axes_all, minlength=3)[2]    # z's pulses
    bang, _ = bang_bang_answer(p, col, time_budget=2.0)
    assert bang is not None and bang.success, "no switch-time answer"
    assert bang.tf < col.tf
    sol = solve(p, warm_start=None)
    assert sol.success and sol.method in ("indirect", "switch-time"), sol.route
    assert sol.tf == pytest.approx(0.7307206172, rel=1e-8)


def test_the_fallback_round_does_not_repeat_a_sequence_already_tried(monkeypatch):
    """Where the torque is interior on one axis only, pulses 'on every interior axis' are the
    4-pair round's pulses: the fallback round is not run again on them."""
    from types import SimpleNamespace
    from solvers import switch_time_opt as sto
    t = np.linspace(0.0, 2.0, 41)
    u = np.ones((41, 3))
    u[10:30, 0] = 0.1                     # axis x interior on half the samples, the others saturated
    col = SimpleNamespace(t=t, u=u, tf=2.0, tf_tol=1e-3, u_first=[1, 1, 1], switch_times=[np.array([1.0])] * 3)
    p = SlewProblem([1.0, 1.0, 1.0], qf=[math.cos(0.3), math.sin(0.3), 0.0, 0.0])
    tried = []

    def optimise(problem, signs0, axes, times, T, **kw):
        tried.append((axes.tobytes(), times.tobytes()))
        return SimpleNamespace(success=False)
    out = sto.answer_from_collocation(p, col, AttitudeBVP(p), optimise, 5.0, None, 10, __import__("time").perf_counter())
    assert out == (None, None)
    assert len(tried) == len(set(tried)) == len(sto.PULSE_ROUNDS)


def test_switches_at_the_ends_are_dropped_and_a_first_one_flips_its_axis():
    from solvers.switch_time_opt import _without_end_switches
    sw, signs = _without_end_switches([np.array([1e-19, 0.4]), np.array([0.5, 2.0 - 1e-15]), np.array([0.0, 3e-13, 1.0])],
                                      np.array([1.0, -1.0, 1.0]), 2.0)
    assert [list(s) for s in sw] == [[0.4], [0.5], [1.0]]
    assert list(signs) == [-1.0, -1.0, 1.0]       # z: two switches at the start, flipped twice


def test_a_zero_length_first_arc_does_not_keep_the_exact_extremal_away():
    """The same slew in units where collocation's sequence came out with a switch at 1.1e-19 tf on
    one axis: the exact solver, given that switch, had failed ("line search failed"), and the answer
    was a switch-time slew; in kg m² and N m (tau = 300.7 s) it was the exact extremal (an outside
    check of units, session 43)."""
    P = SlewProblem(inertia=[0.01, 0.009808055744539709, 0.00892799124180289], torque_max=1.0,
                    qf=[0.739740556742725, 0.30169689433591673, 0.3621766905574723, -0.48019885201327045],
                    omega0=[-1.1096731029898133, -2.092965270570267, -1.1862955502361963])
    sol = solve(P)
    assert sol.success and sol.exact and sol.method == "indirect", sol.route
    assert sol.tf / P.time_unit == pytest.approx(1.939848151231, rel=1e-10)
    assert sorted(len(s) for s in sol.switch_times) == [1, 2, 2]
