"""The shooting engine knows nothing about attitudes: a toy BVP it must solve too."""
import math
from dataclasses import dataclass

import numpy as np
import pytest

from solvers.shooting import newton_shoot


@dataclass
class _Flow:
    y: np.ndarray
    Phi: object
    f: np.ndarray
    ok: bool = True
    message: str = ""


class Oscillator:
    """x'' = -x from x(0)=0, x'(0)=p; reach x(T)=a, x'(T)=0. Answer: p=a, T=π/2."""
    n_y = 2
    n_p = 1

    def __init__(self, a):
        self.a = a

    def initial(self, p):
        return np.array([0.0, p[0]]), np.array([[0.0], [1.0]])

    def param_residual(self, p):
        return np.zeros(0), np.zeros((0, 1))

    def flow(self, y0, T, Phi0):
        c, s = math.cos(T), math.sin(T)
        M = np.array([[c, s], [-s, c]])
        y = M @ y0
        return _Flow(y, None if Phi0 is None else M @ Phi0, np.array([y[1], -y[0]]))

    def terminal(self, y, T):
        return np.array([y[0] - self.a, y[1]]), np.eye(2), np.zeros(2)


@pytest.mark.parametrize("segments", [1, 2, 5])
def test_oscillator_bvp(segments):
    r = newton_shoot(Oscillator(2.0), [1.5], 1.2, segments=segments, tol=1e-13)
    assert r.success, r.message
    assert r.p[0] == pytest.approx(2.0, abs=1e-12)
    assert r.T == pytest.approx(math.pi / 2, abs=1e-12)
    assert len(r.nodes) == segments - 1
    assert r.nit <= 10


def test_nonpositive_duration_is_a_clean_failure():
    r = newton_shoot(Oscillator(1.0), [1.0], -1.0)
    assert not r.success
    assert "duration" in r.message or "Propagation failed" in r.message


def test_segments_must_be_positive():
    with pytest.raises(ValueError, match="segments"):
        newton_shoot(Oscillator(1.0), [1.0], 1.0, segments=0)



def test_stall_criterion_stops_a_newton_that_creeps():
    """Steps capped at 1 % (``max_step``) shrink the residual by about 3 % an iteration: the
    free run converges after 39 iterations, the stall criterion (half in 4 iterations) stops it
    after 4."""
    from solvers.shooting import STATUS_STALLED
    free = newton_shoot(Oscillator(2.0), [1.5], 1.2, max_iter=60, max_step=0.01)
    cut = newton_shoot(Oscillator(2.0), [1.5], 1.2, max_iter=60, max_step=0.01, stall=(4, 0.5, 1e-5))
    assert free.success and free.nit > 30
    assert not cut.success and cut.status == STATUS_STALLED and "Stalled" in cut.message
    assert cut.nit == 4 and cut.history == free.history[:5]
    assert cut.history[-1] > 0.5 * cut.history[0]
    # below the floor the criterion does not apply: the same creeping run is left to finish
    floor = newton_shoot(Oscillator(2.0), [1.5], 1.2, max_iter=60, max_step=0.01, stall=(4, 0.5, 10.0))
    assert floor.success and floor.nit == free.nit


def test_stall_criterion_leaves_a_converging_newton_alone():
    plain = newton_shoot(Oscillator(2.0), [1.5], 1.2, tol=1e-13)
    cut = newton_shoot(Oscillator(2.0), [1.5], 1.2, tol=1e-13, stall=(2, 0.5, 1e-5))
    assert cut.success and cut.nit == plain.nit and cut.p[0] == plain.p[0]


def test_past_the_solves_deadline_newton_and_its_line_search_stop():
    # inside a solve whose time is up (solvers.deadline), the engine takes no further step: its
    # line search would otherwise halve the step ~20 times, each trial a propagation cut short
    import time
    from solvers.deadline import propagation_deadline
    from solvers.shooting import STATUS_DEADLINE

    class Failing(Oscillator):
        calls = 0

        def flow(self, y0, T, Phi0):
            Failing.calls += 1
            out = super().flow(y0, T, Phi0)
            if Phi0 is None:        # every trial of the line search fails, as a capped run does
                out.ok, out.message = False, "the time budget ran out during a propagation"
            return out
    free = newton_shoot(Failing(2.0), [1.5], 1.2)
    assert not free.success and free.nit >= 1            # its line search ran (and failed)
    Failing.calls = 0
    with propagation_deadline(time.perf_counter() - 1.0):
        r = newton_shoot(Failing(2.0), [1.5], 1.2)
    assert r.status == STATUS_DEADLINE and r.nit == 0 and Failing.calls == 1
    # outside, the engine is as before
    assert newton_shoot(Oscillator(2.0), [1.5], 1.2, tol=1e-13).success


def test_the_measured_step_cost_moves_at_most_a_factor_two_a_call():
    from solvers import attitude_bvp as ab
    saved = dict(ab._STEP_COST)
    try:
        ab._STEP_COST[6] = 2e-5
        ab._learn_step_cost(6, 1.0, 1000)          # a call descheduled for a second
        assert ab._STEP_COST[6] == pytest.approx(0.7 * 2e-5 + 0.3 * 4e-5)
        ab._learn_step_cost(6, 1e-5, 100)          # too short to time: ignored
        assert ab._STEP_COST[6] == pytest.approx(2.6e-5)
    finally:
        ab._STEP_COST.clear()
        ab._STEP_COST.update(saved)
