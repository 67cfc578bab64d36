"""Train PPO or SAC (stable-baselines3) on ``slew_env/Slew-v0``.

::

    slew train-rl --algo ppo --family full-attitude [--config training/rl/configs/ppo.yaml]
                  [--timesteps N] [--n-envs N] [--seed S] [--out runs/NAME]
                  [--resume CHECKPOINT] [--bc-pretrain N_EPISODES] [--progress-bar]
                  [--vec-env dummy|subproc] [--set KEY=VALUE ...]
    python -m training.rl.train ...          (the same options)

Hyperparameters come from an rl-zoo style YAML file (one per algorithm, one entry per task
family; ``training/rl/configs/``). The run directory ``--out`` receives:

==============================  ===============================================================
``model.zip``                   the final model
``vecnormalize.pkl``            its ``VecNormalize`` statistics (load with ``training=False``)
``config.yaml``                 the resolved configuration (algo, family, seed, every setting; after
                                cloning, the ``bc.rl_learning_rate`` that runs as ``learning_rate``)
``train_info.json``             steps, wall time, seed, versions, command, BC statistics
``checkpoints/``                ``rl_model_<N>_steps.zip`` + ``rl_model_vecnormalize_<N>_steps.pkl``
``best/``                       EvalCallback's ``best_model.zip`` + its ``vecnormalize.pkl``
``eval/evaluations.npz``        EvalCallback's log (deterministic; the eval env is re-seeded with seed +
                                10000 before each evaluation: the same problems every time)
``tb/``                         TensorBoard logs (when tensorboard is installed)
==============================  ===============================================================

``--resume`` takes a checkpoint zip (its ``VecNormalize`` file is found by name), a
``model.zip`` or a run directory, and continues counting timesteps
(``reset_num_timesteps=False``); ``--timesteps`` is then the number of *additional* steps
(default: what is left of the configured ``n_timesteps``). Without ``--out`` a run resumed from
a run directory's files goes on in that directory. A resumed run that writes into a directory
holding a run's files (in place, or an ``--out`` used before) keeps them: ``train_info.json``'s
record goes under ``previous_runs``, the new evaluations are appended to ``eval/evaluations.npz``,
and ``best/best_model.zip`` is replaced only by an evaluation better than the best there.
"""
from __future__ import annotations

import argparse
import copy
import json
import platform
import re
import sys
import time
import warnings
from pathlib import Path
from typing import Optional

from . import ALGOS, EVAL_ENV_SEED_OFFSET, FAMILIES

CONFIG_DIR = Path(__file__).resolve().parent / "configs"
CONFIG_KEYS = {"n_envs", "n_timesteps", "policy", "policy_kwargs", "hyperparameters", "normalize",
               "env_kwargs", "eval", "checkpoint", "bc", "shield", "capture"}
DEFAULTS = {"policy": "MlpPolicy", "policy_kwargs": {}, "hyperparameters": {}, "normalize": {"norm_obs": True,
            "norm_reward": False}, "env_kwargs": {}, "eval": {"eval_freq": 50000, "n_eval_episodes": 50},
            "checkpoint": {"save_freq": 100000}, "bc": {}, "shield": None, "capture": None}
_ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU", "gelu": "GELU",
                "silu": "SiLU"}


# --------------------------------------------------------------------------- configuration
def default_config_path(algo: str) -> Path:
    return CONFIG_DIR / f"{algo}.yaml"


def load_config(algo: str, family: str, path=None) -> dict:
    """The entry ``family`` of the YAML file ``path`` (default: ``configs/<algo>.yaml``), with defaults."""
    import yaml

    if algo not in ALGOS:
        raise ValueError(f"--algo: expected one of {', '.join(ALGOS)}, got {algo!r}")
    path = Path(path) if path is not None else default_config_path(algo)
    if not path.exists():
        raise FileNotFoundError(f"config file {path} not found")
    with open(path) as f:
        data = yaml.safe_load(f) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping of task family -> settings")
    if family not in data:
        raise ValueError(f"{path}: no entry for family {family!r} (entries: {', '.join(map(str, data)) or 'none'})")
    entry = data[family] or {}
    unknown = set(entry) - CONFIG_KEYS
    if unknown:
        raise ValueError(f"{path}: entry {family!r}: unknown key(s) {sorted(unknown)}; known: {sorted(CONFIG_KEYS)}")
    cfg = copy.deepcopy(DEFAULTS)
    cfg.update(copy.deepcopy(entry))
    cfg.setdefault("n_envs", 1)
    cfg.setdefault("n_timesteps", 100000)
    try:   # the shipped files: a path relative to the repository root
        shown = str(path.resolve().relative_to(CONFIG_DIR.parents[2]))
    except ValueError:
        shown = str(path)
    cfg["algo"], cfg["family"], cfg["config_file"] = algo, family, shown
    return cfg


