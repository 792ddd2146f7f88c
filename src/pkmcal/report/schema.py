"""The calibration report (the JSON twin ``pkmcal calibrate`` writes): reading and checking.

``pkmcal report`` and ``pkmcal compensate`` read a report a user hands them; it may be any
file. :func:`load_report` parses it and checks every section those commands use against a
schema (pydantic) before any of it is used, so a wrong file is one :class:`InputError` naming
the file and the key (``cal.json: parameters[3].std: not a number``), never a ``KeyError``
inside the HTML builder. Sections that are not used are not checked (a newer pkmcal may add
some); sections that are used and present must have the right shape.

A report is at most :data:`MAX_REPORT_BYTES` long and :data:`MAX_DEPTH` deep (a calibration
report of 1000 parameters is a few tens of megabytes; deep nesting would exhaust the parser's
recursion).
"""

from __future__ import annotations

import itertools
import json
import re
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    Strict,
    ValidationError,
    field_validator,
    model_validator,
)

from ..errors import InputError
from ..paths import path_text

__all__ = ["MAX_DEPTH", "MAX_REPORT_BYTES", "CalibrationReport", "load_report",
           "validate_report"]

#: largest report read (bytes)
MAX_REPORT_BYTES = 512 * 1024 * 1024
#: deepest nesting of JSON arrays/objects accepted (pkmcal writes at most 4)
MAX_DEPTH = 32

#: a JSON number (not a bool, not a string); NaN/Infinity literals are refused
Num = Annotated[float, Strict(), Field(allow_inf_nan=False)]
Int = Annotated[int, Strict()]
OptNum = Num | None


class _Section(BaseModel):
    model_config = ConfigDict(extra="allow", strict=True)


class SectionIndex(_Section):
    """One entry of ``sections``: an instrument's typed section of the result (its title, the
    report keys it wrote, its summary rows), as the console and the HTML page show it."""

    title: str
    keys: list[str] = Field(default_factory=list)
    summary: list[Annotated[list[str], Field(min_length=2, max_length=2)]] = Field(
        default_factory=list)


class Convergence(_Section):
    """``convergence``: whether and how the estimator ended."""

    success: bool
    message: str = ""
    status: Int | None = None
    iterations: Int | None = Field(default=None, ge=0)
    evaluations: Int | None = Field(default=None, ge=0)


class Unidentifiable(_Section):
    """One named group of unidentifiable directions."""

    name: str
    dimension: Int = Field(ge=0)
    description: str = ""


class Identifiability(_Section):
    """``identifiability``: rank, named null directions, singular values."""

    free_parameters: Int = Field(ge=0)
    identifiable: Int = Field(ge=0)
    unidentifiable: list[Unidentifiable] = Field(default_factory=list)
    condition_number: OptNum = None
    singular_values: list[Num] = Field(default_factory=list)

    @model_validator(mode="after")
    def _rank_at_most_count(self):
        if self.identifiable > self.free_parameters:
            raise ValueError(f"identifiable ({self.identifiable}) exceeds free_parameters "
                             f"({self.free_parameters})")
        return self


class Parameter(_Section):
    """One row of ``parameters``."""

    name: str
    unit: str = ""
    nominal: OptNum = None
    identified: OptNum = None
    change: OptNum = None
    std: OptNum = Field(default=None, ge=0)
    fixed: bool | None = None


class RatioStats(_Section):
    """Distance-ratio statistics (percent)."""

    mean: Num
    min: Num
    max: Num
    std: Num


class DistanceRatio(_Section):
    """``distance_ratio`` (Delta tracker reports)."""

    before: RatioStats | None = None
    after: RatioStats | None = None
    after_two_step: RatioStats | None = None
    pairs: Int | None = None
    pairs_from: str = ""


