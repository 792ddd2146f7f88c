"""Which poses to measure: the pose-selection policy of ``pkmcal select-poses`` (SPEC 3).

:func:`select_plan` chooses ``n`` poses among candidates (the instrument's, or given ones)
by a criterion (:mod:`.design`): greedy, then exchanges, and - when the instrument's standard
plan of ``n`` poses is reachable within the joint bounds - exchanges started at the standard
plan too, its poses added to the candidates. The result is never worse than the standard plan
by the criterion nor by the predicted RMS position error when the standard plan is among the
candidates: if the search ends worse, the standard plan itself is returned (and said so). The
selected plan is compared with the standard plan and with random sets of the same size.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InputError
from ..instruments.scenarios import (
    StandardPlan,
    candidate_set,
    describe_noise,
    planned_problem,
    scenario_for,
    standard_plan,
)
from ..paths import path_text
from .assessment import WORKSPACE_POSES, prediction_summary, write_prediction_map
from .design import (
    Design,
    Selection,
    criterion_value,
    design_from_problem,
    random_values,
    select_poses,
)

__all__ = ["CRITERION_WORDS", "NO_WORSE_RTOL", "PoseSelection", "criterion_ratio",
           "reachable_standard_plan", "select_plan"]

#: relative tolerance of "no worse than the standard plan" (the search keeps a 1e-9 ridge)
NO_WORSE_RTOL = 1e-6

#: each criterion in words, and its ratio between two sets in words (``{p}``: the rank)
CRITERION_WORDS = {
    "d": ("-log det of the information", "D-efficiency: (det ratio)^(1/{p})"),
    "a": ("mean variance of the scaled parameters", "ratio of the mean parameter variances"),
    "pose": ("mean squared position error over the workspace",
             "ratio of the mean squared position errors"),
}


def criterion_ratio(criterion: str, other: float, selected: float, rank: int) -> float:
    """How many times better the selected set is than another by the criterion (> 1: better).

    Parameters
    ----------
    criterion : {'d', 'a', 'pose'}
        The criterion.
    other, selected : float
        Criterion values (:func:`~pkmcal.planning.criterion_value`) of the other and the
        selected set.
    rank : int
        Number ``p`` of identifiable directions (the dimension of the information).

    Returns
    -------
    float
        ``(det M_sel / det M_other)^(1/p)`` for ``d`` (the D-efficiency), ``other /
        selected`` for ``a`` and ``pose``; inf when only the other is singular.
    """
    if not (np.isfinite(selected) and np.isfinite(other)):
        return float("inf") if np.isfinite(selected) else float("nan")
    if criterion == "d":
        return float(np.exp((other - selected) / max(rank, 1)))
    return float(other / selected) if selected > 0 else float("nan")


def reachable_standard_plan(machine, scenario: str, n: int, seed: int = 0,
                            joint_bounds=None, bounds_words: str = "the joint limits",
                            setup=None) -> StandardPlan:
    """The instrument's standard plan of ``n`` poses, unavailable (with the reason) when the
    machine cannot reach it or it needs joint values outside ``joint_bounds``.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : str
        The instrument.
    n : int
        Number of poses.
    seed : int, optional
        Seed of sampled plans.
    joint_bounds : tuple of ndarray, optional
        ``(lo, hi)``, (n_joints,) each, internal units.
    bounds_words : str, optional
        The bounds in words, for the reason.
    setup : object, optional
        The instrument's set-up (:mod:`pkmcal.instruments.setups`: a ballbar's planned
        mountings); default the planning one.

    Returns
    -------
    StandardPlan
        The plan, or the reason there is none.
    """
    try:
        plan = standard_plan(machine, scenario, n, seed, setup)
    except InputError as exc:
        return StandardPlan(f"standard plan of {n} poses", reason=str(exc))
    if not plan.available:
        return plan
    q = machine.ik(plan.P, plan.R)
    reach = np.all(np.isfinite(q), -1)
    if not reach.all():
        return StandardPlan(plan.name, reason=f"{int((~reach).sum())} of its poses are out of "
                            "this machine's reach")
    if joint_bounds is not None and not np.all((q >= joint_bounds[0]) & (q <= joint_bounds[1])):
        return StandardPlan(plan.name, reason=f"it needs joint values outside {bounds_words}")
    return plan


@dataclass
class PoseSelection:
    """Result of :func:`select_plan`.

    Attributes
    ----------
    scenario : str
        The instrument (canonical name).
    criterion : str
        The criterion.
    n : int
        Number of poses chosen.
    P : ndarray, shape (n, 3)
        The chosen positions, m.
    R : ndarray, shape (n, 3, 3)
        Their orientations.
    q : ndarray, shape (n, n_joints)
        Their joint values, internal units.
    candidate : ndarray of int, shape (n,)
        Each chosen pose's candidate number (1-based; a candidate file's row; the standard
        plan's poses numbered after the candidates).
    group : ndarray of int, shape (n,) or None
        Each chosen pose's 0-based target / setup, None for one.
    value : float
        The criterion value of the chosen set.
    position_rms : float
        Its predicted RMS position error over the workspace, m.
    origin : str
        Where the chosen set came from, in words.
    exchanges : int
        Exchanges made after that start (0 when the standard plan is returned).
    candidates : int
        Number of candidates proper (within the joint bounds).
    outside_joint_range : int
        Candidates dropped for needing joints outside the bounds.
    joint_limits : str or None
        The joint bounds in words.
    candidates_file : str or None
        The name of given candidate poses.
    standard : StandardPlan
        The standard plan compared (``available`` false, with the reason, when not).
    standard_value, standard_position_rms : float
        Its criterion value and predicted RMS position error (m); inf when singular or not
        available.
    standard_candidates : list of int or None
        First and last candidate number of its poses, when they were further candidates.
    standard_start : bool
        The exchanges started at the standard plan too.
    returned_standard : bool
        The search ended worse than the standard plan, which is returned.
    search_start : int or None
        The start the search's best set came from (None: greedy; 0: the standard plan).
    note : str or None
        The fallback decision in words (returned standard plan, worse than a standard plan not
        among the candidates, best from the standard plan's start).
    random_sets : int
        Number of random sets of ``n`` candidates compared.
    random_position_rms : ndarray, shape (random_sets,)
        Their predicted RMS position errors, m (inf: singular).
    random_criterion : ndarray, shape (random_sets,)
        Their criterion values.
    rank : Rank
        The chosen plan's identifiable and weak directions (:func:`~pkmcal.identifiability.
        rank_rule`).
    observability : dict
        Its observability indices.
    prediction : dict
        Its predicted pose accuracy over the workspace
        (:func:`~pkmcal.planning.prediction_summary`), with the noise in words.
    seed : int
        The seed of candidates, random sets and the default workspace.
    design : Design
        Per-pose information of the candidates (standard plan included).
    information : ndarray
        The chosen set's information.
    n_machine : int
        Number of machine parameters among the problem's.
    workspace : Workspace
        Where the accuracy is predicted.
    machine : Machine
        The nominal machine.
    """

    scenario: str
    criterion: str
    n: int
    P: np.ndarray
    R: np.ndarray
    q: np.ndarray
    candidate: np.ndarray
    group: np.ndarray | None
    value: float
    position_rms: float
    origin: str
    exchanges: int
    candidates: int
    outside_joint_range: int
    joint_limits: str | None
    candidates_file: str | None
    standard: StandardPlan
    standard_value: float
    standard_position_rms: float
    standard_candidates: list | None
    standard_start: bool
    returned_standard: bool
    search_start: int | None
    note: str | None
    random_sets: int
    random_position_rms: np.ndarray
    random_criterion: np.ndarray
    rank: object
    observability: dict
    prediction: dict
    seed: int
    design: Design = field(repr=False)
    information: np.ndarray = field(repr=False)
    n_machine: int = 0
    workspace: object = field(default=None, repr=False)
    machine: object = field(default=None, repr=False)

    @property
    def standard_poses(self) -> int:
        """Number of poses of the standard plan compared (0: none)."""
        return len(self.standard)

    @property
    def random_median(self) -> float:
        """Median predicted RMS position error of the random sets, m (nan: none)."""
        r = self.random_position_rms
        return float(np.median(r)) if r.size else float("nan")

    @property
    def random_criterion_median(self) -> float:
        """Median criterion value of the random sets (nan: none)."""
        r = self.random_criterion
        return float(np.median(r)) if r.size else float("nan")

    def as_dict(self) -> dict:
        """The report's selection sections (JSON-ready but for non-finite numbers).

        Returns
        -------
        dict
            ``measurement`` ... ``seed`` of ``pkmcal select-poses --json``.
        """
        k, rms, rank = self.standard_poses, self.position_rms, self.design.rank
        std_rms = self.standard_position_rms
        finite = self.random_position_rms[np.isfinite(self.random_position_rms)]
        median = self.random_median
        return {
            "measurement": self.scenario,
            "candidates": int(self.candidates),
            "outside_joint_range": self.outside_joint_range,
            "joint_limits": self.joint_limits,
            "candidates_file": self.candidates_file,
            "selected": int(self.n),
            "criterion": self.criterion,
            "exchanges": self.exchanges,
            "identifiable": self.rank.identifiable,
            "weakly_identifiable": self.rank.weak,
            "max_std": self.rank.max_std,
            "observability": self.observability,
            "predicted_accuracy": self.prediction,
            "selected_plan": {"origin": self.origin, "criterion_value": self.value,
                              "position_rms_um": rms * 1e6},
            "standard_plan": {
                "name": self.standard.name, "available": bool(k),
                "reason": self.standard.reason or None, "poses": int(k),
                "candidates": self.standard_candidates,
                "start": self.standard_start,
                "criterion_value": self.standard_value if k else None,
                "position_rms_um": std_rms * 1e6 if k else None,
                "ratio_to_selected": std_rms / rms if k and rms > 0 else None,
                "criterion_ratio_to_selected": criterion_ratio(
                    self.criterion, self.standard_value, self.value, rank) if k else None,
                "returned": self.returned_standard, "note": self.note},
            "random_sets": {
                "sets": int(self.random_sets),
                "singular": int(self.random_position_rms.size - finite.size),
                "position_rms_median_um": median * 1e6,
                "position_rms_best_um": float(finite.min()) * 1e6 if finite.size else None,
                "ratio_median_to_selected": median / rms if rms > 0 else None,
                "criterion_median": self.random_criterion_median,
                "criterion_ratio_median_to_selected":
                    criterion_ratio(self.criterion, self.random_criterion_median, self.value,
                                    rank) if self.random_sets else None},
            "seed": self.seed,
        }

    def write_map(self, path, bounds=None):
        """Plot the predicted accuracy with the chosen poses
        (:func:`~pkmcal.planning.write_prediction_map`).

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
            path, self.machine, self.design, self.n_machine, self.information, self.P,
            f"predicted accuracy with the {self.n} selected poses ({self.prediction['noise']})",
            bounds=bounds)


def _nothing(*args, **kwargs):
    return None


def select_plan(machine, scenario: str | None, n: int, *, noise=None, candidates: int = 2000,
                poses=None, rows=None, groups=None, source: str | None = None,
                criterion: str = "d", random_sets: int = 0, seed: int = 0, workspace=None,
                joint_bounds=None, bounds_words: str = "", targets: int | None = None,
                progress=None, setup=None) -> PoseSelection:
    """Choose ``n`` poses to measure by a criterion, never worse than the standard plan.

    The candidates are ``candidates`` feasible poses of the instrument (``seed``) or the given
    ``poses``, those needing joints outside ``joint_bounds`` dropped. The instrument's standard
    plan of ``n`` poses (:func:`reachable_standard_plan`) is evaluated by the same criterion;
    without given poses its poses are further candidates and a start of the exchanges, with
    the bound of its predicted position error (:func:`~pkmcal.planning.select_poses`). If the
    search still ends worse than it (beyond :data:`NO_WORSE_RTOL`), the standard plan is
    returned. Given poses that cannot see every direction the standard plan identifies are
    compared without it.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    scenario : str or None
        The instrument; None: the machine's default.
    n : int
        Number of poses to choose.
    noise : object, optional
        The instrument's noise model (:func:`~pkmcal.planning.noise_model`); default its own.
    candidates : int, optional
        Number of random candidate poses (without ``poses``).
    poses : tuple of array_like, optional
        ``(P, R)`` given candidate positions (K, 3), m, and orientations (K, 3, 3).
    rows : array_like of int, optional
        Row numbers of ``poses`` (their file's), for messages and the chosen candidates.
    groups : array_like of int, optional
        0-based target / setup of each of ``poses``.
    source : str, optional
        The name of ``poses`` (their file).
    criterion : {'d', 'a', 'pose'}, optional
        The criterion (:func:`~pkmcal.planning.criterion_value`).
    random_sets : int, optional
        Number of random sets of ``n`` candidates to compare with.
    seed : int, optional
        Seed of the candidates, the sampled standard plans, the random sets and the default
        workspace.
    workspace : Workspace, optional
        Where the position error is predicted; default the SPEC 5 cube around home.
    joint_bounds : tuple of ndarray, optional
        ``(lo, hi)``, (n_joints,) each, internal units: candidates and the standard plan must
        stay within.
    bounds_words : str, optional
        The bounds in words, for messages.
    targets : int, optional
        Tracker targets used in turn.
    progress : callable, optional
        ``progress(advance, description=None)``, called at each of 5 steps.
    setup : object, optional
        The instrument's set-up (a ballbar's planned mountings:
        :meth:`~pkmcal.instruments.base.Instrument.planned_setup`); default the planning
        one.

    Returns
    -------
    PoseSelection
        The chosen poses, their criterion value and predicted accuracy, the standard plan
        compared and the fallback decision, the random sets.

    Raises
    ------
    InputError
        When there are fewer than ``n`` candidates, ``n`` poses cannot identify the
        directions the candidates do, or the candidates leave directions that move the
        platform unidentified.
    """
    from ..analysis.accuracy import default_workspace
    from ..analysis.prediction import pose_error_operator
    from ..identifiability import numerical_rank, observability_indices, rank_rule
    from ..instruments.registry import instrument

    step = progress or _nothing
    kind = scenario_for(machine, scenario)
    noise = instrument(kind).noise_option(None, None, machine) if noise is None else noise
    ws = default_workspace(machine, WORKSPACE_POSES, seed) if workspace is None else workspace
    given = poses is not None
    if given:
        P, R = (np.asarray(a, float) for a in poses)
        G, src = groups, str(source)
    else:
        if candidates < n:
            raise InputError(f"-n/--poses {n}: more than the {candidates} candidate poses "
                             "(--candidates); choose fewer or more candidates")
        P, R, G = candidate_set(machine, kind, candidates, rng=seed, setup=setup)
        rows, src = None, "<candidates>"
    if targets:
        G = np.arange(len(P)) % targets
    dropped = 0
    lo_hi = joint_bounds
    if lo_hi is not None:
        q = machine.ik(P, R)
        inside = np.all((q >= lo_hi[0]) & (q <= lo_hi[1]), axis=-1)   # NaN: outside
        dropped = int((~inside).sum())
        P, R = P[inside], R[inside]
        G = None if G is None else np.asarray(G)[inside]
        rows = None if rows is None else np.asarray(rows)[inside]
        if not given:
            rows = np.flatnonzero(inside) + 1
    if len(P) < n:
        raise InputError(f"{path_text(src)}: {len(P)} candidate pose(s)"
                         + (f" within {bounds_words} ({dropped} outside)" if dropped else "")
                         + f"; cannot choose {n}")
    K = len(P)
    # the instrument's standard plan of n poses: evaluated by the same criterion, and
    # (without given poses) further candidates and a start of the exchanges
    std = reachable_standard_plan(machine, kind, n, seed, lo_hi,
                                  bounds_words or "the joint limits", setup)
    k = len(std)
    P_all = np.concatenate([P, std.P]) if k else P
    R_all = np.concatenate([R, std.R]) if k else R
    std_G = std.group if not (k and targets) else np.arange(k) % targets
    G_all = G
    if k and (G is not None or std_G is not None):
        G_all = np.concatenate([np.zeros(K, int) if G is None else np.asarray(G, int),
                                np.zeros(k, int) if std_G is None else np.asarray(std_G, int)])
    rows_all = rows
    if k and rows is not None:
        first = len(rows) if given else candidates
        rows_all = np.concatenate([np.asarray(rows), first + 1 + np.arange(k)])
    step(1, "select-poses: information of each candidate")
    problem = planned_problem(machine, kind, P_all, R_all, noise, rows_all, src, group=G_all,
                              setup=setup)
    design = design_from_problem(problem)
    selectable = K + (0 if given else k)
    pool = replace(design, F=design.F[:selectable])
    if k and selectable == K:
        sv = np.linalg.svd(pool.F.reshape(-1, design.rank), compute_uv=False)
        if numerical_rank(sv) < design.rank:
            # the standard plan sees directions the given poses cannot: not comparable
            std = replace(std, P=None, R=None, reason="it identifies directions the "
                          f"poses of {path_text(source)} cannot")
            k = 0
            problem = planned_problem(machine, kind, P, R, noise, rows, src, group=G,
                                      setup=setup)
            G_all = G
            design = pool = design_from_problem(problem)
    step(1, "select-poses: pose-error operator over the workspace")
    op = pose_error_operator(machine, design, ws.P, ws.R, problem.n_machine)
    if op.unbounded:
        cause = instrument(kind).unbounded_cause(machine)
        if cause is not None:
            from ..instruments.registry import INSTRUMENTS

            other = [name for name, inst in INSTRUMENTS.items() if inst.applies(machine)
                     is None and inst.unbounded_cause(machine) is None]
            where = getattr(machine, "source", None) or "the machine"
            raise InputError(f"--scenario {kind} on {where}: {cause}; they leave "
                             f"{op.unbounded} direction(s) that move the platform "
                             "unidentified; choose a scenario that measures the platform: "
                             + ", ".join(other))
        raise InputError(f"{src}: even all {len(P_all)} candidates leave {op.unbounded} "
                         "direction(s) that move the platform unidentified; widen the "
                         "candidate set")
    per = design.F.shape[1]
    if n * per < design.rank:
        need = -(-design.rank // per)
        raise InputError(f"-n/--poses: {n} {kind} measurement(s) give at most {n * per} "
                         f"independent equations ({per} each) for the {design.rank} "
                         f"identifiable parameter directions; choose at least {need}")
    A = op.A
    std_idx = np.arange(K, K + k)
    std_value = std_ms = float("inf")
    if k:
        M_std = design.information(std_idx)
        std_value = criterion_value(M_std, criterion, A)
        std_ms = criterion_value(M_std, "pose", A)
    as_start = bool(k and selectable > K and np.isfinite(std_ms))
    step(1, f"select-poses: choosing {n} of {selectable} (greedy and the standard plan, "
         "then exchanges)")
    sel: Selection = select_poses(pool, n, criterion, A=A,
                                  starts=[std_idx] if as_start else (),
                                  bound=std_ms * (1 + 1e-9) if as_start else None)
    idx = np.asarray(sel.index)
    value = criterion_value(design.information(idx), criterion, A)
    ms = criterion_value(design.information(idx), "pose", A)
    note = None
    worse = bool(k and np.isfinite(std_ms) and (
        value > std_value + NO_WORSE_RTOL * max(abs(std_value), 1.0)
        or ms > std_ms * (1 + NO_WORSE_RTOL)))
    returned_standard = False
    if worse and as_start:
        note = (f"the search ended worse than the standard plan (criterion {value:.6g} "
                f"against {std_value:.6g}, {np.sqrt(ms) * 1e6:.3g} um against "
                f"{np.sqrt(std_ms) * 1e6:.3g} um); the standard plan is returned")
        idx, value, ms, returned_standard = std_idx, std_value, std_ms, True
    elif worse:
        note = (f"worse than the standard plan, which is not among the poses of "
                f"{path_text(source)}")
    elif as_start and sel.start is not None:
        note = "the best plan came from the exchanges started at the standard plan"
    M = design.information(idx)
    rms = float(np.sqrt(ms))
    step(1, f"select-poses: {random_sets} random sets for comparison")
    random_pool = replace(design, F=design.F[:K])       # the candidates proper
    baseline = np.sqrt(random_values(random_pool, n, random_sets, "pose", A,
                                     rng=seed + 1)) if random_sets else np.zeros(0)
    random_crit = random_values(random_pool, n, random_sets, criterion, A,
                                rng=seed + 1) if random_sets else np.zeros(0)
    step(1)
    F_plan = design.F[idx].reshape(-1, design.rank)
    sv = np.linalg.svd(F_plan, compute_uv=False)
    # the selected plan's counts by the rule calibrate applies to its data (same noise)
    plan_rank = rank_rule(sv, parameters=design.rank + design.null.shape[1])
    section = prediction_summary(machine, design, problem.n_machine, M, op=op, workspace=ws)
    section["noise"] = describe_noise(kind, noise)
    origin = ("the standard plan" if returned_standard
              else "exchanges from the standard plan" if sel.start is not None
              else "greedy, then exchanges")
    std_rows = None
    if k and selectable > K:
        std_rows = [K + 1 if rows_all is None else int(rows_all[K]),
                    K + k if rows_all is None else int(rows_all[-1])]
    label = idx + 1 if rows_all is None else np.asarray(rows_all)[idx]
    return PoseSelection(
        scenario=kind, criterion=criterion, n=int(n), P=P_all[idx], R=R_all[idx],
        q=machine.ik(P_all[idx], R_all[idx]), candidate=np.asarray(label),
        group=None if G_all is None else np.asarray(G_all)[idx], value=value,
        position_rms=rms, origin=origin, exchanges=0 if returned_standard else sel.exchanges,
        candidates=int(K), outside_joint_range=dropped,
        joint_limits=None if lo_hi is None else bounds_words,
        candidates_file=str(source) if given else None, standard=std,
        standard_value=std_value, standard_position_rms=float(np.sqrt(std_ms)),
        standard_candidates=std_rows, standard_start=as_start,
        returned_standard=returned_standard, search_start=sel.start, note=note,
        random_sets=int(random_sets), random_position_rms=baseline,
        random_criterion=random_crit, rank=plan_rank,
        # per measured row, as identifiability states it of the same plan
        observability=observability_indices(sv, F_plan.shape[0]),
        prediction=section, seed=seed, design=design, information=M,
        n_machine=problem.n_machine, workspace=ws, machine=machine)
