"""Rotations (SPEC 1): conventions, round trips, precision at tiny angles and near pi.

scipy.spatial.transform.Rotation serves as the independent implementation: its intrinsic
``'YXZ'`` Euler sequence with angles ``[theta, psi, phi]`` is ``RY(theta) RX(psi) RZ(phi)``, and
its quaternions are scalar-last like ours.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pkmcal.kinematics import (
    euler_from_matrix,
    kabsch,
    matrix_from_euler,
    matrix_from_quaternion,
    matrix_from_rotvec,
    quaternion_from_matrix,
    rot_x,
    rot_y,
    rot_z,
    rotation_angle,
    rotvec_from_matrix,
    rotvec_from_quaternion,
    skew,
)

N = 2000


@pytest.fixture
def rng():
    return np.random.default_rng(20240611)


def random_euler(rng, n=N, max_psi_deg=89.0):
    """``[psi, theta, phi]`` with psi in (-max_psi_deg, max_psi_deg), the others in (-pi, pi)."""
    max_psi = np.deg2rad(max_psi_deg)
    return np.column_stack([rng.uniform(-max_psi, max_psi, n), rng.uniform(-np.pi, np.pi, n),
                            rng.uniform(-np.pi, np.pi, n)])


def random_rotvecs(rng, n, angle_low, angle_high):
    axis = rng.standard_normal((n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    return axis * rng.uniform(angle_low, angle_high, (n, 1))


def assert_rotations(R):
    """Proper rotations: orthonormal with determinant +1, to rounding."""
    eye = np.broadcast_to(np.eye(3), R.shape)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), eye, atol=1e-13)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-13)


# -- elementary rotations and the Euler convention ---------------------------------------------

def test_elementary_rotations_turn_counterclockwise():
    """Right-handed: a quarter turn about Z takes X to Y, about X takes Y to Z, about Y Z to X."""
    ex, ey, ez = np.eye(3)
    q = np.pi / 2
    np.testing.assert_allclose(rot_z(q) @ ex, ey, atol=1e-13)
    np.testing.assert_allclose(rot_x(q) @ ey, ez, atol=1e-13)
    np.testing.assert_allclose(rot_y(q) @ ez, ex, atol=1e-13)


def test_elementary_rotations_batch(rng):
    a = rng.uniform(-np.pi, np.pi, (4, 5))
    for rot, axis in ((rot_x, 0), (rot_y, 1), (rot_z, 2)):
        R = rot(a)
        assert R.shape == (4, 5, 3, 3)
        assert_rotations(R)
        v = np.zeros(3)
        v[axis] = 1.0
        np.testing.assert_allclose(
            R, Rotation.from_rotvec((a[..., None] * v).reshape(-1, 3)).as_matrix()
            .reshape(4, 5, 3, 3), atol=1e-13)


def test_euler_convention_is_ry_rx_rz(rng):
    """SPEC 1: ``R = RY(theta) @ RX(psi) @ RZ(phi)`` for ``[psi, theta, phi]``."""
    ang = random_euler(rng)
    psi, theta, phi = ang.T
    expected = rot_y(theta) @ rot_x(psi) @ rot_z(phi)
    np.testing.assert_allclose(matrix_from_euler(ang), expected, atol=1e-13)
    independent = Rotation.from_euler("YXZ", ang[:, [1, 0, 2]]).as_matrix()
    np.testing.assert_allclose(matrix_from_euler(ang), independent, atol=1e-13)


def test_euler_round_trip(rng):
    ang = random_euler(rng)
    np.testing.assert_allclose(euler_from_matrix(matrix_from_euler(ang)), ang, rtol=0,
                               atol=1e-13)
    R = Rotation.random(N, random_state=1).as_matrix()
    np.testing.assert_allclose(matrix_from_euler(euler_from_matrix(R)), R, atol=1e-13)


def test_euler_shapes():
    assert matrix_from_euler([0.1, 0.2, 0.3]).shape == (3, 3)
    assert matrix_from_euler(np.zeros((2, 7, 3))).shape == (2, 7, 3, 3)
    assert euler_from_matrix(np.eye(3)).shape == (3,)
    np.testing.assert_array_equal(euler_from_matrix(np.eye(3)), 0.0)


def test_euler_range_of_psi():
    """psi comes back in [-90, 90] deg; a pose written with psi > 90 deg is another triple."""
    ang = np.array([np.deg2rad(120.0), 0.3, -0.4])
    back = euler_from_matrix(matrix_from_euler(ang))
    assert abs(back[0]) <= np.pi / 2
    np.testing.assert_allclose(matrix_from_euler(back), matrix_from_euler(ang), atol=1e-13)


# -- quaternions --------------------------------------------------------------------------------

def test_quaternion_matches_scipy(rng):
    R = Rotation.random(N, random_state=2)
    q = quaternion_from_matrix(R.as_matrix())
    ref = R.as_quat()                                       # scalar-last
    ref = np.where(ref[:, 3:] < 0, -ref, ref)
    np.testing.assert_allclose(q, ref, atol=1e-13)
    np.testing.assert_allclose(matrix_from_quaternion(ref), R.as_matrix(), atol=1e-13)


def test_quaternion_round_trip(rng):
    q = rng.standard_normal((N, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(q[:, 3:] < 0, -q, q)
    np.testing.assert_allclose(quaternion_from_matrix(matrix_from_quaternion(q)), q,
                               atol=1e-13)
    assert np.all(quaternion_from_matrix(matrix_from_quaternion(-q))[:, 3] >= 0)


def test_quaternion_is_normalised_first():
    q = np.array([0.0, 0.0, 2.0, 2.0])                       # 90 deg about Z, not unit
    np.testing.assert_allclose(matrix_from_quaternion(q), rot_z(np.pi / 2), atol=1e-13)


@pytest.mark.parametrize("angle", [np.pi, np.pi - 1e-7, np.pi - 1e-3, 1e-12, 1e-8, 1e-5])
def test_quaternion_precision_near_pi_and_tiny(rng, angle):
    """Shepperd's choice keeps full precision where ``1 + trace`` vanishes (angle near pi) and
    for tiny angles (quaternion ~ [v/2, 1])."""
    v = random_rotvecs(rng, 500, angle, angle)
    R = Rotation.from_rotvec(v)
    q = quaternion_from_matrix(R.as_matrix())
    ref = R.as_quat()
    # at exactly pi q and -q both have qw = 0: compare up to sign
    sign = np.where(np.sum(q * ref, axis=1, keepdims=True) < 0, -1.0, 1.0)
    np.testing.assert_allclose(q, sign * ref, rtol=0, atol=1e-13)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-13)
    if angle < 1e-4:   # vector part = v / 2 to relative precision
        np.testing.assert_allclose(q[:, :3], v / 2, rtol=1e-9, atol=0)


# -- rotation vectors ---------------------------------------------------------------------------

@pytest.mark.parametrize("low,high", [(1e-14, 1e-9), (1e-6, 2e-4), (1e-3, 1.0), (1.0, 3.0),
                                      (np.pi - 1e-6, np.pi - 1e-9)])
def test_rotvec_round_trip_and_scipy(rng, low, high):
    v = random_rotvecs(rng, 1000, low, high)
    R = matrix_from_rotvec(v)
    assert_rotations(R)
    np.testing.assert_allclose(R, Rotation.from_rotvec(v).as_matrix(), rtol=0, atol=1e-13)
    back = rotvec_from_matrix(R)
    # precision of the angle: relative for tiny angles, ~1e-15 otherwise
    # (near pi the matrix fixes the angle only to sqrt(eps) * ... in 1 + trace; Shepperd's
    # largest-diagonal branch keeps it at ~1e-15 absolute; 1e-13 leaves room for another
    # libm/CPU and still fails the sqrt(eps) ~ 1e-8 loss)
    np.testing.assert_allclose(back, v, rtol=1e-12, atol=1e-13 if high > 1e-3 else 0)
    np.testing.assert_allclose(rotation_angle(R), np.linalg.norm(v, axis=1), rtol=1e-12,
                               atol=1e-13 if high > 1e-3 else 0)


def test_rotvec_continuous_across_series_switch():
    """matrix_from_rotvec switches to series below 1e-4 rad: no jump at the switch, and the
    small off-diagonal entries keep relative precision on both sides.

    Regression: ``(1 - cos t) / t^2`` lost 8 digits to cancellation just above the switch
    (relative error 5e-13 in ``R - I``); now ``2 sin^2(t/2) / t^2``."""
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    angles = 1e-4 * (1 + np.array([-1e-9, -1e-12, 0.0, 1e-12, 1e-9]))
    R = matrix_from_rotvec(angles[:, None] * axis)
    ref = Rotation.from_rotvec(angles[:, None] * axis).as_matrix()
    off = ~np.eye(3, dtype=bool)                 # entries of size 1e-4: relative precision
    np.testing.assert_allclose(R[:, off], ref[:, off], rtol=1e-13, atol=0)
    # ulps of 1 (scipy's formula is another one, 1 ulp off here; the regression is caught
    # just above)
    np.testing.assert_allclose(R, ref, rtol=0, atol=1e-14)


def test_rotvec_composition_about_one_axis(rng):
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    a, b = 0.7, -1.9
    np.testing.assert_allclose(matrix_from_rotvec(a * axis) @ matrix_from_rotvec(b * axis),
                               matrix_from_rotvec((a + b) * axis), atol=1e-13)


def test_rotvec_shapes():
    assert matrix_from_rotvec([0.0, 0.0, 0.1]).shape == (3, 3)
    assert matrix_from_rotvec(np.zeros((2, 4, 3))).shape == (2, 4, 3, 3)
    np.testing.assert_array_equal(matrix_from_rotvec(np.zeros(3)), np.eye(3))
    assert rotvec_from_quaternion(np.array([0, 0, 0, 1.0])).shape == (3,)


def test_small_rotation_is_about_base_axes(rng):
    """SPEC 1: ``R_new = exp(dOmega) R`` rotates about the base axes: the derivative of
    ``R_new @ p`` is ``dOmega x (R @ p)``."""
    R = matrix_from_euler(random_euler(rng, 1)[0])
    p = rng.standard_normal(3)
    w = rng.standard_normal(3)
    h = 1e-6
    d = (matrix_from_rotvec(h * w) @ R @ p - matrix_from_rotvec(-h * w) @ R @ p) / (2 * h)
    # central difference: truncation ~h^2, rounding ~eps |p| / h ~ 2e-10 (1e-10 seen)
    expected = np.cross(w, R @ p)
    np.testing.assert_allclose(d, expected, rtol=0, atol=1e-8 * np.abs(expected).max())


def test_skew_is_cross_product(rng):
    v, w = rng.standard_normal((2, 10, 3))
    np.testing.assert_allclose(skew(v) @ w[..., None], np.cross(v, w)[..., None], atol=1e-13)
    np.testing.assert_allclose(skew(v), -np.swapaxes(skew(v), -1, -2))


# -- kabsch --------------------------------------------------------------------------------------

def test_kabsch_recovers_known_rotation(rng):
    G = Rotation.random(random_state=5).as_matrix()
    src = rng.standard_normal((50, 3))
    np.testing.assert_allclose(kabsch(src, src @ G.T), G, atol=1e-14)


def test_kabsch_with_noise_and_weights(rng):
    G = matrix_from_rotvec([0.1, -0.2, 0.05])
    src = rng.standard_normal((400, 3))
    tgt = src @ G.T + 1e-6 * rng.standard_normal((400, 3))
    assert rotation_angle(kabsch(src, tgt) @ G.T) < 1e-6
    # a zero weight removes an outlier completely
    tgt[0] += 10.0
    w = np.ones(400)
    w[0] = 0.0
    assert rotation_angle(kabsch(src, tgt, weights=w) @ G.T) < 1e-6
    assert rotation_angle(kabsch(src, tgt) @ G.T) > 1e-3


def test_kabsch_returns_proper_rotation_for_reflected_data(rng):
    """Points mirrored through the origin are best fitted by a reflection; kabsch must still
    return a rotation (det +1)."""
    src = rng.standard_normal((20, 3))
    G = kabsch(src, -src)
    assert_rotations(G[None])
