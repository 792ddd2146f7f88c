"""Hexa Slide kinematics (SPEC 2.1, appendix A): IK/FK round trips, every analytic derivative
against central finite differences, workspace failures, frame transforms; on the default
geometry and on one that shares none of its numbers."""

import numpy as np
import pytest

from pkmcal.errors import ConvergenceError
from pkmcal.kinematics import matrix_from_euler, matrix_from_rotvec, rotation_angle
from pkmcal.machines import (
    HexaSlide,
    default_hexaslide,
    hexaslide_parameters,
    newton_pose_solve,
    paper_table1_deviations,
)
from pkmcal.machines.base import solve_batched
from pkmcal.machines.hexaslide import CHAIN_FIELDS, rail_direction


def skewed_hexaslide() -> HexaSlide:
    """A geometry sharing no number with the default: rails not aimed at the axis (alpha off
    by +/-6 deg), unequal inclinations beta, unequal link lengths, other radii, A0 and B not in
    planes, another Lc and home height, and the pattern turned by 5 deg."""
    k = np.repeat(np.arange(3), 2)
    sgn = np.tile([-1.0, 1.0], 3)
    g = np.deg2rad(120 * k + sgn * 24 + 5)
    gb = np.deg2rad(120 * k + sgn * 50 + 5)
    a0 = np.column_stack([0.52 * np.cos(g), 0.52 * np.sin(g),
                          [-0.42, -0.41, -0.43, -0.42, -0.40, -0.42]])
    b = np.column_stack([0.10 * np.cos(gb), 0.10 * np.sin(gb),
                         [0.0, 0.01, -0.01, 0.0, 0.005, -0.005]])
    alpha = g + np.pi + sgn * np.deg2rad(6)
    beta = np.deg2rad([64, 66, 65, 63, 66, 64])
    l = np.array([0.47, 0.48, 0.47, 0.46, 0.48, 0.47])
    return HexaSlide(hexaslide_parameters(b, a0, alpha, beta, l),
                     home=(np.array([0.0, 0.0, 0.32]), np.eye(3)),
                     name="skewed test geometry", constraint_link_length=0.32)


GEOMETRIES = {"default": default_hexaslide, "skewed": skewed_hexaslide}


@pytest.fixture(params=list(GEOMETRIES))
def machine(request):
    return GEOMETRIES[request.param]()


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def random_poses(machine, rng, n, reach=0.04, tilt_deg=8.0):
    """Poses around home: +/- ``reach`` m, Euler angles +/- ``tilt_deg``."""
    P0, R0 = machine.home
    P = P0 + rng.uniform(-reach, reach, (n, 3))
    R = matrix_from_euler(rng.uniform(-1, 1, (n, 3)) * np.deg2rad(tilt_deg)) @ R0
    return P, R


# -- the default geometry is SPEC 2.1's ----------------------------------------------------------

def test_default_geometry_matches_spec():
    m = default_hexaslide()
    p = m.parameters
    deg = np.deg2rad
    for k in range(3):
        for s, sign in enumerate((-1, 1)):
            i = 2 * k + s + 1
            g, gb = deg(120 * k + sign * 20), deg(120 * k + sign * 45)
            np.testing.assert_allclose(p.get(f"chain{i}.a0"),
                                       [0.48 * np.cos(g), 0.48 * np.sin(g), -0.4], atol=1e-13)
            np.testing.assert_allclose(p.get(f"chain{i}.b"),
                                       [0.12 * np.cos(gb), 0.12 * np.sin(gb), 0.0], atol=1e-13)
            assert np.isclose(np.cos(p.get(f"chain{i}.alpha") - (g + np.pi)), 1.0)
            assert p.get(f"chain{i}.beta") == pytest.approx(deg(70))
            assert p.get(f"chain{i}.l") == pytest.approx(0.45)
    assert m.constraint_link_length == pytest.approx(0.3)
    np.testing.assert_array_equal(m.home[0], [0, 0, 0.3])
    np.testing.assert_array_equal(m.home[1], np.eye(3))
    assert p.names[:9] == tuple(f"chain1.{f}" for f in CHAIN_FIELDS)


def test_paper_table1_deviations_by_name():
    p = default_hexaslide().parameters
    du = paper_table1_deviations(p)
    assert du[p.index("chain3.alpha")] == -7.0e-2
    assert du[p.index("chain5.b.x")] == 1.9e-3
    assert du[p.index("chain6.a0.z")] == -1.3e-3
    assert du[p.index("chain2.l")] == 1.8e-3
    np.testing.assert_array_equal(du[p.indices([f"chain{i}.beta" for i in range(1, 7)])],
                                  -2.4e-2)
    assert np.count_nonzero(du) == 54


