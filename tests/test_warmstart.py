"""Learned warm start: canonical form, model files, inference, solve() integration, training, CLI."""
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from slew_env import SlewProblem
from slew_env.core.quaternion import qmul
from solvers import Guess, solve
from solvers.warmstart import (DEFAULT_MODEL_FILE, ModelFileError, NearestNeighbourModel, WarmStartModel,
                               canonical_form, default_model, load_model, solution_from_canonical,
                               solution_to_canonical)
from solvers.warmstart.features import canonical_problem

DATA = os.path.join(os.path.dirname(__file__), "data", "full-attitude-small.jsonl")


def _records():
    lines = open(DATA).read().splitlines()[1:]
    return [json.loads(l) for l in lines]


def _exact(n=None):
    r = [r for r in _records() if r["method"] == "indirect"]
    return r if n is None else r[:n]


def _axis_quat(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * a])


# --------------------------------------------------------------------------- canonical form
def test_canonical_form_ignores_the_inertial_frame():
    rng = np.random.default_rng(0)
    p = SlewProblem(inertia=[0.5, 1.0, 0.8], qf=_axis_quat([0.3, -0.8, 0.5], 2.0))
    R = _axis_quat(rng.normal(size=3), 1.3)            # rotate the whole scene
    p2 = p.replace(q0=qmul(R, p.q0), qf=qmul(R, p.qf))
    np.testing.assert_allclose(canonical_form(p).x, canonical_form(p2).x, atol=1e-12)


def test_symmetric_body_relabellings_share_one_canonical_form():
    """For a symmetric body all 24 axis relabellings of a slew are the same problem."""
    import itertools
    n = np.array([0.3, -0.8, 0.5])
    xs = []
    for perm in itertools.permutations(range(3)):
        for sg in itertools.product((1, -1), repeat=3):
            P = np.zeros((3, 3))
            for i, j in enumerate(perm):
                P[i, j] = sg[i]
            if np.linalg.det(P) < 0:
                continue
            xs.append(canonical_form(SlewProblem(inertia=[1.0, 1.0, 1.0], qf=_axis_quat(P @ n, 2.0))).x)
    assert len(xs) == 24
    np.testing.assert_allclose(np.array(xs), np.tile(xs[0], (24, 1)), atol=1e-12)
    x = xs[0]
    assert x[0] >= x[1] >= abs(x[2]) and x[1] >= 0 and abs(x[3] - 2.0 / math.pi) < 1e-12


def test_canonical_features_of_an_asymmetric_body():
    p = SlewProblem(inertia=[2.0, 4.0, 1.0], torque_max=[1.0, 2.0, 2.0], qf=_axis_quat([0.1, -0.2, 0.9], 1.0))
    cf = canonical_form(p)
    assert cf.order == (2, 1, 0)
    np.testing.assert_allclose(cf.x[4:7], [0.25, 1.0, 0.5])     # J / J_max in canonical order
    np.testing.assert_allclose(cf.x[7:10], [1.0, 1.0, 0.5])     # u / u_max
    assert abs(np.linalg.det(cf.A) - 1.0) < 1e-12 and cf.tau == pytest.approx(math.sqrt(4.0 / 2.0))


@pytest.mark.parametrize("bad, field", [
    (dict(sensor_target=[0.0, 1.0, 0.0], qf=None), "sensor_target"),
    (dict(cones=[{"axis": [0, 0, 1], "half_angle_deg": 10}]), "cones"),
    (dict(omega0=[0.01, 0, 0]), "omega0"),
])
def test_canonical_form_rejects_what_it_does_not_cover(bad, field):
    base = dict(inertia=[1.0, 1.0, 1.0], qf=list(_axis_quat([1, 1, 0], 1.0)))
    base.update(bad)
    with pytest.raises(ValueError, match=field):
        canonical_form(SlewProblem.from_dict(base))


