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
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..parameters import ParameterSet


class BlockProblem(Protocol):
    """What the estimator needs from a calibration problem."""

    #: global unknowns, start values and fixed flags
    parameters: ParameterSet
    #: column scale of each global parameter (lengths by a characteristic length, angles by 1)
    scales: np.ndarray
    #: number of local unknowns per measurement (0 when there are none)
    local_dof: int
    #: optional: cost at the numerical precision of the residuals (inner solves such as
    #: forward kinematics converge to a tolerance); the estimator stops below it
    cost_floor: float

    def initial_state(self) -> Any: ...

    def global_values(self, state) -> np.ndarray: ...

    def evaluate(self, state, jacobian: bool = True):
        """``(r (K,m), J_g (K,m,n) or None, J_l (K,m,d) or None)``; NaN in r = infeasible."""

    def retract(self, state, du: np.ndarray, dl: np.ndarray | None) -> Any: ...


@dataclass
class CalibrationResult:
    """Result of a calibration, in the style of :class:`scipy.optimize.OptimizeResult`.

    Attributes
    ----------
    x : (n,) identified global parameters (internal units).
    parameters : ParameterSet with ``x`` as values.
    cost : ``0.5 * sum(r^2)`` of the whitened residuals.
    residuals : (K, m) whitened residuals at the solution.
    success, status, message : convergence; ``status`` 1 Gauss-Newton step small, 2 cost flat,
        3 no step reduces the cost, 0 maximum iterations.
    nit, nfev : iterations and residual evaluations.
    rank : number of directions identified (stepped along) among the free parameters.
    singular_values : of the scaled reduced Jacobian of the free parameters.
    null_space : (n, k) unidentifiable directions (numerically null) in scaled coordinates.
    weak_space : (n, w) weakly identifiable directions: not null, but with a standard
        deviation above ``max_std`` (scaled units) under the assumed noise; not adjusted.
    weak_std : (w,) their standard deviations (scaled units).
    covariance : (n, n) of ``x`` (zeros for fixed parameters), minimum-norm (pseudo-inverse)
        covariance, multiplied by ``residual_variance`` unless ``absolute_sigma``.
    std : (n,) standard deviations, ``sqrt(diag(covariance))``.
    residual_variance : ``2 cost / dof`` (SPEC STYLE: not ``cost^2/(m-n)``).
    dof : number of whitened residuals minus identified and local unknowns.
    state : final problem state (e.g. the per-measurement poses).
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
    extras: dict = field(default_factory=dict)

    def __getitem__(self, key):  # scipy-style access: result["x"]
        return getattr(self, key)


#: default ``max_std`` of the machine calibrations (scaled units, see levenberg_marquardt)
MAX_STD = 0.1


def reduce_local(r, Jg, Jl):
    """Eliminate local unknowns: reduced rows/residuals and the back-substitution operator.

    Returns ``(Jr (M, n), er (M,), back)`` with ``back(du) -> dl (K, d)``.
    """
    K, m = r.shape
    if Jl is None or Jl.shape[-1] == 0:
        return Jg.reshape(K * m, -1), r.reshape(-1), (lambda du: None)
    d = Jl.shape[-1]
    Q, Rf = np.linalg.qr(Jl, mode="complete")             # (K, m, m), (K, m, d)
    Q1, Q2, R1 = Q[..., :d], Q[..., d:], Rf[..., :d, :]
    Jr = np.einsum("kmi,kmn->kin", Q2, Jg).reshape(K * (m - d), -1)
    er = np.einsum("kmi,km->ki", Q2, r).reshape(-1)
    Q1r = np.einsum("kmi,km->ki", Q1, r)
    Q1J = np.einsum("kmi,kmn->kin", Q1, Jg)

    def back(du):
        rhs = Q1r + Q1J @ du
        return -np.linalg.solve(R1, rhs[..., None])[..., 0]

    return Jr, er, back


def levenberg_marquardt(problem: BlockProblem, rtol: float = 1e-7, xtol: float = 1e-12,
                        ftol: float = 1e-14, max_iter: int = 100,
                        absolute_sigma: bool = False, state=None,
                        max_std: float | None = None) -> CalibrationResult:
    """Solve a :class:`BlockProblem` by Levenberg-Marquardt on the reduced (Schur) system.

    Parameters
    ----------
    rtol : relative tolerance on singular values of the scaled reduced Jacobian; directions
        with ``s_i < rtol * s_1`` are unidentifiable and never stepped along.
    xtol : stop when the largest component of the (undamped) Gauss-Newton step, in scaled
        coordinates, is below ``xtol``, or when that step would lower the cost by less than
        ``1e-12`` of it (the optimum of noisy data), or when the cost is below the problem's
        ``cost_floor`` (the precision of residuals computed by an inner solve).
    ftol : stop when the relative cost decrease of an accepted step is below ``ftol``.
    absolute_sigma : residuals are whitened by true standard deviations: report the
        covariance without rescaling by the residual variance.
    max_std : a direction whose standard deviation under the assumed noise exceeds this, in
        scaled units (0.1 = 10 % of the characteristic length, or 5.7 deg), is not determined
        by the data in any useful sense: it is neither stepped along (stepping along it stalls
        the iteration in a curved valley) nor counted as identified, and it is returned in
        ``weak_space``. None (default): numerical rank only; the machine calibrations pass
        :data:`MAX_STD`, where scaled units have that meaning.
    """
    for name, v in (("rtol", rtol), ("xtol", xtol), ("ftol", ftol)):
        if not (np.isfinite(v) and 0 <= v < 1):
            raise ValueError(f"{name} must be in [0, 1), got {v}")
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
    if max_std is not None and not max_std > 0:
        raise ValueError(f"max_std must be positive or None, got {max_std}")
    min_s = 0.0 if max_std is None else 1.0 / max_std

    def ranks(s):
        numerical = int(np.sum(s > rtol * s[0])) if s.size else 0
        return numerical, min(numerical, int(np.sum(s > min_s)))

    params = problem.parameters
    free = params.free
    scales = np.asarray(problem.scales, float)
    cost_floor = float(getattr(problem, "cost_floor", 0.0))
    state = problem.initial_state() if state is None else state
    r, Jg, Jl = problem.evaluate(state)
    nfev = 1
    if not np.all(np.isfinite(r)):
        raise ValueError("residuals are not finite at the start point")
    cost = 0.5 * float(np.sum(r * r))
    lam = 0.0
    status, message = 0, "maximum number of iterations reached"
    nit = 0
    for nit in range(1, max_iter + 1):  # noqa: B007
        Jr, er, back = reduce_local(r, Jg[..., free] * scales[free], Jl)
        U, s, Vt = np.linalg.svd(Jr, full_matrices=False)
        _, rank = ranks(s)
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
            new_cost = 0.5 * float(np.sum(new_r * new_r)) if np.all(np.isfinite(new_r)) \
                else np.inf
            if new_cost <= cost:
                accepted = True
                break
            lam = max(lam * 10.0, 1e-6 * s1**2)
        if not accepted:
            if predicted <= 1e-8 * cost:   # only rounding left to gain: converged
                status, message = 2, "cost cannot decrease beyond rounding (converged)"
            else:
                status, message = 3, "no step reduces the cost (stuck at a local minimum?)"
            break
        decrease = (cost - new_cost) / max(cost, 1e-300)
        lam_used = lam
        state, r, Jg, Jl, cost = new_state, new_r, new_Jg, new_Jl, new_cost
        lam = lam / 10.0 if lam > 1e-12 * s1**2 else 0.0
        if (decrease < ftol and cost > 0 and lam_used == 0.0) or decrease <= 0.0:
            # an accepted step that gains exactly nothing: rounding has the last word
            status, message = 2, "relative cost decrease below ftol"
            break
    # final statistics at the solution
    Jr, er, _ = reduce_local(r, Jg[..., free] * scales[free], Jl)
    U, s, Vt = np.linalg.svd(Jr, full_matrices=False)
    numerical, rank = ranks(s)
    n_free = int(free.sum())
    null_free = (Vt[numerical:].T if Vt.shape[0] >= n_free
                 else _complete_null(Vt[:numerical], n_free))
    null_space = np.zeros((len(params), null_free.shape[1]))
    null_space[free] = null_free
    weak_space = np.zeros((len(params), numerical - rank))
    weak_space[free] = Vt[rank:numerical].T
    cov_free_scaled = (Vt[:rank].T / s[:rank] ** 2) @ Vt[:rank]
    d = Jl.shape[-1] if Jl is not None else 0
    dof = int(r.size - rank - d * r.shape[0])
    variance = 2.0 * cost / dof if dof > 0 else float("nan")
    factor = 1.0 if absolute_sigma else variance
    cov = np.zeros((len(params), len(params)))
    sf = scales[free]
    cov[np.ix_(free, free)] = cov_free_scaled * np.outer(sf, sf) * factor
    x = problem.global_values(state)
    return CalibrationResult(
        x=x, parameters=params.with_values(x), cost=cost, residuals=r,
        success=status in (1, 2), status=status, message=message, nit=nit, nfev=nfev,
        rank=rank, singular_values=s, null_space=null_space, scales=scales,
        weak_space=weak_space, weak_std=1.0 / s[rank:numerical], covariance=cov,
        std=np.sqrt(np.clip(np.diag(cov), 0, None)), residual_variance=variance, dof=dof,
        state=state,
    )


def _complete_null(row_basis: np.ndarray, n: int) -> np.ndarray:
    """Orthonormal complement of the rows of ``row_basis`` in R^n."""
    if row_basis.shape[0] == 0:
        return np.eye(n)
    _, _, Vt = np.linalg.svd(row_basis, full_matrices=True)
    return Vt[row_basis.shape[0]:].T