# -- inverse kinematics --------------------------------------------------------------------------

def test_ik_closes_every_loop(machine, rng):
    """q from the closed form: the slider point is at distance l from the platform joint and
    on the working branch (a.n > 0)."""
    P, R = random_poses(machine, rng, 500)
    q = machine.ik(P, R)
    b, a0, alpha, beta, l = machine.chains()
    a = rail_direction(alpha, beta)
    B_world = P[:, None, :] + np.einsum("kij,cj->kci", R, b)
    n = B_world - (a0 + q[..., None] * a)
    # metre-scale closed form: rounding of a few ulps (another BLAS/CPU: a few more), not 1e-13
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), np.broadcast_to(l, q.shape), rtol=0,
                               atol=1e-13)
    assert np.all(np.einsum("kci,ci->kc", n, a) > 0)


def test_ik_broadcasting_shapes(machine, rng):
    P, R = random_poses(machine, rng, 12)
    q = machine.ik(P, R)
    assert q.shape == (12, 6)
    np.testing.assert_allclose(machine.ik(P[3], R[3]), q[3], rtol=0, atol=1e-13)
    # one orientation for many positions, and a 2-D batch
    np.testing.assert_allclose(machine.ik(P, R[0]), machine.ik(P, np.broadcast_to(R[0], R.shape)))
    np.testing.assert_allclose(machine.ik(P.reshape(3, 4, 3), R.reshape(3, 4, 3, 3)),
                               q.reshape(3, 4, 6))
    qj, J, Ju = machine.ik_jacobians(P.reshape(3, 4, 3), R.reshape(3, 4, 3, 3))
    assert J.shape == (3, 4, 6, 6) and Ju.shape == (3, 4, 6, 54)
    assert machine.ik(np.zeros((0, 3)), np.zeros((0, 3, 3))).shape == (0, 6)


def test_ik_unreachable_is_nan(machine):
    P = np.array([[0.0, 0.0, 2.0], machine.home[0], [1.5, 0.0, 0.3]])
    q, J, Ju = machine.ik_jacobians(P, np.eye(3))
    assert np.all(np.isnan(q[0])) and np.all(np.isnan(q[2]))
    assert np.all(np.isfinite(q[1]))
    assert np.all(np.isnan(J[0])) and np.all(np.isfinite(J[1]))


# -- forward kinematics --------------------------------------------------------------------------

def test_fk_inverts_ik(machine, rng):
    P, R = random_poses(machine, rng, 3000)
    res = machine.fk(machine.ik(P, R))
    assert res.converged.all()
    assert np.max(res.residual) < 1e-12 * machine.characteristic_length()
    np.testing.assert_allclose(res.P, P, rtol=0, atol=1e-10)
    assert np.max(rotation_angle(res.R @ np.swapaxes(R, -1, -2))) < 1e-10


def test_ik_inverts_fk(machine, rng):
    """Random joint vectors (not made from poses) around home: ik(fk(q)) == q."""
    q_home = machine.ik(*machine.home)
    q = q_home + rng.uniform(-0.015, 0.015, (2000, 6))
    res = machine.fk(q)
    assert res.converged.all()
    # bound: the FK's stopping tolerance on |q| (1e-12 x the characteristic length) plus
    # rounding of the IK at the metre scale
    np.testing.assert_allclose(machine.ik(res.P, res.R), q, rtol=0,
                               atol=1e-12 * machine.characteristic_length() + 1e-12)


def test_fk_in_chunks_and_with_per_pose_starts(rng):
    """Batches larger than a chunk, and per-pose starts, give the same poses as one by one."""
    m = default_hexaslide()
    m.fk_chunk = 64
    P, R = random_poses(m, rng, 300)
    q = m.ik(P, R)
    res = m.fk(q)
    assert res.converged.all() and res.P.shape == (300, 3) and res.R.shape == (300, 3, 3)
    np.testing.assert_allclose(res.P, P, atol=1e-10)
    one = m.fk(q[17:18])
    np.testing.assert_allclose(one.P[0], res.P[17], atol=1e-12)
    start = (P + 1e-3, matrix_from_rotvec(np.full((300, 3), 1e-3)) @ R)
    res2 = m.fk(q, start=start)
    assert res2.converged.all()
    assert res2.iterations < res.iterations        # a close start converges sooner
    np.testing.assert_allclose(res2.P, P, atol=1e-10)


