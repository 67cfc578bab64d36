"""auto's route through the nearest tabled solutions' switching sequences: where the learned
candidates fail and the singular table votes bang-bang, the neighbours' sequences, their switch
times optimised, lead the exact solver to the extremal without collocation."""
import pytest

from solvers import solve, multistart
from solvers.warm_routes import faster_verified, neighbour_sequences_route, table_votes_bang_bang

from test_switch_time_opt import _replay


def _held_out(index):
    from training.generate import GenerationSpec, problem_for
    return problem_for(GenerationSpec("full-attitude", seed=20261122), index)


@pytest.fixture(scope="module")
def p575():
    """A held-out bang-bang problem on which every learned candidate fails (the network's and
    the 8 nearest tabled solutions' costates), with its extremal by the collocation route."""
    p = _held_out(575)
    ref = solve(p, singular_table=False)
    assert ref.method == "indirect" and "collocation" in ref.route
    return p, ref


def test_the_neighbours_sequences_lead_to_the_exact_extremal(p575):
    p, ref = p575
    s = solve(p)
    assert s.warm_start["succeeded"] is False           # the learned candidates did fail
    assert table_votes_bang_bang(s.warm_start) and s.warm_start["singular_table"]["used"] is False
    rec = s.warm_start["neighbour_sequences"]
    assert rec["used"] and rec["exact"] and 1 <= rec["tried"] <= 8
    assert s.success and s.exact and s.method == "indirect"
    assert "nearest tabled solutions' sequences" in s.route and "exact extremal from its KKT costates" in s.route
    assert "collocation" not in s.route.split("nearest tabled solutions' sequences", 1)[1]
    assert s.tf == pytest.approx(ref.tf, rel=1e-9) and s.tf < s.baseline_tf
    assert s.verification["boundary_attitude_error"]["value"] < 1e-8
    assert max(_replay(p, s.switch_times, s.u_first, s.tf)) < 1e-8
    # no such route without the default model, nor when the table is switched off
    assert "neighbour_sequences" not in solve(p, singular_table=False).warm_start
    assert "nearest tabled" not in solve(p, warm_start=None).route


def test_a_neighbours_bang_bang_answer_must_beat_the_collocation_route():
    # held-out 828: the neighbours' sequences give a verified bang-bang slew that is not an
    # extremal and 1.6e-4 slower than the extremal the collocation route refines
    p = _held_out(828)
    info = {}
    bang, _ = neighbour_sequences_route(p, {}, info)
    assert bang is not None and bang.success and bang.method == "switch-time" and not bang.exact
    assert info["neighbour_sequences"]["used"] and info["neighbour_sequences"]["exact"] is False
    assert max(_replay(p, bang.switch_times, bang.u_first, bang.tf)) < 1e-8
    s = solve(p)
    assert s.warm_start["neighbour_sequences"]["exact"] is False
    assert s.success and s.exact and s.tf < bang.tf * (1 - 1e-5)
    assert "collocation" in s.route


def test_the_faster_verified_answer_is_kept_and_the_work_counted(p575):
    p, ref = p575
    info = {}
    ex, _ = neighbour_sequences_route(p, {}, info)
    assert ex.exact and ex.tf == pytest.approx(ref.tf, rel=1e-9)

    class Slower:   # a verified answer of the other route, slower
        success, tf, method, nit, nfev, message, exact = True, ref.tf * 1.01, "collocation", 7, 9, "", False

    nit = ex.nit
    kept = faster_verified(Slower(), ex)
    assert kept is ex and kept.nit == nit + 7 and "faster than the collocation route's" in kept.route
    other = Slower()
    other.tf = ref.tf            # a tie keeps the route's answer
    assert faster_verified(other, ex) is other

    class Exact(Slower):   # a certified extremal within 1e-6 of a bang-bang slew keeps its place
        tf, method, exact = ref.tf * (1 + 5e-7), "indirect", True

    assert isinstance(faster_verified(Exact(), ex), Exact)

    class Failed:
        success, tf, method, nit, nfev, message, exact = False, float("nan"), "indirect", 1, 1, "no candidate converged", False

    assert faster_verified(Failed(), ex) is ex and "no verified answer" in ex.route


