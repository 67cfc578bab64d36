"""A limit on the norm of the body rate (``rate_norm_max``): what star-tracker and gyro rate
limits usually are. The per-axis box of ``rate_max`` lets the norm reach √3 times its value; a
GNC review had to divide its limit by √3 (27 % slower on the case below)."""
import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import slew_env  # noqa: F401  (registers Slew-v0)
import solvers
from slew_env import SlewProblem

# a GNC review's case A1: J = diag(40, 55, 70) kg m², 0.1 N m a wheel, 90° about z
A1 = SlewProblem([40.0, 55.0, 70.0], torque_max=0.1, qf=[math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)])
R = math.radians(1.0)


def test_the_field_in_rad_or_degrees_round_trips_and_is_checked():
    p = A1.replace(rate_norm_max_deg=1.0)
    assert p.rate_norm_max == pytest.approx(R, rel=1e-15) and p.has_rate_limit and p.rate_max is None
    assert p.to_dict()["rate_norm_max"] == p.rate_norm_max
    assert SlewProblem.from_dict(p.to_dict()) == p and SlewProblem.from_json(p.to_json()) == p
    assert A1.to_dict()["rate_norm_max"] is None and not A1.has_rate_limit
    assert p.rate_limit_ratio([[R, 0, 0], [0.6 * R, 0.8 * R, 0]]) == pytest.approx(1.0, rel=1e-15)
    assert p.replace(rate_max=2 * R).rate_limit_ratio([[R, R, 0]]) == pytest.approx(math.sqrt(2), rel=1e-15)
    for bad, needle in ((dict(rate_norm_max=-1.0), "rate_norm_max: expected one finite positive number"),
                        (dict(rate_norm_max=[1.0, 1.0, 1.0]), "rate_norm_max: expected one positive number"),
                        (dict(rate_norm_max="0.1"), "rate_norm_max: expected one positive number, got text"),
                        (dict(rate_norm_max=math.inf), "rate_norm_max: expected one finite positive number"),
                        (dict(rate_norm_max_deg=True), "rate_norm_max_deg: expected one positive number"),
                        (dict(rate_norm_max=0.1, rate_norm_max_deg=5.0), "rate_norm_max, rate_norm_max_deg: give"),
                        (dict(rate_norm_max=0.1, omega0=[0.08, 0.08, 0.0]), "omega0: its norm 0.113137 exceeds")):
        with pytest.raises(ValueError, match=needle):
            A1.replace(**bad)


def test_the_environment_refuses_it_by_name():
    env = gym.make(slew_env.ENV_ID)
    with pytest.raises(ValueError, match="^rate_norm_max: the environment and its task arrays hold per-axis"):
        env.reset(options={"problem": A1.replace(rate_norm_max=0.1)})


def test_the_eigenaxis_slew_coasts_at_the_norm_limit():
    # about z the rate is along z: the closed form θ/r + r/α (α = u/J_z), with the norm or the box
    alpha = 0.1 / 70.0
    closed = (math.pi / 2) / R + R / alpha
    for kw in (dict(rate_norm_max=R), dict(rate_max=R)):
        sol = solvers.solve(A1.replace(**kw), method="eigenaxis")
        assert sol.success and sol.tf == pytest.approx(closed, rel=1e-9)
    # about (1, 1, 1)/√3 the box lets the norm reach √3 r; the norm limit holds it at r
    p = SlewProblem([1.0, 1.0, 1.0], qf=[math.cos(1.0), *(math.sin(1.0) / math.sqrt(3) * np.ones(3))])
    box = solvers.solve(p.replace(rate_max=0.5), method="eigenaxis")
    norm = solvers.solve(p.replace(rate_norm_max=0.5), method="eigenaxis")
    assert np.max(np.linalg.norm(box.omega, axis=1)) == pytest.approx(0.5 * math.sqrt(3), rel=1e-9)
    assert np.max(np.linalg.norm(norm.omega, axis=1)) == pytest.approx(0.5, rel=1e-9)
    # θ = 2 rad; the box torque bound gives α = √3 along n (each axis at its bound)
    assert norm.tf == pytest.approx(2.0 / 0.5 + 0.5 / math.sqrt(3), rel=1e-9)
    assert norm.verification["rate_limit"]["passed"]


def test_auto_keeps_the_norm_and_beats_the_box_workaround():
    example = Path(__file__).resolve().parent.parent / "examples" / "a1_rate_norm_1deg.json"
    p = SlewProblem.from_dict(json.loads(example.read_text()))
    assert p == A1.replace(rate_norm_max_deg=1.0)
    sol = solvers.solve(p)
    assert sol.success and sol.verification["rate_limit"]["passed"]
    assert sol.verification["rate_limit"]["value"] <= 1.0 + 1e-9
    assert float(np.max(np.linalg.norm(sol.omega, axis=1))) <= R * (1.0 + 1e-6)
    # a rotation by 90° at a rate of norm ≤ r takes at least θ / r = 90 s; the eigenaxis slew
    # (bang-coast-bang at r) 102.2173 s is feasible
    assert 90.0 < sol.tf <= 102.2174
    assert sol.tf == pytest.approx(102.005, abs=2e-3)          # examples/README.md (collocation)
    # the route names the rate-limited coast and keeps the last stage's reason whole (it had been
    # cut after 300 characters, mid-word); its middle may be elided
    assert "rate-limited coast" in sol.route and sol.route.endswith("(tolerance 1))")
    # the conservative box r/√3 per axis (what a user had to give) is much slower
    box = solvers.solve(A1.replace(rate_max=R / math.sqrt(3)))
    assert box.success and sol.tf < 0.8 * box.tf


def test_an_inactive_norm_limit_leaves_the_exact_answer():
    free = solvers.solve(A1)
    assert free.success and free.exact
    peak = float(np.max(np.linalg.norm(free.omega, axis=1)))
    sol = solvers.solve(A1.replace(rate_norm_max=1.01 * peak))
    assert sol.success and sol.exact and sol.tf == pytest.approx(free.tf, rel=1e-9)
    assert sol.verification["rate_limit"]["value"] == pytest.approx(1 / 1.01, rel=1e-6)
    # the same extremal with the limit below its peak: the indirect route's check refuses it
    low = solvers.solve(A1.replace(rate_norm_max=0.9 * peak), method="indirect", warm_start=None)
    assert not low.success and "rate_limit" in low.message


def test_learned_warm_starts_do_not_cover_it():
    from solvers import warmstart
    model = warmstart.default_warm_start()
    p = SlewProblem([0.5, 0.8, 1.0], qf=[0.9, 0.3, 0.2, 0.2449489742783178], rate_norm_max=2.0)
    assert model.covers(p.replace(rate_norm_max=None)) is None
    assert "rate_norm_max" in model.covers(p)


def test_a_nan_rate_fails_the_rate_check():
    # max(0.0, nan) is 0.0: one NaN had made the ratio 0, a pass, and hidden real excesses beside it
    from solvers.collocation_nlp import Scaled
    for p in (A1.replace(rate_norm_max=R), A1.replace(rate_max=R), A1.replace(rate_max=R, rate_norm_max=R)):
        assert p.rate_limit_ratio([[math.nan, 0.0, 0.0], [2 * R, 0.0, 0.0]]) == math.inf
        assert Scaled.of(p).rate_ratio([[0.0, math.nan, 0.0]]) == math.inf
