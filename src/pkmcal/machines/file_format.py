"""How a machine type is read from and written to a machine file: the pieces a machine module
needs to state its own file section (:class:`MachineFormat`, the strict pydantic base and the
number types).

They live below :mod:`pkmcal.io` because a machine module declares its section and io imports
machines (never the reverse): :mod:`pkmcal.io.machine_file` adds what every machine file has
(``pkmcal``, ``machine``, ``name``, ``units``, the instrument sections, ``joint_limits``,
``calibration``) to the schema a machine module gives (:func:`pkmcal.io.machine_file` reads
``FILE_FORMAT`` of every module listed in :mod:`pkmcal.machines.registry`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, Strict

from .base import Machine

#: a finite number (an int is read as a float)
Number = Annotated[float, Strict(), Field(allow_inf_nan=False)]
#: a finite number > 0
Positive = Annotated[float, Strict(), Field(allow_inf_nan=False, gt=0)]
#: three finite numbers
Vector3 = Annotated[list[Number], Field(min_length=3, max_length=3)]
#: two finite numbers (a point of a plane)
Vector2 = Annotated[list[Number], Field(min_length=2, max_length=2)]
#: six finite numbers (a pose x, y, z, psi, theta, phi)
Pose6 = Annotated[list[Number], Field(min_length=6, max_length=6)]


class StrictModel(BaseModel):
    """A file section: unknown keys refused, no type coercion (``"1"`` is not a number)."""

    model_config = ConfigDict(extra="forbid", strict=True)


@dataclass(frozen=True)
class MachineFormat:
    """How one machine type is read from and written to a file.

    Attributes
    ----------
    schema : type of pydantic.BaseModel
        Validates the file's mapping.
    build : callable
        ``build(document, source) -> Machine`` (document validated, file units).
    dump : callable
        ``dump(machine, units) -> dict`` of the machine-specific keys, in file order.
    counts : dict of str to int
        Required length of each list key (``{"chains": 6}``), for messages.
    home_text : str, optional
        What ``home`` holds, for messages.
    hints : dict of str to str, optional
        Hints shown with a missing key of this machine type.
    kinds : dict of tuple to str, optional
        Key pattern -> ``"length"``, ``"angle"`` or ``"gain"`` (``"*"`` matches any key or
        index), for the plausibility of the numbers; ``home`` is known to every format.
    size : callable, optional
        ``size(document) -> (metres, what it is)``: the machine's own size for plausibility.
    kind : str, optional
        The machine type (``machine:`` in files) of a format a machine module exports
        (:mod:`pkmcal.machines.registry`); empty for the formats io defines itself.
    """

    schema: type[BaseModel]
    build: Callable[[Any, str], Machine]
    dump: Callable[[Machine, dict], dict]
    counts: dict[str, int]
    home_text: str = "[x, y, z, psi, theta, phi]"
    hints: dict[str, str] | None = None
    #: key pattern -> "length", "angle" or "gain" (``"*"`` matches any key or index); ``home``
    #: is known to every format
    kinds: dict[tuple, str] | None = None
    #: ``size(document) -> (metres, what it is)``: the machine's own size for plausibility
    size: Callable[[Any], tuple[float, str]] | None = None
    kind: str = ""
