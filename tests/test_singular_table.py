"""The singular table: which problems have a singular arc, and auto's route through the near
singular answers' switching sequences (no collocation)."""
import json
import os

import numpy as np
import pytest

import solvers.warmstart as warmstart
from slew_env import SlewProblem
from solvers import solve
from solvers.switch_time_opt import bang_bang_from_sequences
from solvers.warmstart import ModelFileError
from solvers.warmstart.singular_table import SingularTable
from training.warmstart.singular_table import build, main

from test_switch_time_opt import SINGULAR, _replay

DATA = os.path.join(os.path.dirname(__file__), "data", "full-attitude-small.jsonl")
EXAMPLES = os.path.join(os.path.dirname(__file__), os.pardir, "examples")
# SINGULAR's answer by the collocation route (a bang-bang slew of optimised switch times)
SINGULAR_TF = 1.67520601


@pytest.fixture(scope="module")
def singular_answer():
    s = solve(SINGULAR, warm_start=None)
    assert s.method == "switch-time" and s.tf == pytest.approx(SINGULAR_TF, rel=1e-6)
    return s


def _dataset(path, singular_answer, with_singular=True):
    lines = open(DATA).read().splitlines()
    recs = [json.loads(l) for l in lines[1:]]
    exact = [r for r in recs if r.get("method") == "indirect"][:12]
    for r in exact:
        r["exact"] = True
    out = [lines[0]] + [json.dumps(r) for r in exact]
    if with_singular:
        d = singular_answer.to_dict()
        rec = {"index": 10_000, "problem": SINGULAR.to_dict(), "success": True, "exact": False,
               "method": "switch-time", "tf": d["tf"], "switch_times": d["switch_times"], "u_first": d["u_first"]}
        out.append(json.dumps(rec))
    # a collocation answer is left out
    out.append(json.dumps({"index": 10_001, "problem": SINGULAR.to_dict(), "success": True, "exact": False,
                           "method": "collocation", "tf": 1.7, "switch_times": [[], [], []], "u_first": [1, 1, 1]}))
    path.write_text("\n".join(out) + "\n")
    return str(path)


def _solve_with_table(path, monkeypatch):
    """``solve(SINGULAR)`` with the table file ``path`` in place of the shipped one."""
    monkeypatch.setattr(warmstart, "DEFAULT_SINGULAR_TABLE_FILE", str(path))
    warmstart.default_singular_table.cache_clear()
    try:
        return solve(SINGULAR)
    finally:
        warmstart.default_singular_table.cache_clear()


def test_table_builds_saves_loads_and_maps_the_sequence_back(tmp_path, singular_answer):
    data = _dataset(tmp_path / "d.jsonl", singular_answer)
    t = build([data], k=3, vote=0.3, n_sequences=2, tf_rel_tol=1e-4)
    assert t.training["singular"] == 1 and t.training["exact"] == 12 and t.training["left_out"] >= 1
    t.save(tmp_path / "t.npz")
    t2 = SingularTable.load(tmp_path / "t.npz")
    assert t2.vote == 0.3 and t2.k == 3 and t2.tf_rel_tol == 1e-4 and t2.singular.sum() == 1
    share, seqs = t2.query(SINGULAR)
    # the problem itself is its own nearest neighbour: 1 singular in its 3 nearest, and its own
    # sequence comes back in its own axes and units (float32 storage)
    assert share == pytest.approx(1 / 3) and len(seqs) == 1
    uf, sw, tf = seqs[0]
    np.testing.assert_array_equal(uf, singular_answer.u_first)
    assert tf == pytest.approx(singular_answer.tf, rel=1e-12)
    for a in range(3):
        np.testing.assert_allclose(sw[a], singular_answer.switch_times[a], rtol=1e-6, atol=1e-6)


