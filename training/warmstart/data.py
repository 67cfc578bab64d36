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

import json
import math
import os

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


# --------------------------------------------------------------------------- the config's domain
# A model's card claims the config's ``domain`` (what WarmStartModel.covers and
# ConeWarmStartModel.covers accept); the data must be drawn from that domain, all of it: data from
# outside give a model that refuses its own training problems, data from a part of it a model
# that claims problems it never saw.
_TOL = 1e-9


def _norm_text(p) -> str:
    """``torque_norm`` as ``covers`` compares it: ``"inf"`` or ``repr(float)``."""
    return "inf" if str(p) == "inf" or math.isinf(float(p)) else repr(float(p))


def data_span(dist: dict) -> dict:
    """What the problems of a ``TaskDistribution`` (a file's ``meta["distribution"]``) span, in
    the terms of a model's ``domain``; fields the distribution does not state are left out."""
    span = {}
    if "torque_norm" in dist:
        span["torque_norm"] = _norm_text(dist["torque_norm"])
    if "pointing_prob" in dist:
        p = float(dist["pointing_prob"])
        span["target"] = "full-attitude" if p == 0.0 else "pointing" if p == 1.0 else f"mixed ({p:g} pointing)"
    if "angle_deg" in dist:
        span["angle_deg"] = tuple(float(a) for a in dist["angle_deg"])
    mode = dist.get("inertia_mode")
    if mode == "asymmetric" and "inertia_ratio" in dist:
        lo, hi = (float(a) for a in dist["inertia_ratio"])
        span["inertia_ratio"] = lo / hi           # the smallest J_min/J_max it can draw
    elif mode == "fixed" and "inertia" in dist:
        J = np.atleast_1d(np.asarray(dist["inertia"], float))
        span["inertia_ratio"] = float(J.min() / J.max())
    elif mode == "symmetric":
        span["inertia_ratio"] = 1.0
    if "torque_max" in dist:
        u = np.atleast_1d(np.asarray(dist["torque_max"], float))
        span["torque_ratio"] = float(u.min() / u.max())
    if "n_cones" in dist:
        span["n_cones"] = tuple(int(n) for n in dist["n_cones"])
        if span["n_cones"][1] > 0 and "cone_half_angle_deg" in dist:
            span["cone_half_angle_deg"] = tuple(float(a) for a in dist["cone_half_angle_deg"])
    return span


def _outside(span, domain) -> list:
    """``(field, what)`` for each part of ``span`` outside ``domain``."""
    bad = []

    def interval(field, data_key=None):
        v = span.get(data_key or field)
        if field in domain and v is not None:
            lo, hi = (float(a) for a in domain[field])
            if v[0] < lo - _TOL or v[1] > hi + _TOL:
                bad.append((field, f"the data's [{v[0]:g}, {v[1]:g}] is outside the domain's [{lo:g}, {hi:g}]"))
    if "torque_norm" in domain and "torque_norm" in span and str(domain["torque_norm"]) != span["torque_norm"]:
        bad.append(("torque_norm", f"the data's {span['torque_norm']}, the domain's {domain['torque_norm']}"))
    if "target" in domain and "target" in span and span["target"] != domain["target"]:
        bad.append(("target", f"the data's targets are {span['target']}, the domain's {domain['target']}"))
    if domain.get("cones") is False and span.get("n_cones", (0, 0)) != (0, 0):
        bad.append(("cones", f"the data have {span['n_cones'][0]}–{span['n_cones'][1]} cones, the domain none"))
    interval("angle_deg")
    interval("n_cones")
    interval("cone_half_angle_deg")
    if "inertia_ratio" in domain and "inertia_ratio" in span:
        lo = float(domain["inertia_ratio"][0])
        if span["inertia_ratio"] < lo - _TOL:
            bad.append(("inertia_ratio", f"the data's J_min/J_max reaches {span['inertia_ratio']:.3g}, "
                                         f"below the domain's {lo:g}"))
    if "torque_ratio_min" in domain and "torque_ratio" in span:
        lo = float(domain["torque_ratio_min"])
        if span["torque_ratio"] < lo - _TOL:
            bad.append(("torque_ratio_min", f"the data's u_min/u_max is {span['torque_ratio']:.3g}, "
                                            f"below the domain's {lo:g}"))
    return bad


