"""Behaviour cloning of the solvers' time-optimal controls, and the comparison with RL.

The expert is ``solvers.solve``: expert problem ``i`` is the family's task distribution
sampled with ``np.random.default_rng([bc_seed, i])`` (the ``slew generate`` scheme), solved
once and kept in a ``slew generate`` dataset file (``runs/solutions/<family>-seed<S>.jsonl``
by default, continued when more problems are asked for). Each verified solution is flown in
the environment: at every control step the action is the optimal torque ``u(t) / u_max``
averaged over the step (``action: average``, the default: the same impulse as the bang-bang
control, switch instants included) or taken at the step's start (``action: start``). The
environment's control is piecewise constant over ``control_dt``, so the flown trajectory is
an approximation of the optimal one; the observations along it, paired with the actions,
are the behaviour-cloning data.

With ``bc.expert: dense`` (the ``pointing-cones`` entry of ``configs/ppo.yaml``) the expert is
instead ``training.rl.dense_expert``: dense collocation answers of the problems with every cone
inflated by ``bc.margin_deg``, each dense state labelled with the control averaged over the
step that starts there, plus the records of DAgger rounds listed in ``bc.extra_data``.

Pre-training (``slew train-rl --bc-pretrain N``, ``pretrain``):

* the ``VecNormalize`` observation statistics are set from the expert observations (and,
  with ``freeze_normalization`` (default true), kept fixed during the RL that follows:
  otherwise RL's first, very different states move them and the cloned policy collapses);
* PPO: the Gaussian policy's mean is fitted to the expert actions (MSE), and, with
  ``value_pretrain``, the value network to the expert's discounted returns; ``log_std``
  (if set) replaces the policy's log standard deviation (the RL phase's exploration noise);
  ``rl_learning_rate`` (if set, PPO and SAC) replaces the learning rate of the RL phase;
* SAC: the actor's deterministic action ``tanh(mean)`` is fitted (MSE); with
  ``prefill_replay`` the expert transitions are put in the replay buffer (and the random-action
  warm-up ``learning_starts`` is skipped); ``ent_coef_init`` sets the initial entropy
  temperature; ``actor_warmup`` keeps the actor frozen for that many gradient steps while the
  critic learns (without these, the untrained critic and the initial temperature 1 undid the
  cloned actor).

Command line::

    python -m training.rl.bc dataset --family full-attitude --episodes 200 [--out bc.npz]
    python -m training.rl.bc clone   --algo ppo --family full-attitude --episodes 200 --out runs/bc
    python -m training.rl.bc compare --algo ppo --family full-attitude --timesteps 200000 \\
                                     --episodes 200 --n-eval 200 --out runs/compare

``compare`` trains RL from scratch, cloning alone and cloning then RL with equal budgets
(the same RL steps for both RL variants, the same expert problems for both cloning
variants), evaluates the three with ``training.rl.evaluate`` on the same held-out tasks
and writes ``compare.md`` and ``compare.json``.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from . import ALGOS, DEFAULT_BC_SEED, DEFAULT_EVAL_SEED, FAMILIES

ACTION_MODES = ("average", "start")
BC_DEFAULTS = {"epochs": 50, "batch_size": 256, "learning_rate": 1e-3, "action": "average",
               "value_pretrain": True, "prefill_replay": True, "n_sub": 32, "log_std": None, "rl_learning_rate": None, "actor_warmup": 0,
               "ent_coef_init": None, "expert": "switch-times", "margin_deg": 2.5,
               "extra_data": []}
EXPERT_KINDS = ("switch-times", "dense")


# --------------------------------------------------------------------------- expert solutions
def default_solutions_path(family: str, seed: int) -> Path:
    return Path("runs") / "solutions" / f"{family}-seed{int(seed)}.jsonl"


def solve_spec(family: str, n: int, seed: int, solve_fn: Optional[str] = None, solve_options=None):
    """The ``GenerationSpec`` the problems are solved under; its checks raise a ``ValueError``
    naming a bad solve route or option before anything is written."""
    from training.generate import DEFAULT_SOLVE_FN, GenerationSpec
    return GenerationSpec(family=family, seed=int(seed), n=int(n), solve_options=dict(solve_options or {}),
                          solve_fn=solve_fn or DEFAULT_SOLVE_FN)


def solve_problems(family: str, n: int, seed: int, path=None, workers: int = 1, solve_options=None,
                   progress: bool = True, solve_fn: Optional[str] = None) -> list:
    """Records ``0 .. n-1`` of the ``slew generate`` dataset (family, seed), solving what is missing.

    Returns the records (failures included) sorted by index. Problem ``i`` is
    ``TaskDistribution.family(family).sample(np.random.default_rng([seed, i]))``. ``solve_fn``:
    the solve route as ``"module:function"`` (default ``solvers.solve``, as ``slew generate``).
    """
    from training.dataset import load
    from training.generate import generate

    spec = solve_spec(family, n, seed, solve_fn, solve_options)    # (checked first: nothing made for a bad one)
    path = Path(path) if path is not None else default_solutions_path(family, seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    have = {r["index"] for r in load(path)} if path.exists() else set()
    if n > 0 and not set(range(n)) <= have:   # all there: read only (no lock, no solver)
        summary = generate(spec, path, workers=max(int(workers), 1), progress=progress)
        if summary.interrupted:
            raise KeyboardInterrupt
    records = [r for r in load(path) if r["index"] < n] if path.exists() else []
    if len(records) < n:
        raise RuntimeError(f"{path}: only {len(records)} of {n} problems are solved or recorded; run again")
    return records


def control_from_record(rec: dict) -> Optional[Callable]:
    """The optimal torque ``u(t)`` (problem units) of a verified bang-bang record, or None.

    Per-axis bound: ``u_i(t) = u_max,i · u_first_i · (−1)^(switches of axis i before t)``,
    zero after ``tf`` (the switch times alone reproduce the extremal, CONVENTIONS.md).
    """
    if rec.get("success") is not True or rec.get("switch_times") is None or rec.get("u_first") is None:
        return None
    from slew_env import SlewProblem

    prob = SlewProblem.from_dict(rec["problem"])
    if not math.isinf(prob.torque_norm):
        return None
    sw = [np.asarray(s if s is not None else [], dtype=float) for s in rec["switch_times"]]
    u_first = np.asarray(rec["u_first"], dtype=float)
    umax = np.asarray(prob.torque_max, dtype=float)
    tf = float(rec["tf"])

    def control(t):
        t = np.asarray(t, dtype=float)
        flips = np.stack([np.searchsorted(sw[i], t, side="right") for i in range(3)], axis=-1)
        u = umax * u_first * np.where(flips % 2 == 0, 1.0, -1.0)
        return np.where((t <= tf)[..., None], u, 0.0)

    return control


def _env_for(env_kwargs: dict, shield: Optional[dict] = None, capture: Optional[dict] = None):
    """A ``SlewEnv`` with a run's ``env_kwargs``, wrapped as the policy flies it (``train.wrap_controller``)."""
    from slew_env import SlewEnv

    from .train import wrap_controller

    kw = {k: v for k, v in (env_kwargs or {}).items() if k not in ("max_episode_steps", "task_distribution")}
    return wrap_controller(SlewEnv(**kw), shield, capture)