def apply_overrides(cfg: dict, items) -> dict:
    """``KEY.SUB=VALUE`` overrides (VALUE parsed as YAML), e.g. ``hyperparameters.learning_rate=1e-4``."""
    import yaml

    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--set: expected KEY=VALUE, got {item!r}")
        node = cfg
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ValueError(f"--set: {key!r}: {p!r} is not a mapping")
        node[parts[-1]] = yaml.safe_load(value)
    return cfg


def _schedule(value):
    """rl-zoo's ``"lin_X"``: linear decay from X to 0 over training."""
    if isinstance(value, str) and value.startswith("lin_"):
        x0 = float(value[4:])
        return lambda progress_remaining: progress_remaining * x0
    return value


def policy_kwargs_from(cfg: dict) -> dict:
    import torch.nn as nn

    kw = copy.deepcopy(cfg.get("policy_kwargs") or {})
    act = kw.get("activation_fn")
    if isinstance(act, str):
        name = _ACTIVATIONS.get(act.lower())
        if name is None:
            raise ValueError(f"policy_kwargs.activation_fn: unknown {act!r}; known: {sorted(_ACTIVATIONS)}")
        kw["activation_fn"] = getattr(nn, name)
    if "features_extractor_class" in kw and kw["features_extractor_class"] is None:
        del kw["features_extractor_class"]            # null: SB3's default (the flattened observation)
    fx = kw.get("features_extractor_class")
    if isinstance(fx, str):
        from .features import EXTRACTORS
        if fx not in EXTRACTORS:
            raise ValueError(f"policy_kwargs.features_extractor_class: unknown {fx!r}; known: {sorted(EXTRACTORS)}")
        kw["features_extractor_class"] = EXTRACTORS[fx]
    return kw


def hyperparameters_from(cfg: dict) -> dict:
    hp = copy.deepcopy(cfg.get("hyperparameters") or {})
    for k in ("learning_rate", "clip_range", "clip_range_vf"):
        if k in hp:
            hp[k] = _schedule(hp[k])
    for k in ("policy", "env", "policy_kwargs", "seed", "tensorboard_log"):
        if k in hp:
            raise ValueError(f"hyperparameters.{k}: set it with its own key, not in hyperparameters")
    return hp


# --------------------------------------------------------------------------- environments
def make_env_kwargs(cfg: dict) -> dict:
    kw = dict(cfg.get("env_kwargs") or {})
    kw.setdefault("task_distribution", cfg["family"])
    return kw


def shield_kwargs(cfg: dict) -> Optional[dict]:
    """The ``ConeShield`` arguments of a config's ``shield`` entry; None without a shield.

    ``shield: null`` or ``false``: none; ``true`` or ``{}``: the filter's defaults; a mapping:
    ``ConeShield`` arguments (``margin_deg``, ``barrier_rate``, ``brake``, ``sweeps``, ``gap_deg``).
    """
    sh = cfg.get("shield")
    if sh is None or sh is False:
        return None
    if sh is True:
        return {}
    if not isinstance(sh, dict):
        raise ValueError(f"shield: expected null, true/false or a mapping of ConeShield arguments, got {sh!r}")
    from slew_env.shield import ConeShieldFilter
    try:
        ConeShieldFilter(**sh)
    except TypeError as exc:
        raise ValueError(f"shield: {exc}; known: margin_deg, barrier_rate, brake, sweeps, gap_deg") from None
    except ValueError as exc:
        raise ValueError(f"shield.{exc}") from None
    return dict(sh)


