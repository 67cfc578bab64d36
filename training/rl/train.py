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
and ``best/best_model.zip`` is replaced only by an evaluation better than the best there. A run
directory given to ``--resume`` is resumed from its newest model (``newest_in_run``).

Without ``--resume``, an ``--out`` that already holds a run is refused (a new run had overwritten it).
Every setting is checked before anything is built or written (``check_config``), and a failed
start leaves no directory behind. Ctrl-C or SIGTERM stops training at the next step, saves
``model.zip``, ``vecnormalize.pkl`` and ``train_info.json`` there, and exits 130 / 143 with one
line giving the ``--resume`` command that continues it.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shlex
import shutil
import signal
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Optional

from slew_env.checks import is_real

from . import ALGOS, EVAL_ENV_SEED_OFFSET, FAMILIES

# the configuration (the YAML files, --set, the checks of every setting)
from .config import (_algo_class, apply_overrides, check_config, hyperparameters_from, load_config,
                     policy_kwargs_from, read_yaml)

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


def _subproc_wrapper(env, shield=None, capture=None):
    """A ``SubprocVecEnv`` copy: Ctrl-C ignored in the worker (``_ignore_sigint_in_workers``), then
    ``wrap_controller``."""
    return wrap_controller(_ignore_sigint_in_workers(env), shield, capture)


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
    if cls is SubprocVecEnv:
        wrap = {"wrapper_class": _subproc_wrapper, "wrapper_kwargs": {"shield": shield, "capture": capture}}
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
def _zip_timesteps(path: Path) -> Optional[int]:
    """``num_timesteps`` recorded in an SB3 model zip (its ``data`` JSON), None if unreadable."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            return int(json.loads(z.read("data"))["num_timesteps"])
    except (OSError, KeyError, ValueError, TypeError, zipfile.BadZipFile):
        return None


def _checkpoint_steps(path: Path) -> Optional[int]:
    m = re.fullmatch(r"rl_model_(\d+)_steps\.zip", path.name)
    return int(m.group(1)) if m else None


def newest_in_run(run: Path) -> Path:
    """The model a run directory is resumed from: the most recently written of ``model.zip`` and
    ``checkpoints/rl_model_<N>_steps.zip`` (``model.zip`` on a tie). A run killed before its end
    (SIGKILL, a crash) has checkpoints but no ``model.zip``, or a ``model.zip`` older than them (a
    resumed run killed in place). Not the largest step count: a run resumed in place from an
    older checkpoint leaves the abandoned line's later checkpoints behind (a review)."""
    found = []
    model = run / "model.zip"
    if model.exists():
        found.append((model.stat().st_mtime, 1, model))
    ck = run / "checkpoints"
    for p in (sorted(ck.glob("rl_model_*_steps.zip")) if ck.is_dir() else []):
        if _checkpoint_steps(p) is not None:
            found.append((p.stat().st_mtime, 0, p))
    if not found:
        raise FileNotFoundError(f"--resume: {run} holds no model.zip and no checkpoints/rl_model_<N>_steps.zip")
    return max(found)[2]


def find_checkpoint_files(resume) -> tuple[Path, Optional[Path], Optional[Path], Optional[Path]]:
    """``(model zip, vecnormalize pkl or None, replay buffer pkl or None, run dir or None)`` of ``resume``.

    ``resume``: a run directory (its newest model: ``newest_in_run``), a ``model.zip``/``best_model.zip``
    (its ``vecnormalize.pkl`` beside it) or a checkpoint ``rl_model_<N>_steps.zip``
    (``rl_model_vecnormalize_<N>_steps.pkl`` beside it).
    """
    p = Path(resume)
    if p.is_dir():
        p = newest_in_run(p)
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
        if p.name == "model.zip" and (p.parent / "replay_buffer.pkl").exists():   # (saved at an interrupt)
            replay = p.parent / "replay_buffer.pkl"
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


def save_yaml(obj, path):
    import yaml
    with open(path, "w") as f:
        yaml.safe_dump(obj, f, sort_keys=False)


# --------------------------------------------------------------------------- the run directory
# files that make a directory hold a run: a fresh run would overwrite them (the final model, its
# statistics, the record, the best model, the evaluation log) or mix its checkpoints with them
RUN_MARKERS = ("model.zip", "vecnormalize.pkl", "train_info.json", "best/best_model.zip", "eval/evaluations.npz")


