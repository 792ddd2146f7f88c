"""Monte Carlo of simulated calibrations while one setting varies (seed 000 Figs. 5 and 6,
``pkmcal montecarlo``).

One *run* is: the true machine (nominal + deviations), simulated data of the machine's
measurement scenario, the default calibration (what ``pkmcal calibrate`` does), and the
accuracy of the calibrated model against the truth, measured so that the frames the data
cannot fix do not count. The scenario's instrument performs it
(:meth:`~pkmcal.instruments.base.Instrument.montecarlo_run`, e.g. the constraint link's
pose accuracy over the SPEC 5 workspace, the tracker's and the full poses' held-out
validation) and names its metrics, default and minimum poses and the variables it can sweep
(``montecarlo_*`` of :mod:`pkmcal.instruments.base`); this module asks it, never its name,
and provides what sits above the instruments (:class:`MonteCarloRun`: the true machine, the
simulated experiment, the pose accuracy over the workspace).

Every run gets a status (:func:`acceptance`): ``ok``; ``not converged`` (the estimator
said so); ``rejected`` (it claimed convergence, but the residuals are more than the simulated
noise explains, chi^2/dof against the chi-square distribution, so the geometry is wrong; or
the calibrated model fails at the evaluation poses); ``failed`` (an exception). Summaries
count every status and compute their statistics over the ok runs only, with the median and a
robust (MAD) spread beside the mean.

Every run is a pure function of ``(settings, seed)``: run ``r`` at value ``i`` of the swept
variable draws everything (deviations, poses, noise, evaluation poses) from
``np.random.SeedSequence(seed, spawn_key=(i, r))``, which is
``SeedSequence(seed).spawn(n_values)[i].spawn(runs)[r]``. Results are therefore bit-identical
whatever the executor: in process (``workers=1``), local processes (forked from this one
where the platform allows, so that they start computing at once; else a fork server with the
library preloaded, else spawned with one BLAS thread each), or a Dask cluster
(``scheduler=ADDRESS``).

Variables (SI internally): ``noise`` (the instrument's measurement noise std: encoder noise
of the constraint link, point noise of a tracker, leg-reading noise of full poses, ...),
``lc-error`` (the true link is ``Lc`` minus this while the calibration assumes ``Lc``),
``poses`` (number of measurements), ``tolerance`` (half-width of uniform random deviations of
the lengths; angles and gains scaled in proportion to
:attr:`~pkmcal.machines.base.Machine.RANDOM_DEVIATION`); an instrument's
``montecarlo_variables`` say which apply to it.
"""

from __future__ import annotations

import math
import os
import re
import time
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import ConvergenceError, InputError
from ..estimation.distributions import t_ppf
from ..instruments.base import Instrument
from ..instruments.setups import Setups
from ..machines.base import Machine
from ..paths import path_text
from ..plausibility import check_option_scale

#: the variables a Monte Carlo can sweep: quantity, display unit, factor of that unit to SI
VARIABLES = {
    "noise": ("length", "um", 1e-6),
    "lc-error": ("length", "um", 1e-6),
    "poses": ("count", "", 1.0),
    "tolerance": ("length", "mm", 1e-3),
}
#: statistics of each metric in a summary, over the ``ok`` runs of a value: mean, std (ddof
#: 1), 95 % confidence interval of the mean (Student t), median, robust spread (1.4826 x the
#: median absolute deviation: the std for normal data, blind to a few outliers), 5 % and 95 %
#: quantiles. NaN (empty in CSV, null in JSON) where undefined: everything with no ok run, all
#: but the mean and median with one.
STATISTICS = ("mean", "std", "ci95_low", "ci95_high", "median", "mad_std", "q05", "q95")
#: status of a run: the calibration converged and passed the acceptance test; the estimator
#: did not converge; it converged, but to residuals the noise cannot explain (a wrong
#: geometry) or to a model that fails at the evaluation poses; an exception
STATUSES = ("ok", "not converged", "rejected", "failed")
#: summary key of each status's count
STATUS_COUNTS = {"ok": "ok", "not converged": "not_converged", "rejected": "rejected",
                 "failed": "failed"}
#: acceptance test of noisy data: chi^2/dof of the whitened residuals above this quantile of
#: the chi-square distribution with dof degrees of freedom (divided by dof) ...
ACCEPTANCE_QUANTILE = 0.999
#: ... and above this (residuals sqrt(2) = 1.4 x the noise; the quantile alone tends to 1 at
#: large dof) rejects a run
ACCEPTANCE_MIN_RATIO = 2.0
#: acceptance test of exact (noise-free) data: residual RMS above this fraction of the
#: machine's characteristic length (plus a deliberate model error, ``lc_error``) rejects a run
EXACT_RESIDUAL_RATIO = 1e-9
#: scaled median absolute deviation: 1 / Phi^-1(3/4), the std of normal data
MAD_SCALE = 1.4826
#: the calibration weighs by the noise; exact data are weighed as if this noisy (m)
NOISE_FLOOR = 1e-7
#: a run whose noise levels were estimated is rejected when a level exceeds the simulated one
#: by the chi-square limit and by more than this many of its standard deviations
ACCEPTANCE_LEVEL_STD = 4.0
#: environment of worker processes: one BLAS/OpenMP thread each
SINGLE_THREAD_ENV = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS",
                     "NUMEXPR_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")
#: most runs per task (the progress and the load balance need several tasks per worker)
MAX_CHUNK = 10


