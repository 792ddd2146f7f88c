"""One calibration of a machine from a data file, as ``pkmcal calibrate`` runs it.

:func:`calibrate` tells the measurement kind from the data's columns, checks the options that
apply to it, holds out rows for validation when asked, runs the kind's estimator and builds
the report (the JSON ``pkmcal calibrate`` writes beside the calibrated file) and the
calibrated file's ``calibration:`` section. It prints nothing: what the command prints as
warnings is in :attr:`Calibration.warnings`. :meth:`Calibration.write` writes the calibrated
machine file, its report and optionally the HTML report, all together or none.

Measurement kinds are entries of :data:`KINDS`, one per instrument of the registry
(:mod:`pkmcal.instruments.registry`): an instrument with a calibration flow of its own
(:meth:`~pkmcal.instruments.base.Instrument.calibrate`, given only the options its
``Options`` declare) is dispatched by :func:`flow_kind`, one bringing only a model by the generic
path (:func:`instrument_kind`), and handlers registered here (:func:`register_kind`) take
precedence. Every flow ends the same way (:func:`_finish`: covariance, residual verdict,
acceptance, provenance). Adding an instrument is adding its module; neither this module, the
estimator nor the command line changes.

Options may be given as the user's strings (``"2um"``, ``"leica"``, ``"20um,50urad"``,
``"20%"``), parsed with the messages of the command line, or as SI numbers and noise models.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..estimation.acceptance import WHITENED_METHODS
from ..estimation.sections import add_sections
from ..instruments.flow import (
    CalibrationNotConverged,
    FlowContext,
    JointPart,
    fit_with_baseline,
    json_safe,
    report_head,
    rows_text,
    scalar_metadata,
    scalar_residuals_json,
    variance_json,
)
from ..instruments.flow import convergence_json as _convergence_json
from ..instruments.flow import identifiability_json as _identifiability_json
from ..instruments.flow import identifiability_metadata as _identifiability_metadata
from ..instruments.flow import load_data as _load
from ..instruments.flow import only_for_poses as _only_for_poses
from ..instruments.flow import parameter_table as _parameter_table
from ..instruments.flow import public_parameters as _public
from ..instruments.flow import require_converged as _require_converged
from ..instruments.flow import scalar_rms as _scalar_rms
from ..instruments.flow import source_of as _source_of
from ..instruments.flow import split_rows as _split_rows
from ..instruments.flow import um as _um
from ..instruments.flow import validation_section as _validation
from ..instruments.setups import legacy_setups
from ..paths import file_identity, path_text, same_file
from .bed_surface import with_bed_surface
from .parameter_sets import apply_parameter_set, parameter_set_names
from .tolerances import tolerance_report

__all__ = ["KINDS", "WHITENED_METHODS", "Calibration",
           "CalibrationNotConverged", "CalibrateOptions", "JointPart", "MeasurementKind",
           "apply_parameter_set", "calibrate", "calibrate_joint", "file_units", "flow_kind",
           "holdout_arg", "json_safe", "report_json", "measurement_kind", "noise_per_file_arg",
           "parameter_set_names", "provenance", "register_kind",
           "rows_text", "supported_kinds", "text_digest", "versions"]


# --------------------------------------------------------------------------------------------
# small helpers shared with the command line
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# options given as the user's strings
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# measurement kinds
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CalibrateOptions:
    """The options of :func:`calibrate` a measurement kind may use or refuse.

    Attributes
    ----------
    method : str or None
        Estimation method (kind-specific; None: the kind's default).
    noise : object
        Noise of the measurements: the user's text, or an SI number / noise model.
    pose_noise : str or None
        Noise of measured poses (full-pose data), ``POSITION,ORIENTATION``.
    estimate_lc : bool or None
        Constraint link: estimate the link length (None: the method's default).
    two_step : bool
        Tracker: registration first, then the errors.
    robust : bool
        Tracker: find and leave out outliers.
    fix_frames : bool
        Full pose: hold the measurement frames at the machine file's.
    extensions : str or None
        ``"auto"``: try the machine's model extensions, adopted by cross-validation
        (full poses); ``"none"``: the plain model; None: not asked for (``"auto"`` where the
        data take extensions).
    bed_tilt : str or None
        Probe heights on a printer: ``"auto"`` (None), ``"estimate"`` or ``"square"``
        (:func:`~pkmcal.instruments.probe.bed_choice`).
    """

    method: str | None = None
    noise: object = None
    pose_noise: str | None = None
    estimate_lc: bool | None = None
    two_step: bool = False
    robust: bool = False
    fix_frames: bool = False
    extensions: str | None = None
    bed_tilt: str | None = None


@dataclass(frozen=True)
class MeasurementKind:
    """How :func:`calibrate` calibrates from one instrument's data (the calibration layer's
    part of an instrument of :mod:`pkmcal.instruments.registry`).

    What its files hold, how they are recognised, which machines it applies to: the
    instrument's (:attr:`columns`, :meth:`detect`, ...); how the calibration layer fits and
    reports it: this entry's handlers.

    Attributes
    ----------
    instrument : str
        The instrument's registry name (also the report's ``measurement``).
    calibrate : callable
        ``calibrate(machine, data, source, options, split) -> Calibration``; ``data`` is a
        path or a data object, ``split`` None or ``(holdout, seed)``.
    check_options : callable
        ``check_options(options, source)``: raise :class:`InputError` for options that do not
        apply.
    joint : callable or None
        ``joint(machine, data, source, noise) -> JointPart``: the file's part of a fit of
        several files (None, or None returned: from the instrument problem of its own
        calibration, unless the instrument's ``joint_refusal`` says why it cannot combine).
    """

    instrument: str
    calibrate: Callable
    check_options: Callable
    joint: Callable | None = None

    @property
    def entry(self):
        """The instrument (:func:`~pkmcal.instruments.registry.instrument`)."""
        from ..instruments.registry import instrument

        return instrument(self.instrument)

    @property
    def name(self) -> str:
        """The kind's name: the instrument's."""
        return self.entry.name

    def __getattr__(self, attr):
        # what the data are (columns, detect, priority, readings_only, missing,
        # fixes_lengths, data_class, joint_refusal): the instrument's
        if attr.startswith("_") or attr in ("instrument", "calibrate", "check_options", "joint"):
            raise AttributeError(attr)
        return getattr(self.entry, attr)

    def why_not(self, machine) -> str | None:
        """Why ``machine`` cannot be calibrated from this kind (None: it can).

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        str or None
            The instrument's reason (:meth:`~pkmcal.instruments.base.Instrument.applies`).
        """
        return self.entry.applies(machine)


#: the measurement kinds :func:`calibrate` knows, by name (:func:`register_kind`)
KINDS: dict[str, MeasurementKind] = {}


def register_kind(kind: MeasurementKind) -> MeasurementKind:
    """Make a measurement kind known to :func:`calibrate` (replacing one of the same name).

    Parameters
    ----------
    kind : MeasurementKind
        The kind.

    Returns
    -------
    MeasurementKind
        ``kind``.
    """
    KINDS[kind.name] = kind
    return kind


def _kinds() -> list[MeasurementKind]:
    """Every instrument's calibration (its registered handlers, else its own flow, else the
    generic path), in the order data files are recognised."""
    from ..instruments.registry import INSTRUMENTS

    for name, inst in INSTRUMENTS.items():
        if name in KINDS:
            continue
        if inst.Options is not None:
            KINDS[name] = flow_kind(inst)
        elif inst.fit_model is not None:
            KINDS[name] = instrument_kind(inst)
    return sorted(KINDS.values(), key=lambda k: k.priority)


def supported_kinds(machine) -> dict[str, str]:
    """The measurement kinds ``machine`` can be calibrated from, with the columns they need.

    Parameters
    ----------
    machine : Machine
        The machine.

    Returns
    -------
    dict
        Kind name -> what its data file holds.
    """
    return {k.name: k.columns for k in _kinds() if k.why_not(machine) is None}


def measurement_kind(path, header: list[str], machine) -> str:
    """The measurement kind of a data file, from its columns, for ``machine``.

    Parameters
    ----------
    path : str or os.PathLike
        The data file (named in messages).
    header : list of str
        Its column names.
    machine : Machine
        The machine to calibrate.

    Returns
    -------
    str
        A key of :data:`KINDS`.

    Raises
    ------
    InputError
        When the columns match no kind, or ``machine`` cannot be calibrated from that kind.
    """
    supported = supported_kinds(machine)
    need = "; ".join(f"{k}: {v}" for k, v in supported.items()) or "none yet"
    matches = [k for k in _kinds() if k.detect(header) and not k.readings_only]
    if len(matches) > 1:
        raise InputError(f"{path_text(path)}: "
                         f"columns of {len(matches)} kinds of measurement in one file ("
                         + "; ".join(f"{k.name}: {k.columns}" for k in matches)
                         + "): give each instrument's rows in a file of its own (several files "
                         "are fitted together: pkmcal calibrate MACHINE A.csv B.csv)")
    found = next((k for k in _kinds() if k.detect(header)), None)
    if found is None:
        raise InputError(f"{path_text(path)}: cannot tell the measurement type from the columns "
                         f"({', '.join(header)}); a {machine.kind} is calibrated from {need}")
    if found.name not in supported:
        hints = [KINDS[k].missing for k in supported if KINDS[k].missing]
        if found.readings_only and found.instrument == machine.default_instrument:
            # the machine's own instrument lacks something in the machine file
            raise InputError(f"{_source_of(machine)}: {found.why_not(machine)}; {path_text(path)} "
                             "has "
                             f"joint readings alone ({found.name} data)")
        if found.readings_only and hints:
            columns, words = hints[0]
            raise InputError(f"{path_text(path)}: missing columns {columns}: a {machine.kind} is "
                             f"calibrated from {words} ({need}); columns found: "
                             f"{', '.join(header)}")
        raise InputError(f"{path_text(path)}: "
                         f"{found.name} measurements cannot calibrate a {machine.kind}: "
                         f"{found.why_not(machine)}; a {machine.kind} is calibrated from "
                         f"{need}")
    return found.name


def _names_of(kind: MeasurementKind) -> tuple:
    """The kind's names: its instrument's and the instrument's aliases."""
    return (kind.entry.name, *kind.entry.aliases)




