"""Pose errors of a six-leg platform from joint clearance, leg errors and loads (seed 003,
SPEC 2.3), and tolerance analysis: signs by hand, statics, Jacobians by finite differences, the
first-order model against the exact perturbed closure, the paper's case study, envelopes,
Monte Carlo against the linear covariance, and every geometric value an input."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pkmcal.analysis import errors as err
from pkmcal.analysis import tolerance as tl
from pkmcal.errors import InputError
from pkmcal.kinematics import matrix_from_euler, matrix_from_rotvec
from pkmcal.machines import cubic_6upu

C_B = 10e-6
G = err.STANDARD_GRAVITY


def leg_indices(machine):
    names = machine.parameters
    ib = np.stack([names.indices(f"leg{i + 1}.base") for i in range(6)])
    ip = np.stack([names.indices(f"leg{i + 1}.platform") for i in range(6)])
    il0 = np.array([names.index(f"leg{i + 1}.l0") for i in range(6)])
    return ib, ip, il0


def perturbed(machine, db=None, dp=None, dl=None):
    """The machine with base joints + db, platform joints + dp (platform frame), legs + dl."""
    ib, ip, il0 = leg_indices(machine)
    du = np.zeros(len(machine.parameters))
    if db is not None:
        du[ib] = db
    if dp is not None:
        du[ip] = dp
    if dl is not None:
        du[il0] = dl
    return machine.with_parameters(machine.u + du)


def exact_error(machine, real, P0, R0):
    """Pose the real machine reaches with the readings the nominal one commands for (P0, R0)."""
    sol = real.fk(machine.ik(P0, R0)[None], start=(P0, R0))
    assert sol.converged.all()
    return err.pose_difference(sol.P[0], sol.R[0], P0, R0)


@pytest.fixture(scope="module")
def cubic():
    return cubic_6upu()


@pytest.fixture(scope="module")
def aligned():
    """The cubic device with z1 = z2 = 0.14 m: at (0, 0, 0.41) m, R = I, legs 1-3 are vertical,
    4-5 run along +X and 6 along -Y (a pose whose forces are known by hand)."""
    return cubic_6upu(z1=0.14, z2=0.14), np.array([0.0, 0.0, 0.41]), np.eye(3)


@pytest.fixture(scope="module")
def paper(cubic):
    """Seed 003 case study: circle r = 0.1 m at z = 0.41 m, 10 rad/s, 360 samples."""
    path = err.circle_trajectory(0.1, 0.41, 10.0, 360)
    return err.trajectory_errors(cubic, path, mass=4.8, cutting_force=(0, 0, -500),
                                 clearance=C_B)


# --------------------------------------------------------------------------------------------
# signs and statics
# --------------------------------------------------------------------------------------------


def test_aligned_pose_has_the_hand_geometry(aligned):
    machine, P, R = aligned
    _, _, z = machine.jacobians(P, R)
    expected = np.array([[0, 0, 1]] * 3 + [[1, 0, 0]] * 2 + [[0, -1, 0]], float)
    np.testing.assert_allclose(z, expected, atol=1e-13)


def test_vertical_load_on_vertical_legs_is_compression(aligned):
    """Hand check (SPEC 2.3): the platform's weight on vertical legs compresses them. Moments
    about the origin put half the weight on leg 3 and a quarter on legs 1 and 2; the
    horizontal legs carry nothing."""
    machine, P, R = aligned
    W = 4.8 * G
    Jp, _, _ = machine.jacobians(P, R)
    f = err.link_forces(Jp, err.platform_wrench(None, 4.8, (0, 0, 0)))
    np.testing.assert_allclose(f, [-W / 4, -W / 4, -W / 2, 0, 0, 0], atol=1e-12 * W)
    assert np.all(f[:3] < 0)
    # pulled upwards (a force larger than the weight): tension
    f_up = err.link_forces(Jp, err.platform_wrench(None, 4.8, (0, 0, 3 * W)))
    np.testing.assert_allclose(f_up, [W / 2, W / 2, W, 0, 0, 0], atol=1e-12 * W)
    # legs 4-5 run from base joints at -X to platform joints at +X: pushing the platform
    # toward +X pulls them (tension, half the push each); leg 6 (along Y) stays unloaded
    f_x = err.link_forces(Jp, err.platform_wrench(None, 0.0, (100.0, 0, 0)))
    np.testing.assert_allclose(f_x[3:], [50.0, 50.0, 0.0], atol=1e-9)


def test_tension_lengthens_and_compression_shortens(aligned):
    """Vertical legs in compression: the joints are pushed together, the platform sinks by
    2 c_b; pulled up it rises by 2 c_b."""
    machine, P, R = aligned
    Jp, Js, z = machine.jacobians(P, R)
    for load, expected in (((0, 0, -500.0), -2 * C_B), ((0, 0, +2000.0), +2 * C_B)):
        f = err.link_forces(Jp, err.platform_wrench(None, 4.8, load))
        e = err.clearance_errors(Jp, Js, z, R, f, C_B)
        # legs 4-6 carry nothing: their side is undetermined and the x, y envelope is open
        assert list(e.side) == [np.sign(expected)] * 3 + [0, 0, 0]
        assert e.dx[2] == pytest.approx(expected, rel=1e-12)
        assert e.dx_min[2] == e.dx_max[2] == e.dx[2]


def test_statics_balance_the_loads(paper):
    """Forces reproduce the load: sum of leg forces on the platform + weight + cutting force =
    m a, moments about the origin zero, written out leg by leg (not through J_p)."""
    path = paper.trajectory
    machine = cubic_6upu()
    w, s, L = machine.leg_vectors(path.P, path.R)
    z = w / L[..., None]
    on_platform = -paper.forces[..., None] * z                    # tension pulls to the base
    weight = np.array([0, 0, -4.8 * G])
    total = on_platform.sum(axis=1) + weight + np.array([0, 0, -500.0])
    np.testing.assert_allclose(total, 4.8 * path.acceleration, atol=1e-9 * 500)
    moment = np.cross(s, on_platform).sum(axis=1)
    np.testing.assert_allclose(moment, 0.0, atol=1e-9 * 500 * 0.3)
    Jp = machine.jacobians(path.P, path.R)[0]
    assert np.max(np.abs(err.force_residual(Jp, paper.forces, paper.wrench))) < 1e-9
    # centripetal: |a| = omega^2 r = 10 m/s^2 toward the centre
    np.testing.assert_allclose(np.linalg.norm(path.acceleration, axis=1), 10.0, rtol=1e-12)
    assert np.all(np.einsum("ij,ij->i", path.acceleration[:, :2], path.P[:, :2]) < 0)


def test_statics_at_random_poses_and_loads(cubic):
    rng = np.random.default_rng(7)
    P = np.array([0, 0, 0.41]) + rng.uniform(-0.05, 0.05, (50, 3))
    R = matrix_from_euler(rng.uniform(-0.1, 0.1, (50, 3)))
    wrench = err.platform_wrench(rng.normal(0, 10, (50, 3)), 3.0, rng.normal(0, 300, (50, 3)))
    Jp = cubic.jacobians(P, R)[0]
    f = err.link_forces(Jp, wrench)
    assert np.max(np.abs(err.force_residual(Jp, f, wrench))) < 1e-9


# --------------------------------------------------------------------------------------------
# Jacobians and the first-order model against the exact closure
# --------------------------------------------------------------------------------------------


def test_jacobians_against_finite_differences_of_ik(cubic):
    P = np.array([0.04, -0.03, 0.42])
    R = matrix_from_euler([0.06, -0.04, 0.1])
    Jp, Js, _ = cubic.jacobians(P, R)
    h = 1e-7
    fd = np.empty((6, 6))
    for k in range(6):
        d = np.zeros(6)
        d[k] = h
        plus = cubic.ik(P + d[:3], matrix_from_rotvec(d[3:]) @ R)
        minus = cubic.ik(P - d[:3], matrix_from_rotvec(-d[3:]) @ R)
        fd[:, k] = (plus - minus) / (2 * h)
    np.testing.assert_allclose(Jp, fd, atol=1e-8)
    # J_s: leg i's length against its platform joint (platform frame) and base joint
    for i in range(6):
        for k in range(6):
            d = np.zeros((6, 3))
            d[i, k % 3] = h
            kw = {"dp": d} if k < 3 else {"db": d}
            kw_m = {key: -v for key, v in kw.items()}
            dl = (perturbed(cubic, **kw).ik(P, R) - perturbed(cubic, **kw_m).ik(P, R)) / (2 * h)
            assert dl[i] == pytest.approx(Js[i, k], abs=1e-8)
            assert np.all(np.abs(np.delete(dl, i)) < 1e-12)


def test_first_order_error_matches_exact_closure(cubic):
    """eq. 10 against Stewart.fk of the perturbed machine: agreement to second order (relative
    ~1e-4 at 10 um; the discrepancy shrinks as the square of the errors)."""
    rng = np.random.default_rng(11)
    db, dp = rng.uniform(-1, 1, (2, 6, 3))
    dl = rng.uniform(-1, 1, 6)
    P0, R0 = np.array([0.03, -0.02, 0.40]), matrix_from_euler([0.05, -0.03, 0.08])
    Jp, Js, _ = cubic.jacobians(P0, R0)
    rel = []
    for scale in (10e-6, 5e-6):
        exact = exact_error(cubic, perturbed(cubic, scale * db, scale * dp, scale * dl), P0, R0)
        first = err.pose_error(Jp, scale * dl, Js, scale * np.concatenate([dp, db], axis=-1))
        rel.append(np.max(np.abs(exact - first)) / np.max(np.abs(first)))
    assert rel[0] < 2e-4
    assert rel[1] / rel[0] == pytest.approx(0.5, abs=0.05)      # second order


def test_clearance_error_matches_exact_closure(cubic, paper):
    """Joints displaced to the side the force pushes them (eq. 17-18, physical sign): the exact
    pose of that machine agrees with the first-order clearance error."""
    for k in (15, 120, 200, 300):
        P0, R0 = paper.trajectory.P[k], paper.trajectory.R[k]
        side = paper.errors.side[k]
        assert np.all(side != 0)
        _, _, z = cubic.jacobians(P0, R0)
        db = side[:, None] * C_B * z                        # tension: toward the platform
        dp = -side[:, None] * C_B * z @ R0                  # tension: toward the base
        exact = exact_error(cubic, perturbed(cubic, db, dp), P0, R0)
        np.testing.assert_allclose(paper.errors.dx[k], exact, rtol=1e-4,
                                   atol=1e-4 * np.max(np.abs(exact)))


def test_closure_pose_agrees_with_stewart_fk(cubic):
    rng = np.random.default_rng(2)
    P0, R0 = np.array([0.0, 0.05, 0.41]), matrix_from_euler([0.02, 0.0, -0.05])
    ib, ip, il0 = leg_indices(cubic)
    du = rng.uniform(-1e-4, 1e-4, (4, len(cubic.parameters)))
    du[:, [cubic.parameters.index(f"leg{i + 1}.gain") for i in range(6)]] = 0
    q = cubic.ik(P0, R0)
    u = cubic.u + du
    sol = err.closure_pose(P0, R0, u[:, ib], u[:, ip], u[:, il0] + q)
    for n in range(4):
        ref = cubic.with_parameters(u[n]).fk(q[None], start=(P0, R0))
        np.testing.assert_allclose(sol.P[n], ref.P[0], atol=1e-12)
        np.testing.assert_allclose(sol.R[n], ref.R[0], atol=1e-12)


# --------------------------------------------------------------------------------------------
# the paper's case study (seed 003 Figs. 6-7)
# --------------------------------------------------------------------------------------------


def test_paper_case_dx_switches_where_legs_4_5_change_direction(paper):
    angle = np.degrees(paper.trajectory.angle)
    f = paper.forces
    for leg in (3, 4):
        crossings = err.zero_crossings(angle, f[:, leg], 360.0)
        assert crossings.size == 2
        assert abs(crossings[0] - 90) < 1 and abs(crossings[1] - 270) < 1
    dx_cross = err.zero_crossings(angle, paper.errors.dx[:, 0], 360.0)
    assert dx_cross.size == 2
    assert abs(dx_cross[0] - 90) < 3 and abs(dx_cross[1] - 270) < 3
    # x error follows legs 4-5 (they run along +X): tension -> platform pushed toward +X
    both = (paper.errors.side[:, 3] == paper.errors.side[:, 4]) & (paper.errors.side[:, 3] != 0)
    assert np.all(np.sign(paper.errors.dx[both, 0]) == paper.errors.side[both, 3])


def test_paper_case_dy_follows_leg_6_and_dz_leg_1(paper):
    side, dx = paper.errors.side, paper.errors.dx
    angle = np.degrees(paper.trajectory.angle)
    # leg 6 runs from its base joint toward -Y: in tension the platform moves to -Y
    ok = side[:, 5] != 0
    assert np.all(np.sign(dx[ok, 1]) == -side[ok, 5])
    f6 = err.zero_crossings(angle, paper.forces[:, 5], 360.0)
    dy = err.zero_crossings(angle, dx[:, 1], 360.0)
    assert f6.size == dy.size == 2
    gap = np.abs((dy[:, None] - f6[None, :] + 180) % 360 - 180)
    assert np.all(gap.min(axis=1) < 1.0)
    # legs 1-3 stay in compression along the whole circle: the platform sits low
    assert np.all(paper.forces[:, :3] < 0)
    assert np.all(np.sign(dx[:, 2]) == side[:, 0]) and np.all(dx[:, 2] < 0)


def test_paper_case_magnitudes_and_pure_translation(paper):
    """Errors of the order of 2 c_b; at R = I legs 1-3 are parallel (b_i = p_i) and so are
    4-5, so the platform only translates while legs 4 and 5 push the same way."""
    dx = paper.errors.dx
    for j in range(3):
        assert 2 * C_B <= np.max(np.abs(dx[:, j])) <= 4 * C_B
    agree = np.all(paper.errors.side != 0, axis=1) & \
        (paper.errors.side[:, 3] == paper.errors.side[:, 4])
    assert agree.sum() > 340
    assert np.max(np.abs(dx[agree, 3:])) < 1e-12
    assert np.max(np.abs(dx[~agree, 3:])) > 1e-5          # they tilt the platform near 90/270


def test_paper_case_round_off_forces_give_envelopes(paper):
    """At 0, 90, 180 and 270 deg a force is zero up to round-off: never a sign there."""
    und = paper.errors.undetermined
    for k, legs in ((0, [5]), (90, [3, 4]), (180, [5]), (270, [3, 4])):
        assert np.all(und[k, legs])
        assert np.all(paper.errors.dx_max[k] >= paper.errors.dx_min[k])
        for leg in legs:
            assert np.max(paper.errors.dx_max[k] - paper.errors.dx_min[k]) > 0
    # everywhere else with every side determined the envelope is closed
    closed = ~np.any(und, axis=1)
    np.testing.assert_array_equal(paper.errors.dx_min[closed], paper.errors.dx[closed])
    np.testing.assert_array_equal(paper.errors.dx_max[closed], paper.errors.dx[closed])


# --------------------------------------------------------------------------------------------
# envelopes
# --------------------------------------------------------------------------------------------


def _all_sides(Jp, Js, z, R, side, undetermined, c, e=0.0):
    """Pose errors for every side combination of the undetermined legs (brute force)."""
    out = []
    legs = np.flatnonzero(undetermined)
    for combo in itertools.product((-1, 1), repeat=legs.size):
        s = side.copy()
        s[legs] = combo
        dp = err.clearance_joint_errors(z, R, s, c, c)
        out.append(err.pose_error(Jp, s * e, Js, dp))
    return np.array(out)


def test_envelope_where_a_force_is_exactly_zero(cubic):
    """A load chosen so that leg 4 carries exactly nothing at a generic pose: its side is
    undetermined, the envelope is the min/max over both sides, and a load that makes leg 4
    slightly pulled or pushed lands on the envelope's edges."""
    P, R = np.array([0.03, 0.05, 0.40]), matrix_from_euler([0.04, 0.02, -0.03])
    Jp, Js, z = cubic.jacobians(P, R)
    A = np.linalg.inv(Jp.T)[:, :3]                      # f = -A F for a force F at the origin
    F = np.cross(A[3], [0.3, -0.2, 1.0])
    F *= 400 / np.linalg.norm(F)
    f = err.link_forces(Jp, err.platform_wrench(None, 0.0, -F))
    assert abs(f[3]) < 1e-12 * 400 and np.all(np.abs(np.delete(f, 3)) > 1.0)
    for tol in (1.0, 0.0):                       # even without a tolerance: not a sign of 1e-14
        e = err.clearance_errors(Jp, Js, z, R, f, C_B, force_tol=tol)
        assert list(np.flatnonzero(e.undetermined)) == [3]
        combos = _all_sides(Jp, Js, z, R, e.side, e.undetermined, C_B)
        np.testing.assert_allclose(e.dx_min, combos.min(axis=0), atol=1e-18)
        np.testing.assert_allclose(e.dx_max, combos.max(axis=0), atol=1e-18)
        np.testing.assert_allclose(e.dx, combos.mean(axis=0), atol=1e-18)
    for sign in (-1, 1):
        f_near = err.link_forces(Jp, err.platform_wrench(None, 0.0, -F + sign * 5 * A[3]
                                                         / np.linalg.norm(A[3])))
        assert np.sign(f_near[3]) == sign
        near = err.clearance_errors(Jp, Js, z, R, f_near, C_B)
        assert np.all(near.side != 0)
        assert np.all(near.dx >= e.dx_min - 1e-15) and np.all(near.dx <= e.dx_max + 1e-15)
        edge = np.isclose(near.dx, e.dx_min, atol=1e-15) | np.isclose(near.dx, e.dx_max,
                                                                        atol=1e-15)
        assert np.all(edge | (e.dx_max - e.dx_min < 1e-15))


