"""ConeShield: the keep-out-cone safety filter on the environment's observation."""
import math
import warnings

import gymnasium as gym
import numpy as np
import pytest

from slew_env import SlewEnv, SlewProblem
from slew_env.core import dynamics
from slew_env.core import env_kernels as K
from slew_env.core import shield as S
from slew_env.shield import ConeShield, ConeShieldFilter


def _cone_problem(J=(0.6, 0.9, 1.0), umax=(1.0, 0.7, 1.0), norm="inf"):
    # sensor +x, target 100° away about z, a 20° cone centred on the short path at 50°
    return SlewProblem(inertia=J, torque_max=umax, torque_norm=norm, q0=[1, 0, 0, 0], sensor_axis=[1, 0, 0],
                       sensor_target=[math.cos(math.radians(100)), math.sin(math.radians(100)), 0.0],
                       cones=[{"axis": [math.cos(math.radians(50)), math.sin(math.radians(50)), 0.05],
                               "half_angle_deg": 20.0}])


def _obs64(env):
    obs = np.zeros(K.obs_length(env.max_cones))
    K.write_obs(env.task_array, env.state, obs)
    return obs


def _pd(obs):
    """Straight at the target: a PD law on the error quaternion (enters the cone across the path)."""
    dq = obs[K.OB_DQ:K.OB_DQ + 4]
    w = obs[K.OB_W:K.OB_W + 3]
    ang = 2.0 * math.atan2(np.linalg.norm(dq[1:]), dq[0])
    axis = dq[1:] / max(np.linalg.norm(dq[1:]), 1e-12)
    return np.clip(5.0 * ang * axis - 3.0 * w, -1.0, 1.0)


def _fly_pd(env, steps=400, **reset):
    """Fly the PD law in ``env`` (reset with ``reset``) until it ends: ``(last info, smallest cone
    margin, steps where the filter changed the action)``."""
    obs, _ = env.reset(**reset)
    worst, active = math.inf, 0
    for _ in range(steps):
        obs, _, term, _, info = env.step(_pd(obs))
        worst = min(worst, info["min_cone_margin"])
        active += info.get("shield_active", 0)
        if term:
            break
    return info, worst, active


@pytest.mark.parametrize("v", [[0.0, 0.0, 0.0], [1.0, -0.3, 0.5], [-0.2, 0.9, -1.0]])
def test_barrier_terms_are_the_derivatives_of_the_flown_margin(v):
    """h(τ) of the propagated body equals h + ḣτ + ½(G·v + a0)τ² to third order."""
    env = SlewEnv(task_distribution="pointing-cones", terminate_on_violation=False)
    # physical units (time unit T = 10 s): the filter works on the scale-free observation
    env.reset(options={"problem": _cone_problem(J=(60.0, 90.0, 100.0))})
    T = env.problem.time_unit
    assert T == pytest.approx(10.0)
    # put the body in a spinning state near the cone
    x = np.array([math.cos(0.3), 0.05, 0.02, math.sin(0.3), 0.4 / T, -0.3 / T, 0.7 / T])
    x[:4] /= np.linalg.norm(x[:4])
    task = env.task_array
    obs = np.zeros(K.obs_length(env.max_cones))
    K.write_obs(task, x, obs)
    h, hd, G0, G1, G2, a0 = S.cone_barrier_terms(obs, 0, 0.0)
    hdd = G0 * v[0] + G1 * v[1] + G2 * v[2] + a0
    assert abs(G0) + abs(G1) + abs(G2) > 0.1 and abs(hd) > 0.01    # a non-trivial state
    p = env.problem
    u = np.asarray(v) * np.asarray(p.torque_max)                     # per-axis bound: no scaling
    for tau in (2e-3, 1e-3):
        xs = dynamics.propagate(x.copy(), u, np.asarray(p.inertia, float), tau * T, 50)
        xe = xs[-1] if np.ndim(xs) == 2 else xs
        obs_e = np.zeros_like(obs)
        K.write_obs(task, np.asarray(xe, float), obs_e)
        h_e = S.cone_barrier_terms(obs_e, 0, 0.0)[0]
        taylor = h + hd * tau + 0.5 * hdd * tau * tau
        # the second-order term is ~1e-6..1e-7 here; the remainder is third order
        assert abs(h_e - taylor) < 2e-3 * abs(0.5 * hdd * tau * tau) + 5e-9 * (tau / 1e-3) ** 3


