"""The instruments' set-ups travel beside the machine (issue 38 item 2): each instrument
declares its set-up type and how its machine-file section reads and writes it; the loader
returns them as a :class:`~pkmcal.instruments.setups.Setups`, and writing them back gives the
same file, byte for byte."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pkmcal.instruments.registry import INSTRUMENTS
from pkmcal.instruments.setups import Setups
from pkmcal.io import load_machine_file, machine_to_text, parse_machine_file

HEXASLIDE = """\
pkmcal: 1
machine: hexaslide
units: {length: mm, angle: deg}
constraint_link: {length: 300.0}
chains:
  - {a0: [451.05, -164.17, -400.0], alpha: 160.0, beta: 70.0, b: [84.85, -84.85, 0.0], l: 450.0}
  - {a0: [-83.35, 472.69, -400.0], alpha: 280.0, beta: 70.0, b: [31.06, 115.91, 0.0], l: 450.0}
  - {a0: [-367.7, 308.52, -400.0], alpha: 280.0, beta: 70.0, b: [-115.91, -31.06, 0.0], l: 450.0}
  - {a0: [-367.7, -308.52, -400.0], alpha: 40.0, beta: 70.0, b: [-115.91, 31.06, 0.0], l: 450.0}
  - {a0: [-83.35, -472.69, -400.0], alpha: 40.0, beta: 70.0, b: [31.06, -115.91, 0.0], l: 450.0}
  - {a0: [451.05, 164.17, -400.0], alpha: 160.0, beta: 70.0, b: [84.85, 84.85, 0.0], l: 450.0}
"""

SECTIONS = """\
tracker: {rotation: [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], \
translation: [1200.0, -400.0, -300.0], targets: [[10.0, -5.0, -15.0], [0.0, 12.5, -15.0]]}
ballbar:
  - {pivot: [0.0, 0.0, 200.0], ball: [0.0, 0.0, 0.0]}
  - {pivot: [100.0, 0.0, 250.0], ball: [5.0, 0.0, 0.0]}
bed: {height: 0.5, tilt_x: -0.0004, tilt_y: 0.0}
measurement_frames:
  mocap_from_base: {rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], \
translation: [10.0, 20.0, 30.0]}
  platform_from_marker: {rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], \
