"""Bad arguments to ``slew generate``, ``slew evaluate`` and ``slew env-demo``: exit 2 with one
line naming the flag, before anything is written (each found by a fuzz run, session 33)."""
import pytest

from training.cli import main


@pytest.mark.parametrize("extra, needle", [
    # every record had become a rejection, kept for good by a resumed run, with exit 0
    (["--solve-options", '{"bogus": 1}'], "unknown option(s) ['bogus']"),
    (["--solve-options", '{"max_candidates": "x"}'], "max_candidates: expected an integer"),
    (["--solve-options", '{"collocation": {"tol": -1}}'], "tol: must be a positive number"),
    (["--time-budget", "inf"], "time_budget: must be a positive number of seconds, got inf"),
])
def test_generate_checks_its_solve_options_before_writing(tmp_path, capsys, extra, needle):
    out = tmp_path / "g.jsonl"
    code = main(["generate", "--family", "full-attitude", "--n", "2", "--workers", "1", "--no-progress",
                 "-o", str(out)] + extra)
    err = capsys.readouterr().err
    assert code == 2 and needle in err and "Traceback" not in err
    assert err.strip().startswith("slew generate: error: ")
    assert not out.exists()


def test_generate_makes_the_output_directory(tmp_path):
    # a user's report: the README's `slew generate ... -o data/a.jsonl` failed on a fresh clone
    out = tmp_path / "data" / "a.jsonl"
    assert main(["generate", "--family", "full-attitude", "--n", "1", "--workers", "1", "--no-progress",
                 "-o", str(out)]) == 0
    assert len(out.read_text().splitlines()) == 2          # the metadata line and one record


@pytest.mark.parametrize("extra, needle", [
    (["--budget", "-1"], "--budget: must be a positive number of seconds"),
    (["--budget", "nan"], "--budget: must be a positive number of seconds"),
    (["--warm-budget", "0"], "--warm-budget: must be a positive number of seconds"),
    (["--baseline-n", "-3"], "--baseline-n: must be ≥ 0"),
    (["--workers", "0"], "--workers: must be ≥ 1"),
])
def test_evaluate_refuses_arguments_that_would_give_an_empty_report(tmp_path, capsys, extra, needle):
    out = tmp_path / "ev"
    code = main(["evaluate", "--n", "2", "--no-progress", "-o", str(out)] + extra)
    err = capsys.readouterr().err
    assert code == 2 and needle in err and "Traceback" not in err
    assert not out.exists()


def test_evaluate_into_an_existing_file_is_one_line(tmp_path, capsys):
    f = tmp_path / "a_file"
    f.write_text("keep me")
    assert main(["evaluate", "--n", "1", "--no-progress", "-o", str(f)]) == 2
    assert "exists and is not a directory" in capsys.readouterr().err
    assert f.read_text() == "keep me"


@pytest.mark.parametrize("extra, needle", [
    (["--out", "frame.xyz"], "--out: expected a .png file name"),
    (["--seed", "-1"], "--seed: must be >= 0"),
])
def test_env_demo_bad_arguments(tmp_path, capsys, extra, needle):
    code = main(["env-demo", "--steps", "2"] + extra)
    err = capsys.readouterr().err
    assert code == 2 and needle in err and "Traceback" not in err
