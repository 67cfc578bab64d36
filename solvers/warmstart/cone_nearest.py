"""Nearest-neighbour warm start for pointing slews with keep-out cones: the data-driven
baseline of the pointing-cones model (``cone_model``), built from the same data.

The table holds, per exact solution, its canonical features (``cone_features``) and its
canonical solution: costates ``z'``, ``T`` (with the reference time ``T_ref``), first-arc
signs, switch instants per canonical axis as fractions of ``T``, and per cone slot the touch
(flag, instant as a fraction of ``T``, ``log ν``). A query's ``k`` nearest rows (standardised
Euclidean distance) become the guess and its candidates, nearest first, mapped to the query's
axes and cones exactly as the network's outputs are.

File format (``.nn.npz``, ``card.kind = "pointing-cones"``): ``X`` (n, 24), ``Z`` (n, 6), ``T``,
``T_ref`` (n,), ``U`` (n, 3), ``F`` (n, 3, K), ``touch``, ``frac``, ``log_nu`` (n, 3), ``card``.
"""
from __future__ import annotations

import json

import numpy as np

from slew_env import SlewProblem
from ..guesses import Guess
from ..core import warmstart_kernels as _k
from .cone_features import MAX_CONES, N_CONE_FEATURES, cone_canonical_form, cone_unsupported_reason, solution_from_canonical
from .model import ModelFileError
from .nearest import NN_FORMAT, NN_FORMAT_VERSION, neighbour_count, table_card, table_coverage, table_fields

ARRAYS = ("X", "Z", "T", "T_ref", "U", "F", "touch", "frac", "log_nu")


