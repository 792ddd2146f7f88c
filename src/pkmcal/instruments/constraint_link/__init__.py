"""Self-calibration with a constraint link (seed 000, SPEC 2.1): the instrument's package.

A bar of length ``Lc`` with ball joints joins the base point O and the platform point P, so
``|P| = Lc``; five actuators drive, the sixth is passive and read as a sensor. Three methods
(``ml``, the default; the paper's ``ik`` and ``fk``) calibrate the geometry from the joint
readings alone.

This module is the instrument's home: the :class:`ConstraintLink` instrument
(:data:`INSTRUMENT`), its options (:class:`ConstraintLinkOptions`), its plan helpers and its
calibration flow (``pkmcal calibrate``). One concept per sub-module, their public names
re-exported here:

:mod:`.data`
    The measurements (:class:`ConstraintLinkData`) and their simulation.
:mod:`.start`
    Starting a calibration far from the machine: continuation, pose multi-starts, rows left
    out (:class:`StartReport`, :func:`continuation_solve`).
:mod:`.problems`
    The estimation problems: the poses on the sphere and the loop each method fits
    (:class:`ConstraintLinkML`, :class:`ConstraintLinkIK`, :class:`ConstraintLinkIKExplicit`,
    :class:`ConstraintLinkFK`).
:mod:`.section`
    What a calibration adds to its result (:class:`ConstraintLinkSection`).
:mod:`.methods`
    The calibration methods (:func:`calibrate_constraint_link`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...errors import InputError
from ...estimation.estimator import levenberg_marquardt
from ...machines.base import Machine
from ...paths import path_text
from ..base import Instrument, StandardPlan, _rows, _sigma_arg, _space_words, has_column, reachable
from ..experiment import MOUNTING_ERROR
from ..flow import (
    FlowContext,
    FlowResult,
    convergence_json,
    identifiability_json,
    identifiability_metadata,
    load_data,
    parameter_table,
    public_parameters,
    require_converged,
    rows_text,
    solve,
    source_of,
    split_rows,
    um,
    validation_section,
)
from ..flow import option as _option
from .data import (
    ConstraintLinkData,
    loop_conditioning,
    sample_sphere_poses,
    simulate_constraint_link,
)
from .methods import PAPER_METHOD_START, calibrate_constraint_link
from .problems import (
    LINK,
    METHODS,
    PROBLEMS,
    ConstraintLinkFK,
    ConstraintLinkIK,
    ConstraintLinkIKExplicit,
    ConstraintLinkML,
    SphereState,
    solve_sphere_poses,
    sphere_tangents,
)
from .section import ConstraintLinkSection
from .start import (
    MAX_LEFT_OUT,
    NEIGHBOURS,
    OUTLIER_FACTOR,
    OUTLIER_FLOOR,
    START_TOL,
    SUBSET_SHARE,
    TRIM_KEEP,
    TRIM_ROUNDS,
    StartReport,
    continuation_solve,
    neighbour_poses,
    sphere_pose_candidates,
    start_sensitivity,
)

__all__ = ["INSTRUMENT", "LINK", "MAX_LEFT_OUT", "METHODS", "NEIGHBOURS", "OUTLIER_FACTOR",
           "OUTLIER_FLOOR", "PAPER_METHOD_START", "PROBLEMS", "SPHERE_TOL", "START_TOL",
           "SUBSET_SHARE", "TRIM_KEEP", "TRIM_ROUNDS", "ConstraintLink", "ConstraintLinkData",
           "ConstraintLinkFK", "ConstraintLinkIK", "ConstraintLinkIKExplicit",
           "ConstraintLinkML", "ConstraintLinkOptions", "ConstraintLinkSection", "SphereState",
           "StartReport", "calibrate_constraint_link", "constraint_link_reading_rms",
           "continuation_solve", "link_length", "link_noise_arg", "loop_conditioning",
           "neighbour_poses", "sample_sphere_poses", "simulate_constraint_link",
           "solve_sphere_poses", "sphere_pose_candidates", "sphere_tangents",
           "start_sensitivity"]


def link_noise_arg(text: str | float | None, machine=None) -> float:
    """The encoder noise of constraint-link data (``--noise``, default 1 um), m.

    Parameters
    ----------
    text : str or float or None
        A length with its unit (``"2um"``), a number in metres, or None for 1 um.
    machine : Machine, optional
        Checked against its size when given.

    Returns
    -------
    float
        The standard deviation, m.

    Raises
    ------
    InputError
        When it is not a positive length or implausible for the machine.
    """
    if text is None or (isinstance(text, str) and not text):
        text = "1um"
    return _sigma_arg(text, machine, "the encoder noise", None)


@dataclass(frozen=True, slots=True)
class ConstraintLinkOptions:
    """The options of the constraint link's calibration flow (:meth:`ConstraintLink.calibrate`)."""

    method: str | None = _option(
        None, "--method", "ml maximum likelihood, every reading noisy (default); ik the "
        "paper's inverse-kinematics method (needs the passive column); fk the paper's "
        "forward-kinematics method (estimates Lc).", choices=("ml", "ik", "fk"))
    noise: object = _option(
        None, "--noise", "encoder noise, standard deviation (default 1um); held as given, else "
        "estimated from the residuals.")
    estimate_lc: bool | None = _option(
        None, "--estimate-lc/--no-estimate-lc", "Estimate the constraint-link length too "
        "(default: only with --method fk).", negative_help="Hold the constraint-link length "
        "at the machine file's, with --method fk too.")
    robust: bool = _option(
        False, "--robust", "Leave out the rows the noise cannot explain (a chi-square test of "
        "each row) and fit again (ml).")