def test_bang_bang_from_a_near_sequence_reaches_the_same_answer(singular_answer):
    s = singular_answer
    # the answer's own sequence, with its instants moved by 1 % of tf
    rng = np.random.default_rng(1)
    sw = [np.sort(np.clip(a + 0.01 * s.tf * rng.standard_normal(a.size), 0, s.tf)) for a in s.switch_times]
    ans, kkt, (nit, nfev) = bang_bang_from_sequences(SINGULAR, [(s.u_first, sw, 1.01 * s.tf)], time_budget=2.0,
                                                     tf_rel_tol=1e-4)
    assert ans is not None and ans.method == "switch-time" and not ans.exact
    assert ans.nit == nit > 0 and ans.nfev == nfev > 0
    assert ans.tf == pytest.approx(SINGULAR_TF, rel=1e-6)
    assert max(_replay(SINGULAR, ans.switch_times, ans.u_first, ans.tf)) < 1e-9
    assert ans.tf_tol == pytest.approx(1e-4 * ans.tf) and "not compared with collocation" in ans.message
    # a singular problem's sequence is not stationary after 60 iterations: no KKT guess
    assert kkt is None
    # a bang-bang optimum's own sequence is: its KKT costates come back for the exact solver
    r3 = SlewProblem.from_dict(json.load(open(os.path.join(EXAMPLES, "r3_seed_report_per_axis.json"))))
    e = solve(r3, warm_start=None)
    sw3 = [a * 1.01 for a in e.switch_times]
    ans3, kkt3, _ = bang_bang_from_sequences(r3, [(e.u_first, sw3, 1.01 * e.tf)], time_budget=2.0)
    assert ans3.tf == pytest.approx(e.tf, rel=1e-9) and kkt3 is not None
    assert kkt3.source == "switch-time optimisation"
    assert solve(r3, guess=kkt3, method="indirect", warm_start=None).tf == pytest.approx(e.tf, rel=1e-10)
    # no tolerance measured: none claimed
    ans2, _, _ = bang_bang_from_sequences(SINGULAR, [(s.u_first, sw, 1.01 * s.tf)], time_budget=2.0)
    assert np.isnan(ans2.tf_tol)
    # what it does not cover
    assert bang_bang_from_sequences(SINGULAR.replace(torque_norm=2.0), [(s.u_first, sw, s.tf)]) == (None, None, (0, 0))


def test_auto_takes_the_table_route_when_the_learned_guess_fails(tmp_path, singular_answer, monkeypatch):
    data = _dataset(tmp_path / "d.jsonl", singular_answer)
    build([data], k=1, vote=1.0, n_sequences=1, tf_rel_tol=1e-4).save(tmp_path / "t.npz")
    s = _solve_with_table(tmp_path / "t.npz", monkeypatch)
    assert s.success and s.method == "switch-time" and not s.exact
    assert s.warm_start["singular_table"]["used"] and s.warm_start["singular_table"]["share"] == 1.0
    assert "singular table" in s.route and "collocation" not in s.route.split("→", 2)[-1]
    assert s.tf == pytest.approx(SINGULAR_TF, rel=1e-6) and s.tf < s.baseline_tf
    assert max(_replay(SINGULAR, s.switch_times, s.u_first, s.tf)) < 1e-9
    # no table route without the default model
    s2 = solve(SINGULAR, warm_start=None)
    assert "singular table" not in s2.route


def test_a_table_that_votes_no_leaves_the_collocation_route(tmp_path, singular_answer, monkeypatch):
    data = _dataset(tmp_path / "d.jsonl", singular_answer)
    # 1 of the 6 nearest is singular: below the uncertain tier's share (0.2)
    build([data], k=6, vote=0.9, n_sequences=1).save(tmp_path / "t.npz")
    s = _solve_with_table(tmp_path / "t.npz", monkeypatch)
    assert s.success and s.warm_start["singular_table"]["used"] is False
    assert s.warm_start["singular_table"]["share"] == pytest.approx(1 / 6)
    assert "singular table" not in s.route and "collocation" in s.route


