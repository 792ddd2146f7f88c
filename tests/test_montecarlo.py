"""Monte Carlo of simulated calibrations (``pkmcal montecarlo``, issue 5 item 4): runs are
pure functions of (settings, seed), so the same seed gives identical runs in process, in
local processes and on a Dask cluster; seed 000 Figs. 5 and 6 reproduced through the engine;
every machine type and scenario; statistics; the command line and its bad input."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from clitools import assert_input_error
from pkmcal.analysis import montecarlo as mc
from pkmcal.analysis.montecarlo import MonteCarloSettings, montecarlo, run_once, run_seed
from pkmcal.errors import InputError
from pkmcal.instruments.registry import instrument
from pkmcal.machines import default_hexaslide
from pkmcal.workflows.common import load_machine_arg

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
DELTA = str(EXAMPLES / "delta_default.yaml")
STEWART = str(EXAMPLES / "cubic_6upu.yaml")


@pytest.fixture(scope="module")
def hexaslide():
    return default_hexaslide()


def machine(spec):
    return load_machine_arg(spec)


def without_timing(result):
    return [{k: v for k, v in row.items() if k != "seconds"} for row in result.rows]


# -- reproducibility ----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def in_process(hexaslide):
    return montecarlo(MonteCarloSettings(hexaslide), "noise", [1e-6, 4e-6], runs=3, seed=7,
                      workers=1)


def test_seeds_are_spawned_per_value_and_run():
    spawned = np.random.SeedSequence(5).spawn(3)[2].spawn(4)[1]
    assert np.random.default_rng(run_seed(5, 2, 1)).random() == \
        np.random.default_rng(spawned).random()


def test_same_seed_same_runs_in_process_and_in_two_processes(hexaslide, in_process):
    assert in_process.executor == "in-process"
    again = montecarlo(MonteCarloSettings(hexaslide), "noise", [1e-6, 4e-6], runs=3, seed=7,
                       workers=2)
    assert again.executor == "local processes" and again.workers == 2
    assert without_timing(again) == without_timing(in_process)
    assert mc.runs_table(again) == mc.runs_table(in_process)
    other = montecarlo(MonteCarloSettings(hexaslide), "noise", [1e-6], runs=3, seed=8,
                       workers=1)
    assert other.rows[0]["position_mean"] != in_process.rows[0]["position_mean"]


def test_dask_cluster_gives_the_same_runs(hexaslide, in_process):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        done = []
        result = montecarlo(MonteCarloSettings(hexaslide), "noise", [1e-6, 4e-6], runs=3,
                            seed=7, scheduler=cluster.scheduler_address, progress=done.append)
    assert result.executor.startswith("dask")
    assert sum(done) == 6
    assert without_timing(result) == without_timing(in_process)


def test_unreachable_or_malformed_scheduler_is_an_input_error(hexaslide):
    pytest.importorskip("distributed")
    with pytest.raises(InputError, match="cannot reach the Dask scheduler"):
        montecarlo(MonteCarloSettings(hexaslide), "noise", [1e-6], runs=1,
                   scheduler="tcp://127.0.0.1:1", scheduler_timeout=0.5)
    with pytest.raises(InputError, match="HOST:PORT"):
        mc.dask_client("no-port-here")


# -- seed 000 Figs. 5 and 6 ---------------------------------------------------------------------

def test_fig5_position_error_is_proportional_to_the_noise(hexaslide):
    """Two decades of encoder noise give two decades of calibrated error, ~2-6 x the noise
    (measured with 20 runs: 3.5-4.0 x at 0.1, 0.3, 1, 3, 10 um)."""
    noise = np.array([0.1e-6, 1e-6, 10e-6])
    res = montecarlo(MonteCarloSettings(hexaslide), "noise", noise, runs=4, seed=0, workers=1)
    assert all(p["converged"] == 4 for p in res.summary)
    ratio = res.mean("position_mean") / noise
    assert np.all((ratio > 2) & (ratio < 6)), ratio
    slope = np.polyfit(np.log10(noise), np.log10(res.mean("position_mean")), 1)[0]
    assert 0.85 < slope < 1.15, slope


def test_fig6_position_error_equals_the_link_length_error(hexaslide):
    """Noise-free data, Lc assumed 10 or 100 um too long: the calibrated pose error is the
    Lc error (measured 1.009 x); estimating Lc removes it."""
    errs = np.array([10e-6, 100e-6])
    fixed = montecarlo(MonteCarloSettings(hexaslide, noise=0.0), "lc-error", errs, runs=2,
                       seed=1, workers=1)
    ratio = fixed.mean("position_mean") / errs
    assert np.all(np.abs(ratio - 1) < 0.1), ratio
    est = montecarlo(MonteCarloSettings(hexaslide, noise=0.0, estimate_lc=True), "lc-error",
                     errs[1:], runs=1, seed=1, workers=1)
    assert est.mean("position_mean")[0] < 1e-9


# -- every machine type -------------------------------------------------------------------------

def test_delta_tracker_runs_and_more_points_calibrate_better():
    res = montecarlo(MonteCarloSettings(machine(DELTA)), "poses", [8, 60], runs=3, seed=2,
                     workers=1)
    assert res.settings.scenario == "tracker"
    assert set(res.metrics) == {"position_mean", "position_max"}
    assert all(p["converged"] == 3 for p in res.summary)
    few, many = res.mean("position_mean")
    assert 2e-6 < many < few < 1e-3


def test_delta_without_deviations_or_noise_calibrates_exactly():
    res = montecarlo(MonteCarloSettings(machine(DELTA), noise=0.0), "tolerance", [0.0, 1e-3],
                     runs=1, seed=3, workers=1)
    exact, rough = res.mean("position_mean")
    assert exact < 1e-10 and rough < 1e-9        # deviations are identified exactly


def test_stewart_full_pose_runs_with_the_gauge_free_parameter_error():
    res = montecarlo(MonteCarloSettings(machine(STEWART)), "noise", [1e-6, 20e-6], runs=2,
                     seed=4, workers=1)
    assert res.settings.scenario == "pose"
    assert "parameter_rms" in res.metrics and "orientation_mean" in res.metrics
    assert all(p["converged"] == 2 for p in res.summary)
    pos = res.mean("position_mean")
    assert np.all((pos > 1e-6) & (pos < 1e-3)) and pos[1] > pos[0]
    assert np.all(np.isfinite(res.metric("parameter_rms")))


def test_hexaslide_tolerance_scales_random_deviations(hexaslide):
    s = MonteCarloSettings(hexaslide, tolerance=1e-3).resolved()
    assert s.deviations == "random"
    nominal_u = hexaslide.u
    du = mc._true_machine(s, np.random.default_rng(0)).u - nominal_u
    kinds = np.array(hexaslide.parameters.kinds)
    assert np.abs(du[kinds == "length"]).max() <= 1e-3
    assert np.abs(du[kinds == "angle"]).max() <= 0.01        # 0.02 rad per 2 mm
    assert np.abs(du[kinds == "length"]).max() > 0.5e-3


# -- statistics, failures, bad input ------------------------------------------------------------

def test_summary_statistics():
    v = np.array([1.0, 2.0, 4.0, 8.0, 3.0])
    rows = [{"converged": True, "failure": "", "seconds": 0.1, "m": x} for x in v]
    rows.append({"converged": False, "failure": "", "seconds": 0.1, "m": 100.0})
    s = mc.summarize(rows, {"m": ("", 1.0, "")}, value=1.0)
    assert (s["runs"], s["converged"]) == (6, 5)
    m = s["m"]
    half = stats.t.ppf(0.975, 4) * v.std(ddof=1) / math.sqrt(5)
    assert m["mean"] == pytest.approx(v.mean())
    assert m["ci95_high"] - m["mean"] == pytest.approx(half)
    assert m["median"] == 3.0 and m["q05"] < m["q95"]


def test_a_failing_run_is_recorded_not_raised(monkeypatch, hexaslide):
    def broken(settings, rng):
        raise InputError("the true machine cannot reach some commanded points")

    monkeypatch.setattr(type(instrument("constraint-link")), "montecarlo_run",
                        lambda self, run: broken(run.settings, run.rng))
    row = run_once(MonteCarloSettings(hexaslide).resolved(), run_seed(0, 0, 0))
    assert row["converged"] is False and math.isnan(row["position_mean"])
    assert "cannot reach" in row["failure"]


@pytest.mark.parametrize("spec, variable, values, kwargs, words", [
    ("default", "speed", [1.0], {}, ["unknown variable"]),
    (DELTA, "lc-error", [1e-6], {}, ["does not apply", "tracker"]),
    ("default", "poses", [20], {}, ["at least 48"]),
    ("default", "noise", [-1e-6], {}, ["noise", ">= 0"]),
    ("default", "noise", [1e-6], {"runs": 0}, ["--runs"]),
    ("default", "lc-error", [0.5], {}, ["not positive"]),
    (STEWART, "noise", [1e-6], {"workers": 0}, ["--workers"]),
])
def test_bad_settings_are_input_errors(spec, variable, values, kwargs, words):
    with pytest.raises(InputError) as exc:
        montecarlo(MonteCarloSettings(machine(spec)), variable, values,
                   **{"runs": 1, **kwargs})
    for w in words:
        assert w in str(exc.value)


def test_an_instrument_without_a_run_is_refused_by_name():
    """Pair distances have no Monte Carlo run: an input error naming the scenarios that do,
    not an internal error."""
    with pytest.raises(InputError) as exc:
        montecarlo(MonteCarloSettings(machine(DELTA), "pair-distances"), "noise", [1e-6],
                   runs=1)
    assert "no Monte Carlo" in str(exc.value) and "tracker" in str(exc.value)


def test_every_instrument_with_variables_runs_and_names_its_metrics():
    """The registry is the Monte Carlo's only list of scenarios: an instrument that sweeps
    variables performs its own run and names its metrics."""
    from pkmcal.instruments.base import Instrument
    from pkmcal.instruments.registry import INSTRUMENTS

    runnable = [i for i in INSTRUMENTS.values() if i.montecarlo_variables]
    assert {i.name for i in runnable} >= {"constraint-link", "tracker", "pose", "distance",
                                          "probe"}
    for inst in runnable:
        assert type(inst).montecarlo_run is not Instrument.montecarlo_run, inst.name
        assert inst.montecarlo_metrics and set(inst.montecarlo_variables) <= set(mc.VARIABLES)


def test_tolerance_does_not_apply_to_fixed_deviations(hexaslide):
    with pytest.raises(InputError, match="random deviations"):
        montecarlo(MonteCarloSettings(hexaslide, deviations="paper-table1"), "tolerance",
                   [1e-3], runs=1)


# -- command line -------------------------------------------------------------------------------

def test_cli_writes_the_outputs_reproducibly(cli, tmp_path):
    args = ["montecarlo", "default", "--vary", "noise=0.5,5um", "--runs", "2", "--seed", "3"]
    one = cli(*args, "--workers", "1", "-o", "one")
    assert one.returncode == 0, one.stderr
    two = cli(*args, "--workers", "2", "-o", "two")
    assert two.returncode == 0, two.stderr
    for name in ("runs.csv", "summary.csv", "summary.json", "montecarlo.png"):
        assert (tmp_path / "one" / name).stat().st_size > 0
    runs = (tmp_path / "one" / "runs.csv").read_text()
    assert runs == (tmp_path / "two" / "runs.csv").read_text()
    header = runs.splitlines()[0].split(",")
    assert header[:5] == ["noise_um", "value_index", "run", "converged", "iterations"]
    assert "position_mean_um" in header and "orientation_max_urad" in header
    assert len(runs.splitlines()) == 1 + 4
    summary = (tmp_path / "one" / "summary.csv").read_text().splitlines()
    assert "position_mean_ci95_low_um" in summary[0].split(",") and len(summary) == 3
    report = json.loads((tmp_path / "one" / "summary.json").read_text())
    assert report["variable"] == "noise" and report["values"] == [0.5, 5.0]
    assert report["seed"] == 3 and report["versions"]["numpy"]
    assert report["summary"][0]["converged"] == 2
    assert "position" in one.stdout and "noise (um)" in one.stdout
    assert one.stderr == ""                                     # no progress bar off a TTY


@pytest.mark.parametrize("args, words", [
    (["default", "--vary", "speed=1,2"], ["unknown variable"]),
    (["default", "--vary", "noise=1qq"], ["--vary noise", "unit"]),
    (["default", "--vary", "noise"], ["VARIABLE=V1,V2"]),
    ([DELTA, "--vary", "lc-error=1um"], ["lc-error", "tracker"]),
    (["default", "--vary", "noise=1um", "--runs", "0"], ["--runs"]),
    (["default", "--vary", "poses=10.5"], ["whole numbers"]),
    (["default", "--vary", "noise=1um", "--scheduler", "nonsense"], ["--scheduler"]),
])
def test_cli_bad_input_exits_2_and_writes_nothing(cli, tmp_path, args, words):
    proc = cli("montecarlo", *args, "-o", "out")
    assert_input_error(proc, *words)
    assert not (tmp_path / "out").exists()


def test_help_has_examples(cli):
    proc = cli("montecarlo", "--help")
    assert proc.returncode == 0
    for word in ("--vary", "--scheduler", "lc-error", "Example"):
        assert word in proc.stdout


@pytest.mark.skipif("fork" not in __import__("multiprocessing").get_all_start_methods(),
                    reason="the platform cannot fork")
def test_local_workers_start_with_the_library_imported(tmp_path):
    """Issue 37 item 4: spawned workers imported numpy and pkmcal afresh (~1 s of each
    worker's CPU) while the command waited idle (200 runs on 2 workers were 1.22x one). Now
    the command computes beside a pool of ``workers - 1`` processes forked from it: each is
    its copy - a change made to the library in the parent before the pool starts is seen by
    every run (nothing is imported again) - and both compute."""
    script = tmp_path / "probe.py"
    script.write_text(
        "import os\n"
        "from pkmcal.analysis import montecarlo as mc\n"
        "from pkmcal.machines import default_hexaslide\n"
        "original = mc.run_once\n"
        "def marked(settings, seed):\n"
        "    row = original(settings, seed)\n"
        "    row['failure'] = f'parent-copy {os.getpid()}'\n"
        "    return row\n"
        "mc.run_once = marked\n"
        "settings = mc.MonteCarloSettings(machine=default_hexaslide(), poses=60)\n"
        "res = mc.montecarlo(settings, 'noise', [2e-6], 6, seed=1, workers=2)\n"
        "marked = [r['failure'] for r in res.rows if r['failure'].startswith('parent-copy')]\n"
        "assert len(marked) == len(res.rows), marked\n"
        "pids = {m.split()[1] for m in marked}\n"
        "print(len(res.rows), len(pids), str(os.getpid()) in pids)\n")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    n, processes, parent = proc.stdout.split()
    assert int(n) == 6 and int(processes) == 2 and parent == "True", proc.stdout
