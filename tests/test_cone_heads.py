"""A pointing-cones network with several heads (winner-takes-all, and a selector): its file,
its guesses in the selector's order, its loss, and training it from a solution table."""
import json
import os

import numpy as np
import pytest

from solvers.warmstart import ModelFileError, load_model
from solvers.warmstart.cone_features import N_CONE_FEATURES, cone_canonical_form
from solvers.warmstart.cone_model import ConeWarmStartModel, cone_output_layout, cone_output_size

from reference_cases import TOUCH

HERE = os.path.dirname(__file__)
CONFIG = os.path.join(HERE, "..", "training", "warmstart", "configs", "pointing-cones.yaml")
K = 5
PER = cone_output_layout(K)["times_logit"][1]


def _heads_model(heads=3, first=1, seed=0, card_heads=None):
    """A random model with ``heads`` heads whose selector ranks head ``first`` first, whatever
    the features (selector columns: zero weights, biases)."""
    rng = np.random.default_rng(seed)
    n_out = cone_output_size(K, heads)
    W1 = rng.normal(size=(16, n_out)) * 0.3
    b1 = np.zeros(n_out)
    W1[:, heads * PER:] = 0.0
    b1[heads * PER:] = np.arange(heads, dtype=float)[::-1] * 0.1      # head 0 next, then 2, ...
    b1[heads * PER + first] = 5.0
    weights = [(rng.normal(size=(N_CONE_FEATURES, 16)) * 0.3, np.zeros(16)), (W1, b1)]
    card = {"name": "random heads model", "max_switches": K, "activation": "tanh",
            "heads": heads if card_heads is None else card_heads,
            "domain": {"n_cones": [1, 3], "angle_deg": [0.0, 180.0]}}
    return ConeWarmStartModel(weights, np.zeros(N_CONE_FEATURES), np.ones(N_CONE_FEATURES), card)


def test_output_size_of_several_heads():
    assert cone_output_size(K) == PER == 52
    assert cone_output_size(K, 8) == 8 * (PER + 1)


def test_heads_file_round_trip(tmp_path):
    m = _heads_model()
    m.save(tmp_path / "h.npz")
    back = load_model(tmp_path / "h.npz")
    assert isinstance(back, ConeWarmStartModel) and back.heads == 3 and back.card["heads"] == 3
    x = cone_canonical_form(TOUCH).x
    np.testing.assert_allclose(back.forward(x), m.forward(x), atol=1e-6)


@pytest.mark.parametrize("bad", [0, -2, "3", True, 2.5])
def test_a_bad_head_count_in_the_card_is_refused_by_name(bad):
    with pytest.raises(ModelFileError, match="card.heads: expected a whole number ≥ 1"):
        _heads_model(card_heads=bad)


def test_weights_of_another_head_count_are_refused():
    with pytest.raises(ModelFileError, match=r"outputs of a pointing-cones model \(max_switches 5, 4 heads\)"):
        _heads_model(heads=3, card_heads=4)


def test_guesses_follow_the_selector_order():
    """The first guess is the selector's first head's (head 1 here, not head 0), each head gives
    its guess and its variant, and every head's prediction is among the guesses."""
    m = _heads_model(heads=3, first=1)
    cf = cone_canonical_form(TOUCH)
    out = m.forward(cf.x)[0]
    np.testing.assert_array_equal(m.head_order(out), [1, 0, 2])
    g = m.guess(TOUCH)
    parts = g.all()
    assert 3 <= len(parts) <= 6
    tfs = [m.predict_canonical(cf.x, cf.T_ref, head=h)[1] * cf.tau for h in (1, 0, 2)]
    assert g.tf == pytest.approx(tfs[0], rel=1e-12)
    # the heads' final times appear in the selector's order (a variant repeats its head's)
    seen = []
    for p in parts:
        if not seen or abs(p.tf - seen[-1]) > 1e-12 * p.tf:
            seen.append(p.tf)
    np.testing.assert_allclose(seen, tfs, rtol=1e-12)
    # the default head is the selector's first; predict_heads gives them all in order
    np.testing.assert_allclose(m.predict_canonical(cf.x, cf.T_ref)[1], m.predict_heads(cf.x, cf.T_ref)[0][1])
    with pytest.raises(ValueError, match="head: the model has 3 head"):
        m.predict_canonical(cf.x, cf.T_ref, head=3)


