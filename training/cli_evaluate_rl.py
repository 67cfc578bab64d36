"""``slew evaluate-rl``: a trained policy on held-out slews against the time-optimal solutions
(``training.rl.evaluate``, ``docs/RL.md``).

::

    slew evaluate-rl POLICY_DIR [--family NAME] [--n 200] [--seed S] [--out REPORT_DIR] [--plot-k 3]
"""


def add_arguments(p):
    from training.rl.evaluate import add_arguments as add
    add(p)


def run(args):
    from training.rl.evaluate import run as run_
    return run_(args)
