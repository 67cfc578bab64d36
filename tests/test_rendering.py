"""Rendering (rgb_array / human) and the env-demo command."""

import gymnasium as gym
import numpy as np
import pytest

import slew_env  # noqa: F401 (registers the environment)
from slew_env import SlewEnv, SlewVectorEnv
from slew_env.rendering import HEIGHT, WIDTH, cone_circle


@pytest.fixture
def headless(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")


def test_rgb_array_frame():
    env = gym.make("slew_env/Slew-v0", task_distribution="pointing-cones", render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    for _ in range(15):
        env.step(env.action_space.sample())
    frame = env.render()
    assert frame.shape == (HEIGHT, WIDTH, 3) and frame.dtype == np.uint8
    assert frame.std() > 10  # an actual picture, not a blank canvas
    assert not np.array_equal(first, frame)  # the histories and the path grew
    env.close()


def test_render_without_mode_warns_and_returns_none():
    env = SlewEnv()
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.render() is None


def test_human_mode_runs_headless(headless):
    env = SlewEnv(render_mode="human")
    env.reset(seed=0)
    env.step(np.zeros(3))
    assert env.render() is None
    env.close()


def test_cone_circle_lies_at_half_angle():
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    pts = cone_circle(axis, 0.3)
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.arccos(np.clip(pts @ axis, -1, 1)), 0.3, atol=1e-9)


def test_vector_env_frames():
    vec = SlewVectorEnv(num_envs=2, task_distribution="pointing-cones", render_mode="rgb_array")
    vec.reset(seed=0)
    frames = vec.render()
    assert len(frames) == 2 and all(f.shape == (HEIGHT, WIDTH, 3) for f in frames)


def test_env_demo_command(tmp_path, capsys):
    from training.cli import main

    out = tmp_path / "frame.png"
    assert main(["env-demo", "--steps", "20", "--seed", "1", "--out", str(out)]) == 0
    import matplotlib.image as mpimg
    img = mpimg.imread(out)
    assert img.shape[:2] == (HEIGHT, WIDTH)
    assert "saved to" in capsys.readouterr().out
    assert main(["env-demo", "--steps", "0"]) == 2
