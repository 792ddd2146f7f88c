"""Delta robot kinematics (seed 001, SPEC 2.2): IK/FK round trips, the analytical FK against
Newton and against an independent transcription of the paper's eq. 9-11, degenerate readings,
every analytic derivative against central finite differences, and the ``db - da`` invariance;
on the default 90-degree Delta with random errors, a classic 120-degree Delta and an odd
geometry that shares none of their numbers."""

import warnings

import numpy as np
import pytest

from pkmcal.errors import ConvergenceError, InputError
from pkmcal.machines import Delta, default_delta, delta_parameters
from pkmcal.machines.delta import LEG_FIELDS

deg = np.deg2rad


def random_errors(rng, length_m=1e-3, angle_deg=0.5):
    """27 error parameters: lengths (da, dl1, dl2, db) ~ N(0, length_m), dtheta ~ N(0, angle)."""
    angle_rad = deg(angle_deg)
    u = rng.normal(0.0, length_m, 27)
    u[LEG_FIELDS.index("dtheta")::9] = rng.normal(0.0, angle_rad, 3)
    return u


def default_with_errors():
    m = default_delta()
    return m.with_parameters(random_errors(np.random.default_rng(11)))


def classic_120():
    """The classic layout: legs at 0/120/240 deg, default dimensions, with errors."""
    m = Delta(0.2, 0.05, 0.3, 0.8, deg([0.0, 120.0, 240.0]), smr_offset=0.03)
    return m.with_parameters(random_errors(np.random.default_rng(12)))


def odd_geometry():
    """Other radii and arms, legs at unequal spacings 25/150/280 deg, with errors."""
    m = Delta(0.16, 0.035, 0.27, 0.62, deg([25.0, 150.0, 280.0]), smr_offset=0.02)
    return m.with_parameters(random_errors(np.random.default_rng(13)))


GEOMETRIES = {"default-90": default_with_errors, "classic-120": classic_120,
              "odd": odd_geometry}


@pytest.fixture(params=list(GEOMETRIES))
def machine(request):
    return GEOMETRIES[request.param]()


@pytest.fixture
def rng():
    return np.random.default_rng(2024)


def random_positions(machine, rng, n, reach=(0.12, 0.12, 0.05)):
    """Positions in a box around home (all reachable: checked)."""
    P = machine.home[0] + rng.uniform(-1.0, 1.0, (n, 3)) * np.asarray(reach)
    assert np.all(np.isfinite(machine.ik(P)))
    return P


def leg_offsets_eq5(machine, q, u):
    """``d_i`` (K, 3 legs, 3) and ``L2`` (3,) written out from seed 001 eq. 5 (per leg)."""
    p = machine.parameters.with_values(u)
    d, L2 = [], []
    for i in range(3):
        leg = f"leg{i + 1}"
        da, db = p.get(f"{leg}.da"), p.get(f"{leg}.db")
        L1 = machine.l1 + p.get(f"{leg}.dl1")
        th = q[:, i] + p.get(f"{leg}.dtheta")
        d.append(np.column_stack([-L1 * np.cos(th) - (machine.a + da[0]) + (machine.b + db[0]),
                                  np.full(len(q), -da[1] + db[1]),
                                  -L1 * np.sin(th) - da[2] + db[2]]))
        L2.append(machine.l2 + p.get(f"{leg}.dl2"))
    return np.stack(d, 1), np.array(L2)


def paper_fk(machine, q, u):
    """Seed 001 eq. 8-11 as printed: planes e_j, ``px, py`` as functions of ``pz`` through
    ``q0..q4`` (eq. 9), sphere 1 (eq. 10), the quadratic ``k0 pz^2 + k1 pz + k2 = 0`` (eq. 11).

    Returns both roots (lower, upper) as (K, 3) arrays and ``q2`` (K,).
    """
    d, L2 = leg_offsets_eq5(machine, q, u)
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    c, s = np.cos(machine.leg_angles), np.sin(machine.leg_angles)
    A = 2 * (c * dx - s * dy)                 # coefficient of px in eq. 7, per leg
    Bc = 2 * (s * dx + c * dy)                # of py
    Cc = 2 * dz                               # of pz
    D = dx**2 + dy**2 + dz**2 - L2**2         # constant
    e1 = {j: A[:, 0] - A[:, j - 1] for j in (2, 3)}
    e2 = {j: Bc[:, 0] - Bc[:, j - 1] for j in (2, 3)}
    e3 = {j: Cc[:, 0] - Cc[:, j - 1] for j in (2, 3)}
    e4 = {j: D[:, 0] - D[:, j - 1] for j in (2, 3)}
    q0 = e2[2] * e3[3] - e2[3] * e3[2]
    q1 = e1[3] * e3[2] - e1[2] * e3[3]
    q2 = e1[2] * e2[3] - e2[2] * e1[3]
    q3 = e2[2] * e4[3] - e2[3] * e4[2]
    q4 = e1[3] * e4[2] - e1[2] * e4[3]
    q5, q6, q7, q8 = A[:, 0], Bc[:, 0], Cc[:, 0], D[:, 0]
    k0 = 1 + q0**2 / q2**2 + q1**2 / q2**2
    k1 = 2 * q0 * q3 / q2**2 + 2 * q1 * q4 / q2**2 + q0 * q5 / q2 + q1 * q6 / q2 + q7
    k2 = q3**2 / q2**2 + q4**2 / q2**2 + q3 * q5 / q2 + q4 * q6 / q2 + q8
    disc = np.sqrt(k1**2 - 4 * k0 * k2)
    roots = []
    for pz in ((-k1 - disc) / (2 * k0), (-k1 + disc) / (2 * k0)):   # k0 > 0: lower first
        roots.append(np.column_stack([(q0 * pz + q3) / q2, (q1 * pz + q4) / q2, pz]))
    return roots[0], roots[1], q2


