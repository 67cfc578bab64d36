"""Slew datasets: an appendable, crash-safe JSON Lines file of solved (or failed) problems.

File format (``docs/DATASET.md`` has the full description)::

    {"_meta": {"format": "slewopt-dataset", "version": 1, "family": ..., "seed": ..., ...}}
    {"index": 0, "family": ..., "seed": ..., "problem": {...}, "success": true, "tf": ..., ...}
    {"index": 3, ...}
    ...

* UTF-8 JSON Lines, one object per line, every line ends with ``\\n``.
* Line 1 is the metadata object ``{"_meta": {...}}``; every later line is one record,
  keyed by its ``index``. Records appear in completion order, not index order.
* Each record line is written with one ``os.write`` of the whole line on a file opened
  ``O_APPEND`` (then ``fsync``), so a process killed at any instant leaves at most one
  partial last line: bytes with no newline after them. Opening a file for appending
  (``DatasetWriter``) truncates such a partial last line away; readers (``read``, ``load``)
  ignore it. A line that ends with its newline but does not parse is corruption wherever it
  is, the last line included: it was not cut short by a killed run, so it is refused, not cut.
* Appending is refused when the file's metadata differs from the run's in ``format``,
  ``version``, ``family``, ``seed`` or ``distribution`` (``DatasetMismatchError``). A run
  holds an exclusive ``flock`` on the file, so two runs never append to one file.

Reading::

    from training.dataset import load, to_arrays
    records = load("data/a.jsonl")            # list of dicts, sorted by index
    arrays = to_arrays(records)               # numpy arrays: success, tf, costate0, switch times...
"""
from __future__ import annotations

import errno
import json
import math
import os
import tempfile
from typing import Iterable, Optional

import numpy as np

FORMAT_NAME = "slewopt-dataset"
FORMAT_VERSION = 1
META_KEY = "_meta"
# metadata fields that must agree before a run may append to an existing file
IDENTITY_FIELDS = ("format", "version", "family", "seed", "distribution")


class DatasetError(ValueError):
    """A dataset file that cannot be read or appended to (a ``ValueError``: one clear line in the CLI)."""


class DatasetMismatchError(DatasetError):
    """The file was generated with another family / seed / distribution / format."""


class CorruptLineError(DatasetError):
    """A complete line (it ends with its newline) that is not valid JSON; ``lineno`` is 1-based."""

    def __init__(self, message, lineno):
        super().__init__(message)
        self.lineno = lineno

    def __reduce__(self):
        return type(self), (str(self), self.lineno)


# --------------------------------------------------------------------------- JSON helpers
def clean_json(x):
    """``x`` with numpy types turned into Python ones and non-finite floats into ``None``."""
    if isinstance(x, dict):
        return {str(k): clean_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean_json(v) for v in x]
    if isinstance(x, np.ndarray):
        return clean_json(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    return x


def dumps_line(obj) -> bytes:
    """One JSON line (compact, strict JSON: no NaN), with its trailing newline, as bytes."""
    text = json.dumps(clean_json(obj), separators=(",", ":"), allow_nan=False, ensure_ascii=False)
    if "\n" in text:   # cannot happen with json.dumps, but the format depends on it
        raise DatasetError("record: serialised JSON contains a newline")
    return (text + "\n").encode("utf-8")


def make_meta(family: str, seed: int, distribution: dict, n: Optional[int] = None, **extra) -> dict:
    """The metadata object of a dataset file (the value of ``"_meta"``)."""
    meta = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "family": family, "seed": int(seed),
            "distribution": distribution, "n": None if n is None else int(n)}
    meta.update(extra)
    return clean_json(meta)


# --------------------------------------------------------------------------- scanning
class _Scan:
    """Result of parsing a dataset file's bytes."""

    def __init__(self):
        self.meta = None             # dict or None (empty file)
        self.records = []            # list of dicts, file order
        self.good_bytes = 0          # length of the valid prefix (complete, parsable lines)
        self.partial_tail = b""      # trailing bytes after the valid prefix (partial last line)


