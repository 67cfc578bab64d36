"""Model and table files whose card or layers are malformed are refused at load with a
``ModelFileError`` that names the file and the field (fuzz report s42, violations 3, 4 and 9).

Every bad file is a copy of a shipped one, changed and written under ``tmp_path``; the shipped
files are only read."""
import json
import os

import numpy as np
import pytest

from slew_env.core import quat_from_euler321_deg as Q
from solvers import solve
from solvers.warmstart import (DEFAULT_CONE_MODEL_FILE, DEFAULT_CONE_TABLE_FILE, DEFAULT_MODEL_FILE,
                               DEFAULT_SINGULAR_TABLE_FILE, DEFAULT_TABLE_FILE, ModelFileError, NearestNeighbourModel,
                               WarmStartModel, load_model)
from solvers.warmstart.cone_model import ConeWarmStartModel
from solvers.warmstart.cone_nearest import ConeNearestNeighbourModel
from solvers.warmstart.model import MAX_NEIGHBOURS, weights_checksum
from solvers.warmstart.singular_table import SingularTable

PROBLEM = dict(inertia=[1.0, 1.0, 1.0], torque_max=1.0, qf=list(Q(-20, 10, 90)))
SHIPPED = [DEFAULT_MODEL_FILE, DEFAULT_TABLE_FILE, DEFAULT_CONE_MODEL_FILE, DEFAULT_CONE_TABLE_FILE,
           DEFAULT_SINGULAR_TABLE_FILE]


def _read(path):
    with np.load(path, allow_pickle=False) as f:
        d = {k: f[k] for k in f.files}
    return d, json.loads(str(d["card"]))


def _network_copy(tmp_path, src, name, card_fn=None, arr_fn=None):
    """A copy of the network ``src`` with its arrays (``arr_fn(d)``) and card (``card_fn(card)``,
    which may return another JSON value) changed, and a valid checksum: only the change is wrong."""
    d, card = _read(src)
    if arr_fn:
        arr_fn(d)
    n = sum(1 for k in d if k.startswith("W"))
    if isinstance(card, dict):
        card["n_layers"] = n
        card["sha256"] = weights_checksum([d[f"{w}{k}"] for k in range(n) for w in "Wb"] + [d["x_mean"], d["x_std"]])
    return _written(tmp_path, name, d, card_fn(card) if card_fn else card)


def _written(tmp_path, name, d, card):
    """``d``'s arrays with ``card`` as its card, saved as ``tmp_path / name``."""
    d["card"] = np.array(json.dumps(card))
    path = tmp_path / name
    with open(path, "wb") as f:
        np.savez(f, **d)
    return path


def _table_copy(tmp_path, src, name, card_fn=None, rows=None):
    """A copy of the table ``src`` with its card changed (``card_fn``); ``rows``: its first rows only."""
    d, card = _read(src)
    if rows is not None:
        if "singular" in d:      # the singular rows' arrays follow the kept rows' flags
            m = int(d["singular"][:rows].sum())
            d = {k: (v[:m] if k in ("T", "T_eig", "U", "S") else v[:rows] if k != "card" else v) for k, v in d.items()}
        else:
            d = {k: (v[:rows] if k != "card" else v) for k, v in d.items()}
    return _written(tmp_path, name, d, card_fn(card) if card_fn else card)


def _refused(path, *fragments, loader=load_model):
    with pytest.raises(ModelFileError) as e:
        loader(path)
    msg = str(e.value)
    assert os.path.basename(str(path)) in msg, msg
    for f in fragments:
        assert f in msg, msg
    return msg


# --------------------------------------------------------------------------- the shipped files
def test_the_shipped_models_and_tables_still_load(tmp_path):
    m = load_model(DEFAULT_MODEL_FILE)
    assert type(m) is WarmStartModel and m.K == 5 and [W.shape[1] for W, _ in m.weights][-1] == 43
    c = load_model(DEFAULT_CONE_MODEL_FILE)
    assert isinstance(c, ConeWarmStartModel) and c.heads == 8
    t = load_model(DEFAULT_TABLE_FILE)
    assert type(t) is NearestNeighbourModel and t.k == 3 and t.X.shape == (39494, 11)
    ct = load_model(DEFAULT_CONE_TABLE_FILE)
    assert isinstance(ct, ConeNearestNeighbourModel) and ct.k == 4
    s = SingularTable.load(DEFAULT_SINGULAR_TABLE_FILE)
    assert (s.k, s.n_sequences, s.vote) == (5, 3, 0.6)
    # and an unchanged copy (the helpers below only change what a test asks for)
    assert load_model(_network_copy(tmp_path, DEFAULT_MODEL_FILE, "copy.npz")).K == 5
    assert load_model(_network_copy(tmp_path, DEFAULT_CONE_MODEL_FILE, "ccopy.npz")).heads == 8