def test_the_ensemble_tries_every_head_after_the_neighbours():
    from solvers.warmstart import default_cone_model
    from solvers.warmstart.cone_ensemble import ConeEnsembleWarmStart
    shipped = default_cone_model()
    m = _heads_model(heads=3, first=2)
    ens = ConeEnsembleWarmStart(m, shipped.table)
    parts = ens.guess(TOUCH).all()
    sources = [p.source for p in parts]
    assert sources[:4] == [f"nearest-neighbour[{k}]" for k in range(4)]
    net = parts[4:]
    assert 3 <= len(net) <= 6 and all(s.startswith("learned") for s in sources[4:])
    cf = cone_canonical_form(TOUCH)
    assert net[0].tf == pytest.approx(m.predict_canonical(cf.x, cf.T_ref, head=2)[1] * cf.tau, rel=1e-12)


def _with_bad_head(m, head):
    """``m`` with ``head``'s final time overflowing (its guess cannot be made)."""
    L = cone_output_layout(K)
    W, b = m.weights[-1]
    b = b.copy()
    b[head * PER + L["log_T_ratio"][0]] = 1e4
    m.weights = m.weights[:-1] + [(W, b)]
    return m


def test_a_head_without_a_guess_is_passed_over_alone():
    """A later head that cannot be decoded fails as its own candidate, once (its variant is
    skipped), in the network's guess and in the ensemble; a first head that cannot is passed
    over, the next one leads; none at all raises the first head's error."""
    from solvers.warmstart import default_cone_model
    from solvers.warmstart.cone_ensemble import ConeEnsembleWarmStart
    m = _with_bad_head(_heads_model(heads=3, first=1), 2)      # order 1, 0, 2: the last fails
    errors = []
    parts = list(m.guess(TOUCH).iter_all(errors))
    assert 2 <= len(parts) <= 4 and len(errors) == 1 and "final time is inf" in errors[0]
    ens = ConeEnsembleWarmStart(m, default_cone_model().table)
    errors = []
    parts = list(ens.guess(TOUCH).iter_all(errors))
    assert [p.source for p in parts[:4]] == [f"nearest-neighbour[{k}]" for k in range(4)]
    assert 2 <= len(parts) - 4 <= 4 and len(errors) == 1 and "final time is inf" in errors[0]
    # the selector's first head fails: head 0 (next in order) leads
    m = _with_bad_head(_heads_model(heads=3, first=1), 1)
    cf = cone_canonical_form(TOUCH)
    g = m.guess(TOUCH)
    assert g.tf == pytest.approx(m.predict_canonical(cf.x, cf.T_ref, head=0)[1] * cf.tau, rel=1e-12)
    for h in (0, 2):
        m = _with_bad_head(m, h)
    with pytest.raises(ValueError, match="final time is inf"):
        m.guess(TOUCH)


