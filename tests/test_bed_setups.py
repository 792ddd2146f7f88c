"""A printer's bed is a set-up of the experiment, not an attribute of its machine (issue 38).

The bed (:class:`~pkmcal.instruments.probe.BedSetup`: the plane ``z = height + tilt_x x +
tilt_y y`` and its own shape) reaches the code that reads it as an argument: the machines'
``bed=`` (the plane, :meth:`~pkmcal.machines.Machine.reachability`, ``print_workspace``), the
firmware formats' ``setups=``, and an import's :meth:`~pkmcal.export.base.ControllerFormat.
imported_setups`. Checked here: the export of a machine file with a tilted, shaped bed writes
the same bytes when the machine carries a different bed of its own (nothing reads one), and
not the same without the bed section (the bed is used); an import writes the bed its values
state; a printer's workspace lies on the bed it is given.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pkmcal.export import controller_format
from pkmcal.instruments.probe import BedSetup, bed_of, bed_plane
from pkmcal.instruments.setups import Setups
from pkmcal.io import load_machine, load_machine_file
from pkmcal.workflows import export as export_workflow

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
#: a tilted bed with a shape of its own (mm, the machine file's unit)
BED = ("bed: {height: 0.0, tilt_x: 0.002, tilt_y: -0.001, surface: {radius: 100.0, values: "
       "[[0.0, 0.01, 0.0], [0.01, 0.02, -0.01], [0.0, 0.0, 0.01]]}}\n")
#: a Klipper config that takes a bed mesh (the export saves into it)
CONFIG = ("[printer]\nkinematics: delta\ndelta_radius: 132.5\n[stepper_a]\narm_length: 250\n"
          "position_endstop: 285\n[stepper_b]\n[stepper_c]\n[bed_mesh]\nmesh_radius: 80\n")
FORMATS = ("klipper", "marlin", "reprapfirmware", "linuxcnc-lineardelta")


def _printer(directory: Path, bed: bool = True) -> Path:
    path = directory / "printer.yaml"
    text = (EXAMPLES / "linear_delta.yaml").read_text()
    path.write_text(text + (BED if bed else ""))
    return path


def _exports(directory: Path, bed: bool = True) -> dict:
    """Every printer format's export of the example printer (with the bed section or
    without), Klipper's saved into a config with a [bed_mesh]: file name -> text (the
    directory's name taken out; the dated backup left out)."""
    directory.mkdir()
    machine = _printer(directory, bed)
    (directory / "printer.cfg").write_text(CONFIG)
    for name in FORMATS:
        out = directory / ("printer.cfg" if name == "klipper" else f"{name}.out")
        export_workflow.run_export(str(machine), name, out)
    return {p.name: p.read_text().replace(str(directory), "DIR")
            for p in sorted(directory.iterdir()) if "-20" not in p.name}


def test_the_exports_read_the_bed_from_the_set_ups_not_from_the_machine(tmp_path,
                                                                         monkeypatch):
    """The machine handed to the export carries a different bed of its own (the attributes
    older code read): the files are byte for byte those of the plain machine; without the
    bed section they differ (the bed is read from the set-ups)."""
    plain = _exports(tmp_path / "plain")
    loader = export_workflow.load_machine_setups_arg

    def decoy(spec):
        machine, setups = loader(spec)
        machine.probe_bed = (0.003, -0.004, 0.005)          # what nothing may read
        machine.bed_surface = None
        return machine, setups

    monkeypatch.setattr(export_workflow, "load_machine_setups_arg", decoy)
    assert _exports(tmp_path / "decoy") == plain
    monkeypatch.undo()
    flat = _exports(tmp_path / "flat", bed=False)
    for name in ("printer.cfg", "marlin.out", "reprapfirmware.out", "linuxcnc-lineardelta.out"):
        assert flat[name] != plain[name], name
    # the bed is in what was written: its comment, Klipper's mesh, LinuxCNC's note
    assert "; pkmcal bed: height=0.000000 tilt_x=0.002 tilt_y=-0.001" in plain["marlin.out"]
    assert "[bed_mesh pkmcal]" in plain["printer.cfg"]
    assert "dz/dx 0.002, dz/dy -0.001" in plain["linuxcnc-lineardelta.out"]


