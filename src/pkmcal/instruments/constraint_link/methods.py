"""Self-calibration with a constraint link (seed 000, SPEC 2.1): three methods
(:func:`calibrate_constraint_link`).

``ml`` (default)
    Maximum likelihood, implicit loop: unknowns = geometry + one pose per measurement on the
    sphere ``|P| = Lc`` (2 tangent + 3 rotation coordinates); residuals = all six readings
    divided by their noise. Solved by :func:`~pkmcal.estimation.estimator.levenberg_marquardt`
    with the per-pose unknowns eliminated (Schur complement). Treats every encoder as noisy.
``ik``
    The paper's inverse-kinematics method (3.4.1): the five active readings and the link fix
    the pose, the residual is the passive reading minus its inverse kinematics. Needs the
    ``passive`` column and the exact ``Lc``. By default all chains are solved jointly, with the
    active readings as (heavily weighted) equations of the implicit loop
    (:class:`ConstraintLinkIK`); ``per_chain=True`` runs the paper's algorithm literally
    (:class:`ConstraintLinkIKExplicit`: forward kinematics of the five active readings, chain
    by chain, only that chain's 9 parameters, in sweeps).
``fk``
    The paper's forward-kinematics method (3.4.2): the pose follows from all six readings, the
    residual is ``|P| - Lc`` with ``Lc`` estimated.
"""

from __future__ import annotations

import math

import numpy as np

from ...errors import ConvergenceError, InputError
from ...estimation.acceptance import (
    ResidualTest,
    chi2_bound,
    residual_test,
)
from ...estimation.estimator import (
    MAX_STD,
    CalibrationResult,
    levenberg_marquardt,
    require_redundancy,
)
from ...estimation.variance import fit
from ...identifiability import (
    CONSTRAINT_LINK_GAUGES,
    gauge_groups,
    name_null_space,
    name_weak_directions,
)
from ...machines.base import Machine
from ...parameters import ParameterSet
from ...paths import path_text
from .data import ConstraintLinkData
from .problems import (
    METHODS,
    PROBLEMS,
    ConstraintLinkIKExplicit,
    ConstraintLinkML,
    SphereState,
    _ImplicitPoseProblem,
)
from .section import ConstraintLinkSection
from .start import _rows_text, continuation_solve


