"""The library workflows of ``pkmcal compensate``, ``export`` and ``import``
(:mod:`pkmcal.workflows.compensate`, :mod:`pkmcal.workflows.export`) called from Python, no
CLI: what they write reads back, and what their summaries state is what the files hold,
recomputed (issue 38 item 3)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pkmcal.export import controller_format
from pkmcal.export.base import load_formats
from pkmcal.export.fitting import commandable, position_errors
from pkmcal.io import load_machine, read_joints, read_positions, read_table
from pkmcal.io.machine_file import save_machine
from pkmcal.machines.deviations import deviations
from pkmcal.report.summary import RawText, Summary, SummaryTable
from pkmcal.units import format_quantity, format_um
from pkmcal.workflows.compensate import read_covariance, run_compensate
from pkmcal.workflows.export import run_export, run_import
from pkmcal.workflows.report import calibration_report_path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _deviated(example: str, path: Path, seed: int = 3) -> Path:
    """The example machine with random deviations of its parameters, saved to ``path``."""
    nominal = load_machine(EXAMPLES / example)
    machine = nominal.with_parameters(nominal.parameters.values
                                      + deviations(nominal, "random", np.random.default_rng(seed)))
    save_machine(machine, path, nominal.file_units)
    return path


def _pairs(summary: Summary) -> dict:
    """The label / value rows of a summary's first table."""
    table = next(b for b in summary.blocks if isinstance(b, SummaryTable))
    return {row[0]: row[1] for row in table.rows}


def _column(path: Path, name: str) -> np.ndarray:
    header, rows = read_table(path)
    k = header.index(name)
    return np.array([float(fields[k]) for _, fields in rows])


# -- compensate --------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def calibrated_delta(tmp_path_factory):
    """A Delta calibrated from simulated tracker data: ``(dir, cal.yaml)`` with its report
    cal.json beside it (made by the pkmcal commands in this process: the files under test
    here are compensate's)."""
    from pkmcal.cli import main

    d = tmp_path_factory.mktemp("delta")
    main(["simulate", str(EXAMPLES / "delta_default.yaml"), "--grid", "4x4x3", "--seed", "2",
          "-o", str(d / "data.csv")])
    main(["calibrate", str(EXAMPLES / "delta_default.yaml"), str(d / "data.csv"),
          "-o", str(d / "cal.yaml")])
    return d, d / "cal.yaml"


def _targets(path: Path, machine, n: int = 12, seed: int = 0) -> np.ndarray:
    """Positions in a 60 mm cube around home, written in mm with every digit."""
    P = machine.home[0] + np.random.default_rng(seed).uniform(-0.03, 0.03, (n, 3))
    path.write_text("x_mm,y_mm,z_mm\n" + "\n".join(
        ",".join(repr(float(v * 1e3)) for v in p) for p in P) + "\n")
    return P


def test_compensate_writes_the_calibrated_inverse_kinematics_and_states_its_residual(
        calibrated_delta, tmp_path):
    from pkmcal.compensation import compensate

    d, cal_file = calibrated_delta
    cal = load_machine(cal_file)
    nominal_file = str(EXAMPLES / "delta_default.yaml")
    P = _targets(tmp_path / "targets.csv", cal)
    out = tmp_path / "commands.csv"
    summary = run_compensate(str(cal_file), tmp_path / "targets.csv", out,
                             nominal_spec=nominal_file, json_output=True)
    assert isinstance(summary, Summary) and summary.exit_code == 0
    assert summary.warnings == []                        # the report beside cal.yaml was found
    assert len(summary.blocks) == 1 and isinstance(summary.blocks[0], RawText)
    record = json.loads(summary.blocks[0].text)
    assert record["targets"] == len(P) and record["covariance_from"].endswith("cal.json")

    # the file holds the targets as given and the commands of the calibrated model
    size = np.linalg.norm(cal.home[0])
    P_file, _ = read_positions(out)
    np.testing.assert_allclose(P_file, P, rtol=0, atol=1e-12 * size)
    q = read_joints(out, cal.n_joints, "angle")[0]
    np.testing.assert_allclose(cal.fk(q).P, P, rtol=0, atol=1e-9 * size)

    # the stated residual is that of the file's column, which is the covariance's prediction
    predicted = _column(out, "predicted_position_um")
    assert record["predicted_position_um"]["rms"] == pytest.approx(
        np.sqrt(np.mean(predicted**2)), rel=1e-12)
    assert record["predicted_position_um"]["max"] == pytest.approx(predicted.max(), rel=1e-12)
    report = calibration_report_path(cal, str(cal_file), None)
    C, N = read_covariance(report, cal)
    comp = compensate(cal, P, np.broadcast_to(np.eye(3), (len(P), 3, 3)), C,
                      load_machine(nominal_file), N)
    np.testing.assert_allclose(predicted, comp.position_std * 1e6, rtol=1e-9)
    uncompensated = _column(out, "uncompensated_position_um")
    np.testing.assert_allclose(uncompensated, comp.uncompensated_position * 1e6, rtol=1e-9)
    # a calibration of random deviations: the old commands are far worse than the prediction
    assert uncompensated.min() > 5 * predicted.max()

    # the table states the same figures, and the same file is written
    table_out = tmp_path / "commands_table.csv"
    summary = run_compensate(str(cal_file), tmp_path / "targets.csv", table_out,
                             nominal_spec=nominal_file)
    rows = _pairs(summary)
    pp = record["predicted_position_um"]
    assert rows["predicted residual"].startswith(
        f"position {format_um(pp['rms'], 3)} RMS, {format_um(pp['max'], 3)} max")
    assert table_out.read_bytes() == out.read_bytes()