def test_envelope_over_several_undetermined_legs(aligned):
    """Weight only on the hand pose: legs 4, 5, 6 carry exactly nothing; the envelope is the
    min/max over their 8 side combinations (clearance and backlash together)."""
    machine, P, R = aligned
    Jp, Js, z = machine.jacobians(P, R)
    f = err.link_forces(Jp, err.platform_wrench(None, 4.8, (0, 0, -500)))
    e = err.clearance_errors(Jp, Js, z, R, f, C_B, backlash=3e-6)
    assert list(np.flatnonzero(e.undetermined)) == [3, 4, 5]
    combos = _all_sides(Jp, Js, z, R, e.side, e.undetermined, C_B, 3e-6)
    assert len(combos) == 8
    np.testing.assert_allclose(e.dx_min, combos.min(axis=0), atol=1e-18)
    np.testing.assert_allclose(e.dx_max, combos.max(axis=0), atol=1e-18)
    assert e.dx_max[0] - e.dx_min[0] == pytest.approx(2 * (2 * C_B + 3e-6), rel=1e-9)


def test_force_tolerance_decides_which_sides_are_known(paper, cubic):
    path = paper.trajectory
    loose = err.trajectory_errors(cubic, path, clearance=C_B, force_tol=10.0)
    assert loose.errors.undetermined.sum() > paper.errors.undetermined.sum()
    assert np.all(np.abs(loose.forces[loose.errors.undetermined]) <= 10.0)
    assert np.all(np.abs(loose.forces[~loose.errors.undetermined]) > 10.0)


