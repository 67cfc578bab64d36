"""The shipped full-attitude warm start: the network, then the nearest tabled solutions."""
import json
import os

import numpy as np
import pytest

from solvers import solve, auto_route
from solvers.warmstart import (DEFAULT_TABLE_FILE, ModelFileError, NearestNeighbourModel, WarmStartModel,
                               default_model, default_warm_start, load_model)
from solvers.warmstart.attitude_ensemble import AttitudeEnsembleWarmStart
from training.generate import GenerationSpec, problem_for

DATA = os.path.join(os.path.dirname(__file__), "data", "full-attitude-small.jsonl")


def _exact():
    rows = [json.loads(line) for line in open(DATA).read().splitlines()[1:]]
    return [r for r in rows if r["method"] == "indirect"]


def _table(k=3):
    from training.warmstart.data import training_arrays
    a = training_arrays([DATA])
    return NearestNeighbourModel(a["X"], a["Z"], a["T"], a["T_eig"], a["U"], a["S"], k=k)


def _sources(g):
    return [c if callable(c) else c.source for c in [g] + list(g.candidates)]


def test_the_default_warm_start_is_the_network_then_the_table():
    m = default_warm_start()
    assert isinstance(m, AttitudeEnsembleWarmStart)
    assert m.network is default_model() and m.table.domain == m.network.domain
    assert m.table.X.shape[0] > 30_000 and os.path.getsize(DEFAULT_TABLE_FILE) < 4_000_000
    p = problem_for(GenerationSpec("full-attitude", seed=20261122), 0)
    g = m.guess(p)
    src = _sources(g)
    # the network's guess, its propagated structure, the three nearest solutions and five more
    # (all deferred: callables), and last the network's costates alone
    assert src[0] == "learned" and all(callable(c) for c in src[1:10])
    assert src[10] == "learned-costate" and len(src) == 11
    made = [c.source for c in g.iter_all()]
    assert made[2:5] == ["nearest-neighbour[0]", "nearest-neighbour[1]", "nearest-neighbour[2]"]
    assert g.inference_s > 0
    assert m.covers(p) is None and "rate_max" in m.covers(p.replace(rate_max=0.5))


def test_a_neighbour_answers_where_the_network_fails():
    # a network with every weight zero predicts no switches and a rotation about nothing:
    # its candidates fail, and the tabled solution of the same problem converges at once
    net = default_model()
    zero = WarmStartModel([(np.zeros_like(W), np.zeros_like(b)) for W, b in net.weights], net.x_mean, net.x_std,
                          net.card)
    ens = AttitudeEnsembleWarmStart(zero, _table())
    r = _exact()[3]
    s = solve(r["problem"], method="indirect", warm_start=ens)
    assert s.success and s.exact and s.guess == "nearest-neighbour[0]"
    assert s.tf == pytest.approx(r["tf"], rel=1e-9)
    assert s.warm_start["succeeded"] and s.warm_start["model"] == ens.name


def test_auto_tries_the_neighbours_before_collocation():
    # auto holds the costates-only candidate until after collocation; the neighbours are not held
    net = default_model()
    zero = WarmStartModel([(np.zeros_like(W), np.zeros_like(b)) for W, b in net.weights], net.x_mean, net.x_std,
                          net.card)
    r = _exact()[3]
    s = solve(r["problem"], warm_start=AttitudeEnsembleWarmStart(zero, _table()))
    assert s.success and s.guess == "nearest-neighbour[0]" and "collocation" not in s.route
    assert s.warm_start["deferred"] == 1


def test_ensemble_rejects_wrong_parts():
    with pytest.raises(ValueError, match="ensemble needs"):
        AttitudeEnsembleWarmStart(_table(), _table())
    with pytest.raises(ValueError, match="n_neighbours"):
        AttitudeEnsembleWarmStart(default_model(), _table(), n_neighbours=0)