class FramesCovariance(_Section):
    """``covariance.with_frames``: machine + frame parameters together."""

    parameters: list[str]
    matrix: list[list[Num]]
    null_space: list[list[Num]] | None = None

    @model_validator(mode="after")
    def _square(self):
        n = len(self.parameters)
        _check_square(self.matrix, n)
        _check_null_space(self.null_space, n)
        return self


class Covariance(_Section):
    """``covariance``: of the machine parameters (SI units), with the null space."""

    parameters: list[str]
    matrix: list[list[Num]]
    null_space: list[list[Num]] | None = None
    with_frames: FramesCovariance | None = None

    @model_validator(mode="after")
    def _shapes(self):
        n = len(self.parameters)
        _check_square(self.matrix, n)
        _check_null_space(self.null_space, n)
        return self


def _check_null_space(null_space, n: int) -> None:
    if null_space is not None:
        if len(null_space) != n or len({len(r) for r in null_space}) > 1:
            raise ValueError(f"null_space must have {n} rows of one length")


def _check_square(matrix, n: int) -> None:
    if len(matrix) != n or any(len(row) != n for row in matrix):
        raise ValueError(f"matrix must be {n} x {n} (one row and column per parameter)")


Scalar = str | bool | int | float | None


class Units(_Section):
    """``units``: the units of the calibrated file, used for the tables."""

    length: Literal["mm", "m", "in"]
    angle: Literal["deg", "rad"]


class Residuals(_Section):
    """``residuals``: the numbers shown are checked; other keys are shown as written."""

    rms_um: OptNum = Field(default=None, ge=0)
    max_abs_um: OptNum = Field(default=None, ge=0)
    before_rms_um: OptNum = Field(default=None, ge=0)
    before_max_abs_um: OptNum = Field(default=None, ge=0)
    noise_scale: OptNum = Field(default=None, ge=0)
    count: Int | None = Field(default=None, ge=0)
    dof: Int | None = None
    residual_variance: OptNum = Field(default=None, ge=0)
    estimated_noise_um: OptNum = Field(default=None, ge=0)


class NoiseGroup(_Section):
    """One noise group of ``noise_model`` (``NoiseEstimate.as_dict``)."""

    key: str
    name: str
    unit: str
    assumed: Num = Field(gt=0)
    sigma: Num = Field(gt=0)
    std: OptNum = Field(default=None, ge=0)
    ratio: Num = Field(gt=0)
    redundancy: Num = Field(ge=0)
    capacity: OptNum = Field(default=None, ge=0)
    count: Int = Field(ge=0)
    status: Literal["estimated", "held", "assumed", "at most"]


class NoiseModel(_Section):
    """``noise_model``: the levels used, assumed, estimated or held."""

    estimated: bool
    groups: list[NoiseGroup]
    min_redundancy: Num = Field(ge=0)
    iterations: Int | None = Field(default=None, ge=0)


class OutlierRow(_Section):
    """A row the outlier test names."""

    row: str
    statistic: Num = Field(ge=0)
    dof: Int = Field(ge=0)
    p: Num = Field(ge=0, le=1)
    left_out: bool


class Outliers(_Section):
    """``outliers``: the rows the test names, and those left out of the fit."""

    alpha: Num = Field(gt=0, lt=1)
    threshold_p: Num = Field(ge=0, le=1)
    flagged: list[OutlierRow]
    left_out: list[str]


class AdequacyGroup(_Section):
    """One noise group of ``model_adequacy``: its residuals' RMS and the levels."""

    name: str
    unit: str
    rms: OptNum = Field(default=None, ge=0)
    count: Int = Field(ge=0)
    over_assumed: OptNum = Field(default=None, ge=0)
    assumed: OptNum = Field(default=None, gt=0)
    used: OptNum = Field(default=None, gt=0)


class Trend(_Section):
    """A significant trend of a residual column against a reading or pose coordinate."""

    residual: str
    against: str
    shape: Literal["linear", "quadratic"]
    explained: Num = Field(ge=0, le=1)
    p: Num = Field(ge=0, le=1)
    p_adjusted: Num = Field(ge=0, le=1)


