"""The instrument concept: what every instrument of :mod:`pkmcal.instruments.registry` knows
for any machine (the base class), its standard plan and the reach of planned poses."""

from __future__ import annotations

import dataclasses
import inspect
import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from ..paths import path_text
from ..units import format_um
from .experiment import MOUNTING_ERROR


@dataclass
class StandardPlan:
    """The instrument's standard measurement plan (what one measures without planning), or
    the reason there is none of a given size.

    Attributes
    ----------
    name : str
        The plan in words, e.g. "seed 001's 3x3x3 grid around home".
    P : ndarray, shape (n, 3) or None
        Positions, m; None when there is no standard plan of the size asked for.
    R : ndarray, shape (n, 3, 3) or None
        Orientations.
    reason : str
        Why there is none (empty when there is one).
    group : ndarray of int, shape (n,) or None
        0-based setup of each pose (distance plans), else None.
    """

    name: str
    P: np.ndarray | None = None
    R: np.ndarray | None = None
    reason: str = ""
    group: np.ndarray | None = None

    @property
    def available(self) -> bool:
        """True when the plan has poses."""
        return self.P is not None

    def __len__(self) -> int:
        return 0 if self.P is None else len(self.P)


def _rows(rows, limit: int = 10) -> str:
    rows = [int(r) for r in rows]
    return ", ".join(map(str, rows[:limit])) + (" ..." if len(rows) > limit else "")


def reachable(machine: Machine, P, R, rows, source) -> np.ndarray:
    """Joint values of planned poses; InputError naming the rows the machine cannot reach."""
    q = machine.ik(P, R)
    bad = ~np.all(np.isfinite(q), -1)
    if bad.any():
        raise InputError(f"{path_text(source)}: "
                         f"row(s) {_rows(rows[bad])}: pose(s) the machine cannot "
                         "reach")
    return q


def has_column(header, base: str) -> bool:
    """Whether a header has the column ``base`` (alone or with a unit suffix, ``base_mm``).

    Parameters
    ----------
    header : list of str
        Column names.
    base : str
        The column's name without its unit.

    Returns
    -------
    bool
        True when present.
    """
    return any(n == base or n.startswith(base + "_") for n in header)