def calibrate_constraint_link(machine: Machine, data: ConstraintLinkData, method: str = "ml",
                              sigma_m=1e-6, estimate_link_length: bool | None = None,
                              per_chain: bool = False, max_sweeps: int = 200, rtol: float = 1e-7,
                              estimate_noise=True, robust: bool = False,
                              **options) -> CalibrationResult:
    """Calibrate ``machine`` from constraint-link data.

    Parameters
    ----------
    machine : Machine
        Start geometry (a Hexa Slide with ``constraint_link_length``); not modified.
    data : ConstraintLinkData
        Readings taken with the link mounted.
    method : {'ml', 'ik', 'fk'}, optional
        Maximum likelihood, the paper's inverse- or forward-kinematics method (see the module
        docstring).
    sigma_m : float or array_like, optional
        Encoder noise standard deviation(s), m (scalar or per actuator).
    estimate_link_length : bool, optional
        Estimate ``Lc`` too (default: only for ``'fk'``).
    per_chain : bool, optional
        ``'ik'`` only: the paper's chain-by-chain sweeps.
    max_sweeps : int, optional
        ``per_chain`` only: maximum number of sweeps over the chains.
    rtol : float, optional
        Rank tolerance of :func:`levenberg_marquardt`.
    estimate_noise : bool, optional
        ``'ml'``: estimate the encoder noise from the residuals (``sigma_m`` its prior;
        :func:`~pkmcal.estimation.variance.fit`); False holds ``sigma_m``.
    robust : bool, optional
        ``'ml'``: leave out the rows the outlier test names.
    **options
        Passed to :func:`levenberg_marquardt` (``xtol``, ``ftol``, ``max_iter``, ``max_std``;
        without ``per_chain``, ``max_std`` defaults to :data:`MAX_STD`).

    Returns
    -------
    CalibrationResult
        With ``method``; ``machine``, the calibrated machine (home kept from ``machine``
        when reachable, else the nearest measured pose); ``unidentifiable``, the named null
        and weak directions; its :class:`ConstraintLinkSection`: ``link_length``,
        ``dropped_rows``, file rows
        left out (the paper's methods: no pose for the start geometry; ``'ml'``: no pose found
        that explains them with the calibrated geometry); with ``per_chain`` also ``sweeps``.
        ``'ml'`` also: ``start``, the :class:`StartReport` (plain fit
        or the fallback of :func:`continuation_solve` when the plain
        fit fails the residual test); ``problem``, the problem solved (its data: the rows
        kept); ``warnings``, sentences for the user (rows left out or retried, and why).

    Raises
    ------
    InputError
        When ``method`` is unknown, ``per_chain`` is used without ``'ik'``, the data give fewer
        equations than identifiable parameters, or the problem cannot be set up (see the
        problem classes).
    """
    if method not in PROBLEMS:
        raise InputError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if per_chain and method != "ik":
        raise InputError("per_chain applies to the inverse-kinematics method (method='ik')")
    cls = PROBLEMS[method]
    if estimate_link_length is None:
        estimate_link_length = cls.estimates_link_length
    paper = method != "ml" and not per_chain        # the paper's methods start from ml's
    if paper:
        cls.check_data(data)
    problem = (ConstraintLinkML if paper else cls)(machine, data, sigma_m,
                                                   estimate_link_length=estimate_link_length)
    n_id = int(problem.parameters.free.sum()) - 6
    distinct, repeats = data.distinct()
    n_rows = distinct * (machine.n_joints - 5 if method == "ml" else 1)
    require_redundancy(data.source, f"{len(data)} rows, {distinct} distinct ({repeats})"
                       if repeats else f"{len(data)} measurements", n_rows, n_id,
                       "measure more poses spread over the sphere with varied orientation")
    start = None
    if per_chain:
        result = _per_chain_sweeps(problem, max_sweeps, rtol, **options)
    elif method == "ml":
        # far starts (large build errors, other geometries): continuation, pose multi-starts,
        # rows without a start pose retried and named (calibration.start). Not for 'ik': its
        # residuals (active readings taken as exact) fail the chi-square test by design
        lm_options = {"max_std": MAX_STD, **options}
        every_row = problem
        result, problem, start = continuation_solve(
            problem, lambda p, state: levenberg_marquardt(p, rtol=rtol, state=state,
                                                          **lm_options),
            noise_known=estimate_noise is False)
        state, left_out = result.state, None
        if start.kept is not None and not start.kept.all():
            # rows the start strategy left out are the outlier rounds' first candidates, not
            # their verdict: posed with the geometry found, brought back when it explains them
            problem, left_out = every_row, ~start.kept
            P, R = np.zeros((len(data), 3)), np.tile(np.eye(3), (len(data), 1, 1))
            P[start.kept], R[start.kept] = state.P, state.R
            P[left_out], R[left_out] = start.left_out_poses
            state = SphereState(state.u.copy(), P, R)
        # the encoder noise from the residuals, rows the noise cannot explain named (or left
        # out with robust): from the solution the start strategy found (its fit is the plain
        # refit's, when that fit ended there: it is not made again)
        result = fit(problem, estimate_noise, robust=robust, rtol=rtol, state=state,
                     left_out=left_out, fitted=result if left_out is None else None,
                     **lm_options)
        if left_out is not None:
            start.readmit(~result.outliers.kept, data.rows)
    else:
        result, problem, start = _paper_method(cls, problem, method, rtol,
                                               {"max_std": MAX_STD, **options})
    _refuse_degenerate(data, result, n_id, repeats)
    um, Lc = problem.split(result.x)
    calibrated = machine.with_parameters(um)
    calibrated.constraint_link_length = float(Lc)
    # keep the user's working pose as home (the FK start) when the calibrated machine
    # reaches it; a measured pose may lie at the edge of the workspace
    calibrated.home = machine.home
    if not np.all(np.isfinite(calibrated.ik(*machine.home))) and result.state is not None:
        i = int(np.argmin(np.linalg.norm(result.state.P - machine.home[0], axis=-1)))
        calibrated.home = (result.state.P[i], result.state.R[i])
    groups = gauge_groups(machine, um, CONSTRAINT_LINK_GAUGES, result.scales,
                          len(problem.parameters))
    section = ConstraintLinkSection.of(result)
    section.dropped_rows = getattr(problem, "dropped_rows", np.array([], int))
    if start is not None:
        section.dropped_rows = start.dropped_rows
        section.start, section.warnings = start, list(start.warnings)
        result.problem = problem
    names = list(result.parameters.names)
    k = names.index("link.length") if "link.length" in names else None
    section.link_length, section.assumed = float(Lc), float(data.link_length)
    section.estimated = k is not None and not bool(result.parameters.fixed[k])
    section.std = float(result.std[k]) if section.estimated else None
    result.method, result.machine = method, calibrated
    result.unidentifiable = (name_null_space(result.null_space, problem.parameters, groups)
                             + name_weak_directions(result, problem.parameters))
    return result