translation: [0.0, 0.0, 5.0]}
"""

LEGACY = ("base_from_tracker", "tracker_targets", "ballbar_setups", "probe_bed", "bed_surface",
          "measurement_frames")


@pytest.fixture
def machine_and_setups():
    return parse_machine_file(HEXASLIDE + SECTIONS, "setups.yaml")


def test_every_instrument_with_a_section_declares_its_setup_type():
    with_section = {name for name, inst in INSTRUMENTS.items() if inst.section is not None}
    with_setup = {name for name, inst in INSTRUMENTS.items() if inst.Setup is not None}
    assert with_section == with_setup == {"tracker", "pose", "distance", "probe"}
    orders = [inst.section_order for inst in INSTRUMENTS.values() if inst.Setup is not None]
    assert len(set(orders)) == len(orders)          # one place each in the file


def test_the_loader_returns_the_setups_by_instrument(machine_and_setups):
    machine, setups = machine_and_setups
    assert isinstance(setups, Setups)
    assert set(setups) == {"tracker", "distance", "probe", "pose"}
    for name, setup in setups.items():
        assert isinstance(setup, INSTRUMENTS[name].Setup)
    R, t = setups["tracker"].base_from_tracker
    np.testing.assert_allclose(t, [1.2, -0.4, -0.3], rtol=1e-15)
    np.testing.assert_allclose(setups["tracker"].targets[1], [0.0, 0.0125, -0.015], rtol=1e-15)
    pivot, ball = setups["distance"].mountings[1]
    np.testing.assert_allclose(pivot, [0.1, 0.0, 0.25], rtol=1e-15)
    assert setups["probe"].plane == pytest.approx((0.5e-3, -0.0004, 0.0), rel=1e-15)
    np.testing.assert_allclose(setups["pose"].platform_from_marker[1], [0, 0, 0.005],
                               rtol=1e-15)


def test_setups_round_trip_byte_identical(machine_and_setups, tmp_path):
    machine, setups = machine_and_setups
    text = machine_to_text(machine, setups=setups)
    path = tmp_path / "again.yaml"
    path.write_text(text)
    machine2, setups2 = load_machine_file(path)
    assert setups2 == setups
    assert machine_to_text(machine2, setups=setups2) == text
    for key in ("tracker:", "ballbar:", "bed:", "measurement_frames:"):
        assert text.count("\n" + key) == 1
    # the sections in the file's order: tracker, ballbar, bed, measurement_frames
    where = [text.index("\n" + key) for key in ("tracker:", "ballbar:", "bed:",
                                                  "measurement_frames:")]
    assert where == sorted(where)


def test_a_machine_without_setups_writes_no_instrument_section(machine_and_setups):
    machine, _ = machine_and_setups
    text = machine_to_text(machine, setups=Setups())
    for key in ("tracker", "ballbar", "bed", "measurement_frames"):
        assert f"\n{key}:" not in text


def test_shifted_setups_move_base_points_only(machine_and_setups):
    _, setups = machine_and_setups
    t = np.array([0.01, -0.02, 0.03])
    moved = setups.shifted(t)
    np.testing.assert_allclose(moved["tracker"].base_from_tracker[1],
                               setups["tracker"].base_from_tracker[1] + t, rtol=1e-15)
    np.testing.assert_array_equal(moved["tracker"].targets, setups["tracker"].targets)
    (p0, b0), (p1, b1) = setups["distance"].mountings[0], moved["distance"].mountings[0]
    np.testing.assert_allclose(p1, p0 + t, rtol=1e-15)
    np.testing.assert_array_equal(b1, b0)
    # a base point x is measured at A x + a; moved, x + t is measured there
    x = np.array([0.1, 0.2, 0.3])
    before = setups["pose"].measured(x, np.eye(3))[0]
    after = moved["pose"].measured(x + t, np.eye(3))[0]
    np.testing.assert_allclose(after, before, rtol=1e-12)
    # the bed's plane at a point: its height moves with the frame
    xy = np.array([[0.05, -0.03]])
    np.testing.assert_allclose(moved["probe"].height_at(xy + t[:2]),
                               setups["probe"].height_at(xy) + t[2], rtol=1e-12)


def test_moved_consumers_read_the_setups_not_the_machine(machine_and_setups):
    """fk --frame instrument, compensate's instrument frames, plans and simulations take the
    set-ups given to them: with the older machine attributes removed, they still use the
    file's tracker frame and ballbar mountings (a reader of the attributes would fall back to
    the defaults and fail these comparisons)."""
    from pkmcal.compensation import instrument_frames
    from pkmcal.instruments import predict_instrument
    from pkmcal.instruments.scenarios import planned_data, standard_plan
    from pkmcal.instruments.simulate import simulate_scenario

    machine, setups = machine_and_setups
    for name in LEGACY:
        if hasattr(machine, name):
            delattr(machine, name)
    P0, R0 = machine.home
    q = machine.ik(P0 + np.array([[0.0, 0.0, 0.0], [0.01, -0.005, 0.002]]),
                   np.broadcast_to(R0, (2, 3, 3)))
    pred = predict_instrument(machine, setups, q, "tracker", np.array([0, 1]))
    R, t = setups["tracker"].base_from_tracker
    fk = machine.fk(q)
    c = setups["tracker"].targets[[0, 1]]
    expected = (fk.P + np.einsum("kij,kj->ki", fk.R, c) - t) @ R
    np.testing.assert_allclose(pred.values, expected, rtol=1e-12,
                               atol=1e-12 * np.abs(expected).max())
    frame = instrument_frames(machine, setups)["tracker"]
    np.testing.assert_array_equal(frame.targets, setups["tracker"].targets)
    # a plan on the file's two mountings (the default plans three)
    plan = standard_plan(machine, "distance", 30, setup=setups["distance"])
    assert set(plan.group.tolist()) == {0, 1}
    data = planned_data(machine, "distance", plan.P, plan.R, group=plan.group,
                        setup=setups["distance"])
    pivots = np.array([p for p, _ in setups["distance"]])[plan.group]
    balls = np.array([b for _, b in setups["distance"]])[plan.group]
    d = np.linalg.norm(plan.P + np.einsum("kij,kj->ki", plan.R, balls) - pivots, axis=-1)
    np.testing.assert_allclose(data.values[:, 0], d, rtol=1e-12)
    # a simulation's true tracker stands where the file's does; the truth file's set-ups
    # keep the file's others
    _, _, truth = simulate_scenario(machine, "tracker", 8, rng=2, machine_setups=setups,
                                    targets=2)
    np.testing.assert_array_equal(truth["setup"].base_from_tracker[1], t)
    assert set(truth["true_setups"]) == set(setups)
    assert truth["true_setups"]["distance"] is setups["distance"]


def test_io_names_no_instrument():
    """The machine-file module reads the instrument sections through the registry: no
    instrument's section, set-up type or key is named in its code (docstrings aside)."""
    import ast
    import inspect

    import pkmcal.io.machine_file as mf

    tree = ast.parse(inspect.getsource(mf))
    words = {"tracker", "ballbar", "bed", "measurement_frames", "targets", "distance",
             "probe", "pose", "TrackerSection", "Ballbar", "BedPlane", "TrackerSetup",
             "BallbarSetup", "BedSetup", "MeasurementFrames", "base_from_tracker",
             "ballbar_setups", "probe_bed", "bed_surface", "tracker_targets"}
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.FunctionDef, ast.ClassDef))
                  and node.body and isinstance(node.body[0], ast.Expr)}
    named = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and id(node) not in docstrings and node.value in words:
            named.add(node.value)
        elif isinstance(node, ast.Name) and node.id in words - {"pose"}:   # a home pose
            named.add(node.id)
        elif isinstance(node, ast.Attribute) and node.attr in words:
            named.add(node.attr)
        elif isinstance(node, ast.alias) and node.name in words:
            named.add(node.name)
    assert named == set()