class ConstraintLink(Instrument):
    """Seed 000: joint readings with the constraint link mounted, one joint passive."""

    name = "constraint-link"
    words = "a fixed-length constraint link, one joint passive (no external sensor)"
    plan_size = 150
    columns = "q1_mm..q6_mm (optionally passive) with a constraint_link in the machine file"
    calibrate_help = """
        The machine's errors from the loop the link closes; the link length too with
        --method fk or --estimate-lc.

        Example: `pkmcal calibrate default data.csv --estimate-lc -o calibrated.yaml`
        """
    priority = 90
    readings_only = True
    data_class = "ConstraintLinkData"
    joint_refusal = "the constraint link estimates a platform pose per measurement"

    def detect(self, header):
        return has_column(header, "q1")

    def applies(self, machine):
        if not machine.rotates:
            return ("the constraint link takes one degree of freedom of a platform that "
                    "rotates; this machine's platform only translates")
        if len(machine.pose_space) != 6:
            return ("the constraint link takes one degree of freedom of a platform that moves "
                    "in space (six pose coordinates); this machine's platform moves along "
                    f"{_space_words(machine)} only")
        if getattr(machine, "constraint_link_length", None) is None:
            return ("the machine file has no constraint link: add `constraint_link: {length: "
                    "...}` (in the file's length unit)")
        return None

    def default_noise(self):
        return 1e-6

    def describe_noise(self, noise):
        return f"encoder noise {noise * 1e6:.4g} um (std)"

    montecarlo_variables = ("noise", "lc-error", "poses", "tolerance")
    montecarlo_metrics = {
        "position_mean": ("um", 1e-6, "mean position error over the workspace, aligned"),
        "position_max": ("um", 1e-6, "max position error over the workspace, aligned"),
        "orientation_mean": ("urad", 1e-6, "mean orientation error, aligned"),
        "orientation_max": ("urad", 1e-6, "max orientation error, aligned"),
    }
    montecarlo_evaluation_poses = 300
    montecarlo_poses = 150
    montecarlo_exact_data = True

    def montecarlo_minimum_poses(self, settings):
        # one equation per pose
        return len(settings.machine.parameters) - 6 + int(settings.estimate_lc)

    def check_montecarlo(self, settings, what):
        Lc = getattr(settings.machine, "constraint_link_length", None)
        if Lc is None:
            raise InputError(f"{getattr(settings.machine, 'source', 'the machine')}: "
                             "constraint_link: the machine has no constraint-link length; add "
                             "`constraint_link: {length: ...}` to the machine file")
        if not Lc - settings.lc_error > 0:
            raise InputError(f"{what['lc_error']}: the true link length "
                             f"{(Lc - settings.lc_error) * 1e3:.6g} mm is not positive")

    def montecarlo_run(self, run):
        """Maximum likelihood (Lc estimated with ``estimate_lc``) from encoder readings on the
        true link's sphere; pose accuracy over the SPEC 5 workspace, gauge-aligned."""
        s = run.settings
        nominal = s.machine
        true = run.true_machine()
        lc_true = nominal.constraint_link_length - s.lc_error
        true.constraint_link_length = lc_true
        noise = 2e-6 if s.noise is None else s.noise
        data = simulate_constraint_link(true, s.poses or self.montecarlo_poses, noise,
                                        link_length=lc_true, link_length_error=s.lc_error,
                                        rng=run.rng)
        res = calibrate_constraint_link(nominal, data, sigma_m=run.weight(noise),
                                        estimate_link_length=s.estimate_lc)
        return res, run.workspace_accuracy(true, res.machine,
                                           self.montecarlo_evaluation_poses)

    def candidates(self, machine, n, rng, setup=None):

        P, R = sample_sphere_poses(machine, link_length(machine), n, rng)
        return P, R, None

    def standard_plan(self, machine, n, seed, setup=None):
        P, R, _ = self.candidates(machine, n, np.random.default_rng(seed))
        return StandardPlan(f"{n} random planned poses on the constraint sphere (seed {seed})",
                            P, R)

    def planned_data(self, machine, P, R, rows, source, group=None, setup=None):

        P = _on_sphere(P, machine, rows, source)
        q = reachable(machine, P, R, rows, source)
        return ConstraintLinkData(q, link_length(machine),
                                  np.arange(len(P)) % machine.n_joints, rows, source,
                                  true_P=P, true_R=R)

    report_sections = {"link_length": "a constraint-link report states the link length it used"}

    simulate_options = {"link_error": 0.0}
    simulate_options_words = "link_error: applies to the constraint-link scenario"

    def simulate(self, machine, true, n, noise, rng, truth, *, setup=None, poses=None,
                 mounting_error=MOUNTING_ERROR, link_error=0.0):
        """:func:`simulate_constraint_link` on the sphere of the true link (the file's length
        minus ``link_error``); ``noise`` the encoder std (m, default 1 um; False: exact).
        See :meth:`Instrument.simulate <pkmcal.instruments.base.Instrument.simulate>`.

        Returns
        -------
        tuple
            ``(data, true, truth)``; ``truth`` with ``link_length``.
        """
        Lc = float(machine.constraint_link_length) - float(link_error)
        if not Lc > 0:
            raise InputError(f"link_error: the true link length {Lc * 1e3:.6g} mm is not "
                             "positive")
        true.constraint_link_length = Lc
        sigma = 1e-6 if noise is None else (0.0 if noise is False else float(noise))
        data = simulate_constraint_link(true, n, sigma, link_length=Lc,
                                        link_length_error=float(link_error), rng=rng)
        lc = machine.constraint_link_length
        rows = [("link", f"true length {Lc * 1e3:.6g} mm")]
        if abs(lc - Lc) > 0:
            rows.append(("Lc error", f"machine file says {lc * 1e3:.6g} mm, true link "
                         f"{Lc * 1e3:.6g} mm"))
        truth.update(link_length=Lc, poses=f"{n} poses on the true link's sphere |P| = "
                     f"{Lc * 1e3:.6g} mm", rows=rows)
        return data, true, truth

    simulate_flags = {"--lc-error": "--scenario constraint-link"}

    def simulate_arguments(self, machine, noise, lc_error="0", **flags):
        from ...plausibility import check_option_scale
        from ...units import parse_quantity

        text = "2um" if noise is None else noise
        noise_m = parse_quantity(text, "length", "--noise")
        if not noise_m >= 0:
            raise InputError(f"--noise: must be >= 0, got {text}")
        check_option_scale(noise_m, machine, "--noise", "noise", text)
        lc_error_m = check_option_scale(parse_quantity(lc_error, "length", "--lc-error"),
                                        machine, "--lc-error", "error", lc_error)
        lc = machine.constraint_link_length
        if not lc - lc_error_m > 0:
            raise InputError(f"--lc-error: the true link length {(lc - lc_error_m) * 1e3:.6g} "
                             "mm is not positive")
        return noise_m, f"encoder noise {noise_m * 1e6:.4g} um", {"link_error": lc_error_m}

    writer = "write_constraint_link"

    def calibration_summary(self, report):
        res, ident = report["residuals"], report["identifiability"]
        noise = res["estimated_noise_um"]
        rows = [("measurement", f"{report['measurement']}, {report['measurements']} poses"),
                ("method", {"ml": "ml (maximum likelihood, all readings noisy)",
                            "ik": "ik (paper 3.4.1, inverse kinematics of the passive chain)",
                            "fk": "fk (paper 3.4.2, spread of the link length)"}
                 [report["method"]]),
                *([("start", report["start"])] if "start" in report else []),
                "identifiable",
                ("RMS residual", f"{res['rms_um']:.4g} um ({res['of']}; assumed noise "
                 f"{report['noise_sigma_um']:.4g} um"
                 + (f", estimated {noise:.3g} um)" if noise is not None else ")")),
                # the link length: its section's row (ConstraintLinkSection.summary_rows)
                "held-out", "noise levels", "convergence", "sections"]
        if ident["unidentifiable"]:
            rows.append(("note", "note: the data do not fix the directions listed as not "
                         "identifiable; the changes are the smallest ones (scaled) that fit "
                         "the data, and std is for the identifiable part."))
        return rows

    def problem(self, machine, data, noise=None, setup=None, **start):

        return ConstraintLinkML(machine, data, self.default_noise() if noise is None else noise)

    measurement_words = ("constraint link (maximum likelihood: every reading noisy; one pose on "
                         "the sphere per measurement)")

    def noise_arg(self, text, machine=None):
        """The encoder noise of ``--noise`` (default 1 um), m."""
        return _sigma_arg(text, machine, "the encoder noise", 1e-6)

    #: the io reader of its CSV files (:func:`pkmcal.io.read_measurements`)
    reader = "read_constraint_link"
    Options = ConstraintLinkOptions

    def check_options(self, options, source) -> None:
        """``--robust`` with ml alone (see
        :meth:`~pkmcal.instruments.base.Instrument.check_options`)."""
        _check_options(options, source)

    def calibrate(self, machine: Machine, data, context, options):
        """The geometry (and the link length with ``estimate_lc``) by ``method``, the joint
        readings' residuals before and after (see
        :meth:`~pkmcal.instruments.base.Instrument.calibrate`)."""
        return _calibration_flow(machine, data, context, options)


