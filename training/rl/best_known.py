"""The best verified answer known for each held-out problem, from several solver runs.

``slew evaluate-rl`` measures ``tf_policy / tf_optimal`` against a solutions file. A
single solve route can miss the fastest extremal of a cone problem (on the 200 held-out
``pointing-cones`` problems, ``solvers.solve`` without a warm start answered 7 more than
1 % slower than the best of three runs then), so the shipped cone policy is measured against
the fastest verified answer of several runs::

    python -m training.rl.best_known OUT.jsonl RUN1.jsonl RUN2.jsonl ...

Every input is a ``slew generate`` file of the same problems (same family and seed);
only records with ``success`` count; the first file's header is kept.
"""
from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path


def merge(out, files) -> dict:
    """Write ``out`` with the fastest verified record per problem index; returns counts per input file."""
    if not files:
        raise ValueError("best_known: give at least one solutions file")
    meta = None
    best, origin = {}, {}
    for f in files:
        with open(f) as fh:
            for line in fh:
                line = line.strip()
                if not line:
                    continue
                try:
                    r = json.loads(line)
                except json.JSONDecodeError:
                    continue            # a line cut by a kill: the generator skips it too
                if "_meta" in r:
                    if meta is None:
                        meta = r
                    elif (r["_meta"].get("family"), r["_meta"].get("seed")) != \
                            (meta["_meta"].get("family"), meta["_meta"].get("seed")):
                        raise ValueError(f"{f}: family/seed {r['_meta'].get('family')}/{r['_meta'].get('seed')} "
                                         f"differ from the first file's")
                    continue
                i = r.get("index")
                if i is None or not r.get("success"):
                    continue
                if i not in best or float(r["tf"]) < float(best[i]["tf"]):
                    best[i], origin[i] = r, str(f)
    if meta is None:
        raise ValueError("best_known: no slew generate header in the inputs")
    with open(out, "w") as g:
        g.write(json.dumps(meta) + "\n")
        for i in sorted(best):
            g.write(json.dumps(best[i]) + "\n")
    return {"problems": len(best), "from": dict(Counter(origin.values()))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m training.rl.best_known", description=__doc__.split("\n")[0])
    p.add_argument("out", type=Path)
    p.add_argument("files", nargs="+", type=Path)
    a = p.parse_args(argv)
    print(json.dumps(merge(a.out, a.files)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
