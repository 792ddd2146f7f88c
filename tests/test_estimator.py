"""The block Levenberg-Marquardt estimator and the three constraint-link calibration methods.

Part 1 checks the estimator on a classic problem with a known optimum (orthogonal-distance
circle fit, one local unknown per point) against scipy, and its algebra (reduced rows = Schur
complement, covariance = block of the full inverse, minimum-norm gauge steps).
Part 2 re-runs every calibration method (SPEC 2.1) on noise-free and noisy Hexa Slide data,
compares gauge-free (SPEC 5) and checks the reported rank, named gauges and uncertainty.
"""

import numpy as np
import pytest
from scipy import stats
from scipy.optimize import least_squares

from pkmcal.calibration import (
    calibrate_constraint_link,
    levenberg_marquardt,
    reduce_local,
)
from pkmcal.errors import InputError
from pkmcal.identifiability import (
    BASE_ROTATION_ABOUT_O,
    CONSTRAINT_LINK_GAUGES,
    PLATFORM_ROTATION_ABOUT_P,
    align_gauge,
    transport_covariance,
)
from pkmcal.instruments.constraint_link import (
    ConstraintLinkData,
    ConstraintLinkML,
    sample_sphere_poses,
    simulate_constraint_link,
)
from pkmcal.machines import default_hexaslide, paper_table1_deviations
from pkmcal.parameters import ParameterSet
from test_hexaslide import skewed_hexaslide

# =============================================================================================
# Part 1: the estimator on a circle fit (implicit loop: one angle per point)
# =============================================================================================


class CircleFit:
    """Points ``(x_k, y_k) = c + r [cos t_k, sin t_k] + noise``: globals ``c, r`` (or ``r`` split
    in two parameters whose sum only is identifiable), one local angle ``t_k`` per point."""

    local_dof = 1

    def __init__(self, xy, sigma=1.0, split_radius=False, fixed=()):
        self.xy = np.asarray(xy, float)
        self.sigma = sigma
        self.split = split_radius
        c0 = self.xy.mean(0)
        r0 = np.mean(np.linalg.norm(self.xy - c0, axis=1))
        names = ["c.x", "c.y"] + (["r1", "r2"] if split_radius else ["r"])
        values = [*c0] + ([0.7 * r0, 0.3 * r0] if split_radius else [r0])
        self.parameters = ParameterSet(names, ["length"] * len(names), values)
        if fixed:
            self.parameters = self.parameters.with_fixed(list(fixed))
        self.scales = self.parameters.scales(1.0)

    def initial_state(self):
        u = self.parameters.values.copy()
        t = np.arctan2(*(self.xy - u[:2]).T[::-1])
        return u, t

    def global_values(self, state):
        return state[0]

    def radius(self, u):
        return u[2] + u[3] if self.split else u[2]

    def evaluate(self, state, jacobian=True):
        u, t = state
        c, s = np.cos(t), np.sin(t)
        rad = self.radius(u)
        r = np.column_stack([u[0] + rad * c - self.xy[:, 0],
                             u[1] + rad * s - self.xy[:, 1]]) / self.sigma
        if not jacobian:
            return r, None, None
        K = len(t)
        Jg = np.zeros((K, 2, len(u)))
        Jg[:, 0, 0] = 1.0
        Jg[:, 1, 1] = 1.0
        for j in range(2, len(u)):
            Jg[:, 0, j], Jg[:, 1, j] = c, s
        Jl = np.stack([-rad * s, rad * c], -1)[..., None]
        return r, Jg / self.sigma, Jl / self.sigma

    def retract(self, state, du, dl):
        return state[0] + du, state[1] + dl[:, 0]


@pytest.fixture
def circle_points():
    rng = np.random.default_rng(11)
    t = rng.uniform(0.2, 2.5, 40)                        # an arc: a non-trivial fit
    xy = np.array([1.5, -0.7]) + 2.0 * np.column_stack([np.cos(t), np.sin(t)])
    return xy + 0.01 * rng.standard_normal(xy.shape)