class AdequacyColumn(_Section):
    """A residual column: its RMS and its strongest trend."""

    name: str
    unit: str
    rms: OptNum = Field(default=None, ge=0)
    strongest_trend: Trend | None = None


class ModelAdequacy(_Section):
    """``model_adequacy`` (:func:`pkmcal.calibration.adequacy.model_adequacy`)."""

    noise_ratio: OptNum = Field(default=None, ge=0)
    far_above_noise: bool
    far_above: OptNum = Field(default=None, ge=0)
    groups: list[AdequacyGroup]
    columns: list[AdequacyColumn]
    trends: list[Trend]
    significant_trends: Int = Field(ge=0)
    tests: Int = Field(ge=0)
    alpha: Num = Field(gt=0, lt=1)
    verdict: str


class ExtensionTrial(_Section):
    """A model extension tried: its held-out loss with and without it, and the verdict."""

    name: str
    description: str = ""
    cv_loss: OptNum = Field(default=None, ge=0)
    cv_loss_baseline: OptNum = Field(default=None, ge=0)
    cv_gain: OptNum = None
    cv_se: OptNum = Field(default=None, ge=0)
    adopted: bool
    why: str


class ModelExtensions(_Section):
    """``model_extensions``: the extensions tried by cross-validation and those adopted."""

    tried: list[str]
    adopted: list[str]
    criterion: str = ""
    folds: Int | None = Field(default=None, ge=2)
    trials: list[ExtensionTrial] = []
    skipped: str | None = None

    @model_validator(mode="after")
    def _adopted_were_tried(self):
        tried = {t.name for t in self.trials} | set(self.tried)
        missing = [a for a in self.adopted if a not in tried]
        if missing:
            raise ValueError(f"adopted: {missing[0]!r} is not among the extensions tried")
        if self.trials and self.folds is None:
            raise ValueError("folds: missing (the trials' cross-validation states its folds)")
        return self


class BedPlaneState(_Section):
    """A bed plane: ``height`` (the section's unit) and the slopes ``tilt_x``, ``tilt_y``."""

    height: Num
    tilt_x: Num = 0.0
    tilt_y: Num = 0.0


class Bed(BedPlaneState):
    """``bed`` (probe heights): the fitted bed plane and the one before."""

    before: BedPlaneState | None = None


class PoorParameter(_Section):
    """One parameter of ``poorly_determined``."""

    name: str
    std: Num = Field(ge=0)
    correlated_with: str | None = None
    correlation: OptNum = Field(default=None, ge=-1, le=1)


class PoorlyDetermined(_Section):
    """``poorly_determined``: parameters these data determine only loosely."""

    threshold_mm: OptNum = Field(default=None, ge=0)
    fraction: OptNum = Field(default=None, gt=0)
    characteristic_length_mm: OptNum = Field(default=None, gt=0)
    parameters: list[PoorParameter] = Field(default_factory=list)


class ResidualTestSection(_Section):
    """``acceptance.residuals``: the chi-square test of the residuals, or why there is none
    (:meth:`pkmcal.estimation.acceptance.ResidualVerdict.from_dict` reads it)."""

    tested: bool | None = None
    verdict: str | None = None
    chi2: OptNum = Field(default=None, ge=0)
    dof: Int | None = None
    chi2_per_dof: OptNum = Field(default=None, ge=0)
    upper_999: OptNum = Field(default=None, ge=0)
    noise_ratio: OptNum = Field(default=None, ge=0)
    passed: bool | None = None
    alarming: bool | None = None


class Acceptance(_Section):
    """``acceptance``: the verdicts of the calibration."""

    residuals: ResidualTestSection | None = None


class OutcomeVerdict(_Section):
    """``outcome.verdict``: the residual test's verdict in one sentence."""

    status: str
    words: str
    headline: str