# --------------------------------------------------------------------------- the loss
def _batch(torch, n=6, seed=1):
    rng = np.random.default_rng(seed)
    Z = rng.normal(size=(n, 6))
    Z /= np.linalg.norm(Z, axis=1, keepdims=True)
    touch = np.array([[1, 0, 0], [0, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 0], [1, 0, 0]], float)[:n]
    present = np.array([[1, 1, 0], [1, 0, 0], [1, 1, 1], [1, 1, 0], [1, 0, 0], [1, 1, 1]], float)[:n]
    frac = np.where(touch > 0, rng.uniform(0.2, 0.8, size=(n, 3)), np.nan)
    counts = rng.integers(0, K + 1, size=(n, 3))
    Fr = np.full((n, 3, K), np.nan)
    for i in range(n):
        for a in range(3):
            Fr[i, a, :counts[i, a]] = np.sort(rng.uniform(0.05, 0.95, counts[i, a]))
    b = {"Z": Z, "log_T_ratio": rng.normal(size=n) * 0.1, "touch": touch, "present": present, "frac": frac,
         "log_nu": np.where(touch > 0, rng.normal(size=(n, 3)), np.nan), "U": np.sign(rng.normal(size=(n, 3))),
         "counts": counts, "F": Fr}
    return {k: torch.tensor(v, dtype=torch.int64 if k == "counts" else torch.float32) for k, v in b.items()}


def test_per_problem_losses_average_to_the_batch_losses():
    """The batch mean of each per-problem part is the batch-level loss written out here: masked
    parts divided by the batch's count of slots or instants they use, the others plain means."""
    torch = pytest.importorskip("torch")
    from training.warmstart.cone_data import _normalisers, _one_head, _per_problem
    F = torch.nn.functional
    L = cone_output_layout(K)
    cfg = {"max_switches": K, "loss_weights": {"z": 1.0, "log_T": 4.0, "log_nu": 1.0}}
    b = _batch(torch)
    out = torch.randn(6, PER, generator=torch.Generator().manual_seed(0))
    _, parts = _per_problem(out, b, cfg, torch, _normalisers(b, torch))
    pres, mask, smask = b["present"], torch.isfinite(b["frac"]), torch.isfinite(b["F"])
    z = out[:, slice(*L["z"])]
    nz = z.norm(dim=1, keepdim=True)
    tt = torch.sigmoid(out[:, slice(*L["touch_time_logit"])])
    sl = torch.sigmoid(out[:, slice(*L["times_logit"])].reshape(-1, 3, K))
    want = {
        "z": ((z / nz - b["Z"]) ** 2).sum(dim=1).mean() + 0.01 * ((nz - 1.0) ** 2).mean(),
        "log_T": ((out[:, L["log_T_ratio"][0]] - b["log_T_ratio"]) ** 2).mean(),
        "touch": (F.binary_cross_entropy_with_logits(out[:, slice(*L["touch_logit"])], b["touch"],
                                                     reduction="none") * pres).sum() / pres.sum(),
        "touch_times": ((tt - torch.nan_to_num(b["frac"])) ** 2)[mask].sum() / mask.sum(),
        "log_nu": ((out[:, slice(*L["log_nu"])] - torch.nan_to_num(b["log_nu"])) ** 2)[mask].sum() / mask.sum(),
        "u_first": F.binary_cross_entropy_with_logits(out[:, slice(*L["u_first_logit"])], (b["U"] > 0).float()),
        "counts": F.cross_entropy(out[:, slice(*L["count_logits"])].reshape(-1, K + 1), b["counts"].reshape(-1)),
        "times": ((sl - torch.nan_to_num(b["F"])) ** 2)[smask].sum() / smask.sum(),
    }
    for key, value in want.items():
        assert parts[key].shape == (6,)
        assert float(parts[key].mean()) == pytest.approx(float(value), rel=1e-5), key
    total, mean_parts, _ = _one_head(out, b, cfg, torch)
    assert mean_parts["touch"] == pytest.approx(float(want["touch"]), rel=1e-5)
    w = {"z": 1.0, "log_T": 4.0, "touch": 0.2, "touch_times": 2.0, "log_nu": 1.0, "u_first": 0.2, "counts": 0.2,
         "times": 2.0}
    assert float(total) == pytest.approx(float(sum(w[k] * want[k] for k in w)), rel=1e-5)


