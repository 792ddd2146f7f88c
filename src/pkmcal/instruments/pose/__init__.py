"""Full poses of a marker on the platform (motion capture, SPEC 2.4): the instrument's package.

A motion-capture system (or a 6-D tracker) measures the pose of a marker frame fixed to the
platform in its own measurement frame; the leg parameters and both frames are calibrated from
the leg readings and the measured poses (methods ``ml``, the default, and ``ik``).

This module is the instrument's home: the :class:`Pose` instrument (:data:`INSTRUMENT`), its
options (:class:`PoseOptions`, :func:`full_pose_noise_arg`, :func:`pose_noise_option`), its
set-up (:func:`measurement_frames`) and its calibration flow (``pkmcal calibrate``). One
concept per sub-module, their public names re-exported here:

:mod:`.data`
    The measurements and their model: the noise (:class:`FullPoseNoise`), the two frames
    (:class:`MeasurementFrames`), the data (:class:`FullPoseData`), the default frames and the
    simulation (:func:`simulate_full_pose`).
:mod:`.problems`
    The estimation: the problems each method fits (:class:`FullPoseML`, :class:`FullPoseIK`),
    the closed-form start of the frames (:func:`estimate_frames`) and the calibration
    (:func:`calibrate_full_pose`).
:mod:`.errors`
    How well a model explains data (:func:`full_pose_errors`) and its gauge-free error against
    a known truth (:func:`align_to`, :func:`gauge_free_error`).
:mod:`.section`
    What a calibration adds to its result (:class:`PoseSection`).
"""


from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ...errors import InputError
from ...estimation.acceptance import FAILED_ALARMING, report_verdict
from ...machines.base import Machine
from ...machines.file_format import file_rotation, frame_section
from ...paths import path_text
from ..base import Instrument, _space_words, has_column, reachable
from ..experiment import MOUNTING_ERROR
from ..flow import (
    FlowContext,
    FlowResult,
    convergence_json,
    identifiability_json,
    identifiability_metadata,
    json_safe,
    load_data,
    parameter_table,
    public_parameters,
    require_converged,
    solve,
    source_of,
    split_rows,
    validation_section,
)
from ..flow import option as _option
from .data import (
    POSE_HALF_RANGE,
    POSE_MAX_ANGLE,
    Frame,
    FullPoseData,
    FullPoseNoise,
    MeasurementFrames,
    default_measurement_frames,
    sample_platform_poses,
    simulate_full_pose,
)
from .errors import FullPoseErrors, align_to, full_pose_errors, gauge_free_error
from .problems import (
    DEGENERATE_SPREAD,
    FRAME_FIELDS,
    FRAME_NAMES,
    FRAME_WORDS,
    METHODS,
    PROBLEMS,
    FullPoseIK,
    FullPoseML,
    FullPoseProblem,
    FullPoseState,
    calibrate_full_pose,
    estimate_frames,
    frame_parameters,
    pose_spread,
    right_jacobian_inverse,
)
from .section import PoseSection

__all__ = ["DEGENERATE_SPREAD", "FRAME_FIELDS", "FRAME_NAMES", "FRAME_WORDS", "INSTRUMENT",
           "METHODS", "POSE_HALF_RANGE", "POSE_MAX_ANGLE", "PROBLEMS", "Frame", "FullPoseData",
           "FullPoseErrors", "FullPoseIK", "FullPoseML", "FullPoseNoise", "FullPoseProblem",
           "FullPoseState", "MeasurementFrames", "Pose", "PoseOptions", "PoseSection",
           "align_to", "calibrate_full_pose", "default_measurement_frames", "estimate_frames",
           "frame_parameters", "full_pose_errors", "full_pose_noise_arg", "gauge_free_error",
           "measurement_frames", "pose_noise_option", "pose_spread", "right_jacobian_inverse",
           "sample_platform_poses", "simulate_full_pose"]