class Instrument:
    """An instrument (see the module docstring); subclasses fill in the methods."""

    #: canonical name (scenario and measurement type)
    name: str = ""
    #: other names users may give (``--scenario points``)
    aliases: tuple = ()
    #: what it measures, in words
    words: str = ""
    #: default number of planned poses
    plan_size: int = 60
    #: the quantities of its machine-file section, ``{key path: "length" | "angle"}`` (``*``
    #: matches any key or index): unit conversion and magnitude checks of machine files
    file_quantities: dict = {}
    #: what its data files hold, in words (messages)
    columns: str = ""
    #: what ``pkmcal calibrate --help`` says of it beyond :meth:`help_paragraphs`' first
    #: sentence (markdown paragraphs, blank-line separated: what is fitted, an example)
    calibrate_help: str = ""
    #: data files are recognised in increasing priority (a readings-only fallback last)
    priority: int = 50
    #: its data files hold joint readings alone (no column of its own)
    readings_only: bool = False
    #: ``(columns, words)`` named when readings-only data come for a machine measured with it
    missing: tuple[str, str] | None = None
    #: its measurements can fix a length of the machine (heights along z alone cannot fix a
    #: printer's arms: a parameter set's ``without_lengths`` applies)
    fixes_lengths: bool = True
    #: its values are the nozzle's heights above a printer's bed (a bed probe): many of them
    #: (a mesh) show the bed's own shape (:mod:`pkmcal.calibration.bed_surface`); the report
    #: maps them, with their residuals, over the bed
    measures_bed_height: bool = False
    #: class name of its data objects (data given in memory)
    data_class: str = "InstrumentData"
    #: why its files cannot be fitted together with other files in one fit (empty: they can)
    joint_refusal: str = ""
    #: its measurements in words, one and several (messages: "does not apply to ...")
    singular: str = ""
    plural: str = ""
    #: what the residuals of its calibration report are, in words
    residual_words: str = "measured - predicted"
    #: what to measure when its calibration does not converge
    advice: str = "measure more, in other directions"
    #: what to measure when its data leave parameters poorly determined
    #: (:mod:`pkmcal.identifiability.determination`); empty: its ``MEASURE_NEXT``
    measure_next: str = ""
    #: ``fit_model(machine, data) -> NuisanceModel``: the model :func:`pkmcal.calibrate`
    #: fits by the calibration layer's generic path; None: the calibration layer registers
    #: handlers of its own for this instrument
    fit_model = None

    def noise_text(self, noise) -> str:
        """The noise in the report's words (default :meth:`describe_noise`).

        Parameters
        ----------
        noise : object
            A noise model of this instrument.

        Returns
        -------
        str
            One line.
        """
        return self.describe_noise(noise)

    def detect(self, header) -> bool:
        """Whether a data file's columns are this instrument's.

        Parameters
        ----------
        header : list of str
            The file's column names.

        Returns
        -------
        bool
            True for its files (:func:`has_column` of its own columns).
        """
        return False

    def plan_size_for(self, machine: Machine) -> int:
        """The default number of planned poses for ``machine``.

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        int
            :attr:`plan_size` unless the instrument says otherwise.
        """
        return self.plan_size

    def applies(self, machine: Machine) -> str | None:
        """Why this instrument cannot calibrate ``machine`` (None: it can).

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        str or None
            The reason in words.
        """
        return None

    def unbounded_cause(self, machine: Machine) -> str | None:
        """Why this instrument leaves directions that move ``machine``'s platform unidentified
        whatever the poses measured (so that more or other poses cannot help).

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        str or None
            The reason in words; None when other poses may see those directions.
        """
        return None

    def default_noise(self):
        """The noise model ``pkmcal calibrate`` assumes by default.

        Returns
        -------
        object
            The instrument's noise model.
        """
        raise NotImplementedError

    def describe_noise(self, noise) -> str:
        """The noise model in words (um, urad).

        Parameters
        ----------
        noise : object
            A noise model of this instrument.

        Returns
        -------
        str
            One line.
        """
        raise NotImplementedError

    # -- Monte Carlo (:mod:`pkmcal.analysis.montecarlo`) --------------------------------------

    #: the Monte Carlo variables (:data:`pkmcal.analysis.montecarlo.VARIABLES`) a run of this
    #: instrument can sweep; empty: the instrument has no Monte Carlo run
    montecarlo_variables: tuple = ()
    #: accuracy metrics of a Monte Carlo run: name -> (unit suffix, factor of that unit to SI,
    #: words)
    montecarlo_metrics: dict = {}
    #: metrics a machine may not define (NaN then, without rejecting the run)
    montecarlo_optional_metrics: frozenset = frozenset()
    #: held-out evaluation poses of a Monte Carlo run
    montecarlo_evaluation_poses: int = 100
    #: measurements of a Monte Carlo run when ``poses`` is not given
    montecarlo_poses: int = 60
    #: whether noise 0 simulates exact data (weighed as if ``NOISE_FLOOR`` noisy and judged by
    #: the residual RMS); False when some noise stays at its default anyway
    montecarlo_exact_data: bool = False
    #: words ``pkmcal montecarlo --noise`` takes for the instrument's default noise
    montecarlo_noise_words: tuple = ()

    def montecarlo_default_poses(self, machine: Machine):
        """The number of measurements of a Monte Carlo run when not given, as
        ``summary.json`` states it.

        Parameters
        ----------
        machine : Machine
            The nominal machine.

        Returns
        -------
        int or str
            :attr:`montecarlo_poses`, or the plan in words.
        """
        return self.montecarlo_poses

    def montecarlo_minimum_poses(self, settings) -> int:
        """Fewest measurements a Monte Carlo run's calibration accepts (default: 6 equations
        per pose, 12 gauges).

        Parameters
        ----------
        settings : MonteCarloSettings
            The run's settings (``machine``, ``estimate_lc``).

        Returns
        -------
        int
            The minimum.
        """
        return max(4, math.ceil(len(settings.machine.parameters) / 6))

    def check_montecarlo(self, settings, what: dict) -> None:
        """Raise :class:`InputError` for Monte Carlo settings no run of this instrument can
        use (beyond the generic checks).

        Parameters
        ----------
        settings : MonteCarloSettings
            Resolved settings.
        what : dict
            The option naming each field (``lc_error`` -> ``--lc-error``).
        """
        return None

    def montecarlo_run(self, run):
        """One Monte Carlo run: the true machine measured by the instrument, the default
        calibration, and the accuracy of the calibrated model against the truth.

        Parameters
        ----------
        run : MonteCarloRun
            The run (:class:`pkmcal.analysis.montecarlo.MonteCarloRun`): its ``settings`` and
            random generator ``rng`` (every draw comes from it, in a fixed order), and what
            the layers above the instruments provide: ``true_machine()``, ``deviations()``,
            ``weight(noise)`` (the noise the calibration assumes), ``simulate(n, noise)``
            (:func:`~pkmcal.instruments.simulate.simulate_scenario` of this instrument) and
            ``workspace_accuracy(true, calibrated, n)``.

        Returns
        -------
        result : CalibrationResult
            The calibration.
        metrics : dict
            The metrics of :attr:`montecarlo_metrics` (SI).
        """
        raise NotImplementedError(f"{self.name}: no Monte Carlo run")

    def candidates(self, machine: Machine, n: int, rng, setup=None):
        """``n`` feasible candidate poses and their setups.

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        n : int
            Number of poses.
        rng : numpy.random.Generator
            Random generator.
        setup : object, optional
            The instrument's set-up (:attr:`Setup`) of the machine file (a ballbar's
            mountings, a tracker's frame); None: the instrument's planning default.

        Returns
        -------
        P : ndarray, shape (n, 3)
            Positions, m.
        R : ndarray, shape (n, 3, 3)
            Orientations.
        group : ndarray of int, shape (n,) or None
            0-based setup of each pose (None: one).
        """
        from ..machines.reach import sample_workspace_poses

        P, R = sample_workspace_poses(machine, n, rng)
        return P, R, None

    def standard_plan(self, machine: Machine, n: int, seed: int, setup=None) -> StandardPlan:
        """The standard plan of ``n`` poses (default: the candidate sample of ``seed``).

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        n : int
            Number of poses.
        seed : int
            Seed of sampled plans.
        setup : object, optional
            The instrument's set-up (:attr:`Setup`) of the machine file (a ballbar's
            mountings, a tracker's frame); None: the instrument's planning default.

        Returns
        -------
        StandardPlan
            The plan.
        """
        P, R, group = self.candidates(machine, n, np.random.default_rng(seed), setup)
        return StandardPlan(f"{n} random planned poses around home (seed {seed})", P, R,
                            group=group)

    def planned_data(self, machine: Machine, P, R, rows, source, group=None, setup=None):
        """Noise-free measurements of the nominal machine at planned poses.

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        P : ndarray, shape (K, 3)
            Positions, m.
        R : ndarray, shape (K, 3, 3)
            Orientations.
        rows : ndarray of int, shape (K,)
            Row labels for messages.
        source : str
            Name of the plan.
        group : ndarray of int, shape (K,), optional
            0-based setup of each pose.
        setup : object, optional
            The instrument's set-up (:attr:`Setup`) of the machine file (a ballbar's
            mountings, a tracker's frame); None: the instrument's planning default.

        Returns
        -------
        object
            The instrument's data.
        """
        raise NotImplementedError

    #: the report sections a calibration with this instrument must carry, each with why (the
    #: report schema checks them: :class:`pkmcal.report.schema.CalibrationReport`)
    report_sections: dict = {}

    #: the machine-file section a calibration with this instrument writes its fitted
    #: unknowns to (None: it writes none, and nothing can be predicted for it)
    section: str | None = None
    #: which calibration writes :attr:`section`, in words
    section_words: str = ""
    #: the type of its set-up (:mod:`pkmcal.instruments.setups`: a frame, mountings, a bed),
    #: read from and written to :attr:`section`; None: it has none
    Setup: type | None = None
    #: the place of :attr:`section` among a machine file's instrument sections (file order)
    section_order: int = 0
    #: the schema of :attr:`section` for a machine whose own schema does not state it (a
    #: :mod:`pkmcal.machines.file_format` model or annotation); None: only machines whose
    #: schema states it have the section
    section_schema = None
    #: list keys of its section and what they hold, in words (machine-file messages)
    section_lists: dict = {}

    def read_setup(self, section, length_factor: float, machine: Machine):
        """Its set-up from its validated machine-file section (:attr:`section`).

        Parameters
        ----------
        section : pydantic model or list
            The section as the machine file's schema validated it (file units).
        length_factor : float
            Metres per length unit of the file.
        machine : Machine
            The machine of the file.

        Returns
        -------
        object
            An instance of :attr:`Setup` (internal units).
        """
        raise NotImplementedError

    def setup_section(self, setup, length_factor: float, machine: Machine):
        """The machine-file section of a set-up (the inverse of :meth:`read_setup`), or None
        when the machine's file holds no such section.

        Parameters
        ----------
        setup : object
            An instance of :attr:`Setup`.
        length_factor : float
            Metres per length unit of the file.
        machine : Machine
            The machine of the file.

        Returns
        -------
        dict or list or None
            Plain values in the file's units.
        """
        raise NotImplementedError

    def carried_by(self, machine: Machine, setup) -> bool:
        """True when a (calibrated) machine file carries this instrument's fitted unknowns
        (its :attr:`section`) for ``machine``.

        Parameters
        ----------
        machine : Machine
            The machine.
        setup : object or None
            This instrument's set-up (:attr:`Setup`) from the file, None without one.

        Returns
        -------
        bool
            Whether :meth:`predict` can use it.
        """
        return False

    def predict(self, machine: Machine, setup, P, R, ok, group, rows=None, source=None):
        """The measurements this instrument, with its fitted unknowns, makes at platform poses
        (:func:`~pkmcal.instruments.predict_instrument`).

        Parameters
        ----------
        machine : Machine
            The calibrated machine.
        setup : object
            This instrument's set-up (:attr:`Setup`; :meth:`carried_by`).
        P : ndarray, shape (K, 3)
            Platform positions, m (0 where the forward kinematics failed).
        R : ndarray, shape (K, 3, 3)
            Platform orientations.
        ok : ndarray of bool, shape (K,)
            Rows whose forward kinematics converged.
        group : ndarray of int, shape (K,)
            0-based target / setup of each row.
        rows : array_like of int, optional
            File line numbers, for messages.
        source : str, optional
            The readings' file, for messages.

        Returns
        -------
        values : ndarray, shape (K, m)
            The predicted measurements, SI.
        R : ndarray, shape (K, 3, 3) or None
            Predicted orientations (a marker's), else None.
        group : ndarray of int, shape (K,)
            The groups the prediction used.

        Raises
        ------
        InputError
            For a target / setup number beyond those of the machine file.
        """
        raise NotImplementedError

    #: the options of :meth:`simulate` this instrument takes beyond every instrument's, with
    #: their defaults (a value other than its default is an option given)
    simulate_options: dict = {}
    #: those options and this instrument in words, for a message refusing them elsewhere
    simulate_options_words: str = ""

    def simulate(self, machine: Machine, true: Machine, n: int, noise, rng, truth: dict, *,
                 setup=None, poses=None, mounting_error: float = MOUNTING_ERROR, **options):
        """A simulated experiment of this instrument (see
        :func:`~pkmcal.instruments.simulate.simulate_scenario`, which checks the options and
        draws the true machine first).

        Parameters
        ----------
        machine : Machine
            The nominal machine (it commands the poses).
        true : Machine
            The true machine.
        n : int
            Number of measurements.
        noise : object
            The instrument's noise model; None its default; False exact data.
        rng : numpy.random.Generator
            Random generator (poses, mounting errors, noise).
        truth : dict
            ``{"scenario": name}``, completed here.
        setup : object, optional
            The instrument's set-up (:attr:`Setup`) of the machine file: the true one's
            start (a tracker's frame, a ballbar's mountings); None: the simulations' default.
        poses : tuple, optional
            ``(P, R)`` or ``(P, R, group)``: commanded poses instead of the instrument's.
        mounting_error : float, optional
            Half-width of the uniform error of true targets, pivots and balls, m.
        **options
            The options of :attr:`simulate_options`.

        Returns
        -------
        tuple
            ``(data, true, truth)``: ``truth`` with ``poses`` (the plan in words), the
            instrument's truth, ``setup`` (the true set-up, an instance of :attr:`Setup`, for
            an instrument that has one) and ``rows``, that truth in words (``(name, text)``
            pairs).
        """
        raise NotImplementedError

    #: the ``pkmcal simulate`` options this instrument takes (beyond ``--noise``), each with
    #: where it applies in words (``--targets``: ``--scenario points (tracker)``)
    simulate_flags: dict = {}

    def simulates_grid(self, machine: Machine, targets=None) -> bool:
        """True when ``pkmcal simulate`` measures a grid of points on ``machine`` (seed 001's
        tracker on a platform that only translates) instead of :meth:`simulate`.

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        targets : int, optional
            ``--targets`` (None: not given).

        Returns
        -------
        bool
            False unless the instrument measures a grid there.
        """
        return False

    def simulate_arguments(self, machine: Machine, noise, **flags):
        """The noise model and :meth:`simulate` options of ``pkmcal simulate``'s option texts.

        Parameters
        ----------
        machine : Machine
            The nominal machine (levels are checked against its size).
        noise : str or None
            ``--noise``; None the simulation's default.
        **flags
            The other options as given (``pose_noise``, ``lc_error``, ``targets``, ``setups``,
            ``radius``, ``circles``); an instrument reads those of :attr:`simulate_flags`.

        Returns
        -------
        model : object
            The noise model (False: exact data).
        words : str
            The noise in words.
        options : dict
            Options of :meth:`simulate`.
        """
        raise NotImplementedError

    #: the name of the :mod:`pkmcal.io` function writing its data
    #: (:func:`pkmcal.io.write_measurements`)
    writer: str = "write_instrument"
    #: the columns of its measurement in a data file (without unit), one per value of a row
    data_columns: tuple = ()
    #: what ``pkmcal fk --frame instrument`` writes, in words
    prediction_words: str = ""

    def prediction_columns(self, prediction, unit: str) -> dict:
        """The columns ``pkmcal fk --frame instrument`` writes for predicted measurements.

        Parameters
        ----------
        prediction : InstrumentPrediction
            The predicted measurements (``values``, SI).
        unit : str
            The machine file's length unit.

        Returns
        -------
        dict
            Column name -> values, in ``unit`` (:attr:`data_columns` with the unit).
        """
        from ..units import LENGTH

        f = LENGTH[unit]
        return {f"{c}_{unit}": prediction.values[:, j] / f
                for j, c in enumerate(self.data_columns)}

    def calibration_summary(self, report: dict) -> list:
        """The rows of ``pkmcal calibrate``'s summary of a calibration with this instrument,
        in order: ``(name, text)`` pairs; the names of rows every summary may share, which the
        CLI fills in from the report (``"parameter set"``, ``"identifiable"`` or
        ``"identifiable, grouped"`` (one line per description of what is not identifiable),
        ``"held-out"``, ``"bed"``, ``"sections"`` (the rows of the result's typed sections,
        :meth:`~pkmcal.estimation.sections.ResultSection.summary_rows`, from the report's
        ``sections``), ``"noise levels"``, ``"residual test"`` (the residual
        verdict, added before ``"convergence"`` when the rows do not place it),
        ``"convergence"``); and ``("note", text)`` pairs, printed after the parameter
        changes.

        Parameters
        ----------
        report : dict
            The calibration report (JSON-ready).

        Returns
        -------
        list
            The rows, in order.
        """
        rows = [("measurement", f"{report['measurement']}, {report['measurements']} rows"),
                ("method", str(report["method"])), "parameter set", "identifiable"]
        res = report.get("residuals", {})
        if res.get("rms_um") is not None:
            before = (f"; before calibration {format_um(res['before_rms_um'])} "
                      f"({res['before']})" if res.get("before_rms_um") is not None else "")
            rows.append(("RMS residual", f"{format_um(res['rms_um'])} over {res.get('count')} "
                         f"rows ({res.get('of', 'measured - predicted')}){before}"))
        if report.get("noise") is not None:
            rows.append(("noise", f"{report['noise']}"))
        # the rows of the instrument's typed section (``report["sections"]``), then the rest
        return rows + ["sections", "held-out", "bed", "noise levels", "residual test",
                       "convergence"]

    def problem(self, machine: Machine, data, noise=None, setup=None, **start):
        """The calibration problem ``pkmcal calibrate`` solves by default, unsolved.

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        data : object
            The instrument's data.
        noise : object, optional
            Noise model; default :meth:`default_noise`.
        setup : object, optional
            The instrument's set-up (:attr:`Setup`) of the machine file: start values of its
            unknowns; None: the planning default.
        **start
            Start values of the instrument's unknowns (``registration``, ``frames``).

        Returns
        -------
        BlockProblem
            The problem.
        """
        raise NotImplementedError

    #: the measurement in words, as ``identifiability`` and ``select-poses`` print it
    measurement_words: str = ""
    #: the plan file's column naming each pose's group (``target``, ``setup``); None: one
    group_column: str | None = None
    #: the plan options the instrument takes (:meth:`planned_setup`)
    plan_options: tuple = ()

    def groups_carried(self, setup) -> int:
        """How many groups (targets, setups) the machine file's section of this instrument
        holds (0: none, or the instrument has no groups).

        Parameters
        ----------
        setup : object or None
            This instrument's set-up (:attr:`Setup`), None without one.

        Returns
        -------
        int
            The count.
        """
        return 0

    def check_group_column(self, setup, given: bool, source=None) -> None:
        """Refuse a data file without the :attr:`group_column` (``setup``, ``target``) for a
        machine whose file holds several groups of this instrument: its rows would be taken
        as one group, the mountings silently merged (issue 37). The one rule of every
        command that reads such a file (``calibrate``, ``fk --frame instrument``,
        ``compensate --frame instrument``).

        Parameters
        ----------
        setup : object or None
            This instrument's set-up from the command's machine file (:attr:`Setup`).
        given : bool
            The file has the column.
        source : str or os.PathLike, optional
            The data file, for the message.

        Raises
        ------
        InputError
            Naming the file, the column and the machine file's count.
        """
        n = self.groups_carried(setup)
        if given or self.group_column is None or n <= 1:
            return
        column = self.group_column
        where = f"{path_text(source)}: " if source else ""
        raise InputError(f"{where}no {column} column, but the machine file's {self.section} "
                         f"has {n} {column}s: add the column {column} (1..{n}) saying which "
                         f"{column} each row was measured with (without it every row would be "
                         f"taken as {column} 1)")

    def noise_arg(self, text, machine: Machine | None = None):
        """The noise model of ``--noise`` (None: :meth:`default_noise`; a model as it is).

        Parameters
        ----------
        text : str or float or object or None
            A level with its unit, an SI number, a noise model, or None.
        machine : Machine, optional
            Levels are checked against its size when given.

        Returns
        -------
        object
            The instrument's noise model.

        Raises
        ------
        InputError
            Naming ``--noise``, when the instrument takes no level.
        """
        if text is None:
            return self.default_noise()
        if not isinstance(text, (str, int, float)):
            return text
        raise InputError(f"--noise: {self.name} measurements take no noise level, got {text}")

    def noise_option(self, noise, pose_noise=None, machine: Machine | None = None):
        """The noise model of ``--noise`` and ``--pose-noise`` (as ``pkmcal calibrate`` takes
        them).

        Parameters
        ----------
        noise : str or float or object or None
            ``--noise`` (:meth:`noise_arg`).
        pose_noise : str or None, optional
            ``--pose-noise``: full poses alone take it.
        machine : Machine, optional
            Levels are checked against its size when given.

        Returns
        -------
        object
            The instrument's noise model.

        Raises
        ------
        InputError
            For ``pose_noise`` on an instrument that measures no pose, or a bad level.
        """
        if pose_noise is not None:
            raise InputError(f"--pose-noise applies to full-pose measurements, not {self.name}")
        return self.noise_arg(noise, machine)

    #: the readings of a row of its CSV files, by column suffix (``q1<s>..``): one set
    reading_sets: tuple[str, ...] = ("",)
    #: its value columns ``(name, quantity)`` (read by :func:`pkmcal.io.read_measurements`
    #: when no ``reader`` is named)
    value_columns: tuple = ()
    #: its values must be above 0
    positive_values: bool = False

    def from_columns(self, readings, values, rows, source):
        """Its data from the columns it declares (``reading_sets``, ``value_columns``).

        Parameters
        ----------
        readings : list of ndarray, shape (K, n_joints)
            The joint readings of each set, SI.
        values : ndarray, shape (K, m)
            The value columns, SI.
        rows : ndarray of int, shape (K,)
            The file's row numbers.
        source : str
            The file.

        Returns
        -------
        object
            The instrument's data.
        """
        raise NotImplementedError

    #: the name of the :mod:`pkmcal.io` function reading its CSV files
    #: (:func:`pkmcal.io.read_measurements`); instruments sit below io and name it
    reader: str = ""

    # -- its own calibration flow (``pkmcal calibrate`` from one file) -----------------------

    #: the options of its calibration: a frozen dataclass of
    #: :func:`~pkmcal.instruments.flow.option` fields (typed, with default, flag and help),
    #: the only options :meth:`calibrate` (or :meth:`calibration_model`) receives;
    #: ``pkmcal calibrate``'s options are built from them; None: it declares none
    Options: type | None = None
    #: the :mod:`pkmcal.io` function reading its files for :meth:`calibrate` (empty:
    #: :attr:`reader`)
    calibration_reader: str = ""

    def help_paragraphs(self) -> str:
        """Its part of ``pkmcal calibrate --help``: the columns that make a file its data,
        what it measures and the calibrated file's section it fits (from its attributes),
        then its own :attr:`calibrate_help`.

        Returns
        -------
        str
            Markdown paragraphs, blank-line separated.
        """
        # "<unit>" escaped: the help is markdown, where it would read as an HTML tag
        columns = self.columns.replace("<", "\\<").replace(">", "\\>")
        head = f"{self.name} data, {self.words}: files with {columns}"
        if self.section:
            head += f"; its set-up is fitted and written to the calibrated file's " \
                    f"`{self.section}` section"
        return "\n\n".join(t for t in (head + ".", inspect.cleandoc(self.calibrate_help))
                            if t.strip())

    def options_of(self, given):
        """Its :attr:`Options` from the options of a calibration: each field it declares read
        from ``given`` by name, its default where ``given`` has none.

        Parameters
        ----------
        given : mapping
            Option name -> value (the generic ones, ``noise`` and ``robust``, included).

        Returns
        -------
        object or None
            An :attr:`Options` instance (None: it declares no options).
        """
        if self.Options is None:
            return None
        return self.Options(**{f.name: given[f.name] for f in dataclasses.fields(self.Options)
                               if f.name in given})

    def check_options(self, options, source) -> None:
        """Raise :class:`InputError`, naming the options, for options it declares that do not
        go together (an option it does not declare, or a value out of an option's choices,
        is refused by the calibration layer before).

        Parameters
        ----------
        options : Options
            Its own options (:attr:`Options`).
        source : str or os.PathLike
            The data file, named in messages.
        """
        return None

    @property
    def has_flow(self) -> bool:
        """It brings a calibration flow of its own (:meth:`calibrate`); else the calibration
        layer's generic path fits its :meth:`calibration_model`."""
        return type(self).calibrate is not Instrument.calibrate

    def calibration_model(self, machine: Machine, data, options=None):
        """The model the calibration layer's generic path fits (:attr:`fit_model`), given its
        own options (:attr:`Options`; None when it declares none).

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        data : InstrumentData
            The data.
        options : Options, optional
            Its options.

        Returns
        -------
        NuisanceModel
            The model.
        """
        return self.fit_model(machine, data)

    def calibrate(self, machine: Machine, data, context, options):
        """Calibrate ``machine`` from this instrument's data (``pkmcal calibrate`` from one
        file): read, split, fit, and the report's sections; the calibration layer finishes it
        (:func:`~pkmcal.calibration.run.calibrate`).

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        data : path or data object
            The data (a path is read with ``context.read``).
        context : FlowContext
            What the calibration layer gives (:class:`~pkmcal.instruments.flow.FlowContext`;
            the experiment's set-ups: ``context.setups``).
        options : Options
            Its own options (:attr:`Options`), nothing else.

        Returns
        -------
        FlowResult
            The fit, its report and metadata, and the set-up it determined
            (:class:`~pkmcal.instruments.flow.FlowResult`).
        """
        raise NotImplementedError(f"{self.name}: no calibration flow of its own")

    def joint_part(self, machine: Machine, data, source, noise, read, options=None):
        """This instrument's part of a fit of several files (``pkmcal calibrate`` with several
        data files): its data, its model of the instrument's unknowns and its noise.

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        data : path or data object
            The file's data (a path is read with ``read``).
        source : str or os.PathLike
            The file, named in messages and the report.
        noise : object
            The file's ``--noise`` (text, SI number or noise model; None: the default).
        read : callable
            ``read(path, machine) -> data``: the :mod:`pkmcal.io` reader the instrument names
            (:attr:`calibration_reader`, else :attr:`reader`).
        options : Options, optional
            Its own options (:attr:`Options`; None when it declares none).

        Returns
        -------
        JointPart or None
            The part (:class:`~pkmcal.instruments.flow.JointPart`); None (the default): the
            calibration layer takes the instrument problem of the file's own calibration.
        """
        return None

    def measured_problem(self, machine: Machine, data, noise=None, source: str = "",
                         setup=None):
        """The calibration problem ``pkmcal calibrate`` solves for measured ``data``, unsolved,
        the instrument's unknowns started from the data on the machine's geometry (a fit with
        the machine held where they need one).

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        data : object
            The instrument's measurements (:meth:`read`).
        noise : object, optional
            Noise model; default :meth:`default_noise`.
        source : str, optional
            Name of the data, for messages.
        setup : object, optional
            The instrument's set-up of the machine file (:attr:`Setup`): start values.

        Returns
        -------
        BlockProblem
            The problem.
        """
        return self.problem(machine, data, noise, setup=setup)

    def planned_setup(self, machine: Machine, setup=None, **options):
        """The set-up the instrument's plans use, with the plan options of
        :attr:`plan_options` (e.g. a ballbar's planned mountings).

        Parameters
        ----------
        machine : Machine
            The nominal machine.
        setup : object, optional
            The set-up of the machine file (:attr:`Setup`), None without one.
        **options
            The instrument's plan options (None: not given).

        Returns
        -------
        object or None
            ``setup``, or the planned one.
        """
        return setup