def capture_kwargs(cfg: dict) -> Optional[dict]:
    """The ``CaptureHandover`` arguments of a config's ``capture`` entry (``training.rl.capture``); None without."""
    c = cfg.get("capture")
    if c is None or c is False:
        return None
    from .capture import check
    return check({} if c is True else c)


def wrap_controller(env, shield: Optional[dict] = None, capture: Optional[dict] = None):
    """``env`` as the policy flies it: ``CaptureHandover(ConeShield(env))``, each only when configured
    (the capture law's actions pass through the cone filter too)."""
    if shield is not None:
        from slew_env.shield import ConeShield
        env = ConeShield(env, **shield)
    if capture is not None:
        from .capture import CaptureHandover
        env = CaptureHandover(env, **capture)
    return env


def make_vec(cfg: dict, n_envs: int, seed: int, vec_env: str = "dummy"):
    """``make_vec_env`` of Slew-v0 (Monitor-wrapped, copy i seeded with ``seed + i``; wrapped in
    ``ConeShield`` / ``CaptureHandover`` when the config has a ``shield`` / ``capture``)."""
    import slew_env  # noqa: F401  (registers Slew-v0)
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if vec_env not in ("dummy", "subproc"):
        raise ValueError(f"--vec-env: expected dummy or subproc, got {vec_env!r}")
    cls = SubprocVecEnv if vec_env == "subproc" and n_envs > 1 else DummyVecEnv
    # "module:id" makes gymnasium import slew_env (which registers Slew-v0) in SubprocVecEnv workers too
    shield, capture = shield_kwargs(cfg), capture_kwargs(cfg)
    wrap = {}
    if shield is not None or capture is not None:
        wrap = {"wrapper_class": wrap_controller, "wrapper_kwargs": {"shield": shield, "capture": capture}}
    return make_vec_env(f"slew_env:{slew_env.ENV_ID}", n_envs=n_envs, seed=seed, vec_env_cls=cls,
                        env_kwargs=make_env_kwargs(cfg), monitor_kwargs={"info_keywords": ("is_success",)}, **wrap)


def normalize_kwargs(cfg: dict) -> Optional[dict]:
    norm = cfg.get("normalize")
    if norm in (None, False):
        return None
    if norm is True:
        return {}
    return dict(norm)


# VecNormalize settings a resume takes from the run's config (its statistics come from the file);
# norm_obs / norm_reward stay as saved: switching them mid-run would feed the policy another scale
RESUMED_NORMALIZE_SETTINGS = ("gamma", "clip_obs", "clip_reward", "epsilon")


def resume_normalize_settings(vn, cfg: dict, gamma: float) -> None:
    """Give a loaded ``VecNormalize`` the settings the resumed run's config records: the reward
    discount is the model's ``gamma`` (or ``normalize.gamma``), as ``wrap_normalize`` gives a new
    run. ``VecNormalize.load`` keeps the saved ones, so a ``--set hyperparameters.gamma`` on resume
    changed the agent's discount but not the one its rewards were scaled with."""
    kw = dict(normalize_kwargs(cfg) or {})
    kw.setdefault("gamma", gamma)
    for key in RESUMED_NORMALIZE_SETTINGS:
        if key in kw:
            setattr(vn, key, float(kw[key]))


def wrap_normalize(venv, cfg: dict, gamma: float, training=True):
    from stable_baselines3.common.vec_env import VecNormalize

    kw = normalize_kwargs(cfg)
    if kw is None:
        return venv
    kw.setdefault("gamma", gamma)
    if not training:
        kw.update(training=False, norm_reward=False)
    return VecNormalize(venv, **kw)


# --------------------------------------------------------------------------- callbacks
def _eval_callback_class():
    from stable_baselines3.common.callbacks import EvalCallback

    class SeededEvalCallback(EvalCallback):
        """``EvalCallback`` whose environment is re-seeded with ``eval_seed`` before each
        evaluation: every evaluation flies the same problems, so ``best/`` compares the policy's
        scores on one sample, not on a new draw each time. ``history`` (``earlier_evaluations``):
        a resumed run's earlier evaluations, which ``evaluations.npz`` goes on from, and the
        best mean reward ``best/best_model.zip`` holds, which a new evaluation must beat."""

        def __init__(self, eval_env, eval_seed: int, history: Optional[dict] = None, **kwargs):
            super().__init__(eval_env, **kwargs)
            self.eval_seed = int(eval_seed)
            if history:
                self.evaluations_timesteps = list(history["timesteps"])
                self.evaluations_results = list(history["results"])
                self.evaluations_length = list(history["ep_lengths"])
                self.evaluations_successes = list(history["successes"])
                self.best_mean_reward = float(history["best_mean_reward"])

        def _on_step(self):
            if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                self.eval_env.seed(self.eval_seed)     # taken by the reset evaluate_policy begins with
            return super()._on_step()

    return SeededEvalCallback