class OutcomeFigures(_Section):
    """Accuracy figures (um): RMS and largest; ``lowest`` .. ``highest`` a signed range."""

    rms: OptNum = Field(default=None, ge=0)
    max: OptNum = Field(default=None, ge=0)
    std: OptNum = Field(default=None, ge=0)
    lowest: OptNum = None
    highest: OptNum = None


class OutcomeAccuracy(_Section):
    """``outcome.accuracy``: the machine's accuracy before and after."""

    quantity: str
    unit: Literal["um"]
    basis: str
    where: str = ""
    before: OutcomeFigures | None = None
    after: OutcomeFigures | None = None


class OutcomeChange(_Section):
    """A change of ``outcome.changes`` or ``outcome.firmware`` (the file's units)."""

    name: str
    unit: str
    before: Num
    after: Num
    change: Num
    std: OptNum = Field(default=None, ge=0)


class OutcomeStep(_Section):
    """A next command and why."""

    command: str
    why: str


class OutcomeMap(_Section):
    """``outcome.map``: a printer's bed (``grid_mm`` square, ``before_um``,
    ``after_std_um`` row by row) or the workspace's points (``x_mm``, ``y_mm``, ``before_um``,
    ``after_um``)."""

    kind: Literal["bed", "workspace"]
    unit: Literal["um"]
    grid_mm: list[Num] | None = None
    radius_mm: OptNum = Field(default=None, gt=0)
    before_um: list[Num | None]
    after_std_um: list[Num | None] | None = None
    after_um: list[Num | None] | None = None
    x_mm: list[Num] | None = None
    y_mm: list[Num] | None = None
    points: dict[str, list[Num | None]] | None = None
    measured_points: dict[str, list[Num | None]] | None = None

    @model_validator(mode="after")
    def _shapes(self):
        if self.kind == "bed":
            if self.grid_mm is None or self.after_std_um is None or self.radius_mm is None:
                raise ValueError("a bed map has grid_mm, radius_mm, before_um and after_std_um")
            n = len(self.grid_mm) ** 2
            if len(self.before_um) != n or len(self.after_std_um) != n:
                raise ValueError(f"before_um and after_std_um: {n} values (grid_mm squared)")
            if self.points is not None:
                sizes = {len(self.points.get(k, ())) for k in ("x_mm", "y_mm", "before_um",
                                                               "after_um")}
                if len(sizes) != 1:
                    raise ValueError("points: x_mm, y_mm, before_um, after_um of one length")
        else:
            if self.x_mm is None or self.y_mm is None or self.after_um is None:
                raise ValueError("a workspace map has x_mm, y_mm, before_um and after_um")
            if not len(self.x_mm) == len(self.y_mm) == len(self.before_um) == \
                    len(self.after_um):
                raise ValueError("x_mm, y_mm, before_um and after_um: one length")
        return self


class SameAsRunning(_Section):
    """``outcome.same_as_running``: every change within its standard deviation."""

    same: bool
    largest_change_over_std: OptNum = Field(default=None, ge=0)


class Outcome(_Section):
    """``outcome``: the answer the report gives first (issue 36)."""

    verdict: OutcomeVerdict
    accuracy: OutcomeAccuracy
    same_as_running: SameAsRunning | None = None
    changes: list[OutcomeChange] = Field(default_factory=list)
    firmware: list[OutcomeChange] | None = None
    next: list[OutcomeStep] = Field(default_factory=list)
    held_out_rows: dict[str, Any] | None = None
    map: OutcomeMap | None = None


#: a report's ``measurement`` beside the instruments' names: a fit of several data files
JOINT = "joint"


def measurements() -> tuple[str, ...]:
    """The measurements a calibration report may state: every instrument of the registry
    (:mod:`pkmcal.instruments.registry`) and :data:`JOINT`.

    Returns
    -------
    tuple of str
        Names.
    """
    from ..instruments.registry import INSTRUMENTS

    return (*INSTRUMENTS, JOINT)