def _space_words(machine: Machine) -> str:
    """The pose coordinates a platform moves along, in words (``x, y, rz``)."""
    return ", ".join(("x", "y", "z", "rx", "ry", "rz")[i] for i in machine.pose_space)


def _sigma_arg(text, machine, what: str, default: float, allow_zero: bool = False) -> float:
    """A standard deviation of ``--noise`` (text with a unit or an SI number; None: the
    default), m; checked against the machine's size when given. ``allow_zero``: 0 is taken
    (exact data) and returned unchecked; ``what`` names the reading in the message
    (``the encoder noise``)."""
    from ..plausibility import check_option_scale
    from ..units import parse_quantity

    if text is None:
        return default
    sigma = parse_quantity(text, "length", "--noise") if isinstance(text, str) \
        else float(text)
    if not (sigma > 0 or (allow_zero and sigma == 0)):
        raise InputError(f"--noise: must be > 0 (the standard deviation of {what}), "
                         f"got {text}")
    if sigma == 0:
        return 0.0
    if machine is not None:
        check_option_scale(sigma, machine, "--noise", "noise", str(text))
    return sigma


def _noise_model_arg(instrument, text, machine, what: str, allow_zero: bool = False):
    """The isotropic noise model of ``--noise`` for an instrument with one length reading
    (text with a unit, an SI number or a noise model; None: ``instrument.default_noise()``);
    ``allow_zero``: 0 gives exact data (False). ``what`` as :func:`_sigma_arg`."""
    from .models import IsotropicNoise

    if text is None:
        return instrument.default_noise()
    if hasattr(text, "whitening"):
        return text
    sigma = _sigma_arg(text, machine, what, None, allow_zero)
    return IsotropicNoise(sigma) if sigma else False