def variable_name(name: str) -> str:
    """``'lc_error'`` -> ``'lc-error'``; :class:`InputError` for an unknown variable."""
    key = str(name).strip().lower().replace("_", "-")
    if key not in VARIABLES:
        raise InputError(f"--vary {name}: unknown variable; choose one of "
                         f"{', '.join(VARIABLES)}")
    return key


@dataclass(frozen=True)
class MonteCarloSettings:
    """Everything a run needs besides its seed (picklable).

    machine : the nominal machine (what the calibration starts from and assumes).
    scenario : measurement type; None = the machine's (hexaslide: constraint-link, delta:
        tracker, stewart: pose).
    poses : number of measurements; None = the scenario default (150, the 3x3x3 grid, 60).
    noise : measurement noise std (m); None = the scenario default (2 um encoder noise;
        Leica-type tracker noise; 2 um leg-reading noise with 20 um / 50 urad pose noise).
    lc_error : the true constraint link is ``Lc - lc_error`` (m); the calibration assumes Lc.
    deviations : ``'paper-table1'``, ``'random'`` (a new draw per run), ``'none'``, or an
        explicit vector (true - nominal parameters); None = the CLI default of the machine
        type (hexaslide: paper-table1, else random).
    tolerance : half-width (m) of random length deviations (angles and gains in proportion);
        implies random deviations. None = the default size.
    estimate_lc : constraint link: estimate Lc too (seed 000 Fig. 6, second curve).
    setups : the machine file's instrument set-ups (a
        :class:`~pkmcal.instruments.setups.Setups` or mapping: the simulated instrument's is
        the true one's start, the fit's start where it reads one); None = none.
    """

    machine: Machine
    scenario: str | None = None
    poses: int | None = None
    noise: float | None = None
    lc_error: float = 0.0
    deviations: str | np.ndarray | None = None
    tolerance: float | None = None
    estimate_lc: bool = False
    setups: Setups = field(default_factory=Setups)

    def __post_init__(self):
        object.__setattr__(self, "setups", Setups(self.setups))

    def resolved(self) -> MonteCarloSettings:
        """These settings with the defaults filled in and checked (:class:`InputError`)."""
        from ..instruments.scenarios import scenario_for

        scenario = scenario_for(self.machine, self.scenario)
        deviations = self.deviations
        if deviations is None:
            deviations = ("random" if self.tolerance is not None
                          else self.machine.DEFAULT_DEVIATIONS)
        out = replace(self, scenario=scenario, deviations=deviations)
        _check_settings(out)
        return out

    def with_value(self, variable: str, value) -> MonteCarloSettings:
        """These settings with ``variable`` set to ``value`` (SI)."""
        if variable == "poses":
            return replace(self, poses=int(value))
        attribute = {"noise": "noise", "lc-error": "lc_error", "tolerance": "tolerance"}
        return replace(self, **{attribute[variable]: float(value)})

    def describe(self) -> dict:
        """JSON-ready description (SI units and words)."""
        dev = self.deviations
        return {
            "machine": path_text(getattr(self.machine, "source", None) or self.machine.name),
            "kind": self.machine.kind, "scenario": self.scenario,
            "poses": self.poses if self.poses is not None else _default_poses(self),
            "noise_m": self.noise if self.noise is not None else "default",
            "lc_error_m": self.lc_error,
            "deviations": dev if isinstance(dev, str) else "given vector",
            "tolerance_m": self.tolerance, "estimate_lc": self.estimate_lc,
            "evaluation_poses": self.instrument().montecarlo_evaluation_poses,
        }

    def instrument(self) -> Instrument:
        """The instrument of :attr:`scenario` (resolved settings): it performs the runs and
        names their metrics."""
        from ..instruments.registry import instrument

        return instrument(self.scenario)


def _default_poses(settings: MonteCarloSettings):
    """The number of measurements of a run when not given (words for seed 001's grid)."""
    return settings.instrument().montecarlo_default_poses(settings.machine)


def scenarios_varying(variable: str) -> str:
    """``the constraint-link scenario``: the instruments whose runs can sweep ``variable``, in
    words."""
    from ..instruments.registry import INSTRUMENTS

    names = [i.name for i in INSTRUMENTS.values() if variable in i.montecarlo_variables]
    listed = names[0] if len(names) < 2 else f"{', '.join(names[:-1])} or {names[-1]}"
    return f"the {listed} scenario"