def test_margin_uses_the_true_cone_geometry():
    env = SlewEnv(task_distribution="pointing-cones")
    env.reset(options={"problem": _cone_problem()})
    obs = _obs64(env)
    h = S.cone_barrier_terms(obs, 0, 0.0)[0]
    margin = obs[K.OB_CONES + 4]           # angle(sensor, axis) - half-angle
    alpha = obs[K.OB_CONES + 3]
    assert h == pytest.approx(math.cos(alpha) - math.cos(alpha + margin), abs=1e-12)
    assert h > 0


def test_far_from_the_cones_the_action_is_unchanged():
    f = ConeShieldFilter()
    env = SlewEnv(task_distribution="pointing-cones")
    env.reset(options={"problem": _cone_problem()})
    obs = _obs64(env)                      # at rest, 30° from the cone
    for a in ([1.0, -1.0, 0.5], [0.0, 0.0, 0.0], [-0.25, 0.75, 1.0]):
        out = f(obs, np.array(a))
        assert np.array_equal(out, np.array(a))
        assert f.last[S.F_ACTIVE] == 0
    # no cones at all: never filtered
    env2 = SlewEnv(task_distribution="full-attitude")
    o2, _ = env2.reset(seed=3)
    assert np.array_equal(f(o2, np.array([1.0, 1.0, -1.0])), [1.0, 1.0, -1.0])


def test_pd_law_enters_the_cone_without_the_shield_and_not_with_it():
    prob = {"options": {"problem": _cone_problem()}}
    info, worst, _ = _fly_pd(SlewEnv(task_distribution="pointing-cones", terminate_on_violation=False), **prob)
    assert worst < -math.radians(5)                       # straight through the cone
    info, worst, active = _fly_pd(ConeShield(SlewEnv(task_distribution="pointing-cones")), **prob)
    assert not info["violation"] and info["is_success"]   # round it, and onto the target
    assert worst > 0.0 and active > 0


def test_pd_law_with_the_shield_on_drawn_cone_problems():
    """30 drawn pointing-cones tasks: the PD law alone violates most; with the filter none."""
    counts = {"bare": 0, "shield": 0}
    margins = []
    for seed in range(30):
        for name, env in (("bare", SlewEnv(task_distribution="pointing-cones")),
                          ("shield", ConeShield(SlewEnv(task_distribution="pointing-cones")))):
            info, worst, _ = _fly_pd(env, seed=seed)
            counts[name] += info["violation"]
            if name == "shield":
                margins.append(worst)
    assert counts["bare"] >= 15
    assert counts["shield"] == 0
    assert min(margins) > 0.0


def test_p_norm_bound_filtered_action_stays_in_the_inscribed_box():
    f = ConeShieldFilter()
    env = SlewEnv(task_distribution="pointing-cones", terminate_on_violation=False)
    obs, _ = env.reset(options={"problem": _cone_problem(norm=2)})
    seen = 0
    for _ in range(200):
        a = _pd(obs)
        v = f(obs, a)
        if f.last[S.F_ACTIVE] > 0:
            seen += 1
            assert np.all(np.abs(v) <= 3 ** -0.5 + 1e-12)
        obs, _, term, _, info = env.step(v)
        assert not info["violation"]
        if term:
            break
    assert seen > 0


def test_p_norm_bound_the_conditions_are_checked_on_the_action_the_environment_flies():
    """An action outside the p-ball is flown scaled onto it: the filter treats it so."""
    f = ConeShieldFilter()
    env = SlewEnv(task_distribution="pointing-cones", terminate_on_violation=False)
    rng = np.random.default_rng(5)
    n_active = 0
    for seed in range(40):
        obs, _ = env.reset(options={"problem": _cone_problem(norm=2)}, seed=seed)
        for _ in range(int(rng.integers(5, 40))):
            obs, *_ = env.step(_pd(obs))
        a = rng.choice([-1.0, 1.0], 3) * rng.uniform(0.7, 1.0, 3)       # outside the unit 2-ball
        flown = a / np.linalg.norm(a)
        np.testing.assert_allclose(f(obs, a), f(obs, flown), atol=1e-12)
        n_active += f.last[S.F_ACTIVE] > 0
    assert n_active > 0