# --------------------------------------------------------------------------- layers (violation 3)
def test_hidden_layers_that_do_not_chain_are_refused_at_load(tmp_path):
    def bad_chain(d):     # the fuzz report's file, with 2,000 rows instead of 2,000,000
        d["W1"] = d["W1"][:, :1].copy()
        d["b1"] = d["b1"][:1].copy()
        d["W2"] = np.ones((2000, 1), np.float32)
        d["b2"] = np.zeros(1, np.float32)
        d["W3"] = np.ones((1, 43), np.float32)
    path = _network_copy(tmp_path, DEFAULT_MODEL_FILE, "chain.npz", arr_fn=bad_chain)
    _refused(path, "weights: W2 expects 2000 inputs, W1 gives 1")
    # solve refuses it too, before any guess (the compiled pass had read past W1's outputs)
    with pytest.raises(ModelFileError, match="W2 expects 2000 inputs, W1 gives 1"):
        solve(PROBLEM, warm_start=str(path), time_budget=1)


def test_a_bias_of_another_length_and_arrays_of_another_rank_are_refused(tmp_path):
    def short_bias(d):
        d["b2"] = d["b2"][:100].copy()
    _refused(_network_copy(tmp_path, DEFAULT_MODEL_FILE, "bias.npz", arr_fn=short_bias),
             "weights: b2 has 100 entries, W2 has 256 outputs")

    def flat_w(d):
        d["W1"] = d["W1"].reshape(-1)
    _refused(_network_copy(tmp_path, DEFAULT_MODEL_FILE, "flat.npz", arr_fn=flat_w),
             "weights: W1 has shape (65536,), expected a 2-D array")

    def text_w(d):
        d["W2"] = d["W2"].astype(str)
    _refused(_network_copy(tmp_path, DEFAULT_MODEL_FILE, "text.npz", arr_fn=text_w), "weights: W2 holds")


def test_the_cone_models_layers_must_chain_too(tmp_path):
    def bad_chain(d):
        d["W2"] = d["W2"][:64].copy()      # 64 inputs, W1 gives 128
    _refused(_network_copy(tmp_path, DEFAULT_CONE_MODEL_FILE, "cchain.npz", arr_fn=bad_chain),
             "weights: W2 expects 64 inputs, W1 gives 128")


def test_the_weights_setter_refuses_layers_that_do_not_chain():
    m = load_model(DEFAULT_MODEL_FILE)
    W1, b1 = m.weights[1]
    with pytest.raises(ModelFileError, match="weights: W2 expects 256 inputs, W1 gives 10"):
        WarmStartModel([m.weights[0], (W1[:, :10], b1[:10])] + m.weights[2:], m.x_mean, m.x_std, dict(m.card))


def test_non_finite_or_overflowing_weights_are_refused(tmp_path):
    def nan_w(d):
        d["W1"] = d["W1"].copy()
        d["W1"][3, 4] = np.nan
    _refused(_network_copy(tmp_path, DEFAULT_MODEL_FILE, "nan.npz", arr_fn=nan_w),
             "weights: W1 has 1 entries that are not finite")

    def huge(d):          # finite in float32, but the outputs overflow
        for k in range(4):
            d[f"W{k}"] = (d[f"W{k}"] * np.float32(1e15)).astype(np.float32)
    _refused(_network_copy(tmp_path, DEFAULT_MODEL_FILE, "huge.npz", arr_fn=huge),
             "outputs at the features' mean (x_mean) are not finite")


@pytest.mark.parametrize("field, value, fragment", [
    ("x_std", 0.0, "x_std: the features' scales must be positive, x_std[0] is 0.0"),
    ("x_std", -1.0, "x_std: the features' scales must be positive"),
    ("x_std", np.inf, "x_std: 1 entries are not finite"),
    ("x_mean", np.nan, "x_mean: 1 entries are not finite"),
    ("x_mean", "short", "x_mean: expected 11 real numbers"),
])
def test_feature_standardisation_is_checked(tmp_path, field, value, fragment):
    def change(d):
        if isinstance(value, str):
            d[field] = d[field][:5].copy()
        else:
            d[field] = d[field].copy()
            d[field][0] = value
    path = _network_copy(tmp_path, DEFAULT_MODEL_FILE, "std.npz", arr_fn=change)
    _refused(path, fragment)


