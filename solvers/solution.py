"""``SlewSolution``: a scipy-style result with the extremal, in the problem's units."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, Callable, List, Optional

import numpy as np

from slew_env.checks import has_bool, has_text

# status -> message (scipy style: a fixed table; ``message`` may add details)
STATUS_SUCCESS = 0
STATUS_NOT_CONVERGED = 1
STATUS_VERIFICATION_FAILED = 2
STATUS_BUDGET_EXHAUSTED = 3
STATUS_WORSE_THAN_BASELINE = 4

STATUS_MESSAGES = {
    STATUS_SUCCESS: "Verified extremal found.",
    STATUS_NOT_CONVERGED: "No candidate converged.",
    STATUS_VERIFICATION_FAILED: "A candidate converged but failed its own verification.",
    STATUS_BUDGET_EXHAUSTED: "Time budget exhausted before any candidate converged.",
    STATUS_WORSE_THAN_BASELINE: "Only extremals slower than the eigenaxis slew were found (local optima).",
}


def bang_bang_control(switch_times, u_first, torque_max):
    """``u(t)`` of a bang-bang control: axis ``i`` starts at ``u_first[i]·torque_max[i]`` and flips
    at each of its ``switch_times[i]`` (from the instant on: a sample at a switch takes the next arc)."""
    sw = [np.asarray(s, dtype=float).copy() for s in switch_times]
    u_first = np.asarray(u_first, dtype=float).copy()
    torque = np.asarray(torque_max, dtype=float).copy()

    def control(tq):
        tq = np.asarray(tq, dtype=float)
        flips = np.stack([np.searchsorted(sw[i], tq, side="right") for i in range(3)], axis=-1)
        return torque * u_first * np.where(flips % 2 == 0, 1.0, -1.0)
    return control


# how the returned control is defined (``SlewSolution.control_law``; README, 'Solution format')
CONTROL_LAWS = {
    "bang-bang": "±torque_max per axis, the sign u_first on the first arc, flipping at each of switch_times",
    "costate": "the closed-form p-norm law of the costates, propagated with the state from costate0",
    "quadratic-samples": "on each interval [t[2k], t[2k+2]], the quadratic through u at t[2k], t[2k+1], t[2k+2]",
    "linear-samples": "linear in t between the samples t, u",
}
# the laws that the samples define: a record without its dense samples keeps t and u for these
SAMPLE_LAWS = ("quadratic-samples", "linear-samples")


def control_law(method, verification, torque_norm) -> str:
    """The rule of ``SlewSolution.control_law`` (``CONTROL_LAWS``), for a solution or its JSON
    record: collocation's control is its quadratic model, a penalised cone answer's and the
    eigenaxis slew's are their samples, and an indirect or switch-time answer's is bang-bang per
    axis or, for a p-norm bound, its costates'."""
    if method == "collocation":
        return "quadratic-samples"
    if method == "eigenaxis" or "regularisation" in (verification or {}):
        return "linear-samples"
    if method in ("indirect", "multiple-shooting", "switch-time"):
        return "bang-bang" if math.isinf(float(torque_norm)) else "costate"
    return ""


def is_exact(success, method, verification) -> bool:
    """The rule of ``SlewSolution.exact``, for a solution or its JSON record: verified, from an
    indirect route, and not the penalised extremal of the cone route."""
    return bool(success is True and method in ("indirect", "multiple-shooting")
                and "regularisation" not in (verification or {}))


