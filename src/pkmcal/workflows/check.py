"""``pkmcal check`` as a library function: a calibrated or imported machine scored on data it
was not fitted to (:func:`pkmcal.calibration.check.check`), with its verdict."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..io import atomic_write_text
from ..paths import path_text
from ..report.summary import Summary
from ..units import format_um
from .common import (
    check_outputs,
    commit_outputs,
    load_machine_setups_arg,
    machine_inputs,
)

__all__ = ["check"]


def check(machine_spec: str, data_paths, noise=None, output: Path | None = None) -> Summary:
    """``pkmcal check``: the machine's parameters held, each data file's residuals against
    its noise and the verdict.

    Parameters
    ----------
    machine_spec : str
        A machine file, or ``"default"``.
    data_paths : sequence of Path
        Data the machine was not fitted to: measurement files of any instrument, Klipper
        configs (sessions), pasted probe reports.
    noise : sequence of str, optional
        ``FILE=VALUE`` per file (``probe.csv=20um``); default each instrument's.
    output : Path, optional
        Also write the check's report (JSON) here.

    Returns
    -------
    Summary
        A table titled ``pkmcal check: MACHINE on DATA``: a row per file (RMS, largest
        residual and its row, the ratio to the noise, explained or not), ``verdict``,
        ``free`` (the offsets left free) and a ``drift`` row per session; then ``wrote
        OUTPUT`` when written. Its exit code is 0 whatever the verdict.

    Raises
    ------
    InputError
        Bad input (a file, row, column or option named); nothing is written then.
    """
    from ..calibration.check import check as score
    from ..calibration.run import json_safe, noise_per_file_arg, report_json

    paths = list(data_paths)
    noise = noise_per_file_arg(noise, paths) if noise else None
    if isinstance(noise, str):
        raise InputError("--noise: give FILE=VALUE per file (e.g. --noise probe.csv=20um)")
    machine, file_setups = load_machine_setups_arg(machine_spec)
    if output is not None:
        check_outputs([output], paths + machine_inputs(machine_spec))
    result = score(machine, paths, noise=noise, setups=file_setups)
    if output is not None:
        text = report_json(json_safe(result.report))
        atomic_write_text(output, text if text.endswith("\n") else text + "\n")
        commit_outputs()
    summary = Summary()
    table = summary.pairs(title=f"pkmcal check: {path_text(machine_spec)} on "
                                f"{', '.join(path_text(p) for p in paths)}")
    for f in result.report["files"]:
        table.add_row(f["label"], f"{f['measurement']}, {f['rows']} rows: RMS "
                      f"{format_um(f['rms_um'])}, max {format_um(f['max_um'])} (row "
                      f"{f['max_row']}); {f['noise_ratio']:.3g}x the noise ({f['noise']}): "
                      + ("explained" if f["explained"] else
                         f"not explained (at most {f['noise_ratio_limit']:.3g}x)"))
    table.add_row("verdict", result.report["verdict"]["text"])
    table.add_row("free", result.report["offsets_are"])
    for line in result.lines:
        if line.startswith("session "):
            table.add_row("drift", line)
    if output is not None:
        summary.line(f"wrote {path_text(output)}")
    return summary