def test_infeasible_condition_pushes_away_as_hard_as_the_box_allows():
    f = ConeShieldFilter()
    env = SlewEnv(task_distribution="pointing-cones", terminate_on_violation=False)
    env.reset(options={"problem": _cone_problem()})
    # racing straight at the cone, 1° from it: no torque in the box can stop in time
    x = env.state
    obs = np.zeros(K.obs_length(4))
    K.write_obs(env.task_array, x, obs)
    c = obs[K.OB_CONES:K.OB_CONES + 3]
    b = obs[K.OB_SENSOR:K.OB_SENSOR + 3]
    x[4:7] = 3.0 * np.cross(b, c) / np.linalg.norm(np.cross(b, c)) / env.problem.time_unit
    K.write_obs(env.task_array, x, obs)
    v = f(obs, np.zeros(3))
    assert f.last[S.F_FEASIBLE] == 0 and f.last[S.F_ACTIVE] == 1
    G = np.array(S.cone_barrier_terms(obs, 0, 0.0)[2:5])
    np.testing.assert_allclose(v, np.sign(G), atol=1e-5)      # the largest G·v the box gives


def test_zero_cone_slots_and_a_longer_control_step():
    f = ConeShieldFilter(max_cones=0)
    env = SlewEnv(task_distribution="full-attitude", max_cones=0)
    obs, _ = env.reset(seed=0)
    assert np.array_equal(f(obs, np.array([0.3, -1.0, 1.0])), [0.3, -1.0, 1.0])
    with pytest.warns(UserWarning, match="control_dt"):
        ConeShield(SlewEnv(task_distribution="pointing-cones", control_dt=0.1))
    with pytest.warns(UserWarning, match=r"brake <= 0\.3"):       # the margin alone is not enough
        ConeShield(SlewEnv(task_distribution="pointing-cones", control_dt=0.1), margin_deg=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ConeShield(SlewEnv(task_distribution="pointing-cones", control_dt=0.1), margin_deg=1.0, brake=0.3)
    with pytest.raises(ValueError, match="sweeps"):
        ConeShieldFilter(sweeps=float("inf"))
    with pytest.raises(ValueError, match="max_cones"):
        ConeShieldFilter(max_cones=float("nan"))


def test_batch_equals_rows_and_nan_action_is_zero():
    f = ConeShieldFilter()
    env = SlewEnv(task_distribution="pointing-cones")
    obs_rows, acts = [], []
    for seed in range(6):
        o, _ = env.reset(seed=seed)
        for _ in range(10):
            o, _, terminated, *_ = env.step(_pd(o))
            if terminated:   # a terminated episode takes no more steps (ResetNeeded)
                break
        obs_rows.append(o)
        acts.append(_pd(o))
    O, A = np.array(obs_rows), np.array(acts)
    batch = f(O, A)
    rows = np.array([f(o, a) for o, a in zip(O, A)])
    assert np.array_equal(batch, rows)
    v = f(obs_rows[0], np.array([np.nan, 0.5, np.nan]))
    np.testing.assert_array_equal(v, f(obs_rows[0], np.array([0.0, 0.5, 0.0])))   # NaN flies as zero torque
    # float32 observations (as the environment gives them) and float64 give the same action
    np.testing.assert_array_equal(f(O.astype(np.float32), A), f(O.astype(np.float64), A))
    with pytest.raises(ValueError, match="obs: not finite"):
        bad = obs_rows[0].copy()
        bad[K.OB_W] = np.nan
        f(bad, np.zeros(3))


def test_bad_arguments_name_the_field():
    with pytest.raises(ValueError, match="margin_deg"):
        ConeShieldFilter(margin_deg=-1)
    with pytest.raises(ValueError, match="barrier_rate"):
        ConeShieldFilter(barrier_rate=float("nan"))
    with pytest.raises(ValueError, match="brake"):
        ConeShieldFilter(brake=1.5)
    with pytest.raises(ValueError, match="sweeps"):
        ConeShieldFilter(sweeps=0)
    with pytest.raises(ValueError, match="gap_deg"):
        ConeShieldFilter(gap_deg=-1.0)
    with pytest.raises(ValueError, match="gap_deg"):
        ConeShieldFilter(gap_deg=None)
    with pytest.raises(ValueError, match="brake"):
        ConeShieldFilter(brake="fast")
    with pytest.raises(ValueError, match="max_cones"):
        ConeShieldFilter(max_cones=99)
    f = ConeShieldFilter(max_cones=4)
    with pytest.raises(ValueError, match="obs"):
        f(np.zeros(10), np.zeros(3))
    with pytest.raises(ValueError, match="action"):
        f(np.zeros(K.obs_length(4)), np.zeros(4))
    with pytest.raises(ValueError, match="env"):
        ConeShield(gym.make("Pendulum-v1"))
    env = ConeShield(SlewEnv(task_distribution="pointing-cones"))
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(3))