def test_solution_round_trip_and_canonical_problem_has_the_same_optimum():
    r = _exact()[3]
    cf = canonical_form(r["problem"])
    z, T, sw, uf = solution_to_canonical(r["problem"], cf, r["costate0"], r["tf"], r["switch_times"], r["u_first"])
    assert abs(np.linalg.norm(z) - 1.0) < 1e-12
    c0, tf, sw2, uf2 = solution_from_canonical(r["problem"], cf, z, T, sw, uf)
    assert tf == pytest.approx(r["tf"], rel=1e-14)
    for a, b in zip(sw2, r["switch_times"]):
        np.testing.assert_allclose(a, b, rtol=1e-13)
    np.testing.assert_array_equal(uf2, r["u_first"])
    # the costates agree up to the positive scale
    c = np.asarray(r["costate0"])
    assert np.dot(c0, c) / (np.linalg.norm(c0) * np.linalg.norm(c)) == pytest.approx(1.0, abs=1e-12)
    # the canonical problem, solved from the mapped solution, has the same final time (nondim)
    cp = canonical_problem(cf)
    ccf = canonical_form(cp)
    g = Guess(*solution_from_canonical(cp, ccf, z, T, sw, uf))
    s = solve(cp, method="indirect", guess=g, max_candidates=1, min_candidates=1, warm_start=None)
    assert s.success and s.tf == pytest.approx(T, rel=1e-9)


# --------------------------------------------------------------------------- model files
def test_shipped_model_loads_and_has_a_card():
    m = default_model()
    c = m.card
    assert c["format"] == "slewopt-warmstart" and c["format_version"] == 1 and len(c["sha256"]) == 64
    assert c["training"]["n_exact_solutions"] > 0 and c["domain"]["torque_norm"] == "inf"
    assert os.path.getsize(DEFAULT_MODEL_FILE) < 2_000_000


def test_model_file_errors(tmp_path):
    with pytest.raises(ModelFileError, match="file not found"):
        WarmStartModel.load(tmp_path / "nope.npz")
    bad = tmp_path / "corrupt.npz"
    bad.write_bytes(open(DEFAULT_MODEL_FILE, "rb").read()[:500])
    with pytest.raises(ModelFileError, match="not a readable"):
        WarmStartModel.load(bad)
    # another version
    with np.load(DEFAULT_MODEL_FILE) as f:
        arrays = {k: f[k] for k in f.files}
    card = json.loads(str(arrays["card"]))
    old = dict(arrays, card=np.array(json.dumps(dict(card, format_version=0))))
    np.savez(tmp_path / "old.npz", **old)
    with pytest.raises(ModelFileError, match="format version 0"):
        WarmStartModel.load(tmp_path / "old.npz")
    # tampered weights
    tam = dict(arrays)
    tam["W0"] = tam["W0"] + np.float32(1e-3)
    np.savez(tmp_path / "tampered.npz", **tam)
    with pytest.raises(ModelFileError, match="checksum"):
        WarmStartModel.load(tmp_path / "tampered.npz")
    with pytest.raises(ValueError, match="warm_start"):
        solve(SlewProblem(inertia=[1.0, 1.0, 1.0], qf=_axis_quat([1, 0, 0], 1.0)), warm_start=42)
    with pytest.raises(ModelFileError, match="file not found"):
        solve(SlewProblem(inertia=[1.0, 1.0, 1.0], qf=_axis_quat([1, 0, 0], 1.0)), warm_start=str(tmp_path / "missing.npz"))
    # a file of another kind (a problem's JSON): named as such, not numpy's advice to unpickle it
    js = tmp_path / "problem.json"
    js.write_text('{"inertia": [1, 1, 1]}')
    with pytest.raises(ModelFileError, match="is not a .npz model file") as e:
        solve(SlewProblem(inertia=[1.0, 1.0, 1.0], qf=_axis_quat([1, 0, 0], 1.0)), warm_start=str(js))
    assert "pickle" not in str(e.value)
    # a directory given as the model: named, not a raw IsADirectoryError
    (tmp_path / "adir.npz").mkdir()
    with pytest.raises(ModelFileError, match="adir.npz cannot be read"):
        solve(SlewProblem(inertia=[1.0, 1.0, 1.0], qf=_axis_quat([1, 0, 0], 1.0)), warm_start=str(tmp_path / "adir.npz"))
    # the command line's 'none' given from Python: the valid spellings, not "file not found: .../none"
    with pytest.raises(ValueError, match="pass None") as e:
        solve(SlewProblem(inertia=[1.0, 1.0, 1.0], qf=_axis_quat([1, 0, 0], 1.0)), warm_start="none")
    assert "'default' and 'pointing-cones'" in str(e.value)


