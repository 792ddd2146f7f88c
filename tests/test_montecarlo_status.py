"""Monte Carlo runs that are not ok (issue 12 item 4): every run gets a status (ok, not
converged, rejected, failed); a run whose estimator did not converge, or converged to residuals
the noise cannot explain (a wrong geometry), is counted and never averaged; honest runs are
never rejected; summaries give the median and a robust spread beside the mean; undefined
statistics are empty cells / null, never ``nan``; the command warns about runs that are not
ok and exits 1 when a value has none."""

import functools
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import pkmcal.instruments.constraint_link as constraint_link
import pkmcal.instruments.pose as pose
from pkmcal.analysis import montecarlo as mc
from pkmcal.analysis.montecarlo import MonteCarloSettings, montecarlo
from pkmcal.cli._console import print_summary
from pkmcal.instruments.registry import instrument
from pkmcal.io.atomic import OutputSet
from pkmcal.machines import default_hexaslide
from pkmcal.workflows.common import load_machine_arg
from pkmcal.workflows.montecarlo import montecarlo as montecarlo_workflow

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DELTA = str(EXAMPLES / "delta_default.yaml")
STEWART = str(EXAMPLES / "cubic_6upu.yaml")
METRIC = {"m": ("", 1.0, "")}


@pytest.fixture(scope="module")
def hexaslide():
    return default_hexaslide()


def every_other(calls, bad, good):
    """``bad`` on the first, third, ... call, ``good`` on the others (runs in process are
    called in order)."""
    def pick(*args, **kwargs):
        calls.append(None)
        return (bad if len(calls) % 2 else good)(*args, **kwargs)
    return pick


# -- (a) not converged ----------------------------------------------------------------------

def test_a_run_that_does_not_converge_is_counted_never_averaged(monkeypatch, hexaslide):
    """One LM iteration: the estimator says it did not converge; its (poor) accuracy must
    not enter the mean, and it is not 'failed' either."""
    original = constraint_link.calibrate_constraint_link
    # (one iteration of one fit: the noise held, else its estimation refits several times)
    monkeypatch.setattr(constraint_link, "calibrate_constraint_link", every_other(
        [], functools.partial(original, max_iter=1, estimate_noise=False), original))
    res = montecarlo(MonteCarloSettings(hexaslide), "noise", [1e-6], runs=4, seed=5,
                     workers=1)
    status = [row["status"] for row in res.rows]
    assert status == ["not converged", "ok", "not converged", "ok"]
    for row in res.rows:
        assert row["converged"] is (row["status"] == "ok")
        assert bool(row["failure"]) is (row["status"] != "ok")
    assert "not converged" in res.rows[0]["failure"]
    assert "iterations" in res.rows[0]["failure"]
    p = res.summary[0]
    assert (p["runs"], p["ok"], p["not_converged"], p["rejected"], p["failed"]) == \
        (4, 2, 2, 0, 0)
    assert p["converged"] == 2
    ok = [row["position_mean"] for row in res.rows if row["status"] == "ok"]
    bad = [row["position_mean"] for row in res.rows if row["status"] != "ok"]
    assert min(bad) > 10 * max(ok)                     # what averaging in would have cost
    assert p["position_mean"]["mean"] == pytest.approx(np.mean(ok))
    assert p["position_mean"]["mean"] <= p["position_mean"]["q95"]
    assert np.isnan(res.metric("position_mean", ok_only=True)[0, [0, 2]]).all()


# -- (b) converged to residuals the noise cannot explain ------------------------------------

def test_residuals_20x_the_noise_are_rejected(monkeypatch, hexaslide):
    """The calibration assumes 20x less noise than the data carry (every other run): the
    estimator converges, but chi2/dof ~ 400, the signature of a wrong geometry."""
    honest = mc._weight
    monkeypatch.setattr(mc, "_weight", every_other([], lambda n: honest(n) / 20, honest))
    res = montecarlo(MonteCarloSettings(hexaslide), "noise", [1e-6], runs=4, seed=6,
                     workers=1)
    assert [row["status"] for row in res.rows] == ["rejected", "ok"] * 2
    for row in res.rows:
        assert row["converged"]                   # the estimator's claim, kept in runs.csv
        if row["status"] == "rejected":
            assert 15 < math.sqrt(row["chi2_dof"]) < 25
            assert "x the noise" in row["failure"] and "wrong geometry" in row["failure"]
        else:
            assert row["chi2_dof"] < 2 and row["failure"] == ""
    p = res.summary[0]
    assert (p["ok"], p["rejected"], p["not_converged"], p["failed"], p["converged"]) == \
        (2, 2, 0, 0, 4)
    ok = [row["position_mean"] for row in res.rows if row["status"] == "ok"]
    assert p["position_mean"]["mean"] == pytest.approx(np.mean(ok))


