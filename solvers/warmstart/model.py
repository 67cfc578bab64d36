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
weight arrays. ``load`` refuses a file that is missing, unreadable, of another format or
version, or whose weights do not match the checksum.
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
    if card.get("format") != fmt or card.get("format_version") != version:
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
        self.weights = weights
        self.x_mean = np.asarray(x_mean, np.float64)
        self.x_std = np.asarray(x_std, np.float64)
        self.card = card
        self.activation = card.get("activation", "silu")
        if self.activation not in ACTIVATIONS:
            raise ModelFileError(f"card.activation: unknown activation {self.activation!r}")
        self._check_layout(card)
        self.domain = card.get("domain", {})
        self.name = card.get("name", "warm-start model")
        self.path = card.get("_path")

    KIND = "full-attitude"

    @property
    def weights(self):
        """``[(W_k, b_k), ...]``, float32; assigning it also refreshes the compiled row path."""
        return self._weights

    @weights.setter
    def weights(self, value):
        self._weights = [(np.asarray(W, np.float32), np.asarray(b, np.float32)) for W, b in value]
        # the compiled single-row path (``forward`` of one row): writable row-major copies, so
        # that numba sees one array type in the tuple
        self._rows = (tuple(np.array(W, np.float32, order="C") for W, _ in self._weights),
                      tuple(np.array(b, np.float32, order="C") for _, b in self._weights))

    def _check_layout(self, card):
        self.K = int(card["max_switches"])
        self.layout = {k: tuple(v) for k, v in card.get("output_layout", output_layout(self.K)).items()}
        n_out = self.weights[-1][0].shape[1]
        if n_out != output_size(self.K) or self.weights[0][0].shape[0] != N_FEATURES:
            raise ModelFileError(f"weights: shapes {self.weights[0][0].shape[0]} → {n_out} do not match "
                                 f"{N_FEATURES} features → {output_size(self.K)} outputs (max_switches {self.K})")

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
        if card.get("format") != FORMAT:
            raise ModelFileError(f"model: {path} is not a {FORMAT} file (format {card.get('format')!r})")
        if card.get("format_version") != FORMAT_VERSION:
            raise ModelFileError(f"model: {path} has format version {card.get('format_version')!r}; this "
                                 f"version of slewopt reads version {FORMAT_VERSION} (re-export the model)")
        n_layers = int(card.get("n_layers", 0))
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
            return ConeWarmStartModel(weights, x_mean, x_std, card)
        if kind != "full-attitude":
            raise ModelFileError(f"model: {path}: unknown model kind {kind!r}")
        return cls(weights, x_mean, x_std, card)

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
        norm = d.get("torque_norm", "inf")
        p = problem.torque_norm
        if str(norm) != ("inf" if math.isinf(p) else repr(float(p))):
            return f"torque_norm: the model covers torque_norm={norm}, got {p}"
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
