"""The output file of ``slew solve --batch``: one JSON record a line, each written as soon as its
problem is solved, so that an interrupted batch keeps its finished results and ``--resume``
continues it (a fuzz run: the whole-file atomic writer had dropped every finished record on Ctrl-C).

The file is written as ``slew generate`` writes a dataset, with its helpers (``training.dataset``):
opened ``O_APPEND`` under an exclusive ``flock`` (two runs never write one file), each record one
``os.write`` of its whole line and newline, then ``fsync``. A run killed at any instant (SIGKILL
included) thus leaves complete records and at most one partial last line without its newline,
which ``--resume`` cuts away. A complete line that is not a record of this batch is refused with
its line number, never repaired by guessing.

Without ``--resume`` an existing file is overwritten: emptied once the lock is held, before the
first record. ``-`` (stdout) and a path that is not a regular file (``/dev/null``, a FIFO) are
written straight through; they cannot be read back, so they cannot be resumed.
"""
from __future__ import annotations

import json
import os
import stat
import sys

from .dataset import DatasetError, json_lines, lock_exclusive, read_fd, write_all

# every record begins so: ``solve_line`` puts "line" first and writes it with ``json.dumps``
RECORD_HEAD = b'{"line": '


def _begins_a_record(data: bytes) -> bool:
    return data.startswith(RECORD_HEAD) or RECORD_HEAD.startswith(data)


def _same_problem(recorded, text) -> bool:
    """Whether a record's ``problem`` is the problem of the input line ``text`` (both read as
    ``SlewProblem``s, so that formatting does not matter)."""
    from slew_env import SlewProblem
    try:
        return _close(SlewProblem.from_dict(recorded).to_dict(), SlewProblem.from_dict(json.loads(text)).to_dict())
    except (ValueError, TypeError, AttributeError):
        return False


def _close(a, b) -> bool:
    """``a == b`` for JSON values, numbers to 1e-12 (a unit quaternion normalised once more may
    change in its last bit)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_close(x, y) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool) and not isinstance(b, bool):
        return abs(a - b) <= 1e-12 * max(1.0, abs(a), abs(b))
    return a == b


class BatchOutput:
    """Where a batch's records go.

    ``BatchOutput(path, resume, lines)``: ``lines`` maps the input line numbers that hold a
    problem to their text. With ``resume`` the records already in the file are read into ``done``
    (input line number -> record); each must be a record of one of ``lines``, at most one per line,
    and a record that carries its problem must carry that line's (not another batch's).
    ``write(text)`` appends one record (JSON text without its newline). Errors are one-line
    ``ValueError``s naming ``-o`` or ``--resume``.
    """

    def __init__(self, path, resume: bool = False, lines=(), fsync: bool = True):
        self.path = path
        self.fsync = fsync
        self.done = {}
        self.written = 0              # records written by this run
        self.truncated_bytes = 0      # partial last line cut away by --resume
        self.resumable = False        # a regular file: a later --resume can continue it
        self._fd = -1
        self._stream = None
        if path == "-":
            if resume:
                raise ValueError("--resume: needs -o FILE: stdout cannot be read back to continue")
            self._stream = sys.stdout
            return
        try:
            st = os.stat(path)
        except FileNotFoundError:
            st = None
        except OSError as e:
            raise ValueError(f"-o: cannot use {path!r}: {e.strerror or e}") from None
        if st is not None and not stat.S_ISREG(st.st_mode):
            if resume:
                raise ValueError(f"--resume: -o {path!r} is not a regular file; it cannot be read back to continue")
            try:
                self._stream = open(path, "w", encoding="utf-8")
            except OSError as e:
                raise ValueError(f"-o: cannot write to {path!r}: {e.strerror or e}") from None
            return
        try:
            fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o666)
        except OSError as e:
            raise ValueError(f"-o: cannot open {path!r} for writing: {e.strerror or e}") from None
        try:
            try:
                lock_exclusive(fd, path)
            except DatasetError as e:
                raise ValueError(f"-o: {e}") from None
            if resume:
                self._read_done(fd, dict(lines) if isinstance(lines, dict) else set(lines))
            else:
                os.ftruncate(fd, 0)
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        self.resumable = True

    def _read_done(self, fd, lines):
        path = self.path
        data = read_fd(fd)
        refuse = (f"-o: {path}: not the output of 'slew solve --batch' (it does not begin with a record "
                  f"{RECORD_HEAD.decode()}...); refusing to continue it: give another -o, or leave out "
                  "--resume to overwrite it")
        if data and not _begins_a_record(data):
            raise ValueError(refuse)
        try:
            records, end = json_lines(data, path)
        except DatasetError as e:
            raise ValueError(f"-o: {e}") from None
        at = {}
        for lineno, rec in records:
            k = rec.get("line") if isinstance(rec, dict) else None
            if not isinstance(k, int) or isinstance(k, bool):
                raise ValueError(f"-o: {path}: line {lineno} is not a record of 'slew solve --batch' (no input "
                                 "\"line\" number); refusing to continue the file: give another -o")
            if k not in lines:
                raise ValueError(f"-o: {path}: line {lineno} is the record of input line {k}, which holds no "
                                 "problem in the --batch file: was it written from another batch? Give another -o")
            if k in at:
                raise ValueError(f"-o: {path}: input line {k} has two records (lines {at[k]} and {lineno}); "
                                 "one run never writes that: fix the file or give another -o")
            if isinstance(lines, dict) and "problem" in rec and not _same_problem(rec["problem"], lines[k]):
                raise ValueError(f"-o: {path}: line {lineno} is the record of another problem than input line {k} "
                                 "of the --batch file (another batch, or the file was edited): give another -o, or "
                                 "leave out --resume to overwrite it")
            at[k] = lineno
            self.done[k] = rec
        tail = data[end:]
        if tail:
            # a record cut short by a killed run (or the zeros a power cut leaves): anything else
            # there is someone's text, not to be cut away
            if not _begins_a_record(tail) and tail.strip(b"\0"):
                raise ValueError(f"-o: {path}: its last {len(tail)} byte(s), without a newline, are not the "
                                 "beginning of a record; refusing to cut them away: fix the file or give another -o")
            os.ftruncate(fd, end)
            os.fsync(fd)
            self.truncated_bytes = len(tail)

    @property
    def count(self) -> int:
        """Records in the output: those found by ``--resume`` and those written since."""
        return len(self.done) + self.written

    def write(self, text: str) -> None:
        line = text + "\n"
        try:
            if self._stream is not None:
                self._stream.write(line)
                self._stream.flush()      # (a reader of the pipe sees each record as it is solved)
            else:
                write_all(self._fd, line.encode("utf-8"))
                if self.fsync:
                    os.fsync(self._fd)
        except OSError as e:
            raise ValueError(f"-o: cannot write to {self._name()}: {e.strerror or e}") from None
        self.written += 1

    def _name(self):
        return "stdout" if self.path == "-" else repr(self.path)

    def close(self):
        try:
            if self._fd >= 0:
                os.close(self._fd)    # releases the lock
            elif self._stream is not None and self._stream is not sys.stdout:
                self._stream.close()
            elif self._stream is sys.stdout:
                sys.stdout.flush()
        except OSError as e:
            raise ValueError(f"-o: cannot write to {self._name()}: {e.strerror or e}") from None
        finally:
            self._fd = -1
            self._stream = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
