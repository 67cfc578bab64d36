"""Dataset records → canonical training arrays for the warm-start network.

Only *exact* successes are used (extremals whose costates and switch times reproduce
the trajectory; ``record["exact"]``, or for older files a record solved by an indirect
route): the approximate collocation answers of (near-)singular problems have costates
known only to the collocation's accuracy and switch times that do not reproduce them.

Arrays (``N`` problems, ``K = max_switches``): ``X`` (N, 11) canonical features; ``Z``
(N, 6) canonical costates; ``T`` (N,) nondimensional final time; ``T_eig`` (N,) eigenaxis
guess time; ``log_T_ratio`` = log(T / T_eig); ``U`` (N, 3) first-arc signs; ``counts`` (N, 3)
switches per canonical axis (solutions with more than K on an axis are left out and counted
in ``n_overflow``); ``S`` (N, 3,
K) nondimensional switch times (NaN-padded); ``F`` = S / T (fractions); ``key`` (N,)
"file:index" strings.
"""
from __future__ import annotations

import math

import numpy as np

from solvers.warmstart.features import canonical_form, solution_to_canonical
from .. import dataset as ds


def is_exact(rec: dict) -> bool:
    if rec.get("success") is not True or rec.get("costate0") is None:
        return False
    if "exact" in rec:
        return bool(rec["exact"])
    return rec.get("method") in ("indirect", "multiple-shooting")


def exact_records(paths, family, counts):
    """``(path, record)`` for the exact records of the dataset files ``paths`` (one path or a
    list), in index order; ``counts["seen"]`` and ``counts["exact"]`` are kept up to date.
    A file of another ``family`` (unless ``None``) is an error."""
    if isinstance(paths, (str, bytes)) or hasattr(paths, "__fspath__"):
        paths = [paths]
    counts.update(seen=0, exact=0)
    for path in paths:
        meta, recs = ds.read(path)
        if family is not None and meta.get("family") != family:
            raise ValueError(f"{path}: family {meta.get('family')!r}, expected {family!r}")
        for r in sorted(recs, key=lambda r: r["index"]):
            counts["seen"] += 1
            if is_exact(r):
                counts["exact"] += 1
                yield path, r


def training_arrays(paths, max_switches: int = 5, family=None) -> dict:
    """Arrays from one or more dataset files (see the module docstring)."""
    rows = []
    n_overflow = 0
    counts = {}
    for path, r in exact_records(paths, family, counts):
        p = r["problem"]
        cf = canonical_form(p)
        if r.get("switch_times") is None or r.get("u_first") is None:
            continue
        z, T, sw, uf = solution_to_canonical(p, cf, r["costate0"], r["tf"], r["switch_times"], r["u_first"])
        if max(len(a) for a in sw) > int(max_switches):
            n_overflow += 1      # a structure the network cannot represent: left out, counted
            continue
        rows.append((cf.x, z, T, cf.T_eig, uf, sw, f"{path}:{r['index']}"))
    K = int(max_switches)
    N = len(rows)
    out = {"X": np.zeros((N, len(rows[0][0]) if N else 11)), "Z": np.zeros((N, 6)), "T": np.zeros(N),
           "T_eig": np.zeros(N), "U": np.zeros((N, 3)), "counts": np.zeros((N, 3), np.int64),
           "overflow": np.zeros(N, bool), "S": np.full((N, 3, K), np.nan), "key": np.array([r[6] for r in rows])}
    for k, (x, z, T, Te, uf, sw, _) in enumerate(rows):
        out["X"][k] = x
        out["Z"][k] = z
        out["T"][k] = T
        out["T_eig"][k] = Te
        out["U"][k] = np.where(uf >= 0, 1.0, -1.0)
        for i in range(3):
            c = len(sw[i])
            out["overflow"][k] |= c > K
            m = min(c, K)
            out["counts"][k, i] = m
            out["S"][k, i, :m] = np.sort(sw[i])[:m]
    out["log_T_ratio"] = np.log(out["T"] / np.maximum(out["T_eig"], 1e-300))
    out["F"] = out["S"] / np.maximum(out["T"], 1e-300)[:, None, None]
    out["n_records"] = counts["seen"]
    out["n_overflow"] = n_overflow
    out["n_exact"] = counts["exact"]
    return out


def nearest_table(paths, max_switches=5, k=3):
    """The exact solutions of ``paths`` as a ``NearestNeighbourModel`` (the nearest-neighbour
    baseline of ``slew evaluate``, and the table shipped with the model)."""
    from solvers.warmstart import NearestNeighbourModel
    a = training_arrays(paths, max_switches)
    return NearestNeighbourModel(a["X"], a["Z"], a["T"], a["T_eig"], a["U"], a["S"], k=k,
                                 name=f"nearest-neighbour (k={k}, {a['X'].shape[0]} solutions)")


def split(arrays: dict, val_fraction: float, seed: int):
    """Train/validation index arrays (seeded permutation)."""
    N = arrays["X"].shape[0]
    rng = np.random.default_rng(seed)
    perm = rng.permutation(N)
    n_val = int(math.floor(val_fraction * N))
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])