# --------------------------------------------------------------------------------------------
# the result
# --------------------------------------------------------------------------------------------


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
                                    setups=legacy_setups(self.calibrated))  # transitional
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


# --------------------------------------------------------------------------------------------
# calibrate
# --------------------------------------------------------------------------------------------


#: ``--parameters auto``'s chooser: :func:`pkmcal.calibration.model_choice.calibrate_auto`,
#: registered by its module (it scores candidates with :func:`pkmcal.calibration.check`, which
#: reads data through this module: this module does not import it)
_MODEL_CHOOSER: list[Callable] = []


def register_model_chooser(choose: Callable) -> Callable:
    """Register ``--parameters auto``'s chooser (see :data:`_MODEL_CHOOSER`).

    Parameters
    ----------
    choose : callable
        ``choose(calibrate, machine, data, candidates, bed_tilt, options) -> Calibration``.

    Returns
    -------
    callable
        ``choose``.
    """
    _MODEL_CHOOSER[:] = [choose]
    return choose


def model_chooser() -> Callable:
    """The registered chooser of ``--parameters auto`` (importing :mod:`pkmcal.calibration`
    registers it).

    Returns
    -------
    callable
        The chooser.
    """
    if not _MODEL_CHOOSER:
        raise RuntimeError("no model chooser registered: import pkmcal.calibration")
    return _MODEL_CHOOSER[0]