#: constraint-link plans: largest allowed deviation of |P| from Lc (m); poses within it are
#: put on the sphere (rounding in a hand-made plan file)
SPHERE_TOL = 1e-4


def link_length(machine: Machine) -> float:
    """The machine file's constraint-link length, m; InputError when it has none."""
    Lc = getattr(machine, "constraint_link_length", None)
    if Lc is None:
        raise InputError(f"{getattr(machine, 'source', 'the machine file')}: no "
                         "constraint_link length; constraint-link plans need it")
    return float(Lc)


def _on_sphere(P, machine, rows, source):
    """Constraint-link plan poses put exactly on ``|P| = Lc`` (refused beyond SPHERE_TOL)."""
    Lc = link_length(machine)
    norm = np.linalg.norm(P, axis=-1)
    off = ~(np.abs(norm - Lc) <= SPHERE_TOL)
    if off.any():
        raise InputError(f"{path_text(source)}: row(s) {_rows(rows[off])}: |P| differs from the "
                         f"constraint-link length {Lc * 1e3:.6g} mm by more than "
                         f"{SPHERE_TOL * 1e3:g} mm; a constraint-link plan has its poses on "
                         "that sphere")
    return P * (Lc / norm)[:, None]


#: this module's instrument (:data:`~pkmcal.instruments.registry.INSTRUMENT_MODULES`)
INSTRUMENT = ConstraintLink()