# --------------------------------------------------------------------------- cards (violation 9)
@pytest.mark.parametrize("src", [DEFAULT_MODEL_FILE, DEFAULT_CONE_MODEL_FILE])
@pytest.mark.parametrize("card", [[1, 2], "a card", 3, None])
def test_a_network_card_that_is_not_a_json_object_is_refused(tmp_path, src, card):
    path = _network_copy(tmp_path, src, "card.npz", card_fn=lambda c: card)
    _refused(path, "the card is a JSON")
    with pytest.raises(ModelFileError, match="the card is a JSON"):
        solve(PROBLEM, warm_start=str(path), time_budget=1)


@pytest.mark.parametrize("src", [DEFAULT_TABLE_FILE, DEFAULT_CONE_TABLE_FILE, DEFAULT_SINGULAR_TABLE_FILE])
def test_a_table_card_that_is_not_a_json_object_is_refused(tmp_path, src):
    path = _table_copy(tmp_path, src, "card.nn.npz", card_fn=lambda c: [1, 2], rows=50)
    loader = SingularTable.load if src == DEFAULT_SINGULAR_TABLE_FILE else load_model
    _refused(path, "the card is a JSON array", loader=loader)


@pytest.mark.parametrize("src, field, value, fragment", [
    (DEFAULT_MODEL_FILE, "max_switches", "five", "card.max_switches: expected a whole number ≥ 0 and ≤ 50, got 'five'"),
    (DEFAULT_MODEL_FILE, "max_switches", 2.5, "card.max_switches: expected a whole number"),
    (DEFAULT_MODEL_FILE, "max_switches", True, "card.max_switches: expected a whole number"),
    (DEFAULT_MODEL_FILE, "max_switches", 10 ** 6, "card.max_switches: expected a whole number ≥ 0 and ≤ 50"),
    (DEFAULT_MODEL_FILE, "n_layers", "4", "card.n_layers: expected a whole number ≥ 1 and ≤ 64, got '4'"),
    (DEFAULT_MODEL_FILE, "n_layers", 3, "card.n_layers: 3, but the file holds W3, b3 too"),
    (DEFAULT_MODEL_FILE, "heads", 8, "card.heads: a full-attitude model has one head"),
    (DEFAULT_MODEL_FILE, "activation", ["silu"], "card.activation: unknown activation"),
    (DEFAULT_MODEL_FILE, "name", {"a": 1}, "card.name: expected text"),
    (DEFAULT_MODEL_FILE, "format_version", True, "has format version True"),
    (DEFAULT_CONE_MODEL_FILE, "heads", 1000, "card.heads: expected a whole number ≥ 1 and ≤ 64"),
    (DEFAULT_CONE_MODEL_FILE, "heads", "8", "card.heads: expected a whole number ≥ 1"),
    (DEFAULT_CONE_MODEL_FILE, "max_switches", None, "card.max_switches: expected a whole number"),
])
def test_card_fields_of_the_wrong_type_or_range_are_named(tmp_path, src, field, value, fragment):
    def change(c):
        c[field] = value
        return c
    path = _network_copy(tmp_path, src, "field.npz", card_fn=change)
    _refused(path, fragment)


def test_an_output_layout_the_decoder_would_read_out_of_bounds_is_refused(tmp_path):
    def shifted(c):
        c["output_layout"]["times_logit"] = [40, 55]      # past the 43 outputs
        return c
    _refused(_network_copy(tmp_path, DEFAULT_MODEL_FILE, "layout.npz", card_fn=shifted),
             "card.output_layout.times_logit: expected [start, start + 15] within the 43 outputs")

    def narrow(c):
        c["output_layout"]["touch_logit"] = [7, 9]        # 2 slots: the decoder reads 3
        return c
    _refused(_network_copy(tmp_path, DEFAULT_CONE_MODEL_FILE, "clayout.npz", card_fn=narrow),
             "card.output_layout.touch_logit: expected [start, start + 3] within the 52 outputs of a head")

    def missing(c):
        del c["output_layout"]["z"]
        return c
    _refused(_network_copy(tmp_path, DEFAULT_MODEL_FILE, "nolayout.npz", card_fn=missing),
             "card.output_layout: expected the slices")