def calibrate(machine, data, *, method: str | None = None, noise=None,
              pose_noise: str | None = None, estimate_lc: bool | None = None,
              two_step: bool = False, robust: bool = False, fix_frames: bool = False,
              holdout: float | str | None = None, seed: int = 0,
              parameters: str | None = None, extensions: str | None = None,
              bed_tilt: str | None = None) -> Calibration:
    """Calibrate ``machine`` from measurements; the measurement kind follows from the data.

    Parameters
    ----------
    machine : Machine
        The machine's nominal model (the start of the estimation).
    data : str or os.PathLike or data object, or a list of them
        A data file (its columns give the kind, see :data:`KINDS`) or data read already
        (:class:`~pkmcal.instruments.constraint_link.ConstraintLinkData`,
        :class:`~pkmcal.instruments.tracker.TrackerData`,
        :class:`~pkmcal.instruments.pose.FullPoseData`). A list of several: one geometry from all
        of them, each file with its own instrument unknowns and noise (a kind's ``joint``
        combine; see :func:`calibrate_joint`); a list of one is that one. A Klipper
        ``printer.cfg`` is read for the measurements its ``[delta_calibrate]`` section saved
        (heights, manual heights, DELTA_ANALYZE distances:
        :func:`~pkmcal.io.klipper_config.delta_calibrate_data`) and its bed meshes
        (:func:`~pkmcal.io.klipper_config.bed_mesh_data`); several configs are sessions
        (:func:`~pkmcal.io.klipper_config.klipper_sessions`).
    method : str, optional
        Constraint link: ``ml`` (default), ``ik`` or ``fk``; full pose: ``ml`` (default) or
        ``ik``; not for tracker data (see ``two_step``).
    noise : str or float or noise model, optional
        Constraint link: the encoder noise (m, or text such as ``"1um"``, the default).
        Tracker: a :class:`~pkmcal.instruments.tracker.TrackerNoise`, or ``"leica"`` (default) or
        a length. Full pose: a :class:`~pkmcal.instruments.pose.FullPoseNoise`, or the readings'
        noise as a leg length (text).
    pose_noise : str, optional
        Full pose: noise of the measured poses, ``"POSITION,ORIENTATION"`` with units.
    estimate_lc : bool, optional
        Constraint link: estimate the link length (default: only with ``fk``).
    two_step : bool, optional
        Tracker: the paper's method, registration first.
    robust : bool, optional
        Tracker: find and leave out outlier rows.
    fix_frames : bool, optional
        Full pose: hold the measurement frames at the machine file's.
    holdout : float or str, optional
        Hold out a share (< 1, or text such as ``"20%"``) or a number of rows, chosen at
        random, for validation (the report's ``validation`` section); with several files, of
        every file.
    seed : int, optional
        Seed of the choice of held-out rows.
    parameters : str, optional
        A named parameter set of the machine (``machine.parameter_set(name)``, e.g. a
        firmware's set): its fixed flags replace the machine's before the fit.
    extensions : {"auto", "none"}, optional
        Full pose: ``"auto"`` tries the machine's model extensions
        (:meth:`~pkmcal.machines.Machine.model_extensions`, e.g. a six-leg platform's reading
        curvature) and adopts one only when it predicts held-out rows better
        (cross-validation, :mod:`pkmcal.calibration.extensions`); ``"none"`` fits the plain
        model. None (default): ``"auto"`` for full poses; other data take no extensions and
        refuse the option when it is given.
    bed_tilt : {"auto", "estimate", "square"}, optional
        Probe heights on a printer (its frame is its bed): whether the bed's tilt against the
        towers is estimated (default ``"auto"``: where the data tell it from the parameter
        set; :func:`~pkmcal.instruments.probe.bed_choice`).

    Returns
    -------
    Calibration
        The calibrated machine, the estimator's result, the report, the calibrated file's
        metadata, the parameter table and the warnings.

    Raises
    ------
    InputError
        Bad data or options (the message names the file, row or option).
    CalibrationNotConverged
        When the estimator did not converge.
    """
    from ..io import read_table

    split = None
    if holdout is not None:
        split = (holdout_arg(holdout) if isinstance(holdout, str) else float(holdout), seed)
    if extensions is not None and extensions not in ("auto", "none"):
        raise InputError(f"--extensions {extensions}: auto (adopted by cross-validation) or "
                         "none (the plain model)")
    if getattr(machine, "tolerances", "none") is None and hasattr(machine, "with_tolerances"):
        # a machine that never said (made in code, imported from a firmware's file) is fitted
        # with its default build tolerances, as its machine file would give it (SPEC 9);
        # ``tolerances: none`` / ``with_tolerances(None)`` fits without
        machine = machine.with_tolerances("default")
    given = data
    data = expand_firmware_data(data, machine)
    noise = _noise_through_expansion(noise, given, data)
    notes = [n for item in (data if isinstance(data, (list, tuple)) else [data])
             for n in getattr(item, "notes", None) or []]
    chosen, note = None, ""
    items = list(data) if isinstance(data, (list, tuple)) else [data]
    if parameters == "auto" or parameters is None:
        kinds = _data_kinds(data, machine)
        lengths = any(k.fixes_lengths for k in kinds)
        candidates = machine.model_candidates(lengths) if hasattr(machine, "model_candidates") \
            else []
        if not any(k.measures_bed_height for k in kinds):
            # a bed's tilt is a candidate's only where the data are heights above the bed
            candidates = list({c.parameters: replace(c, bed_tilt=None)
                               for c in candidates}.values())
        if candidates:
            return model_chooser()(calibrate, machine, given, candidates, bed_tilt,
                                  dict(method=method, noise=noise, pose_noise=pose_noise,
                                       estimate_lc=estimate_lc, two_step=two_step,
                                       robust=robust, fix_frames=fix_frames,
                                       holdout=holdout, seed=seed, extensions=extensions))
        if parameters == "auto":
            parameters = None
    suggested = {getattr(d, "parameter_set", None) for d in items}
    if parameters is None and len(suggested) == 1 and None not in suggested \
            and next(iter(suggested)) in getattr(machine, "PARAMETER_SETS", {}):
        # a firmware's saved data are fitted in the set that firmware fits them in
        parameters = next(iter(suggested))
        note = (f"the firmware's saved data: fitted in its own set (--parameters "
                f"{parameters}; --parameters full fits every tower quantity)")
    if parameters is not None:
        subset = getattr(machine, "PARAMETER_SETS", {}).get(parameters)
        fallback = getattr(subset, "without_lengths", None)
        if fallback and not any(k.fixes_lengths for k in _data_kinds(data, machine)):
            note = ((note + "; ") if note else "") + (
                f"{parameters} with heights alone is {fallback}: no measurement fixes a "
                "length (as the firmware does without distances)")
            parameters = fallback
        subset = getattr(machine, "PARAMETER_SETS", {}).get(parameters)
        if getattr(subset, "kinds", None):
            items = list(data) if isinstance(data, (list, tuple)) else [data]
            kinds = _data_kinds(items, machine)
            out = [getattr(d, "source", str(d)) for d, k in zip(items, kinds, strict=True)
                   if k.name not in subset.kinds]
            if len(out) == len(items):
                raise InputError(f"--parameters {parameters}: fitted from "
                                 f"{' and '.join(subset.kinds)} data alone "
                                 f"({subset.description.split(':')[0]}); "
                                 f"{', '.join(map(str, out))} hold none")
            if out:
                items = [d for d, k in zip(items, kinds, strict=True) if k.name in subset.kinds]
                notes.append(f"{', '.join(map(str, out))}: left out: --parameters "
                             f"{parameters} is fitted from {' and '.join(subset.kinds)} data "
                             f"alone ({subset.description.split(':')[0]})")
                data = items[0] if len(items) == 1 else items
        machine, chosen = apply_parameter_set(machine, parameters), str(parameters)
    if bed_tilt is not None and bed_tilt not in ("auto", "estimate", "square"):
        raise InputError(f"--bed-tilt {bed_tilt}: auto, estimate or square")
    if isinstance(data, (list, tuple)):
        if not data:
            raise InputError("no data file given")
        if len(data) > 1:
            options = CalibrateOptions(method, None, pose_noise, estimate_lc, two_step, robust,
                                       fix_frames, extensions, bed_tilt)
            calibration = _noting(notes, calibrate_joint, machine, list(data), noise=noise,
                                  split=split, options=options)
            calibration.inputs = _inputs_of(given, calibration.inputs)
            calibration.warnings[:0] = notes
            return with_bed_surface(_with_parameter_set(calibration, chosen, note), data)
        data = data[0]
    if isinstance(noise, dict):     # named as the joint fit names it: the path or its source
        noise = _noise_of(noise, [data if isinstance(data, (str, Path))
                                  else getattr(data, "source", None) or "data1"], 0)
    if isinstance(data, (str, Path)):
        source = Path(data)
        header, _ = read_table(source)
        kind = KINDS[measurement_kind(source, header, machine)]
    else:
        source = getattr(data, "source", None) or "the data"
        kind = next((k for k in _kinds() if k.data_class == type(data).__name__
                     and getattr(data, "kind", k.instrument) in _names_of(k)), None)
        if kind is None:
            raise InputError(f"{path_text(source)}: "
                             f"{type(data).__name__} is no calibration data (known: "
                             f"{', '.join(k.data_class for k in _kinds())})")
        supported = supported_kinds(machine)
        if kind.name not in supported:
            need = "; ".join(f"{k}: {v}" for k, v in supported.items()) or "none yet"
            raise InputError(f"{path_text(source)}: {kind.name} measurements cannot calibrate a "
                             f"{machine.kind}: {kind.why_not(machine)}; a {machine.kind} is "
                             f"calibrated from {need}")
    options = CalibrateOptions(method, noise, pose_noise, estimate_lc, two_step, robust,
                               fix_frames, extensions, bed_tilt)
    kind.check_options(options, source)
    calibration = _noting(notes, kind.calibrate, machine, data, source, options, split)
    inputs = [Path(source)] if isinstance(data, (str, Path)) else []
    machine_file = getattr(machine, "source", None)
    if machine_file and machine_file != "default" and Path(machine_file).is_file():
        inputs.append(Path(machine_file))
    calibration.inputs = _inputs_of(given, inputs)
    calibration.warnings[:0] = notes
    return with_bed_surface(_with_parameter_set(calibration, chosen, note), [data])


