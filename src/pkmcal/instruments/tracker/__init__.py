"""Calibration from laser-tracker points (seed 001 eq. 12-15), jointly with the registration.

Any machine: the points instrument of :mod:`pkmcal.instruments`
(:class:`~pkmcal.instruments.PointsModel`) on the machine's forward kinematics. Unknowns: the
machine's parameters, the tracker pose ``base_from_tracker = (R, t)`` (``tracker.rx/ry/rz``:
rotation increments about the base axes, applied on the left of the closed-form start;
``tracker.x/y/z``: translation) and, unless the machine gives it (a Delta's ``smr_offset``),
the place ``c_k`` of every target on the platform (``target<k>.x/y/z``). Residual of point i,
whitened with the tracker's anisotropic noise (:class:`~pkmcal.instruments.tracker.TrackerNoise`)::

    e_i = W_i (m_i - R^T (P(q_i; u) + R_p(q_i; u) c_k - t))

Seed 001 registers first (with the nominal model) and then identifies the errors with the
registration fixed (``joint=False`` reproduces that); ``joint=True`` (default) estimates both
together, which removes the bias the nominal model leaves in the registration.

Identifiability is found from the data and named by the machine's frame motions: on the Delta
(SPEC 2.2) ``da`` and ``db`` enter only as ``db - da`` (9 directions) and a translation of the
platform frame is absorbed by the tracker frame (3): 21 of 33; on a platform that rotates a
rigid motion of the base frame is absorbed by the tracker frame and one of the platform frame
by the targets (12).

Laser-tracker measurements of a reflector (SMR) on the platform (seed 001 section 3).

The tracker measures the SMR centre, ``h_M`` below the platform point, in its own frame:
``m = R^T (p + (0, 0, -h_M) - t)`` with ``(R, t)`` = base_from_tracker (a base vector
``x_base = R m + t``). One measurement = the actuator readings and the measured point.

Noise model (documented, Leica-type): the maximum permissible error (MPE) is
``+/-(15 um + 6 um/m * range)`` transverse to the beam and ``+/-10 um`` along it; the typical
error is about half the MPE, so the standard deviations are half these values. The noise is
anisotropic: each point has its own 3x3 covariance in the tracker frame.

This package is the instrument's home: the :class:`Tracker` instrument (:data:`INSTRUMENT`),
its options (:class:`TrackerOptions`) and its calibration flow (``pkmcal calibrate``). One
concept per sub-module, their public names re-exported here:

:mod:`.noise`
    The tracker's noise model (:class:`TrackerNoise`) and the words of ``--noise``.
:mod:`.setup`
    Where the tracker stands and where its targets are on the platform
    (:class:`TrackerSetup`, :func:`tracker_pose`, :func:`planned_targets`).
:mod:`.data`
    The measurements (:class:`TrackerData`), seed 001's grid and their simulation.
:mod:`.section`
    What a calibration adds to its result (:class:`TrackerSection`).
:mod:`.fit`
    The estimation problem (:class:`TrackerProblem`), the calibration
    (:func:`calibrate_tracker`) and the calibrated model's predictions.
:mod:`.distances`
    Seed 001 Fig. 6's distance ratio between neighbouring points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...estimation.acceptance import FAILED_ALARMING, report_verdict
from ...machines.base import Machine
from ...machines.delta import TRACKER_GRID_SPACING  # seed 001's grid
from ...machines.file_format import TrackerSection as TrackerFileSection
from ...machines.file_format import file_rotation, frame_section, vector
from ...paths import path_text
from ...units import format_um
from ..base import Instrument, StandardPlan, _check_groups, _fk_of, has_column, reachable
from ..experiment import MOUNTING_ERROR
from ..flow import (
    FlowContext,
    FlowResult,
    JointPart,
    convergence_json,
    identifiability_json,
    identifiability_metadata,
    load_data,
    option,
    parameter_table,
    public_parameters,
    require_converged,
    rows_text,
    solve,
    source_of,
    split_rows,
    validation_section,
    variance_json,
)
from ..models import NuisanceState, PointsModel
from .data import TrackerData, as_points, as_tracker_data, grid_points, simulate_tracker
from .distances import (
    _ratio_stats,
    distance_ratio_pairs,
    distance_ratios,
    grid_neighbour_pairs,
    neighbour_pairs,
)
from .fit import (
    TRACKER,
    TrackerProblem,
    calibrate_tracker,
    predict_tracker_points,
    prediction_covariance,
    registration_of,
)
from .noise import TrackerNoise, _tracker_noise_text, tracker_noise_arg
from .section import TrackerSection
from .setup import (
    TARGET_OFFSET,
    TRACKER_POSITION,
    TRACKER_TILT,
    TrackerSetup,
    default_tracker_pose,
    plan_target,
    planned_targets,
    tracker_pose,
    tracker_targets,
)

__all__ = ["INSTRUMENT", "TARGET_OFFSET", "TRACKER", "TRACKER_GRID_SPACING", "TRACKER_POSITION",
           "TRACKER_TILT", "Tracker", "TrackerData", "TrackerNoise", "TrackerOptions",
           "TrackerProblem", "TrackerSection", "TrackerSetup", "as_points", "as_tracker_data",
           "calibrate_tracker", "check_spread", "default_tracker_pose", "distance_ratio_pairs",
           "distance_ratios", "grid_neighbour_pairs", "grid_points", "neighbour_pairs",
           "plan_target", "planned_targets", "predict_tracker_points", "prediction_covariance",
           "registration_of", "simulate_tracker", "tracker_noise_arg", "tracker_pose",
           "tracker_targets"]


def _point_errors(measured, exact) -> dict:
    """Mean and max distance between predicted and exact tracker points (NaN where a
    prediction failed; NaN metrics when all did)."""
    e = np.linalg.norm(measured - exact, axis=-1)
    ok = np.isfinite(e)
    return {"position_mean": float(np.mean(e[ok])) if ok.any() else math.nan,
            "position_max": float(np.max(e[ok])) if ok.any() else math.nan}


@dataclass(frozen=True, slots=True)
class TrackerOptions:
    """The options of the tracker's calibration flow (:meth:`Tracker.calibrate`)."""

    noise: object = option(
        None, "--noise", "leica (default) or a length for isotropic noise (e.g. 10um); held "
        "as given (a TrackerNoise too), else the levels are estimated from the residuals.")
    two_step: bool = option(
        False, "--two-step", "The paper's method, registration first (closed form with the "
        "nominal model) and then the errors with the registration fixed. Default: errors and "
        "registration together.")
    robust: bool = option(
        False, "--robust", "Leave out the rows the noise cannot explain (a chi-square test of "
        "each row) and fit again.")