def _uncovered(spans, domain) -> list:
    """``(field, what)`` for each part of ``domain`` that none of ``spans`` (one a file) reaches."""
    bad = []
    for field in ("angle_deg", "n_cones", "cone_half_angle_deg"):
        have = sorted(s[field] for s in spans if field in s)
        if field not in domain or not have or len(have) < len(spans):
            continue
        lo, hi = (float(a) for a in domain[field])
        step = 1 if field == "n_cones" else 0      # cone counts: [1, 1] and [2, 3] cover [1, 3]
        reach = lo - step
        for a, b in have:
            if a > reach + step + _TOL:
                break
            reach = max(reach, b)
        if reach < hi - _TOL:
            bad.append((field, f"the domain's [{lo:g}, {hi:g}], the data reach only "
                               f"{', '.join(f'[{a:g}, {b:g}]' for a, b in have)}"))
    for field, key in (("inertia_ratio", "inertia_ratio"), ("torque_ratio_min", "torque_ratio")):
        have = [s[key] for s in spans if key in s]
        if field not in domain or not have or len(have) < len(spans):
            continue
        lo = float(domain[field][0] if field == "inertia_ratio" else domain[field])
        if min(have) > lo + _TOL:
            bad.append((field, f"the domain reaches {lo:g}, the data only {min(have):.3g}"))
    return bad


def data_meta(path) -> dict:
    """The metadata of a ``--data`` file: a dataset file's first line, or what a solution table
    (``NAME.nn.npz``, ``table_data``) records."""
    from .table_data import is_table, table_meta
    return table_meta(path) if is_table(path) else ds.read_meta(path)


def check_domain(paths, domain: dict) -> None:
    """Refuse data that do not match the config's ``domain`` (see above): a ``ValueError``
    naming the file and the field, or, for a part of the domain no file reaches, the field.
    A solution table states no distribution: nothing is checked of it."""
    if not domain:
        return
    spans = []
    for path in paths:
        span = data_span(data_meta(path).get("distribution") or {})
        bad = _outside(span, domain)
        if bad:
            field, what = bad[0]
            raise ValueError(f"--data: {path}: {field}: {what} (the config's domain, which the model will "
                             f"claim to cover); give data of that domain, or a config whose domain is the data's")
        spans.append(span)
    bad = _uncovered(spans, domain)
    if bad:
        field, what = bad[0]
        raise ValueError(f"--data: {field}: {what}: the model would claim problems it never saw; give data "
                         f"that cover the config's domain, or narrow the domain")


def check_distinct(paths) -> None:
    """Refuse two data files that hold the same problems: the same file twice, or two files of
    one family, seed and distribution (problem ``index`` is drawn from exactly these, so their
    records pair up index by index). The split would put one copy of a problem in training and
    the other in validation, and the validation metrics would flatter the model. One solution
    table (``table_data``) at most; a dataset file given beside it must not hold its solutions
    (``table_data.check_not_in_table``, when the arrays are built)."""
    from .table_data import is_table
    tables = [p for p in paths if is_table(p)]
    if len(tables) > 1:
        raise ValueError(f"--data: one solution table at most ({tables[0]}, {tables[1]}): tables record no seeds, so "
                         f"two could hold the same solutions unseen; give the dataset files instead")
    seen = {}
    for path in paths:
        try:
            meta = data_meta(path)
        except ValueError as e:      # the first look at --data's files: name the option
            msg = str(e)
            raise ValueError(msg if msg.startswith("--data") else f"--data: {msg}") from None
        key = json.dumps([meta.get("family"), meta.get("seed"), meta.get("distribution")], sort_keys=True)
        if key in seen:
            same = "is given twice" if os.path.realpath(seen[key]) == os.path.realpath(path) else \
                f"and {path} hold the same problems (family {meta.get('family')}, seed {meta.get('seed')}, " \
                f"one distribution)"
            raise ValueError(f"--data: {seen[key]} {same}: their rows would be in both the training and the "
                             f"validation split; give each once")
        seen[key] = path


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
