"""Pointing-cones dataset records → canonical training arrays, and the network's losses.

Only *exact* successes are used: extremals that clear the cones without touching them, and
touch-point extremals (``solvers.cone_touch``, whose ``verification["touch_multipliers"]``
gives the instants, cones and multipliers). Collocation answers (boundary arcs, singular
problems) have costates known only approximately and are left out, as are the rare answers
touching one cone twice (one slot holds one touch), counted in ``n_double``.

Arrays (``N`` problems, ``C = MAX_CONES`` slots): ``X`` (N, 24) features; ``Z`` (N, 6)
canonical costates; ``T``, ``T_ref``, ``log_T_ratio`` (N,); ``touch`` (N, C) 0/1; ``frac``
(N, C) touch instant / T (NaN where no touch); ``log_nu`` (N, C) (NaN where no touch);
``present`` (N, C) cone in the slot; ``key`` (N,).
"""
from __future__ import annotations

import math

import numpy as np

from slew_env import SlewProblem
from solvers.warmstart.cone_features import (MAX_CONES, N_CONE_FEATURES, cone_canonical_form,
                                             solution_to_canonical)
from solvers.warmstart.cone_model import cone_output_layout
from .data import exact_records

N_IN = N_CONE_FEATURES


def training_arrays(paths, family="pointing-cones", max_switches=5) -> dict:
    from .table_data import check_not_in_table, cone_table_arrays, is_table, joined
    paths = [paths] if isinstance(paths, (str, bytes)) or hasattr(paths, "__fspath__") else list(paths)
    tables = [p for p in paths if is_table(p)]
    if tables:      # a solution table, and any dataset files beside it (none holding its solutions)
        files = [p for p in paths if not is_table(p)]
        parts = [cone_table_arrays(p, max_switches) for p in tables]
        if files:
            more = training_arrays(files, family, max_switches)
            for t, path in zip(parts, tables):
                check_not_in_table(more, t, path)
            parts.append(more)
        return joined(parts)
    rows = []
    n_double = n_overflow = 0
    counts = {}
    for path, r in exact_records(paths, family, counts):
        if r.get("switch_times") is None or r.get("u_first") is None:
            continue
        tm = (r.get("verification") or {}).get("touch_multipliers") or {"cones": [], "times": [], "multipliers": []}
        if len(set(tm["cones"])) < len(tm["cones"]):
            n_double += 1
            continue
        p = SlewProblem.from_dict(r["problem"])
        cf = cone_canonical_form(p)
        z, _, T, sw, U, tc = solution_to_canonical(p, cf, r["costate0"], r["tf"], r["switch_times"], r["u_first"],
                                                   zip(tm["cones"], tm["times"], tm["multipliers"]))
        touch = np.zeros(MAX_CONES)
        frac = np.full(MAX_CONES, np.nan)
        lnu = np.full(MAX_CONES, np.nan)
        for k, (t, nu) in tc.items():
            touch[k] = 1.0
            frac[k] = t / T
            lnu[k] = math.log(max(nu, 1e-12))
        present = cf.x[9 + 4::5][:MAX_CONES].copy()
        if max(len(a) for a in sw) > max_switches:
            n_overflow += 1
            continue
        S = np.full((3, max_switches), np.nan)
        for i in range(3):
            S[i, :len(sw[i])] = sw[i] / T
        n_sw = np.array([len(a) for a in sw])
        rows.append((cf.x, z, T, cf.T_ref, touch, frac, lnu, present, f"{path}:{r['index']}", U, n_sw, S))
    N = len(rows)
    out = {"X": np.array([r[0] for r in rows]).reshape(N, N_IN), "Z": np.array([r[1] for r in rows]).reshape(N, 6),
           "T": np.array([r[2] for r in rows]), "T_ref": np.array([r[3] for r in rows]),
           "touch": np.array([r[4] for r in rows]).reshape(N, MAX_CONES),
           "frac": np.array([r[5] for r in rows]).reshape(N, MAX_CONES),
           "log_nu": np.array([r[6] for r in rows]).reshape(N, MAX_CONES),
           "present": np.array([r[7] for r in rows]).reshape(N, MAX_CONES), "key": np.array([r[8] for r in rows]),
           "U": np.array([r[9] for r in rows]).reshape(N, 3),
           "counts": np.array([r[10] for r in rows], dtype=np.int64).reshape(N, 3),
           "F": np.array([r[11] for r in rows]).reshape(N, 3, max_switches)}
    out["log_T_ratio"] = np.log(out["T"] / np.maximum(out["T_ref"], 1e-300))
    out.update(n_records=counts["seen"], n_exact=counts["exact"], n_double=n_double, n_overflow=n_overflow)
    return out