class Tracker(Instrument):
    """Points of a target on the platform in the instrument's frame (seed 001's tracker)."""

    name = "tracker"
    aliases = ("points",)
    words = "a target on the platform measured in the instrument frame (laser tracker, CMM)"
    calibrate_help = """
        Seed 001's calibration: the tracker's pose (and, with several targets, their places
        on the platform) fitted with the machine's errors, or with --two-step registration
        first.

        Example: `pkmcal calibrate examples/delta_default.yaml tracker.csv --robust -o
        cal.yaml`
        """
    plan_size = 27
    #: the quantities of its machine-file section (unit conversion, magnitude checks)
    file_quantities = {("tracker", "translation", "*"): "length",
                       ("tracker", "targets", "*", "*"): "length"}
    columns = "q1_deg..q3_deg and the tracker points mx_mm, my_mm, mz_mm"
    priority = 10
    missing = ("mx_<unit>, my_<unit>, mz_<unit> (e.g. mx_mm)", "laser-tracker points")
    data_class = "TrackerData"

    def detect(self, header):
        return has_column(header, "mx") or has_column(header, "my") or has_column(header, "mz")

    def plan_size_for(self, machine):
        # the source paper's 3x3x3 grid (seed 001, the Delta); random poses otherwise
        return self.plan_size if machine.tracker_grid_spacing() is not None else 60

    def default_noise(self):

        return TrackerNoise()

    def describe_noise(self, noise):
        if hasattr(noise, "sigma"):
            return f"points: {noise.sigma * 1e6:.3g} um per coordinate (std)"
        return (f"laser tracker: {noise.distance * 1e6:.3g} um along the beam, "
                f"{noise.transverse * 1e6:.3g} um + {noise.transverse_per_m * 1e6:.3g} um/m "
                "across (std)")

    montecarlo_variables = ("noise", "poses", "tolerance")
    montecarlo_metrics = {
        "position_mean": ("um", 1e-6, "mean held-out tracker-point error"),
        "position_max": ("um", 1e-6, "max held-out tracker-point error"),
    }
    montecarlo_evaluation_poses = 200
    montecarlo_exact_data = True
    montecarlo_noise_words = ("leica",)

    def montecarlo_default_poses(self, machine):
        # seed 001's grid on a platform that only translates, the plan size otherwise
        return "3x3x3 grid" if not machine.rotates else self.plan_size_for(machine)

    def montecarlo_minimum_poses(self, settings):
        # 3 equations per point, 12 gauges
        return max(4, math.ceil((len(settings.machine.parameters) + 6 - 12) / 3))

    @staticmethod
    def _montecarlo_noises(run):
        """Simulated and fitted tracker noise of a run (None: Leica-type)."""
        noise = run.settings.noise
        if noise is None:
            return TrackerNoise(), TrackerNoise()
        sim_noise = TrackerNoise(noise, noise, 0.0) if noise > 0 else None
        return sim_noise, TrackerNoise(run.weight(noise), run.weight(noise), 0.0)

    def montecarlo_run(self, run):
        """Errors jointly with the tracker pose; held out: the tracker points at readings in
        the grid's box that were not measured, the calibrated model with its registration
        against the true machine's exact points. A machine whose file does not give the
        target's place (a platform that rotates): :meth:`_montecarlo_points_run`."""
        s = run.settings
        nominal = s.machine
        if nominal.tracker_target() is None:
            return self._montecarlo_points_run(run)
        true = run.true_machine()
        pose = tracker_pose(run.settings.setups.get(self.name))
        sim_noise, fit_noise = self._montecarlo_noises(run)
        if s.poses is None and nominal.tracker_grid_spacing() is not None:
            targets = grid_points(nominal.home[0], nominal.tracker_grid_spacing())
        else:
            targets = self.candidates(nominal, s.poses or self.montecarlo_poses, run.rng)[0]
        data = simulate_tracker(true, nominal, targets, pose, sim_noise, rng=run.rng)
        res = calibrate_tracker(nominal, data, fit_noise)
        held = self.candidates(nominal, self.montecarlo_evaluation_poses, run.rng)[0]
        q = nominal.ik(held)
        m = predict_tracker_points(res.machine, q, res.section(TrackerSection).registration)
        return res, _point_errors(m, predict_tracker_points(true, q, pose))

    def _montecarlo_points_run(self, run):
        """Random workspace poses with rotations, the target's place estimated; held out: the
        points at other poses through the identified registration and target."""
        nominal = run.settings.machine
        sim_noise, fit_noise = self._montecarlo_noises(run)
        data, true, truth = run.simulate(run.settings.poses,
                                         False if sim_noise is None else sim_noise)
        res = calibrate_tracker(nominal, data, fit_noise)
        P, R, _ = self.candidates(nominal, self.montecarlo_evaluation_poses, run.rng)
        q = nominal.ik(P, R)
        sec = res.section(TrackerSection)
        m = predict_tracker_points(res.machine, q, sec.registration, targets=sec.targets)
        return res, _point_errors(m, predict_tracker_points(true, q, truth["base_from_tracker"],
                                                            targets=truth["targets"]))

    def candidates(self, machine, n, rng, setup=None):
        if machine.tracker_grid_spacing() is None:
            return super().candidates(machine, n, rng)
        from ...machines.deviations import draw_accepted

        half = np.asarray(machine.tracker_grid_spacing(), float)   # the 3x3x3 grid: +/- spacing
        centre = machine.home[0]

        def draw(m, rng):
            P = centre + rng.uniform(-1.0, 1.0, (m, 3)) * half
            R = np.broadcast_to(np.eye(3), (m, 3, 3))
            q, J, _ = machine.ik_jacobians(P, R, want_du=False)
            ok = np.all(np.isfinite(q), -1)
            sv = np.linalg.svd(np.asarray(J)[ok][..., :3], compute_uv=False)
            ok[ok] = sv[..., -1] / sv[..., 0] > 0.05
            return P, R, ok

        where = str(getattr(machine, "source", "") or "").replace("{", "{{").replace("}", "}}")
        P, R = draw_accepted(draw, n, rng, (f"{where}: " if where else "")
                             + "only {have} of {n} candidate points around home are reachable "
                             "and well conditioned: check the geometry and home")
        return P, R, None

    def standard_plan(self, machine, n, seed, setup=None):
        if machine.tracker_grid_spacing() is None:
            return super().standard_plan(machine, n, seed, setup)

        k = int(round(n ** (1.0 / 3.0)))
        if k < 2 or k**3 != n:
            return StandardPlan("seed 001's grid around home",
                                reason=f"seed 001's grid has 3 x 3 x 3 = 27 points (k x k x k "
                                       f"grids in its box: 8, 27, 64, ...), not {n}")
        span = 2.0 * np.asarray(machine.tracker_grid_spacing(), float)   # 3x3x3 extent
        P = grid_points(machine.home[0], span / (k - 1), (k, k, k))
        return StandardPlan(f"the {k}x{k}x{k} grid of seed 001 around home", P,
                            np.broadcast_to(np.eye(3), (n, 3, 3)))

    def planned_data(self, machine, P, R, rows, source, group=None, setup=None):

        q = reachable(machine, P, R, rows, source)
        Rt, t = tracker_pose(setup)
        x = P + np.einsum("kij,j->ki", R, plan_target(machine))
        return TrackerData(q, (x - t) @ Rt, rows=rows, source=source, true_P=P,
                           target=None if group is None else np.asarray(group, int))

    section = "tracker"
    section_words = ("a calibration from points (mx, my, mz: laser tracker, CMM) writes the "
                     "tracker section")
    Setup = TrackerSetup
    section_order = 10
    section_schema = TrackerFileSection
    section_lists = {"targets": "a list of target places [[x, y, z], ...] on the platform "
                                "(one per target)"}

    def read_setup(self, section, length_factor, machine):
        targets = getattr(section, "targets", None)
        return TrackerSetup(
            (file_rotation(section.rotation),
             np.asarray(section.translation, float) * length_factor),
            None if targets is None else np.asarray(targets, float) * length_factor)

    def setup_section(self, setup, length_factor, machine):
        out = frame_section(setup.base_from_tracker, length_factor)
        if setup.targets is not None:
            targets = np.asarray(setup.targets, float).reshape(-1, 3)
            known = machine.tracker_target()
            if known is None:
                out["targets"] = [vector(c, length_factor) for c in targets]
            elif not np.allclose(targets, known, rtol=0, atol=1e-12):
                raise InputError(f"cannot save tracker targets for a {machine.kind}: its "
                                 "target on the platform is fixed by the machine file "
                                 "(smr_offset)")
        return out

    def carried_by(self, machine, setup):
        return setup is not None

    def groups_carried(self, setup):
        return 0 if setup is None or setup.targets is None else len(setup.targets)

    def predict(self, machine, setup, P, R, ok, group, rows=None, source=None):
        targets, shared = tracker_targets(machine, setup)
        if shared:
            group = np.zeros(len(P), int)     # every target number is the file's reflector
        _check_groups(group, len(targets), "target", "tracker.targets" if setup.targets
                      is not None else "tracker (one target: the platform origin, no targets "
                      "key)", rows, source)
        A, a = (np.asarray(v, float) for v in setup.base_from_tracker)
        model = PointsModel(len(targets), targets[0] if shared else None)
        values = np.concatenate([np.zeros(3), a] + ([] if shared else [targets.ravel()]))
        return model.predict(NuisanceState(values, [A]), P, R, group), None, group

    simulate_options = {"targets": 1}
    simulate_options_words = "targets: apply to the tracker (points) scenario"

    def simulate(self, machine, true, n, noise, rng, truth, *, setup=None, poses=None,
                 mounting_error=MOUNTING_ERROR, targets=1):
        """``n`` random workspace poses (:meth:`candidates`: rotations on platforms that
        rotate), or ``poses``; ``targets`` targets, rows cycling through them; the tracker at
        the machine file's (``setup``, else the simulations' default); true target
        places = planned (:func:`planned_targets`) + a uniform error of ``mounting_error`` per
        coordinate (the file's target when it gives one). ``noise`` a tracker noise model
        (default ``TrackerNoise()``; False: exact data). See
        :meth:`Instrument.simulate <pkmcal.instruments.base.Instrument.simulate>`.

        Returns
        -------
        tuple
            ``(data, true, truth)``; ``truth`` with ``base_from_tracker``, ``targets``,
            ``planned_targets`` and ``setup`` (the true :class:`TrackerSetup`).
        """
        from ..experiment import given_poses, mm_text, noise_model, simulate_instrument

        k = int(targets)
        planned = planned_targets(machine, k)
        known = machine.tracker_target() is not None
        c = planned if known else planned + rng.uniform(-mounting_error, mounting_error,
                                                        planned.shape)
        Rt, t = tracker_pose(setup)
        model = PointsModel(k, machine.tracker_target())
        state = model.initial()
        state.rotations = [np.asarray(Rt, float)]
        state.values[3:6] = t
        if not known:
            state.values[model._it.ravel()] = c.ravel()
        if poses is None:
            P, R, _ = self.candidates(machine, n, rng)
            words = (f"{n} random workspace poses around home"
                     + (" with rotations within +/-10 deg" if machine.rotates else ""))
        else:
            P, R = given_poses(poses)
            words = f"{len(P)} given poses"
        group = np.arange(len(P)) % k
        data = simulate_instrument(true, machine, model, state, P, R, group,
                                   noise_model(noise, TrackerNoise()), rng)
        true_setup = TrackerSetup((np.asarray(Rt, float), np.asarray(t, float)),
                                  None if known else c)
        R_true, t_true = true_setup.base_from_tracker
        angle = np.degrees(np.arccos(np.clip((np.trace(R_true) - 1) / 2, -1, 1)))
        rows = [("tracker pose", f"at {mm_text(t_true)} mm in the base frame, rotated "
                 f"{angle:.4g} deg relative to it")]
        rows += [(f"target {g + 1}", f"{mm_text(cg)} mm on the platform (true)")
                 for g, cg in enumerate(c)]
        truth.update(base_from_tracker=true_setup.base_from_tracker, targets=c,
                     planned_targets=planned, poses=words, rows=rows, setup=true_setup)
        return data, true, truth

    simulate_flags = {"--targets": "--scenario points (tracker)"}

    def simulates_grid(self, machine, targets=None):
        # seed 001's grid on a platform that only translates (its file gives the spacing)
        return machine.tracker_grid_spacing() is not None and not targets

    def simulate_arguments(self, machine, noise, targets=None, **flags):
        model, words = tracker_noise_arg(noise, allow_none=True, machine=machine)
        model = False if model is None else model
        targets = 1 if targets is None else targets
        if targets < 1:
            raise InputError(f"--targets: must be >= 1, got {targets}")
        return model, words, {"targets": targets}

    data_columns = ("mx", "my", "mz")

    def calibration_summary(self, report):
        res, ident = report["residuals"], report["identifiability"]
        reg, dr = report["registration"], report["distance_ratio"]
        unit = report["units"]["length"]
        if "smr_offset" in report:
            where = f"reflector {report['smr_offset']:.6g} {unit} below the platform point"
        else:
            places = report["targets"]["places"]
            where = (f"{len(places)} target(s) at estimated places on the platform: "
                     + ", ".join("(" + ", ".join(f"{v:.6g}" for v in c) + ")" for c in places)
                     + f" {unit}")
        rows = [("measurement", f"laser tracker, {report['measurements']} points ({where})"),
                ("method", "joint: the leg errors and the tracker pose together"
                 if report["method"] == "joint" else
                 "two-step (seed 001): tracker registered first with the nominal model, then "
                 "the leg errors with the registration fixed"),
                "identifiable, grouped",
                ("RMS residual", f"{format_um(res['rms_um'])} over {res['count']} points "
                 f"(3-D, measured - predicted tracker point); before calibration "
                 f"{format_um(res['before_rms_um'])} ({res['before']})"),
                ("noise", f"{report['noise']}")]
        if report["robust"]:
            if res["outliers"]:
                worst = ", ".join(f"row {o['row']}: {o['residual_um']:.4g} um"
                                  for o in res["outliers"][:10])
                rows.append(("outliers", f"{len(res['outliers'])} row(s) left out (--robust): "
                             f"{worst}"))
            else:
                rows.append(("outliers", "none found (--robust)"))
        if dr["pairs"] and dr["before"]["std"] is not None:
            b, a = dr["before"], dr["after"]
            change = 100 * (1 - a["std"] / b["std"]) if b["std"] > 0 else 0.0
            change_text = (f"{change:.3g} % smaller" if change >= 0
                           else f"{-change:.3g} % larger")
            rows.append(("distance ratio", f"spread (std) {b['std']:.4g} % before, "
                         f"{a['std']:.4g} % after ({change_text}); range {b['min']:.3f}.."
                         f"{b['max']:.3f} % -> {a['min']:.3f}..{a['max']:.3f} %; "
                         f"{dr['pairs']} pairs ({dr['pairs_from']})"))
        t = reg["translation"]
        rows += [("tracker pose", f"base_from_tracker: tracker origin at ({t[0]:.6g}, "
                  f"{t[1]:.6g}, {t[2]:.6g}) {unit}; "
                  + ("estimated: " if reg["estimated"] else "fixed: ")
                  + f"{reg['rotation_change_deg']:.3g} deg and "
                  f"{reg['translation_change']:.3g} {unit} from the closed-form registration"),
                 "held-out", "noise levels", "residual test", "convergence"]
        if report_verdict(report).status == FAILED_ALARMING:
            causes = ["outliers (try --robust)" if not report["robust"] else None,
                      "a registration biased by the nominal model (drop --two-step)"
                      if report["method"] == "two-step" else None,
                      "a wrong smr_offset or noise model", "errors the model does not have"]
            rows.append(("note", "note: the residual test failed; usual causes: "
                         f"{', '.join(c for c in causes if c)}."))
        if ident["unidentifiable"] and "identifiable_combinations" in report:
            what = report["identifiable_combinations"]["description"].split(" (file length")[0]
            rows.append(("note", f"note: {what}; the changes are the smallest ones (scaled) "
                         "that fit the data, and std is for the identifiable part."))
        elif ident["unidentifiable"]:
            rows.append(("note", "note: the data fix the machine only relative to the tracker "
                         "frame and the targets; the changes are the smallest ones (scaled) "
                         "that fit the data, and std is for the identifiable part."))
        return rows
    prediction_words = "predicted tracker point(s) (target in the tracker frame)"

    def problem(self, machine, data, noise=None, setup=None, registration=None, targets=None,
                **start):

        groups = getattr(data, "target", getattr(data, "group", None))
        n_targets = 1 if groups is None or not len(groups) else int(np.max(groups)) + 1
        target = None if machine.tracker_target() is not None else \
            np.tile(plan_target(machine), (n_targets, 1)) if targets is None else targets
        return TrackerProblem(machine, data, self.default_noise() if noise is None else noise,
                              tracker_pose(setup) if registration is None else registration,
                              targets=target)

    measurement_words = ("points of a target on the platform (laser tracker; tracker pose and "
                         "unknown target places estimated jointly)")
    group_column = "target"
    plan_options = ("targets",)

    def noise_arg(self, text, machine=None):
        """The tracker noise of ``--noise``: leica (default), or a length per coordinate."""

        if text is not None and not isinstance(text, str):
            return text
        return tracker_noise_arg(text, allow_none=False, machine=machine)[0]

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_points"
    #: its flow reads :class:`TrackerData` (the registration's start needs the points alone)
    calibration_reader = "read_tracker"
    Options = TrackerOptions

    def check_options(self, options, source) -> None:
        """``--robust`` with ``--two-step`` refused (see
        :meth:`~pkmcal.instruments.base.Instrument.check_options`)."""
        _check_options(options, source)

    def calibrate(self, machine: Machine, data, context, options):
        """Registration and errors together (or ``two_step``), the distance ratio (seed 001
        Fig. 6) before and after (see :meth:`~pkmcal.instruments.base.Instrument.calibrate`)."""
        return _calibration_flow(machine, data, context, options)

    def joint_part(self, machine: Machine, data, source, noise, read, options=None):
        """The tracker file's part of a fit of several files: its points, one target per
        ``target`` group, the tracker's pose unknown (see
        :meth:`~pkmcal.instruments.base.Instrument.joint_part`)."""
        if noise is None or isinstance(noise, str):
            noise_model, text = tracker_noise_arg(noise, allow_none=False, machine=machine)
        else:
            noise_model, text = noise, _tracker_noise_text(noise)
        raw = as_tracker_data(load_data(data, read, machine))
        check_spread(raw, noise_model)
        points = as_points(raw)
        points.source = str(source)
        return JointPart(points, PointsModel(points.n_groups, machine.tracker_target()),
                         noise_model, text, "tracker")

    def measured_problem(self, machine, data, noise=None, source="", setup=None):
        """The tracker's pose and the target places started from the data: registered on the
        machine file's forward kinematics, then (unknown targets) fitted with the machine
        held."""
        from ...estimation.estimator import levenberg_marquardt
        from ..models import PointsModel

        noise = self.default_noise() if noise is None else noise
        fk = _fk_of(machine, data, source)
        start = PointsModel(data.n_groups, machine.tracker_target()).start(
            fk.P, fk.R, data.values, data.group, str(source))
        registration = (start.rotation_starts[0], start.parameters.values[3:6].copy())
        targets = None
        if machine.tracker_target() is None:
            alone = TrackerProblem(machine, data, noise, registration).with_machine_fixed()
            first = levenberg_marquardt(alone)
            registration = registration_of(first.state)
            targets = first.state.nuisance.values[6:].copy()
        return self.problem(machine, data, noise, registration=registration, targets=targets)

    def planned_setup(self, machine, setup=None, targets=None, **options):
        """The file's set-up (several targets in turn need the target's place unknown)."""
        if targets is not None and targets > 1 and machine.tracker_target() is not None:
            raise InputError(f"--targets {targets}: {machine.source} gives the target's place "
                             "on the platform; one target only")
        return setup