def full_pose_noise_arg(noise: str | None, pose_noise: str | None, strict: bool,
                        machine=None):
    """The full-pose noise model of ``--noise`` and ``--pose-noise``.

    Parameters
    ----------
    noise : str or None
        Noise of the readings, as a leg length (default: the model's).
    pose_noise : str or None
        ``POSITION,ORIENTATION`` with units (e.g. ``20um,50urad``; default: the model's).
    strict : bool
        Every standard deviation must be > 0 (a calibration weighs by them); else >= 0 (a
        simulation may be exact).
    machine : Machine, optional
        The values are checked against its size when given.

    Returns
    -------
    FullPoseNoise
        The noise model, SI units.

    Raises
    ------
    InputError
        When a value is malformed, out of range or implausible for the machine.
    """
    from ...plausibility import check_option_scale
    from ...units import parse_quantity

    default = FullPoseNoise()
    reading = default.reading_m if noise is None else parse_quantity(noise, "length", "--noise")
    if pose_noise is None:
        position, orientation = default.position_m, default.orientation_rad
    else:
        parts = [p.strip() for p in str(pose_noise).split(",")]
        if len(parts) != 2:
            raise InputError(f"--pose-noise: expected POSITION,ORIENTATION with units (e.g. "
                             f"20um,50urad), got {pose_noise!r}")
        position = parse_quantity(parts[0], "length", "--pose-noise (position)")
        orientation = parse_quantity(parts[1], "angle", "--pose-noise (orientation)")
    for option, value, text in (("--noise", reading, noise),
                                ("--pose-noise", position, pose_noise),
                                ("--pose-noise", orientation, pose_noise)):
        if not (math.isfinite(value) and (value > 0 if strict else value >= 0)):
            need = ("must be > 0 (a standard deviation that weighs the residuals)" if strict
                    else "must be >= 0")
            raise InputError(f"{option}: {need}, got {text}")
    if machine is not None:
        check_option_scale(reading, machine, "--noise", "noise", noise)
        check_option_scale(position, machine, "--pose-noise (position)", "noise", pose_noise)
        check_option_scale(orientation, machine, "--pose-noise (orientation)", "angle noise",
                           pose_noise)
    return FullPoseNoise(reading, position, orientation)


@dataclass(frozen=True, slots=True)
class PoseOptions:
    """The options of the full-pose calibration flow (:meth:`Pose.calibrate`)."""

    method: str | None = _option(
        None, "--method", "ml maximum likelihood, readings and measured poses noisy "
        "(default); ik inverse-kinematic residuals (Zhuang, Yan & Masory 1998), measured poses "
        "exact.", choices=("ml", "ik"))
    noise: object = _option(
        None, "--noise", "noise of the leg readings, as a leg length (default 2um); held as "
        "given (a FullPoseNoise too), else estimated from the residuals.")
    pose_noise: str | None = _option(
        None, "--pose-noise", "Noise of the measured poses, POSITION,ORIENTATION with units, "
        "held as given (default: estimated from the residuals, starting from 20um,50urad).",
        metavar="POS,ORI")
    fix_frames: bool = _option(
        False, "--fix-frames", "Hold the measurement frames (mocap_from_base, "
        "platform_from_marker) at the machine file's measurement_frames (identity without "
        "that section) instead of estimating them.")
    extensions: str | None = _option(
        None, "--extensions", "auto (default) tries the machine's model extensions (a six-leg "
        "platform's per-leg reading curvature) and adopts one only when it predicts rows held "
        "out of the fit better (5-fold cross-validation, in the report); none fits the plain "
        "model.", metavar="auto|none",
        choices=("auto", "none"))
    robust: bool = _option(
        False, "--robust", "Leave out the rows the noise cannot explain (a chi-square test of "
        "each row) and fit again (ml).")


