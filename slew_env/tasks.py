"""Task distributions: the random slews the environment draws on reset.

The dataset generator and the RL scripts reuse the same named families, so a
family name fixes the distribution everywhere::

    from slew_env.tasks import TaskDistribution
    dist = TaskDistribution.family("pointing-cones")          # or "full-attitude"
    problem = dist.sample(np.random.default_rng(0))            # a validated SlewProblem
    custom = TaskDistribution.family("pointing-cones", n_cones=(2, 4))

Sampling runs in compiled code (``slew_env.core.sampling``) on a block of
uniforms drawn from the caller's generator; see that module for the exact
order in which uniforms are used.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Optional, Union

import numpy as np

from .core import sampling as _s
from .core import task as _t
from .checks import is_finite, is_real, whole
from .problem import MAX_AXIS_SPREAD, SlewProblem, _vector, check_time_unit

# Uniforms per sampling attempt. A failed attempt (cone rejections exhausted the
# block) is retried from scratch on the next block of the same generator.
BLOCK = 256
# Blocks tried before the distribution is declared unable to produce a task.
MAX_BLOCKS = 64

_INERTIA_MODES = {"fixed": _s.INERTIA_FIXED, "symmetric": _s.INERTIA_SYMMETRIC,
                  "asymmetric": _s.INERTIA_ASYMMETRIC}


def _pair(name, value, lo_bound=None, hi_bound=None, integer=False):
    pair = value.tolist() if isinstance(value, np.ndarray) else value
    if not (isinstance(pair, (list, tuple)) and len(pair) == 2 and all(is_real(v) for v in pair)):
        raise ValueError(f"{name}: expected a (low, high) pair of numbers, got {value!r:.80}")
    lo, hi = pair
    if not (is_finite(lo) and is_finite(hi)) or lo > hi:
        raise ValueError(f"{name}: need finite low <= high, got ({lo!r:.40}, {hi!r:.40})")
    lo, hi = float(lo), float(hi)
    if lo_bound is not None and lo < lo_bound or hi_bound is not None and hi > hi_bound:
        raise ValueError(f"{name}: must lie in [{lo_bound}, {hi_bound}], got ({lo:g}, {hi:g})")
    if integer:
        if lo != int(lo) or hi != int(hi):
            raise ValueError(f"{name}: expected whole numbers, got ({lo:g}, {hi:g})")
        return int(lo), int(hi)
    return lo, hi


def _positive3(name, value):
    # the problem's own check: booleans and text refused, one number broadcast to three
    if value is None:
        raise ValueError(f"{name}: expected one or three positive numbers, got None")
    return tuple(_vector(name, value, 3, positive=True, allow_scalar=True).tolist())


def _number_in(name, value, lo, hi, hi_open=False, what=None):
    """``value`` as a float in ``[lo, hi]`` (``[lo, hi)`` if ``hi_open``), or a ``ValueError`` naming ``name``."""
    interval = f"[{lo:g}, {hi:g}{')' if hi_open else ']'}"
    if not (is_finite(value) and lo <= value and (value < hi if hi_open else value <= hi)):
        raise ValueError(f"{name}: must be a number in {interval}{what or ''}, got {value!r:.80}")
    return float(value)


def _probability(name, value):
    return _number_in(name, value, 0.0, 1.0)


@dataclass(frozen=True)
class TaskDistribution:
    """Distribution of random rest-to-rest slews.

    ======================  =====================  ==============================================
    Field                   Default                Meaning
    ======================  =====================  ==============================================
    ``angle_deg``           ``(10, 180)``          slew angle range θ (deg): eigenaxis angle of a
                                                   full target, or the angle between the start
                                                   sensor direction and a pointing target
    ``pointing_prob``       ``0.0``                probability of a pointing-only target (roll
                                                   about the sensor free); else a full attitude
    ``inertia_mode``        ``"asymmetric"``       ``"fixed"``: ``inertia``; ``"symmetric"``:
                                                   ``(1, 1, 1)``; ``"asymmetric"``: each ``J_i``
                                                   uniform in ``inertia_ratio``
    ``inertia``             ``(1, 1, 1)``          inertia of the fixed mode
    ``inertia_ratio``       ``(0.4, 1.0)``         range of ``J_i`` in the asymmetric mode
    ``symmetric_prob``      ``0.0``                asymmetric mode: probability that the body
                                                   is symmetric ``(1, 1, 1)`` instead
    ``torque_max``          ``(1, 1, 1)``          torque bound (one number or three)
    ``torque_norm``         ``"inf"``              ``"inf"`` per-axis bound, or ``1.05 ≤ p ≤ 100``
    ``sensor_axis``         ``(1, 0, 0)``          body sensor axis
    ``n_cones``             ``(0, 0)``             number of keep-out cones, uniform integer
    ``cone_half_angle_deg`` ``(10, 30)``           cone half-angle range (deg)
    ``cone_clearance_deg``  ``3.0``                start and target sensor directions clear
                                                   every cone by at least this (deg)
    ``path_cone_prob``      ``0.5``                probability that a cone after the first lies
                                                   across the short start→target arc (the first
                                                   one always does); others have random axes
    ``path_offset``         ``0.5``                sideways offset of a path cone's axis from the
                                                   arc, as a fraction of its half-angle (< 1, so
                                                   the arc goes through the cone)
    ``max_cone_tries``      ``20``                 rejections of one cone before the whole task
                                                   is redrawn
    ``name``                ``"custom"``           label; the families set their own name
    ======================  =====================  ==============================================

    Start attitudes are uniform on SO(3); start and target rates are zero. The
    start attitude, the slew axis, the pointing direction and cone axes are
    uniform random, so the distribution is rotation invariant.

    Families (``TaskDistribution.family(name, **overrides)``):

    - ``"full-attitude"``: full attitude targets, θ in [10°, 180°], no cones,
      half symmetric bodies (1, 1, 1), half asymmetric with ``J_i`` in [0.4, 1],
      unit per-axis torque.
    - ``"pointing-cones"``: pointing-only targets, θ in [40°, 180°], 1 to 3 cones
      with half-angles in [10°, 30°] (the first across the short path), the same
      bodies and torque bound.

    Only start and target are guaranteed clear of the cones; cones may overlap,
    and no check is made that some path between them stays clear.

    Every field is checked by name on construction (numbers written as text,
    booleans, ``None``, NaN and inf are refused), and so is a distribution that
    could draw a body ``SlewProblem`` refuses: acceleration bounds
    ``u_max,i / J_i`` that can differ by more than ``slew_env.problem.MAX_AXIS_SPREAD``
    over the inertias the mode can draw.
    """

    angle_deg: tuple = (10.0, 180.0)
    pointing_prob: float = 0.0
    inertia_mode: str = "asymmetric"
    inertia: tuple = (1.0, 1.0, 1.0)
    inertia_ratio: tuple = (0.4, 1.0)
    symmetric_prob: float = 0.0
    torque_max: Union[float, tuple] = (1.0, 1.0, 1.0)
    torque_norm: Union[str, float] = "inf"
    sensor_axis: tuple = (1.0, 0.0, 0.0)
    n_cones: tuple = (0, 0)
    cone_half_angle_deg: tuple = (10.0, 30.0)
    cone_clearance_deg: float = 3.0
    path_cone_prob: float = 0.5
    path_offset: float = 0.5
    max_cone_tries: int = 20
    name: str = "custom"

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("angle_deg", _pair("angle_deg", self.angle_deg, 0.0, 180.0))
        set_("pointing_prob", _probability("pointing_prob", self.pointing_prob))
        if not isinstance(self.inertia_mode, str) or self.inertia_mode not in _INERTIA_MODES:
            raise ValueError(f"inertia_mode: expected one of {list(_INERTIA_MODES)}, "
                             f"got {self.inertia_mode!r}")
        set_("inertia", _positive3("inertia", self.inertia))
        ratio = _pair("inertia_ratio", self.inertia_ratio)
        if ratio[0] <= 0.0:
            raise ValueError(f"inertia_ratio: must be positive, got {ratio}")
        set_("inertia_ratio", ratio)
        p_sym = _probability("symmetric_prob", self.symmetric_prob)
        if p_sym >= 1.0:
            raise ValueError("symmetric_prob: must be < 1 (use inertia_mode='symmetric' for symmetric bodies only)")
        set_("symmetric_prob", p_sym)
        set_("torque_max", _positive3("torque_max", self.torque_max))
        set_("torque_norm", self._check_norm(self.torque_norm))
        set_("sensor_axis", tuple(_vector("sensor_axis", self.sensor_axis, 3, unit=True).tolist()))
        set_("n_cones", _pair("n_cones", self.n_cones, 0, None, integer=True))
        set_("cone_half_angle_deg", _pair("cone_half_angle_deg", self.cone_half_angle_deg, 0.0, 180.0))
        if self.cone_half_angle_deg[0] <= 0.0:
            raise ValueError(f"cone_half_angle_deg: must be positive, got {self.cone_half_angle_deg}")
        clear = _number_in("cone_clearance_deg", self.cone_clearance_deg, 0.0, 90.0, hi_open=True)
        set_("cone_clearance_deg", clear)
        set_("path_cone_prob", _probability("path_cone_prob", self.path_cone_prob))
        set_("path_offset", _number_in("path_offset", self.path_offset, 0.0, 1.0, hi_open=True,
                                       what=" so the arc crosses the cone"))
        set_("max_cone_tries", whole("max_cone_tries", self.max_cone_tries, 1))
        if not isinstance(self.name, str):
            raise ValueError(f"name: expected a string, got {self.name!r:.80}")
        self._check_axis_spread()
        if self.n_cones[1] > 0:
            # The first cone sits on the start→target arc with both ends clear.
            need = 2.0 * (self.cone_half_angle_deg[0] + clear)
            if self.angle_deg[1] <= need:
                raise ValueError(
                    f"cone_half_angle_deg: a cone of {self.cone_half_angle_deg[0]:g}° with "
                    f"{clear:g}° clearance needs slews above {need:g}°, but angle_deg allows at most "
                    f"{self.angle_deg[1]:g}°")

    def _check_axis_spread(self):
        """Refuse a distribution that can draw a body ``SlewProblem`` refuses: per-axis
        acceleration bounds ``u_max,i / J_i`` differing by more than ``MAX_AXIS_SPREAD``."""
        u = np.asarray(self.torque_max)
        u_spread = float(u.max() / u.min())
        if self.inertia_mode == "fixed":
            check_time_unit(np.asarray(self.inertia), u, "inertia, torque_max")
            accel = u / np.asarray(self.inertia)
            worst, fields = float(accel.max() / accel.min()), "inertia, torque_max"
            how = f"inertia {list(self.inertia)}"
        elif self.inertia_mode == "symmetric":
            worst, fields, how = u_spread, "torque_max", "inertia (1, 1, 1)"
        else:
            # each J_i is drawn independently in [lo, hi]: the largest bound over the smallest is
            # at worst u_max/u_min with the strong axis at J = lo and the weak one at J = hi (the
            # symmetric bodies drawn with symmetric_prob spread by u_max/u_min only)
            lo, hi = self.inertia_ratio
            worst = u_spread * hi / lo
            fields, how = "inertia_ratio, torque_max", f"J_i drawn in [{lo:g}, {hi:g}]"
        if not worst <= MAX_AXIS_SPREAD:      # (NaN too: inf / inf)
            raise ValueError(
                f"{fields}: the axes' acceleration bounds u_max,i / J_i can differ by a factor {worst:.3g} "
                f"(torque_max {list(self.torque_max)}, {how}), beyond the {MAX_AXIS_SPREAD:g} that "
                "SlewProblem accepts")

    @staticmethod
    def _check_norm(value):
        # the problem's own check (the same accepted values and messages, its supported range)
        from .problem import _torque_norm
        p = _torque_norm(value)
        return "inf" if math.isinf(p) else p

    # ------------------------------------------------------------------ families
    @classmethod
    def family(cls, name: str, **overrides) -> "TaskDistribution":
        """A named family, optionally with some fields changed."""
        if not isinstance(name, str) or name not in FAMILIES:
            raise ValueError(f"task_distribution: unknown family {name!r:.80}; known: {sorted(FAMILIES)}")
        _check_fields(overrides)
        return dataclasses.replace(FAMILIES[name], **overrides)

    @classmethod
    def resolve(cls, spec) -> "TaskDistribution":
        """A family name, a ``TaskDistribution`` or a dict of fields (optionally with ``family``)."""
        if isinstance(spec, TaskDistribution):
            return spec
        if isinstance(spec, str):
            return cls.family(spec)
        if isinstance(spec, dict):
            d = dict(spec)
            base = d.pop("family", None)
            _check_fields(d)
            return cls.family(base, **d) if base is not None else cls(**d)
        raise ValueError(f"task_distribution: expected a family name, a TaskDistribution or a dict, "
                         f"got {type(spec).__name__}")

    # ------------------------------------------------------------------ sampling
    @property
    def max_cones(self) -> int:
        return self.n_cones[1]

    def to_array(self) -> np.ndarray:
        """The parameter array read by ``slew_env.core.sampling.sample_task``."""
        d = np.zeros(_s.DIST_LENGTH)
        d[_s.D_ANGLE_MIN] = math.radians(self.angle_deg[0])
        d[_s.D_ANGLE_MAX] = math.radians(self.angle_deg[1])
        d[_s.D_POINTING_PROB] = self.pointing_prob
        d[_s.D_INERTIA_MODE] = _INERTIA_MODES[self.inertia_mode]
        d[_s.D_INERTIA:_s.D_INERTIA + 3] = self.inertia
        d[_s.D_RATIO_MIN], d[_s.D_RATIO_MAX] = self.inertia_ratio
        d[_s.D_UMAX:_s.D_UMAX + 3] = self.torque_max
        d[_s.D_PNORM] = 0.0 if self.torque_norm == "inf" else self.torque_norm
        d[_s.D_SENSOR:_s.D_SENSOR + 3] = self.sensor_axis
        d[_s.D_NCONES_MIN], d[_s.D_NCONES_MAX] = self.n_cones
        d[_s.D_HALF_MIN] = math.radians(self.cone_half_angle_deg[0])
        d[_s.D_HALF_MAX] = math.radians(self.cone_half_angle_deg[1])
        d[_s.D_CLEARANCE] = math.radians(self.cone_clearance_deg)
        d[_s.D_PATH_PROB] = self.path_cone_prob
        d[_s.D_PATH_OFFSET] = self.path_offset
        d[_s.D_MAX_TRIES] = self.max_cone_tries
        d[_s.D_SYMMETRIC_PROB] = self.symmetric_prob
        return d

    def sample_task_array(self, rng, max_cones: Optional[int] = None, out=None) -> np.ndarray:
        """One random task in the flat layout of ``slew_env.core.task`` (``max_cones`` slots)."""
        if max_cones is None:
            max_cones = self.max_cones
        if out is None:
            out = np.zeros(_t.task_length(max_cones))
        draw_task(_rng(rng), self.to_array(), out)
        return out

    def sample(self, rng=None) -> SlewProblem:
        """One random problem, validated as a ``SlewProblem``."""
        return SlewProblem.from_task_array(self.sample_task_array(rng))


def _check_fields(d):
    """Unknown or non-string keys: a ``ValueError``, not the dataclass's ``TypeError``."""
    known = [f.name for f in dataclasses.fields(TaskDistribution)]
    unknown = [k for k in d if k not in known]
    if unknown:
        raise ValueError(f"task_distribution: unknown field(s) {unknown!r:.120}; known fields are {known}")


