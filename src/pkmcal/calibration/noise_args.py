"""The options of :func:`~pkmcal.calibration.calibrate` given as the user's strings that are
not an instrument's: ``--holdout`` and ``--noise`` per data file (``FILE=VALUE``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..paths import same_file

__all__ = ["holdout_arg", "noise_per_file_arg", "noise_of", "noise_through_expansion"]


def holdout_arg(text: str) -> float:
    """``--holdout``: a share (0.2 or 20%) or a whole number of rows (30).

    Parameters
    ----------
    text : str
        The option's text.

    Returns
    -------
    float
        The share (< 1) or the count; the range is checked against the data by
        :func:`~pkmcal.calibration.holdout_split`.

    Raises
    ------
    InputError
        When the text is neither.
    """
    t = text.strip()
    try:
        value = float(t[:-1]) / 100 if t.endswith("%") else float(t)
    except ValueError:
        value = float("nan")
    if not np.isfinite(value) or (t.endswith("%") and not 0 < value < 1):
        raise InputError(f"--holdout {text}: give the share of rows to hold out (e.g. 0.2 or "
                         "20%) or their number (e.g. 30)")
    return value


def noise_per_file_arg(texts, sources) -> dict | str | None:
    """``--noise`` of several files: ``FILE=VALUE`` per file (files without one: the kind's
    default).

    Parameters
    ----------
    texts : list of str or None
        The option's values as given.
    sources : list of str or os.PathLike
        The data files.

    Returns
    -------
    dict or str or None
        One file: its value (or None); several: file (as given) -> value.

    Raises
    ------
    InputError
        When a value names no data file, a file twice, or (several files) has no ``FILE=``.
    """
    texts = list(texts or [])
    if len(sources) <= 1:
        if len(texts) > 1:
            raise InputError("--noise: given more than once for one data file")
        if texts and "=" in texts[0]:
            name, value = texts[0].split("=", 1)
            if not value.strip():
                raise InputError(f"--noise {texts[0]}: no value after '='")
            if _match_file(name, sources) is None:
                raise InputError(f"--noise {texts[0]}: {name} is not the data file "
                                 f"({sources[0]})")
            return value
        return texts[0] if texts else None
    out: dict = {}
    for text in texts:
        if "=" not in text:
            raise InputError(f"--noise {text}: with several data files give FILE=VALUE per "
                             "file (e.g. --noise bar.csv=2um); the levels of files without "
                             "one are estimated")
        name, value = text.split("=", 1)
        if not value.strip():
            raise InputError(f"--noise {text}: no value after '=' (e.g. --noise "
                             f"{name.strip() or 'bar.csv'}=2um)")
        i = _match_file(name, sources)
        if i is None:
            raise InputError(f"--noise {text}: {name} is none of the data files ("
                             + ", ".join(map(str, sources)) + ")")
        if str(sources[i]) in out:
            raise InputError(f"--noise: {sources[i]} given twice")
        out[str(sources[i])] = value
    return out


def _match_file(name: str, sources) -> int | None:
    """Index of the data file ``name`` names (as given, or its file name when unique)."""
    from ..instruments.joint import file_labels

    name = name.strip()
    if not name:
        return None
    for i, s in enumerate(sources):
        if str(s) == name or Path(str(s)) == Path(name):
            return i
    for i, s in enumerate(sources):        # the same file by another name (links, spelling)
        if isinstance(s, (str, Path)) and same_file(s, name):
            return i
    labels = file_labels(sources)
    if name in labels:
        return labels.index(name)
    return None


def noise_of(noise, sources, i: int):
    """The noise of file ``i`` of ``sources``: from a mapping (key: the file as given, its
    index, or its label - the file name, ``a.csv#2`` for the second of one name), else the
    value given (one file) or the default (several)."""
    if isinstance(noise, dict):
        # one matching for the command line's FILE=VALUE and a Python mapping; a key that
        # names no file is refused (it would leave that file's level estimated silently)
        import numbers

        found, seen = None, {}
        for key, value in noise.items():
            at = (int(key) if isinstance(key, numbers.Integral) and not isinstance(key, bool)
                  and 0 <= int(key) < len(sources) else
                  _match_file(str(key), sources) if isinstance(key, (str, Path)) else None)
            if at is None:
                raise InputError(f"noise: {key!r} is none of the data files ("
                                 + ", ".join(map(str, sources)) + ")")
            if at in seen:
                raise InputError(f"noise: {seen[at]!r} and {key!r} name the same data file "
                                 f"({sources[at]})")
            seen[at] = key
            if at == i:
                found = value
        return found
    if noise is not None and len(sources) > 1:
        raise InputError("--noise: with several data files give FILE=VALUE per file (e.g. "
                         "--noise bar.csv=2um)")
    return noise


def noise_through_expansion(noise, given, data):
    """``--noise`` for files a firmware reader expanded into several data objects (a
    printer.cfg's heights and distances): the value given for the file (its FILE=VALUE, or
    the one value for one file) holds the level of every measurement read from it."""
    if noise is None or data is given:
        return noise
    items = list(given) if isinstance(given, (list, tuple)) else [given]
    sources = [item if isinstance(item, (str, Path)) else getattr(item, "source", None)
               or f"data{i + 1}" for i, item in enumerate(items)]
    objects = list(data) if isinstance(data, (list, tuple)) else [data]
    out = {}
    for i, item in enumerate(items):
        value = noise_of(noise, sources, i) if isinstance(noise, dict) or len(items) > 1 \
            else noise
        if value is None:
            continue
        mine = [o for o in objects if getattr(o, "origin", None) == item] or \
            [o for o in objects if o is item]
        for obj in mine:
            out[getattr(obj, "source", None) or str(obj)] = value
    return out or None
