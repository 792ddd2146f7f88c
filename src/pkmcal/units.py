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


# -- numbers for people to read (tables and lines of the CLI and reports; JSON keeps its own
# numbers): a unit that reads naturally, never exponent notation for ordinary magnitudes ------

#: the readable unit of a magnitude, per quantity: the first unit whose upper bound (SI,
#: exclusive) the magnitude is below, else the last (um below 1 mm, then mm; urad below
#: 1 mrad, mrad below 0.1 rad, then deg)
READABLE_UNITS: dict[str, tuple[tuple[str, float], ...]] = {
    "length": (("um", 1e-3), ("mm", float("inf"))),
    "angle": (("urad", 1e-3), ("mrad", 0.1), ("deg", float("inf"))),
}


def readable_unit(value: float, quantity: str) -> str:
    """The unit in which ``value`` reads naturally (:data:`READABLE_UNITS`).

    Parameters
    ----------
    value : float
        A magnitude in SI (m or rad); its sign does not matter. Not finite: the smallest unit.
    quantity : str
        ``"length"`` or ``"angle"``.

    Returns
    -------
    str
        ``"um"`` or ``"mm"``; ``"urad"``, ``"mrad"`` or ``"deg"``.
    """
    units = READABLE_UNITS[quantity]
    magnitude = abs(value)
    for unit, bound in units:
        if magnitude < bound:
            return unit
    return units[0][0]                          # nan


def format_number(value: float, digits: int = 4, sign: bool = False) -> str:
    """``value`` to ``digits`` significant digits in positional notation: ``20180`` where
    ``format(value, '.4g')`` gives ``2.018e+04``; trailing zeros dropped as ``g`` drops them.
    Magnitudes below 1e-4 (far below anything a table here shows) keep ``g``'s exponent.

    Parameters
    ----------
    value : float
        The number.
    digits : int, optional
        Significant digits (integers with more digits are rounded to this many: 20180).
    sign : bool, optional
        A ``+`` before positive numbers (a change).

    Returns
    -------
    str
        The number; ``nan``, ``inf`` or ``-inf`` as Python prints them.
    """
    plus = "+" if sign else ""
    value = float(value)
    if value == 0 or not (abs(value) >= 1e-4) or value != value or abs(value) == float("inf"):
        return format(value, f"{plus}.{digits}g")
    exponent = int(format(value, f".{digits - 1}e").rsplit("e", 1)[1])   # after rounding
    decimals = max(digits - 1 - exponent, 0)
    rounded = value if decimals else round(value, digits - 1 - exponent)   # 20180, not 20184
    text = format(rounded, f"{plus}.{decimals}f")
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return text


def format_quantity(value: float, quantity: str, digits: int = 4, sign: bool = False,
                    unit: str | None = None) -> str:
    """``value`` (SI) with its unit, for people: ``3.59 mm``, ``850 um``, ``15.94 mrad``.

    Parameters
    ----------
    value : float
        The value in SI (m or rad).
    quantity : str
        ``"length"`` or ``"angle"``.
    digits : int, optional
        Significant digits (:func:`format_number`).
    sign : bool, optional
        A ``+`` before positive values.
    unit : str, optional
        The unit to use (e.g. a table's row shares one unit between two columns); default
        :func:`readable_unit` of ``value``.

    Returns
    -------
    str
        Number and unit separated by a space.
    """
    unit = unit or readable_unit(value, quantity)
    return f"{format_number(value / factor(unit, quantity), digits, sign)} {unit}"


def format_um(value_um: float | None, digits: int = 4) -> str:
    """A length given in um (a report's ``*_um`` number), for people (:func:`format_quantity`).

    Parameters
    ----------
    value_um : float or None
        The length in um.
    digits : int, optional
        Significant digits.

    Returns
    -------
    str
        ``850 um``, ``3.59 mm``; ``n/a`` for None.
    """
    return "n/a" if value_um is None else format_quantity(value_um * 1e-6, "length", digits)


def format_urad(value_urad: float | None, digits: int = 4) -> str:
    """An angle given in urad (a report's ``*_urad`` number), for people
    (:func:`format_quantity`).

    Parameters
    ----------
    value_urad : float or None
        The angle in urad.
    digits : int, optional
        Significant digits.

    Returns
    -------
    str
        ``85 urad``, ``1.2 mrad``; ``n/a`` for None.
    """
    return "n/a" if value_urad is None else format_quantity(value_urad * 1e-6, "angle", digits)