def test_an_uncertain_vote_answers_from_the_table_after_collocation_sees_a_singular_arc(
        tmp_path, singular_answer, monkeypatch):
    data = _dataset(tmp_path / "d.jsonl", singular_answer)
    # 1 of the 3 nearest is singular: below the vote (0.9), above the uncertain share (0.2)
    build([data], k=3, vote=0.9, n_sequences=1, tf_rel_tol=5e-4).save(tmp_path / "t.npz")
    s = _solve_with_table(tmp_path / "t.npz", monkeypatch)
    rec = s.warm_start["singular_table"]
    assert s.success and s.method == "switch-time" and not s.exact
    assert rec["used"] is True and rec["uncertain"] is True
    # collocation checked for an exact extremal and found the singular arc
    assert "singular arc" in rec["exact_check"]
    assert s.route.startswith("learned") and "singular table" in s.route
    assert s.tf == pytest.approx(SINGULAR_TF, rel=5e-4) and s.tf < s.baseline_tf
    assert max(_replay(SINGULAR, s.switch_times, s.u_first, s.tf)) < 1e-9


def test_a_damaged_table_is_recorded_and_the_solve_goes_on(tmp_path, monkeypatch):
    bad = tmp_path / "t.npz"
    bad.write_bytes(b"not an npz file")
    with pytest.raises(ModelFileError):
        SingularTable.load(bad)
    s = _solve_with_table(bad, monkeypatch)
    assert s.success and "error" in s.warm_start["singular_table"]


def test_builder_refuses_data_without_singular_answers(tmp_path, singular_answer, capsys):
    data = _dataset(tmp_path / "d.jsonl", singular_answer, with_singular=False)
    assert main(["--data", data, "--out", str(tmp_path / "t.npz"), "--tf-rel-tol", "5e-4"]) == 2
    assert "no switch-time (singular) records" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--data", data, "--out", str(tmp_path / "t.npz"), "--vote", "0", "--tf-rel-tol", "5e-4"])
    with pytest.raises(ValueError, match="not covered"):
        build([_dataset(tmp_path / "e.jsonl", singular_answer)]).query(SINGULAR.replace(rate_max=1.0))


@pytest.fixture(scope="module")
def held_out_28():
    """Held-out problem 28 (seed 20261122, J = I): singular, and among singular ones in the shipped
    table; with its answer by the collocation route."""
    from training.generate import GenerationSpec, problem_for
    p = problem_for(GenerationSpec("full-attitude", seed=20261122), 28)
    ref = solve(p, singular_table=False)
    assert ref.method == "switch-time" and "singular table" not in ref.route
    return p, ref


def test_the_shipped_table_answers_a_held_out_singular_problem(held_out_28):
    p, ref = held_out_28
    t = warmstart.default_singular_table()
    assert t is not None and t.training["singular"] > 2000 and t.tf_rel_tol == 5e-4
    share, seqs = t.query(p)
    assert share >= t.vote and len(seqs) == t.n_sequences
    s = solve(p)
    assert s.success and s.method == "switch-time" and s.warm_start["singular_table"]["used"]
    assert s.route.startswith("learned guess's structured candidates failed") and "singular table" in s.route
    assert "collocation" not in s.route.split("singular table", 1)[1]
    # as fast as the collocation route's answer to within the reported tolerance, exactly feasible
    assert ref.tf * (1 - 1e-6) <= s.tf <= ref.tf * (1 + 5e-4)
    assert s.tf_tol == pytest.approx(5e-4 * s.tf) and s.tf < s.baseline_tf
    assert max(_replay(p, s.switch_times, s.u_first, s.tf)) < 1e-9
    assert s.verification["eigenaxis_baseline"]["passed"] and s.verification["replay"]["passed"]
    # costate0: the KKT multipliers' estimate (the iterate is not stationary: no dense costates);
    # a dataset keeps the answer as a verified record
    assert np.all(np.isfinite(s.costate0)) and np.all(np.isnan(s.costate))
    from training.generate import _verified
    assert _verified(json.loads(json.dumps(s.to_dict()))) is None
    with pytest.raises(ValueError, match="singular_table"):
        solve(p, singular_table="yes")


