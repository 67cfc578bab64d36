"""``training.dataset``: the JSON Lines dataset format, its writer (resume, locking) and readers."""
import json
import math

import numpy as np
import pytest

from training.dataset import (FORMAT_NAME, FORMAT_VERSION, META_KEY, DatasetError, DatasetMismatchError,
                              DatasetWriter, load, make_meta, read, read_meta, to_arrays)

DIST = {"angle_deg": [10.0, 180.0], "name": "full-attitude"}


def _meta(family="full-attitude", seed=0, dist=DIST, n=5):
    return make_meta(family, seed, dict(dist), n=n, note="test")


def _record(i, success=True):
    if success:
        return {"index": i, "family": "full-attitude", "seed": 0, "success": True, "status": 0,
                "message": "ok", "tf": 1.0 + i, "tf_tol": 1e-10, "costate0": [0.1 * i] * 7,
                "switch_times": [[0.1], [0.2, 0.3], []], "u_first": [1.0, -1.0, 1.0], "n_candidates": 4,
                "baseline_tf": 2.0 + i, "wall_time_s": 0.5}
    return {"index": i, "family": "full-attitude", "seed": 0, "success": False, "status": -1,
            "message": "cones: not supported", "tf": float("nan"), "costate0": None, "switch_times": None,
            "u_first": None, "n_candidates": None, "baseline_tf": None, "wall_time_s": 0.01}


def _lines(path):
    return path.read_bytes().split(b"\n")


def test_round_trip(tmp_path):
    p = tmp_path / "d.jsonl"
    with DatasetWriter(p, _meta()) as w:
        assert w.done == {} and w.truncated_bytes == 0
        for i in (2, 0, 3):
            w.append(_record(i, success=(i != 3)))
    raw = p.read_bytes()
    assert raw.endswith(b"\n")
    lines = raw.decode().splitlines()
    assert len(lines) == 4
    first = json.loads(lines[0])
    assert set(first) == {META_KEY}
    meta = first[META_KEY]
    assert meta["format"] == FORMAT_NAME and meta["version"] == FORMAT_VERSION
    assert meta["family"] == "full-attitude" and meta["seed"] == 0 and meta["n"] == 5
    assert "NaN" not in raw.decode()           # strict JSON: NaN written as null
    assert read_meta(p) == meta
    recs = load(p)
    assert [r["index"] for r in recs] == [0, 2, 3]
    assert recs[0] == _record(0)
    assert recs[2]["tf"] is None
    assert [r["index"] for r in load(p, only_success=True)] == [0, 2]
    # resume: the writer sees what is there, refuses duplicates, appends the rest
    with DatasetWriter(p, _meta(n=7)) as w:       # n may differ: it does not fix the problems
        assert w.done == {0: True, 2: True, 3: False}
        with pytest.raises(DatasetError, match="already in the file"):
            w.append(_record(2))
        w.append(_record(1))
    assert [r["index"] for r in load(p)] == [0, 1, 2, 3]
    assert read_meta(p)["n"] == 5                 # metadata written once, by the creating run


def test_to_arrays(tmp_path):
    recs = [_record(1), _record(0), _record(2, success=False)]
    a = to_arrays(recs)
    assert a["index"].tolist() == [0, 1, 2]
    assert a["success"].tolist() == [True, True, False]
    assert a["status"].tolist() == [0, 0, -1]
    assert a["tf"][:2].tolist() == [1.0, 2.0] and math.isnan(a["tf"][2])
    assert a["costate0"].shape == (3, 7) and np.all(np.isnan(a["costate0"][2]))
    assert a["switch_times"].shape == (3, 3, 2)
    assert a["n_switches"].tolist() == [[1, 2, 0], [1, 2, 0], [0, 0, 0]]
    assert a["switch_times"][0, 1].tolist() == [0.2, 0.3]
    assert a["switch_times"][0, 0, 0] == 0.1 and np.isnan(a["switch_times"][0, 0, 1])
    assert np.all(np.isnan(a["switch_times"][2]))
    assert a["u_first"].tolist()[2] == [0.0, 0.0, 0.0]
    assert to_arrays(recs, max_switches=4)["switch_times"].shape == (3, 3, 4)
    empty = to_arrays([])
    assert empty["tf"].shape == (0,) and empty["costate0"].shape == (0, 7)


@pytest.mark.parametrize("tail", [b'{"index": 4, "family": "full-att',     # killed mid-write: no newline
                                  b"\x00\x00\x00\x00"])                       # zero-filled tail
# (a line with its newline that does not parse is corruption, even the last: test_dataset_last_line.py)
def test_partial_last_line_truncated_on_resume(tmp_path, tail):
    p = tmp_path / "d.jsonl"
    with DatasetWriter(p, _meta()) as w:
        w.append(_record(0))
        w.append(_record(1, success=False))
    good = p.read_bytes()
    with open(p, "ab") as f:
        f.write(tail)
    # readers ignore the partial line and do not touch the file
    assert [r["index"] for r in load(p)] == [0, 1]
    assert p.read_bytes() == good + tail
    # the writer cuts it away before appending
    with DatasetWriter(p, _meta()) as w:
        assert w.truncated_bytes == len(tail)
        assert w.done == {0: True, 1: False}
        w.append(_record(4))
    assert p.read_bytes().startswith(good)
    assert [r["index"] for r in load(p)] == [0, 1, 4]
    assert all(json.loads(line) for line in p.read_text().splitlines())


