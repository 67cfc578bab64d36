"""Initial guesses for the indirect solvers, all behind one ``Guess`` type.

A ``Guess`` is given in the units of the problem (the same units as a
``SlewSolution``): ``costate0 = [λq(0) (4), λω(0) (3)]`` (any positive scale, any
gauge: the solver projects out the component of ``λq(0)`` along ``q(0)``), ``tf``,
optionally the switch times per axis and the sign of each axis's first arc (a
bang-bang guess can then go straight to the exact switch-time solver), and
optionally further ``candidates`` tried in order (a candidate may be deferred: a function
returning a ``Guess`` or ``None``, called only if the solver reaches it). A learned model returns the same
type (``Guess(costate0=..., tf=..., switch_times=..., source="learned")``).

Classical guesses provided here:

* ``eigenaxis_guess`` — the analytic eigenaxis costates of the seed report
  (eqs. 39–44): ``μ = -n``, ``λω(0) = -(tf/4) n`` in nondimensional units, with ``n``
  the eigenaxis in body axes and ``tf`` that of the rest-to-rest eigenaxis slew with
  the largest constant acceleration the bound allows about ``n``. Exact for the
  2-norm ball and a symmetric body at rest.
* ``symmetric_images`` — images of a guess under the signed axis permutations that map
  the problem onto itself (mirror-image extremals, e.g. the 180° case of R1).
* ``perturbed`` — seeded random perturbations of a guess (multi-start).
"""
from __future__ import annotations

import copy
import itertools
import math
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from slew_env.checks import has_bool, has_text
from slew_env.core.quaternion import qaxis_angle, qconj, qmul


class _FailedCandidate:
    """A deferred candidate that had failed when its guess was pickled: calling it raises that
    failure again (a ``ValueError`` as it was, any other as a ``RuntimeError`` of its name)."""

    def __init__(self, kind, message):
        self.kind, self.message = kind, message

    def __call__(self):
        if self.kind == "ValueError":
            raise ValueError(self.message)
        # a stand-in type of the same name, so that the solver's report reads as it would have
        raise type(self.kind, (RuntimeError,), {})(self.message)


def _numbers(name, value):
    """``value`` as a float array, or a ``ValueError`` naming ``name``."""
    if type(value) is np.ndarray and value.dtype.kind == "f":
        # the models' own guesses: no look at the entries (a guess is built in microseconds)
        return value if value.dtype == np.float64 else value.astype(np.float64)
    if value is None or has_bool(value) or has_text(value):
        raise ValueError(f"{name}: expected numbers, got {value!r:.80}")
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}: expected numbers, got {value!r:.80}") from None


# switch times an axis that a guess may carry: the switch-time Jacobian is dense, (3n + 7)² numbers
# (1,000 an axis: 72 MB; 100,000 had asked numpy for 671 GiB). Optimal slews have a few to a few
# tens; a singular arc's switch-time answers, some tens
MAX_GUESS_SWITCHES = 1000