def test_winner_takes_all_and_the_selector_learns_the_winner():
    """Head 1 predicts every solution exactly (up to the logits' finite size): it wins each
    problem, the loss is (1 - eps) of its loss plus eps of the others' mean plus the selector's
    cross-entropy towards head 1, and only the selector's and head 1's outputs feel most of it."""
    torch = pytest.importorskip("torch")
    from training.warmstart.cone_data import _normalisers, _per_problem, losses
    L = cone_output_layout(K)
    heads, eps, w_sel = 3, 0.05, 0.2
    cfg = {"max_switches": K, "heads": heads, "wta_eps": eps, "loss_weights": {"select": w_sel}}
    b = _batch(torch)
    n = b["Z"].shape[0]
    good = torch.zeros(n, PER)
    good[:, slice(*L["z"])] = b["Z"]
    good[:, L["log_T_ratio"][0]] = b["log_T_ratio"]
    good[:, slice(*L["touch_logit"])] = (b["touch"] * 2 - 1) * 12
    good[:, slice(*L["touch_time_logit"])] = torch.logit(torch.nan_to_num(b["frac"], nan=0.5))
    good[:, slice(*L["log_nu"])] = torch.nan_to_num(b["log_nu"], nan=0.0)
    good[:, slice(*L["u_first_logit"])] = b["U"] * 12
    cl = torch.full((n, 3, K + 1), -12.0)
    cl.scatter_(2, b["counts"][:, :, None], 12.0)
    good[:, slice(*L["count_logits"])] = cl.reshape(n, -1)
    good[:, slice(*L["times_logit"])] = torch.logit(torch.nan_to_num(b["F"], nan=0.5)).reshape(n, -1)
    bad = torch.randn(heads, n, PER, generator=torch.Generator().manual_seed(3)) * 2
    sel = torch.tensor([0.3, -0.2, 0.1]).repeat(n, 1)
    out = torch.cat([bad[0], good, bad[2], sel], dim=1).requires_grad_(True)
    total, parts, metrics = losses(out, b, cfg, torch)
    norms = _normalisers(b, torch)
    Ls = torch.stack([_per_problem(o, b, cfg, torch, norms)[0] for o in (bad[0], good, bad[2])], dim=1)
    assert bool((Ls.argmin(dim=1) == 1).all())
    ce = torch.nn.functional.cross_entropy(sel, torch.ones(n, dtype=torch.int64))
    want = ((1 - eps) * Ls[:, 1] + eps / 2 * (Ls[:, 0] + Ls[:, 2])).mean() + w_sel * ce
    assert float(total.detach()) == pytest.approx(float(want.detach()), rel=1e-5)
    assert parts["select"] == pytest.approx(float(ce), rel=1e-6)
    # the selector ranks head 0 first here: the metrics are head 0's; some head has it all right
    assert metrics["selector_acc"] == 0.0 and metrics["structure_acc_any_head"] == 1.0
    total.backward()
    g = out.grad
    assert float(g[:, PER:2 * PER].abs().sum()) < 1e-2 * float(g[:, :PER].abs().sum()) + 1e-3
    assert float(g[:, 3 * PER:].abs().sum()) > 0.0


# --------------------------------------------------------------------------- the config
@pytest.mark.parametrize("heads, msg", [(0, "config.heads: expected a whole number ≥ 1"),
                                        ("8", "config.heads: expected a whole number ≥ 1"),
                                        (True, "config.heads: expected a whole number ≥ 1")])
def test_config_heads_are_checked(heads, msg):
    from training.warmstart.train import load_config
    with pytest.raises(ValueError, match=msg):
        load_config(CONFIG, {"heads": heads})


def test_several_heads_are_for_the_cone_family_only():
    from training.warmstart.train import load_config
    with pytest.raises(ValueError, match="config.heads: several heads .* pointing-cones family only"):
        load_config(None, {"heads": 4})
    with pytest.raises(ValueError, match=r"config.wta_eps: expected a number in \[0, 1\)"):
        load_config(CONFIG, {"wta_eps": 1.0})


