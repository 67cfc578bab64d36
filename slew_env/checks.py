"""What counts as a number in the input of every layer (problem fields, environment
arguments, solver options, guesses).

Python and numpy read more than numbers as numbers: ``float(True)`` is 1, ``float("1")``
is 1, and ``np.asarray(["1"], float)`` parses the text. A boolean or a quoted number in a
problem file or an option is more likely a slip than intent, so the checks here let the
callers refuse it by name rather than guess at it.
"""
from __future__ import annotations

import math

import numpy as np


def is_real(v) -> bool:
    """A real number: an int or float (Python or numpy), not a boolean or text."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def is_integer(v) -> bool:
    """An int (Python or numpy), not a boolean."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def is_finite(v) -> bool:
    """A finite real number (a Python int too large for a float is not)."""
    try:
        return is_real(v) and math.isfinite(v)
    except OverflowError:
        return False


def whole(name, v, lo, hi=2 ** 53) -> int:
    """``v`` as an int in ``[lo, hi]`` (an integral float too), or a ``ValueError`` naming ``name``."""
    if not (is_real(v) and (is_integer(v) or (math.isfinite(v) and int(v) == v)) and v >= lo):
        raise ValueError(f"{name}: must be a whole number >= {lo}, got {v!r:.80}")
    if v > hi:
        raise ValueError(f"{name}: must be a whole number <= {hi}, got {v!r:.80}")
    return int(v)


def has_bool(value) -> bool:
    """Whether ``value`` is or holds a boolean (JSON ``true``), which numpy would take as 1."""
    if isinstance(value, (bool, np.bool_)):
        return True
    if isinstance(value, np.ndarray):
        return value.dtype == bool
    if isinstance(value, (list, tuple)):
        return any(has_bool(v) for v in value)
    return False


def has_text(value) -> bool:
    """Whether ``value`` is or holds a string, which numpy would parse as a number."""
    if isinstance(value, (str, bytes, np.str_, np.bytes_)):
        return True
    if isinstance(value, np.ndarray):
        return value.dtype.kind in "SUO" and (value.dtype.kind != "O"
                                             or any(has_text(v) for v in value.ravel()))
    if isinstance(value, (list, tuple)):
        return any(has_text(v) for v in value)
    return False