def test_compensate_without_a_report_warns_and_writes_no_prediction(calibrated_delta,
                                                                   tmp_path):
    d, cal_file = calibrated_delta
    alone = tmp_path / "cal.yaml"
    alone.write_bytes(cal_file.read_bytes())           # the YAML without its report
    cal = load_machine(alone)
    _targets(tmp_path / "targets.csv", cal, n=4)
    summary = run_compensate(str(alone), tmp_path / "targets.csv", tmp_path / "c.csv")
    assert len(summary.warnings) == 1 and "cal.json" in summary.warnings[0]
    assert "predicted residual" not in _pairs(summary)
    header, _ = read_table(tmp_path / "c.csv")
    assert header == ["x_mm", "y_mm", "z_mm", "q1_deg", "q2_deg", "q3_deg"]


# -- export and import -------------------------------------------------------------------------


def test_genhexkins_export_then_import_gives_the_machine_back(tmp_path):
    machine_file = _deviated("cubic_6upu.yaml", tmp_path / "machine.yaml")
    machine = load_machine(machine_file)
    nominal = load_machine(EXAMPLES / "cubic_6upu.yaml")
    summary = run_export(str(machine_file), "linuxcnc-genhexkins", tmp_path / "hexapod.hal")
    assert summary.blocks[-1] == (f"wrote {tmp_path / 'hexapod.hal'} and "
                                  f"{tmp_path / 'hexapod.hal.json'}")
    record = json.loads((tmp_path / "hexapod.hal.json").read_text())
    assert _pairs(summary)["remaining error"].startswith(
        f"RMS {format_quantity(record['remaining_rms_um'] * 1e-6, 'length')}, ")

    summary = run_import(tmp_path / "hexapod.hal", "linuxcnc-genhexkins",
                         tmp_path / "back.yaml", like=str(machine_file))
    assert summary.text().endswith("written to "
                                   f"{tmp_path / 'back.yaml'} as a stewart machine file\n")
    back = load_machine(tmp_path / "back.yaml")
    assert back.parameters.names == machine.parameters.names
    size = np.linalg.norm(machine.home[0])               # the machine's scale, m
    v, v0 = machine.parameters.values, nominal.parameters.values
    tol = 1e-6 * np.maximum(np.abs(v), size)             # the file's digits: far below ...
    np.testing.assert_array_less(np.abs(back.parameters.values - v), tol)
    assert np.mean(np.abs(v - v0) > 100 * tol) > 0.5     # ... the deviations carried back