@pytest.mark.parametrize("spec, noise", [(DELTA, 20e-6), (STEWART, 1e-6)])
def test_residuals_20x_the_noise_are_rejected_in_every_scenario(monkeypatch, spec, noise):
    """Tracker and full pose: the same test on their whitened residuals (the pose scenario's
    pose noise stays as assumed, so its readings are made 20x noisier than assumed)."""
    machine = load_machine_arg(spec)
    if machine.kind == "delta":
        honest = mc._weight
        monkeypatch.setattr(mc, "_weight", lambda n: honest(n) / 20)
    else:
        simulate = pose.simulate_full_pose

        def noisier(machine, n, frames, noise, rng):
            if noise is not None:
                noise = mc.replace(noise, reading_m=20 * noise.reading_m)
            return simulate(machine, n, frames, noise, rng)

        monkeypatch.setattr(pose, "simulate_full_pose", noisier)
    res = montecarlo(MonteCarloSettings(machine), "noise", [noise], runs=2, seed=6,
                     workers=1)
    assert [row["status"] for row in res.rows] == ["rejected"] * 2, res.rows
    assert res.summary[0]["ok"] == 0 and math.isnan(res.mean("position_mean")[0])


def test_exact_data_with_residuals_is_rejected(hexaslide):
    """Noise-free data: residuals above 1e-9 of the machine's size mean a wrong geometry
    (here faked: an estimator result whose residuals are 1 um)."""
    s = MonteCarloSettings(hexaslide, noise=0.0).resolved()
    res = SimpleNamespace(success=True, x=np.zeros(3), nit=4, message="", dof=100,
                          residual_variance=1e2, residuals=np.full(300, 10.0))  # 10 x 1e-7
    status, chi2_dof, why = mc.acceptance(res, s, {"position_mean": 1e-6})
    assert status == "rejected" and "exact" in why and chi2_dof == 1e2
    res.residuals = np.full(300, 1e-3)                                  # 1e-10 m: exact
    assert mc.acceptance(res, s, {"position_mean": 1e-6})[0] == "ok"
    assert mc.acceptance(res, s, {"position_mean": math.nan})[0] == "rejected"
    res.dof = 0                                                  # no test without dof
    res.residuals = np.zeros(0)
    assert mc.acceptance(res, MonteCarloSettings(hexaslide).resolved(), {})[:1] == ("ok",)


# -- (c) honest runs are never rejected -----------------------------------------------------

def test_honest_default_runs_are_all_ok(hexaslide):
    res = montecarlo(MonteCarloSettings(hexaslide), "noise", [1e-6], runs=10, seed=0,
                     workers=1)
    assert [row["status"] for row in res.rows] == ["ok"] * 10
    chi = np.array([row["chi2_dof"] for row in res.rows])
    assert np.all((chi > 0.5) & (chi < 1.6)), chi          # the noise is what was assumed
    assert abs(chi.mean() - 1) < 0.2
    assert res.summary[0]["ok"] == res.summary[0]["converged"] == 10


@pytest.mark.parametrize("spec, variable, values", [
    ("default", "noise", [1e-6]),
    (DELTA, "tolerance", [2e-3]),                        # Leica-type noise, 3x3x3 grid
    (DELTA, "noise", [0.0, 20e-6]),
    (STEWART, "noise", [0.0, 5e-6]),
])
def test_no_false_rejection_over_30_honest_runs(spec, variable, values):
    """The acceptance test rejects nothing the noise explains (measured: 0 of 300 Hexa Slide,
    1200 Delta and 500 Stewart runs; chi2/dof at most 1.6 against a limit of >= 2)."""
    res = montecarlo(MonteCarloSettings(load_machine_arg(spec)), variable, values, runs=30,
                     seed=21, workers=2)
    assert sum(p["rejected"] for p in res.summary) == 0, [r["failure"] for r in res.not_ok()]
    assert all(p["ok"] == 30 for p in res.summary)