# --------------------------------------------------------------------------- training from a table
def _small_table(tmp_path, rows=300):
    """The last ``rows`` rows of the shipped table (the test dataset's problems are among its
    first rows: the shipped data's first seed)."""
    from solvers.warmstart import default_cone_model
    from solvers.warmstart.cone_nearest import ARRAYS, ConeNearestNeighbourModel
    a = {k: v[-rows:] for k, v in default_cone_model().table.a.items()}
    t = ConeNearestNeighbourModel({k: a[k] for k in ARRAYS}, k=4, name="small")
    path = tmp_path / "small.nn.npz"
    t.save(path, compact=True)
    return path, {k: a[k] for k in ARRAYS}


def test_training_from_a_solution_table(tmp_path):
    pytest.importorskip("torch")
    from training.cli import main
    from training.warmstart.cone_data import training_arrays
    table, a = _small_table(tmp_path)
    arrays = training_arrays([str(table)])
    np.testing.assert_allclose(arrays["X"], a["X"])
    np.testing.assert_array_equal(arrays["counts"], np.isfinite(a["F"]).sum(axis=2))
    np.testing.assert_array_equal(arrays["present"], a["X"][:, [13, 18, 23]])
    np.testing.assert_allclose(arrays["log_T_ratio"], np.log(a["T"] / a["T_ref"]))
    export = tmp_path / "models" / "m.npz"
    assert main(["train", "--config", CONFIG, "--data", str(table), "--out", str(tmp_path / "run"), "--epochs", "2",
                 "--no-progress", "--export", str(export)]) == 0
    m = load_model(export)
    assert isinstance(m, ConeWarmStartModel) and m.heads == 8
    files = m.card["training"]["data_files"]
    assert files[0]["file"] == "small.nn.npz" and files[0]["table"] is True and files[0]["seed"] is None
    assert "a solution table" in (export.parent / "m.md").read_text()
    assert m.card["training"]["n_exact_solutions"] == 300
    # the exported table holds the same solutions
    t = load_model(export.parent / "m.nn.npz")
    np.testing.assert_allclose(t.a["X"], a["X"])
    assert len(m.guess(TOUCH).all()) >= 8


def test_a_table_with_dataset_files_of_other_problems(tmp_path):
    """Beside a table, dataset files add their exact solutions; a file whose solutions are rows of
    the table (the same problems) is refused, naming the file and the table."""
    pytest.importorskip("torch")
    from solvers.warmstart.cone_nearest import ConeNearestNeighbourModel
    from training.cli import main
    from training.warmstart.cone_data import training_arrays
    data = os.path.join(HERE, "data", "pointing-cones-small.jsonl")
    table, a = _small_table(tmp_path, rows=50)
    files = training_arrays([data])
    both = training_arrays([str(table), data])
    assert both["X"].shape[0] == 50 + files["X"].shape[0] and both["n_exact"] == 50 + files["n_exact"]
    np.testing.assert_allclose(both["X"][50:], files["X"])
    assert str(both["key"][0]).startswith("small.nn.npz:") and str(both["key"][50]).startswith(data)
    # a table made of the file's own solutions: the file beside it is refused
    own = tmp_path / "own.nn.npz"
    ConeNearestNeighbourModel({k: files[k] for k in ("X", "Z", "T", "T_ref", "U", "F", "touch", "frac", "log_nu")},
                              k=4).save(own, compact=True)
    code = main(["train", "--config", CONFIG, "--data", str(own), data, "--out", str(tmp_path / "r0"), "--epochs",
                 "1", "--no-progress"])
    assert code == 2
    with pytest.raises(ValueError, match=r"--data: \d+ of the exact solutions of .*pointing-cones-small.jsonl are rows "
                                         r"of the table .*own.nn.npz"):
        training_arrays([str(own), data])