def _check_settings(s: MonteCarloSettings, what: dict | None = None) -> None:
    """InputError for settings no run can use; ``what`` names the option of each field."""
    what = {"noise": "--noise", "lc_error": "--lc-error", "poses": "--poses",
            "tolerance": "--tolerance", **(what or {})}
    inst = s.instrument()
    if not inst.montecarlo_variables:
        raise InputError(f"--scenario {s.scenario}: no Monte Carlo of this instrument; use "
                         f"{scenarios_varying('noise')}")
    if s.noise is not None and not (math.isfinite(s.noise) and s.noise >= 0):
        raise InputError(f"{what['noise']}: must be >= 0 (a standard deviation), got "
                         f"{s.noise:g} m")
    if not math.isfinite(s.lc_error):
        raise InputError(f"{what['lc_error']}: must be finite")
    if s.lc_error and "lc-error" not in inst.montecarlo_variables:
        raise InputError(f"{what['lc_error']}: applies to {scenarios_varying('lc-error')} "
                         f"(hexaslide), not {s.scenario} ({s.machine.kind})")
    inst.check_montecarlo(s, what)
    if s.poses is not None:
        low = inst.montecarlo_minimum_poses(s)
        if s.poses < low:
            raise InputError(f"{what['poses']}: {s.poses} measurements; a {s.scenario} "
                             f"calibration of this machine needs at least {low}")
    if s.tolerance is not None:
        if not (math.isfinite(s.tolerance) and s.tolerance >= 0):
            raise InputError(f"{what['tolerance']}: must be >= 0, got {s.tolerance:g} m")
        if not (isinstance(s.deviations, str) and s.deviations == "random"):
            raise InputError(f"{what['tolerance']}: scales random deviations; it does not "
                             f"apply with --deviations {s.deviations}")
    for name, kind in (("noise", "noise"), ("lc_error", "error"), ("tolerance", "error")):
        if getattr(s, name) is not None:
            check_option_scale(getattr(s, name), s.machine, what[name], kind)
    dev = s.deviations
    if isinstance(dev, str):
        if dev not in ("random", "none", "paper-table1"):
            raise InputError(f"--deviations {dev}: use random, paper-table1 or none")
        if dev == "paper-table1" and s.machine.paper_deviations() is None:
            raise InputError(f"--deviations paper-table1 applies to hexaslide machines (seed "
                             f"000 Table 1), not {s.machine.kind}; use random or none")
    elif np.shape(dev) != (len(s.machine.parameters),):
        raise InputError(f"deviations: expected {len(s.machine.parameters)} values, got "
                         f"{np.shape(dev)}")


# -- one run --------------------------------------------------------------------------------


def _true_machine(s: MonteCarloSettings, rng) -> Machine:
    from ..machines.deviations import deviations as _deviations

    machine = s.machine
    if isinstance(s.deviations, str):
        du = _deviations(machine, s.deviations, rng)
        if s.tolerance is not None:
            du = du * (s.tolerance / machine.RANDOM_DEVIATION[0])
    else:
        du = np.asarray(s.deviations, float)
    return machine.with_parameters(machine.u + du)


def _weight(noise: float) -> float:
    return max(noise, NOISE_FLOOR)


def _deviation_vector(s: MonteCarloSettings, rng) -> np.ndarray:
    """True minus nominal parameters of a run (drawn as :func:`_true_machine` does)."""
    return _true_machine(s, rng).u - s.machine.u


class MonteCarloRun:
    """One run as its instrument's :meth:`~pkmcal.instruments.base.Instrument.montecarlo_run`
    sees it: the settings, the run's random generator, and what the layers above the
    instruments provide (the true machine of the settings, the noise the calibration assumes,
    the simulated experiment, the pose accuracy over the workspace).

    Every draw comes from ``rng`` in the order the instrument asks: the same seed gives the
    same run.
    """

    def __init__(self, settings: MonteCarloSettings, rng: np.random.Generator):
        self.settings = settings
        self.rng = rng

    def true_machine(self) -> Machine:
        """The true machine: nominal plus the settings' deviations (drawn now)."""
        return _true_machine(self.settings, self.rng)

    def deviations(self) -> np.ndarray:
        """True minus nominal parameters (drawn now, as :meth:`true_machine` does)."""
        return _deviation_vector(self.settings, self.rng)

    @staticmethod
    def weight(noise: float) -> float:
        """The noise level the calibration assumes for simulated ``noise`` (m)."""
        return _weight(noise)

    def simulate(self, n: int | None, noise):
        """:func:`~pkmcal.instruments.simulate.simulate_scenario` of the run's instrument on
        the nominal machine, the deviations drawn first: ``(data, true, truth)``."""
        from ..instruments.simulate import simulate_scenario

        s = self.settings
        return simulate_scenario(s.machine, s.scenario, n, noise, self.rng,
                                 deviations=self.deviations(), machine_setups=s.setups)

    def workspace_accuracy(self, true: Machine, calibrated: Machine, n: int) -> dict:
        """Pose accuracy of ``calibrated`` against ``true`` at ``n`` poses of the SPEC 5
        workspace (0.1 m cube around home, +/-10 deg), gauge-aligned: position and
        orientation, mean and max (m, rad)."""
        from .accuracy import pose_accuracy, workspace_poses

        P, R = workspace_poses(true.home[0], n=n, rng=self.rng)
        acc = pose_accuracy(true, calibrated, P, R)
        return {"position_mean": acc.position_mean, "position_max": acc.position_max,
                "orientation_mean": acc.orientation_mean,
                "orientation_max": acc.orientation_max}


def run_once(settings: MonteCarloSettings, seed) -> dict:
    """One simulated calibration, judged.

    Parameters
    ----------
    settings : MonteCarloSettings
        :meth:`~MonteCarloSettings.resolved` settings.
    seed : object
        Anything :func:`numpy.random.default_rng` takes (a
        :class:`~numpy.random.SeedSequence`).

    Returns
    -------
    dict
        ``converged`` (the estimator's claim), ``status`` (one of :data:`STATUSES`; see
        :func:`acceptance`), ``iterations``, ``chi2_dof`` (chi^2/dof of the whitened
        residuals; NaN where undefined), the scenario's metrics (SI; NaN when the run
        failed), ``failure`` (empty for an ``ok`` run, else why it is not ok) and
        ``seconds``.
    """
    t0 = time.perf_counter()
    inst = settings.instrument()
    try:
        res, metrics = inst.montecarlo_run(MonteCarloRun(settings, np.random.default_rng(seed)))
        converged = bool(res.success and np.all(np.isfinite(res.x)))
        status, chi2_dof, why = acceptance(res, settings, metrics)
        row = {"converged": converged, "iterations": int(res.nit), "status": status,
               "chi2_dof": chi2_dof, **metrics, "failure": why}
    except (InputError, ConvergenceError, ValueError, np.linalg.LinAlgError) as exc:
        row = {"converged": False, "iterations": 0, "status": "failed", "chi2_dof": math.nan,
               **dict.fromkeys(inst.montecarlo_metrics, math.nan),
               "failure": " ".join(f"{type(exc).__name__}: {exc}".split())}
    row["seconds"] = time.perf_counter() - t0
    return row