def test_wrapper_reports_filter_activity_in_info():
    env = ConeShield(SlewEnv(task_distribution="pointing-cones"))
    obs, _ = env.reset(options={"problem": _cone_problem()})
    keys = set()
    any_active = False
    for _ in range(100):
        obs, _, term, _, info = env.step(_pd(obs))
        keys |= set(info)
        any_active |= info["shield_active"] > 0
        if term:
            break
    assert {"shield_active", "shield_feasible"} <= keys and any_active


def test_vector_wrapper_flies_each_copy_as_the_single_wrapper():
    from slew_env import SlewVectorEnv
    from slew_env.shield import ConeShieldVector

    n = 4
    problems = []
    for seed in range(n):
        e = SlewEnv(task_distribution="pointing-cones")
        e.reset(seed=seed)
        problems.append(e.problem)
    vec = ConeShieldVector(SlewVectorEnv(num_envs=n, task_distribution="pointing-cones"))
    obs, _ = vec.reset(seed=11, options={"problems": problems})
    singles = []
    for i in range(n):
        env = ConeShield(SlewEnv(task_distribution="pointing-cones"))
        o, _ = env.reset(options={"problem": problems[i]})
        np.testing.assert_array_equal(o, obs[i])
        singles.append((env, o))
    active = 0
    for _ in range(30):
        acts = np.array([_pd(o) for o in obs])
        obs, _, term, _, infos = vec.step(acts)
        active += int(infos["shield_active"].sum())
        for i, (env, o) in enumerate(singles):
            o2, _, t2, _, _ = env.step(_pd(o))
            singles[i] = (env, o2)
            if not term[i]:
                np.testing.assert_array_equal(o2, obs[i])
        if term.any():
            break
    assert active > 0
    # through autoreset: the step that resets an ended copy has no filter entry for it
    vec = ConeShieldVector(SlewVectorEnv(num_envs=n, task_distribution="pointing-cones", max_episode_steps=20))
    obs, _ = vec.reset(seed=3)
    ended = np.zeros(n, bool)
    seen_reset = 0
    for _ in range(60):
        obs, _, term, trunc, infos = vec.step(np.array([_pd(o) for o in obs]))
        np.testing.assert_array_equal(infos["_shield_active"], ~ended)
        assert np.all(infos["shield_active"][ended] == 0)
        seen_reset += int(ended.sum())
        ended = term | trunc
    assert seen_reset > 0


