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