def _exact_data(settings: MonteCarloSettings) -> bool:
    """Whether the simulated data carry no noise at all (the calibration then weighs them
    as if :data:`NOISE_FLOOR` noisy); the pose scenario's pose noise stays at its default."""
    return settings.instrument().montecarlo_exact_data and settings.noise == 0


def acceptance(result, settings: MonteCarloSettings,
               metrics: dict | None = None) -> tuple[str, float, str]:
    """Judge one calibration of a Monte-Carlo run.

    A run is ``ok`` when the estimator converged (``success`` and finite parameters), its
    residuals are what the simulated noise explains, and every metric is finite. Residuals:

    - noisy data (the calibration weighs by the noise the data were simulated with): the
      chi^2 of the whitened residuals per degree of freedom, ``residual_variance``, is ~1.
      Above both ``chi2.ppf(ACCEPTANCE_QUANTILE, dof) / dof`` and
      :data:`ACCEPTANCE_MIN_RATIO` the run converged to a wrong geometry: ``rejected``. A
      deliberate model error (``lc_error``, the assumed link length wrong) widens the limit
      by ``1 + (lc_error / noise)^2``, the most it can add. When the calibration estimated
      its noise levels (the default), they weigh the fit: a level above the simulated one
      by that limit (in variance) and by more than :data:`ACCEPTANCE_LEVEL_STD` of its
      standard deviations rejects the run.
    - exact data (noise 0): the residual RMS must stay below :data:`EXACT_RESIDUAL_RATIO` of
      the machine's characteristic length plus ``lc_error``.

    With ``dof <= 0`` there is no test of the residuals (``chi2_dof`` NaN).

    Parameters
    ----------
    result : CalibrationResult
        The run's calibration (``success``, ``x``, ``residuals``, ``residual_variance``,
        ``dof``, ``message``, ``nit``).
    settings : MonteCarloSettings
        The run's resolved settings (scenario, noise, lc_error, machine).
    metrics : dict, optional
        The run's accuracy metrics; a non-finite one rejects the run.

    Returns
    -------
    status : str
        ``'ok'``, ``'not converged'`` or ``'rejected'``.
    chi2_dof : float
        chi^2 / dof of the whitened residuals (NaN when ``dof <= 0``).
    reason : str
        Empty when ``ok``, else the status and why, in words.
    """
    from ..estimation.acceptance import chi2_bound

    dof = int(getattr(result, "dof", 0) or 0)
    chi2_dof = float(getattr(result, "residual_variance", math.nan))
    if dof <= 0 or not math.isfinite(chi2_dof):
        chi2_dof = math.nan
    if not (result.success and np.all(np.isfinite(result.x))):
        what = "non-finite parameters" if result.success else \
            f"{result.message or 'no convergence'}"
        return "not converged", chi2_dof, (f"not converged: {what} after {int(result.nit)} "
                                           "iterations")
    model_error = abs(float(settings.lc_error or 0.0))
    if _exact_data(settings):
        r = np.asarray(result.residuals, float).ravel()
        rms = float(np.sqrt(np.mean(r**2))) * NOISE_FLOOR if r.size else 0.0
        size = float(settings.machine.characteristic_length())
        limit = EXACT_RESIDUAL_RATIO * size + model_error
        if not rms <= limit:
            return "rejected", chi2_dof, (
                f"rejected: residual RMS {rms:.3g} m on exact (noise-free) data, above "
                f"{limit:.3g} m ({EXACT_RESIDUAL_RATIO:g} of the machine's size"
                + (" + the Lc error" if model_error else "") + "): a wrong geometry")
    elif math.isfinite(chi2_dof):
        # the chi-square bound of calibrate's own acceptance test, and at least a factor 2
        limit = max(ACCEPTANCE_MIN_RATIO, chi2_bound(dof, alpha=1.0 - ACCEPTANCE_QUANTILE))
        if model_error:
            weight = _weight(settings.noise) if settings.noise is not None else NOISE_FLOOR
            limit *= 1.0 + (model_error / weight) ** 2
        levels = getattr(result, "noise", None)
        if levels is not None and levels.estimated:
            # the levels were estimated from the residuals (the fit weighs by them, not by the
            # simulated noise): a wrong geometry shows as a level significantly above the
            # simulated one
            for name, sigma, assumed, std in zip(levels.names, levels.sigma, levels.assumed,
                                                 levels.std, strict=True):
                if (sigma**2 > limit * assumed**2 and np.isfinite(std)
                        and sigma - assumed > ACCEPTANCE_LEVEL_STD * std):
                    return "rejected", chi2_dof, (
                        f"rejected: {name} {sigma / assumed:.3g} x the noise simulated "
                        f"({sigma:.3g} +- {std:.2g}, more than {ACCEPTANCE_LEVEL_STD:g} std "
                        "above it): a wrong geometry")
        elif not chi2_dof <= limit:
            return "rejected", chi2_dof, (
                f"rejected: residuals {math.sqrt(chi2_dof):.3g} x the noise (chi2/dof "
                f"{chi2_dof:.3g} > {limit:.3g}, {dof} dof): a wrong geometry")
    optional = settings.instrument().montecarlo_optional_metrics
    bad = [name for name, v in (metrics or {}).items()
           if not np.isfinite(v) and name not in optional]
    if bad:
        return "rejected", chi2_dof, (f"rejected: {', '.join(bad)} not finite: the calibrated "
                                      "model fails at the evaluation poses")
    return "ok", chi2_dof, ""


