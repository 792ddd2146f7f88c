"""Monte Carlo of simulated calibrations while one setting varies (seed 000 Figs. 5 and 6,
``pkmcal montecarlo``).

One *run* is: the true machine (nominal + deviations), simulated data of the machine's
measurement scenario, the default calibration (what ``pkmcal calibrate`` does), and the
accuracy of the calibrated model against the truth, measured so that the frames the data
cannot fix do not count:

- ``constraint-link`` (Hexa Slide): maximum likelihood; pose accuracy over the SPEC 5
  workspace (0.1 m cube around home, +/-10 deg), gauge-aligned (best-fit base rotation about
  O, constant platform re-orientation), 300 poses: position and orientation, mean and max.
- ``tracker`` (Delta): errors jointly with the tracker pose; held-out validation as in
  ``tests/test_tracker.py``: the calibrated model with its identified registration predicts
  the tracker points at 200 readings in the grid's box that were not measured, against the
  true machine's exact points: position mean and max (a Delta platform does not rotate).
- ``pose`` (six-leg platform): maximum likelihood with both measurement frames estimated;
  held-out validation at 100 exact poses through the identified frames (position and
  orientation of the marker, mean and max), and the gauge-free parameter error
  (:func:`~pkmcal.calibration.gauge_free_error`), RMS in the estimator's scaled coordinates.

Every run is a pure function of ``(settings, seed)``: run ``r`` at value ``i`` of the swept
variable draws everything (deviations, poses, noise, evaluation poses) from
``np.random.SeedSequence(seed, spawn_key=(i, r))``, which is
``SeedSequence(seed).spawn(n_values)[i].spawn(runs)[r]``. Results are therefore bit-identical
whatever the executor: in process (``workers=1``), local processes (``spawn`` context, one
BLAS thread each), or a Dask cluster (``scheduler=ADDRESS``).

Variables (SI internally): ``noise`` (constraint-link: encoder noise std; tracker: isotropic
point noise std, default Leica-type; pose: leg-reading noise as a length), ``lc-error`` (the
true link is ``Lc`` minus this while the calibration assumes ``Lc``; constraint link only),
``poses`` (number of measurements; tracker: commanded points uniform in the box of seed 001's
3x3x3 grid instead of the grid itself), ``tolerance`` (half-width of uniform random
deviations of the lengths; angles and gains scaled in proportion to
:data:`~pkmcal.measurements.RANDOM_DEVIATION`).
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
from ..io.plausibility import check_option_scale
from ..machines.base import Machine

#: the variables a Monte Carlo can sweep: quantity, display unit, factor of that unit to SI
VARIABLES = {
    "noise": ("length", "um", 1e-6),
    "lc-error": ("length", "um", 1e-6),
    "poses": ("count", "", 1.0),
    "tolerance": ("length", "mm", 1e-3),
}
#: the variables each scenario can sweep
APPLIES = {
    "constraint-link": ("noise", "lc-error", "poses", "tolerance"),
    "tracker": ("noise", "poses", "tolerance"),
    "pose": ("noise", "poses", "tolerance"),
}
#: accuracy metrics per scenario: name -> (unit suffix, factor of that unit to SI, words)
METRICS = {
    "constraint-link": {
        "position_mean": ("um", 1e-6, "mean position error over the workspace, aligned"),
        "position_max": ("um", 1e-6, "max position error over the workspace, aligned"),
        "orientation_mean": ("urad", 1e-6, "mean orientation error, aligned"),
        "orientation_max": ("urad", 1e-6, "max orientation error, aligned"),
    },
    "tracker": {
        "position_mean": ("um", 1e-6, "mean held-out tracker-point error"),
        "position_max": ("um", 1e-6, "max held-out tracker-point error"),
    },
    "pose": {
        "position_mean": ("um", 1e-6, "mean held-out marker position error"),
        "position_max": ("um", 1e-6, "max held-out marker position error"),
        "orientation_mean": ("urad", 1e-6, "mean held-out marker orientation error"),
        "orientation_max": ("urad", 1e-6, "max held-out marker orientation error"),
        "parameter_rms": ("", 1.0, "RMS gauge-free parameter error, scaled coordinates"),
    },
}
#: statistics of each metric in a summary (over the converged runs of a value)
STATISTICS = ("mean", "std", "ci95_low", "ci95_high", "median", "q05", "q95")
#: evaluation poses per run (constraint-link workspace, tracker and pose held out)
EVALUATION_POSES = {"constraint-link": 300, "tracker": 200, "pose": 100}
#: default number of measurements (tracker: None = seed 001's 3x3x3 grid)
DEFAULT_POSES = {"constraint-link": 150, "tracker": None, "pose": 60}
#: the calibration weighs by the noise; exact data are weighed as if this noisy (m)
NOISE_FLOOR = 1e-7
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
    """

    machine: Machine
    scenario: str | None = None
    poses: int | None = None
    noise: float | None = None
    lc_error: float = 0.0
    deviations: str | np.ndarray | None = None
    tolerance: float | None = None
    estimate_lc: bool = False

    def resolved(self) -> MonteCarloSettings:
        """These settings with the defaults filled in and checked (:class:`InputError`)."""
        from ..measurements.deviations import DEFAULT_DEVIATIONS
        from ..planning import scenario_for

        kind = self.machine.kind
        scenario = scenario_for(self.machine, self.scenario)
        deviations = self.deviations
        if deviations is None:
            deviations = "random" if self.tolerance is not None else \
                DEFAULT_DEVIATIONS.get(kind, "random")
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
            "machine": str(getattr(self.machine, "source", None) or self.machine.name),
            "kind": self.machine.kind, "scenario": self.scenario,
            "poses": self.poses if self.poses is not None else (
                "3x3x3 grid" if self.scenario == "tracker" else DEFAULT_POSES.get(
                    self.scenario)),
            "noise_m": self.noise if self.noise is not None else "default",
            "lc_error_m": self.lc_error,
            "deviations": dev if isinstance(dev, str) else "given vector",
            "tolerance_m": self.tolerance, "estimate_lc": self.estimate_lc,
            "evaluation_poses": EVALUATION_POSES[self.scenario],
        }


