"""Learned warm start for pointing-only slews with keep-out cones (numpy inference).

The network maps the canonical features of ``cone_features`` to

* the nondimensional costates ``z'`` (canonical axes, unit norm, the gauge of
  ``solvers.attitude_bvp``) at t = 0;
* the final time, as ``log(T / T_ref)`` (``T_ref``: the eigenaxis pointing slew, cones
  ignored);
* for each cone slot: whether the optimal path touches that cone (a logit), when (a logit of
  the fraction of ``T``) and with which multiplier (``log ν``, ``ν`` in the normalisation of
  ``z'``; ``solvers.cone_touch``);
* the switching structure, as in ``model.WarmStartModel``: first-arc signs, switches per
  canonical axis (0 … ``max_switches``) and their instants as fractions of ``T``.

**Several heads.** The map from a problem to its optimal slew has branches (touch a cone or
not, pass it on one side or the other, another switching structure), and a single regression
blurs them: a network trained so predicts costates 18° off in the median and the whole
structure right on 30 % of held-out solutions. A model with ``heads`` K > 1 (card ``heads``)
predicts K solutions and a selector logit for each: trained winner-takes-all (each solution
teaches the head that predicts it best, ``training.warmstart.cone_data.losses``), each head
specialises in a branch, and the selector learns which head wins. Its outputs are K blocks of
``cone_output_layout(max_switches)``, then the K selector logits.

``guess(problem)`` returns a ``solvers.Guess`` for the head the selector ranks first, whose
``touches`` are the predicted contacts (probability above one half), followed by the other
reading as a candidate: no touch if touches were predicted, else the most likely touch; then
the same two for each further head, in the selector's order. Every guess carries the predicted
switching structure, so the solver goes straight to the switch-time Newton (with the touch
junctions, ``cone_touch.structured_newton``; without touches, the extremal of the problem
without cones, whose path clearance is then certified).

File format: that of ``model.WarmStartModel`` with ``kind: "pointing-cones"`` in the card,
``heads`` (1 if absent) and the output layout of one head, ``cone_output_layout(max_switches)``.
"""
from __future__ import annotations

import math
import time

import numpy as np

from slew_env import SlewProblem
from ..core import warmstart_kernels as _k
from ..guesses import Guess
from .cone_features import (MAX_CONES, N_CONE_FEATURES, cone_unsupported_reason, form_of_supported,
                            solution_from_canonical)
from .model import (MAX_HEADS, MAX_SWITCHES, ModelFileError, WarmStartModel, card_whole,
                    check_output_layout)



def cone_output_layout(max_switches: int) -> dict:
    """Slices of the output vector (also written in the card)."""
    K, C = int(max_switches), MAX_CONES
    o = {"z": (0, 6), "log_T_ratio": (6, 7), "touch_logit": (7, 7 + C), "touch_time_logit": (7 + C, 7 + 2 * C),
         "log_nu": (7 + 2 * C, 7 + 3 * C)}
    b = 7 + 3 * C
    o.update(u_first_logit=(b, b + 3), count_logits=(b + 3, b + 3 + 3 * (K + 1)),
             times_logit=(b + 3 + 3 * (K + 1), b + 3 + 3 * (K + 1) + 3 * K))
    return o


def cone_output_size(max_switches: int, heads: int = 1) -> int:
    """Outputs of a network with ``heads`` heads: one head's block each, then (several heads)
    one selector logit a head."""
    per = cone_output_layout(max_switches)["times_logit"][1]
    heads = int(heads)
    return per if heads == 1 else heads * (per + 1)

SECOND_TOUCH_PROB = 0.1   # a touch this likely is tried as a candidate when none is predicted