@pytest.mark.parametrize("src, domain_change, fragment", [
    (DEFAULT_MODEL_FILE, {"angle_deg": "x"}, "card.domain.angle_deg: expected [low, high]"),
    (DEFAULT_MODEL_FILE, {"angle_deg": [10.0]}, "card.domain.angle_deg: expected [low, high]"),
    (DEFAULT_MODEL_FILE, {"angle_deg": [90.0, 10.0]}, "card.domain.angle_deg: expected [low, high]"),
    (DEFAULT_MODEL_FILE, {"inertia_ratio": [0.4, 2.0]}, "card.domain.inertia_ratio"),
    (DEFAULT_MODEL_FILE, {"torque_ratio_min": "1"}, "card.domain.torque_ratio_min: expected a number in [0, 1]"),
    (DEFAULT_MODEL_FILE, {"torque_norm": "banana"}, "card.domain.torque_norm: expected \"inf\" or a number ≥ 1"),
    (DEFAULT_MODEL_FILE, {"rate_max": "no"}, "card.domain.rate_max: expected true, false or null"),
    (DEFAULT_CONE_MODEL_FILE, {"n_cones": [1, 9]}, "card.domain.n_cones"),
    (DEFAULT_CONE_MODEL_FILE, {"n_cones": [1.5, 3]}, "card.domain.n_cones"),
    (DEFAULT_CONE_MODEL_FILE, {"cone_half_angle_deg": [10.0, float("nan")]}, "card.domain.cone_half_angle_deg"),
])
def test_a_malformed_domain_is_refused_by_field(tmp_path, src, domain_change, fragment):
    def change(c):
        c["domain"] = dict(c["domain"], **domain_change)
        return c
    path = _network_copy(tmp_path, src, "domain.npz", card_fn=change)
    _refused(path, fragment)


def test_a_domain_that_is_not_an_object_is_refused(tmp_path):
    path = _network_copy(tmp_path, DEFAULT_MODEL_FILE, "dlist.npz", card_fn=lambda c: dict(c, domain=[10, 180]))
    _refused(path, "card.domain: expected a JSON object")


def test_a_numeric_torque_norm_in_the_domain_is_compared_as_a_number(tmp_path):
    # "inf" as text (the shipped card), or a number: both well formed, compared as numbers
    m = load_model(_network_copy(tmp_path, DEFAULT_MODEL_FILE, "p2.npz",
                                 card_fn=lambda c: dict(c, domain=dict(c["domain"], torque_norm=2))))
    assert m._torque_norm == 2.0
    assert "torque_norm" in m.covers(PROBLEM)            # a per-axis problem: not this model's norm
    assert load_model(DEFAULT_MODEL_FILE).covers(PROBLEM) is None


# --------------------------------------------------------------------------- tables (violation 4)
@pytest.mark.parametrize("src", [DEFAULT_TABLE_FILE, DEFAULT_CONE_TABLE_FILE])
@pytest.mark.parametrize("k, fragment", [
    (100000, "card.k: expected a whole number ≥ 1 and ≤ 64 (a guess maps every neighbour's solution"),
    (65, "card.k: expected a whole number ≥ 1 and ≤ 64"),
    (0, "card.k: expected a whole number ≥ 1"),
    ("3", "card.k: expected a whole number"),
    (2.0, "card.k: expected a whole number"),
])
def test_a_tables_neighbour_count_is_bounded(tmp_path, src, k, fragment):
    path = _table_copy(tmp_path, src, "k.nn.npz", card_fn=lambda c: dict(c, k=k), rows=300)
    _refused(path, "not a usable nearest-neighbour table" if src == DEFAULT_TABLE_FILE else "", fragment)


@pytest.mark.parametrize("src", [DEFAULT_TABLE_FILE, DEFAULT_CONE_TABLE_FILE])
def test_a_table_with_fewer_rows_than_its_k_gives_all_its_rows(tmp_path, src):
    # (a table of a small data file, slew evaluate --train-data: refused for a while in session 42)
    few = load_model(_table_copy(tmp_path, src, "few.nn.npz", card_fn=lambda c: dict(c, k=5), rows=3))
    assert few.k == 5
    if src == DEFAULT_TABLE_FILE:
        g = few.guess(PROBLEM)
        assert 1 + len(g.candidates) == 3
    # k up to the bound and the rows loads, and a guess is quick (the budget's part of it)
    ok = load_model(_table_copy(tmp_path, src, "ok.nn.npz", card_fn=lambda c: dict(c, k=MAX_NEIGHBOURS), rows=200))
    assert ok.k == MAX_NEIGHBOURS


