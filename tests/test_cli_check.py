"""``slew check PROBLEM.json``: a valid problem is described (rate limits and cones included), an
invalid one refused by name, and an infeasible cone set refused as ``slew solve`` refuses it."""
import json
import math
import os
import subprocess
import sys

import numpy as np

from training.cli import main

ROOT = os.path.join(os.path.dirname(__file__), "..")


def _write(tmp_path, d, name="p.json"):
    path = tmp_path / name
    path.write_text(json.dumps(d))
    return str(path)


def test_a_problem_with_rate_limits_and_a_cone_is_described(tmp_path, capsys):
    d = {"inertia": [1, 1, 1], "sensor_target": [0, 1, 0], "rate_max_deg": [2, 3, 4], "rate_norm_max_deg": 3.5,
         "cones": [{"axis": [math.cos(math.radians(45)), math.sin(math.radians(45)), 0], "half_angle_deg": 10}]}
    assert main(["check", _write(tmp_path, d)]) == 0
    out = capsys.readouterr().out
    assert "slew angle: 90.000000 deg" in out
    assert "rate limit per axis: |ω_i| ≤ 2, 3, 4 deg" in out
    assert "rate limit on the norm: ‖ω‖ ≤ 3.5 deg" in out
    # the sensor starts on +x and ends on +y, 45° from the cone's axis: 35° outside it at both ends
    assert "cone 1: half-angle 10 deg; the sensor starts 35 deg and ends 35 deg outside it" in out
    assert json.loads(out[out.index("{"):])["rate_max"] == [math.radians(2), math.radians(3), math.radians(4)]


def test_cones_that_block_every_path_are_refused(tmp_path, capsys):
    # a ring of 8 cones of 15° round the target +y, 30° from it (a user review: check passed it)
    ring = [{"axis": [math.sin(math.radians(30)) * math.cos(a), math.cos(math.radians(30)),
                      math.sin(math.radians(30)) * math.sin(a)], "half_angle_deg": 15}
            for a in np.linspace(0.0, 2 * math.pi, 8, endpoint=False)]
    path = _write(tmp_path, {"inertia": [1, 1, 1], "sensor_target": [0, 1, 0], "cones": ring})
    assert main(["check", path]) == 2
    err = capsys.readouterr().err
    assert err.startswith("slew check: error: cones:") and "infeasible" in err


def test_a_bad_field_is_named(tmp_path, capsys):
    assert main(["check", _write(tmp_path, {"inertia": [1, -1, 1], "qf": [0, 0, 0, 1]})]) == 2
    assert "inertia" in capsys.readouterr().err


def test_a_reader_that_stops_early_is_no_error(tmp_path):
    # `slew check X.json | head -1`: the closed pipe is not reported as an error (here the reader
    # closes before the command writes anything, so every write meets the closed pipe)
    path = _write(tmp_path, {"inertia": [1, 1, 1], "qf": [0, 0, 0, 1]})
    r, w = os.pipe()
    os.close(r)
    # block-buffered stdout, as from a shell (PYTHONUNBUFFERED would make every print meet the pipe
    # inside the command's try, and hide a write that fails at exit)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    try:
        proc = subprocess.run([sys.executable, "-m", "training.cli", "check", path], cwd=ROOT, stdout=w,
                              stderr=subprocess.PIPE, text=True, timeout=120, env=env)
    finally:
        os.close(w)
    assert proc.returncode == 0, proc.stderr
    assert "Broken pipe" not in proc.stderr and "Error" not in proc.stderr