def test_training_config_wraps_the_environments_and_evaluation_follows_the_run():
    from training.rl.evaluate import resolve_shield
    from training.rl.train import load_config, make_vec, shield_kwargs

    cfg = load_config("ppo", "pointing-cones")
    assert shield_kwargs(cfg) == {"margin_deg": 0.5, "barrier_rate": 20.0, "brake": 0.6, "gap_deg": 1.0}
    venv = make_vec(cfg, 2, seed=0)

    def chain(e):
        out = []
        while isinstance(e, gym.Wrapper):
            out.append(type(e).__name__)
            e = e.env
        return out

    from training.rl.capture import CaptureHandover
    for e in venv.envs:                  # the capture law's actions pass through the filter too
        names = chain(e)
        assert names.index("CaptureHandover") < names.index("ConeShield")
        assert isinstance(e, CaptureHandover)
    venv.reset()
    _, _, _, infos = venv.step(np.zeros((2, 3), np.float32))
    assert "shield_active" in infos[0] and "captured" in infos[0]
    assert shield_kwargs(load_config("ppo", "full-attitude")) is None
    assert shield_kwargs({"shield": True}) == {}
    with pytest.raises(ValueError, match="shield"):
        shield_kwargs({"shield": {"margin": 1.0}})
    with pytest.raises(ValueError, match="shield.brake"):
        shield_kwargs({"shield": {"brake": 0.0}})
    with pytest.raises(ValueError, match="shield"):
        shield_kwargs({"shield": "yes"})
    # evaluation: the run's filter by default, the defaults on request, none when off
    assert resolve_shield("policy", cfg) == shield_kwargs(cfg)
    assert resolve_shield("off", cfg) is None
    assert resolve_shield("on", {"shield": None}) == {}
    assert resolve_shield("policy", {"shield": None}) is None
    with pytest.raises(ValueError, match="--shield"):
        resolve_shield("maybe", cfg)


def test_two_overlapping_cones_across_the_path_are_not_squeezed_through():
    """Two 20° cones whose axes are 39.4° apart overlap across the short path: the PD law cuts
    through the overlap (−0.28°); through the filter it stays clear of both (it cannot pass)."""
    d = math.radians
    prob = SlewProblem(inertia=(0.5, 0.8, 1.0), torque_max=1.0, q0=[1, 0, 0, 0], sensor_axis=[1, 0, 0],
                       sensor_target=[math.cos(d(120)), math.sin(d(120)), 0.0],
                       cones=[{"axis": [math.cos(d(60)), math.sin(d(60)), math.sin(d(21))], "half_angle_deg": 20.0},
                              {"axis": [math.cos(d(60)), math.sin(d(60)), -math.sin(d(21))], "half_angle_deg": 20.0}])
    worst = {}
    for shield in (False, True):
        env = SlewEnv(task_distribution="pointing-cones", terminate_on_violation=False)
        env = ConeShield(env) if shield else env
        worst[shield] = _fly_pd(env, options={"problem": prob})[1]
    assert worst[False] < -math.radians(0.1)
    assert worst[True] > 0.0


def test_rollout_history_records_the_torque_flown_after_the_filter():
    from training.rl.evaluate import rollout

    class Straight:
        def predict(self, o, deterministic=True):
            return _pd(np.asarray(o, float)[0])[None], None

    env = ConeShield(SlewEnv(task_distribution="pointing-cones"))
    r = rollout(Straight(), None, env, _cone_problem(), max_steps=400, history=True)
    assert r["success"] and not r["violation"] and r["shield_steps"] > 0
    u = r["history"]["u"]
    # replay the recorded torques open loop on the bare environment: the same flight
    bare = SlewEnv(task_distribution="pointing-cones")
    obs, _ = bare.reset(options={"problem": _cone_problem()})
    for k, uk in enumerate(u):
        obs, _, term, _, info = bare.step(uk)       # recorded as u / u_max
    assert info["is_success"] and k + 1 == r["steps"]
    assert len({tuple(np.round(x, 12)) for x in u}) > 3


def _gap_problem(gap_deg, target_deg=120.0):
    """Two 20° cones either side of the short path (the equator), ``gap_deg`` apart at 60°."""
    d = math.radians
    e = 20.0 + 0.5 * gap_deg                     # elevation of each axis
    return SlewProblem(inertia=(0.5, 0.8, 1.0), torque_max=1.0, q0=[1, 0, 0, 0], sensor_axis=[1, 0, 0],
                       sensor_target=[math.cos(d(target_deg)), math.sin(d(target_deg)), 0.0],
                       cones=[{"axis": [math.cos(d(60)) * math.cos(d(e)), math.sin(d(60)) * math.cos(d(e)), s * math.sin(d(e))],
                               "half_angle_deg": 20.0} for s in (1.0, -1.0)])


