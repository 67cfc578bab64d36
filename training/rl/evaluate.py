"""Evaluate a trained policy on held-out slews, against the time-optimal solutions.

::

    slew evaluate-rl POLICY [--family NAME] [--n 200] [--seed S] [--out REPORT_DIR] [--plot-k 3]
                     [--solutions FILE.jsonl] [--solver-workers N] [--solve-options JSON]
                     [--max-steps 400]
    python -m training.rl.evaluate ...        (the same options)

``POLICY`` is a run directory of ``slew train-rl`` (``model.zip``, ``vecnormalize.pkl``,
``config.yaml``), a ``model.zip`` / ``best/best_model.zip`` or a checkpoint
``rl_model_<N>_steps.zip`` (its VecNormalize file is found by name, the config in the run
directory).

Held-out problem ``i`` is ``TaskDistribution.family(family).sample(np.random.default_rng([seed, i]))``
(the scheme of ``slew generate``; training environments draw from other streams). Each
problem is posed to the environment with ``env.reset(options={"problem": p})`` and the
deterministic policy flies it (observations normalised with the saved statistics,
``training=False``); the same problem goes to ``solvers.solve``, whose answers are kept in a
``slew generate`` dataset file (``--solutions``, default
``runs/solutions/<family>-seed<S>.jsonl``; reused and continued by later evaluations).

Metrics: success rate; cone/rate violations; final time ``tf_policy`` (episode time at
success, physical units); ``tf_policy / tf_optimal`` where the policy succeeded and the
solver returned a verified optimum (median, mean, p95), and ``tf_policy / tf_eigenaxis``
against the eigenaxis baseline. Problems where the solver failed or refused the problem
(today: every cone problem) are counted by reason. Writes ``report.md``, ``results.json``
and ``overlay.png`` (policy torques, attitude error and sensor path over the optimal ones,
for ``--plot-k`` problems).
"""
from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Optional

import numpy as np

from . import DEFAULT_EVAL_SEED, FAMILIES, resolve_policy

DEFAULT_MAX_STEPS = 400   # the TimeLimit of the registered slew_env/Slew-v0


# --------------------------------------------------------------------------- loading
def _find_policy_files(policy):
    p = resolve_policy(policy)
    if p.is_dir():
        p = p / "model.zip"
    if not p.exists():
        raise FileNotFoundError(f"policy: no model at {p}")
    m = re.fullmatch(r"(.*)_(\d+)_steps\.zip", p.name)
    if m:
        vn = p.with_name(f"{m.group(1)}_vecnormalize_{m.group(2)}_steps.pkl")
        run_dir = p.parent.parent
    else:
        vn = p.with_name("vecnormalize.pkl")
        run_dir = p.parent.parent if p.parent.name == "best" else p.parent
    cfg = run_dir / "config.yaml"
    if not cfg.exists():
        raise FileNotFoundError(f"policy: no config.yaml in {run_dir} (a slew train-rl run directory)")
    return p, (vn if vn.exists() else None), cfg


def load_policy(policy):
    """``(model, vecnormalize or None, config dict)`` of a policy directory or model zip (CPU, eval mode)."""
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from .bc import _env_for
    from .config import read_yaml
    from .train import _first_line

    model_path, vn_path, cfg_path = _find_policy_files(policy)
    cfg = read_yaml(cfg_path, "a mapping (the run's configuration)")     # a one-line error naming the file
    cls = {"ppo": PPO, "sac": SAC}.get(cfg.get("algo"))
    if cls is None:
        raise ValueError(f"{cfg_path}: unknown algo {cfg.get('algo')!r}")
    model = cls.load(str(model_path), device="cpu")
    vn = None
    if vn_path is not None:
        env_kwargs = cfg.get("env_kwargs") or {}
        if not isinstance(env_kwargs, dict):
            raise ValueError(f"{cfg_path}: env_kwargs: expected a mapping, got {env_kwargs!r}")
        venv = DummyVecEnv([lambda: _env_for(env_kwargs)])
        try:
            vn = VecNormalize.load(str(vn_path), venv)
        except Exception as exc:
            # unpickling fails in many ways (UnpicklingError, EOFError, AttributeError...): name the file
            raise ValueError(f"{vn_path}: not VecNormalize statistics ({_first_line(exc)})") from None
        vn.training = False
        vn.norm_reward = False
    elif cfg.get("normalize"):
        raise FileNotFoundError(f"policy: the run normalises observations but {model_path.parent} has no "
                                "VecNormalize statistics")
    return model, vn, cfg


