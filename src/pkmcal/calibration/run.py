"""One calibration of a machine from a data file, as ``pkmcal calibrate`` runs it.

:func:`calibrate` tells the measurement kind from the data's columns, checks the options that
apply to it, holds out rows for validation when asked, runs the kind's estimator and builds
the report (the JSON ``pkmcal calibrate`` writes beside the calibrated file) and the
calibrated file's ``calibration:`` section. It prints nothing: what the command prints as
warnings is in :attr:`Calibration.warnings`. :meth:`Calibration.write` writes the calibrated
machine file, its report and optionally the HTML report, all together or none.

Measurement kinds are entries of :data:`KINDS` (:func:`register_kind`): how to recognise the
data, which options apply, what the data need (for messages) and the handler that calibrates.
Adding a kind is adding an entry; neither the estimator nor the command line changes.

Options may be given as the user's strings (``"2um"``, ``"leica"``, ``"20um,50urad"``,
``"20%"``), parsed with the messages of the command line, or as SI numbers and noise models.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from ..errors import ConvergenceError, InputError
from ..estimation.acceptance import WHITENED_METHODS
from ..instruments.constraint_link import link_noise_arg  # noqa: F401
from ..instruments.pose import full_pose_noise_arg, pose_noise_option  # noqa: F401
from ..instruments.tracker import (  # noqa: F401
    _tracker_noise_text,
    as_tracker_data,
    tracker_noise_arg,
)
from ..paths import file_identity, path_text, same_file

__all__ = ["KINDS", "WHITENED_METHODS", "Calibration",
           "CalibrationNotConverged", "CalibrateOptions", "JointPart", "MeasurementKind",
           "apply_parameter_set", "calibrate", "calibrate_joint", "distance_ratio_pairs",
           "file_units", "full_pose_noise_arg", "grid_neighbour_pairs", "holdout_arg",
           "json_safe", "link_noise_arg", "report_json", "measurement_kind", "noise_per_file_arg",
           "parameter_set_names", "provenance", "register_kind", "rows_text",
           "supported_kinds", "text_digest", "tracker_noise_arg", "versions"]


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


def json_safe(value):
    """A value made JSON-safe: NaN and infinities become None, numpy values Python ones.

    Parameters
    ----------
    value : object
        A number, array, list, tuple or dict (nested), or anything else (returned as is).

    Returns
    -------
    object
        The same structure with lists for arrays and tuples, Python numbers for numpy
        scalars and None for non-finite floats.
    """
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "biu" or (value.dtype.kind == "f" and np.isfinite(value).all()):
            return value.tolist()           # Python numbers already, every one finite
        return json_safe(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def rows_text(rows, limit: int = 10) -> str:
    """Row numbers for a message: the first ``limit``, then ``...``.

    Parameters
    ----------
    rows : iterable of int
        Row numbers.
    limit : int, optional
        How many to show.

    Returns
    -------
    str
        E.g. ``"3, 7, 12"``.
    """
    rows = [int(r) for r in rows]
    return ", ".join(map(str, rows[:limit])) + (" ..." if len(rows) > limit else "")


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


def _source_of(machine) -> str:
    """The machine's file (``default`` for the embedded one), else its name."""
    return path_text(getattr(machine, "source", None) or getattr(machine, "name", None)
                     or "the machine")


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
        several files (None: from the instrument problem of its own calibration, unless the
        instrument's ``joint_refusal`` says why it cannot combine).
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
    """Every instrument's calibration (its registered handlers, else the generic path), in
    the order data files are recognised."""
    from ..instruments.registry import INSTRUMENTS

    for name, inst in INSTRUMENTS.items():
        if name not in KINDS and inst.fit_model is not None:
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


class CalibrationNotConverged(ConvergenceError):
    """The estimator did not converge; nothing to write.

    Parameters
    ----------
    message : str
        Why, naming the data, and what to try.
    result : CalibrationResult, optional
        The estimator's last state (also the attribute ``result``).
    """

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


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
        yaml_text = machine_to_text(self.calibrated, self.units, calibration=metadata)
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
        :func:`~pkmcal.io.klipper_config.delta_calibrate_data`).
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
    given = data
    data = expand_firmware_data(data, machine)
    noise = _noise_through_expansion(noise, given, data)
    notes = [n for item in (data if isinstance(data, (list, tuple)) else [data])
             for n in getattr(item, "notes", None) or []]
    chosen, note = None, ""
    items = list(data) if isinstance(data, (list, tuple)) else [data]
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
            return _with_parameter_set(calibration, chosen, note)
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
    return _with_parameter_set(calibration, chosen, note)


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


def _load(data, reader, machine):
    """Data read from ``data`` (a path) with ``reader``, or ``data`` itself."""
    return reader(Path(data), machine) if isinstance(data, (str, Path)) else data


def _only_for_poses(options: CalibrateOptions, source, kind: str) -> None:
    for option, given in (("--pose-noise", options.pose_noise is not None),
                          ("--fix-frames", options.fix_frames),
                          ("--extensions", options.extensions is not None)):
        if given:
            raise InputError(f"{option}: applies to full-pose data (a Stewart with x, y, z "
                             f"and orientation columns); {path_text(source)} has {kind} data")


def _parameter_table(result, nominal_of: dict, units):
    """Rows of the report's parameter list, in the machine file's units; ``nominal_of`` maps
    parameter names to their start (nominal) values."""
    from ..units import ANGLE, LENGTH

    fl, fa = LENGTH[units["length"]], ANGLE[units["angle"]]
    rows = []
    params = result.parameters
    for i, (name, kind) in enumerate(zip(params.names, params.kinds, strict=True)):
        f = fl if kind == "length" else fa if kind == "angle" else 1e-3 if kind == "slope" \
            else 1.0
        unit = units["length"] if kind == "length" else units["angle"] if kind == "angle" \
            else "mm/m" if kind == "slope" else "1"
        nominal = nominal_of.get(name, float("nan"))
        fixed = bool(params.fixed[i])
        rows.append({
            "name": name, "kind": kind, "unit": unit,
            "nominal": nominal / f, "identified": result.x[i] / f,
            "change": (result.x[i] - nominal) / f,
            "std": None if fixed else result.std[i] / f,
            "fixed": fixed,
            "scaled_change": abs(result.x[i] - nominal) / result.scales[i],
        })
    return rows


def _um(value_m: float) -> float | None:
    """Metres -> micrometres for a report; None when not finite."""
    return json_safe(float(value_m) * 1e6)


def _split_rows(data, split, source):
    """``(calibration data, held-out data or None)`` for ``holdout``/``seed``."""
    if split is None:
        return data, None
    from .validation import holdout_split

    try:
        train, held = holdout_split(len(data), *split)
    except ValueError as exc:
        raise InputError(f"--holdout: {path_text(source)}: {exc}") from None
    return data.subset(train), data.subset(held)


def _validation(split, held, of: str, unit: str, before, after, calibration, **extra) -> dict:
    """The report's held-out validation section: RMS residuals of the held-out rows with the
    machine file's and the calibrated model, next to the calibration rows' own RMS."""
    ratio = after / calibration if after is not None and calibration else None
    summary = (f"{len(held)} held-out rows: RMS {_fmt(before)} -> {_fmt(after)} {unit} "
               f"(calibration rows {_fmt(calibration)} {unit}"
               + (f"; held-out / calibration = {ratio:.3g}" if ratio is not None else "") + ")")
    return {"summary": summary, "held_out": len(held), "rows": [int(r) for r in held.rows],
            "holdout": split[0], "seed": split[1], "of": of, "unit": unit,
            "before_rms": before, "after_rms": after, "calibration_rms": calibration,
            "held_out_over_calibration": ratio, **extra}


def _fmt(value) -> str:
    return "n/a" if value is None else f"{value:.4g}"