# --------------------------------------------------------------------------------------------
# every value an input
# --------------------------------------------------------------------------------------------


def test_scaled_device_gives_scaled_errors(paper):
    """All lengths x k (geometry, circle, clearance) and omega / sqrt(k) (same accelerations):
    the same forces, position errors x k, the same orientation errors."""
    k = 2.5
    geometry = dict(a=0.16, b=0.14, c=0.195, d=0.270, e=0.055, f=0.205, g=0.130, z1=0.130,
                    z2=0.130, z3=0.280, height=0.41)
    big = cubic_6upu(**{n: k * v for n, v in geometry.items()})
    path = err.circle_trajectory(0.1 * k, 0.41 * k, 10.0 / np.sqrt(k), 360)
    res = err.trajectory_errors(big, path, clearance=C_B * k)
    np.testing.assert_allclose(res.forces, paper.forces, atol=1e-9)
    np.testing.assert_array_equal(res.errors.side, paper.errors.side)
    np.testing.assert_allclose(res.errors.dx[:, :3], k * paper.errors.dx[:, :3], atol=1e-15)
    np.testing.assert_allclose(res.errors.dx[:, 3:], paper.errors.dx[:, 3:], atol=1e-12)
    np.testing.assert_allclose(res.errors.dx_max[:, :3], k * paper.errors.dx_max[:, :3],
                               atol=1e-15)