def test_partial_meta_line_is_rewritten(tmp_path):
    p = tmp_path / "d.jsonl"
    p.write_bytes(b'{"_meta": {"format": "slewopt-da')   # killed while writing the first line
    with DatasetWriter(p, _meta()) as w:
        assert w.truncated_bytes > 0 and w.done == {}
        w.append(_record(0))
    assert read_meta(p)["family"] == "full-attitude"
    assert [r["index"] for r in load(p)] == [0]


@pytest.mark.parametrize("change, field", [({"family": "pointing-cones"}, "family"),
                                           ({"seed": 1}, "seed"),
                                           ({"dist": {"angle_deg": [40.0, 180.0], "name": "full-attitude"}},
                                            "distribution")])
def test_meta_mismatch_refused(tmp_path, change, field):
    p = tmp_path / "d.jsonl"
    with DatasetWriter(p, _meta()) as w:
        w.append(_record(0))
    before = p.read_bytes()
    with pytest.raises(DatasetMismatchError, match=f"refusing to append.*{field}"):
        DatasetWriter(p, _meta(**change))
    assert p.read_bytes() == before
    assert isinstance(DatasetMismatchError("x"), ValueError)


def test_format_version_mismatch_refused(tmp_path):
    p = tmp_path / "d.jsonl"
    meta = _meta()
    meta["version"] = FORMAT_VERSION + 1
    p.write_text(json.dumps({META_KEY: meta}) + "\n")
    with pytest.raises(DatasetMismatchError, match="version"):
        DatasetWriter(p, _meta())


def test_not_a_dataset_and_mid_file_corruption(tmp_path):
    p = tmp_path / "x.jsonl"
    p.write_text('{"inertia": [1, 1, 1]}\n')
    with pytest.raises(DatasetError, match="not a slew dataset"):
        DatasetWriter(p, _meta())
    q = tmp_path / "d.jsonl"
    with DatasetWriter(q, _meta()) as w:
        w.append(_record(0))
    text = q.read_text()
    q.write_text(text + "garbage\n" + json.dumps(_record(1)) + "\n")
    with pytest.raises(DatasetError, match="line 3 is not valid JSON"):
        load(q)
    with pytest.raises(DatasetError, match="line 3"):
        DatasetWriter(q, _meta())


def test_duplicates_detected_by_reader(tmp_path):
    p = tmp_path / "d.jsonl"
    with DatasetWriter(p, _meta()) as w:
        w.append(_record(0))
    with open(p, "a") as f:
        f.write(json.dumps(_record(0)) + "\n")
    with pytest.raises(DatasetError, match="more than once"):
        load(p)
    _, recs = read(p, allow_duplicates=True)
    assert len(recs) == 2


def test_second_writer_is_locked_out(tmp_path):
    p = tmp_path / "d.jsonl"
    with DatasetWriter(p, _meta()):
        with pytest.raises(DatasetError, match="another process is writing"):
            DatasetWriter(p, _meta())
    with DatasetWriter(p, _meta()) as w:          # lock released on close
        w.append(_record(0))


def test_bad_records_refused(tmp_path):
    p = tmp_path / "d.jsonl"
    with DatasetWriter(p, _meta()) as w:
        for bad in ({"success": True}, {"index": -1}, {"index": True}, {"index": 1, META_KEY: {}}):
            with pytest.raises(DatasetError):
                w.append(bad)
    assert load(p) == []


@pytest.mark.parametrize("content", [b'{"inertia": [1, 1, 1], "qf": [0, 0, 0, 1]}',   # json.dump: no newline
                                     b"my notes\n", b"x"])
def test_an_existing_file_that_is_not_a_dataset_is_left_alone(tmp_path, content):
    # a one-line file had been read as "a partial last line", cut away and replaced by metadata
    p = tmp_path / "problem.json"
    p.write_bytes(content)
    with pytest.raises(DatasetError, match="not a slew dataset file .* refusing to append to it or overwrite it"):
        DatasetWriter(p, _meta())
    assert p.read_bytes() == content


def test_a_metadata_line_cut_in_its_first_bytes_is_rewritten(tmp_path):
    # a crash or a full disk while the metadata went into an existing empty file can leave any
    # prefix of it; the refusal of files that are not datasets must not take these for one
    p = tmp_path / "d.jsonl"
    p.write_bytes(b'{"_me')
    with DatasetWriter(p, _meta()) as w:
        assert w.truncated_bytes == 5
        w.append(_record(0))
    assert [r["index"] for r in load(p)] == [0]
