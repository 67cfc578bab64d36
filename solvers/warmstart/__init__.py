"""Learned warm starts for the indirect solver (numpy inference; training lives in ``training``).

``solvers.solve(problem)`` asks the default model (shipped in ``models/``) for a guess when
the problem is in the family the model covers, and falls back to the classical route when
it is not or when the guess fails. Pass ``warm_start=`` a ``WarmStartModel``, a
``NearestNeighbourModel``, a path to a model file, or ``None`` (no warm start).
"""
from __future__ import annotations

import functools
import os

import numpy as np

from .features import (FEATURE_NAMES, N_FEATURES, CanonicalForm, canonical_form, features,
                       solution_from_canonical, solution_to_canonical)
from .model import FORMAT, FORMAT_VERSION, ModelFileError, WarmStartModel
from .nearest import NearestNeighbourModel

MODELS_DIR = os.path.join(os.path.dirname(__file__), "models")
DEFAULT_MODEL_FILE = os.path.join(MODELS_DIR, "full-attitude.npz")
# its table of solved problems (its own training solutions), whose nearest solutions are tried
# after the network's structured candidates (``attitude_ensemble``)
DEFAULT_TABLE_FILE = os.path.join(MODELS_DIR, "full-attitude.nn.npz")
# the shipped model for pointing-only slews with keep-out cones (used by default when present)
DEFAULT_CONE_MODEL_FILE = os.path.join(MODELS_DIR, "pointing-cones.npz")
# its table of solved problems, whose nearest solutions are tried before the network's guess
DEFAULT_CONE_TABLE_FILE = os.path.join(MODELS_DIR, "pointing-cones.nn.npz")
# which full-attitude problems are singular, and the near singular answers' sequences
# (``singular_table``): ``auto``'s route when the default model's guess fails
DEFAULT_SINGULAR_TABLE_FILE = os.path.join(MODELS_DIR, "full-attitude-singular.npz")


def load_model(path):
    """A warm-start model from a file: ``.npz`` (learned) or ``.nn.npz`` (nearest-neighbour table).

    Loaded models are cached per (path, modification time, size): solving many problems with
    ``warm_start=PATH`` reads the file once."""
    path = os.path.abspath(os.fspath(path))
    try:
        st = os.stat(path)
        key = (st.st_mtime_ns, st.st_size)
    except OSError:
        key = None
    return _load_cached(path, key)


@functools.lru_cache(maxsize=8)
def _load_cached(path, key):
    if path.endswith(".nn.npz"):
        return NearestNeighbourModel.load(path)
    return WarmStartModel.load(path)


@functools.lru_cache(maxsize=1)
def default_model() -> WarmStartModel:
    """The shipped full-attitude network (loaded once per process)."""
    return WarmStartModel.load(DEFAULT_MODEL_FILE)


def default_warm_start():
    """What ``warm_start="default"`` uses for full-attitude problems: the shipped network, then
    the nearest solutions of its table (``attitude_ensemble``), or the network alone if no table
    is shipped."""
    try:    # its vote decides whether more neighbours are worth trying (attitude_ensemble)
        singular = default_singular_table()
    except (OSError, ValueError):   # a damaged file: solve() records the error on its own route
        singular = None
    return _with_table(default_model(), DEFAULT_TABLE_FILE, "attitude", singular)


@functools.lru_cache(maxsize=4)
def _ensemble(network, table, kind, singular=None):
    if kind == "attitude":
        from .attitude_ensemble import AttitudeEnsembleWarmStart
        return AttitudeEnsembleWarmStart(network, table, singular_table=singular)
    from .cone_ensemble import ConeEnsembleWarmStart
    return ConeEnsembleWarmStart(network, table)


def _with_table(network, table_file, kind, singular=None):
    """``network`` with the shipped neighbour table ``table_file`` (one ensemble object per
    set of loaded files, cached), or ``network`` alone if no table is shipped or the file is
    damaged (the network still gives its guess; ``table_error`` says why the table is missing,
    and ``solve`` records it in ``warm_start["table_error"]``)."""
    try:
        st = os.stat(table_file)
    except OSError:
        return network
    key = (st.st_mtime_ns, st.st_size)
    bad = _TABLE_ERRORS.get(table_file)
    if bad is not None and bad[0] == key:      # the same damaged file: not read again
        return network
    try:
        table = load_model(table_file)
    except (OSError, ValueError) as e:
        _TABLE_ERRORS[table_file] = (key, f"{type(e).__name__}: {e}"[:300])
        return network
    _TABLE_ERRORS.pop(table_file, None)
    return _ensemble(network, table, kind, singular)


_TABLE_ERRORS = {}    # path → ((mtime, size), reason) of a shipped table that failed to load


def table_error(model_file_kind="full-attitude"):
    """Why the shipped neighbour table of ``"full-attitude"`` or ``"pointing-cones"`` was not
    used on the last load, or ``None``."""
    path = DEFAULT_TABLE_FILE if model_file_kind == "full-attitude" else DEFAULT_CONE_TABLE_FILE
    bad = _TABLE_ERRORS.get(path)
    return None if bad is None else bad[1]