def test_errors_are_linear_in_clearance_and_backlash_adds(paper, cubic):
    path = paper.trajectory
    triple = err.trajectory_errors(cubic, path, clearance=3 * C_B)
    np.testing.assert_allclose(triple.errors.dx, 3 * paper.errors.dx, atol=1e-15)
    # clearance c at both joints = backlash 2 c on the leg (same effective length change)
    screw = err.trajectory_errors(cubic, path, clearance=0.0, backlash=2 * C_B)
    np.testing.assert_allclose(screw.errors.dx, paper.errors.dx, atol=1e-15)
    np.testing.assert_allclose(screw.errors.dx_min, paper.errors.dx_min, atol=1e-15)
    # base and platform clearances are separate inputs
    half = err.trajectory_errors(cubic, path, clearance=C_B, clearance_platform=0.0)
    np.testing.assert_allclose(half.errors.dx, paper.errors.dx / 2, atol=1e-15)


def test_a_different_geometry_changes_the_answer(paper):
    other = err.trajectory_errors(cubic_6upu(f=0.25, z3=0.3), paper.trajectory,
                                  clearance=C_B)
    assert np.max(np.abs(other.forces - paper.forces)) > 1.0


def test_bad_inputs_raise_input_error(cubic, paper):
    with pytest.raises(InputError, match="clearance"):
        err.trajectory_errors(cubic, paper.trajectory, clearance=-1e-6)
    with pytest.raises(InputError, match="mass"):
        err.trajectory_errors(cubic, paper.trajectory, mass=float("nan"))
    with pytest.raises(InputError, match="samples"):
        err.circle_trajectory(samples=0)
    with pytest.raises(InputError, match="singularity"):
        err.trajectory_errors(cubic, err.circle_trajectory(0.0, 0.0, 1.0, 4))
    with pytest.raises(InputError, match="increase"):
        err.trajectory_from_poses([0, 1, 1], np.zeros((3, 3)), np.broadcast_to(np.eye(3),
                                                                                (3, 3, 3)))


