"""A shipped or exported pointing-cones table (``NAME.nn.npz``) as training data for ``slew train``.

``slew train --export`` writes, next to the network, the table of the exact solutions it was
trained on, in canonical form (``solvers.warmstart.cone_nearest``): per solution the features,
the costates, ``T`` and ``T_ref``, the first-arc signs, the switch instants as fractions of
``T`` and per cone slot the touch, its instant and its multiplier. That is everything the
pointing-cones network learns from, so ``slew train --data TABLE.nn.npz`` trains a network on
it without the dataset files (which are large and not shipped): another architecture, or more
heads, on the same solutions; and, with new dataset files beside it, on more solutions. The
table keeps float32 values (the training runs in float32) and states no distribution, so the
config's domain is not checked against it (the dataset files beside it are checked); the card
names the table (and its sha256) as its data, with the data files the table's own card names
(``sources``: tables exported since session 39 record them; the one shipped before, made from
``pointing-cones`` seeds 31-33, does not). A dataset file whose exact solutions are rows of the table is refused
(``check_not_in_table``): the same problems would sit in both the training and the validation
split.
"""
from __future__ import annotations

import os

import numpy as np

TABLE_SUFFIX = ".nn.npz"


def is_table(path) -> bool:
    return os.fspath(path).endswith(TABLE_SUFFIX)


def _read(path):
    from solvers.warmstart.model import ModelFileError, read_table
    from solvers.warmstart.nearest import NN_FORMAT, NN_FORMAT_VERSION
    try:
        return read_table(path, NN_FORMAT, NN_FORMAT_VERSION)
    except ModelFileError as e:
        raise ValueError(f"--data: {path}: not a usable solution table ({e})") from None


def table_meta(path) -> dict:
    """What ``slew train`` knows of a table as a data file: its family (the table's kind), no
    seed or distribution, ``table: True`` and its row count. A damaged table is named here,
    before any training."""
    d, card = _read(path)
    if card.get("kind") != "pointing-cones":
        raise ValueError(f"--data: {path}: a {card.get('kind') or 'full-attitude'} table; training from a table "
                         f"is built for pointing-cones tables (give the full-attitude dataset files)")
    n = _checked(path, d, None)["X"].shape[0]
    return {"family": "pointing-cones", "seed": None, "distribution": None, "table": True,
            "rows": int(n), "name": card.get("name"), "sources": list(card.get("data_files") or [])}


def _checked(path, d, max_switches) -> dict:
    """The table's arrays (float64), their shapes and values checked; ``max_switches``: the
    config's switch slots, which the table's ``F`` must hold (``None``: any number)."""
    from solvers.warmstart.cone_features import MAX_CONES, N_CONE_FEATURES
    from solvers.warmstart.cone_nearest import ARRAYS
    try:
        a = {k: np.asarray(d[k], np.float64) for k in ARRAYS}
    except KeyError as e:
        raise ValueError(f"--data: {path}: the table lacks the array {e}") from None
    except (TypeError, ValueError) as e:
        raise ValueError(f"--data: {path}: an array that is not numbers ({e})") from None
    N = a["X"].shape[0] if a["X"].ndim == 2 else -1
    want = {"X": (N, N_CONE_FEATURES), "Z": (N, 6), "T": (N,), "T_ref": (N,), "U": (N, 3),
            "touch": (N, MAX_CONES), "frac": (N, MAX_CONES), "log_nu": (N, MAX_CONES)}
    for key, shape in want.items():
        if a[key].shape != shape:
            raise ValueError(f"--data: {path}: {key} has shape {a[key].shape}, expected {shape} "
                             f"({max(N, 0)} solutions)")
    if N == 0:
        raise ValueError(f"--data: {path}: the table holds no solutions")
    if a["F"].ndim != 3 or a["F"].shape[:2] != (N, 3):
        raise ValueError(f"--data: {path}: F has shape {a['F'].shape}, expected ({N}, 3, max_switches)")
    if max_switches is not None and a["F"].shape[2] != int(max_switches):
        raise ValueError(f"--data: {path}: the table holds {a['F'].shape[2]} switch slots per axis, the config's "
                         f"max_switches is {int(max_switches)}")
    if not (np.isfinite(a["X"]).all() and np.isfinite(a["Z"]).all() and np.isfinite(a["U"]).all()
            and np.isfinite(a["T"]).all() and np.isfinite(a["T_ref"]).all()
            and (a["T"] > 0).all() and (a["T_ref"] > 0).all()):
        raise ValueError(f"--data: {path}: features, costates, first-arc signs and times must be finite and the "
                         f"times positive")
    return a


def cone_table_arrays(path, max_switches: int) -> dict:
    """The training arrays of ``training.warmstart.cone_data.training_arrays`` from a table."""
    from solvers.warmstart.cone_features import MAX_CONES
    d, _ = _read(path)
    a = _checked(path, d, int(max_switches))
    N = a["X"].shape[0]
    counts = np.isfinite(a["F"]).sum(axis=2).astype(np.int64)
    present = a["X"][:, [9 + 5 * k + 4 for k in range(MAX_CONES)]].copy()
    name = os.path.basename(os.fspath(path))
    out = {"X": a["X"], "Z": a["Z"], "T": a["T"], "T_ref": a["T_ref"], "touch": a["touch"], "frac": a["frac"],
           "log_nu": a["log_nu"], "present": present, "key": np.array([f"{name}:{j}" for j in range(N)]),
           "U": np.where(a["U"] >= 0, 1.0, -1.0), "counts": counts, "F": a["F"]}
    out["log_T_ratio"] = np.log(out["T"] / out["T_ref"])
    out.update(n_records=N, n_exact=N, n_double=0, n_overflow=0)
    return out


def check_not_in_table(arrays, table, path) -> None:
    """Refuse dataset arrays holding problems of ``table`` (a table from ``path``): rows whose
    features, rounded to the table's float32, equal a table row's."""
    have = {row.tobytes() for row in np.asarray(table["X"], np.float32)}
    X = np.asarray(arrays["X"], np.float32)
    dup = [k for k in range(X.shape[0]) if X[k].tobytes() in have]
    if dup:
        files = sorted({str(arrays["key"][k]).rsplit(":", 1)[0] for k in dup})
        raise ValueError(f"--data: {len(dup)} of the exact solutions of {', '.join(files)} are rows of the table "
                         f"{path} already (the same problems): they would be in both the training and the "
                         f"validation split; give files of other seeds beside the table")


ARRAY_KEYS = ("X", "Z", "T", "T_ref", "touch", "frac", "log_nu", "present", "key", "U", "counts", "F", "log_T_ratio")
COUNT_KEYS = ("n_records", "n_exact", "n_double", "n_overflow")


def joined(parts) -> dict:
    """Training arrays of several sources, one after the other."""
    if len(parts) == 1:
        return parts[0]
    out = {k: np.concatenate([p[k] for p in parts]) for k in ARRAY_KEYS}
    out.update({k: int(sum(p[k] for p in parts)) for k in COUNT_KEYS})
    return out
