"""The experiment carries the set-ups, not the machine (issue 38, Build 2): ``calibrate``
takes the machine file's set-ups beside the machine, its result's ``setups`` are those with
the fitted ones in their place, ``Calibration.write`` writes them and they load back; the
machine given is not changed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pkmcal.calibration import calibrate
from pkmcal.instruments.setups import Setups
from pkmcal.instruments.simulate import simulate_scenario
from pkmcal.io import load_machine, load_machine_file
from pkmcal.io.machine_file import bed_frame

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
#: the attributes set-ups used to live in on a machine
LEGACY = ("base_from_tracker", "tracker_targets", "ballbar_setups", "probe_bed", "bed_surface",
          "measurement_frames")
#: instrument -> (machine file, rows simulated)
CASES = {"tracker": ("hexaslide_default.yaml", 40), "distance": ("hexaslide_default.yaml", 90),
         "pose": ("cubic_6upu.yaml", 40), "probe": ("linear_delta.yaml", 40)}


def _numbers(setup) -> list[np.ndarray]:
    """Every number of a set-up (its fields, flattened), for comparisons with a tolerance."""
    out = []

    def walk(value):
        if value is None:
            return
        if isinstance(value, (tuple, list)):
            for v in value:
                walk(v)
        elif hasattr(value, "__dataclass_fields__"):
            for f in value.__dataclass_fields__:
                walk(getattr(value, f))
        else:
            out.append(np.asarray(value, float))

    walk(setup)
    return out


def _assert_same(a: Setups, b: Setups):
    assert set(a) == set(b)
    for name in a:
        assert type(a[name]) is type(b[name])
        x, y = _numbers(a[name]), _numbers(b[name])
        assert len(x) == len(y), name
        for u, v in zip(x, y, strict=True):
            scale = max(np.abs(u).max(initial=0.0), np.abs(v).max(initial=0.0))
            np.testing.assert_allclose(u, v, rtol=1e-12, atol=1e-12 * scale)


def _simulated(machine, name, n, rng, setups, where: Path) -> Path:
    """A data file of instrument ``name`` simulated on ``machine`` (its set-ups ``setups``)."""
    from pkmcal.instruments.registry import INSTRUMENTS
    from pkmcal.io import write_measurements

    data, _, truth = simulate_scenario(machine, name, n, rng=rng, machine_setups=setups)
    path = where / f"{name}.csv"
    write_measurements(INSTRUMENTS[name], path, data, machine)
    return path, truth


@pytest.fixture(scope="module", params=list(CASES))
def calibrated(request, tmp_path_factory):
    name = request.param
    path, n = CASES[name]
    machine, setups = load_machine_file(EXAMPLES / path)
    data, _ = _simulated(machine, name, n, 3, setups, tmp_path_factory.mktemp(name))
    for attr in LEGACY:                 # a machine that holds no set-up
        if hasattr(machine, attr):
            delattr(machine, attr)
    before = dict(vars(machine))
    u = machine.u.copy()
    cal = calibrate(machine, data, setups=setups)
    return name, machine, setups, cal, before, u


def test_the_result_holds_the_fitted_setup(calibrated):
    name, machine, given, cal, _, _ = calibrated
    assert isinstance(cal.setups, Setups)
    assert set(cal.setups) == set(given) | {name}
    for other in set(given) - {name}:         # the others as given
        assert cal.setups[other] is given[other]
    assert cal.setups[name] is not given.get(name)
    # the fitted set-up is the instrument's section of the result
    section = cal.result.sections[name]
    fitted = cal.setups[name]
    if name == "tracker":
        for a, b in zip(fitted.base_from_tracker, section.registration, strict=True):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(fitted.targets, section.targets)
    elif name == "distance":
        for (p, b), (p2, b2) in zip(fitted.mountings, section.setups, strict=True):
            np.testing.assert_array_equal(p, p2)
            np.testing.assert_array_equal(b, b2)
    elif name == "pose":
        assert fitted is section.frames
    else:
        assert fitted.plane == tuple(section.bed)
    for attr in LEGACY:
        assert not hasattr(cal.calibrated, attr), attr


def test_the_machine_given_is_not_changed(calibrated):
    _, machine, _, _, before, u = calibrated
    assert set(vars(machine)) == set(before)
    for attr in LEGACY:
        assert not hasattr(machine, attr), attr
    np.testing.assert_array_equal(machine.u, u)


def test_write_writes_the_setups_and_they_load_back(calibrated, tmp_path):
    _, _, _, cal, _, _ = calibrated
    cal.write(tmp_path / "cal.yaml")
    machine, setups = load_machine_file(tmp_path / "cal.yaml")
    # a printer's file is in its bed's frame (the bed at z = 0): the set-ups moved with it
    _, expected = bed_frame(cal.calibrated, cal.setups)
    _assert_same(setups, expected)
    for attr in LEGACY:
        assert not hasattr(machine, attr), attr


def test_the_given_frames_are_used(tmp_path):
    """Full poses with --fix-frames: the frames given in ``setups`` are held (the fit reads
    the experiment's set-ups, not the machine); without them the identity is held and the
    same data do not fit."""
    machine, setups = load_machine_file(EXAMPLES / "cubic_6upu.yaml")
    data, truth = _simulated(machine, "pose", 40, 5, setups, tmp_path)
    frames = truth["setup"]
    given = calibrate(machine, data, setups={"pose": frames}, fix_frames=True)
    held = given.setups["pose"]
    for a, b in zip(_numbers(held), _numbers(frames), strict=True):
        scale = max(np.abs(a).max(initial=0.0), np.abs(b).max(initial=0.0))
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * scale)
    assert "machine file's measurement_frames" in given.report["frames"]["from"]
    identity = calibrate(machine, data, fix_frames=True)
    assert "identity" in identity.report["frames"]["from"]
    rms = [c.report["residuals"]["after_calibration"]["position_rms"]
           for c in (given, identity)]
    assert rms[0] < 0.1 * rms[1]
    assert not hasattr(machine, "measurement_frames")


def test_the_given_mountings_decide_the_setup_column(tmp_path):
    """A ballbar file without its ``setup`` column is refused when the set-ups given hold
    several mountings (the data are read with the experiment's set-ups, not the machine's
    attributes): one message naming the column and the count."""
    import csv

    from pkmcal.errors import InputError

    machine = load_machine(EXAMPLES / "hexaslide_default.yaml")
    bar, truth = _simulated(machine, "distance", 90, 1, Setups(), tmp_path)
    rows = list(csv.reader(bar.open()))
    k = rows[0].index("setup")
    with (tmp_path / "merged.csv").open("w", newline="") as f:
        csv.writer(f).writerows([r[:k] + r[k + 1:] for r in rows])
    mountings = truth["setup"]
    assert len(mountings) == 3
    with pytest.raises(InputError, match="no setup column"):
        calibrate(machine, tmp_path / "merged.csv", setups={"distance": mountings})
    # the file with its column calibrates, the mountings fitted in the given ones' place
    cal = calibrate(machine, bar, setups={"distance": mountings})
    assert len(cal.setups["distance"]) == 3 and cal.setups["distance"] is not mountings
