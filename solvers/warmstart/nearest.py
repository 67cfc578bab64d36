"""Nearest-neighbour warm start: the data-driven baseline (look the problem up in a table
of solved problems, reuse the neighbours' solutions).

The table holds, per solved problem, its canonical features and its canonical
nondimensional solution (``z'``, ``T``, the first-arc signs and switch times per canonical
axis). A query is put in canonical form and the ``k`` nearest rows (Euclidean distance on
standardised features) become the guess and its candidates, nearest first: each
neighbour's costates, final time (rescaled by the ratio of eigenaxis times) and
structure, mapped back to the query's axes.

File format (``.nn.npz``): ``X`` (n, N_FEATURES), ``Z`` (n, 6), ``T`` (n,), ``T_eig``
(n,), ``U`` (n, 3), ``S`` (n, 3, K) switch times (NaN-padded), and ``card`` (JSON:
``format`` "slewopt-nn", ``format_version``, ``domain``, ``k``). ``k`` is a whole number from
1 to ``MAX_NEIGHBOURS`` (64; ``checked_neighbours``): a guess
maps every neighbour to the problem inside the solve's time budget.
"""
from __future__ import annotations

import json
import math
import os

import numpy as np
from scipy.spatial import cKDTree

from slew_env import SlewProblem
from ..guesses import Guess
from .features import N_FEATURES, canonical_form, solution_from_canonical, unsupported_reason
from .model import (MAX_NEIGHBOURS, ModelFileError, card_text, card_whole, checked_domain, read_table,
                    whole_field)

NN_FORMAT = "slewopt-nn"
NN_FORMAT_VERSION = 1


NEIGHBOURS_WHY = (" (a guess maps every neighbour's solution to the problem before the solver starts, inside "
                  "its time budget: about 25 µs a neighbour)")


def checked_neighbours(k, n_rows, field="k", what="neighbours", at_most_rows=False):
    """A table's count of ``what`` (``k``, or a singular table's ``n_sequences``): a whole number
    from 1 to ``MAX_NEIGHBOURS``; ``ModelFileError`` naming ``field`` otherwise (a card with
    k = 100,000 had made every row a candidate: a guess of a second, outside any time budget).
    More than the table's ``n_rows`` is allowed unless ``at_most_rows``: a query gives all its rows
    (a table made from a small data file, ``slew evaluate --train-data``; the singular table's
    vote needs its ``k`` rows)."""
    k = whole_field(k, field, 1, MAX_NEIGHBOURS, NEIGHBOURS_WHY)
    if at_most_rows and n_rows is not None and k > n_rows:
        raise ModelFileError(f"{field}: {k} {what}, but the table holds only {n_rows} row{'s' if n_rows != 1 else ''}")
    return k


def check_signs(U, field="U"):
    """First-arc signs: every entry ±1 (a 0 or NaN sign maps to no bang-bang arc)."""
    if U.size and not np.all(np.abs(U) == 1.0):
        raise ValueError(f"{field}: the first-arc signs must be ±1, {int(np.sum(np.abs(U) != 1.0))} entries are not")


def table_card(card, default_name):
    """The neighbour table card's fields checked: ``(k, domain, name)`` (``k`` 3 where absent;
    ``ModelFileError`` naming the field)."""
    k = card_whole(card, "k", 1, MAX_NEIGHBOURS, default=3, why=NEIGHBOURS_WHY)
    return k, checked_domain(card.get("domain")), card_text(card, "name", default_name)


def table_fields(U, k, domain, name):
    """``(k, domain, name)`` of a neighbour table being built, checked, with its first-arc signs
    ``U`` (the full-attitude and the pointing-cones tables alike)."""
    check_signs(U)
    k = checked_neighbours(k, None)
    domain = checked_domain(domain)
    if not isinstance(name, str):
        raise ValueError(f"name: expected text, got {name!r}"[:200])
    return k, domain, name


def table_rows(d, key="X"):
    """The number of rows of a table file's array ``key`` (``None`` if it is missing or not an
    array of rows: the array checks say so)."""
    a = d.get(key)
    return int(a.shape[0]) if isinstance(a, np.ndarray) and a.ndim >= 1 else None


def table_coverage(problem, unsupported):
    """Why a table of rest-to-rest, per-axis solutions without rate limits does not cover
    ``problem`` (``unsupported``: the canonical form's own reasons), or ``None``."""
    why = unsupported(problem)
    if why:
        return why
    if problem.rate_max is not None:
        return "rate_max: the table holds problems without rate limits"
    if problem.rate_norm_max is not None:
        return "rate_norm_max: the table holds problems without rate limits"
    if not math.isinf(problem.torque_norm):
        return f"torque_norm: the table holds per-axis (inf) solutions, got {problem.torque_norm}"
    return None


def tabled_solution(problem, cf, T, T_eig, S, U, z):
    """A tabled canonical solution (nondimensional ``T``, its problem's eigenaxis time ``T_eig``,
    NaN-padded switch times ``S`` (3, K), first signs ``U``, costates ``z``) mapped to ``problem``
    (canonical form ``cf``): ``(costate0, tf, switch_times, u_first)`` in its units, the times
    rescaled by the ratio of eigenaxis times."""
    T_new = T * cf.T_eig / T_eig
    ratio = T_new / T
    times = [S[i][np.isfinite(S[i])] * ratio for i in range(3)]
    return solution_from_canonical(problem, cf, z, T_new, times, U)