def _bridges(obs, gap, delta=0.0):
    B = np.zeros((2, 4))
    n = S.pair_bridges(obs, 0, 1, gap, delta, B)
    return B[:n]


def _width_at(p, obs):
    """Angular width of the free corner at ``p``: its clearance from both cones of ``obs``."""
    c = [obs[K.OB_CONES + K.OB_CONE_STRIDE * k:K.OB_CONES + K.OB_CONE_STRIDE * k + 4] for k in (0, 1)]
    return sum(math.acos(np.dot(p, ck[:3])) - ck[3] for ck in c)


def test_a_narrow_gap_between_two_cones_is_closed_by_a_bridge():
    """The bridge sits on the gap point; at its rim the gap is 2·(threshold + margin) wide."""
    d = math.radians
    env = SlewEnv(task_distribution="pointing-cones")
    env.reset(options={"problem": _gap_problem(0.2)})
    obs = _obs64(env)
    gap, delta = d(1.0), d(0.5)
    (b,) = _bridges(obs, gap, delta)
    m, r = b[:3], b[3]
    assert np.allclose(m, [math.cos(d(60)), math.sin(d(60)), 0.0], atol=1e-12)   # the gap point
    kappa = 1.0 / math.tan(d(20.0))
    assert r == pytest.approx(math.sqrt((2 * (gap + delta) - d(0.2)) / kappa), rel=1e-12)
    # the width at the rim, along the gap's own line (perpendicular to the axes' plane)
    along = np.cross(m, [0.0, 0.0, 1.0])
    along /= np.linalg.norm(along)
    assert _width_at(math.cos(r) * m + math.sin(r) * along, obs) == pytest.approx(2 * (gap + delta), rel=0.05)
    # a wide gap, a threshold of 0, a target in the gap, or a sensor already in it: no bridge
    env.reset(options={"problem": _gap_problem(3.0)})
    assert len(_bridges(_obs64(env), gap)) == 0
    env.reset(options={"problem": _gap_problem(0.2)})
    assert len(_bridges(_obs64(env), 0.0)) == 0
    env.reset(options={"problem": _gap_problem(0.2, target_deg=61.0)})
    assert len(_bridges(_obs64(env), gap)) == 0
    env.reset(options={"problem": _gap_problem(0.2)})
    obs = _obs64(env)
    obs[K.OB_SENSOR:K.OB_SENSOR + 3] = math.cos(0.5 * r) * m + math.sin(0.5 * r) * along   # inside the bridge
    assert len(_bridges(obs, gap)) == 0
    # an overlap smaller than the threshold is a gap too: one bridge on the gap point
    env.reset(options={"problem": _gap_problem(-0.5)})
    (b,) = _bridges(_obs64(env), gap)
    assert np.allclose(b[:3], [math.cos(d(60)), math.sin(d(60)), 0.0], atol=1e-12)


def _two_cones_obs(c1, a1, c2, a2, target=(0.0, 0.0, 1.0)):
    """An observation at rest with sensor +x, the given target and two cones (body axes as given)."""
    obs = np.zeros(K.obs_length(4))
    obs[K.OB_DQ] = 1.0
    obs[K.OB_SENSOR:K.OB_SENSOR + 3] = [1.0, 0.0, 0.0]
    obs[K.OB_TARGET:K.OB_TARGET + 3] = target
    obs[K.OB_J:K.OB_J + 3] = 1.0
    obs[K.OB_UMAX:K.OB_UMAX + 3] = 1.0
    for k, (c, a) in enumerate(((c1, a1), (c2, a2))):
        o = K.OB_CONES + K.OB_CONE_STRIDE * k
        obs[o:o + 3] = c
        obs[o + 3] = a
        obs[o + 5] = 1.0
    return obs


