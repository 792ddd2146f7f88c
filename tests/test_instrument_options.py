"""Every option an instrument's calibration reads is declared in its module (issue 38): its
``Options`` dataclass, typed, with flag, help, default and choices; ``pkmcal calibrate``'s
instrument flags are built from those declarations (the CLI and the calibration layer declare
none), and one rule refuses an option the data's instrument does not declare."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import sys
from pathlib import Path

import pytest

from pkmcal.calibration import calibrate
from pkmcal.calibration.options import GENERIC, command_options, command_values
from pkmcal.errors import InputError
from pkmcal.instruments.flow import option_specs
from pkmcal.instruments.registry import INSTRUMENTS

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
DECLARING = [inst for inst in INSTRUMENTS.values() if inst.Options is not None]
IDS = [inst.name for inst in DECLARING]
#: the options of ``pkmcal calibrate`` that are no instrument's: calibrate()'s generic
#: arguments and the command's own (output, report, JSON, column map, help)
COMMAND_OWN = {"--output", "-o", "--noise", "--robust", "--holdout", "--seed", "--parameters",
               "--report", "--json", "--columns", "--help", "-h"}
#: what a mapping (not an Options object) may be asked in an instrument module: solver
#: settings passed as ``options`` dictionaries
MAPPING_METHODS = {"get", "items", "keys", "values"}


def _command():
    import typer.main

    from pkmcal.cli import app

    return typer.main.get_command(app).commands["calibrate"]


@pytest.mark.parametrize("inst", DECLARING, ids=IDS)
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
    with pytest.raises(AttributeError):     # slotted: nothing else to read
        options.unrelated    # noqa: B018
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(options, specs[0]["name"], "y")


def _options_read(path: Path, options_class: str) -> dict:
    """``{function: (typed, attributes)}``: the attributes read as ``options.X`` by every
    function of a module with an ``options`` parameter, and whether that parameter is
    annotated with ``options_class`` (``X`` or ``X | None``)."""
    out = {}
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        args = node.args.posonlyargs + node.args.args + node.args.kwonlyargs
        param = next((a for a in args if a.arg == "options"), None)
        if param is None:
            continue
        note = ast.unparse(param.annotation) if param.annotation is not None else ""
        typed = note.replace(" | None", "").replace("None | ", "") == options_class
        out[node.name] = (typed, {sub.attr for sub in ast.walk(node)
                                  if isinstance(sub, ast.Attribute)
                                  and isinstance(sub.value, ast.Name)
                                  and sub.value.id == "options"})
    return out


@pytest.mark.parametrize("inst", DECLARING, ids=IDS)
def test_every_option_an_instrument_reads_is_declared_in_its_module(inst):
    """Statically: every ``options.X`` its module reads is a field of its ``Options`` (or, in
    a function whose ``options`` is a solver's settings, a mapping's method)."""
    path = Path(sys.modules[type(inst).__module__].__file__)
    read = _options_read(path, inst.Options.__name__)
    assert any(typed for typed, _ in read.values()), \
        f"{path.name}: no function takes options: {inst.Options.__name__}"
    declared = {f.name for f in dataclasses.fields(inst.Options)}
    for function, (typed, attributes) in read.items():
        allowed = declared if typed else declared | MAPPING_METHODS
        assert attributes <= allowed, (path.name, function, attributes - allowed)


def test_the_audit_of_options_read_sees_an_undeclared_one(tmp_path):
    """Not blind: a flow reading an option its class does not declare is found, typed as
    ``X`` or ``X | None``."""
    module = tmp_path / "m.py"
    module.write_text("def flow(machine, options: XOptions):\n"
                      "    return options.noise, options.bed_tilt\n"
                      "def model(machine, options: XOptions | None = None):\n"
                      "    return options.point\n")
    assert _options_read(module, "XOptions") == {"flow": (True, {"noise", "bed_tilt"}),
                                                 "model": (True, {"point"})}


def test_every_flag_of_the_command_is_an_instrument_field_or_a_generic_argument():
    """The command's flags are the generic ones and those the instruments declare, nothing
    else; every declared flag is there."""
    declared = {flag for inst in DECLARING for spec in option_specs(inst.Options)
                for flag in spec["flag"].split("/")}
    flags = {opt for param in _command().params if param.param_type_name == "option"
             for opt in param.opts + param.secondary_opts}
    assert flags - COMMAND_OWN <= declared, flags - COMMAND_OWN - declared
    assert declared - {"--noise", "--robust"} <= flags, declared - flags


def test_the_command_and_the_library_declare_no_instrument_option():
    """The command function and calibrate() take the generic arguments and the instruments'
    options as a mapping: none of their own parameters is an instrument's field."""
    from pkmcal.calibration.run import calibrate as library
    from pkmcal.cli import calibrate as command

    fields = {f.name for inst in DECLARING for f in dataclasses.fields(inst.Options)}
    own = set(inspect.signature(command.__wrapped__).parameters)
    assert not (own & fields) - set(GENERIC), own & fields
    assert not (set(inspect.signature(library).parameters) & fields) - set(GENERIC)
    source = (ROOT / "src/pkmcal/cli/__init__.py").read_text()
    tree = ast.parse(source)
    function = next(n for n in ast.walk(tree)
                    if isinstance(n, ast.FunctionDef) and n.name == "calibrate")
    docstring = function.body[0].value
    texts = [n.value for n in ast.walk(function) if isinstance(n, ast.Constant)
             and isinstance(n.value, str) and n is not docstring]
    for inst in DECLARING:
        for spec in option_specs(inst.Options):
            if spec["name"] not in GENERIC:
                assert not any(spec["flag"].split("/")[0] in t for t in texts), spec["flag"]