@dataclass
class SlewSolution:
    """Result of ``solvers.solve``.

    Attributes (scipy style first): ``success``, ``status`` (see ``STATUS_MESSAGES``),
    ``message``, ``nit`` (Newton iterations, all candidates), ``nfev`` (propagations),
    ``wall_time`` (s). Then, in the problem's units: ``tf`` and its tolerance ``tf_tol``; ``costate0 = [λq(0), λω(0)]``
    in the gauge ``λq(0)·q(0) = 0`` and the scale ``H ≡ -1``; ``switch_times`` (3 arrays,
    bang-bang only; empty for a p-norm bound and for the smooth control of a penalised cone
    answer, whose ``costate0`` is at the scale ``λ0 = 1``); ``u_first`` (sign of each axis's first arc);
    dense samples ``t, q, omega, u, costate`` (``costate`` is (n, 7)); ``control(t)``, and
    ``control_law`` (how a record defines that control: ``CONTROL_LAWS``);
    ``method``, ``route`` (how the answer was reached), ``guess`` (which guess won);
    ``n_candidates`` tried and ``candidates_tf`` (final times of all converged
    candidates, the local optima seen); ``baseline_tf`` (the eigenaxis slew's time, for
    rest-to-rest problems); ``verification`` (dict of checks); ``exact`` (a verified exact
    extremal, not an approximation: see the property); ``warm_start`` (the learned
    warm start: ``model``, ``covered`` or the ``reason`` it was not, ``succeeded``,
    ``candidates`` tried, ``time_s`` spent on it, ``inference_s``; with the shipped model also
    ``predicted_tf`` and, when ``auto`` checked its answer against the collocation route,
    ``local_optimum_check``; ``table_error`` if a shipped table could not be read);
    ``kernel_load_time`` (s), before the clock started (not in ``wall_time``, not in the time
    budget): loading the compiled kernels of the problem's kind, the first solve of that kind in a
    process (``solvers.load_kernels``), and where the route begins with collocation (pointing
    and cone problems; ``auto`` on full-attitude problems no warm start covers) building the
    collocation NLPs of their mesh and cone count the first time.
    """
    success: bool
    status: int
    message: str
    nit: int
    nfev: int
    wall_time: float
    tf: float = math.nan
    tf_tol: float = math.nan
    costate0: np.ndarray = field(default_factory=lambda: np.full(7, np.nan))
    switch_times: List[np.ndarray] = field(default_factory=lambda: [np.zeros(0)] * 3)
    u_first: np.ndarray = field(default_factory=lambda: np.zeros(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    q: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    omega: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    u: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    costate: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    method: str = ""
    route: str = ""
    guess: str = ""
    n_candidates: int = 0
    candidates_tf: List[float] = field(default_factory=list)
    baseline_tf: float = math.nan
    verification: dict = field(default_factory=dict)
    warm_start: dict = field(default_factory=dict)
    kernel_load_time: float = 0.0
    problem: Any = None
    _control: Optional[Callable] = None
    # collocation's deferred tf_tol measurement (``collocation.settle_tf_tol``), if any
    _tf_tol_pending: Optional[Callable] = field(default=None, repr=False, compare=False)
    # an answer of a problem with cones that is the answer (or an extremal) of that problem without
    # them, certified clear of the cones (``cone_routes``: ``refine_inactive_cones``,
    # ``clear_without_cones``): ``cone_free_challenger`` leaves it alone
    _cone_free: bool = field(default=False, repr=False, compare=False)

    def control(self, t):
        """Torque at time(s) ``t`` (problem units). Bang-bang: exact from the switch times.

        Defined on ``[0, tf]`` only: outside it the law is extended (the first or last arc's
        torque, the samples' end values), not switched off; a simulation that runs past ``tf``
        must stop torquing itself."""
        if self._control is None:
            raise ValueError("control: this solution has no trajectory")
        try:
            raw = None if has_bool(t) or has_text(t) else np.asarray(t)
        except (TypeError, ValueError):
            raw = None
        # numbers only: text and booleans, also inside a list and beside numbers, are not instants
        # ('0.5' and True had been read as 0.5 and 1.0)
        if raw is None or raw.dtype.kind not in "iuf":
            raise ValueError(f"t: the instants must be numbers, got {type(t).__name__} {t!r:.80}")
        tq = raw.astype(float)
        if not np.all(np.isfinite(tq)):
            # (a NaN instant would otherwise get a torque: the first arc's, by searchsorted)
            raise ValueError(f"t: the instants must be finite numbers, got {t!r:.80}")
        return self._control(tq)

    @property
    def exact(self) -> bool:
        """A verified exact extremal of the problem as posed: an indirect answer that is not
        the penalised extremal of the cone route (``verification['regularisation']``).
        Collocation and penalised answers are approximations of the optimum."""
        return is_exact(bool(self.success), self.method, self.verification)

    @property
    def control_law(self) -> str:
        """How the returned control is defined, for a replay from the record alone: a key of
        ``CONTROL_LAWS`` (``""`` where there is no trajectory)."""
        if self.problem is None or len(self.t) == 0:
            return ""
        return control_law(self.method, self.verification, self.problem.torque_norm)

    @property
    def n_switches(self) -> int:
        return int(sum(len(s) for s in self.switch_times))

    def __repr__(self):
        lines = [f"{k:>13}: {v}" for k, v in (
            ("success", self.success), ("status", self.status), ("message", self.message),
            ("tf", f"{self.tf} ± {self.tf_tol:.1g}"), ("switches", [len(s) for s in self.switch_times]),
            ("u_first", self.u_first.tolist()), ("nit", self.nit), ("nfev", self.nfev),
            ("wall_time", f"{self.wall_time:.4f} s"), ("method", self.method), ("route", self.route),
            ("guess", self.guess), ("n_candidates", self.n_candidates))]
        return "\n".join(lines)

    def to_dict(self, dense=True) -> dict:
        """JSON-ready dict (see README, 'Solution format'). ``dense=False`` leaves out the dense
        samples ``t, q, omega, u, costate``, except ``t`` and ``u`` where they define the control
        (``control_law`` in ``SAMPLE_LAWS``: collocation, penalised and eigenaxis answers)."""
        def clean(x):
            if isinstance(x, dict):
                return {k: clean(v) for k, v in x.items()}
            if isinstance(x, (list, tuple)):
                return [clean(v) for v in x]
            if isinstance(x, np.ndarray):
                return clean(x.tolist())
            if isinstance(x, (np.floating, float)):
                x = float(x)
                return x if math.isfinite(x) else None
            if isinstance(x, (np.integer,)):
                return int(x)
            if isinstance(x, np.bool_):
                return bool(x)
            return x
        d = {
            "success": self.success, "status": self.status, "message": self.message, "exact": self.exact,
            "tf": self.tf, "tf_tol": self.tf_tol, "costate0": self.costate0, "switch_times": self.switch_times,
            "u_first": self.u_first, "nit": self.nit, "nfev": self.nfev,
            "wall_time_s": self.wall_time, "kernel_load_time_s": self.kernel_load_time, "method": self.method, "route": self.route,
            "guess": self.guess, "n_candidates": self.n_candidates,
            "candidates_tf": self.candidates_tf, "baseline_tf": self.baseline_tf, "control_law": self.control_law,
            "verification": self.verification, "warm_start": self.warm_start,
        }
        if self.problem is not None:
            d["problem"] = self.problem.to_dict()
        if dense:
            d["t"] = self.t
            d["q"] = self.q
            d["omega"] = self.omega
            d["u"] = self.u
            d["costate"] = self.costate
        elif d["control_law"] in SAMPLE_LAWS:
            # the samples are the control here (its switch times are not): without them the
            # record could not be flown
            d["t"] = self.t
            d["u"] = self.u
        return clean(d)

    def to_json(self, dense=True, **kw) -> str:
        return json.dumps(self.to_dict(dense=dense), **kw)
