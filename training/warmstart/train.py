"""``slew train``: the warm-start network (torch), trained on canonical solutions, exported
to the numpy format of ``solvers.warmstart``.

The network is an MLP on the 11 canonical features with one output vector (layout in
``solvers.warmstart.model.output_layout``): ``z'`` (6; loss ``|z/|z| - z*|²`` plus a small
pull of ``|z|`` to 1), ``log(T/T_eig)`` (MSE), first-arc signs (3 logits, BCE), switch
counts per axis (3 × (K+1) logits, cross-entropy) and switch instants as fractions of
``T`` (3 × K sigmoids, MSE on the slots a problem uses). Loss weights, sizes and the
schedule come from a YAML config (``configs/full-attitude.yaml``).

Run directory: ``config.yaml`` (the resolved config, with the seed and the data files),
``log.csv`` (per epoch: losses and validation metrics), ``loss.png``,
``checkpoints/epoch_NNNN.pt`` (each with its run's identity: ``--resume`` continues only
the same run), ``model.npz`` (the export), ``model.md`` (its card, readable),
``model.nn.npz`` (the neighbour table of the same exact solutions) and ``summary.json``
(the card's training part, the paths written). Reproducible from the seed: one torch
thread, seeded split, shuffles and initialisation.
"""
from __future__ import annotations

import copy
import csv
import glob
import hashlib
import json
import math
import os
import platform
import time

import numpy as np
import yaml

from .data import check_distinct, check_domain, data_meta, split, training_arrays

DEFAULT_CONFIG = os.path.join(os.path.dirname(__file__), "configs", "full-attitude.yaml")


def load_config(path=None, overrides=None) -> dict:
    with open(path or DEFAULT_CONFIG) as f:
        cfg = yaml.safe_load(f) or {}
    for k, v in (overrides or {}).items():
        cfg[k] = v
    for key in ("max_switches", "hidden", "epochs", "batch_size", "learning_rate"):
        if key not in cfg:
            raise ValueError(f"config: missing key {key!r}")
    if int(cfg["epochs"]) < 1:
        raise ValueError(f"config.epochs: must be ≥ 1, got {cfg['epochs']}")
    heads = cfg.get("heads", 1)
    if isinstance(heads, bool) or not isinstance(heads, int) or heads < 1:
        raise ValueError(f"config.heads: expected a whole number ≥ 1, got {heads!r}")
    if heads > 1 and cfg.get("family") != "pointing-cones":
        raise ValueError(f"config.heads: several heads ({heads}) are built for the pointing-cones family only, "
                         f"got family {cfg.get('family')!r}")
    eps = cfg.get("wta_eps", 0.05)
    if isinstance(eps, bool) or not isinstance(eps, (int, float)) or not 0.0 <= eps < 1.0:
        raise ValueError(f"config.wta_eps: expected a number in [0, 1), got {eps!r}")
    _check_exportable(cfg)
    return cfg


def _check_exportable(cfg) -> None:
    """The network the config describes is one that a model file may hold (``solvers.warmstart.model``'s
    limits on switches, layers, heads and weights), checked before training rather than at its
    export, after every epoch had run (a review: ``hidden: [2048, 2048]``, 4.3 M weights)."""
    from solvers.warmstart.features import N_FEATURES
    from solvers.warmstart.model import MAX_HEADS, MAX_LAYERS, MAX_SWITCHES, MAX_WEIGHTS, output_size
    K = cfg["max_switches"]
    if isinstance(K, bool) or not isinstance(K, int) or not 0 <= K <= MAX_SWITCHES:
        raise ValueError(f"config.max_switches: expected a whole number from 0 to {MAX_SWITCHES}, got {K!r}")
    hidden = cfg["hidden"]
    if (not isinstance(hidden, list) or not 1 <= len(hidden) + 1 <= MAX_LAYERS
            or any(isinstance(h, bool) or not isinstance(h, int) or h < 1 for h in hidden)):
        raise ValueError(f"config.hidden: expected a list of at most {MAX_LAYERS - 1} layer widths (whole numbers "
                         f"≥ 1), got {hidden!r}"[:300])
    heads = int(cfg.get("heads", 1))
    if heads > MAX_HEADS:
        raise ValueError(f"config.heads: at most {MAX_HEADS} heads, got {heads}")
    if _is_cones(cfg):
        from solvers.warmstart.cone_model import cone_output_size
        from .cone_data import N_IN as n_in
        n_out = cone_output_size(K, heads)
    else:
        n_in, n_out = N_FEATURES, output_size(K)
    sizes = [n_in, *hidden, n_out]
    weights = sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:]))
    if weights > MAX_WEIGHTS:
        raise ValueError(f"config.hidden: {weights:,} weights in all, more than the {MAX_WEIGHTS:,} a model file may "
                         f"hold (a guess must stay within milliseconds)")