def _solve(source, estimator, *args, held=None, **kwargs):
    """Run a calibration; numerical failures caused by the data become an InputError naming
    the data. With ``held`` (the rows held out) a failure names the option too: the rows left
    may be too few."""
    try:
        return estimator(*args, **kwargs)
    except (InputError, ValueError, np.linalg.LinAlgError) as exc:
        message = str(exc) if isinstance(exc, InputError) else \
            f"{path_text(source)}: calibration failed: {exc}"
        if held is not None:
            message = (f"--holdout: holding out {len(held)} row(s) leaves {len(args[1])} "
                       f"to calibrate on: {message}")
        raise InputError(message) from None


def _require_converged(result, source, advice: str = "") -> None:
    """Raise :class:`CalibrationNotConverged` (saying why and what to try, naming the data)
    unless the calibration converged."""
    if result.success and np.all(np.isfinite(result.x)):
        return
    raise CalibrationNotConverged(
        f"{path_text(source)}: calibration did not converge: {result.message} (after {result.nit} "
        "iterations)" + (f"; {advice}" if advice else "") + "; check the columns (order, "
        "units) and the machine file; no file written", result)


def _identifiability_json(n_free, rank, unidentifiable, s) -> dict:
    """The identifiability section of a calibration report: the directions the data cannot
    fix, and apart from them the weakly identifiable ones (counted in ``identifiable``, left
    at their start values; each with its standard deviation)."""
    return {
        "free_parameters": n_free,
        "identifiable": rank,
        "unidentifiable": [d.as_dict() for d in unidentifiable if d.std is None],
        "weakly_identifiable": [d.as_dict() for d in unidentifiable if d.std is not None],
        "condition_number": float(s[0] / s[rank - 1]) if rank else None,
        "singular_values": s.tolist(),
    }


def _convergence_json(result) -> dict:
    return {"success": bool(result.success), "status": int(result.status),
            "message": result.message, "iterations": int(result.nit),
            "evaluations": int(result.nfev)}


def _identifiability_metadata(unidentifiable) -> dict:
    return {"unidentifiable": [f"{d.dimension} x {d.name}" for d in unidentifiable
                               if d.std is None],
            "weakly_identifiable": [d.name for d in unidentifiable if d.std is not None]}


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
                f"{path_text(source)}: "
                f"residual test {verdict.sentence()}; the noise levels estimated "
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
            warnings.append(f"{path_text(source)}: residual test {test.message(gross)}")
    if nominal is not None:
        changes = parameter_changes(nominal, calibrated)
        out["parameter_changes"] = {"suspicious": changes.suspicious}
        if changes.suspicious:
            warnings.append(f"{path_text(source)}: {changes.message()}")
    return out


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
    report["provenance"] = provenance()
    return Calibration(kind=kind, machine=machine, calibrated=calibrated, result=result,
                       report=report, metadata=metadata, params=params, warnings=warnings,
                       units=units)


def _poorly_determined(result, machine, report: dict, source, units) -> list[str]:
    """The rule a probe calibration warns by on weakly determined parameters
    (:func:`~pkmcal.instruments.probe.poorly_determined`: a standard deviation beyond the
    threshold at the machine's scale), for files fitted together: the report's
    ``poorly_determined`` section and its warning."""
    from ..instruments.probe import POOR_STD, poorly_determined, poorly_determined_warnings
    from ..units import LENGTH

    try:
        poor = poorly_determined(result, len(machine.parameters),
                                 machine.characteristic_length())
    except (AttributeError, IndexError, ValueError, TypeError):
        return []                   # a result without a covariance of its parameters
    fl = LENGTH[units["length"]]
    measure = "more or other measurements where they tell most (pkmcal select-poses), or " \
              "another instrument (distances or points)"
    report["poorly_determined"] = {
        "threshold_mm": POOR_STD * 1e3,
        "rule": "a determined parameter whose standard deviation (an angle's or ratio's times "
                "the characteristic length) exceeds the threshold",
        "measure_next": measure,
        "parameters": [{"name": p.name, "std": p.std / (fl if p.kind == "length" else 1.0),
                        "kind": p.kind, "correlated_with": p.partner,
                        "correlation": p.correlation} for p in poor]}
    kinds = {f.get("measurement") for f in report.get("files") or []}
    return poorly_determined_warnings(poor, source, " and ".join(sorted(kinds)) or
                                      report.get("measurement", "these"), units)


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

    head = {"pkmcal_report": 1, "command": "calibrate", "date": run_date(),
            "machine_file": _source_of(machine), "data_file": path_text(source),
            "calibrated_file": None, "measurement": kind, "method": method}
    return head if units is None else {**head, "units": units}


def _public(params) -> list[dict]:
    return [{k: v for k, v in p.items() if k != "scaled_change"} for p in params]


# -- constraint link ---------------------------------------------------------------------------


def _check_constraint_link(options: CalibrateOptions, source) -> None:
    _only_for_poses(options, source, "constraint-link")
    if options.two_step:
        raise InputError(f"--two-step: applies to laser-tracker data (mx, my, mz columns); "
                         f"{path_text(source)} has constraint-link data")
    if options.robust and options.method not in (None, "ml"):
        raise InputError(f"--robust: applies to the ml method (its residuals are the noise's); "
                         f"--method {options.method} takes some readings as exact")