def _noise_through_expansion(noise, given, data):
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
        value = _noise_of(noise, sources, i) if isinstance(noise, dict) or len(items) > 1 \
            else noise
        if value is None:
            continue
        mine = [o for o in objects if getattr(o, "origin", None) == item] or \
            [o for o in objects if o is item]
        for obj in mine:
            out[getattr(obj, "source", None) or str(obj)] = value
    return out or None


def _noting(notes: list, fit, *args, **kwargs):
    """``fit(*args, **kwargs)``; a refusal also names what the data's reader passed over
    (heights after a gap in Klipper's indices: why fewer rows than the user sees)."""
    try:
        return fit(*args, **kwargs)
    except InputError as exc:
        if not notes:
            raise
        raise InputError(f"{exc} (note: {'; '.join(notes)})") from None


def _data_kinds(data, machine) -> list:
    """The measurement kinds of the data (paths by their columns, objects by their class)."""
    from ..io import read_table

    out = []
    for item in (list(data) if isinstance(data, (list, tuple)) else [data]):
        if isinstance(item, (str, Path)):
            header, _ = read_table(Path(item))
            out.append(KINDS[measurement_kind(Path(item), header, machine)])
        else:
            kind = next((k for k in _kinds() if k.data_class == type(item).__name__
                         and getattr(item, "kind", k.instrument) in _names_of(k)), None)
            if kind is None:
                source = getattr(item, "source", None) or "the data"
                raise InputError(f"{path_text(source)}: "
                                 f"{type(item).__name__} is no calibration data")
            out.append(kind)
    return out


def _inputs_of(given, inputs: list) -> list:
    """The input files to protect: ``inputs`` and every path the user gave (a firmware file
    read for its measurements is an input too)."""
    items = list(given) if isinstance(given, (list, tuple)) else [given]
    out = list(inputs)
    for item in items:
        if isinstance(item, (str, Path)) and Path(item) not in out:
            out.append(Path(item))
    return out


def _acceptance(result, nominal, calibrated, source, method, warnings: list,
                verdict=None) -> dict:
    """The believability checks of a converged calibration (the residual verdict of
    :func:`~pkmcal.estimation.acceptance.residual_verdict`; size of the changes against the
    machine's scale): warnings in words with the usual causes (appended to ``warnings``; each
    opens with the verdict's sentence), and the report's ``acceptance`` section."""
    from ..estimation.acceptance import (
        FAILED_ALARMING,
        GROSS_RESIDUAL,
        MAX_NOISE_FACTOR,
        parameter_changes,
        residual_verdict,
    )

    out = {}
    noise = result.extras.get("noise")
    verdict = verdict if verdict is not None else residual_verdict(result, method)
    out["residuals"] = verdict.as_dict()
    test = verdict.test
    if verdict.status == FAILED_ALARMING:
        gross = None
        if noise is not None and calibrated is not None:
            # the residuals' size in metres, per group of lengths: tens of micrometres on a
            # printer are a noisier probe or a missing effect, not swapped columns
            size = [float(s) * (test.noise_ratio if st != "estimated" else 1.0)
                    for s, k, st in zip(noise.sigma, noise.kinds, noise.status, strict=True)
                    if k == "length"]
            if size:
                gross = max(size) > GROSS_RESIDUAL * calibrated.characteristic_length()
        if noise is not None and noise.estimated:
            high = [f"{name} {ratio:.3g}x the assumed" for name, ratio, status
                    in zip(noise.names, noise.ratio, noise.status, strict=True)
                    if status == "estimated" and ratio >= MAX_NOISE_FACTOR]
            high = ", ".join(high) or f"none {MAX_NOISE_FACTOR:g}x the assumed"
            warnings.append(
                f"{path_text(source)}: {_failed_words(verdict)}: the noise levels estimated "
                f"from the residuals ({high}) weigh the fit and its standard deviations. If "
                "the instruments are not that noisy, the model misses something: see the "
                "report's residual checks (per "
                "reading, per pose, against each reading) and its model_adequacy section" + (
                    ", and look for swapped columns, a wrong unit or outlier rows"
                    if gross is not False else ", and look for outlier rows"))
        elif gross is False and noise is not None \
                and all(st == "assumed" for st in noise.status):
            # too few rows to estimate any level (Klipper's 7 heights for 6 unknowns): the
            # residuals' size is shown, not taken for a fault of the data
            out["residuals"]["note"] = (
                "the data leave too few equations to estimate the noise, so whether the "
                "instrument or the model is worse than assumed cannot be told")
        else:
            warnings.append(f"{path_text(source)}: {_failed_words(verdict)}: usual causes: "
                            f"{test.causes(gross)}")
    if nominal is not None:
        changes = parameter_changes(nominal, calibrated)
        out["parameter_changes"] = {"suspicious": changes.suspicious}
        if changes.suspicious:
            warnings.append(f"{path_text(source)}: {changes.message()}")
    return out


def _failed_words(verdict) -> str:
    """The failed residual test as a warning opens: its ratio and a pointer to the verdict,
    which the summary's ``residual test`` row and the report state in full (said once)."""
    return (f"residual test failed, {verdict.noise_ratio:.3g}x the assumed noise (the "
            "verdict states it)")


def _state_verdict(report: dict, verdict, sigma_um=None) -> None:
    """The residuals section's numbers that compare the residuals with the noise, from the
    verdict (one definition: ``noise_scale`` is the noise ratio, ``residual_variance`` its
    square; None when the residuals are not tested)."""
    res = report.get("residuals")
    if not isinstance(res, dict):
        return
    ratio = verdict.noise_ratio
    tested = ratio is not None and math.isfinite(ratio)
    for key, value in (("residual_variance", verdict.test.ratio if tested else None),
                       ("noise_scale", ratio if tested else None),
                       ("estimated_noise_um", ratio * sigma_um if tested and sigma_um
                        else None)):
        if key in res:
            res[key] = value


def _standardised(result):
    """Leverage-corrected standardised residuals for the report (None when the problem
    cannot be evaluated again)."""
    # the problem as fitted: reweighted by the estimated noise levels when they were
    problem = result.extras.get("weighted") or result.extras.get("problem")
    if problem is None and callable(result.extras.get("rebuild_problem")):
        problem = result.extras["rebuild_problem"]()
    if problem is None or result.state is None:
        return None
    from ..report.residuals import standardised_residuals

    if "weighted_residuals" in result.extras:
        result = dataclasses.replace(result, residuals=result.extras["weighted_residuals"])
    try:
        return standardised_residuals(problem, result)
    except (ValueError, np.linalg.LinAlgError):
        return None