def test_compact_table_round_trip_and_damaged_files(tmp_path):
    t = _table()
    t.save(tmp_path / "c.nn.npz", compact=True)
    t2 = load_model(tmp_path / "c.nn.npz")
    np.testing.assert_allclose(t2.Z, t.Z, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(t2.T, t.T, rtol=1e-6)
    r = _exact()[5]
    g1, g2 = t.guess(r["problem"], k=2), t2.guess(r["problem"], k=2)
    assert len(g2.candidates) == 1 and g2.source == g1.source
    np.testing.assert_allclose(g2.costate0, g1.costate0, rtol=1e-5, atol=1e-6)
    # a table whose arrays disagree in length is refused with the reason, not an IndexError later
    with np.load(tmp_path / "c.nn.npz") as f:
        arrays = {k: f[k] for k in f.files}
    np.savez(tmp_path / "bad.nn.npz", **dict(arrays, Z=arrays["Z"][:-1]))
    with pytest.raises(ModelFileError, match="one row per tabled problem"):
        load_model(tmp_path / "bad.nn.npz")
    np.savez(tmp_path / "nan.nn.npz", **dict(arrays, T=arrays["T"] * np.nan))
    with pytest.raises(ModelFileError, match="times positive"):
        load_model(tmp_path / "nan.nn.npz")


def test_training_writes_the_table_next_to_the_model(tmp_path):
    pytest.importorskip("torch")
    from training.warmstart.train import table_path, train
    s = train([DATA], tmp_path / "a", seed=3, epochs=2, progress_bar=False)
    assert s["table"] == table_path(s["model"]) and os.path.exists(s["table"])
    t = load_model(s["table"])
    assert type(t) is NearestNeighbourModel and t.X.shape[0] == 69 and t.domain == WarmStartModel.load(s["model"]).domain


def test_degenerate_guess_is_an_error_from_a_user_and_a_failed_candidate_from_a_model():
    from solvers import Guess
    r = _exact()[3]
    zero = Guess(np.zeros(7), r["tf"], source="mine")
    with pytest.raises(ValueError, match="costate is zero"):
        solve(r["problem"], method="indirect", guess=zero)

    class ZeroModel:
        name = "zero"

        def covers(self, problem):
            return None

        def guess(self, problem):
            return Guess(np.zeros(7), r["tf"], source="learned")

    s = solve(r["problem"], method="indirect", warm_start=ZeroModel(), max_candidates=3)
    assert s.warm_start["succeeded"] is False and s.warm_start["candidates"] == 0
    assert s.success and s.tf == pytest.approx(r["tf"], rel=1e-9)
    assert "unusable guess" in s.route


def _held_out(i):
    return problem_for(GenerationSpec("full-attitude", seed=20261122), i)


def test_more_neighbours_only_where_the_singular_table_does_not_vote_singular():
    m = default_warm_start()
    assert m.singular_table is not None and m.n_more == 5
    # held-out 5: all 5 nearest tabled problems singular; 465: a bang-bang optimum that the
    # network and the 3 nearest miss, and the 4th nearest solution reaches
    sing, share = _held_out(5), m.singular_table.query(_held_out(5))[0]
    assert share >= m.singular_table.vote
    assert [g.source for g in m.guess(sing).iter_all()] == [
        "learned", "learned-propagated", "nearest-neighbour[0]", "nearest-neighbour[1]", "nearest-neighbour[2]",
        "learned-costate"]
    p = _held_out(465)
    assert m.singular_table.query(p)[0] < m.singular_table.vote
    src = [g.source for g in m.guess(p).iter_all()]
    assert src[-6:] == [f"nearest-neighbour[{k}]" for k in range(3, 8)] + ["learned-costate"]
    # (a loaded machine must not cut the 6th candidate; nor may compiling a kernel the first time
    # in a fresh clone, inside the warm stage: in a clean-clone run beside another job it did,
    # and the route's neighbour sequences answered. The second solve times solving alone)
    solve(p, warm_budget=5.0)
    s = solve(p, warm_budget=5.0)
    assert s.success and s.exact and s.guess == "nearest-neighbour[3]" and "collocation" not in s.route


def test_a_model_guess_runs_alone_without_classical_candidates():
    from solvers import Guess

    class Wrong:              # a guess that fails, and a deferred candidate that gives nothing
        name = "wrong"

        def covers(self, problem):
            return None

        def guess(self, problem):
            g = Guess(np.array([0, 1, 0, 0, 1, 1, 1.0]), 0.3, [[0.15], [0.15], [0.15]], [1, 1, 1], source="learned")
            g.candidates = [lambda: None]
            return g

    r = _exact()[3]
    s = solve(r["problem"], method="indirect", warm_start=Wrong())
    # the empty slot is not handed to the eigenaxis guess inside the warm stage
    assert s.warm_start["succeeded"] is False and s.warm_start["candidates"] == 1
    assert s.success and s.route.startswith("learned guess failed")


def test_auto_challenges_a_learned_answer_much_slower_than_predicted():
    # held-out 789: the network's guess fails and the 2nd nearest solution converges to a local
    # extremal 1.6 % above the network's predicted time (1.6575 vs 1.6311); the collocation route
    # finds the optimum, 1.2 % faster
    s = solve(_held_out(789), warm_budget=5.0)      # (the 2nd neighbour is reached on a loaded machine too)
    rec = s.warm_start["local_optimum_check"]
    assert rec["won"] and rec["tf"] == pytest.approx(1.65752232, rel=1e-7)
    assert s.warm_start["succeeded"] is False        # the answer is the challenger's
    assert rec["tf"] > rec["predicted_tf"] * 1.015
    assert s.success and s.exact and s.tf == pytest.approx(1.63743643, rel=1e-7) and s.guess == "collocation"
    assert "above the model's predicted" in s.route
    # an answer near the prediction is not challenged
    s0 = solve(_held_out(0))
    assert s0.guess == "learned" and "local_optimum_check" not in s0.warm_start
    assert s0.tf <= s0.warm_start["predicted_tf"] * 1.015


def test_the_challenge_respects_the_time_budget():
    solve(_held_out(789), warm_budget=5.0)    # every kernel on this path compiled or loaded
    s = solve(_held_out(789), time_budget=0.3, warm_budget=0.25)
    # the neighbour's local extremal, kept: no time for the collocation route
    rec = s.warm_start["local_optimum_check"]
    assert s.success and s.warm_start["succeeded"] and s.tf == pytest.approx(1.65752232, rel=1e-7)
    assert rec["skipped"].startswith("time_budget") and "challenger_tf" not in rec


def test_only_a_model_that_predicts_the_time_is_challenged():
    # the table alone as the warm start: a neighbour's time is not a prediction
    s = solve(_held_out(789), warm_start=load_model(DEFAULT_TABLE_FILE))
    assert "predicted_tf" not in s.warm_start and "local_optimum_check" not in s.warm_start
    assert default_model().guess(_held_out(789)).predicted_tf == pytest.approx(1.63115, rel=1e-4)


def test_a_damaged_shipped_table_leaves_the_network_and_is_recorded(tmp_path, monkeypatch):
    import solvers.warmstart as ws
    bad = tmp_path / "full-attitude.nn.npz"
    bad.write_bytes(open(DEFAULT_TABLE_FILE, "rb").read()[:1000])
    monkeypatch.setattr(ws, "DEFAULT_TABLE_FILE", str(bad))
    m = ws.default_warm_start()
    assert m is default_model()
    s = solve(_held_out(0))
    assert s.success and s.guess == "learned" and "not a readable" in s.warm_start["table_error"]
    assert ws.default_warm_start() is default_model()     # not read again while the file is unchanged


def test_bad_model_candidates_are_failed_candidates_not_exceptions():
    from solvers import Guess
    r = _exact()[3]

    def boom():
        raise RuntimeError("model bug")

    class Bad:
        name = "bad"

        def __init__(self, extra):
            self.extra = extra

        def covers(self, problem):
            return None

        def guess(self, problem):
            g = Guess(np.array([0, 1, 0, 0, 1, 1, 1.0]), 0.3, [[0.15], [0.15], [0.15]], [1, 1, 1], source="learned")
            g.candidates = list(self.extra)
            return g

    for extra in ([boom], [lambda: 42], [lambda: Guess(np.ones(7), 1.0, [[0.5], [], []], [1, 1], source="x")]):
        for method in ("indirect", "auto"):
            s = solve(r["problem"], method=method, warm_start=Bad(extra))
            assert s.success and s.warm_start["succeeded"] is False, (extra, method)
    # a deferred candidate with malformed signs: skipped, and the reason is in the route
    s = solve(r["problem"], method="indirect", warm_start=Bad([lambda: Guess(np.ones(7), 1.0, u_first=[1, 1])]))
    assert s.success and "u_first" in s.route


def test_cli_says_when_the_collocation_route_beat_the_learned_guess(tmp_path, capsys):
    from training.cli import main
    path = tmp_path / "p789.json"
    path.write_text(json.dumps(_held_out(789).to_dict()))
    solve(_held_out(789), warm_budget=5.0)    # kernels loaded: the 1 s warm budget reaches the 2nd neighbour
    assert main(["solve", str(path)]) == 0
    out = capsys.readouterr().out
    assert "above the predicted time, likely a local optimum); the collocation route found a faster answer" in out
    assert "guess         collocation" in out


def test_a_faster_switch_time_slew_beats_a_local_extremal():
    # bench_solver's problem 99 (seed 1): the 8th nearest solution converges to an exact extremal
    # 3.2 % above the network's predicted time; the optimum has a singular arc, and the collocation
    # route's bang-bang slew with optimised switch times is 3.1 % faster: it is the answer
    from slew_env import SlewProblem
    p = SlewProblem(inertia=[0.35015398069615, 0.7351693128988736, 0.8265504518087083],
                    q0=[0.15833771429963162, -0.521062390730974, -0.7659247855777316, -0.3417343647247024],
                    qf=[0.43318841955645965, -0.4647876784819946, 0.7683443059928374, -0.07724787726455516])
    s = solve(p, warm_budget=5.0)
    rec = s.warm_start["local_optimum_check"]
    assert rec["won"] and not rec["challenger_exact"] and rec["tf"] == pytest.approx(2.46588316, rel=1e-7)
    assert s.success and s.method == "switch-time" and not s.exact
    assert s.tf + s.tf_tol < rec["tf"] and s.tf == pytest.approx(2.3902, rel=1e-3)
    assert "not an extremal" in s.route and s.warm_start["succeeded"] is False


def test_evaluate_reports_the_network_and_the_table_query_apart(tmp_path):
    from training.warmstart.evaluate import evaluate
    s = evaluate(n=2, baseline_n=0, workers=1, out=str(tmp_path), progress_bar=False)
    assert s["learned"]["n"] == 2 and 0 < s["inference_s_median"] < 0.01 and 0 < s["table_query_s_median"] < 0.01
    assert 0 < s["network_s_median"] < 0.01
    report = open(tmp_path / "report.md").read()
    assert "the model's whole call as solve makes it" in report and "The canonical form + network alone" in report
    assert "The table's query" in report


def test_near_a_half_turn_auto_also_runs_the_collocation_route():
    # held-out 623, a 175.9° slew: the nearest solution converges to an extremal within 0.2 % of the
    # predicted time, but the collocation route finds one 0.87 % faster (near a half turn the short
    # and long ways round and their mirror images are nearly degenerate extremals)
    import math
    p = _held_out(623)
    assert 170.0 < math.degrees(p.slew_angle) < 180.0
    s = solve(p, warm_budget=5.0)
    rec = s.warm_start["local_optimum_check"]
    assert rec["reason"] == "near a half turn" and rec["won"] and s.warm_start["succeeded"] is False
    assert s.success and s.exact and s.tf == pytest.approx(2.54269746, rel=1e-7)
    # off: the learned answer at once
    fast = solve(p, warm_budget=5.0, local_optimum_check=False)
    assert "local_optimum_check" not in fast.warm_start and fast.warm_start["succeeded"]
    assert fast.exact and fast.tf == pytest.approx(2.56494756, rel=1e-7)
    with pytest.raises(ValueError, match="local_optimum_check"):
        solve(p, local_optimum_check="yes")


def test_a_half_turn_check_that_confirms_the_learned_answer_leaves_a_trace(tmp_path, capsys):
    # held-out 65, a 178° slew: the network's own extremal is the best the collocation route finds
    s = solve(_held_out(65), warm_budget=5.0)
    rec = s.warm_start["local_optimum_check"]
    assert rec["reason"] == "near a half turn" and not rec["won"] and rec["time_s"] > 0
    assert s.guess == "learned" and s.warm_start["succeeded"] and s.exact
    assert rec["challenger_exact"] and rec["challenger_tf"] == pytest.approx(s.tf, rel=1e-8)
    assert "(checked, near a half turn: the collocation route gave" in s.route
    # and the CLI says why a half-turn challenger won (held-out 623)
    from training.cli import main
    path = tmp_path / "p623.json"
    path.write_text(json.dumps(_held_out(623).to_dict()))
    assert main(["solve", str(path)]) == 0
    out = capsys.readouterr().out
    assert "(a slew near a half turn, likely a local optimum); the collocation route found a faster answer" in out
    # --no-local-optimum-check: the learned answer at once
    assert main(["solve", str(path), "--no-local-optimum-check", "--repeat", "0"]) == 0
    out = capsys.readouterr().out
    assert "its guess won" in out and "guess         nearest-neighbour[0]" in out and "checked" not in out


def test_a_challenger_that_raises_leaves_the_verified_answer(monkeypatch):

    def broken(*a, **k):
        raise RuntimeError("collocation broke")
    monkeypatch.setattr(auto_route, "solve_auto", broken)
    s = solve(_held_out(623), warm_budget=5.0)
    rec = s.warm_start["local_optimum_check"]
    assert s.success and s.guess == "nearest-neighbour[0]" and "collocation broke" in rec["error"]


def test_an_uncertain_singular_vote_keeps_the_exact_extremal():
    # held-out 377: 2 of the 5 nearest tabled problems singular; its optimum is bang-bang, but
    # every learned candidate fails. The table's bang-bang answer is 8.7e-7 slower; collocation
    # shows no singular arc, and its refinement certifies the extremal (the best known answer)
    p = _held_out(377)
    m = default_warm_start()
    assert 0.2 <= m.singular_table.query(p)[0] < m.singular_table.vote
    s = solve(p)
    rec = s.warm_start["singular_table"]
    assert s.success and s.exact and s.method == "indirect"
    assert rec["uncertain"] is True and rec["exact_check"] == "an exact extremal, no slower"
    assert "uncertain" in s.route and s.tf == pytest.approx(2.2701855619728395, rel=1e-9)