# --------------------------------------------------------------------------------------------
# trajectories from poses
# --------------------------------------------------------------------------------------------


def test_accelerations_by_finite_differences_on_an_uneven_grid():
    rng = np.random.default_rng(5)
    t = np.sort(rng.uniform(0, 0.6, 400))
    P = np.column_stack([0.1 * np.cos(10 * t), 0.1 * np.sin(10 * t), np.full_like(t, 0.41)])
    a = err.acceleration_from_positions(t, P)
    exact = -100 * P * [1, 1, 0]
    h = np.max(np.diff(t))
    inner = slice(1, -1)
    assert np.max(np.abs(a[inner] - exact[inner])) < 10 * (10 * h + (10 * h) ** 2)
    # a uniform grid is second-order accurate
    t = np.linspace(0, 0.6, 301)
    P = np.column_stack([0.1 * np.cos(10 * t), 0.1 * np.sin(10 * t), np.full_like(t, 0.41)])
    a = err.acceleration_from_positions(t, P)
    np.testing.assert_allclose(a[1:-1], (-100 * P * [1, 1, 0])[1:-1], atol=10 * (0.02**2))


# --------------------------------------------------------------------------------------------
# tolerance analysis
# --------------------------------------------------------------------------------------------


def test_sensitivity_is_eq_10(cubic):
    """dx/du with readings held: -J_p^-1 J_s on the joints, J_p^-1 on the leg offsets."""
    P, R = np.array([0.02, 0.03, 0.41]), matrix_from_euler([0.03, -0.02, 0.05])
    S = tl.sensitivity(cubic, P, R)
    Jp, Js, _ = cubic.jacobians(P, R)
    Jinv = np.linalg.inv(Jp)
    ib, ip, il0 = leg_indices(cubic)
    for i in range(6):
        np.testing.assert_allclose(S[:, ip[i]], -Jinv[:, [i]] * Js[i, :3], atol=1e-12)
        np.testing.assert_allclose(S[:, ib[i]], -Jinv[:, [i]] * Js[i, 3:], atol=1e-12)
        np.testing.assert_allclose(S[:, il0[i]], Jinv[:, i], atol=1e-12)