EVAL_KEYS = ("timesteps", "results", "ep_lengths", "successes")     # what EvalCallback saves


def earlier_evaluations(out: Path, n_eval_episodes: int, steps_before: Optional[int] = None) -> Optional[dict]:
    """What a run resumed into ``out`` goes on from: the lists of ``out/eval/evaluations.npz``
    (``timesteps``, ``results``, ``ep_lengths``, ``successes``: all that ``EvalCallback`` saves)
    and ``best_mean_reward``, the best earlier mean reward if ``best/best_model.zip`` is there
    (else -inf); None without earlier evaluations.

    Evaluations of another ``n_eval_episodes`` cannot share the file's arrays: that file is
    kept as ``evaluations_until_<N>_steps.npz`` (N its last evaluation) and the new file starts
    afresh; the best mean reward still guards ``best/``.

    A run resumed from a checkpoint older than the last evaluation (``steps_before``, the
    checkpoint's timesteps) goes on from that checkpoint: the evaluations past it belong to the
    training it leaves, and are kept in ``evaluations_beyond_<steps_before>_steps.npz``, not mixed
    into the file's history out of order; ``best/`` still holds the best model of either.
    """
    import numpy as np

    path = out / "eval" / "evaluations.npz"
    if not path.exists():
        return None
    with np.load(path) as f:
        old = {k: f[k].tolist() for k in f.files}
    hist = {k: old.get(k) or [] for k in EVAL_KEYS}
    hist["best_mean_reward"] = -np.inf
    if hist["results"] and (out / "best" / "best_model.zip").exists():
        hist["best_mean_reward"] = max(float(np.mean(r)) for r in hist["results"])
    later = [i for i, t in enumerate(hist["timesteps"]) if steps_before is not None and t > steps_before]
    if later:
        keep = path.with_name(f"evaluations_beyond_{steps_before}_steps.npz")
        # (the arrays of each evaluation: those EvalCallback saved, one entry per evaluation)
        per_eval = [k for k in EVAL_KEYS if len(hist[k]) == len(hist["timesteps"])]
        np.savez(keep, **{k: np.asarray([hist[k][i] for i in later]) for k in per_eval})
        warnings.warn(f"eval: resumed from {steps_before} steps, before {len(later)} of the run's evaluations; "
                      f"those are kept in {keep}, and {path} goes on from the checkpoint")
        for k in per_eval:
            hist[k] = [v for i, v in enumerate(hist[k]) if i not in later]
    widths = {len(r) for key in ("results", "ep_lengths", "successes") for r in hist[key]}
    if widths - {int(n_eval_episodes)}:
        keep = path.with_name(f"evaluations_until_{hist['timesteps'][-1] if hist['timesteps'] else 0}_steps.npz")
        path.replace(keep)
        warnings.warn(f"eval: the earlier evaluations have {sorted(widths)} episodes, not n_eval_episodes="
                      f"{n_eval_episodes}; they are kept in {keep} and {path} starts afresh")
        hist.update({k: [] for k in EVAL_KEYS})
    return hist


