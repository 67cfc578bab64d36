"""The ``slew`` command line.

Each subcommand lives in its own module and is imported only when it runs, so
``slew --help`` stays fast and never imports torch.
"""
from __future__ import annotations

import argparse
import importlib
import sys

# name -> (module, help). Each module provides ``add_arguments(parser)`` and ``run(args) -> int``.
SUBCOMMANDS = {
    "check": ("training.cli_check", "validate a problem JSON file and describe it"),
    "generate": ("training.cli_generate", "generate a dataset of solved slews from a task family (resumable)"),
    "env-demo": ("training.cli_env_demo", "run a random policy on Slew-v0 and save a rendered frame"),
    "solve": ("training.cli_solve", "solve a slew (time-optimal, verified) from a problem JSON or a JSONL batch"),
    "train": ("training.cli_train", "train the warm-start network on generated data and export it (numpy)"),
    "evaluate": ("training.cli_evaluate", "evaluate a warm-start model against classical guesses on held-out slews"),
    "train-rl": ("training.cli_train_rl", "train PPO or SAC on Slew-v0 from a YAML config (resumable)"),
    "evaluate-rl": ("training.cli_evaluate_rl", "evaluate a trained policy on held-out slews against the optimum"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="slew", description="Time-optimal spacecraft slews: environment, solvers, learned warm starts.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        importlib.import_module(module).add_arguments(p)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 0
    module = importlib.import_module(args._module)
    try:
        return int(module.run(args) or 0)
    except ValueError as e:  # bad input: one clear line, no traceback
        print(f"slew {args.command}: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:     # a file that cannot be read or written: one line too
        print(f"slew {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