class ParameterSetSection(_Section):
    """``parameter_set``: the named set fitted (``--parameters``, or the one ``auto`` chose)."""

    name: str
    fixed: Int = Field(ge=0)


class CalibrationReport(_Section):
    """The sections of a calibration report that ``pkmcal report`` and ``compensate`` use;
    every report ``pkmcal calibrate`` writes has the required ones."""

    command: Literal["calibrate"]
    pkmcal_report: Literal[1]
    measurement: str
    method: str
    units: Units
    measurements: Int = Field(ge=1)
    calibrated_file: str | None = None      # None: not written to a file (the library)
    convergence: Convergence
    identifiability: Identifiability
    residuals: Residuals
    noise_sigma_um: OptNum = Field(default=None, gt=0)
    normalised_residuals: list[Num | None] | None = None
    #: residual / (assumed std x sqrt(1 - h_ii)), leverage-corrected (None: fitted exactly)
    standardised_residuals: list[Num | None] | None = None
    distance_ratio: DistanceRatio | None = None
    validation: dict[str, Any] | None = None
    link_length: dict[str, Any] | None = None
    registration: dict[str, Any] | None = None
    frames: dict[str, Any] | None = None
    identifiable_combinations: dict[str, Any] | None = None
    parameters: Annotated[list[Parameter], Field(min_length=1)]
    covariance: Covariance
    provenance: dict[str, Scalar] | None = None
    noise_model: NoiseModel | None = None
    outliers: Outliers | None = None
    model_adequacy: ModelAdequacy | None = None
    model_extensions: ModelExtensions | None = None
    bed: Bed | None = None
    parameter_set: ParameterSetSection | None = None
    poorly_determined: PoorlyDetermined | None = None
    acceptance: Acceptance | None = None
    outcome: Outcome | None = None
    sections: dict[str, SectionIndex] | None = None

    @field_validator("measurement")
    @classmethod
    def _known_measurement(cls, value):
        known = measurements()
        if value not in known:
            raise ValueError("Input should be " + ", ".join(repr(k) for k in known))
        return value

    @model_validator(mode="after")
    def _sections_of_the_measurement(self):
        if self.measurement == JOINT:
            return self
        from ..instruments.registry import instrument

        for section, words in instrument(self.measurement).report_sections.items():
            if getattr(self, section) is None:
                raise ValueError(f"{section}: missing ({words})")
        return self


#: a JSON string, escapes included; unterminated, the rest of the text
_JSON_STRING = re.compile(r'"[^"\\]*(?:\\[\s\S][^"\\]*)*(?:"|\\?\Z)')
_NOT_BRACKET = re.compile(r"[^\[\]{}]+")
_BRACKET_STEP = {"[": 1, "{": 1, "]": -1, "}": -1}


def _depth(text: str) -> int:
    """Deepest nesting of brackets outside strings (cheap, no recursion): the largest running
    count of the brackets left once the strings are removed, at most ``MAX_DEPTH + 1``. No
    Python loop over the characters (one took ~20 ms per report of a six-leg machine)."""
    brackets = _NOT_BRACKET.sub("", _JSON_STRING.sub("", text))
    deepest = max(itertools.accumulate(map(_BRACKET_STEP.__getitem__, brackets), initial=0))
    return min(deepest, MAX_DEPTH + 1)


def _key_path(loc) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


#: what a pydantic type error expected, in the words of a JSON file
_EXPECTED = {"float_type": "a number", "int_type": "a whole number", "int_from_float":
             "a whole number", "bool_type": "true or false", "string_type": "text",
             "list_type": "a list", "dict_type": "an object", "model_type": "an object",
             "model_attributes_type": "an object", "finite_number": "a finite number"}