def expert_action(control, t0: float, dt: float, umax: np.ndarray, mode: str = "average", n_sub: int = 32):
    """Normalised action of the step ``[t0, t0 + dt)``: mean of ``u / u_max`` over the step, or its value at ``t0``."""
    if mode == "average":
        ts = t0 + (np.arange(n_sub) + 0.5) / n_sub * dt
        a = control(ts).mean(axis=0) / umax
    elif mode == "start":
        a = control(np.asarray([t0]))[0] / umax
    else:
        raise ValueError(f"bc.action: expected one of {ACTION_MODES}, got {mode!r}")
    return np.clip(a, -1.0, 1.0)


def solution_actions(solution, control_dt: float = 0.05, n_sub: int = 32) -> np.ndarray:
    """The actions that fly ``solution`` (a ``solvers.solve`` answer with a trajectory) in a
    ``SlewEnv`` posed with ``solution.problem`` at control step ``control_dt`` (time units T, the
    environment's ``control_dt``): ``(ceil(tf / Δt), 3)`` float32, row k the mean of
    ``u(t) / u_max`` over the step ``[kΔt, (k + 1)Δt)`` (``n_sub`` midpoints; ``Δt = control_dt · T``),
    the torque cut off at ``tf`` (``SlewSolution.control`` goes on past it).

    ::

        obs, _ = env.reset(options={"problem": sol.problem})
        for a in solution_actions(sol, env.unwrapped.control_dt):
            obs, reward, terminated, truncated, info = env.step(a)
            if terminated or truncated:
                break
    """
    prob = solution.problem
    if prob is None or not len(solution.t):
        raise ValueError("solution: no trajectory to fly (a solve that failed before one was found?)")
    tf = float(solution.tf)

    def control(t):
        t = np.asarray(t, dtype=float)
        return np.where((t <= tf)[..., None], solution.control(t), 0.0)

    dt = float(control_dt) * prob.time_unit
    umax = np.asarray(prob.torque_max, dtype=float)
    n_steps = int(math.ceil(tf / dt - 1e-9))
    return np.array([expert_action(control, k * dt, dt, umax, "average", n_sub) for k in range(n_steps)],
                    dtype=np.float32).reshape(n_steps, 3)