def test_a_deliberately_wrong_link_length_is_not_a_wrong_geometry(hexaslide):
    """seed 000 Fig. 6: noise-free data, Lc assumed wrong; the residuals it leaves are the
    point of the study, not a failed calibration."""
    res = montecarlo(MonteCarloSettings(hexaslide, noise=0.0), "lc-error", [1e-6, 100e-6],
                     runs=2, seed=1, workers=1)
    assert all(p["ok"] == 2 for p in res.summary)


# -- (d) one run per value: empty cells and null, never nan ---------------------------------

def test_one_run_per_value_writes_empty_cells_and_null(cli, tmp_path):
    proc = cli("montecarlo", "default", "--vary", "noise=1,3um", "--runs", "1", "--workers",
               "1", "-o", "one")
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "one"
    for name in ("summary.csv", "summary.json", "runs.csv"):
        assert "nan" not in (out / name).read_text().lower(), name
    lines = (out / "summary.csv").read_text().splitlines()
    header = lines[0].split(",")
    for stat in ("runs", "ok", "not_converged", "rejected", "failed", "converged",
                 "position_mean_mean_um", "position_mean_median_um",
                 "position_mean_mad_std_um", "position_mean_q05_um"):
        assert stat in header
    row = dict(zip(header, lines[1].split(","), strict=True))
    assert (row["runs"], row["ok"], row["rejected"]) == ("1", "1", "0")
    assert float(row["position_mean_mean_um"]) == float(row["position_mean_median_um"]) > 0
    for stat in ("std", "ci95_low", "ci95_high", "mad_std", "q05", "q95"):
        assert row[f"position_mean_{stat}_um"] == ""
    report = json.loads((out / "summary.json").read_text())
    p = report["summary"][0]
    assert p["ok"] == 1 and p["position_mean"]["std"] is None
    assert p["position_mean"]["mad_std"] is None and p["position_mean"]["median"] > 0
    runs = (out / "runs.csv").read_text().splitlines()
    assert runs[0].split(",")[:7] == ["noise_um", "value_index", "run", "converged",
                                      "iterations", "status", "chi2_dof"]
    assert runs[1].split(",")[5] == "ok" and 0 < float(runs[1].split(",")[6]) < 2
    assert "median" in proc.stdout and "1/1" in proc.stdout


def fake_runs(monkeypatch, run):
    """The constraint link's Monte Carlo run replaced by ``run(settings, rng)``."""
    monkeypatch.setattr(type(instrument("constraint-link")), "montecarlo_run",
                        lambda self, mc_run: run(mc_run.settings, mc_run.rng))


def fake_run(settings, rng):
    """A quick stand-in for a scenario's run: converged, honest residuals, unless the draw
    says otherwise."""
    u = rng.random()
    res = SimpleNamespace(success=u > 0.25, x=np.zeros(3), nit=7, dof=50, message="maximum "
                          "number of iterations reached", residual_variance=1.0,
                          residuals=np.ones(50))
    if 0.25 < u < 0.5:
        res.residual_variance = 400.0                          # converged, wrong geometry
    m = 1e-6 * (1 + u) if u > 0.5 else 1e-3
    return res, {"position_mean": m, "position_max": 2 * m, "orientation_mean": m,
                 "orientation_max": 2 * m}


def command(*args, **kwargs) -> int:
    """``pkmcal montecarlo`` in this process (so that monkeypatches hold), inside the output
    set the command line gives every command: the workflow, printed as the CLI prints it."""
    with OutputSet():
        return print_summary(montecarlo_workflow(*args, workers=1, **kwargs))