@pytest.mark.parametrize("distribution", ["uniform", "normal"])
def test_monte_carlo_agrees_with_linear_covariance(cubic, distribution):
    tol = tl.stewart_tolerances(cubic, joint=1e-6, length=2e-6, distribution=distribution)
    P, R = np.array([0.05, 0.02, 0.41]), matrix_from_euler([0.0, 0.02, 0.0])
    mc = tl.monte_carlo(cubic, P, R, tol, samples=20000, rng=3)
    assert mc.exact and mc.converged.all()
    sd = np.sqrt(np.diag(mc.linear_cov))
    np.testing.assert_allclose(mc.std, sd, rtol=0.03)
    corr = (mc.cov - mc.linear_cov) / np.outer(sd, sd)
    assert np.max(np.abs(corr)) < 0.03
    assert np.all(np.abs(mc.mean) < 4 * sd / np.sqrt(20000))
    if distribution == "uniform":
        assert np.all(np.abs(mc.dx) <= mc.worst_case * (1 + 1e-3))
        assert np.all(np.max(np.abs(mc.dx), axis=0) > 0.3 * mc.worst_case)
    # the same seed gives the same samples
    again = tl.monte_carlo(cubic, P, R, tol, samples=20000, rng=3)
    np.testing.assert_array_equal(again.dx, mc.dx)


