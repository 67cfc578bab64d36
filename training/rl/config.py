"""``slew train-rl``'s configuration: the rl-zoo style YAML files, ``--set`` overrides, and the
checks of every setting by name before anything is built (``check_config``)."""
from __future__ import annotations

import copy
from pathlib import Path

from slew_env.checks import is_real

from . import ALGOS


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
    if algo not in ALGOS:
        raise ValueError(f"--algo: expected one of {', '.join(ALGOS)}, got {algo!r}")
    path = Path(path) if path is not None else default_config_path(algo)
    if not path.exists():
        raise FileNotFoundError(f"--config: config file {path} not found")
    try:
        data = read_yaml(path, "a mapping of task family -> settings")
    except ValueError as exc:
        raise ValueError(f"--config: {exc}") from None
    if family not in data:
        raise ValueError(f"{path}: no entry for family {family!r} (entries: {', '.join(map(str, data)) or 'none'})")
    entry = data[family] or {}
    if not isinstance(entry, dict):
        raise ValueError(f"{path}: entry {family!r}: expected a mapping of settings, got {entry!r}")
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
            if node.get(p) is None:      # (`eval: null`, off: --set eval.eval_freq=N switches it on)
                node[p] = {}
            node = node[p]
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


# --------------------------------------------------------------------------- checks before training
def _yaml_error(path, exc) -> str:
    """One line for a YAML file that does not parse (PyYAML's message spans several lines)."""
    mark = getattr(exc, "problem_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    what = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    return f"{path}: not a valid YAML file ({what}{where})"


def read_yaml(path, what: str = "a mapping") -> dict:
    """The mapping in YAML file ``path``; a ``ValueError`` naming the file if it does not parse or
    holds something else (PyYAML's own errors are multi-line tracebacks)."""
    import yaml

    try:
        with open(path) as f:
            data = yaml.safe_load(f)
    except yaml.YAMLError as exc:
        raise ValueError(_yaml_error(path, exc)) from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a valid YAML file (not text)") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected {what}, got {type(data).__name__}")
    return data


def _number(key: str, v, low=None, low_open: bool = False, integer: bool = False):
    """``v`` as a finite number (an int if ``integer``; ``1.0e5`` is taken as 100000) >= ``low``
    (> if ``low_open``); a ``ValueError`` naming ``key`` otherwise. YAML reads ``nan`` or ``1e5``
    as text, which SB3 would only trip over mid-training."""
    import math

    if not is_real(v) or not math.isfinite(v):
        raise ValueError(f"{key}: expected a finite {'integer' if integer else 'number'}, got {v!r}")
    if integer:
        if v != int(v):
            raise ValueError(f"{key}: expected an integer, got {v!r}")
        v = int(v)
    if low is not None and (v <= low if low_open else v < low):
        raise ValueError(f"{key}: must be {'>' if low_open else '>='} {low}, got {v!r}")
    return v


def _mapping(cfg: dict, key: str) -> dict:
    v = cfg.get(key)
    if v is None:
        return {}
    if not isinstance(v, dict):
        raise ValueError(f"{key}: expected a mapping, got {v!r}")
    return v


# keyword arguments of PPO/SAC that train() sets itself (hyperparameters_from refuses them by name)
_OWN_ARGUMENTS = {"self", "policy", "env", "policy_kwargs", "seed", "tensorboard_log", "verbose", "device",
                  "_init_setup_model"}
_SCHEDULES = ("learning_rate", "clip_range", "clip_range_vf")
NORMALIZE_KEYS = {"norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon", "norm_obs_keys"}