def _json_value(value) -> str:
    """A value as JSON writes it (``"abc"``, ``true``, ``null``); a list or an object by
    what it is."""
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "an object"
    try:
        text = json.dumps(value)
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _error_words(err: dict) -> str:
    """One pydantic error in the words of the JSON file: what was expected, what is there."""
    kind = err.get("type", "")
    value = err.get("input")
    if kind == "missing":
        return "missing (the section needs this key)"
    if kind in _EXPECTED:
        return f"expected {_EXPECTED[kind]}, got {_json_value(value)}"
    if kind == "literal_error":
        expected = str((err.get("ctx") or {}).get("expected", ""))
        if isinstance(value, str) and expected == value:
            # pkmcal_report: "1" -- the version as text
            return f"must be the number {expected}, not the text {_json_value(value)}"
        return f"expected {expected}, got {_json_value(value)}"
    msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
    msg = msg.replace("Input should be", "must be", 1)
    if kind.startswith(("greater", "less")) or isinstance(value, (str, bool)) or value is None:
        msg += f", got {_json_value(value)}"
    return msg


#: a JSON string, or a constant JSON does not allow (outside strings)
_CONSTANT = re.compile(r'"(?:[^"\\]|\\.)*"|-?Infinity|NaN')


def _constant_place(text: str) -> str:
    """``"line 12, column 5: "`` of the first NaN or Infinity outside strings (empty when
    there is none)."""
    for match in _CONSTANT.finditer(text):
        if not match.group().startswith('"'):
            line = text.count("\n", 0, match.start()) + 1
            column = match.start() - (text.rfind("\n", 0, match.start()) + 1) + 1
            return f"line {line}, column {column}: "
    return ""


#: keys whose values pkmcal writes as numbers (or lists of numbers, or null) wherever they
#: stand in a report: the sections shown as written (registration, frames, files, ...) are
#: held to them too, so that text where a number belongs is named by its key path
NUMBER_KEYS = frozenset((
    "after_rms", "alpha", "assumed", "ball", "before_rms", "calibration_rms", "capacity",
    "change", "chi2", "chi2_per_dof", "chi_square", "chosen", "condition_number", "correlation",
    "count", "cv_gain", "cv_loss", "cv_loss_baseline", "cv_se", "data_share", "dimension",
    "dof",
    "evaluations", "explained", "far_above", "fk_failed", "folds", "fraction",
    "free_parameters",
    "height", "held_out", "held_out_over_calibration", "holdout", "identifiable",
    "identifiable_alone", "identified", "in_file", "iterations", "joint_identifiable",
    "leg_length_max", "leg_length_rms", "leg_length_rms_per_leg", "loo_rms_over_noise",
    "matrix", "max", "mean", "measured", "measurements", "min", "min_redundancy",
    "noise_ratio", "noise_scale", "nominal",
    "normalised_residuals", "null_space", "p", "p_adjusted", "pairs", "pivot", "places",
    "position_max", "position_rms", "posterior_std", "prior_held", "prior_std", "ratio",
    "redundancy", "residual_variance", "rms",
    "rotation", "rows", "seed", "setup", "sigma", "sigmas_off", "significant_trends",
    "singular_values",
    "smr_offset", "standardised_residuals", "std", "tests", "threshold_p", "tilt_x",
    "tilt_y", "translation", "translation_change", "upper_999", "used", "value"))
#: so are keys ending in a unit
NUMBER_SUFFIX = re.compile(r"_(um|mm|m|in|deg|rad|urad|percent)$")


def _number_leaves(value) -> bool:
    """A number, null, or a (nested) list of them."""
    if value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)):
        return True
    return isinstance(value, list) and all(_number_leaves(v) for v in value)


def _first_non_number(value, loc: tuple):
    """``(loc, value)`` of the first leaf of ``value`` that is not a number or null."""
    if isinstance(value, list):
        for i, v in enumerate(value):
            found = _first_non_number(v, (*loc, i))
            if found is not None:
                return found
        return None
    return None if _number_leaves(value) else (loc, value)