def json_lines(data: bytes, path) -> tuple:
    """``([(line number, parsed JSON), ...], end)`` of the complete lines of JSON Lines bytes;
    ``end`` is the length of those lines, and ``data[end:]`` the partial last line, if any.

    Only bytes after the last newline count as a partial line: a writer puts each line and its
    newline in one ``os.write``, so a run killed at any instant leaves nothing else. A line that
    ends with its newline and does not parse was not left by a killed run, even the last one (a
    fuzz run: a hand-edited last line was cut away as "a partial last line"), so it is
    corruption: a ``CorruptLineError`` naming its line, and the caller repairs nothing. Shared by
    the dataset writer and the output of ``slew solve --batch`` (``training.batch_output``).
    """
    end = data.rfind(b"\n") + 1
    out = []
    pos = 0
    lineno = 0
    while pos < end:
        nl = data.index(b"\n", pos)
        lineno += 1
        try:
            out.append((lineno, json.loads(data[pos:nl].decode("utf-8"))))
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise CorruptLineError(f"{path}: line {lineno} is not valid JSON ({e}); it ends with its newline, so "
                                   "it is not a write cut short by an interrupted run: the file is corrupt there and "
                                   "is not repaired automatically (fix or remove that line)", lineno) from None
        pos = nl + 1
    return out, end


def _scan_bytes(data: bytes, path) -> _Scan:
    s = _Scan()
    try:
        lines, s.good_bytes = json_lines(data, path)
    except CorruptLineError as e:
        if e.lineno == 1:       # no metadata line: notes or a problem file given by mistake
            raise DatasetError(f"{path}: not a slew dataset file (line 1 is not JSON, let alone a metadata "
                               "line)") from None
        raise
    for lineno, obj in lines:
        if not isinstance(obj, dict):
            raise DatasetError(f"{path}: line {lineno} is not a JSON object")
        if lineno == 1:
            if META_KEY not in obj or not isinstance(obj[META_KEY], dict):
                raise DatasetError(f"{path}: line 1 is not a {{\"{META_KEY}\": {{...}}}} metadata object; "
                                   "not a slew dataset file")
            s.meta = obj[META_KEY]
            if s.meta.get("format") != FORMAT_NAME:
                raise DatasetError(f"{path}: format {s.meta.get('format')!r} is not {FORMAT_NAME!r}")
        else:
            if META_KEY in obj:
                raise DatasetError(f"{path}: line {lineno}: a second metadata line")
            idx = obj.get("index")
            if not isinstance(idx, int) or isinstance(idx, bool) or idx < 0:
                raise DatasetError(f"{path}: line {lineno}: record without a valid 'index' ({idx!r})")
            s.records.append(obj)
    s.partial_tail = data[s.good_bytes:]
    return s


def _read_bytes(path) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read()
    except FileNotFoundError:
        raise
    except OSError as e:
        raise DatasetError(f"{path}: cannot read: {e.strerror or e}") from None


def read(path, allow_duplicates=False):
    """``(meta, records)`` of a dataset file, records in file order.

    A partial last line (a run killed mid-write, or still running) is ignored; the file is
    not modified. Raises ``DatasetError`` on a corrupt line elsewhere, and on duplicate
    indices unless ``allow_duplicates``.
    """
    s = _scan_bytes(_read_bytes(path), path)
    if s.meta is None:
        raise DatasetError(f"{path}: empty file (no metadata line)")
    if not allow_duplicates:
        seen = set()
        for r in s.records:
            if r["index"] in seen:
                raise DatasetError(f"{path}: index {r['index']} appears more than once")
            seen.add(r["index"])
    return s.meta, s.records


def read_meta(path) -> dict:
    """The metadata of a dataset file: its first line only (the records are not read)."""
    try:
        with open(path, "rb") as f:
            first = f.readline()
    except FileNotFoundError:
        raise
    except OSError as e:
        raise DatasetError(f"{path}: cannot read: {e.strerror or e}") from None
    meta = _scan_bytes(first, path).meta
    if meta is None:
        raise DatasetError(f"{path}: not a slew dataset file (no metadata line)")
    return meta


def load(path, only_success: bool = False) -> list:
    """The records of a dataset file, sorted by index (see ``read``)."""
    _, records = read(path)
    records = sorted(records, key=lambda r: r["index"])
    if only_success:
        records = [r for r in records if r.get("success") is True]
    return records


# --------------------------------------------------------------------------- arrays
def _floats(values, width=None):
    out = []
    for v in values:
        if v is None:
            out.append(np.full(width, np.nan) if width else np.nan)
        else:
            a = np.asarray(v, dtype=float) if width else float(v)
            if width and a.shape != (width,):
                a = np.full(width, np.nan)
            out.append(a)
    return np.array(out, dtype=float).reshape((len(out),) + ((width,) if width else ()))