@dataclass
class Guess:
    costate0: np.ndarray
    tf: float
    switch_times: Optional[List[np.ndarray]] = None
    u_first: Optional[np.ndarray] = None
    source: str = "user"
    candidates: list = field(default_factory=list)
    # keep-out cones touched at isolated instants (``solvers.cone_touch``): a list of
    # ``(cone index, time, multiplier)``, the multiplier in the scale of ``costate0`` (as
    # ``verification["touch_multipliers"]`` reports it); ``None``: no touch information
    touches: Optional[list] = None

    def __post_init__(self):
        c = _numbers("guess.costate0", self.costate0)
        if c.shape != (7,):
            raise ValueError(f"guess.costate0: expected 7 numbers [λq (4), λω (3)], got shape {c.shape}")
        if not np.isfinite(c).all():
            raise ValueError("guess.costate0: all entries must be finite")
        self.costate0 = c
        if type(self.tf) is float or type(self.tf) is np.float64:
            tf = float(self.tf)
        else:
            tf = _numbers("guess.tf", self.tf)
            if tf.shape != ():
                raise ValueError(f"guess.tf: must be a positive finite time, got {self.tf!r:.80}")
            tf = float(tf)
        if not (math.isfinite(tf) and tf > 0.0):
            raise ValueError(f"guess.tf: must be a positive finite time, got {self.tf!r:.80}")
        self.tf = tf
        if self.switch_times is not None:
            if isinstance(self.switch_times, (str, bytes)) or not hasattr(self.switch_times, "__len__") \
                    or len(self.switch_times) != 3:
                raise ValueError("guess.switch_times: expected a list of 3 arrays (one per axis)")
            self.switch_times = [_numbers(f"guess.switch_times[{i}]", s).ravel()
                                 for i, s in enumerate(self.switch_times)]
            for i, s in enumerate(self.switch_times):
                if s.size and not np.isfinite(s).all():
                    raise ValueError(f"guess.switch_times[{i}]: all entries must be finite, got {s.tolist()!r:.80}")
                if s.size > MAX_GUESS_SWITCHES:
                    raise ValueError(f"guess.switch_times[{i}]: at most {MAX_GUESS_SWITCHES} switch times an axis "
                                     f"(the switch-time Newton's Jacobian is dense in them), got {s.size}")
        if not isinstance(self.source, str):
            raise ValueError(f"guess.source: expected a text naming where the guess comes from, got {self.source!r:.80}")
        if isinstance(self.candidates, (str, bytes)) or not isinstance(self.candidates, (list, tuple)):
            raise ValueError(f"guess.candidates: expected a list of Guess objects or functions returning one, "
                             f"got {type(self.candidates).__name__}")
        if self.u_first is not None:
            u = _numbers("guess.u_first", self.u_first)
            if u.shape != (3,) or not np.isfinite(u).all():
                raise ValueError(f"guess.u_first: expected 3 finite signs (one per axis), got shape {u.shape}")
            self.u_first = np.sign(u)
        if self.touches is not None:
            rows = []
            for k, t in enumerate(self.touches):
                try:
                    c, tt, nu = t
                    if isinstance(c, (bool, str, bytes)) or float(c) != int(c):      # (0.7 was cone 0)
                        raise ValueError
                    c, tt, nu = int(c), float(tt), float(nu)
                except (TypeError, ValueError, OverflowError):
                    raise ValueError(f"guess.touches[{k}]: expected (cone index, time, multiplier), "
                                     f"got {t!r}") from None
                if c < 0 or not (0.0 < tt < self.tf) or not (math.isfinite(nu) and nu >= 0.0):
                    raise ValueError(f"guess.touches[{k}]: needs cone index ≥ 0, 0 < time < tf "
                                     f"({self.tf:g}) and a finite multiplier ≥ 0, got {t!r}")
                rows.append((c, tt, nu))
            self.touches = sorted(rows, key=lambda r: r[1])

    @classmethod
    def _checked(cls, costate0, tf, switch_times=None, u_first=None, source="user"):
        """A guess from values its maker has already checked: ``costate0`` a finite float64
        array (7,), ``tf`` a positive finite float, ``switch_times`` ``None`` or 3 finite float64
        arrays, ``u_first`` ``None`` or 3 signs ±1. Skips ``__post_init__``'s checks (10 µs,
        a tenth of the learned guess's inference); every other field takes its default."""
        g = cls.__new__(cls)
        g.costate0, g.tf, g.switch_times, g.u_first, g.source = costate0, tf, switch_times, u_first, source
        g.candidates, g.touches = [], None
        return g

    def all(self):
        """This guess followed by its candidates (deferred ones computed now)."""
        return list(self.iter_all())

    def iter_all(self, errors=None):
        """This guess followed by its candidates, a deferred candidate (a function of no
        arguments returning a ``Guess`` or ``None``) computed only when it is reached: a solver
        that converges on the first guess never pays for the later ones. Its result is kept on
        this guess (``None``: skipped); ``candidates`` itself is not changed, so a guess shared
        between calls or threads stays intact (a deferred function may then run more than
        once: it must not have side effects that matter). Pickling a guess (to send it to a
        process pool or Ray) makes its deferred candidates first (``__getstate__``).

        ``errors``: ``None`` (a candidate that is not a ``Guess``, or a deferred one that raises
        or returns something else, is an error), or a list to which such candidates are added
        as ``"candidates[k]: reason"`` and skipped (a model's guess: one bad candidate must not
        stop the solve)."""
        yield self
        memo = self.__dict__.setdefault("_deferred", {})
        for k, c in enumerate(list(self.candidates)):
            if not isinstance(c, Guess):
                try:
                    c = self._made(k, c, memo)
                except Exception as e:      # noqa: BLE001 - any failure of a model's code
                    if errors is None:
                        if isinstance(e, ValueError):
                            raise
                        raise ValueError(f"guess.candidates[{k}]: the deferred candidate raised "
                                         f"{type(e).__name__}: {e}"[:300]) from e
                    errors.append(f"candidates[{k}]: {type(e).__name__}: {e}"[:300])
                    memo[k] = None
                    continue
                if c is None:           # nothing to add (e.g. the same as an earlier candidate)
                    continue
            yield c

    @staticmethod
    def _made(k, c, memo):
        """Candidate ``k`` that is not a ``Guess``: the deferred function's result (made once,
        kept in ``memo``), or an error."""
        if not callable(c):
            raise ValueError(f"guess.candidates[{k}]: expected a Guess or a function returning one, "
                             f"got {type(c).__name__}")
        if k not in memo:
            made = c()
            if made is not None and not isinstance(made, Guess):
                raise ValueError(f"guess.candidates[{k}]: the deferred candidate returned "
                                 f"{type(made).__name__}, expected a Guess or None")
            memo[k] = made
        return memo[k]

    # copying (``copy.copy``, ``copy.deepcopy``) goes through ``__reduce_ex__`` as pickling does;
    # these keep the deferred candidates deferred, so that only pickling runs a model's code
    def __copy__(self):
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        return new

    def __deepcopy__(self, memo):
        new = object.__new__(type(self))
        memo[id(self)] = new
        new.__dict__.update(copy.deepcopy(self.__dict__, memo))
        return new

    def __getstate__(self):
        # A deferred candidate is usually a closure over a model (not picklable), so a pickled
        # guess carries what it makes instead: the ``Guess``, nothing for ``None``, and for one
        # that fails a stand-in that raises the same error when the solver reaches it, so that
        # the solve in the other process reports it as this one would have.
        state = dict(self.__dict__)
        state.pop("_deferred", None)
        if all(isinstance(c, Guess) for c in self.candidates):
            return state
        memo = self.__dict__.setdefault("_deferred", {})
        plain = []
        for k, c in enumerate(self.candidates):
            if isinstance(c, Guess):
                plain.append(c)
                continue
            try:
                made = self._made(k, c, memo)
            except Exception as e:      # noqa: BLE001 - raised again where the solver reaches it
                plain.append(_FailedCandidate(type(e).__name__, str(e)))
                continue
            if made is not None:
                plain.append(made)
        state["candidates"] = plain
        return state

    # --- conversion to / from the solver's nondimensional unknowns
    def to_nondim(self, bvp, with_norm=False):
        """``(z, T)``: normalised ``[μ, λω(0)]`` and the nondimensional final time; with
        ``with_norm``, also ``|z|`` before normalising (quantities in the scale of
        ``costate0``, such as touch multipliers, are divided by it too)."""
        lq = self.costate0[:4]
        mu = qmul(qconj(bvp.q0), lq)[1:4]
        z = np.concatenate([mu / bvp.tau, self.costate0[4:] / bvp.tau ** 2])
        n = float(np.linalg.norm(z))
        if n == 0:
            raise ValueError("guess.costate0: the costate is zero in the solver's gauge")
        return (z / n, self.tf / bvp.tau, n) if with_norm else (z / n, self.tf / bvp.tau)


