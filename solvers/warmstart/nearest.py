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
``format`` "slewopt-nn", ``format_version``, ``domain``, ``k``).
"""
from __future__ import annotations

import json
import math
import os

import numpy as np
from scipy.spatial import cKDTree

from slew_env import SlewProblem
from ..guesses import Guess
from .features import canonical_form, solution_from_canonical, unsupported_reason
from .model import ModelFileError, read_table

NN_FORMAT = "slewopt-nn"
NN_FORMAT_VERSION = 1


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
        self.Z, self.T, self.T_eig = np.asarray(Z, float), np.asarray(T, float), np.asarray(T_eig, float)
        self.U, self.S = np.asarray(U, float), np.asarray(S, float)
        n = self.X.shape[0]
        if (self.Z.shape != (n, 6) or self.T.shape != (n,) or self.T_eig.shape != (n,) or self.U.shape != (n, 3)
                or self.S.ndim != 3 or self.S.shape[:2] != (n, 3)):
            raise ValueError(f"Z, T, T_eig, U, S: expected one row per tabled problem ({n})")
        if not (np.all(np.isfinite(self.X)) and np.all(np.isfinite(self.Z)) and np.all(self.T > 0)
                and np.all(self.T_eig > 0)):
            raise ValueError("X, Z, T, T_eig: the features and costates must be finite and the times positive")
        self.k = int(k)
        if self.k < 1:
            raise ValueError(f"k: need at least one neighbour, got {self.k}")
        self.domain = domain or {}
        self.name = name
        self.scale = np.maximum(self.X.std(axis=0), 1e-3)
        self.tree = cKDTree(self.X / self.scale)

    @classmethod
    def from_arrays(cls, arrays: dict, **kw):
        return cls(arrays["X"], arrays["Z"], arrays["T"], arrays["T_eig"], arrays["U"], arrays["S"], **kw)

    @classmethod
    def load(cls, path):
        path = os.fspath(path)
        d, card = read_table(path, NN_FORMAT, NN_FORMAT_VERSION)
        if card.get("kind") == "pointing-cones":
            from .cone_nearest import ConeNearestNeighbourModel
            return ConeNearestNeighbourModel.from_card(d, card, path)
        try:
            return cls.from_arrays(d, k=card.get("k", 3), domain=card.get("domain"),
                                   name=card.get("name", "nearest-neighbour"))
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
