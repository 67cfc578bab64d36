"""``slew evaluate-rl`` and behaviour cloning on tiny policies and three held-out problems."""
import json
import math

import numpy as np
import pytest
import yaml

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

from training.rl import SHIPPED_POLICIES  # noqa: E402
from training.rl.bc import build_dataset, clone_actor, compare, control_from_record, solve_problems  # noqa: E402
from training.rl.evaluate import evaluate, heldout_problems  # noqa: E402
from training.rl.train import train  # noqa: E402

SEED = 100    # held-out problems 0..2 of this seed: two verified optima, one local-optimum failure (~7 s)
TINY = {"n_envs": 2, "n_timesteps": 256, "policy": "MlpPolicy",
        "policy_kwargs": {"net_arch": {"pi": [32, 32], "vf": [32, 32]}},
        "hyperparameters": {"n_steps": 128, "batch_size": 64, "n_epochs": 1},
        "normalize": {"norm_obs": True, "norm_reward": False},
        "env_kwargs": {"max_episode_steps": 100}, "eval": None, "checkpoint": None,
        "bc": {"epochs": 3}}
REPORT_KEYS = {"n", "n_success", "success_rate", "n_violation", "violation_rate", "tf_policy_median",
               "solver_ok", "solver_failed", "solver_refused", "ratio_n", "ratio_median", "ratio_mean",
               "ratio_p95"}


@pytest.fixture(scope="module")
def solutions(tmp_path_factory):
    path = tmp_path_factory.mktemp("sol") / f"full-attitude-seed{SEED}.jsonl"
    recs = solve_problems("full-attitude", 3, SEED, path, workers=1, progress=False)
    assert [r["index"] for r in recs] == [0, 1, 2]
    return path, recs


