"""Task sampler and TaskDistribution."""
import math
import re

import numpy as np
import pytest

from slew_env import SlewProblem
from slew_env.core import sampling as S
from slew_env.core import task as T
from slew_env.core.cones import angle_between
from slew_env.tasks import BLOCK, FAMILIES, TaskDistribution, draw_task


def arc_distance(axis, a, b):
    """Smallest angle between ``axis`` and the short great-circle arc from ``a`` to ``b``."""
    ts = np.linspace(0.0, 1.0, 2001)
    L = angle_between(a, b)
    e = b - np.dot(a, b) * a
    e /= np.linalg.norm(e)
    pts = np.cos(ts * L)[:, None] * a + np.sin(ts * L)[:, None] * e
    return float(np.min(np.arccos(np.clip(pts @ axis, -1, 1))))


@pytest.fixture(scope="module")
def samples():
    rng = np.random.default_rng(2024)
    return {name: [TaskDistribution.family(name).sample(rng) for _ in range(1500)] for name in FAMILIES}


def test_full_attitude_family(samples):
    probs = samples["full-attitude"]
    angles = np.degrees([p.slew_angle for p in probs])
    assert angles.min() >= 10.0 and angles.max() <= 180.0
    assert abs(angles.mean() - 95.0) < 4.0  # uniform on [10, 180]
    assert not any(p.is_pointing or p.cones for p in probs)
    J = np.array([p.inertia for p in probs])
    assert J.min() >= 0.4 and J.max() <= 1.0
    assert all(p.is_rest_to_rest for p in probs)
    # uniform start attitudes: the start sensor direction averages to zero
    s = np.array([p.start_direction for p in probs])
    assert np.linalg.norm(s.mean(axis=0)) < 0.1


def test_pointing_cones_family(samples):
    probs = samples["pointing-cones"]
    clearance = math.radians(3.0)
    counts = np.bincount([len(p.cones) for p in probs], minlength=4)
    assert counts[0] == 0 and all(c > 300 for c in counts[1:])
    for p in probs:
        assert p.is_pointing
        assert math.radians(40) - 1e-12 <= p.slew_angle <= math.pi
        a, b = p.start_direction, p.target_direction
        for c in p.cones:
            assert math.radians(10) - 1e-12 <= c.half_angle <= math.radians(30) + 1e-12
            assert c.margin(a) >= clearance - 1e-9 and c.margin(b) >= clearance - 1e-9
        # the first cone blocks the short path: the arc passes within half of its half-angle
        first = p.cones[0]
        if p.slew_angle < math.pi - 1e-6:
            assert arc_distance(first.axis, a, b) <= 0.5 * first.half_angle + 1e-3


def test_sampled_tasks_are_exact_problems():
    dist = TaskDistribution.family("pointing-cones")
    task = dist.sample_task_array(np.random.default_rng(0), max_cones=4)
    prob = SlewProblem.from_task_array(task)  # validates: unit quaternions, cones clear of start/target
    np.testing.assert_allclose(prob.to_task_array(4), task, atol=1e-15)
    assert task[T.T_TUNIT] == prob.time_unit


def test_same_generator_same_task_and_block_consumption():
    dist = TaskDistribution.family("pointing-cones")
    a = dist.sample(np.random.default_rng(9))
    b = dist.sample(np.random.default_rng(9))
    assert a == b
    # one attempt consumes exactly one block of BLOCK uniforms from the generator
    rng, ref = np.random.default_rng(9), np.random.default_rng(9)
    dist.sample_task_array(rng)
    ref.random(BLOCK)
    assert rng.random() == ref.random()


def test_buffer_exhaustion_is_signalled_never_filled_in():
    dist = TaskDistribution.family("pointing-cones").to_array()
    task = np.zeros(T.task_length(4))
    u = np.random.default_rng(0).random(BLOCK)
    assert S.sample_task(dist, u[:8], task) == -1
    used = S.sample_task(dist, u, task)
    assert 0 < used <= BLOCK
    with pytest.raises(RuntimeError, match="cones"):
        draw_task(np.random.default_rng(0), dist, task, block=8, max_blocks=3)


def test_too_few_slots_for_the_distribution():
    dist = TaskDistribution.family("pointing-cones").to_array()
    assert S.sample_task(dist, np.random.default_rng(0).random(BLOCK), np.zeros(T.task_length(2))) \
        == S.TOO_MANY_CONES
    with pytest.raises(ValueError, match="max_cones"):
        draw_task(np.random.default_rng(0), dist, np.zeros(T.task_length(2)))


