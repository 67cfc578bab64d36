"""SlewProblem / Cone: validation (ValueError naming the field and the reason) and the
dict / JSON / file / task-array round trips."""
import json
import math
import warnings

import numpy as np
import pytest

from slew_env.core import quaternion as Q
from slew_env.core import task as T
from slew_env.problem import FIELDS, QUAT_REJECT_TOL, QUAT_SILENT_TOL, Cone, SlewProblem

QF_Z180 = [0.0, 0.0, 0.0, 1.0]
QF_R3 = [0.6830127, -0.1830127, -0.0616284, 0.7044160]


def base(**kw):
    """R1: J = I, |u_i| ≤ 1, rest to rest, 180° about z; overridden by ``kw``."""
    args = dict(inertia=[1.0, 1.0, 1.0], qf=QF_Z180)
    args.update(kw)
    return SlewProblem(**args)


def melton(alpha_deg, theta_deg, **kw):
    """R4: cone axis [cos α, sin α, 0] with half-angle α; sensor x starts on its boundary."""
    al = math.radians(alpha_deg)
    a = np.array([math.cos(al), math.sin(al), 0.0])
    e1 = np.array([1.0, 0.0, 0.0])
    th = math.radians(theta_deg)
    b = e1 * math.cos(th) - np.cross(e1, a) * math.sin(th) + (e1 @ a) * a * (1 - math.cos(th))
    return SlewProblem(inertia=[1, 1, 1], sensor_target=b,
                       cones=[{"axis": a.tolist(), "half_angle_deg": alpha_deg}], **kw)


def full_problem():
    """Every field set to a non-default value."""
    return SlewProblem(
        inertia=[5621.0, 4547.0, 2364.0], torque_max=[50.0, 40.0, 30.0], torque_norm=2.5,
        q0=Q.quat_from_euler321_deg(10, -5, 30), omega0=[0.01, -0.02, 0.03],
        qf=Q.quat_from_euler321_deg(-20, 10, 90), sensor_axis=[0.0, 1.0, 1.0],
        omegaf=[0.0, 0.001, 0.0], rate_max=[0.5, 0.4, 0.3],
        cones=[Cone([0.0, 0.0, -1.0], half_angle_deg=20.0),
               {"axis": [1.0, -1.0, 0.0], "half_angle": 0.2}])