# --------------------------------------------------------------------------- problems and solutions
def heldout_problems(family: str, n: int, seed: int) -> list:
    from training.generate import GenerationSpec, problem_for

    spec = GenerationSpec(family=family, seed=int(seed), n=int(n))
    return [problem_for(spec, i) for i in range(n)]


def optimal_solutions(family, n, seed, path=None, workers=1, solve_options=None, progress=True,
                      solve_fn=None) -> list:
    """Solver records of held-out problems ``0 .. n-1`` (``training.rl.bc.solve_problems``)."""
    from .bc import solve_problems
    return solve_problems(family, n, seed, path, workers, solve_options, progress, solve_fn)


# --------------------------------------------------------------------------- rollouts
def _sensor_inertial(q, s_b):
    from slew_env.core.quaternion import qrotate
    return np.asarray(qrotate(np.asarray(q, float).copy(), np.asarray(s_b, float).copy()))


def rollout(model, vn, env, problem, max_steps: int = DEFAULT_MAX_STEPS, history: bool = False) -> dict:
    """Fly ``problem`` with the deterministic policy in ``env`` (a ``SlewEnv``)."""
    obs, info = env.reset(options={"problem": problem})
    s_b = np.asarray(problem.sensor_axis, float)
    base = env.unwrapped
    H = {"t": [0.0], "att": [info["attitude_error"]], "sensor": [_sensor_inertial(base.state[:4], s_b)],
         "u": []} if history else None
    violation = False
    min_margin = math.inf
    term = False
    steps = 0
    shield_steps = 0
    shield_infeasible = 0
    captured_steps = 0
    for steps in range(1, max_steps + 1):
        o = vn.normalize_obs(obs[None]) if vn is not None else obs[None]
        action, _ = model.predict(o, deterministic=True)
        a = np.clip(np.asarray(action, float).reshape(3), -1.0, 1.0)
        obs, _, term, trunc, info = env.step(a)
        violation |= bool(info["violation"])
        min_margin = min(min_margin, float(info["min_cone_margin"]))
        captured_steps += bool(info.get("captured"))
        if info.get("shield_active"):
            shield_steps += 1
            shield_infeasible += not info.get("shield_feasible", True)
        if history:   # the torque flown: after the cone filter and the capture law, if any
            H["u"].append(base.last_torque / np.asarray(problem.torque_max, float))
            H["t"].append(info["time"])
            H["att"].append(info["attitude_error"])
            H["sensor"].append(_sensor_inertial(base.state[:4], s_b))
        if term:
            break
    res = {"success": bool(info["is_success"]), "violation": violation, "steps": steps, "time": float(info["time"]),
           "final_attitude_error_deg": float(np.degrees(info["attitude_error"])),
           "final_rate_error": float(info["rate_error"]),
           "min_cone_margin_deg": float(np.degrees(min_margin)) if math.isfinite(min_margin) else None,
           "terminated": bool(term), "shield_steps": shield_steps, "shield_infeasible_steps": shield_infeasible,
           "captured_steps": captured_steps}
    if history:
        res["history"] = {k: np.asarray(v) for k, v in H.items()}
    return res


def _error_angle(prob, q):
    """Error angle (rad) of attitudes ``q`` (n, 4): full target ``2 acos|q·qf|``; pointing: sensor to target."""
    q = np.atleast_2d(q)
    if prob.qf is not None:
        return 2.0 * np.arccos(np.clip(np.abs(q @ np.asarray(prob.qf, float)), 0.0, 1.0))
    s = np.array([_sensor_inertial(qq, prob.sensor_axis) for qq in q])
    return np.arccos(np.clip(s @ np.asarray(prob.target_direction, float), -1.0, 1.0))


def optimal_trajectory_solved(rec: dict) -> Optional[dict]:
    """The optimal trajectory of ``rec``'s problem from ``solvers.solve`` (dense samples), or None."""
    from slew_env import SlewProblem

    try:
        import solvers
        prob = SlewProblem.from_dict(rec["problem"])
        sol = solvers.solve(prob)
    except Exception:    # a plot must not fail on a solver error
        return None
    if not sol.success or len(sol.t) == 0:
        return None
    umax = np.asarray(prob.torque_max, float)
    return {"t": np.asarray(sol.t), "att": _error_angle(prob, sol.q),
            "sensor": np.array([_sensor_inertial(q, prob.sensor_axis) for q in sol.q]),
            "u": np.asarray(sol.u)[:-1] / umax, "tf": float(sol.tf), "source": "solvers.solve"}