def test_linuxcnc_configuration_round_trip_asks_the_format(tmp_path):
    """``-o DIR/`` writes the format's configuration files, and importing the directory gives
    the machine back with its home and name from the INI (the format reads it)."""
    machine_file = _deviated("cubic_6upu.yaml", tmp_path / "machine.yaml", seed=5)
    machine = load_machine(machine_file)
    fmt = controller_format("linuxcnc-genhexkins")
    summary = run_export(str(machine_file), fmt.name, str(tmp_path / "cfg") + "/")
    files = sorted(p.name for p in (tmp_path / "cfg").iterdir())
    assert files == sorted([*fmt.configuration_files, "export.json"])
    assert summary.blocks[-1].startswith(f"wrote {fmt.configuration_words} {tmp_path / 'cfg'}")
    assert json.loads((tmp_path / "cfg" / "export.json").read_text())["file"] == str(
        tmp_path / "cfg" / fmt.configuration_values_file)

    run_import(tmp_path / "cfg", fmt.name, tmp_path / "back.yaml")
    back = load_machine(tmp_path / "back.yaml")
    v = machine.parameters.values
    np.testing.assert_array_less(np.abs(back.parameters.values - v),
                                 1e-6 * np.maximum(np.abs(v), 0.3))
    np.testing.assert_allclose(back.home[0], machine.home[0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.home[1], machine.home[1], rtol=0, atol=1e-9)
    assert back.name == machine.name


def test_klipper_export_states_the_error_its_written_values_leave(tmp_path):
    """The remaining error stated and recorded is that of the values the written printer.cfg
    holds, read back and run through Klipper's kinematics over the printer's workspace."""
    machine_file = _deviated("linear_delta.yaml", tmp_path / "printer.yaml")
    machine = load_machine(machine_file)
    fmt = controller_format("klipper")
    summary = run_export(str(machine_file), "klipper", tmp_path / "printer.cfg",
                         nominal=str(EXAMPLES / "linear_delta.yaml"))
    record = json.loads((tmp_path / "printer.cfg.json").read_text())
    params = fmt.parse((tmp_path / "printer.cfg").read_text(), "printer.cfg")
    ws = machine.print_workspace(rng=0)
    P, R, _, _ = commandable(fmt, machine, ws.P, ws.R, ws.surface)
    e = np.linalg.norm(position_errors(fmt, params, machine, P, R), axis=-1)
    assert record["points"] == len(P) == 500
    assert record["remaining_rms_um"] == pytest.approx(np.sqrt(np.mean(e**2)) * 1e6, rel=1e-9)
    assert record["remaining_max_um"] == pytest.approx(e.max() * 1e6, rel=1e-9)
    assert record["remaining_rms_um"] > 1.0              # tower tilts Klipper cannot hold
    assert record["before_rms_um"] > 5 * record["remaining_rms_um"]
    values = next(b for b in summary.blocks
                  if isinstance(b, SummaryTable) and b.columns == ("value", "written"))
    assert values.rows == [tuple(r) for r in fmt.values_text(params)]


def test_a_one_file_format_refuses_a_directory_and_writes_nothing(tmp_path):
    from pkmcal.errors import InputError

    machine_file = _deviated("linear_delta.yaml", tmp_path / "printer.yaml")
    writers = [n for n, f in load_formats().items() if f.configuration_files]
    assert writers and "klipper" not in writers
    before = sorted(tmp_path.iterdir())
    with pytest.raises(InputError, match="names a directory; klipper writes one file") as exc:
        run_export(str(machine_file), "klipper", str(tmp_path / "cfg") + "/")
    assert all(name in str(exc.value) for name in writers)
    assert sorted(tmp_path.iterdir()) == before


def test_export_asks_the_format_whether_it_writes_a_configuration(tmp_path, monkeypatch):
    """Regression (issue 38): the workflow asked ``isinstance(fmt, LinuxCNCKinematics)``;
    any format that declares configuration files writes a directory now."""
    import pkmcal.workflows.export as workflow

    base = type(controller_format("klipper"))

    class KlipperDirectory(base):
        configuration_files = {"printer.cfg": "the values", "notes.txt": "a note"}
        configuration_values_file = "printer.cfg"
        configuration_words = "the test configuration"

        def configuration(self, result, machine, workspace):
            return {"printer.cfg": result.text, "notes.txt": f"{len(workspace.P)} poses\n"}

        def configuration_start(self, directory):
            return f"klippy {directory / 'printer.cfg'}"

    fmt = KlipperDirectory()
    monkeypatch.setattr(workflow, "controller_format", lambda name, option=None: fmt)
    machine_file = _deviated("linear_delta.yaml", tmp_path / "printer.yaml")
    summary = run_export(str(machine_file), "klipper", str(tmp_path / "cfg") + "/")
    assert sorted(p.name for p in (tmp_path / "cfg").iterdir()) == [
        "export.json", "notes.txt", "printer.cfg"]
    assert (tmp_path / "cfg" / "notes.txt").read_text() == "500 poses\n"
    params = fmt.parse((tmp_path / "cfg" / "printer.cfg").read_text(), "printer.cfg")
    record = json.loads((tmp_path / "cfg" / "export.json").read_text())
    np.testing.assert_allclose([record["values"][n] for n in params.names], params.values,
                               rtol=1e-12)
    assert summary.blocks[-1].endswith(f"(start it with: klippy {tmp_path / 'cfg'}/printer.cfg)")
