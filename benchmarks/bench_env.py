"""Step throughput of Slew-v0 beside Pendulum-v1, and of the batched vector env.

    python benchmarks/bench_env.py [--seconds 0.5] [--repeats 3]

Goals: one Slew-v0 step costs at most 2x a Pendulum-v1 step; the batched env
reaches 1e6 env-steps/s at 1024 copies. Each figure is the best of
``--repeats`` timed runs of about ``--seconds`` each, after a warm-up that
loads the compiled kernels from numba's cache (the first run compiles them).
"""
import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import gymnasium as gym  # noqa: E402
import numba  # noqa: E402
import numpy as np  # noqa: E402

import slew_env  # noqa: E402
from slew_env import SlewVectorEnv  # noqa: E402


def time_single(env, seconds, repeats):
    """Best seconds per step() with a fixed sampled action, resetting on episode end."""
    env.reset(seed=0)
    action = env.action_space.sample()
    best = np.inf
    n = 2000
    for _ in range(repeats + 1):  # the first round is the warm-up
        step = env.step
        t0 = time.perf_counter()
        for _ in range(n):
            _, _, terminated, truncated, _ = step(action)
            if terminated or truncated:
                env.reset()
        dt = (time.perf_counter() - t0) / n
        best = min(best, dt)
        n = max(2000, int(seconds / dt))
    return best


def time_vector(num_envs, seconds, repeats, **kwargs):
    """Best env-steps per second of ``SlewVectorEnv`` with random actions (autoresets included)."""
    env = SlewVectorEnv(num_envs=num_envs, **kwargs)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (num_envs, 3)).astype(np.float32)
    best = np.inf
    n = 20
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        for _ in range(n):
            env.step(actions)
        dt = (time.perf_counter() - t0) / n
        best = min(best, dt)
        n = max(20, int(seconds / dt))
    return num_envs / best, best, env.parallel


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=0.5, help="length of each timed run")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per figure (best is kept)")
    args = ap.parse_args(argv)

    print(f"numpy {np.__version__}, numba {numba.__version__}, gymnasium {gym.__version__}, "
          f"{numba.config.NUMBA_NUM_THREADS} numba threads, {os.cpu_count()} CPUs, "
          f"1-min load average {os.getloadavg()[0]:.2f} before the run")
    print()
    print("single environment step()                   us/step       steps/s")
    rows = {}
    for env_id, kwargs in (("Pendulum-v1", {}), (slew_env.ENV_ID, {}),
                           (slew_env.ENV_ID, {"task_distribution": "pointing-cones"})):
        for how in ("gymnasium.make", ".unwrapped"):
            env = gym.make(env_id, **kwargs)
            target = env if how == "gymnasium.make" else env.unwrapped
            dt = time_single(target, args.seconds, args.repeats)
            env.close()
            label = env_id.split("/")[-1] + (" (pointing-cones)" if kwargs else "")
            rows[(label, how)] = dt
            print(f"  {label:<26s} {how:<15s} {dt * 1e6:7.2f}  {1 / dt:12,.0f}")
    for how in ("gymnasium.make", ".unwrapped"):
        for label in ("Slew-v0", "Slew-v0 (pointing-cones)"):
            ratio = rows[(label, how)] / rows[("Pendulum-v1", how)]
            print(f"  {label} / Pendulum-v1 via {how}: {ratio:.2f}x "
                  f"(goal <= 2x: {'met' if ratio <= 2.0 else 'NOT met'})")

    print()
    print("batched SlewVectorEnv (one compiled call per step, autoreset inside)")
    print("  family           copies  kernel     env-steps/s   us/call")
    at_1024 = None
    for family, parallel in (("full-attitude", False), ("pointing-cones", False),
                             ("full-attitude", True)):
        for n in (1, 64, 1024):
            if parallel and n == 1:
                continue
            rate, per_call, _ = time_vector(n, args.seconds, args.repeats, task_distribution=family,
                                            parallel=parallel)
            if family == "full-attitude" and n == 1024 and not parallel:
                at_1024 = rate
            kernel = "parallel" if parallel else "serial"
            note = "   (opt-in: parallel=True)" if parallel else ""
            print(f"  {family:<16s} {n:6d}  {kernel:<9s} {rate:13,.0f}  {per_call * 1e6:8.1f}{note}")
    print(f"  goal >= 1,000,000 env-steps/s at 1024 copies (default serial kernel): "
          f"{'met' if at_1024 >= 1e6 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