def expert_rollout(env, rec: dict, mode: str = "average", n_sub: int = 32) -> Optional[dict]:
    """Fly the optimal control of ``rec`` in ``env`` (a ``SlewEnv``) for ``ceil(tf / dt)`` steps.

    Returns ``obs, actions, rewards, next_obs, terminated`` arrays and whether the flown
    (piecewise-constant) control reached the environment's success region; None when the
    record has no verified bang-bang control.
    """
    control = control_from_record(rec)
    if control is None:
        return None
    from slew_env import SlewProblem

    prob = SlewProblem.from_dict(rec["problem"])
    obs, _ = env.reset(options={"problem": prob})
    dt = env.control_dt * prob.time_unit
    umax = np.asarray(prob.torque_max, dtype=float)
    n_steps = int(math.ceil(float(rec["tf"]) / dt - 1e-9))
    O, A, R, O2, D = [], [], [], [], []
    info = {"is_success": False, "attitude_error": math.nan, "rate_error": math.nan}
    for k in range(n_steps):
        a = expert_action(control, k * dt, dt, umax, mode, n_sub)
        obs2, r, term, _, info = env.step(a.astype(np.float32))
        O.append(obs)
        A.append(a)
        R.append(r)
        O2.append(obs2)
        D.append(term)
        obs = obs2
        if term:
            break
    return {"obs": np.asarray(O, np.float32), "actions": np.asarray(A, np.float32),
            "rewards": np.asarray(R, np.float64), "next_obs": np.asarray(O2, np.float32),
            "terminated": np.asarray(D, bool), "success": bool(info["is_success"]),
            "final_attitude_error": float(info["attitude_error"]), "final_rate_error": float(info["rate_error"]),
            "tf": float(rec["tf"]), "steps": len(A)}


def discounted_returns(rewards: np.ndarray, gamma: float) -> np.ndarray:
    g = np.zeros_like(rewards)
    acc = 0.0
    for k in range(len(rewards) - 1, -1, -1):
        acc = rewards[k] + gamma * acc
        g[k] = acc
    return g


def build_dataset(records: list, env_kwargs: Optional[dict] = None, mode: str = "average", gamma: float = 0.99,
                  n_sub: int = 32, keep_failed: bool = False) -> dict:
    """(observation, action) pairs of the expert's rollouts of the verified records.

    Keys: ``obs`` (N, obs_dim) float32, ``actions`` (N, 3) float32 in [-1, 1], ``rewards``,
    ``next_obs``, ``terminated``, ``returns`` (discounted with ``gamma``), ``episode``
    (index of the record), and the statistics ``n_records``, ``n_flown`` (records with a
    bang-bang control), ``replay_success_rate`` (share of the flown optimal controls that met
    the environment's success tolerance), ``n_episodes`` (episodes kept). A flown control
    that misses the tolerance (the switch times do not reproduce the extremal, e.g. a
    collocation answer with a singular arc) is dropped unless ``keep_failed``.
    """
    env = _env_for(env_kwargs)
    eps = []
    flown = []
    for rec in records:
        ro = expert_rollout(env, rec, mode, n_sub)
        if ro is not None and ro["steps"] > 0:
            flown.append(ro["success"])
            if not (ro["success"] or keep_failed):
                continue
            ro["returns"] = discounted_returns(ro["rewards"], gamma)
            ro["index"] = int(rec["index"])
            eps.append(ro)
    env.close()
    replay_rate = float(np.mean(flown)) if flown else math.nan
    obs_dim = env.observation_space.shape[0]
    if not eps:
        return {"obs": np.zeros((0, obs_dim), np.float32), "actions": np.zeros((0, 3), np.float32),
                "rewards": np.zeros(0), "next_obs": np.zeros((0, obs_dim), np.float32),
                "terminated": np.zeros(0, bool), "returns": np.zeros(0), "episode": np.zeros(0, np.int64),
                "n_records": len(records), "n_flown": len(flown), "n_episodes": 0, "replay_success_rate": replay_rate}
    cat = lambda k: np.concatenate([e[k] for e in eps])  # noqa: E731
    return {"obs": cat("obs"), "actions": cat("actions"), "rewards": cat("rewards"), "next_obs": cat("next_obs"),
            "terminated": cat("terminated"), "returns": cat("returns"),
            "episode": np.concatenate([np.full(e["steps"], e["index"], np.int64) for e in eps]),
            "n_records": len(records), "n_flown": len(flown), "n_episodes": len(eps),
            "replay_success_rate": replay_rate,
            "replay_final_attitude_error_deg_median": float(np.degrees(np.median([e["final_attitude_error"]
                                                                                  for e in eps])))}