def _finish(kind: str, machine, calibrated, result, report: dict, metadata: dict, params,
            units) -> Calibration:
    """The common end of every kind: the covariance of the machine's parameters (SI: m, rad;
    the identifiable part, frames the data cannot fix held at the start values, which
    ``pkmcal compensate`` propagates to the targets), the normalised and standardised
    residuals, the acceptance checks (their warnings) and the provenance."""
    names = list(calibrated.parameters.names)
    n = len(names)
    report["covariance"] = {
        "of": "machine parameters, SI units (m, rad, ratio), minimum-norm (identifiable "
              "part)",
        "parameters": names,
        "matrix": np.asarray(result.covariance, float)[:n, :n].tolist(),
        # unidentifiable directions (columns, same units): pose changes along them are
        # changes of frames the data cannot see, removed before predicting errors
        "null_space": (np.asarray(result.null_space, float)
                       * np.asarray(result.scales, float)[:, None])[:n].tolist(),
    }
    all_names = list(result.parameters.names)
    if len(all_names) > n and all_names[:n] == names:
        # with the measurement frames (tracker pose, motion-capture frames) and Lc: what
        # compensate needs for targets given in the instrument's frame
        report["covariance"]["with_frames"] = {
            "parameters": all_names,
            "matrix": np.asarray(result.covariance, float).tolist(),
            "null_space": (np.asarray(result.null_space, float)
                           * np.asarray(result.scales, float)[:, None]).tolist(),
        }
    # residual / std of every residual, for the report's histogram: the noise levels the fit
    # used (estimated from the residuals, or assumed / given)
    report["normalised_residuals"] = np.asarray(
        result.extras.get("weighted_residuals", result.residuals), float).ravel().tolist()
    standardised = _standardised(result)
    if standardised is not None:
        report["standardised_residuals"] = standardised
    warnings: list[str] = []
    source = report.get("data_file", "the data")
    _noise_report(result, report, source, warnings, result.extras.get("robust", True))
    from ..estimation.acceptance import residual_verdict
    from .adequacy import add_to_report

    # the one verdict on the residuals against the noise: every section states it
    verdict = residual_verdict(result, report.get("method"))
    _state_verdict(report, verdict, report.get("noise_sigma_um"))
    add_to_report(result, report, verdict)  # model_adequacy: residuals against readings, pose
    report["acceptance"] = _acceptance(result, machine, calibrated, source,
                                       report.get("method"), warnings, verdict)
    tolerance_report(result, calibrated, report, path_text(source), units, warnings)
    # weakly determined parameters: one rule on every machine and instrument
    warnings.extend(_weakly_determined(result, machine, report, source, units))
    # each instrument's typed section: its report keys and their index (rendered generically)
    add_sections(report, getattr(result, "sections", {}), units, metadata)
    report["provenance"] = provenance()
    return Calibration(kind=kind, machine=machine, calibrated=calibrated, result=result,
                       report=report, metadata=metadata, params=params, warnings=warnings,
                       units=units)


def _weakly_determined(result, machine, report: dict, source, units) -> list[str]:
    """The one rule every calibration warns by on weakly determined parameters
    (:func:`~pkmcal.identifiability.determination.poorly_determined`: a standard deviation
    beyond 1/2500 of the machine's size at its scale), whatever the machine, the instruments
    and the number of files: the report's ``poorly_determined`` section and its one warning
    (what to measure next from the instruments that measured). The size is the nominal
    machine's (the file's), as the probe's own list has it."""
    from ..identifiability.determination import (
        MEASURE_NEXT,
        poorly_determined,
        poorly_determined_section,
        poorly_determined_warning,
    )
    from ..instruments.registry import INSTRUMENTS

    length = machine.characteristic_length()
    try:
        poor = poorly_determined(result, len(machine.parameters), length)
    except (AttributeError, IndexError, ValueError, TypeError):
        return []                   # a result without a covariance of its parameters
    kinds = sorted({f.get("measurement") for f in report.get("files") or []} - {None}) \
        or [report.get("measurement", "these")]
    advice = [getattr(INSTRUMENTS.get(k), "measure_next", "") for k in kinds]
    measure = "; or ".join(dict.fromkeys(a for a in advice if a)) or MEASURE_NEXT
    report["poorly_determined"] = poorly_determined_section(poor, length, units, measure)
    return poorly_determined_warning(poor, path_text(source), " and ".join(kinds), length,
                                     measure, units)


def _noise_report(result, report: dict, source, warnings: list, robust: bool = True) -> None:
    """The noise levels (assumed, estimated) and the outlier rows of a calibration: the
    report's ``noise_model`` and ``outliers`` sections and their warnings (rows left out
    without ``robust``: those a start strategy could not fit, kept out by the outlier
    test)."""
    noise, test = result.extras.get("noise"), result.extras.get("outliers")
    if noise is not None:
        report["noise_model"] = noise.as_dict()
    if test is None:
        return
    report["outliers"] = test.as_dict()
    flagged = [test.names[i] for i in test.flagged if test.kept[i]]
    left = [test.names[i] for i in test.left_out]
    if flagged:
        shown = ", ".join(flagged[:10]) + (f" and {len(flagged) - 10} more"
                                            if len(flagged) > 10 else "")
        warnings.append(f"{path_text(source)}: "
                        f"{shown}: residuals the noise does not explain (chi-square "
                        f"test of each row, p < {test.threshold:.2g}); check "
                        f"{'them' if len(flagged) > 1 else 'it'} (a beam break, a mis-read "
                        "marker, a wrong row) or leave them out with --robust")
    if left:
        shown = ", ".join(left[:10]) + (f" and {len(left) - 10} more" if len(left) > 10 else "")
        why = ("--robust" if robust else "the start could not fit them, and the outlier "
               "test agrees")
        warnings.append(f"{path_text(source)}: "
                        f"{len(left)} row(s) left out as outliers ({why}): {shown}")


def _report_head(machine, source, kind: str, method: str, units=None) -> dict:
    """The first keys of every report (``units`` last, when given)."""
    from ..report.provenance import run_date

    return report_head(run_date(), machine, source, kind, method, units)



def _fit_with_baseline(machine, data, source, split, reader, fit, noise, advice: str,
                       options: CalibrateOptions):
    """:func:`~pkmcal.instruments.flow.fit_with_baseline` for the flows that still live here
    (read with ``reader``; the noise estimated unless given; ``--robust``)."""
    context = FlowContext(source=source, split=split, units=file_units(machine), date=str,
                          read=reader)
    return fit_with_baseline(machine, data, context, fit, noise, advice,
                             estimate_noise=options.noise is None, robust=options.robust)


def _with_parameter_set(calibration: Calibration, name: str | None,
                        note: str = "") -> Calibration:
    """Record the parameter set of ``--parameters`` in the report and the calibrated file."""
    if name is None:
        return calibration
    mp = calibration.machine.parameters
    calibration.report["parameter_set"] = {
        "name": name, "free": [n for n, f in zip(mp.names, mp.fixed, strict=True) if not f],
        "fixed": int(np.sum(mp.fixed)), **({"note": note} if note else {})}
    calibration.metadata["parameter_set"] = name
    return calibration