def _minimum_poses(settings: MonteCarloSettings) -> int:
    """Fewest measurements the scenario's calibration accepts."""
    n = len(settings.machine.parameters)
    if settings.scenario == "constraint-link":
        return n - 6 + int(settings.estimate_lc)               # one equation per pose
    if settings.scenario == "tracker":
        return max(4, math.ceil((n + 6 - 12) / 3))             # 3 per point, 12 gauges
    return max(4, math.ceil(n / 6))                            # 6 per pose, 12 gauges


def _check_settings(s: MonteCarloSettings, what: dict | None = None) -> None:
    """InputError for settings no run can use; ``what`` names the option of each field."""
    what = {"noise": "--noise", "lc_error": "--lc-error", "poses": "--poses",
            "tolerance": "--tolerance", **(what or {})}
    if s.noise is not None and not (math.isfinite(s.noise) and s.noise >= 0):
        raise InputError(f"{what['noise']}: must be >= 0 (a standard deviation), got "
                         f"{s.noise:g} m")
    if not math.isfinite(s.lc_error):
        raise InputError(f"{what['lc_error']}: must be finite")
    if s.lc_error and s.scenario != "constraint-link":
        raise InputError(f"{what['lc_error']}: applies to the constraint-link scenario "
                         f"(hexaslide), not {s.scenario} ({s.machine.kind})")
    if s.scenario == "constraint-link":
        Lc = getattr(s.machine, "constraint_link_length", None)
        if Lc is None:
            raise InputError(f"{getattr(s.machine, 'source', 'the machine')}: constraint_link: "
                             "the machine has no constraint-link length; add "
                             "`constraint_link: {length: ...}` to the machine file")
        if not Lc - s.lc_error > 0:
            raise InputError(f"{what['lc_error']}: the true link length "
                             f"{(Lc - s.lc_error) * 1e3:.6g} mm is not positive")
    if s.poses is not None:
        low = _minimum_poses(s)
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
        if dev == "paper-table1" and s.machine.kind != "hexaslide":
            raise InputError(f"--deviations paper-table1 applies to hexaslide machines (seed "
                             f"000 Table 1), not {s.machine.kind}; use random or none")
    elif np.shape(dev) != (len(s.machine.parameters),):
        raise InputError(f"deviations: expected {len(s.machine.parameters)} values, got "
                         f"{np.shape(dev)}")


