"""What a stage of ``solve`` gets of the time budget, and the answer when it has none left."""

from __future__ import annotations

import time

from .solution import STATUS_BUDGET_EXHAUSTED, STATUS_MESSAGES, SlewSolution

# s: what a stage gets when the time budget is spent before it starts: it stops at its first
# check and reports the budget exhausted. (Stages used to get 0.5-1 s whatever was left, so
# that a budget of 0.05 s could take 3 s; ``benchmarks/bench_budget.py``)
MIN_STAGE_BUDGET = 1e-3


def left(budget, spent) -> float:
    """Seconds left of ``budget`` after ``spent``, at least ``MIN_STAGE_BUDGET``."""
    return max(MIN_STAGE_BUDGET, float(budget) - float(spent))


def budget_spent(prob, what, nit, nfev, t0, route) -> SlewSolution:
    """Status 3 where a stage of ``auto`` has used the whole time budget (``what``: the stage,
    the subject of a sentence): the next stage is not started, as building an NLP is not
    interruptible."""
    return SlewSolution(False, STATUS_BUDGET_EXHAUSTED,
                        f"{STATUS_MESSAGES[STATUS_BUDGET_EXHAUSTED]} {what} used the whole time budget.",
                        nit, nfev, time.perf_counter() - t0, method="indirect", problem=prob, route=route)