def test_fk_unreachable_reports_failure(machine, rng):
    P, R = random_poses(machine, rng, 5)
    q = machine.ik(P, R)
    q[1, 0] += 0.3                                  # one slider 0.3 m further: no pose
    q[3, 2] = np.nan
    res = machine.fk(q)
    np.testing.assert_array_equal(res.converged, [True, False, True, False, True])
    np.testing.assert_allclose(res.P[[0, 2, 4]], P[[0, 2, 4]], atol=1e-10)
    with pytest.raises(ConvergenceError, match=r"2 pose\(s\), row\(s\) 2, 4"):
        machine.fk(q, raise_on_failure=True)
    with pytest.raises(ConvergenceError, match=r"row\(s\) 12, 14"):
        res.raise_if_failed(rows=np.arange(11, 16))


def test_fk_unreachable_start_fails_cleanly(machine, rng):
    P, R = random_poses(machine, rng, 3)
    res = machine.fk(machine.ik(P, R), start=(np.array([0, 0, 3.0]), np.eye(3)))
    assert not res.converged.any()


# -- derivatives against central differences ------------------------------------------------------

def central_difference(f, x0, h):
    """(f(x0 + h e_j) - f(x0 - h e_j)) / 2h for every j; f returns an array."""
    cols = []
    for j in range(len(x0)):
        e = np.zeros(len(x0))
        e[j] = h[j] if np.ndim(h) else h
        cols.append((f(x0 + e) - f(x0 - e)) / (2 * e[j]))
    return np.stack(cols, -1)


def test_pose_jacobian_against_finite_differences(machine, rng):
    P, R = random_poses(machine, rng, 20)
    _, J, _ = machine.ik_jacobians(P, R)
    h = 1e-6
    for k in range(len(P)):
        dP = central_difference(lambda p, k=k: machine.ik(p, R[k]), P[k], h)
        dW = central_difference(lambda w, k=k: machine.ik(P[k], matrix_from_rotvec(w) @ R[k]),
                                np.zeros(3), h)
        np.testing.assert_allclose(J[k, :, :3], dP, rtol=0, atol=1e-8 * np.abs(dP).max())
        np.testing.assert_allclose(J[k, :, 3:], dW, rtol=0, atol=1e-8 * np.abs(dW).max())


def test_parameter_jacobian_against_finite_differences(machine, rng):
    """All 54 columns of dq/du (B, A0, alpha, beta, l of every chain)."""
    P, R = random_poses(machine, rng, 10)
    u = machine.u + 0.3 * paper_table1_deviations(machine.parameters)   # not the nominal
    _, _, Ju = machine.ik_jacobians(P, R, u)
    h = 1e-6 * machine.parameters.scales(1.0)                           # 1 um, 1 urad
    fd = central_difference(lambda v: machine.ik(P, R, v), u, h)        # (10, 6, 54)
    scale = np.abs(fd).max(axis=(0, 1))
    assert np.all(scale > 0)
    np.testing.assert_allclose(Ju, fd, rtol=0, atol=1e-8 * scale.max())
    # each column to its own size too (the angle columns are small for some chains)
    assert np.all(np.abs(Ju - fd).max(axis=(0, 1)) <= 1e-7 * scale)


def test_parameter_jacobian_is_block_diagonal(machine, rng):
    """Joint i depends only on chain i's nine parameters."""
    P, R = random_poses(machine, rng, 4)
    _, _, Ju = machine.ik_jacobians(P, R)
    p = machine.parameters
    for i in range(6):
        own = np.zeros(54, bool)
        own[p.indices(f"chain{i + 1}")] = True
        assert np.all(Ju[:, i, ~own] == 0.0)
        assert np.all(np.abs(Ju[:, i, own]).max(axis=0) > 0)


def test_length_derivative_closed_forms(machine, rng):
    """Appendix A in words: dq/dl = -l/s and dq/dA0 = -dq/dP (moving the rail start is moving
    the platform the other way)."""
    P, R = random_poses(machine, rng, 6)
    q, J, Ju = machine.ik_jacobians(P, R)
    p = machine.parameters
    for i in range(6):
        np.testing.assert_allclose(Ju[:, i, p.indices(f"chain{i + 1}.a0")], -J[:, i, :3],
                                   atol=1e-13)
    b, a0, alpha, beta, l = machine.chains()
    a = rail_direction(alpha, beta)
    d = P[:, None, :] + np.einsum("kij,cj->kci", R, b) - a0
    s = np.einsum("kci,ci->kc", d - q[..., None] * a, a)
    np.testing.assert_allclose(Ju[:, np.arange(6), p.indices([f"chain{i}.l" for i in
                                                              range(1, 7)])], -l / s,
                               rtol=1e-12)