# -- the default geometry is SPEC 2.2's ----------------------------------------------------------

def test_default_geometry_matches_spec():
    m = default_delta()
    assert (m.a, m.b, m.l1, m.l2) == (0.2, 0.05, 0.3, 0.8)
    np.testing.assert_allclose(np.rad2deg(m.leg_angles), [90.0, 180.0, -90.0])
    assert m.smr_offset == 0.03
    np.testing.assert_array_equal(m.home[0], [0.0, 0.0, -0.75])
    assert len(m.parameters) == 27 and np.all(m.u == 0)
    assert m.parameters.names[:9] == tuple(f"leg1.{f}" for f in LEG_FIELDS)
    assert m.parameters.names[-1] == "leg3.db.z"
    # leg frames of eq. 1/4: Rphi = [[c, s, 0], [-s, c, 0], [0, 0, 1]]
    for i, phi in enumerate(m.leg_angles):
        c, s = np.cos(phi), np.sin(phi)
        np.testing.assert_allclose(m.Rphi[i], [[c, s, 0], [-s, c, 0], [0, 0, 1]], atol=1e-13)


def test_three_legs_required():
    with pytest.raises(InputError, match="3 legs: got 4"):
        Delta(0.2, 0.05, 0.3, 0.8, deg([0, 90, 180, 270]))


def test_ik_satisfies_the_leg_equation_eq4(machine, rng):
    """|Rphi_i p + d_i| = l2 + dl2_i with d_i written out from eq. 5 in the test."""
    P = random_positions(machine, rng, 200)
    q = machine.ik(P)
    d, L2 = leg_offsets_eq5(machine, q, machine.u)
    lhs = np.linalg.norm(np.einsum("lij,kj->kli", machine.Rphi, P) + d, axis=-1)
    # metre scale, closed form: a few ulps here, more on another BLAS/CPU; a bug is >> 1e-9
    scale = float(np.max(np.abs(L2)))
    np.testing.assert_allclose(lhs, np.broadcast_to(L2, lhs.shape), rtol=0, atol=1e-12 * scale)


def test_ik_returns_elbow_out(machine, rng):
    """The elbow (end of the upper arm) is farther from the Z axis than the base joint."""
    P = random_positions(machine, rng, 100)
    q = machine.ik(P)
    da, dth, dl1, _, _ = machine.legs()
    # elbow in the leg frame: (a + da_x + L1 cos t, da_y, da_z + L1 sin t)
    radial = machine.a + da[:, 0] + (machine.l1 + dl1) * np.cos(q + dth)
    assert np.all(radial > machine.a + da[:, 0])


# -- round trips and cross-checks ----------------------------------------------------------------