def test_linear_monte_carlo_and_the_tolerance_registry(cubic):
    tol = tl.tolerances(cubic, {"leg*.base.*": 5e-6, "leg4.base.x": 0.0})
    assert tol.band[cubic.parameters.index("leg4.base.x")] == 0.0
    assert tol.band[cubic.parameters.index("leg4.base.y")] == 5e-6
    assert tol.band[cubic.parameters.index("leg4.platform.y")] == 0.0
    P, R = np.array([0.0, 0.0, 0.41]), np.eye(3)
    mc = tl.monte_carlo(cubic, P, R, tol, samples=5000, rng=1, exact=False)
    S = tl.sensitivity(cubic, P, R)
    np.testing.assert_allclose(mc.dx, tl.Tolerances(tol.names, tol.band).sample(5000, 1) @ S.T)
    with pytest.raises(InputError, match="no parameter"):
        tl.tolerances(cubic, {"chain*.b.*": 1e-6})
    with pytest.raises(InputError, match="distribution"):
        tl.tolerances(cubic, {}, "triangular")


def test_error_map_matches_pointwise_analysis(cubic):
    tol = tl.stewart_tolerances(cubic, joint=10e-6, length=5e-6)
    x, y = np.linspace(-0.1, 0.1, 5), np.linspace(-0.08, 0.08, 4)
    emap = tl.error_map(cubic, x, y, 0.41, tol)
    assert emap.worst.shape == (4, 5, 6) and emap.valid.all()
    S = tl.sensitivity(cubic, np.array([x[1], y[2], 0.41]), np.eye(3))
    np.testing.assert_allclose(emap.worst[2, 1], tl.worst_case(S, tol), rtol=1e-12)
    np.testing.assert_allclose(emap.std[2, 1], np.sqrt(np.diag(tl.linear_covariance(S, tol))),
                               rtol=1e-12)
    # twice the tolerances, twice the errors
    emap2 = tl.error_map(cubic, x, y, 0.41, tl.stewart_tolerances(cubic, 20e-6, 10e-6))
    np.testing.assert_allclose(emap2.worst, 2 * emap.worst, rtol=1e-12)


def test_clearance_map_matches_the_trajectory_analysis(cubic):
    x, y = np.array([-0.05, 0.02, 0.1]), np.array([0.0, 0.03])
    cmap = err.clearance_map(cubic, x, y, 0.41, clearance=C_B)
    path = err.Trajectory(np.zeros(1), np.array([[0.02, 0.03, 0.41]]), np.eye(3)[None],
                          np.zeros((1, 3)))
    res = err.trajectory_errors(cubic, path, clearance=C_B)
    np.testing.assert_allclose(cmap.dx[1, 1], res.errors.dx[0], atol=1e-18)
    # the bound covers every side combination
    Jp, Js, z = cubic.jacobians(path.P[0], np.eye(3))
    combos = _all_sides(Jp, Js, z, np.eye(3), np.zeros(6, int), np.ones(6, bool), C_B)
    np.testing.assert_allclose(cmap.bound[1, 1], np.max(np.abs(combos), axis=0), rtol=1e-12)