def test_circle_fit_matches_scipy(circle_points):
    """Maximum likelihood with per-point angles = orthogonal-distance fit (scipy, no locals)."""
    res = levenberg_marquardt(CircleFit(circle_points))
    assert res.success, res.message
    ref = least_squares(lambda p: np.linalg.norm(circle_points - p[:2], axis=1) - p[2],
                        [1.0, -1.0, 1.0], xtol=1e-15, ftol=1e-15, gtol=1e-15)
    # the estimator stops when the Gauss-Newton step would lower the cost by < 1e-12 of it,
    # i.e. within ~1e-6 standard deviations of the optimum: compare in standard deviations
    assert np.all(np.abs(res.x - ref.x) < 1e-4 * res.std), (res.x - ref.x) / res.std
    np.testing.assert_allclose(res.cost, ref.cost, rtol=1e-10)
    assert res.rank == 3 and res.null_space.shape == (3, 0)
    assert res.dof == 2 * 40 - 3 - 40
    assert res.residual_variance == pytest.approx(2 * res.cost / res.dof, rel=1e-12)


def test_covariance_is_block_of_full_inverse(circle_points):
    """The Schur-complement covariance equals the global block of the inverse of the full
    normal matrix (globals + every local angle), times 2 cost / dof."""
    problem = CircleFit(circle_points, sigma=0.01)
    res = levenberg_marquardt(problem)
    r, Jg, Jl = problem.evaluate(res.state)
    K = len(r)
    J = np.zeros((2 * K, 3 + K))
    J[:, :3] = Jg.reshape(2 * K, 3)
    for k in range(K):
        J[2 * k:2 * k + 2, 3 + k] = Jl[k, :, 0]
    full = np.linalg.inv(J.T @ J)[:3, :3]
    np.testing.assert_allclose(res.covariance, full * res.residual_variance, rtol=1e-8)
    absolute = levenberg_marquardt(problem, absolute_sigma=True)
    np.testing.assert_allclose(absolute.covariance, full, rtol=1e-8)
    np.testing.assert_allclose(absolute.std, np.sqrt(np.diag(full)), rtol=1e-8)


def test_reduce_local_is_the_schur_complement(circle_points):
    problem = CircleFit(circle_points)
    r, Jg, Jl = problem.evaluate(problem.initial_state())
    Jr, er, back = reduce_local(r, Jg, Jl)
    U = np.einsum("kmi,kmj->ij", Jg, Jg)
    W = np.einsum("kmi,kmd->kid", Jg, Jl)                 # (K, n, 1)
    V = np.einsum("kmd,kme->kde", Jl, Jl)                 # (K, 1, 1)
    S = U - np.einsum("kid,kde,kje->ij", W, np.linalg.inv(V), W)
    np.testing.assert_allclose(Jr.T @ Jr, S, rtol=1e-12, atol=1e-12 * np.abs(S).max())
    b = np.einsum("kmi,km->i", Jg, r)
    bl = np.einsum("kmd,km->kd", Jl, r)
    g = b - np.einsum("kid,kde,ke->i", W, np.linalg.inv(V), bl)
    np.testing.assert_allclose(Jr.T @ er, g, rtol=1e-12, atol=1e-12 * np.abs(g).max())
    # back-substitution: the locals minimising the cost for a given global step
    du = np.array([1e-3, -2e-3, 5e-4])
    dl = back(du)
    expected = -np.linalg.solve(V, (bl + np.einsum("kid,i->kd", W, du))[..., None])[..., 0]
    np.testing.assert_allclose(dl, expected, rtol=1e-10)


def test_unidentifiable_direction_gets_minimum_norm_steps(circle_points):
    """Only r1 + r2 is identifiable: rank 2 + 1, the null direction is (r1 - r2)/sqrt 2 and
    every step is orthogonal to it, so r1 - r2 keeps its start value."""
    problem = CircleFit(circle_points, split_radius=True)
    r1, r2 = problem.parameters.values[2:]
    res = levenberg_marquardt(problem)
    assert res.success and res.rank == 3
    n = res.null_space[:, 0] * np.sign(res.null_space[2, 0])
    np.testing.assert_allclose(n, [0, 0, 1 / np.sqrt(2), -1 / np.sqrt(2)], atol=1e-12)
    assert res.x[2] - res.x[3] == pytest.approx(r1 - r2, abs=1e-12)
    ref = levenberg_marquardt(CircleFit(circle_points))
    assert abs(res.x[2] + res.x[3] - ref.x[2]) < 1e-4 * ref.std[2]
    # the pseudo-inverse covariance has no variance along the null direction
    assert abs(n @ res.covariance @ n) < 1e-12 * np.trace(res.covariance)


