"""``slew train``: train the warm-start network on dataset files and export it for numpy inference."""
from __future__ import annotations

import json
import os


def add_arguments(p):
    p.add_argument("--data", nargs="+", required=True, metavar="FILE.jsonl",
                   help="dataset files from 'slew generate' (exact solutions are used)")
    p.add_argument("--config", default=None, help="YAML config (default: training/warmstart/configs/full-attitude.yaml)")
    p.add_argument("--out", "-o", default="runs/warmstart", help="run directory (default runs/warmstart)")
    p.add_argument("--seed", type=int, default=0, help="seed of the split, the initialisation and the shuffles")
    p.add_argument("--epochs", type=int, default=None, help="override the config's epochs")
    p.add_argument("--resume", action="store_true", help="continue from the last checkpoint in --out")
    p.add_argument("--export", default=None, metavar="MODEL.npz",
                   help="also write the exported model here (e.g. solvers/warmstart/models/full-attitude.npz)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args) -> int:
    from training.warmstart.train import train
    for path in args.data:
        if not os.path.exists(path):
            raise FileNotFoundError(f"--data: no such file: {path}")
    s = train(args.data, args.out, config=args.config, seed=args.seed, epochs=args.epochs, resume=args.resume,
              progress_bar=not args.no_progress)
    if args.export:
        import shutil
        shutil.copyfile(s["model"], args.export)
        shutil.copyfile(os.path.splitext(s["model"])[0] + ".md", os.path.splitext(args.export)[0] + ".md")
        if s.get("table"):
            from training.warmstart.train import table_path
            shutil.copyfile(s["table"], table_path(args.export))
    print(json.dumps({k: s[k] for k in ("n_exact_solutions", "n_train", "n_val", "epochs", "train_wall_time_s", "model")}))
    print("validation:", json.dumps(s["val_metrics"]))
    return 0