class ConeWarmStartModel(WarmStartModel):
    """A numpy MLP warm-start model for the pointing-cones family (module docstring)."""

    KIND = "pointing-cones"

    def _check_layout(self, card):
        """The card's structure fields against the weights: ``max_switches``, ``heads``, the
        output size, the ``output_layout`` of one head that the compiled decoder reads at each
        head's offset (``warmstart_kernels.decode_cone``: as many touch slots as ``MAX_CONES``)."""
        self.K = card_whole(card, "max_switches", 0, MAX_SWITCHES)
        heads = card_whole(card, "heads", 1, MAX_HEADS, default=1,
                           why=" (each head adds two candidates to a guess)")
        self.heads = heads
        self.head_size = cone_output_layout(self.K)["times_logit"][1]
        n_in, n_out = self.weights[0][0].shape[0], self.weights[-1][0].shape[1]
        if n_out != cone_output_size(self.K, heads) or n_in != N_CONE_FEATURES:
            raise ModelFileError(f"weights: shapes {n_in} → {n_out} do not match {N_CONE_FEATURES} features → "
                                 f"{cone_output_size(self.K, heads)} outputs of a pointing-cones model "
                                 f"(max_switches {self.K}, {heads} head{'s' if heads > 1 else ''})")
        self.layout = check_output_layout(card.get("output_layout"), cone_output_layout(self.K), self.head_size,
                                          self.K)

    def _coverage(self, problem, supported=False):
        """``(reason or None, canonical form or None)``; ``supported``: the caller has just found
        ``cone_unsupported_reason(problem)`` to be ``None`` (not asked again)."""
        why = None if supported else cone_unsupported_reason(problem)
        if why:
            return why, None
        d = self.domain
        if problem.rate_max is not None and not d.get("rate_max", False):
            return "rate_max: the model was trained without rate limits", None
        if problem.rate_norm_max is not None and not d.get("rate_norm_max", False):
            return "rate_norm_max: the model was trained without a limit on the rate's norm", None
        if not math.isinf(problem.torque_norm):
            return f"torque_norm: the model covers the per-axis bound ('inf'), got {problem.torque_norm}", None
        lo_n, hi_n = d.get("n_cones", (1, MAX_CONES))
        if not lo_n <= len(problem.cones) <= hi_n:
            return f"cones: the model covers {lo_n}–{hi_n} cones, got {len(problem.cones)}", None
        cf = form_of_supported(problem)
        th_deg = math.degrees(math.acos(min(1.0, max(-1.0, float(cf.x[0])))))
        lo, hi = d.get("angle_deg", (0.0, 180.0))
        if not (lo - 1e-9 <= th_deg <= hi + 1e-9):
            return f"slew angle {th_deg:.3g}° outside the model's range [{lo:g}°, {hi:g}°]", cf
        rlo = d.get("inertia_ratio", (0.0, 1.0))[0]
        if float(cf.x[3:6].min()) < rlo - 1e-9:
            return f"inertia: J_min/J_max = {cf.x[3:6].min():.3g} below the model's range ({rlo:g})", cf
        if float(cf.x[6:9].min()) < d.get("torque_ratio_min", 1.0) - 1e-9:
            return f"torque_max: u_min/u_max = {cf.x[6:9].min():.3g} below the model's range", cf
        ha = [c.half_angle for c in problem.cones]
        alo, ahi = d.get("cone_half_angle_deg", (0.0, 90.0))
        if min(ha) < math.radians(alo) - 1e-9 or max(ha) > math.radians(ahi) + 1e-9:
            return f"cones: half angles outside the model's range [{alo:g}°, {ahi:g}°]", cf
        return None, cf

    def head_order(self, out) -> np.ndarray:
        """The heads in the selector's order (most likely first) for the raw outputs ``out``
        of one problem; ``[0]`` for a single head."""
        if self.heads == 1:
            return np.zeros(1, np.int64)
        sel = np.asarray(out[self.heads * self.head_size:], np.float64)
        return np.argsort(-sel, kind="stable")

    def predict_canonical(self, x, T_ref, head=None):
        """``(z', T, touch probabilities, touch instants, multipliers, first-arc signs, switch
        instants per axis)``, canonical and nondimensional (cone quantities per slot), of
        ``head`` (default: the one the selector ranks first)."""
        out = self.forward(np.asarray(x, np.float64).reshape(-1))[0]
        return self._decode(out, int(self.head_order(out)[0]) if head is None else int(head), T_ref)

    def predict_heads(self, x, T_ref) -> list:
        """``predict_canonical`` of every head, in the selector's order (one network pass)."""
        out = self.forward(np.asarray(x, np.float64).reshape(-1))[0]
        return [self._decode(out, int(h), T_ref) for h in self.head_order(out)]

    def _decode(self, out, head, T_ref):
        if not 0 <= head < self.heads:
            raise ValueError(f"head: the model has {self.heads} head(s), got {head}")
        L = self.layout
        o = head * self.head_size
        n_slots = L["touch_logit"][1] - L["touch_logit"][0]
        z, T, p, tc, nu, uf, counts, tt = _k.decode_cone(
            out, self.K, n_slots, o + L["z"][0], o + L["log_T_ratio"][0], o + L["touch_logit"][0],
            o + L["touch_time_logit"][0], o + L["log_nu"][0], o + L["u_first_logit"][0], o + L["count_logits"][0],
            o + L["times_logit"][0], float(T_ref))
        if not (math.isfinite(T) and T > 0.0):
            raise ValueError(f"x: the network's final time is {T!r} (features outside the model's range?)")
        return z, T, p, tc, nu, uf, [tt[i, :counts[i]] for i in range(3)]

    def predicted_tf(self, problem):
        """The final time the selector's first head predicts for ``problem`` (problem units),
        ``None`` where the model does not cover it; no guess is made."""
        why, cf = self._coverage(SlewProblem.from_dict(problem))
        return None if why else float(self.predict_canonical(cf.x, cf.T_ref)[1]) * cf.tau

    def guess_or_reason(self, problem, propagate=True):
        problem = SlewProblem.from_dict(problem)
        t0 = time.perf_counter()
        why, cf = self._coverage(problem)
        if why:
            return None, why
        return self.guess_from_form(problem, cf, t0), None

    def guess_from_form(self, problem, cf, t0=None):
        """The guess for a covered ``problem`` whose canonical form ``cf`` is known: the
        selector's first head's guess, then as candidates its variant and the other heads'
        guesses and variants in the selector's order (module docstring). One network pass; the
        later heads are decoded and their guesses made only when a solver reaches them
        (deferred candidates, ``Guess.iter_all``). A head whose outputs decode to no usable guess
        (a final time that is not finite) is passed over: the first head that gives one leads,
        a later one fails as its candidate; if none gives one, the first head's error is raised."""
        t0 = time.perf_counter() if t0 is None else t0
        out = self.forward(np.asarray(cf.x, np.float64).reshape(-1))[0]
        order = [int(h) for h in self.head_order(out)]
        first, error = None, None
        while order and first is None:
            h = order.pop(0)
            try:
                first = self._head_guesses(problem, cf, *self._decode(out, h, cf.T_ref))
            except ValueError as e:
                error = error or e
        if first is None:
            raise error
        g = first[0]
        g.candidates = first[1:]
        for h in order:
            pair = _DeferredPair(self, problem, cf, out, h)
            g.candidates += [pair.part(0), pair.part(1)]
        self.last_inference_s = time.perf_counter() - t0
        return g

    @staticmethod
    def _head_guesses(problem, cf, z, T, p, tc, nu, uf_c, sw_c):
        """One head's guess and its variant (with or without the touches)."""
        used = range(len(problem.cones))
        c0, tf, sw, uf, touches = solution_from_canonical(problem, cf, z, T, sw_c, uf_c,
                                                          [(k, tc[k], nu[k]) for k in used])
        rows = dict(zip(used, touches))      # per slot: (problem cone, time, multiplier)
        touched = [k for k in used if p[k] >= 0.5]
        no_touch = Guess(c0, tf, sw, uf, source="learned")
        out = []
        if touched:
            out = [Guess(c0, tf, sw, uf, source="learned", touches=[rows[k] for k in touched]), no_touch]
        else:
            out = [no_touch]
            best = max(used, key=lambda k: p[k])
            if p[best] >= SECOND_TOUCH_PROB:
                out.append(Guess(c0, tf, sw, uf, source="learned-touch", touches=[rows[best]]))
        out[0].touch_probabilities = {int(cf.slots[k]): float(p[k]) for k in used}
        return out


class _DeferredPair:
    """One head's guess and variant (``head`` of the network's outputs ``out``), decoded and made
    once when a deferred candidate first asks for them. A head that cannot be decoded raises its
    error once, from its first part; its second part is then skipped (``None``)."""

    def __init__(self, model, problem, cf, out, head):
        self.model, self.problem, self.cf, self.out, self.head = model, problem, cf, out, head
        self._pair = None
        self._failed = False

    def part(self, k):
        def make():
            if self._failed:
                return None
            if self._pair is None:
                m = self.model
                try:
                    self._pair = m._head_guesses(self.problem, self.cf,
                                                 *m._decode(self.out, self.head, self.cf.T_ref))
                except Exception:    # noqa: BLE001 - recorded once by the caller (iter_all's errors)
                    self._failed = True
                    raise
            return self._pair[k] if k < len(self._pair) else None
        return make