# -- one run --------------------------------------------------------------------------------


def _true_machine(s: MonteCarloSettings, rng) -> Machine:
    from ..measurements import RANDOM_DEVIATION
    from ..measurements.deviations import deviations as _deviations

    machine = s.machine
    if isinstance(s.deviations, str):
        du = _deviations(machine, s.deviations, rng)
        if s.tolerance is not None:
            du = du * (s.tolerance / RANDOM_DEVIATION.get(machine.kind, (2e-3, 0.02))[0])
    else:
        du = np.asarray(s.deviations, float)
    return machine.with_parameters(machine.u + du)


def _weight(noise: float) -> float:
    return max(noise, NOISE_FLOOR)


def _constraint_link_run(s: MonteCarloSettings, rng):
    from ..calibration import calibrate_constraint_link
    from ..measurements import simulate_constraint_link
    from .accuracy import pose_accuracy, workspace_poses

    nominal = s.machine
    true = _true_machine(s, rng)
    lc_true = nominal.constraint_link_length - s.lc_error
    true.constraint_link_length = lc_true
    noise = 2e-6 if s.noise is None else s.noise
    data = simulate_constraint_link(true, s.poses or DEFAULT_POSES[s.scenario], noise,
                                    link_length=lc_true, link_length_error=s.lc_error, rng=rng)
    res = calibrate_constraint_link(nominal, data, sigma_m=_weight(noise),
                                    estimate_link_length=s.estimate_lc)
    P, R = workspace_poses(true.home[0], n=EVALUATION_POSES[s.scenario], rng=rng)
    acc = pose_accuracy(true, res.extras["machine"], P, R)
    return res, {"position_mean": acc.position_mean, "position_max": acc.position_max,
                 "orientation_mean": acc.orientation_mean,
                 "orientation_max": acc.orientation_max}


def _tracker_run(s: MonteCarloSettings, rng):
    from ..calibration import calibrate_tracker, predict_tracker_points
    from ..measurements import TrackerNoise, grid_points, simulate_tracker
    from ..planning import candidate_poses, tracker_pose

    nominal = s.machine
    true = _true_machine(s, rng)
    pose = tracker_pose(nominal)
    true.base_from_tracker = pose
    if s.noise is None:
        sim_noise = fit_noise = TrackerNoise()
    else:
        sim_noise = TrackerNoise(s.noise, s.noise, 0.0) if s.noise > 0 else None
        fit_noise = TrackerNoise(_weight(s.noise), _weight(s.noise), 0.0)
    if s.poses is None:
        targets = grid_points(nominal.home[0])
    else:
        targets = candidate_poses(nominal, "tracker", s.poses, rng)[0]
    data = simulate_tracker(true, nominal, targets, pose, sim_noise, rng=rng)
    res = calibrate_tracker(nominal, data, fit_noise)
    held = candidate_poses(nominal, "tracker", EVALUATION_POSES[s.scenario], rng)[0]
    q = nominal.ik(held)
    m = predict_tracker_points(res.extras["machine"], q, res.extras["registration"])
    e = np.linalg.norm(m - predict_tracker_points(true, q, pose), axis=-1)
    ok = np.isfinite(e)
    return res, {"position_mean": float(np.mean(e[ok])) if ok.any() else math.nan,
                 "position_max": float(np.max(e[ok])) if ok.any() else math.nan}


def _pose_run(s: MonteCarloSettings, rng):
    from ..calibration import calibrate_full_pose, full_pose_errors, gauge_free_error
    from ..measurements import FullPoseNoise, simulate_full_pose
    from ..planning import measurement_frames

    nominal = s.machine
    true = _true_machine(s, rng)
    frames = measurement_frames(nominal)
    true.measurement_frames = frames
    default = FullPoseNoise()
    noise = default.reading_m if s.noise is None else s.noise
    data = simulate_full_pose(true, s.poses or DEFAULT_POSES[s.scenario], frames,
                              replace(default, reading_m=noise), rng)
    res = calibrate_full_pose(nominal, data, "ml", noise=replace(default,
                                                                 reading_m=_weight(noise)))
    held = simulate_full_pose(true, EVALUATION_POSES[s.scenario], frames, None, rng)
    err = full_pose_errors(res.extras["machine"], res.extras["frames"], held)
    ok = err.converged
    e = gauge_free_error(nominal, res, true.u, frames)

    def stat(f, v):
        return float(f(v[ok])) if ok.any() else math.nan

    return res, {"position_mean": stat(np.mean, err.position),
                 "position_max": stat(np.max, err.position),
                 "orientation_mean": stat(np.mean, err.orientation),
                 "orientation_max": stat(np.max, err.orientation),
                 "parameter_rms": float(np.sqrt(np.mean(e**2)))}


