"""A table of solved full-attitude problems that says which ones have no bang-bang optimum
(a singular arc), and holds the switching sequences of those answers.

About one random per-axis slew in eight has a singular arc: no list of switch times is an
extremal, so the learned guess cannot converge, and ``auto`` answers with a bang-bang slew whose
switch times are optimised (``solvers.switch_time_opt``), seeded by collocation. Near problems
have near sequences, so where the learned guess fails and most of the ``k`` nearest tabled
problems are singular, ``auto`` first optimises the switch times of the nearest singular
answers' sequences (``switch_time_opt.bang_bang_from_sequences``), with no collocation.

File format (``.npz``): ``X`` (n, N_FEATURES) float32, the canonical features of every
tabled problem (singular or not); ``singular`` (n,) bool; for the m singular rows, in their
order: ``T`` (m,) nondimensional final time, ``T_eig`` (m,), ``U`` (m, 3) first-arc signs and
``S`` (m, 3, K) nondimensional switch times per canonical axis (NaN-padded); ``card`` (JSON:
``format`` "slewopt-singular", ``format_version``, ``k`` neighbours of the vote, ``vote`` (the
share of singular neighbours that sends a problem to the table route), ``n_sequences``
(neighbours' sequences tried), ``tf_rel_tol`` (the relative ``tf_tol`` reported, measured on
held-out problems), ``domain`` and ``training``).
"""
from __future__ import annotations

import json
import math
import os

import numpy as np
from scipy.spatial import cKDTree

from slew_env import SlewProblem
from .features import N_FEATURES, canonical_form, unsupported_reason
from .model import MAX_NEIGHBOURS, ModelFileError, _is_number, card_text, card_whole, checked_domain, read_table
from .nearest import NEIGHBOURS_WHY, check_signs, checked_neighbours, table_coverage, table_rows, tabled_solution

SINGULAR_FORMAT = "slewopt-singular"
SINGULAR_FORMAT_VERSION = 1


