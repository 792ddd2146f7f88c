"""G-code text as users paste it: a firmware's file, its replies, a printer's host or terminal
log (an OctoPrint ``serial.log``, a Pronterface log). What the host and the firmware put
before each line is taken off, commands the host sent are told from the firmware's replies,
and a line's command and letter words are read. Marlin's and RepRapFirmware's files and
probe reports are read through it."""

from __future__ import annotations

import re

from ..errors import InputError

__all__ = ["gcode_line_kind", "gcode_lines", "gcode_words", "host_line"]

#: a host's time stamp (OctoPrint's ``serial.log``: ``2024-05-01 12:00:00,123 - ``)
_TIME_STAMP = re.compile(r"^\d{4}-\d\d-\d\d[ T]\d\d:\d\d:\d\d(?:[,.]\d+)?\s+-\s+")
#: what a host sent (OctoPrint ``Send:``, Pronterface ``SENDING:``, ``>>>``)
_SENT = re.compile(r"^(?:Send:|SENDING:|>>>)\s*", re.I)
#: what a host received (OctoPrint ``Recv:``, ``<<<``)
_RECEIVED = re.compile(r"^(?:Recv:|<<<)\s*", re.I)


def host_line(raw: str) -> tuple[str, bool]:
    """One line of a pasted text without what a host or the firmware put before it.

    Removed: a ``serial.log`` time stamp, OctoPrint's ``Recv:``, Marlin's ``echo:`` (its
    ``SERIAL_ECHO_START``, as ``M503`` prints every line) and a leading ``ok``.

    Parameters
    ----------
    raw : str
        The line.

    Returns
    -------
    text : str
        The line's content, stripped.
    sent : bool
        The host sent it (``Send:``, ``SENDING:``, ``>>>``): a command, not the firmware's
        report.
    """
    line = _TIME_STAMP.sub("", raw.strip())
    if _SENT.match(line):
        return _SENT.sub("", line).strip(), True
    line = _RECEIVED.sub("", line)
    previous = None
    while previous != line:
        previous, line = line, re.sub(r"^(?:echo:|ok\b)\s*", "", line, flags=re.I)
    return line.strip(), False


def gcode_words(line: str, source: str, n: int, code: str) -> dict:
    """The letter words of one G-code line (``X1.5 Y-2``), values as text.

    Parameters
    ----------
    line : str
        The line without its comment and command.
    source : str
        The file's name.
    n : int
        1-based line number.
    code : str
        The command, for messages.

    Returns
    -------
    dict
        Upper-case letter -> value text.

    Raises
    ------
    InputError
        For a word without a value.
    """

    pair = r"[A-Za-z][-+]?[0-9.]+"
    words = []
    tokens = line.split()
    k = 0
    while k < len(tokens):
        tok = tokens[k]
        if not tok[0].isalpha():
            raise InputError(f"{source}: line {n}: {code}: {tok!r} is not a letter word")
        exponent = re.search(r"\d[eE][-+]?\d", tok)       # 1e9 is one number, not 1 and E9
        if len(tok) > 1 and not exponent and re.fullmatch(f"({pair}){{2,}}", tok):
            # several words without spaces ("H285L250"), as Marlin reads them
            words += [(w[0], w[1:]) for w in re.findall(pair, tok)]
        else:
            value = tok[1:]
            if not value and k + 1 < len(tokens) and not tokens[k + 1][0].isalpha():
                k += 1
                value = tokens[k]               # "L 250": the value after a space
            words.append((tok[0], value))
        k += 1
    out = {}
    for letter, value in words:
        letter = letter.upper()
        if not value:
            raise InputError(f"{source}: line {n}: {code} {letter}: no value")
        if letter in out:
            raise InputError(f"{source}: line {n}: {code} {letter}: given twice")
        out[letter] = value
    return out


_COMMAND = re.compile(r"^(?:N\d+\s*)?[GMT]\d", re.I)


def gcode_line_kind(raw: str) -> bool | None:
    """Whether a line is G-code: a command (``G``, ``M``, ``T`` and a number, after a host
    log's prefixes, :func:`host_line`) True, a blank line or a comment None, anything else
    False (for :func:`~pkmcal.export.base.refuse_foreign_text`).

    Parameters
    ----------
    raw : str
        The line.

    Returns
    -------
    bool or None
        As above.
    """
    line, _ = host_line(raw)
    line = re.sub(r"\([^)]*\)", " ", line.split(";", 1)[0]).strip()
    if not line:
        return None
    return bool(_COMMAND.match(line))


def gcode_lines(text: str, codes: tuple, sent: bool = False):
    """The lines of a G-code file with one of the commands (``M665``), comments removed.

    Marlin's ``M503`` report (``echo:  M665 L...``), host logs (:func:`host_line`), line
    numbers (``N12``) and checksums (``*71``) are accepted; lines a host sent are skipped
    unless ``sent``.

    Parameters
    ----------
    text : str
        The file's text.
    codes : tuple of str
        Commands, upper case.
    sent : bool, optional
        Also yield the commands a host log shows as sent.

    Yields
    ------
    tuple
        ``(line number, command, rest of the line)``.
    """
    for n, raw in enumerate(text.splitlines(), 1):
        line, was_sent = host_line(raw)
        if was_sent and not sent:
            continue
        line = line.split(";", 1)[0]
        line = re.sub(r"\([^)]*\)", " ", line)
        line = re.sub(r"\*\d+\s*$", "", line).strip()
        line = re.sub(r"^N\d+\s+", "", line, flags=re.I)
        m = re.match(r"([GMgm])0*(\d+)(?=\s|$|[A-Za-z])(.*)", line)
        if m and f"{m.group(1).upper()}{m.group(2)}" in codes:
            yield n, f"{m.group(1).upper()}{m.group(2)}", m.group(3)