def _text_in_numbers(doc, loc: tuple = ()):
    """``(loc, value)`` of the first value under a number key (:data:`NUMBER_KEYS`,
    :data:`NUMBER_SUFFIX`, a combination ``"a - b"`` of ``identifiable_combinations``) that is
    not a number, anywhere in the report; None."""
    if isinstance(doc, dict):
        for key, value in doc.items():
            here = (*loc, key)
            if isinstance(key, str) and (key in NUMBER_KEYS or NUMBER_SUFFIX.search(key)
                                         or (loc[-1:] == ("identifiable_combinations",)
                                             and " - " in key)) \
                    and not _number_leaves(value):
                return _first_non_number(value, here)
            found = _text_in_numbers(value, here)
            if found is not None:
                return found
    elif isinstance(doc, list):
        for i, value in enumerate(doc):
            found = _text_in_numbers(value, (*loc, i))
            if found is not None:
                return found
    return None


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not a number JSON allows")


def validate_report(doc: Any, source: str | Path = "report") -> dict:
    """Check a parsed calibration report; return it unchanged.

    Parameters
    ----------
    doc : Any
        The parsed JSON document.
    source : str or Path, optional
        The file's name, for messages.

    Returns
    -------
    dict
        ``doc``, when it is a calibration report whose used sections have the right shape.

    Raises
    ------
    InputError
        Naming the file and the first wrong key.
    """
    if not isinstance(doc, dict):
        raise InputError(f"{path_text(source)}: "
                         "not a calibration report (a JSON object was expected, "
                         f"got {type(doc).__name__})")
    if doc.get("command") != "calibrate":
        raise InputError(f"{path_text(source)}: not a calibration report of pkmcal calibrate (no "
                         "\"command\": \"calibrate\")")
    try:
        CalibrationReport.model_validate(doc)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = err.get("loc", ())
        where = f"{_key_path(loc)}: " if loc else ""
        raise InputError(f"{source}: {where}{_error_words(err)}") from None
    found = _text_in_numbers(doc)
    if found is not None:
        loc, value = found
        raise InputError(f"{source}: {_key_path(loc)}: expected a number, got "
                         f"{_json_value(value)}")
    return doc


def load_report(path: str | Path, what: str = "calibration report") -> dict:
    """Read and check a calibration report (JSON) a user gives.

    Parameters
    ----------
    path : str or Path
        The JSON file.
    what : str, optional
        What the file is, for messages.

    Returns
    -------
    dict
        The checked report (see :func:`validate_report`).

    Raises
    ------
    InputError
        Unreadable, too large, not JSON, nested too deeply, or not a calibration report.
    """
    from ..io.atomic import read_input_text

    path = Path(path)
    try:
        size = path.stat().st_size
    except OSError:
        size = 0
    if size > MAX_REPORT_BYTES:
        raise InputError(f"{path_text(path)}: {size} bytes is too large for a {what} (at most "
                         f"{MAX_REPORT_BYTES // 2**20} MiB)")
    text = read_input_text(path, what)
    # only a text that opens an array or object can nest (the depth scan is a Python loop:
    # seconds over a large file of something else, which json refuses at its first character)
    if text.lstrip()[:1] in ("{", "[") and _depth(text) > MAX_DEPTH:
        raise InputError(f"{path_text(path)}: not a {what}: JSON nested more than {MAX_DEPTH} deep")
    try:
        doc = json.loads(text, parse_constant=_refuse_constant)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path_text(path)}: not JSON (line {exc.lineno}, column {exc.colno}): "
                         f"{exc.msg}") from None
    except ValueError as exc:  # NaN / Infinity literals
        raise InputError(f"{path}: {_constant_place(text)}not a {what}: {exc}") from None
    return validate_report(doc, path)

