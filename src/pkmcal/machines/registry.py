"""The machine types of machine modules: one line per module.

A machine module (``pkmcal.machines.<module>``) holding its :class:`~pkmcal.machines.Machine`
subclass and its file section exports ``FILE_FORMAT``, a
:class:`~pkmcal.machines.file_format.MachineFormat` whose ``kind`` is the machine type files
name (``machine: planar_3rpr``). Listing the module here is all it takes for machine files
(:data:`pkmcal.io.machine_file.MACHINE_FORMATS`), and through them every command, to know it.
"""

from __future__ import annotations

import importlib

from .file_format import MachineFormat

#: the machine modules (under :mod:`pkmcal.machines`), each stating its own file section;
#: the order is the order messages list the machine types in
MACHINE_MODULES: tuple[str, ...] = (
    "hexaslide",
    "delta",
    "stewart",
    "linear_delta",
    "planar_3rpr",
)


def machine_formats() -> dict[str, MachineFormat]:
    """The file formats of the registered machine modules, by machine type.

    Returns
    -------
    dict of str to MachineFormat
        ``{kind: FILE_FORMAT}`` in the order of :data:`MACHINE_MODULES`.
    """
    out: dict[str, MachineFormat] = {}
    for name in MACHINE_MODULES:
        fmt = importlib.import_module(f"{__package__}.{name}").FILE_FORMAT
        out[fmt.kind] = fmt
    return out


def bed_frame_kinds() -> tuple[str, ...]:
    """The machine types whose frame is their bed (a printer's: ``frame_is_bed``), for
    messages that send a user measuring a bed to them.

    Returns
    -------
    tuple of str
        Machine types in the order of :data:`MACHINE_MODULES`, e.g. ``("linear_delta",)``.
    """
    from .base import Machine

    kinds = []
    for name in MACHINE_MODULES:
        module = importlib.import_module(f"{__package__}.{name}")
        for value in vars(module).values():
            if isinstance(value, type) and issubclass(value, Machine) \
                    and value.__module__ == module.__name__ and value.frame_is_bed \
                    and getattr(value, "kind", None) and value.kind not in kinds:
                kinds.append(value.kind)
    return tuple(kinds)
