"""Noise levels from the residuals (issue 16, items 2 and 3): recovered, held, honest, robust.

Every instrument - a laser tracker on the Delta and on the Stewart platform, full poses,
the constraint link, ballbar lengths, probe heights and a joint fit of two files (probe
heights and ballbar lengths) - on ``benchmarks/noise.py``'s cases (the geometries of
``benchmarks/instruments.py`` and ``benchmarks/printer.py``, none of the examples'), smaller
where many runs are needed, with data whose noise is NOT the one the calibration assumes (the
library's default for the instrument):

(a) the estimated levels recover the true ones: ``|estimate - true| < 4 std`` (the reported
    std of the level; a normal deviate exceeds 4 with probability 6e-5), and the assumed
    level is far off for at least one group (the prior does not pass the test);
    ``estimate_noise=False`` holds every level at the given value and a list of keys holds
    those (the others estimated); with one group the estimate and its covariance are those of
    the old behaviour (covariance scaled by the residual variance);
(b) the uncertainty the calibration REPORTS is honest: over many runs the prediction errors at
    held-out measurements, whitened by the covariance the calibration reports (with the
    estimated levels), have unit variance - ``t = d^T S^+ d / r`` per run
    (``NoiseCase.whitened_error``) is about F(r, nu), ``nu`` the redundancy of the estimated
    levels; the mean over the runs lies in the band ``[1 - z sd_chi2, E_F + z sd_F]`` (``z``
    for a two-sided false-alarm rate of 1e-3, normal approximation of the mean; the lower end
    is that of known levels, the upper that of the smallest redundancy: conservative on both
    sides). Runs start from the true geometry (what is tested is the covariance, not the start
    strategy: a direction the rank rule leaves unadjusted then carries no start error the
    covariance does not claim);
(c) gross errors (50, 75 and 100 times the noise: a beam break, a mis-read marker) in 2-3 rows
    are named by ``result.outliers``, and ``robust=True`` leaves out exactly those rows;
    clean data name no row in most runs (binomial bound at the test's family-wise rate).

The measured figures are in the docstrings (the study's sizes; ``make test`` runs (b) at
half of them).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from pkmcal.estimation.variance import OUTLIER_ALPHA
from pkmcal.instruments import IsotropicNoise
from pkmcal.instruments.pose import FullPoseNoise
from pkmcal.instruments.tracker import TrackerNoise

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "noise.py"


def _bench():
    name = "noise_bench"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module                      # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


bench = _bench()
M = bench.Mismatch
D = TrackerNoise()

#: name -> (case, poses per run or None for the benchmark's own number)
CASES = {
    "delta-tracker": (M("delta", "points", "isotropic", "isotropic 7 um, Leica-type assumed",
                        IsotropicNoise(7e-6)), None),
    "stewart-tracker": (M("stewart", "points", "3x", "TrackerNoise() x 3",
                          TrackerNoise(3 * D.distance, 3 * D.transverse,
                                       3 * D.transverse_per_m)), None),
    "poses": (M("stewart", "poses", "mixed", "readings 5x, positions 3x, orientations 2x",
                FullPoseNoise(10e-6, 60e-6, 100e-6)), 30),
    "constraint-link": (M("stewart", "constraint-link", "2.5x", "encoders 5 um, 2 um assumed",
                          5e-6), 72),
    "ballbar": (M("delta", "distances", "3x", "3 um, 1 um assumed", IsotropicNoise(3e-6)),
                None),
    "probe": (M("printer", "probe", "3x", "30 um, 10 um assumed", 30e-6), None),
    "joint": (M("printer", "probe+ballbar", "2x-3x", "probe 20 um (10 um assumed), 60 ballbar "
                "lengths 3 um (1 um assumed)", (20e-6, 3e-6)), None),
}
NAMES = list(CASES)


@cache
def noise_case(name: str):
    mismatch, poses = CASES[name]
    return bench.NoiseCase(mismatch, seed=0, poses=poses)


def _levels(result) -> dict:
    noise = result.noise
    return {k: (float(s), float(sd), st) for k, s, sd, st in
            zip(noise.keys, noise.sigma, noise.std, noise.status, strict=True)}


# -- (a) the levels are recovered, held where given -------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_estimated_levels_recover_the_true_ones(name):
    """One data set per instrument, the default options from the nominal start: every group
    estimated, within 4 of its reported standard deviations of the true level; the assumed
    level is more than 4 of them off for at least one group."""
    case = noise_case(name)
    result = case.fit(case.simulate(np.random.default_rng(1)))
    assert result.success
    levels = _levels(result)
    assert set(levels) == set(case.true_levels)
    far = []
    noise = result.noise
    for key, (sigma, std, status) in levels.items():
        true = case.true_levels[key]
        assert status == "estimated", (key, status)
        assert std > 0, (key, std)
        assert abs(sigma - true) < 4 * std, (key, sigma, true, std)
        far.append(abs(noise.assumed[noise.keys.index(key)] - true) > 4 * std)
    assert any(far), levels


def test_encoder_noise_ten_times_the_assumed_is_recovered():
    """Stewart platform, constraint link, 120 poses, encoder noise 20 um where 2 um is assumed
    (the benchmark's case): no row left out, the level within 4 std of 20 um."""
    case = bench.NoiseCase({m.name: m for m in bench.mismatches()}
                           ["stewart-constraint-link:readings10x"])
    result = case.fit(case.simulate(np.random.default_rng(1)))
    dropped = result.sections["constraint_link"].dropped_rows
    assert len(dropped) == 0, dropped
    sigma, std, status = _levels(result)["reading"]
    assert status == "estimated" and abs(sigma - 20e-6) < 4 * std, (sigma, std)


def test_estimate_noise_false_holds_every_level():
    """``estimate_noise=False``: every level held at the given value (status ``held``), no
    standard deviation claimed; the residual variance is against that noise."""
    case = noise_case("poses")
    data = case.simulate(np.random.default_rng(2))
    result = case.fit(data, estimate_noise=False)
    noise = result.noise
    assert noise.status == ["held"] * 3
    np.testing.assert_array_equal(noise.sigma, noise.assumed)
    p = bench.ASSUMED["poses"]
    np.testing.assert_array_equal(noise.assumed, [p.reading_m, p.position_m, p.orientation_rad])
    assert np.isnan(noise.std).all()
    assert not noise.estimated


def test_held_keys_keep_their_values_and_the_others_are_estimated():
    """A list of keys holds those groups (what ``--noise`` / ``--pose-noise`` do): full poses
    with the true orientation level given and held, the readings and positions (wrongly
    assumed) estimated; a tracker with the true level along the beam given and held."""
    case = noise_case("poses")
    true = case.true_noise
    data = case.simulate(np.random.default_rng(3))
    given = FullPoseNoise(2e-6, 20e-6, true.orientation_rad)     # the first two are wrong
    levels = _levels(case.fit(data, estimate_noise=["orientation"], noise=given))
    assert levels["orientation"][0] == true.orientation_rad
    assert levels["orientation"][2] == "held"
    for key in ("reading", "position"):
        sigma, std, status = levels[key]
        assert status == "estimated"
        assert abs(sigma - case.true_levels[key]) < 4 * std, (key, sigma, std)

    case = noise_case("delta-tracker")
    data = case.simulate(np.random.default_rng(4))
    given = TrackerNoise(distance=7e-6)                             # across: Leica-type
    levels = _levels(case.fit(data, estimate_noise=["along"], noise=given))
    assert levels["along"][0] == 7e-6 and levels["along"][2] == "held"
    sigma, std, status = levels["across"]
    assert status == "estimated" and abs(sigma - 7e-6) < 4 * std, (sigma, std)


def test_a_joint_fit_holds_one_file_and_estimates_the_other():
    """Two files: ``"bar.csv:*"`` holds every group of the ballbar file (what ``--noise
    bar.csv=1um`` does), the probe file's level is estimated."""
    case = bench.NoiseCase({m.name: m for m in bench.mismatches()}
                           ["printer-probe+ballbar:probe3x"])       # ballbar noise as assumed
    data = case.simulate(np.random.default_rng(5))
    levels = _levels(case.fit(data, estimate_noise=["bar.csv:*"]))
    assert levels["bar.csv:distances"][0] == bench.printer.BALLBAR_SIGMA
    assert levels["bar.csv:distances"][2] == "held"
    sigma, std, status = levels["probe.csv:probe"]
    assert status == "estimated" and abs(sigma - 30e-6) < 4 * std, (sigma, std)


@pytest.mark.parametrize("name", ["ballbar", "probe", "constraint-link"])
def test_one_group_estimated_is_the_old_behaviour(name):
    """With one noise group the estimated level only rescales the weights: the estimate is the
    one with the level held, and its standard deviations are those of the covariance scaled by
    the residual variance (to the variance-component iteration's 1e-3 tolerance)."""
    case = noise_case(name)
    data = case.simulate(np.random.default_rng(6))
    new, old = case.fit(data), case.fit(data, estimate_noise=False)
    free = new.parameters.free & (new.std > 0)
    scaled = (new.x - old.x)[free] / new.std[free]
    assert np.abs(scaled).max() < 1e-3, np.abs(scaled).max()
    np.testing.assert_allclose(new.std[free], old.std[free], rtol=5e-3)
    sigma = new.noise.sigma[0]
    assumed = new.noise.assumed[0]
    assert abs(sigma**2 / assumed**2 / old.residual_variance - 1) < 5e-3
    # the level's redundancy and std come from the last Helmert step's matrix (one group:
    # the hat matrix does not depend on the level): those of the final fit's own
    from pkmcal.estimation.variance import hat_factors, helmert_matrix

    weighted = new.weighted
    final = dataclasses.replace(new, residuals=new.weighted_residuals)
    L, G = hat_factors(weighted, final)
    used = np.broadcast_to(new.used, weighted.groups.labels.shape)
    S, red = helmert_matrix(L, G, weighted.groups.labels, used, 1)
    noise = new.noise
    np.testing.assert_allclose(noise.redundancy, red, rtol=1e-8)
    np.testing.assert_allclose(noise.std, sigma / np.sqrt(2.0 * S[0, 0]), rtol=1e-6)


# -- (b) the reported uncertainty is honest -----------------------------------------------------

#: runs per instrument (fewer where a run costs more: the full poses' and the constraint link's
#: check differentiates the forward kinematics numerically)
RUNS = {"delta-tracker": 100, "stewart-tracker": 60, "poses": 50, "constraint-link": 50,
        "ballbar": 100, "probe": 100, "joint": 60}
#: make test's size: half the runs (the bands and the binomial limit are those of the runs
#: made, so the false-alarm rate stays 1e-3), the joint fit's in full (the power the
#: held-levels study shows is that of this band); ``make studies`` runs :data:`RUNS` and the
#: held-levels study
QUICK_RUNS = {name: (n if name == "joint" else n // 2) for name, n in RUNS.items()}
SIZES = {"quick": QUICK_RUNS, "study": RUNS}
SIZE_PARAMS = [pytest.param("quick", id="quick"),
               pytest.param("study", id="study", marks=pytest.mark.study)]
#: two-sided false-alarm rate of each band
FALSE_ALARM = 1e-3


@cache
def monte_carlo(name: str, estimate_noise: bool = True, size: str = "quick") -> dict:
    """``SIZES[size][name]`` calibrations with fresh noise from the true geometry: ``t`` per
    run, the adjusted directions ``r``, the smallest redundancy ``nu`` of the estimated levels,
    and the rows the outlier test named."""
    case = noise_case(name)
    rng = np.random.default_rng(1000 + NAMES.index(name))
    out = {"t": [], "r": [], "nu": [], "flagged": [], "status": []}
    for _ in range(SIZES[size][name]):
        result = case.fit(case.simulate(rng), estimate_noise, start="truth")
        assert result.success
        t, r = case.whitened_error(result)
        noise = result.noise
        estimated = [red for red, st in zip(noise.redundancy, noise.status, strict=True)
                     if st == "estimated"]
        out["t"].append(t)
        out["r"].append(r)
        out["nu"].append(min(estimated) if estimated else np.inf)
        out["flagged"].append(list(result.outliers.flagged))
        out["status"].append(list(noise.status))
    return {k: (np.array(v, float) if k in ("t", "r", "nu") else v) for k, v in out.items()}


def band(r, nu, alpha: float = FALSE_ALARM) -> tuple[float, float]:
    """Acceptance band of the mean of ``t_i ~ F(r_i, nu_i)`` over the runs (see the module
    docstring): the lower end for known levels (chi-square / r), the upper for estimated ones
    with the smallest redundancy."""
    r, nu = np.asarray(r, float), np.asarray(nu, float)
    n = len(r)
    z = stats.norm.ppf(1 - alpha / 2)
    assert np.all(nu > 4), nu.min()
    mean_f = nu / (nu - 2)
    var_f = 2 * nu**2 * (r + nu - 2) / (r * (nu - 2) ** 2 * (nu - 4))
    lower = 1 - z * np.sqrt(np.sum(2 / r)) / n
    upper = np.mean(mean_f) + z * np.sqrt(np.sum(var_f)) / n
    return float(lower), float(upper)


@pytest.mark.parametrize("size", SIZE_PARAMS)
@pytest.mark.parametrize("name", NAMES)
def test_reported_uncertainty_is_calibrated(name, size):
    """Mean ``t`` (prediction errors whitened by the REPORTED covariance, levels estimated)
    within the band. Measured (mean t, band): Delta tracker 0.982 [0.898, 1.212]; Stewart
    tracker 1.024 [0.913, 1.191]; full poses 1.090 [0.905, 1.320] (in 4 of the 50 runs a level
    is only bounded, ``at most``: its covariance is then conservative); constraint link 1.032
    [0.898, 1.250]; ballbar 1.022 [0.910, 1.157]; probe 1.172 [0.879, 1.284]; joint fit 1.057
    [0.877, 1.242] (the study's runs, :data:`RUNS`)."""
    mc = monte_carlo(name, size=size)
    lower, upper = band(mc["r"], mc["nu"])
    mean = float(mc["t"].mean())
    assert lower < mean < upper, (lower, mean, upper)


@pytest.mark.study      # a power study (make studies): 60 more joint fits, ~2.5 % of make test
def test_holding_wrong_levels_is_seen_by_the_same_test():
    """The test has the power to see a dishonest covariance: the joint fit with both files'
    levels held at the assumed ones (probe 2x, ballbar 3x too small: one scale for both files
    mis-weighs them) reports a covariance the errors do not follow (measured: mean t 1.311,
    above the band's 1.242). The study's runs (those of make test's joint fit too: its band
    is the one shown to have this power)."""
    mc = monte_carlo("joint", estimate_noise=False, size="study")
    held = monte_carlo("joint", size="study")
    lower, upper = band(held["r"], held["nu"])
    mean = float(mc["t"].mean())
    assert not lower < mean < upper, (lower, mean, upper)


# -- (c) gross errors ------------------------------------------------------------------------

#: 0-based rows given a gross error, and its size in multiples of the (largest) true level
GROSS_ROWS = np.array([3, 11, 17])
GROSS_SIZE = np.array([50.0, -75.0, 100.0])
#: the joint fit: probe row 5 and ballbar rows 3 and 11 (ids: the probe's 37 rows first)
JOINT_IDS = {5, 37 + 3, 37 + 11}


def with_gross_errors(name: str, data):
    """``data`` with gross errors in :data:`GROSS_ROWS`; returns the data and the ids of the
    rows hit (indices into the outlier test's rows; the constraint link: file rows)."""
    case = noise_case(name)
    level = max(case.true_levels.values())
    rows, size = GROSS_ROWS, GROSS_SIZE
    if name == "poses":                     # a mis-read marker position
        P = data.P.copy()
        P[rows, 1] += size * case.true_levels["position"]
        return dataclasses.replace(data, P=P), set(rows.tolist())
    if name == "constraint-link":           # an encoder that skipped
        q = data.q.copy()
        q[rows, 2] += size * level
        return dataclasses.replace(data, q=q), set((rows + 1).tolist())
    if name == "joint":
        probe, bar = data
        pv, bv = probe.values.copy(), bar.values.copy()
        pv[5, 0] += size[2] * case.true_levels["probe.csv:probe"]
        bv[rows[:2], 0] += size[:2] * case.true_levels["bar.csv:distances"]
        return (dataclasses.replace(probe, values=pv),
                dataclasses.replace(bar, values=bv)), set(JOINT_IDS)
    values = data.values.copy()             # a beam break, a bad probe trigger, a slipped bar
    values[rows, 0] += size * level
    return dataclasses.replace(data, values=values), set(rows.tolist())


def named(name: str, result, left_out: bool = False) -> set:
    """Rows the outlier test names (or leaves out); the constraint link: the file rows it
    names, with those its start strategy left out (``dropped_rows``: its problem holds the
    other rows only)."""
    test = result.outliers
    idx = np.flatnonzero(~test.kept) if left_out else test.flagged
    if name != "constraint-link":
        return set(idx.tolist())
    rows = {int(test.names[i].split()[-1]) for i in idx}
    return rows | {int(r) for r in result.sections["constraint_link"].dropped_rows}


@cache
def gross_fits(name: str):
    case = noise_case(name)
    data, hit = with_gross_errors(name, case.simulate(np.random.default_rng(7)))
    return case.fit(data), case.fit(data, robust=True), hit




def _row_by_row_statistics(weighted, result, L, G):
    """Baarda's statistic of each row, one row at a time (the loop the library's batched
    test replaced): ``r_S^T M_S^+ r_S`` with ``M = I - H`` restricted to the row (its left-out
    form ``I + G G^T / w^2`` for a row out of the fit), and its rank."""
    from pkmcal.estimation.variance import LEFT_OUT_WEIGHT

    groups = weighted.groups
    ids = groups.ids.reshape(-1)
    K, m = groups.labels.shape
    r = np.asarray(result.residuals, float).reshape(-1) / np.where(
        weighted.kept[ids], 1.0, LEFT_OUT_WEIGHT)
    Gf, block = G.reshape(K * m, -1), np.repeat(np.arange(K), m)
    stat, dof = np.zeros(len(groups.id_names)), np.zeros(len(groups.id_names), int)
    for i in range(len(groups.id_names)):
        S = np.flatnonzero(ids == i)
        M = np.eye(len(S))
        if L is not None:
            Lf = L.reshape(K * m, -1)[S]
            M -= (Lf @ Lf.T) * (block[S][:, None] == block[S][None, :])
        Gs = Gf[S] if weighted.kept[i] else Gf[S] / LEFT_OUT_WEIGHT
        M += (-1.0 if weighted.kept[i] else 1.0) * (Gs @ Gs.T)
        w, V = np.linalg.eigh(0.5 * (M + M.T))
        good = w > 1e-8 * max(1.0, w.max())
        z = V[:, good].T @ r[S]
        stat[i], dof[i] = np.sum(z**2 / w[good]), good.sum()
    return stat, dof


@pytest.mark.parametrize("name", NAMES)
def test_batched_outlier_test_is_the_row_by_row_one(name):
    """The outlier test evaluates every row at once; on fits with gross errors (rows left out
    by the robust fit, whose statistic carries the left-out weight) its statistics and
    degrees of freedom are those of one row at a time."""
    from pkmcal.estimation.variance import _outlier_test, hat_factors

    for result in gross_fits(name)[:2]:
        weighted = result.weighted
        restored = dataclasses.replace(result, residuals=result.weighted_residuals)
        L, G = hat_factors(weighted, restored)
        test = _outlier_test(weighted, restored, L, G, OUTLIER_ALPHA)
        stat, dof = _row_by_row_statistics(weighted, restored, L, G)
        np.testing.assert_array_equal(test.dof, dof)
        np.testing.assert_allclose(test.statistic, stat, rtol=1e-9,
                                   atol=1e-12 * np.abs(stat).max())


@pytest.mark.parametrize("name", NAMES)
def test_robust_leaves_out_exactly_the_gross_errors(name):
    """``robust=True``: exactly the rows with gross errors left out, and the levels estimated
    without them recover the true ones (4 std)."""
    _, robust, hit = gross_fits(name)
    assert named(name, robust, left_out=True) == hit
    case = noise_case(name)
    levels = _levels(robust)
    assert any(status == "estimated" for _, _, status in levels.values())
    for key, (sigma, std, status) in levels.items():
        if status == "estimated":
            assert abs(sigma - case.true_levels[key]) < 4 * std, (key, sigma, std)


@pytest.mark.parametrize("name", NAMES)
def test_default_options_name_every_gross_error_and_no_clean_row(name):
    """Default options (no ``robust``): the rows named are exactly those with gross errors
    (the fit keeps them). With one test the level estimated with the gross errors in would
    hide the smaller ones (masking: 12x the true level on the Delta's tracker); the rows named
    are those the robust rounds leave out. The constraint link: rows its start strategy could
    not fit stay out when the rounds name them too (here two of the three), and only those."""
    default, _, hit = gross_fits(name)
    assert named(name, default) == hit
    kept = default.outliers.kept
    if name == "constraint-link":
        dropped = {int(r) for r in default.sections["constraint_link"].dropped_rows}
        assert dropped <= hit
        out = {int(default.outliers.names[i].split()[-1])
               for i in np.flatnonzero(~kept)}
        assert out == dropped
    else:
        assert kept.all()


def test_constraint_link_rows_the_start_strategy_left_out_are_tested_again():
    """The constraint link's start strategy leaves out rows its trimmed rounds cannot explain
    (here clean rows with the bad ones, the plain fit bent by three gross encoder errors);
    the outlier rounds start from them and bring back every clean one: the start report says
    which, its warning names only the rows still out, and the report's residuals are those of
    the rows in the fit."""
    default, robust, hit = gross_fits("constraint-link")
    for result in (default, robust):
        start = result.sections["constraint_link"].start
        assert start.readmitted_rows.size > 0
        assert not set(start.readmitted_rows.tolist()) & hit
        assert set(start.dropped_rows.tolist()) <= hit
        left = [w for w in start.warnings if "left out" in w]
        assert len(left) == 1 and all(f"{r}" in left[0] for r in start.dropped_rows.tolist())
        assert start.as_dict()["readmitted_rows"] == start.readmitted_rows.tolist()
    # the problem holds every row; those out carry no weight in the levels
    assert len(robust.problem.data) == noise_case("constraint-link").n_poses
    noise = robust.noise
    assert noise.status == ["estimated"]


@pytest.mark.parametrize("size", SIZE_PARAMS)
@pytest.mark.parametrize("name", NAMES)
def test_clean_data_name_no_row_in_most_runs(name, size):
    """Over the runs of (b) (clean data), the runs in which the test names a row: at most
    the binomial quantile of the test's family-wise rate ``OUTLIER_ALPHA`` at a false-alarm
    rate of 1e-3 (a row named by chance is what the rate allows)."""
    mc = monte_carlo(name, size=size)
    runs = len(mc["flagged"])
    with_rows = sum(bool(f) for f in mc["flagged"])
    limit = stats.binom.ppf(1 - FALSE_ALARM, runs, OUTLIER_ALPHA)
    assert with_rows <= limit, (with_rows, limit, runs)


@pytest.mark.parametrize("name,true_noise", [
    # levels far above the assumed ones (a level over 3x makes the plain fit suspect)
    ("probe", 100e-6),                      # 10x the assumed 10 um
    ("delta-tracker", IsotropicNoise(30e-6)),   # 2-6x the Leica-type default
    ("ballbar", IsotropicNoise(10e-6)),     # 10x the assumed 1 um
])
def test_robust_fit_that_leaves_no_row_out_is_the_plain_fit(name, true_noise, monkeypatch):
    """``robust=True`` on clean data whose levels are far from the assumed ones (the plain fit
    is suspect, the robust rounds run): when it leaves no row out, its geometry, covariance
    and levels are the plain fit's, bit for bit (they were the rounds' last fit, started from
    other levels, and ended elsewhere on data that fix the geometry poorly)."""
    mismatch = dataclasses.replace(CASES[name][0], true=true_noise)
    case = bench.NoiseCase(mismatch, seed=0)
    data = case.simulate(np.random.default_rng(3))
    from pkmcal.estimation import variance

    searched = []
    robust_candidates = variance._robust_candidates
    monkeypatch.setattr(variance, "_robust_candidates",
                        lambda *a, **k: searched.append(1) or robust_candidates(*a, **k))
    plain = case.fit(data)
    assert searched, "the plain fit was not suspect: the robust rounds did not run"
    robust = case.fit(data, robust=True)
    assert robust.outliers.kept.all(), named(name, robust, left_out=True)
    assert robust.robust and not plain.robust
    np.testing.assert_array_equal(robust.x, plain.x)
    np.testing.assert_array_equal(robust.covariance, plain.covariance)
    np.testing.assert_array_equal(robust.noise.sigma, plain.noise.sigma)
    np.testing.assert_array_equal(robust.outliers.flagged,
                                  plain.outliers.flagged)
