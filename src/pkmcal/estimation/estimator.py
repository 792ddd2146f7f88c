"""Levenberg-Marquardt for calibration problems with per-pose unknowns (implicit loops).

One estimator serves every machine and measurement type. A problem has *global* unknowns
``u`` (geometry, measurement frames, link length; named in a
:class:`~pkmcal.parameters.ParameterSet`) and, optionally, ``d`` *local* unknowns per
measurement k (the pose of the platform at that measurement). Residuals are whitened (divided by
their standard deviation) and grouped per measurement: ``r`` (K, m).

Block structure (SPEC appendix A). The normal equations are ``[[U, W], [W^T, V]]`` with ``V``
block-diagonal. Rather than forming ``S = U - W V^-1 W^T`` we form its square root: for every
measurement a complete QR of the local Jacobian ``J_l,k = [Q1 Q2] [R1; 0]`` gives the reduced
rows ``Q2^T J_g,k`` and residuals ``Q2^T r_k``, whose normal matrix *is* the Schur complement.
Working with the reduced Jacobian (not ``S``) keeps singular values at full precision, so the
numerical rank is decided on singular values of the scaled Jacobian with a relative tolerance.
After the global step ``du`` each pose is back-substituted,
``dl_k = -R1^-1 Q1^T (r_k + J_g,k du)``.

Gauge. Directions of ``u`` that change no residual (e.g. rotating the base about the
constraint-link point) make the reduced Jacobian rank deficient. The step is taken in the
identifiable subspace only (minimum-norm step in scaled coordinates), so the estimate stays, to
first order, the member of its equivalence class closest to the starting geometry; the null
space is returned so it can be reported in words (:mod:`pkmcal.identifiability`).

Priors (SPEC 9). When the parameters carry a :class:`~pkmcal.parameters.Prior` (build
tolerances: rows ``A u ~ N(mean, std^2)``), its whitened rows ``(A u - mean) / std`` are
appended to the reduced residuals and the fit is maximum a posteriori. The rows act only in the
data's row space (their part along the data's numerical null space is removed): a direction
no measurement changes stays a gauge, where the start put it. The rank, the null space and the
degrees of freedom count what the data alone fix; the covariance is the posterior's (the data
rows scaled by the residual variance unless ``absolute_sigma``, the prior's as stated), and
:meth:`CalibrationResult.prior_summary` says per row what the data measured and what the
prior held.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..parameters import ParameterSet
from ..paths import path_text

# MAX_STD: the machine calibrations' default max_std, re-exported for them (one rank rule)
from .rank import MAX_STD, RTOL, rank_rule  # noqa: F401


class BlockProblem(Protocol):
    """What the estimator needs from a calibration problem (a structural protocol).

    Attributes
    ----------
    parameters : ParameterSet
        Global unknowns, start values and fixed flags.
    scales : ndarray, shape (n,)
        Column scale of each global parameter (lengths by a characteristic length, angles by 1).
    local_dof : int
        Number of local unknowns per measurement (0 when there are none).
    cost_floor : float
        Optional: cost at the numerical precision of the residuals (inner solves such as
        forward kinematics converge to a tolerance); the estimator stops below it.
    """

    parameters: ParameterSet
    scales: np.ndarray
    local_dof: int
    cost_floor: float

    def initial_state(self) -> Any:
        """The start state (global values and any per-measurement unknowns).

        Returns
        -------
        object
            A problem-specific state, passed to :meth:`evaluate` and :meth:`retract`.
        """

    def global_values(self, state) -> np.ndarray:
        """The global parameter values of a state.

        Parameters
        ----------
        state : object
            A state of this problem.

        Returns
        -------
        ndarray, shape (n,)
            Global parameters, internal units.
        """

    def evaluate(self, state, jacobian: bool = True):
        """Whitened residuals and Jacobians at a state.

        Parameters
        ----------
        state : object
            A state of this problem.
        jacobian : bool, optional
            Also compute the Jacobians.

        Returns
        -------
        r : ndarray, shape (K, m)
            Whitened residuals per measurement; NaN marks an infeasible state.
        J_g : ndarray, shape (K, m, n) or None
            Derivatives with respect to the global parameters (None without ``jacobian``).
        J_l : ndarray, shape (K, m, d) or None
            Derivatives with respect to each measurement's local unknowns (None when there are
            none or without ``jacobian``).
        """

    def retract(self, state, du: np.ndarray, dl: np.ndarray | None) -> Any:
        """The state after a step.

        Parameters
        ----------
        state : object
            A state of this problem.
        du : ndarray, shape (n,)
            Step of the global parameters, internal units.
        dl : ndarray, shape (K, d) or None
            Step of the local unknowns (None when there are none).

        Returns
        -------
        object
            The new state (the old one is not modified).
        """


@dataclass
class CalibrationResult:
    """Result of a calibration, in the style of :class:`scipy.optimize.OptimizeResult`.

    Items can also be read as ``result["x"]``. The estimator fills in the fit (``x`` to
    ``prior_cost``); the calibration built on it fills in what every fit has (``machine`` to
    ``sections``, None or empty from :func:`levenberg_marquardt`; see
    :mod:`pkmcal.estimation.sections`).

    Attributes
    ----------
    x : ndarray, shape (n,)
        Identified global parameters (internal units).
    parameters : ParameterSet
        The problem's parameters with ``x`` as values.
    cost : float
        ``0.5 * sum(r^2)`` of the whitened residuals.
    residuals : ndarray, shape (K, m)
        Whitened residuals at the solution.
    success : bool
        Whether the iteration converged (``status`` 1 or 2).
    status : int
        1 Gauss-Newton step negligible, 2 cost cannot decrease further, 3 no step reduces the
        cost, 0 maximum iterations.
    message : str
        ``status`` in words.
    nit : int
        Iterations.
    nfev : int
        Residual evaluations.
    rank : int
        Number of identifiable directions of the free parameters (numerical rank,
        :func:`~pkmcal.estimation.rank.rank_rule`); includes the weak ones, which are not
        stepped along (``adjusted`` are).
    singular_values : ndarray
        Singular values of the scaled reduced Jacobian of the free parameters.
    null_space : ndarray, shape (n, k)
        Unidentifiable directions (numerically null) in scaled coordinates.
    scales : ndarray, shape (n,)
        Column scales of the parameters (the problem's ``scales``).
    weak_space : ndarray, shape (n, w)
        Weakly identifiable directions: identifiable (counted in ``rank``), but with a standard
        deviation of at least ``max_std`` (scaled units) under the assumed noise; not adjusted.
    weak_std : ndarray, shape (w,)
        Their standard deviations (scaled units).
    covariance : ndarray, shape (n, n)
        Covariance of ``x`` (zeros for fixed parameters), minimum-norm (pseudo-inverse),
        multiplied by ``residual_variance`` unless ``absolute_sigma``.
    std : ndarray, shape (n,)
        Standard deviations, ``sqrt(diag(covariance))``.
    residual_variance : float
        ``2 cost / dof`` (SPEC STYLE: not ``cost^2/(m-n)``); NaN when ``dof <= 0``.
    dof : int
        Number of whitened residuals minus adjusted directions and local unknowns.
    state : object, optional
        Final problem state (e.g. the per-measurement poses).
    max_std : float or None, optional
        The weak-direction threshold used (None: numerical rank only).
    fitted : int or None, optional
        With a prior: the directions the fit adjusted, the data's and the prior's (``rank``
        counts the data's alone); None without a prior.
    prior_cost : float, optional
        Half the sum of squares of the prior's whitened rows (not in ``cost``, which is the
        data's); 0 without a prior.
    machine : Machine or None
        The calibrated machine.
    problem : object or None
        The problem solved (unweighted).
    method : str or None
        The calibration method (``"ml"``, ``"tracker-joint"``, ...).
    unidentifiable : list
        The unidentifiable and weakly identifiable directions, named
        (:func:`~pkmcal.identifiability.name_null_space`).
    model, start_model : object or None
        The instrument's model at the estimate and at the start.
    noise : NoiseEstimate or None
        The noise levels used (estimated or held, :mod:`pkmcal.estimation.variance`).
    outliers : OutlierTest or None
        The outlier test of the rows.
    weighted : object or None
        The problem reweighted by the noise levels used.
    weighted_residuals : ndarray or None
        The residuals over those levels.
    used : ndarray of bool or None
        The residuals in the fit (not left out).
    robust : bool or None
        Whether the outlier rows were left out.
    residual_test : ResidualTest or None
        The chi-square test in the terms of a whitened model, when the method's residuals
        are not those.
    untested : str or None
        Why the residuals are not tested against the noise.
    extensions : object or None
        The model extensions tried (:mod:`pkmcal.calibration.extensions`).
    poorly_determined : list or None
        Parameters the data determine only loosely.
    rebuild_problem : callable or None
        Builds the problem again (methods that do not keep it).
    sections : dict
        What each instrument adds, typed: instrument name -> its section
        (:class:`~pkmcal.estimation.sections.ResultSection`).
    """

    x: np.ndarray
    parameters: ParameterSet
    cost: float
    residuals: np.ndarray
    success: bool
    status: int
    message: str
    nit: int
    nfev: int
    rank: int
    singular_values: np.ndarray
    null_space: np.ndarray
    scales: np.ndarray
    weak_space: np.ndarray
    weak_std: np.ndarray
    covariance: np.ndarray
    std: np.ndarray
    residual_variance: float
    dof: int
    state: Any = None
    max_std: float | None = None
    fitted: int | None = None
    prior_cost: float = 0.0
    # the generic part a calibration fills in (pkmcal.estimation.sections.DETAILS)
    machine: Any = None
    problem: Any = None
    method: str | None = None
    unidentifiable: list = field(default_factory=list)
    model: Any = None
    start_model: Any = None
    noise: Any = None
    outliers: Any = None
    weighted: Any = None
    weighted_residuals: np.ndarray | None = None
    used: np.ndarray | None = None
    robust: bool | None = None
    residual_test: Any = None
    untested: str | None = None
    extensions: Any = None
    poorly_determined: list | None = None
    rebuild_problem: Callable | None = None
    #: instrument name -> its typed section (pkmcal.estimation.sections.ResultSection)
    sections: dict = field(default_factory=dict)

    def section(self, kind: type):
        """The section of a type.

        Parameters
        ----------
        kind : type
            A section class (e.g. an instrument's ``TrackerSection``).

        Returns
        -------
        object or None
            The result's section of that type; None when it has none.
        """
        return next((s for s in self.sections.values() if isinstance(s, kind)), None)

    def add_section(self, section) -> None:
        """Attach an instrument's section.

        Parameters
        ----------
        section : object
            A typed section (:mod:`pkmcal.estimation.sections`), kept under its
            ``instrument`` name.
        """
        self.sections[section.instrument] = section

    @property
    def weak(self) -> int:
        """Number of weakly identifiable directions (counted in ``rank``, not adjusted)."""
        return int(self.weak_space.shape[1])

    @property
    def adjusted(self) -> int:
        """Number of directions fitted: ``rank - weak``; with a prior, those the posterior
        fixes (``fitted``: the prior may hold directions the data leave free)."""
        if self.fitted is not None:
            return int(self.fitted)
        return int(self.rank) - self.weak

    def prior_summary(self, share: float = 0.5) -> list[PriorRow]:
        """What the data measured and what the prior held, per row of the parameters' prior
        (SPEC 9); empty without a prior.

        A row's information is ``1 / std_prior^2`` from the prior and ``1 / std_post^2 -
        1 / std_prior^2`` from the data, so the data's share is ``1 - std_post^2 /
        std_prior^2``; a row is ``measured`` when that share is at least ``share``, else
        ``prior-held``.

        Parameters
        ----------
        share : float, optional
            The data's share of the information from which a row counts as measured.

        Returns
        -------
        list of PriorRow
            One per prior row that involves a free parameter.
        """
        prior = self.parameters.prior
        if prior is None:
            return []
        free = np.asarray(self.parameters.free, bool)
        N = np.asarray(self.null_space, float)[free]
        out = []
        for j in range(len(prior)):
            a = prior.matrix[j]
            if not np.any(a[free] != 0):
                continue
            value = float(a @ self.x)
            scaled = a[free] * np.asarray(self.scales, float)[free]
            along_null = float(np.linalg.norm(scaled @ N)) if N.size else 0.0
            if along_null > 0.9 * float(np.linalg.norm(scaled)):
                # a gauge: no measurement changes it, it stays where the start put it
                out.append(PriorRow(prior.names[j], prior.key[j], value, float(prior.mean[j]),
                                    float(prior.std[j]), float("nan"), 0.0,
                                    "unidentifiable", self._kind_of(a)))
                continue
            post = float(np.sqrt(max(a @ self.covariance @ a, 0.0)))
            data_share = float(np.clip(1.0 - (post / prior.std[j]) ** 2, 0.0, 1.0))
            out.append(PriorRow(prior.names[j], prior.key[j], value, float(prior.mean[j]),
                                float(prior.std[j]), post, data_share,
                                "measured" if data_share >= share else "prior-held",
                                self._kind_of(a)))
        return out

    def _kind_of(self, a) -> str:
        kinds = {self.parameters.kinds[i] for i in np.flatnonzero(a)}
        return kinds.pop() if len(kinds) == 1 else "length"

    def rank_words(self) -> str:
        """The identifiable and weak counts in words (:meth:`~pkmcal.estimation.rank.
        Rank.words`).

        Returns
        -------
        str
            One line, e.g. ``"48 of 60 free parameter directions identifiable, of which 4
            weakly (...)"``.
        """
        from .rank import Rank

        n = int(self.parameters.free.sum()) if self.parameters is not None else 0
        return Rank(int(self.rank), self.weak, n, self.max_std).words()

    def __getitem__(self, key):  # scipy-style access: result["x"]
        return getattr(self, key)

    def __getstate__(self):
        # levenberg_marquardt keeps its final factors on the result (``_linear``, a
        # Linearisation: used again by the noise rounds and the report's leverages); they
        # refer to the problem: not pickled (nor copied)
        state = dict(self.__dict__)
        state.pop("_linear", None)
        return state




@dataclass(frozen=True)
class PriorRow:
    """One row of a fit's prior (:meth:`CalibrationResult.prior_summary`).

    Attributes
    ----------
    name : str
        The row: a parameter or a combination in words.
    key : str
        The machine file's key that sets its tolerance (``tolerances.arm_trim``).
    value, mean : float
        The fitted value of the row and its nominal, internal units.
    prior_std, posterior_std : float
        Its tolerance and its standard deviation after the fit.
    data_share : float
        The data's share of the information about it (0: the prior alone, 1: the data).
    label : str
        ``"measured"``, ``"prior-held"``, or ``"unidentifiable"`` (a gauge: no measurement
        changes it; it stays at the start, the prior does not act on it).
    kind : str
        ``length`` or ``angle`` (its unit).
    """

    name: str
    key: str
    value: float
    mean: float
    prior_std: float
    posterior_std: float
    data_share: float
    label: str
    kind: str

    @property
    def sigmas(self) -> float:
        """How many prior standard deviations the fitted value lies from the nominal."""
        return abs(self.value - self.mean) / self.prior_std


def require_redundancy(source, what: str, equations: int, n_id: int, advice: str) -> None:
    """Refuse data that leave no equation to check a fit: with ``equations <= n_id`` it would
    be exact whatever the noise (or fail to fix every direction), its residuals and covariance
    meaningless.

    Parameters
    ----------
    source : str or path
        The data file, named in the message.
    what : str
        The data in words (``"48 rows"``, ``"30 rows, 20 distinct (...)"``).
    equations : int
        Independent equations the data give.
    n_id : int
        Parameters they would have to fix.
    advice : str
        What to measure instead (ends the message).

    Raises
    ------
    InputError
        When ``equations <= n_id``.
    """
    if equations > n_id:
        return
    from ..errors import InputError

    how = "fewer than" if equations < n_id else "as many as"
    raise InputError(f"{path_text(source)}: "
                     f"{what} give {equations} independent equation(s), {how} the "
                     f"{n_id} identifiable parameters, with nothing left to check the fit; "
                     f"{advice}")


def reduce_local(r, Jg, Jl):
    """Eliminate local unknowns: reduced rows/residuals and the back-substitution operator.

    A complete QR of each measurement's local Jacobian ``J_l,k = [Q1 Q2] [R1; 0]`` gives the
    reduced rows ``Q2^T J_g,k`` and residuals ``Q2^T r_k``.

    Parameters
    ----------
    r : ndarray, shape (K, m)
        Residuals.
    Jg : ndarray, shape (K, m, n)
        Jacobian of the global unknowns (in whatever column scaling the caller uses).
    Jl : ndarray, shape (K, m, d) or None
        Jacobian of the local unknowns; None or ``d = 0`` when there are none.

    Returns
    -------
    Jr : ndarray, shape (M, n)
        Reduced Jacobian, ``M = K (m - d)``.
    er : ndarray, shape (M,)
        Reduced residuals.
    back : callable
        ``back(du) -> dl`` (K, d): the local step that goes with a global step ``du`` (in the
        columns of ``Jg``); returns None without local unknowns.
    """
    Jr, er, back, _ = _reduce(r, Jg, Jl)
    return Jr, er, back


def _reduce(r, Jg, Jl):
    """:func:`reduce_local` and the factors of the local Jacobians' QR, ``(Q1, Q2, R1)``
    (None without local unknowns)."""
    K, m = r.shape
    if Jl is None or Jl.shape[-1] == 0:
        return Jg.reshape(K * m, -1), r.reshape(-1), (lambda du: None), None
    d = Jl.shape[-1]
    Q, Rf = np.linalg.qr(Jl, mode="complete")             # (K, m, m), (K, m, d)
    Q1, Q2, R1 = Q[..., :d], Q[..., d:], Rf[..., :d, :]
    Jr = np.einsum("kmi,kmn->kin", Q2, Jg).reshape(K * (m - d), -1)
    er = np.einsum("kmi,km->ki", Q2, r).reshape(-1)
    # Q1^T r and Q1^T J_g only when a step is taken: an iteration that converges, the final
    # statistics and the rank analyses take none (Q1^T J_g is the costliest product here)
    parts = []

    def back(du):
        if not parts:
            parts.extend((np.einsum("kmi,km->ki", Q1, r), np.swapaxes(Q1, -1, -2) @ Jg))
        Q1r, Q1J = parts
        rhs = Q1r + Q1J @ du
        return -np.linalg.solve(R1, rhs[..., None])[..., 0]

    return Jr, er, back, (Q1, Q2, R1)


#: :func:`levenberg_marquardt`'s default step and cost tolerances and iteration limit
XTOL, FTOL, MAX_ITER = 1e-12, 1e-14, 100


def settings_of(rtol: float = RTOL, absolute_sigma: bool = False, xtol: float = XTOL,
                ftol: float = FTOL, max_iter: int = MAX_ITER, max_std: float | None = None,
                **_) -> tuple:
    """The settings of a :func:`levenberg_marquardt` call (its keywords, defaults applied) as
    a :class:`Linearisation` records them.

    Parameters
    ----------
    rtol, absolute_sigma, xtol, ftol, max_iter, max_std
        As :func:`levenberg_marquardt`; other keywords (``state``) are ignored.

    Returns
    -------
    tuple
        ``(rtol, xtol, ftol, max_iter, max_std, absolute_sigma)``.
    """
    return (float(rtol), float(xtol), float(ftol), int(max_iter),
            None if max_std is None else float(max_std), bool(absolute_sigma))


def levenberg_marquardt(problem: BlockProblem, rtol: float = RTOL, xtol: float = XTOL,
                        ftol: float = FTOL, max_iter: int = MAX_ITER,
                        absolute_sigma: bool = False, state=None,
                        max_std: float | None = None) -> CalibrationResult:
    """Solve a :class:`BlockProblem` by Levenberg-Marquardt on the reduced (Schur) system.

    Parameters
    ----------
    problem : BlockProblem
        The calibration problem.
    rtol : float, optional
        Relative tolerance on singular values of the scaled reduced Jacobian; directions with
        ``s_i <= rtol * s_1`` are unidentifiable and never stepped along (the one rank rule,
        :func:`~pkmcal.estimation.rank.rank_rule`).
    xtol : float, optional
        Stop when the largest component of the (undamped) Gauss-Newton step, in scaled
        coordinates, is below ``xtol``, or when that step would lower the cost by less than
        ``1e-12`` of it (the optimum of noisy data), or when the cost is below the problem's
        ``cost_floor`` (the precision of its residuals: the readings' rounding, an inner
        solve's tolerance); a step that lowers no cost from there is convergence too.
    ftol : float, optional
        Stop when the relative cost decrease of an accepted undamped step is below ``ftol``.
    max_iter : int, optional
        Maximum iterations (>= 1).
    absolute_sigma : bool, optional
        Residuals are whitened by true standard deviations: report the covariance without
        rescaling by the residual variance.
    state : object, optional
        State to start from; default ``problem.initial_state()``.
    max_std : float, optional
        An identifiable direction whose standard deviation under the assumed noise is at least
        this, in scaled units (0.1 = 10 % of the characteristic length, or 5.7 deg), is not
        determined by the data in any useful sense: it is counted as identifiable (``rank``)
        but weakly, not stepped along (stepping along it stalls the iteration in a curved
        valley and would fit noise), and returned in ``weak_space`` with its standard
        deviation. None (default): numerical rank only; the machine calibrations pass
        :data:`MAX_STD`, where scaled units have that meaning.

    Returns
    -------
    CalibrationResult
        The estimate, its statistics and the identifiable / null / weak directions.

    Raises
    ------
    ValueError
        When a tolerance is outside [0, 1), ``max_iter < 1``, ``max_std`` is not positive, or
        the residuals are not finite at the start point.
    """
    for name, v in (("xtol", xtol), ("ftol", ftol)):
        if not (np.isfinite(v) and 0 <= v < 1):
            raise ValueError(f"{name} must be in [0, 1), got {v}")
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
    rank_rule(np.zeros(0), rtol, max_std)      # checks rtol and max_std (ValueError)

    params = problem.parameters
    free = params.free
    scales = np.asarray(problem.scales, float)
    cost_floor = float(getattr(problem, "cost_floor", 0.0))
    prior = params.prior
    if prior is not None and not np.any(prior.matrix[:, free] != 0):
        prior = None                    # no row involves a free parameter

    def prior_part(state):
        """The prior's whitened residuals and scaled Jacobian rows at ``state`` (empty
        without a prior)."""
        if prior is None:
            return np.zeros(0), np.zeros((0, int(free.sum())))
        ep, Ap, _ = prior.whitened(problem.global_values(state), free, scales)
        return ep, Ap

    state = problem.initial_state() if state is None else state
    r, Jg, Jl = problem.evaluate(state)
    nfev = 1
    if not np.all(np.isfinite(r)):
        raise ValueError("residuals are not finite at the start point")
    ep, Ap = prior_part(state)
    cost = 0.5 * float(np.sum(r * r) + np.sum(ep * ep))
    lam = 0.0
    status, message = 0, "maximum number of iterations reached"
    nit = 0
    current = None      # (QR factors, U, s, Vt, data rows) of r, Jg, Jl as they are now
    for nit in range(1, max_iter + 1):  # noqa: B007
        Jr, er, back, qr = _reduce(r, Jg[..., free] * scales[free], Jl)
        data_rows = Jr
        if prior is not None:           # maximum a posteriori: the prior's rows appended
            Jr, er = np.vstack([Jr, _off_null(Ap, data_rows, rtol)]), np.concatenate([er, ep])
        U, s, Vt = np.linalg.svd(Jr, full_matrices=False)
        current = (qr, U, s, Vt, data_rows)
        rank = rank_rule(s, rtol, max_std).adjusted
        Ur, sr, Vr = U[:, :rank], s[:rank], Vt[:rank].T
        g = Ur.T @ er
        s1 = float(sr[0]) if rank else 1.0
        # stationary point: the Gauss-Newton step is negligible, or could lower the cost by
        # no more than rounding (noisy data: the cost stays near dof/2 at the optimum)
        predicted = 0.5 * float(g @ g)
        if nit > 1 and (np.max(np.abs(Vr @ (g / sr)), initial=0.0) < xtol
                        or predicted <= 1e-12 * cost or cost <= cost_floor):
            status, message = 1, "Gauss-Newton step negligible (converged)"
            break
        accepted = False
        for _ in range(30):
            ds = -Vr @ (sr * g / (sr**2 + lam))
            du = np.zeros(len(params))
            du[free] = ds * scales[free]
            new_state = problem.retract(state, du, back(ds))  # back works in scaled columns
            new_r, new_Jg, new_Jl = problem.evaluate(new_state)
            nfev += 1
            new_ep, new_Ap = prior_part(new_state)
            new_cost = 0.5 * float(np.sum(new_r * new_r) + np.sum(new_ep * new_ep)) \
                if np.all(np.isfinite(new_r)) else np.inf
            if new_cost <= cost:
                accepted = True
                break
            if predicted <= 1e-8 * cost or cost <= cost_floor:
                # the Gauss-Newton step could gain only rounding and did not: at the optimum
                # (a converged fit started again, reweighted; noise-free data fitted to the
                # precision of the residuals); shorter steps gain no more
                break
            lam = max(lam * 10.0, 1e-6 * s1**2)
        if not accepted:
            if predicted <= 1e-8 * cost or cost <= cost_floor:   # only rounding left to gain
                status, message = 2, "cost cannot decrease beyond rounding (converged)"
            else:
                status, message = 3, "no step reduces the cost (stuck at a local minimum?)"
            break
        decrease = (cost - new_cost) / max(cost, 1e-300)
        lam_used = lam
        state, r, Jg, Jl, cost = new_state, new_r, new_Jg, new_Jl, new_cost
        ep, Ap = new_ep, new_Ap
        current = None
        lam = lam / 10.0 if lam > 1e-12 * s1**2 else 0.0
        if (decrease < ftol and cost > 0 and lam_used == 0.0) or decrease <= 0.0:
            # an accepted step that gains exactly nothing: rounding has the last word
            status, message = 2, "relative cost decrease below ftol"
            break
    # final statistics at the solution: the last iteration's factors when it took no step (a
    # converged fit, or one that cannot go on), else those of the state it ended at
    if current is None:
        Jr, _, _, qr = _reduce(r, Jg[..., free] * scales[free], Jl)
        data_rows = Jr
        if prior is not None:
            Jr = np.vstack([Jr, _off_null(Ap, data_rows, rtol)])
        U, s, Vt = np.linalg.svd(Jr, full_matrices=False)
        current = (qr, U, s, Vt, data_rows)
    qr, U, s, Vt, data_rows = current
    decision = rank_rule(s, rtol, max_std)
    numerical, rank = decision.identifiable, decision.adjusted   # rank: adjusted directions
    n_free = int(free.sum())
    d = Jl.shape[-1] if Jl is not None else 0
    data_cost = 0.5 * float(np.sum(r * r))
    if prior is None:
        s_data, Vt_data, data_decision = s, Vt, decision
    else:
        # identifiability counts what the data alone fix (SPEC 9); the fit and its
        # covariance are the posterior's
        _, s_data, Vt_data = np.linalg.svd(data_rows, full_matrices=False)
        data_decision = rank_rule(s_data, rtol, max_std)
    numerical_data = data_decision.identifiable
    null_free = (Vt_data[numerical_data:].T if Vt_data.shape[0] >= n_free
                 else _complete_null(Vt_data[:numerical_data], n_free))
    null_space = np.zeros((len(params), null_free.shape[1]))
    null_space[free] = null_free
    weak_space = np.zeros((len(params), numerical - rank))
    weak_space[free] = Vt[rank:numerical].T
    dof = int(r.size - data_decision.adjusted - d * r.shape[0])
    variance = 2.0 * data_cost / dof if dof > 0 else float("nan")
    factor = 1.0 if absolute_sigma else variance
    if prior is None or factor == 1.0 or not np.isfinite(factor) or factor <= 0:
        cov_free_scaled = (Vt[:rank].T / s[:rank] ** 2) @ Vt[:rank]
        scale_data = factor if prior is None else 1.0
    else:
        # the data's rows take the residual variance, the prior's stay as stated
        _, sv, Vtv = np.linalg.svd(np.vstack([data_rows / np.sqrt(factor),
                                              _off_null(Ap, data_rows, rtol)]),
                                   full_matrices=False)
        cov_free_scaled = (Vtv[:rank].T / sv[:rank] ** 2) @ Vtv[:rank]
        scale_data = 1.0
    cov = np.zeros((len(params), len(params)))
    sf = scales[free]
    cov[np.ix_(free, free)] = cov_free_scaled * np.outer(sf, sf) * scale_data
    x = problem.global_values(state)
    result = CalibrationResult(
        x=x, parameters=params.with_values(x), cost=data_cost, residuals=r,
        success=status in (1, 2), status=status, message=message, nit=nit, nfev=nfev,
        rank=numerical_data if prior is not None else numerical, singular_values=s_data,
        null_space=null_space, scales=scales,
        weak_space=weak_space, weak_std=1.0 / s[rank:numerical], covariance=cov,
        std=np.sqrt(np.clip(np.diag(cov), 0, None)), residual_variance=variance, dof=dof,
        state=state, max_std=max_std,
        fitted=rank if prior is not None else None,
        prior_cost=0.5 * float(np.sum(ep * ep)),
    )
    # the hat matrix of the data under the posterior: the data rows of the augmented
    # factors (U's first rows), with the augmented singular values
    M = data_rows.shape[0]
    result._linear = Linearisation(problem, state, r.shape, qr, U[:M], s,
                                   settings_of(rtol, absolute_sigma, xtol, ftol, max_iter,
                                               max_std),
                                   fitted=rank if prior is not None else None)
    return result


@dataclass
class Linearisation:
    """The factors of the scaled reduced Jacobian a fit ended with (at ``state`` of
    ``problem``): the local Jacobians' QR ``(Q1, Q2, R1)`` (None without local unknowns) and
    the SVD's ``U``, ``s``; and the call's settings (:func:`settings_of`). Hat matrices and
    likelihoods of the fit (:mod:`.variance`) take them from here instead of evaluating and
    factoring the same Jacobian again."""

    problem: Any
    state: Any
    shape: tuple
    qr: tuple | None
    U: np.ndarray
    s: np.ndarray
    settings: tuple = ()
    #: with a prior: the number of fitted directions of ``U`` (those of the posterior,
    #: maybe more than the data's rank); None: the result's ``adjusted``
    fitted: int | None = None


def linearisation_of(result, problem) -> Linearisation | None:
    """The :class:`Linearisation` a fit ended with, when it is that of ``problem`` at
    ``result.state`` (the same objects).

    Parameters
    ----------
    result : CalibrationResult
        A fit (:func:`levenberg_marquardt` keeps its factors; a copy or an unpickled result
        has none).
    problem : BlockProblem
        The problem the factors must be of.

    Returns
    -------
    Linearisation or None
        The factors, or None when ``result`` has none of ``problem`` at its state.
    """
    lin = getattr(result, "_linear", None)
    if lin is None or lin.problem is not problem or lin.state is not result.state:
        return None
    return lin


def _off_null(prior_rows: np.ndarray, data_rows: np.ndarray, rtol: float) -> np.ndarray:
    """The prior's rows (scaled free columns) without their part along the data's numerical
    null space: a prior holds what the data see weakly, never a gauge (a direction no
    measurement changes stays where the start put it, as without a prior, SPEC appendix A).

    Parameters
    ----------
    prior_rows : ndarray, shape (p, n)
        Whitened prior rows.
    data_rows : ndarray, shape (M, n)
        The data's scaled reduced Jacobian.
    rtol : float
        The rank tolerance.

    Returns
    -------
    ndarray, shape (p, n)
        The rows projected onto the data's row space.
    """
    from .rank import numerical_rank

    _, s, Vt = np.linalg.svd(data_rows, full_matrices=False)
    k = numerical_rank(s, rtol)
    N = _complete_null(Vt[:k], data_rows.shape[1]).T
    if not len(N):
        return prior_rows
    return prior_rows - (prior_rows @ N.T) @ N


def _complete_null(row_basis: np.ndarray, n: int) -> np.ndarray:
    """Orthonormal complement of the rows of ``row_basis`` in R^n."""
    if row_basis.shape[0] == 0:
        return np.eye(n)
    _, _, Vt = np.linalg.svd(row_basis, full_matrices=True)
    return Vt[row_basis.shape[0]:].T