def test_an_import_writes_the_bed_its_values_state(tmp_path):
    """RepRapFirmware's M666 A, B are the bed's slopes: the imported machine holds none, its
    machine file's bed section has them; a Klipper export's bed is folded in (none)."""
    machine = _printer(tmp_path)
    export_workflow.run_export(str(machine), "reprapfirmware", tmp_path / "config.g")
    export_workflow.run_import(tmp_path / "config.g", "reprapfirmware", tmp_path / "rrf.yaml")
    imported, setups = load_machine_file(tmp_path / "rrf.yaml")
    fmt = controller_format("reprapfirmware")
    values = fmt.parse((tmp_path / "config.g").read_text(), "config.g").as_dict()
    assert bed_plane(setups) == pytest.approx((0.0, values["x_tilt"], values["y_tilt"]),
                                              rel=1e-12, abs=1e-15)
    assert abs(values["x_tilt"]) > 1e-4                     # the tilt, not nothing
    back = fmt.to_machine(fmt.parse((tmp_path / "config.g").read_text(), "config.g"))
    assert not hasattr(back, "probe_bed") and not hasattr(back, "bed_surface")
    export_workflow.run_export(str(machine), "klipper", tmp_path / "k.cfg")
    export_workflow.run_import(tmp_path / "k.cfg", "klipper", tmp_path / "k.yaml")
    assert bed_of(load_machine_file(tmp_path / "k.yaml")[1]) is None
    assert "bed:" not in (tmp_path / "k.yaml").read_text()


def test_a_printers_workspace_lies_on_the_bed_it_is_given():
    """The print disk lies on the tilted plane given as ``bed=``, the volume above it, every
    point within the printer's limits over that bed; without a bed, on z = 0."""
    m = load_machine(EXAMPLES / "linear_delta.yaml")
    plane = (0.0, 0.002, -0.001)
    ws = m.print_workspace(rng=0, bed=plane)
    P = ws.P
    above = P[:, 2] - (plane[0] + plane[1] * P[:, 0] + plane[2] * P[:, 1])
    scale = np.abs(P).max()
    assert ws.surface.sum() > 100 and (~ws.surface).sum() > 100
    np.testing.assert_allclose(above[ws.surface], 0.0, atol=1e-12 * scale)
    assert np.all(above[~ws.surface] >= -1e-12 * scale)
    assert above.max() > 0.5 * m.PRINT_HEIGHT
    assert m.within_physical_limits(P, None, bed=plane).all()
    assert m.reachability(P, bed=plane).ok.all()
    # the same draw without a bed: on z = 0, and the tilted disk's low side below it
    flat = m.print_workspace(rng=0)
    np.testing.assert_allclose(flat.P[flat.surface, 2], 0.0, atol=1e-12 * scale)
    low = ws.surface & (above <= 1e-12 * scale) & (P[:, 2] < -1e-5)
    assert low.any() and not m.within_physical_limits(P[low], None).any()


def test_the_set_ups_bed_accessors():
    bed = BedSetup(1e-3, 2e-3, -3e-3)
    setups = Setups({"probe": bed})
    assert bed_of(setups) is bed and bed_plane(setups) == (1e-3, 2e-3, -3e-3)
    assert bed_of(Setups()) is None and bed_plane(None) is None


def _attribute_uses(tree, names) -> list:
    """Lines naming one of ``names`` as an attribute: ``x.name`` or ``getattr/setattr/
    hasattr/delattr(x, "name")``."""
    import ast

    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr in names:
            found.append(node.lineno)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ("getattr", "setattr", "hasattr", "delattr")
              and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant)
              and node.args[1].value in names):
            found.append(node.lineno)
    return found


def test_no_reader_names_the_beds_machine_attributes():
    """The machines, the exports, the outcome, the check and the workflows read the bed from
    the set-ups: no module but the transitional ones names ``probe_bed`` or ``bed_surface``
    as a machine's attribute (the audit itself sees one)."""
    import ast

    import pkmcal

    root = Path(pkmcal.__file__).parent
    names = {"probe_bed", "bed_surface"}
    found = {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        lines = _attribute_uses(ast.parse(path.read_text()), names)
        if lines:
            found[rel] = lines
    assert found == {}
    assert _attribute_uses(ast.parse("m.probe_bed = 1\ngetattr(m, 'bed_surface', None)\n"),
                           names) == [1, 2]
