"""An instrument's calibration flow and its options live in its module (issue 38): the
calibration layer dispatches every instrument that brings a flow through the registry, and the
flow reads only the options its module declares (typed, with flag, help and default)."""

from __future__ import annotations

import ast
import dataclasses
import sys
from pathlib import Path

import pytest

from pkmcal.calibration.flows import calibrate_flow, check_instrument, joint_flow
from pkmcal.calibration.kinds import KINDS, all_kinds
from pkmcal.instruments.base import Instrument
from pkmcal.instruments.flow import option_specs
from pkmcal.instruments.registry import INSTRUMENTS

all_kinds()
FLOWS = [inst for inst in INSTRUMENTS.values() if inst.has_flow]
IDS = [inst.name for inst in FLOWS]
#: every instrument declaring options (its flow's, or its generic path's model's)
DECLARING = [inst for inst in INSTRUMENTS.values() if inst.Options is not None]


def test_the_older_instruments_bring_their_flows_and_the_registry_dispatches_them():
    assert {"tracker", "pose", "distance", "constraint-link", "probe"} <= set(IDS)
    for inst in FLOWS:
        kind = KINDS[inst.name]
        assert kind.calibrate.func is calibrate_flow, inst.name
        assert kind.calibrate.keywords == {"inst": inst}
        assert kind.check_options.func is check_instrument
        assert kind.check_options.keywords == {"inst": inst}


def test_the_instruments_bring_their_parts_of_a_fit_of_several_files():
    """The joint fit's part of every instrument with a flow of its own that combines is its
    module's (Instrument.joint_part), dispatched through the registry (run.py names none)."""
    combining = [inst for inst in FLOWS if not inst.joint_refusal]
    assert {"tracker", "distance", "probe"} <= {inst.name for inst in combining}
    for inst in combining:
        owner = next(c for c in type(inst).__mro__ if "joint_part" in vars(c))
        assert owner is not Instrument and owner.__module__ == type(inst).__module__, inst.name
        kind = KINDS[inst.name]
        assert kind.joint.func is joint_flow and kind.joint.keywords == {"inst": inst}


@pytest.mark.parametrize("inst", DECLARING, ids=[i.name for i in DECLARING])
def test_options_are_declared_typed_with_flag_help_and_default(inst):
    assert inst.Options.__module__ == type(inst).__module__      # declared in its module
    specs = option_specs(inst.Options)
    assert specs
    for spec in specs:
        assert spec["flag"].startswith("--") and len(spec["help"]) > 20, spec
        assert spec["type"] not in (None, ""), spec
        if spec["choices"]:
            assert spec["default"] is None or spec["default"] in spec["choices"], spec
    declared = {spec["name"] for spec in specs}
    options = inst.options_of({name: "x" for name in declared} | {"unrelated": 1})
    assert {f.name for f in dataclasses.fields(options)} == declared
    assert all(getattr(options, name) == "x" for name in declared)
    defaults = inst.options_of({})
    assert all(getattr(defaults, s["name"]) == s["default"] for s in specs)
    with pytest.raises(AttributeError):     # frozen and slotted: nothing else to read
        options.unrelated    # noqa: B018
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.noise = "1um"


def _options_read(path: Path, options_class: str) -> dict:
    """``{function: attributes}`` read as ``options.X`` by the functions of a module whose
    ``options`` parameter is annotated with ``options_class``."""
    out = {}
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.FunctionDef):
            continue
        args = {a.arg: a.annotation for a in node.args.args + node.args.kwonlyargs}
        note = args.get("options")
        if note is None or ast.unparse(note) != options_class:
            continue
        out[node.name] = {sub.attr for sub in ast.walk(node)
                          if isinstance(sub, ast.Attribute) and isinstance(sub.value, ast.Name)
                          and sub.value.id == "options"}
    return out


@pytest.mark.parametrize("inst", DECLARING, ids=[i.name for i in DECLARING])
def test_every_option_the_flow_reads_is_declared_in_its_module(inst):
    path = Path(sys.modules[type(inst).__module__].__file__)
    read = _options_read(path, inst.Options.__name__)
    assert read, f"{path.name}: no function takes options: {inst.Options.__name__}"
    declared = {f.name for f in dataclasses.fields(inst.Options)}
    for function, attributes in read.items():
        assert attributes, function
        assert attributes <= declared, (function, attributes - declared)


def test_the_audit_of_options_read_sees_an_undeclared_one(tmp_path):
    """The check is not blind: a flow reading an option its class does not declare is
    found."""
    module = tmp_path / "m.py"
    module.write_text("def flow(machine, options: XOptions):\n"
                      "    return options.noise, options.bed_tilt\n")
    assert _options_read(module, "XOptions") == {"flow": {"noise", "bed_tilt"}}


def test_every_declared_option_is_an_option_of_the_command():
    """The flags the instruments declare are ``pkmcal calibrate``'s (which still lists them
    itself; building the command's options from the registry is the next step)."""
    import typer

    from pkmcal.cli import app

    command = typer.main.get_command(app).commands["calibrate"]
    flags = {opt for param in command.params for opt in param.opts + param.secondary_opts}
    for inst in DECLARING:
        for spec in option_specs(inst.Options):
            for flag in spec["flag"].split("/"):
                assert flag in flags, (inst.name, flag)
