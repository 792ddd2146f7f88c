"""Machine files carry what an instrument's calibration fitted (issue 13): ``tracker`` (with
optional ``targets``), ``ballbar`` and ``measurement_frames`` on every machine type that can
have them; strict schemas naming the key, the file's length unit, exact round trips and the
plausibility checks of the new lengths."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, run
from pkmcal.errors import InputError
from pkmcal.instruments.distance import BallbarSetup
from pkmcal.instruments.pose import MeasurementFrames
from pkmcal.instruments.setups import Setups
from pkmcal.instruments.tracker import TrackerSetup
from pkmcal.io import (
    load_machine,
    load_machine_file,
    parse_machine,
    parse_machine_file,
    save_machine,
)
from pkmcal.io.machine_file import machine_to_text
from pkmcal.kinematics import matrix_from_rotvec

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
FILES = {"hexaslide": EXAMPLES / "hexaslide_default.yaml",
         "delta": EXAMPLES / "delta_default.yaml",
         "stewart": EXAMPLES / "cubic_6upu.yaml"}


def fitted(kind: str, seed: int = 1):
    """An example machine and every instrument set-up its type can have."""
    m = load_machine(FILES[kind])
    rng = np.random.default_rng(seed)
    pose = (matrix_from_rotvec(rng.normal(size=3)),
            np.array([2.1, -1.4, 0.3]) + rng.normal(size=3) * 0.1)
    items = {}
    if kind != "delta":
        items["tracker"] = TrackerSetup(pose, rng.normal(size=(3, 3)) * 0.05)
        items["pose"] = MeasurementFrames(
            (matrix_from_rotvec(rng.normal(size=3)), rng.normal(size=3)),
            (matrix_from_rotvec(rng.normal(size=3) * 0.3), rng.normal(size=3) * 0.05))
    else:
        items["tracker"] = TrackerSetup(pose)
    items["distance"] = BallbarSetup([(m.home[0] + rng.normal(size=3) * 0.1,
                                       rng.normal(size=3) * 0.03) for _ in range(2)])
    return m, Setups(items)


def sections(m, setups) -> list[np.ndarray]:
    """Every number of the instrument sections, SI units."""
    out = [np.asarray(v, float) for v in setups["tracker"].base_from_tracker]
    out += [np.asarray(v, float) for s in setups["distance"].mountings for v in s]
    if m.kind != "delta":
        out.append(np.asarray(setups["tracker"].targets, float))
        f = setups["pose"]
        out += [np.asarray(v, float) for v in (*f.mocap_from_base, *f.platform_from_marker)]
    return out


@pytest.mark.parametrize("kind", list(FILES))
@pytest.mark.parametrize("units", [None, {"length": "m", "angle": "rad"},
                                   {"length": "in", "angle": "deg"}])
def test_round_trip(kind, units):
    m, setups = fitted(kind)
    text = machine_to_text(m, units, setups=setups)
    back, again = parse_machine_file(text, "m.yaml")
    for a, b in zip(sections(m, setups), sections(back, again), strict=True):
        if units and units["length"] == "m":
            assert np.array_equal(a, b)             # metres: nothing to convert
        else:
            np.testing.assert_allclose(b, a, rtol=1e-15, atol=1e-17)
    assert machine_to_text(back, units, setups=again) == text   # a fixed point after one round
    if kind == "delta":
        assert again["tracker"].targets is None and again.get("pose") is None
        assert "targets" not in text and "measurement_frames" not in text
    else:
        assert again["tracker"].targets.shape == (3, 3)


@pytest.mark.parametrize("kind", list(FILES))
def test_sections_are_optional_and_in_the_file_unit(kind, tmp_path):
    plain, setups = load_machine_file(FILES[kind])
    assert setups.get("distance") is None
    if kind != "delta":
        assert setups.get("tracker") is None and setups.get("pose") is None
    else:
        assert getattr(setups.get("tracker"), "targets", None) is None
    assert "ballbar" not in machine_to_text(plain, setups=setups)
    head = FILES[kind].read_text()
    text = head + ("ballbar:\n  - {pivot: [10, 20, 30], ball: [1, 2, 3]}\n"
                   "  - {pivot: [-10, 0, 5], ball: [0, 0, 0]}\n")
    m, setups = parse_machine_file(text, "m.yaml")
    np.testing.assert_allclose(setups["distance"].mountings[0][0], [0.01, 0.02, 0.03],
                               rtol=1e-15)
    np.testing.assert_allclose(setups["distance"].mountings[1][1], [0, 0, 0])
    if kind != "delta":
        text = head + ("tracker: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "
                       "translation: [1000, 0, 0], targets: [[10, 0, -5]]}\n")
        m, setups = parse_machine_file(text, "m.yaml")
        np.testing.assert_allclose(setups["tracker"].base_from_tracker[1], [1, 0, 0])
        np.testing.assert_allclose(setups["tracker"].targets, [[0.01, 0, -0.005]])
    m, setups = fitted(kind)
    save_machine(m, tmp_path / "f.yaml", setups=setups)
    assert load_machine_file(tmp_path / "f.yaml")[1].get("distance") is not None


def refused(text: str) -> str:
    with pytest.raises(InputError) as info:
        parse_machine(text, "m.yaml")
    return str(info.value)


@pytest.mark.parametrize("kind", list(FILES))
def test_strict_schemas_name_the_key(kind):
    head = FILES[kind].read_text()
    msg = refused(head + "ballbar:\n  - {pivot: [1, 2, 3], ball: [0, 0, 0], radius: 3}\n")
    assert "ballbar[0].radius: unknown key (allowed here: pivot, ball)" in msg
    msg = refused(head + "ballbar:\n  - {pivot: [1, 2], ball: [0, 0, 0]}\n")
    assert "ballbar[0].pivot: expected 3 numbers, got 2" in msg
    msg = refused(head + "ballbar:\n  - {pivot: [1, 2, 3]}\n")
    assert "ballbar[0].ball: missing key" in msg
    msg = refused(head + "ballbar: []\n")
    assert "ballbar: expected at least one entry" in msg
    msg = refused(head + "ballbar: 3\n")
    assert "ballbar: expected a list of mountings" in msg
    msg = refused(head + "ballbar:\n  - {pivot: [1, 'a', 3], ball: [0, 0, 0]}\n")
    assert "ballbar[0].pivot[1]: not a number" in msg
    msg = refused(head + "ballbar:\n  - {pivot: [1.0e9, 0, 0], ball: [0, 0, 0]}\n")
    assert "ballbar[0].pivot[0]:" in msg and "not a plausible length" in msg
    msg = refused(head + "ballbar:\n  - {pivot: [0, 0, 0], ball: [0, 0, .inf]}\n")
    assert "ballbar[0].ball[2]: must be a finite number" in msg
    rot = "rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]"
    if kind == "delta":
        # the Delta's target is its smr_offset: no targets key
        assert "tracker:" not in head
        msg = refused(head + f"tracker: {{{rot}, translation: [0, 0, 0], targets: [[0, 0, 0]]}}\n")
        assert "tracker.targets: unknown key (allowed here: rotation, translation)" in msg
        msg = refused(head + f"measurement_frames: {{mocap_from_base: {{{rot}, translation: "
                             "[0, 0, 0]}}\n")
        assert "measurement_frames: unknown key" in msg
        return
    msg = refused(head + f"tracker: {{{rot}, translation: [0, 0, 0], targets: [[0, 0]]}}\n")
    assert "tracker.targets[0]: expected 3 numbers, got 2" in msg
    msg = refused(head + f"tracker: {{{rot}, translation: [0, 0, 0], targets: []}}\n")
    assert "tracker.targets: expected at least one entry" in msg
    msg = refused(head + f"tracker: {{{rot}, translation: [0, 0, 0], targets: 5}}\n")
    assert "tracker.targets: expected a list of target places" in msg
    msg = refused(head + f"tracker: {{{rot}, translation: [0, 0, 0], target: [[0, 0, 0]]}}\n")
    assert "tracker.target: unknown key (allowed here: rotation, translation, targets)" in msg
    msg = refused(head + f"tracker: {{{rot}, translation: [0, 0, 0], "
                         "targets: [[0, 0, 1.0e12]]}\n")
    assert "tracker.targets[0][2]:" in msg and "not a plausible length" in msg
    msg = refused(head + "tracker: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 2]], "
                         "translation: [0, 0, 0]}\n")
    assert "tracker.rotation: not a rotation matrix" in msg
    msg = refused(head + f"tracker: {{{rot}, translation: [1.0e12, 0, 0]}}\n")
    assert "tracker.translation[0]:" in msg and "not a plausible length" in msg
    frame = f"{{{rot}, translation: [0, 0, 0]}}"
    msg = refused(head + f"measurement_frames: {{mocap_from_base: {frame}}}\n")
    assert "measurement_frames.platform_from_marker: missing key" in msg
    msg = refused(head + f"measurement_frames: {{mocap_from_base: {frame}, platform_from_marker: "
                         f"{{{rot}, translation: [0, 0, 1.0e12]}}}}\n")
    assert "measurement_frames.platform_from_marker.translation[2]:" in msg
    assert "not a plausible length" in msg


def test_delta_targets_other_than_its_reflector_are_not_saved():
    m, setups = fitted("delta")
    pose = setups["tracker"].base_from_tracker
    reflector = setups.with_setup("tracker", TrackerSetup(pose, np.array([[0.0, 0.0,
                                                                          -m.smr_offset]])))
    assert "targets" not in machine_to_text(m, setups=reflector)   # the reflector: harmless
    other = setups.with_setup("tracker", TrackerSetup(pose, np.array([[0.01, 0.0, 0.0]])))
    with pytest.raises(InputError, match="smr_offset"):
        machine_to_text(m, setups=other)


def test_command_line_refuses_a_bad_section(tmp_path):
    (tmp_path / "m.yaml").write_text(FILES["hexaslide"].read_text()
                                     + "ballbar:\n  - {pivot: [1, 2, 3], bal: [0, 0, 0]}\n")
    (tmp_path / "j.csv").write_text("q1_mm,q2_mm,q3_mm,q4_mm,q5_mm,q6_mm\n1,2,3,4,5,6\n")
    proc = run("fk", "m.yaml", "j.csv", "--frame", "instrument", "-o", "o.csv", cwd=tmp_path)
    assert_input_error(proc, "m.yaml", "ballbar[0].bal: unknown key", "line")
    assert not (tmp_path / "o.csv").exists()
