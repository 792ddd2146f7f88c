"""What the help texts name: the machine types and the controller formats, in words.

``import pkmcal.cli`` loads no machine or format module (they import numpy; start-up matters).
The machine types are read from the machine registry's source
(:data:`pkmcal.machines.registry.MACHINE_MODULES`, whose module names are the machine types),
without importing :mod:`pkmcal.machines`: a machine module added there is in the help with no
other line. The format names are a copy of :data:`pkmcal.export.FORMATS`' names, which
tests/test_help_texts.py checks against the registry.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

from ..paths import path_text

#: ``--to`` / ``--from``: the names of :data:`pkmcal.export.FORMATS` (one controller's
#: formats together)
FORMAT_NAMES: tuple[str, ...] = (
    "linuxcnc-genhexkins",
    "linuxcnc-rotarydelta",
    "linuxcnc-lineardelta",
    "klipper",
    "klipper-rotary-delta",
    "marlin",
    "reprapfirmware",
)


@cache
def machine_modules() -> tuple[str, ...]:
    """:data:`pkmcal.machines.registry.MACHINE_MODULES`, read from the registry's source.

    Returns
    -------
    tuple of str
        The machine modules, in the registry's order (their names are the machine types).
    """
    path = Path(__file__).resolve().parents[1] / "machines" / "registry.py"
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.AnnAssign | ast.Assign):
            targets = [node.target] if isinstance(node, ast.AnnAssign) else node.targets
            if any(isinstance(t, ast.Name) and t.id == "MACHINE_MODULES" for t in targets):
                return tuple(ast.literal_eval(node.value))
    raise LookupError(f"{path_text(path)}: no MACHINE_MODULES")


def words(names, last: str = "or") -> str:
    """``a, b, c or d``."""
    names = list(names)
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} {last} {names[-1]}"


def machine_types(last: str = "or") -> str:
    """Every machine type: ``hexaslide, delta, stewart, linear_delta or planar_3rpr``."""
    return words(machine_modules(), last)


def formats() -> str:
    """Every controller format, comma separated (wraps in a narrow help column)."""
    return ", ".join(FORMAT_NAMES)