def dense_returns(records: list, env_kwargs: Optional[dict], gamma: float) -> np.ndarray:
    """Approximate discounted returns of the dense expert's states (for value pre-training).

    A state at time ``t`` of an answer with final time ``tf`` is ``K = ceil((tf − t) / Δt)`` control
    steps from success: return ``−Δt·(1 − γ^K)/(1 − γ) + γ^(K−1)·(bonus − Φ(s))`` with ``Φ(s) = −(error
    angle + rate error)`` (the shaping terms telescope to ``−Φ(s)`` at the terminal step; undiscounted there).
    """
    from slew_env import SlewProblem
    from slew_env.core import env_kernels as _k

    kw = dict(env_kwargs or {})
    dt = float(kw.get("control_dt", 0.05))
    bonus = float(kw.get("success_bonus", 10.0))
    shaping = float(kw.get("shaping", 1.0))
    out = []
    for rec in records:
        if not rec.get("success"):
            continue
        prob = SlewProblem.from_dict(rec["problem"])
        task = prob.to_task_array(int(kw.get("max_cones", 4)))
        T = prob.time_unit
        obs = np.zeros(_k.obs_length(int(kw.get("max_cones", 4))), np.float32)
        ts = list(rec["t"]) + [rec["tf"]] * 3
        X = np.concatenate([np.asarray(rec["q"], float), np.asarray(rec["omega"], float)], axis=1)
        X = np.concatenate([X, np.repeat(np.concatenate([X[-1:, :4], np.zeros((1, 3))], axis=1), 3, axis=0)])
        for t, x in zip(ts, X):
            x = x.copy()
            x[:4] /= np.linalg.norm(x[:4])
            att, rate = _k.write_obs(task, x, obs)
            K = max(int(math.ceil((float(rec["tf"]) - t) / (dt * T) - 1e-9)), 1)
            out.append(-dt * (1.0 - gamma ** K) / (1.0 - gamma) + gamma ** (K - 1) * (bonus + shaping * (att + rate)))
    return np.asarray(out, np.float64)


def dense_expert_dataset(family: str, n_episodes: int, seed: Optional[int] = None, env_kwargs=None, gamma=0.99,
                         expert_data=None, margin_deg: float = 2.5, progress=True, extra_data=()) -> dict:
    """Cloning pairs from dense collocation answers with inflated cones (``training.rl.dense_expert``).

    ``extra_data``: more dense record files (DAgger rounds, ``python -m training.rl.dense_expert
    dagger``); their solved records are added to those of the ``n_episodes`` expert problems.
    """
    from .dense_expert import build_pairs, default_dense_path, load_records, solve_range

    seed = DEFAULT_BC_SEED if seed is None else int(seed)
    path = expert_data or default_dense_path(family, seed)
    records = solve_range(family, seed, n_episodes, path, margin_deg, progress)
    n_extra = 0
    for extra in extra_data or ():
        if not Path(extra).exists():
            raise FileNotFoundError(f"bc.extra_data: no file {extra}")
        more = load_records(extra)
        n_extra += len(more)
        records = records + more
    ok = [r for r in records if r.get("success")]
    if not ok:
        raise ValueError(f"behaviour cloning: none of the {len(records)} dense expert problems of {family!r} solved")
    kw = dict(env_kwargs or {})
    data = build_pairs(ok, int(kw.get("max_cones", 4)), float(kw.get("control_dt", 0.05)))
    data["returns"] = dense_returns(ok, kw, gamma)
    data.update(n_records=len(records), n_solved=len(ok), n_episodes=len(ok), seed=seed, n_extra_records=n_extra,
                replay_success_rate=math.nan, expert="dense", margin_deg=float(margin_deg),
                expert_min_margin_deg=float(min(r["min_margin_deg"] for r in ok)))
    return data