def optimal_trajectory(rec: dict, env_kwargs=None, dt_fine: float = 0.002) -> Optional[dict]:
    """The optimal control of ``rec`` (switch times) flown on a fine grid (``dt_fine`` time units, one RK4 step each)."""
    from slew_env import SlewEnv, SlewProblem

    from .bc import control_from_record

    control = control_from_record(rec)
    if control is None:
        return None
    prob = SlewProblem.from_dict(rec["problem"])
    kw = {k: v for k, v in (env_kwargs or {}).items() if k in ("max_cones",)}
    env = SlewEnv(control_dt=dt_fine, substeps=1, shaping=0.0, att_tol_deg=1e-6, rate_tol=1e-9, **kw)
    _, info = env.reset(options={"problem": prob})
    s_b = np.asarray(prob.sensor_axis, float)
    umax = np.asarray(prob.torque_max, float)
    dt = dt_fine * prob.time_unit
    n = int(math.ceil(float(rec["tf"]) / dt))
    t, att, sensor, u = [0.0], [info["attitude_error"]], [_sensor_inertial(env.state[:4], s_b)], []
    for k in range(n):
        a = control(np.asarray([(k + 0.5) * dt]))[0] / umax
        _, _, term, _, info = env.step(a)
        u.append(a)
        t.append(info["time"])
        att.append(info["attitude_error"])
        sensor.append(_sensor_inertial(env.state[:4], s_b))
        if term:        # at the target's tolerance, or a cone grazed past 1e-9 rad: the flight ends
            break
    env.close()
    return {"t": np.asarray(t), "att": np.asarray(att), "sensor": np.asarray(sensor), "u": np.asarray(u),
            "tf": float(rec["tf"]), "source": "switch times"}


# --------------------------------------------------------------------------- metrics
def _stats(x):
    x = np.asarray([v for v in x if v is not None and math.isfinite(v)], float)
    if len(x) == 0:
        return {"n": 0, "median": None, "mean": None, "p95": None, "min": None, "max": None}
    return {"n": int(len(x)), "median": float(np.median(x)), "mean": float(np.mean(x)),
            "p95": float(np.percentile(x, 95)), "min": float(x.min()), "max": float(x.max())}


def solver_outcome(rec: dict) -> str:
    """``"ok"``, ``"refused"`` (the solver raised: the problem is outside what it supports) or ``"failed"``."""
    if rec.get("success") is True:
        return "ok"
    from training.generate import STATUS_REJECTED   # the solve route raised ValueError

    if rec.get("status") == STATUS_REJECTED:
        return "refused"
    return "failed"


def summarise(episodes: list) -> dict:
    n = len(episodes)
    succ = [e for e in episodes if e["success"]]
    ratio = _stats([e["ratio"] for e in episodes if e.get("ratio") is not None])
    ratio_eig = _stats([e["ratio_eigenaxis"] for e in episodes if e.get("ratio_eigenaxis") is not None])
    tfp = _stats([e["time"] for e in succ])
    outcomes = Counter(e["solver"] for e in episodes)
    reasons = Counter(e["solver_message"][:160] for e in episodes if e["solver"] != "ok")
    margins = [e["min_cone_margin_deg"] for e in episodes if e.get("min_cone_margin_deg") is not None]
    return {
        "n": n, "n_success": len(succ), "success_rate": len(succ) / n if n else math.nan,
        "n_violation": sum(e["violation"] for e in episodes),
        "violation_rate": sum(e["violation"] for e in episodes) / n if n else math.nan,
        "n_with_cones": len(margins), "min_cone_margin_deg": min(margins) if margins else None,
        "n_truncated": sum(not e["terminated"] for e in episodes),
        "n_shielded": sum(bool(e.get("shield_steps")) for e in episodes),
        "n_shield_infeasible": sum(bool(e.get("shield_infeasible_steps")) for e in episodes),
        "n_captured": sum(bool(e.get("captured_steps")) for e in episodes),
        "tf_policy_median": tfp["median"], "tf_policy_mean": tfp["mean"],
        "solver_ok": outcomes.get("ok", 0), "solver_ok_exact": sum(bool(e.get("optimal_exact")) for e in episodes),
        "solver_failed": outcomes.get("failed", 0),
        "solver_refused": outcomes.get("refused", 0), "solver_reasons": dict(reasons.most_common(8)),
        "success_rate_where_solver_ok": (sum(e["success"] for e in episodes if e["solver"] == "ok")
                                         / max(outcomes.get("ok", 0), 1)) if outcomes.get("ok") else None,
        "ratio_n": ratio["n"], "ratio_median": ratio["median"], "ratio_mean": ratio["mean"],
        "ratio_p95": ratio["p95"], "ratio_min": ratio["min"], "ratio_max": ratio["max"],
        "ratio_eigenaxis_n": ratio_eig["n"], "ratio_eigenaxis_median": ratio_eig["median"],
    }