def _is_cones(cfg):
    return cfg.get("family") == "pointing-cones"


def _net(cfg, torch):
    from solvers.warmstart.features import N_FEATURES
    from solvers.warmstart.model import output_size
    act = {"silu": torch.nn.SiLU, "tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}[cfg.get("activation", "silu")]
    if _is_cones(cfg):
        from solvers.warmstart.cone_model import cone_output_size
        from .cone_data import N_IN as n_in
        n_out = cone_output_size(int(cfg["max_switches"]), int(cfg.get("heads", 1)))
    else:
        n_in, n_out = N_FEATURES, output_size(int(cfg["max_switches"]))
    layers = []
    for h in cfg["hidden"]:
        layers += [torch.nn.Linear(n_in, int(h)), act()]
        n_in = int(h)
    layers.append(torch.nn.Linear(n_in, n_out))
    return torch.nn.Sequential(*layers)


def _arrays(data_paths, cfg):
    if _is_cones(cfg):
        from .cone_data import training_arrays as cone_arrays
        return cone_arrays(data_paths, family="pointing-cones", max_switches=int(cfg["max_switches"]))
    return training_arrays(data_paths, int(cfg["max_switches"]), family=cfg.get("family"))


def _losses(out, batch, cfg, torch):
    if _is_cones(cfg):
        from .cone_data import losses
        return losses(out, batch, cfg, torch)
    from solvers.warmstart.model import output_layout
    K = int(cfg["max_switches"])
    L = output_layout(K)
    F = torch.nn.functional
    z = out[:, slice(*L["z"])]
    nz = z.norm(dim=1, keepdim=True).clamp_min(1e-8)
    l_z = ((z / nz - batch["Z"]) ** 2).sum(dim=1).mean() + 0.01 * ((nz - 1.0) ** 2).mean()
    l_T = ((out[:, slice(*L["log_T_ratio"])][:, 0] - batch["log_T_ratio"]) ** 2).mean()
    l_u = F.binary_cross_entropy_with_logits(out[:, slice(*L["u_first_logit"])], (batch["U"] > 0).float())
    cl = out[:, slice(*L["count_logits"])].reshape(-1, 3, K + 1)
    l_c = F.cross_entropy(cl.reshape(-1, K + 1), batch["counts"].reshape(-1))
    tl = torch.sigmoid(out[:, slice(*L["times_logit"])].reshape(-1, 3, K))
    mask = torch.isfinite(batch["F"])
    tgt = torch.where(mask, batch["F"], torch.zeros_like(batch["F"]))
    l_t = (((tl - tgt) ** 2) * mask).sum() / mask.sum().clamp_min(1)
    w = cfg.get("loss_weights", {})
    total = (w.get("z", 1.0) * l_z + w.get("log_T", 1.0) * l_T + w.get("u_first", 0.2) * l_u
             + w.get("counts", 0.2) * l_c + w.get("times", 1.0) * l_t)
    with torch.no_grad():
        cos = ((z / nz) * batch["Z"]).sum(dim=1)
        metrics = {
            "z_angle_deg_median": float(torch.rad2deg(torch.arccos(cos.clamp(-1, 1))).median()),
            "T_rel_err_median": float((out[:, 6] - batch["log_T_ratio"]).abs().median()),
            "u_first_acc": float(((out[:, slice(*L["u_first_logit"])] >= 0) == (batch["U"] > 0)).all(dim=1).float().mean()),
            "structure_acc": float((cl.argmax(dim=2) == batch["counts"]).all(dim=1).float().mean()),
        }
    parts = {k: float(v.detach()) for k, v in (("z", l_z), ("log_T", l_T), ("u_first", l_u), ("counts", l_c), ("times", l_t))}
    return total, parts, metrics


def _tensors(arrays, idx, torch):
    if "touch" in arrays:
        from .cone_data import TENSOR_KEYS
        return {k: torch.tensor(arrays[k][idx], dtype=torch.int64 if t == "long" else torch.float32)
                for k, t in TENSOR_KEYS.items()}
    return {"X": torch.tensor(arrays["X"][idx], dtype=torch.float32),
            "Z": torch.tensor(arrays["Z"][idx], dtype=torch.float32),
            "log_T_ratio": torch.tensor(arrays["log_T_ratio"][idx], dtype=torch.float32),
            "U": torch.tensor(arrays["U"][idx], dtype=torch.float32),
            "counts": torch.tensor(arrays["counts"][idx], dtype=torch.int64),
            "F": torch.tensor(arrays["F"][idx], dtype=torch.float32)}


def train(data_paths, out, config=None, seed=0, epochs=None, resume=False, progress_bar=True,
          export_path=None, overrides=None) -> dict:
    """Train, write the run directory, export ``model.npz``; returns a summary dict."""
    import torch
    torch.set_num_threads(1)
    torch.manual_seed(seed)
    # epochs as an override, so that load_config's check (≥ 1) applies to it before the data load
    cfg = load_config(config, dict(overrides or {}, **({} if epochs is None else {"epochs": int(epochs)})))
    out = os.fspath(out)
    data_paths = [os.fspath(p) for p in data_paths]
    check_distinct(data_paths)
    from .table_data import is_table
    if not _is_cones(cfg) and any(is_table(p) for p in data_paths):
        raise ValueError(f"--data: {next(p for p in data_paths if is_table(p))} is a solution table, which trains the "
                         f"pointing-cones network only (the config's family is {cfg.get('family')!r})")
    check_domain(data_paths, cfg.get("domain"))
    identity = run_identity(cfg, seed, data_paths)
    # before the data load: a refused --resume is known at once
    resumed = resume_checkpoint(out, identity, torch) if resume else None
    os.makedirs(os.path.join(out, "checkpoints"), exist_ok=True)
    arrays = _arrays(data_paths, cfg)
    N = arrays["X"].shape[0]
    if N < 10:
        raise ValueError(f"data: only {N} exact solutions in {data_paths}; need at least 10")
    tr_idx, va_idx = split(arrays, float(cfg.get("val_fraction", 0.1)), seed)
    x_mean = arrays["X"][tr_idx].mean(axis=0)
    x_std = np.maximum(arrays["X"][tr_idx].std(axis=0), 1e-6)
    train_t, val_t = _tensors(arrays, tr_idx, torch), _tensors(arrays, va_idx, torch)
    for t in (train_t, val_t):
        t["X"] = (t["X"] - torch.tensor(x_mean, dtype=torch.float32)) / torch.tensor(x_std, dtype=torch.float32)
    net = _net(cfg, torch)
    opt = torch.optim.AdamW(net.parameters(), lr=float(cfg["learning_rate"]), weight_decay=float(cfg.get("weight_decay", 0.0)))
    E = int(cfg["epochs"])
    lr0, lr1 = float(cfg["learning_rate"]), float(cfg.get("lr_final", cfg["learning_rate"]))
    start_epoch = 0
    log_rows = []
    if resumed is not None:
        path, st = resumed
        try:
            net.load_state_dict(st["net"])
            opt.load_state_dict(st["opt"])
        except (RuntimeError, ValueError, KeyError) as e:   # the identity matched, the file did not
            raise ValueError(f"--resume: {path}: does not fit this run's network "
                             f"({str(e).strip().splitlines()[-1][:160]}); start afresh with another --out") from None
        torch.set_rng_state(st["rng"])
        start_epoch = int(st["epoch"])
        log_rows = st["log"]
    with open(os.path.join(out, "config.yaml"), "w") as f:
        yaml.safe_dump(dict(cfg, seed=seed, data=data_paths), f, sort_keys=False)
    bs = int(cfg["batch_size"])
    n_tr = len(tr_idx)
    bar = None
    if progress_bar:
        from tqdm import tqdm
        bar = tqdm(total=E, initial=start_epoch, desc="slew train", unit="epoch")
    t0 = time.perf_counter()
    saved = start_epoch     # the last epoch with a checkpoint on disk
    last = None             # the state at the end of the last finished epoch, for a Ctrl-C
    try:
        for epoch in range(start_epoch, E):
            frac = epoch / max(1, E - 1)
            lr = lr1 + 0.5 * (lr0 - lr1) * (1 + math.cos(math.pi * frac)) if cfg.get("lr_schedule") == "cosine" else lr0
            for g in opt.param_groups:
                g["lr"] = lr
            net.train()
            perm = torch.randperm(n_tr)
            tot = 0.0
            for b in range(0, n_tr, bs):
                i = perm[b:b + bs]
                batch = {k: v[i] for k, v in train_t.items()}
                loss, _, _ = _losses(net(batch["X"]), batch, cfg, torch)
                opt.zero_grad()
                loss.backward()
                opt.step()
                tot += float(loss.detach()) * len(i)
            net.eval()
            with torch.no_grad():
                vl, parts, met = _losses(net(val_t["X"]), val_t, cfg, torch) if len(va_idx) else (torch.tensor(math.nan), {}, {})
            row = {"epoch": epoch + 1, "lr": lr, "train_loss": tot / n_tr, "val_loss": float(vl),
                   **{f"val_{k}": v for k, v in parts.items()}, **{f"val_{k}": v for k, v in met.items()}}
            log_rows.append(row)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(train=f"{row['train_loss']:.4f}", val=f"{row['val_loss']:.4f}",
                                struct=f"{met.get('structure_acc', met.get('touch_set_acc', 0)):.3f}")
            # a copy: the next epoch changes the live tensors, and a Ctrl-C in it must save this state
            last = copy.deepcopy({"net": net.state_dict(), "opt": opt.state_dict(), "rng": torch.get_rng_state(),
                                  "epoch": epoch + 1, "log": list(log_rows), "identity": identity})
            if (epoch + 1) % int(cfg.get("checkpoint_every", 50)) == 0 or epoch + 1 == E:
                _save_checkpoint(torch, out, last)
                saved = epoch + 1
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        raise TrainingInterrupted(_keep_on_interrupt(out, torch, log_rows, last, saved, E)) from None
    if bar is not None:
        bar.close()
    try:
        wall = time.perf_counter() - t0
        _write_log(out, log_rows)
        final = log_rows[-1]
        card_training = {
            "family": cfg.get("family"), "data": [os.path.basename(p) for p in data_paths],
            "data_files": data_files(data_paths, identity["data_sha256"]),
            "n_records": int(arrays["n_records"]), "n_exact_solutions": int(N), "n_train": int(n_tr),
            "n_val": int(len(va_idx)), "epochs": E, "seed": seed, "train_wall_time_s": round(wall, 1),
            "torch": torch.__version__, "python": platform.python_version(),
            "val_metrics": {k[4:]: final[k] for k in final if k.startswith("val_")},
        }
        path = export(net, cfg, x_mean, x_std, card_training, export_path or os.path.join(out, "model.npz"))
        summary = dict(card_training, model=path, run_dir=out)
        if _is_cones(cfg):
            # the shipped pointing-cones warm start tries the nearest solved problems first
            # (solvers.warmstart.cone_ensemble): their table, from the same data, goes next to the model
            summary["table"] = export_cone_table(data_paths, table_path(path), int(cfg["max_switches"]),
                                                 data_files=card_training["data_files"])
        else:
            # the shipped full-attitude warm start tries them after the network's structured
            # candidates (solvers.warmstart.attitude_ensemble)
            summary["table"] = export_attitude_table(data_paths, table_path(path), int(cfg["max_switches"]),
                                                     cfg.get("domain", {}))
        with open(os.path.join(out, "summary.json"), "w") as f:
            json.dump(summary, f, indent=1)
    except KeyboardInterrupt:
        # the last checkpoint holds the finished training: a resume only writes the files again
        raise TrainingInterrupted(f"after the last epoch ({E}), while writing the model into {out}: "
                                  f"--resume writes it again from checkpoints/epoch_{E:04d}.pt") from None
    return summary


def data_files(data_paths, sha256) -> list:
    """What the card records of each data file: its name, checksum, and the family, seed and
    distribution its problems are drawn from (``slew evaluate`` warns when its held-out problems
    are these)."""
    out = []
    for path, sha in zip(data_paths, sha256):
        meta = data_meta(path)
        out.append({"file": os.path.basename(path), "sha256": sha, "family": meta.get("family"),
                    "seed": meta.get("seed"), "distribution": meta.get("distribution"),
                    # a table: the data files its own card names (none for tables exported before
                    # session 39)
                    **({"table": True, "sources": meta.get("sources", [])} if meta.get("table") else {})})
    return out


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during the epochs or while the run directory is written; ``args[0]`` says what
    was kept."""


def _keep_on_interrupt(out, torch, log_rows, last, saved, E) -> str:
    """After a Ctrl-C: ``log.csv`` of the epochs done and a checkpoint of the last finished
    epoch (the periodic ones can be up to ``checkpoint_every - 1`` epochs behind), which
    ``--resume`` continues as if nothing had happened. Returns what was kept, in words."""
    from ..interrupts import interrupt_deferred
    with interrupt_deferred(reraise=False):     # (a second Ctrl-C must not cut what the first keeps)
        if last is not None and last["epoch"] > saved:
            _save_checkpoint(torch, out, last)
            saved = last["epoch"]
        rows = [r for r in log_rows if r["epoch"] <= saved]    # the log of the state kept (a Ctrl-C can
        if rows:                                               # come between an epoch's row and its copy)
            _write_log(out, rows)
    if not saved:
        return f"in epoch 1 of {E}: no epoch finished, no checkpoint written"
    return (f"after epoch {saved} of {E}: {os.path.join(out, 'log.csv')} and "
            f"{os.path.join(out, 'checkpoints', f'epoch_{saved:04d}.pt')} kept; --resume continues")


def file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def run_identity(cfg, seed, data_paths) -> dict:
    """What makes two runs the same run: the resolved config (epochs included: the learning-rate
    schedule depends on it), the seed, and the data files (where they are, and their content)."""
    # checkpoint_every only says when to save: a resume may change it
    cfg = {k: v for k, v in cfg.items() if k != "checkpoint_every"}
    return {"config": json.loads(json.dumps(cfg, default=str)), "seed": int(seed),
            "data": [os.path.realpath(p) for p in data_paths],
            "data_sha256": [file_sha256(p) for p in data_paths]}


def identity_differences(saved, now, epoch) -> list:
    """The options in which the run of a checkpoint at ``epoch`` (identity ``saved``) differs
    from this one (``now``), each with the two values."""
    diffs = []
    if saved["data"] != now["data"]:
        diffs.append(f"--data ({', '.join(map(os.path.basename, saved['data']))}; now "
                     f"{', '.join(map(os.path.basename, now['data']))})")
    elif saved["data_sha256"] != now["data_sha256"]:
        changed = [os.path.basename(p) for p, a, b in zip(now["data"], saved["data_sha256"], now["data_sha256"]) if a != b]
        diffs.append(f"--data (the content of {', '.join(changed)} changed since)")
    if saved["seed"] != now["seed"]:
        diffs.append(f"--seed ({saved['seed']}; now {now['seed']})")
    c0, c1 = saved["config"], now["config"]
    if c0.get("epochs") != c1.get("epochs"):
        beyond = f", already at epoch {epoch}, beyond" if epoch > int(c1["epochs"]) else ""
        diffs.append(f"--epochs (a {c0.get('epochs')}-epoch run{beyond}; now {c1.get('epochs')})")
    keys = sorted(k for k in set(c0) | set(c1) if k != "epochs" and c0.get(k) != c1.get(k))
    if keys:
        diffs.append(f"--config ({', '.join(keys)})")
    return diffs


def resume_checkpoint(out, identity, torch):
    """``(path, state)`` of the latest checkpoint in ``out`` written by this run (same
    identity), ``None`` if there is no checkpoint at all. Checkpoints of other runs (a fresh run
    into the same ``--out`` leaves them) are never resumed: if none is of this run, an error
    names what differs from the latest one."""
    where = os.path.join(out, "checkpoints")
    other, unreadable = None, []
    for path in sorted(glob.glob(os.path.join(where, "epoch_*.pt")), reverse=True):
        try:
            st = torch.load(path, weights_only=False)
        except Exception as e:   # noqa: BLE001 - a torn or foreign file is not this run's checkpoint
            unreadable.append(f"{os.path.basename(path)}: {type(e).__name__}")
            continue
        if isinstance(st, dict) and st.get("identity") == identity:
            return path, st
        other = other or (path, st if isinstance(st, dict) else {})
    if other is None and not unreadable:
        return None
    if other is None:
        raise ValueError(f"--resume: no checkpoint in {where} can be read ({'; '.join(unreadable)}); "
                         f"start afresh with another --out")
    path, st = other
    if not st.get("identity"):
        raise ValueError(f"--resume: no checkpoint in {where} is of this run; the latest ({os.path.basename(path)}) "
                         f"was written before checkpoints recorded their run (config, seed, data), so it cannot be "
                         f"told from another run's: start afresh with another --out")
    diffs = identity_differences(st["identity"], identity, int(st.get("epoch", 0)))
    raise ValueError(f"--resume: no checkpoint in {where} is of this run; the latest ({os.path.basename(path)}) "
                     f"differs in {'; '.join(diffs)}. Give that run's options, or another --out")


def _save_checkpoint(torch, out, state):
    """Write to a temporary name, then rename: a run stopped mid-write keeps its last checkpoint."""
    path = os.path.join(out, "checkpoints", f"epoch_{state['epoch']:04d}.pt")
    tmp = path + ".tmp"
    try:
        torch.save(state, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def table_path(model_path):
    """Where the neighbour table of a model lives: ``NAME.nn.npz`` next to ``NAME.npz``."""
    return os.path.splitext(os.fspath(model_path))[0] + ".nn.npz"


def export_attitude_table(data_paths, path, max_switches, domain, k=3):
    """The exact solutions of ``data_paths`` as a compact nearest-neighbour table (float32,
    compressed; ``solvers.warmstart.nearest``), with the network's domain."""
    from .data import nearest_table
    table = nearest_table(data_paths, max_switches, k)
    table.domain = domain or {}
    table.name = f"full-attitude solutions ({table.X.shape[0]:,} exact)"
    table.save(path, compact=True)
    return path


def export_cone_table(data_paths, path, max_switches, k=4, data_files=None):
    """The exact solutions of ``data_paths`` as a compact nearest-neighbour table (float32,
    compressed; ``solvers.warmstart.cone_nearest``); ``data_files``: where they came from (the
    card's), written into the table's card, so that a training from the table records them."""
    from .cone_data import nearest_table
    table = nearest_table(data_paths, max_switches, k)
    table.data_files = list(data_files or [])
    table.name = f"pointing-cones solutions ({table.a['X'].shape[0]:,} exact)"
    table.save(path, compact=True)
    return path


def export(net, cfg, x_mean, x_std, training_info, path):
    """Write the numpy model file ``NAME.npz`` and its readable card ``NAME.md`` next to it."""
    from solvers.warmstart.model import WarmStartModel, output_layout
    import solvers
    lin = [m for m in net if hasattr(m, "weight")]
    weights = [(m.weight.detach().numpy().T.astype(np.float32), m.bias.detach().numpy().astype(np.float32)) for m in lin]
    if _is_cones(cfg):
        from solvers.warmstart.cone_model import ConeWarmStartModel as cls, cone_output_layout
        K = int(cfg["max_switches"])
        layout = cone_output_layout(K)
    else:
        cls, K = WarmStartModel, int(cfg["max_switches"])
        layout = output_layout(K)
    card = {"name": f"learned warm start ({cfg.get('family')})", "family": cfg.get("family"),
            "activation": cfg.get("activation", "silu"), "max_switches": K, "kind": cls.KIND,
            "output_layout": {k: list(v) for k, v in layout.items()},
            "hidden": list(cfg["hidden"]), "domain": cfg.get("domain", {}), "training": training_info,
            **({"heads": int(cfg["heads"])} if int(cfg.get("heads", 1)) > 1 else {}),
            "slewopt_version": getattr(solvers, "__version__", "0.1.0"),
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    m = cls([(W.astype(np.float64), b.astype(np.float64)) for W, b in weights], x_mean, x_std, card)
    m.weights = weights
    m.save(path)
    write_card_md(m.card, os.path.splitext(path)[0] + ".md")
    return path


def write_card_md(card, path):
    t = card.get("training", {})
    vm = t.get("val_metrics", {})
    n_params = None
    lines = [f"# Model card: {card.get('name')}", "",
             f"- format: {card.get('format')} v{card.get('format_version')}, sha256 of the weights `{card.get('sha256')}`",
             f"- network: MLP {card.get('hidden')} ({card.get('activation')}), {card.get('max_switches')} switch slots per axis"
             + (f", {card['heads']} heads and a selector (winner-takes-all)" if card.get("heads", 1) > 1 else ""),
             f"- covers (domain): `{json.dumps(card.get('domain'))}`",
             f"- training family: {t.get('family')}; data files: {_data_names(t)}",
             f"- dataset: {t.get('n_records')} records"
             + (" (a solution table's rows counted as records)" if any(d.get("table") for d in t.get("data_files") or [])
                else "")
             + f", {t.get('n_exact_solutions')} exact solutions ({t.get('n_train')} train / {t.get('n_val')} validation)",
             f"- epochs {t.get('epochs')}, seed {t.get('seed')}, training wall time {t.get('train_wall_time_s')} s, torch {t.get('torch')}",
             "", "Validation metrics (held-out 10 % of the exact solutions):", ""]
    for k, v in vm.items():
        lines.append(f"- {k}: {v:.6g}" if isinstance(v, float) else f"- {k}: {v}")
    if card.get("evaluation"):
        lines += ["", "Evaluation (`slew evaluate`):", "", card["evaluation"]]
    del n_params
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


def _data_names(training) -> str:
    """The data files, with their seeds where the card records them."""
    files = training.get("data_files")
    if not files:
        return ", ".join(training.get("data", []))
    return ", ".join(f"{d['file']} ({'a solution table' if d.get('table') else 'seed ' + str(d['seed'])}, "
                     f"sha256 {str(d['sha256'])[:12]}…)" for d in files)


def _write_log(out, rows):
    keys = list(rows[0].keys())
    with open(os.path.join(out, "log.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        ep = [r["epoch"] for r in rows]
        fig, ax = plt.subplots(1, 2, figsize=(10, 3.5))
        ax[0].semilogy(ep, [r["train_loss"] for r in rows], label="train")
        ax[0].semilogy(ep, [r["val_loss"] for r in rows], label="validation")
        ax[0].set_xlabel("epoch")
        ax[0].set_ylabel("loss")
        ax[0].legend()
        ax[1].plot(ep, [r.get("val_structure_acc", np.nan) for r in rows], label="structure accuracy")
        ax[1].plot(ep, [r.get("val_u_first_acc", np.nan) for r in rows], label="first-sign accuracy")
        ax[1].set_xlabel("epoch")
        ax[1].legend()
        fig.tight_layout()
        fig.savefig(os.path.join(out, "loss.png"), dpi=90)
        plt.close(fig)
    except Exception:   # noqa: BLE001 - a missing plot must not lose the trained model
        pass
