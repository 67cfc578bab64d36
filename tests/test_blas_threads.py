"""``solvers.solve`` runs with one BLAS thread (``solvers/blas_threads.py``) and gives the
caller's setting back afterwards, also when the solve raises."""
import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from slew_env import SlewProblem
from solvers import solve


def _blas_threads():
    return {d["filepath"]: d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"}


class _Spy:
    """A warm-start model that covers nothing and records the BLAS threads when asked."""
    def __init__(self):
        self.seen = None

    def covers(self, problem):
        self.seen = _blas_threads()
        return False

    def guess(self, problem):   # pragma: no cover - never reached
        raise AssertionError


def _problem():
    return SlewProblem([1.0, 1.0, 1.0], torque_max=1.0, q0=[1, 0, 0, 0], qf=[np.cos(0.3), np.sin(0.3), 0, 0])


def test_one_blas_thread_inside_and_the_callers_setting_after():
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        assert before and all(n == 2 for n in before.values())
        spy = _Spy()
        sol = solve(_problem(), warm_start=spy)
        assert sol.success
        assert spy.seen is not None and set(spy.seen) >= set(before)
        assert all(spy.seen[f] == 1 for f in before)
        assert _blas_threads() == before


def test_setting_restored_when_the_solve_raises():
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        with pytest.raises(ValueError, match="method"):
            solve(_problem(), method="no-such-method")
        assert _blas_threads() == before


def test_overlapping_solves_restore_the_setting_when_the_last_one_leaves():
    """Solves in two Python threads overlap (A in, B in, A out, B out): B keeps one thread after
    A leaves, and the setting found before A comes back after B."""
    from solvers.blas_threads import single_threaded_blas
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        a, b = single_threaded_blas(), single_threaded_blas()
        a.__enter__()
        b.__enter__()
        a.__exit__(None, None, None)
        assert all(n == 1 for n in _blas_threads().values())
        b.__exit__(None, None, None)
        assert _blas_threads() == before
