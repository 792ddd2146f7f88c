"""Optimal measurement design: which poses to measure (SPEC 3, ``pkmcal select-poses``).

Each measurement k adds the information ``F_k^T F_k`` on the global parameters, where ``F_k``
are its reduced rows: the whitened, column-scaled identification Jacobian with the pose's own
unknowns eliminated (:func:`~pkmcal.estimation.estimator.reduce_local`; a constraint-link pose
gives 6 readings - 5 pose unknowns = 1 row, a tracker point 3 rows). The information of a set
S is ``M(S) = sum_k F_k^T F_k``; its inverse is the Cramer-Rao bound of the scaled parameters
(identifiable part). Everything is expressed in an orthonormal basis ``V`` of the directions
the whole candidate set identifies, so that gauges (rotating the base about O, ...) never
enter the criteria.

Criteria (smaller is better, as returned by :func:`criterion_value`):

- ``d``: ``-log det M`` (D-optimality; maximises observability index O1),
- ``a``: ``trace M^-1`` (A-optimality: mean variance of the scaled parameters),
- ``pose``: ``trace(A M^-1)``, the mean predicted squared pose error over a workspace
  (I-optimality; ``A`` from :func:`pkmcal.analysis.prediction.pose_error_operator`).

Selection (:func:`select_poses`) is greedy from a tiny ridge, then exchanges (remove the
member that costs least, add the candidate that gains most; kept when the criterion improves)
until no exchange improves it - the DETMAX/Fedorov family, with rank-r updates evaluated for
all candidates at once. Further starts (the instrument's standard plan, :mod:`.scenarios`) are
improved the same way and the best result is kept, so that the choice is never worse than a
start; a bound on the predicted position error keeps it no worse than the standard plan by
that figure either.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError

CRITERIA = ("d", "a", "pose")


@dataclass
class Design:
    """Per-candidate information on the identifiable subspace of a candidate set.

    Attributes
    ----------
    F : ndarray, shape (K, r, p)
        Reduced rows of each candidate in the basis ``V``.
    V : ndarray, shape (n_free, p)
        Orthonormal basis (scaled coordinates of the free parameters) of the directions the
        whole candidate set identifies.
    null : ndarray, shape (n_free, z)
        The directions it does not identify (scaled coordinates).
    free : ndarray of bool, shape (n,)
        Mask of the free problem parameters.
    scales : ndarray, shape (n,)
        Their column scales.
    """

    F: np.ndarray
    V: np.ndarray
    null: np.ndarray
    free: np.ndarray
    scales: np.ndarray

    @property
    def rank(self) -> int:
        """Dimension ``p`` of the identifiable subspace."""
        return self.V.shape[1]

    def __len__(self) -> int:
        return len(self.F)

    def information(self, idx=None) -> np.ndarray:
        """``M(S)`` of a set of candidates: ``sum_k F_k^T F_k``.

        Parameters
        ----------
        idx : array_like of int, optional
            Candidate indices; all candidates when None.

        Returns
        -------
        ndarray, shape (p, p)
            The information matrix.
        """
        F = self.F if idx is None else self.F[np.asarray(idx)]
        return np.einsum("kri,krj->ij", F, F)


def design_from_problem(problem, rtol: float | None = None) -> Design:
    """The :class:`Design` of a calibration problem's measurements, at its initial state.

    Parameters
    ----------
    problem : BlockProblem
        A calibration problem whose measurements are the candidates.
    rtol : float, optional
        Singular values at or below ``rtol`` times the largest count as unidentified; default
        :data:`~pkmcal.estimation.rank.RTOL`, the one rank rule of ``calibrate`` and
        ``identifiability`` (:func:`~pkmcal.estimation.rank.numerical_rank`).

    Returns
    -------
    Design
        One candidate per measurement.

    Raises
    ------
    InputError
        When the residuals or the Jacobian are not finite at the initial state.
    """
    from ..estimation.estimator import reduce_local
    from ..estimation.rank import RTOL, numerical_rank
    from ..identifiability.analysis import right_singular

    state = problem.initial_state()
    r, Jg, Jl = problem.evaluate(state)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(Jg))):
        raise InputError("the nominal machine cannot reproduce some planned measurements")
    free = np.asarray(problem.parameters.free, bool)
    scales = np.asarray(problem.scales, float)
    Jr, _, _ = reduce_local(r, Jg[..., free] * scales[free], Jl)
    K = r.shape[0]
    s, Vt = right_singular(Jr)
    rank = numerical_rank(s, RTOL if rtol is None else rtol)
    V, null = Vt[:rank].T, Vt[rank:].T
    F = (Jr @ V).reshape(K, -1, rank)
    return Design(F, V, null, free, scales)


def criterion_value(M, criterion: str = "d", A=None) -> float:
    """Value (smaller is better) of a criterion at information ``M``; inf when singular.

    Parameters
    ----------
    M : array_like, shape (p, p)
        Information matrix.
    criterion : {'d', 'a', 'pose'}, optional
        ``-log det M``, ``trace M^-1`` or ``trace(A M^-1)`` (see the module docstring).
    A : array_like, shape (p, p), optional
        Workspace operator, for ``criterion='pose'``.

    Returns
    -------
    float
        The criterion value.

    Raises
    ------
    ValueError
        For an unknown criterion.
    """
    try:
        L = np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return float("inf")
    if criterion == "d":
        return float(-2.0 * np.sum(np.log(np.diag(L))))
    Linv = np.linalg.solve(L, np.eye(len(M)))
    Minv = Linv.T @ Linv
    if criterion == "a":
        return float(np.trace(Minv))
    if criterion == "pose":
        return float(np.sum(A * Minv))
    raise ValueError(f"unknown criterion {criterion!r}; use one of {', '.join(CRITERIA)}")


def _gains(F, Minv, criterion, A, sign: float):
    """Decrease of the criterion when each candidate is added (``sign=+1``) or removed
    (``sign=-1``): rank-r updates of ``M^-1`` for all candidates at once."""
    H = F @ Minv                                       # (K, r, p)
    G = np.einsum("krp,ksp->krs", H, F)                # F M^-1 F^T
    I = np.eye(F.shape[1])
    S = I + sign * G
    if criterion == "d":
        sgn, logdet = np.linalg.slogdet(S)
        # -log det(M + s F^T F) = -log det M - log det(I + s G)
        return np.where(sgn > 0, logdet, -np.inf)
    # trace(A (M + s F^T F)^-1) = trace(A M^-1) - s trace((I + s G)^-1 H A H^T)  (A = I: "a")
    HA = H if criterion == "a" else H @ A
    Q = np.einsum("krp,ksp->krs", HA, H)
    try:
        X = np.linalg.solve(S, Q)
    except np.linalg.LinAlgError:
        return np.full(len(F), -np.inf)
    gain = sign * np.trace(X, axis1=1, axis2=2)
    return np.where(np.isfinite(gain), gain, -np.inf)


@dataclass
class Selection:
    """Result of :func:`select_poses`.

    Attributes
    ----------
    index : ndarray of int, shape (n,)
        Chosen candidates, in the order of their start (greedy order, or the order of the
        given start; an exchanged candidate takes the place of the one it replaced).
    value : float
        Criterion value of the chosen set.
    criterion : str
        The criterion.
    exchanges : int
        Number of exchanges made after the start the chosen set came from.
    start : int or None
        That start: None for the greedy one, else its index in ``starts``.
    """

    index: np.ndarray
    value: float
    criterion: str
    exchanges: int
    start: int | None = None


def _exchange(F, chosen, free, M, ridge, criterion, A, max_exchanges, bound):
    """Exchanges from the set ``chosen`` (information ``M``, ridge included) until none
    improves the criterion; with ``bound``, a set whose ``trace(A M^-1)`` is within it is
    only exchanged for sets within it. Returns ``(chosen, M, value, exchanges, within)``."""
    n = len(chosen)

    def within(Mc):
        return bound is None or criterion_value(Mc - ridge, "pose", A) <= bound

    value = criterion_value(M - ridge, criterion, A)
    ok = within(M)
    exchanges = 0
    tries = min(n, 8)
    while exchanges < max_exchanges:
        Minv = np.linalg.inv(M)
        loss = -_gains(F[chosen], Minv, criterion, A, -1.0)      # increase on removal
        improved = False
        for i in np.argsort(loss)[:tries]:
            out = int(chosen[i])
            M_out = M - F[out].T @ F[out]
            cand = np.flatnonzero(free)
            if cand.size == 0:
                break
            gain = _gains(F[cand], np.linalg.inv(M_out), criterion, A, +1.0)
            # the value after the exchange falls with the gain: best additions first
            for jj in np.argsort(-gain)[:1 if bound is None else tries]:
                j = int(cand[jj])
                M_new = M_out + F[j].T @ F[j]
                new_value = criterion_value(M_new - ridge, criterion, A)
                if not new_value < value - 1e-12 * max(abs(value), 1.0):
                    break
                if ok and not within(M_new):
                    continue
                chosen[i] = j
                free[out], free[j] = True, False
                M, value = M_new, new_value
                ok = ok or within(M)
                exchanges += 1
                improved = True
                break
            if improved:
                break
        if not improved:
            break
    return chosen, M, value, exchanges, ok


def select_poses(design: Design, n: int, criterion: str = "d", A=None,
                 max_exchanges=None, starts=(), bound=None) -> Selection:
    """Choose ``n`` of the candidates of ``design`` that minimise a criterion (module doc).

    The greedy start uses a ridge of ``1e-9`` of the mean candidate information so that the
    first picks are defined; exchanges run until none improves the criterion (at most
    ``max_exchanges``). Further ``starts`` (e.g. the instrument's standard plan) are improved
    by exchanges the same way, and the best result is returned: never worse by the criterion
    than any start. With ``bound`` (on ``trace(A M^-1)``, the predicted mean squared position
    error), a start within the bound stays within it, and results within it are preferred:
    with a start at the standard plan and ``bound`` its own value, the result is no worse
    than the standard plan by the criterion nor by the predicted position error.

    Parameters
    ----------
    design : Design
        The candidates.
    n : int
        Number of poses to choose, 1..K.
    criterion : {'d', 'a', 'pose'}, optional
        The criterion.
    A : array_like, shape (p, p), optional
        Workspace operator, required for ``criterion='pose'`` and with ``bound``.
    max_exchanges : int, optional
        Largest number of exchanges from each start; default ``10 n``.
    starts : sequence of array_like of int, optional
        Further starting sets, each of ``n`` distinct candidate indices.
    bound : float, optional
        Largest admissible ``trace(A M^-1)`` (A's units squared).

    Returns
    -------
    Selection
        The chosen candidates, the criterion value and the start they came from.

    Raises
    ------
    InputError
        For an unknown criterion or ``n`` outside 1..K.
    ValueError
        When ``criterion='pose'`` or ``bound`` is given without ``A``, or a start is not
        ``n`` distinct candidate indices.
    """
    if criterion not in CRITERIA:
        raise InputError(f"unknown criterion {criterion!r}; use one of {', '.join(CRITERIA)}")
    if (criterion == "pose" or bound is not None) and A is None:
        raise ValueError("criterion 'pose' and a bound need the workspace operator A")
    K, p = len(design), design.rank
    if not 1 <= n <= K:
        raise InputError(f"cannot choose {n} of {K} candidate poses")
    F = design.F
    ridge = 1e-9 * np.trace(design.information()) / max(K * p, 1) * np.eye(p)
    max_exchanges = 10 * n if max_exchanges is None else max_exchanges
    chosen: list[int] = []
    free = np.ones(K, bool)
    M = ridge.copy()
    for _ in range(n):
        gain = _gains(F[free], np.linalg.inv(M), criterion, A, +1.0)
        j = int(np.flatnonzero(free)[int(np.argmax(gain))])
        chosen.append(j)
        free[j] = False
        M += F[j].T @ F[j]
    runs = [(None, *_exchange(F, np.array(chosen), free, M, ridge, criterion, A,
                              max_exchanges, bound))]
    for s, start in enumerate(starts):
        idx = np.array(start, dtype=int).ravel()
        if len(idx) != n or len(np.unique(idx)) != n or idx.min() < 0 or idx.max() >= K:
            raise ValueError(f"start {s}: expected {n} distinct candidate indices in 0..{K - 1}")
        free = np.ones(K, bool)
        free[idx] = False
        runs.append((s, *_exchange(F, idx, free, ridge + design.information(idx), ridge,
                                   criterion, A, max_exchanges, bound)))
    admissible = [r for r in runs if r[5]] or runs
    start, index, _, value, exchanges, _ = min(admissible, key=lambda r: r[3])
    return Selection(index, value, criterion, exchanges, start)


def random_values(design: Design, n: int, sets: int, criterion: str = "d", A=None,
                  rng=None) -> np.ndarray:
    """Criterion values of ``sets`` random subsets of ``n`` candidates (the baseline).

    Parameters
    ----------
    design : Design
        The candidates.
    n : int
        Size of each subset.
    sets : int
        Number of subsets.
    criterion : {'d', 'a', 'pose'}, optional
        The criterion.
    A : array_like, shape (p, p), optional
        Workspace operator, for ``criterion='pose'``.
    rng : int, numpy.random.Generator or None, optional
        Random generator or seed.

    Returns
    -------
    ndarray, shape (sets,)
        Criterion values.
    """
    rng = np.random.default_rng(rng)
    K = len(design)
    return np.array([criterion_value(design.information(rng.choice(K, n, replace=False)),
                                     criterion, A) for _ in range(sets)])
