"""Dense collocation experts with a safety margin on the cones, for cloning cone-avoiding policies.

Cloning the switch times of the solver's answers works for full-attitude slews (exact
bang-bang extremals), not for the ``pointing-cones`` family: its answers are collocation
answers whose paths ride the cone boundaries, so a flown (piecewise-constant) copy of the
control, or a policy that drifts a fraction of a degree off it, enters a cone (the expert
rollouts of ``training.rl.bc`` reached the target without a violation on 131 of 298
problems). Here each expert problem is instead solved by direct collocation with every
cone's half-angle **inflated by a margin** (default 2.5°, less where the start or target
direction is closer to a cone than that), and the collocation's dense solution — times,
attitudes, rates and controls at the nodes and midpoints — is kept. The behaviour-cloning
pairs are the environment's observation of the *original* problem (true cones) at every
dense state, labelled with the expert torque averaged over the control step that starts
there (``u / u_max``, the collocation control model: a quadratic through node, midpoint
and node on each interval; zero after ``tf``), plus a few rest states on the target.

Records (JSON Lines, one problem a line, resumable: problems already in the file are
skipped): ``index, family, seed, margin_deg, inflation_deg [per cone], success, tf,
problem (original), t, q, omega, u, min_margin_deg (dense samples vs the original cones),
wall_time_s``.

Command line::

    python -m training.rl.dense_expert solve --family pointing-cones --seed 1 --n 1200 \\
        --margin-deg 2.5 --out runs/solutions/pointing-cones-dense-seed1.jsonl
    python -m training.rl.dense_expert stats runs/solutions/pointing-cones-dense-seed1.jsonl
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Optional

import numpy as np

DEFAULT_MARGIN_DEG = 2.5
# the inflated cones keep the start and target sensor directions this far outside (deg)
ENDPOINT_SLACK_DEG = 0.25


def default_dense_path(family: str, seed: int) -> Path:
    return Path("runs") / "solutions" / f"{family}-dense-seed{int(seed)}.jsonl"


def _sensor_dir(q, s_b):
    from slew_env.core.quaternion import qrotate
    return np.asarray(qrotate(np.asarray(q, float).copy(), np.asarray(s_b, float).copy()))


def inflate_cones(prob, margin_deg: float):
    """``(problem dict with inflated cones, inflation per cone in degrees)``.

    Each half-angle grows by ``margin_deg``, capped so that the start and target sensor
    directions stay ``ENDPOINT_SLACK_DEG`` outside the inflated cone.
    """
    d = prob.to_dict()
    s0 = _sensor_dir(prob.q0, prob.sensor_axis)
    ends = [s0, np.asarray(prob.target_direction, float)]
    infl = []
    for c in d["cones"]:
        a = np.asarray(c["axis"], float)
        a = a / np.linalg.norm(a)
        alpha = float(c["half_angle"])
        room = min(math.degrees(math.acos(np.clip(e @ a, -1.0, 1.0)) - alpha) for e in ends) - ENDPOINT_SLACK_DEG
        extra = max(0.0, min(float(margin_deg), room))
        c["half_angle"] = alpha + math.radians(extra)
        infl.append(extra)
    return d, infl


def min_margin_deg(prob, q: np.ndarray) -> float:
    """Smallest clearance (deg) of the sensor from the problem's cones over attitudes ``q`` (n, 4)."""
    if not prob.cones:
        return math.inf
    s = np.array([_sensor_dir(qq, prob.sensor_axis) for qq in q])
    m = math.inf
    for c in prob.cones:
        a = np.asarray(c.axis, float)
        ang = np.arccos(np.clip(s @ a, -1.0, 1.0)) - c.half_angle
        m = min(m, float(ang.min()))
    return math.degrees(m)


def solve_dense(prob, margin_deg: float = DEFAULT_MARGIN_DEG, solve_options: Optional[dict] = None) -> dict:
    """Collocation answer of ``prob`` with inflated cones, as a dense record (see the module docstring)."""
    import solvers
    from slew_env import SlewProblem

    d, infl = inflate_cones(prob, margin_deg)
    t0 = time.perf_counter()
    rec = {"margin_deg": float(margin_deg), "inflation_deg": infl, "problem": prob.to_dict()}
    try:
        sol = solvers.solve(SlewProblem.from_dict(d), method="collocation", **(solve_options or {}))
    except Exception as e:  # a failed expert problem is recorded, not fatal
        rec.update(success=False, message=f"{type(e).__name__}: {e}", wall_time_s=time.perf_counter() - t0)
        return rec
    rec["wall_time_s"] = time.perf_counter() - t0
    rec["success"] = bool(sol.success) and sol.t is not None
    rec["message"] = str(sol.message)
    if rec["success"]:
        q = np.asarray(sol.q, float)
        rec.update(tf=float(sol.tf), t=np.asarray(sol.t, float).round(10).tolist(), q=q.round(10).tolist(),
                   omega=np.asarray(sol.omega, float).round(10).tolist(),
                   u=np.asarray(sol.u, float).round(10).tolist(), min_margin_deg=min_margin_deg(prob, q))
    return rec