def test_a_solve_with_a_table_of_the_largest_k_keeps_its_time_budget(tmp_path):
    path = _table_copy(tmp_path, DEFAULT_TABLE_FILE, "k64.nn.npz", card_fn=lambda c: dict(c, k=MAX_NEIGHBOURS))
    t = load_model(path)
    g = t.guess(PROBLEM)
    assert 1 + len(g.candidates) == MAX_NEIGHBOURS
    s = solve(PROBLEM, warm_start=str(path), time_budget=0.3)
    assert s.wall_time < 0.3 + 0.05


@pytest.mark.parametrize("src", [DEFAULT_TABLE_FILE, DEFAULT_CONE_TABLE_FILE])
@pytest.mark.parametrize("change, fragment", [
    ({"domain": [1, 2]}, "card.domain: expected a JSON object"),
    ({"domain": {"angle_deg": "x"}}, "card.domain.angle_deg"),
    ({"name": 7}, "card.name: expected text"),
])
def test_a_tables_domain_and_name_are_checked(tmp_path, src, change, fragment):
    path = _table_copy(tmp_path, src, "dom.nn.npz", card_fn=lambda c: dict(c, **change), rows=50)
    _refused(path, fragment)


def test_the_cone_tables_data_files_must_be_a_list(tmp_path):
    path = _table_copy(tmp_path, DEFAULT_CONE_TABLE_FILE, "df.nn.npz",
                       card_fn=lambda c: dict(c, data_files="seed31.jsonl"), rows=50)
    _refused(path, "card.data_files: expected a list")


def test_a_full_attitude_table_of_other_features_or_signs_is_refused(tmp_path):
    d, card = _read(DEFAULT_TABLE_FILE)
    d = {k: v[:50] for k, v in d.items() if k != "card"}
    d["X"] = d["X"][:, :10]
    np.savez(tmp_path / "x10.nn.npz", card=np.array(json.dumps(card)), **d)
    _refused(tmp_path / "x10.nn.npz", "X: the table's features have shape (50, 10), expected (50, 11)")
    d, _ = _read(DEFAULT_TABLE_FILE)
    d = {k: v[:50] for k, v in d.items() if k != "card"}
    d["U"] = np.zeros_like(d["U"])
    np.savez(tmp_path / "u0.nn.npz", card=np.array(json.dumps(card)), **d)
    _refused(tmp_path / "u0.nn.npz", "U: the first-arc signs must be ±1")


def test_an_unknown_table_kind_is_refused(tmp_path):
    path = _table_copy(tmp_path, DEFAULT_TABLE_FILE, "kind.nn.npz", card_fn=lambda c: dict(c, kind="banana"), rows=50)
    _refused(path, "unknown table kind 'banana'")


# --------------------------------------------------------------------------- the singular table
@pytest.mark.parametrize("change, fragment", [
    ({"k": "five"}, "card.k: expected a whole number ≥ 1 and ≤ 64"),
    ({"k": 1000}, "card.k: expected a whole number ≥ 1 and ≤ 64"),
    ({"k": 40}, "card.k: 40 neighbours, but the table holds only 30 rows"),
    ({"n_sequences": 100000}, "card.n_sequences: expected a whole number ≥ 1 and ≤ 64"),
    ({"n_sequences": 1.5}, "card.n_sequences: expected a whole number"),
    ({"vote": True}, "card.vote: the share of singular neighbours must be a number in (0, 1]"),
    ({"vote": "0.6"}, "card.vote"),
    ({"tf_rel_tol": -1.0}, "card.tf_rel_tol: expected a number in [0, 1)"),
    ({"domain": {"torque_norm": []}}, "card.domain.torque_norm"),
    ({"training": [1]}, "card.training: expected a JSON object"),
    ({"name": None}, "card.name: expected text"),
])
def test_singular_table_card_fields_are_named(tmp_path, change, fragment):
    path = _table_copy(tmp_path, DEFAULT_SINGULAR_TABLE_FILE, "sing.npz", card_fn=lambda c: dict(c, **change), rows=30)
    _refused(path, "not a usable singular table", fragment, loader=SingularTable.load)


def test_a_missing_singular_card_field_is_named(tmp_path):
    def drop(c):
        del c["n_sequences"]
        return c
    path = _table_copy(tmp_path, DEFAULT_SINGULAR_TABLE_FILE, "sing.npz", card_fn=drop, rows=30)
    _refused(path, "card.n_sequences: missing", loader=SingularTable.load)
    # an unchanged slice of the shipped table loads (the checks pass the shipped fields)
    assert SingularTable.load(_table_copy(tmp_path, DEFAULT_SINGULAR_TABLE_FILE, "ok.npz", rows=60)).k == 5
