"""Gymnasium's ``check_env`` on the observing wrappers ``ConeShield`` and ``CaptureHandover``.

``check_env`` re-creates a wrapped environment from ``env.spec`` (its close check, its render
check); a wrapper that does not record its constructor's arguments
(``gymnasium.utils.RecordConstructorArgs``) made it raise ``ValueError: ConeShield wrapper does
not inherit from gymnasium.utils.RecordConstructorArgs``.
"""
import gymnasium as gym
import pytest

import slew_env  # noqa: F401  (registers Slew-v0)
from slew_env import ENV_ID
from slew_env.shield import ConeShield

SHIELD = {"margin_deg": 0.7, "barrier_rate": 15.0, "brake": 0.5, "sweeps": 12, "gap_deg": 0.8}
CAPTURE = {"deg": 5.0, "kp": 4.0, "damping": 0.9, "law": "braking", "brake": 0.8, "aim_deg": 0.5}


@pytest.fixture
def headless(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")  # check_env opens a "human" window


def _shielded():
    return ConeShield(gym.make(ENV_ID, task_distribution="pointing-cones"), **SHIELD)


def _captured():
    from training.rl.capture import CaptureHandover
    return CaptureHandover(_shielded(), **CAPTURE)


@pytest.mark.parametrize("make", [_shielded, _captured], ids=["ConeShield", "CaptureHandover(ConeShield)"])
def test_gymnasium_check_env_passes_on_the_wrappers(make, headless):
    from gymnasium.utils.env_checker import check_env

    env = make()
    check_env(env)       # raised ValueError (the wrapper cannot be recreated) before
    env.close()


def test_spec_records_the_wrapper_arguments_and_remakes_the_same_wrappers():
    env = _captured()
    names = [w.name for w in env.spec.additional_wrappers]
    assert names[-2:] == ["ConeShield", "CaptureHandover"]
    assert env.spec.additional_wrappers[-2].kwargs == SHIELD
    assert env.spec.additional_wrappers[-1].kwargs == CAPTURE
    again = env.spec.make()
    assert type(again).__name__ == "CaptureHandover" and type(again.env).__name__ == "ConeShield"
    assert again.env.filter.config() == env.env.filter.config() == SHIELD
    assert (again.deg, again.kp, again.damping, again.law, again.brake, again.aim_deg) == tuple(CAPTURE.values())
    assert again.unwrapped.task_distribution.name == "pointing-cones"
    env.close()
    again.close()
