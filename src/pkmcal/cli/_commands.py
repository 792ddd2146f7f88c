"""Implementations of the ``pkmcal`` commands (imported lazily by :mod:`pkmcal.cli`).

Every command validates its inputs and options first, computes, and writes its output files
only at the very end, atomically; problems are raised as :class:`~pkmcal.errors.InputError`
(exit code 2 in :func:`pkmcal.cli.main`).
"""

from __future__ import annotations

from pathlib import Path

from ._console import error

# --------------------------------------------------------------------------------------------
# calibrate (the calibration itself is pkmcal.calibration.calibrate)
# --------------------------------------------------------------------------------------------


def run_calibrate(machine_spec: str, data_path, output: Path, noise, json_output: bool,
                  robust: bool = False, report_dir: Path | None = None,
                  holdout: str | None = None, seed: int = 0, parameters: str | None = None,
                  options: dict | None = None) -> int:
    from ..errors import ConvergenceError
    from ..workflows.calibrate import calibrate_files
    from ._console import print_summary

    try:
        summary = calibrate_files(machine_spec, data_path, output, noise, json_output, robust,
                                  report_dir, holdout, seed, parameters, options)
    except ConvergenceError as exc:     # the fit ran and did not succeed: exit 1, nothing written
        error(str(exc))
        return 1
    return print_summary(summary)


