"""What measurements will identify and how accurate the calibration will be (SPEC 3), before
and after measuring: the library side of ``pkmcal identifiability``.

:func:`assess_identifiability` builds the calibration problem of a plan (the instrument's
standard plan, random planned poses or given poses) or of measured data
(:func:`measured_problem`), and returns its identifiability report and the predicted pose
accuracy over a workspace (:func:`prediction_summary`); :func:`write_prediction_map` draws that
accuracy over two slices through the workspace. The instrument's noise model of the options
of ``pkmcal calibrate`` is :func:`noise_model`. Nothing here switches on an instrument: each
is asked through the registry (:mod:`pkmcal.instruments.registry`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..instruments.registry import instrument
from ..instruments.scenarios import (
    candidate_set,
    describe_noise,
    planned_problem,
    scenario_for,
    standard_plan,
)
from .design import Design, design_from_problem

__all__ = ["MAP_STEPS", "WORKSPACE_POSES", "IdentifiabilityAnalysis", "assess_identifiability",
           "measured_problem", "noise_model", "prediction_summary", "write_prediction_map"]

#: workspace poses of the predicted-accuracy summary (SPEC 5 cube) and of the map (per axis)
WORKSPACE_POSES = 500
MAP_STEPS = 31


def noise_model(scenario: str, noise=None, pose_noise: str | None = None, machine=None):
    """The noise model of ``--noise`` / ``--pose-noise`` for a scenario, as ``pkmcal
    calibrate`` takes them (:meth:`~pkmcal.instruments.base.Instrument.noise_option`).

    Parameters
    ----------
    scenario : str
        The scenario (an instrument's name or alias).
    noise : str or float or object, optional
        A level with its unit, an SI number or the instrument's noise model; default the
        instrument's.
    pose_noise : str, optional
        Full poses: the position and orientation levels.
    machine : Machine, optional
        Levels are checked against its size when given.

    Returns
    -------
    object
        The instrument's noise model.

    Raises
    ------
    InputError
        For a level that is not positive or implausible for the machine, or options the
        instrument does not take.
    """
    return instrument(scenario).noise_option(noise, pose_noise, machine)


def measured_problem(machine, data_path, scenario: str, noise=None, setup=None):
    """The calibration problem ``pkmcal calibrate`` would solve (default method) for a
    measurement file, unsolved, its instrument's unknowns started from the data on the machine
    file's geometry (a fit with the machine held: the registration and target places, the
    pivots and balls, the measurement frames).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    data_path : str or os.PathLike
        The measurement file.
    scenario : str
        Its measurement kind (:func:`~pkmcal.calibration.run.measurement_kind`).
    noise : object, optional
        The instrument's noise model (:func:`noise_model`); default the instrument's.
    setup : object, optional
        The instrument's set-up of the machine file (start values).

    Returns
    -------
    problem : BlockProblem
        The problem.
    data : object
        The measurements read.

    Raises
    ------
    InputError
        When the file cannot be read or its readings are out of the machine's reach.
    """
    inst = instrument(scenario)
    from ..io import read_measurements

    data = read_measurements(inst, data_path, machine, {inst.name: setup})
    return inst.measured_problem(machine, data, noise, str(data_path), setup=setup), data


def prediction_summary(machine, design: Design, n_machine: int, M=None, op=None,
                       workspace=None, seed: int = 0) -> dict:
    """Predicted pose accuracy over a workspace (the report's ``predicted_accuracy``).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    design : Design
        The design of the problem (:func:`~pkmcal.planning.design_from_problem`).
    n_machine : int
        Number of machine parameters among the problem's.
    M : ndarray, optional
        Information of the poses measured; default all the design's.
    op : PoseErrorOperator, optional
        The pose-error operator at the workspace's poses when already computed.
    workspace : Workspace, optional
        Where (:class:`~pkmcal.analysis.accuracy.Workspace`); default the SPEC 5 cube around
        home (:data:`WORKSPACE_POSES` poses of ``seed``).
    seed : int, optional
        Seed of the default workspace.

    Returns
    -------
    dict
        ``workspace`` (in words), ``poses``, ``unbounded_directions`` and the position (um)
        and orientation (urad) RMS, 95th percentile and maximum.
    """
    from ..analysis.accuracy import default_workspace
    from ..analysis.prediction import predict_pose_accuracy

    ws = default_workspace(machine, WORKSPACE_POSES, seed) if workspace is None else workspace
    P, R = (op.P, op.R) if op is not None else (ws.P, ws.R)
    pred = predict_pose_accuracy(machine, design, P, R, M, n_machine, op=op)
    s = pred.summary()
    out = {"workspace": ws.description, "poses": s["poses"],
           "unbounded_directions": s["unbounded"]}
    for key, scale, unit in (("position", 1e6, "um"), ("orientation", 1e6, "urad")):
        if s[key] is not None:
            for stat in ("rms", "p95", "max"):
                out[f"{key}_{stat}_{unit}"] = s[key][stat] * scale
    return out


def write_prediction_map(path, machine, design: Design, n_machine: int, M, plan_P, title: str,
                         bounds=None) -> Path:
    """Plot the predicted position error (1 sigma) over two slices through the workspace's
    centre (x-y and x-z, home orientation) and the planned measurement positions.

    Parameters
    ----------
    path : str or os.PathLike
        The image file.
    machine : Machine
        The nominal machine.
    design : Design
        The design of the problem.
    n_machine : int
        Number of machine parameters among the problem's.
    M : ndarray or None
        Information of the poses measured; None: all the design's.
    plan_P : array_like, shape (K, 3) or None
        Measurement positions to mark, m.
    title : str
        The figure's title.
    bounds : tuple of array_like, optional
        ``(lo, hi)`` of the slices, m; default home +/- 50 mm.

    Returns
    -------
    pathlib.Path
        The path written.
    """
    from ..analysis.prediction import predict_pose_accuracy
    from ..report import plots

    if bounds is None:
        c = machine.home[0]
        half = np.full(3, 0.05)
    else:
        lo, hi = (np.asarray(b, float) for b in bounds)
        c, half = (lo + hi) / 2, np.maximum((hi - lo) / 2, 1e-6)
    t = np.linspace(-1.0, 1.0, MAP_STEPS)
    slices = []
    for (i, j) in ((0, 1), (0, 2)):
        A, B = np.meshgrid(t * half[i], t * half[j])
        P = np.tile(c, (A.size, 1))
        P[:, i] += A.ravel()
        P[:, j] += B.ravel()
        R = np.broadcast_to(machine.home[1] if machine.rotates else np.eye(3), (len(P), 3, 3))
        pred = predict_pose_accuracy(machine, design, P, R, M, n_machine)
        k = 3 - i - j
        a, b = "xyz"[i], "xyz"[j]
        through = "home" if bounds is None else "the workspace's centre"
        slices.append((f"{a}-{b} slice through {through} ({'xyz'[k]} = {c[k] * 1e3:.4g} mm)",
                       (c[i] + t * half[i]) * 1e3, (c[j] + t * half[j]) * 1e3,
                       (pred.position * 1e6).reshape(A.shape),
                       f"{a} [mm]", f"{b} [mm]", "predicted position error, 1 sigma [um]"))
    plan = None if plan_P is None else np.asarray(plan_P) * 1e3
    return plots.plot_prediction_map(slices, path, title, plan, c * 1e3)


@dataclass
class IdentifiabilityAnalysis:
    """Result of :func:`assess_identifiability`.

    Attributes
    ----------
    machine : Machine
        The nominal machine analysed.
    scenario : str
        The measurement (an instrument's canonical name).
    planned : bool
        Planned measurements (noise-free, on the nominal machine), not measured data.
    source : str
        What was analysed, in words (a file, the standard plan, random poses).
    problem : BlockProblem
        The calibration problem, unsolved.
    data : object
        Its measurements.
    report : IdentifiabilityReport
        Rank, named unidentifiable and weak directions, correlations, observability.
    design : Design
        Per-measurement information on the identifiable directions.
    noise : object
        The noise model assumed.
    prediction : dict
        The predicted pose accuracy over the workspace (:func:`prediction_summary`), with the
        noise in words (``noise``).
    workspace : Workspace
        Where the accuracy is predicted.
    """

    machine: object
    scenario: str
    planned: bool
    source: str
    problem: object
    data: object
    report: object
    design: Design
    noise: object
    prediction: dict = field(default_factory=dict)
    workspace: object = None

    @property
    def measurements(self) -> int:
        """Number of measurements."""
        return len(self.data)

    def as_dict(self) -> dict:
        """The report's analysis sections (JSON-ready but for non-finite numbers).

        Returns
        -------
        dict
            ``planned``, ``measurement``, ``measurements``, the identifiability report's
            keys, ``predicted_accuracy`` and ``singular_values``.
        """
        return {"planned": self.planned, "measurement": self.scenario,
                "measurements": self.measurements, **self.report.as_dict(),
                "predicted_accuracy": self.prediction,
                "singular_values": np.asarray(self.report.singular_values, float).tolist()}

    def write_map(self, path, bounds=None) -> Path:
        """Plot the predicted accuracy after calibration with these measurements
        (:func:`write_prediction_map`).

        Parameters
        ----------
        path : str or os.PathLike
            The image file.
        bounds : tuple of array_like, optional
            ``(lo, hi)`` of the slices, m; default home +/- 50 mm.

        Returns
        -------
        pathlib.Path
            The path written.
        """
        return write_prediction_map(
            path, self.machine, self.design, self.problem.n_machine, None,
            getattr(self.data, "true_P", None),
            f"predicted accuracy after calibration ({self.measurements} measurements, "
            f"{self.prediction['noise']})", bounds=bounds)


def assess_identifiability(machine, scenario: str | None = None, *, data=None, poses=None,
                           rows=None, groups=None, source: str | None = None,
                           n: int | None = None, noise=None, seed: int = 0, workspace=None,
                           targets: int | None = None, setup=None) -> IdentifiabilityAnalysis:
    """Identifiability and predicted accuracy of measured data or of a plan.

    One of: ``data`` (a measurement file: the problem ``pkmcal calibrate`` would solve,
    :func:`measured_problem`), ``poses`` (planned poses, e.g. of a plan file), ``n`` (random
    planned poses of ``seed``); with none of them, the instrument's standard plan (what
    ``pkmcal select-poses`` compares with).

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : str, optional
        The instrument; default, for ``data`` the file's measurement kind
        (:func:`~pkmcal.calibration.run.measurement_kind`), else the machine's.
    data : str or os.PathLike, optional
        A measurement file.
    poses : tuple of array_like, optional
        ``(P, R)`` planned positions (K, 3), m, and orientations (K, 3, 3).
    rows : array_like of int, optional
        Row labels of ``poses``, for messages.
    groups : array_like of int, optional
        0-based target / setup of each of ``poses``.
    source : str, optional
        Name of ``poses`` (their file), for messages.
    n : int, optional
        Number of random planned poses.
    noise : object, optional
        The instrument's noise model (:func:`noise_model`); default its own.
    seed : int, optional
        Seed of random and standard plans and of the default workspace.
    workspace : Workspace, optional
        Where the accuracy is predicted; default the SPEC 5 cube around home.
    targets : int, optional
        Planned tracker targets, used in turn (``poses`` with ``groups``: the targets they
        give).
    setup : object, optional
        The instrument's set-up (:mod:`pkmcal.instruments.setups`: the machine file's, or a
        ballbar's planned mountings,
        :meth:`~pkmcal.instruments.base.Instrument.planned_setup`); default the planning one.

    Returns
    -------
    IdentifiabilityAnalysis
        The problem, its identifiability report, design and predicted accuracy.

    Raises
    ------
    InputError
        For an instrument that does not apply, a standard plan that is not available, data
        or poses the machine cannot reproduce, or a failed analysis.
    """
    from ..analysis.accuracy import default_workspace
    from ..identifiability import identifiability_report

    measured = data is not None
    if measured and scenario is None:
        from ..calibration.run import measurement_kind
        from ..io import read_table

        scenario = measurement_kind(data, read_table(data)[0], machine)
    kind = scenario_for(machine, scenario)
    noise = instrument(kind).noise_option(None, None, machine) if noise is None else noise
    ws = default_workspace(machine, WORKSPACE_POSES, seed) if workspace is None else workspace
    where = str(data) if measured else source or "plan"
    if measured:
        words = f"{data}"
    else:
        if poses is not None:
            P, R = poses
            words = f"planned poses of {source}"
        elif n is not None or targets:
            n = instrument(kind).plan_size_for(machine) if n is None else n
            P, R, groups = candidate_set(machine, kind, n, rng=seed, setup=setup)
            rows, words = None, f"{n} random planned poses (seed {seed})"
        else:
            plan = standard_plan(machine, kind, seed=seed, setup=setup)
            if not plan.available:
                raise InputError(f"{plan.name}: {plan.reason}")
            P, R, groups = plan.P, plan.R, plan.group
            rows, words = None, plan.name
        if targets and (poses is None or groups is None):   # a plan's own targets win
            groups = np.arange(len(P)) % targets
            words += f", {targets} target(s) in turn"
    try:
        if measured:
            problem, measurements = measured_problem(machine, data, kind, noise, setup)
        else:
            problem = planned_problem(machine, kind, P, R, noise, rows, source or "<plan>",
                                      group=groups, setup=setup)
            measurements = problem.data
        rep = identifiability_report(problem)
        design = design_from_problem(problem)
        section = prediction_summary(machine, design, problem.n_machine, seed=seed,
                                     workspace=ws)
    except InputError:
        raise
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise InputError(f"{where}: identifiability analysis failed: {exc}") from None
    section["noise"] = describe_noise(kind, noise)
    return IdentifiabilityAnalysis(machine, kind, not measured, words, problem, measurements, rep,
                                   design, noise, section, ws)
