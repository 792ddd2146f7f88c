"""Quick self-checks of the independent Klipper delta reference, ``tests/klipper_reference.py``."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

import klipper_reference as kr

#: the published printers' saved data, outside the project (``../shared`` beside the repository)
DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), os.pardir,
                    "shared", "data", "printers", "klipper_saved")


def _calib():
    return kr.DeltaCalibration(
        radius=140.0,
        angles=[210.3, 329.8, 90.0],
        arms=[330.2, 329.7, 330.5],
        endstops=[300.4, 300.1, 299.8],
        stepdists=[40 / (200 * 16)] * 3,
    )


def _probe_points(radius=120.0):
    # DELTA_CALIBRATE's default pattern: the centre and six scattered points
    points = [(0.0, 0.0)]
    for i, scatter in enumerate([0.95, 0.90, 0.85, 0.70, 0.75, 0.80]):
        angle = math.radians(90.0 + 60.0 * i)
        points.append((math.cos(angle) * radius * scatter, math.sin(angle) * radius * scatter))
    return points


def test_stable_position_round_trip():
    calib = _calib()
    rng = np.random.default_rng(1)
    for x, y, z in rng.uniform([-100, -100, 0], [100, 100, 150], size=(20, 3)):
        stable = calib.calc_stable_position((x, y, z))
        assert calib.get_position_from_stable(stable) == pytest.approx([x, y, z], abs=1e-9)
    # vectorised path agrees with the scalar one
    stables = [calib.calc_stable_position((10.0 * i, -5.0 * i, 3.0 * i)) for i in range(5)]
    many = calib.positions_from_stable(stables)
    for row, stable in zip(many, stables, strict=True):
        assert list(row) == calib.get_position_from_stable(stable)


def test_home_position_is_above_the_centre():
    calib = _calib()
    x, y, z = calib.get_position_from_stable([0.0, 0.0, 0.0])  # at the endstops
    assert abs(x) < 5 and abs(y) < 5 and 295 < z < 305


def test_coordinate_descent_reduces_the_error_on_a_simulated_printer():
    true = _calib()
    data = kr.CalibrationData(stepdists=true.stepdists)
    for x, y in _probe_points():
        data.probe_heights.append((0.0, true.calc_stable_position((x, y, 0.0))))
    # the printer believes in the nominal geometry
    nominal = kr.DeltaCalibration(
        141.0, [210.0, 330.0, 90.0], true.arms, [300.0] * 3, true.stepdists
    )
    error, z_weight = kr.make_error_function(nominal, data)
    assert z_weight == 1.0
    start_err = error(nominal.as_params())
    result = kr.delta_calibrate(nominal, data)
    assert result.adjusted == (
        "radius",
        "angle_a",
        "angle_b",
        "endstop_a",
        "endstop_b",
        "endstop_c",
    )
    assert result.error < 1e-3 * start_err
    assert kr.rms(kr.height_residuals(result.calibration, data)) < 5e-3
    assert kr.rms(kr.height_residuals(nominal, data)) > 0.1


def test_coordinate_descent_step_rule():
    # a separable quadratic: the steps grow by 1.1 on success and shrink by 0.9 otherwise
    params, best, rounds = kr.coordinate_descent(
        ("a", "b"),
        {"a": 0.0, "b": 0.0, "c": 7.0},
        lambda p: (p["a"] - 3.3) ** 2 + (p["b"] + 1) ** 2,
    )
    assert params["a"] == pytest.approx(3.3, abs=1e-3)
    assert params["b"] == pytest.approx(-1.0, abs=1e-3)
    assert params["c"] == 7.0 and 0 < rounds < 10000 and best < 1e-6


def test_error_function_weights_heights_against_distances():
    calib = _calib()
    data = kr.CalibrationData(stepdists=calib.stepdists)
    for x, y in _probe_points():
        data.probe_heights.append((0.1, calib.calc_stable_position((x, y, 0.0))))
    data.manual_heights.append((0.2, calib.calc_stable_position((0.0, 0.0, 0.0))))
    p1, p2 = calib.calc_stable_position((0, 0, 0)), calib.calc_stable_position((50, 0, 0))
    data.distances = [(50.3, p1, p2)] * 3
    error, z_weight = kr.make_error_function(calib, data)
    # probed heights only in the denominator, manual heights in the sum
    assert z_weight == 3 / (0.5 * 7)
    expected = z_weight * (7 * 0.1**2 + 0.2**2) + 3 * 0.3**2
    assert error(calib.as_params()) == pytest.approx(expected, rel=1e-9)
    assert kr.distance_residuals(calib, data) == pytest.approx([-0.3] * 3, abs=1e-9)


def test_config_precedence_includes_and_comments(tmp_path):
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "b.cfg").write_text("[stepper_b]\nmicrosteps: 32\n")
    (tmp_path / "parts" / "a.cfg").write_text("[stepper_b]\nmicrosteps: 8\nrotation_distance: 40\n")
    text = (
        "[printer]\nkinematics: delta\ndelta_radius: 150 # body value\n"
        "[include parts/*.cfg]\n"
        "[stepper_a]\n; a comment\nrotation_distance: 40 ; inline\nmicrosteps: 16\n"
        "gear_ratio: 80:16, 60:16\n"
        "[stepper_c]\nstep_distance: .0125\n"
        + kr.AUTOSAVE_HEADER
        + "#*# [printer]\n#*# delta_radius = 151.209444\n#*#\n"
        "#*# [stepper_a]\n#*# arm_length = 315.000000\n"
    )
    path = tmp_path / "printer.cfg"
    path.write_text(text)
    cfg = kr.read_klipper_config(str(path))
    assert cfg.get("printer", "delta_radius") == "150"  # the body wins
    assert cfg.get("stepper_a", "arm_length") == "315.000000"  # the block adds
    assert cfg.overridden == [("printer", "delta_radius", "150", "151.209444")]
    assert cfg.get("stepper_b", "microsteps") == "32"  # globbed includes, sorted, later wins
    assert cfg.get("stepper_a", "rotation_distance") == "40"
    assert kr.step_distance(cfg.sections["stepper_a"]) == pytest.approx(40 / 3200 / 18.75)
    assert kr.step_distance(cfg.sections["stepper_b"]) == 40 / 6400
    assert kr.step_distance(cfg.sections["stepper_c"]) == 0.0125  # pre-2021 style


def test_a_tampered_autosave_block_is_ignored():
    # a line after the header without the "#*# " prefix: Klipper ignores the whole block and
    # reads the file as plain config, in which the "#*#" lines are comments
    text = "[printer]\ndelta_radius: 150\n" + kr.AUTOSAVE_HEADER
    text += "#*# [printer]\n#*# delta_radius = 151\nfoo: 1\n"
    cfg = kr.read_klipper_config(text=text)
    assert cfg.autosave == {} and cfg.get("printer", "delta_radius") == "150"
    assert cfg.get("printer", "foo") == "1"


@pytest.mark.skipif(not os.path.isdir(DATA), reason=f"{DATA} not found: the real printers' "
                    "files stay outside the project (../shared)")
def test_the_port_reproduces_a_saved_klipper_calibration():
    ds = kr.load_data_set(os.path.join(DATA, "v400-fzechert-run2.cfg"))
    result = kr.delta_calibrate(ds.calibration, ds.data)
    saved = ds.calibration.as_params()
    # Klipper saved its result with 6 decimals; the port lands on the same optimum
    assert max(abs(result.params[n] - saved[n]) for n in result.adjusted) < 1e-4
    assert kr.rms(kr.height_residuals(ds.calibration, ds.data)) == pytest.approx(0.0041, abs=1e-4)