_RUNS = {"constraint-link": _constraint_link_run, "tracker": _tracker_run, "pose": _pose_run}


def run_once(settings: MonteCarloSettings, seed) -> dict:
    """One simulated calibration: ``converged``, ``iterations``, the scenario's metrics (SI),
    ``failure`` (empty, or why the run failed: its metrics are then NaN) and ``seconds``.

    ``settings`` must be :meth:`~MonteCarloSettings.resolved`; ``seed`` is anything
    :func:`numpy.random.default_rng` takes (a :class:`~numpy.random.SeedSequence`).
    """
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    try:
        res, metrics = _RUNS[settings.scenario](settings, rng)
        converged = bool(res.success and np.all(np.isfinite(res.x)))
        row = {"converged": converged, "iterations": int(res.nit), **metrics, "failure": ""}
    except (InputError, ConvergenceError, ValueError, np.linalg.LinAlgError) as exc:
        row = {"converged": False, "iterations": 0,
               **dict.fromkeys(METRICS[settings.scenario], math.nan),
               "failure": " ".join(f"{type(exc).__name__}: {exc}".split())}
    row["seconds"] = time.perf_counter() - t0
    return row


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
    size = max(1, min(MAX_CHUNK, math.ceil(len(tasks) / (4 * max(n_workers, 1)))))
    return [tasks[k:k + size] for k in range(0, len(tasks), size)]


def _in_process(settings, variable, seed, tasks, progress):
    for task in tasks:
        rows = run_chunk(settings, variable, seed, [task])
        progress(len(rows))
        yield from rows


def _watch_parent(parent_pid: int, interval_s: float = 0.2) -> None:
    """Worker start-up: end this worker as soon as the process that started it is gone
    (``kill -9`` of ``pkmcal montecarlo`` must not leave workers computing); Ctrl-C is the
    parent's to handle (it cancels the pool), so the worker ignores SIGINT."""
    import signal
    import sys
    import threading
    import time

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        try:                # immediate on Linux: the kernel signals us when the parent dies
            import ctypes

            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:      # the parent died before the line above
        os._exit(1)

    def watch():
        while os.getppid() == parent_pid:
            time.sleep(interval_s)
        os._exit(1)

    threading.Thread(target=watch, name="pkmcal-parent-watch", daemon=True).start()


def _local_processes(settings, variable, seed, tasks, workers, progress):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    context = multiprocessing.get_context("spawn")     # children import numpy afresh
    with single_threaded_environment():
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                   initializer=_watch_parent, initargs=(os.getpid(),))
        try:
            futures = [pool.submit(run_chunk, settings, variable, seed, chunk)
                       for chunk in _chunks(tasks, workers)]
            for future in as_completed(futures):
                rows = future.result()
                progress(len(rows))
                yield from rows
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
        iterations, <metrics>, failure, seconds``.
    summary : one dict per value: ``value, runs, converged, failed`` and, per metric, a dict
        of :data:`STATISTICS` over the converged runs.
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

    def metric(self, name: str) -> np.ndarray:
        """``(n_values, runs)`` array of a metric (NaN where a run failed)."""
        out = np.full((len(self.values), self.runs), np.nan)
        for row in self.rows:
            out[row["value_index"], row["run"]] = row[name]
        return out

    def mean(self, name: str) -> np.ndarray:
        """Mean of a metric over the converged runs, per value."""
        return np.array([s[name]["mean"] for s in self.summary])


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
    if variable not in APPLIES[settings.scenario]:
        raise InputError(f"--vary {variable}: does not apply to the {settings.scenario} "
                         f"scenario ({settings.machine.kind}); it can vary "
                         f"{', '.join(APPLIES[settings.scenario])}")
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
    metrics = METRICS[settings.scenario]
    summary = [summarize([row for row in rows if row["value_index"] == i], metrics, value)
               for i, value in enumerate(values)]
    return MonteCarloResult(settings, variable, values, int(runs), int(seed), rows, summary,
                            metrics, executor, int(workers), seconds)