def constraint_link_reading_rms(machine, data, sigma_m: float, max_iter: int = 20) -> float:
    """RMS joint-reading residual (m) of ``machine``'s geometry on constraint-link ``data``.

    The poses on the link's sphere are fitted by maximum likelihood with the geometry and the
    link length (``data.link_length``) held: the residual a calibration would start from, or,
    for held-out data, the residual the calibrated geometry leaves on readings it never saw.

    Parameters
    ----------
    machine : HexaSlide
        The geometry to test (its current parameters are held).
    data : ConstraintLinkData
        Readings taken with the link mounted.
    sigma_m : float
        Encoder noise (m); it only scales the iterations, not the result.
    max_iter : int
        Gauss-Newton iterations for the poses.

    Returns
    -------
    float
        RMS over all readings (m); NaN when the poses cannot be fitted.
    """
    try:
        problem = ConstraintLinkML(machine.with_parameters(machine.u), data, sigma_m)
        problem.parameters = problem.parameters.with_fixed(list(problem.parameters.names))
        res = levenberg_marquardt(problem, max_iter=max_iter)
    except (InputError, ValueError, np.linalg.LinAlgError):
        return float("nan")
    r = np.asarray(res.residuals, float) * sigma_m
    return float(np.sqrt(np.mean(r**2))) if r.size and np.all(np.isfinite(r)) else float("nan")


# -- calibration flow (pkmcal calibrate) ------------------------------------------------------


def _check_options(options: ConstraintLinkOptions, source) -> None:
    """The constraint link's options that do not go together, refused naming them (an option
    it does not declare is refused by the calibration layer)."""
    if options.robust and options.method not in (None, "ml"):
        raise InputError(f"--robust: applies to the ml method (its residuals are the noise's); "
                         f"--method {options.method} takes some readings as exact")


