"""``slew train-rl``: train PPO or SAC on Slew-v0 (``training.rl.train``, ``docs/RL.md``).

::

    slew train-rl --algo ppo|sac --family full-attitude|pointing-cones [--config YAML]
                  [--timesteps N] [--n-envs N] [--seed S] [--out runs/NAME]
                  [--resume CHECKPOINT] [--bc-pretrain N_EPISODES] [--progress-bar]
"""


def add_arguments(p):
    from training.rl.train import add_arguments as add
    add(p)


def run(args):
    from training.rl.train import run as run_
    return run_(args)