@functools.lru_cache(maxsize=1)
def default_singular_table():
    """The shipped singular table (loaded once per process), or ``None`` if none is shipped."""
    if not os.path.exists(DEFAULT_SINGULAR_TABLE_FILE):
        return None
    from .singular_table import SingularTable
    return SingularTable.load(DEFAULT_SINGULAR_TABLE_FILE)


def default_cone_model():
    """The shipped pointing-cones warm start (loaded once per process): the neighbour table
    and the network (``cone_ensemble``), or the network alone if no table is shipped, or
    ``None`` if no model is shipped."""
    if not os.path.exists(DEFAULT_CONE_MODEL_FILE):
        return None
    return _with_table(load_model(DEFAULT_CONE_MODEL_FILE), DEFAULT_CONE_TABLE_FILE, "cones")


class _ConeModelOptIn:
    """What ``warm_start="default"`` gives a pointing problem with cones as a first guess: none,
    and the reason recorded in ``SlewSolution.warm_start`` (the shipped cone model is opt-in as
    a first guess; ``method="auto"`` uses it as a challenger after the default route instead,
    ``solvers.cone_routes.cone_challenger``)."""
    name = "shipped models"
    REASON = ("cones: the shipped pointing-cones warm start is opt-in as a first guess, warm_start='pointing-cones' "
              "(on held-out problems it converges on 70 %, and 42 % of those answers are slower local extremals "
              "than the collocation route's; docs/WARMSTART.md); method='auto' tries it after the default route "
              "and keeps its answer only if faster")

    def covers(self, problem):
        return self.REASON

    def guess(self, problem):
        raise ValueError(self.REASON)


class _UserModel:
    """A user's model with ``covers()`` read either way: the package's rule (``None`` or ``""``:
    covered; a text: the reason it is not) or a boolean (``True``: covered). A user model
    answering ``True`` had been taken as "not covered, reason True" and never used."""

    def __init__(self, model):
        self.model = model
        self.name = getattr(model, "name", type(model).__name__)

    def covers(self, problem):
        why = self.model.covers(problem)
        if why is True or isinstance(why, np.bool_) and bool(why):
            return None
        if why is False or isinstance(why, np.bool_):
            return f"{self.name}.covers() returned False"
        return why or None

    def guess(self, problem):
        return self.model.guess(problem)

    def __getattr__(self, attr):
        # the model's other attributes (``last_inference_s``, a card) as they are
        if attr == "model":
            raise AttributeError(attr)
        return getattr(self.model, attr)


def resolve(warm_start, problem=None):
    """``"default"`` → the shipped full-attitude warm start (a pointing problem with cones gets no
    guess by default, with the reason recorded); ``"pointing-cones"`` → the shipped
    pointing-cones model; a path → that file; a model → itself; ``None`` → ``None``."""
    if warm_start is None or warm_start is False:
        return None
    if isinstance(warm_start, str) and warm_start == "default":
        if problem is not None and problem.cones and problem.qf is None:
            return _ConeModelOptIn()
        return default_warm_start()
    if isinstance(warm_start, str) and warm_start == "pointing-cones":
        cone = default_cone_model()
        if cone is None:
            raise ValueError(f"warm_start: no pointing-cones model is shipped ({DEFAULT_CONE_MODEL_FILE} is missing)")
        return cone
    if isinstance(warm_start, (str, os.PathLike)):
        if isinstance(warm_start, str) and warm_start.strip().lower() in ("none", "null", "") \
                and not os.path.exists(warm_start):
            # (the command line's spelling of None, given from Python)
            raise ValueError(f"warm_start: {warm_start!r} is no model name or file; for no warm start pass None "
                             "(Python) or 'none' (the command line); the names are 'default' and 'pointing-cones'")
        return load_model(warm_start)
    if hasattr(warm_start, "guess") and hasattr(warm_start, "covers"):
        if type(warm_start).__module__.startswith(__name__):
            return warm_start
        return _UserModel(warm_start)
    raise ValueError(f"warm_start: expected 'default', 'pointing-cones', None, a model file path or a model with "
                     f"guess() and covers(), got {type(warm_start).__name__}")


__all__ = ["FEATURE_NAMES", "N_FEATURES", "CanonicalForm", "canonical_form", "features",
           "solution_from_canonical", "solution_to_canonical", "FORMAT", "FORMAT_VERSION",
           "ModelFileError", "WarmStartModel", "NearestNeighbourModel", "load_model", "default_model",
           "resolve", "DEFAULT_MODEL_FILE", "DEFAULT_TABLE_FILE", "default_warm_start", "table_error", "DEFAULT_CONE_MODEL_FILE", "DEFAULT_CONE_TABLE_FILE",
           "default_cone_model", "default_singular_table", "DEFAULT_SINGULAR_TABLE_FILE"]