def expert_dataset(family: str, n_episodes: int, seed: Optional[int] = None, env_kwargs=None, mode="average",
                   gamma=0.99, expert_data=None, workers: int = 1, solve_options=None, progress=True) -> dict:
    """Solve (or load) ``n_episodes`` expert problems and build the cloning dataset (``build_dataset``)."""
    seed = DEFAULT_BC_SEED if seed is None else int(seed)
    records = solve_problems(family, n_episodes, seed, expert_data, workers, solve_options, progress)
    ok = [r for r in records if r.get("success") is True]
    if not ok:
        reasons = sorted({str(r.get("message"))[:120] for r in records})
        raise ValueError(f"behaviour cloning: none of the {len(records)} expert problems of {family!r} has a "
                         f"verified optimal solution ({'; '.join(reasons[:3])})")
    data = build_dataset(ok, env_kwargs, mode, gamma)
    data["n_records"] = len(records)
    data["n_solved"] = len(ok)
    data["seed"] = seed
    return data


# --------------------------------------------------------------------------- cloning
def _policy_mean(model, obs_t):
    """Deterministic action of the SB3 model as a differentiable tensor (PPO: Gaussian mean; SAC: tanh(mean))."""
    from stable_baselines3 import SAC

    if isinstance(model, SAC):
        return model.actor(obs_t, deterministic=True)
    return model.policy.get_distribution(obs_t).distribution.mean


