"""A solution record says how its control is defined (``control_law``), and carries what that
law needs even without the dense samples: an outside check flies the record alone (a session-32
replay audit of the CLI's JSON could not fly collocation answers from a default batch record,
and the eigenaxis answer's 401 samples, flown linearly, missed the target by up to 1.4e-2)."""
import json
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import solvers
from slew_env import SlewProblem
from slew_env.core.dynamics import state_rhs
from slew_env.core.quaternion import qconj, qmul
from solvers.solution import CONTROL_LAWS, SAMPLE_LAWS, control_law

ASYM = SlewProblem([0.3, 0.6, 1.0], torque_max=1.0,
                   qf=[0.6427876096865394, -0.17156463728611898, 0.7351811813937538, 0.1299934405684849])


def _fly_samples(rec, law):
    """Fly a JSON record's samples ``t, u`` under ``law``, interval by interval (DOP853, tight);
    the end attitude error (rad) and rate error."""
    prob = SlewProblem.from_dict(rec["problem"])
    t, u = np.array(rec["t"], float), np.array(rec["u"], float)
    if law == "linear-samples":
        pieces = [(a, b, (lambda tt, a=a, b=b, k=k: u[k] + (tt - a) / (b - a) * (u[k + 1] - u[k])))
                  for k, (a, b) in enumerate(zip(t[:-1], t[1:])) if b > a]
    else:
        assert t.size % 2 == 1

        def quad(k):
            t0, t2 = t[2 * k], t[2 * k + 2]

            def f(tt):
                s = (tt - t0) / (t2 - t0)
                return (2 * (s - 0.5) * (s - 1) * u[2 * k] - 4 * s * (s - 1) * u[2 * k + 1]
                        + 2 * s * (s - 0.5) * u[2 * k + 2])
            return t0, t2, f
        pieces = [quad(k) for k in range(t.size // 2)]
    x = np.concatenate([prob.q0, prob.omega0])
    for a, b, f in pieces:
        x = solve_ivp(lambda tt, y: state_rhs(y, f(tt), prob.inertia), (a, b), x,
                      method="DOP853", rtol=1e-12, atol=1e-13).y[:, -1]
    q = x[:4] / np.linalg.norm(x[:4])
    e = qmul(qconj(prob.qf), q)
    return 2.0 * math.atan2(np.linalg.norm(e[1:]), abs(e[0])), float(np.linalg.norm(x[4:] - prob.omegaf))


def test_the_law_of_each_kind_of_answer():
    assert control_law("collocation", {}, math.inf) == "quadratic-samples"
    assert control_law("eigenaxis", {}, 2.0) == "linear-samples"
    assert control_law("indirect", {"regularisation": {}}, math.inf) == "linear-samples"
    assert control_law("indirect", {}, math.inf) == "bang-bang"
    assert control_law("switch-time", {}, math.inf) == "bang-bang"
    assert control_law("multiple-shooting", {}, 2.0) == "costate"
    assert set(SAMPLE_LAWS) < set(CONTROL_LAWS)
    exact = solvers.solve(ASYM, method="indirect")
    rec = json.loads(exact.to_json(dense=False))
    # the switch times are the control: no samples in a record without them
    assert rec["control_law"] == "bang-bang" and "t" not in rec and "u" not in rec
    assert solvers.SlewSolution(False, 1, "no", 0, 0, 0.0).control_law == ""


def test_a_collocation_record_without_dense_samples_flies_from_its_samples():
    sol = solvers.solve(ASYM, method="collocation")
    assert sol.success and sol.control_law == "quadratic-samples"
    rec = json.loads(sol.to_json(dense=False))
    assert rec["control_law"] == "quadratic-samples" and "q" not in rec and "costate" not in rec
    att, rate = _fly_samples(rec, rec["control_law"])
    assert att < 1e-4 and rate < 1e-4
    # flown linearly instead, the same samples miss (the audit's reading)
    assert max(_fly_samples(rec, "linear-samples")) > 1e-4


@pytest.mark.parametrize("J, rate_max, tol", [([1.0, 1.0, 1.0], None, 1e-9), ([0.3, 0.6, 1.0], None, 1e-4),
                                              ([0.3, 0.6, 1.0], 0.5, 1e-4)], ids=["symmetric", "asymmetric", "rate"])
def test_the_eigenaxis_answers_samples_fly_it(J, rate_max, tol):
    """Its samples are the exact profile at 2,001 instants, and twice at each breakpoint of the
    acceleration (before, then after): flown linearly, exact for a symmetric body (the torque is
    constant between breakpoints) and within 1e-4 rad with the gyroscopic term."""
    prob = ASYM.replace(inertia=J, rate_max=rate_max)
    sol = solvers.solve(prob, method="eigenaxis")
    rec = json.loads(sol.to_json(dense=False))
    assert rec["control_law"] == "linear-samples"
    t = np.array(rec["t"])
    assert np.all(np.diff(t) >= 0) and np.sum(np.diff(t) == 0) >= 1      # the switch to braking, twice
    att, rate = _fly_samples(rec, "linear-samples")
    assert att < tol and rate < tol
