"""One BLAS thread during a solve.

The solvers' dense linear algebra is small: SLSQP's subproblems in the switch-time optimisers
(tens of unknowns, a few hundred constraints), Newton steps on a dozen unknowns. OpenBLAS, which
numpy and scipy ship, runs such calls on all cores anyway; its threads cost more than they give
here, and when another process holds a core they wait for it. On the 2-core machine, with one
core busy, the cone switch-time step of one problem took 5 s with OpenBLAS's default threads and
0.55 s with one (SLSQP's subproblem was 4.3 s of the 5; `runs/s24/`), the same iterates either
way. So ``solvers.solve`` runs with the BLAS libraries limited to one thread, and restores what
they had after.

The limit is process-wide while a solve runs (OpenBLAS has no per-thread setting), and it covers
the BLAS libraries loaded when the first solve starts (numpy's and scipy's), not ones loaded
later (CasADi's IPOPT, whose time did not change with it).
"""
from __future__ import annotations

from threadpoolctl import ThreadpoolController

_controller = None


def single_threaded_blas():
    """A context manager: the BLAS libraries at one thread inside, their own setting after.
    Costs about 20 µs (the libraries are found once, on the first call)."""
    global _controller
    if _controller is None:
        import scipy.linalg  # noqa: F401  (scipy's own OpenBLAS, loaded before it is found)
        _controller = ThreadpoolController()
    return _controller.limit(limits=1, user_api="blas")