def test_evaluate_reports_the_model_with_the_table_next_to_the_model_alone(held_out_28):
    from training.warmstart import evaluate as ev
    ev._init(None, None)
    rows = ev._run_one(("full-attitude", 20261122, 28, ("learned", "learned+table"), 2.0, 1.0))
    learned, table = rows
    assert learned["guess"] == "learned" and learned["success"] is False
    assert table["guess"] == "learned+table" and table["success"] and table["exact"] is False
    assert table["won"].startswith("the singular table") and table["wall_time_s"] > learned["wall_time_s"]
    assert table["tf"] == pytest.approx(held_out_28[1].tf, rel=5e-4)
    s = ev.summarise(rows)
    assert s["learned"]["converged"] == 0 and s["learned+table"]["converged"] == 1 and s["learned+table"]["exact"] == 0
    s.update(family="full-attitude", n=1, seed=20261122, baseline_n=0, model="default", workers=1,
             inference_s_median=1e-4)
    assert "| learned+table | 1 | 0 | 1 (100.0 % verified, 0 exact)" in ev.markdown(s)      # 0: not covered


@pytest.mark.parametrize("j_scale, u_scale", [(100.0, 0.25), (0.01, 1.0)])
def test_the_table_route_works_in_any_units(held_out_28, j_scale, u_scale):
    # the same slew with scaled inertia and torque: time scales by sqrt(j/u); the eigenaxis
    # check must compare times in the problem's own units (it did not, found by an audit)
    p0, ref = held_out_28
    p = p0.replace(inertia=j_scale * np.asarray(p0.inertia), torque_max=u_scale * np.asarray(p0.torque_max))
    tau = (j_scale / u_scale) ** 0.5
    s = solve(p)
    assert s.success and s.warm_start["singular_table"]["used"] and s.method == "switch-time"
    assert s.tf == pytest.approx(tau * ref.tf, rel=5e-4)
    eig = solve(p, method="eigenaxis")
    assert s.tf < eig.tf and s.baseline_tf <= eig.tf * (1 + 1e-4) and s.baseline_tf == pytest.approx(eig.tf, rel=1e-3)
    assert max(_replay(p, s.switch_times, s.u_first, s.tf)) < 1e-9 * max(1.0, tau)


@pytest.mark.parametrize("change", ["k0", "vote0", "t_eig_short"])
def test_a_loadable_but_inconsistent_table_is_refused_and_the_solve_goes_on(tmp_path, singular_answer, monkeypatch,
                                                                             change):
    data = _dataset(tmp_path / "d.jsonl", singular_answer)
    build([data], k=1, vote=1.0, n_sequences=1, tf_rel_tol=1e-4).save(tmp_path / "t.npz")
    d = dict(np.load(tmp_path / "t.npz"))
    card = json.loads(str(d["card"]))
    if change == "k0":
        card["k"] = 0
    elif change == "vote0":
        card["vote"] = 0.0
    else:
        d["T_eig"] = d["T_eig"][:0]
    d["card"] = np.array(json.dumps(card))
    np.savez(tmp_path / "bad.npz", **d)
    with pytest.raises(ModelFileError, match="not a usable singular table"):
        SingularTable.load(tmp_path / "bad.npz")
    s = _solve_with_table(tmp_path / "bad.npz", monkeypatch)
    assert s.success and "not a usable singular table" in s.warm_start["singular_table"]["error"]


def test_of_several_sequences_the_fastest_verified_answer_is_kept(singular_answer):
    s = singular_answer
    # a poor sequence first (one switch per axis: far fewer switches than the singular arc wants),
    # then the answer's own: both are optimised and the faster kept
    poor = ([1.0, 1.0, 1.0], [np.array([0.5 * s.tf])] * 3, s.tf)
    good = (s.u_first, s.switch_times, s.tf)
    one, _, w1 = bang_bang_from_sequences(SINGULAR, [good], time_budget=2.0, max_iter=10)
    both, _, w2 = bang_bang_from_sequences(SINGULAR, [poor, good], time_budget=2.0, max_iter=10)
    assert both.n_candidates == 2 and both.tf == pytest.approx(one.tf, rel=1e-12)
    assert "of table 2" in both.route and "2 sequence(s) tried" in both.route
    assert w2[0] > w1[0] and both.nit == w2[0]


