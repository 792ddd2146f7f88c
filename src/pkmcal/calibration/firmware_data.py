"""Data files that are a firmware's saved state rather than a CSV file: read for the
measurements they hold before :func:`~pkmcal.calibration.calibrate` tells their kinds."""

from __future__ import annotations

from pathlib import Path

__all__ = ["expand_firmware_data"]


def _head(item) -> str:
    """A data file's first 4 kB (empty when it cannot be read)."""
    try:
        with open(item, encoding="utf-8", errors="replace") as f:
            return f.read(4096)
    except OSError:
        return ""


def expand_firmware_data(data, machine):
    """Data files that are a controller's saved files holding measurements replaced by the
    measurements they hold: each controller format of :mod:`pkmcal.export` says which files
    are its own and reads them (:meth:`~pkmcal.export.base.ControllerFormat.
    holds_measurements`, :meth:`~pkmcal.export.base.ControllerFormat.read_measurements`:
    a Klipper ``printer.cfg`` with ``[delta_calibrate]`` data, several of them as one
    printer's sessions; a pasted Marlin or RepRapFirmware probe report).

    Parameters
    ----------
    data : path, data object or list of them
        What :func:`calibrate` was given.
    machine : Machine
        The machine.

    Returns
    -------
    object or list
        ``data`` with each such file replaced by its data objects, in its place (files read
        together in the first one's place; a list when that gives more than one). Each data
        object's ``origin`` is the file given (``--noise FILE=VALUE`` names it).
    """
    from ..export.base import load_formats

    items = list(data) if isinstance(data, (list, tuple)) else [data]
    files = {i: item for i, item in enumerate(items)
             if isinstance(item, (str, Path)) and Path(item).is_file()}
    if all(str(item).lower().endswith(".csv") for item in files.values()):
        return data         # pkmcal's own CSV files: no controller's file to look for
    heads = {i: _head(item) for i, item in files.items()}
    placed, claimed = {}, set()
    for fmt in load_formats().values():
        mine = [i for i in files
                if i not in claimed and fmt.holds_measurements(files[i], heads[i])]
        if not mine:
            continue
        groups = [mine] if fmt.measurements_together and len(mine) > 1 else [[i] for i in mine]
        for group in groups:
            paths = [files[i] for i in group]
            found = fmt.read_measurements(paths, machine)
            if not found:                   # holds none: read as a CSV file
                continue
            for obj in found:
                obj.origin = next((p for p in paths if str(obj.source).startswith(str(p))),
                                  paths[0])
            placed[group[0]] = found
            claimed.update(group)
    if not claimed:
        return data
    out = []
    for i, item in enumerate(items):
        if i in placed:
            out.extend(placed[i])
        elif i not in claimed:
            out.append(item)
    return out[0] if len(out) == 1 else out