# --------------------------------------------------------------------------- the evaluation
def default_report_dir(policy, family: str, seed: int) -> Path:
    """Where ``evaluate`` writes without ``out``: beside the policy.

    ``eval-<family>-seed<seed>`` for a run directory, its ``model.zip`` or
    ``best/best_model.zip`` (one model to a folder); ``eval-<zip name>-<family>-seed<seed>``
    for any other zip, such as a checkpoint ``rl_model_<N>_steps.zip``, so that the checkpoints
    of one run get a report each; ``runs/eval-<policy dir>-<family>-seed<seed>`` for a shipped
    policy (never into the installed package).
    """
    p = Path(resolve_policy(policy))
    pdir = p if p.is_dir() else p.parent
    shipped = Path(__file__).resolve().parent / "policies"
    if shipped in pdir.resolve().parents or pdir.resolve() == shipped:
        return Path("runs") / f"eval-{pdir.name}-{family}-seed{seed}"
    if p.is_dir() or p.name in ("model.zip", "best_model.zip"):
        return pdir / f"eval-{family}-seed{seed}"
    return pdir / f"eval-{p.stem}-{family}-seed{seed}"


def evaluate(policy, family: Optional[str] = None, n: int = 200, seed: int = DEFAULT_EVAL_SEED, out=None,
             plot_k: int = 3, solutions=None, solver_workers: int = 1, solve_options=None,
             max_steps: int = DEFAULT_MAX_STEPS, progress: bool = True, command: Optional[str] = None,
             solve_fn: Optional[str] = None, shield="policy", capture="policy") -> dict:
    """Roll the policy out on ``n`` held-out problems and compare with the optimum; returns the results dict.

    ``shield``: ``"policy"`` flies the policy with the ``ConeShield`` of its ``config.yaml`` (the
    run's training setting, unless edited since, as for the shipped cone policy; none if it has
    none); ``"on"`` adds the filter with its defaults when the run had none; ``"off"`` flies the
    bare network; a dict gives ``ConeShield`` arguments. ``capture``: the same for the capture
    law near the target (``training.rl.capture.CaptureHandover``: PD settling or braking curve).

    Writes ``report.md``, ``results.json`` and (``plot_k > 0``) ``overlay.png`` to ``out``
    (default ``default_report_dir``: ``<policy dir>/eval-<family>-seed<seed>``, with the zip's
    name for a checkpoint).
    """
    from slew_env import SlewProblem

    from .bc import _env_for, solve_spec

    if n < 1:
        raise ValueError(f"--n: must be >= 1, got {n}")
    if max_steps < 1:
        raise ValueError(f"--max-steps: must be >= 1, got {max_steps}")
    if plot_k < 0:     # (-1 had been taken as 0, no plot, without a word)
        raise ValueError(f"--plot-k: must be >= 0, got {plot_k}")
    if solver_workers < 1:
        raise ValueError(f"--solver-workers: must be >= 1, got {solver_workers}")
    t0 = time.perf_counter()
    policy = resolve_policy(policy)
    model, vn, cfg = load_policy(policy)
    family = family or cfg.get("family")
    if family not in FAMILIES:
        raise ValueError(f"--family: expected one of {', '.join(FAMILIES)}, got {family!r}")
    pdir = Path(policy) if Path(policy).is_dir() else Path(policy).parent
    # the solve route and its options are checked before the report directory is made (a bad
    # --solve-options had left an empty report directory behind)
    solve_spec(family, n, seed, solve_fn, solve_options)
    out = Path(out) if out is not None else default_report_dir(policy, family, seed)
    out.mkdir(parents=True, exist_ok=True)

    t_solve = time.perf_counter()
    records = optimal_solutions(family, n, seed, solutions, solver_workers, solve_options, progress, solve_fn)
    t_solve = time.perf_counter() - t_solve
    problems = heldout_problems(family, n, seed)
    env_kwargs = dict(cfg.get("env_kwargs") or {})
    shield_kw = resolve_shield(shield, cfg)
    capture_kw = resolve_capture(capture, cfg)
    env = _env_for(env_kwargs, shield_kw, capture_kw)
    episodes = []
    t_roll = time.perf_counter()
    histories = {}
    for i, (prob, rec) in enumerate(zip(problems, records)):
        if rec.get("problem") is not None and SlewProblem.from_dict(rec["problem"]) != prob:
            raise ValueError(f"solutions file: problem {i} differs from the held-out problem; was it made "
                             "with another family distribution?")
        r = rollout(model, vn, env, prob, max_steps, history=i < plot_k)
        if "history" in r:
            histories[i] = r.pop("history")
        outcome = solver_outcome(rec)
        tf_opt = float(rec["tf"]) if outcome == "ok" else None
        base = rec.get("baseline_tf")
        r.update(index=i, slew_angle_deg=float(np.degrees(prob.slew_angle)), n_cones=len(prob.cones),
                 solver=outcome, solver_status=rec.get("status"), solver_message=str(rec.get("message") or ""),
                 tf_optimal=tf_opt, tf_eigenaxis=float(base) if isinstance(base, (int, float)) else None,
                 optimal_exact=(bool(rec["exact"]) if rec.get("exact") is not None
                                else rec.get("method") in ("indirect", "multiple-shooting")) if tf_opt else None,
                 solver_method=rec.get("method"),
                 ratio=r["time"] / tf_opt if (r["success"] and tf_opt) else None,
                 ratio_eigenaxis=r["time"] / float(base) if (r["success"] and isinstance(base, (int, float))
                                                                and base > 0) else None)
        episodes.append(r)
    t_roll = time.perf_counter() - t_roll
    env.close()
    summary = summarise(episodes)
    results = {"policy": str(policy), "algo": cfg.get("algo"), "trained_family": cfg.get("family"),
               "family": family, "n": n, "seed": seed, "max_steps": max_steps, "env_kwargs": env_kwargs,
               # the filter and capture law flown, and those of the policy's config.yaml (which may
               # differ from the ones it trained with: see the config's comments)
               "shield": shield_kw, "config_shield": resolve_shield("policy", cfg), "capture": capture_kw,
               "config_capture": resolve_capture("policy", cfg),
               "solutions": str(solutions) if solutions else None, "summary": summary,
               "timing": {"solve_s": t_solve, "rollout_s": t_roll, "total_s": time.perf_counter() - t0},
               "command": command, "train_info": _train_info(pdir), "episodes": episodes}
    results["solver_commits"] = sorted({str(r.get("solver_commit")) for r in records})
    (out / "results.json").write_text(json.dumps(_clean(results), indent=2))
    if plot_k > 0:
        plot_overlay(problems, records, histories, episodes, out / "overlay.png", env_kwargs)
    (out / "report.md").write_text(report_markdown(results, plot_k > 0))
    results["out"] = str(out)
    return results