#: where the paper's methods start (the report's ``start``, the console's ``start`` row)
PAPER_METHOD_START = ("the maximum-likelihood estimate (seed 000's methods converge only from "
                      "a start close to the machine; the ml method's global start finds one "
                      "on any geometry)")


def _paper_method(cls, ml: ConstraintLinkML, method: str, rtol: float, lm_options: dict):
    """Seed 000's inverse- or forward-kinematics method (problem class ``cls``) from the
    maximum-likelihood estimate of ``ml``: the paper's methods converge only from a start
    close to the machine, which the machine file is not on other geometries (Table 1's errors
    from a far start: no convergence, a wrong geometry or too few rows solvable); the ml
    method's global start and continuation find one on any geometry. The method's own optimum
    is then returned (with noise, its estimate, not the ml one).

    Its geometry is then tested like an ml fit: every reading noisy, the poses refitted with
    the geometry held (:func:`_paper_method_test`, ``result.residual_test``). A geometry
    the readings reject (residuals :data:`MAX_NOISE_FACTOR` times the assumed noise beyond the
    chi-square bound) is refused (:class:`~pkmcal.errors.ConvergenceError`): these methods
    estimate no noise level, so no wrong geometry is returned with success.

    Returns
    -------
    result : CalibrationResult
        The method's fit (``residual_test``; its section's ``start_from``).
    problem : ConstraintLinkIK or ConstraintLinkFK
        The problem solved (its data: the rows the ml start kept).
    start : StartReport
        The ml start's report (rows left out, strategy).
    """
    machine, data = ml.machine, ml.data
    estimate = not ml.parameters.fixed[-1]
    # the start's tests as the ml method's with the noise estimated (a typical residual within
    # MAX_NOISE_FACTOR of the assumed noise): data noisier than assumed are not a far start;
    # the method's own geometry is tested at the assumed noise below
    ml_result, ml_problem, start = continuation_solve(
        ml, lambda p, state: levenberg_marquardt(p, rtol=rtol, state=state, **lm_options),
        noise_known=False)
    state = ml_result.state
    if issubclass(cls, _ImplicitPoseProblem):
        problem = cls(machine, ml_problem.data, ml.sigma, estimate_link_length=estimate,
                      start=state)
        result = levenberg_marquardt(problem, rtol=rtol, **lm_options)
    else:
        problem = cls(machine, ml_problem.data, ml.sigma, estimate_link_length=estimate)
        result = levenberg_marquardt(problem, rtol=rtol, state=state, **lm_options)
    unsolved = np.asarray(getattr(problem, "dropped_rows", np.zeros(0, int)), int)
    if unsolved.size:       # rows the method's own pose solve fails on, even from ml's poses
        start.dropped_rows = np.union1d(start.dropped_rows, unsolved).astype(int)
        start.warnings.append(f"{unsolved.size} row(s) left out: the {method} method finds no "
                              "pose for them with the maximum-likelihood estimate's geometry: "
                              f"rows {_rows_text(unsolved)}")
    if not result.success:
        return result, problem, start
    test, ml_test = _paper_method_test(problem, result), residual_test(ml_result)
    if test.alarming:
        # the paper's methods do not estimate the noise: residuals far beyond the assumed
        # noise are a wrong geometry or a wrong assumed noise, and either way no result
        why = ("the data are noisier than assumed (give --noise) or the start geometry is "
               "far from the machine" if ml_test.alarming else
               "the maximum-likelihood estimate explains them: use --method ml")
        raise ConvergenceError(
            f"{path_text(data.source)}: "
            f"the {method} method converged to a geometry the readings reject: "
            f"residuals {test.noise_factor:.3g}x the assumed noise with every reading noisy "
            f"and the poses refitted (chi2/dof = {test.ratio:.3g}, at most {test.upper:.3g} "
            f"expected; the maximum-likelihood start: {ml_test.noise_factor:.3g}x); {why}; "
            "no file written")
    result.residual_test = test
    ConstraintLinkSection.of(result).start_from = PAPER_METHOD_START
    return result, problem, start


def _paper_method_test(problem, result) -> ResidualTest:
    """The chi-square test of a paper method's geometry in the ml model's terms: every reading
    noisy (the assumed noise), each pose refitted to its six readings on the link's sphere
    with the geometry (and link length) held. Degrees of freedom as an ml fit's: the readings
    minus 5 per pose and the identified parameters (the geometry was fitted to the same
    readings)."""
    u = np.asarray(result.x, float)
    held = ConstraintLinkML(problem.machine, problem.data, problem.sigma)
    held.parameters = held.parameters.with_values(u).with_fixed(list(held.parameters.names))
    P, R = result.state.P.copy(), result.state.R.copy()
    P *= (u[-1] / np.linalg.norm(P, axis=-1))[:, None]          # onto the sphere
    poses = levenberg_marquardt(held, state=SphereState(u.copy(), P, R))
    dof = int(poses.dof) - int(result.rank)
    chi2 = 2.0 * float(poses.cost)
    if dof <= 0 or not math.isfinite(chi2):
        return ResidualTest(chi2, dof, math.nan, math.nan, True)
    ratio, upper = chi2 / dof, chi2_bound(dof)
    return ResidualTest(chi2, dof, ratio, upper, bool(ratio <= upper))


