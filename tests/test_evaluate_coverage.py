"""``slew evaluate`` says how many held-out problems the model covers, refuses a model that
covers none, and lists as "not applicable" only guesses that ran and rejected every problem
(review s35, finding 7: a model covering half the problems reported "100 %" on all of them, and
a model of the other family still "evaluated", exit 0)."""
import json
import os

import pytest

from solvers.warmstart import DEFAULT_MODEL_FILE, WarmStartModel
from training.cli import main
from training.generate import GenerationSpec, problem_for
from training.warmstart.evaluate import evaluate, summarise


def test_a_model_that_covers_none_of_the_family_is_refused(tmp_path, capsys):
    out = tmp_path / "ev"
    code = main(["evaluate", "--family", "pointing-cones", "--model", "default", "--n", "3", "--baseline-n", "1",
                 "--workers", "1", "--no-progress", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "--model: default covers none of the 3 held-out --family pointing-cones problems" in err
    assert not out.exists()
    with pytest.raises(ValueError, match="--model: .*full-attitude.npz covers none of the 1 held-out --family "
                                         "pointing-cones problems"):
        evaluate("pointing-cones", n=1, model_path=DEFAULT_MODEL_FILE, out=str(out), baseline_n=0, workers=1,
                 progress_bar=False)


def test_the_report_counts_the_problems_the_model_does_not_cover(tmp_path):
    """The shipped network with its card's domain cut to 10°-90° slews: about half the held-out
    problems are outside it, and the report says so."""
    m = WarmStartModel.load(DEFAULT_MODEL_FILE)
    m.card["domain"] = dict(m.card["domain"], angle_deg=[10.0, 90.0])
    m.save(tmp_path / "narrow.npz")
    narrow = WarmStartModel.load(tmp_path / "narrow.npz")
    n, seed = 6, 20261122
    covered = sum(narrow.covers(problem_for(GenerationSpec("full-attitude", seed=seed), i)) is None for i in range(n))
    assert 0 < covered < n
    s = evaluate("full-attitude", n=n, seed=seed, model_path=str(tmp_path / "narrow.npz"), out=str(tmp_path / "ev"),
                 baseline_n=0, workers=1, progress_bar=False)
    assert s["model_covers"] == covered and s["learned"]["n"] == covered
    assert s["learned"]["not_covered"] == n - covered
    report = open(tmp_path / "ev" / "report.md").read()
    assert "| guess | problems | not covered | converged |" in report
    assert f"| learned | {covered} | {n - covered} |" in report
    assert f"The model covers {covered} of the {n} problems" in report
    assert json.load(open(tmp_path / "ev" / "summary.json"))["model_covers"] == covered


def test_not_applicable_lists_only_guesses_that_ran_and_rejected_every_problem():
    def row(i, g, covered=True):
        return ({"index": i, "guess": g, "covered": True, "success": True, "exact": True, "tf": 2.0, "nit": 3,
                 "wall_time_s": 0.01} if covered else {"index": i, "guess": g, "covered": False, "reason": "no"})
    s = summarise([row(0, "learned"), row(1, "learned"), row(0, "eigenaxis", False), row(1, "eigenaxis", False)])
    assert s["not_applicable"] == ["eigenaxis"]      # random, collocation... never ran: not listed


def test_a_run_without_baselines_lists_nothing_as_not_applicable(tmp_path):
    s = evaluate("full-attitude", n=1, seed=5, out=str(tmp_path), baseline_n=0, workers=1, progress_bar=False)
    assert s["not_applicable"] == []
    assert "Not applicable" not in open(tmp_path / "report.md").read()
