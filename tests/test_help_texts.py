"""Help texts that cannot go stale (issue 26): the machine types and controller formats the
help names are the registries' (pkmcal.workflows.names reads the machine registry's list and
holds a light copy of the format names, checked here), and the
format lists of ``export --help`` / ``import --help`` are readable whole at 80 columns."""

from __future__ import annotations

import importlib
import math

import pytest

from clitools import run_in_process
from pkmcal.machines import (
    Machine,
    cubic_6upu,
    default_delta,
    default_hexaslide,
    default_linear_delta,
)
from pkmcal.machines.registry import MACHINE_MODULES, machine_formats
from pkmcal.workflows import names as _names

#: rich's mark of a word cut at the edge of a column
CUT = "\u2026"


def test_machine_types_are_the_registry():
    """The help reads the registry's list from its source (no import of the machines); its
    module names are the machine types files name."""
    assert _names.machine_modules() == MACHINE_MODULES
    assert list(_names.machine_modules()) == list(machine_formats())


def test_the_defaults_the_help_states():
    """simulate / identifiability / montecarlo --scenario, --deviations and --tolerance give
    examples of the machine types' defaults, and paper-table1 as the hexaslide's alone."""
    classes = {m.kind: m for m in (default_hexaslide(), default_delta(), cubic_6upu(),
                                   default_linear_delta())}
    assert {k: m.default_instrument for k, m in classes.items()} == {
        "hexaslide": "constraint-link", "delta": "tracker", "stewart": "pose",
        "linear_delta": "probe"}
    assert classes["hexaslide"].RANDOM_DEVIATION == pytest.approx((2e-3, 0.02))
    assert classes["delta"].RANDOM_DEVIATION == pytest.approx((1e-3, math.radians(0.5)))
    for module in MACHINE_MODULES:
        for cls in vars(importlib.import_module(f"pkmcal.machines.{module}")).values():
            if isinstance(cls, type) and issubclass(cls, Machine) and cls is not Machine:
                assert cls.DEFAULT_DEVIATIONS == ("paper-table1" if cls.kind == "hexaslide"
                                                  else "random"), cls


def test_format_names_are_the_registry():
    from pkmcal.export import FORMATS, load_formats

    load_formats()
    assert len(set(_names.FORMAT_NAMES)) == len(_names.FORMAT_NAMES)
    assert sorted(_names.FORMAT_NAMES) == sorted(FORMATS)


def _help(tmp_path, monkeypatch, *command) -> str:
    monkeypatch.setenv("COLUMNS", "80")
    proc = run_in_process(*command, "--help", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert max(map(len, proc.stdout.splitlines())) <= 80
    return proc.stdout


@pytest.mark.parametrize("command", ["export", "import"])
def test_format_list_whole_at_80_columns(tmp_path, monkeypatch, command):
    """The list was one word joined by '|', cut by rich at the column's edge."""
    from pkmcal.export import FORMATS, load_formats

    load_formats()
    text = _help(tmp_path, monkeypatch, command)
    assert CUT not in text, text
    words = {w.strip("│,.[]()") for w in text.split()}
    for name in FORMATS:
        assert name in words, (name, text)


@pytest.mark.parametrize("command", [(), ("simulate",), ("montecarlo",)])
def test_every_machine_type_in_the_help(tmp_path, monkeypatch, command):
    """The machine file's types (pkmcal --help; MACHINE arguments), the defaults per type
    (simulate --scenario and --deviations; montecarlo)."""
    text = _help(tmp_path, monkeypatch, *command)
    words = {w.strip("│,.;:()`") for w in text.split()}
    for kind in machine_formats():
        assert kind in words, (kind, text)


def _command_names() -> list[str]:
    import typer.main

    from pkmcal.cli import app

    return sorted(typer.main.get_command(app).commands)


# every command, from the app (calibrate's help column was 16 characters at 80 columns: a
# --x/--no-x pair and long metavars widened every row, and inverse-kinematics was cut)
@pytest.mark.parametrize("command", _command_names())
def test_no_word_cut_at_80_columns(tmp_path, monkeypatch, command):
    text = _help(tmp_path, monkeypatch, command)
    assert CUT not in text, text
    assert "x_," not in text and "phi_ " not in text   # <len> placeholders not eaten as HTML


def test_calibrate_help_has_every_instrument_from_its_module(tmp_path, monkeypatch):
    """Issue 38: the command declares nothing an instrument owns. Its help lists each
    registered instrument's paragraph, composed from the instrument's own attributes (its
    columns with their ``<unit>`` shown, not read as markup) and its ``calibrate_help``;
    the command's own docstring names none of them."""
    import inspect

    from pkmcal.cli import calibrate
    from pkmcal.instruments.registry import INSTRUMENTS

    text = " ".join(_help(tmp_path, monkeypatch, "calibrate").split())
    for inst in INSTRUMENTS.values():
        first = " ".join(inst.help_paragraphs().split("\n\n")[0].replace("\\", "").split())
        assert f"{inst.name} data, " in text, inst.name
        assert first.split(": files with ")[1][:30] in text, (inst.name, first)
    own = inspect.cleandoc(calibrate.__wrapped__.__doc__).lower()
    for inst in INSTRUMENTS.values():
        for word in (inst.name, *inst.aliases):
            assert word not in own, word