# --------------------------------------------------------------------------------------------
# several data files in one fit
# --------------------------------------------------------------------------------------------


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


def _noise_of(noise, sources, i: int):
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


def _combining() -> str:
    """The kinds whose files combine in one fit, in words."""
    return ", ".join(sorted(k.name for k in _kinds() if not k.joint_refusal))


def _joint_part(machine, data, source, kind: MeasurementKind, noise) -> JointPart:
    """The joint fit's view of one file (its kind's ``joint`` preparation, else the kind's
    own calibration's instrument problem); refused for instruments with a ``joint_refusal``
    (full poses and the constraint link: a pose per measurement)."""
    from ..instruments import InstrumentProblem

    if kind.joint_refusal:
        raise InputError(f"{path_text(source)}: "
                         f"{kind.name} data cannot be combined with other files in "
                         f"one fit ({kind.joint_refusal}); the kinds that combine: "
                         f"{_combining()}; calibrate from {path_text(source)} on its own")
    part = kind.joint(machine, data, source, noise) if kind.joint is not None else None
    if part is not None:
        return part
    kind.check_options(CalibrateOptions(noise=noise), source)
    alone = kind.calibrate(machine, data, source, CalibrateOptions(noise=noise), None)
    problem = alone.result.extras.get("problem")
    if not isinstance(problem, InstrumentProblem) or getattr(problem, "local_dof", 0):
        raise InputError(f"{path_text(source)}: "
                         f"{kind.name} data cannot be combined with other files in "
                         f"one fit (no instrument model of the shared layer); the kinds that "
                         f"combine: {', '.join(sorted(k.name for k in _kinds() if k.joint))}")
    text = alone.report.get("noise")
    return JointPart(problem.data, problem.model, problem.noise,
                     str(text) if text is not None else f"{kind.name} default", kind.name)


def _part_rms(problem, state, data) -> tuple[float | None, np.ndarray]:
    """RMS (um) of the per-row residual norm (3-D for points) and the residuals (m)."""
    predicted = problem.predict(state, data.q, data.group)
    r = data.values - predicted
    norm = np.linalg.norm(r, axis=1)
    ok = np.isfinite(norm)
    return (_um(math.sqrt(float(np.mean(norm[ok] ** 2)))) if ok.any() else None), r


def session_report(summary, problem, state, result, fl: float, unit: str) -> dict:
    """The report's ``sessions``: how many, which files repeated another's points, which meshes
    were used or left out and why, and each session's own reading offsets (the drift of its
    endstops against the reference session) with their standard deviations."""
    out = dict(summary or {})
    offsets = {}
    nj = problem.machine.n_joints
    for k, name in enumerate(problem.session_names):
        cols = problem.dq_offset + k * nj + np.arange(nj)
        offsets[name] = {"offsets": [float(v) / fl for v in np.ravel(state.dq[k])],
                         "std": [float(result.std[c]) / fl for c in cols], "unit": unit}
    out["offsets"] = offsets
    out["offsets_are"] = ("each session's reading offsets against the reference session "
                          "(the newest): where its endstops triggered; a session's heights "
                          "also have their own height offset, its probe z_offset")
    return out


def _check_joint_options(options: CalibrateOptions) -> None:
    for option, given in (("--method", options.method is not None),
                          ("--pose-noise", options.pose_noise is not None),
                          ("--estimate-lc", options.estimate_lc is not None),
                          ("--two-step", options.two_step),
                          ("--fix-frames", options.fix_frames),
                          ("--extensions", options.extensions is not None)):
        if given:
            raise InputError(f"{option}: does not apply to a fit of several data files (one "
                             "maximum-likelihood fit of every file's instrument); see --noise "
                             "FILE=VALUE, --robust and --holdout")


def _source_and_kind(machine, item, i: int):
    """The name and :class:`MeasurementKind` of data item ``i`` of several: a file's kind by
    its columns (:func:`measurement_kind`), a data object's by its class and instrument
    (named ``data{i+1}`` unless it has a source).

    Raises
    ------
    InputError
        When an object is no calibration data (or a file's columns fit no kind).
    """
    from ..io import read_table

    if isinstance(item, (str, Path)):
        source = Path(item)
        header, _ = read_table(source)
        return source, KINDS[measurement_kind(source, header, machine)]
    source = getattr(item, "source", None) or f"data{i + 1}"
    kind = next((k for k in _kinds() if k.data_class == type(item).__name__
                 and getattr(item, "kind", k.instrument) in _names_of(k)), None)
    if kind is None:
        raise InputError(f"{path_text(source)}: {type(item).__name__} is no calibration data")
    return source, kind