def costate_from_nondim(bvp, z) -> np.ndarray:
    """The costates ``[λq, λω]`` in problem units of the solver's parameters ``z = [μ, λω(0)]``
    (``λq(0) = q0 ⊗ [0, μ]``, scaled by τ; ``λω`` by τ²): ``Guess.to_nondim`` undone, unnormalised."""
    lq = qmul(bvp.q0, np.array([0.0, z[0], z[1], z[2]])) * bvp.tau
    lw = np.asarray(z[3:6]) * bvp.tau ** 2
    return np.concatenate([lq, lw])


def from_nondim(bvp, z, T, source, switch_times=None, u_first=None):
    st = None if switch_times is None else [np.asarray(s) * bvp.tau for s in switch_times]
    return Guess(costate_from_nondim(bvp, z), T * bvp.tau, st, u_first, source)


def eigenaxis_axis_angle(problem):
    """Eigenaxis ``n`` (body axes, unit) and angle ``θ`` in [0, π] from ``q0`` to ``qf``."""
    n, th = qaxis_angle(np.ascontiguousarray(problem.q0, dtype=np.float64),
                        np.ascontiguousarray(problem.qf, dtype=np.float64))
    return n, float(th)


def eigenaxis_acceleration(J, umax, p, n):
    """Largest constant angular acceleration about unit axis ``n`` the bound allows (at rest)."""
    a = np.abs(J * n) / umax     # torque per unit acceleration, in units of the bound
    if math.isinf(p):
        return 1.0 / float(np.max(a))
    return 1.0 / float(np.sum(a ** p) ** (1.0 / p))


def eigenaxis_guess(bvp, long_way=False) -> Guess:
    """Seed report eqs. 39–44, generalised to any inertia and bound (nondimensional)."""
    n, th = eigenaxis_axis_angle(bvp.ref_problem)   # pointing-only: to the reference attitude
    if long_way:
        n, th = -n, 2.0 * math.pi - th
    acc = eigenaxis_acceleration(bvp.J, bvp.umax, bvp.problem.torque_norm, n)
    T = 2.0 * math.sqrt(max(th, 1e-12) / acc)
    z = np.concatenate([-n, -(T / 4.0) * n])
    z /= np.linalg.norm(z)
    return from_nondim(bvp, z, T, "eigenaxis-long" if long_way else "eigenaxis")