def test_bridges_in_degenerate_pairs():
    d = math.radians
    gap = d(1.0)
    # a small cone inside a larger one near its rim: no free corner, no bridge
    inner = [0.0, math.cos(d(19.6)), math.sin(d(19.6))]       # 19.6° + 0.3° < 20°
    assert len(_bridges(_two_cones_obs([0.0, 1.0, 0.0], d(20.0), inner, d(0.3)), gap)) == 0
    # a small cone beside a large one: the bridge is at most half the small cone plus the threshold
    near = [0.0, math.cos(d(30.0 + 10.0 + 0.2)), math.sin(d(30.0 + 10.0 + 0.2))]
    (b,) = _bridges(_two_cones_obs([0.0, 1.0, 0.0], d(30.0), near, d(10.0)), gap, d(0.5))
    assert b[3] == pytest.approx(d(5.0) + gap, rel=1e-12)
    # parallel axes that are not unit length (a crafted observation): no bridge, no crash
    for c2 in ([-0.99999994, 0.0, 0.0], [0.99999994, 0.0, 0.0]):
        obs = _two_cones_obs([1.0, 0.0, 0.0], d(89.9), c2, d(89.9))
        assert len(_bridges(obs, gap)) == 0
        v = ConeShieldFilter()(obs, np.array([0.2, 0.1, -0.3]))
        assert np.all(np.isfinite(v))


def test_the_sharp_notches_of_two_crossing_cones_are_closed_by_bridges():
    """Two cones overlapping by 4°: a bridge on each point where their rims cross, of the radius
    where the free corner is 2·threshold wide; overlapping by 30° (wide corners): none."""
    d = math.radians
    env = SlewEnv(task_distribution="pointing-cones")
    env.reset(options={"problem": _gap_problem(-4.0)})
    obs = _obs64(env)
    gap = d(1.0)
    bridges = _bridges(obs, gap)
    assert len(bridges) == 2
    c = [obs[K.OB_CONES + K.OB_CONE_STRIDE * k:K.OB_CONES + K.OB_CONE_STRIDE * k + 3] for k in (0, 1)]
    for b in bridges:
        x, r = b[:3], b[3]
        assert np.linalg.norm(x) == pytest.approx(1.0, abs=1e-12)
        for ck in c:                                                    # on both rims
            assert math.acos(np.dot(x, ck)) == pytest.approx(d(20.0), abs=1e-9)
        assert abs(x[2]) < 1e-9                                         # symmetric cones: on the equator
        # along the corner's bisector (the equator, away from the cones) the width at r is 2·gap
        mid = np.array([math.cos(d(60)), math.sin(d(60)), 0.0])
        away = np.cross(np.cross(x, -mid), x)                           # tangent at x, pointing from mid
        away /= np.linalg.norm(away)
        assert _width_at(math.cos(r) * x + math.sin(r) * away, obs) == pytest.approx(2 * gap, rel=0.1)
    env.reset(options={"problem": _gap_problem(-30.0)})
    assert len(_bridges(_obs64(env), gap)) == 0


@pytest.mark.parametrize("gap_deg, bare_below, bridged_above", [(0.2, 0.0, 0.2), (0.6, 0.0, 0.2),
                                                                  (-1.5, -0.5, 1.0), (-4.0, -0.5, 1.0)])
def test_pd_law_is_not_squeezed_into_a_narrow_gap_or_a_sharp_notch(gap_deg, bare_below, bridged_above):
    """Driven at a gap narrower than the two margins, or at the notch of two cones overlapping by a
    few degrees, the filter at brake 0.6 without the bridges cannot hold both cones (the PD law
    enters one, in a notch by over 0.5°); with them it stays clear of both."""
    worst = {}
    for bridge in (0.0, 1.0):
        env = ConeShield(SlewEnv(task_distribution="pointing-cones", terminate_on_violation=False),
                         brake=0.6, gap_deg=bridge)
        worst[bridge] = _fly_pd(env, 300, options={"problem": _gap_problem(gap_deg)})[1]
    assert worst[0.0] < math.radians(bare_below)
    assert worst[1.0] > math.radians(bridged_above)


def test_a_passable_gap_stays_open():
    """A gap wider than the threshold is flown through (the PD law reaches the target)."""
    env = ConeShield(SlewEnv(task_distribution="pointing-cones"), brake=0.6)
    info, _, _ = _fly_pd(env, 300, options={"problem": _gap_problem(1.2)})
    assert info["is_success"] and not info["violation"]
