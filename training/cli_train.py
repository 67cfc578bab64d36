"""``slew train``: train the warm-start network on dataset files and export it for numpy inference."""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys

from .interrupts import interrupt_deferred


def add_arguments(p):
    p.add_argument("--data", nargs="+", required=True, metavar="FILE.jsonl",
                   help="dataset files from 'slew generate' (exact solutions are used), or one pointing-cones "
                        "solution table NAME.nn.npz that 'slew train --export' wrote (its exact solutions)")
    p.add_argument("--config", default=None, help="YAML config (default: training/warmstart/configs/full-attitude.yaml)")
    p.add_argument("--out", "-o", default="runs/warmstart", help="run directory (default runs/warmstart)")
    p.add_argument("--seed", type=int, default=0, help="seed of the split, the initialisation and the shuffles")
    p.add_argument("--epochs", type=int, default=None, help="override the config's epochs")
    p.add_argument("--resume", action="store_true",
                   help="continue from the last checkpoint of this run in --out (same config, epochs, seed and data)")
    p.add_argument("--export", default=None, metavar="MODEL.npz",
                   help="also write the exported model here (e.g. solvers/warmstart/models/full-attitude.npz)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args) -> int:
    from training.warmstart.train import train
    # options first: a bad one found after the data load and the training wastes minutes
    if args.epochs is not None and args.epochs < 1:
        raise ValueError(f"--epochs: must be ≥ 1, got {args.epochs}")
    for path in args.data:
        if not os.path.exists(path):
            raise FileNotFoundError(f"--data: no such file: {path}")
    if args.config and not os.path.isfile(args.config):
        raise FileNotFoundError(f"--config: no such file: {args.config}")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ValueError(f"--out: {args.out!r} exists and is not a directory")
    if args.export:
        check_export(args.export)
    stage = "before the training started: the checkpoints in --out are as they were"
    try:
        s = train(args.data, args.out, config=args.config, seed=args.seed, epochs=args.epochs, resume=args.resume,
                  progress_bar=not args.no_progress)
        if args.export:
            stage = f"while exporting: the files at --export {args.export} are as they were"
            publish(export_copies(s, args.export))
    except KeyboardInterrupt as e:
        # Ctrl-C: one line saying what was kept, no traceback, 130 as for slew generate
        from training.warmstart.train import TrainingInterrupted
        print(f"slew train: interrupted {e.args[0] if isinstance(e, TrainingInterrupted) else stage}",
              file=sys.stderr)
        return 130
    print(json.dumps({k: s[k] for k in ("n_exact_solutions", "n_train", "n_val", "epochs", "train_wall_time_s", "model")}))
    print("validation:", json.dumps(s["val_metrics"]))
    return 0


def check_export(path):
    """``--export``'s directory exists (made if missing, as ``slew generate`` makes its output's)
    and can be written to, before the training rather than after it."""
    if os.path.isdir(path):
        raise ValueError(f"--export: {path!r} is a directory; give the model's file name (MODEL.npz)")
    d = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(d, exist_ok=True)
    except OSError as e:
        raise ValueError(f"--export: cannot create the directory {d!r}: {e.strerror or e}") from None
    if not os.access(d, os.W_OK):
        raise ValueError(f"--export: the directory {d!r} is not writable")


def export_copies(summary, export_path):
    """``(source, target)`` of the files an export writes: the network, its card, its table."""
    from training.warmstart.train import table_path
    pairs = [(os.path.splitext(summary["model"])[0] + ".md", os.path.splitext(export_path)[0] + ".md")]
    if summary.get("table"):
        pairs.append((summary["table"], table_path(export_path)))
    return pairs + [(summary["model"], export_path)]


def publish(pairs):
    """Copy each ``(source, target)``: all to temporary names in the targets' directories first,
    then renamed over the targets with Ctrl-C held back, so that an interrupted export leaves
    the old files or the new ones, never a new network next to an old table or card (the
    shipped models are exported this way)."""
    tmps = []
    try:
        for src, dst in pairs:
            tmp = os.path.join(os.path.dirname(os.path.abspath(dst)), f".{os.path.basename(dst)}.{os.getpid()}.tmp")
            tmps.append(tmp)
            shutil.copyfile(src, tmp)
        with interrupt_deferred():
            for tmp, (_, dst) in zip(tmps, pairs):
                os.replace(tmp, dst)
    finally:
        for tmp in tmps:
            with contextlib.suppress(FileNotFoundError):
                os.remove(tmp)