def test_a_loaded_machine_holds_no_setup(machine_and_setups, tmp_path):
    """The set-ups travel beside the machine, never on it (issue 38, Build 2): the loader
    sets none of the older attributes, and a calibrated file loads back the same way."""
    machine, setups = machine_and_setups
    assert len(setups) == 4
    for name in LEGACY:
        assert not hasattr(machine, name), name
    path = tmp_path / "m.yaml"
    path.write_text(machine_to_text(machine, setups=setups))
    again, _ = load_machine_file(path)
    for name in LEGACY:
        assert not hasattr(again, name), name


def test_no_module_reads_or_writes_a_setup_on_the_machine():
    """No module of pkmcal names the older set-up attributes on an object (``x.probe_bed``,
    ``getattr(x, "bed_surface")``); ``base_from_tracker`` is the tracker set-up's own field
    and stays."""
    import ast

    import pkmcal

    root = Path(pkmcal.__file__).parent
    names = set(LEGACY) - {"base_from_tracker"}
    found = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr in names:
                found.append(f"{path.relative_to(root)}:{node.lineno}: .{node.attr}")
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) \
                    and node.func.id in ("getattr", "setattr", "hasattr", "delattr") \
                    and len(node.args) > 1 and isinstance(node.args[1], ast.Constant) \
                    and node.args[1].value in LEGACY:
                found.append(f"{path.relative_to(root)}:{node.lineno}: {node.func.id}"
                             f"({node.args[1].value!r})")
            elif isinstance(node, ast.Tuple) and any(
                    isinstance(e, ast.Constant) and e.value == "probe_bed" for e in node.elts):
                found.append(f"{path.relative_to(root)}:{node.lineno}: 'probe_bed' listed")
    assert found == [], "\n".join(found)
