"""Units of files and command-line numbers.

Internal units are SI: metres, radians, newtons, seconds, kilograms. Files name their units
(``units: {length: mm, angle: deg}`` in machine files, a suffix such as ``_mm`` in CSV column
names); command-line numbers take a suffix (``100mm``, ``10rad/s``) and a bare number is SI.
"""

from __future__ import annotations

import re

from .errors import InputError

#: factor to SI for every unit the toolkit understands, grouped by quantity
LENGTH = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "cm": 1e-2, "in": 0.0254, "inch": 0.0254}
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

#: largest magnitude of a command-line number, SI, per quantity: beyond these a value is a typo
#: (``--noise 1e308``), refused naming the option before it overflows a computation. Checks
#: against the machine's own scale (a noise of a tenth of the machine) come later, where the
#: machine is known.
MAX_MAGNITUDE: dict[str, float] = {
    "length": 1e6,            # 1000 km
    "angle": 1e3,             # 160 turns
    "force": 1e9,             # N
    "mass": 1e7,              # kg
    "angular_speed": 1e5,     # rad/s (about a million rpm)
    "time": 1e9,              # s (30 years)
}

#: suffixes allowed in CSV column names (SPEC 6), with their quantity
COLUMN_SUFFIXES: dict[str, str] = {
    "m": "length", "mm": "length", "um": "length", "in": "length",
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
        When the text is not a number, the unit is not one of ``quantity`` or the magnitude
        exceeds :data:`MAX_MAGNITUDE`.
    """
    m = _NUMBER.match(str(text))
    if not m:
        raise InputError(f"{what}: cannot read {text!r} as a number with a {quantity} unit")
    value, unit = float(m.group(1)), m.group(2)
    try:
        si = value * factor(unit, quantity) if unit else value
    except InputError as exc:
        raise InputError(f"{what}: {exc}") from None
    limit = MAX_MAGNITUDE[quantity]
    if not abs(si) <= limit:
        raise InputError(f"{what}: {text} is out of range ({quantity.replace('_', ' ')} "
                         f"at most {limit:g} in SI units; a bare number is SI)")
    return si


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