def test_inertia_modes():
    rng = np.random.default_rng(1)
    fixed = TaskDistribution(inertia_mode="fixed", inertia=(3.0, 2.0, 1.0), torque_max=0.5)
    p = fixed.sample(rng)
    assert p.inertia.tolist() == [3.0, 2.0, 1.0] and p.time_unit == math.sqrt(3.0 / 0.5)
    assert TaskDistribution(inertia_mode="symmetric").sample(rng).inertia.tolist() == [1.0, 1.0, 1.0]
    J = np.array([TaskDistribution(inertia_ratio=(0.2, 0.3)).sample(rng).inertia for _ in range(50)])
    assert J.min() >= 0.2 and J.max() <= 0.3


def test_mixed_targets_and_pnorm():
    rng = np.random.default_rng(3)
    dist = TaskDistribution(pointing_prob=0.5, torque_norm=2, angle_deg=(30, 30))
    probs = [dist.sample(rng) for _ in range(200)]
    frac = np.mean([p.is_pointing for p in probs])
    assert 0.35 < frac < 0.65
    assert all(p.torque_norm == 2.0 for p in probs)
    np.testing.assert_allclose([p.slew_angle for p in probs], math.radians(30), atol=1e-9)


@pytest.mark.parametrize("kwargs, field", [
    ({"angle_deg": (10, 200)}, "angle_deg"),
    ({"angle_deg": (50, 20)}, "angle_deg"),
    ({"pointing_prob": 1.5}, "pointing_prob"),
    ({"inertia_mode": "oblate"}, "inertia_mode"),
    ({"inertia_ratio": (0.0, 1.0)}, "inertia_ratio"),
    ({"torque_norm": 1}, "torque_norm"),
    ({"n_cones": (1, 2), "cone_half_angle_deg": (40, 50), "angle_deg": (10, 60)}, "cone_half_angle_deg"),
    ({"n_cones": (0.5, 2)}, "n_cones"),
    ({"path_offset": 1.0}, "path_offset"),
    ({"sensor_axis": (0, 0, 0)}, "sensor_axis"),
])
def test_invalid_parameters_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        TaskDistribution(**kwargs)


def test_resolve():
    assert TaskDistribution.resolve("full-attitude") == FAMILIES["full-attitude"]
    d = TaskDistribution.resolve({"family": "pointing-cones", "n_cones": (2, 2)})
    assert d.n_cones == (2, 2) and d.pointing_prob == 1.0 and d.name == "pointing-cones"
    with pytest.raises(ValueError, match="task_distribution"):
        TaskDistribution.resolve("nope")


@pytest.mark.parametrize("kwargs, match", [
    # a fuzz run: float()/int() raised their own TypeError/OverflowError, or text and
    # booleans were read as numbers, or max_cone_tries=1.5 was truncated to 1
    ({"max_cone_tries": float("inf")}, r"^max_cone_tries: must be a whole number >= 1, got inf"),
    ({"max_cone_tries": float("nan")}, r"^max_cone_tries: must be a whole number >= 1, got nan"),
    ({"max_cone_tries": 1.5}, r"^max_cone_tries: must be a whole number >= 1, got 1.5"),
    ({"max_cone_tries": None}, r"^max_cone_tries: must be a whole number >= 1, got None"),
    ({"max_cone_tries": "20"}, r"^max_cone_tries: must be a whole number >= 1, got '20'"),
    ({"max_cone_tries": True}, r"^max_cone_tries: must be a whole number >= 1, got True"),
    ({"pointing_prob": None}, r"^pointing_prob: must be a number in \[0, 1\], got None"),
    ({"pointing_prob": "0.5"}, r"^pointing_prob: must be a number in \[0, 1\], got '0.5'"),
    ({"pointing_prob": True}, r"^pointing_prob: must be a number in \[0, 1\], got True"),
    ({"symmetric_prob": float("nan")}, r"^symmetric_prob: must be a number in \[0, 1\], got nan"),
    ({"path_cone_prob": [0.5]}, r"^path_cone_prob: must be a number in \[0, 1\]"),
    ({"cone_clearance_deg": None}, r"^cone_clearance_deg: must be a number in \[0, 90\), got None"),
    ({"cone_clearance_deg": "3"}, r"^cone_clearance_deg: must be a number in \[0, 90\), got '3'"),
    ({"path_offset": "0.2"}, r"^path_offset: must be a number in \[0, 1\)"),
    ({"path_offset": float("inf")}, r"^path_offset: must be a number in \[0, 1\)"),
    ({"angle_deg": ["10", "20"]}, r"^angle_deg: expected a \(low, high\) pair of numbers"),
    ({"angle_deg": "ab"}, r"^angle_deg: expected a \(low, high\) pair of numbers"),
    ({"angle_deg": None}, r"^angle_deg: expected a \(low, high\) pair of numbers"),
    ({"angle_deg": (10, float("nan"))}, r"^angle_deg: need finite low <= high"),
    ({"inertia_ratio": (True, 1)}, r"^inertia_ratio: expected a \(low, high\) pair of numbers"),
    ({"n_cones": (1, float("inf"))}, r"^n_cones: need finite low <= high"),
    ({"cone_half_angle_deg": (10, "30")}, r"^cone_half_angle_deg: expected a \(low, high\) pair"),
    ({"inertia": None}, r"^inertia: expected one or three positive numbers, got None"),
    ({"inertia": ["1", 1, 1]}, r"^inertia: expected numbers, got text"),
    ({"torque_max": "0.5"}, r"^torque_max: expected numbers, got text"),
    ({"torque_max": [1, True, 1]}, r"^torque_max: expected numbers, got a boolean"),
    ({"sensor_axis": ["1", 0, 0]}, r"^sensor_axis: expected numbers, got text"),
    ({"sensor_axis": None}, r"^sensor_axis: expected 3 numbers"),
    ({"inertia_mode": ["fixed"]}, r"^inertia_mode: expected one of"),
    ({"name": 3}, r"^name: expected a string, got 3"),
])
def test_fields_of_the_wrong_type_are_refused_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TaskDistribution(**kwargs)


