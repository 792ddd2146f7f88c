"""Real data: the Jugglebot six-leg platform (shared/data/jugglebot, see its README).

Calibrate the design geometry (examples/jugglebot.yaml) on the 108 calibration poses and
validate on the 60 poses recorded separately (a day apart). "Before" is the design geometry
with the measurement frames fitted alone (the motion-capture frame is not the design base
frame), "after" the calibrated legs with their frames. Held out, the frames are either carried
over from the calibration session or re-registered on the held-out session (a fit of the 12
frame parameters only, legs fixed, for both models alike): the data show that the frames
moved between the sessions (the measurement frame by about 0.25 deg and 3 mm), so the second
is the fair test of the legs.

Measured (calibrate_full_pose with the plain model, noise priors readings 0.1 mm, position
0.3 mm, orientation 1.3 mrad; ml estimates the levels from the residuals):

====================================  ================  ================
RMS                                   ik: before/after  ml: before/after
====================================  ================  ================
calibration set, leg length (mm)      1.83 -> 0.41      1.83 -> 0.41
calibration set, position (mm)        4.84 -> 0.95      4.83 -> 0.95
calibration set, orientation (deg)    0.82 -> 0.17      0.81 -> 0.17
held out, frames carried, leg (mm)    1.49 -> 0.98      1.49 -> 0.98
held out, frames carried, pos. (mm)   3.61 -> 1.97      3.61 -> 1.97
held out, re-registered, leg (mm)     1.23 -> 0.32      1.23 -> 0.32
held out, re-registered, pos. (mm)    2.91 -> 0.67      2.78 -> 0.67
held out, re-registered, ori. (deg)   0.51 -> 0.13      0.52 -> 0.13
====================================  ================  ================

The command line's default adds the legs' reading curvature, adopted by cross-validation
(:func:`test_default_is_as_good_as_ik_on_the_held_out_session`: held out, re-registered,
0.313 mm / 0.582 mm / 0.132 deg).

The data files' own column names are converted here (they are not part of the CLI contract).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from clitools import run
from pkmcal.calibration import calibrate_full_pose, full_pose_errors
from pkmcal.instruments.pose import FullPoseNoise
from pkmcal.io import load_machine, load_machine_file, read_full_pose

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "jugglebot"
MACHINE = Path(__file__).resolve().parents[1] / "examples" / "jugglebot.yaml"
FILES = {"calibration": "calibration_108_poses.csv", "validation": "validation_60_poses.csv"}

pytestmark = pytest.mark.skipif(
    not all((DATA / f).is_file() for f in FILES.values()),
    reason=f"the Jugglebot measurements are not at {DATA} (../shared/data/jugglebot)")

#: of the order of the residuals of a first fit (leg length, position, orientation)
NOISE = FullPoseNoise(0.1e-3, 0.3e-3, 1.3e-3)


def convert(source: Path, target: Path) -> Path:
    """The data file's columns (leg_length_1..6 in rev, position_x/y/z in mm, orientation_x/y/
    z/w) as pkmcal full-pose columns (q1_rev..q6_rev, x_mm, y_mm, z_mm, qx, qy, qz, qw)."""
    with open(source, newline="") as f:
        rows = list(csv.DictReader(f))
    with open(target, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow([f"q{i}_rev" for i in range(1, 7)] + ["x_mm", "y_mm", "z_mm", "qx",
                                                               "qy", "qz", "qw"])
        for r in rows:
            writer.writerow([r[f"leg_length_{i}"] for i in range(1, 7)]
                            + [r[f"position_{c}"] for c in "xyz"]
                            + [r[f"orientation_{c}"] for c in "xyzw"])
    return target


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("jugglebot")
    return {k: convert(DATA / v, d / f"{k}.csv") for k, v in FILES.items()}


@pytest.fixture(scope="module")
def design():
    return load_machine(MACHINE)


@pytest.fixture(scope="module")
def data(files, design):
    return {k: read_full_pose(v, design) for k, v in files.items()}


def figures(design, data, method):
    """Before/after figures (mm, deg) on both sets; see the module docstring."""
    cal, val = data["calibration"], data["validation"]
    result = calibrate_full_pose(design, cal, method=method, noise=NOISE)
    before = calibrate_full_pose(design, cal, method=method, noise=NOISE, fit_machine=False)
    model, frames = result.machine, result.sections["pose"].frames

    def summary(machine, f, d):
        s = full_pose_errors(machine, f, d).summary()
        assert s["fk_failed"] == 0
        return {"leg": s["leg_length_rms"] * 1e3, "position": s["position_rms"] * 1e3,
                "orientation": float(np.degrees(s["orientation_rms"]))}

    def reregistered(machine, f):
        fit = calibrate_full_pose(machine, val, method=method, noise=NOISE, frames=f,
                                  fit_machine=False)
        return summary(machine, fit.sections["pose"].frames, val)

    out = {
        "calibration": (summary(design, before.sections["pose"].frames, cal),
                        summary(model, frames, cal)),
        "held out, frames carried": (summary(design, before.sections["pose"].frames, val),
                                     summary(model, frames, val)),
        "held out, frames re-registered": (reregistered(design, before.sections["pose"].frames),
                                           reregistered(model, frames)),
    }
    print(f"\nJugglebot, method {method} (before = design legs, after = calibrated):")
    for name, (b, a) in out.items():
        print(f"  {name:32s} leg-length RMS {b['leg']:.3f} -> {a['leg']:.3f} mm, position "
              f"{b['position']:.3f} -> {a['position']:.3f} mm, orientation "
              f"{b['orientation']:.3f} -> {a['orientation']:.3f} deg")
    return result, out


@pytest.mark.parametrize("method", ["ik", "ml"])
def test_calibration_improves_the_held_out_poses(design, data, method):
    result, out = figures(design, data, method)
    assert result.success
    assert (result.rank, int(result.parameters.free.sum())) == (48, 60)
    assert {d.name: d.dimension for d in result.unidentifiable} == {
        "rigid motion of the base frame": 6, "rigid motion of the platform frame": 6}
    b, a = out["calibration"]
    assert a["leg"] < 0.6 and a["leg"] < 0.3 * b["leg"]
    assert a["position"] < 0.25 * b["position"]
    # held out, with the calibration session's frames
    b, a = out["held out, frames carried"]
    assert a["leg"] < 0.75 * b["leg"] and a["position"] < 0.75 * b["position"]
    # held out, frames re-registered for both models: the legs explain new poses to ~0.4 mm
    b, a = out["held out, frames re-registered"]
    assert a["leg"] < 0.45 and a["leg"] < 0.35 * b["leg"]
    assert a["position"] < 0.35 * b["position"]
    assert a["orientation"] < 0.35 * b["orientation"]


def test_identified_gains_match_the_other_legs(design, data):
    """The README's measured gain of leg 1 (13.21 rev/mm x 1e-3) stands out from the other
    five (13.8-14.2); calibration brings it in line (about 71.4 mm/rev, 14.0 rev/m x 1e-3)."""
    result = calibrate_full_pose(design, data["calibration"], method="ik", noise=NOISE)
    gains = result.machine.legs()[3] * 1e3                  # mm/rev
    assert abs(design.legs()[3][0] * 1e3 - 75.69) < 0.01
    assert np.all(np.abs(gains - 71.3) < 0.6), gains


def test_command_line_calibration_of_the_real_data(files, tmp_path):
    proc = run("calibrate", MACHINE, files["calibration"], "--method", "ik", "--noise",
               "0.1mm", "-o", "jugglebot_calibrated.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    # the legs' reading curvature predicts held-out poses better: adopted (6 more parameters)
    assert "54 of 66" in proc.stdout and "leg-length RMS" in proc.stdout
    assert "reading curvature: adopted" in proc.stdout
    report = json.loads((tmp_path / "jugglebot_calibrated.json").read_text())
    assert report["model_extensions"]["adopted"] == ["reading curvature"]
    res = report["residuals"]
    assert report["reading_unit"] == "rev" and report["measurements"] == 108
    assert res["after_calibration"]["leg_length_rms"] < 0.3 * res["before_calibration"][
        "leg_length_rms"]
    gains = [p for p in report["parameters"] if p["name"].endswith(".gain")]
    assert gains[0]["unit"] == "mm/rev" and abs(gains[0]["nominal"] - 75.69) < 0.01
    curvature = [p for p in report["parameters"] if p["name"].endswith(".curvature")]
    assert len(curvature) == 6 and curvature[0]["unit"] == "mm/rev^2"
    calibrated, setups = load_machine_file(tmp_path / "jugglebot_calibrated.yaml")
    assert calibrated.reading_unit == "rev" and setups.get("pose") is not None
    assert np.allclose(calibrated.curvature() * 1e3, [c["identified"] for c in curvature])
    # the calibrated file predicts the held-out session through fk
    proc = run("fk", tmp_path / "jugglebot_calibrated.yaml", files["validation"], "-o",
               "fk.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr


# -- the default options against --method ik on the held-out session (issue 16) ---------------

#: the data files' columns named for pkmcal (``--columns``)
COLUMNS = ",".join([f"q{i}_rev=leg_length_{i}" for i in range(1, 7)]
                   + [f"{c}_mm=position_{c}" for c in "xyz"]
                   + [f"q{c}=orientation_{c}" for c in "xyzw"])
#: the command lines compared: the default, --method ik, and both without model extensions
RUNS = {"default": [], "ik": ["--method", "ik"], "default, plain model": ["--extensions", "none"],
        "ik, plain model": ["--method", "ik", "--extensions", "none"]}


@pytest.fixture(scope="module")
def command_line_models(tmp_path_factory):
    """``pkmcal calibrate examples/jugglebot.yaml <calibration file> --columns ...`` with the
    options of :data:`RUNS`: the calibrated machines and their reports."""
    d = tmp_path_factory.mktemp("jugglebot_cli")
    out = {}
    for i, (name, options) in enumerate(RUNS.items()):
        proc = run("calibrate", MACHINE, DATA / FILES["calibration"], "--columns", COLUMNS,
                   *options, "-o", f"run{i}.yaml", cwd=d)
        assert proc.returncode == 0, proc.stderr
        out[name] = (load_machine_file(d / f"run{i}.yaml"),
                     json.loads((d / f"run{i}.json").read_text()))
    return out


def held_out_errors(machine_and_setups, method, val):
    """Squared errors per held-out pose (leg lengths averaged over the legs, mm^2; position,
    mm^2; orientation, deg^2), the frames re-registered on the held-out session by the
    model's own method (legs fixed), as :func:`figures` does."""
    machine, setups = machine_and_setups
    fit = calibrate_full_pose(machine, val, method=method, noise=NOISE,
                              frames=setups["pose"], fit_machine=False)
    e = full_pose_errors(machine, fit.sections["pose"].frames, val)
    assert e.converged.all()
    return np.column_stack([np.mean((e.leg_length * 1e3) ** 2, axis=1),
                            (e.position * 1e3) ** 2, np.degrees(e.orientation) ** 2])