def _simulated_sigma(noise, default: str, machine: Machine) -> float:
    """A standard deviation of ``pkmcal simulate --noise`` (text with a unit; None:
    ``default``), m; 0 allowed (exact data), checked against the machine's size."""
    from ..plausibility import check_option_scale
    from ..units import parse_quantity

    text = default if noise is None else noise
    sigma = parse_quantity(text, "length", "--noise")
    if not sigma >= 0:
        raise InputError(f"--noise: must be >= 0 (a standard deviation), got {text}")
    check_option_scale(sigma, machine, "--noise", "noise", text)
    return sigma


def _check_groups(group, n: int, what: str, section: str, rows, source) -> None:
    """Refuse target / setup numbers beyond the ``n`` of the machine file's ``section``."""
    bad = np.flatnonzero((group < 0) | (group >= n))
    if bad.size:
        k = int(bad[0])
        where = (f"{path_text(source)}: " if source else "") + (
            f"row {int(rows[k])}, column {what}: " if rows is not None else f"{what} ")
        raise InputError(f"{where}{what} {int(group[k]) + 1}, but the machine file's "
                         f"{section} has {n} (numbered 1..{n})")


def _fk_of(machine: Machine, data, source):
    """The forward kinematics of measured readings; InputError naming the rows none
    reproduces."""
    fk = machine.fk(data.q)
    if not fk.converged.all():
        raise InputError(f"{path_text(source)}: row(s) {_rows(data.rows[~fk.converged])}: no "
                         f"platform pose of {machine.source} reproduces these readings "
                         "(outside the workspace, or a wrong unit or zero)")
    return fk