def _run_part(choice, cfg: dict, key: str) -> Optional[dict]:
    """Arguments of the run's ``key`` part (``shield``: ``ConeShield``; ``capture``:
    ``CaptureHandover``) for a rollout; None: without it. ``choice``: ``"policy"`` as the run
    trained, ``"on"`` the part's defaults where the run had none, ``"off"`` none, or a dict of
    arguments (validated as the config's)."""
    from .train import capture_kwargs, shield_kwargs
    parse = {"shield": shield_kwargs, "capture": capture_kwargs}[key]
    if isinstance(choice, dict):
        return parse({key: choice})
    trained = parse(cfg)
    if choice == "policy":
        return trained
    if choice == "on":
        return trained if trained is not None else parse({key: True})
    if choice == "off":
        return None
    raise ValueError(f"--{key}: expected policy, on or off, got {choice!r}")


def resolve_shield(shield, cfg: dict) -> Optional[dict]:
    """``ConeShield`` arguments for a rollout (None: no filter); see ``evaluate``'s ``shield``."""
    return _run_part(shield, cfg, "shield")


def resolve_capture(capture, cfg: dict) -> Optional[dict]:
    """``CaptureHandover`` arguments for a rollout (None: none); as ``resolve_shield``."""
    return _run_part(capture, cfg, "capture")


def _train_info(pdir: Path):
    for d in (pdir, pdir.parent):
        f = d / "train_info.json"
        if f.exists():
            try:
                ti = json.loads(f.read_text())
                return {k: ti.get(k) for k in ("algo", "family", "seed", "num_timesteps", "wall_time_s", "bc",
                                               "command")}
            except ValueError:
                return None
    return None


def _clean(x):
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


# --------------------------------------------------------------------------- report
def _f(x, spec=".3f"):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return format(x, spec)


def _shield_text(kw: dict) -> str:
    from slew_env.shield import ConeShieldFilter
    cfg = ConeShieldFilter(**kw).config()
    return ", ".join(f"{k} {v:g}" for k, v in cfg.items())


def _capture_text(kw: dict) -> str:
    if kw.get("law") == "braking":
        return (f"braking curve: brake {kw['brake']:g}, aim {kw['aim_deg']:g}°, "
                f"damping {kw['damping']:g}")
    return f"kp {kw['kp']:g}, damping {kw['damping']:g}"


