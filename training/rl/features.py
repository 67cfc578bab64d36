"""Policy input features for Slew-v0 (stable-baselines3 features extractors).

``HighGainFeatures`` passes the (normalised) observation through and appends
``tanh(g · x_i)`` of the error-rotation vector and the body rates for a few gains
``g``. Near the target a time-optimal policy is a high-gain law: a roll rate of
0.03 (nondimensional), which the success test refuses (tolerance 0.02), must map
to a torque of about −0.6, while rest maps to 0. After observation normalisation
those two inputs differ by under 0.1, and a tanh network fitted to the whole
flight smooths the step away: the cloned cone policies came to the target and
kept spinning slowly about the sensor axis with zero torque. The saturated
high-gain copies give the network that step as an input.
"""
from __future__ import annotations

import gymnasium as gym
import torch as th
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

from slew_env.core import env_kernels as _k

# error-rotation vector (quaternion vector part) and body rates
DEFAULT_INDICES = tuple(range(_k.OB_DQ + 1, _k.OB_DQ + 4)) + tuple(range(_k.OB_W, _k.OB_W + 3))


class HighGainFeatures(BaseFeaturesExtractor):
    """``[x, tanh(g₁ x_I), tanh(g₂ x_I), …]`` for the indices ``I`` (default: error vector, rates)."""

    def __init__(self, observation_space: gym.spaces.Box, gains=(10.0, 100.0), indices=DEFAULT_INDICES):
        gains = [float(g) for g in gains]
        indices = [int(i) for i in indices]
        n = int(observation_space.shape[0])
        if not gains or any(not g > 0 for g in gains):
            raise ValueError(f"policy_kwargs.features_extractor_kwargs.gains: positive numbers expected, got {gains}")
        if not indices or any(not 0 <= i < n for i in indices):
            raise ValueError(f"policy_kwargs.features_extractor_kwargs.indices: each in [0, {n}), got {indices}")
        super().__init__(observation_space, features_dim=n + len(gains) * len(indices))
        self.register_buffer("_gains", th.tensor(gains, dtype=th.float32).repeat_interleave(len(indices)))
        self._idx = indices
        self._reps = len(gains)

    def forward(self, obs):
        sel = obs[:, self._idx].repeat(1, self._reps)
        return th.cat([obs, th.tanh(sel * self._gains)], dim=1)


EXTRACTORS = {"high_gain": HighGainFeatures}
