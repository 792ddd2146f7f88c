"""Identifiability of a calibration problem before calibrating (SPEC 3, ``pkmcal
identifiability``).

The problem is evaluated at its initial state (the nominal machine and the data's poses), the
per-pose unknowns are eliminated (:func:`~pkmcal.estimation.estimator.reduce_local`) and the
free columns are scaled by ``problem.scales`` (lengths by a characteristic length, angles by
1). On that scaled reduced Jacobian: the numerical rank and the unidentifiable directions in
words (:func:`~pkmcal.identifiability.analysis.analyze`), a minimal identifiable parameter set
(QR with column pivoting) and the strongly correlated parameter pairs.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Sequence

import numpy as np

from ..errors import InputError
from ..estimation.rank import MAX_STD, RTOL
from ..paths import path_text
from .analysis import IdentifiabilityReport, NullGroup, analyze

#: parameter pairs with a larger absolute correlation are reported
CORRELATION_THRESHOLD = 0.9


def problem_null_groups(problem, state) -> list[NullGroup]:
    """The known unidentifiable directions of a calibration problem, in words.

    Problems with a ``null_groups`` method name them themselves (tracker: ``(scales)``, full
    pose: ``(state, scales)``); the constraint-link problems (parameters = the machine's +
    ``link.length``) get the two frame gauges of SPEC 2.1.

    Parameters
    ----------
    problem : BlockProblem
        The calibration problem.
    state : object
        The state to linearise at.

    Returns
    -------
    list of NullGroup
        Empty for problems of neither kind.
    """
    scales = np.asarray(problem.scales, float)
    method = getattr(problem, "null_groups", None)
    if method is not None:
        n_args = len(inspect.signature(method).parameters)
        return list(method(state, scales) if n_args >= 2 else method(scales))
    if hasattr(problem, "split") and hasattr(problem, "machine"):
        from .gauge import CONSTRAINT_LINK_GAUGES, gauge_groups

        um = problem.split(problem.global_values(state))[0]
        return gauge_groups(problem.machine, um, CONSTRAINT_LINK_GAUGES, scales,
                            len(problem.parameters))
    return []


def minimal_identifiable_set(jacobian_scaled, rank: int) -> np.ndarray:
    """Column indices to hold fixed so that the remaining columns have full rank ``rank``.

    QR with column pivoting (:func:`scipy.linalg.qr`): the first ``rank`` pivots are the best
    conditioned independent columns; the others are returned (in pivot order).

    Parameters
    ----------
    jacobian_scaled : array_like, shape (M, n)
        Scaled Jacobian.
    rank : int
        Its numerical rank.

    Returns
    -------
    ndarray of int, shape (n - rank,)
        Column indices.
    """
    from scipy.linalg import qr

    J = np.asarray(jacobian_scaled, float)
    if J.shape[1] == 0:
        return np.zeros(0, int)
    _, piv = qr(J, mode="r", pivoting=True)
    return np.asarray(piv[rank:], int)


def correlated_pairs(jacobian_scaled, rank: int, names: Sequence[str],
                     threshold: float = CORRELATION_THRESHOLD):
    """Strongly correlated parameter pairs of the identifiable part.

    ``r`` is the correlation of the pseudo-inverse covariance ``V_r S_r^-2 V_r^T``; of
    parameters with parallel columns only the first is paired.

    Parameters
    ----------
    jacobian_scaled : array_like, shape (M, n)
        Scaled Jacobian.
    rank : int
        Its numerical rank.
    names : sequence of str
        Names of the ``n`` columns.
    threshold : float, optional
        Pairs with ``|r| > threshold`` are returned.

    Returns
    -------
    list of tuple
        ``(a, b, r)``, largest ``|r|`` first.
    """
    J = np.asarray(jacobian_scaled, float)
    if rank == 0 or J.shape[1] < 2:
        return []
    _, s, Vt = np.linalg.svd(J, full_matrices=False)
    Vr = Vt[:rank].T / s[:rank]
    C = Vr @ Vr.T
    d = np.sqrt(np.clip(np.diag(C), 0, None))
    ok = d > 1e-12 * max(float(d.max()), 1e-300)
    with np.errstate(invalid="ignore", divide="ignore"):
        R = C / np.outer(d, d)
    iu, ju = np.triu_indices(len(d), 1)
    keep = ok[iu] & ok[ju] & (np.abs(R[iu, ju]) > threshold)
    # parameters with parallel columns act as one (their combination is unidentifiable and
    # named as such, e.g. a Delta leg's da + db): report pairs of the first of each class only
    norms = np.linalg.norm(J, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(J.T @ J) / np.outer(norms, norms)
    parallel = np.triu(cos > 1.0 - 1e-9, 1)
    first = ~parallel.any(axis=0)
    keep &= first[iu] & first[ju]
    pairs = [(names[i], names[j], float(np.clip(R[i, j], -1.0, 1.0)))
             for i, j in zip(iu[keep], ju[keep], strict=True)]
    pairs.sort(key=lambda p: -abs(p[2]))
    return pairs


def identifiability_report(problem, groups: Sequence[NullGroup] | Callable | None = None,
                           rtol: float = RTOL, state=None,
                           max_std: float | None = MAX_STD) -> IdentifiabilityReport:
    """What the data of ``problem`` can identify, at its initial state.

    Parameters
    ----------
    problem : BlockProblem
        ``ConstraintLinkML``, ``TrackerProblem``, ``FullPoseML``, ...
    groups : sequence of NullGroup, callable or None, optional
        Known unidentifiable directions (scaled coordinates of the full parameter vector),
        named before any parameter combination; a callable ``(problem, state) -> groups``; or
        None: :func:`problem_null_groups`.
    rtol : float, optional
        Relative tolerance on the singular values of the scaled reduced Jacobian.
    state : object, optional
        Where to evaluate (default ``problem.initial_state()``).
    max_std : float or None, optional
        Weak-direction threshold (scaled units), as the calibrations apply it
        (:data:`~pkmcal.estimation.rank.MAX_STD`): with the problem's noise model the
        counts are ``calibrate``'s (:mod:`pkmcal.estimation.rank`).

    Returns
    -------
    IdentifiabilityReport
        The free-parameter count, the rank, the weakly identifiable directions, the named
        unidentifiable directions, O1..O5, the condition number, ``hold_fixed`` (a minimal
        identifiable set by QR with column pivoting: the parameters to hold fixed) and
        ``correlated`` (pairs with ``|correlation| > 0.9``).

    Raises
    ------
    ValueError
        When ``rtol`` is outside [0, 1) or ``max_std`` is not positive.
    InputError
        When the residuals or Jacobians are not finite at the state.
    """
    from ..estimation.estimator import reduce_local
    from ..estimation.rank import rank_rule

    rank_rule(np.zeros(0), rtol, max_std)      # checks rtol and max_std (ValueError)
    state = problem.initial_state() if state is None else state
    r, Jg, Jl = problem.evaluate(state)
    source = getattr(getattr(problem, "data", None), "source", "the data")
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(Jg))
            and (Jl is None or np.all(np.isfinite(Jl)))):
        raise InputError(f"{path_text(source)}: "
                         "the model cannot reproduce some measurements with the "
                         "nominal machine (residuals not finite)")
    params = problem.parameters
    free = params.free
    scales = np.asarray(problem.scales, float)
    Jr, _, _ = reduce_local(r, Jg[..., free] * scales[free], Jl)
    if groups is None:
        groups = problem_null_groups(problem, state)
    elif callable(groups):
        groups = groups(problem, state)
    report = analyze(Jr, params, rtol=rtol, groups=list(groups), max_std=max_std)
    free_names = [n for n, f in zip(params.names, free, strict=True) if f]
    report.hold_fixed = [free_names[i]
                         for i in minimal_identifiable_set(Jr, report.identifiable)]
    report.correlated = correlated_pairs(Jr, report.identifiable, free_names)
    return report
