"""Build the singular table (``solvers.warmstart.singular_table``) from generated datasets.

    python -m training.warmstart.singular_table --data FILE.jsonl [FILE.jsonl ...] \
        --out solvers/warmstart/models/full-attitude-singular.npz --tf-rel-tol 5e-4 \
        [--k 5] [--vote 0.6] [--n-sequences 3]

Every verified record of the full-attitude family becomes a row: an exact extremal
(``training.warmstart.data.is_exact``, as for the network's training data) as a
bang-bang problem, a switch-time answer (``method == "switch-time"``, the problems with a
singular arc) as a singular one, with its switching sequence in canonical axes. Collocation
answers (no exactly feasible bang-bang answer was found) and failures are left out. The data
must come from a route that gives switch-time answers, ``solve()``'s ``auto`` (for instance
``slew generate --solve-fn training.generate:solve_warm --solve-options '{"fallback": true,
"singular_table": false}'``: with the table off, so that the answers come from collocation's
sequences, not from an earlier table's); a file of the warm route alone has no singular answers.
``--tf-rel-tol`` is the ``tf_tol`` (relative) the table's answers report: measure it on held-out
problems against the collocation route (``singular_table=False``).
"""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from solvers.warmstart.features import canonical_form, solution_to_canonical
from solvers.warmstart.singular_table import SingularTable
from .. import dataset as ds
from .data import is_exact


def table_rows(paths):
    """``(X, singular, T, T_eig, U, sequences, counts)`` from the dataset files ``paths``."""
    if isinstance(paths, (str, bytes)) or hasattr(paths, "__fspath__"):
        paths = [paths]
    X, singular, T, T_eig, U, seqs = [], [], [], [], [], []
    counts = {"records": 0, "exact": 0, "singular": 0, "left_out": 0}
    for path in paths:
        meta, recs = ds.read(path)
        if meta.get("family") != "full-attitude":
            raise ValueError(f"{path}: family {meta.get('family')!r}, expected 'full-attitude'")
        for r in sorted(recs, key=lambda r: r["index"]):
            counts["records"] += 1
            if r.get("success") is not True or r.get("switch_times") is None or r.get("u_first") is None:
                counts["left_out"] += 1
                continue
            if is_exact(r):
                is_singular = False
            elif r.get("method") == "switch-time":
                is_singular = True
            else:
                counts["left_out"] += 1
                continue
            cf = canonical_form(r["problem"])
            X.append(cf.x)
            singular.append(is_singular)
            if is_singular:
                counts["singular"] += 1
                # (the costates are not kept: a unit vector stands in for the mapping)
                _, Tn, sw, uf = solution_to_canonical(r["problem"], cf, np.r_[np.zeros(4), 1.0, 0.0, 0.0], r["tf"],
                                                      r["switch_times"], r["u_first"])
                T.append(Tn)
                T_eig.append(cf.T_eig)
                U.append(np.where(uf >= 0, 1.0, -1.0))
                seqs.append([np.sort(np.asarray(a, float)) for a in sw])
            else:
                counts["exact"] += 1
    return X, singular, T, T_eig, U, seqs, counts


def build(paths, k=5, vote=0.6, n_sequences=3, tf_rel_tol=math.nan) -> SingularTable:
    X, singular, T, T_eig, U, seqs, counts = table_rows(paths)
    if not any(singular):
        raise ValueError("data: no switch-time (singular) records; generate them with auto (see the module docstring)")
    K = max(len(a) for s in seqs for a in s)
    S = np.full((len(seqs), 3, max(K, 1)), np.nan)
    for j, s in enumerate(seqs):
        for i in range(3):
            S[j, i, :len(s[i])] = s[i]
    training = dict(counts, files=[str(p) for p in paths], max_switches=int(K))
    domain = {"family": "full-attitude", "torque_norm": "inf", "rest_to_rest": True, "rate_max": None}
    return SingularTable(np.array(X), np.array(singular), np.array(T), np.array(T_eig), np.array(U), S, k=k,
                         vote=vote, n_sequences=n_sequences, tf_rel_tol=tf_rel_tol, domain=domain, training=training)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m training.warmstart.singular_table", description=__doc__.split("\n")[0])
    ap.add_argument("--data", nargs="+", required=True, metavar="FILE.jsonl")
    ap.add_argument("--out", required=True, metavar="FILE.npz")
    ap.add_argument("--k", type=int, default=5, help="neighbours of the singular vote (default 5)")
    ap.add_argument("--vote", type=float, default=0.6,
                    help="share of singular neighbours that sends a problem to the table route (default 0.6)")
    ap.add_argument("--n-sequences", type=int, default=3, help="nearest singular sequences tried (default 3)")
    ap.add_argument("--tf-rel-tol", type=float, required=True,
                    help="relative tf_tol the table route reports (measured on held-out problems)")
    a = ap.parse_args(argv)
    for name in ("k", "n_sequences"):
        if getattr(a, name) < 1:
            ap.error(f"--{name.replace('_', '-')}: must be at least 1")
    if not 0.0 < a.vote <= 1.0:
        ap.error("--vote: must be in (0, 1]")
    if not (a.tf_rel_tol > 0.0 and math.isfinite(a.tf_rel_tol)):
        ap.error("--tf-rel-tol: must be a positive number")
    try:
        t = build(a.data, a.k, a.vote, a.n_sequences, a.tf_rel_tol)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    t.save(a.out)
    tr = t.training
    print(f"{a.out}: {tr['exact']} bang-bang and {tr['singular']} singular problems "
          f"({tr['left_out']} of {tr['records']} records left out); up to {tr['max_switches']} switches an axis")
    return 0


if __name__ == "__main__":
    sys.exit(main())