class Pose(Instrument):
    """Full poses of a marker on the platform (motion capture), SPEC 2.4."""

    name = "pose"
    aliases = ("poses",)
    words = "the marker pose (motion capture, 6-D tracker)"
    calibrate_help = """
        Full-pose calibration fits the legs and, unless --fix-frames, the measurement frames.
        The summary compares the machine file's legs (frames fitted alone) with the
        calibrated ones.

        Example: `pkmcal calibrate examples/cubic_6upu.yaml poses.csv --method ik -o cal.yaml`
        """
    plan_size = 60
    #: the quantities of its machine-file section (unit conversion, magnitude checks)
    file_quantities = {("measurement_frames", "*", "translation", "*"): "length"}
    columns = ("the leg readings q1_<unit>..q6_<unit> (the machine's reading unit) and the "
               "measured pose x_mm, y_mm, z_mm with qx, qy, qz, qw or psi_deg, theta_deg, "
               "phi_deg")
    priority = 20
    data_class = "FullPoseData"
    joint_refusal = "full poses estimate a platform pose per measurement"

    def detect(self, header):
        return (has_column(header, "x") or has_column(header, "y") or has_column(header, "z")
                or "qw" in header)

    def applies(self, machine):
        if not machine.rotates:
            return ("full poses need a platform that rotates; this machine's platform only "
                    "translates: measure points (tracker) instead")
        if len(machine.pose_space) != 6:
            return ("full poses need a platform that moves in space (six pose coordinates); "
                    f"this machine's platform moves along {_space_words(machine)} only: "
                    "measure points (tracker) instead")
        return None

    def default_noise(self):

        return FullPoseNoise()

    def describe_noise(self, noise):
        return (f"leg readings {noise.reading_m * 1e6:.3g} um, poses "
                f"{noise.position_m * 1e6:.3g} um / {noise.orientation_rad * 1e6:.3g} urad "
                "(std)")

    montecarlo_variables = ("noise", "poses", "tolerance")
    montecarlo_metrics = {
        "position_mean": ("um", 1e-6, "mean held-out marker position error"),
        "position_max": ("um", 1e-6, "max held-out marker position error"),
        "orientation_mean": ("urad", 1e-6, "mean held-out marker orientation error"),
        "orientation_max": ("urad", 1e-6, "max held-out marker orientation error"),
        "parameter_rms": ("", 1.0, "RMS gauge-free parameter error, scaled coordinates"),
    }
    #: the gauge-free parameter error needs a six-leg platform's leg layout
    montecarlo_optional_metrics = frozenset({"parameter_rms"})
    montecarlo_evaluation_poses = 100
    montecarlo_poses = 60

    def montecarlo_run(self, run):
        """Maximum likelihood with both measurement frames estimated, the noise of leg
        readings varied (the pose noise at its default); held out: exact poses through the
        identified frames, and the gauge-free parameter error (:func:`gauge_free_error`)."""
        from ...machines.reach import sample_workspace_poses

        s = run.settings
        nominal = s.machine
        true = run.true_machine()
        frames = measurement_frames(run.settings.setups.get(self.name))
        default = FullPoseNoise()
        noise = default.reading_m if s.noise is None else s.noise
        data = simulate_full_pose(true, sample_workspace_poses(true, s.poses or
                                                               self.montecarlo_poses, run.rng),
                                  frames, replace(default, reading_m=noise), run.rng)
        res = calibrate_full_pose(nominal, data, "ml",
                                  noise=replace(default, reading_m=run.weight(noise)))
        held = simulate_full_pose(true, sample_workspace_poses(
            true, self.montecarlo_evaluation_poses, run.rng), frames, None, run.rng)
        err = full_pose_errors(res.machine, res.section(PoseSection).frames, held)
        ok = err.converged
        e = gauge_free_error(nominal, res, true.u, frames)

        def stat(f, v):
            return float(f(v[ok])) if ok.any() else math.nan

        return res, {"position_mean": stat(np.mean, err.position),
                     "position_max": stat(np.max, err.position),
                     "orientation_mean": stat(np.mean, err.orientation),
                     "orientation_max": stat(np.max, err.orientation),
                     "parameter_rms": float(np.sqrt(np.mean(e**2)))}

    def planned_data(self, machine, P, R, rows, source, group=None, setup=None):

        q = reachable(machine, P, R, rows, source)
        Pm, Rm = measurement_frames(setup).measured(P, R)
        return FullPoseData(q, Pm, Rm, rows, source, true_P=P, true_R=R)

    section = "measurement_frames"
    section_words = ("a calibration from poses (x, y, z, qx..qw: motion capture) writes "
                     "measurement_frames")
    Setup = MeasurementFrames
    section_order = 40

    def read_setup(self, section, length_factor, machine):
        return MeasurementFrames(
            *((file_rotation(f.rotation), np.asarray(f.translation, float) * length_factor)
              for f in (section.mocap_from_base, section.platform_from_marker)))

    def setup_section(self, setup, length_factor, machine):
        if len(machine.pose_space) != 6:
            return None
        return {"mocap_from_base": frame_section(setup.mocap_from_base, length_factor),
                "platform_from_marker": frame_section(setup.platform_from_marker,
                                                      length_factor)}

    def carried_by(self, machine, setup):
        return setup is not None and len(machine.pose_space) == 6

    def predict(self, machine, setup, P, R, ok, group, rows=None, source=None):
        values, Rm = setup.measured(P, R)
        return values, np.where(ok[:, None, None], Rm, np.nan), np.zeros(len(P), int)

    def simulate(self, machine, true, n, noise, rng, truth, *, setup=None, poses=None,
                 mounting_error=MOUNTING_ERROR):
        """:func:`simulate_full_pose` at ``n`` random poses (or ``poses``), through the machine
        file's measurement frames (``setup``, else the default); ``noise`` a
        ``FullPoseNoise`` (False: exact). See
        :meth:`Instrument.simulate <pkmcal.instruments.base.Instrument.simulate>`.

        Returns
        -------
        tuple
            ``(data, true, truth)``; ``truth`` with ``frames`` (also its ``setup``).
        """
        from ...machines.reach import sample_workspace_poses
        from ..experiment import given_poses, mm_text, noise_model

        frames = measurement_frames(setup)
        model = noise_model(noise, FullPoseNoise())
        if poses is None:
            poses = sample_workspace_poses(true, n, rng)
            words = (f"{n} random poses in the 0.1 m cube around home, Euler angles within "
                     "+/-10 deg")
        else:
            poses = given_poses(poses)
            words = f"{len(poses[0])} given poses"
        data = simulate_full_pose(true, poses, frames, model, rng)
        rows = [("frames", f"measurement origin at {mm_text(frames.mocap_from_base[1])} mm; "
                 f"marker origin at {mm_text(frames.platform_from_marker[1])} mm in the "
                 "platform frame")]
        truth.update(frames=frames, poses=words, rows=rows, setup=frames)
        return data, true, truth

    simulate_flags = {"--pose-noise": "--scenario pose"}

    def simulate_arguments(self, machine, noise, pose_noise=None, **flags):
        model = full_pose_noise_arg(noise, pose_noise, strict=False, machine=machine)
        return model, (f"readings {model.reading_m * 1e6:.4g} um (as leg length), position "
                       f"{model.position_m * 1e6:.4g} um, orientation "
                       f"{model.orientation_rad * 1e6:.4g} urad"), {}

    writer = "write_full_pose"

    def calibration_summary(self, report):
        res, ident = report["residuals"], report["identifiability"]
        unit = report["units"]["length"]
        b, a = res["before_calibration"], res["after_calibration"]
        n = report["noise"]
        fr = report["frames"]
        m, k = fr["mocap_from_base"], fr["platform_from_marker"]
        rows = [("measurement", f"full pose, {report['measurements']} poses (readings in "
                 f"{report['reading_unit']}, marker pose in the measurement frame)"),
                ("method", {"ml": "ml (maximum likelihood: readings and measured poses "
                                  "noisy, one pose unknown per measurement)",
                            "ik": "ik (inverse-kinematic residuals, Zhuang, Yan & Masory "
                                  "1998: measured poses exact)"}[report["method"]]),
                "identifiable",
                ("leg-length RMS", f"{b['leg_length_rms']:.4g} {unit} before, "
                 f"{a['leg_length_rms']:.4g} {unit} after ({res['before']})"),
                ("pose error RMS", f"position {b['position_rms']:.4g} -> "
                 f"{a['position_rms']:.4g} {unit}, orientation "
                 f"{b['orientation_rms_deg']:.4g} -> {a['orientation_rms_deg']:.4g} deg "
                 "(forward kinematics of the readings vs measured)"),
                ("noise", f"readings {n['reading_um']:.4g} um, position "
                 f"{n['position_um']:.4g} um, orientation {n['orientation_urad']:.4g} urad "
                 "(assumed)"),
                ("frames", ("fixed: " if fr["fixed"] else f"estimated ({fr['from']}): ")
                 + "mocap_from_base turned "
                 f"{m['rotation_angle_deg']:.4g} deg, base origin at "
                 f"({', '.join(f'{v:.6g}' for v in m['translation'])}) {unit} measured; "
                 f"platform_from_marker turned {k['rotation_angle_deg']:.4g} deg, marker at "
                 f"({', '.join(f'{v:.6g}' for v in k['translation'])}) {unit}"),
                "held-out", "noise levels"]
        ext = report.get("model_extensions") or {}
        for t in ext.get("trials", []):
            rows.append(("model extension", f"{t['name']}: {t['why']} ({ext['folds']}-fold "
                         f"cross-validation: held-out loss {t['cv_loss']:.4g} vs "
                         f"{t['cv_loss_baseline']:.4g} per pose)"))
        if "model_adequacy" in report:
            adequacy = report["model_adequacy"]
            rows.append(("model adequacy", adequacy.get("findings", adequacy["verdict"])))
        rows += ["residual test", "convergence"]
        if report_verdict(report).status == FAILED_ALARMING:
            rows.append(("note", "note: the residual test failed: give the real noise "
                         "(--noise, --pose-noise), or the model lacks errors the machine "
                         "has."))
        if ident["unidentifiable"]:
            rows.append(("note", "note: the data fix the legs only relative to the "
                         "measurement frames; the changes are the smallest ones (scaled) that "
                         "fit the data, and std is for the identifiable part."))
        return rows
    prediction_words = "predicted marker pose(s) (motion-capture frame)"

    def prediction_columns(self, prediction, unit):
        """``x, y, z`` (``unit``) and ``qx, qy, qz, qw`` of the predicted marker poses."""
        from ...kinematics import quaternion_from_matrix
        from ...units import LENGTH

        f = LENGTH[unit]
        Q = quaternion_from_matrix(prediction.R)
        columns = {f"{c}_{unit}": prediction.values[:, j] / f for j, c in enumerate("xyz")}
        columns.update({c: Q[:, j] for j, c in enumerate(("qx", "qy", "qz", "qw"))})
        return columns

    def problem(self, machine, data, noise=None, setup=None, frames=None, **start):

        return FullPoseML(machine, data, self.default_noise() if noise is None else noise,
                          measurement_frames(setup) if frames is None else frames)

    measurement_words = "full pose (maximum likelihood; both measurement frames estimated)"

    def noise_option(self, noise, pose_noise=None, machine=None):

        if noise is not None and not isinstance(noise, str):
            return noise
        return full_pose_noise_arg(noise, pose_noise, strict=True, machine=machine)

    def noise_arg(self, text, machine=None):
        """The full-pose noise of ``--noise`` (the leg readings; poses at their default)."""
        return self.noise_option(text, None, machine)

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_full_pose"
    Options = PoseOptions

    def check_options(self, options, source) -> None:
        """``--robust`` with ml alone (see
        :meth:`~pkmcal.instruments.base.Instrument.check_options`)."""
        _check_options(options, source)

    def calibrate(self, machine: Machine, data, context, options):
        """Legs and both measurement frames (or the frames held), the machine's model
        extensions adopted by cross-validation, errors before and after (see
        :meth:`~pkmcal.instruments.base.Instrument.calibrate`)."""
        return _calibration_flow(machine, data, context, options)

    def measured_problem(self, machine, data, noise=None, source="", setup=None):
        """The measurement frames of the machine file, else estimated from the data (at least
        4 poses)."""

        if len(data) < 4:
            raise InputError(f"{path_text(source)}: "
                             f"{len(data)} pose(s); the measurement frames need at "
                             "least 4")
        frames = setup
        if frames is None:
            frames = estimate_frames(machine, data)
        return self.problem(machine, data, noise, frames=frames)