def run_files(out: Path) -> list:
    """The files of an earlier run in ``out`` (``RUN_MARKERS`` and ``checkpoints/``)."""
    if not out.is_dir():
        return []
    found = [m for m in RUN_MARKERS if (out / m).exists()]
    if (out / "checkpoints").is_dir() and any((out / "checkpoints").glob("rl_model_*")):
        found.append("checkpoints/")
    return found


def check_out(out: Path, fresh: bool, given: bool) -> Optional[Path]:
    """Refuse an ``--out`` a run cannot go to, before anything is built; returns ``out`` if it does
    not exist yet (removed again if the start fails: no empty run directory left behind), or None.
    Only ``out`` itself: its missing parents, once made, may hold other runs by the time this one
    fails (a review: a failed start into runs/sweep/a had removed runs/sweep, and with it the
    run training into runs/sweep/b).

    ``fresh`` (no ``--resume``): an ``out`` holding a run is refused. A new run wrote its
    ``model.zip``, ``best/``, ``eval/evaluations.npz`` and ``train_info.json`` over the old
    run's and left the old run's later checkpoints among its own; ``--resume`` continues a run.
    """
    name = "--out" if given else f"--out (default {out})"
    if out.exists() and not out.is_dir():
        raise ValueError(f"{name}: {out} exists and is not a directory")
    if fresh:
        found = run_files(out)
        if found:
            raise ValueError(f"{name}: {out} already holds a run ({', '.join(found)}); a new run would overwrite "
                             f"it: continue it with --resume {out}, or choose another --out")
    parent = out
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"{name}: cannot create {out}: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ValueError(f"{name}: cannot write in {parent}")
    return None if out.exists() else out


# --------------------------------------------------------------------------- Ctrl-C / SIGTERM
class TrainingInterrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM stopped ``train``, which saved the run where it stopped first: ``info`` is
    the ``train_info`` written, ``signum`` the signal. A ``KeyboardInterrupt``, so that a script
    running several trainings stops as on Ctrl-C rather than going on to the next one."""

    def __init__(self, info: dict, signum: int):
        super().__init__(info, signum)
        self.info, self.signum = info, signum


class SignalInterrupt(KeyboardInterrupt):
    """A second SIGINT / SIGTERM that would not wait for the save: ``signum`` gives the exit
    status (128 + signal) a shell expects of that signal."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