class NearestNeighbourModel:
    def __init__(self, X, Z, T, T_eig, U, S, k=3, domain=None, name="nearest-neighbour"):
        self.X = np.asarray(X, float)
        if self.X.ndim != 2 or self.X.shape[0] == 0:
            raise ValueError("X: the nearest-neighbour table needs at least one solved problem")
        if self.X.shape[1] != N_FEATURES:
            raise ValueError(f"X: the table's features have shape {self.X.shape}, expected ({self.X.shape[0]}, "
                             f"{N_FEATURES}) (the full-attitude canonical features)")
        self.Z, self.T, self.T_eig = np.asarray(Z, float), np.asarray(T, float), np.asarray(T_eig, float)
        self.U, self.S = np.asarray(U, float), np.asarray(S, float)
        n = self.X.shape[0]
        if (self.Z.shape != (n, 6) or self.T.shape != (n,) or self.T_eig.shape != (n,) or self.U.shape != (n, 3)
                or self.S.ndim != 3 or self.S.shape[:2] != (n, 3)):
            raise ValueError(f"Z, T, T_eig, U, S: expected one row per tabled problem ({n})")
        if not (np.all(np.isfinite(self.X)) and np.all(np.isfinite(self.Z)) and np.all(self.T > 0)
                and np.all(self.T_eig > 0) and np.all(np.isfinite(self.T)) and np.all(np.isfinite(self.T_eig))):
            raise ValueError("X, Z, T, T_eig: the features and costates must be finite and the times positive")
        self.k, self.domain, self.name = table_fields(self.U, k, domain, name)
        self.scale = np.maximum(self.X.std(axis=0), 1e-3)
        self.tree = cKDTree(self.X / self.scale)

    @classmethod
    def from_arrays(cls, arrays: dict, **kw):
        return cls(arrays["X"], arrays["Z"], arrays["T"], arrays["T_eig"], arrays["U"], arrays["S"], **kw)

    @classmethod
    def load(cls, path):
        path = os.fspath(path)
        d, card = read_table(path, NN_FORMAT, NN_FORMAT_VERSION)
        kind = card.get("kind", "full-attitude")
        if kind == "pointing-cones":
            from .cone_nearest import ConeNearestNeighbourModel
            return ConeNearestNeighbourModel.from_card(d, card, path)
        if kind != "full-attitude":
            raise ModelFileError(f"model: {path}: unknown table kind {kind!r}"[:300])
        try:
            k, domain, name = table_card(card, "nearest-neighbour")
            return cls.from_arrays(d, k=k, domain=domain, name=name)
        except (KeyError, ValueError, TypeError) as e:
            raise ModelFileError(f"model: {path} is not a usable nearest-neighbour table ({e})") from None

    def save(self, path, compact=False):
        """Write the table; ``compact``: float32 features, costates and switch times, int8 signs,
        compressed (a third of the size; a guess needs no more digits), as the shipped table."""
        card = {"format": NN_FORMAT, "format_version": NN_FORMAT_VERSION, "k": self.k, "domain": self.domain,
                "name": self.name}
        if compact:
            f32 = np.float32
            np.savez_compressed(path, X=self.X.astype(f32), Z=self.Z.astype(f32), T=self.T.astype(f32),
                                T_eig=self.T_eig.astype(f32), U=self.U.astype(np.int8), S=self.S.astype(f32),
                                card=np.array(json.dumps(card)))
            return
        np.savez(path, X=self.X, Z=self.Z, T=self.T, T_eig=self.T_eig, U=self.U, S=self.S,
                 card=np.array(json.dumps(card)))

    def covers(self, problem):
        return table_coverage(SlewProblem.from_dict(problem), unsupported_reason)

    def nearest(self, x, k=None) -> np.ndarray:
        """Row indices of the ``k`` (default ``self.k``) tabled problems nearest to the canonical
        features ``x``, nearest first (the k-d tree: 11 features)."""
        k = neighbour_count(k, self.k, self.X.shape[0])
        return np.atleast_1d(self.tree.query(np.asarray(x, float) / self.scale, k=k)[1])

    def guess(self, problem, k=None) -> Guess:
        """The ``k`` (default: the table's) nearest solutions, as one guess and its candidates."""
        problem = SlewProblem.from_dict(problem)
        why = self.covers(problem)
        if why:
            raise ValueError(f"problem not covered by {self.name}: {why}")
        cf = canonical_form(problem)
        out = None
        for rank, j in enumerate(self.nearest(cf.x, k)):
            c0, tf, sw, uf = tabled_solution(problem, cf, self.T[j], self.T_eig[j], self.S[j], self.U[j], self.Z[j])
            g = Guess(c0, tf, sw, uf, source=f"nearest-neighbour[{rank}]")
            if out is None:
                out = g
            else:
                out.candidates.append(g)
        return out


def neighbour_count(k, default, n_rows) -> int:
    """The neighbours a table's ``nearest(x, k)`` returns: ``k`` (``None``: the table's
    ``default``), at most its ``n_rows``; ``ValueError`` naming ``k`` below 1."""
    k = default if k is None else int(k)
    if k < 1:
        raise ValueError(f"k: need at least one neighbour, got {k}")
    return min(k, n_rows)
