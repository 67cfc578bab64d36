"""``slew generate`` family options under which no problem can be drawn: refused up front, naming
--family-options, before the file is created.

A fuzz run (s42, violation 6): ``--family-options '{"n_cones": [50, 50]}'`` was accepted; every
index became a "sampling: internal error" record, the run exited 0, and a resumed run kept them
for good (other options are refused on resume, their metadata differing)."""
import pytest

from training.cli import main
from training.generate import GenerationSpec, UnsampleableError, problem_for


def test_the_cli_refuses_unplaceable_cones_before_writing(tmp_path, capsys):
    out = tmp_path / "g.jsonl"
    code = main(["generate", "--family", "pointing-cones", "--n", "3", "-o", str(out), "--workers", "1",
                 "--no-progress", "--family-options", '{"n_cones": [50, 50]}'])
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err
    assert lines[0].startswith('slew generate: error: --family-options: no problem can be drawn with '
                               '{"n_cones": [50, 50]}: ')
    assert "cones cannot be placed" in lines[0]          # the sampler's reason, with its advice
    assert not out.exists()


def test_the_python_api_refuses_it_too():
    with pytest.raises(UnsampleableError, match=r'overrides \{"n_cones": \[50, 50\]\}: no problem can be drawn'):
        GenerationSpec("pointing-cones", n=3, overrides={"n_cones": [50, 50]})
    assert issubclass(UnsampleableError, ValueError)


def test_options_that_can_be_sampled_are_accepted():
    spec = GenerationSpec("pointing-cones", n=2, overrides={"n_cones": [3, 3], "cone_half_angle_deg": [5, 10]})
    assert len(problem_for(spec, 1).cones) == 3