class ConeNearestNeighbourModel:
    KIND = "pointing-cones"

    def __init__(self, arrays: dict, k=3, domain=None, name="nearest-neighbour (pointing-cones)"):
        self.a = {key: np.asarray(arrays[key], float) for key in ARRAYS}
        if self.a["X"].ndim != 2 or self.a["X"].shape[0] == 0:
            raise ValueError("X: the nearest-neighbour table needs at least one solved problem")
        a = self.a
        n = a["X"].shape[0]
        # every array's shape, before compiled code reads rows of them (a table saved with another
        # layout had been read past its arrays' ends, or raised numba's typing errors mid-solve)
        shapes = {"X": (n, N_CONE_FEATURES), "Z": (n, 6), "T": (n,), "T_ref": (n,), "U": (n, 3),
                  "touch": (n, MAX_CONES), "frac": (n, MAX_CONES), "log_nu": (n, MAX_CONES)}
        for key, want in shapes.items():
            if a[key].shape != want:
                raise ValueError(f"{key}: the pointing-cones table's array has shape {a[key].shape}, expected {want}")
        if a["F"].ndim != 3 or a["F"].shape[:2] != (n, 3) or a["F"].shape[2] < 1:
            raise ValueError(f"F: the pointing-cones table's switch fractions have shape {a['F'].shape}, expected "
                             f"({n}, 3, K)")
        if not (np.all(np.isfinite(a["X"])) and np.all(np.isfinite(a["Z"])) and np.all(a["T"] > 0)
                and np.all(a["T_ref"] > 0) and np.all(np.isfinite(a["T"])) and np.all(np.isfinite(a["T_ref"]))):
            raise ValueError("X, Z, T, T_ref: the features and costates must be finite and the times positive")
        self.k, self.domain, self.name = table_fields(a["U"], k, domain, name)
        # the data files its solutions came from, as slew train's card records them (a table
        # exported since session 39; a table is trained on again: slew train --data NAME.nn.npz)
        self.data_files = []
        self.scale = np.maximum(self.a["X"].std(axis=0), 1e-3)
        # standardised, transposed, float32: the layout of the compiled brute-force query
        self._XT = np.ascontiguousarray((self.a["X"] / self.scale).T, dtype=np.float32)
        self._group_tables()

    def _group_tables(self):
        """The rows of each presence pattern of the cone slots apart (``nearest`` scans the
        query's own pattern first), and per slot the least squared standardised distance that a
        row having the slot adds against a problem lacking it (whose slot features are zeros):
        the least standardised norm of the slot's features over the rows that have it. Grouping needs the rows lacking a slot to have
        zeros in its features (as the canonical form writes them); a table without that is
        always scanned whole."""
        X = self.a["X"]
        slots = [slice(9 + 5 * k, 9 + 5 * k + 5) for k in range(MAX_CONES)]
        present = np.stack([X[:, sl][:, 4] > 0.5 for sl in slots], axis=1)
        self._groups = {}
        self._groups_by_code = [None] * 2 ** MAX_CONES
        self._slot_bound = np.full(MAX_CONES, np.inf)
        self._slot_has = present.any(axis=0)
        self._slot_lacks = (~present).any(axis=0)
        if any(np.any(X[~present[:, k], sl] != 0.0) for k, sl in enumerate(slots)):
            return
        s = self.scale
        for k, sl in enumerate(slots):
            if self._slot_has[k]:
                # exactly the least a row having the slot adds against zeros (a canonical row's
                # flag, unit axis and half-angle add at least 1/s_p² + 1/max(s_axis)² +
                # (α_min/s_α)²; any row: its own standardised slot norm)
                self._slot_bound[k] = float(((X[present[:, k], sl] / s[sl]) ** 2).sum(axis=1).min())
        for pattern in np.unique(present, axis=0):
            rows = np.flatnonzero((present == pattern).all(axis=1))
            # only the features of the pattern's slots (and the 9 of the slew): the others are
            # zeros in its rows and in a query of that pattern, and add exactly nothing to a
            # distance (a 1-cone query scans 14 features, not 24)
            dims = np.concatenate([np.arange(9)] + [np.arange(9 + 5 * k, 14 + 5 * k)
                                                    for k in range(MAX_CONES) if pattern[k]])
            self._groups[tuple(bool(v) for v in pattern)] = (rows, np.ascontiguousarray(self._XT[np.ix_(dims, rows)]),
                                                             dims)
        # by the pattern's code (bit k: slot k present), as the compiled query plan gives it
        self._groups_by_code = [self._groups.get(tuple(bool(c >> k & 1) for k in range(MAX_CONES)))
                                for c in range(2 ** MAX_CONES)]

    @classmethod
    def from_card(cls, d, card, path):
        try:
            k, domain, name = table_card(card, "nearest-neighbour (pointing-cones)")
            data_files = card.get("data_files") or []
            if not isinstance(data_files, list):
                raise ModelFileError(f"card.data_files: expected a list of data files, got {data_files!r}"[:300])
            t = cls({key: d[key] for key in ARRAYS}, k=k, domain=domain, name=name)
        except KeyError as e:
            raise ModelFileError(f"model: {path} lacks the array {e}") from None
        except ValueError as e:
            raise ModelFileError(f"model: {path}: {e}") from None
        t.data_files = list(data_files)
        return t

    def save(self, path, compact=False):
        """``compact``: float32 arrays, compressed (a shipped table; Newton polishes the
        neighbour's solution anyway)."""
        card = {"format": NN_FORMAT, "format_version": NN_FORMAT_VERSION, "kind": self.KIND, "k": self.k,
                "domain": self.domain, "name": self.name}
        if self.data_files:     # where its solutions came from (slew train's data_files)
            card["data_files"] = self.data_files
        if compact:
            np.savez_compressed(path, **{key: v.astype(np.float32) for key, v in self.a.items()},
                                card=np.array(json.dumps(card)))
        else:
            np.savez(path, **self.a, card=np.array(json.dumps(card)))

    def covers(self, problem):
        problem = SlewProblem.from_dict(problem)
        why = table_coverage(problem, cone_unsupported_reason)
        if why is None and not problem.cones:
            why = "cones: the table holds problems with 1–3 cones"
        return why

    def nearest(self, x, k=None) -> np.ndarray:
        """Row indices of the ``k`` (default ``self.k``) tabled problems nearest to the
        canonical features ``x`` (standardised Euclidean distance), nearest first."""
        k = neighbour_count(k, self.k, self.a["X"].shape[0])
        x = np.asarray(x, float)
        if x.shape != (self._XT.shape[0],):
            raise ValueError(f"x: expected {self._XT.shape[0]} finite canonical features, got {x!r:.80}")
        # one compiled call checks x, standardises it, finds its pattern of cones and the bound
        # below (the same steps in numpy took 9 of the query's 25 µs)
        finite, code, xs, bound = _k.cone_query_plan(x, self.scale, self._slot_has, self._slot_lacks,
                                                      self._slot_bound)
        if not finite:
            raise ValueError(f"x: expected {self._XT.shape[0]} finite canonical features, got {x!r:.80}")
        idx = np.empty(k, dtype=np.int64)
        # the rows of the query's pattern of cones first (a third of the table): where the k-th
        # of them is nearer than any row of another pattern can be, they are the k nearest of all
        # (93 % of held-out queries on the 15,760-row table; else the whole table is scanned).
        # A query whose absent slot has features other than zeros (code -1) is not grouped
        group = self._groups_by_code[code] if code >= 0 else None
        if group is not None and group[0].size >= k:
            rows, XT, dims = group
            if _k.nearest_rows_kth_dims(XT, xs, dims, k, idx) < (1.0 - 1e-4) * bound:
                return rows[idx]
        return _k.nearest_rows(self._XT, xs, k, idx)

    def row_guess(self, problem, cf, j, rank=0) -> Guess:
        """The solution of table row ``j`` mapped to ``problem`` (canonical form ``cf``): one
        compiled call (``warmstart_kernels.cone_row_solution``); a row with an entry that is not
        finite takes the staged path (``row_guess_staged``), whose ``Guess`` names the fault."""
        a = self.a
        c0, tf, sw, counts, uf, tc, ok = _k.cone_row_solution(
            problem.q0, cf.axial, cf.order_array, cf.tau, cf.T_ref, len(problem.cones), cf.slots_array,
            a["Z"], a["T"], a["T_ref"], a["U"], a["F"], a["touch"], a["frac"], a["log_nu"], j)
        if not ok:
            return self.row_guess_staged(problem, cf, j, rank)
        touches = [(int(c), float(t), float(nu)) for c, t, nu in tc] or None
        g = Guess._checked(c0, tf, [sw[i, :counts[i]] for i in range(3)], uf, source=f"nearest-neighbour[{rank}]")
        g.touches = touches
        return g

    def row_guess_staged(self, problem, cf, j, rank=0) -> Guess:
        """``row_guess`` in numpy, stage by stage (the reference the compiled path is tested
        against)."""
        a = self.a
        T = a["T"][j] * cf.T_ref / a["T_ref"][j]
        sw = [np.sort(f[np.isfinite(f)]) * T for f in a["F"][j]]
        touches = [(k, a["frac"][j, k] * T, np.exp(a["log_nu"][j, k]))
                   for k in range(len(problem.cones)) if a["touch"][j, k] > 0.5]
        c0, tf, sw, uf, touches = solution_from_canonical(problem, cf, a["Z"][j], T, sw, a["U"][j], touches)
        return Guess(c0, tf, sw, uf, source=f"nearest-neighbour[{rank}]", touches=touches or None)

    def guess(self, problem, k=None, cf=None) -> Guess:
        """The solutions of the ``k`` (default ``self.k``) nearest problems, nearest first.
        ``cf``: the problem's canonical form, when the caller has it (and has checked coverage)."""
        problem = SlewProblem.from_dict(problem)
        if cf is None:
            why = self.covers(problem)
            if why:
                raise ValueError(f"problem not covered by {self.name}: {why}")
            cf = cone_canonical_form(problem)
        idx = self.nearest(cf.x, k)
        out = self.row_guess(problem, cf, int(idx[0]), 0)
        out.candidates = [self.row_guess(problem, cf, int(j), rank) for rank, j in enumerate(idx[1:], 1)]
        return out