# ====================================================================== basics
def test_defaults_and_properties():
    p = base()
    np.testing.assert_array_equal(p.inertia, [1, 1, 1])
    np.testing.assert_array_equal(p.torque_max, [1, 1, 1])       # scalar broadcast
    assert p.torque_norm == math.inf and p.p == math.inf
    np.testing.assert_array_equal(p.q0, [1, 0, 0, 0])
    np.testing.assert_array_equal(p.omega0, [0, 0, 0])
    np.testing.assert_array_equal(p.omegaf, [0, 0, 0])
    np.testing.assert_array_equal(p.sensor_axis, [1, 0, 0])
    assert p.sensor_target is None and p.rate_max is None and p.cones == ()
    assert not p.is_pointing and p.is_rest_to_rest
    assert p.slew_angle == pytest.approx(math.pi, abs=1e-15)
    np.testing.assert_allclose(p.start_direction, [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(p.target_direction, [-1, 0, 0], atol=1e-15)
    assert p.time_unit == 1.0


def test_reference_case_numbers():
    r3 = base(qf=QF_R3)
    assert r3.slew_angle == pytest.approx(1.6378, abs=5e-5)
    r5 = SlewProblem(inertia=[5621, 4547, 2364], torque_max=50, rate_max=0.5,
                     qf=[math.cos(math.radians(75)), math.sin(math.radians(75)), 0, 0])
    assert r5.slew_angle == pytest.approx(math.radians(150), abs=1e-12)
    assert r5.time_unit == pytest.approx(math.sqrt(5621 / 50), rel=1e-15)
    np.testing.assert_array_equal(r5.rate_max, [0.5, 0.5, 0.5])
    r2 = base(torque_norm=2)
    assert r2.torque_norm == 2.0
    assert not base(omega0=[0, 0, 0.1]).is_rest_to_rest


def test_arrays_are_read_only_copies():
    J = np.array([1.0, 2.0, 3.0])
    p = SlewProblem(inertia=J, qf=QF_Z180)
    J[0] = 100.0
    assert p.inertia[0] == 1.0
    for arr in (p.inertia, p.torque_max, p.q0, p.omega0, p.qf, p.sensor_axis, p.omegaf):
        with pytest.raises(ValueError):
            arr[0] = 0.5
    c = Cone([0, 0, 1], 0.3)
    with pytest.raises(ValueError):
        c.axis[0] = 1.0


def test_axes_are_normalised():
    p = base(sensor_axis=[0, 3, 4], cones=[{"axis": [0, 0, -2], "half_angle": 0.1}])
    np.testing.assert_allclose(p.sensor_axis, [0, 0.6, 0.8], rtol=1e-15)
    np.testing.assert_allclose(p.cones[0].axis, [0, 0, -1], rtol=1e-15)
    q = SlewProblem([1, 1, 1], sensor_target=[0, -5, 0])
    np.testing.assert_allclose(q.sensor_target, [0, -1, 0], rtol=1e-15)
    assert q.is_pointing
    assert q.slew_angle == pytest.approx(math.pi / 2, abs=1e-15)


# ====================================================================== validation
@pytest.mark.parametrize("field", ["inertia", "torque_max", "omega0", "omegaf", "sensor_axis",
                                   "rate_max"])
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_vectors_rejected(field, bad):
    v = [0.1, bad, 0.1]
    with pytest.raises(ValueError, match=rf"^{field}: .*finite"):
        base(**{field: v})


@pytest.mark.parametrize("field", ["q0", "qf"])
def test_non_finite_quaternion_rejected(field):
    with pytest.raises(ValueError, match=rf"^{field}: .*finite"):
        base(**{field: [1.0, math.nan, 0.0, 0.0]})


def test_non_finite_sensor_target_rejected():
    with pytest.raises(ValueError, match=r"^sensor_target: .*finite"):
        SlewProblem([1, 1, 1], sensor_target=[1.0, math.inf, 0.0])


@pytest.mark.parametrize("value", [[1, 0, 1], [1, -2, 1], 0.0, -1.0])
def test_non_positive_inertia_rejected(value):
    with pytest.raises(ValueError, match=r"^inertia: .*positive"):
        base(inertia=value if isinstance(value, list) else [value, 1, 1])


@pytest.mark.parametrize("value", [0.0, -1.0, [1, 0, 1], [1, 1, -0.5]])
def test_non_positive_torque_rejected(value):
    with pytest.raises(ValueError, match=r"^torque_max: .*positive"):
        base(torque_max=value)


@pytest.mark.parametrize("field, value", [("inertia", [1, 1]), ("inertia", 1.0),
                                          ("torque_max", [1, 1]), ("q0", [1, 0, 0]),
                                          ("omega0", [0, 0]), ("inertia", "abc"),
                                          ("inertia", [[1, 2, 3]])])
def test_wrong_shape_rejected(field, value):
    with pytest.raises(ValueError, match=rf"^{field}: expected"):
        base(**{field: value})


def test_inertia_required():
    with pytest.raises(ValueError, match=r"^inertia: missing"):
        SlewProblem.from_dict({"qf": QF_Z180})
    with pytest.raises(ValueError, match=r"^inertia: missing"):
        SlewProblem.from_dict({"inertia": None, "qf": QF_Z180})


# ---------------------------------------------------------------------- torque norm
@pytest.mark.parametrize("value, expected", [("inf", math.inf), ("Infinity", math.inf),
                                             (" INF ", math.inf), (math.inf, math.inf),
                                             (2, 2.0), ("2", 2.0), (1.5, 1.5), (20.0, 20.0)])
def test_torque_norm_accepted(value, expected):
    assert base(torque_norm=value).torque_norm == expected


@pytest.mark.parametrize("value", [1, 1.0, 0.5, 0, -2, "1"])
def test_torque_norm_p_at_most_one_rejected(value):
    with pytest.raises(ValueError, match=r"^torque_norm: p must be > 1"):
        base(torque_norm=value)


@pytest.mark.parametrize("value", ["abc", None, [2], math.nan, "nan"])
def test_torque_norm_garbage_rejected(value):
    with pytest.raises(ValueError, match=r"^torque_norm: "):
        base(torque_norm=value)


# ---------------------------------------------------------------------- unit quaternions
@pytest.mark.parametrize("field", ["q0", "qf"])
def test_quaternion_within_silent_tol_normalised_without_warning(field):
    q = np.array([0.6, 0.8, 0.0, 0.0]) * (1 + 0.5 * QUAT_SILENT_TOL)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        p = base(**{field: q})
    got = getattr(p, field)
    assert np.linalg.norm(got) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(got, [0.6, 0.8, 0, 0], atol=1e-15)


@pytest.mark.parametrize("field", ["q0", "qf"])
@pytest.mark.parametrize("factor", [1 + 5e-6, 1 + 9e-4, 1 - 9e-4])
def test_quaternion_in_warning_band_normalised_with_userwarning(field, factor):
    q = np.array([0.6, 0.0, 0.0, 0.8]) * factor
    with pytest.warns(UserWarning, match=rf"^{field}: quaternion norm .*normalised"):
        p = base(**{field: q})
    np.testing.assert_allclose(getattr(p, field), [0.6, 0, 0, 0.8], atol=1e-15)


def test_quaternion_warning_points_at_the_caller():
    """The UserWarning is attributed to the user's line, not to a line inside slew_env."""
    for src in ("SlewProblem([1, 1, 1], q0=[1 + 1e-4, 0, 0, 0], qf=[0, 0, 0, 1])",
                "SlewProblem.from_dict({'inertia': [1, 1, 1], 'q0': [1 + 1e-4, 0, 0, 0], 'qf': [0, 0, 0, 1]})",
                "SlewProblem.from_json('{\"inertia\": [1, 1, 1], \"qf\": [0, 0, 0, 1.0001]}')"):
        code = compile(src, "user_script.py", "exec")
        with pytest.warns(UserWarning) as rec:
            exec(code, {"SlewProblem": SlewProblem})
        assert [w.filename for w in rec] == ["user_script.py"], src


@pytest.mark.parametrize("field", ["q0", "qf"])
@pytest.mark.parametrize("factor", [1 + 1.1e-3, 1 - 1.1e-3, 2.0, 0.5, 0.0])
def test_quaternion_beyond_reject_tol_rejected(field, factor):
    q = np.array([0.0, 0.6, 0.8, 0.0]) * factor
    with pytest.raises(ValueError, match=rf"^{field}: not a unit quaternion .*> 0\.001"):
        base(**{field: q})


def test_quaternion_tolerances_are_the_documented_ones():
    assert QUAT_SILENT_TOL == 1e-6 and QUAT_REJECT_TOL == 1e-3


# ---------------------------------------------------------------------- axes
@pytest.mark.parametrize("field", ["sensor_axis", "sensor_target"])
def test_zero_length_axes_rejected(field):
    kw = {"inertia": [1, 1, 1], field: [0.0, 0.0, 0.0]}
    if field == "sensor_axis":
        kw["qf"] = QF_Z180
    with pytest.raises(ValueError, match=rf"^{field}: zero-length axis"):
        SlewProblem(**kw)


def test_zero_length_cone_axis_rejected():
    with pytest.raises(ValueError, match=r"^cones\[1\]\.axis: zero-length axis"):
        base(cones=[{"axis": [0, 0, 1], "half_angle": 0.1}, {"axis": [0, 0, 0], "half_angle": 0.1}])
    with pytest.raises(ValueError, match=r"^cone\.axis: zero-length axis"):
        Cone([0, 0, 0], 0.1)


# ---------------------------------------------------------------------- half-angles
@pytest.mark.parametrize("deg", [0.0, 180.0, -10.0, 200.0, 180.0001])
def test_half_angle_deg_outside_range_rejected(deg):
    with pytest.raises(ValueError, match=r"^cones\[0\]\.half_angle_deg: half-angle must lie in \(0°, 180°\)"):
        base(cones=[{"axis": [0, 0, 1], "half_angle_deg": deg}])


@pytest.mark.parametrize("rad", [0.0, math.pi, -0.1, 4.0])
def test_half_angle_rad_outside_range_rejected(rad):
    with pytest.raises(ValueError, match=r"^cones\[0\]\.half_angle: half-angle must lie in \(0, π\)"):
        base(cones=[{"axis": [0, 0, 1], "half_angle": rad}])


@pytest.mark.parametrize("key", ["half_angle", "half_angle_deg"])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_half_angle_non_finite_rejected(key, bad):
    with pytest.raises(ValueError, match=rf"^cones\[0\]\.{key}: must be finite"):
        base(cones=[{"axis": [0, 0, 1], key: bad}])


def test_half_angle_not_a_number_rejected():
    with pytest.raises(ValueError, match=r"^cones\[0\]\.half_angle_deg: expected a number"):
        base(cones=[{"axis": [0, 0, 1], "half_angle_deg": "wide"}])


def test_half_angle_both_or_neither_rejected():
    with pytest.raises(ValueError, match=r"^cones\[0\]: give exactly one of half_angle"):
        base(cones=[{"axis": [0, 0, 1], "half_angle": 0.1, "half_angle_deg": 10}])
    with pytest.raises(ValueError, match=r"^cones\[0\]: give exactly one of half_angle"):
        base(cones=[{"axis": [0, 0, 1]}])
    with pytest.raises(ValueError, match=r"^cone: give exactly one"):
        Cone([0, 0, 1])


def test_half_angle_just_inside_range_accepted():
    p = base(cones=[{"axis": [0, 0, 1], "half_angle_deg": 1e-6}, {"axis": [0, 0, 1], "half_angle": 0.5}])
    assert p.cones[0].half_angle == pytest.approx(math.radians(1e-6), rel=1e-15)
    assert p.cones[1].half_angle_deg == pytest.approx(math.degrees(0.5), rel=1e-15)


def test_cone_entries_malformed():
    with pytest.raises(ValueError, match=r"^cones\[0\]\.axis: missing"):
        base(cones=[{"half_angle": 0.1}])
    with pytest.raises(ValueError, match=r"^cones\[0\]: expected an object"):
        base(cones=[[0, 0, 1, 0.1]])
    with pytest.raises(ValueError, match=r"^cones: expected a list of cones, got a single cone"):
        base(cones={"axis": [0, 0, 1], "half_angle": 0.1})
    with pytest.raises(ValueError, match=r"^cones: expected a list of cones"):
        base(cones=5)
    with pytest.raises(ValueError, match=r"^cones\[0\]: unknown field\(s\) \['radius'\]"):
        base(cones=[{"axis": [0, 0, 1], "half_angle": 0.1, "radius": 2}])


# ---------------------------------------------------------------------- targets
def test_both_targets_rejected():
    with pytest.raises(ValueError, match=r"^qf, sensor_target: give exactly one target.*both were given"):
        SlewProblem([1, 1, 1], qf=QF_Z180, sensor_target=[0, 1, 0])


def test_neither_target_rejected():
    with pytest.raises(ValueError, match=r"^qf, sensor_target: give exactly one target.*neither was given"):
        SlewProblem([1, 1, 1])
    with pytest.raises(ValueError, match=r"^qf, sensor_target: .*neither"):
        SlewProblem.from_dict({"inertia": [1, 1, 1], "qf": None, "sensor_target": None})


# ---------------------------------------------------------------------- cones vs start / target
CONE_Z30 = {"axis": [0, 0, 1], "half_angle_deg": 30}


def test_start_inside_cone_rejected():
    q0 = Q.qfrom_axis_angle(np.array([0.0, 1.0, 0.0]), -math.radians(80))   # x → 10° from z
    with pytest.raises(ValueError, match=r"^q0: infeasible, the start sensor direction lies inside cones\[1\] "
                                         r"\(20° deep"):
        base(q0=q0, cones=[{"axis": [0, 0, -1], "half_angle": 0.1}, CONE_Z30])


def test_start_inside_cone_via_sensor_axis_rejected():
    with pytest.raises(ValueError, match=r"^q0: infeasible.*inside cones\[0\]"):
        base(sensor_axis=[0, 0.1, 1], cones=[CONE_Z30])


def test_pointing_target_inside_cone_rejected():
    with pytest.raises(ValueError, match=r"^sensor_target: infeasible, the target sensor direction lies "
                                         r"inside cones\[0\]"):
        SlewProblem([1, 1, 1], sensor_target=[0.1, 0, 1], cones=[CONE_Z30])


def test_full_attitude_target_inside_cone_rejected():
    qf = Q.qfrom_axis_angle(np.array([0.0, 1.0, 0.0]), -math.radians(70))   # x → 20° from z
    with pytest.raises(ValueError, match=r"^qf: infeasible, the target sensor direction lies inside cones\[0\] "
                                         r"\(10° deep"):
        base(qf=qf, cones=[CONE_Z30])
    # the same cone is fine for a different sensor axis
    base(qf=qf, sensor_axis=[0, 1, 0], cones=[CONE_Z30])


def test_just_outside_cone_accepted_and_just_inside_rejected():
    for delta, ok in ((1e-7, True), (-1e-7, False)):
        ang = math.radians(30) + delta
        target = [math.sin(ang), 0.0, math.cos(ang)]
        if ok:
            p = SlewProblem([1, 1, 1], sensor_target=target, cones=[CONE_Z30])
            assert p.cones[0].margin(p.target_direction) == pytest.approx(delta, abs=1e-12)
        else:
            with pytest.raises(ValueError, match=r"^sensor_target: infeasible"):
                SlewProblem([1, 1, 1], sensor_target=target, cones=[CONE_Z30])


@pytest.mark.parametrize("alpha, theta", [(45.0, -90.0), (23.0, -70.0)])
def test_r4_start_on_cone_boundary_accepted(alpha, theta):
    p = melton(alpha, theta)
    assert p.is_pointing
    assert abs(p.cones[0].margin(p.start_direction)) < 1e-12
    assert p.cones[0].half_angle == pytest.approx(math.radians(alpha), rel=1e-15)
    if alpha == 23.0:
        np.testing.assert_allclose(p.sensor_target, [0.89954568, 0.23665555, 0.36716716], atol=1e-8)
    # the same case from JSON text, as a user would write it
    text = json.dumps({"inertia": [1, 1, 1], "torque_max": 1, "torque_norm": "inf",
                       "sensor_target": p.sensor_target.tolist(),
                       "cones": [{"axis": p.cones[0].axis.tolist(), "half_angle_deg": alpha}]})
    assert SlewProblem.from_json(text) == p


# ---------------------------------------------------------------------- rate limit
def test_rate_max_scalar_and_vector():
    np.testing.assert_array_equal(base(rate_max=0.5).rate_max, [0.5, 0.5, 0.5])
    np.testing.assert_array_equal(base(rate_max=[1, 2, 3]).rate_max, [1, 2, 3])
    base(rate_max=0.5, omega0=[0.5, -0.5, 0.0])          # on the limit is allowed


@pytest.mark.parametrize("value", [0.0, -1.0, [1, 0, 1]])
def test_rate_max_non_positive_rejected(value):
    with pytest.raises(ValueError, match=r"^rate_max: .*positive"):
        base(rate_max=value)


def test_rate_max_non_finite_rejected():
    with pytest.raises(ValueError, match=r"^rate_max: .*finite"):
        base(rate_max=math.inf)


@pytest.mark.parametrize("field", ["omega0", "omegaf"])
def test_rates_beyond_rate_max_rejected(field):
    with pytest.raises(ValueError, match=rf"^{field}: exceeds rate_max"):
        base(rate_max=[1.0, 0.1, 1.0], **{field: [0.0, -0.2, 0.0]})


# ====================================================================== round trips
def test_dict_uses_documented_field_names():
    d = full_problem().to_dict()
    assert set(d) == set(FIELDS) == {"inertia", "torque_max", "torque_norm", "q0", "omega0", "qf",
                                     "sensor_axis", "sensor_target", "omegaf", "cones", "rate_max",
                                     "rate_norm_max"}
    assert set(d["cones"][0]) == {"axis", "half_angle"}
    assert d["cones"][0]["half_angle"] == pytest.approx(math.radians(20), rel=1e-15)
    assert d["torque_norm"] == 2.5
    assert base().to_dict()["torque_norm"] == "inf"
    assert base().to_dict()["rate_max"] is None and base().to_dict()["sensor_target"] is None
    json.dumps(d, allow_nan=False)        # strict JSON, no NaN / Infinity


def _problems():
    rng = np.random.default_rng(7)
    out = [base(), base(torque_norm=2), full_problem(), melton(45, -90), melton(23, -70, rate_max=2.0)]
    for k in range(30):      # random attitudes: renormalising must not drift by an ulp
        kw = {"qf": Q.qfrom_uniform(*rng.random(3))} if k % 2 else {"sensor_target": rng.normal(size=3)}
        out.append(SlewProblem(rng.uniform(0.5, 3, 3), q0=Q.qfrom_uniform(*rng.random(3)),
                               sensor_axis=rng.normal(size=3), **kw))
    return out


def test_dict_round_trip_exact():
    for p in _problems():
        d = p.to_dict()
        p2 = SlewProblem.from_dict(d)
        assert p2 == p
        assert p2.to_dict() == d
        for f in FIELDS:        # bit for bit, not just ==
            a, b = getattr(p, f), getattr(p2, f)
            if isinstance(a, np.ndarray):
                np.testing.assert_array_equal(a, b)
        assert hash(p2) == hash(p)


def test_json_round_trip_exact():
    for p in _problems():
        text = p.to_json()
        assert SlewProblem.from_json(text) == p
        assert json.loads(text) == p.to_dict()


def test_save_load_round_trip(tmp_path):
    for k, p in enumerate(_problems()[:6]):
        path = tmp_path / f"p{k}.json"
        p.save(path)
        assert SlewProblem.load(path) == p
        assert SlewProblem.load(str(path)) == p
        assert json.loads(path.read_text()) == p.to_dict()


def test_task_array_round_trip():
    for p in _problems():
        t = p.to_task_array()
        assert t.dtype == np.float64 and t.shape == (T.task_length(len(p.cones)),)
        assert SlewProblem.from_task_array(t) == p
        padded = p.to_task_array(max_cones=4)
        assert padded.shape == (T.task_length(4),)
        assert T.max_cones_of(len(padded)) == 4
        assert SlewProblem.from_task_array(padded) == p


def test_task_array_layout():
    p = full_problem()
    t = p.to_task_array(max_cones=3)
    np.testing.assert_array_equal(t[T.T_J:T.T_J + 3], p.inertia)
    np.testing.assert_array_equal(t[T.T_UMAX:T.T_UMAX + 3], p.torque_max)
    assert t[T.T_PNORM] == 2.5
    np.testing.assert_array_equal(t[T.T_Q0:T.T_Q0 + 4], p.q0)
    np.testing.assert_array_equal(t[T.T_W0:T.T_W0 + 3], p.omega0)
    np.testing.assert_array_equal(t[T.T_QF:T.T_QF + 4], p.qf)
    assert t[T.T_POINTING] == 0.0
    np.testing.assert_array_equal(t[T.T_SENSOR:T.T_SENSOR + 3], p.sensor_axis)
    np.testing.assert_allclose(t[T.T_TARGET:T.T_TARGET + 3], Q.qrotate(p.qf, p.sensor_axis), atol=1e-15)
    np.testing.assert_array_equal(t[T.T_WF:T.T_WF + 3], p.omegaf)
    np.testing.assert_array_equal(t[T.T_RATEMAX:T.T_RATEMAX + 3], p.rate_max)
    assert t[T.T_TUNIT] == pytest.approx(math.sqrt(5621 / 50), rel=1e-15)
    assert t[T.T_NCONES] == 2
    for k, c in enumerate(p.cones):
        o = T.T_CONES + T.CONE_STRIDE * k
        np.testing.assert_array_equal(t[o:o + 3], c.axis)
        assert t[o + 3] == c.half_angle
    np.testing.assert_array_equal(t[T.T_CONES + 2 * T.CONE_STRIDE:], 0.0)   # padding
    # per-axis bound and no rate limit
    t = melton(45, -90).to_task_array()
    assert t[T.T_PNORM] == 0.0 and t[T.T_POINTING] == 1.0
    assert np.all(np.isinf(t[T.T_RATEMAX:T.T_RATEMAX + 3]))
    np.testing.assert_array_equal(t[T.T_QF:T.T_QF + 4], [1, 0, 0, 0])


def test_task_layout_slots_do_not_overlap():
    slots = [(T.T_J, 3), (T.T_UMAX, 3), (T.T_PNORM, 1), (T.T_Q0, 4), (T.T_W0, 3), (T.T_QF, 4),
             (T.T_POINTING, 1), (T.T_SENSOR, 3), (T.T_TARGET, 3), (T.T_WF, 3), (T.T_RATEMAX, 3),
             (T.T_TUNIT, 1), (T.T_NCONES, 1)]
    used = np.zeros(T.T_CONES, dtype=int)
    for start, n in slots:
        used[start:start + n] += 1
    np.testing.assert_array_equal(used, 1)      # every slot before the cones used exactly once
    assert T.task_length(0) == T.T_CONES and T.task_length(3) == T.T_CONES + 12


def test_task_array_too_many_cones_rejected():
    with pytest.raises(ValueError, match=r"^cones: 2 cones given but at most 1"):
        full_problem().to_task_array(max_cones=1)


def test_half_angle_deg_input_round_trips_as_radians():
    d = {"inertia": [1, 1, 1], "qf": QF_Z180, "cones": [{"axis": [0, 1, 0], "half_angle_deg": 15}]}
    p = SlewProblem.from_dict(d)
    assert p.cones[0].half_angle == pytest.approx(math.radians(15), rel=1e-15)
    assert p.cones[0].half_angle_deg == pytest.approx(15.0, rel=1e-15)
    out = p.to_dict()["cones"][0]
    assert "half_angle_deg" not in out
    assert SlewProblem.from_dict(p.to_dict()) == p
    assert p == SlewProblem.from_dict({**d, "cones": [{"axis": [0, 1, 0], "half_angle": math.radians(15)}]})


def test_unknown_fields_rejected():
    with pytest.raises(ValueError, match=r"^problem: unknown field\(s\) \['q_f', 'tf'\]"):
        SlewProblem.from_dict({"inertia": [1, 1, 1], "q_f": QF_Z180, "tf": 3.0})
    with pytest.raises(ValueError, match=r"^problem: unknown field"):
        SlewProblem.from_json('{"inertia": [1, 1, 1], "qf": [0, 0, 0, 1], "torque": 1}')


def test_from_dict_and_json_bad_input():
    with pytest.raises(ValueError, match=r"^problem: expected a SlewProblem or a dict \(JSON object\)"):
        SlewProblem.from_dict([1, 2, 3])
    with pytest.raises(ValueError, match=r"^problem: not valid JSON"):
        SlewProblem.from_json("{inertia: [1, 1, 1]}")
    with pytest.raises(ValueError, match=r"^q0: .*finite"):
        SlewProblem.from_json('{"inertia": [1, 1, 1], "qf": [0, 0, 0, 1], "q0": [NaN, 0, 0, 1]}')
    p = base()
    assert SlewProblem.from_dict(p) is p


def test_from_dict_none_means_default():
    p = SlewProblem.from_dict({"inertia": [1, 1, 1], "qf": QF_Z180, "q0": None, "cones": None,
                               "torque_norm": None, "rate_max": None, "sensor_target": None})
    assert p == base()


def test_replace():
    p = base(cones=[CONE_Z30])
    r = p.replace(torque_norm=2)
    assert r.torque_norm == 2 and r.cones == p.cones and p.torque_norm == math.inf
    s = p.replace(sensor_target=[0, 1, 0])
    assert s.is_pointing and s.qf is None
    assert s.replace(qf=QF_R3).qf is not None
    with pytest.raises(ValueError, match=r"^inertia: .*positive"):
        p.replace(inertia=[1, -1, 1])


def test_equality_and_repr():
    assert base() == base()
    assert base() != base(torque_max=2)
    assert base() != base(cones=[CONE_Z30])
    assert base() != "not a problem"
    text = repr(melton(45, -90))
    assert "sensor_target" in text and "cones=1" in text
    assert "Cone(axis=" in repr(Cone([0, 0, 1], half_angle_deg=30))


def test_cone_object():
    c = Cone([0, 0, 2], half_angle_deg=30)
    assert c == Cone.from_dict({"axis": [0, 0, 1], "half_angle": math.radians(30)})
    assert c == Cone.from_dict(c.to_dict())
    assert hash(c) == hash(Cone.from_dict(c.to_dict()))
    assert c.margin([0, 0, 5]) == pytest.approx(-math.radians(30), abs=1e-15)
    assert c.margin([1, 0, 0]) == pytest.approx(math.radians(60), abs=1e-15)
    assert c.margin([0, 0, -1]) == pytest.approx(math.radians(150), abs=1e-15)


# ----------------------------------------------------------------- found by a fuzz run (session 28)
def test_p_norms_outside_the_solvers_range_are_refused_by_name():
    # p = 1.01 crashed inside the compiled control law (its exponent 1/(p-1) underflows), 1e6
    # in the eigenaxis guess (a ** p overflows): refused with the supported range
    for p in (1.0001, 1.01, 1.04):
        with pytest.raises(ValueError, match=r"^torque_norm: p = .* too close to 1 .*1\.05 ≤ p ≤ 100"):
            SlewProblem([1.0, 1.0, 1.0], torque_norm=p, qf=[0.0, 1.0, 0.0, 0.0])
    for p in (200.0, 1e6, 1e308):
        with pytest.raises(ValueError, match=r"^torque_norm: p = .* beyond .* give 'inf'"):
            SlewProblem([1.0, 1.0, 1.0], torque_norm=p, qf=[0.0, 1.0, 0.0, 0.0])
    assert SlewProblem([1.0, 1.0, 1.0], torque_norm=1.05, qf=[0.0, 1.0, 0.0, 0.0]).torque_norm == 1.05
    assert SlewProblem([1.0, 1.0, 1.0], torque_norm=100, qf=[0.0, 1.0, 0.0, 0.0]).torque_norm == 100.0
    assert math.isinf(SlewProblem([1.0, 1.0, 1.0], torque_norm=float("inf"), qf=[0.0, 1.0, 0.0, 0.0]).torque_norm)


def test_huge_direction_vectors_are_normalised_not_zeroed():
    # their norm overflowed to inf and the direction became [0, 0, 0] (then "target equals the start")
    p = SlewProblem([1.0, 1.0, 1.0], sensor_target=[1e308, 1e308, 1e308],
                    cones=[{"axis": [0.0, 1e308, 0.0], "half_angle": 0.1}])
    np.testing.assert_allclose(p.sensor_target, np.full(3, 1.0 / math.sqrt(3.0)), rtol=1e-15)
    np.testing.assert_allclose(p.cones[0].axis, [0.0, 1.0, 0.0])


def test_booleans_and_huge_integers_are_refused_by_name():
    with pytest.raises(ValueError, match=r"^inertia: expected numbers, got a boolean"):
        SlewProblem([True, 1.0, 1.0], qf=[0.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"^inertia: expected 3 finite numbers"):
        SlewProblem([10 ** 400, 1, 1], qf=[0.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"^torque_norm: expected 'inf' or a number"):
        SlewProblem([1.0, 1.0, 1.0], torque_norm=10 ** 400, qf=[0.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"^cones\[0\]\.half_angle: expected a number \(rad\), got True"):
        SlewProblem.from_dict({"inertia": [1, 1, 1], "qf": [0, 1, 0, 0], "cones": [{"axis": [1, 0, 0], "half_angle": True}]})


def test_numbers_written_as_text_are_refused_by_name():
    # numpy reads "1" as 1.0; a quoted number in a JSON file is a slip, not a request
    with pytest.raises(ValueError, match=r"^inertia: expected numbers, got text"):
        SlewProblem(["1", "2", "3"], qf=[0.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"^torque_max: expected numbers, got text"):
        SlewProblem([1.0, 2.0, 3.0], torque_max="1", qf=[0.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"^qf: expected numbers, got text"):
        SlewProblem([1.0, 2.0, 3.0], qf=np.array(["0", "1", "0", "0"]))
    with pytest.raises(ValueError, match=r"^cones\[0\]\.half_angle: expected a number \(rad\), got text"):
        SlewProblem.from_dict({"inertia": [1, 1, 1], "qf": [0, 1, 0, 0], "cones": [{"axis": [1, 0, 0], "half_angle": "0.3"}]})
    # the one documented text value: the per-axis bound, which JSON cannot write as a number
    assert SlewProblem([1.0, 2.0, 3.0], torque_norm="inf", qf=[0.0, 1.0, 0.0, 0.0]).torque_norm == math.inf


def test_bodies_and_rates_beyond_the_solvers_range_are_refused_by_name():
    # a 1e6 spread of the axes' accelerations, or rates of 1e6 / τ, ran seconds past a time budget
    with pytest.raises(ValueError, match=r"^inertia, torque_max: the axes' acceleration bounds .* 1\.5e\+06"):
        SlewProblem([1e-6, 1.0, 1.5], qf=[0.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"^inertia, torque_max: "):
        SlewProblem([1.0, 1.0, 1.0], torque_max=[1.0, 1e-6, 1.0], qf=[0.0, 1.0, 0.0, 0.0])
    SlewProblem([1e-2, 1.0, 10.0], qf=[0.0, 1.0, 0.0, 0.0])                  # 1e3: fine
    with pytest.raises(ValueError, match=r"^inertia, torque_max: .* 1\.5e\+03, beyond the 1000"):
        SlewProblem([1e-2, 1.0, 15.0], qf=[0.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"^omega0: rates up to 100 / τ are supported"):
        SlewProblem([1.0, 1.0, 1.0], omega0=[1e6, 0.0, 0.0], qf=[0.0, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"^omegaf: rates up to 100 / τ"):
        SlewProblem([4.0, 1.0, 1.0], omegaf=[0.0, 60.0, 0.0], qf=[0.0, 1.0, 0.0, 0.0])   # τ = 2
    SlewProblem([4.0, 1.0, 1.0], omegaf=[0.0, 40.0, 0.0], qf=[0.0, 1.0, 0.0, 0.0])


def test_unreadable_problem_files_are_clear_errors(tmp_path):
    with pytest.raises(ValueError, match=r"^problem: cannot read .*IsADirectoryError"):
        SlewProblem.load(tmp_path)
    bad = tmp_path / "latin1.json"
    bad.write_bytes(b'{"inertia": [1, 1, 1], "qf": [0, 1, 0, 0], "x": "\xe9"}')
    with pytest.raises(ValueError, match=r"^problem: cannot read .*UnicodeDecodeError"):
        SlewProblem.load(bad)
    with pytest.raises(ValueError, match=r"^problem: not valid JSON \(nested too deeply\)"):
        SlewProblem.from_json("[" * 50000 + "]" * 50000)
    with pytest.raises(ValueError, match=r"^problem: not valid JSON \(.*digit"):
        SlewProblem.from_json('{"inertia": [1' + "0" * 5000 + ', 1, 1], "qf": [1, 0, 0, 0]}')
    with pytest.raises(ValueError, match=r"^t: expected a task array"):
        SlewProblem.from_task_array([1.0, 2.0])


def test_a_rate_limit_in_degrees():
    # a GNC review: rate_max=2 meant as deg/s was taken as 2 rad/s without a word; cones take
    # half_angle_deg, and the rate limit now takes rate_max_deg the same way
    deg = SlewProblem([40, 55, 70], torque_max=0.1, qf=[0.0, 0.0, 0.0, 1.0], rate_max_deg=[1.0, 2.0, 0.5])
    np.testing.assert_array_equal(deg.rate_max, np.radians([1.0, 2.0, 0.5]))
    assert "rate_max_deg" not in deg.to_dict() and SlewProblem.from_dict(deg.to_dict()) == deg
    js = SlewProblem.from_json('{"inertia": [40, 55, 70], "qf": [0, 0, 0, 1], "rate_max_deg": 2}')
    np.testing.assert_array_equal(js.rate_max, np.full(3, math.radians(2.0)))
    assert deg.replace(rate_max_deg=3.0).rate_max.tolist() == [math.radians(3.0)] * 3
    with pytest.raises(ValueError, match=r"^rate_max, rate_max_deg: give the rate limit once"):
        SlewProblem([1, 1, 1], qf=[0, 0, 0, 1], rate_max=0.1, rate_max_deg=5.0)
    with pytest.raises(ValueError, match=r"^rate_max_deg: "):
        SlewProblem([1, 1, 1], qf=[0, 0, 0, 1], rate_max_deg=-1.0)
    with pytest.raises(ValueError, match=r"^problem: unknown field\(s\) \['rate_max_rad'\].*'rate_max_deg'"):
        SlewProblem.from_dict({"inertia": [1, 1, 1], "qf": [0, 0, 0, 1], "rate_max_rad": 1.0})