def test_command_values_pairs_and_repeats():
    names = {opt.name: opt for opt in command_options()}
    assert names["estimate_lc"].kind == "either" and names["two_step"].kind == "switch"
    assert command_values({"estimate_lc": False, "no_estimate_lc": True}) == \
        {"estimate_lc": False}
    assert command_values({"two_step": False, "method": None}) == {}
    assert command_values({"method": ["ik"]}) == {"method": "ik"}
    with pytest.raises(InputError, match="--estimate-lc and --no-estimate-lc together"):
        command_values({"estimate_lc": True, "no_estimate_lc": True})
    with pytest.raises(InputError, match="--method: given more than once"):
        command_values({"method": ["ik", "ml"]})


def test_an_option_no_instrument_declares_is_refused():
    from pkmcal.machines import default_delta

    with pytest.raises(InputError, match="sideways: no instrument's calibration takes"):
        calibrate(default_delta(), "never-read.csv", sideways=True)


def _given(spec):
    """A value of an option that is not its default."""
    if spec["default"] is False:
        return True
    if spec["default"] is None and "/" in spec["flag"]:
        return False
    return next((c for c in spec["choices"] or () if c != spec["default"]), "2um")


@pytest.mark.parametrize("inst", list(INSTRUMENTS.values()), ids=list(INSTRUMENTS))
def test_an_option_the_data_instrument_does_not_declare_is_refused_naming_who_takes_it(inst):
    """One rule for every instrument and option: the flag, the instruments that take it and
    what the data are; a value out of an option's choices names the values it takes."""
    from pkmcal.calibration.options import check_instrument_options, declared_options

    own = {f.name for f in dataclasses.fields(inst.Options)} if inst.Options else set()
    for name, owners in declared_options().items():
        spec = next(s for s in option_specs(owners[0][0].Options) if s["name"] == name)
        flag = spec["flag"].split("/")[0]
        if name in GENERIC:
            continue
        if name not in own:
            with pytest.raises(InputError) as found:
                check_instrument_options({name: _given(spec)}, "x.csv", inst)
            text = str(found.value)
            assert text.startswith(f"{flag}: applies to ") and "x.csv has " in text, text
            assert all(f"{i.name} data" in text for i, _ in owners), text
        elif spec["choices"]:
            with pytest.raises(InputError, match=f"{flag} bogus: {inst.name} data take "):
                check_instrument_options({name: "bogus"}, "x.csv", inst)