def measurement_frames(setup: MeasurementFrames | None = None) -> MeasurementFrames:
    """The measurement frames of the machine file (its set-up), else the simulations'
    default.

    Parameters
    ----------
    setup : MeasurementFrames, optional
        The machine file's (None: none).

    Returns
    -------
    MeasurementFrames
        The frames.
    """
    return default_measurement_frames() if setup is None else setup


#: this module's instrument (:data:`~pkmcal.instruments.registry.INSTRUMENT_MODULES`)
INSTRUMENT = Pose()


def pose_noise_option(noise, pose_noise, machine):
    """The noise model of a full-pose calibration and the levels held (those the user gave;
    the others are estimated from the residuals).

    Parameters
    ----------
    noise : str, float, FullPoseNoise or None
        ``--noise`` (the leg readings' std), or a whole noise model.
    pose_noise : str or None
        ``--pose-noise`` (``POSITION,ORIENTATION``).
    machine : Machine
        The machine (levels checked against its size).

    Returns
    -------
    noise_model : FullPoseNoise
        The model.
    hold : list of str
        Its levels given by the user (``reading``, ``position``, ``orientation``).

    Raises
    ------
    InputError
        For ``pose_noise`` beside a whole model, or a bad level.
    """
    if isinstance(noise, FullPoseNoise):
        if pose_noise is not None:
            raise InputError("--pose-noise: the noise model given as noise holds the pose "
                             "noise already")
        return noise, ["reading", "position", "orientation"]
    model = full_pose_noise_arg(noise, pose_noise, strict=True, machine=machine)
    hold = ((["reading"] if noise is not None else [])
            + (["position", "orientation"] if pose_noise is not None else []))
    return model, hold