def _calibration_flow(machine, data, context: FlowContext,
                      options: ConstraintLinkOptions) -> FlowResult:
    """``pkmcal calibrate`` from constraint-link readings (:meth:`ConstraintLink.calibrate`)."""

    source, split = context.source, context.split
    method = options.method or "ml"
    estimate_lc = options.estimate_lc
    sigma = link_noise_arg(options.noise, machine)
    kind = "constraint-link"
    data, held = split_rows(load_data(data, context.read, machine), split, source)

    result = solve(source, calibrate_constraint_link, machine, data, held=held,
                    method=method, sigma_m=sigma, estimate_link_length=estimate_lc,
                    estimate_noise=options.noise is None, robust=options.robust)
    require_converged(result, source)
    kw = {} if estimate_lc is None else {"estimate_link_length": estimate_lc}
    result.rebuild_problem = lambda: PROBLEMS[method](machine, data, sigma, **kw)

    units = context.units
    calibrated = result.machine
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    # FK start of the calibrated file: the input machine's home (a central pose of the working
    # assembly mode) rather than the first measured pose, which may sit at the workspace edge
    home_P, home_R = machine.home
    if np.all(np.isfinite(calibrated.ik(home_P, home_R))):
        calibrated.home = (home_P, home_R)
    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    nominal_of["link.length"] = data.link_length
    params = parameter_table(result, nominal_of, units)
    r = np.asarray(result.residuals, float)
    if result.used is not None:             # the rows in the fit (not those left out)
        r = r[np.asarray(result.used, bool).reshape(len(r), -1).all(axis=-1)]
    r_m = r * sigma
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.unidentifiable)
    section = ConstraintLinkSection.of(result)
    dropped = [int(v) for v in np.asarray(section.dropped_rows)]
    lc_estimated = bool(section.estimated)
    lc = float(section.link_length if section.link_length is not None else data.link_length)
    residual_what = {"ml": "all joint readings", "ik": "passive joint readings",
                     "fk": "computed link length |P| - Lc"}[method]
    report = {
        **context.head(machine, kind, method, units),
        "measurements": len(data),
        "dropped_rows": dropped,
        "noise_sigma_um": sigma * 1e6,
        **section.as_report(units),         # link_length
        "convergence": convergence_json(result),
        "residuals": {
            "of": residual_what,
            "count": int(r.size),
            "rms_um": float(np.sqrt(np.mean(r_m**2)) * 1e6) if r.size else None,
            "max_abs_um": float(np.max(np.abs(r_m)) * 1e6) if r.size else None,
            "rms_per_column_um": (np.sqrt(np.mean(r_m**2, axis=0)) * 1e6).tolist()
            if r.ndim == 2 and r.shape[1] > 1 else None,
            "before_rms_um": um(constraint_link_reading_rms(machine, data, sigma)),
            "before": "machine file's geometry, all readings, poses fitted (maximum "
                      "likelihood)",
            "residual_variance": float(result.residual_variance),
            "estimated_noise_um": float(np.sqrt(result.residual_variance) * sigma * 1e6)
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": identifiability_json(n_free, rank, unidentifiable, s),
        "parameters": public_parameters(params),
    }
    if section.start_from is not None:      # the paper's methods: where they started
        report["start"] = section.start_from
    if held is not None:
        report["validation"] = validation_section(
            split, held, "joint readings of the held-out rows (poses fitted, geometry and Lc "
            "held); before: the machine file's geometry", "um",
            um(constraint_link_reading_rms(machine, held, sigma)),
            um(constraint_link_reading_rms(calibrated, replace(held, link_length=lc),
                                            sigma)),
            report["residuals"]["rms_um"])
    metadata = {
        "method": method,
        "date": report["date"],
        "data": path_text(source),
        "machine": source_of(machine),
        "measurements": len(data),
        "rms_residual_um": report["residuals"]["rms_um"],
        "identifiable": rank,
        "free_parameters": n_free,
        **identifiability_metadata(unidentifiable),
        "link_length_estimated": lc_estimated,
    }
    calibration = FlowResult(kind, machine, calibrated, result, report, metadata, params, units)
    if section.warnings is not None:        # ml: the start strategy says what it left out
        calibration.warnings += [f"{path_text(source)}: "
                                 f"{text}" for text in section.warnings]
    elif dropped:
        calibration.warnings.append(
            f"{path_text(source)}: "
            f"{len(dropped)} row(s) left out (no pose from the five active readings "
            f"and the link with the start geometry): {rows_text(dropped)}")
    return calibration