@pytest.fixture(scope="module")
def tiny_policy(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tiny")
    cfg = tmp / "ppo.yaml"
    cfg.write_text(yaml.safe_dump({"full-attitude": TINY}))
    out = tmp / "run"
    train("ppo", "full-attitude", config=cfg, seed=0, out=out)
    return cfg, out


def _check_report(out, n):
    for f in ("report.md", "results.json"):
        assert (out / f).exists(), f
    res = json.loads((out / "results.json").read_text())
    assert REPORT_KEYS <= set(res["summary"]) and res["summary"]["n"] == n and len(res["episodes"]) == n
    md = (out / "report.md").read_text()
    assert "tf_policy / tf_optimal: median" in md and "success rate" in md
    return res


def test_evaluate_tiny_policy_writes_report(tiny_policy, solutions, tmp_path):
    _, run = tiny_policy
    sol_path, recs = solutions
    res = evaluate(run, n=3, seed=SEED, out=tmp_path / "rep", plot_k=2, solutions=sol_path, progress=False)
    out = tmp_path / "rep"
    rj = _check_report(out, 3)
    assert (out / "overlay.png").stat().st_size > 10_000
    s = res["summary"]
    ok = sum(r["success"] is True for r in recs)
    assert s["solver_ok"] == ok and s["solver_ok"] + s["solver_failed"] + s["solver_refused"] == 3
    for e in rj["episodes"]:
        assert (e["tf_optimal"] is not None) == (e["solver"] == "ok")
        if e["success"] and e["solver"] == "ok":
            assert math.isfinite(e["ratio"]) and e["ratio"] > 0.5
        else:
            assert e["ratio"] is None


def refuse_cones(problem, **options):
    """A solve route that raises, as solvers.solve did for every cone problem before the cone solver."""
    raise ValueError("cones: keep-out cones are not supported by this route")


def test_evaluate_cone_family_counts_solver_refusals(tiny_policy, tmp_path):
    _, run = tiny_policy
    res = evaluate(run, family="pointing-cones", n=2, seed=3, out=tmp_path / "cones", plot_k=1,
                   solutions=tmp_path / "cones.jsonl", progress=False,
                   solve_fn=f"{__name__}:refuse_cones")
    s = res["summary"]
    assert s["solver_refused"] == 2 and s["ratio_n"] == 0 and s["n_with_cones"] == 2
    assert "cones" in next(iter(s["solver_reasons"]))
    assert all(e["tf_optimal"] is None and e["ratio"] is None for e in res["episodes"])
    _check_report(tmp_path / "cones", 2)
    assert (tmp_path / "cones" / "overlay.png").exists()
    assert "refused" in (tmp_path / "cones" / "report.md").read_text()


def test_shipped_policy_has_finite_ratio(solutions, tmp_path):
    path = SHIPPED_POLICIES["full-attitude"]
    if not (path / "model.zip").exists():
        pytest.skip("no shipped policy")
    sol_path, recs = solutions
    res = evaluate(path, n=3, seed=SEED, out=tmp_path / "shipped", plot_k=1, solutions=sol_path, progress=False)
    _check_report(tmp_path / "shipped", 3)
    ratios = [e["ratio"] for e in res["episodes"] if e["solver"] == "ok" and e["success"]]
    assert ratios and all(0.8 < r < 3.0 for r in ratios)
    from training.cli import main
    assert main(["evaluate-rl", "shipped", "--n", "3", "--seed", str(SEED), "--solutions", str(sol_path),
                 "--out", str(tmp_path / "cli"), "--plot-k", "0", "--no-progress"]) == 0


def test_bc_dataset_shapes_and_cloning_reduces_mse(solutions, tiny_policy):
    _, recs = solutions
    ok = [r for r in recs if r["success"] is True]
    assert ok
    # the optimal control: bang-bang, unit torque, zero after tf
    u = control_from_record(ok[0])
    tf = ok[0]["tf"]
    vals = u(np.linspace(0, tf, 50))
    assert vals.shape == (50, 3) and np.allclose(np.abs(vals), 1.0)
    assert np.all(u(np.array([tf * 1.01])) == 0.0)
    data = build_dataset(ok, {}, "average")
    n = len(data["obs"])
    assert data["n_flown"] == len(ok) and 1 <= data["n_episodes"] <= len(ok) and n > 20
    assert data["obs"].shape == (n, 51) and data["obs"].dtype == np.float32
    assert data["actions"].shape == (n, 3) and np.all(np.abs(data["actions"]) <= 1.0)
    assert data["next_obs"].shape == (n, 51) and data["returns"].shape == (n,)
    # the flown optimal control (averaged over each step) reaches the success region; episodes
    # that do not (switch times of a collocation answer with a singular arc) are dropped
    assert data["replay_success_rate"] >= 0.5
    assert data["n_episodes"] == round(data["replay_success_rate"] * data["n_flown"])
    assert np.all(data["terminated"][np.r_[np.diff(data["episode"]) != 0, True]])
    from stable_baselines3 import PPO
    _, run = tiny_policy
    model = PPO.load(str(run / "model.zip"), device="cpu")
    obs = (data["obs"] - data["obs"].mean(0)) / (data["obs"].std(0) + 1e-3)
    hist = clone_actor(model, obs, data["actions"], epochs=4, batch_size=32, learning_rate=3e-3)
    assert len(hist["train_mse"]) == 5
    assert hist["train_mse"][-1] < 0.7 * hist["train_mse"][0]


def test_tiny_compare(tiny_policy, solutions, tmp_path):
    cfg, _ = tiny_policy
    sol_path, _ = solutions
    res = compare("ppo", "full-attitude", timesteps=256, episodes=3, n_eval=3, seed=0, out=tmp_path / "cmp",
                  config=cfg, eval_seed=SEED, bc_seed=SEED, expert_data=sol_path, solutions=sol_path)
    assert [r["variant"] for r in res["rows"]] == ["scratch", "bc", "bc+rl"]
    assert res["rows"][1]["rl_steps"] == 0 and res["rows"][0]["rl_steps"] >= 256
    md = (tmp_path / "cmp" / "compare.md").read_text()
    assert "| scratch |" in md and "| bc+rl |" in md
    info = json.loads((tmp_path / "cmp" / "bc-rl" / "train_info.json").read_text())
    assert info["bc"]["n_pairs"] > 0 and info["bc"]["train_mse_last"] < info["bc"]["train_mse_first"]


def test_heldout_problems_are_deterministic():
    a = heldout_problems("full-attitude", 2, 7)
    b = heldout_problems("full-attitude", 2, 7)
    assert a == b and a[0] != a[1]


def test_sac_bc_pretrain_prefills_replay_and_warms_up(solutions, tmp_path):
    sol_path, _ = solutions
    cfg = tmp_path / "sac.yaml"
    cfg.write_text(yaml.safe_dump({"full-attitude": {
        "n_envs": 1, "n_timesteps": 300, "policy_kwargs": {"net_arch": [32, 32]},
        "hyperparameters": {"buffer_size": 2000, "learning_starts": 1000, "batch_size": 32},
        "env_kwargs": {"max_episode_steps": 100}, "eval": None, "checkpoint": None,
        "bc": {"epochs": 3, "actor_warmup": 100, "ent_coef_init": 0.02, "rl_learning_rate": 1e-4}}}))
    info = train("sac", "full-attitude", config=cfg, seed=0, out=tmp_path / "run", bc_pretrain=3,
                 expert_data=sol_path, bc_seed=SEED)
    bc = info["bc"]
    assert bc["replay_prefilled"] > 20 and bc["actor_warmup"] == 100 and bc["ent_coef_init"] == 0.02
    assert bc["train_mse_last"] < bc["train_mse_first"]
    from stable_baselines3 import SAC
    m = SAC.load(str(tmp_path / "run" / "model.zip"), device="cpu")
    assert m.learning_starts == 0 and m.num_timesteps >= 300
    assert all(p.requires_grad for p in m.actor.parameters())


def test_best_known_keeps_the_fastest_verified_answer(tmp_path):
    import json

    from training.rl.best_known import merge

    head = {"_meta": {"family": "pointing-cones", "seed": 100}}
    a = [head, {"index": 0, "success": True, "tf": 2.0}, {"index": 1, "success": True, "tf": 3.0}]
    b = [head, {"index": 0, "success": True, "tf": 1.5}, {"index": 1, "success": False, "tf": 1.0},
         {"index": 2, "success": True, "tf": 4.0}]
    for name, rows in (("a", a), ("b", b)):
        (tmp_path / f"{name}.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n{\"cut")
    res = merge(tmp_path / "out.jsonl", [tmp_path / "a.jsonl", tmp_path / "b.jsonl"])
    rows = [json.loads(x) for x in (tmp_path / "out.jsonl").read_text().splitlines()]
    assert rows[0] == head and res["problems"] == 3
    assert [(r["index"], r["tf"]) for r in rows[1:]] == [(0, 1.5), (1, 3.0), (2, 4.0)]
    other = tmp_path / "c.jsonl"
    other.write_text(json.dumps({"_meta": {"family": "pointing-cones", "seed": 7}}) + "\n")
    with pytest.raises(ValueError, match="seed"):
        merge(tmp_path / "o2.jsonl", [tmp_path / "a.jsonl", other])
