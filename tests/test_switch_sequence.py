"""The compiled switching-sequence flow of switch-time shooting against the arc-by-arc Python
loop it replaced (transition matrix per arc, then Φ @ G), and its Jacobian against finite
differences."""
import numpy as np
import pytest

from slew_env import SlewProblem
from slew_env.core import qfrom_uniform
from solvers import Guess, solve, multistart
from solvers.attitude_bvp import NY, AttitudeBVP
from solvers.core.attitude_flow import ext_rhs
from solvers.switch_time import Structure, _residual, solve_switch_times

from python_sequence_flows import switch_residual as _python_residual


def _cases(n_cases=12, seed=3):
    rng = np.random.default_rng(seed)
    for k in range(n_cases):
        J = rng.uniform(0.3, 1.0, 3) * (10.0 if k % 3 == 0 else 1.0)
        p = SlewProblem(J, torque_max=rng.uniform(0.2, 2.0, 3), q0=qfrom_uniform(*rng.random(3)),
                        qf=qfrom_uniform(*rng.random(3)))
        if k % 4 == 1:
            p = p.replace(qf=None, sensor_axis=[0.0, 0.0, 1.0], sensor_target=rng.normal(size=3))
        bvp = AttitudeBVP(p)
        bvp.set_mode("bang")
        n = int(rng.integers(0, 9))
        T = float(rng.uniform(1.0, 4.0))
        times = rng.uniform(0.0, 1.1 * T, n)          # some beyond T, any order
        if n >= 2:
            times[1] = times[0]                       # a tie keeps the callers' order
        z = rng.normal(size=6)
        z /= np.linalg.norm(z) * rng.uniform(0.9, 1.1)
        st = Structure(rng.choice([-1.0, 1.0], 3), rng.integers(0, 3, n), times)
        yield bvp, z, times, T, st


@pytest.mark.parametrize("want_jac", [True, False])
def test_the_compiled_sequence_flow_matches_the_python_loop(want_jac):
    for bvp, z, times, T, st in _cases():
        r, Jm = _residual(bvp, z, times, T, st, want_jac)
        r0, J0 = _python_residual(bvp, z, times, T, st, want_jac)
        assert np.allclose(r, r0, rtol=1e-12, atol=1e-13)
        if want_jac:
            assert np.allclose(Jm, J0, rtol=1e-11, atol=1e-12)
        else:
            assert Jm is None


def test_its_jacobian_is_the_derivative_of_its_residual():
    for bvp, z, times, T, st in list(_cases(6, seed=11)):
        keep = times < 0.95 * T
        times, st = times[keep], Structure(st.signs0, st.axes[keep], times[keep])
        if st.n >= 2 and abs(times[1] - times[0]) < 1e-9:
            times[1] += 1e-3            # central differences need distinct instants
        bvp.rtol = bvp.atol = 1e-13
        x = np.concatenate([z, times, [T]])
        n = st.n
        r, Jm = _residual(bvp, z, times, T, st, True)
        h = 1e-6
        for c in range(x.size):
            xp, xm = x.copy(), x.copy()
            xp[c] += h
            xm[c] -= h
            rp, _ = _residual(bvp, xp[:6], xp[6:6 + n], xp[-1], st, False)
            rm, _ = _residual(bvp, xm[:6], xm[6:6 + n], xm[-1], st, False)
            assert np.allclose((rp - rm) / (2 * h), Jm[:, c], rtol=1e-5, atol=1e-6), c


def test_bad_times_fail_cleanly_and_newton_still_converges():
    bvp, z, times, T, st = next(_cases())
    t_bad = times.copy()
    if t_bad.size:
        t_bad[0] = np.nan
        assert _residual(bvp, z, t_bad, T, st, True) == (None, None)
    assert _residual(bvp, z, times, float("nan"), st, True) == (None, None)
    # from a perturbed extremal, Newton on the sequence returns to it
    p = SlewProblem([0.6, 0.8, 1.0], q0=qfrom_uniform(0.1, 0.2, 0.3), qf=qfrom_uniform(0.7, 0.4, 0.9))
    sol = solve(p, method="indirect", warm_start=None)
    assert sol.success and sol.exact
    bvp = AttitudeBVP(p)
    bvp.set_mode("bang")
    z, T = Guess(sol.costate0, sol.tf).to_nondim(bvp)
    axes = np.concatenate([np.full(len(s_), a) for a, s_ in enumerate(sol.switch_times)]).astype(np.int64)
    times = np.concatenate(sol.switch_times) / bvp.tau
    o = np.argsort(times)
    rng = np.random.default_rng(0)
    res = solve_switch_times(bvp, z + 1e-3 * rng.normal(size=6),
                             Structure(np.asarray(sol.u_first, float), axes[o], times[o] * (1 + 1e-3)), T * 1.002)
    assert res.success and res.residual_norm < 1e-12
    assert res.T * bvp.tau == pytest.approx(sol.tf, rel=1e-10)


