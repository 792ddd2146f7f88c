"""Every machine type's file section is its module's ``FILE_FORMAT``, found through the
machine registry (issue 25: a new machine is one module and one registry line), and round-trips:
load -> save -> load gives the same machine and the same text."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from pkmcal.io.machine_file import MACHINE_FORMATS, machine_to_text, parse_machine
from pkmcal.machines import (
    cubic_6upu,
    default_delta,
    default_hexaslide,
    default_linear_delta,
)
from pkmcal.machines.planar_3rpr import default_planar_3rpr
from pkmcal.machines.registry import MACHINE_MODULES, machine_formats

#: a nominal machine of each machine type (a new machine type adds its own here)
NOMINAL = {"hexaslide": default_hexaslide, "delta": default_delta, "stewart": cubic_6upu,
           "linear_delta": default_linear_delta, "planar_3rpr": default_planar_3rpr}

UNITS = ({"length": "mm", "angle": "deg"}, {"length": "m", "angle": "rad"},
         {"length": "in", "angle": "deg"})


def test_every_registered_module_states_its_machine_type():
    formats = machine_formats()
    assert list(formats) == list(MACHINE_FORMATS)          # io knows exactly the registry's
    assert set(formats) == set(NOMINAL)
    for module in MACHINE_MODULES:
        fmt = importlib.import_module(f"pkmcal.machines.{module}").FILE_FORMAT
        assert formats[fmt.kind] is fmt
        # io reads with the module's schema, adding only what every file has
        assert issubclass(MACHINE_FORMATS[fmt.kind].schema, fmt.schema)


@pytest.mark.parametrize("kind", list(NOMINAL))
@pytest.mark.parametrize("units", UNITS, ids=lambda u: u["length"])
def test_file_format_round_trips(kind, units):
    fmt = machine_formats()[kind]
    nominal = NOMINAL[kind]()
    assert nominal.kind == kind
    text = machine_to_text(nominal, units)                   # the registry's dumper ...
    first = parse_machine(text, f"{kind}.yaml")              # ... load
    assert type(first) is type(nominal)
    # the module's own keys are in the file, in the order its dump gives them
    own = list(fmt.dump(first, units))
    keys = [line.split(":", 1)[0] for line in text.splitlines() if line[:1].isalpha()]
    assert [k for k in keys if k in own] == own
    again = machine_to_text(first)                           # save (the file's units kept)
    assert again == text
    second = parse_machine(again, f"{kind}-again.yaml")      # load
    assert np.array_equal(second.u, first.u)
    for a, b in zip(second.home, first.home, strict=True):
        assert np.array_equal(a, b)
    assert second.file_units == first.file_units == units
    np.testing.assert_allclose(first.u, nominal.u, rtol=0,
                               atol=1e-12 * np.abs(nominal.u).max())
