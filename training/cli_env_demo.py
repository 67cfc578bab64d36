"""``slew env-demo``: run a random policy on Slew-v0 and save a rendered frame."""
import os


def add_arguments(p):
    p.add_argument("--steps", type=int, default=100, help="control steps to run (default 100)")
    p.add_argument("--seed", type=int, default=0, help="seed of the reset and of the actions")
    p.add_argument("--family", default="pointing-cones",
                   help="task distribution family: pointing-cones (default) or full-attitude")
    p.add_argument("--out", default="frame.png", help="PNG file for the last frame (default frame.png)")


def _check_writable(path):
    """Fail before the episode, naming ``--out``, if the frame cannot be written there (a missing
    directory, a directory of that name, a name too long...): the OS error had come only after the
    run, without the option's name. Opening for append changes nothing in a file already there, and
    the empty file made for the test is removed again."""
    existed = os.path.lexists(path)
    try:
        with open(path, "ab"):
            pass
    except OSError as exc:
        raise ValueError(f"--out: cannot write {path}: {exc.strerror or exc}") from None
    if not existed:
        os.remove(path)


def run(args):
    import gymnasium as gym
    import matplotlib.image as mpimg
    import numpy as np

    import slew_env

    if args.steps < 1:
        raise ValueError(f"--steps: must be >= 1, got {args.steps}")
    if args.seed < 0:
        raise ValueError(f"--seed: must be >= 0, got {args.seed}")
    if not args.out.lower().endswith(".png") or os.path.basename(args.out).lower() == ".png":
        # (".png" alone has no suffix to matplotlib, which said only "unknown file extension")
        raise ValueError(f"--out: expected a .png file name, got {args.out!r}")
    _check_writable(args.out)
    try:
        env = gym.make(slew_env.ENV_ID, task_distribution=args.family, render_mode="rgb_array",
                       terminate_on_violation=False)
    except ValueError as exc:
        raise ValueError(f"--family: {exc}") from None
    env.action_space.seed(args.seed)
    _, info = env.reset(seed=args.seed)
    print(repr(env.unwrapped.problem))
    total, steps = 0.0, 0
    for steps in range(1, args.steps + 1):
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
        total += reward
        if terminated or truncated:
            break
    frame = env.render()
    env.close()
    mpimg.imsave(args.out, np.asarray(frame))
    print(f"{steps} steps, return {total:.4f}, time {info['time']:.4g}, "
          f"error {np.degrees(info['attitude_error']):.3f} deg, violation {info['violation']}, "
          f"min cone margin {np.degrees(info['min_cone_margin']):.3f} deg")
    print(f"frame {frame.shape[1]}x{frame.shape[0]} saved to {args.out}")
    return 0