class _SignalStop:
    """SIGINT / SIGTERM while training: the first asks ``learn`` to stop at the next environment step
    (``callback``, which returns False), so that the model can be saved whole; a second one raises
    ``KeyboardInterrupt`` at once (the user will not wait for the step to end), except during the
    save (``hold``), which it must not cut. Main thread only (only there can handlers be set)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.signum, self._old, self._holding = None, {}, False

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for s in self.SIGNALS:
                self._old[s] = signal.signal(s, self._handle)
        return self

    def __exit__(self, *exc):
        for s, h in self._old.items():
            signal.signal(s, signal.SIG_DFL if h is None else h)
        return False

    def _handle(self, signum, frame):
        if self.signum is None:
            self.signum = signum
        elif not self._holding:
            raise SignalInterrupt(signum)

    def hold(self):
        self._holding = True

    def callback(self):
        from stable_baselines3.common.callbacks import BaseCallback

        stop = self

        class StopOnSignal(BaseCallback):
            def _on_step(self):
                return stop.signum is None

        return StopOnSignal()


def _ignore_sigint_in_workers(env):
    """``wrapper_class`` of ``SubprocVecEnv`` copies: a Ctrl-C at a terminal (or a SIGTERM) goes to the whole
    process group, and a worker it killed left the parent nothing to step, and no model to save.
    The parent stops them when it has saved (a worker also ends when its pipe closes)."""
    import multiprocessing
    if multiprocessing.parent_process() is not None:
        # (SIGTERM too: timeout, scancel and kill -TERM -PGID signal the whole group, and a worker
        # it killed had left the parent nothing to save from; a worker still ends with its pipe)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return env


def _atomic_save(save, path: Path):
    """``save(tmp)`` then rename over ``path``: a kill during the save leaves the old file whole."""
    tmp = path.with_name(path.stem + ".partial" + path.suffix)
    save(str(tmp))
    os.replace(tmp, path)


def _first_line(exc) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


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

    Every setting is checked, and ``out`` too, before anything is built or written; a start that
    fails leaves no directory behind. A fresh run refuses an ``out`` that holds a run. SIGINT or
    SIGTERM stops training at the next step and saves the run there (``model.zip``,
    ``vecnormalize.pkl``, ``train_info.json`` with ``interrupted``), then raises
    ``TrainingInterrupted``; ``--resume out`` continues it.
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
    if seed is not None and not 0 <= seed < 2 ** 32:
        raise ValueError(f"--seed: must be between 0 and 2**32 - 1, got {seed}")
    resume_files = find_checkpoint_files(resume) if resume else None
    if config is None and resume_files and resume_files[3] is not None:
        cfg = read_yaml(resume_files[3] / "config.yaml")
        if cfg.get("algo") != algo or cfg.get("family") != family:
            raise ValueError(f"--resume: the checkpoint's run is {cfg.get('algo')} on {cfg.get('family')}, "
                             f"not {algo} on {family}")
        for section, freq in (("eval", "eval_freq"), ("checkpoint", "save_freq")):
            # runs before check_config switched these off with a frequency of 0; their config.yaml
            # says so, and resuming them must not be refused for it
            sec = cfg.get(section)
            if isinstance(sec, dict) and is_real(sec.get(freq)) and sec[freq] <= 0:
                cfg[section] = None
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
    if solver_workers < 1:      # (0 had run with one worker without a word)
        raise ValueError(f"--solver-workers: must be >= 1, got {solver_workers}")
    if bc_seed is not None and bc_seed < 0:
        raise ValueError(f"--bc-seed: must be >= 0, got {bc_seed}")
    check_config(cfg, algo)
    seed = 0 if seed is None else int(seed)
    cfg["seed"] = seed
    n = int(cfg["n_envs"])
    given = out is not None
    if out is None and resume_files and resume_files[3] is not None:
        # a resumed run goes on in its own directory, where its train_info.json and curves are
        # (it had gone to runs/ALGO-FAMILY-seedN, with no previous_runs)
        out, given = resume_files[3], True
    out = Path(out) if out is not None else Path("runs") / f"{algo}-{family}-seed{seed}"
    created = check_out(out, fresh=not resume_files, given=given)
    t_start = time.perf_counter()
    venv = eval_env = None
    try:
        set_random_seed(seed)
        hp = hyperparameters_from(cfg)
        gamma = float(hp.get("gamma", 0.99))
        try:
            venv = wrap_normalize(make_vec(cfg, n, seed, vec_env), cfg, gamma)
            if (cfg.get("eval") or {}).get("eval_freq", 0) > 0:
                eval_env = wrap_normalize(make_vec(cfg, 1, seed + EVAL_ENV_SEED_OFFSET), cfg, gamma, training=False)
        except (TypeError, ValueError) as exc:
            # (a name is checked by check_config; a value by SlewEnv, whose message names the field)
            raise ValueError(f"env_kwargs: {_first_line(exc)}") from None
        tb = tensorboard_dir(out)
        cls = _algo_class(algo)
        steps_before = 0
        bc_info = None
        if resume_files:
            model_path, vn_path, replay_path, _ = resume_files
            if isinstance(venv, VecNormalize):
                if vn_path is None:
                    raise FileNotFoundError(f"--resume: no VecNormalize statistics next to {model_path}")
                try:
                    venv = VecNormalize.load(str(vn_path), venv.venv)
                except Exception as exc:     # a pickle can fail in many ways; say which file
                    raise ValueError(f"--resume: {vn_path}: not VecNormalize statistics ({_first_line(exc)})") from None
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
            try:
                model = cls(cfg.get("policy", "MlpPolicy"), venv, policy_kwargs=policy_kwargs_from(cfg), seed=seed,
                            tensorboard_log=tb, verbose=verbose, device="cpu", **hp)
            except (TypeError, ValueError, AssertionError, KeyError) as exc:
                # what check_config cannot see (a policy name, a policy_kwargs entry, a value SB3
                # checks itself): SB3's message, named as a setting, without its traceback
                raise ValueError(f"policy / policy_kwargs / hyperparameters: {_first_line(exc)}") from None
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
        out.mkdir(parents=True, exist_ok=True)
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
    except BaseException:
        for e in (venv, eval_env):
            if e is not None:
                e.close()
        if created is not None:
            # a start that failed (or was interrupted) leaves no empty or partial run directory
            shutil.rmtree(created, ignore_errors=True)
        raise

    stop = _SignalStop()
    callbacks.callbacks.insert(0, stop.callback())
    target = steps_before + int(timesteps)
    t_learn = time.perf_counter()
    with stop:
        if timesteps > 0:
            model.learn(total_timesteps=int(timesteps), callback=callbacks, reset_num_timesteps=not resume_files,
                        tb_log_name=f"{algo}", progress_bar=use_rich)
        learn_time = time.perf_counter() - t_learn
        stop.hold()           # a signal from here on waits for the save below
        _atomic_save(model.save, out / "model.zip")
        if isinstance(model.get_vec_normalize_env(), VecNormalize):
            _atomic_save(model.get_vec_normalize_env().save, out / "vecnormalize.pkl")
        if (cfg.get("checkpoint") or {}).get("save_replay_buffer") and hasattr(model, "save_replay_buffer"):
            # beside model.zip, which --resume then loads it with (a stale one must not outlive its model)
            _atomic_save(model.save_replay_buffer, out / "replay_buffer.pkl")
        info = {
            "algo": algo, "family": family, "seed": seed, "num_timesteps": int(model.num_timesteps),
            "timesteps_this_run": int(model.num_timesteps) - steps_before,
            "resumed_from": str(resume) if resume else None,
            "resumed_file": str(resume_files[0]) if resume_files else None,
            "steps_before": steps_before, "n_envs": n, "vec_env": vec_env,
            "wall_time_s": time.perf_counter() - t_start, "learn_time_s": learn_time,
            "cpu_threads": torch.get_num_threads(), "bc": bc_info, "command": command,
            "versions": versions(), "out": str(out),
        }
        if stop.signum is not None:
            info["interrupted"] = {"signal": signal.Signals(stop.signum).name, "target_timesteps": target}
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
        tmp = prev.with_name("train_info.partial.json")
        tmp.write_text(json.dumps(info, indent=2))
        os.replace(tmp, prev)
        venv.close()
        if eval_env is not None:
            eval_env.close()
    if stop.signum is not None:
        raise TrainingInterrupted(info, stop.signum)
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
    p.add_argument("--out", metavar="DIR", help="run directory (default runs/<algo>-<family>-seed<S>); one that "
                   "already holds a run is refused unless --resume is given")
    p.add_argument("--resume", metavar="CHECKPOINT",
                   help="continue from a checkpoint zip, a model.zip or a run directory (its newest model: "
                        "model.zip or the latest checkpoints/ zip; VecNormalize loaded too)")
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
                   help="override a config value, e.g. --set hyperparameters.learning_rate=1.0e-4 (repeatable; the value is read as YAML, where 1e-4 is text)")
    p.add_argument("-v", "--verbose", type=int, default=0, help="SB3 verbosity (0, 1, 2)")


def run(args) -> int:
    try:
        info = train(args.algo, args.family, config=args.config, timesteps=args.timesteps, n_envs=args.n_envs,
                     seed=args.seed, out=args.out, resume=args.resume, bc_pretrain=args.bc_pretrain,
                     progress_bar=args.progress_bar, vec_env=args.vec_env, overrides=args.set, verbose=args.verbose,
                     expert_data=args.expert_data, bc_seed=args.bc_seed, solver_workers=args.solver_workers,
                     command=" ".join(sys.argv), threads=args.threads)
    except TrainingInterrupted as e:
        # Ctrl-C / SIGTERM: one line saying what was kept and how to go on, no traceback, 128 + signal
        i, name = e.info, signal.Signals(e.signum).name
        left = max(i["interrupted"]["target_timesteps"] - i["num_timesteps"], 0)
        out = shlex.quote(i["out"])
        files = "model.zip" + (", vecnormalize.pkl" if (Path(i["out"]) / "vecnormalize.pkl").exists() else "")
        print(f"slew train-rl: interrupted ({name}) at step {i['num_timesteps']}: {files} and train_info.json "
              f"saved in {i['out']}; continue with: slew train-rl --algo {i['algo']} --family {i['family']} "
              f"--resume {out} --timesteps {left}", file=sys.stderr)
        return 128 + int(e.signum)
    except KeyboardInterrupt as e:
        # before training started (nothing to save, no directory left), or a second Ctrl-C (or
        # SIGTERM: exit 143, as a shell expects) that would not wait for the save
        print("slew train-rl: interrupted before the model was saved; the checkpoints already written "
              "(checkpoints/ of the run directory, if any) are kept, and --resume continues from the newest",
              file=sys.stderr)
        return 128 + int(getattr(e, "signum", signal.SIGINT))
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
