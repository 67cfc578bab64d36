"""A dataset's last line that ends with its newline but is not valid JSON is corruption, refused
with its line number like corruption in the middle; only bytes without a newline after them are a
write cut short by a killed run, and only those are cut away.

A fuzz run (s42, violation 5): a hand-written last line with a typo was deleted on resume and
reported as "a partial last line ... left by an interrupted run". A record's line is written
together with its newline (one ``os.write``), so a killed run never leaves such a line."""
import json

import pytest

from training.cli import main
from training.dataset import DatasetError, DatasetWriter, load, make_meta, read

BAD_LAST = b'{"index": 7, "note": "hand-written, a typo:" oops}\n'


def _dataset(path, n=2):
    with DatasetWriter(path, make_meta("full-attitude", 0, {"name": "full-attitude"}, n=n)) as w:
        for i in range(n):
            w.append({"index": i, "success": False, "status": 1, "message": "x"})
    return path.read_bytes()


@pytest.mark.parametrize("tail", [BAD_LAST, b'{"index": 4, "fam\n', b"\n"])
def test_a_complete_unparsable_last_line_is_refused_not_cut(tmp_path, tail):
    p = tmp_path / "d.jsonl"
    good = _dataset(p)
    p.write_bytes(good + tail)
    with pytest.raises(DatasetError, match=r"line 4 is not valid JSON .*not a write cut short by an interrupted "
                                           r"run.*fix or remove that line"):
        DatasetWriter(p, make_meta("full-attitude", 0, {"name": "full-attitude"}))
    with pytest.raises(DatasetError, match="line 4 is not valid JSON"):
        load(p)                                     # readers refuse it too, as in the middle
    assert p.read_bytes() == good + tail            # nothing cut


def test_a_partial_last_line_without_its_newline_is_still_cut(tmp_path):
    p = tmp_path / "d.jsonl"
    good = _dataset(p)
    p.write_bytes(good + BAD_LAST[:-1])             # the same text, cut before its newline
    assert [r["index"] for r in read(p)[1]] == [0, 1]
    with DatasetWriter(p, make_meta("full-attitude", 0, {"name": "full-attitude"})) as w:
        assert w.truncated_bytes == len(BAD_LAST) - 1 and set(w.done) == {0, 1}
    assert p.read_bytes() == good


def _generate(out, n):
    return main(["generate", "--family", "full-attitude", "--n", str(n), "-o", str(out), "--workers", "1",
                 "--no-progress", "--solve-fn", "gen_sleepy:solve", "--solve-options", '{"sleep": 0}'])


def test_slew_generate_refuses_to_resume_it_naming_the_line(tmp_path, capsys):
    out = tmp_path / "d.jsonl"
    assert _generate(out, 2) == 0
    with open(out, "ab") as f:
        f.write(BAD_LAST)
    before = out.read_bytes()
    capsys.readouterr()
    assert _generate(out, 3) == 2
    cap = capsys.readouterr()
    lines = [ln for ln in cap.err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("slew generate: error: ") and "Traceback" not in cap.err
    assert f"{out}: line 4 is not valid JSON" in lines[0]
    assert "cut away" not in cap.out
    assert out.read_bytes() == before
    # removing that line (as the message says) lets the run continue
    out.write_bytes(before[:-len(BAD_LAST)])
    assert _generate(out, 3) == 0
    assert [json.loads(ln)["index"] for ln in out.read_text().splitlines()[1:]] == [0, 1, 2]