def test_save_load_round_trip_gives_identical_predictions(tmp_path):
    m = default_model()
    m.save(tmp_path / "copy.npz")
    m2 = WarmStartModel.load(tmp_path / "copy.npz")
    X = np.random.default_rng(0).normal(size=(5, 11))
    np.testing.assert_allclose(m.forward(X), m2.forward(X), rtol=1e-6)


def test_coverage_reasons():
    m = default_model()
    p = SlewProblem(inertia=[0.6, 1.0, 0.8], qf=_axis_quat([0.3, -0.8, 0.5], 2.0))
    assert m.covers(p) is None
    assert "rate_max" in m.covers(p.replace(rate_max=0.5))
    assert "torque_norm" in m.covers(p.replace(torque_norm=2))
    assert "inertia" in m.covers(p.replace(inertia=[0.1, 1.0, 1.0]))
    assert "angle" in m.covers(p.replace(qf=_axis_quat([1, 0, 0], 0.05)))
    assert "sensor_target" in m.covers(SlewProblem(inertia=[1.0, 1.0, 1.0], sensor_target=[0, 1, 0]))


# --------------------------------------------------------------------------- solve() integration
def test_solve_uses_the_learned_guess_by_default_and_records_it():
    ok = 0
    for r in _exact(6):
        s = solve(r["problem"])
        assert s.success
        assert s.warm_start["covered"] is True and s.warm_start["model"]
        if s.warm_start["succeeded"]:
            ok += 1
            assert s.guess.startswith("learned") and s.route.startswith("learned guess")
            # the same optimum as the dataset's (multi-start / collocation-first) answer
            assert s.tf == pytest.approx(r["tf"], rel=1e-7)
            assert s.verification["replay"]["passed"]
    assert ok >= 4


def test_no_warm_start_and_uncovered_problems_take_the_classical_route():
    r = _exact()[0]
    s = solve(r["problem"], method="indirect", warm_start=None)
    assert s.success and s.warm_start == {} and not s.route.startswith("learned")
    p = SlewProblem.from_dict(r["problem"]).replace(rate_max=10.0)
    s2 = solve(p, method="indirect")
    assert s2.warm_start["covered"] is False and "rate_max" in s2.warm_start["reason"]


def test_failed_learned_guess_falls_back_and_says_so():
    class Wrong:
        name = "wrong model"

        def covers(self, problem):
            return None

        def guess(self, problem):   # a structure that cannot be right: one switch on each axis at tf/2
            return Guess(np.array([0, 1, 0, 0, 1, 1, 1.0]), 0.3, [[0.15], [0.15], [0.15]], [1, 1, 1], source="learned")
    r = _exact()[1]
    s = solve(r["problem"], method="indirect", warm_start=Wrong())
    assert s.warm_start["succeeded"] is False and s.warm_start["candidates"] >= 1
    if s.success:
        assert not s.guess.startswith("learned") and s.route.startswith("learned guess failed")


def test_nearest_neighbour_model(tmp_path):
    from training.warmstart.data import training_arrays
    a = training_arrays([DATA])
    nn = NearestNeighbourModel(a["X"], a["Z"], a["T"], a["T_eig"], a["U"], a["S"], k=3)
    nn.save(tmp_path / "t.nn.npz")
    nn2 = load_model(tmp_path / "t.nn.npz")
    r = _exact()[5]
    g = nn2.guess(r["problem"])
    assert g.source == "nearest-neighbour[0]" and len(g.candidates) == 2
    s = solve(r["problem"], method="indirect", warm_start=nn2)   # its own solution is in the table
    assert s.success and s.guess == "nearest-neighbour[0]" and s.nit <= 3
    assert s.tf == pytest.approx(r["tf"], rel=1e-9)