#: this module's instrument (:data:`~pkmcal.instruments.registry.INSTRUMENT_MODULES`)
INSTRUMENT = Tracker()


# -- calibration flow (pkmcal calibrate) ------------------------------------------------------


def check_spread(data, noise_model) -> None:
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


def _check_options(options: TrackerOptions, source) -> None:
    """The tracker's options that do not go together, refused naming them (an option it does
    not declare is refused by the calibration layer)."""
    if options.two_step and options.robust:
        raise InputError("--robust: applies to the joint method (its residuals are the "
                         "noise's); --two-step holds a registration of the nominal model, whose "
                         "residuals exceed the noise by design")


def _calibration_flow(machine, data, context: FlowContext,
                      options: TrackerOptions) -> FlowResult:
    """``pkmcal calibrate`` from tracker points (:meth:`Tracker.calibrate`)."""
    from ...units import LENGTH

    source, split = context.source, context.split
    two_step, robust = options.two_step, options.robust
    if options.noise is None or isinstance(options.noise, str):
        noise_model, noise_text = tracker_noise_arg(options.noise, allow_none=False,
                                                    machine=machine)
    else:
        noise_model, noise_text = options.noise, _tracker_noise_text(options.noise)
    data, held = split_rows(as_tracker_data(load_data(data, context.read, machine)), split,
                            source)
    check_spread(data, noise_model)
    fk = machine.fk(data.q)
    if not fk.converged.all():
        raise InputError(f"{path_text(source)}: row(s) {rows_text(data.rows[~fk.converged])}: no "
                         f"platform pose of {source_of(machine)} reproduces these readings "
                         "(outside the workspace, or a wrong unit or zero)")
    result = solve(source, calibrate_tracker, machine, data, noise_model, held=held,
                    joint=not two_step, robust=robust, estimate_noise=options.noise is None)
    require_converged(result, source,
                       "spread the points in all three directions, e.g. a 3x3x3 grid")

    units = context.units
    fl = LENGTH[units["length"]]
    method = "two-step" if two_step else "joint"
    calibrated = result.machine
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    # FK start of the calibrated file: the input machine's home, else the measured position
    # closest to the middle of the data that the calibrated model reaches
    fk_cal = calibrated.fk(data.q)
    order = np.argsort(np.linalg.norm(fk_cal.P - np.nanmean(fk_cal.P, axis=0), axis=1))
    for P_home, R_home in [machine.home, *zip(fk_cal.P[order], fk_cal.R[order], strict=True)]:
        if np.all(np.isfinite(calibrated.ik(P_home, R_home))):
            calibrated.home = (np.asarray(P_home, float), np.asarray(R_home, float))
            break
    section = result.section(TrackerSection)
    R, t = section.registration
    R0, t0 = section.start_registration
    given = machine.tracker_target() is not None
    targets, targets0 = section.targets, section.start_targets
    # the tracker's set-up the fit determined (the targets only where the file gives none)
    fitted = TrackerSetup((R, t), None if given else np.array(targets, float))
    kept = np.asarray(section.kept, bool)
    outlier_rows = [int(v) for v in section.outlier_rows]

    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    nominal_of.update(zip(("tracker.rx", "tracker.ry", "tracker.rz"), (0.0, 0.0, 0.0),
                          strict=True))
    nominal_of.update(zip(("tracker.x", "tracker.y", "tracker.z"), t0, strict=True))
    params = parameter_table(result, nominal_of, units)

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
    unidentifiable = list(result.unidentifiable)
    combinations = calibrated.identifiable_combinations()
    if combinations is not None:
        combinations = {k: (v if k == "description" else (np.asarray(v) / fl).tolist())
                        for k, v in combinations.items()}
        combinations["description"] += " (file length unit)"
    report = {
        **context.head(machine, "tracker", method),
        "robust": robust,
        "units": units,
        "measurements": len(data),
        "used": int(kept.sum()),
        "outlier_rows": outlier_rows,
        "noise": noise_text,
        **({"smr_offset": float(-machine.tracker_target()[2]) / fl} if given else {}),
        **section.as_report(units),         # targets, registration
        "convergence": convergence_json(result),
        "residuals": {
            "of": "tracker points, measured - predicted (3-D distance, tracker frame)",
            "count": int(kept.sum()),
            "rms_um": rms(norm[kept]),
            "max_um": float(norm[kept].max() * 1e6) if kept.any() else None,
            "rms_per_axis_um": (np.sqrt(np.mean(r[kept] ** 2, axis=0)) * 1e6).tolist(),
            "before_rms_um": rms(norm0[kept]),
            "before": "machine file's model, closed-form registration" if given else
                      "machine file's model, tracker frame and targets fitted alone",
            **variance_json(result),
            "outliers": [{"row": int(row), "residual_um": float(v * 1e6)} for row, v in
                         zip(data.rows[~kept], norm[~kept], strict=True)],
        },
        "distance_ratio": {
            "unit": "%", "pairs": int(len(pairs)), "pairs_from": pairs_from,
            "before": before, "after": after,
        },
        "identifiability": identifiability_json(n_free, rank, unidentifiable, s),
        **({"identifiable_combinations": combinations} if combinations else {}),
        "parameters": public_parameters(params),
    }
    if held is not None:
        d_after = np.linalg.norm(held.m - predict_tracker_points(
            calibrated, held.q, (R, t), targets, held.target), axis=1)
        d_before = np.linalg.norm(held.m - predict_tracker_points(
            machine, held.q, (R0, t0), targets0, held.target), axis=1)
        ok = np.isfinite(d_after) & np.isfinite(d_before)
        report["validation"] = validation_section(
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
        "machine": source_of(machine),
        "measurements": len(data),
        "outlier_rows": outlier_rows,
        "rms_residual_um": report["residuals"]["rms_um"],
        "identifiable": rank,
        "free_parameters": n_free,
        **identifiability_metadata(unidentifiable),
        "distance_ratio_std_percent": {"before": before["std"], "after": after["std"]},
    }
    return FlowResult("tracker", machine, calibrated, result, report, metadata, params, units,
                      setups={"tracker": fitted})