def run_seed(seed: int, value_index: int, run: int) -> np.random.SeedSequence:
    """Seed of run ``run`` at value ``value_index``: ``SeedSequence(seed).spawn(...)[value]
    .spawn(...)[run]``, built directly."""
    return np.random.SeedSequence(seed, spawn_key=(value_index, run))


def run_chunk(settings: MonteCarloSettings, variable: str, seed: int, tasks) -> list[dict]:
    """Runs ``tasks = [(value_index, run, value), ...]`` (a task of an executor)."""
    out = []
    for i, r, value in tasks:
        row = run_once(settings.with_value(variable, value), run_seed(seed, i, r))
        out.append({"value_index": i, "run": r, **row})
    return out


# -- executors ------------------------------------------------------------------------------


@contextmanager
def single_threaded_environment():
    """Set one BLAS/OpenMP thread in the environment (inherited by processes started inside),
    and restore it afterwards."""
    saved = {k: os.environ.get(k) for k in SINGLE_THREAD_ENV}
    os.environ.update(dict.fromkeys(SINGLE_THREAD_ENV, "1"))
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _chunks(tasks: list, n_workers: int) -> list[list]:
    """Tasks in chunks sized to the study: about 4 per worker (few hand-outs, each paying a
    round trip), at most :data:`MAX_CHUNK` runs (the progress, and a short tail: the last
    chunk a worker takes is what the others may wait for)."""
    size = max(1, min(MAX_CHUNK, math.ceil(len(tasks) / (4 * max(n_workers, 1)))))
    return [tasks[k:k + size] for k in range(0, len(tasks), size)]


def _worker_context():
    """The multiprocessing context of local workers: ``fork`` where the platform has it and
    this process runs no other thread (a worker is then this process with pkmcal and numpy
    already imported: it computes at once, where a spawned one first imports them, ~1 s of
    each worker's CPU that a short study never wins back - 200 runs on 2 workers were 1.2x
    one), else ``forkserver`` with the library preloaded (imported once, in the server,
    while this process goes on), else ``spawn``. Every run is a pure function of its
    settings and seed: the results are the same whatever the context."""
    import multiprocessing
    import threading

    methods = multiprocessing.get_all_start_methods()
    if "fork" in methods and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    if "forkserver" in methods:
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload([__name__])
        return context
    return multiprocessing.get_context("spawn")      # children import numpy afresh


def _in_process(settings, variable, seed, tasks, progress):
    for task in tasks:
        rows = run_chunk(settings, variable, seed, [task])
        progress(len(rows))
        yield from rows