TENSOR_KEYS = {"X": "float", "Z": "float", "log_T_ratio": "float", "touch": "float", "frac": "float",
               "log_nu": "float", "present": "float", "U": "float", "counts": "long", "F": "float"}


def nearest_table(paths, max_switches=5, k=3):
    """The exact solutions of ``paths`` as a ``ConeNearestNeighbourModel`` (the
    nearest-neighbour baseline of ``slew evaluate``, and the table shipped with the model)."""
    from solvers.warmstart.cone_nearest import ConeNearestNeighbourModel
    a = training_arrays(paths, max_switches=max_switches)
    return ConeNearestNeighbourModel(a, k=k, name=f"nearest-neighbour (k={k}, {a['X'].shape[0]} solutions)")


def losses(out, batch, cfg, torch):
    """Total loss, its parts and validation metrics (see ``training.warmstart.train``).

    A network with ``cfg["heads"]`` K > 1 outputs K solution blocks and K selector logits
    (``solvers.warmstart.cone_model``). Each problem's loss is ``1 - wta_eps`` times that of the
    head that predicts its solution best (winner takes all) plus ``wta_eps`` (default 0.05) times
    the others' mean, so that no head is left untrained, plus ``loss_weights.select`` (default
    0.2) times the selector's cross-entropy against the winning head. The metrics are those of the head the selector
    ranks first, with ``structure_acc_any_head`` (some head has the whole structure right) and
    ``selector_acc`` (the selector picks the winner)."""
    heads = int(cfg.get("heads", 1))
    if heads == 1:
        return _one_head(out, batch, cfg, torch)
    F = torch.nn.functional
    per = cone_output_layout(int(cfg["max_switches"]))["times_logit"][1]
    outs = out[:, :heads * per].reshape(-1, heads, per)
    sel = out[:, heads * per:]
    # per problem and head: the total of _per_problem (each part divided by its batch-wide
    # normaliser: the batch mean is one head's loss, _one_head's)
    norms = _normalisers(batch, torch)
    L = torch.stack([_per_problem(outs[:, h], batch, cfg, torch, norms)[0] for h in range(heads)], dim=1)
    win = L.detach().argmin(dim=1)
    eps = float(cfg.get("wta_eps", 0.05))
    wt = torch.full_like(L, eps / (heads - 1))
    wt.scatter_(1, win[:, None], 1.0 - eps)
    l_sel = F.cross_entropy(sel, win)
    total = (L * wt).sum(dim=1).mean() + float(cfg.get("loss_weights", {}).get("select", 0.2)) * l_sel
    top = sel.detach().argmax(dim=1)
    rows = torch.arange(out.shape[0])
    _, parts, metrics = _one_head(outs[rows, top], batch, cfg, torch)
    with torch.no_grad():
        right = torch.stack([_structure_right(outs[:, h], batch, cfg) for h in range(heads)], dim=1)
        metrics["structure_acc_any_head"] = float(right.any(dim=1).float().mean())
        metrics["selector_acc"] = float((top == win).float().mean())
    parts["select"] = float(l_sel.detach())
    return total, parts, metrics


def _normalisers(batch, torch):
    """The batch-wide counts ``_one_head`` divides its masked sums by."""
    return {"present": batch["present"].sum().clamp_min(1) / batch["present"].shape[0],
            "touch": torch.isfinite(batch["frac"]).sum().clamp_min(1) / batch["frac"].shape[0],
            "switch": torch.isfinite(batch["F"]).sum().clamp_min(1) / batch["F"].shape[0]}


