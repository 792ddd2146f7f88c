"""Units of files and command-line numbers.

Internal units are SI: metres, radians, newtons, seconds, kilograms. Files name their units
(``units: {length: mm, angle: deg}`` in machine files, a suffix such as ``_mm`` in CSV column
names); command-line numbers take a suffix (``100mm``, ``10rad/s``) and a bare number is SI.
"""

from __future__ import annotations

import re

from .errors import InputError

#: factor to SI for every unit the toolkit understands, grouped by quantity
LENGTH = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "cm": 1e-2}
ANGLE = {"rad": 1.0, "deg": 0.017453292519943295, "urad": 1e-6, "mrad": 1e-3}
FORCE = {"N": 1.0, "kN": 1e3}
MASS = {"kg": 1.0, "g": 1e-3}
ANGULAR_SPEED = {"rad/s": 1.0, "deg/s": 0.017453292519943295, "rpm": 0.10471975511965977}
TIME = {"s": 1.0, "ms": 1e-3}

QUANTITIES: dict[str, dict[str, float]] = {
    "length": LENGTH,
    "angle": ANGLE,
    "force": FORCE,
    "mass": MASS,
    "angular_speed": ANGULAR_SPEED,
    "time": TIME,
}

#: suffixes allowed in CSV column names (SPEC 6), with their quantity
COLUMN_SUFFIXES: dict[str, str] = {
    "m": "length", "mm": "length", "um": "length",
    "rad": "angle", "deg": "angle", "urad": "angle",
    "N": "force",
}


def factor(unit: str, quantity: str) -> float:
    """Factor that converts a value in ``unit`` to SI for ``quantity``.

    Parameters
    ----------
    unit : str
        Unit name, e.g. ``"mm"``.
    quantity : str
        A key of :data:`QUANTITIES` (``"length"``, ``"angle"``, ...).

    Returns
    -------
    float
        SI value of one ``unit``.

    Raises
    ------
    InputError
        When ``unit`` is not a unit of ``quantity``, naming the accepted ones.
    """
    table = QUANTITIES[quantity]
    try:
        return table[unit]
    except KeyError:
        raise InputError(
            f"unknown {quantity} unit {unit!r} (accepted: {', '.join(table)})"
        ) from None


def unit_of(unit: str) -> str | None:
    """Quantity of a unit name (``'mm'`` -> ``'length'``), or None when not known.

    Parameters
    ----------
    unit : str
        Unit name.

    Returns
    -------
    str or None
        A key of :data:`QUANTITIES`.
    """
    for quantity, table in QUANTITIES.items():
        if unit in table:
            return quantity
    return None


_NUMBER = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-z/]*)\s*$")


def parse_quantity(text: str, quantity: str, what: str = "value") -> float:
    """Parse a command-line number with an optional unit suffix into SI.

    ``parse_quantity("100mm", "length") == 0.1``; a bare number is SI.

    Parameters
    ----------
    text : str
        The number, e.g. ``"2um"``, ``"10 deg"`` or ``"1e-3"``.
    quantity : str
        A key of :data:`QUANTITIES`.
    what : str, optional
        What the value is, the start of error messages.

    Returns
    -------
    float
        The value in SI units.

    Raises
    ------
    InputError
        When the text is not a number or the unit is not one of ``quantity``.
    """
    m = _NUMBER.match(str(text))
    if not m:
        raise InputError(f"{what}: cannot read {text!r} as a number with a {quantity} unit")
    value, unit = float(m.group(1)), m.group(2)
    if not unit:
        return value
    try:
        return value * factor(unit, quantity)
    except InputError as exc:
        raise InputError(f"{what}: {exc}") from None


def parse_vector(text: str, quantity: str, n: int, what: str = "value") -> list[float]:
    """Parse ``"0,0,-500N"`` (the unit applies to every component) into SI.

    Parameters
    ----------
    text : str
        ``n`` comma-separated numbers; a unit suffix on the last one applies to all.
    quantity : str
        A key of :data:`QUANTITIES`.
    n : int
        Number of components.
    what : str, optional
        What the value is, the start of error messages.

    Returns
    -------
    list of float
        The components in SI units.

    Raises
    ------
    InputError
        When there are not ``n`` components or one cannot be read.
    """
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != n:
        raise InputError(f"{what}: expected {n} comma-separated numbers, got {text!r}")
    m = re.match(r"^(.*?)([A-Za-z/]*)$", parts[-1])
    unit = m.group(2) if m else ""
    parts[-1] = m.group(1) if m else parts[-1]
    return [parse_quantity(p + unit, quantity, what) for p in parts]
