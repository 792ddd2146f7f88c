"""The calibration as a library (``pkmcal.calibration.calibrate``), without the command line:
every measurement kind from simulated data, the same report as ``pkmcal calibrate --json``,
warnings returned and never printed, and files written that load back."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clitools import run
from pkmcal.calibration import KINDS, Calibration, CalibrationNotConverged, calibrate
from pkmcal.errors import InputError
from pkmcal.instruments.tracker import TrackerNoise
from pkmcal.io import load_machine, read_constraint_link
from pkmcal.machines import default_hexaslide

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MACHINES = {"constraint-link": "default", "tracker": EXAMPLES / "delta_default.yaml",
            "pose": EXAMPLES / "cubic_6upu.yaml"}
SIMULATE = {"constraint-link": [], "tracker": [], "pose": ["--poses", "30"]}


def machine_of(kind):
    spec = MACHINES[kind]
    if spec == "default":
        return default_hexaslide()
    return load_machine(spec)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A simulated data file of each kind, and the command's JSON report of it."""
    d = tmp_path_factory.mktemp("api")
    out = {}
    for kind, spec in MACHINES.items():
        proc = run("simulate", spec, "-o", f"{kind}.csv", "--seed", "3", *SIMULATE[kind], cwd=d)
        assert proc.returncode == 0, proc.stderr
        proc = run("calibrate", spec, f"{kind}.csv", "-o", f"{kind}_cli.yaml", "--json",
                   "--holdout", "0.2", cwd=d)
        assert proc.returncode == 0, proc.stderr
        out[kind] = (d / f"{kind}.csv", json.loads(proc.stdout))
    return out


def keys(tree, prefix=""):
    """Every key path of a nested dict (lists of dicts: their first element's)."""
    found = set()
    for k, v in tree.items():
        found.add(prefix + k)
        if isinstance(v, dict) and k not in ("covariance",):
            found |= keys(v, prefix + k + ".")
    return found


@pytest.mark.parametrize("kind", list(MACHINES))
def test_calibrate_each_kind_returns_the_commands_report(kind, data, tmp_path, capsys):
    path, cli_report = data[kind]
    cal = calibrate(machine_of(kind), path, holdout=0.2)
    assert isinstance(cal, Calibration) and cal.kind == kind
    assert capsys.readouterr() == ("", "")          # the library prints nothing
    assert cal.report["measurement"] == kind
    assert cal.result.success
    # the same report as the command's JSON (whose own keys the CLI tests check), with the
    # answer the command puts first: the library's pkmcal.analysis.outcome (a layer above the
    # calibration, as the command is)
    from pkmcal.analysis.outcome import calibration_outcome

    assert "outcome" not in cal.report and "outcome" in cli_report
    cal.report["outcome"] = calibration_outcome(cal, f"{kind}_cli.yaml")
    assert keys(json.loads(cal.json_text())) == keys(cli_report)
    assert cal.report["validation"]["held_out"] == cli_report["validation"]["held_out"]
    assert cal.report["calibrated_file"] is None
    assert [p["name"] for p in cal.params] == [p["name"] for p in cli_report["parameters"]]
    assert cal.metadata["identifiable"] == cli_report["identifiability"]["identifiable"]
    assert "report" not in cal.metadata and "report_sha256" not in cal.metadata
    assert all(isinstance(w, str) for w in cal.warnings)

    # write: the machine file names and pins its report, and loads back
    out = tmp_path / "cal.yaml"
    text = cal.write(out, report_dir=tmp_path / "rep")
    assert capsys.readouterr() == ("", "")
    written = json.loads((tmp_path / "cal.json").read_text())
    assert written == json.loads(text) and written["calibrated_file"] == str(out)
    assert (tmp_path / "rep" / "report.html").is_file()
    assert json.loads((tmp_path / "rep" / "report.json").read_text()) == written
    back = load_machine(out)
    np.testing.assert_allclose(back.u, cal.calibrated.u, rtol=0,
                               atol=1e-12 * float(np.max(np.abs(cal.calibrated.u))))
    info = back.calibration_info
    assert info["report"] == "cal.json" and len(info["report_sha256"]) == 64
    assert info["measurements"] == cal.report["measurements"]


