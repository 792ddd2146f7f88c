"""Probe reports pasted from Marlin and RepRapFirmware as calibration data (issue 24 item 2):
positions in firmware coordinates plus the firmware's values in force give the carriage
readings through the firmware's own kinematics. A simulated printer whose values are off
(Marlin's set: endstop adjustments, radius, tower angle trims) is probed by its firmware, the
report is written as Marlin prints it (``Bed X: Y: Z:``, G30 / G29 V3, with the M503 lines),
and pkmcal recovers the true values from it."""

from __future__ import annotations

import numpy as np

from pkmcal.calibration.run import calibrate
from pkmcal.export.marlin import MARLIN
from pkmcal.instruments.registry import instrument
from pkmcal.instruments.simulate import probe_trigger
from pkmcal.machines import linear_delta


def test_a_marlin_probe_report_calibrates_the_printer(tmp_path):
    firmware = linear_delta(0.105, 0.215, np.deg2rad([210.0, 330.0, 90.0]), (0.2505,) * 3)
    true = linear_delta(0.1054, 0.215, np.deg2rad([209.7, 330.25, 90.0]),
                        (0.2508, 0.2499, 0.2512))
    P, R, _ = instrument("probe").candidates(firmware, 19, np.random.default_rng(2))
    # the firmware lowers the nozzle until the TRUE nozzle touches the TRUE bed; it reports
    # where it believes the nozzle is then (M851 Z0: a nozzle probe)
    q, _ = probe_trigger(true, firmware, P, R, (0.0, 0.0, 0.0), np.zeros(len(P)))
    believed = firmware.fk(q).P * 1e3
    values = MARLIN.initial(firmware)
    lines = ["Send: M503", *("Recv: echo:  " + line for line in MARLIN.text(
        values, firmware).splitlines() if line.startswith("M66")), "Send: G29 V3"]
    lines += [f"Recv: Bed X: {x:.3f} Y: {y:.3f} Z: {z:.5f}" for x, y, z in believed]
    (tmp_path / "probe.log").write_text("\n".join(lines) + "\n")
    c = calibrate(firmware, tmp_path / "probe.log", parameters="marlin")
    assert c.kind == "probe" and c.report["measurements"] == len(P)
    cal = c.calibrated
    for name in ("tower1.endstop", "tower2.endstop", "tower3.endstop", "delta_radius"):
        i = cal.parameters.index(name)
        assert abs(cal.u[i] - true.u[i]) < 2e-6, name          # the report's 5 decimals
    angles = [cal.parameters.index(f"tower{k}.angle") for k in (1, 2)]
    assert np.abs(cal.u[angles] - true.u[angles]).max() < 2e-5
