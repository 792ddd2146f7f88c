"""``pkmcal calibrate`` as a library function: the machine and data named, the outputs checked
first, :func:`pkmcal.calibration.calibrate`, the answer (:mod:`pkmcal.analysis.outcome`), the
calibrated file with its JSON report (and the HTML report) written all or none, and the
summary returned (:func:`pkmcal.report.calibration_summary.calibrate_summary`)."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..io.atomic import is_stream
from ..paths import path_text
from ..report.calibration_summary import calibrate_summary
from ..report.summary import Summary
from .common import check_outputs, load_machine_setups_arg, machine_inputs, wrote

__all__ = ["calibrate_files"]


def calibrate_files(machine_spec: str, data_path, output: Path, noise=None,
                    json_output: bool = False, robust: bool = False,
                    report_dir: Path | None = None, holdout: str | None = None, seed: int = 0,
                    parameters: str | None = None, options: dict | None = None) -> Summary:
    """Calibrate a machine file from data files and write the calibrated machine file, its
    JSON report beside it and, with ``report_dir``, the HTML report (all or none).

    Parameters
    ----------
    machine_spec : str
        The machine file, or ``default``.
    data_path : path or list of paths
        The data file(s); several are fitted together.
    output : Path
        The calibrated machine file (YAML); the JSON report is written beside it.
    noise, robust, holdout, seed, parameters
        As :func:`pkmcal.calibration.calibrate` takes them (``noise``: one text, or one
        ``FILE=VALUE`` text per file).
    options : dict, optional
        The instruments' own options by name (``{"bed_tilt": "square"}``), each declared by
        its instrument (:attr:`~pkmcal.instruments.base.Instrument.Options`).
    json_output : bool, optional
        The summary is the JSON report itself (raw text) and the warnings.
    report_dir : Path, optional
        Directory of ``report.html`` and ``report.json``.

    Returns
    -------
    Summary
        The answer, the details, the largest changes, the instrument's notes, the "wrote"
        line and the warnings (or, with ``json_output``, the JSON text and the warnings).

    Raises
    ------
    InputError
        Bad input or options (nothing written).
    ConvergenceError
        The fit ran and did not succeed (nothing written).
    """
    from ..analysis.outcome import calibration_outcome
    from ..calibration.run import calibrate, noise_per_file_arg

    paths = list(data_path) if isinstance(data_path, (list, tuple)) else [data_path]
    noise = noise_per_file_arg(noise if isinstance(noise, (list, tuple)) or noise is None
                               else [noise], paths)
    data_path = paths[0] if len(paths) == 1 else paths
    output = Path(output)
    if output.suffix.lower() == ".json":
        raise InputError(f"{path_text(output)}: "
                         "the calibrated machine is a YAML file; choose a name "
                         "ending in .yaml (the JSON report is written beside it)")
    report_path = output.with_suffix(".json")
    machine, file_setups = load_machine_setups_arg(machine_spec)
    outputs = [output] + ([] if is_stream(output) else [report_path])
    if report_dir is not None:
        report_dir = Path(report_dir)
        if report_dir.exists() and not report_dir.is_dir():
            raise InputError(f"--report {report_dir}: a file, not a directory")
        outputs += [report_dir / "report.html", report_dir / "report.json"]
    check_outputs(outputs, [Path(p) for p in paths] + machine_inputs(machine_spec),
                  [report_dir] if report_dir is not None else [])
    calibration = calibrate(machine, data_path, noise=noise, robust=robust, holdout=holdout,
                            seed=seed, parameters=parameters, options=options,
                            setups=file_setups)
    # the answer (verdict, accuracy before and after, what changed, what next): the report's
    # first section, and the summary's first rows
    calibration.report["outcome"] = calibration_outcome(calibration, path_text(output),
                                                        setups=file_setups)
    # staged first: a calibrated geometry that cannot be written is the one message (exit 2)
    json_text = calibration.write(output, report_dir)
    if json_output:
        summary = Summary()
        summary.raw(json_text)
    else:
        shown = data_path if len(paths) == 1 else ", ".join(map(str, paths))
        summary = calibrate_summary(
            calibration.report, calibration.params, calibration.kind, machine.source,
            str(shown), report_path,
            report_dir / "report.html" if report_dir is not None else report_path)
        summary.line(wrote(output, report_path))
    # each warning once, after the summary (the summary's verdict row points to it)
    for text in calibration.warnings:
        summary.warn(text)
    return summary