def test_warnings_are_returned_not_printed(data, capsys):
    """A noise model far below the data's noise: the chi-square warning is in the result."""
    path, _ = data["tracker"]
    cal = calibrate(machine_of("tracker"), path, noise=TrackerNoise(1e-7, 1e-7, 0.0))
    assert capsys.readouterr() == ("", "")
    assert cal.report["noise"] == "isotropic 0.1 um"
    assert any("noise" in w for w in cal.warnings), cal.warnings
    assert all(w.startswith(str(path)) for w in cal.warnings)


def test_si_options_and_user_text_agree(data):
    path, _ = data["constraint-link"]
    machine = machine_of("constraint-link")
    a = calibrate(machine, path, noise=2e-6, method="ik")
    b = calibrate(machine, path, noise="2um", method="ik")
    assert a.report["noise_sigma_um"] == pytest.approx(2.0)
    np.testing.assert_array_equal(a.result.x, b.result.x)


def test_data_in_memory(data):
    path, _ = data["constraint-link"]
    machine = machine_of("constraint-link")
    read = read_constraint_link(path, machine)
    cal = calibrate(machine, read)
    assert cal.kind == "constraint-link" and cal.report["data_file"] == str(path)
    np.testing.assert_array_equal(cal.result.x, calibrate(machine, path).result.x)


def test_options_of_another_kind_are_refused_with_the_commands_words(data):
    path, _ = data["tracker"]
    with pytest.raises(InputError, match="--method: applies to constraint-link data"):
        calibrate(machine_of("tracker"), path, method="ml")
    path, _ = data["constraint-link"]
    with pytest.raises(InputError, match="--two-step: applies to tracker data; .* has "
                                         "constraint-link data"):
        calibrate(machine_of("constraint-link"), path, two_step=True)
    with pytest.raises(InputError, match="--holdout 2x"):
        calibrate(machine_of("constraint-link"), path, holdout="2x")
    path, _ = data["pose"]
    with pytest.raises(InputError, match="--two-step: applies to tracker data; .* has pose "
                                         "data"):
        calibrate(machine_of("pose"), path, two_step=True)
    # --robust applies to every instrument, but not to a method that takes poses as exact
    with pytest.raises(InputError, match="--robust: applies to the ml method"):
        calibrate(machine_of("pose"), path, robust=True, method="ik")


def test_a_machine_that_cannot_use_the_data(data):
    path, _ = data["pose"]
    # the Delta's platform does not rotate: the registry's reason is given
    with pytest.raises(InputError, match="pose measurements cannot calibrate a delta: full "
                                         "poses need a platform that rotates"):
        calibrate(machine_of("tracker"), path)


def test_not_converged_is_an_exception(data, monkeypatch):
    import pkmcal.instruments.constraint_link as link

    real = link.calibrate_constraint_link

    def one_iteration(*args, **kwargs):
        result = real(*args, **kwargs)
        result.success, result.message = False, "maximum number of iterations"
        return result

    monkeypatch.setattr(link, "calibrate_constraint_link", one_iteration)
    path, _ = data["constraint-link"]
    with pytest.raises(CalibrationNotConverged, match="did not converge") as info:
        calibrate(machine_of("constraint-link"), path)
    assert info.value.result is not None


def test_kinds_are_a_registry():
    """Every instrument of the registry is a kind; every kind names its data columns, its
    machines and its handler."""
    from pkmcal.instruments.registry import INSTRUMENTS

    assert set(KINDS) == set(INSTRUMENTS)
    assert {"constraint-link", "tracker", "pose", "distance", "probe",
            "pair-distances"} <= set(KINDS)
    for kind in KINDS.values():
        assert kind.columns and callable(kind.calibrate) and callable(kind.check_options)