def _calibrate_constraint_link(machine, data, source, options: CalibrateOptions,
                               split) -> Calibration:
    from ..io import read_constraint_link
    from ..units import LENGTH

    method = options.method or "ml"
    estimate_lc = options.estimate_lc
    sigma = link_noise_arg(options.noise, machine)
    kind = "constraint-link"
    data, held = _split_rows(_load(data, read_constraint_link, machine), split, source)

    from ..instruments.constraint_link import calibrate_constraint_link
    from .validation import constraint_link_reading_rms

    result = _solve(source, calibrate_constraint_link, machine, data, held=held,
                    method=method, sigma_m=sigma, estimate_link_length=estimate_lc,
                    estimate_noise=options.noise is None, robust=options.robust)
    _require_converged(result, source)
    from ..instruments.constraint_link import PROBLEMS

    kw = {} if estimate_lc is None else {"estimate_link_length": estimate_lc}
    result.extras["rebuild_problem"] = lambda: PROBLEMS[method](machine, data, sigma, **kw)

    units = file_units(machine)
    fl = LENGTH[units["length"]]
    calibrated = result.extras["machine"]
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    # FK start of the calibrated file: the input machine's home (a central pose of the working
    # assembly mode) rather than the first measured pose, which may sit at the workspace edge
    home_P, home_R = machine.home
    if np.all(np.isfinite(calibrated.ik(home_P, home_R))):
        calibrated.home = (home_P, home_R)
    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    nominal_of["link.length"] = data.link_length
    params = _parameter_table(result, nominal_of, units)
    r = np.asarray(result.residuals, float)
    if "used" in result.extras:             # the rows in the fit (not those left out)
        r = r[np.asarray(result.extras["used"], bool).reshape(len(r), -1).all(axis=-1)]
    r_m = r * sigma
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.extras.get("unidentifiable", []))
    dropped = [int(v) for v in np.asarray(result.extras.get("dropped_rows", []))]
    lc_index = result.parameters.names.index("link.length") \
        if "link.length" in result.parameters.names else None
    lc_estimated = lc_index is not None and not bool(result.parameters.fixed[lc_index])
    lc = float(result.extras.get("link_length", data.link_length))
    residual_what = {"ml": "all joint readings", "ik": "passive joint readings",
                     "fk": "computed link length |P| - Lc"}[method]
    report = {
        **_report_head(machine, source, kind, method, units),
        "measurements": len(data),
        "dropped_rows": dropped,
        "noise_sigma_um": sigma * 1e6,
        "link_length": {"value": lc / fl, "assumed": data.link_length / fl,
                        "unit": units["length"], "estimated": lc_estimated,
                        "std": params[lc_index]["std"] if lc_estimated else None},
        "convergence": _convergence_json(result),
        "residuals": {
            "of": residual_what,
            "count": int(r.size),
            "rms_um": float(np.sqrt(np.mean(r_m**2)) * 1e6) if r.size else None,
            "max_abs_um": float(np.max(np.abs(r_m)) * 1e6) if r.size else None,
            "rms_per_column_um": (np.sqrt(np.mean(r_m**2, axis=0)) * 1e6).tolist()
            if r.ndim == 2 and r.shape[1] > 1 else None,
            "before_rms_um": _um(constraint_link_reading_rms(machine, data, sigma)),
            "before": "machine file's geometry, all readings, poses fitted (maximum "
                      "likelihood)",
            "residual_variance": float(result.residual_variance),
            "estimated_noise_um": float(np.sqrt(result.residual_variance) * sigma * 1e6)
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": _public(params),
    }
    if "start_from" in result.extras:       # the paper's methods: where they started
        report["start"] = result.extras["start_from"]
    if held is not None:
        report["validation"] = _validation(
            split, held, "joint readings of the held-out rows (poses fitted, geometry and Lc "
            "held); before: the machine file's geometry", "um",
            _um(constraint_link_reading_rms(machine, held, sigma)),
            _um(constraint_link_reading_rms(calibrated, dataclasses.replace(held, link_length=lc),
                                            sigma)),
            report["residuals"]["rms_um"])
    metadata = {
        "method": method,
        "date": report["date"],
        "data": path_text(source),
        "machine": _source_of(machine),
        "measurements": len(data),
        "rms_residual_um": report["residuals"]["rms_um"],
        "identifiable": rank,
        "free_parameters": n_free,
        **_identifiability_metadata(unidentifiable),
        "link_length_estimated": lc_estimated,
    }
    calibration = _finish(kind, machine, calibrated, result, report, metadata, params, units)
    if "warnings" in result.extras:         # ml: the start strategy says what it left out
        calibration.warnings += [f"{path_text(source)}: "
                                 f"{text}" for text in result.extras["warnings"]]
    elif dropped:
        calibration.warnings.append(
            f"{path_text(source)}: "
            f"{len(dropped)} row(s) left out (no pose from the five active readings "
            f"and the link with the start geometry): {rows_text(dropped)}")
    return calibration


# -- laser tracker -----------------------------------------------------------------------------


def grid_neighbour_pairs(P, abs_tol: float = 1e-4, rel_tol: float = 0.01) -> np.ndarray:
    """Index pairs of neighbouring points of an axis-aligned grid.

    ``j`` is the neighbour of ``i`` along an axis when ``P_j - P_i`` points along the positive
    axis (off-axis part within ``abs_tol + rel_tol * distance``) and no closer point lies that
    way; missing grid points are allowed. Seed 001 Fig. 6 compares such pairs.

    Parameters
    ----------
    P : array_like, shape (K, 3)
        Positions, m.
    abs_tol : float, optional
        Absolute off-axis tolerance, m.
    rel_tol : float, optional
        Off-axis tolerance relative to the distance.

    Returns
    -------
    ndarray of int, shape (n, 2)
        The pairs ``(i, j)``.
    """
    P = np.asarray(P, float)
    K = len(P)
    pairs = []
    for start in range(0, K, 512):                       # K x K temporaries in blocks
        D = P[None, :, :] - P[start:start + 512, None, :]   # (B, K, 3) P_j - P_i
        for axis in range(3):
            along = D[..., axis]
            off = np.linalg.norm(np.delete(D, axis, axis=-1), axis=-1)
            dist = np.where((along > abs_tol) & (off <= abs_tol + rel_tol * along), along,
                            np.inf)
            j = np.argmin(dist, axis=1)
            i = np.flatnonzero(np.isfinite(dist[np.arange(len(D)), j]))
            pairs.append(np.stack([i + start, j[i]], -1))
    return np.concatenate(pairs) if pairs else np.zeros((0, 2), int)


def distance_ratio_pairs(machine, q) -> tuple[np.ndarray, str]:
    """Pairs of measurements for the distance ratio (seed 001 Fig. 6).

    Neighbours of the grid the readings were commanded to (``machine``'s forward kinematics
    of them, i.e. the commanded points when ``machine`` is the controller's model); nearest
    neighbours when the points form no grid.

    Parameters
    ----------
    machine : Machine
        The controller's model.
    q : array_like, shape (K, n)
        Joint readings.

    Returns
    -------
    tuple
        ``(pairs (n, 2) of row indices, how they were found)``.
    """
    P = machine.fk(q).P
    ok = np.all(np.isfinite(P), axis=-1)
    pairs = grid_neighbour_pairs(np.where(ok[:, None], P, 1e9))
    pairs = pairs[ok[pairs].all(axis=1)] if len(pairs) else pairs
    if len(pairs) >= max(1, len(P) // 4):      # a grid: most points have a neighbour
        return pairs, "neighbours on the commanded grid"
    D = np.linalg.norm(P[:, None] - P[None], axis=-1)
    np.fill_diagonal(D, np.inf)
    j = np.argmin(np.where(np.isfinite(D), D, np.inf), axis=1)
    pairs = np.unique(np.sort(np.stack([np.arange(len(P)), j], -1), axis=1), axis=0)
    return pairs[ok[pairs].all(axis=1)], "nearest neighbours (the points form no grid)"


def _ratio_stats(r) -> dict:
    r = np.asarray(r, float)
    r = r[np.isfinite(r)]
    if not r.size:
        return {"mean": None, "std": None, "min": None, "max": None}
    return {"mean": float(r.mean()), "std": float(r.std()), "min": float(r.min()),
            "max": float(r.max())}


def _check_spread(data, noise_model) -> None:
    """Refuse (nearly) collinear tracker points: the registration's rotation about their line
    would be fixed only by the noise. Also fewer than 4 points (seed 001 eq. 12-14)."""
    K = len(data)
    if K < 4:
        raise InputError(f"{path_text(data.source)}: "
                         f"{K} point(s): the tracker registration needs at "
                         "least 4 points that are not on one line (seed 001 uses a 3x3x3 grid)")
    m = data.m - data.m.mean(0)
    sv = np.linalg.svd(m, compute_uv=False)
    off_line = sv[1] / math.sqrt(K)                       # RMS distance from the best line
    sigma = float(np.sqrt(np.max(np.trace(noise_model.covariance(data.m), axis1=1, axis2=2))))
    if off_line <= max(20 * sigma, 1e-6 * sv[0]):
        raise InputError(f"{path_text(data.source)}: "
                         f"the {K} tracker points lie on one line or nearly (RMS "
                         f"distance from the best line {off_line * 1e6:.3g} um, tracker noise "
                         f"{sigma * 1e6:.3g} um): the "
                         "rotation of the tracker about that line cannot be found; measure "
                         "points spread in 2-3 directions (e.g. a 3x3x3 grid)")


def _rotvec(R):
    from ..kinematics import rotvec_from_matrix

    return rotvec_from_matrix(R)


def _check_tracker(options: CalibrateOptions, source) -> None:
    _only_for_poses(options, source, "tracker")
    for option, given in (("--method", options.method is not None),
                          ("--estimate-lc", options.estimate_lc is not None)):
        if given:
            raise InputError(f"{option}: applies to constraint-link data; {path_text(source)} has "
                             "tracker points (see --two-step, --robust)")
    if options.two_step and options.robust:
        raise InputError("--robust: applies to the joint method (its residuals are the "
                         "noise's); --two-step holds a registration of the nominal model, whose "
                         "residuals exceed the noise by design")


def _calibrate_tracker(machine, data, source, options: CalibrateOptions, split) -> Calibration:
    from ..instruments.tracker import calibrate_tracker, distance_ratios, predict_tracker_points
    from ..io import read_tracker
    from ..units import LENGTH

    two_step, robust = options.two_step, options.robust
    if options.noise is None or isinstance(options.noise, str):
        noise_model, noise_text = tracker_noise_arg(options.noise, allow_none=False,
                                                    machine=machine)
    else:
        noise_model, noise_text = options.noise, _tracker_noise_text(options.noise)
    data, held = _split_rows(as_tracker_data(_load(data, read_tracker, machine)), split,
                             source)
    _check_spread(data, noise_model)
    fk = machine.fk(data.q)
    if not fk.converged.all():
        raise InputError(f"{path_text(source)}: row(s) {rows_text(data.rows[~fk.converged])}: no "
                         f"platform pose of {_source_of(machine)} reproduces these readings "
                         "(outside the workspace, or a wrong unit or zero)")
    result = _solve(source, calibrate_tracker, machine, data, noise_model, held=held,
                    joint=not two_step, robust=robust, estimate_noise=options.noise is None)
    _require_converged(result, source,
                       "spread the points in all three directions, e.g. a 3x3x3 grid")

    units = file_units(machine)
    fl = LENGTH[units["length"]]
    method = "two-step" if two_step else "joint"
    calibrated = result.extras["machine"]
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    # FK start of the calibrated file: the input machine's home, else the measured position
    # closest to the middle of the data that the calibrated model reaches
    fk_cal = calibrated.fk(data.q)
    order = np.argsort(np.linalg.norm(fk_cal.P - np.nanmean(fk_cal.P, axis=0), axis=1))
    for P_home, R_home in [machine.home, *zip(fk_cal.P[order], fk_cal.R[order], strict=True)]:
        if np.all(np.isfinite(calibrated.ik(P_home, R_home))):
            calibrated.home = (np.asarray(P_home, float), np.asarray(R_home, float))
            break
    R, t = result.extras["registration"]
    R0, t0 = result.extras["start_registration"]
    given = machine.tracker_target() is not None
    targets, targets0 = result.extras["targets"], result.extras["start_targets"]
    calibrated.tracker_targets = None if given else np.array(targets, float)
    kept = np.asarray(result.extras["kept"], bool)
    outlier_rows = [int(v) for v in result.extras["outlier_rows"]]

    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    nominal_of.update(zip(("tracker.rx", "tracker.ry", "tracker.rz"), (0.0, 0.0, 0.0),
                          strict=True))
    nominal_of.update(zip(("tracker.x", "tracker.y", "tracker.z"), t0, strict=True))
    params = _parameter_table(result, nominal_of, units)

    # residuals in the tracker frame (m); before = nominal model + closed-form registration
    r = data.m - predict_tracker_points(calibrated, data.q, (R, t), targets, data.target)
    r0 = data.m - predict_tracker_points(machine, data.q, (R0, t0), targets0, data.target)
    norm, norm0 = np.linalg.norm(r, axis=1), np.linalg.norm(r0, axis=1)
    rms = lambda v: float(np.sqrt(np.mean(v**2)) * 1e6) if v.size else None  # noqa: E731
    # distance ratio (seed 001 Fig. 6) over pairs of kept rows
    pairs, pairs_from = distance_ratio_pairs(machine, data.q)
    pairs = pairs[kept[pairs].all(axis=1)] if len(pairs) else pairs
    d_meas = np.linalg.norm(data.m[pairs[:, 0]] - data.m[pairs[:, 1]], axis=-1) \
        if len(pairs) else np.zeros(0)
    pairs = pairs[d_meas > 1e-9] if len(pairs) else pairs
    ratio_before = distance_ratios(machine, data.q, data.m, pairs, targets0, data.target) \
        if len(pairs) else []
    ratio_after = distance_ratios(calibrated, data.q, data.m, pairs, targets, data.target) \
        if len(pairs) else []
    before, after = _ratio_stats(ratio_before), _ratio_stats(ratio_after)

    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.extras.get("unidentifiable", []))
    combinations = calibrated.identifiable_combinations()
    if combinations is not None:
        combinations = {k: (v if k == "description" else (np.asarray(v) / fl).tolist())
                        for k, v in combinations.items()}
        combinations["description"] += " (file length unit)"
    rot_change = float(np.degrees(np.linalg.norm(_rotvec(R @ R0.T))))
    report = {
        **_report_head(machine, source, "tracker", method),
        "robust": robust,
        "units": units,
        "measurements": len(data),
        "used": int(kept.sum()),
        "outlier_rows": outlier_rows,
        "noise": noise_text,
        **({"smr_offset": float(-machine.tracker_target()[2]) / fl} if given else {}),
        "targets": {"given_by_machine_file": given, "unit": units["length"],
                    "places": (np.asarray(targets, float) / fl).tolist(),
                    "what": "target places on the platform (platform frame)"},
        "registration": {
            "estimated": not two_step,
            "rotation": R.tolist(), "translation": (np.asarray(t) / fl).tolist(),
            "unit": units["length"],
            "start": {"rotation": R0.tolist(), "translation": (np.asarray(t0) / fl).tolist(),
                      "method": "closed form (SVD) with the nominal model"},
            "rotation_change_deg": rot_change,
            "translation_change": float(np.linalg.norm(t - t0) / fl),
        },
        "convergence": _convergence_json(result),
        "residuals": {
            "of": "tracker points, measured - predicted (3-D distance, tracker frame)",
            "count": int(kept.sum()),
            "rms_um": rms(norm[kept]),
            "max_um": float(norm[kept].max() * 1e6) if kept.any() else None,
            "rms_per_axis_um": (np.sqrt(np.mean(r[kept] ** 2, axis=0)) * 1e6).tolist(),
            "before_rms_um": rms(norm0[kept]),
            "before": "machine file's model, closed-form registration" if given else
                      "machine file's model, tracker frame and targets fitted alone",
            "residual_variance": float(result.residual_variance),
            "noise_scale": float(np.sqrt(result.residual_variance))
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
            "outliers": [{"row": int(row), "residual_um": float(v * 1e6)} for row, v in
                         zip(data.rows[~kept], norm[~kept], strict=True)],
        },
        "distance_ratio": {
            "unit": "%", "pairs": int(len(pairs)), "pairs_from": pairs_from,
            "before": before, "after": after,
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        **({"identifiable_combinations": combinations} if combinations else {}),
        "parameters": _public(params),
    }
    if held is not None:
        d_after = np.linalg.norm(held.m - predict_tracker_points(
            calibrated, held.q, (R, t), targets, held.target), axis=1)
        d_before = np.linalg.norm(held.m - predict_tracker_points(
            machine, held.q, (R0, t0), targets0, held.target), axis=1)
        ok = np.isfinite(d_after) & np.isfinite(d_before)
        report["validation"] = _validation(
            split, held, "tracker points of the held-out rows, measured - predicted (3-D "
            "distance) with the identified tracker pose; before: the machine file's model and "
            "the closed-form registration of the calibration rows", "um",
            rms(d_before[ok]), rms(d_after[ok]), report["residuals"]["rms_um"],
            max_after=float(d_after[ok].max() * 1e6) if ok.any() else None,
            not_reached=[int(r) for r in held.rows[~ok]])
    metadata = {
        "method": f"tracker-{method}",
        "date": report["date"],
        "data": path_text(source),
        "machine": _source_of(machine),
        "measurements": len(data),
        "outlier_rows": outlier_rows,
        "rms_residual_um": report["residuals"]["rms_um"],
        "identifiable": rank,
        "free_parameters": n_free,
        **_identifiability_metadata(unidentifiable),
        "distance_ratio_std_percent": {"before": before["std"], "after": after["std"]},
    }
    return _finish("tracker", machine, calibrated, result, report, metadata, params, units)


# -- full pose ---------------------------------------------------------------------------------


def _frame_report(frame, fl: float, unit: str) -> dict:
    from ..kinematics import rotation_angle

    R, t = frame
    return {"rotation": np.asarray(R, float).tolist(),
            "translation": (np.asarray(t, float) / fl).tolist(), "unit": unit,
            "rotation_angle_deg": float(np.degrees(rotation_angle(np.asarray(R, float))))}


def _errors_report(errors, fl: float) -> dict:
    s = errors.summary()
    return {"leg_length_rms": s["leg_length_rms"] / fl, "leg_length_max": s["leg_length_max"] / fl,
            "leg_length_rms_per_leg": [v / fl for v in s["leg_length_rms_per_leg"]],
            "position_rms": s["position_rms"] / fl, "position_max": s["position_max"] / fl,
            "orientation_rms_deg": float(np.degrees(s["orientation_rms"])),
            "orientation_max_deg": float(np.degrees(s["orientation_max"])),
            "fk_failed": s["fk_failed"]}


def _check_full_pose(options: CalibrateOptions, source) -> None:
    for option, given in (("--estimate-lc", options.estimate_lc is not None),
                          ("--two-step", options.two_step)):
        if given:
            raise InputError(f"{option}: does not apply to full-pose data ({path_text(source)}); "
                             "see --method ml|ik, --fix-frames, --noise, --pose-noise, --robust")
    if options.robust and options.method == "ik":
        raise InputError("--robust: applies to the ml method (its residuals are the noise's); "
                         "--method ik takes the measured poses as exact")
    if options.method not in (None, "ml", "ik"):
        raise InputError(f"--method {options.method}: full-pose data are calibrated by ml "
                         "(maximum likelihood, default) or ik (inverse-kinematic residuals)")


def _calibrate_full_pose(machine, data, source, options: CalibrateOptions,
                         split) -> Calibration:
    from ..instruments.pose import (
        FullPoseNoise,
        MeasurementFrames,
        calibrate_full_pose,
        full_pose_errors,
    )
    from ..io import read_full_pose
    from ..machines.stewart import reading_factor
    from ..units import LENGTH

    method, fix_frames = options.method or "ml", options.fix_frames
    noise_model, hold = pose_noise_option(options.noise, options.pose_noise, machine)
    data, held = _split_rows(_load(data, read_full_pose, machine), split, source)
    file_frames = getattr(machine, "measurement_frames", None)
    if fix_frames:
        frames = file_frames if file_frames is not None else MeasurementFrames.identity()
        frames_from = ("the machine file's measurement_frames" if file_frames is not None
                       else "identity (the machine file has no measurement_frames)")
    else:
        frames = file_frames
        frames_from = ("start: the machine file's measurement_frames" if file_frames is not None
                       else "start: closed form from the design model")
    result = _solve(source, calibrate_full_pose, machine, data, held=held, method=method,
                    noise=noise_model, frames=frames, fix_frames=fix_frames,
                    estimate_noise=hold, robust=options.robust)
    # the machine's model extensions (a leg's reading curvature ...), adopted only when they
    # predict rows held out of the fit better (k-fold cross-validation on these data)
    model, choice = machine, None
    if options.extensions != "none" and machine.model_extensions():
        from .extensions import choose_full_pose_extensions

        _require_converged(result, source)
        levels = result.extras.get("noise")
        cv_noise = noise_model if levels is None else FullPoseNoise(
            **{f"{k}_{'rad' if k == 'orientation' else 'm'}": v
               for k, v in zip(levels.keys, levels.sigma, strict=True)})
        choice = choose_full_pose_extensions(machine, data, method, cv_noise, frames=frames,
                                             fix_frames=fix_frames)
        if choice.adopted:
            model = choice.machine
            result = _solve(source, calibrate_full_pose, model, data, held=held,
                            method=method, noise=noise_model, frames=frames,
                            fix_frames=fix_frames, estimate_noise=hold, robust=options.robust)
        result.extras["extensions"] = choice
    # the machine file's legs with the frames fitted alone: "before calibration"
    before = _solve(source, calibrate_full_pose, machine, data, held=held, method=method,
                    noise=noise_model, frames=frames if fix_frames
                    else result.extras["start_frames"], fix_frames=fix_frames,
                    fit_machine=False)
    _require_converged(result, source)

    units = file_units(machine)
    fl = LENGTH[units["length"]]
    calibrated = result.extras["machine"]
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    calibrated.home = machine.home
    frames_id = result.extras["frames"]
    err_after = full_pose_errors(calibrated, frames_id, data)
    err_before = full_pose_errors(machine, before.extras["frames"], data)

    reading_unit = getattr(machine, "reading_unit", None) or machine.joint_unit()[0]
    gain_factor = fl / reading_factor(reading_unit)         # internal gain -> file gain
    nominal_of = dict(zip(model.parameters.names, model.u, strict=True))
    start = result.extras["start_frames"]
    for name, (R, t) in (("mocap_from_base", start.mocap_from_base),
                         ("platform_from_marker", start.platform_from_marker)):
        nominal_of.update({f"{name}.r{c}": 0.0 for c in "xyz"})
        nominal_of.update({f"{name}.{c}": v for c, v in zip("xyz", t, strict=True)})
    params = _parameter_table(result, nominal_of, units)
    for p in params:
        if p["name"].endswith(".gain"):
            for key in ("nominal", "identified", "change", "std"):
                if p[key] is not None:
                    p[key] = p[key] / gain_factor
            p["unit"] = f"{units['length']}/{reading_unit}"
        elif p["name"].endswith(".curvature"):           # internal -> file length / reading^2
            for key in ("nominal", "identified", "change", "std"):
                if p[key] is not None:
                    p[key] = p[key] * reading_factor(reading_unit) ** 2 / fl
            p["unit"] = f"{units['length']}/{reading_unit}^2"
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.extras.get("unidentifiable", []))
    # the ik estimate takes the poses as exact, but their noise is in the residuals: its
    # residual test is against the whole noise (readings + poses through the IK); the residuals
    # section states the verdict's numbers (_finish)
    variance = float(result.residual_variance)
    after, before_rep = _errors_report(err_after, fl), _errors_report(err_before, fl)
    extensions = (choice.as_dict({"leg_length": (fl, units["length"]), "position": (
        fl, units["length"]), "orientation": (math.pi / 180, "deg")}) if choice is not None
        else {"tried": [], "adopted": [], "skipped": "--extensions none" if
              options.extensions == "none" else "the machine offers none"})
    report = {
        **_report_head(machine, source, "pose", method, units),
        "reading_unit": reading_unit,
        "measurements": len(data),
        "noise": {"reading_um": noise_model.reading_m * 1e6,
                  "position_um": noise_model.position_m * 1e6,
                  "orientation_urad": noise_model.orientation_rad * 1e6},
        "frames": {
            "fixed": bool(fix_frames), "from": frames_from,
            "mocap_from_base": _frame_report(frames_id.mocap_from_base, fl, units["length"]),
            "platform_from_marker": _frame_report(frames_id.platform_from_marker, fl,
                                                  units["length"]),
        },
        "convergence": _convergence_json(result),
        "residuals": {
            "unit": units["length"],
            "leg_length": "l0 + gain q minus the leg length at the measured pose (through the "
                          "frames)",
            "pose": "measured marker pose minus the one forward kinematics of the readings "
                    "predict (through the frames)",
            "before": "the machine file's legs, frames fitted alone",
            "before_calibration": before_rep,
            "after_calibration": after,
            "residual_variance": variance,
            "noise_scale": math.sqrt(variance) if math.isfinite(variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": _public(params),
        "model_extensions": extensions,
    }
    if held is not None:
        h_after = _errors_report(full_pose_errors(calibrated, frames_id, held), fl)
        h_before = _errors_report(full_pose_errors(machine, before.extras["frames"], held), fl)
        report["validation"] = _validation(
            split, held, "pose error of the held-out rows: forward kinematics of the readings "
            "(through the identified frames) vs the measured pose; before: the machine file's "
            "legs, frames fitted alone on the calibration rows", units["length"],
            *json_safe([h_before["position_rms"], h_after["position_rms"],
                        after["position_rms"]]), before_calibration=h_before,
            after_calibration=h_after)
    metadata = {
        "method": f"full-pose-{method}",
        "date": report["date"],
        "data": path_text(source),
        "machine": _source_of(machine),
        "measurements": len(data),
        "leg_length_rms": {"before": before_rep["leg_length_rms"],
                           "after": after["leg_length_rms"], "unit": units["length"]},
        "frames_fixed": bool(fix_frames),
        "model_extensions": list(choice.adopted) if choice is not None else [],
        "identifiable": rank,
        "free_parameters": n_free,
        **_identifiability_metadata(unidentifiable),
    }
    # the nominal of the fitted model (with an adopted extension at its neutral values)
    return _finish("pose", model, calibrated, result, report, metadata, params, units)


# -- ballbar distances ------------------------------------------------------------------------


def _check_distances(options: CalibrateOptions, source) -> None:
    _only_for_poses(options, source, "distance")
    for option, given in (("--method", options.method is not None),
                          ("--estimate-lc", options.estimate_lc is not None),
                          ("--two-step", options.two_step)):
        if given:
            raise InputError(f"{option}: does not apply to ballbar data ({path_text(source)}); see "
                             "--noise (the ballbar's standard deviation, default 1um), "
                             "--robust")


def _distance_noise(noise, machine):
    """The ballbar noise of ``--noise`` (:meth:`~pkmcal.instruments.distance.Distance.noise_arg`;
    default 1 um)."""
    from ..instruments.registry import instrument

    return instrument("distance").noise_arg(noise, machine)


def _scalar_rms(problem, state, data) -> tuple[float | None, np.ndarray]:
    """RMS (um) and residuals (m) of a one-value instrument (ballbar lengths, probe heights)
    under a problem's state (NaN where the forward kinematics fail)."""
    predicted = problem.predict(state, data.q, data.group)[:, 0]
    r = data.values[:, 0] - predicted
    ok = np.isfinite(r)
    return (_um(math.sqrt(float(np.mean(r[ok] ** 2)))) if ok.any() else None), r


def _fit_with_baseline(machine, data, source, split, reader, fit, noise, advice: str,
                       options: CalibrateOptions):
    """What the instrument-layer kinds share: read and split the data, fit the instrument
    with the machine and alone on the machine file's model (the "before" baseline), check
    convergence, name the calibrated machine and build the parameter table (start values of
    the instrument's unknowns as their nominal)."""
    data, held = _split_rows(_load(data, reader, machine), split, source)
    # the noise level from the residuals unless the user gave it; rows it cannot explain
    # named (left out with --robust)
    result = _solve(source, fit, machine, data, noise, held=held,
                    estimate_noise=options.noise is None, robust=options.robust)
    before = _solve(source, fit, machine, data, noise, held=held, fit_machine=False)
    _require_converged(result, source, advice)
    units = file_units(machine)
    calibrated = result.extras["machine"]
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    calibrated.home = machine.home
    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    start = result.extras["start_model"].parameters
    nominal_of.update(zip(start.names, start.values, strict=True))
    params = _parameter_table(result, nominal_of, units)
    return data, held, result, before, calibrated, params, units


def _calibrate_distances(machine, data, source, options: CalibrateOptions,
                         split) -> Calibration:
    from ..instruments.distance import calibrate_distances
    from ..io import read_distances
    from ..units import LENGTH

    noise = _distance_noise(options.noise, machine)
    data, held, result, before, calibrated, params, units = _fit_with_baseline(
        machine, data, source, split, read_distances, calibrate_distances, noise,
        "measure each mounting over a spread of poses (a sphere around the pivot, with "
        "rotations on a platform that rotates)", options)
    fl = LENGTH[units["length"]]
    problem, before_problem = result.extras["problem"], before.extras["problem"]
    rms_after, r_after = _scalar_rms(problem, result.state, data)
    rms_before, _ = _scalar_rms(before_problem, before.state, data)
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.extras.get("unidentifiable", []))
    setups = result.extras["setups"]
    ok = np.isfinite(r_after)
    report = {
        **_report_head(machine, source, "distance", "joint"),
        "units": units,
        "measurements": len(data),
        "noise": f"ballbar {noise.sigma * 1e6:.4g} um (std)",
        "setups": [{"setup": g + 1, "rows": int(np.sum(data.group == g)),
                    "pivot": (p / fl).tolist(), "ball": (b / fl).tolist(),
                    "unit": units["length"]} for g, (p, b) in enumerate(setups)],
        "convergence": _convergence_json(result),
        "residuals": {
            "of": "ballbar lengths, measured - predicted (forward kinematics of the readings)",
            "count": int(ok.sum()),
            "rms_um": rms_after,
            "max_abs_um": _um(float(np.max(np.abs(r_after[ok])))) if ok.any() else None,
            "before_rms_um": rms_before,
            "before": "machine file's model, mountings (pivots and balls) fitted alone",
            "residual_variance": float(result.residual_variance),
            "noise_scale": float(np.sqrt(result.residual_variance))
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": _public(params),
    }
    if held is not None:
        report["validation"] = _validation(
            split, held, "ballbar lengths of the held-out rows, measured - predicted with the "
            "identified mountings; before: the machine file's model with the mountings fitted "
            "alone on the calibration rows", "um",
            _scalar_rms(before_problem, before.state, held)[0],
            _scalar_rms(problem, result.state, held)[0], rms_after)
    metadata = {
        "method": "ballbar",
        "date": report["date"],
        "data": path_text(source),
        "machine": _source_of(machine),
        "measurements": len(data),
        "rms_residual_um": rms_after,
        "identifiable": rank,
        "free_parameters": n_free,
        **_identifiability_metadata(unidentifiable),
    }
    return _finish("distance", machine, calibrated, result, report, metadata, params, units)


# --------------------------------------------------------------------------------------------
# named parameter sets (--parameters)
# --------------------------------------------------------------------------------------------


def _machines_with_sets() -> list[str]:
    """Machine types whose class has named parameter sets (``parameter_set``)."""
    from ..machines.base import Machine

    found, todo = set(), list(Machine.__subclasses__())
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        if getattr(cls, "kind", "") and (getattr(cls, "PARAMETER_SETS", None)
                                         or "parameter_set" in vars(cls)):
            found.add(cls.kind)
    return sorted(found)


def parameter_set_names(machine) -> list[str] | None:
    """The names of a machine's parameter sets, when it lists them (None: it does not).

    Parameters
    ----------
    machine : Machine
        The machine (``parameter_sets``: a list, a mapping or a method giving one).

    Returns
    -------
    list of str or None
        The names.
    """
    sets = getattr(machine, "parameter_sets", None)
    if callable(sets):
        sets = sets()
    if sets is None:
        own = getattr(machine, "PARAMETER_SETS", None)
        if own is None:
            return None
        return sorted(set(map(str, own)) | {"full"})
    return [str(k) for k in (sets.keys() if isinstance(sets, dict) else sets)]


def apply_parameter_set(machine, name: str):
    """A copy of ``machine`` whose fixed flags are those of its parameter set ``name``.

    Parameters
    ----------
    machine : Machine
        A machine with ``parameter_set(name) -> ParameterSet`` (e.g. a firmware's set).
    name : str
        The set's name (``--parameters``).

    Returns
    -------
    Machine
        The copy (values unchanged; parameters the set does not name are fixed).

    Raises
    ------
    InputError
        When the machine has no named sets (naming the machine types that have them) or
        none of this name (listing its sets).
    """
    from ..parameters import ParameterSet

    method = getattr(machine, "parameter_set", None)
    kind = getattr(machine, "kind", "") or "machine"
    if not callable(method):
        having = _machines_with_sets()
        raise InputError(f"--parameters {name}: a {kind} has no named parameter sets ("
                         + (f"machines with them: {', '.join(having)}" if having else
                            "no machine type of this version has them") + ")")
    names = parameter_set_names(machine)
    if names == ["full"] and name != "full":
        having = _machines_with_sets()
        raise InputError(f"--parameters {name}: a {kind} has no named parameter sets besides "
                         "full (every parameter free) ("
                         + (f"machines with them: {', '.join(having)}" if having else
                            "no machine type of this version has them") + ")")
    listing = f"; its sets: {', '.join(names)}" if names else ""
    if names is not None and name not in names:
        raise InputError(f"--parameters {name}: no parameter set of that name for this "
                         f"{kind}{listing}")
    try:
        chosen = method(name)
    except (KeyError, ValueError, InputError) as exc:
        text = str(exc).strip("'\"")
        raise InputError(f"--parameters {name}: no parameter set of that name for this "
                         f"{kind}{listing or (': ' + text if text else '')}") from None
    mp = machine.parameters
    if tuple(chosen.names) == tuple(mp.names):
        fixed = np.asarray(chosen.fixed, bool)
    else:
        lookup = dict(zip(chosen.names, np.asarray(chosen.fixed, bool), strict=True))
        fixed = np.array([lookup.get(n, True) for n in mp.names], bool)
    new = machine.with_parameters(mp.values)
    new.parameters = ParameterSet(mp.names, mp.kinds, mp.values, fixed)
    return new


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


@dataclass
class JointPart:
    """One file of a joint fit, ready for :func:`~pkmcal.instruments.joint.fit_joint`.

    Attributes
    ----------
    data : InstrumentData
        Readings and measurements.
    model : NuisanceModel
        The instrument's model (start values computed by the fit).
    noise : object
        Noise model (``whitening``).
    noise_text : str
        The noise in words.
    kind : str
        The measurement kind (a key of :data:`KINDS`).
    """

    data: object
    model: object
    noise: object
    noise_text: str
    kind: str
    #: ``with_others(equations, unknowns) -> (model, words)``: the part's model once the
    #: other files are known (a printer's bed tilt, decided on every file's equations)
    with_others: Callable | None = None
    frame: str = ""
    #: weighed as the data's source weighs them (relative levels held, common level fitted)
    tied: bool = False


def _joint_tracker(machine, data, source, noise) -> JointPart:
    from ..instruments import PointsModel
    from ..instruments.tracker import as_points
    from ..io import read_tracker

    if noise is None or isinstance(noise, str):
        noise_model, text = tracker_noise_arg(noise, allow_none=False, machine=machine)
    else:
        noise_model, text = noise, _tracker_noise_text(noise)
    raw = as_tracker_data(_load(data, read_tracker, machine))
    _check_spread(raw, noise_model)
    points = as_points(raw)
    points.source = str(source)
    return JointPart(points, PointsModel(points.n_groups, machine.tracker_target()),
                     noise_model, text, "tracker")


def _joint_distances(machine, data, source, noise) -> JointPart:
    from ..instruments import DistancesModel
    from ..io import read_distances

    noise_model = _distance_noise(noise, machine)
    dist = _load(data, read_distances, machine)
    counts = np.bincount(dist.group, minlength=dist.n_groups)
    few = np.flatnonzero(counts < 6)
    if few.size:
        raise InputError(f"{path_text(source)}: "
                         f"setup {few[0] + 1} has {counts[few[0]]} row(s); each "
                         "mounting needs at least 6 lengths (its pivot and ball are unknown)")
    dist.source = str(source)
    return JointPart(dist, DistancesModel(dist.n_groups), noise_model,
                     f"ballbar {noise_model.sigma * 1e6:.4g} um (std)", "distance")


def _joint_probe(machine, data, source, noise) -> JointPart:
    from ..instruments.probe import bed_choice
    from ..io import read_probe

    probe = _load(data, read_probe, machine)
    noise_model = (probe.weights[0] if noise is None and probe.weights is not None
                   else _probe_noise(noise, machine))
    probe.source = str(source)
    _check_heights(probe, machine)

    def with_others(equations, unknowns, choice="auto", data=probe, others=()):
        bed = bed_choice(machine, data, noise_model, choice, equations, unknowns,
                         others=others)
        return bed.model(), bed.words

    model, frame = with_others(0, 0, "estimate" if machine.frame_is_bed else "auto")
    return JointPart(probe, model, noise_model,
                     f"probe trigger {noise_model.sigma * 1e6:.4g} um along z (std)", "probe",
                     with_others, frame)


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
    if kind.joint is not None:
        return kind.joint(machine, data, source, noise)
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
    from ..io import read_table
    from ..units import LENGTH

    _check_joint_options(options or CalibrateOptions())
    if isinstance(noise, str) or (noise is not None and not isinstance(noise, dict)):
        raise InputError("--noise: with several data files give FILE=VALUE per file (e.g. "
                         "--noise bar.csv=2um)")
    sources, kinds = [], []
    for i, item in enumerate(data):
        if isinstance(item, (str, Path)):
            source = Path(item)
            header, _ = read_table(source)
            kinds.append(KINDS[measurement_kind(source, header, machine)])
        else:
            source = getattr(item, "source", None) or f"data{i + 1}"
            kind = next((k for k in _kinds() if k.data_class == type(item).__name__
                         and getattr(item, "kind", k.instrument) in _names_of(k)), None)
            if kind is None:
                raise InputError(f"{path_text(source)}: "
                                 f"{type(item).__name__} is no calibration data")
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
    parts, held, hold = [], [], []
    for i, (item, source, kind) in enumerate(zip(data, sources, kinds, strict=True)):
        given = _noise_of(noise, sources, i)
        if given is not None:       # the user's level for this file is held
            hold.append(f"{labels[i]}:*")
        part = _joint_part(machine, item, source, kind, given)
        weights = getattr(part.data, "weights", None)
        if given is None and weights is not None:    # the data's own source's weights
            hold.append(f"{labels[i]}:*")
            part.noise_text += f" ({weights[1]})"
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
    try:
        result = fit_joint(machine, [(p.data, p.model, p.noise) for p in parts], labels,
                           estimate_noise=hold,
                           robust=bool(options is not None and options.robust))
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
                               robust=bool(options is not None and options.robust))
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
            "residual_variance": float(result.residual_variance),
            "noise_scale": float(np.sqrt(result.residual_variance))
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        "contributions": {**contributions.as_dict(fl, fa, (units["length"], units["angle"])),
                          "summary": contributions.lines()},
        "parameters": _public(params),
    }
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
    # the rule a probe calibration warns by, for the files fitted together too
    calibration.warnings.extend(_poorly_determined(result, machine, report, names, units))
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
# the kinds of today
# --------------------------------------------------------------------------------------------

register_kind(MeasurementKind("tracker", _calibrate_tracker, _check_tracker, _joint_tracker))
register_kind(MeasurementKind("pose", _calibrate_full_pose, _check_full_pose))
register_kind(MeasurementKind("distance", _calibrate_distances, _check_distances,
                              _joint_distances))
register_kind(MeasurementKind("constraint-link", _calibrate_constraint_link,
                              _check_constraint_link))


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
    ok = np.isfinite(r_after)
    n_free = int(np.sum(result.parameters.free))
    unidentifiable = list(result.extras.get("unidentifiable", []))
    report = {
        **_report_head(machine, source, inst.name, "joint"),
        "units": units,
        "measurements": len(data),
        "noise": inst.noise_text(noise),
        "convergence": _convergence_json(result),
        "residuals": {
            "of": inst.residual_words,
            "count": int(ok.sum()),
            "rms_um": rms_after,
            "max_abs_um": _um(float(np.max(np.abs(r_after[ok])))) if ok.any() else None,
            "before_rms_um": rms_before,
            "before": "machine file's model",
            "residual_variance": float(result.residual_variance),
            "noise_scale": float(np.sqrt(result.residual_variance))
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": _identifiability_json(n_free, int(result.rank), unidentifiable,
                                                 np.asarray(result.singular_values, float)),
        "parameters": _public(params),
    }
    metadata = {"method": inst.name, "date": report["date"], "data": path_text(source),
                "machine": _source_of(machine), "measurements": len(data),
                "rms_residual_um": rms_after, "identifiable": int(result.rank),
                "free_parameters": n_free, **_identifiability_metadata(unidentifiable)}
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


#: a common offset of the probe heights against the machine file's model beyond this (m) is
#: checked for a flipped sign or a wrong unit (below it the two cannot be told from a
#: machine file's endstop error)
HEIGHT_CHECK = 2e-4


def _check_heights(data, machine) -> None:
    """Probe heights with a flipped sign or a wrong unit, refused naming the fix.

    On a machine whose frame is its bed the machine file's model puts the nozzle at a height
    for each row's readings; the saved heights sit about there (the file's values are the
    firmware's). When they sit ``HEIGHT_CHECK`` or more away from it and their negatives, or
    the same numbers in mm / um, sit ten times closer, the sign or the unit is wrong.
    """
    if not getattr(machine, "frame_is_bed", False) or not len(data):
        return
    fk = machine.fk(data.q)
    if not fk.converged.all():
        return
    z = np.asarray(fk.P, float)[:, 2]
    h = np.asarray(data.values, float)[:, 0]
    offset = abs(float(np.median(z - h)))
    if offset < HEIGHT_CHECK:
        return
    fixes = (("the opposite sign", -h, "probe_z is the nozzle's height ABOVE the bed when the "
              "probe triggers (Klipper's heightN and [probe] z_offset; Marlin's M851 Z is its "
              "negative): flip the sign"),
             ("in um", h * 1e-3, "the unit of probe_z is wrong (the numbers are um)"),
             ("in mm", h * 1e3, "the unit of probe_z is wrong (the numbers are mm)"))
    for words, other, fix in fixes:
        if abs(float(np.median(z - other))) < 0.1 * offset:
            raise InputError(f"{path_text(data.source)}: "
                             f"the probe heights sit {offset * 1e3:.4g} mm "
                             f"from where the machine file puts the nozzle, and {words} "
                             f"within {abs(float(np.median(z - other))) * 1e3:.3g} mm of it: "
                             f"{fix} (or, if the machine file's position_endstop values are "
                             "that far from the ones the data were probed with, import the "
                             "config the data were saved with)")


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
    from ..io.klipper_config import is_klipper_config, read_klipper_data

    items = list(data) if isinstance(data, (list, tuple)) else [data]
    out, changed = [], False
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


# -- bed-probe heights (issue 14 items 2, 3) --------------------------------------------------


def _check_probe(options: CalibrateOptions, source) -> None:
    _only_for_poses(options, source, "probe")
    for option, given in (("--method", options.method is not None),
                          ("--estimate-lc", options.estimate_lc is not None),
                          ("--two-step", options.two_step)):
        if given:
            raise InputError(f"{option}: does not apply to probe heights ({path_text(source)}); "
                             "see "
                             "--noise (the probe's repeatability along z, default 10um), "
                             "--robust")


def _probe_noise(noise, machine):
    """The probe noise of ``--noise`` (:meth:`~pkmcal.instruments.probe.Probe.noise_arg`)."""
    from ..instruments.registry import instrument

    return instrument("probe").noise_arg(noise, machine)


def _calibrate_probe(machine, data, source, options: CalibrateOptions, split) -> Calibration:
    from ..instruments.probe import (
        MEASURE_NEXT,
        POOR_STD,
        bed_choice,
        calibrate_probe,
        poorly_determined_warnings,
    )
    from ..io import read_probe
    from ..units import LENGTH

    noise = _probe_noise(options.noise, machine)
    chosen: dict = {}

    def fit(machine_, data_, noise_, **kwargs):
        # one bed model for the fit and its baseline, chosen on the parameter set's unknowns
        if "bed" not in chosen:
            _check_heights(data_, machine)
            chosen["bed"] = bed_choice(machine, data_, noise_, options.bed_tilt or "auto")
        return calibrate_probe(machine_, data_, noise_, bed=chosen["bed"], **kwargs)

    data, held, result, before, calibrated, params, units = _fit_with_baseline(
        machine, data, source, split, read_probe, fit, noise,
        "probe over the whole bed (the centre and rings out to the edge of the reachable "
        "radius)", options)
    fl = LENGTH[units["length"]]
    problem, before_problem = result.extras["problem"], before.extras["problem"]
    rms_after, r_after = _scalar_rms(problem, result.state, data)
    rms_before, r_before = _scalar_rms(before_problem, before.state, data)
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.extras.get("unidentifiable", []))
    poor = result.extras.get("poorly_determined", [])
    bed, bed_before = result.extras["bed"], before.extras["bed"]
    ok = np.isfinite(r_after)

    def plane(b):
        return {"height": b[0] / fl, "tilt_x": b[1], "tilt_y": b[2], "unit": units["length"],
                "tilt": "slopes dz/dx, dz/dy"}

    report = {
        **_report_head(machine, source, "probe", "joint"),
        "units": units,
        "measurements": len(data),
        "noise": f"probe trigger {noise.sigma * 1e6:.4g} um along z (std)",
        "bed": {**plane(bed), "before": plane(bed_before),
                "model": "z = height + tilt_x x + tilt_y y (base frame); heights measured "
                         "along z",
                "frame": chosen["bed"].words, "tilt_estimated": chosen["bed"].tilt
                == "estimated"},
        "bed_frame": chosen["bed"].words,
        "convergence": _convergence_json(result),
        "residuals": {
            "of": "probe heights, measured - predicted (forward kinematics of the readings, "
                  "height above the fitted bed along z)",
            "count": int(ok.sum()),
            "rms_um": rms_after,
            "max_abs_um": _um(float(np.max(np.abs(r_after[ok])))) if ok.any() else None,
            "before_rms_um": rms_before,
            "before_max_abs_um": _um(float(np.nanmax(np.abs(r_before))))
            if np.isfinite(r_before).any() else None,
            "before": "machine file's model, bed plane (height and tilt) fitted alone",
            "residual_variance": float(result.residual_variance),
            "noise_scale": float(np.sqrt(result.residual_variance))
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": _identifiability_json(n_free, rank, unidentifiable, s),
        "poorly_determined": {
            "threshold_mm": POOR_STD * 1e3,
            "rule": "a determined parameter whose standard deviation (an angle's or ratio's "
                    "times the characteristic length) exceeds the threshold",
            "measure_next": MEASURE_NEXT["probe"],
            "parameters": [{"name": p.name, "std": p.std / (fl if p.kind == "length" else 1.0),
                            "kind": p.kind, "correlated_with": p.partner,
                            "correlation": p.correlation} for p in poor],
        },
        "parameters": _public(params),
    }
    if held is not None:
        report["validation"] = _validation(
            split, held, "probe heights of the held-out rows, measured - predicted with the "
            "identified bed; before: the machine file's model with the bed fitted alone on "
            "the calibration rows", "um",
            _scalar_rms(before_problem, before.state, held)[0],
            _scalar_rms(problem, result.state, held)[0], rms_after)
    metadata = {
        "method": "probe",
        "date": report["date"],
        "data": path_text(source),
        "machine": _source_of(machine),
        "measurements": len(data),
        "rms_residual_um": rms_after,
        "identifiable": rank,
        "free_parameters": n_free,
        **_identifiability_metadata(unidentifiable),
    }
    calibration = _finish("probe", machine, calibrated, result, report, metadata, params,
                          units)
    calibration.warnings.extend(poorly_determined_warnings(poor, source, "probe", units))
    return calibration


register_kind(MeasurementKind("probe", _calibrate_probe, _check_probe, _joint_probe))

# every instrument without handlers of its own calibrates by the generic path
_kinds()