def test_a_table_answer_that_is_a_kkt_point_goes_on_to_the_exact_extremal(tmp_path, monkeypatch):
    # R3 has a bang-bang optimum; a table holding its answer as if singular gives a KKT point of
    # the right sequence, and the exact solver certifies the extremal from its KKT costates
    r3 = SlewProblem.from_dict(json.load(open(os.path.join(EXAMPLES, "r3_seed_report_per_axis.json"))))
    e = solve(r3, warm_start=None)
    lines = open(DATA).read().splitlines()
    rec = {"index": 1, "problem": r3.to_dict(), "success": True, "exact": False, "method": "switch-time",
           "tf": e.tf, "switch_times": [list(a) for a in e.switch_times], "u_first": list(e.u_first)}
    (tmp_path / "d.jsonl").write_text(lines[0] + "\n" + json.dumps(rec) + "\n")
    build([str(tmp_path / "d.jsonl")], k=1, vote=1.0, n_sequences=1, tf_rel_tol=1e-4).save(tmp_path / "t.npz")

    class Wrong:          # a default model whose guess fails
        name = "wrong"

        def covers(self, problem):
            return None

        def guess(self, problem):
            from solvers import Guess
            return Guess(np.array([0, 1, 0, 0, 1, 1, 1.0]), 0.3, [[0.15], [0.15], [0.15]], [1, 1, 1], source="learned")
    monkeypatch.setattr(warmstart, "default_warm_start", lambda: Wrong())
    monkeypatch.setattr(warmstart, "DEFAULT_SINGULAR_TABLE_FILE", str(tmp_path / "t.npz"))
    warmstart.default_singular_table.cache_clear()
    try:
        s = solve(r3)
    finally:
        warmstart.default_singular_table.cache_clear()
    assert s.success and s.exact and s.tf == pytest.approx(e.tf, rel=1e-10)
    assert s.warm_start["singular_table"]["used"] and "exact extremal from its KKT costates" in s.route


def test_an_uncertain_votes_check_that_raises_leaves_the_tables_answer(tmp_path, singular_answer, monkeypatch):
    import solvers.collocation as collocation
    data = _dataset(tmp_path / "d.jsonl", singular_answer)
    build([data], k=3, vote=0.9, n_sequences=1, tf_rel_tol=5e-4).save(tmp_path / "t.npz")

    def broken(*a, **k):
        raise RuntimeError("collocation broke")
    monkeypatch.setattr(collocation, "solve_collocation", broken)
    s = _solve_with_table(tmp_path / "t.npz", monkeypatch)
    rec = s.warm_start["singular_table"]
    assert s.success and s.method == "switch-time" and rec["uncertain"] is True
    assert rec["exact_check"] == "error: RuntimeError: collocation broke"
    assert "uncertain; collocation's check for an exact extremal: error" in s.route
    assert s.tf == pytest.approx(SINGULAR_TF, rel=5e-4)


def test_a_vote_whose_short_optimisations_verify_nothing_retries_with_more_iterations():
    # held-out 790 (J = I, 131°): 4 of the 5 nearest problems singular; 10 SLSQP iterations on
    # each of the 3 sequences verify none, 40 reach the collocation route's answer (2.5314292)
    from training.generate import GenerationSpec, problem_for
    p = problem_for(GenerationSpec("full-attitude", seed=20261122), 790)
    s = solve(p)
    rec = s.warm_start["singular_table"]
    assert rec["used"] and rec["retried"] and not rec["uncertain"]
    assert s.success and s.method == "switch-time" and "singular table" in s.route
    assert "collocation" not in s.route.split("singular table", 1)[1]
    assert s.tf == pytest.approx(2.5314292, rel=5e-4) and s.tf < s.baseline_tf
    assert max(_replay(p, s.switch_times, s.u_first, s.tf)) < 1e-9