def test_fk_of_ik_is_identity(machine, rng):
    P = random_positions(machine, rng, 500)
    res = machine.fk(machine.ik(P))
    assert res.converged.all()
    np.testing.assert_allclose(res.P, P, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(res.R, np.broadcast_to(np.eye(3), (500, 3, 3)))
    assert res.iterations == 0 and np.all(res.residual == 0)


def test_ik_of_fk_is_identity(machine, rng):
    q0 = machine.ik(machine.home[0])
    q = q0 + rng.uniform(-0.2, 0.2, (500, 3))
    res = machine.fk(q)
    assert res.converged.all()
    np.testing.assert_allclose(machine.ik(res.P), q, rtol=0, atol=1e-12)


def test_fk_matches_newton(machine, rng):
    P = random_positions(machine, rng, 100)
    q = machine.ik(P)
    np.testing.assert_allclose(machine.fk_numerical(q), machine.fk(q).P, rtol=0, atol=1e-12)


def test_fk_matches_paper_eq9_11(machine, rng):
    """An independent transcription of eq. 8-11 (px, py linear in pz; quadratic in pz) gives
    the same position, and the FK takes its lower root (platform side)."""
    P = random_positions(machine, rng, 300)
    q = machine.ik(P)
    lower, upper, q2 = paper_fk(machine, q, machine.u)
    # eq. 9 divides by q2: only where it is well away from zero (here: everywhere). q2 is
    # 4 l_z, l = (c2 - c1) x (c3 - c1) the direction of the planes' line: it vanishes exactly
    # when the two roots are at the same height (no platform side to choose).
    c, _ = machine.sphere_centres(q)
    line = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    np.testing.assert_allclose(q2, 4 * line[:, 2], rtol=1e-10)
    assert np.all(np.abs(q2) > 1e-2 * 4 * machine.l1 ** 2)
    np.testing.assert_allclose(machine.fk(q).P, lower, rtol=0, atol=1e-11)
    np.testing.assert_allclose(lower, P, rtol=0, atol=1e-11)
    # the upper root also closes all three legs, but it is not the platform's position
    d, L2 = leg_offsets_eq5(machine, q, machine.u)
    lhs = np.linalg.norm(np.einsum("lij,kj->kli", machine.Rphi, upper) + d, axis=-1)
    np.testing.assert_allclose(lhs, np.broadcast_to(L2, lhs.shape), rtol=0, atol=1e-10)
    assert np.all(upper[:, 2] > lower[:, 2] + 0.1)


def test_fk_is_vectorized_and_chunked(rng):
    """Chunked evaluation (fk_chunk rows at a time) equals one call and row-by-row calls;
    fk_positions broadcasts over leading axes."""
    m = default_with_errors()
    P = random_positions(m, rng, 50)
    q = m.ik(P)
    whole = m.fk(q).P
    m.fk_chunk = 7                                      # 8 chunks, the last one short
    # other batch sizes: the same formulas, to rounding relative to the positions' scale
    tol = 1e-12 * float(np.max(np.abs(whole)))
    np.testing.assert_allclose(m.fk(q).P, whole, rtol=0, atol=tol)
    rows = np.array([m.fk(qk).P[0] for qk in q])
    np.testing.assert_allclose(rows, whole, rtol=0, atol=tol)
    P2, ok2 = m.fk_positions(q.reshape(5, 10, 3))
    assert P2.shape == (5, 10, 3) and ok2.shape == (5, 10) and ok2.all()
    np.testing.assert_allclose(P2.reshape(-1, 3), whole, rtol=0, atol=tol)
    assert m.fk(np.zeros((0, 3))).P.shape == (0, 3)


# -- degenerate cases ----------------------------------------------------------------------------

def test_unreachable_readings_give_nan_not_exceptions():
    """A forearm shorter than the spread of the sphere centres: the spheres do not meet."""
    short = Delta(0.2, 0.05, 0.3, 0.2)
    q = np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = short.fk(q)
    assert not res.converged.any()
    assert np.all(np.isnan(res.P)) and np.all(np.isinf(res.residual))
    with pytest.raises(ConvergenceError, match=r"2 pose\(s\), row\(s\) 1, 2"):
        short.fk(q, raise_on_failure=True)
    # a bad row does not spoil the good ones
    m = default_delta()
    good = m.ik(m.home[0])
    res = m.fk(np.vstack([good, [np.nan, 0.0, 0.0], good]))
    np.testing.assert_array_equal(res.converged, [True, False, True])
    np.testing.assert_allclose(res.P[[0, 2]], [m.home[0]] * 2, rtol=0, atol=1e-12)


def test_collinear_sphere_centres_are_flagged():
    """Nominal 90-degree Delta at theta = (-60, -120, -60) deg: all three sphere centres lie
    on the Y axis line at z = -l1 sin 60 deg, the intersection is a circle, not two points."""
    m = default_delta()
    q = deg([-60.0, -120.0, -60.0])
    c, _ = m.sphere_centres(q)
    assert np.linalg.norm(np.cross(c[1] - c[0], c[2] - c[0])) < 1e-13   # m^2; 1e-17 here
    # nearly collinear centres have a circumcircle wider than the forearms: unreachable
    near = q + deg([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [5.0, 0.0, 0.0], [-5.0, 0.0, 5.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = m.fk(near)
    assert not res.converged.any() and np.all(np.isnan(res.P))


def test_ik_of_unreachable_points_is_nan():
    m = default_delta()
    P = np.array([[0.0, 0.0, -2.0], [0.0, 0.0, 1.5], [3.0, 0.0, -0.5], m.home[0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        q, dq_dp, dq_du = m.ik_jacobians(P)
    assert np.all(np.isnan(q[:3])) and np.all(np.isfinite(q[3]))
    assert np.all(np.isfinite(dq_dp[3])) and np.all(np.isfinite(dq_du[3]))


# -- derivatives against central finite differences ---------------------------------------------

def test_dq_dp_matches_finite_differences(machine, rng):
    P = random_positions(machine, rng, 20)
    q, J, _ = machine.ik_jacobians(P, want_du=False)
    h = 1e-6
    fd = np.stack([(machine.ik(P + h * e) - machine.ik(P - h * e)) / (2 * h)
                   for e in np.eye(3)], -1)
    np.testing.assert_allclose(J[..., :3], fd, rtol=0, atol=1e-7 * np.abs(fd).max())
    np.testing.assert_array_equal(J[..., 3:], 0.0)       # the platform does not rotate


def test_dq_du_matches_finite_differences_for_all_27_parameters(machine, rng):
    P = random_positions(machine, rng, 20)
    u = machine.u
    _, _, Ju = machine.ik_jacobians(P)
    assert Ju.shape == (20, 3, 27)
    h = 1e-6
    fd = np.empty_like(Ju)
    for k in range(27):
        du = np.zeros(27)
        du[k] = h
        fd[..., k] = (machine.ik(P, u=u + du) - machine.ik(P, u=u - du)) / (2 * h)
    np.testing.assert_allclose(Ju, fd, rtol=0, atol=1e-7 * np.abs(fd).max())
    # every parameter moves only its own leg's angle
    names = machine.parameters.names
    for k, name in enumerate(names):
        leg = int(name[3]) - 1
        others = [j for j in range(3) if j != leg]
        assert np.all(Ju[:, others, k] == 0), name
        assert np.abs(Ju[:, leg, k]).max() > 1e-3, name


def test_fk_jacobian_is_minus_inverse_ik_jacobian(machine, rng):
    """dp/du = -(dq/dp)^-1 dq/du (used by the tracker calibration) against FD of the FK."""
    P = random_positions(machine, rng, 10)
    q = machine.ik(P)
    _, Jp, Ju = machine.ik_jacobians(P)
    dp_du = -np.linalg.solve(Jp[..., :3], Ju)
    h = 1e-6
    u = machine.u
    fd = np.empty_like(dp_du)
    for k in range(27):
        du = np.zeros(27)
        du[k] = h
        fd[..., k] = (machine.fk(q, u + du).P - machine.fk(q, u - du).P) / (2 * h)
    np.testing.assert_allclose(dp_du, fd, rtol=0, atol=1e-7 * np.abs(fd).max())


def test_only_db_minus_da_enters(machine, rng):
    """Moving a leg's base joint and platform joint by the same vector changes neither IK nor
    FK (SPEC 2.2: 9 of the 27 directions are unidentifiable)."""
    P = random_positions(machine, rng, 50)
    q = machine.ik(P)
    p = machine.parameters
    _, _, Ju = machine.ik_jacobians(P)
    for i in range(3):
        shift = rng.normal(0.0, 5e-3, 3)
        u = machine.u.copy()
        u[p.indices(f"leg{i + 1}.da")] += shift
        u[p.indices(f"leg{i + 1}.db")] += shift
        np.testing.assert_allclose(machine.ik(P, u=u), q, rtol=0,
                                   atol=1e-12 * max(1.0, float(np.max(np.abs(q)))))
        np.testing.assert_allclose(machine.fk(q, u).P, P, rtol=0, atol=1e-12)
        np.testing.assert_allclose(Ju[..., p.indices(f"leg{i + 1}.da")],
                                   -Ju[..., p.indices(f"leg{i + 1}.db")], rtol=0,
                                   atol=1e-12 * np.abs(Ju).max())
    # but db alone does change it (the test can fail)
    u = machine.u.copy()
    u[p.index("leg2.db.x")] += 1e-3
    assert np.abs(machine.ik(P, u=u) - q).max() > 1e-4


def test_delta_parameters_registry():
    p = delta_parameters(np.arange(27.0))
    assert p.get("leg2.dtheta") == 12.0
    np.testing.assert_array_equal(p.get("leg3.db"), [24.0, 25.0, 26.0])
    assert p.kinds[p.index("leg1.dtheta")] == "angle"
    assert p.kinds[p.index("leg1.dl2")] == "length"


def test_pose_accuracy_default_poses_do_not_rotate_a_delta():
    """A perfect model of a translation-only platform has no orientation error on the default
    workspace (it used to be given rotated poses)."""
    from pkmcal.analysis.accuracy import pose_accuracy
    from pkmcal.machines import default_delta

    report = pose_accuracy(default_delta(), default_delta(), n=50)
    assert report.n_failed == 0
    assert report.position_max < 1e-12 and report.orientation_max < 1e-12
