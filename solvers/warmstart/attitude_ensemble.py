"""The shipped warm start for full-attitude per-axis slews: the network's guess, then the
solutions of the nearest solved problems, then the network's costates alone.

The network and the lookup fail on different problems. On the 1,000 held-out problems of
``slew evaluate`` (docs/WARMSTART.md) the network converged on 853 and the three nearest of
39,494 tabled solutions on 840, but 14 of the lookup's answers were problems the network
missed (and 27 the other way round): the network regresses a switching structure that can be
one switch off, where a neighbour's solution is one consistent extremal. So the candidates
are, in order:

1. the network's guess and its propagated structure (``WarmStartModel``: the switch-time
   Newton, milliseconds);
2. the solutions of the ``n_neighbours`` nearest tabled problems (``NearestNeighbourModel``,
   mapped to this problem's axes; a failed one costs a few milliseconds);
3. where the singular table (``singular_table``) does not find the problem among singular
   ones, the ``n_more`` next nearest solutions, computed only when reached: of the 12 held-out
   problems with an exact extremal that 1 and 2 missed, 6 converge from neighbours ranked 4th
   to 8th, while a singular problem would only pay for them before the singular table's route;
4. the network's costates alone (smoothing continuation, up to a second; ``solve`` with
   ``method="auto"`` runs it only after collocation, ``solvers.warm_routes.split_continuation``).

Files: the network ``full-attitude.npz`` and, next to it, the table ``full-attitude.nn.npz``
(the network's own training solutions, written by ``slew train --export``:
``training.warmstart.train.export_attitude_table``). Without a ``singular_table`` there are no
further neighbours (3 is skipped).
"""
from __future__ import annotations

import time

from slew_env import SlewProblem


class AttitudeEnsembleWarmStart:
    """The network's structured candidates, the neighbours' solutions, then the network's
    continuation candidate (module docstring)."""

    KIND = "full-attitude-ensemble"

    def __init__(self, network, table, n_neighbours=3, n_more=5, singular_table=None):
        from .model import WarmStartModel
        from .nearest import NearestNeighbourModel
        if not isinstance(network, WarmStartModel) or type(table) is not NearestNeighbourModel:
            raise ValueError("model: the ensemble needs a full-attitude network (WarmStartModel) and a full-attitude "
                             f"table (NearestNeighbourModel), got {type(network).__name__} and {type(table).__name__}")
        if isinstance(n_neighbours, bool) or int(n_neighbours) != n_neighbours or int(n_neighbours) < 1:
            raise ValueError(f"n_neighbours: must be a positive integer, got {n_neighbours!r}")
        if isinstance(n_more, bool) or int(n_more) != n_more or int(n_more) < 0:
            raise ValueError(f"n_more: must be a non-negative integer, got {n_more!r}")
        if singular_table is not None and not hasattr(singular_table, "query"):
            raise ValueError(f"singular_table: expected a SingularTable, got {type(singular_table).__name__}")
        self.network, self.table = network, table
        self.n_neighbours, self.n_more = int(n_neighbours), int(n_more)
        self.singular_table = singular_table
        n = int(table.X.shape[0])
        more = f" (+{self.n_more} where not singular)" if self.n_more and singular_table is not None else ""
        self.name = f"full-attitude (the network, then {self.n_neighbours}{more} nearest of {n:,} solutions)"
        self.domain = network.domain
        self.card = network.card
        self.last_inference_s = float("nan")

    def covers(self, problem):
        """``None`` where the network covers ``problem`` (the table adds candidates where it
        covers it too), else the network's reason."""
        return self.network.covers(SlewProblem.from_dict(problem))

    def guess_or_reason(self, problem):
        problem = SlewProblem.from_dict(problem)
        t0 = time.perf_counter()
        g, why = self.network.guess_or_reason(problem)
        if why:
            return None, why
        if self.table.covers(problem):    # a network that covers more than its table: its guess alone
            g.inference_s = self.last_inference_s = time.perf_counter() - t0
            return g, None
        # the network's structured candidates (the guess and, deferred, its propagated
        # structure) keep their place; the neighbours go before its costate-only candidate. They
        # are deferred too: where the network's guess converges (8 in 10) the table is not read
        structured = [c for c in g.candidates if callable(c) or c.switch_times is not None]
        costate_only = [c for c in g.candidates if not callable(c) and c.switch_times is None]
        g.candidates = structured + self._neighbours(problem) + costate_only
        g.inference_s = self.last_inference_s = time.perf_counter() - t0
        return g, None

    def _neighbours(self, problem):
        """Deferred candidates: the ``n_neighbours`` nearest tabled solutions, then ``n_more``
        further ones only if the singular table does not find the problem among singular ones
        (there, no neighbour converges, and the table's own route follows; where it votes
        against, the alternative to these few milliseconds is collocation). One table query for
        all of them and one vote, each when first reached (the network's guess has failed by then,
        so mapping the further solutions back costs nothing that matters)."""
        memo = {}
        n_more = self.n_more if self.singular_table is not None else 0

        def rows():
            if "rows" not in memo:
                nn = self.table.guess(problem, k=self.n_neighbours + n_more)
                memo["rows"] = [nn] + list(nn.candidates)
            return memo["rows"]

        def further_wanted():
            if "vote" not in memo:
                try:
                    share, _ = self.singular_table.query(problem)
                    memo["vote"] = share < self.singular_table.vote
                except (OSError, ValueError, IndexError):    # not covered, or a damaged file:
                    memo["vote"] = False                     # no vote, no more neighbours
            return memo["vote"]

        def nth(j):
            def make():
                if j >= self.n_neighbours and not further_wanted():
                    return None
                r = rows()
                if j >= len(r):
                    return None
                c = r[j]
                c.candidates = []
                return c
            return make
        return [nth(j) for j in range(self.n_neighbours + n_more)]

    def guess(self, problem):
        g, why = self.guess_or_reason(problem)
        if why:
            raise ValueError(f"problem not covered by {self.name}: {why}")
        return g