# -- calibration flow (pkmcal calibrate) ------------------------------------------------------


def _errors_report(errors, fl: float) -> dict:
    """Full-pose errors in the report (the file's length unit, degrees)."""
    s = errors.summary()
    return {"leg_length_rms": s["leg_length_rms"] / fl, "leg_length_max": s["leg_length_max"] / fl,
            "leg_length_rms_per_leg": [v / fl for v in s["leg_length_rms_per_leg"]],
            "position_rms": s["position_rms"] / fl, "position_max": s["position_max"] / fl,
            "orientation_rms_deg": float(np.degrees(s["orientation_rms"])),
            "orientation_max_deg": float(np.degrees(s["orientation_max"])),
            "fk_failed": s["fk_failed"]}


def _check_options(options: PoseOptions, source) -> None:
    """The full-pose options that do not go together, refused naming them (an option it does
    not declare, or a value out of its choices, is refused by the calibration layer)."""
    if options.robust and options.method == "ik":
        raise InputError("--robust: applies to the ml method (its residuals are the noise's); "
                         "--method ik takes the measured poses as exact")


def _calibration_flow(machine, data, context: FlowContext,
                      options: PoseOptions) -> FlowResult:
    """``pkmcal calibrate`` from full poses (:meth:`Pose.calibrate`)."""
    from ...machines.stewart import reading_factor
    from ...units import LENGTH

    source, split = context.source, context.split
    method, fix_frames = options.method or "ml", options.fix_frames
    noise_model, hold = pose_noise_option(options.noise, options.pose_noise, machine)
    data, held = split_rows(load_data(data, context.read, machine), split, source)
    file_frames = context.setups.get("pose")        # the machine file's
    if fix_frames:
        frames = file_frames if file_frames is not None else MeasurementFrames.identity()
        frames_from = ("the machine file's measurement_frames" if file_frames is not None
                       else "identity (the machine file has no measurement_frames)")
    else:
        frames = file_frames
        frames_from = ("start: the machine file's measurement_frames" if file_frames is not None
                       else "start: closed form from the design model")
    result = solve(source, calibrate_full_pose, machine, data, held=held, method=method,
                    noise=noise_model, frames=frames, fix_frames=fix_frames,
                    estimate_noise=hold, robust=options.robust)
    # the machine's model extensions (a leg's reading curvature ...), adopted only when they
    # predict rows held out of the fit better (k-fold cross-validation on these data)
    model, choice = machine, None
    if options.extensions != "none" and machine.model_extensions():
        require_converged(result, source)
        levels = result.noise
        cv_noise = noise_model if levels is None else FullPoseNoise(
            **{f"{k}_{'rad' if k == 'orientation' else 'm'}": v
               for k, v in zip(levels.keys, levels.sigma, strict=True)})
        choose = context.model_choice.choose_full_pose_extensions
        choice = choose(machine, data, method, cv_noise, frames=frames, fix_frames=fix_frames)
        if choice.adopted:
            model = choice.machine
            result = solve(source, calibrate_full_pose, model, data, held=held,
                            method=method, noise=noise_model, frames=frames,
                            fix_frames=fix_frames, estimate_noise=hold, robust=options.robust)
        result.extensions = choice
    # the machine file's legs with the frames fitted alone: "before calibration"
    before = solve(source, calibrate_full_pose, machine, data, held=held, method=method,
                    noise=noise_model, frames=frames if fix_frames
                    else result.section(PoseSection).start_frames, fix_frames=fix_frames,
                    fit_machine=False)
    require_converged(result, source)

    units = context.units
    fl = LENGTH[units["length"]]
    calibrated = result.machine
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    calibrated.home = machine.home
    section = result.section(PoseSection)
    section.origin = frames_from
    frames_id, frames_before = section.frames, before.section(PoseSection).frames
    err_after = full_pose_errors(calibrated, frames_id, data)
    err_before = full_pose_errors(machine, frames_before, data)

    reading_unit = getattr(machine, "reading_unit", None) or machine.joint_unit()[0]
    gain_factor = fl / reading_factor(reading_unit)         # internal gain -> file gain
    nominal_of = dict(zip(model.parameters.names, model.u, strict=True))
    start = section.start_frames
    for name, (R, t) in (("mocap_from_base", start.mocap_from_base),
                         ("platform_from_marker", start.platform_from_marker)):
        nominal_of.update({f"{name}.r{c}": 0.0 for c in "xyz"})
        nominal_of.update({f"{name}.{c}": v for c, v in zip("xyz", t, strict=True)})
    params = parameter_table(result, nominal_of, units)
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
    unidentifiable = list(result.unidentifiable)
    # the ik estimate takes the poses as exact, but their noise is in the residuals: its
    # residual test is against the whole noise (readings + poses through the IK); the residuals
    # section states the verdict's numbers (the calibration layer's finish)
    variance = float(result.residual_variance)
    after, before_rep = _errors_report(err_after, fl), _errors_report(err_before, fl)
    extensions = (choice.as_dict({"leg_length": (fl, units["length"]), "position": (
        fl, units["length"]), "orientation": (math.pi / 180, "deg")}) if choice is not None
        else {"tried": [], "adopted": [], "skipped": "--extensions none" if
              options.extensions == "none" else "the machine offers none"})
    report = {
        **context.head(machine, "pose", method, units),
        "reading_unit": reading_unit,
        "measurements": len(data),
        "noise": {"reading_um": noise_model.reading_m * 1e6,
                  "position_um": noise_model.position_m * 1e6,
                  "orientation_urad": noise_model.orientation_rad * 1e6},
        **section.as_report(units),         # frames
        "convergence": convergence_json(result),
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
        "identifiability": identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": public_parameters(params),
        "model_extensions": extensions,
    }
    if held is not None:
        h_after = _errors_report(full_pose_errors(calibrated, frames_id, held), fl)
        h_before = _errors_report(full_pose_errors(machine, frames_before, held), fl)
        report["validation"] = validation_section(
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
        "machine": source_of(machine),
        "measurements": len(data),
        "leg_length_rms": {"before": before_rep["leg_length_rms"],
                           "after": after["leg_length_rms"], "unit": units["length"]},
        "frames_fixed": bool(fix_frames),
        "model_extensions": list(choice.adopted) if choice is not None else [],
        "identifiable": rank,
        "free_parameters": n_free,
        **identifiability_metadata(unidentifiable),
    }
    # the nominal of the fitted model (with an adopted extension at its neutral values)
    return FlowResult("pose", model, calibrated, result, report, metadata, params, units,
                      setups={"pose": frames_id})