def _open_append(path: Path):
    """Append mode, after completing a last line cut short by a kill (so the next record starts on its own line)."""
    if path.exists() and path.stat().st_size > 0:
        with open(path, "rb") as f:
            f.seek(-1, 2)
            cut = f.read(1) != b"\n"
        if cut:
            with open(path, "a") as f:
                f.write("\n")
    return open(path, "a")


def load_records(path) -> list:
    path = Path(path)
    if not path.exists():
        return []
    out = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line:
                try:
                    out.append(json.loads(line))
                except ValueError:   # a line cut by a kill: ignored, solved again
                    pass
    return sorted(out, key=lambda r: r["index"])


def solve_range(family: str, seed: int, n: int, path, margin_deg: float = DEFAULT_MARGIN_DEG,
                progress: bool = True) -> list:
    """Solve problems ``0 .. n-1`` of (family, seed) that are not yet in ``path``; returns all records."""
    from training.generate import GenerationSpec, problem_for

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    have = {r["index"] for r in load_records(path)}
    spec = GenerationSpec(family=family, seed=int(seed), n=int(n))
    todo = [i for i in range(n) if i not in have]
    t0 = time.perf_counter()
    with _open_append(path) as f:
        for j, i in enumerate(todo):
            rec = {"index": i, "family": family, "seed": int(seed)}
            rec.update(solve_dense(problem_for(spec, i), margin_deg))
            f.write(json.dumps(rec) + "\n")
            f.flush()
            if progress and (j + 1) % 25 == 0:
                el = time.perf_counter() - t0
                print(f"{j + 1}/{len(todo)} solved, {el:.0f} s", file=sys.stderr, flush=True)
    return [r for r in load_records(path) if r["index"] < n]


# --------------------------------------------------------------------------- cloning pairs
def control_of(rec: dict):
    """``u(t)`` of a dense record: the collocation control model (quadratic through node,
    midpoint, node on each interval), zero after ``tf``."""
    t = np.asarray(rec["t"], float)
    U = np.asarray(rec["u"], float)
    tk = t[0::2]
    Un, Um = U[0::2], U[1::2]
    tf = float(rec["tf"])

    def u_of(tt):
        tt = np.atleast_1d(np.asarray(tt, float))
        k = np.clip(np.searchsorted(tk, tt, side="right") - 1, 0, len(tk) - 2)
        s = np.clip((tt - tk[k]) / (tk[k + 1] - tk[k]), 0.0, 1.0)
        l0 = 2.0 * (s - 0.5) * (s - 1.0)
        l1 = -4.0 * s * (s - 1.0)
        l2 = 2.0 * s * (s - 0.5)
        v = l0[:, None] * Un[k] + l1[:, None] * Um[k] + l2[:, None] * Un[k + 1]
        return np.where((tt < tf)[:, None], v, 0.0)
    return u_of


def record_pairs(rec: dict, max_cones: int = 4, control_dt: float = 0.05, n_sub: int = 16, n_rest: int = 3):
    """(observations, actions) of one dense record: every dense state, and ``n_rest`` rest states on the target."""
    from slew_env import SlewProblem
    from slew_env.core import env_kernels as _k

    prob = SlewProblem.from_dict(rec["problem"])
    task = prob.to_task_array(max_cones)
    umax = np.asarray(prob.torque_max, float)
    dt = control_dt * prob.time_unit
    u_of = control_of(rec)
    t = np.asarray(rec["t"], float)
    X = np.concatenate([np.asarray(rec["q"], float), np.asarray(rec["omega"], float)], axis=1)
    obs = np.zeros(_k.obs_length(max_cones), np.float32)
    O, A = [], []
    for tk, x in zip(t, X):
        x = x.copy()
        x[:4] /= np.linalg.norm(x[:4])
        _k.write_obs(task, x, obs)
        ts = tk + (np.arange(n_sub) + 0.5) / n_sub * dt
        O.append(obs.copy())
        A.append(np.clip(u_of(ts).mean(axis=0) / umax, -1.0, 1.0))
    xf = X[-1].copy()
    xf[:4] /= np.linalg.norm(xf[:4])
    xf[4:] = 0.0
    _k.write_obs(task, xf, obs)
    for _ in range(n_rest):
        O.append(obs.copy())
        A.append(np.zeros(3))
    return np.asarray(O, np.float32), np.asarray(A, np.float32)


