"""Ctrl-C held back over a block that must finish (renaming an export's files, saving the
checkpoint a first Ctrl-C keeps)."""
from __future__ import annotations

import contextlib
import signal
import threading


@contextlib.contextmanager
def interrupt_deferred(reraise: bool = True):
    """A SIGINT inside the block does not cut it: it is raised as ``KeyboardInterrupt`` when the
    block ends (``reraise``), or dropped (``reraise=False``: the block is what a first Ctrl-C
    does, and a second, impatient one must not undo it). Main thread only: only there can a
    handler be set, and only there does Python raise ``KeyboardInterrupt``."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got = []
    old = signal.signal(signal.SIGINT, lambda sig, frame: got.append(sig))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.SIG_DFL if old is None else old)
    if got and reraise:
        raise KeyboardInterrupt
