"""The end of the running solve's time budget, for code it cannot be handed to.

A compiled propagation cannot read the clock, and the shooting engine's line search is called
by routes that pass it no deadline of their own. ``solvers.solve`` opens
``propagation_deadline`` around its route; ``attitude_bvp.step_allowance`` gives each
propagation only the steps the time left pays for, and the shooting engine stops its line
search once the deadline has passed (each trial would otherwise run its capped propagation,
fail, and halve the step). The deadline is per thread: concurrent solves keep their own.
"""
from __future__ import annotations

import math
import threading
import time
from contextlib import contextmanager

_LOCAL = threading.local()


@contextmanager
def propagation_deadline(deadline):
    """Within the block, on this thread, the solve's deadline is ``deadline`` (a
    ``time.perf_counter()`` value); nested blocks keep the earlier one."""
    prev = current()
    _LOCAL.t = min(prev, float(deadline))
    try:
        yield
    finally:
        _LOCAL.t = prev


def current() -> float:
    """This thread's deadline (``math.inf`` outside a solve)."""
    return getattr(_LOCAL, "t", math.inf)


def passed() -> bool:
    return time.perf_counter() > current()