def report_markdown(results: dict, with_plot: bool) -> str:
    s = results["summary"]
    ti = results.get("train_info") or {}
    lines = [f"# evaluate-rl: {results['policy']}", "",
             f"{results['algo']} policy (trained on {results['trained_family']}"
             + (f", {ti.get('num_timesteps')} steps, {_f(ti.get('wall_time_s'), '.0f')} s" if ti else "")
             + f") on {results['n']} held-out `{results['family']}` problems (seed {results['seed']}), "
               f"deterministic, at most {results['max_steps']} control steps"
             + (f", through the keep-out-cone filter `ConeShield` ({_shield_text(results['shield'])})"
                if results.get("shield") is not None else ", without a safety filter")
             + (f", with the capture law within {results['capture']['deg']:g}° of the target ("
                + _capture_text(results["capture"]) + ")"
                if results.get("capture") is not None else "") + ".", ""]
    if results.get("command"):
        lines += ["```", results["command"], "```", ""]
    lines += ["| metric | value |", "|---|---|",
              f"| success rate | {_f(100 * s['success_rate'], '.1f')} % ({s['n_success']}/{s['n']}) |",
              f"| episodes with a cone/rate violation | {s['n_violation']} ({_f(100 * s['violation_rate'], '.1f')} %) |",
              f"| smallest cone margin (deg) | {_f(s['min_cone_margin_deg'], '.2f')} |",
              f"| truncated (time limit) | {s['n_truncated']} |",
              f"| episodes where the cone filter changed an action / could not meet a condition | "
              f"{s['n_shielded']} / {s['n_shield_infeasible']} |",
              f"| episodes the capture law finished | {s['n_captured']} |",
              f"| final time tf_policy at success, median / mean | {_f(s['tf_policy_median'])} / {_f(s['tf_policy_mean'])} |",
              f"| solver: verified optimum / failed / refused | {s['solver_ok']} / {s['solver_failed']} / {s['solver_refused']} |",
              f"| of the verified optima: exact extremals (indirect) / approximate answers (switch-time or "
              f"collocation) | {s['solver_ok_exact']} / {s['solver_ok'] - s['solver_ok_exact']} |",
              f"| success rate where the solver verified an optimum | "
              f"{_f(None if s['success_rate_where_solver_ok'] is None else 100 * s['success_rate_where_solver_ok'], '.1f')} % |",
              f"| tf_policy / tf_optimal: n | {s['ratio_n']} |",
              f"| tf_policy / tf_optimal: median | {_f(s['ratio_median'])} |",
              f"| tf_policy / tf_optimal: mean | {_f(s['ratio_mean'])} |",
              f"| tf_policy / tf_optimal: p95 | {_f(s['ratio_p95'])} |",
              f"| tf_policy / tf_optimal: min / max | {_f(s['ratio_min'])} / {_f(s['ratio_max'])} |",
              f"| tf_policy / tf_eigenaxis: median (n) | {_f(s['ratio_eigenaxis_median'])} ({s['ratio_eigenaxis_n']}) |",
              ""]
    if s["solver_reasons"]:
        lines += ["Problems without a verified optimum, by the solver's message:", ""]
        lines += [f"- {c} × {m}" for m, c in s["solver_reasons"].items()]
        lines.append("")
    lines += ["tf_policy is the episode time at success (a multiple of the control step, the success "
              "tolerance of the environment applies); tf_optimal is `solvers.solve`'s verified final time "
              "for the same problem. A ratio slightly below 1 is possible: the environment accepts the "
              "target within its tolerance.", ""]
    t = results["timing"]
    lines.append(f"Timing: solver {t['solve_s']:.0f} s (0 when cached), rollouts {t['rollout_s']:.1f} s.")
    if with_plot:
        lines += ["", "![overlay](overlay.png)"]
    lines += ["", "## Problems", "", "| # | angle (deg) | cones | success | violation | tf_policy | tf_optimal | ratio |",
              "|---|---|---|---|---|---|---|---|"]
    for e in results["episodes"][:50]:
        lines.append(f"| {e['index']} | {e['slew_angle_deg']:.1f} | {e['n_cones']} | {'yes' if e['success'] else 'no'} "
                     f"| {'yes' if e['violation'] else 'no'} | {_f(e['time'])} | {_f(e['tf_optimal'])} | {_f(e['ratio'])} |")
    if len(results["episodes"]) > 50:
        lines.append(f"\n(first 50 of {len(results['episodes'])}; all in results.json)")
    return "\n".join(lines) + "\n"