def test_table_refusals_are_named(tmp_path, capsys):
    from training.cli import main
    table, _ = _small_table(tmp_path, rows=20)
    other = tmp_path / "other.nn.npz"
    other.write_bytes(table.read_bytes())
    code = main(["train", "--config", CONFIG, "--data", str(table), str(other), "--out", str(tmp_path / "r1"),
                 "--epochs", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "--data: one solution table at most" in err and "Traceback" not in err
    code = main(["train", "--config", CONFIG, "--data", os.path.join(os.path.dirname(HERE), "solvers", "warmstart",
                                                                      "models", "full-attitude.nn.npz"),
                 "--out", str(tmp_path / "r2"), "--epochs", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "full-attitude table" in err and "--data" in err and "Traceback" not in err
    code = main(["train", "--data", str(table), "--out", str(tmp_path / "r4"), "--epochs", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "trains the pointing-cones network only" in err and "Traceback" not in err
    junk = tmp_path / "junk.nn.npz"
    junk.write_bytes(b"not a table")
    code = main(["train", "--config", CONFIG, "--data", str(junk), "--out", str(tmp_path / "r3"), "--epochs", "1",
                 "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "--data:" in err and "junk.nn.npz" in err and "Traceback" not in err
    # a table whose arrays do not fit together: named by array, before any training
    d = dict(np.load(table))
    d["Z"] = d["Z"][:, :5]
    np.savez(tmp_path / "badz.nn.npz", **d)
    code = main(["train", "--config", CONFIG, "--data", str(tmp_path / "badz.nn.npz"), "--out", str(tmp_path / "r5"),
                 "--epochs", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "badz.nn.npz: Z has shape (20, 5), expected (20, 6)" in err and "Traceback" not in err
    for r in ("r1", "r2", "r3", "r4", "r5"):
        assert not (tmp_path / r).exists()


def test_a_table_carries_its_data_files_into_the_next_training(tmp_path):
    """An exported table's card names the data files it came from; a training from that table
    records them (``sources``), and ``slew evaluate`` warns when its held-out problems are among
    them: through the table given as --train-data, and through the model's card."""
    pytest.importorskip("torch")
    from training.dataset import read_meta
    from training.warmstart.evaluate import held_out_in_training
    from training.warmstart.train import train
    data = os.path.join(HERE, "data", "pointing-cones-small.jsonl")
    seed = read_meta(data)["seed"]
    first = train([data], tmp_path / "r1", config=CONFIG, seed=0, epochs=1, progress_bar=False)
    table = load_model(first["table"])
    assert [d["file"] for d in table.data_files] == ["pointing-cones-small.jsonl"]
    assert table.data_files[0]["seed"] == seed
    second = train([first["table"]], tmp_path / "r2", config=CONFIG, seed=0, epochs=1, progress_bar=False)
    m = load_model(second["model"])
    entry = m.card["training"]["data_files"][0]
    assert entry["table"] is True and entry["seed"] is None
    assert [d["seed"] for d in entry["sources"]] == [seed]
    hits = held_out_in_training("pointing-cones", seed, None, m)
    assert hits == ["pointing-cones-small.jsonl (behind model.nn.npz, in the model's card)"]
    hits = held_out_in_training("pointing-cones", seed, [first["table"]])
    assert hits == [f"pointing-cones-small.jsonl (in {first['table']})"]
    assert held_out_in_training("pointing-cones", seed + 1, [first["table"]], m) == []


def test_evaluate_takes_a_table_as_train_data(tmp_path):
    from training.warmstart.evaluate import check_train_data, held_out_in_training
    table, _ = _small_table(tmp_path, rows=20)
    check_train_data([str(table)], "pointing-cones")
    with pytest.raises(ValueError, match="--train-data: .*family 'pointing-cones'"):
        check_train_data([str(table)], "full-attitude")
    assert held_out_in_training("pointing-cones", 20261122, [str(table)]) == []
