"""Reinforcement learning on ``slew_env/Slew-v0`` (stable-baselines3), with the optimality gap.

* ``training.rl.train`` — PPO / SAC training from rl-zoo style YAML configs
  (``training/rl/configs/{ppo,sac}.yaml``, one entry per task family), vectorised
  environments, ``VecNormalize`` saved with every checkpoint, ``EvalCallback``,
  ``CheckpointCallback``, TensorBoard, resume (``slew train-rl``).
* ``training.rl.evaluate`` — rolls a trained policy out on held-out tasks and compares
  its final time with the solvers' time-optimal one (``slew evaluate-rl``).
* ``training.rl.bc`` — behaviour cloning of the solvers' optimal controls, as a
  pre-training option and the comparison scratch / cloning alone / cloning then RL.

Documentation: ``docs/RL.md``. Nothing here is imported by ``slew_env`` or ``solvers``.
"""
ALGOS = ("ppo", "sac")
FAMILIES = ("full-attitude", "pointing-cones")     # == slew_env.tasks.FAMILIES
DEFAULT_EVAL_SEED = 100        # held-out tasks of evaluate-rl: family.sample(default_rng([seed, i]))
DEFAULT_BC_SEED = 1            # expert problems of behaviour cloning (same scheme, another seed)
EVAL_ENV_SEED_OFFSET = 10_000  # EvalCallback's environment: seed + this

from pathlib import Path as _Path

# Trained policies shipped with the package (``slew evaluate-rl shipped`` or ``shipped:FAMILY``).
SHIPPED_POLICIES = {"full-attitude": _Path(__file__).resolve().parent / "policies" / "ppo-full-attitude",
                    "pointing-cones": _Path(__file__).resolve().parent / "policies" / "ppo-pointing-cones"}


def resolve_policy(policy) -> _Path:
    """``"shipped"`` / ``"shipped:FAMILY"`` -> the shipped policy's directory; anything else as a path."""
    s = str(policy)
    if s == "shipped" or s.startswith("shipped:"):
        fam = s.partition(":")[2] or "full-attitude"
        if fam not in SHIPPED_POLICIES:
            raise ValueError(f"policy: no shipped policy for family {fam!r}; shipped: {sorted(SHIPPED_POLICIES)}")
        return SHIPPED_POLICIES[fam]
    return _Path(policy)