def _python_propagate_sequence(bvp, times, axes, signs0, T, y0, want_jac):
    """``solvers.switch_time.propagate_sequence`` as it ran before it was compiled (reference)."""
    E7 = np.ascontiguousarray(np.eye(NY)[:, :7])
    n = times.shape[0]
    order = np.argsort(times, kind="stable")
    signs = np.array(signs0, float)
    y = y0.copy()
    t = 0.0
    mats = []           # transition matrix of each arc (arc k ends at event k; the last at T)
    jumps = []          # f⁻ - f⁺ at each event, in time order
    nfev = 0
    # the events in time order, then the end of the last arc (axis -1). An instant at or after T
    # is beyond the horizon (no flip); one before 0 flips at 0. Either way it does not move the
    # end state to first order: its column of the Jacobian is zero.
    for k in list(order) + [-1]:
        raw = T if k < 0 else float(times[k])
        tk = min(max(raw, 0.0), T)
        if tk > t:
            y, Phi, ok = bvp.arc(y, tk - t, signs, E7 if want_jac else None)
            nfev += 1
            if not ok:
                return None
            if want_jac:
                mats.append(Phi[:7, :7].copy())
            t = tk
        elif want_jac:
            mats.append(np.eye(7))
        if k < 0:
            break
        a = int(axes[k])
        if raw >= T:
            if want_jac:
                jumps.append(np.zeros(7))
            continue
        if want_jac:
            # f⁻ - f⁺ differs only in ω̇_a (as in ``switch_event``)
            jump = np.zeros(7)
            if raw > 0.0:
                jump[4 + a] = 2.0 * signs[a] * bvp.umax[a] / bvp.J[a]
            jumps.append(jump)
        signs[a] = -signs[a]
    r, D, _ = bvp.terminal(y, T)
    if not want_jac:
        return y, r, nfev
    D7 = D[:, :7]
    dx = np.empty((7, n + 1))
    G = np.eye(7)
    # Φ(T, t_k) = M_last … M_{k+1}: accumulated backwards
    for j in range(n - 1, -1, -1):
        G = G @ mats[j + 1]
        dx[:, order[j]] = G @ jumps[j]
    dx[:, n] = ext_rhs(y, bvp.umax * signs, bvp.J)[:7]
    M_total = G @ mats[0]
    return y, r, D7 @ dx, D7, M_total, nfev


def test_the_compiled_sequence_end_matches_the_python_loop():
    from solvers.switch_time import propagate_sequence
    from solvers.switch_time_opt import _start_state
    for k, (bvp, z, times, T, st) in enumerate(_cases(16, seed=21)):
        times = times.copy()
        if k % 4 == 3 and times.size:
            times[-1] = -0.1                      # before 0: flips at 0
        if k % 4 == 1 and times.size >= 2:
            times[0], times[-1] = 0.0, T          # exactly at 0 (no jump) and at T (no flip)
        y0 = _start_state(bvp) if k % 2 else bvp.initial(z)[0]
        for want_jac in (True, False):
            new = propagate_sequence(bvp, times, st.axes, st.signs0, T, y0, want_jac)
            old = _python_propagate_sequence(bvp, times, st.axes, st.signs0, T, y0, want_jac)
            assert new[-1] == old[-1]                                       # arcs integrated
            for a, b in zip(new[:-1], old[:-1]):
                assert np.allclose(a, b, rtol=1e-12, atol=1e-13)
    bvp, z, times, T, st = next(_cases())
    assert propagate_sequence(bvp, times, st.axes, st.signs0, float("nan"), bvp.initial(z)[0], True) is None


def test_a_stalled_template_stops_early_and_a_converging_one_does_not():
    """``stall=(10, 0.1)`` (``multistart.TEMPLATE_STALL``): a structure template whose residual is still
    above 0.1 of its first after 10 iterations stops there, as failed, instead of running to the
    line search's failure or 30 iterations; the templates that converge converge as before."""
    import json
    from pathlib import Path
    from solvers.multistart import TEMPLATE_STALL
    from solvers.guesses import eigenaxis_guess, structure_templates
    r3 = Path(__file__).resolve().parent.parent / "examples" / "r3_seed_report_per_axis.json"
    p = SlewProblem.from_dict(json.loads(r3.read_text())).replace(inertia=[0.5, 0.8, 1.0])
    bvp = AttitudeBVP(p)
    bvp.set_mode("bang")
    z0, T0 = eigenaxis_guess(bvp).to_nondim(bvp)
    stalled = converged = 0
    for zt, Tt, (s0, ax, tt), _ in structure_templates(bvp, z0, T0, np.random.default_rng(0)):
        st = Structure(s0, ax, tt)
        a = solve_switch_times(bvp, zt, st, Tt, stall=TEMPLATE_STALL)
        b = solve_switch_times(bvp, zt, st, Tt)
        if b.success:
            converged += 1
            assert a.success and a.nit == b.nit and a.T == b.T
        elif a.message.startswith("stalled"):
            stalled += 1
            assert a.nit == 10 < b.nit and not a.success
            assert a.history[10] > 0.1 * a.history[0]
    assert converged >= 3 and stalled >= 6


def test_the_classical_route_gives_the_stall_rule_to_templates_only(monkeypatch):
    import math
    seen = []
    real = multistart.solve_structure

    def spy(*a, **k):
        seen.append((k.get("route", ""), k.get("stall")))
        return real(*a, **k)
    monkeypatch.setattr(multistart, "solve_structure", spy)
    p = SlewProblem([0.5, 0.8, 1.0], q0=[1, 0, 0, 0], qf=[math.cos(0.8), 0.0, math.sin(0.8), 0.0])
    solve(p, method="indirect", warm_start=None, time_budget=5.0)
    solve(p, method="indirect", time_budget=5.0)          # the learned guess's structures
    templates = [s for r, s in seen if "template" in r]
    others = [s for r, s in seen if "template" not in r]
    assert templates and all(s == multistart.TEMPLATE_STALL for s in templates)
    assert others and all(s is None for s in others)
