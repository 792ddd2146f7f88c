"""What a calibration report carries about how it was made, and its JSON text: the machine
file's units, the versions and command line that produced it, a text's digest (how a
calibrated file pins its report)."""

from __future__ import annotations

import json

from ..instruments.flow import json_safe
from ..paths import path_text

__all__ = ["file_units", "json_safe", "provenance", "report_json", "text_digest", "versions"]


def report_json(value, indent: str = "") -> str:
    """JSON text of a JSON-safe value (:func:`json_safe`), indented by two spaces, with every
    list of numbers or strings on one line: a 54 x 54 covariance reads as 54 rows, not 2,916
    lines, and the lines are written by :mod:`json`'s C encoder (an indented dump is not).

    Parameters
    ----------
    value : object
        Dicts, lists, strings, numbers, booleans and None (no NaN: ``ValueError``).
    indent : str, optional
        The indentation of the line the value starts on.

    Returns
    -------
    str
        The text (no final newline); :func:`json.loads` gives ``value`` back.
    """
    if isinstance(value, dict):
        if not value:
            return "{}"
        inner = indent + "  "
        return ("{\n" + ",\n".join(f"{inner}{json.dumps(str(k))}: {report_json(v, inner)}"
                                    for k, v in value.items()) + "\n" + indent + "}")
    if isinstance(value, (list, tuple)) and any(isinstance(v, (dict, list, tuple))
                                                for v in value):
        inner = indent + "  "
        return ("[\n" + ",\n".join(inner + report_json(v, inner) for v in value) + "\n"
                + indent + "]")
    return json.dumps(value, allow_nan=False)


def file_units(machine) -> dict:
    """The units of a machine's file (its ``units`` section), the defaults when it has none.

    Parameters
    ----------
    machine : Machine
        A machine, loaded from a file or not.

    Returns
    -------
    dict
        ``{"length": ..., "angle": ...}``.
    """
    from ..io.machine_file import DEFAULT_UNITS

    return dict(getattr(machine, "file_units", None) or DEFAULT_UNITS)


def text_digest(text: str) -> str:
    """SHA-256 (hex) of a text's UTF-8 bytes: how a calibrated file pins its JSON report.

    Parameters
    ----------
    text : str
        The text.

    Returns
    -------
    str
        64 hexadecimal digits.
    """
    import hashlib

    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def versions(*extra: str) -> dict:
    """Versions of Python, pkmcal, numpy, scipy and the ``extra`` packages.

    Parameters
    ----------
    *extra : str
        Further distribution names.

    Returns
    -------
    dict
        Name -> version (None: not installed).
    """
    import platform
    from importlib.metadata import PackageNotFoundError, version

    out = {"python": platform.python_version()}
    for name in ("pkmcal", "numpy", "scipy", *extra):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = None
    return out


def provenance() -> dict:
    """The command line, the versions and the platform that produce a report.

    Returns
    -------
    dict
        ``command`` (``pkmcal`` and this process's arguments), the :func:`versions` and
        ``platform``.
    """
    import platform
    import shlex
    import sys

    def word(arg: str) -> str:
        # a name that is not UTF-8 as bash's $'...' (path_text's \xNN): UTF-8 text that
        # still runs
        text = path_text(arg)
        if text == arg:
            return shlex.quote(arg)
        return "$'" + text.replace("'", "\\'") + "'"

    return {"command": "pkmcal " + " ".join(word(a) for a in sys.argv[1:]), **versions(),
            "platform": platform.platform()}