def clone_actor(model, obs: np.ndarray, actions: np.ndarray, epochs: int = 50, batch_size: int = 256,
                learning_rate: float = 1e-3, seed: int = 0, val_fraction: float = 0.1) -> dict:
    """Fit the policy's deterministic action to ``actions`` on (already normalised) ``obs`` by MSE.

    Returns ``{"train_mse": [...], "val_mse": [...]}`` per epoch (the first entries are
    before any update); a random ``val_fraction`` of the pairs is held out.
    """
    import torch

    rng = np.random.default_rng(seed)
    n = len(obs)
    perm = rng.permutation(n)
    n_val = int(round(val_fraction * n)) if n >= 20 else 0
    val, tr = perm[:n_val], perm[n_val:]
    X = torch.as_tensor(obs, dtype=torch.float32)
    Y = torch.as_tensor(actions, dtype=torch.float32)
    from stable_baselines3 import SAC
    params = model.actor.parameters() if isinstance(model, SAC) else \
        [p for name, p in model.policy.named_parameters() if not name.startswith(("value_net", "mlp_extractor.value"))
         and name != "log_std"]
    opt = torch.optim.Adam(list(params), lr=learning_rate)
    policy = model.policy
    policy.set_training_mode(False)

    def mse(idx):
        if len(idx) == 0:
            return math.nan
        with torch.no_grad():
            return float(((_policy_mean(model, X[idx]) - Y[idx]) ** 2).mean())

    hist = {"train_mse": [mse(tr)], "val_mse": [mse(val)]}
    for _ in range(int(epochs)):
        policy.set_training_mode(True)
        order = tr[rng.permutation(len(tr))]
        for b in range(0, len(order), batch_size):
            idx = order[b:b + batch_size]
            loss = ((_policy_mean(model, X[idx]) - Y[idx]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        policy.set_training_mode(False)
        hist["train_mse"].append(mse(tr))
        hist["val_mse"].append(mse(val))
    return hist


def pretrain_value(model, obs: np.ndarray, returns: np.ndarray, epochs: int = 20, batch_size: int = 256,
                   learning_rate: float = 1e-3, seed: int = 0) -> list:
    """PPO: fit the value network to the expert's discounted returns (MSE per epoch returned)."""
    import torch

    rng = np.random.default_rng(seed + 1)
    X = torch.as_tensor(obs, dtype=torch.float32)
    Y = torch.as_tensor(returns, dtype=torch.float32)
    pol = model.policy
    params = [p for name, p in pol.named_parameters() if name.startswith(("value_net", "mlp_extractor.value"))]
    if not pol.share_features_extractor:
        params += list(pol.vf_features_extractor.parameters())
    opt = torch.optim.Adam(params, lr=learning_rate)
    hist = []
    for _ in range(int(epochs)):
        order = rng.permutation(len(X))
        tot = 0.0
        for b in range(0, len(order), batch_size):
            idx = order[b:b + batch_size]
            loss = ((pol.predict_values(X[idx]).flatten() - Y[idx]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            tot += loss.item() * len(idx)
        hist.append(tot / len(X))
    return hist


def actor_warmup_callback(n_updates: int):
    """SAC: keep the cloned actor frozen for the first ``n_updates`` gradient steps (the critic learns first)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class ActorWarmup(BaseCallback):
        def __init__(self):
            super().__init__()
            self.frozen = False

        def _set(self, frozen):
            for p in self.model.actor.parameters():
                p.requires_grad_(not frozen)
            self.frozen = frozen

        def _on_training_start(self):
            if self.model._n_updates < n_updates:
                self._set(True)

        def _on_step(self):
            if self.frozen and self.model._n_updates >= n_updates:
                self._set(False)
            return True

        def _on_training_end(self):
            if self.frozen:
                self._set(False)

    return ActorWarmup()


def prefill_replay(model, vecnorm, data: dict) -> int:
    """SAC: add the expert transitions (raw observations, as SB3 stores them) to the replay buffer."""
    buf = model.replay_buffer
    k = buf.n_envs
    n = (len(data["obs"]) // k) * k
    for b in range(0, n, k):
        sl = slice(b, b + k)
        buf.add(data["obs"][sl], data["next_obs"][sl], data["actions"][sl], data["rewards"][sl].astype(np.float32),
                data["terminated"][sl].astype(np.float32), [{} for _ in range(k)])
    return n


def pretrain(model, family: str, n_episodes: int, env_kwargs=None, bc_cfg=None, seed=None, expert_data=None,
             workers: int = 1, verbose: int = 0, solve_options=None) -> dict:
    """Behaviour-clone the optimal controls into ``model`` (PPO or SAC) before RL; returns statistics."""
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import VecNormalize

    t0 = time.perf_counter()
    cfg = dict(BC_DEFAULTS)
    cfg.update(bc_cfg or {})
    cfg.pop("freeze_normalization", None)   # used by training.rl.train
    unknown = set(cfg) - set(BC_DEFAULTS)
    if unknown:
        raise ValueError(f"bc: unknown key(s) {sorted(unknown)}; known: {sorted(BC_DEFAULTS)}")
    gamma = float(getattr(model, "gamma", 0.99))
    if cfg["expert"] not in EXPERT_KINDS:
        raise ValueError(f"bc.expert: expected one of {EXPERT_KINDS}, got {cfg['expert']!r}")
    if cfg["expert"] == "dense":
        if isinstance(model, SAC) and cfg["prefill_replay"]:
            raise ValueError("bc.expert: dense has no expert transitions for SAC's replay buffer; "
                             "set bc.prefill_replay=false")
        data = dense_expert_dataset(family, n_episodes, seed, env_kwargs, gamma, expert_data, cfg["margin_deg"],
                                    extra_data=cfg["extra_data"])
    else:
        data = expert_dataset(family, n_episodes, seed, env_kwargs, cfg["action"], gamma, expert_data, workers,
                              solve_options, progress=True)
    t_data = time.perf_counter() - t0
    vn = model.get_vec_normalize_env()
    obs = data["obs"]
    if isinstance(vn, VecNormalize) and vn.norm_obs:
        vn.obs_rms.update(obs.astype(np.float64))
        obs = vn.normalize_obs(obs)
    hist = clone_actor(model, obs, data["actions"], cfg["epochs"], cfg["batch_size"], cfg["learning_rate"])
    info = {"episodes_requested": int(n_episodes), "expert_seed": data["seed"], "n_solved": data["n_solved"],
            "n_episodes": data["n_episodes"], "n_pairs": int(len(obs)),
            "replay_success_rate": data["replay_success_rate"], "action": cfg["action"], "epochs": cfg["epochs"],
            "train_mse_first": hist["train_mse"][0], "train_mse_last": hist["train_mse"][-1],
            "val_mse_first": hist["val_mse"][0], "val_mse_last": hist["val_mse"][-1],
            "dataset_time_s": t_data, "expert": cfg["expert"]}
    if cfg["expert"] == "dense":
        info.update(margin_deg=data["margin_deg"], expert_min_margin_deg=data["expert_min_margin_deg"],
                    extra_data=[str(x) for x in cfg["extra_data"]], n_extra_records=data["n_extra_records"])
    if cfg["log_std"] is not None and not isinstance(model, SAC):
        import torch
        with torch.no_grad():   # PPO: exploration noise of the RL phase that follows the cloning
            model.policy.log_std.fill_(float(cfg["log_std"]))
        info["log_std"] = float(cfg["log_std"])
    if cfg["rl_learning_rate"] is not None:
        # learning rate of the RL phase that follows (a cloned policy is fine-tuned, not learnt)
        model.learning_rate = float(cfg["rl_learning_rate"])
        model._setup_lr_schedule()
        info["rl_learning_rate"] = float(cfg["rl_learning_rate"])
    if isinstance(model, SAC):
        if cfg["prefill_replay"]:
            info["replay_prefilled"] = prefill_replay(model, vn, data)
            model.learning_starts = 0     # no random-action warm-up: the buffer holds the expert's steps
        if cfg["ent_coef_init"] is not None and getattr(model, "log_ent_coef", None) is not None:
            import torch
            with torch.no_grad():         # a cloned, near-deterministic actor: start with a low temperature
                model.log_ent_coef.fill_(math.log(float(cfg["ent_coef_init"])))
            info["ent_coef_init"] = float(cfg["ent_coef_init"])
        if int(cfg["actor_warmup"]) > 0:
            info["actor_warmup"] = int(cfg["actor_warmup"])   # training.rl.train adds ActorWarmup
    elif cfg["value_pretrain"]:
        if isinstance(vn, VecNormalize) and vn.norm_reward:
            info["value_pretrain"] = "skipped (norm_reward: returns are rescaled during RL)"
        else:
            vh = pretrain_value(model, obs, data["returns"], max(cfg["epochs"] // 2, 1), cfg["batch_size"],
                                cfg["learning_rate"])
            info["value_mse_last"] = vh[-1]
    info["time_s"] = time.perf_counter() - t0
    if verbose:
        print(f"bc: {info['n_pairs']} pairs from {info['n_episodes']} episodes, MSE {info['train_mse_first']:.4f} -> "
              f"{info['train_mse_last']:.4f} (val {info['val_mse_last']:.4f})", file=sys.stderr)
    return info


# --------------------------------------------------------------------------- comparison
def compare(algo: str = "ppo", family: str = "full-attitude", timesteps: int = 200000, episodes: int = 200,
            n_eval: int = 200, seed: int = 0, out="runs/compare", config=None, eval_seed: int = DEFAULT_EVAL_SEED,
            bc_seed: Optional[int] = None, expert_data=None, solutions=None, solver_workers: int = 1,
            overrides=None, plot_k: int = 0, variants=("scratch", "bc", "bc+rl"), progress_bar=False) -> dict:
    """Train RL from scratch, cloning alone and cloning then RL with equal budgets; evaluate; write a table.

    ``timesteps``: RL steps of both RL variants; ``episodes``: expert problems of both
    cloning variants. Every variant is evaluated by ``training.rl.evaluate.evaluate`` on
    the same ``n_eval`` held-out problems (seed ``eval_seed``). Writes ``out/compare.md``
    and ``out/compare.json``; returns the latter's content.
    """
    from .evaluate import evaluate
    from .train import train

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    spec = {"scratch": (timesteps, 0), "bc": (0, episodes), "bc+rl": (timesteps, episodes)}
    rows = []
    for v in variants:
        if v not in spec:
            raise ValueError(f"variants: unknown {v!r}; known: {list(spec)}")
        steps, eps = spec[v]
        run_dir = out / v.replace("+", "-")
        cmd = (f"slew train-rl --algo {algo} --family {family} --timesteps {steps} --seed {seed} --out {run_dir}"
               + (f" --config {config}" if config else "") + (f" --bc-pretrain {eps}" if eps else "")
               + (f" --bc-seed {bc_seed}" if eps and bc_seed is not None else "")
               + (f" --expert-data {expert_data}" if eps and expert_data else "")
               + "".join(f" --set {o}" for o in overrides or []) + "   (via training.rl.bc compare)")
        tinfo = train(algo, family, config=config, timesteps=steps, seed=seed, out=run_dir, bc_pretrain=eps,
                      overrides=overrides, expert_data=expert_data, bc_seed=bc_seed, solver_workers=solver_workers,
                      progress_bar=progress_bar, command=cmd)
        res = evaluate(run_dir, family=family, n=n_eval, seed=eval_seed, out=run_dir / "eval-report",
                       plot_k=plot_k, solutions=solutions, solver_workers=solver_workers)
        s = res["summary"]
        rows.append({"variant": v, "rl_steps": tinfo["num_timesteps"], "expert_episodes": eps,
                     "train_wall_time_s": tinfo["wall_time_s"], **{k: s.get(k) for k in (
                         "n", "success_rate", "violation_rate", "tf_policy_median", "ratio_n", "ratio_median",
                         "ratio_mean", "ratio_p95")}})
    result = {"algo": algo, "family": family, "timesteps": timesteps, "episodes": episodes, "n_eval": n_eval,
              "seed": seed, "eval_seed": eval_seed, "rows": rows}
    (out / "compare.json").write_text(json.dumps(result, indent=2))
    (out / "compare.md").write_text(compare_table(result))
    return result


def _fmt(x, spec=".3f"):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return format(x, spec)


def compare_table(result: dict) -> str:
    lines = [f"# {result['algo'].upper()} on {result['family']}: RL from scratch vs cloning alone vs cloning then RL",
             "", f"RL steps {result['timesteps']}, expert problems {result['episodes']}, evaluated on "
                 f"{result['n_eval']} held-out problems (seed {result['eval_seed']}).", "",
             "| variant | RL steps | expert problems | train wall time (s) | success | violations | "
             "median tf_policy | ratio n | median ratio | mean ratio | p95 ratio |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        lines.append(f"| {r['variant']} | {r['rl_steps']} | {r['expert_episodes']} | {_fmt(r['train_wall_time_s'], '.0f')} "
                     f"| {_fmt(100 * r['success_rate'], '.1f')} % | {_fmt(100 * r['violation_rate'], '.1f')} % "
                     f"| {_fmt(r['tf_policy_median'])} | {r['ratio_n']} | {_fmt(r['ratio_median'])} "
                     f"| {_fmt(r['ratio_mean'])} | {_fmt(r['ratio_p95'])} |")
    lines.append("")
    lines.append("ratio = tf_policy / tf_optimal on the problems the policy solved and the solver verified.")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- command line
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m training.rl.bc", description="behaviour cloning of optimal slews")
    sub = p.add_subparsers(dest="cmd", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--family", default="full-attitude", choices=FAMILIES)
    common.add_argument("--episodes", type=int, default=200, help="expert problems (default 200)")
    common.add_argument("--bc-seed", type=int, default=None, help=f"seed of the expert problems (default {DEFAULT_BC_SEED})")
    common.add_argument("--expert-data", help="solutions file (slew generate format; created or continued)")
    common.add_argument("--solver-workers", type=int, default=1)
    d = sub.add_parser("dataset", parents=[common], help="build the (observation, action) dataset")
    d.add_argument("--action", default="average", choices=ACTION_MODES)
    d.add_argument("--out", default=None, help="save the arrays to this .npz")
    for name, hlp in (("clone", "cloning alone: a policy directory usable by evaluate-rl"),
                      ("compare", "scratch vs cloning alone vs cloning then RL, equal budgets")):
        c = sub.add_parser(name, parents=[common], help=hlp)
        c.add_argument("--algo", default="ppo", choices=ALGOS)
        c.add_argument("--config")
        c.add_argument("--seed", type=int, default=0)
        c.add_argument("--out", required=True)
        c.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
        c.add_argument("--threads", type=int, default=1)
        if name == "compare":
            c.add_argument("--timesteps", type=int, required=True, help="RL steps of both RL variants")
            c.add_argument("--n-eval", type=int, default=200)
            c.add_argument("--eval-seed", type=int, default=DEFAULT_EVAL_SEED)
            c.add_argument("--solutions", help="optimal solutions of the held-out problems (see evaluate-rl)")
            c.add_argument("--plot-k", type=int, default=0)
            c.add_argument("--variants", default="scratch,bc,bc+rl")
    args = p.parse_args(argv)
    try:
        if args.cmd == "dataset":
            data = expert_dataset(args.family, args.episodes, args.bc_seed, mode=args.action,
                                  expert_data=args.expert_data, workers=args.solver_workers)
            print(f"{data['n_solved']} of {data['n_records']} problems solved; {len(data['obs'])} pairs from "
                  f"{data['n_episodes']} episodes; flown optimal controls meeting the tolerance: "
                  f"{100 * data['replay_success_rate']:.1f} %")
            if args.out:
                np.savez_compressed(args.out, **{k: v for k, v in data.items() if isinstance(v, np.ndarray)})
            return 0
        import torch
        torch.set_num_threads(args.threads)
        if args.cmd == "clone":
            from .train import train
            info = train(args.algo, args.family, config=args.config, timesteps=0, seed=args.seed, out=args.out,
                         bc_pretrain=args.episodes, overrides=args.set, expert_data=args.expert_data,
                         bc_seed=args.bc_seed, solver_workers=args.solver_workers, threads=args.threads,
                         command=" ".join(sys.argv))
            print(json.dumps(info["bc"], indent=2))
            return 0
        res = compare(args.algo, args.family, args.timesteps, args.episodes, args.n_eval, args.seed, args.out,
                      args.config, args.eval_seed, args.bc_seed, args.expert_data, args.solutions,
                      args.solver_workers, args.set, args.plot_k, tuple(args.variants.split(",")))
        print(compare_table(res))
        return 0
    except (ValueError, FileNotFoundError) as e:
        print(f"bc: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
