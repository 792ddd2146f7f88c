"""``pkmcal fk CALIBRATED JOINTS.csv --frame instrument`` predicts what the calibration's
instrument measures for new readings (issue 13 item 3): tracker points per ``target``, marker
poses, ballbar lengths per ``setup``, on every machine (example and modified geometries), in
the machine file's length unit; the same numbers as the instruments' simulation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, run
from pkmcal.errors import InputError
from pkmcal.instruments import (
    DistancesModel,
    NuisanceState,
    PointsModel,
    fitted_instruments,
    predict_instrument,
)
from pkmcal.instruments.distance import BallbarSetup
from pkmcal.instruments.pose import MeasurementFrames, simulate_full_pose
from pkmcal.instruments.setups import Setups
from pkmcal.instruments.simulate import sample_workspace_poses, simulate_instrument
from pkmcal.instruments.tracker import TrackerSetup
from pkmcal.io import load_machine, load_machine_file, read_poses, save_machine
from pkmcal.io.csv_io import write_full_pose, write_instrument
from pkmcal.kinematics import matrix_from_rotvec
from pkmcal.machines.deviations import random_deviations
from pkmcal.units import LENGTH

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
#: case -> (machine file, file units of the calibrated file, modify the geometry)
CASES = {
    "hexaslide": (EXAMPLES / "hexaslide_default.yaml", None, False),
    "delta": (EXAMPLES / "delta_default.yaml", None, False),
    "stewart": (EXAMPLES / "cubic_6upu.yaml", None, False),
    "hexaslide-modified": (EXAMPLES / "hexaslide_default.yaml",
                           {"length": "m", "angle": "rad"}, True),
    "delta-modified": (EXAMPLES / "delta_default.yaml", {"length": "in", "angle": "deg"}, True),
    "stewart-modified": (EXAMPLES / "cubic_6upu.yaml", {"length": "m", "angle": "deg"}, True),
}
N = 14


def calibrated(case: str, instruments=("tracker", "pose", "distance"), seed: int = 5):
    """A 'calibrated' machine with known instrument set-ups (the truth for the models):
    ``(machine, setups)``."""
    path, units, modify = CASES[case]
    m = load_machine(path)
    rng = np.random.default_rng(seed)
    if modify:
        m = m.with_parameters(m.u + random_deviations(m, rng))
    setups = {}
    L = m.characteristic_length()
    if "tracker" in instruments:
        pose = (matrix_from_rotvec([0.1, -0.2, 2.0]),
                np.array([2.0, -1.5, -0.4]) + rng.normal(size=3) * 0.05)
        targets = rng.normal(size=(3, 3)) * 0.2 * L if m.kind != "delta" else None
        setups["tracker"] = TrackerSetup(pose, targets)
    if "pose" in instruments and m.pose_dof == 6:
        setups["pose"] = MeasurementFrames(
            (matrix_from_rotvec(rng.normal(size=3)), rng.normal(size=3)),
            (matrix_from_rotvec(rng.normal(size=3) * 0.3), rng.normal(size=3) * 0.1 * L))
    if "distance" in instruments:
        setups["distance"] = BallbarSetup([(m.home[0] + rng.normal(size=3) * 0.3 * L,
                                            rng.normal(size=3) * 0.1 * L) for _ in range(2)])
    if units is not None:
        m.file_units = units
    return m, Setups(setups)


def simulate(m, setups, instrument: str, rng):
    """Simulated measurements (the instrument's own simulation) at random poses."""
    P, R = sample_workspace_poses(m, N, rng)
    if instrument == "pose":
        return simulate_full_pose(m, (P, R), setups["pose"], noise=None)
    if instrument == "tracker":
        known = m.tracker_target()
        tracker = setups["tracker"]
        targets = np.atleast_2d(known if known is not None else tracker.targets)
        K = 1 if known is not None else len(targets)
        model = PointsModel(K, known)
        values = np.concatenate([np.zeros(3), tracker.base_from_tracker[1]]
                                + ([] if known is not None else [targets.ravel()]))
        truth = NuisanceState(values, [tracker.base_from_tracker[0]])
    else:
        K = len(setups["distance"])
        model = DistancesModel(K)
        values = np.concatenate([np.concatenate(s) for s in setups["distance"]])
        truth = NuisanceState(values, [])
    group = np.arange(N) % K
    return simulate_instrument(m, m, model, truth, P, R, group=group)


def table(path: Path) -> np.ndarray:
    return np.genfromtxt(path, delimiter=",", names=True)


@pytest.mark.parametrize("case", list(CASES))
def test_predictions_match_the_instruments(case, tmp_path):
    m, s = calibrated(case)
    save_machine(m, tmp_path / "cal.yaml", setups=s)
    unit = (CASES[case][1] or {"length": "mm"})["length"]
    f = LENGTH[unit]
    rng = np.random.default_rng(11)
    expected = ["tracker", "distance"] if m.pose_dof == 3 else ["tracker", "pose", "distance"]
    assert fitted_instruments(*load_machine_file(tmp_path / "cal.yaml")) == expected
    for instrument in expected:
        data = simulate(m, s, instrument, rng)
        joints = tmp_path / f"{instrument}.csv"
        out = tmp_path / f"{instrument}_predicted.csv"
        if instrument == "pose":
            write_full_pose(joints, data, m, "mm")
        else:
            write_instrument(joints, data, m, "mm")
        proc = run("fk", "cal.yaml", joints.name, "--frame", "instrument", "--instrument",
                   instrument, "-o", out.name, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        assert f"({unit})" in proc.stdout
        got = table(out)
        if instrument == "pose":
            P, R, _ = read_poses(out)
            scale = np.abs(data.P).max()
            np.testing.assert_allclose(P, data.P, rtol=1e-9, atol=1e-10 * scale)
            np.testing.assert_allclose(R, data.R, atol=1e-9)
            assert list(got.dtype.names) == [f"x_{unit}", f"y_{unit}", f"z_{unit}", "qx", "qy",
                                             "qz", "qw"]
        elif instrument == "tracker":
            pred = np.column_stack([got[f"m{c}_{unit}"] for c in "xyz"]) * f
            scale = np.abs(data.values).max()
            np.testing.assert_allclose(pred, data.values, rtol=1e-9, atol=1e-10 * scale)
            if m.kind != "delta":      # several targets: the column goes through
                np.testing.assert_array_equal(got["target"], data.group + 1)
        else:
            pred = got[f"d_{unit}"] * f
            np.testing.assert_allclose(pred, data.values[:, 0], rtol=1e-9)
            np.testing.assert_array_equal(got["setup"], data.group + 1)


@pytest.mark.parametrize("case", ["hexaslide-modified", "delta"])
def test_one_instrument_needs_no_option(case, tmp_path):
    m, s = calibrated(case, instruments=("distance",))
    save_machine(m, tmp_path / "cal.yaml", setups=s)
    data = simulate(m, s, "distance", np.random.default_rng(2))
    write_instrument(tmp_path / "d.csv", data, m, "um")      # any unit in, the file's out
    proc = run("fk", "cal.yaml", "d.csv", "--frame", "instrument", "-o", "p.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    unit = (CASES[case][1] or {"length": "mm"})["length"]
    np.testing.assert_allclose(table(tmp_path / "p.csv")[f"d_{unit}"] * LENGTH[unit],
                               data.values[:, 0], rtol=1e-9)
    # --frame base is today's fk
    assert run("fk", "cal.yaml", "d.csv", "-o", "b.csv", cwd=tmp_path).returncode == 0
    assert "x_" in (tmp_path / "b.csv").read_text().splitlines()[0]


def test_library_prediction():
    m, s = calibrated("stewart-modified")
    data = simulate(m, s, "tracker", np.random.default_rng(4))
    pred = predict_instrument(m, s, data.q, "points", data.group)
    assert pred.instrument == "tracker" and pred.converged.all()
    np.testing.assert_allclose(pred.values, data.values, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(pred.fk.P, data.true_P, atol=1e-9)
    with pytest.raises(InputError, match=r"instrument \(tracker\|pose\|distance\)"):
        predict_instrument(m, s, data.q)
    with pytest.raises(InputError, match="target 4, but"):
        predict_instrument(m, s, data.q, "tracker", np.full(len(data.q), 3))
    with pytest.raises(InputError, match="unknown instrument"):
        predict_instrument(m, s, data.q, "laser")


def test_errors(tmp_path):
    m, s = calibrated("hexaslide-modified")
    save_machine(m, tmp_path / "all.yaml", setups=s)
    data = simulate(m, s, "tracker", np.random.default_rng(3))
    write_instrument(tmp_path / "t.csv", data, m, "mm")

    def fk(*args):
        return run("fk", *args, "-o", "o.csv", cwd=tmp_path)

    assert_input_error(fk("all.yaml", "t.csv", "--frame", "instrument"), "several instruments",
                       "--instrument (tracker|pose|distance)")
    assert_input_error(fk(EXAMPLES / "hexaslide_default.yaml", "t.csv", "--frame",
                          "instrument"), "carries no instrument", "points", "tracker",
                       "measurement_frames", "ballbar")
    assert_input_error(fk("all.yaml", "t.csv", "--instrument", "tracker"), "--instrument",
                       "--frame instrument")
    assert_input_error(fk("all.yaml", "t.csv", "--frame", "instrument", "--instrument",
                          "laser"), "unknown instrument 'laser'", "tracker, pose, distance")
    only, only_setups = calibrated("delta", instruments=("tracker",))
    save_machine(only, tmp_path / "delta.yaml", setups=only_setups)
    assert_input_error(fk("delta.yaml", "t.csv", "--frame", "instrument", "--instrument",
                          "pose"), "--instrument pose", "no measurement_frames section",
                       "it has: tracker")
    # a target the file does not have, named by row and column
    text = (tmp_path / "t.csv").read_text().splitlines()
    head = text[0].split(",")
    k = head.index("target")
    row = text[3].split(",")
    row[k] = "4"
    text[3] = ",".join(row)
    (tmp_path / "t4.csv").write_text("\n".join(text) + "\n")
    assert_input_error(fk("all.yaml", "t4.csv", "--frame", "instrument", "--instrument",
                          "tracker"), "t4.csv", "row 4, column target", "target 4",
                       "tracker.targets has 3")
    ddata = simulate(m, s, "distance", np.random.default_rng(3))
    write_instrument(tmp_path / "d.csv", ddata, m, "mm")
    text = (tmp_path / "d.csv").read_text().replace(",2\n", ",7\n", 1)
    (tmp_path / "d7.csv").write_text(text)
    assert_input_error(fk("all.yaml", "d7.csv", "--frame", "instrument", "--instrument",
                          "distance"), "d7.csv", "column setup", "setup 7", "ballbar has 2")
    lines = (tmp_path / "t.csv").read_text().splitlines()
    lines[0] = ",".join("q3" if c.startswith("q3_") else c for c in lines[0].split(","))
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    assert_input_error(fk("all.yaml", "bad.csv", "--frame", "instrument", "--instrument",
                          "tracker"), "bad.csv", "q3")
    assert not (tmp_path / "o.csv").exists()
