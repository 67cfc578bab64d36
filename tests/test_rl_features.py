"""HighGainFeatures: the policy input with saturated high-gain copies of the error vector and rates."""
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
import torch as th  # noqa: E402

from slew_env import SlewEnv  # noqa: E402
from slew_env.core import env_kernels as K  # noqa: E402
from training.rl.features import DEFAULT_INDICES, HighGainFeatures  # noqa: E402
from training.rl.train import policy_kwargs_from  # noqa: E402


def test_features_are_the_observation_then_saturated_copies():
    env = SlewEnv(task_distribution="pointing-cones")
    fx = HighGainFeatures(env.observation_space, gains=(10.0, 100.0))
    assert fx.features_dim == K.obs_length(4) + 2 * 6
    assert DEFAULT_INDICES == (1, 2, 3, 4, 5, 6)
    x = th.zeros((2, K.obs_length(4)))
    x[0, K.OB_W] = 0.03          # a slow roll about the sensor axis: both copies resolve it
    x[1, K.OB_W] = -0.03
    f = fx(x)
    assert th.equal(f[:, :K.obs_length(4)], x)
    n = K.obs_length(4)
    assert f[0, n + 3].item() == pytest.approx(np.tanh(0.3), rel=1e-6)       # gain 10, rate index 4
    assert f[0, n + 6 + 3].item() == pytest.approx(np.tanh(3.0), rel=1e-6)   # gain 100
    assert f[1, n + 6 + 3].item() == pytest.approx(-np.tanh(3.0), rel=1e-6)


def test_config_names_the_extractor_and_bad_values_name_the_field():
    kw = policy_kwargs_from({"policy_kwargs": {"features_extractor_class": "high_gain"}})
    assert kw["features_extractor_class"] is HighGainFeatures
    with pytest.raises(ValueError, match="features_extractor_class"):
        policy_kwargs_from({"policy_kwargs": {"features_extractor_class": "nope"}})
    env = SlewEnv()
    with pytest.raises(ValueError, match="gains"):
        HighGainFeatures(env.observation_space, gains=(0.0,))
    with pytest.raises(ValueError, match="indices"):
        HighGainFeatures(env.observation_space, indices=(99,))
