"""Cone problems that an independent replay audit found mishandled, now regression tests."""
import numpy as np

from slew_env.core.dynamics import propagate
from solvers import solve
from solvers.clearance import margins


def _fly(sol, n=40000):
    """The returned torque history at the midpoint of each of n steps, environment RK4, with
    the answer's switch instants as step boundaries too (a step across a switch would hold one
    torque through it: for a bang-bang answer with 13 switches that alone put the flown path
    1.3e-5 rad into the cone at n = 40,000, 3e-6 at 160,000)."""
    p = sol.problem
    ts = np.unique(np.concatenate([np.linspace(0.0, sol.tf, n + 1)]
                                  + [np.asarray(s, float) for s in sol.switch_times]))
    ts = ts[ts <= sol.tf]
    x = np.concatenate([p.q0, p.omega0])
    xs = [x]
    for k in range(len(ts) - 1):
        x = propagate(x, sol.control(0.5 * (ts[k] + ts[k + 1])), p.inertia, ts[k + 1] - ts[k], 1)[-1]
        xs.append(x)
    return np.array(xs)


def test_collocation_clearance_is_certified_between_its_samples():
    """The collocation path sagged 1.2e-6 rad into the cone between two of its 24 replay
    samples per interval while reporting -2e-8; the check is now a certified bound."""
    p = {"inertia": [1, 1, 1], "torque_max": 1,
         "sensor_target": [-0.7478787254405308, -0.6531276726547737, -0.11875039050885645],
         "cones": [{"axis": [0.35444717450382496, -0.9286273263363297, -0.10962887059390358],
                    "half_angle": 0.5235987755982988}]}
    sol = solve(p)
    assert sol.success
    assert sol.verification["cone_clearance"]["value"] >= -1e-6
    xs = _fly(sol)
    assert margins(sol.problem, xs[:, 0:4]).min() >= -1e-6


FAR_CONE = {"inertia": [1, 1, 1], "torque_max": 1,
            "sensor_target": [-0.38054398367207576, 0.5740649984012693, -0.725007347619],
            "cones": [{"axis": [-0.5565321268030824, -0.5157518953118683, 0.6513616309840898],
                       "half_angle": 0.3490658503988659}]}


def test_a_far_cone_that_upsets_collocation_does_not_fail_auto():
    """Collocation with the cone stops at IPOPT's 'acceptable level' (a singular problem:
    J = I); that answer is verified by its replay and returned, 1.8 rad clear of the cone."""
    sol = solve(FAR_CONE)
    assert sol.success, sol.message
    assert sol.verification["cone_clearance"]["value"] > 1.0
    assert len(sol.problem.cones) == 1        # reported against the problem as posed
    xs = _fly(sol, 20000)
    assert margins(sol.problem, xs[:, 0:4]).min() > 1.0


def test_when_collocation_fails_with_a_far_cone_auto_answers_without_it(monkeypatch):
    """If collocation with the cones fails, the problem without them is solved and its path
    certified clear of them."""
    from solvers import collocation
    real = collocation.solve_collocation

    def failing_with_cones(prob, **kw):
        sol = real(prob, **kw)
        if getattr(prob, "cones", None):
            sol.success, sol.status, sol.message = False, 1, "forced failure (test)"
        return sol
    monkeypatch.setattr(collocation, "solve_collocation", failing_with_cones)
    sol = solve(FAR_CONE)
    assert sol.success, sol.message
    assert "without cones" in sol.route
    assert sol.verification["cone_clearance"]["value"] > 1.0
    assert len(sol.problem.cones) == 1
    xs = _fly(sol, 20000)
    assert margins(sol.problem, xs[:, 0:4]).min() > 1.0