def to_arrays(records: Iterable[dict], max_switches: Optional[int] = None) -> dict:
    """Numpy arrays of a list of records (sorted by index first).

    Keys: ``index`` (n,) int64; ``success`` (n,) bool (the mask of verified solutions);
    ``status`` (n,) int64; ``tf``, ``tf_tol``, ``baseline_tf``, ``wall_time_s`` (n,) float;
    ``costate0`` (n, 7); ``u_first`` (n, 3); ``n_switches`` (n, 3) int64;
    ``switch_times`` (n, 3, K) padded with NaN, K = ``max_switches`` or the largest
    per-axis count in the records; ``n_candidates`` (n,) int64. Failure records have
    NaN floats, zero switch counts and zero ``u_first``.
    """
    recs = sorted(records, key=lambda r: r["index"])
    n = len(recs)
    sw = []
    for r in recs:
        st = r.get("switch_times") or [[], [], []]
        if len(st) != 3:
            st = [[], [], []]
        sw.append([[float(t) for t in axis] for axis in st])
    counts = np.array([[len(a) for a in s] for s in sw], dtype=np.int64).reshape(n, 3)
    K = int(counts.max()) if (max_switches is None and n) else int(max_switches or 0)
    switch = np.full((n, 3, K), np.nan)
    for k, s in enumerate(sw):
        for i in range(3):
            m = min(len(s[i]), K)
            switch[k, i, :m] = s[i][:m]
    u_first = _floats([r.get("u_first") for r in recs], 3)
    u_first = np.nan_to_num(u_first, nan=0.0)
    return {
        "index": np.array([r["index"] for r in recs], dtype=np.int64),
        "success": np.array([r.get("success") is True for r in recs], dtype=bool),
        "status": np.array([int(r.get("status") if r.get("status") is not None else -2) for r in recs],
                           dtype=np.int64),
        "tf": _floats([r.get("tf") for r in recs]),
        "tf_tol": _floats([r.get("tf_tol") for r in recs]),
        "baseline_tf": _floats([r.get("baseline_tf") for r in recs]),
        "wall_time_s": _floats([r.get("wall_time_s") for r in recs]),
        "costate0": _floats([r.get("costate0") for r in recs], 7),
        "u_first": u_first,
        "n_switches": counts,
        "switch_times": switch,
        "n_candidates": np.array([int(r.get("n_candidates") or 0) for r in recs], dtype=np.int64),
    }


# --------------------------------------------------------------------------- writing
def write_all(fd, data: bytes):
    """``os.write`` until every byte is out (one call in practice for regular files)."""
    view = memoryview(data)
    while view:
        k = os.write(fd, view)
        view = view[k:]


def read_fd(fd) -> bytes:
    """The whole content of an open file (``pread``: the offset of an ``O_APPEND`` fd does not matter)."""
    data = b""
    while True:
        chunk = os.pread(fd, 1 << 24, len(data))
        if not chunk:
            return data
        data += chunk


def lock_exclusive(fd, path) -> None:
    """Take an exclusive ``flock`` on ``fd`` for as long as it is open, or raise ``DatasetError``
    at once when another process holds it: two runs never append to one file."""
    try:
        import fcntl
    except ImportError:   # not POSIX: no lock
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as e:
        if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise DatasetError(f"{path}: another process is writing this file "
                               "(it holds the lock); wait for it or use another output") from None
        raise