def calibrate_joint(machine, data: list, *, noise=None, split=None,
                    options: CalibrateOptions | None = None) -> Calibration:
    """One geometry from several data files of instrument-layer kinds (``calibrate`` with a
    list).

    Every file's kind comes from its columns; each keeps its own instrument unknowns (named
    ``FILE:name``) and noise; one maximum-likelihood fit estimates everything
    (:func:`~pkmcal.instruments.joint.fit_joint`). The report has each file's residuals
    before (the machine file's model, the file's instrument fitted alone) and after, the
    joint identifiability in words and what each file adds
    (:class:`~pkmcal.instruments.joint.JointContributions`); the calibrated file carries the
    instruments' sections (the first tracker file's frame and targets, every ballbar file's
    mountings in order).

    Parameters
    ----------
    machine : Machine
        The machine's nominal model (its fixed flags are kept).
    data : list
        Data files (or data objects of the instrument layer), at least one.
    noise : dict or None, optional
        File (as given, its file name, or its index) -> noise (text or model); files not
        named use their kind's default.
    split : tuple, optional
        ``(holdout, seed)``: the rows held out of every file.
    options : CalibrateOptions, optional
        Other options: refused when given (they apply to one kind).

    Returns
    -------
    Calibration
        Kind ``"joint"``.

    Raises
    ------
    InputError
        Bad data or options, or a file of a kind that does not combine.
    CalibrationNotConverged
        When the estimator did not converge.
    """
    from ..instruments import IsotropicNoise
    from ..instruments.joint import file_labels, fit_joint
    from ..units import LENGTH

    _check_joint_options(options or CalibrateOptions())
    if isinstance(noise, str) or (noise is not None and not isinstance(noise, dict)):
        raise InputError("--noise: with several data files give FILE=VALUE per file (e.g. "
                         "--noise bar.csv=2um)")
    sources, kinds = [], []
    for i, item in enumerate(data):
        source, kind = _source_and_kind(machine, item, i)
        kinds.append(kind)
        sources.append(source)
    seen: dict = {}
    for s in sources:       # one file by two names (hard or symbolic links, ./x and x)
        key = file_identity(s) if isinstance(s, (str, Path)) else ("data", str(s))
        if key in seen:
            first = seen[key]
            how = ("given twice" if str(first) == str(s) else
                   f"given twice: {path_text(first)} and {path_text(s)} are the same file")
            raise InputError(f"{path_text(s)}: the same data file is {how}; give each "
                             "file once")
        seen[key] = s
    labels = file_labels(sources)
    # several sessions (a printer's configs): a source's relative weights hold within one of
    # its runs (Klipper weighs one DELTA_CALIBRATE's heights against its distances), not
    # across runs nobody weighed together; there each file's level is its own variance
    # component, estimated from its residuals where its redundancy allows (a file whose
    # data do not fit the others' machine is down-weighted and named in the noise report)
    pooled = len({getattr(d, "session", None) for d in data}) > 1
    parts, held, hold = [], [], []
    for i, (item, source, kind) in enumerate(zip(data, sources, kinds, strict=True)):
        given = _noise_of(noise, sources, i)
        if given is not None:       # the user's level for this file is held
            hold.append(f"{labels[i]}:*")
        part = _joint_part(machine, item, source, kind, given)
        weights = getattr(part.data, "weights", None)
        if given is None and weights is not None:    # the data's own source's weights
            if pooled:
                part.noise_text += (" (its source's weight as the level assumed; one of "
                                    "several sessions: its level estimated from its own "
                                    "residuals)")
            else:
                part.noise_text += f" ({weights[1]})"
                hold.append(f"{labels[i]}:*")
                part.tied = True
        part.data, h = _split_rows(part.data, split, source)
        parts.append(part)
        held.append(h)
    for i, part in enumerate(parts):
        if part.with_others is not None:
            others = [p for j, p in enumerate(parts) if j != i]
            part.model, part.frame = part.with_others(
                sum(len(p.data) * p.model.size for p in others),
                sum(int(np.sum(p.model.parameters.free)) for p in others),
                (options.bed_tilt if options is not None and options.bed_tilt else "auto"),
                part.data, [(p.data, p.model, p.noise) for p in others])
    names = ", ".join(map(str, sources))
    sessions = [getattr(p.data, "session", None) for p in parts]
    sessions = sessions if any(s is not None for s in sessions) else None
    try:
        result = fit_joint(machine, [(p.data, p.model, p.noise) for p in parts], labels,
                           estimate_noise=hold,
                           robust=bool(options is not None and options.robust),
                           sessions=sessions)
        if all(p.tied for p in parts) and result.dof > 0 \
                and np.isfinite(result.residual_variance):
            # every file weighed as its source weighs them (Klipper's DELTA_CALIBRATE): the
            # relative weights held, their common level from the residuals - the same fit,
            # with the outlier test and the covariance at the data's level
            scale = math.sqrt(result.residual_variance)
            for p in parts:
                p.noise = IsotropicNoise(p.noise.sigma * scale)
                p.noise_text = (f"{p.noise.sigma * 1e6:.4g} um (std; the relative weights "
                                f"as the data's source gives them, x{scale:.3g} from the "
                                "residuals)")
            result = fit_joint(machine, [(p.data, p.model, p.noise) for p in parts], labels,
                               estimate_noise=hold,
                               robust=bool(options is not None and options.robust),
                               sessions=sessions)
            # the residuals set the noise's level: their test against it cannot fail
            result.extras["untested"] = (
                "the noise level was set from these residuals (the data's source gives only "
                "relative weights), so they cannot be tested against it")
    except (InputError, ValueError, np.linalg.LinAlgError) as exc:
        message = str(exc) if isinstance(exc, InputError) else \
            f"{names}: joint calibration failed: {exc}"
        if split is not None:
            message = f"--holdout: {message}"
        raise InputError(message) from None
    _require_converged(result, names, "check that the files measure the same machine")
    problem = result.extras["problem"]
    state = result.state
    units = file_units(machine)
    fl = LENGTH[units["length"]]
    calibrated = result.extras["machine"]
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    calibrated.home = machine.home
    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    for label, start in zip(labels, result.extras["start_models"], strict=True):
        nominal_of.update({f"{label}:{n}": v for n, v in zip(
            start.parameters.names, start.parameters.values, strict=True)})
    nominal_of.update({n: 0.0 for n in problem.parameters.names if n.startswith("session ")})
    params = _parameter_table(result, nominal_of, units)

    # what the files' instruments set on the calibrated machine file (the first file of each
    # instrument its frame, every ballbar file its setups), shared among the files
    files, sections, taken = [], [], {}
    for i, (part, label, source) in enumerate(zip(parts, labels, sources, strict=True)):
        sub = problem.part_state(state, i)
        before = result.extras["before"][i]
        bproblem = before.extras["problem"]
        rms_after, r_after = _part_rms(problem.parts[i], sub, part.data)
        rms_before, _ = _part_rms(bproblem, before.state, part.data)
        model = problem.parts[i].model
        entry = {"file": path_text(source), "label": label, "measurement": part.kind,
                 "measurements": len(part.data), "noise": part.noise_text,
                 "residuals": {"of": ("3-D distance of the points" if model.size == 3 else
                                      "measured - predicted"),
                               "rms_um": rms_after, "before_rms_um": rms_before,
                               "before": "machine file's model, this file's instrument "
                                         "fitted alone",
                               "chi_square": float(np.nansum(problem.split(
                                   result.residuals)[i] ** 2)),
                               "count": int(np.sum(np.isfinite(r_after).all(axis=1)))}}
        found, words = model.joint_section(sub.nuisance, machine, calibrated, str(source), fl,
                                           units, part.frame, taken)
        entry.update(found)
        if words:
            sections.append(words)
        if held[i] is not None:
            entry["validation"] = _validation(
                split, held[i], f"{part.kind} of the held-out rows of {path_text(source)}, "
                                "measured - "
                "predicted with the identified instrument; before: the machine file's model "
                "with the instrument fitted alone", "um",
                _part_rms(bproblem, before.state, held[i])[0],
                _part_rms(problem.parts[i], sub, held[i])[0], rms_after)
        files.append(entry)
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.extras.get("unidentifiable", []))
    contributions = result.extras["contributions"]
    from ..units import ANGLE

    fa = ANGLE[units["angle"]]
    r = np.asarray(result.residuals, float)
    report = {
        **_report_head(machine, names, "joint", "joint", units),
        "data_files": [path_text(s) for s in sources],
        "measurements": int(sum(len(p.data) for p in parts)),
        "files": files,
        "parameter_names": "each file's instrument unknowns are named FILE:name (e.g. "
                           f"{labels[0]}:{parts[0].model.parameters.names[0]})",
        "instrument_sections": sections,
        **({"bed_frame": next(p.frame for p in parts if p.frame)}
           if any(p.frame for p in parts) else {}),
        "convergence": _convergence_json(result),
        "residuals": {
            "of": "every file's whitened residuals (measured - predicted, / assumed noise)",
            "count": int(np.isfinite(r).sum()),
            **variance_json(result),
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        "contributions": {**contributions.as_dict(fl, fa, (units["length"], units["angle"])),
                          "summary": contributions.lines()},
        "parameters": _public(params),
    }
    summary = next((getattr(p.data, "sessions", None) for p in parts
                    if getattr(p.data, "sessions", None)), None)
    if summary is not None or problem.session_names:
        report["sessions"] = session_report(summary, problem, state, result, fl,
                                            units["length"])
    if any(h is not None for h in held):
        report["validation"] = {
            "summary": "; ".join(f"{f['file']}: {f['validation']['summary']}" for f in files
                                 if "validation" in f),
            "holdout": split[0], "seed": split[1]}
    metadata = {
        "method": "joint",
        "date": report["date"],
        "data": [path_text(s) for s in sources],
        "machine": _source_of(machine),
        "measurements": report["measurements"],
        "rms_residual_um": {f["label"]: f["residuals"]["rms_um"] for f in files},
        "identifiable": rank,
        "free_parameters": n_free,
        **_identifiability_metadata(unidentifiable),
    }
    calibration = _finish("joint", machine, calibrated, result, report, metadata, params, units)
    levels = report.get("noise_model")
    if result.extras.get("untested") and isinstance(levels, dict):
        # the levels held in the last fit are the data's weights scaled by the residuals
        for g in levels["groups"]:
            if g["status"] == "held":
                g["status"] = "estimated"
        levels["estimated"] = True
    inputs = [Path(s) for s, item in zip(sources, data, strict=True)
              if isinstance(item, (str, Path))]
    machine_file = getattr(machine, "source", None)
    if machine_file and machine_file != "default" and Path(machine_file).is_file():
        inputs.append(Path(machine_file))
    calibration.inputs = inputs
    return calibration


# --------------------------------------------------------------------------------------------
# instruments whose calibration flow lives in their module (Instrument.calibrate)
# --------------------------------------------------------------------------------------------

def _io_reader(name: str):
    """``read(path, machine)``: the :mod:`pkmcal.io` function of that name."""
    from .. import io

    return getattr(io, name)


def _calibrate_flow(machine, data, source, options: CalibrateOptions, split,
                    inst) -> Calibration:
    """Calibration from an instrument with a flow of its own
    (:meth:`~pkmcal.instruments.base.Instrument.calibrate`): the flow fits and reports, given
    only the options it declares; every calibration's end (:func:`_finish`) follows."""
    from ..report.provenance import run_date
    from . import extensions

    context = FlowContext(source=source, split=split, units=file_units(machine),
                          date=run_date, read=_io_reader(inst.calibration_reader or inst.reader),
                          model_choice=extensions)
    out = inst.calibrate(machine, data, context, inst.options_of(options))
    calibration = _finish(out.kind, out.machine, out.calibrated, out.result, out.report,
                          out.metadata, out.params, out.units)
    calibration.warnings += out.warnings
    return calibration


def _joint_flow(machine, data, source, noise, inst) -> JointPart | None:
    """The file's part of a fit of several files, for an instrument with a flow of its own
    (:meth:`~pkmcal.instruments.base.Instrument.joint_part`; None: the generic one)."""
    return inst.joint_part(machine, data, source, noise,
                           _io_reader(inst.calibration_reader or inst.reader))


def flow_kind(inst) -> MeasurementKind:
    """The calibration of an instrument with a flow of its own: its
    :meth:`~pkmcal.instruments.base.Instrument.calibrate`, its option check and its joint part
    (:meth:`~pkmcal.instruments.base.Instrument.joint_part`, else the generic one).

    Parameters
    ----------
    inst : Instrument
        A registry entry with :attr:`~pkmcal.instruments.base.Instrument.Options`.

    Returns
    -------
    MeasurementKind
        Its calibration, option check and joint part.
    """
    return MeasurementKind(inst.name, partial(_calibrate_flow, inst=inst), inst.check_options,
                           partial(_joint_flow, inst=inst))


# -- any instrument of the shared layer: a model without unknowns of the machine's frame ----

def _check_instrument(options: CalibrateOptions, source, inst) -> None:
    """Options an instrument of the generic path does not take, refused naming it."""
    _only_for_poses(options, source, inst.singular)
    for option, given in (("--method", options.method is not None),
                          ("--estimate-lc", options.estimate_lc is not None),
                          ("--two-step", options.two_step),
                          ("--bed-tilt", options.bed_tilt is not None)):
        if given:
            raise InputError(f"{option}: does not apply to {inst.plural} ({path_text(source)}); "
                             "see "
                             "--noise, --robust")


def _reader_of(inst):
    """``reader(path, machine)``: the instrument's data from a CSV file."""
    from ..io import read_measurements

    return lambda path, machine: read_measurements(inst, path, machine)


def _instrument_noise(inst, data, noise, machine):
    """The noise of ``--noise`` (the data's own weights when none is given)."""
    weights = getattr(data, "weights", None)
    if noise is None and weights is not None:
        return weights[0]
    return inst.noise_arg(noise, machine)


def _calibrate_instrument(machine, data, source, options: CalibrateOptions, split,
                          inst) -> Calibration:
    """Calibration from an instrument of the shared layer that brings no handler of its own:
    its :meth:`~pkmcal.instruments.base.Instrument.fit_model`, noise and words."""
    from ..instruments import fit_instrument

    data = _load(data, _reader_of(inst), machine)
    noise = _instrument_noise(inst, data, options.noise, machine)

    def fit(machine_, data_, noise_, **kwargs):
        return fit_instrument(machine_, data_, inst.fit_model(machine_, data_), noise_,
                              **kwargs)

    data, held, result, before, calibrated, params, units = _fit_with_baseline(
        machine, data, source, split, _reader_of(inst), fit, noise, inst.advice, options)
    problem = result.extras["problem"]
    rms_after, r_after = _scalar_rms(problem, result.state, data)
    rms_before, _ = _scalar_rms(before.extras["problem"], before.state, data)
    n_free = int(np.sum(result.parameters.free))
    unidentifiable = list(result.extras.get("unidentifiable", []))
    report = {
        **_report_head(machine, source, inst.name, "joint"),
        "units": units,
        "measurements": len(data),
        "noise": inst.noise_text(noise),
        "convergence": _convergence_json(result),
        "residuals": scalar_residuals_json(result, r_after, rms_after, rms_before,
                                           inst.residual_words, "machine file's model"),
        "identifiability": _identifiability_json(n_free, int(result.rank), unidentifiable,
                                                 np.asarray(result.singular_values, float)),
        "parameters": _public(params),
    }
    metadata = scalar_metadata(inst.name, report, source, machine, result, rms_after,
                               len(data), unidentifiable)
    return _finish(inst.name, machine, calibrated, result, report, metadata, params, units)


def _joint_instrument(machine, data, source, noise, inst) -> JointPart:
    """The file's part of a fit of several files, for an instrument of the generic path."""
    data = _load(data, _reader_of(inst), machine)
    noise_model = _instrument_noise(inst, data, noise, machine)
    data.source = str(source)
    return JointPart(data, inst.fit_model(machine, data), noise_model,
                     inst.noise_text(noise_model), inst.name)


def instrument_kind(inst) -> MeasurementKind:
    """The calibration of an instrument that registers no handler of its own: the generic
    path of the shared layer (:func:`_calibrate_instrument`).

    Parameters
    ----------
    inst : Instrument
        A registry entry with a :meth:`~pkmcal.instruments.base.Instrument.fit_model`.

    Returns
    -------
    MeasurementKind
        Its calibration, option check and joint part.
    """
    return MeasurementKind(inst.name, partial(_calibrate_instrument, inst=inst),
                           partial(_check_instrument, inst=inst),
                           partial(_joint_instrument, inst=inst))


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


# every instrument without handlers of its own calibrates by the generic path
_kinds()