def test_fixed_parameters_stay(circle_points):
    problem = CircleFit(circle_points, fixed=["c.x"])
    res = levenberg_marquardt(problem)
    assert res.x[0] == problem.parameters.values[0]
    assert np.all(res.covariance[0] == 0) and np.all(res.covariance[:, 0] == 0)
    assert res.rank == 2


@pytest.mark.parametrize("option,value", [("rtol", 1.5), ("xtol", -1.0), ("ftol", np.nan),
                                          ("max_iter", 0)])
def test_options_validated_up_front(circle_points, option, value):
    with pytest.raises(ValueError, match=option):
        levenberg_marquardt(CircleFit(circle_points), **{option: value})


def test_result_supports_item_access(circle_points):
    res = levenberg_marquardt(CircleFit(circle_points))
    assert res["x"] is res.x and res["cost"] == res.cost


# =============================================================================================
# Part 2: constraint-link calibration of the Hexa Slide
# =============================================================================================

METHOD_RANK = {"ml": 48, "ik": 48, "fk": 49}        # fk estimates Lc as well


def well_posed_constraint_link_data(true, n, rng, noise_m=0.0, min_conditioning=0.02):
    """Constraint-link data at sphere poses where the machine *driven by its five active
    actuators and held by the link* is well conditioned for its passive actuator (the paper's
    IK method solves exactly that 6x6 system at every row); the passive actuator cycles."""
    rng = np.random.default_rng(rng)
    Lc = true.constraint_link_length
    P, R = sample_sphere_poses(true, Lc, 6 * n, rng)
    K = len(P)
    passive = np.arange(K) % 6
    q, J, _ = true.ik_jacobians(P, R, want_du=False)
    F = J.copy()
    F[np.arange(K), passive] = np.concatenate([P / Lc, np.zeros((K, 3))], -1)
    F[..., 3:] /= true.characteristic_length()
    sv = np.linalg.svd(F, compute_uv=False)
    good = sv[:, -1] > min_conditioning * sv[:, 0]
    pick = np.sort(np.concatenate([np.flatnonzero(good & (passive == i))[:n // 6 + 1]
                                   for i in range(6)]))[:n]
    assert len(pick) == n
    q = q[pick] + noise_m * rng.standard_normal((n, 6))
    return ConstraintLinkData(q, Lc, passive[pick], true_P=P[pick], true_R=R[pick])


def aligned_error(nominal, result, true):
    """Largest |estimate - truth| / scale after the gauge alignment (SPEC 5)."""
    scales = nominal.parameters.scales(nominal.characteristic_length())
    u_est = result.x[:len(nominal.parameters)]
    u_al, _ = align_gauge(nominal, u_est, true.u, CONSTRAINT_LINK_GAUGES, scales)
    return np.max(np.abs(u_al - true.u) / scales), u_al


def assert_gauges_named(result):
    names = [(d.name, d.dimension) for d in result.unidentifiable]
    assert names == [(BASE_ROTATION_ABOUT_O.name, 3), (PLATFORM_ROTATION_ABOUT_P.name, 3)]


@pytest.fixture(scope="module")
def default_case():
    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + 0.3 * paper_table1_deviations(nominal.parameters))
    return nominal, true, well_posed_constraint_link_data(true, 150, rng=21)


