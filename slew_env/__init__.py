"""slew_env: rigid-body slew physics, the problem specification and the Gymnasium environment.

Importing the package registers ``slew_env/Slew-v0`` with Gymnasium (once), so
that ``gymnasium.make`` / ``make_vec`` also work in spawned vector-environment
workers: they import the package again, through the registered entry point
(Gymnasium's async mode) or by re-importing a main script that does
``import slew_env`` at module level (stable-baselines3's ``SubprocVecEnv``).
"""
from .problem import SlewProblem, Cone

__all__ = ["SlewProblem", "Cone", "SlewEnv", "SlewVectorEnv", "TaskDistribution", "ConeShield",
           "ConeShieldFilter", "ConeShieldVector", "ENV_ID"]
__version__ = "0.1.0"

ENV_ID = "slew_env/Slew-v0"
DEFAULT_MAX_EPISODE_STEPS = 400  # TimeLimit of the registered environment

# Heavier modules load on first use (PEP 562), so ``import slew_env`` stays cheap.
_LAZY = {"SlewEnv": ".env", "SlewVectorEnv": ".vector_env", "TaskDistribution": ".tasks",
         "ConeShield": ".shield", "ConeShieldFilter": ".shield",
         "ConeShieldVector": ".shield"}


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _register() -> None:
    import gymnasium

    if ENV_ID in gymnasium.registry:  # idempotent: re-imports and reloads must not re-register
        return
    gymnasium.register(
        id=ENV_ID,
        entry_point="slew_env.env:SlewEnv",
        vector_entry_point="slew_env.vector_env:SlewVectorEnv",
        max_episode_steps=DEFAULT_MAX_EPISODE_STEPS,
    )


_register()