def _watch_parent(parent_pid: int, interval_s: float = 0.2) -> None:
    """Worker start-up: end this worker as soon as the process that started the pool is gone
    (``kill -9`` of ``pkmcal montecarlo`` must not leave workers computing); Ctrl-C is the
    parent's to handle (it cancels the pool), so the worker ignores SIGINT. A worker forked
    or spawned by that process watches its parent; one a fork server forked (its parent is
    the server, which ends with that process) watches that process by its id."""
    import signal
    import sys
    import threading
    import time

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # a forked worker has the command's handlers: terminating it must end it, not raise
    for name in ("SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_DFL)
    if sys.platform.startswith("linux"):
        try:                # immediate on Linux: the kernel signals us when the parent dies
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    direct = os.getppid() == parent_pid

    def alive() -> bool:
        if direct:
            return os.getppid() == parent_pid
        try:
            os.kill(parent_pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:
            pass
        return True

    if not alive():                     # the parent died before the lines above
        os._exit(1)

    def watch():
        while alive():
            time.sleep(interval_s)
        os._exit(1)

    threading.Thread(target=watch, name="pkmcal-parent-watch", daemon=True).start()


def _next_chunk(remaining, n_workers: int) -> list:
    """The next runs to hand out: about a quarter of each worker's share of what remains, at
    most :data:`MAX_CHUNK` (guided scheduling: large chunks while much remains, single runs at
    the end, so that no worker waits long for another's last chunk)."""
    size = max(1, min(MAX_CHUNK, math.ceil(len(remaining) / (4 * max(n_workers, 1)))))
    return [remaining.popleft() for _ in range(min(size, len(remaining)))]


def _local_processes(settings, variable, seed, tasks, workers, progress):
    """Runs on ``workers`` processes: this one and ``workers - 1`` of a pool
    (:func:`_worker_context`). This process computes from the start, while the pool starts
    and between hand-outs (it would otherwise wait idle: ``workers`` processes compute, as
    many as asked); the pool is kept two chunks deep per process."""
    from collections import deque
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    remaining = deque(tasks)
    context = _worker_context()
    with single_threaded_environment():
        pool = ProcessPoolExecutor(max_workers=workers - 1, mp_context=context,
                                   initializer=_watch_parent, initargs=(os.getpid(),))
        in_flight: set = set()
        try:
            while remaining or in_flight:
                while remaining and len(in_flight) < 2 * (workers - 1):
                    in_flight.add(pool.submit(run_chunk, settings, variable, seed,
                                              _next_chunk(remaining, workers)))
                done = {future for future in in_flight if future.done()}
                for future in done:
                    rows = future.result()
                    progress(len(rows))
                    yield from rows
                in_flight -= done
                if remaining:
                    rows = run_chunk(settings, variable, seed, _next_chunk(remaining, workers))
                    progress(len(rows))
                    yield from rows
                elif in_flight and not done:
                    wait(in_flight, return_when=FIRST_COMPLETED)
        except BaseException:
            # an error or Ctrl-C: stop the workers now instead of waiting for their chunks
            # (the executor has no public call for this)
            for process in list((getattr(pool, "_processes", None) or {}).values()):
                process.terminate()
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown(wait=True)


#: a Dask scheduler address: [protocol://]host:port
_ADDRESS = re.compile(r"^(?:[a-z][a-z0-9+.-]*://)?(?:\[[0-9a-fA-F:.]+\]|[^\s:/\[\]]+):\d+/?$")


def dask_client(address: str, timeout: float = 10.0):
    """A :class:`distributed.Client` connected to ``address``; :class:`InputError` when
    dask.distributed is not installed or the scheduler cannot be reached."""
    try:
        from distributed import Client
    except ImportError:
        raise InputError("--scheduler: Dask is not installed; install it with pip install "
                         "'pkmcal[distributed]' (dask and distributed)") from None
    if not _ADDRESS.match(str(address)):
        raise InputError(f"--scheduler {address}: expected a Dask scheduler address "
                         "HOST:PORT or PROTOCOL://HOST:PORT (e.g. tcp://127.0.0.1:8786)")
    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(f"--scheduler {address}: cannot reach the Dask scheduler "
                         f"({reason})") from None


def _dask(settings, variable, seed, tasks, address, timeout, progress):
    from distributed import as_completed

    with dask_client(address, timeout) as client:
        n = max(1, sum(client.nthreads().values()))
        futures = [client.submit(run_chunk, settings, variable, seed, chunk, pure=False)
                   for chunk in _chunks(tasks, n)]
        for future in as_completed(futures, loop=client.loop):
            rows = future.result()
            progress(len(rows))
            yield from rows


# -- the sweep ------------------------------------------------------------------------------


@dataclass
class MonteCarloResult:
    """Runs and their summary per value of the swept variable (SI units).

    rows : one dict per run, ordered by (value, run): ``value_index, run, value, converged,
        iterations, status, chi2_dof, <metrics>, failure, seconds`` (:func:`run_once`).
    summary : one dict per value (:func:`summarize`): ``value, runs``, the count of each
        status (``ok, not_converged, rejected, failed``), ``converged`` (the estimator's
        claim: ok + rejected) and, per metric, a dict of :data:`STATISTICS` over the ok runs.
    """

    settings: MonteCarloSettings
    variable: str
    values: list
    runs: int
    seed: int
    rows: list[dict]
    summary: list[dict]
    metrics: dict
    executor: str
    workers: int
    seconds: float
    extra: dict = field(default_factory=dict)

    def metric(self, name: str, ok_only: bool = False) -> np.ndarray:
        """A metric of every run.

        Parameters
        ----------
        name : str
            A key of ``metrics`` (``'position_mean'``).
        ok_only : bool, optional
            NaN for the runs that are not ``ok`` too.

        Returns
        -------
        ndarray, shape (n_values, runs)
            The metric (SI), NaN where a run failed.
        """
        out = np.full((len(self.values), self.runs), np.nan)
        for row in self.rows:
            if not ok_only or row["status"] == "ok":
                out[row["value_index"], row["run"]] = row[name]
        return out

    def mean(self, name: str) -> np.ndarray:
        """Mean of a metric over the ok runs.

        Parameters
        ----------
        name : str
            A key of ``metrics``.

        Returns
        -------
        ndarray, shape (n_values,)
            Per value, SI; NaN where no run is ok.
        """
        return np.array([s[name]["mean"] for s in self.summary])

    def not_ok(self) -> list[dict]:
        """The runs that are not ``ok``, in order.

        Returns
        -------
        list of dict
            Their rows (``status`` and ``failure`` say why).
        """
        return [row for row in self.rows if row["status"] != "ok"]


def parse_values(variable: str, values: Sequence) -> list:
    """The swept values, checked: poses whole numbers, the others finite."""
    values = list(values)
    if not values:
        raise InputError(f"--vary {variable}: give at least one value")
    if variable == "poses":
        from ..limits import MAX_MEASUREMENTS

        out = []
        for v in values:
            if not math.isfinite(float(v)) or float(v) != int(float(v)):
                raise InputError(f"--vary poses: whole numbers of measurements, got {v}")
            if not 1 <= int(float(v)) <= MAX_MEASUREMENTS:
                raise InputError(f"--vary poses: between 1 and {MAX_MEASUREMENTS} "
                                 f"measurements, got {v}")
            out.append(int(float(v)))
        return out
    out = [float(v) for v in values]
    if not all(math.isfinite(v) for v in out):
        raise InputError(f"--vary {variable}: values must be finite")
    return out


def montecarlo(settings: MonteCarloSettings, variable: str, values: Sequence, runs: int = 20,
               seed: int = 0, workers: int | None = None, scheduler: str | None = None,
               progress: Callable[[int], None] | None = None,
               scheduler_timeout: float = 10.0) -> MonteCarloResult:
    """``runs`` simulated calibrations at each value of ``variable`` (SI values).

    ``workers``: 1 runs in this process; more uses that many local processes (default: all
    cores); ``scheduler``: the address of a Dask scheduler (``tcp://host:8786``) instead.
    ``progress(n)`` is called with the number of runs just finished. Raises
    :class:`InputError` for settings or values no run can use.
    """
    variable = variable_name(variable)
    if not isinstance(runs, (int, np.integer)) or runs < 1:
        raise InputError(f"--runs: must be a whole number >= 1, got {runs}")
    if variable == "tolerance" and settings.deviations is None:
        settings = replace(settings, deviations="random")
    settings = settings.resolved()
    applies = settings.instrument().montecarlo_variables
    if variable not in applies:
        raise InputError(f"--vary {variable}: does not apply to the {settings.scenario} "
                         f"scenario ({settings.machine.kind}); it can vary "
                         f"{', '.join(applies)}")
    values = parse_values(variable, values)
    option = {"noise": "noise", "lc-error": "lc_error", "poses": "poses",
              "tolerance": "tolerance"}[variable]
    for v in values:
        _check_settings(settings.with_value(variable, v), {option: f"--vary {variable}"})
    if workers is None:
        workers = os.cpu_count() or 1
    if workers < 1:
        raise InputError(f"--workers: must be >= 1, got {workers}")
    tasks = [(i, r, v) for i, v in enumerate(values) for r in range(runs)]
    progress = progress or (lambda n: None)
    t0 = time.perf_counter()
    if scheduler:
        rows = _dask(settings, variable, seed, tasks, scheduler, scheduler_timeout, progress)
        executor = f"dask {scheduler}"
    elif workers == 1 or len(tasks) == 1:
        rows = _in_process(settings, variable, seed, tasks, progress)
        executor, workers = "in-process", 1
    else:
        workers = min(workers, len(tasks))
        rows = _local_processes(settings, variable, seed, tasks, workers, progress)
        executor = "local processes"
    rows = sorted(rows, key=lambda row: (row["value_index"], row["run"]))
    seconds = time.perf_counter() - t0
    for row in rows:
        row["value"] = values[row["value_index"]]
    metrics = settings.instrument().montecarlo_metrics
    summary = [summarize([row for row in rows if row["value_index"] == i], metrics, value)
               for i, value in enumerate(values)]
    return MonteCarloResult(settings, variable, values, int(runs), int(seed), rows, summary,
                            metrics, executor, int(workers), seconds)


def summarize(rows: list[dict], metrics, value=None) -> dict:
    """Counts of each status and statistics of each metric over the ok runs of one value.

    Runs that are not ``ok`` (not converged, rejected, failed) are counted, never averaged.
    A row without ``status`` (an older caller) is ``ok`` when ``converged`` and without
    ``failure``, ``failed`` with a failure text, else ``not converged``.

    Parameters
    ----------
    rows : list of dict
        The runs of the value (:func:`run_once` rows with their metrics).
    metrics : iterable of str
        Names of the metrics to summarize (the keys of an instrument's
        :attr:`~pkmcal.instruments.base.Instrument.montecarlo_metrics`).
    value : object, optional
        The swept value, copied into the summary.

    Returns
    -------
    dict
        ``value``, ``runs``, ``ok``, ``not_converged``, ``rejected``, ``failed``,
        ``converged`` (the estimator's claim: ok + rejected), ``seconds_mean`` and per metric
        a dict of :data:`STATISTICS`: mean, std (ddof 1), 95 % confidence interval of the mean
        (Student t), median, ``mad_std`` (:data:`MAD_SCALE` x the median absolute deviation),
        5 % and 95 % quantiles; NaN where undefined (no ok run; std, confidence interval,
        spread and quantiles of one run).
    """
    status = [_status(row) for row in rows]
    good = [row for row, st in zip(rows, status, strict=True) if st == "ok"]
    out = {"value": value, "runs": len(rows),
           **{STATUS_COUNTS[k]: status.count(k) for k in STATUSES},
           "converged": sum(st in ("ok", "rejected") for st in status),
           "seconds_mean": float(np.mean([row["seconds"] for row in rows])) if rows else
           math.nan}
    for name in metrics:
        v = np.array([row[name] for row in good], float)
        v = v[np.isfinite(v)]
        n = v.size
        st = dict.fromkeys(STATISTICS, math.nan)
        if n:
            st["mean"] = float(v.mean())
            st["median"] = float(np.median(v))
        if n > 1:
            std = float(v.std(ddof=1))
            half = float(t_ppf(0.975, n - 1) * std / math.sqrt(n))
            q05, q95 = np.quantile(v, [0.05, 0.95])
            st.update(std=std, ci95_low=st["mean"] - half, ci95_high=st["mean"] + half,
                      mad_std=MAD_SCALE * float(np.median(np.abs(v - st["median"]))),
                      q05=float(q05), q95=float(q95))
        out[name] = st
    return out


def _status(row: dict) -> str:
    if "status" in row:
        return row["status"]
    if row.get("converged"):
        return "rejected" if row.get("failure") else "ok"
    return "failed" if row.get("failure") else "not converged"


# -- outputs --------------------------------------------------------------------------------


def value_column(variable: str) -> str:
    """CSV column of the swept variable, with its display unit (``noise_um``)."""
    _, unit, _ = VARIABLES[variable]
    name = variable.replace("-", "_")
    return f"{name}_{unit}" if unit else name


def _metric_column(name: str, unit: str, stat: str | None = None) -> str:
    return "_".join(p for p in (name, stat, unit) if p)


def runs_table(result: MonteCarloResult) -> tuple[list[str], list[list]]:
    """Header and columns of ``runs.csv``: one row per run, display units in the names.

    Deterministic (no timings): the same seed gives the same file. Undefined numbers (the
    metrics of a failed run, chi^2/dof without degrees of freedom) are empty cells.

    Parameters
    ----------
    result : MonteCarloResult
        The Monte Carlo.

    Returns
    -------
    header : list of str
        ``<variable>_<unit>, value_index, run, converged, iterations, status, chi2_dof``, the
        metrics with their units, ``failure`` (why a run is not ok).
    columns : list of list
        One list per column.
    """
    _, _, f = VARIABLES[result.variable]
    rows = result.rows
    header = [value_column(result.variable), "value_index", "run", "converged", "iterations",
              "status", "chi2_dof"]
    columns = [[_display(row["value"], f, result.variable) for row in rows],
               [row["value_index"] for row in rows], [row["run"] for row in rows],
               [row["converged"] for row in rows], [row["iterations"] for row in rows],
               [row["status"] for row in rows], [_cell(row["chi2_dof"]) for row in rows]]
    for name, (unit, scale, _) in result.metrics.items():
        header.append(_metric_column(name, unit))
        columns.append([_cell(row[name], scale) for row in rows])
    header.append("failure")
    columns.append([row["failure"] for row in rows])
    return header, columns


def summary_table(result: MonteCarloResult) -> tuple[list[str], list[list]]:
    """Header and columns of ``summary.csv``: one row per value.

    Parameters
    ----------
    result : MonteCarloResult
        The Monte Carlo.

    Returns
    -------
    header : list of str
        ``<variable>_<unit>, runs, ok, not_converged, rejected, failed, converged`` and per
        metric each of :data:`STATISTICS` (``position_mean_median_um``), over the ok runs.
    columns : list of list
        One list per column; undefined statistics are empty strings (never ``nan``).
    """
    _, _, f = VARIABLES[result.variable]
    s = result.summary
    counts = ["runs", *STATUS_COUNTS.values(), "converged"]
    header = [value_column(result.variable), *counts]
    columns = [[_display(p["value"], f, result.variable) for p in s],
               *[[p[k] for p in s] for k in counts]]
    for name, (unit, scale, _) in result.metrics.items():
        for stat in STATISTICS:
            header.append(_metric_column(name, unit, stat))
            columns.append([_cell(p[name][stat], scale) for p in s])
    return header, columns


def _cell(value, scale: float = 1.0):
    """A number for a CSV cell in display units, or ``""`` when undefined."""
    value = float(value)
    return value / scale if math.isfinite(value) else ""


def _display(value, factor: float, variable: str):
    return int(value) if variable == "poses" else value / factor


def plot_montecarlo(result: MonteCarloResult, path, title: str | None = None):
    """Plot each metric against the swept variable.

    The mean over the ok runs with the 95 % confidence band of the mean (dark), the 5-95 %
    band of the runs (light) and the median (open squares); log axes where the values span a
    decade or more; the line error = variable where both are lengths in the same unit. Runs
    that are not ok are counted in the title.

    Parameters
    ----------
    result : MonteCarloResult
        The Monte Carlo.
    path : str or os.PathLike
        Output image.
    title : str, optional
        Figure title; default: scenario, machine and runs per value.

    Returns
    -------
    pathlib.Path
        The image written.
    """
    from ..report.plots import _save, plt

    names = [n for n in result.metrics if not n.endswith("_max")]
    fig, axes = plt.subplots(1, len(names), figsize=(5 * len(names), 4), squeeze=False)
    _, vunit, vf = VARIABLES[result.variable]
    x = np.array([_display(v, vf, result.variable) for v in result.values], float)
    order = np.argsort(x)
    x = x[order]
    for ax, name in zip(axes[0], names, strict=True):
        unit, scale, words = result.metrics[name]
        stat = {k: np.array([p[name][k] for p in result.summary], float)[order] / scale
                for k in STATISTICS}
        ax.fill_between(x, stat["q05"], stat["q95"], color="C0", alpha=0.15,
                        label="5-95 % of runs")
        ax.fill_between(x, stat["ci95_low"], stat["ci95_high"], color="C0", alpha=0.4,
                        label="95 % confidence of the mean")
        ax.plot(x, stat["mean"], "o-", color="C0", label="mean")
        ax.plot(x, stat["median"], "s", color="C1", mfc="none", label="median")
        if name == "position_mean" and result.variable in ("noise", "lc-error"):
            ax.plot(x, x, "k:", lw=1, label="error = variable")
        ax.set_xscale("log" if _spans_decades(x) else "linear")
        band = np.concatenate([stat["q05"], stat["q95"], stat["mean"], stat["median"]])
        ax.set_yscale("log" if _spans_decades(band) else "linear")
        ax.set_xlabel(f"{result.variable}" + (f" [{vunit}]" if vunit else ""))
        ax.set_ylabel(f"{words}" + (f" [{unit}]" if unit else ""), fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    bad = len(result.not_ok())
    fig.suptitle(title or f"Monte Carlo: {result.settings.scenario} calibration of "
                 f"{result.settings.describe()['machine']}, {result.runs} runs per value"
                 + (f"\n{bad} of {len(result.rows)} runs not ok (not converged, rejected or "
                    "failed): counted, left out of the statistics" if bad else ""),
                 fontsize=10 if len(names) < 2 else None)
    fig.tight_layout()
    return _save(fig, path)


def _spans_decades(v) -> bool:
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    return bool(v.size and v.min() > 0 and v.max() / v.min() >= 10)