@pytest.mark.parametrize("method", ["ml", "ik", "fk"])
def test_noise_free_recovery_every_method(default_case, method):
    """0.3 x Table 1 deviations, noise-free: every identifiable direction to 1e-10 of its
    scale, rank 48 (49 with Lc), the two 3-dim gauges named."""
    nominal, true, data = default_case
    res = calibrate_constraint_link(nominal, data, method=method)
    assert res.success, res.message
    assert res.rank == METHOD_RANK[method]
    assert_gauges_named(res)
    assert len(res.sections["constraint_link"].dropped_rows) == 0
    err, _ = aligned_error(nominal, res, true)
    assert err <= 1e-10
    assert res.sections["constraint_link"].link_length == pytest.approx(true.constraint_link_length,
                                                      abs=1e-10 * nominal.characteristic_length())
    assert np.max(np.abs(res.residuals)) < 1e-6      # whitened by 1 um: < 1 pm


def test_ml_from_full_table1_on_simulated_data():
    """The reference scenario (SPEC 2.1) on the public simulator's data: nominal + Table 1."""
    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    data = simulate_constraint_link(true, 150, rng=5)
    res = calibrate_constraint_link(nominal, data)
    assert res.success, res.message
    assert res.rank == 48
    assert_gauges_named(res)
    err, _ = aligned_error(nominal, res, true)
    assert err <= 1e-10
    # the calibrated machine inside the result carries the estimate
    np.testing.assert_array_equal(res.machine.u, res.x[:54])


def test_ml_estimates_link_length_when_asked(default_case):
    nominal, true, data = default_case
    wrong = ConstraintLinkData(data.q, data.link_length + 2e-3, data.passive)
    res = calibrate_constraint_link(nominal, wrong, estimate_link_length=True)
    assert res.success and res.rank == 49
    assert res.sections["constraint_link"].link_length == pytest.approx(
        true.constraint_link_length, abs=1e-12)
    err, _ = aligned_error(nominal, res, true)
    assert err <= 1e-10


@pytest.mark.parametrize("method,factor", [("ml", 1.0), ("ik", 0.3), ("fk", 0.3)])
def test_other_geometry_calibrates_equally_well(method, factor):
    """No hidden dependence on the default geometry (test_hexaslide.skewed_hexaslide)."""
    nominal = skewed_hexaslide()
    true = nominal.with_parameters(nominal.u
                                   + factor * paper_table1_deviations(nominal.parameters))
    data = well_posed_constraint_link_data(true, 150, rng=8)
    res = calibrate_constraint_link(nominal, data, method=method)
    assert res.success, res.message
    assert res.rank == METHOD_RANK[method]
    assert_gauges_named(res)
    err, _ = aligned_error(nominal, res, true)
    assert err <= 1e-10


def test_ml_with_noise_is_consistent_with_its_uncertainty():
    """2 um encoder noise: the aligned error is explained by the reported covariance."""
    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    sigma = 2e-6
    data = simulate_constraint_link(true, 150, noise_m=sigma, rng=17)
    res = calibrate_constraint_link(nominal, data, sigma_m=sigma)
    assert res.success, res.message
    assert res.rank == 48
    # residual variance ~ chi2(dof)/dof, dof = 900 readings - 48 - 5 x 150 pose unknowns
    assert res.dof == 900 - 48 - 750
    lo, hi = stats.chi2.ppf([1e-4, 1 - 1e-4], res.dof) / res.dof
    assert lo < res.residual_variance < hi
    scales = res.scales[:54]
    u_al, g = align_gauge(nominal, res.x[:54], true.u, CONSTRAINT_LINK_GAUGES, scales)
    e = u_al - true.u
    # the covariance follows the estimate into the truth's frames (~1 deg away here);
    # regression: without it e^T C^+ e came out ~2x chi2(48) on average over seeds
    C = transport_covariance(nominal, res.x[:54], CONSTRAINT_LINK_GAUGES, g,
                             res.covariance[:54, :54])
    z = e / np.sqrt(np.diag(C))
    assert np.mean(np.abs(z) < 3) >= 0.95 and np.max(np.abs(z)) < 5
    # the whole error against the whole covariance: e^T C^+ e ~ chi2(48)
    chi2 = (e / scales) @ np.linalg.pinv(C / np.outer(scales, scales), rcond=1e-10,
                                         hermitian=True) @ (e / scales)
    assert stats.chi2.ppf(1e-4, 48) < chi2 < stats.chi2.ppf(1 - 1e-4, 48)
    # and the error is small in absolute terms: of the order of the noise
    assert np.max(np.abs(e[res.parameters.kinds[:54] == np.array("length")])) < 100 * sigma