def _callbacks(cfg, out: Path, eval_env, n_envs, progress_fallback, eval_seed: int,
               eval_history: Optional[dict] = None):
    from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback

    class SaveVecNormalizeOnBest(BaseCallback):
        """Child of EvalCallback: store the VecNormalize statistics next to ``best_model.zip``."""

        def __init__(self, path):
            super().__init__()
            self.path = path

        def _on_step(self):
            vn = self.model.get_vec_normalize_env()
            if vn is not None:
                vn.save(str(self.path))
            return True

    cbs = []
    ck = cfg.get("checkpoint") or {}
    if ck.get("save_freq", 0) > 0:
        cbs.append(CheckpointCallback(save_freq=max(int(ck["save_freq"]) // n_envs, 1),
                                      save_path=str(out / "checkpoints"), name_prefix="rl_model",
                                      save_vecnormalize=True,
                                      save_replay_buffer=bool(ck.get("save_replay_buffer", False))))
    ev = cfg.get("eval") or {}
    if eval_env is not None and ev.get("eval_freq", 0) > 0:
        (out / "best").mkdir(parents=True, exist_ok=True)
        cbs.append(_eval_callback_class()(
            eval_env, eval_seed, eval_history, n_eval_episodes=int(ev.get("n_eval_episodes", 20)),
            eval_freq=max(int(ev["eval_freq"]) // n_envs, 1), deterministic=True,
            best_model_save_path=str(out / "best"), log_path=str(out / "eval"),
            callback_on_new_best=SaveVecNormalizeOnBest(out / "best" / "vecnormalize.pkl"), verbose=0))
    if progress_fallback:
        cbs.append(_TqdmProgress())
    return CallbackList(cbs)


def _tqdm_progress_class():
    from stable_baselines3.common.callbacks import BaseCallback

    class TqdmProgress(BaseCallback):
        """``progress_bar=True`` without ``rich``: a tqdm bar over this run's timesteps."""

        def _on_training_start(self):
            from tqdm import tqdm
            total = self.locals["total_timesteps"] - self.model.num_timesteps
            self.bar = tqdm(total=total, unit="step", desc="train-rl", dynamic_ncols=True)

        def _on_step(self):
            self.bar.update(self.training_env.num_envs)
            return True

        def _on_training_end(self):
            self.bar.close()

    return TqdmProgress


def _TqdmProgress():
    return _tqdm_progress_class()()


def _rich_available():
    try:
        import rich  # noqa: F401
        import tqdm  # noqa: F401
        return True
    except ImportError:
        return False


def tensorboard_dir(out: Path):
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        warnings.warn("tensorboard is not installed: no TensorBoard logs (pip install tensorboard)")
        return None
    return str(out / "tb")


# --------------------------------------------------------------------------- resume
def find_checkpoint_files(resume) -> tuple[Path, Optional[Path], Optional[Path], Optional[Path]]:
    """``(model zip, vecnormalize pkl or None, replay buffer pkl or None, run dir or None)`` of ``resume``.

    ``resume``: a run directory (``model.zip``), a ``model.zip``/``best_model.zip`` (its
    ``vecnormalize.pkl`` beside it) or a checkpoint ``rl_model_<N>_steps.zip``
    (``rl_model_vecnormalize_<N>_steps.pkl`` beside it).
    """
    p = Path(resume)
    if p.is_dir():
        p = p / "model.zip"
    if not p.exists() and p.with_suffix(".zip").exists():
        p = p.with_suffix(".zip")
    if not p.exists():
        raise FileNotFoundError(f"--resume: no checkpoint {p}")
    m = re.fullmatch(r"(.*)_(\d+)_steps\.zip", p.name)
    replay = None
    if m:
        vn = p.with_name(f"{m.group(1)}_vecnormalize_{m.group(2)}_steps.pkl")
        rb = p.with_name(f"{m.group(1)}_replay_buffer_{m.group(2)}_steps.pkl")
        replay = rb if rb.exists() else None
        run_dir = p.parent.parent
    else:
        vn = p.with_name("vecnormalize.pkl")
        run_dir = p.parent.parent if p.parent.name == "best" else p.parent
    return p, (vn if vn.exists() else None), replay, (run_dir if (run_dir / "config.yaml").exists() else None)


# --------------------------------------------------------------------------- versions
def versions() -> dict:
    import gymnasium
    import numpy
    import stable_baselines3
    import torch

    from training.generate import solver_version

    pkg, commit = solver_version()
    return {"python": platform.python_version(), "numpy": numpy.__version__, "torch": torch.__version__,
            "stable_baselines3": stable_baselines3.__version__, "gymnasium": gymnasium.__version__,
            "slewopt": pkg, "commit": commit}


def _algo_class(algo):
    from stable_baselines3 import PPO, SAC
    return {"ppo": PPO, "sac": SAC}[algo]


def save_yaml(obj, path):
    import yaml
    with open(path, "w") as f:
        yaml.safe_dump(obj, f, sort_keys=False)


# --------------------------------------------------------------------------- training
def train(algo: str, family: str, config=None, timesteps: Optional[int] = None, n_envs: Optional[int] = None,
          seed: Optional[int] = None, out=None, resume=None, bc_pretrain: int = 0, progress_bar: bool = False,
          vec_env: str = "dummy", overrides=None, verbose: int = 0, expert_data=None, bc_seed: Optional[int] = None,
          solver_workers: int = 1, command: Optional[str] = None, threads: Optional[int] = 1) -> dict:
    """Train (or resume) a policy; returns the ``train_info`` dict also written to ``out/train_info.json``.

    ``timesteps``: steps to train (resume: additional steps; default: the config's
    ``n_timesteps``, less what the checkpoint already did). ``bc_pretrain``: number of
    expert episodes (problems solved by ``solvers.solve``) for behaviour cloning before RL
    (``training.rl.bc.pretrain``); 0 for none. ``overrides``: ``KEY=VALUE`` strings
    applied to the config. ``threads``: torch CPU threads (default 1: on a small shared
    machine more threads make PPO/SAC several times *slower*; None leaves torch's default).
    """
    import numpy as np
    import torch
    from stable_baselines3.common.utils import set_random_seed
    from stable_baselines3.common.vec_env import VecNormalize

    if threads is not None:
        if threads < 1:
            raise ValueError(f"--threads: must be >= 1, got {threads}")
        torch.set_num_threads(int(threads))
    if family not in FAMILIES:
        raise ValueError(f"--family: expected one of {', '.join(FAMILIES)}, got {family!r}")
    resume_files = find_checkpoint_files(resume) if resume else None
    if config is None and resume_files and resume_files[3] is not None:
        import yaml
        with open(resume_files[3] / "config.yaml") as f:
            cfg = yaml.safe_load(f)
        if cfg.get("algo") != algo or cfg.get("family") != family:
            raise ValueError(f"--resume: the checkpoint's run is {cfg.get('algo')} on {cfg.get('family')}, "
                             f"not {algo} on {family}")
        if seed is None:
            seed = int(cfg.get("seed", 0))
    else:
        cfg = load_config(algo, family, config)
    apply_overrides(cfg, overrides)
    if n_envs is not None:
        if n_envs < 1:
            raise ValueError(f"--n-envs: must be >= 1, got {n_envs}")
        cfg["n_envs"] = int(n_envs)
    if timesteps is not None and timesteps < 0:
        raise ValueError(f"--timesteps: must be >= 0, got {timesteps}")
    if bc_pretrain and bc_pretrain < 0:
        raise ValueError(f"--bc-pretrain: must be >= 0, got {bc_pretrain}")
    seed = 0 if seed is None else int(seed)
    cfg["seed"] = seed
    n = int(cfg["n_envs"])
    if out is None and resume_files and resume_files[3] is not None:
        # a resumed run goes on in its own directory, where its train_info.json and curves are
        # (it had gone to runs/ALGO-FAMILY-seedN, with no previous_runs)
        out = resume_files[3]
    out = Path(out) if out is not None else Path("runs") / f"{algo}-{family}-seed{seed}"
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    set_random_seed(seed)

    hp = hyperparameters_from(cfg)
    gamma = float(hp.get("gamma", 0.99))
    venv = wrap_normalize(make_vec(cfg, n, seed, vec_env), cfg, gamma)
    eval_env = None
    if (cfg.get("eval") or {}).get("eval_freq", 0) > 0:
        eval_env = wrap_normalize(make_vec(cfg, 1, seed + EVAL_ENV_SEED_OFFSET), cfg, gamma, training=False)
    tb = tensorboard_dir(out)
    cls = _algo_class(algo)
    steps_before = 0
    bc_info = None
    if resume_files:
        model_path, vn_path, replay_path, _ = resume_files
        if isinstance(venv, VecNormalize):
            if vn_path is None:
                raise FileNotFoundError(f"--resume: no VecNormalize statistics next to {model_path}")
            venv = VecNormalize.load(str(vn_path), venv.venv)
            venv.training = not cfg.get("normalize_frozen", False)
            resume_normalize_settings(venv, cfg, gamma)
        # hyperparameters changed with --set on this resume run as config.yaml records them (SB3's
        # load keeps the saved ones unless given; the others are the saved run's own)
        asked = {item.partition("=")[0].split(".")[1] for item in overrides or []
                 if item.partition("=")[0].startswith("hyperparameters.")}      # (a nested key: its top)
        model = cls.load(str(model_path), env=venv, tensorboard_log=tb, device="cpu",
                         **{k: v for k, v in hp.items() if k in asked})
        if replay_path is not None and hasattr(model, "load_replay_buffer"):
            model.load_replay_buffer(str(replay_path))
        steps_before = int(model.num_timesteps)
        if timesteps is None:
            timesteps = max(int(cfg["n_timesteps"]) - steps_before, 0)
    else:
        model = cls(cfg.get("policy", "MlpPolicy"), venv, policy_kwargs=policy_kwargs_from(cfg), seed=seed,
                    tensorboard_log=tb, verbose=verbose, device="cpu", **hp)
        if timesteps is None:
            timesteps = int(cfg["n_timesteps"])
        if bc_pretrain:
            from .bc import pretrain
            bc_cfg = dict(cfg.get("bc") or {})
            freeze = bool(bc_cfg.pop("freeze_normalization", True))
            bc_info = pretrain(model, family, int(bc_pretrain), env_kwargs=cfg.get("env_kwargs") or {},
                               bc_cfg=bc_cfg, seed=bc_seed, expert_data=expert_data,
                               workers=solver_workers, verbose=verbose)
            if "rl_learning_rate" in bc_info:
                # the cloning replaced the model's learning rate for the RL phase: record the one
                # that runs, not the one the config file gave (bc.rl_learning_rate says where from)
                cfg["hyperparameters"] = dict(cfg.get("hyperparameters") or {})
                cfg["hyperparameters"]["learning_rate"] = bc_info["rl_learning_rate"]
            if freeze and isinstance(venv, VecNormalize):
                # the cloned policy reads observations normalised with the expert data's statistics;
                # letting RL's own (at first very different) states move them breaks it
                venv.training = False
                cfg["normalize_frozen"] = True
    cfg["n_timesteps_run"] = int(timesteps)
    save_yaml(cfg, out / "config.yaml")

    use_rich = progress_bar and _rich_available()
    history = None
    if resume_files and eval_env is not None:
        # resumed into a directory with evaluations (its own, in place): append to them, and
        # replace best/ only with a better evaluation
        history = earlier_evaluations(out, int((cfg.get("eval") or {}).get("n_eval_episodes", 20)), steps_before)
    callbacks = _callbacks(cfg, out, eval_env, n, progress_bar and not use_rich, seed + EVAL_ENV_SEED_OFFSET,
                           history)
    if bc_info and bc_info.get("actor_warmup"):
        from .bc import actor_warmup_callback
        callbacks.callbacks.append(actor_warmup_callback(bc_info["actor_warmup"]))
    t_learn = time.perf_counter()
    if timesteps > 0:
        model.learn(total_timesteps=int(timesteps), callback=callbacks, reset_num_timesteps=not resume_files,
                    tb_log_name=f"{algo}", progress_bar=use_rich)
    learn_time = time.perf_counter() - t_learn
    model.save(str(out / "model.zip"))
    if isinstance(model.get_vec_normalize_env(), VecNormalize):
        model.get_vec_normalize_env().save(str(out / "vecnormalize.pkl"))
    info = {
        "algo": algo, "family": family, "seed": seed, "num_timesteps": int(model.num_timesteps),
        "timesteps_this_run": int(model.num_timesteps) - steps_before, "resumed_from": str(resume) if resume else None,
        "steps_before": steps_before, "n_envs": n, "vec_env": vec_env,
        "wall_time_s": time.perf_counter() - t_start, "learn_time_s": learn_time,
        "cpu_threads": torch.get_num_threads(), "bc": bc_info, "command": command,
        "versions": versions(), "out": str(out),
    }
    if eval_env is not None and (out / "eval" / "evaluations.npz").exists():
        ev = np.load(out / "eval" / "evaluations.npz")
        info["eval_last"] = {"timesteps": int(ev["timesteps"][-1]), "mean_reward": float(ev["results"][-1].mean()),
                             "success_rate": float(ev["successes"][-1].mean()) if "successes" in ev and
                             len(ev["successes"]) else None}
    prev = out / "train_info.json"
    if resume_files and prev.exists():
        try:
            info["previous_runs"] = [json.loads(prev.read_text())]
        except ValueError:
            pass
    prev.write_text(json.dumps(info, indent=2))
    venv.close()
    if eval_env is not None:
        eval_env.close()
    return info


# --------------------------------------------------------------------------- command line
def add_arguments(p: argparse.ArgumentParser):
    p.add_argument("--algo", required=True, choices=ALGOS, help="ppo or sac")
    p.add_argument("--family", required=True, choices=FAMILIES, help="task family of the environment")
    p.add_argument("--config", metavar="YAML", help="hyperparameter file (default training/rl/configs/<algo>.yaml)")
    p.add_argument("--timesteps", type=int, metavar="N",
                   help="environment steps (default: the config's n_timesteps; with --resume: steps to add, "
                        "default what is left of n_timesteps)")
    p.add_argument("--n-envs", type=int, metavar="N", help="vectorised copies (default: the config's)")
    p.add_argument("--seed", type=int, metavar="S",
                   help="seed (default 0, or the resumed run's); the eval env uses S + 10000")
    p.add_argument("--out", metavar="DIR", help="run directory (default runs/<algo>-<family>-seed<S>)")
    p.add_argument("--resume", metavar="CHECKPOINT",
                   help="continue from a checkpoint zip, a model.zip or a run directory (VecNormalize loaded too)")
    p.add_argument("--bc-pretrain", type=int, default=0, metavar="N_EPISODES",
                   help="behaviour-clone the solvers' optimal controls on N expert problems before RL")
    p.add_argument("--expert-data", metavar="FILE.jsonl",
                   help="solutions of the expert problems (a 'slew generate' dataset; created or continued; "
                        "default runs/solutions/<family>-seed<bc seed>.jsonl)")
    p.add_argument("--bc-seed", type=int, metavar="S", help="seed of the expert problems (default 1)")
    p.add_argument("--solver-workers", type=int, default=1, metavar="N",
                   help="processes solving expert problems not yet in --expert-data (default 1)")
    p.add_argument("--progress-bar", action="store_true", help="show a progress bar")
    p.add_argument("--threads", type=int, default=1, metavar="N",
                   help="torch CPU threads (default 1; more is slower on a small shared machine)")
    p.add_argument("--vec-env", default="dummy", choices=("dummy", "subproc"), help="DummyVecEnv or SubprocVecEnv")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, e.g. --set hyperparameters.learning_rate=1e-4 (repeatable)")
    p.add_argument("-v", "--verbose", type=int, default=0, help="SB3 verbosity (0, 1, 2)")


def run(args) -> int:
    info = train(args.algo, args.family, config=args.config, timesteps=args.timesteps, n_envs=args.n_envs,
                 seed=args.seed, out=args.out, resume=args.resume, bc_pretrain=args.bc_pretrain,
                 progress_bar=args.progress_bar, vec_env=args.vec_env, overrides=args.set, verbose=args.verbose,
                 expert_data=args.expert_data, bc_seed=args.bc_seed, solver_workers=args.solver_workers,
                 command=" ".join(sys.argv), threads=args.threads)
    ev = info.get("eval_last")
    extra = ""
    if ev:
        sr = ev.get("success_rate")
        extra = f", last eval: reward {ev['mean_reward']:.3f}" + (f", success {100 * sr:.0f}%" if sr is not None else "")
    print(f"{info['algo']} on {info['family']}: {info['num_timesteps']} steps "
          f"({info['timesteps_this_run']} this run) in {info['wall_time_s']:.1f} s{extra}; saved to {info['out']}")
    return 0


def main(argv=None) -> int:
    """``python -m training.rl.train`` is ``slew train-rl`` (same options, same error handling)."""
    from training.cli import main as slew
    return slew(["train-rl", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