def build_pairs(records: list, max_cones: int = 4, control_dt: float = 0.05, n_sub: int = 16) -> dict:
    O, A, E = [], [], []
    used = 0
    for rec in records:
        if not rec.get("success"):
            continue
        o, a = record_pairs(rec, max_cones, control_dt, n_sub)
        O.append(o)
        A.append(a)
        E.append(np.full(len(o), rec["index"]))
        used += 1
    return {"obs": np.concatenate(O), "actions": np.concatenate(A), "episode": np.concatenate(E),
            "n_records": len(records), "n_used": used}


# --------------------------------------------------------------------------- DAgger
def visited_states(model, vn, env, problem, n_pick: int, rng, max_steps: int = 400, min_margin_deg: float = 0.5,
                   terminal_deg: Optional[float] = None, handover_deg: float = 0.0):
    """Fly ``problem`` with the deterministic policy; return up to ``n_pick`` visited states
    ``(q, ω)`` (at random control instants before the episode ended, with every cone at least
    ``min_margin_deg`` away), and the rollout's outcome.

    By default the states are on the way (more than 0.5° from the target). With
    ``terminal_deg``, only states within that angle of the target are picked, at random,
    and only from episodes that did not succeed: where a policy dithers at the target
    without coming to rest. States within ``handover_deg`` (a run's capture law, which
    flies there instead of the network) are never picked."""
    obs, info = env.reset(options={"problem": problem})
    states = []
    term = False
    for _ in range(max_steps):
        x = env.unwrapped.state
        err = info["attitude_error"]
        near = terminal_deg is not None and max(1e-4, math.radians(handover_deg)) < err <= math.radians(terminal_deg)
        far = terminal_deg is None and err > math.radians(0.5)
        if info["min_cone_margin"] >= math.radians(min_margin_deg) and (near or far):
            states.append(x)
        o = vn.normalize_obs(obs[None]) if vn is not None else obs[None]
        a, _ = model.predict(o, deterministic=True)
        obs, _, term, _, info = env.step(np.clip(np.asarray(a, float).reshape(3), -1.0, 1.0))
        if term:
            break
    outcome = "success" if info["is_success"] else ("violation" if info["violation"] else "timeout")
    if not states or (terminal_deg is not None and outcome == "success"):
        return [], outcome
    if terminal_deg is not None:
        idx = rng.choice(len(states), size=min(n_pick, len(states)), replace=False)
        return [states[i] for i in sorted(idx.tolist())], outcome
    # later states are where a drifting policy is worst off: half the picks from the last third
    k = min(n_pick, len(states))
    late = len(states) * 2 // 3
    idx = set(rng.choice(len(states), size=(k + 1) // 2, replace=False).tolist())
    if late < len(states):
        idx |= set(rng.choice(np.arange(late, len(states)), size=min(k // 2, len(states) - late),
                              replace=False).tolist())
    return [states[i] for i in sorted(idx)], outcome


def dagger(policy, family: str, seed: int, n_problems: int, out, n_pick: int = 2,
           margin_deg: float = DEFAULT_MARGIN_DEG, progress: bool = True, terminal_deg: Optional[float] = None) -> dict:
    """One DAgger round: fly ``policy`` on problems ``0 .. n_problems-1`` of (family, seed),
    pose the slew from visited states (same target and cones, the state's attitude and rate),
    and append their dense expert answers to ``out`` (resumable by problem index)."""
    from slew_env import SlewProblem
    from training.generate import GenerationSpec, problem_for

    from .bc import _env_for
    from .evaluate import load_policy
    from .train import capture_kwargs, shield_kwargs

    model, vn, cfg = load_policy(policy)
    capture = capture_kwargs(cfg)
    env = _env_for(cfg.get("env_kwargs") or {}, shield_kwargs(cfg), capture)   # fly the policy as its config says
    handover = capture["deg"] if capture else 0.0
    if terminal_deg is not None and terminal_deg <= handover:
        raise ValueError(f"--terminal-deg: {terminal_deg:g}° is inside the policy's capture angle ({handover:g}°), "
                         "where the capture law flies, not the network; use a larger angle")
    spec = GenerationSpec(family=family, seed=int(seed), n=int(n_problems))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    have = {r["index"] for r in load_records(out)}
    outcomes = {}
    t0 = time.perf_counter()
    n_new = 0
    with _open_append(out) as f:
        for i in range(n_problems):
            if i in have:
                continue
            prob = problem_for(spec, i)
            rng = np.random.default_rng([int(seed), i, 7])
            states, outcome = visited_states(model, vn, env, prob, n_pick, rng, terminal_deg=terminal_deg,
                                             handover_deg=handover)
            outcomes[outcome] = outcomes.get(outcome, 0) + 1
            for j, x in enumerate(states):
                d = prob.to_dict()
                d["q0"] = (x[:4] / np.linalg.norm(x[:4])).tolist()
                d["omega0"] = x[4:7].tolist()
                rec = {"index": i, "sub": j, "family": family, "seed": int(seed), "dagger_policy": str(policy),
                       "policy_outcome": outcome}
                try:
                    sub = SlewProblem.from_dict(d)
                except ValueError as e:
                    rec.update(success=False, message=str(e))
                else:
                    rec.update(solve_dense(sub, margin_deg))
                f.write(json.dumps(rec) + "\n")
                n_new += 1
            f.flush()
            if progress and (i + 1) % 25 == 0:
                print(f"dagger: {i + 1}/{n_problems} problems, {n_new} states solved, "
                      f"{time.perf_counter() - t0:.0f} s, outcomes {outcomes}", file=sys.stderr, flush=True)
    env.close()
    return {"outcomes": outcomes, "new_records": n_new, "time_s": time.perf_counter() - t0}


# --------------------------------------------------------------------------- command line
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m training.rl.dense_expert", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("solve", help="solve expert problems with inflated cones (resumable)")
    s.add_argument("--family", default="pointing-cones")
    s.add_argument("--seed", type=int, default=1)
    s.add_argument("--n", type=int, required=True)
    s.add_argument("--margin-deg", type=float, default=DEFAULT_MARGIN_DEG)
    s.add_argument("--out", default=None)
    g = sub.add_parser("dagger", help="one DAgger round: expert answers from states a policy visits")
    g.add_argument("policy")
    g.add_argument("--family", default="pointing-cones")
    g.add_argument("--seed", type=int, required=True, help="seed of the problems flown (not the evaluation's)")
    g.add_argument("--n", type=int, required=True, help="problems flown")
    g.add_argument("--pick", type=int, default=2, help="visited states solved per problem")
    g.add_argument("--margin-deg", type=float, default=DEFAULT_MARGIN_DEG)
    g.add_argument("--terminal-deg", type=float, default=None,
                   help="pick only states within this angle of the target, from episodes that did not succeed "
                        "(where a policy dithers without coming to rest); default: states on the way")
    g.add_argument("--threads", type=int, default=1)
    g.add_argument("--out", required=True)
    st = sub.add_parser("stats", help="summary of a dense expert file")
    st.add_argument("path")
    args = p.parse_args(argv)
    if args.cmd == "solve":
        out = args.out or default_dense_path(args.family, args.seed)
        recs = solve_range(args.family, args.seed, args.n, out, args.margin_deg)
        ok = [r for r in recs if r.get("success")]
        print(f"{out}: {len(ok)}/{len(recs)} solved")
        return 0
    if args.cmd == "dagger":
        import torch
        torch.set_num_threads(args.threads)
        if args.terminal_deg is not None and not 0.0 < args.terminal_deg < 180.0:
            raise SystemExit(f"--terminal-deg: must be in (0, 180), got {args.terminal_deg}")
        res = dagger(args.policy, args.family, args.seed, args.n, args.out, args.pick, args.margin_deg,
                     terminal_deg=args.terminal_deg)
        print(json.dumps(res))
        return 0
    recs = load_records(args.path)
    ok = [r for r in recs if r.get("success")]
    mm = np.array([r["min_margin_deg"] for r in ok if r.get("min_margin_deg") is not None])
    print(json.dumps({"records": len(recs), "solved": len(ok),
                      "median_tf": float(np.median([r["tf"] for r in ok])) if ok else None,
                      "median_wall_s": float(np.median([r["wall_time_s"] for r in recs])) if recs else None,
                      "min_margin_deg": {"min": float(mm.min()), "median": float(np.median(mm))} if len(mm) else None},
                     indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