def rms_ratio(a, b, resamples=2000):
    """RMS of ``a`` over RMS of ``b`` per quantity, and its bootstrap standard deviation over
    the held-out poses (paired: the same poses for both)."""
    idx = np.random.default_rng(0).integers(0, len(a), (resamples, len(a)))
    boot = np.sqrt(a[idx].mean(axis=1) / b[idx].mean(axis=1))
    return np.sqrt(a.mean(axis=0) / b.mean(axis=0)), boot.std(axis=0)


def test_default_is_as_good_as_ik_on_the_held_out_session(command_line_models, data):
    """Issue 16's done-when: with default options (ml, noise levels estimated, model
    extensions by cross-validation) the calibrated legs explain the held-out session at least
    as well as ``--method ik``, within the resolution of its 60 poses (two bootstrap standard
    deviations of the RMS ratio).

    Measured (RMS, frames re-registered; legs mm, position mm, orientation deg):

    ========================  =====  ========  ===========
    options                   legs   position  orientation
    ========================  =====  ========  ===========
    default                   0.313  0.582     0.132
    --method ik               0.313  0.584     0.132
    --extensions none         0.322  0.672     0.129
    --method ik, plain model  0.322  0.666     0.129
    ========================  =====  ========  ===========

    Both methods adopt the reading curvature (5-fold cross-validation: held-out loss per
    pose 3.63 vs 6.84 for ml, 8 standard errors; ik likewise). The models agree within 0.3 %
    once the frames are re-registered alike: the gap the issue measured (ml 7 % worse) came
    from the fixed default noise levels (readings 2 um, poses 20 um / 50 urad), not from the
    method.
    """
    val = data["validation"]
    errors, reports = {}, {}
    for name, (machine, report) in command_line_models.items():
        errors[name] = held_out_errors(machine, report["method"], val)
        reports[name] = report
    print("\nJugglebot held-out session, frames re-registered (RMS legs mm, position mm, "
          "orientation deg):")
    for name, e in errors.items():
        rms = np.sqrt(e.mean(axis=0))
        print(f"  {name:22s} {rms[0]:.3f} {rms[1]:.3f} {rms[2]:.3f}  extensions "
              f"{reports[name]['model_extensions']['adopted']}")
    ext = reports["default"]["model_extensions"]
    assert reports["default"]["method"] == "ml" and ext["adopted"] == ["reading curvature"]
    trial = ext["trials"][0]
    assert trial["cv_gain"] > 2 * trial["cv_se"] and trial["cv_loss"] < trial["cv_loss_baseline"]
    print(f"  cross-validation (ml): held-out loss {trial['cv_loss']:.3f} vs "
          f"{trial['cv_loss_baseline']:.3f} per pose, gain {trial['cv_gain']:.3f} +- "
          f"{trial['cv_se']:.3f}")
    for other in ("ik", "ik, plain model"):
        ratio, sd = rms_ratio(errors["default"], errors[other])
        print(f"  default / {other}: {np.round(ratio, 4)} (bootstrap sd {np.round(sd, 4)})")
        assert np.all(ratio <= 1 + 2 * sd), (other, ratio, sd)
    # the model adequacy checks name the legs' curvature before it is adopted ...
    adequacy = reports["default, plain model"]["model_adequacy"]
    top = adequacy["trends"][0]
    assert adequacy["far_above_noise"] and top["shape"] == "quadratic"
    assert top["residual"].startswith("leg readings") and top["against"].startswith("reading")
    # ... and find no significant trend left once it is
    assert reports["default"]["model_adequacy"]["significant_trends"] == 0
