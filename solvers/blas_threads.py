"""One BLAS thread during a solve.

The solvers' dense linear algebra is small: SLSQP's subproblems in the switch-time optimisers
(tens of unknowns, a few hundred constraints), Newton steps on a dozen unknowns. OpenBLAS, which
numpy and scipy ship, runs such calls on all cores anyway; its threads cost more than they give
here, and when another process holds a core they wait for it. On the 2-core machine, with one
core busy, the cone switch-time step of one problem took 5 s with OpenBLAS's default threads and
0.55 s with one (SLSQP's subproblem was 4.3 s of the 5; `runs/s24/`), the same iterates either
way. So ``solvers.solve`` runs with the BLAS libraries limited to one thread, and restores what
they had after.

The limit is process-wide (OpenBLAS has no per-thread setting). Solves that overlap in several
Python threads share it: the first one in sets it, the last one out restores the setting found
by the first (a counter under a lock), so a thread that changes the BLAS threads while a solve
runs elsewhere has that change undone when the last solve ends. It covers the BLAS libraries
loaded when the first solve starts (numpy's and scipy's), not ones loaded later (CasADi's
IPOPT, whose time did not change with it); on restoring, threadpoolctl resets every library it
found (OpenMP ones too) to what they had when the limit was set.
"""
from __future__ import annotations

import contextlib
import threading

from threadpoolctl import ThreadpoolController

_controller = None
_lock = threading.Lock()
_depth = 0          # solves inside the limit now
_limiter = None     # threadpoolctl's limiter of the first of them (holds the original setting)


@contextlib.contextmanager
def single_threaded_blas():
    """The BLAS libraries at one thread inside, their own setting after the last overlapping
    solve leaves. Costs about 20 µs (the libraries are found once, on the first call)."""
    global _controller, _depth, _limiter
    with _lock:
        if _controller is None:
            import scipy.linalg  # noqa: F401  (scipy's own OpenBLAS, loaded before it is found)
            _controller = ThreadpoolController()
        if _depth == 0:
            _limiter = _controller.limit(limits=1, user_api="blas")
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                _limiter.restore_original_limits()
                _limiter = None
