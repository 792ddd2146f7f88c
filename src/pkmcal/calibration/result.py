"""The result of :func:`~pkmcal.calibration.calibrate`: :class:`Calibration`, and how it
writes the calibrated machine file with its reports (all together or none)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError
from ..instruments.flow import json_safe
from ..instruments.setups import Setups
from ..paths import path_text
from .provenance import report_json, text_digest

__all__ = ["Calibration"]


@dataclass
class Calibration:
    """A calibration of a machine from one data set (:func:`calibrate`).

    Attributes
    ----------
    kind : str
        The measurement kind (a key of :data:`KINDS`).
    machine : Machine
        The machine as given (the nominal, start geometry).
    calibrated : Machine
        The calibrated machine.
    result : CalibrationResult
        The estimator's result.
    report : dict
        The report (what ``pkmcal calibrate`` writes as JSON beside the calibrated file; not
        finite values stay NaN here, :meth:`json_text` makes them null).
    metadata : dict
        The calibrated file's ``calibration:`` section (the report's name and digest are
        added by :meth:`write`).
    params : list of dict
        The parameter table: name, kind, unit, nominal, identified, change, std, fixed and
        the change in scaled units (``scaled_change``).
    warnings : list of str
        What the calibration warns about (rows left out, residuals beyond the noise,
        suspicious changes), each naming the data.
    units : dict
        The units of the machine file (``length``, ``angle``), used by :meth:`write`.
    inputs : list of pathlib.Path
        The files read (never overwritten by :meth:`write`).
    setups : Setups
        The calibrated file's instrument set-ups (:mod:`pkmcal.instruments.setups`): those
        given to :func:`calibrate` with the ones the fit determined in their place.
    """

    kind: str
    machine: object
    calibrated: object
    result: object
    report: dict
    metadata: dict
    params: list
    warnings: list = field(default_factory=list)
    units: dict = field(default_factory=dict)
    inputs: list = field(default_factory=list)
    setups: Setups = field(default_factory=Setups)

    def json_text(self) -> str:
        """The report as JSON text (not finite numbers as null), as :meth:`write` writes it.

        Returns
        -------
        str
            Indented JSON ending with a newline, lists of numbers on one line
            (:func:`report_json`).
        """
        return report_json(json_safe(self.report)) + "\n"

    def write(self, output, report_dir=None) -> str:
        """Write the calibrated machine file, its JSON report beside it (same name, .json) and
        with ``report_dir`` the HTML report and its JSON twin: all together or none.

        Inside an active :class:`~pkmcal.io.atomic.OutputSet` (a ``pkmcal`` command) the
        files are staged in it and the set is committed; else they are written in a set of
        their own. The machine file names its report and pins it by SHA-256; it is checked to
        load back before anything is written.

        Parameters
        ----------
        output : str or os.PathLike
            The calibrated machine file (YAML).
        report_dir : str or os.PathLike, optional
            Directory for ``report.html`` and ``report.json`` (created when missing).

        Returns
        -------
        str
            The JSON report's text.

        Raises
        ------
        InputError
            When ``output`` ends in .json, or an output cannot be written or would replace
            an input.
        """
        from ..io import atomic_write_text, machine_to_text, parse_machine
        from ..io.atomic import OutputSet, active_output_set, is_stream

        output = Path(output)
        if output.suffix.lower() == ".json":
            raise InputError(f"{path_text(output)}: "
                             "the calibrated machine is a YAML file; choose a name "
                             "ending in .yaml (the JSON report is written beside it)")
        report_dir = None if report_dir is None else Path(report_dir)
        report_path = output.with_suffix(".json")
        beside = not is_stream(output)      # no JSON report beside /dev/null or a pipe
        self.report["calibrated_file"] = path_text(output)
        json_text = self.json_text()
        # the machine file names its report and pins it by digest: a report of another run
        # (or a half-replaced pair) is refused by compensate and report
        metadata = {k: v for k, v in self.metadata.items() if k != "report"}
        if beside:
            metadata.update(report=path_text(report_path.name),
                            report_sha256=text_digest(json_text))
        yaml_text = machine_to_text(self.calibrated, self.units, calibration=metadata,
                                    setups=self.setups)
        try:                                    # the calibrated file must load back
            parse_machine(yaml_text, str(output))
        except InputError as exc:
            import re

            what = re.sub(r" \(line \d+\)$", "", str(exc).split(": ", 1)[-1])
            data = self.report.get("data_file") or "the data"
            raise InputError(f"{data}: the calibrated geometry is not a working machine "
                             f"({what}); the data do not determine it, or do not belong to "
                             f"this machine file (see identifiability); {path_text(output)} not "
                             "written") from None
        html_text = None
        if report_dir is not None:
            from ..report.html import build_html

            html_text = build_html(json.loads(json_text))

        def stage():
            # one set: the report, then the machine file that names it, then the report DIR
            if beside:
                atomic_write_text(report_path, json_text)
            atomic_write_text(output, yaml_text)
            if html_text is not None:
                atomic_write_text(report_dir / "report.json", json_text)
                atomic_write_text(report_dir / "report.html", html_text)

        active = active_output_set()
        if active is not None:
            stage()
            active.commit()
        else:
            files = [output] + ([report_path] if beside else [])
            if report_dir is not None:
                files += [report_dir / "report.html", report_dir / "report.json"]
            with OutputSet(files, [report_dir] if report_dir is not None else [],
                           self.inputs):
                stage()
        return json_text