def _project(v, c, b1, b2):
    """Azimuthal equidistant projection of unit vectors ``v`` around ``c`` (degrees)."""
    v = np.atleast_2d(v)
    rho = np.degrees(np.arccos(np.clip(v @ c, -1.0, 1.0)))
    x, y = v @ b1, v @ b2
    nrm = np.hypot(x, y)
    nrm = np.where(nrm < 1e-12, 1.0, nrm)
    return rho * x / nrm, rho * y / nrm


def plot_overlay(problems, records, histories, episodes, path, env_kwargs=None):
    """Torques, attitude error and sensor path of the policy (solid) over the optimal ones (dashed).

    The optimal trajectory is re-solved with ``solvers.solve`` for its dense samples (the
    records keep only switch times); if that fails, the record's switch times are flown.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    idx = sorted(histories)
    k = max(len(idx), 1)
    fig, axes = plt.subplots(k, 3, figsize=(15, 3.6 * k), squeeze=False)
    colors = ["tab:red", "tab:green", "tab:blue"]
    for row, i in enumerate(idx):
        prob, h, e = problems[i], histories[i], episodes[i]
        opt = None
        if records[i].get("success") is True:   # dense optimal trajectory; else replay the switch times
            opt = optimal_trajectory_solved(records[i]) or optimal_trajectory(records[i], env_kwargs)
        ax_u, ax_a, ax_s = axes[row]
        tu = h["t"][:len(h["u"])]
        for j in range(3):
            if len(h["u"]):
                ax_u.step(np.append(tu, h["t"][len(h["u"])]), np.append(h["u"][:, j], h["u"][-1, j]), where="post",
                          color=colors[j], lw=1.5, label=f"policy u{j + 1}")
            if opt is not None:
                ax_u.step(opt["t"][:-1], opt["u"][:, j], where="post", color=colors[j], lw=1.0, ls="--",
                          label=f"optimal u{j + 1}")
        ax_u.set_xlabel("time")
        ax_u.set_ylabel("u / u_max")
        status = "success" if e["success"] else ("violation" if e["violation"] else "no success")
        ratio = f", ratio {e['ratio']:.3f}" if e.get("ratio") else ""
        ax_u.set_title(f"#{i}: {np.degrees(prob.slew_angle):.0f}°, {len(prob.cones)} cones — {status}{ratio}",
                       fontsize=9)
        ax_u.set_ylim(-1.15, 1.15)
        ax_u.legend(fontsize=6, ncol=2, loc="lower right")
        ax_a.plot(h["t"], np.degrees(h["att"]), color="k", lw=1.5, label="policy")
        if opt is not None:
            ax_a.plot(opt["t"], np.degrees(opt["att"]), color="tab:orange", ls="--", lw=1.2,
                      label=f"optimal (tf {opt['tf']:.3f})")
        else:
            ax_a.text(0.5, 0.9, f"no optimum: {e['solver_message'][:60]}", transform=ax_a.transAxes,
                      ha="center", fontsize=7)
        ax_a.set_xlabel("time")
        ax_a.set_ylabel("error angle (deg)")
        ax_a.legend(fontsize=7)
        # sensor path: azimuthal equidistant projection around the start/target midpoint
        s0, sf = np.asarray(prob.start_direction, float), np.asarray(prob.target_direction, float)
        c = s0 + sf
        if np.linalg.norm(c) < 1e-6:
            c = np.cross(s0, [1.0, 0.0, 0.0] if abs(s0[0]) < 0.9 else [0.0, 1.0, 0.0])
        c /= np.linalg.norm(c)
        b1 = s0 - (s0 @ c) * c
        if np.linalg.norm(b1) < 1e-9:
            b1 = np.cross(c, [0.0, 0.0, 1.0] if abs(c[2]) < 0.9 else [1.0, 0.0, 0.0])
        b1 /= np.linalg.norm(b1)
        b2 = np.cross(c, b1)
        for cone in prob.cones:
            a = np.asarray(cone.axis, float)
            p1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
            p1 /= np.linalg.norm(p1)
            p2 = np.cross(a, p1)
            th = np.linspace(0, 2 * np.pi, 200)
            ring = (np.cos(cone.half_angle) * a[None] + np.sin(cone.half_angle)
                    * (np.cos(th)[:, None] * p1 + np.sin(th)[:, None] * p2))
            x, y = _project(ring, c, b1, b2)
            ax_s.fill(x, y, color="tab:red", alpha=0.25, lw=0)
        x, y = _project(h["sensor"], c, b1, b2)
        ax_s.plot(x, y, color="k", lw=1.5, label="policy")
        if opt is not None:
            x, y = _project(opt["sensor"], c, b1, b2)
            ax_s.plot(x, y, color="tab:orange", ls="--", lw=1.2, label="optimal")
        for v, m, lab in ((s0, "o", "start"), (sf, "*", "target")):
            x, y = _project(v, c, b1, b2)
            ax_s.plot(x, y, m, color="tab:purple", ms=8, label=lab)
        ax_s.set_aspect("equal", adjustable="datalim")
        ax_s.set_title("sensor path (deg from the start-target midpoint)", fontsize=9)
        ax_s.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# --------------------------------------------------------------------------- command line
def add_arguments(p: argparse.ArgumentParser):
    p.add_argument("policy", metavar="POLICY",
                   help="slew train-rl run directory, model.zip or checkpoint rl_model_<N>_steps.zip; "
                        "'shipped' (full-attitude) or 'shipped:pointing-cones' for the policies shipped with the package")
    p.add_argument("--family", choices=FAMILIES, help="task family (default: the one the policy was trained on)")
    p.add_argument("--n", type=int, default=200, help="held-out problems (default 200)")
    p.add_argument("--seed", type=int, default=DEFAULT_EVAL_SEED,
                   help=f"seed of the held-out problems (default {DEFAULT_EVAL_SEED})")
    p.add_argument("--out", metavar="DIR", help="report directory (default <policy dir>/eval-<family>-seed<S>; "
                   "eval-<zip name>-<family>-seed<S> for a checkpoint or any zip but model.zip / best_model.zip; "
                   "runs/eval-<policy dir name>-<family>-seed<S> for a shipped policy); "
                   "report.md, results.json and overlay.png already there are replaced")
    p.add_argument("--plot-k", type=int, default=3, help="problems in overlay.png (default 3; 0: no plot)")
    p.add_argument("--solutions", metavar="FILE.jsonl",
                   help="solver answers of the held-out problems (slew generate format; created or continued; "
                        "default runs/solutions/<family>-seed<S>.jsonl)")
    p.add_argument("--solver-workers", type=int, default=1, help="processes solving missing problems (default 1)")
    p.add_argument("--solve-options", metavar="JSON", help="solvers.solve options, e.g. '{\"time_budget\": 10}'")
    p.add_argument("--solve-fn", metavar="MODULE:FUNCTION",
                   help="solve route for missing solutions (default solvers.solve, as slew generate)")
    p.add_argument("--max-steps", type=int, default=DEFAULT_MAX_STEPS,
                   help=f"control steps before an episode counts as failed (default {DEFAULT_MAX_STEPS})")
    p.add_argument("--shield", choices=("policy", "on", "off"), default="policy",
                   help="keep-out-cone safety filter (slew_env.shield.ConeShield): 'policy' as the run's config.yaml "
                        "says (default), 'on' the filter's defaults where the run had none, 'off' the bare network")
    p.add_argument("--capture", choices=("policy", "on", "off"), default="policy",
                   help="capture law near the target (training.rl.capture: PD settling or braking curve): 'policy' "
                        "as the run's config.yaml says (default), 'on' its defaults where the run had none, 'off' "
                        "the network alone")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--no-progress", action="store_true", help="no solver progress bar")


def run(args) -> int:
    import torch

    if args.threads < 1:        # refused as train-rl refuses it (0 had run with 1 thread without a word)
        raise ValueError(f"--threads: must be >= 1, got {args.threads}")
    torch.set_num_threads(int(args.threads))
    try:
        opts = json.loads(args.solve_options) if args.solve_options else None
    except ValueError as exc:
        raise ValueError(f"--solve-options: not valid JSON ({exc})") from None
    if opts is not None and not isinstance(opts, dict):
        raise ValueError("--solve-options: expected a JSON object")
    res = evaluate(args.policy, args.family, args.n, args.seed, args.out, args.plot_k, args.solutions,
                   args.solver_workers, opts, args.max_steps, not args.no_progress, command=" ".join(sys.argv),
                   solve_fn=args.solve_fn, shield=args.shield,
                   capture=args.capture)
    s = res["summary"]
    print(f"{s['n']} problems: success {100 * s['success_rate']:.1f} %, violations {s['n_violation']}, "
          f"median tf_policy {_f(s['tf_policy_median'])}, tf_policy/tf_optimal median {_f(s['ratio_median'])} "
          f"mean {_f(s['ratio_mean'])} p95 {_f(s['ratio_p95'])} (n={s['ratio_n']}; solver ok {s['solver_ok']}, "
          f"failed {s['solver_failed']}, refused {s['solver_refused']})")
    print(f"report: {Path(res['out']) / 'report.md'}")
    return 0


def main(argv=None) -> int:
    """``python -m training.rl.evaluate`` is ``slew evaluate-rl`` (same options, same error handling)."""
    from training.cli import main as slew
    return slew(["evaluate-rl", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
