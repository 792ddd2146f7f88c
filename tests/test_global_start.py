"""A far start never returns a wrong geometry as a result (issue 12, item 1).

On Hexa Slides other than the default one, seed 000's Table 1 errors put the forward
kinematics start of some rows tens of millimetres off (and some on another branch of the
loop), and the maximum-likelihood fit stopped in a local minimum with residuals 20-2000x the
noise, 'converged'. ``calibration.start`` now falls back to a continuation (the rows least
sensitive to the geometry first, every pose re-started with the geometry they give, trimmed
refits) when the plain fit fails the residual test, and names the rows it leaves out.

The Monte Carlo here is ``benchmarks/global_start.py`` with its defaults (200 runs, 120 poses:
196 ok, 4 flagged, none silent, no clean row left out in an ok run; see the README).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from pkmcal.calibration import calibrate_constraint_link
from pkmcal.estimation.acceptance import residual_test
from pkmcal.estimation.estimator import MAX_STD, levenberg_marquardt
from pkmcal.instruments.constraint_link import (
    ConstraintLinkML,
    simulate_constraint_link,
    sphere_pose_candidates,
)
from pkmcal.machines import default_hexaslide, paper_table1_deviations

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "global_start.py"


def _bench():
    spec = importlib.util.spec_from_file_location("global_start_bench", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def bench():
    module = _bench()
    # one calibration per (seed, poses): seed 36 of test_rows_left_out_are_named is also a run
    # of the Monte Carlo (a deterministic function of its arguments; the row is not modified)
    runs = {}
    plain = module.one_run

    def one_run(seed, poses=120):
        if (seed, poses) not in runs:
            runs[seed, poses] = plain(seed, poses)
        return dict(runs[seed, poses])

    module.one_run = one_run
    return module


def _reporter_case(bench):
    """The reporter's dimensions (rails from radius 560 mm at z = -520 mm, 65 deg, struts
    520 mm, link 350 mm; platform radius 140 mm, rail pairs +/- 25 deg, platform joints
    +/- 35 deg about the SPEC's 120-degree layout) with seed 000's Table 1 errors, 150 poses,
    2 um noise: the plain fit stops with residuals 111x the noise ('converged')."""
    nominal = bench.hexaslide(ra=0.56, za=-0.52, beta=65.0, l=0.52, lc=0.35, rb=0.14,
                              ga=25.0, gb=35.0)
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    true.constraint_link_length = nominal.constraint_link_length
    data = simulate_constraint_link(true, 150, 2e-6, rng=3)
    return nominal, true, data


def test_the_plain_start_fails_on_a_reporter_like_machine_and_the_fallback_does_not(bench):
    nominal, true, data = _reporter_case(bench)
    plain = levenberg_marquardt(ConstraintLinkML(nominal, data, 2e-6), max_std=MAX_STD)
    assert residual_test(plain).noise_factor > 20                     # the bug
    res = calibrate_constraint_link(nominal, data, sigma_m=2e-6)
    start = res.sections["constraint_link"].start
    assert start.strategy == "continuation" and start.fallback
    assert residual_test(res).passed
    assert start.attempts[0]["stage"] == "direct" and not start.attempts[0]["passed"]
    from pkmcal.analysis.accuracy import machine_workspace, pose_errors

    Pw, Rw = machine_workspace(true, 200, 0)
    dp, dr, ok, _ = pose_errors(true, res.machine, Pw, Rw)
    pred_p, pred_r = bench.predicted(true, res.problem, Pw[ok], Rw[ok])
    assert np.sqrt(np.mean(dp[ok] ** 2)) < 3 * pred_p
    assert np.sqrt(np.mean(dr[ok] ** 2)) < 3 * pred_r


def test_the_default_machine_takes_the_direct_path():
    machine = default_hexaslide()
    true = machine.with_parameters(machine.u + paper_table1_deviations(machine.parameters))
    true.constraint_link_length = machine.constraint_link_length
    data = simulate_constraint_link(true, 150, 2e-6, rng=0)
    res = calibrate_constraint_link(machine, data, sigma_m=2e-6)
    start = res.sections["constraint_link"].start
    assert start.strategy == "direct" and not start.fallback
    assert len(start.attempts) == 1 and start.attempts[0]["passed"]
    section = res.sections["constraint_link"]
    assert section.dropped_rows.size == 0 and section.warnings == []


def test_rows_left_out_are_named(bench):
    """Seed 36 of the benchmark (the plain fit fails, the continuation solves it) with a
    typing error in one row (3 mm on one reading): the start strategy leaves that row out
    and names it, in dropped_rows and in a warning - the outlier test, given it as a
    candidate, keeps it out; the others calibrate. (Before the neighbours' starts this seed
    left out a clean row: its pose had a narrow basin no start reached.)"""
    import dataclasses

    row = bench.one_run(36)
    assert row["status"] == "ok" and row["dropped"] == 0
    rng = np.random.default_rng(36)
    # rebuild the run's data to read the result itself
    while True:
        nominal, _ = bench.random_geometry(rng)
        shuffle = bool(rng.random() < 0.5)
        true = nominal.with_parameters(nominal.u + bench.table1_sized(nominal, rng, shuffle))
        true.constraint_link_length = nominal.constraint_link_length
        try:
            data = simulate_constraint_link(true, 120, 2e-6, rng=rng)
        except Exception:      # noqa: BLE001 - the benchmark skips such geometries alike
            continue
        break
    q = data.q.copy()
    q[17, 2] += 3e-3
    res = calibrate_constraint_link(nominal, dataclasses.replace(data, q=q), sigma_m=2e-6)
    dropped = [int(v) for v in res.sections["constraint_link"].dropped_rows]
    assert dropped == [int(data.rows[17])]
    (text,) = [w for w in res.sections["constraint_link"].warnings if "left out" in w]
    assert f"rows {dropped[0]}" in text and "1 of 120 row(s)" in text
    # the problem holds every row; the outlier rounds, started from the rows the start
    # strategy left out, keep exactly this one out of the fit
    test = res.outliers
    assert len(res.problem.data) == 120
    assert [int(test.names[i].split()[-1]) for i in test.left_out] == dropped
    assert res.sections["constraint_link"].start.as_dict()["dropped_rows"] == dropped
    assert residual_test(res).passed


def test_pose_candidates_find_the_branch_the_home_start_misses(bench):
    """Rails from radius 608 mm, 73.4 deg, struts 533 mm, link 349 mm: with the TRUE geometry,
    Newton from home lands 3 rows on another local minimum of the pose fit 60-80 mm away (the
    loop's forward kinematics have several solutions there); the multi-start finds all."""
    from pkmcal.instruments.constraint_link import solve_sphere_poses

    nominal = bench.hexaslide(ra=0.608, za=-0.517, beta=73.4, l=0.533, lc=0.349, rb=0.127,
                              ga=24.2, gb=37.9)
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    true.constraint_link_length = nominal.constraint_link_length
    data = simulate_constraint_link(true, 150, 2e-6, rng=3)
    home = solve_sphere_poses(true, None, data.q, data.link_length)
    assert np.sum(np.linalg.norm(home.P - data.true_P, axis=-1) > 0.03) == 3
    P, _, rms = sphere_pose_candidates(true, None, data.q, data.link_length)
    assert np.max(np.linalg.norm(P - data.true_P, axis=-1)) < 1e-4
    assert np.max(rms) < 1e-5


def _stewart_link_case(seed):
    """The cubic 6-UPU (examples/cubic_6upu.yaml) with a 420 mm constraint link, random
    deviations, 150 poses, 2 um noise (the case an independent catalogue found)."""
    from pkmcal.io import load_machine
    from pkmcal.machines.deviations import random_deviations

    nominal = load_machine(Path(__file__).resolve().parents[1] / "examples" / "cubic_6upu.yaml")
    nominal.constraint_link_length = 0.42
    rng = np.random.default_rng(seed)
    true = nominal.with_parameters(nominal.u + random_deviations(nominal, rng))
    true.constraint_link_length = 0.42
    return true, simulate_constraint_link(true, 150, 2e-6, rng=rng)


@pytest.mark.parametrize("seed", [3, 12])
def test_neighbour_starts_find_the_narrow_basins_of_a_six_leg_platform(seed):
    """Near the edge of its workspace a six-leg platform's pose fit on the constraint sphere
    has a wide basin around a wrong pose (25-150 mm off, residuals 200-4000 um) and a narrow
    one around the true pose: with the TRUE geometry, home and the square systems from home
    miss 9 rows (seed 3; 1 in seed 12, which 8 neighbours miss too). The poses of the rows
    explained, nearest in readings, start the square systems on the right assembly mode:
    every row is found."""
    true, data = _stewart_link_case(seed)
    P0, R0, rms0 = sphere_pose_candidates(true, None, data.q, data.link_length)
    missed = np.linalg.norm(P0 - data.true_P, axis=-1) > 0.02
    assert missed.sum() >= 1 and np.all(rms0[missed] > 1e-4)
    # the rows explained as neighbours (those of a fit): the rows missed start from them
    ok = ~missed
    Pm, _, rmsm = sphere_pose_candidates(true, None, data.q[missed], data.link_length,
                                         neighbours=(data.q[ok], P0[ok], R0[ok]))
    assert np.max(np.linalg.norm(Pm - data.true_P[missed], axis=-1)) < 1e-4
    assert np.max(rmsm) < 1e-5


def test_no_clean_row_is_left_out_from_the_true_geometry():
    """The calibration from the TRUE geometry with the true noise held leaves no row out (it
    left out 5 clean rows before the neighbours' starts: their best pose was the wrong one)."""
    true, data = _stewart_link_case(3)
    res = calibrate_constraint_link(true, data, sigma_m=2e-6, estimate_noise=False)
    assert len(res.sections["constraint_link"].dropped_rows) == 0
    assert res.outliers.kept.all()
    assert residual_test(res).passed


#: (runs, least ok, least fallback runs): the study's 200 (measured: 196 ok, fallback 36) and
#: make test's first 60 (measured: 58 ok, 2 flagged, fallback 12, worst ratio 2.32)
GEOMETRY_SIZES = [pytest.param(60, 57, 6, id="quick"),
                  pytest.param(200, 195, 20, id="study", marks=pytest.mark.study)]


@pytest.mark.parametrize("runs, least_ok, least_fallback", GEOMETRY_SIZES)
def test_monte_carlo_over_random_geometries(bench, runs, least_ok, least_fallback):
    """``runs`` calibrations on random non-default Hexa Slides (around the default and the
    reporter's dimensions), Table-1-sized errors, 2 um noise, 120 poses: every run is either
    ok (converged, no warning, gauge-free pose error within 3x the Cramer-Rao prediction) or
    flagged (an error, no convergence, or a warning of the acceptance test). Measured over 200:
    196 ok (worst ratio 2.32), 4 flagged; the plain fit failed the residual test in 35 runs,
    the fallback ran in 36. Every row is clean: no ok run leaves one out (2 ok runs left out 4
    clean rows before the left-out rows also started from their neighbours' poses); one row
    is tolerated (another BLAS may round a borderline pose search the other way).

    The poorly determined parameters ``pkmcal calibrate`` warns of (one rule on every machine:
    a standard deviation beyond 1/2500 of the machine's size) do not flag a run: they say how
    precisely the design fixes each parameter alone, not that the result is wrong, which the
    run's status judges against its predicted error. Measured over the first 60: 33 runs warn
    of them, 58 ok as before; warned runs are among the ok ones."""
    rows = [bench.one_run(seed, 120) for seed in range(runs)]
    s = bench.summary(rows)
    silent = [r for r in rows if r["status"] == "silent"]
    assert not silent, silent
    assert s["ok"] >= least_ok
    assert s["fallback"] >= least_fallback     # the fallback is exercised, and works
    assert s["worst_ok_ratio"] <= 3
    assert sum(r["dropped"] for r in rows if r["status"] == "ok") <= 1
    assert s["warned_poor"] == sum(r.get("poorly_determined", 0) > 0 for r in rows)
    assert any(r["status"] == "ok" and r["poorly_determined"] for r in rows)