def summarize(rows: list[dict], metrics, value=None) -> dict:
    """Statistics of each metric over the converged runs: mean, std, 95 % confidence interval
    of the mean (Student t), median, 5 % and 95 % quantiles."""
    from scipy import stats

    good = [row for row in rows if row["converged"]]
    out = {"value": value, "runs": len(rows), "converged": len(good),
           "failed": sum(bool(row["failure"]) for row in rows),
           "seconds_mean": float(np.mean([row["seconds"] for row in rows])) if rows else
           math.nan}
    for name in metrics:
        v = np.array([row[name] for row in good], float)
        v = v[np.isfinite(v)]
        n = v.size
        if n == 0:
            out[name] = dict.fromkeys(STATISTICS, math.nan)
            continue
        mean = float(v.mean())
        std = float(v.std(ddof=1)) if n > 1 else math.nan
        half = float(stats.t.ppf(0.975, n - 1) * std / math.sqrt(n)) if n > 1 else math.nan
        q05, median, q95 = np.quantile(v, [0.05, 0.5, 0.95])
        out[name] = {"mean": mean, "std": std, "ci95_low": mean - half,
                     "ci95_high": mean + half, "median": float(median), "q05": float(q05),
                     "q95": float(q95)}
    return out


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
    Deterministic (no timings): the same seed gives the same file."""
    _, _, f = VARIABLES[result.variable]
    rows = result.rows
    header = [value_column(result.variable), "value_index", "run", "converged", "iterations"]
    columns = [[_display(row["value"], f, result.variable) for row in rows],
               [row["value_index"] for row in rows], [row["run"] for row in rows],
               [row["converged"] for row in rows], [row["iterations"] for row in rows]]
    for name, (unit, scale, _) in result.metrics.items():
        header.append(_metric_column(name, unit))
        columns.append([row[name] / scale for row in rows])
    header.append("failure")
    columns.append([row["failure"] for row in rows])
    return header, columns


def summary_table(result: MonteCarloResult) -> tuple[list[str], list[list]]:
    """Header and columns of ``summary.csv``: one row per value."""
    _, _, f = VARIABLES[result.variable]
    s = result.summary
    header = [value_column(result.variable), "runs", "converged", "failed"]
    columns = [[_display(p["value"], f, result.variable) for p in s], [p["runs"] for p in s],
               [p["converged"] for p in s], [p["failed"] for p in s]]
    for name, (unit, scale, _) in result.metrics.items():
        for stat in STATISTICS:
            header.append(_metric_column(name, unit, stat))
            columns.append([p[name][stat] / scale for p in s])
    return header, columns


def _display(value, factor: float, variable: str):
    return int(value) if variable == "poses" else value / factor


def plot_montecarlo(result: MonteCarloResult, path, title: str | None = None):
    """Mean of each metric against the swept variable with the 95 % confidence band of the
    mean (dark) and the 5-95 % band of the runs (light); log axes where the values span a
    decade or more; the line error = variable where both are lengths in the same unit."""
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
        if name == "position_mean" and result.variable in ("noise", "lc-error"):
            ax.plot(x, x, "k:", lw=1, label="error = variable")
        ax.set_xscale("log" if _spans_decades(x) else "linear")
        band = np.concatenate([stat["q05"], stat["q95"], stat["mean"]])
        ax.set_yscale("log" if _spans_decades(band) else "linear")
        ax.set_xlabel(f"{result.variable}" + (f" [{vunit}]" if vunit else ""))
        ax.set_ylabel(f"{words}" + (f" [{unit}]" if unit else ""), fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(title or f"Monte Carlo: {result.settings.scenario} calibration of "
                 f"{result.settings.describe()['machine']}, {result.runs} runs per value")
    fig.tight_layout()
    return _save(fig, path)


def _spans_decades(v) -> bool:
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    return bool(v.size and v.min() > 0 and v.max() / v.min() >= 10)
