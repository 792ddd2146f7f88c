"""The CSV table every data file is (SPEC 6): the header with its units, column maps
(``--columns``), separators and quotes checked, numbers parsed; each problem an
:class:`~pkmcal.errors.InputError` naming the file, row and column.

Row numbers are *line numbers of the file* (header = line 1), the row numbers a spreadsheet
shows. Blank lines and lines starting with ``#`` are skipped.
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
import re
from contextvars import ContextVar
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..paths import path_text
from ..units import COLUMN_SUFFIXES, QUANTITIES
from .atomic import read_input_text

Row = tuple[int, list[str]]


def _suffixes(quantity: str) -> list[str]:
    return [s for s, q in COLUMN_SUFFIXES.items() if q == quantity]


#: the column map in force (pkmcal name -> the file's name), see :func:`column_map`
_COLUMN_MAP: ContextVar[dict[str, str] | None] = ContextVar("pkmcal_column_map", default=None)

#: bases of the columns pkmcal reads, with the quantity of their unit suffix (None: no
#: suffix; "any": any unit word, e.g. a Stewart's q1_rev)
_COLUMN_BASES = {"passive": None, "qx": None, "qy": None, "qz": None, "qw": None,
                 "x": "length", "y": "length", "z": "length", "mx": "length", "my": "length",
                 "mz": "length", "psi": "angle", "theta": "angle", "phi": "angle", "t": "time",
                 "target": None, "setup": None, "d": "length", "probe_z": "length"}
_KNOWN_COLUMNS = ("q1_<unit>..qn_<unit>, passive, x_<len>, y_<len>, z_<len>, psi_<ang>, "
                  "theta_<ang>, phi_<ang>, qx, qy, qz, qw, mx_<len>, my_<len>, mz_<len>, "
                  "target, d_<len>, setup, probe_z_<len>, t_s")


def _column_name_problem(name: str) -> str | None:
    """Why ``name`` is not a column pkmcal reads (None when it is one)."""
    m = re.match(r"^q[1-9][0-9]?_([A-Za-z][A-Za-z0-9]*)$", name)
    if m:
        return None
    if re.match(r"^q[1-9][0-9]?$", name):
        return f"{name!r} needs a unit suffix ({name}_mm, {name}_deg, {name}_rev, ...)"
    base, _, unit = name.partition("_")
    if name in _COLUMN_BASES or base in _COLUMN_BASES:
        quantity = _COLUMN_BASES.get(name if name in _COLUMN_BASES else base)
        if quantity is None:
            return None if name == base else f"{name!r}: {base} takes no unit suffix"
        accepted = list(QUANTITIES["time"]) if quantity == "time" else _suffixes(quantity)
        if not unit:
            return f"{name!r} needs a unit suffix ({', '.join(base + '_' + u for u in accepted)})"
        if unit not in accepted:
            return (f"{name!r}: unknown {quantity} unit {unit!r} (accepted: "
                    f"{', '.join(accepted)})")
        return None
    return f"{name!r} is not a column pkmcal reads"


def parse_column_map(text: str) -> dict[str, str]:
    """The column map of ``--columns PKMCAL=FILE,...``: pkmcal's name -> the file's name.

    Parameters
    ----------
    text : str
        Comma-separated pairs, e.g. ``"q1_rev=leg_length_1,x_mm=position_x"``.

    Returns
    -------
    dict of str to str
        pkmcal column name -> the data file's column name.

    Raises
    ------
    InputError
        Naming ``--columns``: a pair that is not ``NAME=NAME``, a left side that is not a
        column pkmcal reads (``q1_<unit>``, ``x_<len>``, ``qx``, ...), or a name given twice.
    """
    mapping: dict[str, str] = {}
    problems = []
    for part in str(text).split(","):
        left, eq, right = (p.strip() for p in part.partition("="))
        if not eq or not left or not right:
            raise InputError(f"--columns: expected PKMCAL=FILE pairs separated by commas (e.g. "
                             f"q1_rev=leg_length_1,x_mm=position_x), got {part.strip()!r}")
        if left in mapping:
            raise InputError(f"--columns: {left} is given twice")
        if right in mapping.values():
            raise InputError(f"--columns: the file's column {right} is mapped twice")
        problem = _column_name_problem(left)
        if problem is not None:
            problems.append(problem)
        mapping[left] = right
    if problems:
        raise InputError(f"--columns: unknown pkmcal column name(s): {'; '.join(problems)} "
                         f"(pkmcal reads {_KNOWN_COLUMNS})")
    return mapping


def set_column_map(mapping: dict[str, str] | None):
    """Make ``mapping`` (pkmcal name -> the file's name) the column map of every data file
    :func:`read_table` reads from now on in this context (None: no renaming).

    Parameters
    ----------
    mapping : dict of str to str or None
        As returned by :func:`parse_column_map`.

    Returns
    -------
    contextvars.Token
        Token to restore the previous map (``_COLUMN_MAP.reset``).
    """
    return _COLUMN_MAP.set(dict(mapping) if mapping else None)


@contextlib.contextmanager
def column_map(mapping: dict[str, str] | None):
    """Read data files with their columns renamed (``--columns``), within a ``with`` block.

    Parameters
    ----------
    mapping : dict of str to str or None
        pkmcal name -> the file's name (:func:`parse_column_map`); None reads the files'
        columns as they are.

    Yields
    ------
    None
        While the block runs, :func:`read_table` renames the columns.
    """
    token = set_column_map(mapping)
    try:
        yield
    finally:
        _COLUMN_MAP.reset(token)


def _renamed(path, line: int, header: list[str]) -> list[str]:
    """The header with the column map in force applied (unchanged without one)."""
    mapping = _COLUMN_MAP.get()
    if not mapping:
        return header
    missing = [right for right in mapping.values() if right not in header]
    if missing:
        shown = ", ".join(header)
        shown = shown if len(shown) <= 300 else shown[:297] + "..."
        raise InputError(f"{path_text(path)}: "
                         f"row {line}: --columns names column(s) this file does not "
                         f"have: {', '.join(missing)} (columns found: {shown})")
    renamed_from = set(mapping.values())
    for left, right in mapping.items():
        if left in header and left not in renamed_from:
            raise InputError(f"{path_text(path)}: "
                             f"row {line}: --columns {left}={right}: the file already "
                             f"has a column {left}")
    back = {right: left for left, right in mapping.items()}
    return [back.get(name, name) for name in header]


def read_table(path) -> tuple[list[str], list[Row]]:
    """Header and data rows of a CSV file.

    Blank lines and lines starting with ``#`` are skipped; fields are stripped. With a column
    map in force (``--columns``, :func:`column_map`) the header's columns are renamed to
    pkmcal's names first; a mapped column the file does not have is refused.

    Parameters
    ----------
    path : str or os.PathLike
        The data file.

    Returns
    -------
    header : list of str
        The column names.
    rows : list of tuple
        ``(line_number, fields)`` per data row (line numbers of the file, header = 1).

    Raises
    ------
    InputError
        For a missing, empty or non-text file, an unnamed or duplicate column, a row with the
        wrong number of fields, a CSV syntax error, no data rows, or a column map that names
        a column the file does not have.
    """
    path = Path(path)
    text = read_input_text(path, "data file")
    reader = csv.reader(io.StringIO(text, newline=""))
    header: list[str] | None = None
    header_line = 0
    rows: list[Row] = []
    last = 0
    numeric: list[int] = []
    useful = True
    lines = _Lines(text)
    try:
        for fields in reader:
            line, start, last = reader.line_num, last + 1, reader.line_num
            _refuse_open_quote(path, text, fields, start, line, header, lines)
            if not fields or all(not f.strip() for f in fields) or fields[0].lstrip(
                    ).startswith("#"):
                continue
            fields = [f.strip() for f in fields]
            if header is None:
                header, header_line = fields, line
                _check_separator(path, line, header)
                header = _renamed(path, line, header)
                _check_names(path, line, header)
                numeric = [i for i, name in enumerate(header) if _is_numeric(name)]
                useful = _reads_any(header)
                continue
            if len(fields) != len(header):
                raise InputError(f"{path_text(path)}: "
                                 f"row {line}: {len(fields)} field(s), the header (row "
                                 f"{header_line}) has {len(header)} columns")
            # refused at the first row that holds text where a number belongs, whatever
            # follows (a large file of words is answered at once, issue 37)
            for i in numeric:
                if fields[i] and not _FLOAT.match(fields[i]):
                    parse_number(path, line, header[i], fields[i])
            rows.append((line, fields))
            if not useful:
                break           # no column to read: the reader names the one it misses
    except csv.Error as exc:
        raise InputError(f"{path_text(path)}: "
                         f"row {reader.line_num}: CSV syntax error: {exc}") from None
    if header is None:
        raise InputError(f"{path_text(path)}: empty file (expected a header line such as "
                         "q1_mm,q2_mm,q3_mm,q4_mm,q5_mm,q6_mm)")
    if not rows:
        raise InputError(f"{path_text(path)}: no data rows after the header")
    return header, rows


#: a field ``float`` reads (Python's syntax, no ``_``): the rest is refused as a row is read
_FLOAT = re.compile(r"^[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|inf(?:inity)?|nan)$",
                    re.IGNORECASE)
#: columns pkmcal reads as numbers: readings (``q1_mm``, a pair's ``q1b_mm``), the bases of
#: :data:`_COLUMN_BASES` with a unit, and the unit-less quaternion and passive actuator
_NUMERIC = re.compile(r"^(?:q[1-9][0-9]?b?_[A-Za-z][A-Za-z0-9]*|(?:x|y|z|mx|my|mz|psi|theta|phi"
                      r"|d|distance|probe_z|t)_[A-Za-z]+|qx|qy|qz|qw|passive)$")


def _is_numeric(name: str) -> bool:
    return bool(_NUMERIC.match(name))


def _check_names(path, line: int, header: list[str]) -> None:
    """Refuse an unnamed or a duplicate column as soon as the header is read."""
    empty = [i + 1 for i, name in enumerate(header) if not name]
    if empty:
        raise InputError(f"{path_text(path)}: row {line}: column {empty[0]} has no name")
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise InputError(f"{path_text(path)}: row {line}: column {name!r} appears twice")
        seen.add(name)


def _reads_any(header: list[str]) -> bool:
    """Whether pkmcal reads any of the header's columns (a file of words has none: its first
    row is enough for the caller to name the column it misses)."""
    return any(_column_name_problem(name) is None or _is_numeric(name) for name in header)


class _Lines:
    """The text's lines as the csv module counts them (a line ends at ``\r\n``, ``\n`` or
    ``\r``): their number counted once, in C, and the list split only where a quote makes
    the rows needed (splitting a large text per row took hours, issue 37)."""

    def __init__(self, text: str):
        self.text = text
        self._lines: list[str] | None = None
        self._count: int | None = None

    def count(self) -> int:
        if self._count is None:
            t = self.text
            crlf = t.count("\r\n")
            self._count = t.count("\n") + t.count("\r") - crlf + 1
        return self._count

    def last(self) -> str:
        t = self.text
        return t[max(t.rfind("\n"), t.rfind("\r")) + 1:]

    def get(self) -> list[str]:
        if self._lines is None:
            self._lines = _LINE_BREAK.split(self.text)
        return self._lines


def _refuse_open_quote(path, text: str, fields: list[str], start: int, end: int,
                       header: list[str] | None, lines: _Lines | None = None) -> None:
    """Refuse a record that a quote left open, naming the row the quote opened on.

    The csv module reads a quoted field on over line breaks to its closing quote or to the end
    of the file, and counts the record's rows to where it ended: a record of rows
    ``start..end`` with a line break in a field, or one ending the file without a final line
    break, whose quote is never closed, is refused at row ``start``, column of the field."""
    broken = [i for i, f in enumerate(fields) if "\n" in f or "\r" in f]
    if not broken and (text.endswith(("\n", "\r")) or end != start):
        return
    lines = lines or _Lines(text)
    if not broken:
        # one row, the file without a final line break: only its last row can be open
        if end != lines.count():
            return
        segment = lines.last()
        if not _open_at_end(segment):
            return
    else:
        segment = "".join(lines.get()[start - 1:end])
    i = broken[0] if broken else len(fields) - 1
    column = f", column {header[i]}" if header is not None and 0 <= i < len(header) else ""
    runs = ("to the end of the file" if end == start or _open_at_end(segment)
            else f"on to row {end}, where a quote closes it")
    raise InputError(f"{path}: row {start}{column}: a quote (\") opens a field that this row "
                     f"does not close (the field runs {runs}); remove the quote or close it on "
                     "this row")


#: where the csv module ends a line (its ``line_num``)
_LINE_BREAK = re.compile(r"(?<=\r\n)|(?<=\n)|(?<=\r)(?!\n)")


def _open_at_end(segment: str) -> bool:
    """Whether ``segment`` ends inside a quoted field (a closing quote would complete it)."""
    def parses(t):
        try:
            list(csv.reader(io.StringIO(t, newline=""), strict=True))
        except csv.Error:
            return False
        return True
    return not parses(segment) and parses(segment + '"')


def _check_separator(path, line: int, header: list[str]) -> None:
    """Refuse a header written with another field separator (a spreadsheet's ';' or a tab)."""
    for sep, word in ((";", "semicolon"), ("\t", "tab")):
        if any(sep in name for name in header):
            shown = ",".join(header)
            shown = shown if len(shown) <= 40 else shown[:37] + "..."
            raise InputError(f"{path_text(path)}: "
                             f"row {line}: the header {shown!r} looks {word}-separated; "
                             "pkmcal reads comma-separated values with '.' decimals (export "
                             "the table as CSV with ',' between fields and '.' as the decimal "
                             "mark)")


def _a(word: str) -> str:
    return "an" if word[:1] in "aeiou" else "a"


def find_column(path, header: list[str], base: str, quantity: str | None,
                required: bool = True) -> tuple[int, float] | None:
    """Position and SI factor of the column ``base_<unit>`` (or ``base`` when ``quantity`` is
    None). Raises :class:`InputError` for a missing column, a missing or unknown unit suffix,
    a unit of the wrong quantity, or two columns for the same value."""
    if quantity is None:
        if base in header:
            return header.index(base), 1.0
        if required:
            raise InputError(f"{path_text(path)}: "
                             f"missing column {base}; columns found: {', '.join(header)}")
        return None
    accepted = _suffixes(quantity)
    example = f"{base}_{accepted[0] if quantity != 'length' else 'mm'}"
    candidates = [i for i, n in enumerate(header) if n == base or n.startswith(base + "_")]
    if not candidates:
        if required:
            raise InputError(f"{path_text(path)}: "
                             f"missing column {base}_<unit> (e.g. {example}); columns "
                             f"found: {', '.join(header)}")
        return None
    if len(candidates) > 1:
        names = ", ".join(header[i] for i in candidates)
        raise InputError(f"{path_text(path)}: more than one column for {base}: {names}; keep one")
    i = candidates[0]
    name = header[i]
    if name == base:
        raise InputError(f"{path_text(path)}: column {name!r} has no unit suffix: write {example} "
                         f"(accepted units: {', '.join(accepted)})")
    unit = name[len(base) + 1:]
    if unit not in COLUMN_SUFFIXES:
        raise InputError(f"{path_text(path)}: "
                         f"column {name!r}: unknown unit suffix {unit!r} (accepted "
                         f"for {quantity}: {', '.join(accepted)})")
    if COLUMN_SUFFIXES[unit] != quantity:
        other = COLUMN_SUFFIXES[unit]
        raise InputError(f"{path_text(path)}: "
                         f"column {name!r}: {unit!r} is {_a(other)} {other} unit, "
                         f"{base} is {_a(quantity)} {quantity} (accepted: "
                         f"{', '.join(accepted)})")
    return i, QUANTITIES[quantity][unit]


def parse_number(path, line: int, column: str, text: str) -> float:
    """A finite float from one CSV field, or :class:`InputError` naming file, row, column."""
    where = f"{path_text(path)}: row {line}, column {column}"
    if not text:
        raise InputError(f"{where}: empty value")
    try:
        if "_" in text:
            raise ValueError
        value = float(text)
    except ValueError:
        hint = ""
        if text.count(",") == 1 and "." not in text:
            try:
                float(text.replace(",", "."))
                hint = " (',' as the decimal mark: pkmcal reads '.' decimals)"
            except ValueError:
                pass
        raise InputError(f"{where}: not a number: {text!r}{hint}") from None
    if not math.isfinite(value):
        raise InputError(f"{where}: not a finite number: {text!r}")
    return value


#: largest magnitude of a length (m) or an angle (rad) in a data file: beyond, a value is garbage
#: (1e300 from a broken export), not a measurement
LIMITS = {"length": (1e6, "a length of more than 1000 km"),
          "angle": (1e6, "an angle of more than 1e6 rad")}


def _column_values(path, header, rows: list[Row], index: int, factor: float) -> np.ndarray:
    name = header[index]
    values = np.array([parse_number(path, line, name, f[index]) for line, f in rows]) * factor
    limit = LIMITS.get(COLUMN_SUFFIXES.get(name.rsplit("_", 1)[-1], ""))
    if limit is not None and values.size:
        k = int(np.argmax(np.abs(values)))
        if not abs(values[k]) <= limit[0]:
            line, fields = rows[k]
            raise InputError(f"{path_text(path)}: "
                             f"row {line}, column {name}: {fields[index]} is out of "
                             f"range ({limit[1]})")
    return values