def _create_with_meta(path, meta):
    """Create ``path`` holding only the metadata line, atomically; no-op if it exists."""
    target = os.path.abspath(path)
    d = os.path.dirname(target)
    if not os.path.isdir(d):
        raise DatasetError(f"{path}: directory {d!r} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(dir=d, prefix=f".{os.path.basename(target)}.", suffix=".tmp")
    except OSError as e:      # (the temporary file's name is not one the user gave)
        raise DatasetError(f"{path}: cannot create the file in {d!r}: {e.strerror or e}") from None
    try:
        write_all(fd, dumps_line({META_KEY: meta}))
        os.fsync(fd)
        os.close(fd)
        fd = -1
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        try:
            os.link(tmp, target)        # atomic, and never replaces an existing file
        except FileExistsError:
            pass
    finally:
        if fd >= 0:
            os.close(fd)
        os.unlink(tmp)


def check_meta(existing: dict, wanted: dict, path="dataset") -> None:
    """Raise ``DatasetMismatchError`` when ``existing`` and ``wanted`` differ in an identity field."""
    diffs = []
    for k in IDENTITY_FIELDS:
        a, b = existing.get(k), wanted.get(k)
        if a != b:
            if isinstance(a, dict) and isinstance(b, dict):
                keys = sorted(kk for kk in set(a) | set(b) if a.get(kk) != b.get(kk))
                diffs.append(f"{k} ({', '.join(f'{kk}: file {a.get(kk)!r}, run {b.get(kk)!r}' for kk in keys)})")
            else:
                diffs.append(f"{k} (file {a!r}, run {b!r})")
    if diffs:
        raise DatasetMismatchError(
            f"{path}: refusing to append: the file was generated with a different "
            + "; ".join(diffs) + ". Use another output file, or the file's own settings to continue it.")


class DatasetWriter:
    """Append records to a dataset file, crash-safely; resumes an existing file.

    ``DatasetWriter(path, meta)`` creates the file (metadata line only) if it does not exist,
    takes an exclusive lock on it, checks that its metadata matches ``meta`` in
    ``IDENTITY_FIELDS`` (``DatasetMismatchError`` otherwise), truncates a partial last line,
    and reads the indices already present (``done``: index -> success). ``append(record)``
    writes one record line; a record whose index is already present raises ``DatasetError``.
    """

    def __init__(self, path, meta: dict, fsync: bool = True):
        self.path = str(path)
        self.fsync = fsync
        self.fd = -1
        self.truncated_bytes = 0
        meta = clean_json(meta)
        if os.path.isdir(self.path):
            raise DatasetError(f"{self.path}: is a directory")
        if not os.path.exists(self.path):
            _create_with_meta(self.path, meta)
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_APPEND)
        except OSError as e:
            raise DatasetError(f"{self.path}: cannot open for appending: {e.strerror or e}") from None
        try:
            lock_exclusive(fd, self.path)
            data = read_fd(fd)
            head = b'{"' + META_KEY.encode() + b'"'
            try:
                scan = _scan_bytes(data, self.path)
            except DatasetError:
                scan = None
                if not data or data.startswith(head):
                    raise        # a dataset, corrupt: the scan's error names the line
            if (scan is None or scan.meta is None) and data and not (data.startswith(head)
                                                                     or head.startswith(data)):
                # content that does not begin a metadata line: not a dataset — a JSON file or
                # notes given as -o by mistake, which cutting a "partial line" away would destroy
                # (a run killed while writing the metadata leaves its beginning, accepted here)
                raise DatasetError(f"{self.path}: not a slew dataset file (its {len(data)} byte(s) hold no "
                                   f"{{\"{META_KEY}\": {{...}}}} metadata line); refusing to append to it or "
                                   "overwrite it: give another output file")
            if scan.partial_tail:
                # a run killed mid-write left a partial line: cut it away before appending
                os.ftruncate(fd, scan.good_bytes)
                os.fsync(fd)
                self.truncated_bytes = len(scan.partial_tail)
            if scan.meta is None:
                # an empty file (or only a partial metadata line, now truncated): write the metadata
                write_all(fd, dumps_line({META_KEY: meta}))
                os.fsync(fd)
                self.meta = meta
            else:
                check_meta(scan.meta, meta, self.path)
                self.meta = scan.meta
            self.done = {}
            for r in scan.records:
                if r["index"] in self.done:
                    raise DatasetError(f"{self.path}: index {r['index']} appears more than once; "
                                       "the file was not written by DatasetWriter")
                self.done[r["index"]] = r.get("success") is True
        except BaseException:
            os.close(fd)
            raise
        self.fd = fd

    def append(self, record: dict) -> None:
        if self.fd < 0:
            raise DatasetError(f"{self.path}: writer is closed")
        idx = record.get("index")
        if not isinstance(idx, int) or isinstance(idx, bool) or idx < 0:
            raise DatasetError(f"record: needs a non-negative integer 'index', got {idx!r}")
        if idx in self.done:
            raise DatasetError(f"{self.path}: index {idx} is already in the file")
        if META_KEY in record:
            raise DatasetError(f"record: must not contain {META_KEY!r}")
        write_all(self.fd, dumps_line(record))
        # (in the file from here on: a signal during the fsync must not leave it counted as missing)
        self.done[idx] = record.get("success") is True
        if self.fsync:
            os.fsync(self.fd)

    def close(self):
        if self.fd >= 0:
            os.close(self.fd)   # releases the lock
            self.fd = -1

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass
