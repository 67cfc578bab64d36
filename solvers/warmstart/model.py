"""Learned warm starts, evaluated in numpy from exported weights (no torch here).

A warm-start model maps the canonical features of a problem (``features``) to a guess of
its time-optimal solution: the nondimensional costates ``z'`` (canonical axes, unit
norm), the final time (as ``log(T / T_eig)``, ``T_eig`` the eigenaxis guess's time), the
sign of each axis's first arc, and the switching structure (number of switches per axis,
0 … ``max_switches``, and their instants as fractions of ``T``). ``guess(problem)`` turns
that into a ``solvers.Guess`` with candidates the solver tries in order:

1. ``learned`` — costates, final time, predicted structure (straight to the switch-time
   Newton);
2. ``learned-propagated`` — the same costates with the structure their own switching
   functions produce (an event-driven propagation), if it differs from 1;
3. ``learned-costate`` — costates and final time alone (smoothing continuation).

File format (``.npz``, written by ``training.warmstart.export``): arrays ``W0, b0, W1,
b1, …`` (float32; layer ``k`` maps ``h ↦ act(h W_k + b_k)``, no activation on the
last), ``x_mean``, ``x_std``, and ``card``, a JSON string: ``format`` ("slewopt-warmstart"),
``format_version``, ``activation``, ``max_switches``, ``output_layout``, ``domain``
(the family the model covers), ``training`` (data and metrics) and ``sha256`` of the
weight arrays. ``load`` refuses (``ModelFileError``, naming the file and the field) a file that
is missing, unreadable, of another format or version, whose weights do not match the checksum,
whose card is not a JSON object or has a field of the wrong type or range (``card_whole``,
``checked_domain``, ``check_output_layout``), or whose layers do not chain as the compiled forward
pass reads them (``check_weight_chain``; docs/WARMSTART.md, "Model file").
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass
from typing import Optional

import numpy as np

from slew_env import SlewProblem
from ..core import warmstart_kernels as _k
from ..guesses import Guess
from .features import N_FEATURES, canonical_form, unsupported_reason

FORMAT = "slewopt-warmstart"
FORMAT_VERSION = 1
ACTIVATIONS = ("silu", "tanh", "relu")

# Bounds on what a model or table file may claim (docs/WARMSTART.md, "Model file"). A guess is made
# inside a solve's time budget, before the solver starts, so every count that sets its cost is
# bounded: the shipped files use 3–5 neighbours, 3 sequences, 5 switches, 4 layers, 8 heads and
# 145,000 weights. 64 neighbours cost about 1.6 ms a guess (mapping each to the problem), 4 Mi
# weights about 0.7 ms a network pass.
MAX_LAYERS = 64
MAX_HEADS = 64
MAX_SWITCHES = 50          # per axis (the switch-time Newton's Jacobian grows as the square of 3·K)
MAX_WEIGHTS = 1 << 22      # weights of all layers together
MAX_NEIGHBOURS = 64        # a table's k (and the singular table's n_sequences)


def output_size(max_switches: int) -> int:
    return 6 + 1 + 3 + 3 * (max_switches + 1) + 3 * max_switches


def output_layout(max_switches: int) -> dict:
    """Slices of the output vector (also written in the card)."""
    K = max_switches
    o = {"z": (0, 6), "log_T_ratio": (6, 7), "u_first_logit": (7, 10),
         "count_logits": (10, 10 + 3 * (K + 1)), "times_logit": (10 + 3 * (K + 1), 10 + 3 * (K + 1) + 3 * K)}
    return o


def weights_checksum(arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


class ModelFileError(ValueError):
    """A model file that cannot be used (missing, corrupt, other format or version)."""


# --------------------------------------------------------------------------- card checks
def _is_whole(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def card_object(card, path):
    """``card`` (parsed JSON) if it is a JSON object; ``ModelFileError`` naming ``path`` otherwise."""
    if not isinstance(card, dict):
        raise ModelFileError(f"model: {path}: the card is a JSON {_json_type(card)}, not an object of named fields "
                             "(a damaged or hand-made file)")
    return card


def _json_type(v) -> str:
    return {list: "array", str: "string", bool: "boolean", type(None): "null", int: "number",
            float: "number"}.get(type(v), type(v).__name__)


def whole_field(value, field, lo, hi, why=""):
    """``value`` as an ``int`` if it is a whole number (not a bool, not text, not 2.5) in
    ``[lo, hi]``; else ``ModelFileError`` naming ``field`` (``why``: the reason for the bound)."""
    if not _is_whole(value) or not lo <= int(value) <= hi:
        raise ModelFileError(f"{field}: expected a whole number ≥ {lo} and ≤ {hi}{why}, got {value!r}"[:300])
    return int(value)


def card_whole(card, field, lo, hi, default=None, why=""):
    """``card[field]`` checked by ``whole_field`` (``default`` where absent; ``None``: required)."""
    if field not in card:
        if default is None:
            raise ModelFileError(f"card.{field}: missing")
        return default
    return whole_field(card[field], f"card.{field}", lo, hi, why)


def card_text(card, field, default):
    """``card[field]`` if it is text, ``default`` where absent; ``ModelFileError`` otherwise."""
    v = card.get(field, default)
    if not isinstance(v, str):
        raise ModelFileError(f"card.{field}: expected text, got {_json_type(v)} {v!r}"[:300])
    return v


def _range_pair(d, key, lo, hi, whole=False):
    v = d[key]
    ok = (isinstance(v, (list, tuple)) and len(v) == 2
          and all((_is_whole(a) if whole else _is_number(a)) and math.isfinite(float(a)) for a in v))
    if ok:
        a, b = (float(x) for x in v)
        ok = lo <= a <= b <= hi
    if not ok:
        kind = "whole numbers" if whole else "numbers"
        raise ModelFileError(f"card.domain.{key}: expected [low, high], {kind} with {lo:g} ≤ low ≤ high ≤ {hi:g}, "
                             f"got {v!r}"[:300])


def checked_domain(domain) -> dict:
    """The card's ``domain`` (``{}`` if absent or null) once its fields are well-formed: the
    ranges the coverage checks read (``angle_deg``, ``inertia_ratio``, ``torque_ratio_min``,
    ``torque_norm``, ``n_cones``, ``cone_half_angle_deg``, the rate-limit flags) and the
    descriptive ones (``target``, ``family``, ...); other fields are kept as they are.
    ``ModelFileError`` naming the field otherwise (a malformed domain had loaded, and then every
    coverage check raised a bare ``ValueError`` inside the solve, which quietly fell back)."""
    if domain is None:
        return {}
    if not isinstance(domain, dict):
        raise ModelFileError(f"card.domain: expected a JSON object of the family's ranges, got "
                             f"{_json_type(domain)} {domain!r}"[:300])
    for key, lo, hi in (("angle_deg", 0.0, 180.0), ("cone_half_angle_deg", 0.0, 180.0), ("inertia_ratio", 0.0, 1.0)):
        if key in domain:
            _range_pair(domain, key, lo, hi)
    if "n_cones" in domain:
        from .cone_features import MAX_CONES
        _range_pair(domain, "n_cones", 0, MAX_CONES, whole=True)
    if "torque_ratio_min" in domain:
        v = domain["torque_ratio_min"]
        if not (_is_number(v) and 0.0 <= float(v) <= 1.0):
            raise ModelFileError(f"card.domain.torque_ratio_min: expected a number in [0, 1], got {v!r}"[:300])
    if "torque_norm" in domain:
        domain_torque_norm(domain)
    for key in ("rate_max", "rate_norm_max", "rest_to_rest", "cones"):
        if key in domain and not (domain[key] is None or isinstance(domain[key], bool)):
            raise ModelFileError(f"card.domain.{key}: expected true, false or null, got {domain[key]!r}"[:300])
    for key in ("target", "family", "sensor_axis"):
        if key in domain and not (domain[key] is None or isinstance(domain[key], str)):
            raise ModelFileError(f"card.domain.{key}: expected text, got {domain[key]!r}"[:300])
    return domain


def domain_torque_norm(domain) -> float:
    """The torque norm ``p`` a domain covers (``"inf"``, or a number ≥ 1, as a number or text)."""
    v = domain.get("torque_norm", "inf")
    try:
        p = float(v) if (_is_number(v) or isinstance(v, str)) else math.nan
    except ValueError:
        p = math.nan
    if not p >= 1.0:      # (NaN too)
        raise ModelFileError(f"card.domain.torque_norm: expected \"inf\" or a number ≥ 1, got {v!r}"[:300])
    return p


def check_weight_chain(weights, where="weights"):
    """The layers ``[(W_k, b_k), ...]`` as the compiled forward pass reads them
    (``warmstart_kernels.mlp_forward``, ``_dense``): at least one; each ``W_k`` a 2-D array of
    real numbers whose rows are the previous layer's outputs (``W_k.shape[0] ==
    W_{k-1}.shape[1]``), each ``b_k`` 1-D with one entry a column of ``W_k``, no empty layer,
    and at most ``MAX_WEIGHTS`` weights in all. ``ModelFileError`` naming the array otherwise
    (a file whose layers did not chain had loaded, and the compiled pass read past the end of a
    layer's outputs)."""
    if len(weights) < 1:
        raise ModelFileError(f"{where}: the network has no layer")
    total = 0
    for k, (W, b) in enumerate(weights):
        for name, a, nd in ((f"W{k}", W, 2), (f"b{k}", b, 1)):
            a = np.asarray(a)
            if a.dtype.kind not in "fiu":
                raise ModelFileError(f"{where}: {name} holds {a.dtype} values, not real numbers")
            if a.ndim != nd:
                raise ModelFileError(f"{where}: {name} has shape {a.shape}, expected a {nd}-D array")
        W, b = np.asarray(W), np.asarray(b)
        if 0 in W.shape:
            raise ModelFileError(f"{where}: W{k} has shape {W.shape}, an empty layer")
        if k > 0:
            given = np.asarray(weights[k - 1][0]).shape[1]
            if W.shape[0] != given:
                raise ModelFileError(f"{where}: W{k} expects {W.shape[0]} inputs, W{k - 1} gives {given} "
                                     f"(W{k - 1} {tuple(weights[k - 1][0].shape)}, W{k} {W.shape})")
        if b.shape[0] != W.shape[1]:
            raise ModelFileError(f"{where}: b{k} has {b.shape[0]} entries, W{k} has {W.shape[1]} outputs")
        total += W.size + b.size
    if total > MAX_WEIGHTS:
        raise ModelFileError(f"{where}: {total:,} weights in all, more than the {MAX_WEIGHTS:,} a guess can pass "
                             "through within a millisecond or so of a solve's time budget")


def check_output_layout(layout, expected, head_size, K):
    """The card's ``output_layout`` (``None``: ``expected``) as ``{name: (start, end)}``: the
    names of ``expected``, each slice as wide as there (the compiled decoders read that many
    outputs from its start) and inside one head's ``head_size`` outputs."""
    if layout is None:
        return {k: tuple(v) for k, v in expected.items()}
    if not isinstance(layout, dict) or set(layout) != set(expected):
        got = sorted(layout) if isinstance(layout, dict) else layout
        raise ModelFileError(f"card.output_layout: expected the slices {sorted(expected)}, got {got!r}"[:300])
    out = {}
    for name, (a0, b0) in expected.items():
        v = layout[name]
        ok = isinstance(v, (list, tuple)) and len(v) == 2 and all(_is_whole(x) for x in v)
        if ok:
            a, b = int(v[0]), int(v[1])
            ok = 0 <= a and b - a == b0 - a0 and b <= head_size
        if not ok:
            raise ModelFileError(f"card.output_layout.{name}: expected [start, start + {b0 - a0}] within the "
                                 f"{head_size} outputs of a head (max_switches {K}), got {v!r}"[:300])
        out[name] = (a, b)
    return out


def read_npz(path) -> dict:
    """All arrays of a model file; ``ModelFileError`` if it is missing or unreadable."""
    if not os.path.exists(path):
        raise ModelFileError(f"model: file not found: {path}")
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError as e:     # a directory, a file without read permission
        raise ModelFileError(f"model: {path} cannot be read ({e.strerror or type(e).__name__})") from None
    if head != b"PK\x03\x04":
        # (np.load reads other formats too, and for a pickle suggests loading it unsafely)
        raise ModelFileError(f"model: {path} is not a .npz model file (a model is a zip archive of arrays "
                             "written by 'slew train --export'; this file starts with "
                             f"{head!r})")
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except Exception as e:   # noqa: BLE001 - any read failure is a corrupt file
        raise ModelFileError(f"model: {path} is not a readable .npz model file ({type(e).__name__}: {e})") from None


def read_table(path, fmt, version):
    """``(arrays, card)`` of a table file (``.npz`` with a JSON ``card`` of ``format`` ``fmt``
    and ``format_version`` ``version``); ``ModelFileError`` otherwise."""
    path = os.fspath(path)
    d = read_npz(path)
    try:
        card = json.loads(str(d["card"]))
    except (KeyError, json.JSONDecodeError) as e:
        raise ModelFileError(f"model: {path} has no readable card ({e})") from None
    card_object(card, path)
    if card.get("format") != fmt or not _is_whole(card.get("format_version")) or card["format_version"] != version:
        raise ModelFileError(f"model: {path} is not a {fmt} v{version} file")
    return d, card


def _act(name, h):
    if name == "silu":
        return 0.5 * h * (1.0 + np.tanh(0.5 * h))   # h·sigmoid(h), without overflow
    if name == "tanh":
        return np.tanh(h)
    return np.maximum(h, 0.0)


@dataclass
class Prediction:
    """Canonical nondimensional prediction for one problem."""
    z: np.ndarray            # (6,) unit norm
    T: float                 # nondimensional final time
    u_first: np.ndarray      # (3,) ±1
    counts: np.ndarray       # (3,) switches per canonical axis
    count_prob: np.ndarray   # (3, K+1)
    times: list              # per canonical axis, nondimensional, sorted


class WarmStartModel:
    """A numpy MLP warm-start model (see the module docstring)."""

    def __init__(self, weights, x_mean, x_std, card: dict):
        # float32 as stored: a 1x256 by 256x256 product is twice as fast as in float64, and a
        # guess needs no more than single precision
        if not isinstance(card, dict):
            raise ModelFileError(f"card: expected a dict of named fields, got {type(card).__name__}")
        self.weights = weights
        self.x_mean = self._standardisation("x_mean", x_mean)
        self.x_std = self._standardisation("x_std", x_std)
        if not np.all(self.x_std > 0.0):
            j = int(np.flatnonzero(~(self.x_std > 0.0))[0])
            raise ModelFileError(f"x_std: the features' scales must be positive, x_std[{j}] is {float(self.x_std[j])!r} "
                                 "(each feature is divided by its scale)")
        self.card = card
        self.activation = card.get("activation", "silu")
        if not isinstance(self.activation, str) or self.activation not in ACTIVATIONS:
            raise ModelFileError(f"card.activation: unknown activation {self.activation!r}")
        self._check_layout(card)
        # a smoke test of the loaded network (numpy, 0.1 ms): finite outputs at the features' mean.
        # Finite weights can still overflow (a copy scaled by 1e20), and every guess then fails
        with np.errstate(all="ignore"):
            out = self.forward(self.x_mean[None, :])
        if not np.all(np.isfinite(out)):
            raise ModelFileError(f"weights: the network's outputs at the features' mean (x_mean) are not finite "
                                 f"({int(np.sum(~np.isfinite(out)))} of {out.size}): weights out of any trained range")
        self.domain = checked_domain(card.get("domain"))
        self._torque_norm = domain_torque_norm(self.domain)
        self.name = card_text(card, "name", "warm-start model")
        self.path = card.get("_path")

    def _standardisation(self, field, v):
        """``x_mean`` or ``x_std``: one finite real number a feature (the first layer's inputs)."""
        a = np.asarray(v)
        n_in = self.weights[0][0].shape[0]
        if a.dtype.kind not in "fiu" or a.shape != (n_in,):
            raise ModelFileError(f"{field}: expected {n_in} real numbers (one a feature, as W0 has rows), got "
                                 f"{a.dtype} values of shape {a.shape}")
        a = a.astype(np.float64)
        if not np.all(np.isfinite(a)):
            raise ModelFileError(f"{field}: {int(np.sum(~np.isfinite(a)))} entries are not finite (NaN or inf)")
        return a

    KIND = "full-attitude"

    @property
    def weights(self):
        """``[(W_k, b_k), ...]``, float32; assigning it also refreshes the compiled row path."""
        return self._weights

    @weights.setter
    def weights(self, value):
        # the layers must chain before the compiled pass reads them (``check_weight_chain``)
        value = list(value)
        check_weight_chain(value)
        self._weights = [(np.asarray(W, np.float32), np.asarray(b, np.float32)) for W, b in value]
        for k, (W, b) in enumerate(self._weights):
            for name, a in ((f"W{k}", W), (f"b{k}", b)):
                if not np.all(np.isfinite(a)):
                    raise ModelFileError(f"weights: {name} has {int(np.sum(~np.isfinite(a)))} entries that are not "
                                         "finite in float32 (NaN, inf, or beyond 3.4e38): every guess would be NaN")
        # the compiled single-row path (``forward`` of one row): writable row-major copies, so
        # that numba sees one array type in the tuple
        self._rows = (tuple(np.array(W, np.float32, order="C") for W, _ in self._weights),
                      tuple(np.array(b, np.float32, order="C") for _, b in self._weights))

    def _check_layout(self, card):
        """The card's structure fields against the weights: ``max_switches``, the output size,
        the ``output_layout`` the compiled decoder reads (``warmstart_kernels.decode_attitude``)."""
        self.K = card_whole(card, "max_switches", 0, MAX_SWITCHES)
        heads = card.get("heads", 1)
        if heads != 1 or isinstance(heads, bool):
            raise ModelFileError(f"card.heads: a full-attitude model has one head, got {heads!r} (several heads are "
                                 "for kind 'pointing-cones')"[:300])
        n_out = self.weights[-1][0].shape[1]
        if n_out != output_size(self.K) or self.weights[0][0].shape[0] != N_FEATURES:
            raise ModelFileError(f"weights: shapes {self.weights[0][0].shape[0]} → {n_out} do not match "
                                 f"{N_FEATURES} features → {output_size(self.K)} outputs (max_switches {self.K})")
        self.layout = check_output_layout(card.get("output_layout"), output_layout(self.K), n_out, self.K)

    # ------------------------------------------------------------------ file
    @classmethod
    def load(cls, path) -> "WarmStartModel":
        """The model in ``path``, of the class its card names (``kind``: ``"full-attitude"``
        or ``"pointing-cones"``)."""
        path = os.fspath(path)
        data = read_npz(path)
        if "card" not in data:
            raise ModelFileError(f"model: {path} has no model card")
        try:
            card = json.loads(str(data["card"]))
        except json.JSONDecodeError as e:
            raise ModelFileError(f"model: {path}: the model card is not valid JSON ({e})") from None
        card_object(card, path)
        if card.get("format") != FORMAT:
            raise ModelFileError(f"model: {path} is not a {FORMAT} file (format {card.get('format')!r})")
        if not _is_whole(card.get("format_version")) or card["format_version"] != FORMAT_VERSION:
            raise ModelFileError(f"model: {path} has format version {card.get('format_version')!r}; this "
                                 f"version of slewopt reads version {FORMAT_VERSION} (re-export the model)")
        try:
            n_layers = card_whole(card, "n_layers", 1, MAX_LAYERS)
            extra = sorted(k for k in data if k[:1] in "Wb" and k[1:].isdigit() and int(k[1:]) >= n_layers)
            if extra:
                raise ModelFileError(f"card.n_layers: {n_layers}, but the file holds {', '.join(extra)} too")
        except ModelFileError as e:
            raise ModelFileError(f"model: {path}: {e}") from None
        try:
            weights = [(data[f"W{k}"], data[f"b{k}"]) for k in range(n_layers)]
            x_mean, x_std = data["x_mean"], data["x_std"]
        except KeyError as e:
            raise ModelFileError(f"model: {path} lacks the array {e}") from None
        arrays = [a for wb in weights for a in wb] + [x_mean, x_std]
        if weights_checksum(arrays) != card.get("sha256"):
            raise ModelFileError(f"model: {path}: weights do not match the checksum in the card (corrupt file)")
        card["_path"] = path
        kind = card.get("kind", "full-attitude")
        if kind == "pointing-cones":
            from .cone_model import ConeWarmStartModel
            model_cls = ConeWarmStartModel
        elif kind == "full-attitude":
            model_cls = cls
        else:
            raise ModelFileError(f"model: {path}: unknown model kind {kind!r}"[:300])
        try:     # the card's fields and the layers' shapes (``__init__``), named with the file
            return model_cls(weights, x_mean, x_std, card)
        except ModelFileError as e:
            raise ModelFileError(f"model: {path}: {e}") from None

    def save(self, path):
        arrays = {}
        flat = []
        for k, (W, b) in enumerate(self.weights):
            arrays[f"W{k}"] = np.asarray(W, np.float32)
            arrays[f"b{k}"] = np.asarray(b, np.float32)
            flat += [arrays[f"W{k}"], arrays[f"b{k}"]]
        arrays["x_mean"] = np.asarray(self.x_mean, np.float64)
        arrays["x_std"] = np.asarray(self.x_std, np.float64)
        card = {k: v for k, v in self.card.items() if not k.startswith("_")}
        card.update(format=FORMAT, format_version=FORMAT_VERSION, n_layers=len(self.weights), kind=self.KIND,
                    max_switches=self.K, output_layout={k: list(v) for k, v in self.layout.items()},
                    activation=self.activation,
                    sha256=weights_checksum(flat + [arrays["x_mean"], arrays["x_std"]]))
        arrays["card"] = np.array(json.dumps(card))
        tmp = os.fspath(path) + ".tmp"
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
        os.replace(tmp, path)
        self.card = card

    # ------------------------------------------------------------------ coverage
    def covers(self, problem) -> Optional[str]:
        """``None`` if ``problem`` is in the model's family, else the reason it is not."""
        return self._coverage(SlewProblem.from_dict(problem))[0]

    def _coverage(self, problem):
        """``(reason or None, canonical form or None)``: the form is computed once, for the
        range checks and then for the prediction."""
        why = self._family_reason(problem)
        if why:
            return why, None
        cf = canonical_form(problem)
        return self._range_reason(cf.x), cf

    def _family_reason(self, problem):
        """Why ``problem`` is not of the model's family (``None`` if it is), before its features."""
        why = unsupported_reason(problem)
        if why:
            return why
        d = self.domain
        if problem.rate_max is not None and not d.get("rate_max", False):
            return "rate_max: the model was trained without rate limits"
        if problem.rate_norm_max is not None and not d.get("rate_norm_max", False):
            return "rate_norm_max: the model was trained without a limit on the rate's norm"
        p = problem.torque_norm
        if float(p) != self._torque_norm:      # (the domain's, checked at load: "inf" or a number)
            return f"torque_norm: the model covers torque_norm={d.get('torque_norm', 'inf')}, got {p}"
        return None

    def _range_reason(self, x):
        """Why the features ``x`` are outside the model's ranges (``None`` if inside)."""
        d = self.domain
        th_deg = math.degrees(x[3] * math.pi)
        lo, hi = d.get("angle_deg", (0.0, 180.0))
        if not (lo - 1e-9 <= th_deg <= hi + 1e-9):
            return f"slew angle {th_deg:.3g}° outside the model's range [{lo:g}°, {hi:g}°]"
        rlo, rhi = d.get("inertia_ratio", (0.0, 1.0))
        if float(x[4:7].min()) < rlo - 1e-9:
            return f"inertia: J_min/J_max = {x[4:7].min():.3g} below the model's range ({rlo:g})"
        ulo = d.get("torque_ratio_min", 1.0)
        if float(x[7:10].min()) < ulo - 1e-9:
            return f"torque_max: u_min/u_max = {x[7:10].min():.3g} below the model's range ({ulo:g})"
        return None

    # ------------------------------------------------------------------ inference
    def forward(self, X):
        """Raw outputs for a batch of feature rows ``X`` (n, N_FEATURES), or ``(1, n_out)`` for
        one row ``X`` (N_FEATURES,) (compiled: ``solvers.core.warmstart_kernels.mlp_forward``)."""
        if np.ndim(X) == 1:
            Ws, bs = self._rows
            x = np.ascontiguousarray(X, dtype=np.float64)
            if x.shape[0] != Ws[0].shape[0] or self.x_mean.shape[0] != x.shape[0]:
                raise ValueError(f"X: expected {Ws[0].shape[0]} features, got {x.shape[0]}")
            return _k.mlp_forward(x, self.x_mean, self.x_std, Ws, bs, ACTIVATIONS.index(self.activation))[None, :]
        h = ((np.atleast_2d(X) - self.x_mean) / self.x_std).astype(np.float32)
        last = len(self.weights) - 1
        for k, (W, b) in enumerate(self.weights):
            h = h @ W + b
            if k < last:
                h = _act(self.activation, h)
        return h

    def predict_canonical(self, x, T_eig) -> Prediction:
        out = self.forward(np.asarray(x, np.float64).reshape(-1))[0]
        L = self.layout
        z, T, uf, counts, cp, tt = _k.decode_attitude(out, self.K, L["z"][0], L["log_T_ratio"][0],
                                                     L["u_first_logit"][0], L["count_logits"][0],
                                                     L["times_logit"][0], float(T_eig))
        if not (math.isfinite(T) and T > 0.0):
            raise ValueError(f"x: the network's final time is {T!r} (features outside the model's range?)")
        return Prediction(z, T, uf, counts, cp, [tt[i, :counts[i]] for i in range(3)])

    def guess(self, problem, propagate=True) -> Guess:
        """The learned guess for ``problem`` (``ValueError`` if the model does not cover it)."""
        g, why = self.guess_or_reason(problem, propagate)
        if why:
            raise ValueError(f"problem not covered by {self.name}: {why}")
        return g

    def guess_or_reason(self, problem, propagate=True):
        """``(guess, None)``, or ``(None, reason)`` when the model does not cover ``problem``
        (one coverage check: ``solvers.solve`` calls this)."""
        problem = SlewProblem.from_dict(problem)
        t0 = time.perf_counter()
        why = self._family_reason(problem)
        if why:
            return None, why
        # one compiled call: canonical form, network, decoding, map back to the problem
        # (``solvers.core.warmstart_kernels.attitude_guess``; the staged reference is
        # ``predict_canonical`` and ``features.solution_from_canonical``)
        L = self.layout
        Ws, bs = self._rows
        x, c0, tf, sw, counts, uf, ok = _k.attitude_guess(
            problem.q0, problem.qf, problem.inertia, problem.torque_max, float(problem.torque_norm),
            self.x_mean, self.x_std, Ws, bs, ACTIVATIONS.index(self.activation), self.K,
            L["z"][0], L["log_T_ratio"][0], L["u_first_logit"][0], L["count_logits"][0], L["times_logit"][0])
        why = self._range_reason(x)
        if why:
            return None, why
        if not ok:
            raise ValueError(f"x: the network's guess is not finite (final time {tf!r}; features outside "
                             f"the model's range?)")
        sw = [sw[i, :counts[i]] for i in range(3)]
        self.last_inference_s = time.perf_counter() - t0
        g = Guess._checked(c0, tf, sw, uf, source="learned")
        # the network's estimate of the optimal final time (``solve`` with ``method="auto"``
        # challenges an answer well above it, ``solvers.warm_routes.challenge_learned_answer``)
        g.predicted_tf = float(tf)
        if propagate:
            # deferred: one propagation (~0.25 ms), paid only when the first candidate fails
            def propagated():
                prop = _propagated_structure(problem, c0, tf)
                if prop is None:
                    return None
                sw_p, uf_p = prop
                same = (np.array_equal(uf_p, g.u_first) and all(len(a) == len(b) for a, b in zip(sw_p, sw)))
                return None if same else Guess(c0, tf, sw_p, uf_p, source="learned-propagated")
            g.candidates.append(propagated)
        g.candidates.append(Guess._checked(c0, tf, source="learned-costate"))
        return g, None


def _propagated_structure(problem, costate0, tf):
    """Switch times and first signs that the guessed costates' own switching functions give."""
    from ..attitude_bvp import AttitudeBVP   # local: keeps model loading light
    bvp = AttitudeBVP(problem)
    try:
        z, T = Guess(costate0, tf).to_nondim(bvp)
    except ValueError:      # degenerate costates (zero in the gauge): nothing to propagate
        return None
    tr = bvp.record(z, T, n_max=0)
    if not tr.ok:
        return None
    sw = [tr.switch_t[tr.switch_axis == i] * bvp.tau for i in range(3)]
    return sw, tr.signs0.copy()