def check_config(cfg: dict, algo: str) -> None:
    """Refuse, before anything is built or written, the settings SB3, gymnasium or VecNormalize would
    only trip over with a raw traceback (or mid-training), naming the key: unknown hyperparameter or
    ``env_kwargs`` names, text where a number goes, non-finite numbers, and frequencies that would
    silently switch checkpoints or evaluation off. Values are normalised in place (``1.0e5`` -> int)."""
    import inspect

    from slew_env import SlewEnv

    cfg["n_envs"] = _number("n_envs", cfg.get("n_envs"), 1, integer=True)
    cfg["n_timesteps"] = _number("n_timesteps", cfg.get("n_timesteps"), 0, integer=True)

    hp = _mapping(cfg, "hyperparameters")
    params = inspect.signature(_algo_class(algo).__init__).parameters
    for k in hp:
        if k in ("policy", "env", "policy_kwargs", "seed", "tensorboard_log"):
            raise ValueError(f"hyperparameters.{k}: set it with its own key, not in hyperparameters")
        if k not in params or k in _OWN_ARGUMENTS:
            known = sorted(set(params) - _OWN_ARGUMENTS)
            raise ValueError(f"hyperparameters.{k}: not a {algo.upper()} argument; known: {', '.join(known)}")
    for k, v in hp.items():
        key = f"hyperparameters.{k}"
        if k in _SCHEDULES:
            if isinstance(v, str) and v.startswith("lin_"):
                try:
                    _number(key, _float_or_text(v[4:]), 0)
                except ValueError:
                    raise ValueError(f"{key}: expected a number or lin_<number> (a linear decay from it), "
                                     f"got {v!r}") from None
            elif not (v is None and k == "clip_range_vf"):
                _number(key, v, 0)       # (0: a frozen policy, as some tests train)
            continue
        default = params[k].default
        if isinstance(default, bool):
            if not isinstance(v, bool):
                raise ValueError(f"{key}: expected true or false, got {v!r}")
        elif isinstance(default, (int, float)) and not (k == "train_freq" and isinstance(v, (list, tuple))):
            # (SAC's train_freq may also be [N, "step"|"episode"]; SB3 checks that form itself)
            hp[k] = _number(key, v, integer=isinstance(default, int))

    nk = cfg.get("normalize")
    if isinstance(nk, dict):
        for k, v in nk.items():
            key = f"normalize.{k}"
            if k not in NORMALIZE_KEYS:
                raise ValueError(f"{key}: not a VecNormalize argument; known: {', '.join(sorted(NORMALIZE_KEYS))}")
            if k in ("norm_obs", "norm_reward") and not isinstance(v, bool):
                raise ValueError(f"{key}: expected true or false, got {v!r}")
            if k in ("clip_obs", "clip_reward", "epsilon"):
                nk[k] = _number(key, v, 0, low_open=True)
            if k == "gamma":
                nk[k] = _number(key, v, 0, low_open=True)
                if nk[k] > 1:
                    raise ValueError(f"{key}: must be <= 1, got {v!r}")
    elif nk not in (None, False, True):
        raise ValueError(f"normalize: expected a mapping of VecNormalize arguments, true or false, got {nk!r}")

    ek = _mapping(cfg, "env_kwargs")
    known = set(inspect.signature(SlewEnv.__init__).parameters) - {"self"} | {"max_episode_steps"}
    for k in ek:
        if k not in known:
            raise ValueError(f"env_kwargs.{k}: not a Slew-v0 argument; known: {', '.join(sorted(known))}")
    if "max_episode_steps" in ek and ek["max_episode_steps"] is not None:
        ek["max_episode_steps"] = _number("env_kwargs.max_episode_steps", ek["max_episode_steps"], 1, integer=True)

    # a frequency of 0 or less had switched evaluation / checkpoints off without a word; off is said
    # with `eval: null` / `checkpoint: null`
    for section, freq in (("eval", "eval_freq"), ("checkpoint", "save_freq")):
        sec = cfg.get(section)
        if sec is None or sec is False:
            continue
        if not isinstance(sec, dict):
            raise ValueError(f"{section}: expected a mapping or null (off), got {sec!r}")
        if freq not in sec:
            raise ValueError(f"{section}.{freq}: missing (set {section}: null to run without)")
        try:
            sec[freq] = _number(f"{section}.{freq}", sec[freq], 1, integer=True)
        except ValueError as exc:
            raise ValueError(f"{exc} (set {section}: null to run without)") from None
    ev = cfg.get("eval") or {}
    if "n_eval_episodes" in ev:
        ev["n_eval_episodes"] = _number("eval.n_eval_episodes", ev["n_eval_episodes"], 1, integer=True)


def _float_or_text(s):
    try:
        return float(s)
    except ValueError:
        return s


def _algo_class(algo):
    from stable_baselines3 import PPO, SAC
    return {"ppo": PPO, "sac": SAC}[algo]