@pytest.mark.parametrize("seed", [0, 2, 4])
def test_a_fit_started_at_its_optimum_stops_at_once(seed):
    """A converged fit started again (as the noise-level rounds do: the same problem, or its
    residuals all scaled by a new level): the first Gauss-Newton step can gain only
    rounding; when it gains nothing the fit stops at once (2 evaluations) where it stood,
    instead of shrinking the step until one gains exactly nothing (3-7 evaluations here)."""
    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    data = simulate_constraint_link(true, 60, 2e-6, rng=seed)
    first = levenberg_marquardt(ConstraintLinkML(nominal, data, 2e-6))
    assert first.success
    for sigma in (2e-6, 6e-6):
        again = levenberg_marquardt(ConstraintLinkML(nominal, data, sigma), state=first.state)
        assert again.success, again.message
        assert again.nfev <= 2, (again.nfev, again.message)
        # where it stood: a step another BLAS might still accept gains only rounding (cost
        # 1e-8 of itself, ~1e-3 standard deviations at most), per parameter in its own std
        known = first.std > 0
        moved = np.abs(again.x - first.x)[known] / first.std[known]
        assert moved.max() < 1e-3, moved.max()


def test_noise_free_data_fitted_exactly_and_started_again_converge(default_case):
    """Noise-free data fitted exactly leave residuals at the rounding of the readings (a few
    1e-16 m): a fit started there (the start strategy re-fits all rows from a subset's exact
    geometry) finds no step that lowers that cost, and must say converged, not "stuck at a
    local minimum" (which made the strategy keep a wrong plain fit instead, issue 27)."""
    nominal, true, _ = default_case
    data = simulate_constraint_link(true, 60, 0.0, rng=5)
    first = levenberg_marquardt(ConstraintLinkML(nominal, data, 1e-6))
    assert first.success
    problem = ConstraintLinkML(nominal, data, 1e-6)
    scale = nominal.characteristic_length()
    rms = np.sqrt(2 * first.cost / first.residuals.size) * 1e-6     # m
    assert rms < 10 * np.finfo(float).eps * scale                   # exact to rounding
    again = levenberg_marquardt(problem, state=first.state)
    assert again.success, again.message
    assert first.cost <= problem.cost_floor
    # where it stood, to rounding (the std are relative to the rounding residuals here)
    moved = np.abs(again.x - first.x) / np.asarray(problem.scales)
    assert moved.max() < 1e-10, moved.max()


def test_sigma_whitening_does_not_change_the_estimate(default_case):
    nominal, _, data = default_case
    a = calibrate_constraint_link(nominal, data, sigma_m=1e-6)
    b = calibrate_constraint_link(nominal, data, sigma_m=[2e-6] * 6)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-13)


@pytest.mark.parametrize("method", ["ml", "ik", "fk"])
def test_too_few_measurements_raise_input_error(default_case, method):
    nominal, _, data = default_case
    few = data.subset(np.arange(40))
    with pytest.raises(InputError, match="40 measurements"):
        calibrate_constraint_link(nominal, few, method=method)


def test_bad_options_raise_input_error(default_case):
    nominal, _, data = default_case
    with pytest.raises(InputError, match="unknown method"):
        calibrate_constraint_link(nominal, data, method="magic")
    with pytest.raises(InputError, match="per_chain"):
        calibrate_constraint_link(nominal, data, method="ml", per_chain=True)
    no_passive = ConstraintLinkData(data.q, data.link_length)
    with pytest.raises(InputError, match="passive"):
        calibrate_constraint_link(nominal, no_passive, method="ik")
    five = ConstraintLinkData(data.q[:, :5], data.link_length)
    with pytest.raises(InputError, match="5 joint columns"):
        calibrate_constraint_link(nominal, five)