def _rng(rng):
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def draw_task(rng: np.random.Generator, dist: np.ndarray, task: np.ndarray,
              block: int = BLOCK, max_blocks: int = MAX_BLOCKS) -> None:
    """Fill ``task`` from ``dist``, drawing blocks of ``block`` uniforms from ``rng``.

    Each attempt takes a fresh block; the vector environment consumes the same
    blocks in the same order, so both draw identical tasks from equal generators.
    """
    for _ in range(max_blocks):
        used = _s.sample_task(dist, rng.random(block), task)
        if used >= 0:
            return
        if used == _s.TOO_MANY_CONES:
            raise ValueError(f"max_cones: the distribution allows {int(dist[_s.D_NCONES_MAX])} cones "
                             f"but the task has {_t.max_cones_of(task.shape[0])} slots")
    raise RuntimeError(unplaceable_message(max_blocks, block))


def unplaceable_message(max_blocks, block):
    return (f"task distribution: no valid task in {max_blocks} blocks of {block} uniforms; the cones "
            "cannot be placed clear of start and target (reduce cone_half_angle_deg or "
            "cone_clearance_deg, or raise angle_deg)")


FAMILIES = {
    "full-attitude": TaskDistribution(name="full-attitude", symmetric_prob=0.5),
    "pointing-cones": TaskDistribution(
        name="pointing-cones", angle_deg=(40.0, 180.0), pointing_prob=1.0, n_cones=(1, 3),
        cone_half_angle_deg=(10.0, 30.0)),
}