def test_cli_warns_about_runs_not_ok_and_fails_without_any(monkeypatch, tmp_path, capsys):
    fake_runs(monkeypatch, fake_run)
    code = command("default", "noise=1,2um", tmp_path / "a", runs=12)
    err = capsys.readouterr().err
    rows = list(zip(*mc.runs_table(mc.montecarlo(
        MonteCarloSettings(default_hexaslide()), "noise", [1e-6, 2e-6], runs=12, seed=0,
        workers=1))[1], strict=True))
    assert code == 0
    assert "not ok" in err and "not converged" in err and "rejected" in err
    assert "noise 1 um" in err and "left out of the statistics" in err
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())["summary"]
    for i, p in enumerate(summary):
        mine = [r for r in rows if r[1] == i]
        assert p["runs"] == 12
        assert p["not_converged"] == sum(r[5] == "not converged" for r in mine)
        assert p["rejected"] == sum(r[5] == "rejected" for r in mine)
        assert p["ok"] + p["not_converged"] + p["rejected"] + p["failed"] == 12
        assert p["position_mean"]["mean"] < 2.1 and p["position_mean"]["q95"] < 2.1   # um

    def never(settings, rng):
        res, metrics = fake_run(settings, rng)
        res.success = False
        return res, metrics

    fake_runs(monkeypatch, never)
    code = command("default", "noise=1um", tmp_path / "b", runs=2)
    err = capsys.readouterr().err
    assert code == 1 and "no run ok" in err and "noise 1 um" in err
    text = (tmp_path / "b" / "summary.csv").read_text()
    assert "nan" not in text.lower()
    assert text.splitlines()[1].split(",")[1:7] == ["2", "0", "2", "0", "0", "0"]


# -- (e) statistics over the ok runs --------------------------------------------------------

def test_summary_median_and_mad_spread_over_the_ok_runs():
    v = np.array([1.0, 2.0, 4.0, 8.0, 3.0, 2.5])
    rows = [{"status": "ok", "converged": True, "failure": "", "seconds": 0.1, "m": x}
            for x in v]
    rows += [
        {"status": "not converged", "converged": False, "failure": "not converged: ...",
         "seconds": 0.1, "m": 1e3},
        {"status": "rejected", "converged": True, "failure": "rejected: ...", "seconds": 0.1,
         "m": 1e4},
        {"status": "failed", "converged": False, "failure": "ValueError: x",
         "seconds": 0.1, "m": math.nan},
    ]
    s = mc.summarize(rows, METRIC, value=1.0)
    assert (s["runs"], s["ok"], s["not_converged"], s["rejected"], s["failed"],
            s["converged"]) == (9, 6, 1, 1, 1, 7)
    m = s["m"]
    assert m["mean"] == pytest.approx(v.mean()) and m["median"] == pytest.approx(2.75)
    # |v - 2.75| = 1.75 0.75 1.25 5.25 0.25 0.25 -> median 1.0
    assert m["mad_std"] == pytest.approx(1.4826 * 1.0)
    assert m["std"] == pytest.approx(v.std(ddof=1))
    assert m["q05"] >= v.min() and m["q95"] <= v.max() and m["mean"] < m["q95"]
    assert set(m) == set(mc.STATISTICS)


def test_summary_of_one_or_no_ok_run_is_undefined_not_zero():
    one = mc.summarize([{"status": "ok", "converged": True, "failure": "", "seconds": 0.1,
                         "m": 5.0}], METRIC)
    assert one["m"]["mean"] == one["m"]["median"] == 5.0
    for stat in ("std", "ci95_low", "ci95_high", "mad_std", "q05", "q95"):
        assert math.isnan(one["m"][stat])
    none = mc.summarize([{"status": "rejected", "converged": True, "failure": "rejected: x",
                          "seconds": 0.1, "m": 5.0}], METRIC)
    assert none["ok"] == 0 and all(math.isnan(v) for v in none["m"].values())


def test_rows_without_a_status_are_read_as_before():
    rows = [{"converged": True, "failure": "", "seconds": 0.1, "m": 1.0},
            {"converged": False, "failure": "", "seconds": 0.1, "m": 9.0},
            {"converged": False, "failure": "ValueError: x", "seconds": 0.1, "m": math.nan}]
    s = mc.summarize(rows, METRIC)
    assert (s["ok"], s["not_converged"], s["failed"]) == (1, 1, 1) and s["m"]["mean"] == 1.0


def test_plot_shows_the_median_and_survives_values_without_ok_runs(monkeypatch, tmp_path):
    fake_runs(monkeypatch, fake_run)
    res = montecarlo(MonteCarloSettings(default_hexaslide()), "noise", [1e-6, 2e-6], runs=1,
                     seed=3, workers=1)
    path = mc.plot_montecarlo(res, tmp_path / "mc.png")
    assert Path(path).stat().st_size > 0
