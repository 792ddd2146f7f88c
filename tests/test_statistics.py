"""Statistical efficiency of the maximum-likelihood calibration (SPEC 3: "Monte Carlo must
agree with the Cramer-Rao bound").

200 noisy ML calibrations (``make studies``; ``make test`` runs 50, its RMS tolerance widened
by sqrt(200 / 50), the chi-square bounds of 50 runs) (150 fixed, seeded sphere poses; fresh
2 um encoder noise per run;
nominal start, truth = nominal + seed 000 Table 1). The bound is built twice: by the estimator
(reduced QR rows, ``absolute_sigma=True``, at the true geometry and poses) and here, densely,
as the pseudo-inverse of the Schur complement of the full whitened normal matrix.
"""

import numpy as np
import pytest
from scipy import stats

from pkmcal.bench import cramer_rao_bound, cramer_rao_efficiency
from pkmcal.instruments.constraint_link import sample_sphere_poses
from pkmcal.machines import default_hexaslide, paper_table1_deviations

NOISE = 2e-6
#: (runs, tolerance of RMS / CRB): make test's quick size and the study's
SIZES = [pytest.param((50, 0.20), id="quick"),
         pytest.param((200, 0.10), id="study", marks=pytest.mark.study)]


@pytest.fixture(scope="module", params=SIZES)
def monte_carlo(request):
    runs, tolerance = request.param
    mc = cramer_rao_efficiency(runs=runs, n_poses=150, noise_m=NOISE, rng=3)
    return {**mc, "runs": runs, "tolerance": tolerance}


def dense_schur_complement(true, P, R, sigma, scales):
    """``U - W V^-1 W^T`` of the full whitened, scaled normal matrix (geometry + 5 unknowns
    per pose: 2 on the sphere, 3 of rotation), built from ik_jacobians without the estimator.
    Any basis of the sphere's tangent plane gives the same complement."""
    _, Jx, Ju = true.ik_jacobians(P, R)
    n_hat = P / np.linalg.norm(P, axis=-1, keepdims=True)
    S = np.zeros((Ju.shape[-1],) * 2)
    for k in range(len(P)):
        tangent = np.linalg.svd(np.eye(3) - np.outer(n_hat[k], n_hat[k]))[0][:, :2]
        Jl = np.concatenate([Jx[k, :, :3] @ tangent, Jx[k, :, 3:]], -1) / sigma    # (6, 5)
        Jg = Ju[k] * scales / sigma                                                 # (6, 54)
        S += Jg.T @ Jg - Jg.T @ Jl @ np.linalg.solve(Jl.T @ Jl, Jl.T @ Jg)
    return S


def test_crb_equals_dense_schur_complement():
    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    P, R = sample_sphere_poses(true, true.constraint_link_length, 150, rng=4)
    crb = cramer_rao_bound(true, P, R, np.arange(150) % 6, NOISE)
    scales = crb.scales[:54]
    S = dense_schur_complement(true, P, R, NOISE, scales)
    s = np.linalg.svd(S, compute_uv=False, hermitian=True)
    assert int(np.sum(s > 1e-10 * s[0])) == 48 == crb.rank
    C = crb.covariance[:54, :54] / np.outer(scales, scales)
    C_dense = np.linalg.pinv(S, rcond=1e-10, hermitian=True)
    np.testing.assert_allclose(C, C_dense, rtol=0, atol=1e-7 * np.abs(C_dense).max())
    # singular values of the reduced Jacobian are those of S, squared
    np.testing.assert_allclose(crb.singular_values[:48] ** 2, s[:48], rtol=1e-7)
    # the null space is the two gauges: S annihilates it
    N = crb.null_space[:54]
    assert N.shape[1] == 6
    assert np.abs(S @ N).max() < 1e-9 * s[0]


def test_ml_attains_the_cramer_rao_bound(monte_carlo):
    """RMS error in the identifiable directions within 10 % (200 runs; 20 % at 50) of the
    CRB prediction."""
    mc = monte_carlo
    runs, tolerance = mc["runs"], mc["tolerance"]
    assert mc["success"].all()
    assert mc["rank"] == 48
    assert abs(mc["rms_ratio"] - 1) <= tolerance, mc["rms_ratio"]
    assert abs(np.sqrt(mc["chi2_ratio"]) - 1) <= tolerance, mc["chi2_ratio"]
    # chi2 statistic per run ~ chi2(48): its mean over the runs has std sqrt(96 / runs)
    lo, hi = stats.chi2.ppf([1e-4, 1 - 1e-4], 48 * runs) / runs
    assert lo < np.mean(mc["chi2"]) < hi


def test_ml_is_efficient_in_every_identifiable_direction(monte_carlo):
    """Whitened along each eigen-direction of the bound, the errors have unit variance (not
    only on average) and no bias."""
    mc = monte_carlo
    C, E = mc["crb_scaled"], mc["errors_scaled"]
    lam, V = np.linalg.eigh(C)
    keep = lam > 1e-10 * lam[-1]
    assert keep.sum() == 48
    W = (E @ V[:, keep]) / np.sqrt(lam[keep])                    # (runs, 48), ~ N(0, 1)
    variance = np.mean(W**2, axis=0)
    alpha = 1e-4 / 48                                            # Bonferroni over directions
    runs = mc["runs"]
    lo, hi = stats.chi2.ppf([alpha, 1 - alpha], runs) / runs
    assert np.all((variance > lo) & (variance < hi)), variance
    # bias: the mean error is ~ N(0, C / runs)
    mean = W.mean(axis=0) * np.sqrt(runs)
    assert np.sum(mean**2) < stats.chi2.ppf(1 - 1e-4, 48)


def test_alignment_leaves_errors_in_the_identifiable_subspace(monte_carlo):
    """The gauge alignment alone already removes the error along the unidentifiable
    directions (to second order): the projection before the comparison only trims it."""
    mc = monte_carlo
    N = mc["crb"].null_space[:54]
    A = mc["aligned_scaled"]
    along = np.linalg.norm(A @ N, axis=1)
    assert np.all(along < 1e-3 * np.linalg.norm(A, axis=1)), along.max()


def test_scipy_reference_solves_the_same_problem():
    """The speed benchmark's reference (scipy least_squares, finite differences, all global and
    per-pose unknowns) reaches our optimum: same cost, same estimate in standard deviations."""
    from pkmcal.bench import scipy_ml
    from pkmcal.calibration import calibrate_constraint_link
    from pkmcal.identifiability import CONSTRAINT_LINK_GAUGES, align_gauge
    from pkmcal.instruments.constraint_link import simulate_constraint_link

    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    data = simulate_constraint_link(true, 60, noise_m=NOISE, rng=9)
    ours = calibrate_constraint_link(nominal, data, sigma_m=NOISE, estimate_noise=False)
    sol, u = scipy_ml(nominal, data, NOISE)
    assert sol.success and sol.x.size == 54 + 5 * 60
    assert sol.cost == pytest.approx(ours.cost, rel=1e-6)
    sc = ours.scales[:54]
    a, _ = align_gauge(nominal, ours.x[:54], true.u, CONSTRAINT_LINK_GAUGES, sc)
    b, _ = align_gauge(nominal, u[:54], true.u, CONSTRAINT_LINK_GAUGES, sc)
    assert np.max(np.abs(a - b) / ours.std[:54]) < 1e-2
