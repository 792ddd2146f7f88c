"""A controller's saved files holding measurements reach ``calibrate`` through its format's
hook (``ControllerFormat.holds_measurements`` / ``read_measurements``): the calibration layer
names no firmware, a new format is one class."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from pkmcal.calibration.firmware_data import expand_firmware_data
from pkmcal.export.base import FORMATS, ControllerFormat, load_formats


class _Toy(ControllerFormat):
    """A controller whose ``.toy`` files each hold two measurements; several are read
    together when ``together``."""

    name = "toy"

    def __init__(self, together: bool):
        self.measurements_together = together
        self.calls = []

    def holds_measurements(self, path, head):
        return str(path).endswith(".toy") and head.startswith("TOY")

    def read_measurements(self, paths, machine):
        self.calls.append([str(p) for p in paths])
        return [SimpleNamespace(source=f"{p}: point {k}") for p in paths for k in (1, 2)]

    # what a controller format must have, unused here
    def initial(self, machine):
        raise NotImplementedError

    def ik(self, params, P, R=None):
        raise NotImplementedError

    def text(self, params, machine):
        raise NotImplementedError

    def parse(self, text, source):
        raise NotImplementedError

    def to_machine(self, params, like=None):
        raise NotImplementedError


@pytest.fixture
def files(tmp_path):
    (tmp_path / "a.toy").write_text("TOY 1\n")
    (tmp_path / "b.toy").write_text("TOY 2\n")
    (tmp_path / "c.toy").write_text("not this controller's\n")     # its suffix, not its text
    (tmp_path / "d.csv").write_text("x,y,z\n")
    return tmp_path


@pytest.mark.parametrize("together", [False, True])
def test_a_registered_format_claims_its_files_in_their_place(files, monkeypatch, together):
    load_formats()
    toy = _Toy(together)
    monkeypatch.setitem(FORMATS, "toy", toy)
    given = [files / "d.csv", files / "a.toy", files / "c.toy", files / "b.toy"]
    out = expand_firmware_data(given, machine=None)
    names = [o if not hasattr(o, "origin") else o.source for o in out]
    a, b = str(files / "a.toy"), str(files / "b.toy")
    if together:        # read once, all in the first one's place
        assert toy.calls == [[a, b]]
        assert names == [files / "d.csv", f"{a}: point 1", f"{a}: point 2",
                         f"{b}: point 1", f"{b}: point 2", files / "c.toy"]
    else:               # each file in its own place
        assert toy.calls == [[a], [b]]
        assert names == [files / "d.csv", f"{a}: point 1", f"{a}: point 2", files / "c.toy",
                         f"{b}: point 1", f"{b}: point 2"]
    # each measurement names the file the user gave (--noise FILE=VALUE)
    assert [str(o.origin) for o in out if hasattr(o, "origin")] == [a, a, b, b]


def test_nothing_claimed_returns_what_was_given(files, monkeypatch):
    load_formats()
    monkeypatch.setitem(FORMATS, "toy", _Toy(True))
    given = [files / "d.csv", files / "c.toy"]
    assert expand_firmware_data(given, machine=None) is given
    one = files / "c.toy"
    assert expand_firmware_data(one, machine=None) is one


def test_one_file_giving_one_measurement_is_that_measurement(files, monkeypatch):
    load_formats()
    toy = _Toy(False)
    toy.read_measurements = lambda paths, machine: [SimpleNamespace(source=str(paths[0]))]
    monkeypatch.setitem(FORMATS, "toy", toy)
    out = expand_firmware_data(files / "a.toy", machine=None)
    assert isinstance(out, SimpleNamespace) and out.origin == files / "a.toy"


def test_the_calibration_layer_names_no_controller():
    """No import, name or string of the code (docstrings aside) names a controller or its
    reader: formats come from the registry."""
    import ast
    from pathlib import Path

    import pkmcal.calibration.firmware_data as mod

    tree = ast.parse(Path(mod.__file__).read_text())
    docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                  if isinstance(n, (ast.Module, ast.FunctionDef, ast.ClassDef)) and n.body
                  and isinstance(n.body[0], ast.Expr)
                  and isinstance(n.body[0].value, ast.Constant)}
    words = []
    for n in ast.walk(tree):
        if isinstance(n, ast.ImportFrom):
            words += [n.module or ""] + [a.name for a in n.names]
        elif isinstance(n, ast.Import):
            words += [a.name for a in n.names]
        elif isinstance(n, ast.Name):
            words.append(n.id)
        elif isinstance(n, ast.Attribute):
            words.append(n.attr)
        elif isinstance(n, ast.Constant) and isinstance(n.value, str) \
                and id(n) not in docstrings:
            words.append(n.value)
    controllers = [*load_formats(), "klipper", "marlin", "probe_report", "rrf"]
    named = [w for w in words for c in controllers if c.lower() in w.lower()]
    assert named == []
    assert "load_formats" in words          # the registry is where the formats come from
