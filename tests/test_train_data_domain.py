"""``slew train`` refuses data drawn from another domain than the config's, which the exported
model's card claims (review s35, finding 5: a model trained on torque_norm = 2 problems said it
covered the per-axis bound, and refused the problems it was trained on)."""
import json
import os

import pytest

from training.cli import main
from training.warmstart.data import check_domain
from training.warmstart.train import load_config

HERE = os.path.dirname(__file__)
DATA = os.path.join(HERE, "data", "full-attitude-small.jsonl")
CONES = os.path.join(HERE, "data", "pointing-cones-small.jsonl")
FULL_DOMAIN = load_config()["domain"]
CONE_DOMAIN = load_config(os.path.join(HERE, "..", "training", "warmstart", "configs", "pointing-cones.yaml"))["domain"]


def _with_distribution(tmp_path, name, src=DATA, seed=None, **changes):
    """A copy of ``src`` whose metadata's distribution has ``changes`` (the records are kept:
    only the metadata is read by the check)."""
    lines = open(src).read().splitlines(keepends=True)
    head = json.loads(lines[0])
    head["_meta"]["distribution"].update(changes)
    if seed is not None:
        head["_meta"]["seed"] = seed
    path = tmp_path / name
    path.write_text(json.dumps(head) + "\n" + "".join(lines[1:]))
    return str(path)


def test_the_test_data_match_their_configs():
    check_domain([DATA], FULL_DOMAIN)
    check_domain([CONES], CONE_DOMAIN)


@pytest.mark.parametrize("changes, needle", [
    ({"torque_norm": 2.0}, "torque_norm: the data's 2.0, the domain's inf"),
    ({"angle_deg": [5.0, 180.0]}, "angle_deg: the data's [5, 180] is outside the domain's [10, 180]"),
    ({"inertia_ratio": [0.2, 1.0]}, "inertia_ratio: the data's J_min/J_max reaches 0.2, below the domain's 0.4"),
    ({"inertia_mode": "fixed", "inertia": [1.0, 0.3, 1.0]}, "inertia_ratio: the data's J_min/J_max reaches 0.3"),
    ({"torque_max": [1.0, 0.5, 1.0]}, "torque_ratio_min: the data's u_min/u_max is 0.5, below the domain's 1"),
    ({"pointing_prob": 0.5}, "target: the data's targets are mixed (0.5 pointing), the domain's full-attitude"),
    ({"n_cones": [1, 2]}, "cones: the data have 1–2 cones, the domain none"),
])
def test_data_outside_the_domain_are_refused_naming_the_file_and_the_field(tmp_path, changes, needle):
    bad = _with_distribution(tmp_path, "bad.jsonl", **changes)
    with pytest.raises(ValueError, match="^--data: ") as e:
        check_domain([DATA, bad], FULL_DOMAIN)
    assert f"{bad}: {needle}" in str(e.value), str(e.value)


@pytest.mark.parametrize("changes, needle", [
    ({"angle_deg": [10.0, 90.0]}, "angle_deg: the domain's [10, 180], the data reach only [10, 90]"),
    ({"inertia_mode": "symmetric"}, "inertia_ratio: the domain reaches 0.4, the data only 1"),
])
def test_data_from_a_part_of_the_domain_are_refused_naming_the_field(tmp_path, changes, needle):
    part = _with_distribution(tmp_path, "part.jsonl", **changes)
    with pytest.raises(ValueError, match=f"^--data: {needle.replace('[', '.').replace(']', '.')}"):
        check_domain([part], FULL_DOMAIN)


def test_files_that_together_cover_the_domain_are_accepted(tmp_path):
    low = _with_distribution(tmp_path, "low.jsonl", angle_deg=[10.0, 90.0])
    high = _with_distribution(tmp_path, "high.jsonl", angle_deg=[90.0, 180.0])
    check_domain([high, low], FULL_DOMAIN)
    one = _with_distribution(tmp_path, "one.jsonl", src=CONES, n_cones=[1, 1])
    more = _with_distribution(tmp_path, "more.jsonl", src=CONES, n_cones=[2, 3])
    check_domain([one, more], CONE_DOMAIN)
    with pytest.raises(ValueError, match=r"^--data: n_cones: the domain's \[1, 3\], the data reach only \[2, 3\]"):
        check_domain([more], CONE_DOMAIN)


def test_the_cone_domain_is_checked_too(tmp_path):
    wide = _with_distribution(tmp_path, "wide.jsonl", src=CONES, cone_half_angle_deg=[10.0, 45.0])
    with pytest.raises(ValueError, match="cone_half_angle_deg: the data's .10, 45. is outside the domain's .10, 30."):
        check_domain([wide], CONE_DOMAIN)
    with pytest.raises(ValueError, match=f"{DATA}: target: the data's targets are full-attitude"):
        check_domain([DATA], CONE_DOMAIN)


def test_slew_train_refuses_them_in_one_line_before_training(tmp_path, capsys):
    pytest.importorskip("torch")
    p2 = _with_distribution(tmp_path, "p2.jsonl", torque_norm=2.0)
    code = main(["train", "--data", p2, "--out", str(tmp_path / "run"), "--epochs", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert f"--data: {p2}: torque_norm: the data's 2.0, the domain's inf" in err
    assert not (tmp_path / "run").exists()