def test_evaluate_counts_the_neighbours_extremal_as_exact():
    # held-out 62 (460 too): all 11 learned candidates fail (none for lack of time); a
    # neighbour's sequence leads to the extremal the collocation route refines. (62, not 460: a
    # more aggressive stall criterion of the smoothing path, tried, let the learned continuation
    # candidate converge on 460, which would have left this test without its subject.)
    from training.warmstart import evaluate as ev
    p = _held_out(62)
    ref = solve(p, singular_table=False)
    assert ref.exact
    ev._init(None, None)
    job = ("full-attitude", 20261122, 62, ("learned", "learned+table"), 2.0, 1.0)
    # once to load and compile what this path needs: on a cold numba cache that takes more than
    # the learned candidates' 1 s budget, and they would fail for lack of time
    ev._run_one(job)
    rows = ev._run_one(job)
    learned, table = rows
    assert learned["success"] is False and "No candidate converged" in learned["message"]
    assert table["success"] and table["exact"] and table["tf"] == pytest.approx(ref.tf, rel=1e-9)
    assert table["wall_time_s"] > learned["wall_time_s"]


def test_the_vote_reader():
    assert not table_votes_bang_bang({})
    assert not table_votes_bang_bang({"singular_table": {"error": "damaged"}})
    assert table_votes_bang_bang({"singular_table": {"share": 0.0, "vote": 0.6}})
    assert not table_votes_bang_bang({"singular_table": {"share": 0.2, "vote": 0.6}})
    assert not table_votes_bang_bang({"singular_table": {"share": 0.8, "vote": 0.6}})


def test_an_extremal_slower_than_an_earlier_sequences_slew_does_not_win(monkeypatch, p575):
    # the first sequence gives a verified bang-bang slew (no extremal from it), the second a
    # slower slew whose extremal is still slower than the first slew: the first slew is the
    # answer (for solve() to compare with the collocation route), not that extremal
    import solvers.switch_time_opt as sto
    p, ref = p575

    class Fake:
        def __init__(self, tf, exact):
            self.tf, self.exact, self.success = tf, exact, True
            self.nit = self.nfev = 1
            self.route, self.message, self.method = "fake", "", "indirect" if exact else "switch-time"
            self.verification, self.baseline_tf, self.wall_time = {}, float("nan"), 0.0

    import itertools
    tfs = itertools.chain([ref.tf, ref.tf * 1.05], itertools.repeat(ref.tf * 1.06))
    monkeypatch.setattr(sto, "bang_bang_from_sequences",
                        lambda *a, **k: (Fake(next(tfs), False), object(), (1, 1)))
    calls = []

    def exact_from_kkt(prob, bang, kkt_guess, options, budget, prefix):
        calls.append(bang.tf)
        return None if len(calls) == 1 else Fake(ref.tf * 1.04, True)

    monkeypatch.setattr(multistart, "exact_from_kkt", exact_from_kkt)
    info = {}
    ans, _ = neighbour_sequences_route(p, {}, info)
    assert len(calls) >= 2 and ans.tf == ref.tf and not ans.exact
    assert info["neighbour_sequences"]["exact"] is False


def test_a_bang_bang_answer_no_faster_than_the_eigenaxis_slew_is_rejected(monkeypatch, p575):
    # every sequence gives a verified bang-bang slew, none an extremal, and the fastest is slower
    # than the eigenaxis slew: the route gives nothing (the collocation route answers), and says why
    import solvers.switch_time_opt as sto
    p, ref = p575
    assert ref.tf < ref.baseline_tf

    class Fake:
        def __init__(self, tf):
            self.tf, self.exact, self.success = tf, False, True
            self.nit = self.nfev = 1
            self.route, self.message, self.method = "fake", "", "switch-time"
            self.verification, self.baseline_tf, self.wall_time = {}, float("nan"), 0.0

    monkeypatch.setattr(sto, "bang_bang_from_sequences",
                        lambda *a, **k: (Fake(ref.baseline_tf * 1.01), object(), (2, 3)))
    monkeypatch.setattr(multistart, "exact_from_kkt", lambda *a, **k: None)
    info = {}
    ans, (nit, nfev) = neighbour_sequences_route(p, {}, info)
    rec = info["neighbour_sequences"]
    assert ans is None and rec["rejected"] == "not faster than the eigenaxis slew"
    assert rec["tried"] >= 1 and nit == 2 * rec["tried"] and nfev == 3 * rec["tried"]
    # a bang-bang answer faster than the eigenaxis slew is kept, with the baseline check recorded
    monkeypatch.setattr(sto, "bang_bang_from_sequences",
                        lambda *a, **k: (Fake(ref.tf * 1.001), object(), (2, 3)))
    info = {}
    ans, _ = neighbour_sequences_route(p, {}, info)
    assert ans is not None and ans.tf == ref.tf * 1.001 and "rejected" not in info["neighbour_sequences"]
    assert ans.verification["eigenaxis_baseline"]["passed"] and ans.baseline_tf > ans.tf
