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


def run_calibrate(machine_spec: str, data_path, output: Path, method: str | None,
                  noise, estimate_lc: bool | None, json_output: bool,
                  two_step: bool = False, robust: bool = False, pose_noise=None,
                  fix_frames: bool = False, report_dir: Path | None = None,
                  holdout: str | None = None, seed: int = 0,
                  parameters: str | None = None, extensions: str | None = None,
                  bed_tilt: str | None = None) -> int:
    from ..errors import ConvergenceError
    from ..workflows.calibrate import calibrate_files
    from ._console import print_summary

    try:
        summary = calibrate_files(machine_spec, data_path, output, method, noise, estimate_lc,
                                  json_output, two_step, robust, pose_noise, fix_frames,
                                  report_dir, holdout, seed, parameters, extensions, bed_tilt)
    except ConvergenceError as exc:     # the fit ran and did not succeed: exit 1, nothing written
        error(str(exc))
        return 1
    return print_summary(summary)


