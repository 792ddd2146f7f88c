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
    """Data files that are a firmware's saved state (a Klipper ``printer.cfg`` with
    ``[delta_calibrate]`` data) or a pasted probe report (Marlin ``Bed X: Y: Z:`` lines,
    RepRapFirmware's ``bed probe heights`` reply:
    :func:`~pkmcal.export.firmware_reports.probe_report_data`) replaced by the measurements they
    hold.

    Parameters
    ----------
    data : path, data object or list of them
        What :func:`calibrate` was given.
    machine : Machine
        The machine.

    Returns
    -------
    object or list
        ``data`` with each firmware file replaced by its data objects (a list when that gives
        more than one).
    """
    from ..export.firmware_reports import is_probe_report, probe_report_data, read_probe_report
    from ..io.atomic import read_input_text
    from ..io.klipper_data import is_klipper_config, read_klipper_data

    items = list(data) if isinstance(data, (list, tuple)) else [data]
    out, changed = [], False
    configs = [item for item in items if isinstance(item, (str, Path)) and Path(item).is_file()
               and is_klipper_config(item, _head(item))]
    if len(configs) > 1:
        # several of a printer's configs (printer.cfg, its backups): sessions, the same saved
        # points counted once, each session its own endstop offsets
        from ..io.klipper_data import klipper_sessions

        found = klipper_sessions(configs, machine).data
        for obj in found:
            obj.origin = next((c for c in configs if str(obj.source).startswith(str(c))),
                              configs[0])
        first = items.index(configs[0])
        items = [item for item in items if item not in configs]
        out = [item for item in items[:first]] + found
        items = items[first:]
        changed = True
    for item in items:
        if isinstance(item, (str, Path)) and Path(item).is_file():
            try:
                with open(item, encoding="utf-8", errors="replace") as f:
                    head = f.read(4096)
            except OSError:
                head = ""
            found = []
            if is_klipper_config(item, head):
                found = read_klipper_data(item, machine)
            elif not str(item).lower().endswith(".csv") and is_probe_report(head):
                text = read_input_text(item, "probe report")
                found = [probe_report_data(read_probe_report(text, str(item)), machine)]
            if found:
                for obj in found:
                    obj.origin = item           # --noise FILE=VALUE names the file given
                out.extend(found)
                changed = True
                continue
        out.append(item)
    if not changed:
        return data
    return out[0] if len(out) == 1 else out