def problem_symmetries(problem, tol=1e-12):
    """Signed axis permutations ``P`` (3x3) that map the problem onto itself.

    ``P`` acts on axial vectors as ``det(P) P``. It must preserve the inertia and torque
    bound, and the relative rotation ``q0* ⊗ qf`` (the body-frame slew) up to sign.
    Only rest-to-rest problems have them here (the images of non-zero rates are other problems).
    """
    out = []
    if not problem.is_rest_to_rest:
        return out
    J, u = problem.inertia, problem.torque_max
    n, th = eigenaxis_axis_angle(problem)
    rot = n * math.sin(th / 2.0)
    half_turn = abs(math.cos(th / 2.0)) < 1e-12   # q ≡ -q: the axis may flip too
    # every solve asks (the multi-start's images): the permutation is tested on J and the
    # bound first, in plain floats, and only the few that keep both get their 8 sign patterns
    for perm in itertools.permutations(range(3)):
        if any(abs(J[j] - J[i]) > tol * abs(J[i]) or abs(u[j] - u[i]) > tol * abs(u[i]) for i, j in enumerate(perm)):
            continue
        for sgn in itertools.product((1.0, -1.0), repeat=3):
            P = np.zeros((3, 3))
            for i, j in enumerate(perm):
                P[i, j] = sgn[i]
            d = np.linalg.det(P)
            img = d * (P @ rot)
            if np.allclose(img, rot, atol=1e-12) or (half_turn and np.allclose(img, -rot, atol=1e-12)):
                out.append(d * P)
    return out


def symmetric_images(bvp, z, T):
    """Images of nondimensional ``(z, T)`` under the problem's symmetries (identity excluded)."""
    imgs = []
    if getattr(bvp, "pointing", False):   # the images of a pointing target are other targets
        return imgs
    for A in problem_symmetries(bvp.problem):
        if np.allclose(A, np.eye(3)):
            continue
        zi = np.concatenate([A @ z[:3], A @ z[3:]])
        if not any(np.allclose(zi, w, atol=1e-9) for w, _ in imgs) and not np.allclose(zi, z, atol=1e-9):
            imgs.append((zi, T))
    return imgs


def perturbed(z, T, rng, scale):
    zz = z + scale * rng.normal(size=6)
    return zz / np.linalg.norm(zz), T * (1.0 + 0.1 * scale * rng.normal())


# Switch counts per axis tried by the structure templates, most common first: a generic
# rest-to-rest per-axis extremal needs at least 5 switches for its 6 boundary conditions
# (plus tf); 2-2-1 patterns are what Bilimoria & Wie report for large slews.
TEMPLATE_COUNTS = ((2, 2, 1), (2, 1, 2), (1, 2, 2), (2, 2, 2), (3, 2, 1), (1, 2, 3), (2, 3, 1),
                   (1, 3, 2), (3, 1, 2), (2, 1, 3))


def structure_templates(bvp, z, T, rng, max_templates=12, inner=(0.25, 0.4)):
    """Switching-structure guesses ``(z, T, (signs0, axes, times), name)`` around the eigenaxis.

    Each axis starts accelerating towards the eigenaxis (``sign(n_i)``; both signs for an
    axis nearly orthogonal to it); an axis with one switch switches near ``T/2``, with two
    near ``aT`` and ``(1-a)T``, with three at ``aT``, ``T/2``, ``(1-a)T``. ``T`` is 0.92 of the
    eigenaxis time (per-axis optima are typically 5-15 % faster). The costate guess is
    ``z`` plus a small seeded perturbation, which breaks the symmetry of the eigenaxis.
    """
    n, _ = eigenaxis_axis_angle(bvp.ref_problem)
    base = np.where(n >= 0, 1.0, -1.0)
    weak = [i for i in range(3) if abs(n[i]) < 0.15]
    sign_sets = [base]
    for i in weak:
        for s in list(sign_sets):
            f = s.copy()
            f[i] = -f[i]
            sign_sets.append(f)
    Tg = 0.92 * T
    out = []
    k = 0
    for counts in TEMPLATE_COUNTS:
        for s0 in sign_sets:
            a = inner[k % len(inner)]
            k += 1
            times, axes = [], []
            for i, c in enumerate(counts):
                pts = {1: [0.5], 2: [a, 1 - a], 3: [a, 0.5, 1 - a]}[c]
                # stagger axes slightly so no two switches start at the same instant
                times += [(x + 0.01 * i) * Tg for x in pts]
                axes += [i] * c
            o = np.argsort(times)
            zz = z + 0.2 * rng.normal(size=6)
            zz /= np.linalg.norm(zz)
            out.append((zz, Tg, (s0.copy(), np.asarray(axes, dtype=np.int64)[o], np.asarray(times)[o]),
                        f"template{counts}"))
            if len(out) >= max_templates:
                return out
    return out
