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


WARM = ["--solve-fn", "training.generate:solve_warm"]


@pytest.mark.parametrize("extra, needle", [
    # the warm route (make_shipped_model.sh, steps 3 and 5) had ignored a typo, and filled a
    # whole file with "model: file not found" failures that a rerun never repaired, with exit 0
    (WARM + ["--solve-options", '{"model": "no/such/model.npz", "time_budget": 0.3}'], "model: "),
    (WARM + ["--solve-options", '{"time_budgt": 0.3}'], "unknown option(s) ['time_budgt']"),
    (WARM + ["--solve-options", '{"fallback": true, "singular_tabel": false}'], "unknown option(s) ['singular_tabel']"),
    (WARM + ["--solve-options", '{"fallback": "yes"}'], "fallback: expected true or false"),
    (WARM + ["--solve-options", '{"time_budget": -1}'], "time_budget: must be a positive"),
    (WARM + ["--solve-options", '{"method": "auto"}'], "method: without the fallback solve_warm runs the indirect"),
    (WARM + ["--solve-options", '{"warm_start": "default"}'], "warm_start: solve_warm takes its model as 'model'"),
    (["--solve-options", '{"warm_start": "no/such/model.npz"}'], "warm_start: "),
    (["--n", "1000000001"], "n: at most 1,000,000 problems a run"),
])
def test_generate_checks_the_warm_route_and_n_before_writing(tmp_path, capsys, extra, needle):
    out = tmp_path / "g.jsonl"
    args = ["generate", "--family", "full-attitude", "--workers", "1", "--no-progress", "-o", str(out)]
    code = main(args + (["--n", "2"] if "--n" not in extra else []) + extra)
    err = capsys.readouterr().err
    assert code == 2 and needle in err and "Traceback" not in err, err
    assert not out.exists()


def test_generate_names_the_output_it_cannot_create(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code = main(["generate", "--family", "full-attitude", "--n", "1", "--workers", "1", "--no-progress",
                 "-o", str(blocker / "sub" / "a.jsonl")])
    err = capsys.readouterr().err
    assert code == 2 and "-o/--output: cannot create the directory" in err and "Traceback" not in err


def test_generate_warns_when_workers_exceed_the_cores(tmp_path, capsys):
    import os
    cores = len(os.sched_getaffinity(0))
    assert main(["generate", "--family", "full-attitude", "--n", "0", "--workers", str(cores + 1),
                 "--no-progress", "-o", str(tmp_path / "g.jsonl")]) == 0
    assert f"--workers {cores + 1} is more than the {cores} usable core(s)" in capsys.readouterr().err


def test_a_continued_file_notes_another_route_and_every_record_names_its_options(tmp_path, capsys):
    from training.dataset import load
    out = tmp_path / "g.jsonl"
    base = ["generate", "--family", "full-attitude", "--workers", "1", "--no-progress", "-o", str(out),
            "--solve-fn", "gen_sleepy:solve"]
    assert main(base + ["--n", "1", "--solve-options", '{"sleep": 0}']) == 0
    assert "note:" not in capsys.readouterr().out
    assert main(base + ["--n", "2", "--solve-options", '{"sleep": 0.01}']) == 0
    out_text = capsys.readouterr().out
    assert 'note: this run solved with solve_options {"sleep": 0.01} (the file began with {"sleep": 0})' in out_text
    assert [r["solve_options"] for r in load(out)] == [{"sleep": 0}, {"sleep": 0.01}]


def test_the_warm_route_with_its_fallback_takes_a_method():
    # accepted before the option check existed (a review: the check had turned it into a TypeError
    # reported as a --family-options error)
    from training.generate import GenerationSpec
    spec = GenerationSpec("full-attitude", n=1, solve_fn="training.generate:solve_warm",
                          solve_options={"fallback": True, "method": "indirect", "time_budget": 1.0})
    assert spec.solve_options["method"] == "indirect"