class SingularTable:
    def __init__(self, X, singular, T, T_eig, U, S, k=5, vote=0.6, n_sequences=3, tf_rel_tol=float("nan"),
                 domain=None, training=None, name="singular table"):
        self.X = np.asarray(X, float)
        self.singular = np.asarray(singular)
        if self.singular.dtype.kind not in "biu" or (self.singular.size and not np.all(np.isin(self.singular, (0, 1)))):
            raise ValueError("singular: expected one flag (true or false) per row")
        self.singular = self.singular.astype(bool)
        if (self.X.ndim != 2 or self.singular.ndim != 1 or self.X.shape[0] != self.singular.shape[0]
                or not self.singular.any()):
            raise ValueError("X, singular: the table needs one flag per row and at least one singular row")
        if self.X.shape[1] != N_FEATURES:
            raise ValueError(f"X: the table's features have shape {self.X.shape}, expected ({self.X.shape[0]}, "
                             f"{N_FEATURES}) (the full-attitude canonical features)")
        self.T, self.T_eig = np.asarray(T, float), np.asarray(T_eig, float)
        self.U, self.S = np.asarray(U, float), np.asarray(S, float)
        if not np.all(np.isfinite(self.X)):
            raise ValueError("X: the features must be finite")
        m = int(self.singular.sum())
        if (self.T.shape != (m,) or self.T_eig.shape != (m,) or self.U.shape != (m, 3) or self.S.ndim != 3
                or self.S.shape[:2] != (m, 3)):
            raise ValueError(f"T, T_eig, U, S: expected one row per singular problem ({m})")
        if not (np.all(self.T > 0) and np.all(self.T_eig > 0) and np.all(np.isfinite(self.T))
                and np.all(np.isfinite(self.T_eig))):
            raise ValueError("T, T_eig: the final times must be positive")
        check_signs(self.U)
        # k: neighbours of the vote, at most the table's rows; n_sequences: the nearest singular
        # answers tried, each mapped to the problem up front (fewer singular rows: all of them)
        self.k = checked_neighbours(k, self.X.shape[0], at_most_rows=True)
        self.n_sequences = checked_neighbours(n_sequences, MAX_NEIGHBOURS, "n_sequences", "sequences")
        if not (_is_number(vote) and 0.0 < float(vote) <= 1.0):
            raise ValueError(f"vote: the share of singular neighbours must be a number in (0, 1], got {vote!r}"[:200])
        self.vote = float(vote)
        if not (_is_number(tf_rel_tol) and (math.isnan(tf_rel_tol) or 0.0 <= float(tf_rel_tol) < 1.0)):
            raise ValueError(f"tf_rel_tol: expected a number in [0, 1) (or NaN: not measured), got {tf_rel_tol!r}"[:200])
        self.tf_rel_tol = float(tf_rel_tol)
        if training is not None and not isinstance(training, dict):
            raise ValueError(f"training: expected a JSON object, got {training!r}"[:200])
        if not isinstance(name, str):
            raise ValueError(f"name: expected text, got {name!r}"[:200])
        self.domain, self.training, self.name = checked_domain(domain), training or {}, name
        self.scale = np.maximum(self.X.std(axis=0), 1e-3)
        self.tree = cKDTree(self.X / self.scale)
        self.tree_singular = cKDTree(self.X[self.singular] / self.scale)

    @classmethod
    def load(cls, path):
        path = os.fspath(path)
        d, card = read_table(path, SINGULAR_FORMAT, SINGULAR_FORMAT_VERSION)
        try:
            # the card's fields by name first (``card.k``, ...), then the arrays
            k = card_whole(card, "k", 1, MAX_NEIGHBOURS, why=NEIGHBOURS_WHY)
            checked_neighbours(k, table_rows(d), "card.k", at_most_rows=True)
            n_sequences = card_whole(card, "n_sequences", 1, MAX_NEIGHBOURS,
                                     why=" (each is mapped to the problem before its optimisation starts)")
            if "vote" not in card:
                raise ModelFileError("card.vote: missing")
            vote = card["vote"]
            if not (_is_number(vote) and 0.0 < float(vote) <= 1.0):
                raise ModelFileError(f"card.vote: the share of singular neighbours must be a number in (0, 1], "
                                     f"got {vote!r}"[:300])
            tf_rel_tol = card.get("tf_rel_tol", float("nan"))
            if not (_is_number(tf_rel_tol) and (math.isnan(tf_rel_tol) or 0.0 <= float(tf_rel_tol) < 1.0)):
                raise ModelFileError(f"card.tf_rel_tol: expected a number in [0, 1) (or NaN: not measured), got "
                                     f"{tf_rel_tol!r}"[:300])
            training = card.get("training")
            if training is not None and not isinstance(training, dict):
                raise ModelFileError(f"card.training: expected a JSON object, got {training!r}"[:300])
            return cls(d["X"], d["singular"], d["T"], d["T_eig"], d["U"], d["S"], k=k, vote=vote,
                       n_sequences=n_sequences, tf_rel_tol=tf_rel_tol, domain=checked_domain(card.get("domain")),
                       training=training, name=card_text(card, "name", "singular table"))
        except (KeyError, ValueError, TypeError) as e:
            raise ModelFileError(f"model: {path} is not a usable singular table ({e})") from None

    def save(self, path):
        card = {"format": SINGULAR_FORMAT, "format_version": SINGULAR_FORMAT_VERSION, "k": self.k, "vote": self.vote,
                "n_sequences": self.n_sequences, "tf_rel_tol": self.tf_rel_tol, "domain": self.domain,
                "training": self.training, "name": self.name}
        np.savez_compressed(path, X=self.X.astype(np.float32), singular=self.singular, T=self.T, T_eig=self.T_eig,
                            U=self.U.astype(np.int8), S=self.S.astype(np.float32), card=np.array(json.dumps(card)))

    def covers(self, problem):
        return table_coverage(SlewProblem.from_dict(problem), unsupported_reason)

    def query(self, problem):
        """``(share, sequences)``: the share of singular problems among the ``k`` nearest tabled
        ones, and the ``n_sequences`` nearest singular answers' sequences mapped to
        ``problem``: ``(u_first, switch_times, tf)`` in its units, ``tf`` rescaled by the ratio
        of eigenaxis times (``ValueError`` if the table does not cover ``problem``)."""
        problem = SlewProblem.from_dict(problem)
        why = self.covers(problem)
        if why:
            raise ValueError(f"problem not covered by {self.name}: {why}")
        cf = canonical_form(problem)
        x = cf.x / self.scale
        _, idx = self.tree.query(x, k=min(self.k, self.X.shape[0]))
        share = float(np.mean(self.singular[np.atleast_1d(idx)]))
        _, sidx = self.tree_singular.query(x, k=min(self.n_sequences, self.T.shape[0]))
        out = []
        for j in np.atleast_1d(sidx):
            _, tf, sw, uf = tabled_solution(problem, cf, self.T[j], self.T_eig[j], self.S[j], self.U[j], np.zeros(6))
            out.append((uf, sw, tf))
        return share, out