def _refuse_degenerate(data, result, n_id: int, repeats: str) -> None:
    """Refuse poses that leave more than the named frames unidentifiable (like collinear
    tracker points): the estimate would be an arbitrary member of a family of geometries."""
    null = 0 if result.null_space is None else result.null_space.shape[1]
    free = int(result.parameters.free.sum()) if result.parameters is not None else 0
    extra = null - (free - n_id)
    if extra <= 0:
        return
    why = f" ({repeats})" if repeats else ""
    raise InputError(f"{path_text(data.source)}: "
                     f"the {len(data)} poses{why} are degenerate: {extra} "
                     f"direction(s) beyond the frames' are not identifiable (only "
                     f"{free - null} of {n_id}); measure more poses spread over the sphere with "
                     "varied orientation")


def _per_chain_sweeps(problem, max_sweeps, rtol, **options):
    """Seed 000 3.4.1 literally: for each chain, fit its 9 parameters to the rows where it was
    passive, poses from the other five; repeat sweeps until no parameter moves."""
    base = problem.parameters
    machine, data = problem.machine, problem.data
    u = base.values.copy()
    state = problem.initial_state()
    P, R = state.P, state.R
    step = np.inf
    for sweep in range(1, max_sweeps + 1):
        u_before = u.copy()
        try:
            u = _one_sweep(problem, base, u, P, R, rtol, **options)
        except (ValueError, InputError) as exc:   # a chain's rows became unsolvable
            return _failed_sweeps(problem, u_before, sweep, f"sweep {sweep} failed: {exc}")
        previous, step = step, np.max(np.abs((u - u_before) / problem.scales))
        if step < options.get("xtol", 1e-12):
            break
        if sweep >= 3 and step > previous:
            return _failed_sweeps(problem, u, sweep,
                                  f"per-chain sweeps diverge (scaled change {step:.2e} after "
                                  f"{previous:.2e}): each chain's fit absorbs the other chains' "
                                  "errors through the forward kinematics of its rows; use the "
                                  "joint methods (ml, ik)")
    full = ConstraintLinkIKExplicit(machine.with_parameters(u[:-1]), data, problem.sigma)
    full.parameters = base.with_values(u)
    final = levenberg_marquardt(full, rtol=rtol, max_iter=1)  # statistics at the solution
    final.x, final.parameters = u, base.with_values(u)
    ConstraintLinkSection.of(final).sweeps = sweep
    final.success = step < options.get("xtol", 1e-12)
    final.message = f"per-chain sweeps: {sweep}"
    return final


def _failed_sweeps(problem, u, sweep, message):
    """A result object for sweeps that cannot go on: nothing identified, reason given."""
    base = problem.parameters
    n = len(base)
    return CalibrationResult(
        x=u, parameters=base.with_values(u), cost=float("nan"), residuals=np.zeros((0, 1)),
        success=False, status=3, message=message, nit=sweep, nfev=0, rank=0,
        singular_values=np.zeros(0), null_space=np.zeros((n, 0)), scales=problem.scales,
        weak_space=np.zeros((n, 0)), weak_std=np.zeros(0),
        covariance=np.zeros((n, n)), std=np.zeros(n), residual_variance=float("nan"), dof=0,
        state=None, sections={"constraint_link": ConstraintLinkSection(sweeps=sweep)})


def _one_sweep(problem, base, u, P, R, rtol, **options):
    """One pass over the chains: each chain's 9 parameters from the rows where it was passive."""
    machine, data = problem.machine, problem.data
    for i in range(machine.n_joints):
        rows = data.passive == i
        if not rows.any():
            continue
        sub = ConstraintLinkIKExplicit(machine.with_parameters(u[:-1]), data.subset(rows),
                                       problem.sigma, start=(P[rows], R[rows]))
        free = np.zeros(len(base), bool)
        free[base.indices(f"chain{i + 1}")] = True
        sub.parameters = ParameterSet(base.names, base.kinds, u, ~free)
        u = levenberg_marquardt(sub, rtol=rtol, **options).x.copy()
    return u
