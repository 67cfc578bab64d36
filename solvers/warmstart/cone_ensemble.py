"""The shipped warm start for pointing slews with keep-out cones: the exact solutions of the
nearest solved problems first, then the network's guess.

Measured on held-out problems (docs/WARMSTART.md): the pointing-cones network's guess alone
converges less often than the solution of a nearby solved problem. A neighbour's solution is
*self-consistent* — its costates, switching structure, switch instants and touches belong to
one extremal — while the network regresses each of them separately, and the switch-time
Newton of ``solvers.cone_touch`` is far more sensitive to wrong switch instants than to wrong
costates (on 40 held-out problems with exact answers: with the true switching structure and
touches, 34 of the network's costate guesses converge; with its own, 10). So the candidates are, in order: the solutions of the
``n_neighbours`` nearest problems of the table (``cone_nearest``, mapped to this problem's
axes and cones), then the network's guesses and their variants (``cone_model``: with several
heads, each head's in the selector's order). The solver tries
them one by one, each under a short time cap (``solvers.cone_routes.CONE_CANDIDATE_CAP``), those with
touches in order of their starting residual (``RANKS_CANDIDATES``). Only the nearest solution's
guess is made by ``guess``; the later candidates are deferred (``Guess.iter_all``: made when the
solver reaches them, which the learned route's ranking does at its start; ``auto``'s collocation
starts take the first two only; pickling such a guess makes them first).

Files: the network ``pointing-cones.npz`` and the table ``pointing-cones.nn.npz`` next to it
(both made by ``slew train --config training/warmstart/configs/pointing-cones.yaml --export``).
"""
from __future__ import annotations

import functools
import time

import numpy as np

from slew_env import SlewProblem


class ConeEnsembleWarmStart:
    """Neighbour solutions, then the network's guess (module docstring)."""

    KIND = "pointing-cones-ensemble"
    # its candidates are cheap to make (table rows mapped to the problem, one network pass: 0.2 ms
    # for all of them), so the solver makes them all up front and tries those with touches in
    # order of their starting residual (``solvers.cone_routes.ranked_by_starting_residual``)
    RANKS_CANDIDATES = True

    def __init__(self, network, table, n_neighbours=4):
        from .cone_model import ConeWarmStartModel
        from .cone_nearest import ConeNearestNeighbourModel
        if not isinstance(network, ConeWarmStartModel) or not isinstance(table, ConeNearestNeighbourModel):
            raise ValueError("model: the ensemble needs a pointing-cones network (ConeWarmStartModel) and a "
                             f"pointing-cones table (ConeNearestNeighbourModel), got {type(network).__name__} and "
                             f"{type(table).__name__}")
        if int(n_neighbours) < 1:
            raise ValueError(f"n_neighbours: must be ≥ 1, got {n_neighbours}")
        self.network, self.table = network, table
        self.n_neighbours = int(n_neighbours)
        n = int(table.a["X"].shape[0])
        self.name = f"pointing-cones ({self.n_neighbours} nearest of {n:,} solutions, then the network)"
        self.domain = network.domain
        self.last_inference_s = float("nan")
        self._warm = False

    def warm_up(self, solve):
        """Load the solver's compiled kernels once per process: ``solve(problem, guess)`` (the
        candidates' own route, without time caps) on two tabled problems from their own
        solutions, one that touches a cone and one that does not (about 0.3–0.5 s the first
        time, nothing after). Without it the first candidates of a process's first solve spend
        their time caps loading compiled code."""
        if self._warm:
            return 0.0
        from .cone_features import canonical_problem
        t0 = time.perf_counter()
        a = self.table.a
        touched = a["touch"].sum(axis=1) > 0
        try:
            for rows in (np.flatnonzero(touched), np.flatnonzero(~touched)):
                if rows.size:
                    try:
                        p = canonical_problem(a["X"][int(rows[0])])
                        solve(p, self.table.guess(p, k=1))
                    except Exception:   # noqa: BLE001 - a warm-up only: any answer (or none, or a
                        pass            # damaged table's error, which the candidates then record) loads the kernels
        finally:
            # once, whatever happened (set after the solves: a concurrent first call warms too,
            # rather than racing ahead with cold kernels)
            self._warm = True
        return time.perf_counter() - t0

    def covers(self, problem):
        problem = SlewProblem.from_dict(problem)
        why, _ = self.network._coverage(problem)
        return why or self.table.covers(problem)

    def guess_or_reason(self, problem):
        problem = SlewProblem.from_dict(problem)
        t0 = time.perf_counter()
        why = self.table.covers(problem)     # (its first check is the canonical form's own)
        if why:
            return None, why
        why, cf = self.network._coverage(problem, supported=True)
        if why:
            return None, why
        # one canonical form for the table and the network. The nearest neighbour's guess is made
        # now; the other neighbours and the network's guess (and its variant) only when the solver
        # reaches them (deferred candidates): the guess object costs 140 µs instead of 385 µs, and
        # a route that takes only the first (collocation's starts: the first two) pays for no more
        idx = self.table.nearest(cf.x, self.n_neighbours)
        first = self.table.row_guess(problem, cf, int(idx[0]), 0)
        later = [functools.partial(self.table.row_guess, problem, cf, int(j), rank)
                 for rank, j in enumerate(idx[1:], 1)]
        net = _NetworkParts(self.network, problem, cf)
        # each head gives a guess and its variant (with or without the touches), in the selector's order
        first.candidates = later + [net.part(k) for k in range(2 * self.network.heads)]
        # on the guess too: the model object is shared (cached), the guess is this call's
        first.inference_s = self.last_inference_s = time.perf_counter() - t0
        return first, None

    def guess(self, problem):
        g, why = self.guess_or_reason(problem)
        if why:
            raise ValueError(f"problem not covered by {self.name}: {why}")
        return g


class _NetworkParts:
    """The network's guess for one problem, made once when a deferred candidate first asks for
    it, as its plain parts: each head's guess, then its variant (with or without the touches),
    each without candidates of its own. The later heads stay deferred (the network's own
    candidates): a head that fails is skipped alone, its error recorded once."""

    def __init__(self, network, problem, cf):
        self.network, self.problem, self.cf = network, problem, cf
        self._parts = None
        self._error = None

    def _make(self):
        if self._parts is None and self._error is None:
            try:
                g = self.network.guess_from_form(self.problem, self.cf)
            except Exception as e:   # noqa: BLE001 - raised once (by the first part), remembered
                self._error = e
                raise
            parts = [g] + list(g.candidates)
            g.candidates = []
            self._parts = parts
        return self._parts

    def part(self, k):
        """A deferred candidate: the network's ``k``-th part, or ``None`` if it has fewer (or if
        the network failed: its first part raised the error, to be recorded once). A part the
        network deferred is made now (its own failure raised here, for this candidate only)."""
        def make():
            parts = self._make()
            if parts is None or k >= len(parts):
                return None
            part = parts[k]
            if callable(part):      # (a Guess is not callable)
                part = parts[k] = part()
                if part is not None:
                    part.candidates = []
            return part
        return make