def test_numpy_numbers_are_accepted():
    d = TaskDistribution(max_cone_tries=np.int64(7), pointing_prob=np.float32(0.25),
                         angle_deg=np.array([20.0, 90.0]), inertia=np.array([1, 2, 3]), n_cones=(np.int64(0), 2),
                         cone_half_angle_deg=(10, 20))
    assert d.max_cone_tries == 7 and type(d.max_cone_tries) is int
    assert d.angle_deg == (20.0, 90.0) and d.inertia == (1.0, 2.0, 3.0) and d.pointing_prob == 0.25


@pytest.mark.parametrize("spec, match", [
    ({"family": "full-attitude", "bogus": 1}, r"^task_distribution: unknown field\(s\) \['bogus'\]"),
    ({"bogus": 1}, r"^task_distribution: unknown field\(s\) \['bogus'\]"),
    ({1: 2}, r"^task_distribution: unknown field\(s\) \[1\]"),
    ({"family": ["full-attitude"]}, r"^task_distribution: unknown family"),
    (3, r"^task_distribution: expected a family name"),
])
def test_resolve_refuses_bad_specs_by_name(spec, match):
    with pytest.raises(ValueError, match=match):
        TaskDistribution.resolve(spec)


@pytest.mark.parametrize("kwargs, field, worst", [
    # every body drawn would be refused by SlewProblem (MAX_AXIS_SPREAD = 1000)
    ({"torque_max": [1e-6, 1, 1]}, "inertia_ratio, torque_max", 2.5e6),
    ({"inertia_mode": "symmetric", "torque_max": [1e-4, 1, 1]}, "torque_max", 1e4),
    ({"inertia_mode": "fixed", "inertia": (1, 1, 1e6)}, "inertia, torque_max", 1e6),
    # each factor alone within the bound, the product beyond it: strong axis at J = 0.1, weak
    # one at J = 1 with a torque 200 times smaller
    ({"inertia_ratio": (0.1, 1.0), "torque_max": [1, 1, 5e-3]}, "inertia_ratio, torque_max", 2e3),
    ({"inertia_ratio": (1e-4, 1.0)}, "inertia_ratio, torque_max", 1e4),
])
def test_distributions_that_can_draw_a_refused_body_are_refused(kwargs, field, worst):
    with pytest.raises(ValueError, match=rf"^{field}: the axes' acceleration bounds .* factor {re.escape(f'{worst:.3g}')} "):
        TaskDistribution(**kwargs)


@pytest.mark.parametrize("kwargs", [
    {"inertia_ratio": (0.1, 1.0), "torque_max": [1, 1, 1e-2]},          # worst case exactly 1000
    {"inertia_mode": "fixed", "inertia": (1, 1, 1e3)},
    {"inertia_mode": "fixed", "inertia": (1, 1, 1e3), "torque_max": [1, 1, 1e3]},   # u / J all equal
    {"inertia_mode": "asymmetric", "inertia": (1, 1, 1e6)},            # inertia unused in this mode
])
def test_distributions_at_the_spread_limit_draw_valid_problems(kwargs):
    dist = TaskDistribution(**kwargs)
    for seed in range(20):
        dist.sample(seed)   # SlewProblem validates every draw


def test_make_with_a_spread_beyond_the_limit_fails_at_construction():
    import gymnasium as gym
    with pytest.raises(ValueError, match=r"^inertia_ratio, torque_max: "):
        gym.make("slew_env/Slew-v0", task_distribution={"family": "full-attitude", "torque_max": [1e-6, 1, 1]})
