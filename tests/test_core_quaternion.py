"""Quaternion algebra of slew_env.core.quaternion against independent closed forms.

Conventions (shared/CONVENTIONS.md): scalar first, Hamilton product, q rotates body to
inertial (v_i = q ⊗ [0, v_b] ⊗ q*).
"""
import math

import numpy as np
import pytest

from slew_env.core import quaternion as Q

RNG_SEED = 20240611


def rand_unit(rng, n):
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rodrigues(axis, angle):
    """Rotation matrix of ``angle`` about unit ``axis`` (independent of quaternions)."""
    n = np.asarray(axis, dtype=float)
    return (math.cos(angle) * np.eye(3) + math.sin(angle) * skew(n)
            + (1.0 - math.cos(angle)) * np.outer(n, n))


def dcm_from_quaternion(q):
    """Body-to-inertial rotation matrix of a scalar-first unit quaternion (textbook form)."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


ONE = np.array([1.0, 0.0, 0.0, 0.0])
I_ = np.array([0.0, 1.0, 0.0, 0.0])
J_ = np.array([0.0, 0.0, 1.0, 0.0])
K_ = np.array([0.0, 0.0, 0.0, 1.0])


# ---------------------------------------------------------------- Hamilton product
def test_hamilton_units():
    for u in (I_, J_, K_):
        np.testing.assert_array_equal(Q.qmul(u, u), -ONE)
    np.testing.assert_array_equal(Q.qmul(Q.qmul(I_, J_), K_), -ONE)   # ijk = -1
    np.testing.assert_array_equal(Q.qmul(I_, J_), K_)                  # ij = k
    np.testing.assert_array_equal(Q.qmul(J_, I_), -K_)                 # ji = -k
    np.testing.assert_array_equal(Q.qmul(J_, K_), I_)                  # jk = i
    np.testing.assert_array_equal(Q.qmul(K_, I_), J_)                  # ki = j
    np.testing.assert_array_equal(Q.qmul(K_, J_), -I_)


def test_hamilton_product_matches_vector_form():
    """p ⊗ q = [p0 q0 - p·q, p0 q + q0 p + p × q] (Hamilton, not JPL)."""
    rng = np.random.default_rng(RNG_SEED)
    for _ in range(50):
        p, q = rng.normal(size=4), rng.normal(size=4)
        expected = np.concatenate([[p[0] * q[0] - p[1:] @ q[1:]],
                                   p[0] * q[1:] + q[0] * p[1:] + np.cross(p[1:], q[1:])])
        np.testing.assert_allclose(Q.qmul(p, q), expected, rtol=0, atol=1e-14)


def test_hamilton_identities():
    rng = np.random.default_rng(RNG_SEED + 1)
    for _ in range(50):
        p, q, r = rng.normal(size=4), rng.normal(size=4), rng.normal(size=4)
        np.testing.assert_allclose(Q.qmul(Q.qmul(p, q), r), Q.qmul(p, Q.qmul(q, r)), atol=1e-13)
        np.testing.assert_allclose(Q.qmul(ONE, q), q, atol=0)
        np.testing.assert_allclose(Q.qmul(q, ONE), q, atol=0)
        # norm is multiplicative, conj reverses the order
        assert np.linalg.norm(Q.qmul(p, q)) == pytest.approx(np.linalg.norm(p) * np.linalg.norm(q),
                                                              rel=1e-14)
        np.testing.assert_allclose(Q.qconj(Q.qmul(p, q)), Q.qmul(Q.qconj(q), Q.qconj(p)), atol=1e-14)
        # q ⊗ q* = |q|² (real)
        np.testing.assert_allclose(Q.qmul(q, Q.qconj(q)), [q @ q, 0, 0, 0], atol=1e-14)
    # not commutative
    assert not np.allclose(Q.qmul(p, q), Q.qmul(q, p))


def test_qconj_and_qnormalize():
    q = np.array([0.5, -1.0, 2.0, -3.0])
    np.testing.assert_array_equal(Q.qconj(q), [0.5, 1.0, -2.0, 3.0])
    n = Q.qnormalize(q)
    assert np.linalg.norm(n) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(n * np.linalg.norm(q), q, atol=1e-14)


def test_qcanonical():
    q = np.array([-0.5, 0.5, -0.5, 0.5])
    np.testing.assert_array_equal(Q.qcanonical(q), -q)
    np.testing.assert_array_equal(Q.qcanonical(-q), -q)
    pos = -q
    c = Q.qcanonical(pos)
    c[1] = 99.0                   # a copy, not the input itself
    assert pos[1] == -0.5


# ---------------------------------------------------------------- rotations
def test_qrotate_matches_rodrigues_matrix():
    rng = np.random.default_rng(RNG_SEED + 2)
    for _ in range(100):
        n = rand_unit(rng, 3)
        angle = rng.uniform(-2 * math.pi, 2 * math.pi)
        v = rng.normal(size=3)
        q = Q.qfrom_axis_angle(n, angle)
        expected = rodrigues(n, angle) @ v
        np.testing.assert_allclose(Q.qrotate(q, v), expected, atol=1e-13)
        np.testing.assert_allclose(dcm_from_quaternion(q) @ v, expected, atol=1e-13)


def test_qrotate_is_sandwich_product_body_to_inertial():
    rng = np.random.default_rng(RNG_SEED + 3)
    for _ in range(50):
        q = rand_unit(rng, 4)
        v = rng.normal(size=3)
        sandwich = Q.qmul(Q.qmul(q, np.concatenate([[0.0], v])), Q.qconj(q))
        assert abs(sandwich[0]) < 1e-14
        np.testing.assert_allclose(Q.qrotate(q, v), sandwich[1:], atol=1e-14)
        np.testing.assert_allclose(Q.qrotate(-q, v), sandwich[1:], atol=1e-14)   # q ≡ -q


def test_qrotate_known_values():
    # +90° about z takes body x to inertial y (active, right-handed)
    q = Q.qfrom_axis_angle(np.array([0.0, 0.0, 1.0]), math.pi / 2)
    np.testing.assert_allclose(Q.qrotate(q, np.array([1.0, 0.0, 0.0])), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(Q.qrotate(q, np.array([0.0, 1.0, 0.0])), [-1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(Q.qrotate_inv(q, np.array([0.0, 1.0, 0.0])), [1, 0, 0], atol=1e-15)


def test_qrotate_inv_is_inverse():
    rng = np.random.default_rng(RNG_SEED + 4)
    for _ in range(50):
        q = rand_unit(rng, 4)
        v = rng.normal(size=3)
        np.testing.assert_allclose(Q.qrotate_inv(q, Q.qrotate(q, v)), v, atol=1e-14)
        np.testing.assert_allclose(Q.qrotate(q, Q.qrotate_inv(q, v)), v, atol=1e-14)
        np.testing.assert_allclose(Q.qrotate_inv(q, v), dcm_from_quaternion(q).T @ v, atol=1e-14)


def test_composition_order():
    """(p ⊗ q) applied to v is p applied after q."""
    rng = np.random.default_rng(RNG_SEED + 5)
    p, q = rand_unit(rng, 4), rand_unit(rng, 4)
    v = rng.normal(size=3)
    np.testing.assert_allclose(Q.qrotate(Q.qmul(p, q), v), Q.qrotate(p, Q.qrotate(q, v)), atol=1e-14)
    assert not np.allclose(Q.qrotate(Q.qmul(p, q), v), Q.qrotate(q, Q.qrotate(p, v)))


# ---------------------------------------------------------------- angles
@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.3, 1.0, 2.0, 3.0, math.pi - 1e-7, math.pi])
def test_qangle_of_axis_angle(angle):
    n = np.array([2.0, -1.0, 2.0]) / 3.0
    q = Q.qfrom_axis_angle(n, angle)
    assert Q.qangle(q) == pytest.approx(angle, rel=1e-12, abs=1e-15)
    assert Q.qangle(-q) == Q.qangle(q)


def test_qangle_wraps_beyond_pi():
    n = np.array([0.0, 1.0, 0.0])
    q = Q.qfrom_axis_angle(n, 1.5 * math.pi)            # same rotation as -π/2
    assert Q.qangle(q) == pytest.approx(0.5 * math.pi, rel=1e-14)
    assert Q.qangle(-q) == pytest.approx(0.5 * math.pi, rel=1e-14)


def test_qerror_angle():
    rng = np.random.default_rng(RNG_SEED + 6)
    for _ in range(30):
        qf = rand_unit(rng, 4)
        n = rand_unit(rng, 3)
        angle = rng.uniform(0, math.pi)
        q = Q.qmul(qf, Q.qfrom_axis_angle(n, angle))
        assert Q.qerror_angle(q, qf) == pytest.approx(angle, abs=1e-12)
        assert Q.qerror_angle(-q, qf) == pytest.approx(angle, abs=1e-12)
        assert Q.qerror_angle(q, q) == pytest.approx(0.0, abs=1e-7)


def test_euler321_conventions_example():
    """CONVENTIONS.md: φ=-20°, θ=10°, ψ=90° → [0.6830127, -0.1830127, -0.0616284, 0.7044160]."""
    q = Q.quat_from_euler321_deg(-20.0, 10.0, 90.0)
    np.testing.assert_allclose(q, [0.6830127, -0.1830127, -0.0616284, 0.7044160], atol=5e-8)
    assert Q.qangle(q) == pytest.approx(1.6378, abs=5e-5)
    # 3-2-1: yaw about z, then pitch about y, then roll about x (body to inertial)
    z, y, x = (np.array(e, dtype=float) for e in ([0, 0, 1], [0, 1, 0], [1, 0, 0]))
    composed = Q.qmul(Q.qmul(Q.qfrom_axis_angle(z, math.radians(90)),
                             Q.qfrom_axis_angle(y, math.radians(10))),
                      Q.qfrom_axis_angle(x, math.radians(-20)))
    np.testing.assert_allclose(q, composed, atol=1e-15)
    np.testing.assert_allclose(Q.quat_from_euler321(math.radians(-20), math.radians(10),
                                                    math.radians(90)), q, atol=0)


def test_euler321_single_axes():
    for args, axis in (((0.7, 0, 0), [1, 0, 0]), ((0, 0.7, 0), [0, 1, 0]), ((0, 0, 0.7), [0, 0, 1])):
        np.testing.assert_allclose(Q.quat_from_euler321(*args),
                                   Q.qfrom_axis_angle(np.array(axis, dtype=float), 0.7), atol=1e-15)


# ---------------------------------------------------------------- two vectors
def _check_two_vectors(a, b, atol=1e-13):
    q = Q.qfrom_two_vectors(a, b)
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(Q.qrotate(q, a), b, atol=atol)
    # the shortest rotation: its angle is the angle between a and b
    ang = math.atan2(np.linalg.norm(np.cross(a, b)), a @ b)
    assert Q.qangle(q) == pytest.approx(ang, abs=atol)
    return q


def test_qfrom_two_vectors_random():
    rng = np.random.default_rng(RNG_SEED + 7)
    for _ in range(200):
        a, b = rand_unit(rng, 3), rand_unit(rng, 3)
        q = _check_two_vectors(a, b)
        # axis orthogonal to both
        assert abs(q[1:] @ a) < 1e-13 and abs(q[1:] @ b) < 1e-13


def test_qfrom_two_vectors_parallel_is_identity():
    a = np.array([0.6, 0.0, -0.8])
    np.testing.assert_allclose(Q.qfrom_two_vectors(a, a.copy()), ONE, atol=1e-15)


@pytest.mark.parametrize("a", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0],
                               [0.6, 0.0, 0.8], [1 / math.sqrt(3)] * 3])
def test_qfrom_two_vectors_antiparallel(a):
    a = np.array(a)
    q = _check_two_vectors(a, -a)
    assert abs(q[0]) < 1e-15                      # a half-turn
    assert abs(q[1:] @ a) < 1e-15                 # about an axis orthogonal to a


@pytest.mark.parametrize("eps", [1e-3, 1e-6, 1e-7, 1e-9, 1e-11, 1e-14])
def test_qfrom_two_vectors_nearly_antiparallel(eps):
    """b at π - eps from a: the rotation must land on b, not on -a (was off by eps up to 1.4e-6)."""
    a = np.array([0.0, 0.6, 0.8])
    perp = np.array([1.0, 0.0, 0.0])
    b = -math.cos(eps) * a + math.sin(eps) * perp
    q = Q.qfrom_two_vectors(a, b)
    r = Q.qrotate(q, a)
    err = math.atan2(np.linalg.norm(np.cross(r, b)), r @ b)
    assert err < 1e-15 + 1e-6 * eps
    assert Q.qangle(q) == pytest.approx(math.pi - eps, abs=1e-15)


# ---------------------------------------------------------------- random rotations
def test_qfrom_uniform_is_haar():
    """Shoemake sampling: unit, and the Haar (uniform on S³) statistics."""
    rng = np.random.default_rng(RNG_SEED + 8)
    n = 100_000
    u = rng.random((n, 3))
    qs = np.array([Q.qfrom_uniform(*row) for row in u])
    np.testing.assert_allclose(np.linalg.norm(qs, axis=1), 1.0, atol=1e-15)
    # each component of a uniform point on S³: E|q_i| = 4/(3π), E q_i² = 1/4
    # (std of |q_i| ≈ 0.264 → standard error 8.4e-4; 5σ ≈ 4.2e-3)
    np.testing.assert_allclose(np.abs(qs).mean(axis=0), 4 / (3 * math.pi), atol=4.2e-3)
    np.testing.assert_allclose((qs ** 2).mean(axis=0), 0.25, atol=3e-3)
    np.testing.assert_allclose(qs.mean(axis=0), 0.0, atol=5e-3)
    # rotation angle of a Haar rotation: P(angle ≤ t) = (t - sin t) / π
    ang = 2.0 * np.arctan2(np.linalg.norm(qs[:, 1:], axis=1), np.abs(qs[:, 0]))
    for t in (0.5, 1.0, 1.5, 2.0, 2.5, 3.0):
        assert np.mean(ang <= t) == pytest.approx((t - math.sin(t)) / math.pi, abs=5e-3)
    # a rotated body axis is uniform on the sphere
    x = np.array([Q.qrotate(q, np.array([1.0, 0.0, 0.0])) for q in qs[:20_000]])
    np.testing.assert_allclose(x.mean(axis=0), 0.0, atol=0.02)
    np.testing.assert_allclose((x ** 2).mean(axis=0), 1 / 3, atol=0.01)