def test_solvers_do_not_import_torch():
    code = ("import sys, solvers; from solvers.warmstart import default_model; m = default_model();"
            "from slew_env import SlewProblem; import numpy as np;"
            "s = solvers.solve(SlewProblem(inertia=[0.6, 1, 0.8], qf=[0.6, 0.48, -0.64, 0.0]));"
            "assert 'torch' not in sys.modules, 'torch imported'; print(s.success, s.guess)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]


# --------------------------------------------------------------------------- training and CLI
def test_training_is_reproducible_exports_and_resumes(tmp_path):
    pytest.importorskip("torch")
    from training.warmstart.train import train
    s1 = train([DATA], tmp_path / "a", seed=3, epochs=4, progress_bar=False)
    s2 = train([DATA], tmp_path / "b", seed=3, epochs=4, progress_bar=False)
    m1, m2 = WarmStartModel.load(s1["model"]), WarmStartModel.load(s2["model"])
    assert m1.card["sha256"] == m2.card["sha256"]
    assert m1.card["training"]["n_exact_solutions"] == 69 and m1.card["training"]["n_train"] + m1.card["training"]["n_val"] == 69
    for f in ("log.csv", "loss.png", "config.yaml", "model.md", "checkpoints/epoch_0004.pt"):
        assert (tmp_path / "a" / f).exists(), f
    # an interrupted run resumed from its last checkpoint equals the uninterrupted run
    ck = {"checkpoint_every": 2}
    s3 = train([DATA], tmp_path / "c", seed=3, epochs=6, progress_bar=False, overrides=ck)
    s4 = train([DATA], tmp_path / "d", seed=3, epochs=6, progress_bar=False, overrides=ck)
    os.remove(tmp_path / "d" / "checkpoints" / "epoch_0006.pt")      # "killed" after epoch 4
    s4 = train([DATA], tmp_path / "d", seed=3, epochs=6, resume=True, progress_bar=False, overrides=ck)
    assert WarmStartModel.load(s3["model"]).card["sha256"] == WarmStartModel.load(s4["model"]).card["sha256"]
    lines = open(tmp_path / "d" / "log.csv").read().splitlines()
    assert len(lines) == 7 and lines[0].startswith("epoch,lr,train_loss,val_loss")
    # the exported model is usable
    g = m1.guess(_exact()[0]["problem"])
    assert g.source == "learned" and g.costate0.shape == (7,)


def test_cli_train_and_evaluate(tmp_path):
    pytest.importorskip("torch")
    from training.cli import main
    assert main(["train", "--data", DATA, "--out", str(tmp_path / "run"), "--epochs", "3", "--no-progress"]) == 0
    model = tmp_path / "run" / "model.npz"
    assert model.exists()
    assert main(["evaluate", "--model", str(model), "--n", "3", "--baseline-n", "1", "--train-data", DATA,
                 "--workers", "1", "--budget", "2", "--out", str(tmp_path / "ev"), "--no-progress"]) == 0
    s = json.load(open(tmp_path / "ev" / "summary.json"))
    assert s["learned"]["n"] == 3 and s["nearest-neighbour"]["n"] == 3 and s["eigenaxis"]["n"] == 1
    assert s["inference_s_median"] < 0.01
    assert "| learned |" in open(tmp_path / "ev" / "report.md").read()
    assert (tmp_path / "ev" / "evaluation.png").exists()
    assert main(["train", "--data", str(tmp_path / "missing.jsonl"), "--out", str(tmp_path / "x")]) == 2


@pytest.mark.parametrize("key, bad", [("warm_budget", -1.0), ("warm_budget", "1"), ("time_budget", 0.0),
                                      ("time_budget", float("nan"))])
def test_budget_options_are_validated(key, bad):
    with pytest.raises(ValueError, match=f"^{key}: must be a positive number"):
        solve(SlewProblem(inertia=[1.0, 1.0, 1.0], qf=_axis_quat([1, 0, 0], 1.0)), **{key: bad})


def test_evaluate_on_a_family_the_model_does_not_cover(tmp_path):
    # refused (review s35, finding 7: it wrote a report that looked like an evaluation, exit 0)
    from training.warmstart.evaluate import evaluate
    with pytest.raises(ValueError, match="^--model: default covers none of the 1 held-out --family pointing-cones"):
        evaluate("pointing-cones", n=1, seed=3, out=str(tmp_path / "ev"), baseline_n=1, workers=1, progress_bar=False)
    assert not (tmp_path / "ev").exists()


def test_a_model_that_raises_falls_back_and_records_the_error():
    class Broken:
        name = "broken"

        def covers(self, problem):
            return None

        def guess(self, problem):
            raise ValueError("weights went NaN")
    r = _exact()[2]
    s = solve(r["problem"], method="indirect", warm_start=Broken())
    assert s.success and "weights went NaN" in s.warm_start["error"] and s.warm_start["succeeded"] is False


@pytest.mark.parametrize("answer, covered", [(True, True), (np.True_, True), (False, False), ("no", False)])
def test_a_user_model_may_say_it_covers_a_problem_with_a_boolean(answer, covered):
    """A demanding user's report: ``covers()`` returning True was read as "not covered, reason
    True" (the package's rule: None or a reason), and the model was never used."""
    r = _exact()[1]

    class Mine:
        name = "mine"

        def covers(self, problem):
            return answer

        def guess(self, problem):
            return Guess(np.asarray(r["costate0"], float), r["tf"], [np.asarray(s) for s in r["switch_times"]],
                         np.asarray(r["u_first"], float), source="learned")
    s = solve(r["problem"], method="indirect", warm_start=Mine())
    assert s.success and s.warm_start["covered"] is covered
    if covered:
        assert s.warm_start["model"] == "mine" and s.warm_start["succeeded"] is True
        assert s.tf == pytest.approx(r["tf"], rel=1e-9)
    else:
        assert s.warm_start["reason"] in ("mine.covers() returned False", "no")


def test_a_model_returning_something_else_is_a_clear_error():
    class Odd:
        name = "odd"

        def covers(self, problem):
            return None

        def guess(self, problem):
            return [1, 2, 3]
    with pytest.raises(ValueError, match="expected a solvers.Guess"):
        solve(_exact()[2]["problem"], method="indirect", warm_start=Odd())


def test_first_candidate_runs_even_when_the_budget_is_spent():
    """In a fresh process compiling the kernels can use up a short budget before the first
    candidate: that candidate must still be tried (found on a clean clone)."""
    r = _exact()[0]
    s = solve(r["problem"], warm_budget=1e-9)
    assert s.warm_start["candidates"] >= 1
    if s.warm_start["succeeded"]:
        assert s.guess.startswith("learned")


def test_deferred_candidates_run_only_when_reached():
    r = _exact()[5]
    prob = SlewProblem.from_dict(r["problem"])
    calls = []

    def never():
        calls.append("never")
        raise AssertionError("a deferred candidate after a converged one must not be computed")

    class Model:
        name = "deferred"

        def __init__(self, g):
            self.g = g

        def covers(self, problem):
            return None

        def guess(self, problem):
            return self.g

    good = Guess(r["costate0"], r["tf"], [np.asarray(s) for s in r["switch_times"]], r["u_first"], source="learned",
                 candidates=[never])
    s = solve(prob, method="indirect", warm_start=Model(good))
    assert s.success and s.guess == "learned" and calls == []
    # a failing first guess reaches the deferred ones; None entries are dropped
    bad = Guess(np.array([0, 1, 0, 0, 1, 1, 1.0]), 0.3, [[0.15], [0.15], [0.15]], [1, 1, 1], source="bad",
                candidates=[lambda: None, lambda: calls.append("made") or Guess(r["costate0"], r["tf"], source="deferred")])
    s2 = solve(prob, method="indirect", warm_start=Model(bad))
    assert calls == ["made"] and s2.success and s2.guess == "deferred" and s2.warm_start["succeeded"]
    assert [g.source for g in bad.all()] == ["bad", "deferred"]
    with pytest.raises(ValueError, match=r"guess.candidates\[0\]"):
        Guess(r["costate0"], r["tf"], candidates=[3.0]).all()
    with pytest.raises(ValueError, match="deferred candidate returned str"):
        Guess(r["costate0"], r["tf"], candidates=[lambda: "x"]).all()


def test_a_guess_with_deferred_candidates_can_be_sent_to_another_process():
    import pickle
    r = _exact()[5]
    made = Guess(r["costate0"], r["tf"], source="deferred")
    g = Guess(2 * np.asarray(r["costate0"]), r["tf"] * 1.1, source="first",
              candidates=[lambda: None, made, lambda: made, lambda: 1 / 0, lambda: "x"])
    back = pickle.loads(pickle.dumps(g))
    assert back.source == "first" and np.array_equal(back.costate0, g.costate0)
    skipped = []
    assert [c.source for c in back.iter_all(errors=skipped)] == ["first", "deferred", "deferred"]
    assert len(skipped) == 2 and "ZeroDivisionError" in skipped[0] and "returned str" in skipped[1]
    with pytest.raises(ValueError, match="deferred candidate raised ZeroDivisionError"):
        pickle.loads(pickle.dumps(g)).all()
    # the original keeps its functions; a guess of plain candidates pickles as it is
    assert callable(g.candidates[0]) and len(g.candidates) == 5
    # copying keeps them deferred: nothing is made until the solver (or pickling) asks
    import copy
    calls = []
    lazy = Guess(r["costate0"], r["tf"], candidates=[lambda: calls.append(1) or made])
    for c in (copy.copy(lazy), copy.deepcopy(lazy)):
        assert callable(c.candidates[0]) and np.array_equal(c.costate0, lazy.costate0)
    assert calls == []
    assert [c.source for c in copy.deepcopy(lazy).all()] == ["user", "deferred"] and calls == [1]
    plain = pickle.loads(pickle.dumps(Guess(r["costate0"], r["tf"], candidates=[made])))
    assert [c.source for c in plain.all()] == ["user", "deferred"]


def test_auto_holds_a_costates_only_candidate_until_collocation_shows_no_singular_arc():
    r = _exact()[5]
    prob = SlewProblem.from_dict(r["problem"])

    class Model:
        name = "split"

        def covers(self, problem):
            return None

        def guess(self, problem):   # a wrong structured guess, then the right costates alone
            return Guess(np.array([0, 1, 0, 0, 1, 1, 1.0]), 0.3, [[0.15], [0.15], [0.15]], [1, 1, 1], source="learned",
                         candidates=[Guess(r["costate0"], r["tf"], source="learned-costate")])
    s = solve(prob, warm_start=Model())
    assert s.success and s.exact and s.tf == pytest.approx(r["tf"], rel=1e-7)
    assert s.guess == "learned-costate" and s.warm_start["deferred"] == 1
    assert s.warm_start["succeeded"] and s.warm_start["after_collocation"]
    assert "no singular arc" in s.route and "continuation candidate" in s.route
    assert s.route.startswith("learned guess's structured candidates failed")
    # the indirect method (no collocation) tries every candidate in the warm stage
    s2 = solve(prob, method="indirect", warm_start=Model())
    assert s2.success and s2.guess == "learned-costate" and "after_collocation" not in s2.warm_start
    assert "deferred" not in s2.warm_start and s2.route.startswith("learned guess (split)")


def test_split_continuation_keeps_structured_and_deferred_candidates_first():
    from solvers.warm_routes import split_continuation
    z = np.array([0, 1, 0, 0, 1, 1, 1.0])
    made = lambda: None  # noqa: E731
    g = Guess(z, 1.0, [[0.5], [], []], [1, 1, 1], source="a",
              candidates=[made, Guess(z, 1.1, source="c1"), Guess(z, 1.2, [[], [], []], [1, 1, 1], source="s"),
                          Guess(z, 1.3, source="c2")])
    fast, later = split_continuation(g)
    assert fast.source == "a" and [c if callable(c) else c.source for c in fast.candidates] == [made, "s"]
    assert [c.source for c in later.all()] == ["c1", "c2"]
    assert len(g.candidates) == 4          # the model's guess is not changed
    # nothing to hold back, or no structure of its own: not split
    assert split_continuation(fast) == (fast, None)
    plain = Guess(z, 1.0, source="p", candidates=[Guess(z, 1.1, source="c")])
    assert split_continuation(plain) == (plain, None)


def test_compiled_single_row_inference_matches_the_numpy_batch_path():
    """One row goes through the compiled kernels (network with a rational tanh, decoding); a
    batch through numpy: the two agree to float32 precision, and the decoded structure is the same."""
    from solvers.core.warmstart_kernels import fast_tanh
    from numba import njit

    from solvers.warmstart import MODELS_DIR, load_model

    @njit
    def tanh_all(a):
        out = np.empty_like(a)
        for i in range(a.shape[0]):
            out[i] = fast_tanh(a[i])
        return out

    xs = np.concatenate([np.linspace(-30.0, 30.0, 200001), [5.827876, -5.827876]]).astype(np.float32)
    err = np.abs(tanh_all(xs).astype(np.float64) - np.tanh(xs.astype(np.float64)))
    assert 3e-7 < np.max(err) < 4.2e-7                 # the documented bound, reached near 5.83
    assert tanh_all(np.array([8.0, -50.0], np.float32)).tolist() == [1.0, -1.0]
    for name in ("full-attitude.npz", "pointing-cones.npz"):
        m = load_model(os.path.join(MODELS_DIR, name))
        rng = np.random.default_rng(1)
        X = m.x_mean + m.x_std * rng.normal(size=(100, m.x_mean.shape[0]))
        batch = m.forward(X)
        rows = np.array([m.forward(x)[0] for x in X])
        assert rows.shape == batch.shape
        np.testing.assert_allclose(rows, batch, atol=2e-6 * np.max(np.abs(batch)))


def test_one_call_guess_matches_the_staged_reference():
    """The network's guess comes from one compiled call (canonical form, network, decoding, map
    back); on problems of every axis order, sign, asymmetric body and bound it equals the staged
    reference (``canonical_form``, ``predict_canonical``, ``solution_from_canonical``), and the
    coverage reasons are the same."""
    m = default_model()
    rng = np.random.default_rng(7)
    n_cov = 0
    for i in range(120):
        q0 = rng.normal(size=4)
        qf = rng.normal(size=4)
        J = rng.uniform(0.3, 1.0, 3) if i % 2 else np.ones(3)    # below 0.4: not covered
        u = rng.uniform(0.5, 1.0, 3) if i % 5 == 0 else np.full(3, rng.uniform(0.5, 2.0))
        p = SlewProblem(inertia=J, torque_max=u, q0=q0 / np.linalg.norm(q0), qf=qf / np.linalg.norm(qf))
        g, why = m.guess_or_reason(p, propagate=False)
        why_ref, cf = m._coverage(p)
        assert why == why_ref
        if why:
            continue
        n_cov += 1
        pr = m.predict_canonical(cf.x, cf.T_eig)
        c0, tf, sw, uf = solution_from_canonical(p, cf, pr.z, pr.T, pr.times, pr.u_first)
        np.testing.assert_allclose(g.costate0, c0, rtol=1e-13, atol=1e-15 * np.abs(c0).max())
        assert g.tf == pytest.approx(tf, rel=1e-14)
        np.testing.assert_array_equal(g.u_first, uf)
        for a, b in zip(g.switch_times, sw):
            np.testing.assert_allclose(a, b, rtol=1e-14)
        assert g.source == "learned" and g.touches is None
        assert [c.source for c in g.candidates] == ["learned-costate"]
        assert g.candidates[0].switch_times is None and g.candidates[0].candidates == []
    assert n_cov > 40


def test_compiled_forward_for_each_activation_and_depth_and_a_wrong_row_length():
    from solvers.warmstart.model import output_size
    rng = np.random.default_rng(2)
    n_out = output_size(5)
    for act, hidden in (("tanh", [32]), ("relu", [24, 24]), ("silu", []), ("tanh", [8, 8, 8])):
        sizes = [11] + hidden + [n_out]
        weights = [(rng.normal(size=(a, b)) * 0.5, rng.normal(size=b) * 0.1) for a, b in zip(sizes[:-1], sizes[1:])]
        W0 = np.asarray(weights[0][0], np.float32)
        W0.setflags(write=False)                   # a read-only array must not break the compiled path
        weights[0] = (W0, weights[0][1])
        m = WarmStartModel(weights, rng.normal(size=11), rng.uniform(0.5, 2, 11), {"max_switches": 5, "activation": act})
        X = rng.normal(size=(20, 11))
        batch = m.forward(X)
        rows = np.array([m.forward(x)[0] for x in X])
        np.testing.assert_allclose(rows, batch, atol=2e-6 * np.max(np.abs(batch)))
        m.weights = [(W * 2, b) for W, b in m.weights]         # the compiled path follows a reassignment
        np.testing.assert_allclose(m.forward(X[0])[0], m.forward(X[:2])[0], atol=2e-6 * np.max(np.abs(m.forward(X[:2]))))
        with pytest.raises(ValueError, match="X: expected 11 features, got 10"):
            m.forward(X[0, :10])


def test_decoding_of_the_outputs():
    """decode_attitude on made-up outputs: unit costates, T = T_eig·e^out, signs, the count by
    argmax (a tie to the fewer switches), softmax probabilities, sorted switch instants."""
    from solvers.core.warmstart_kernels import decode_attitude
    from solvers.warmstart.model import output_layout
    K = 3
    L = output_layout(K)
    out = np.zeros(L["times_logit"][1], np.float32)
    out[0:6] = [3, 0, 0, 4, 0, 0]
    out[6] = math.log(2.0)
    out[7:10] = [0.5, -0.1, 0.0]
    c0, t0 = L["count_logits"][0], L["times_logit"][0]
    out[c0:c0 + 4] = [0, 0, 3, 1]                       # axis 0: 2 switches
    out[c0 + 4:c0 + 8] = [2, 2, 0, 0]                   # axis 1: a tie between 0 and 1 -> 0
    out[c0 + 8:c0 + 12] = [0, 0, 0, 5]                  # axis 2: 3 switches
    out[t0:t0 + 3] = [1.0, -1.0, 9.0]                   # axis 0 uses the first 2, unsorted
    out[t0 + 6:t0 + 9] = [0.3, -2.0, 0.1]
    z, T, uf, counts, cp, tt = decode_attitude(out, K, L["z"][0], L["log_T_ratio"][0], L["u_first_logit"][0],
                                               c0, t0, 1.5)
    np.testing.assert_allclose(z, [0.6, 0, 0, 0.8, 0, 0], atol=1e-7)
    assert T == pytest.approx(3.0, rel=1e-7)
    np.testing.assert_array_equal(uf, [1, -1, 1])
    np.testing.assert_array_equal(counts, [2, 0, 3])
    np.testing.assert_allclose(cp.sum(axis=1), 1.0)
    np.testing.assert_allclose(cp[0], np.exp([0, 0, 3, 1]) / np.exp([0, 0, 3, 1]).sum(), rtol=1e-6)
    sig = lambda v: 1 / (1 + np.exp(-np.asarray(v, float)))
    np.testing.assert_allclose(tt[0, :2], 3.0 * np.sort(sig([1.0, -1.0])), rtol=1e-6)
    np.testing.assert_allclose(tt[2, :3], 3.0 * np.sort(sig([0.3, -2.0, 0.1])), rtol=1e-6)


def test_canonical_form_of_a_tie_and_its_eigenaxis_time():
    """About (1, -1, 0)/√2: |n_1| = |n_2| keeps the axis order; n'_1, n'_2 ≥ 0 and det A = +1;
    T_eig = 2√(θ/acc) with acc the largest constant acceleration about n' under the bound."""
    n = np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0)
    th = 1.2
    p = SlewProblem(inertia=[0.5, 0.8, 1.0], torque_max=[1.0, 0.5, 1.0],
                    qf=[math.cos(th / 2), *(math.sin(th / 2) * n)])
    cf = canonical_form(p)
    assert cf.order == (0, 1, 2)
    np.testing.assert_allclose(cf.A, np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_allclose(cf.x[:3], [1 / math.sqrt(2), 1 / math.sqrt(2), 0.0], atol=1e-15)
    assert cf.x[3] == pytest.approx(th / math.pi)
    np.testing.assert_allclose(cf.x[4:7], [0.5, 0.8, 1.0])
    np.testing.assert_allclose(cf.x[7:10], [1.0, 0.5, 1.0])
    acc = 1.0 / max(0.5 / math.sqrt(2) / 1.0, 0.8 / math.sqrt(2) / 0.5)
    assert cf.T_eig == pytest.approx(2 * math.sqrt(th / acc), rel=1e-14)


def test_the_final_time_gap_needs_a_second_guess_on_the_same_problem():
    from training.warmstart.evaluate import summarise

    def row(i, g, tf):
        return {"index": i, "guess": g, "covered": True, "success": tf is not None, "exact": tf is not None,
                "tf": tf, "nit": 3, "wall_time_s": 0.01}
    alone = [row(0, "learned", 2.0), row(1, "learned", 3.0)]
    s = summarise(alone)
    # a guess alone is not "at best" against itself: nothing is measured
    assert s["gap_problems"] == 0 and math.isnan(s["learned"]["gap_median"])
    assert math.isnan(s["learned"]["share_at_best"])
    # with a second guess on problem 0 (faster by 1 %) and only learned on problem 1
    s = summarise(alone + [row(0, "eigenaxis", 2.0 / 1.01)])
    assert s["gap_problems"] == 1
    assert s["learned"]["gap_median"] == pytest.approx(0.01)
    assert s["learned"]["share_at_best"] == 0.0 and s["eigenaxis"]["share_at_best"] == 1.0