def _per_problem(out, batch, cfg, torch, norms):
    """``(total, parts)``, each a vector over the batch's problems, for one head's block ``out``."""
    F = torch.nn.functional
    K = int(cfg["max_switches"])
    L = cone_output_layout(K)
    z = out[:, slice(*L["z"])]
    nz = z.norm(dim=1, keepdim=True).clamp_min(1e-8)
    l_z = ((z / nz - batch["Z"]) ** 2).sum(dim=1) + 0.01 * ((nz[:, 0] - 1.0) ** 2)
    l_T = (out[:, L["log_T_ratio"][0]] - batch["log_T_ratio"]) ** 2
    pres = batch["present"]
    logit = out[:, slice(*L["touch_logit"])]
    l_p = (F.binary_cross_entropy_with_logits(logit, batch["touch"], reduction="none") * pres).sum(dim=1) / norms["present"]
    mask = torch.isfinite(batch["frac"])
    tf_ = torch.sigmoid(out[:, slice(*L["touch_time_logit"])])
    l_t = (((tf_ - torch.where(mask, batch["frac"], torch.zeros_like(tf_))) ** 2) * mask).sum(dim=1) / norms["touch"]
    lnu = out[:, slice(*L["log_nu"])]
    l_nu = (((lnu - torch.where(mask, batch["log_nu"], torch.zeros_like(lnu))) ** 2) * mask).sum(dim=1) / norms["touch"]
    l_u = F.binary_cross_entropy_with_logits(out[:, slice(*L["u_first_logit"])], (batch["U"] > 0).float(),
                                             reduction="none").mean(dim=1)
    cl = out[:, slice(*L["count_logits"])].reshape(-1, 3, K + 1)
    l_c = F.cross_entropy(cl.reshape(-1, K + 1), batch["counts"].reshape(-1), reduction="none").reshape(-1, 3).mean(dim=1)
    sl = torch.sigmoid(out[:, slice(*L["times_logit"])].reshape(-1, 3, K))
    smask = torch.isfinite(batch["F"])
    l_s = (((sl - torch.where(smask, batch["F"], torch.zeros_like(sl))) ** 2) * smask).sum(dim=(1, 2)) / norms["switch"]
    w = cfg.get("loss_weights", {})
    total = (w.get("z", 1.0) * l_z + w.get("log_T", 4.0) * l_T + w.get("touch", 0.2) * l_p
             + w.get("touch_times", 2.0) * l_t + w.get("log_nu", 0.1) * l_nu + w.get("u_first", 0.2) * l_u
             + w.get("counts", 0.2) * l_c + w.get("times", 2.0) * l_s)
    return total, {"z": l_z, "log_T": l_T, "touch": l_p, "touch_times": l_t, "log_nu": l_nu, "u_first": l_u,
                   "counts": l_c, "times": l_s}


def _structure_right(out, batch, cfg):
    """Per problem: the head ``out`` has the touch set, the first-arc signs and the switch
    counts all right (the structure the switch-time Newton needs)."""
    K = int(cfg["max_switches"])
    L = cone_output_layout(K)
    pres = batch["present"]
    touch = (((out[:, slice(*L["touch_logit"])] >= 0).float() == batch["touch"]) | (pres == 0)).all(dim=1)
    signs = ((out[:, slice(*L["u_first_logit"])] >= 0) == (batch["U"] > 0)).all(dim=1)
    counts = (out[:, slice(*L["count_logits"])].reshape(-1, 3, K + 1).argmax(dim=2) == batch["counts"]).all(dim=1)
    return touch & signs & counts


def _one_head(out, batch, cfg, torch):
    """Total loss, its parts (the batch means of ``_per_problem``'s) and validation metrics of one
    head's block ``out`` (see ``training.warmstart.train``)."""
    per, per_parts = _per_problem(out, batch, cfg, torch, _normalisers(batch, torch))
    total = per.mean()
    parts = {k: float(v.detach().mean()) for k, v in per_parts.items()}
    K = int(cfg["max_switches"])
    L = cone_output_layout(K)
    with torch.no_grad():
        z = out[:, slice(*L["z"])]
        cos = ((z / z.norm(dim=1, keepdim=True).clamp_min(1e-8)) * batch["Z"]).sum(dim=1)
        pres = batch["present"]
        same = (((out[:, slice(*L["touch_logit"])] >= 0).float() == batch["touch"]) | (pres == 0)).all(dim=1)
        mask = torch.isfinite(batch["frac"])
        tf_ = torch.sigmoid(out[:, slice(*L["touch_time_logit"])])
        cl = out[:, slice(*L["count_logits"])].reshape(-1, 3, K + 1)
        sl = torch.sigmoid(out[:, slice(*L["times_logit"])].reshape(-1, 3, K))
        smask = torch.isfinite(batch["F"])
        metrics = {
            "z_angle_deg_median": float(torch.rad2deg(torch.arccos(cos.clamp(-1, 1))).median()),
            "T_rel_err_median": float((out[:, L["log_T_ratio"][0]] - batch["log_T_ratio"]).abs().median()),
            "touch_set_acc": float(same.float().mean()),
            "touch_time_err_median": float((tf_ - batch["frac"])[mask].abs().median()) if bool(mask.any()) else math.nan,
            "u_first_acc": float(((out[:, slice(*L["u_first_logit"])] >= 0) == (batch["U"] > 0)).all(dim=1).float().mean()),
            "structure_acc": float((cl.argmax(dim=2) == batch["counts"]).all(dim=1).float().mean()),
            "switch_time_err_median": float((sl - batch["F"])[smask].abs().median()) if bool(smask.any()) else math.nan,
            "whole_structure_acc": float(_structure_right(out, batch, cfg).float().mean()),
        }
    return total, parts, metrics