# -- frames (gauge) ------------------------------------------------------------------------------

def test_transform_base_leaves_ik_unchanged(machine, rng):
    """Base rotated by G about O: P -> G P, R -> G R with the transformed parameters."""
    P, R = random_poses(machine, rng, 50)
    G = matrix_from_rotvec([0.03, -0.02, 0.25])
    u = machine.u + 0.3 * paper_table1_deviations(machine.parameters)
    u_g = machine.transform_base(u, G)
    np.testing.assert_allclose(machine.ik(P @ G.T, G @ R, u_g), machine.ik(P, R, u),
                               rtol=0, atol=1e-12)
    # the rail directions and starts rotate; B and l do not move
    p = machine.parameters
    rows = p.indices([f"chain{i}.{f}" for i in range(1, 7) for f in ("b.x", "b.y", "b.z",
                                                                       "l")])
    np.testing.assert_array_equal(u_g[rows], u[rows])
    _, a0, al, be, _ = machine.chains(u)
    _, a0_g, al_g, be_g, _ = machine.chains(u_g)
    np.testing.assert_allclose(a0_g, a0 @ G.T, atol=1e-13)
    np.testing.assert_allclose(rail_direction(al_g, be_g), rail_direction(al, be) @ G.T,
                               atol=1e-13)
    # alpha stays on the same branch as the input (no 2 pi jumps)
    assert np.all(np.abs(al_g - al) < 1.0)


def test_transform_platform_leaves_ik_unchanged(machine, rng):
    """Platform frame re-oriented: R -> R C with B -> C^T B."""
    P, R = random_poses(machine, rng, 50)
    C = matrix_from_rotvec([-0.1, 0.05, 0.4])
    u = machine.u + 0.3 * paper_table1_deviations(machine.parameters)
    u_c = machine.transform_platform(u, C)
    np.testing.assert_allclose(machine.ik(P, R @ C, u_c), machine.ik(P, R, u),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(machine.chains(u_c)[0], machine.chains(u)[0] @ C, atol=1e-13)


def test_transforms_do_not_modify_their_input(machine):
    u = machine.u.copy()
    machine.transform_base(machine.u, matrix_from_rotvec([0.1, 0.2, 0.3]))
    machine.transform_platform(machine.u, matrix_from_rotvec([0.1, 0.2, 0.3]))
    np.testing.assert_array_equal(machine.u, u)


# -- the batched solver used by Newton -------------------------------------------------------------

def test_solve_batched_matches_lapack(machine, rng):
    """Vectorised elimination (one pivot order for the batch) equals numpy.linalg.solve; a
    singular and a badly pivoted system in the batch fall back to LAPACK / least squares."""
    P, R = random_poses(machine, rng, 400)
    _, J, _ = machine.ik_jacobians(P, R, want_du=False)
    r = rng.standard_normal((400, 6)) * 1e-3
    J = J.copy()
    J[5] = J[5][::-1]                   # rows reversed: the batch pivot order is bad for it
    J[9, :, 0] = 0.0                    # exactly singular
    x = solve_batched(J, r)
    ok = np.ones(400, bool)
    ok[9] = False
    ref = np.linalg.solve(J[ok], r[ok][..., None])[..., 0]
    np.testing.assert_allclose(x[ok], ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    np.testing.assert_allclose(x[9], np.linalg.lstsq(J[9], r[9], rcond=None)[0], atol=1e-12)
    np.testing.assert_allclose(solve_batched(J[:3], r[:3]),      # small batch: LAPACK path
                               np.linalg.solve(J[:3], r[:3][..., None])[..., 0],
                               rtol=0, atol=1e-12 * np.abs(ref).max())


def test_newton_pose_solve_least_squares_stops_on_step(rng):
    """Over-determined systems converge on the step size."""
    m = default_hexaslide()
    P, R = random_poses(m, rng, 30)
    q = m.ik(P, R)

    def system(idx, P_, R_):
        qc, J, _ = m.ik_jacobians(P_, R_, want_du=False)
        return np.concatenate([qc - q[idx], qc - q[idx]], -1), np.concatenate([J, J], -2)

    start = np.broadcast_to(m.home[0], (30, 3)).copy(), np.broadcast_to(np.eye(3), (30, 3, 3))
    res = newton_pose_solve(system, start[0], start[1].copy(), tol=0.0, max_iter=50,
                            step_tol=1e-13)
    assert res.converged.all()
    np.testing.assert_allclose(res.P, P, atol=1e-10)
