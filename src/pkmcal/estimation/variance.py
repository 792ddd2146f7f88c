"""The noise model from the data: variance components, outlier rows, honest uncertainty.

Users rarely know their instruments' noise. Every residual of a calibration problem belongs to
a *noise group* (:class:`NoiseGroups`: the tracker along and across the beam, the leg
readings, the measured positions and orientations, each file of a joint fit ...), whitened by
an assumed standard deviation. The true variance of group ``c`` is ``theta_c`` times the
assumed one; :func:`fit` estimates the ``theta_c`` from the residuals and refits with them.

Estimator (Helmert's variance-component equations, iterated: REML). With the problem whitened
by the current levels, ``M = I - H`` the residual-maker of the linearised fit (local unknowns
included, weak directions excluded) and ``r`` the whitened residuals, if group ``d``'s true
variance is ``phi_d`` times the current one::

    E[q_c] = sum_d S_cd phi_d,   q_c = sum_{i in c} r_i^2,   S_cd = sum_{i in c, j in d} M_ij^2

(:func:`helmert_matrix`). Each step solves ``S phi = q`` and multiplies the levels by ``phi``
(Förstner's ``q_c / red_c``, ``red_c = sum_{i in c} M_ii`` the group's *redundancy*, where
Helmert's gives no positive value); at the fixed point ``phi = 1``: the REML estimate.
Helmert's step moves every group at once, also one whose redundancy is small at the current
levels (leg readings assumed far more precise than they are carry almost none until their
level rises). The assumed levels are the prior in the plainest sense: the start, and the value
kept for a group the data cannot check (its redundancy, were its level far above the others',
below :data:`MIN_REDUNDANCY`); a group the user fixed (``--noise``) is held. A group whose
redundancy keeps falling below :data:`MIN_REDUNDANCY` is fitted ever more exactly: the data
bound its level from above only ("at most"). The covariance of the estimated ``theta`` is
``2 S^-1`` (Gaussian noise), so a level's standard deviation is
``sigma_c sqrt((S^-1)_cc / 2)`` (``sigma_c / sqrt(2 red_c)`` for one group).

Outliers. Per measurement (a tracker point, a pose, a probe height), the test statistic
``T = r_S^T (I - H_SS)^+ r_S`` is chi-square with ``rank(I - H_SS)`` degrees of freedom for a
correct measurement (Baarda's data snooping, whole rows); a row whose p-value is below
``alpha / (number of rows)`` (Bonferroni) is named. ``robust=True`` leaves the named rows out
(weight :data:`LEFT_OUT_WEIGHT`, which keeps per-measurement unknowns determined), estimates
the levels again without them and tests every row again, a left-out one against its
prediction (the fit's uncertainty added): the rows named then are the ones left out, until a
set repeats. Gross errors inflate a level estimated with them in and hide each other in one
test (masking), so without ``robust`` the rows named are still those the rounds would leave
out; the fit keeps them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .distributions import chi2_ppf, chi2_sf
from .estimator import (
    CalibrationResult,
    Linearisation,
    levenberg_marquardt,
    linearisation_of,
    settings_of,
)
from .rank import RTOL
from .sections import blank_details

__all__ = ["MIN_REDUNDANCY", "NoiseEstimate", "NoiseGroups", "OutlierTest",
           "Weighted", "fit", "hat_factors", "noise_groups_of"]

#: a group is estimated when its residuals have at least this redundancy (relative standard
#: deviation of its level 1/sqrt(2 red) <= 22 %); below it the assumed value is kept
MIN_REDUNDANCY = 10.0
#: stop when no level changes by more than this, relative
VCE_TOL = 1e-3
#: at most this many reweighted fits
VCE_MAX_ITER = 30
#: family-wise false-alarm rate of the outlier test (Bonferroni over the rows)
OUTLIER_ALPHA = 0.01
#: residual weight of a left-out row (small, not zero: its pose unknowns stay determined)
LEFT_OUT_WEIGHT = 1e-6
#: at most this many rounds of leaving rows out
ROBUST_ROUNDS = 10
#: median of chi-square with one degree of freedom (``scipy.stats.chi2.ppf(0.5, 1)``; a literal:
#: scipy.stats takes half a second to import, paid by every command that loads this package)
MEDIAN_CHI2_1 = 0.454936423119572
#: the first robust round judges a group on its median level where that is below this share
#: of its estimated level (in variance): gross errors inflated the estimate
ROBUST_SHRINK = 0.25


@dataclass
class NoiseGroups:
    """Which noise group each whitened residual belongs to, and what was assumed.

    Attributes
    ----------
    labels : ndarray of int, shape (K, m)
        Group of each residual (index into ``keys``).
    keys : list of str
        Short names (``"reading"``, ``"along"``, ``"pts.csv:across"``) used to hold groups.
    names : list of str
        The groups in words.
    assumed : ndarray, shape (G,)
        Assumed standard deviation of each group, SI units (m, rad).
    kinds : list of str
        ``"length"`` or ``"angle"`` per group (for display).
    ids : ndarray of int, shape (K, m)
        Measurement (row) of each residual: the outlier test takes a row's residuals together.
    id_names : list of str
        The rows in words (``"row 17"``, ``"pts.csv row 17"``), one per id.
    """

    labels: np.ndarray
    keys: list
    names: list
    assumed: np.ndarray
    kinds: list
    ids: np.ndarray
    id_names: list

    @classmethod
    def single(cls, shape, key, name, assumed, kind, rows=None, prefix=""):
        """One group for every residual of a (K, m) problem, one id per row.

        Parameters
        ----------
        shape : tuple
            ``(K, m)``.
        key, name : str
            The group's short name and words.
        assumed : float
            Assumed standard deviation, SI.
        kind : str
            ``"length"`` or ``"angle"``.
        rows : array_like of int, optional
            File row of each measurement (default 1..K).
        prefix : str, optional
            In front of the row names (``"pts.csv "``).

        Returns
        -------
        NoiseGroups
            The groups.
        """
        K, m = shape
        return cls(np.zeros((K, m), int), [key], [name], np.array([float(assumed)]), [kind],
                   np.repeat(np.arange(K), m).reshape(K, m), row_names(rows, K, prefix))

    def prefixed(self, label: str, id_offset: int) -> NoiseGroups:
        """The same groups named for a file of a joint fit (``label:key``)."""
        return NoiseGroups(self.labels, [f"{label}:{k}" for k in self.keys],
                           [f"{n} ({label})" for n in self.names], self.assumed, self.kinds,
                           self.ids + id_offset, [f"{label} {n}" for n in self.id_names])


def row_names(rows, K: int, prefix: str = "") -> list[str]:
    """``"row N"`` per measurement (file rows when known, else 1..K)."""
    rows = np.arange(1, K + 1) if rows is None else np.asarray(rows).reshape(-1)
    return [f"{prefix}row {int(r)}" for r in rows]


def concat_groups(parts: list[NoiseGroups]) -> NoiseGroups:
    """Groups of residuals stacked as one column (a joint problem's ``(M, 1)`` rows)."""
    labels, ids, keys, names, assumed, kinds, id_names = [], [], [], [], [], [], []
    for g in parts:
        labels.append(g.labels.reshape(-1) + len(keys))
        ids.append(g.ids.reshape(-1))
        keys += g.keys
        names += g.names
        assumed.append(g.assumed)
        kinds += g.kinds
        id_names += g.id_names
    return NoiseGroups(np.concatenate(labels)[:, None], keys, names, np.concatenate(assumed),
                       kinds, np.concatenate(ids)[:, None], id_names)


def noise_groups_of(problem) -> NoiseGroups | None:
    """The problem's noise groups (its ``noise_groups()``), or None when it has none (its
    residuals are not whitened by a complete noise model: the paper's methods that take some
    measurements as exact)."""
    method = getattr(problem, "noise_groups", None)
    return method() if callable(method) else None


class Weighted:
    """A block problem with its residuals rescaled per noise group and per row.

    Residual ``i`` of group ``c`` is divided by ``sqrt(theta_c)``; the residuals of a row left
    out are multiplied by :data:`LEFT_OUT_WEIGHT`. Everything else is the wrapped problem's
    (attributes are looked up there).

    Parameters
    ----------
    problem : BlockProblem
        The problem, whitened by the assumed levels.
    groups : NoiseGroups
        Its groups.
    theta : array_like, shape (G,)
        Variance factors.
    kept : array_like of bool, shape (n_ids,)
        Rows used.
    weights : array_like, shape (n_ids,), optional
        Row weights of a robust fit (1: full weight).
    evaluations : Evaluations, optional
        The problem's evaluations shared by the reweighted problems of one fit.
    """

    def __init__(self, problem, groups: NoiseGroups, theta, kept, weights=None,
                 evaluations=None):
        self.problem, self.groups = problem, groups
        self.evaluations = evaluations if evaluations is not None \
            and evaluations.problem is problem else None
        self.theta = np.asarray(theta, float)
        self.kept = np.asarray(kept, bool)
        f = 1.0 / np.sqrt(self.theta[groups.labels])
        if weights is not None:         # a robust fit's row weights (variance divisors)
            f = f * np.sqrt(np.asarray(weights, float))[groups.ids]
        self.factor = np.where(self.kept[groups.ids], f, f * LEFT_OUT_WEIGHT)
        self.cost_floor = float(getattr(problem, "cost_floor", 0.0)) * float(
            np.min(self.factor) ** 2)

    def __getattr__(self, name):
        if name in ("problem", "groups", "theta", "kept", "factor", "evaluations"):
            raise AttributeError(name)
        return getattr(self.problem, name)

    def initial_state(self):
        return self.problem.initial_state()

    def global_values(self, state):
        return self.problem.global_values(state)

    def retract(self, state, du, dl):
        return self.problem.retract(state, du, dl)

    def evaluate(self, state, jacobian=True):
        source = self.problem if self.evaluations is None else self.evaluations
        r, Jg, Jl = source.evaluate(state, jacobian)
        f = self.factor
        r = r * f
        if not jacobian:
            return r, None, None
        Jg = Jg * f[..., None]
        Jl = None if Jl is None else Jl * f[..., None]
        return r, Jg, Jl

    def assumed_residuals(self, residuals) -> np.ndarray:
        """Residuals of this problem whitened by the assumed levels again (left-out rows
        unscaled)."""
        return np.asarray(residuals, float) / self.factor


class Evaluations:
    """A problem's last few evaluations, looked up by state (the same object; a problem's
    states are never modified, a step makes a new one).

    The rounds of :func:`fit` evaluate one state under several noise levels (a fit's end
    state is the start of the next refit at new levels, and each group's capacity is a hat
    matrix at it): the same residuals and Jacobians, which :class:`Weighted` only scales.
    Results are only read (:class:`Weighted` scales them into new arrays).
    """

    SIZE = 4

    def __init__(self, problem):
        self.problem = problem
        self._kept = []

    def evaluate(self, state, jacobian=True):
        for kept_state, kept_jacobian, out in self._kept:
            if kept_state is state and kept_jacobian == jacobian:
                return out
        out = self.problem.evaluate(state, jacobian)
        self._kept = [(state, jacobian, out)] + self._kept[:self.SIZE - 1]
        return out


def hat_factors(problem, result):
    """Square-root factors of the hat matrix of the linearised problem at the solution.

    ``H`` restricted to measurement ``k``'s residuals is ``L_k L_k^T + G_k G_k^T``
    (``L = Q1``: the local unknowns' own projection; ``G = Q2 U``: the fitted global
    directions with the local part removed); between measurements it is ``G_k G_j^T``.

    Parameters
    ----------
    problem : BlockProblem
        The problem that produced ``result``.
    result : CalibrationResult
        The estimate (its ``adjusted`` directions are the fitted ones).

    Returns
    -------
    L : ndarray, shape (K, m, d) or None
        Local factors (None without local unknowns).
    G : ndarray, shape (K, m, rank)
        Global factors.
    """
    L, G, _ = _linearised(problem, result)
    return L, G


def _linearised(problem, result):
    """:func:`hat_factors` and ``log det`` of the normal matrix of the fitted directions
    (local unknowns included): the REML likelihood's determinant term. The estimator's own
    factors when ``result`` is a fit of ``problem`` (the same Jacobian)."""
    rank = int(getattr(result, "adjusted", result.rank))
    lin = linearisation_of(result, problem)
    if lin is not None:
        (K, m), qr, U, s = lin.shape, lin.qr, lin.U, lin.s
        if lin.fitted is not None:      # with a prior: the posterior's fitted directions
            rank = int(lin.fitted)
    else:
        _, Jg, Jl = problem.evaluate(result.state)
        free = np.asarray(result.parameters.free, bool)
        scales = np.asarray(result.scales, float)
        Jg = np.asarray(Jg, float)[..., free] * scales[free]
        K, m, _ = Jg.shape
        if Jl is None or np.asarray(Jl).shape[-1] == 0:
            qr = None
            U, s = _data_factors(Jg.reshape(K * m, -1), result)
        else:
            Jl = np.asarray(Jl, float)
            d = Jl.shape[-1]
            Q, Rl = np.linalg.qr(Jl, mode="complete")
            qr = (Q[..., :d], Q[..., d:], Rl[..., :d, :])
            Jr = np.einsum("kmi,kmn->kin", qr[1], Jg)
            U, s = _data_factors(Jr.reshape(K * (m - d), -1), result)
    with np.errstate(divide="ignore"):
        if qr is None:
            return None, U[:, :rank].reshape(K, m, rank), float(np.sum(np.log(s[:rank] ** 2)))
        Q1, Q2, R1 = qr
        d = Q1.shape[-1]
        Ur = U[:, :rank].reshape(K, m - d, rank)
        logdet = float(np.sum(np.log(s[:rank] ** 2))
                       + np.sum(np.log(np.diagonal(R1, axis1=-2, axis2=-1) ** 2)))
    return Q1, np.einsum("kmi,kir->kmr", Q2, Ur), logdet


def _data_factors(rows, result):
    """``U`` (the data rows' part) and ``s`` of the scaled reduced Jacobian ``rows``, with
    the prior's rows of ``result``'s parameters appended when they have a prior (the
    posterior's hat matrix, as the estimator keeps it)."""
    prior = result.parameters.prior
    M = rows.shape[0]
    if prior is not None:
        free = np.asarray(result.parameters.free, bool)
        _, Ap, _ = prior.whitened(result.x, free, np.asarray(result.scales, float))
        rows = np.vstack([rows, Ap])
    U, s, _ = np.linalg.svd(rows, full_matrices=False)
    return U[:M], s


def _reml(weighted: Weighted, result, logdet: float) -> float:
    """REML log-likelihood (up to a constant) of the levels of ``weighted`` at its fit:
    ``-(sum log sigma_i^2 + log det(J^T J) + r^T r) / 2`` with ``sigma_i`` relative to the
    assumed level and ``J``, ``r`` whitened by the levels (``result`` is the fit of
    ``weighted``)."""
    r = np.asarray(result.residuals, float)
    return -0.5 * float(np.sum(-2.0 * np.log(weighted.factor)) + logdet + np.sum(r**2))


def _leverages(L, G) -> np.ndarray:
    h = np.sum(G**2, axis=-1)
    if L is not None:
        h = h + np.sum(L**2, axis=-1)
    return np.clip(h, 0.0, 1.0)


@dataclass
class NoiseEstimate:
    """The noise levels of a calibration: assumed, estimated (or held) and how well known.

    Attributes
    ----------
    keys, names, kinds : list of str
        The groups (:class:`NoiseGroups`).
    assumed : ndarray, shape (G,)
        Assumed standard deviations, SI.
    sigma : ndarray, shape (G,)
        Standard deviations used in the final fit, SI (estimated or assumed).
    std : ndarray, shape (G,)
        Standard deviation of ``sigma`` (NaN where not estimated), SI.
    redundancy : ndarray, shape (G,)
        Redundancy of each group's residuals (their share of the degrees of freedom).
    count : ndarray of int, shape (G,)
        Residuals per group (rows used).
    status : list of str
        ``"estimated"``, ``"held"`` (given by the user), ``"assumed"`` (too little
        redundancy) or ``"at most"`` (the other groups' levels leave it almost no
        redundancy: the data fit it almost exactly and bound its level from above only).
    iterations : int
        Reweighted fits.
    capacity : ndarray, shape (G,), optional
        Redundancy each group would have were its level far above the others' (what decides
        ``"assumed"``: below :data:`MIN_REDUNDANCY`); NaN where not computed (held).
    """

    keys: list
    names: list
    kinds: list
    assumed: np.ndarray
    sigma: np.ndarray
    std: np.ndarray
    redundancy: np.ndarray
    count: np.ndarray
    status: list
    iterations: int = 0
    capacity: np.ndarray | None = None

    @property
    def estimated(self) -> bool:
        """Whether any level was estimated (or bounded) from the data."""
        return "estimated" in self.status or "at most" in self.status

    @property
    def ratio(self) -> np.ndarray:
        """Level used / level assumed, per group."""
        return self.sigma / self.assumed

    def as_dict(self, length_factor: float = 1e-6, angle_factor: float = 1e-6,
                units: tuple = ("um", "urad")) -> dict:
        """JSON-ready levels in display units.

        Parameters
        ----------
        length_factor, angle_factor : float, optional
            SI value of one display unit (1e-6: um and urad).
        units : tuple of str, optional
            The display units' names.

        Returns
        -------
        dict
            ``{"estimated": bool, "groups": [{key, name, unit, assumed, sigma, std,
            ratio, redundancy, capacity, count, status}], "min_redundancy", "method"}``.
        """
        out = []
        capacity = (np.full(len(self.keys), np.nan) if self.capacity is None
                    else np.asarray(self.capacity, float))
        for i, key in enumerate(self.keys):
            f, unit = ((length_factor, units[0]) if self.kinds[i] == "length"
                       else (angle_factor, units[1]))
            out.append({
                "key": key, "name": self.names[i], "unit": unit,
                "assumed": float(self.assumed[i] / f), "sigma": float(self.sigma[i] / f),
                "std": float(self.std[i] / f) if np.isfinite(self.std[i]) else None,
                "ratio": float(self.ratio[i]), "redundancy": float(self.redundancy[i]),
                "capacity": float(capacity[i]) if np.isfinite(capacity[i]) else None,
                "count": int(self.count[i]), "status": self.status[i]})
        return {"estimated": self.estimated, "groups": out,
                "min_redundancy": MIN_REDUNDANCY,
                "method": "variance components from the residuals (REML, Helmert's "
                          "iteration); assumed levels where the redundancy is too small",
                "iterations": int(self.iterations)}

    def lines(self, length_factor: float = 1e-6, angle_factor: float = 1e-6,
              units: tuple = ("um", "urad")) -> list[str]:
        """One line per group, e.g. ``"tracker across the beam: 7.02 +- 0.21 um (assumed
        13.5 um; estimated, redundancy 560)"``."""
        return self.lines_of(self.as_dict(length_factor, angle_factor, units))

    @staticmethod
    def lines_of(levels: dict) -> list[str]:
        """:meth:`lines` of a report's ``noise_model`` section (:meth:`as_dict`)."""
        out = []
        for g in levels["groups"]:
            pm = f" +- {g['std']:.2g}" if g["std"] is not None else ""
            why = {"estimated": f"estimated, redundancy {g['redundancy']:.0f}",
                   "at most": "at most: the data fit these almost exactly, they bound "
                              "the level from above only",
                   "held": "held: given",
                   "assumed": "assumed: redundancy {:.1f} < {:g}, were its level far above "
                              "the others'".format(
                                  g["redundancy"] if g.get("capacity") is None
                                  else g["capacity"], levels["min_redundancy"])}[g["status"]]
            out.append(f"{g['name']}: {g['sigma']:.3g}{pm} {g['unit']} (assumed "
                       f"{g['assumed']:.3g} {g['unit']}; {why})")
        return out


@dataclass
class OutlierTest:
    """Rows whose residuals the noise does not explain (Baarda's test, whole rows).

    Attributes
    ----------
    statistic : ndarray, shape (n_ids,)
        ``r_S^T (I - H_SS)^+ r_S`` per row (left-out rows: against their prediction).
    dof : ndarray of int, shape (n_ids,)
        Its degrees of freedom.
    p : ndarray, shape (n_ids,)
        Chi-square p-values.
    threshold : float
        Rows with ``p`` below this are outliers (``alpha / rows``).
    kept : ndarray of bool, shape (n_ids,)
        Rows used in the final fit.
    names : list of str
        The rows in words.
    named : ndarray of int, optional
        The rows named, when they come from the robust rounds (the fit kept every row):
        what ``robust=True`` leaves out; default the rows whose ``p`` is below the
        threshold.
    """

    statistic: np.ndarray
    dof: np.ndarray
    p: np.ndarray
    threshold: float
    kept: np.ndarray
    names: list = field(default_factory=list)
    named: np.ndarray | None = None

    @property
    def flagged(self) -> np.ndarray:
        """Indices of the rows the test names (used or left out)."""
        if self.named is not None:
            return np.asarray(self.named, int)
        return np.flatnonzero((self.p < self.threshold) & (self.dof > 0))

    @property
    def left_out(self) -> np.ndarray:
        """Indices of the rows left out of the fit."""
        return np.flatnonzero(~self.kept)

    def as_dict(self) -> dict:
        """JSON-ready: the named rows with their statistics."""
        def row(i):
            return {"row": self.names[i], "statistic": float(self.statistic[i]),
                    "dof": int(self.dof[i]), "p": float(self.p[i]),
                    "left_out": bool(not self.kept[i])}
        return {"test": "chi-square of each row's residuals against the noise (Baarda), "
                        "Bonferroni over the rows",
                "alpha": OUTLIER_ALPHA, "threshold_p": float(self.threshold),
                "flagged": [row(i) for i in self.flagged],
                "left_out": [self.names[i] for i in self.left_out]}


class _RowSpaces:
    """What Baarda's test of each row needs besides the residuals: the eigen-decomposition of
    the matrix whose pseudo-inverse weighs the row's residuals (kept: ``I - H_SS``; left out:
    ``I`` plus the uncertainty of its prediction). It depends on the fit only (hat factors,
    rows kept), so one fit's tests (plain and on the robust levels) share it."""

    def __init__(self, weighted: Weighted, L, G):
        groups = weighted.groups
        self.kept = weighted.kept
        ids = groups.ids.reshape(-1)
        self.n_ids = n_ids = len(groups.id_names)
        K, m = groups.labels.shape
        self.Gf = G.reshape(K * m, -1)
        self.Lf = None if L is None else L.reshape(K * m, -1)
        self.block = np.repeat(np.arange(K), m)
        self.order = np.argsort(ids, kind="stable")
        self.starts = np.searchsorted(ids[self.order], np.arange(n_ids + 1))
        sizes = np.diff(self.starts)
        self.batched = bool(n_ids and np.all(sizes == sizes[0]) and sizes[0] > 0)
        self._rows = {}
        if not self.batched:
            return
        # every row has as many residuals (the usual case): all rows at once, as row() below
        Gf, Lf, block = self.Gf, self.Lf, self.block
        S = self.order.reshape(n_ids, sizes[0])                      # (rows, n)
        M = np.broadcast_to(np.eye(sizes[0]), (n_ids, sizes[0], sizes[0])).copy()
        if Lf is not None:
            same = block[S][:, :, None] == block[S][:, None, :]
            M -= (Lf[S] @ np.swapaxes(Lf[S], 1, 2)) * same
        Gs = Gf[S] / np.where(self.kept, 1.0, LEFT_OUT_WEIGHT)[:, None, None]
        # kept: minus its part of the hat matrix; left out: its residual against the
        # prediction (uncertainty of the fit added; its rows of the factors carry the
        # left-out weight)
        M += np.where(self.kept, -1.0, 1.0)[:, None, None] * (Gs @ np.swapaxes(Gs, 1, 2))
        w, V = np.linalg.eigh(0.5 * (M + np.swapaxes(M, 1, 2)))
        good = w > 1e-8 * np.maximum(1.0, w.max(axis=1, initial=0.0))[:, None]
        self.S, self.w, self.V, self.good = S, w, V, good

    def row(self, i):
        """``(S, w, V, good)`` of row ``i`` alone (residual indices, eigenvalues, vectors,
        the eigenvalues counted)."""
        if i not in self._rows:
            S = self.order[self.starts[i]:self.starts[i + 1]]
            Gf, Lf, block = self.Gf, self.Lf, self.block
            M = np.eye(len(S))
            if Lf is not None:
                same = block[S][:, None] == block[S][None, :]
                M -= (Lf[S] @ Lf[S].T) * same
            if self.kept[i]:
                M -= Gf[S] @ Gf[S].T
            else:   # left out: its residual against the prediction (uncertainty of the fit
                # added; its rows of the factors carry the left-out weight)
                Gs = Gf[S] / LEFT_OUT_WEIGHT
                M += Gs @ Gs.T
            w, V = np.linalg.eigh(0.5 * (M + M.T))
            good = w > 1e-8 * max(1.0, float(w.max(initial=0.0)))
            self._rows[i] = (S, w, V, good)
        return self._rows[i]

    def statistics(self, r):
        """Each row's ``r_S^T M^+ r_S`` and its degrees of freedom (0, 0 where a residual is
        not finite or the row has none)."""
        n_ids = self.n_ids
        if self.batched:
            S, w, V, good = self.S, self.w, self.V, self.good
            rs = r[S]
            finite = np.all(np.isfinite(rs), axis=1)
            z = np.einsum("kij,ki->kj", V, np.where(finite[:, None], rs, 0.0))
            with np.errstate(divide="ignore", invalid="ignore"):
                terms = np.where(good, z**2 / np.where(good, w, 1.0), 0.0)
            stat = np.where(finite, terms.sum(axis=1), 0.0)
            dof = np.where(finite, good.sum(axis=1), 0).astype(int)
            return stat, dof
        stat = np.zeros(n_ids)
        dof = np.zeros(n_ids, int)
        for i in range(n_ids):
            S = self.order[self.starts[i]:self.starts[i + 1]]
            if len(S) == 0 or not np.all(np.isfinite(r[S])):
                continue
            _, w, V, good = self.row(i)
            z = V[:, good].T @ r[S]
            stat[i] = float(np.sum(z**2 / w[good]))
            dof[i] = int(good.sum())
        return stat, dof


def _outlier_test(weighted: Weighted, result, L, G, alpha: float,
                  robust_scale: bool = False, spaces: _RowSpaces | None = None) -> OutlierTest:
    """Baarda's test of every row (see the module docstring). ``robust_scale``: each group's
    residuals over its robust level (median of ``r_i^2 / (1 - h_ii)``) where that is below
    :data:`ROBUST_SHRINK` of the estimated one (in variance; clean data's medians scatter far
    less): gross errors in the fit inflate the estimate and can hide every one of them (the
    first round's candidates; later rounds re-admit what their prediction explains).
    ``spaces``: the rows' :class:`_RowSpaces` of this fit, when already made."""
    groups = weighted.groups
    ids = groups.ids.reshape(-1)
    r = np.asarray(result.residuals, float).reshape(-1) / np.where(
        weighted.kept[ids], 1.0, LEFT_OUT_WEIGHT)
    if robust_scale:
        h = _leverages(L, G).reshape(-1)
        lab = groups.labels.reshape(-1)
        used = weighted.kept[ids] & np.isfinite(r) & (1.0 - h > 1e-6)
        scale = np.ones(len(groups.keys))
        for c in range(len(groups.keys)):
            z = r[used & (lab == c)] ** 2 / (1.0 - h[used & (lab == c)])
            rho = float(np.median(z)) / MEDIAN_CHI2_1 if z.size >= 10 else 1.0
            if rho < ROBUST_SHRINK:
                scale[c] = max(rho, 1e-4)
        r = r / np.sqrt(scale[lab])
    if spaces is None:
        spaces = _RowSpaces(weighted, L, G)
    stat, dof = spaces.statistics(r)
    return _outlier_verdict(stat, dof, alpha, weighted, groups)


def _outlier_verdict(stat, dof, alpha: float, weighted: Weighted, groups) -> OutlierTest:
    """Each row's chi-square statistic against its degrees of freedom, Bonferroni over the
    rows tested."""
    p = np.where(dof > 0, chi2_sf(stat, np.maximum(dof, 1)), 1.0)
    n_tested = max(int(np.sum(dof > 0)), 1)
    return OutlierTest(stat, dof, p, alpha / n_tested, weighted.kept.copy(),
                       list(groups.id_names))


#: iterations of the robust (Tukey-weighted) fit
IRLS_ITER = 20
#: a group whose level came out this many times the assumed one (std) makes the fit suspect:
#: a robust fit looks for gross errors the least-squares fit bent to (a few rows for many
#: unknowns hide them from every test of the residuals)
MAX_NOISE_RATIO = 3.0


def _robust_candidates(problem, groups: NoiseGroups, theta, state, rtol, options,
                       alpha: float, out=None, evaluations=None) -> np.ndarray:
    """Rows a robust fit finds far beyond the others: iteratively reweighted least squares
    with Tukey's biweight on each row's chi-square per degree of freedom, over a median scale
    (a least-squares fit bends to gross errors, most with few rows per unknown; the robust one
    does not), its first fit without the rows of ``out``. Returns a mask over the rows."""
    n = len(groups.id_names)
    ids = groups.ids.reshape(-1)
    d = int(getattr(problem, "local_dof", 0) or 0)
    dof = np.maximum(np.bincount(ids, minlength=n) - d, 1)
    cut = chi2_ppf(1.0 - alpha / max(n, 1), dof) / dof
    med = chi2_ppf(0.5, dof) / dof
    f = 1.0 / np.sqrt(np.asarray(theta, float)[groups.labels]).reshape(-1)
    w = np.ones(n) if out is None else np.where(out, 0.0, 1.0)
    u = np.zeros(n)
    for _ in range(IRLS_ITER):
        weighted = Weighted(problem, groups, theta, np.ones(n, bool), np.maximum(w, 1e-12),
                            evaluations)
        result = _refit(weighted, state, rtol, options)
        state = result.state
        r, _, _ = problem.evaluate(state, jacobian=False)
        r = np.asarray(r, float).reshape(-1) * f
        ok = np.isfinite(r)
        z = np.bincount(ids[ok], r[ok] ** 2, minlength=n) / dof
        scale = float(np.median(z / med))
        if not scale > 0:
            break
        u = z / scale
        new = np.where(u < cut, (1.0 - u / cut) ** 2, 0.0)
        if np.max(np.abs(new - w)) < 1e-3:
            break
        w = new
    return u >= cut


def _hold_mask(groups: NoiseGroups, noise) -> np.ndarray:
    """Groups held at their assumed level: ``noise`` False/"fixed" holds all, True/"auto"
    none, a collection of keys (or key suffixes after ``label:``, or ``label:*`` for every
    group of a file) those."""
    G = len(groups.keys)
    if noise is False or noise == "fixed":
        return np.ones(G, bool)
    if noise is True or noise is None or noise == "auto":
        return np.zeros(G, bool)
    held = {str(k) for k in noise}
    prefixes = tuple(k[:-1] for k in held if k.endswith(":*"))
    return np.array([k in held or k.rsplit(":", 1)[-1] in held
                     or (bool(prefixes) and k.startswith(prefixes)) for k in groups.keys])


def fit(problem, noise="auto", robust: bool = False, alpha: float = OUTLIER_ALPHA,
        rtol: float = RTOL, state=None, left_out=None, fitted=None,
        **options) -> CalibrationResult:
    """Fit a calibration problem with its noise levels estimated from the residuals.

    Parameters
    ----------
    problem : BlockProblem
        The problem, whitened by the assumed levels. Without ``noise_groups()`` (a method
        that takes some measurements as exact) this is :func:`levenberg_marquardt` with the
        covariance scaled by the residual variance, as before.
    noise : {"auto", "fixed"} or bool or collection of str, optional
        ``"auto"`` (default): estimate every group with the redundancy for it (at least
        :data:`MIN_REDUNDANCY`); ``"fixed"``/False: hold all at the assumed levels (the
        covariance is then scaled by the overall residual variance, as without groups); a
        collection of group keys: hold those (the user gave them), estimate the others.
    robust : bool, optional
        Leave out the rows the outlier test names, and fit again (repeated until no new row
        is named).
    alpha : float, optional
        False-alarm rate of the outlier test over all rows.
    rtol : float, optional
        Rank tolerance.
    state : object, optional
        Start state.
    left_out : array_like of bool, shape (rows,), optional
        Rows a start strategy could not fit (the constraint link's): out of the plain fit and
        the first candidates of the outlier rounds, which bring back those the fit without
        them predicts. Without ``robust`` the rows the rounds keep out stay out; the other
        rows named are kept in the fit, as always.
    fitted : CalibrationResult, optional
        The :func:`levenberg_marquardt` fit of ``problem`` (with ``rtol`` and ``options``)
        that ended at ``state``, when it is where ``state`` comes from: a refit of the same
        problem from there (every level at its assumed value, every row in) is that fit when
        it converged (its Gauss-Newton step negligible), and is not made again.
    **options
        Passed to :func:`levenberg_marquardt`; ``absolute_sigma=True`` (the noise is known
        exactly) holds every level and does not scale the covariance.

    Returns
    -------
    CalibrationResult
        The final fit; ``residuals`` are whitened by the *assumed* levels (as for every
        problem) and ``residual_variance`` is their variance over the rows used
        (``chi2 / dof`` against the assumed noise); ``cost`` and the covariance are those of
        the fit with the levels used, ``dof`` without the left-out rows. Sets
        ``noise`` (:class:`NoiseEstimate` or None), ``outliers`` (:class:`OutlierTest` or
        None), ``robust``, ``weighted`` (the reweighted problem, or the problem
        itself), ``weighted_residuals`` (whitened by the levels used; left-out rows scaled
        by :data:`LEFT_OUT_WEIGHT`).
    """
    absolute = bool(options.pop("absolute_sigma", False))
    if absolute:        # the caller knows the noise exactly (Cramér-Rao covariances)
        noise = "fixed"
    groups = noise_groups_of(problem)
    if groups is None:
        result = levenberg_marquardt(problem, rtol=rtol, state=state, absolute_sigma=absolute,
                                     **options)
        result.noise, result.outliers = None, None
        result.weighted, result.weighted_residuals = problem, result.residuals
        return result
    G = len(groups.keys)
    held = _hold_mask(groups, noise)
    n_ids = len(groups.id_names)
    out = (np.zeros(n_ids, bool) if left_out is None
           else np.asarray(left_out, bool).reshape(n_ids))

    robust_first = None         # the first round's test on the robust levels, when made
    evaluations = Evaluations(problem)      # shared by the reweighted problems of this fit

    def rounds(n_rounds, state, candidates):
        nonlocal robust_first
        robust_first = None
        levels = _Levels(np.ones(G), held.copy(), np.zeros(G, bool))
        kept = np.ones(len(groups.id_names), bool)
        if candidates is not None and candidates.any() and (~candidates).any():
            kept = ~candidates          # the robust fit's candidates start out
        seen = [kept]                   # the sets fitted
        first = state
        for round_ in range(n_rounds):
            # every round from the start: a fit bent by gross errors can hold the next one,
            # without them, in its local minimum
            state = _estimate_levels(problem, groups, levels, kept, first, rtol, options,
                                     evaluations, fitted)
            weighted = Weighted(problem, groups, levels.theta, kept, evaluations=evaluations)
            estimated = bool(levels.estimated.any() or levels.bounded.any())
            result = _refit(weighted, state, rtol, options,
                            absolute_sigma=bool(estimated or absolute), fitted=fitted)
            state = result.state
            L, G_ = hat_factors(weighted, result)
            spaces = _RowSpaces(weighted, L, G_)       # both tests of this fit
            test = _outlier_test(weighted, result, L, G_, alpha, spaces=spaces)
            # the rows named now are out, the others in (a row left out in an earlier round
            # comes back when its prediction explains it); a set seen before ends the rounds.
            # The first round's candidates are judged on the robust levels (masking)
            if round_ or candidates is not None:
                named = test.flagged
            else:
                robust_first = _outlier_test(weighted, result, L, G_, alpha,
                                             robust_scale=True, spaces=spaces)
                named = robust_first.flagged
            new_kept = np.ones(len(kept), bool)
            new_kept[named] = False
            # never so many out that nothing is left to check the fit
            d = int(getattr(problem, "local_dof", 0) or 0)
            left = int(np.sum(new_kept[groups.ids])) - d * int(new_kept.sum())
            if left <= result.rank:
                break
            if (round_ + 1 == n_rounds or not new_kept.any()
                    or any(np.array_equal(new_kept, k) for k in seen)):
                break
            seen.append(new_kept)
            kept = new_kept
        return result, weighted, test, levels, kept, estimated, L, G_

    start = state
    # the plain fit (every row, levels estimated) decides whether to look for gross errors
    result, weighted, test, levels, kept, estimated, L, G_ = rounds(
        1, start, out if out.any() else None)
    suspect = (out.any() or test.flagged.size > 0
               or bool(np.any(levels.theta > MAX_NOISE_RATIO**2))
               or (robust_first if robust_first is not None else _outlier_test(
                   weighted, result, L, G_, alpha, robust_scale=True)).flagged.size)
    if suspect:
        # gross errors can bend a least-squares fit until no test names them (few rows for
        # many unknowns): the candidates of a robust fit start the rounds, which re-admit
        # what the fit without them predicts
        candidates = _robust_candidates(problem, groups, levels.theta, start, rtol,
                                        options, alpha, out if out.any() else None,
                                        evaluations)
        again = rounds(ROBUST_ROUNDS, start, candidates)
        if robust and np.any(~again[4] & ~out):
            # robust=True leaves out a row the plain fit keeps
            result, weighted, test, levels, kept, estimated, L, G_ = again
        else:
            # name what robust=True leaves out, keeping every row in the fit but those a
            # start strategy could not fit and the rounds keep out. A robust fit that keeps
            # the plain fit's rows IS the plain fit: the rounds' last fit of the same rows
            # started from other levels, and data that fix the geometry poorly can end
            # elsewhere from there
            robust_test, robust_kept = again[2], again[4]
            keep = ~(out & ~robust_kept)
            if not np.array_equal(keep, kept):
                result, weighted, _, levels, kept, estimated, L, G_ = rounds(1, start, ~keep)
            test = dataclasses.replace(robust_test, kept=keep.copy(),
                                       named=np.flatnonzero(~robust_kept))
    # degrees of freedom without the left-out rows' residuals (their own unknowns were fitted)
    used = kept[groups.ids]
    n_out = int(np.sum(~used))
    d = int(getattr(problem, "local_dof", 0) or 0)
    m = groups.labels.shape[1]
    fitted_variance = result.residual_variance
    result.dof = int(result.dof - n_out + d * (n_out // m))
    weighted_r = np.asarray(result.residuals, float)
    assumed_r = weighted.assumed_residuals(weighted_r)
    ok = used & np.isfinite(assumed_r)
    if n_out and not (estimated or absolute) and result.dof > 0:
        # the covariance was scaled with the left-out rows' (tiny) residuals counted
        scale = float(np.sum(weighted_r[ok] ** 2)) / result.dof / fitted_variance
        result.covariance = result.covariance * scale
        result.std = np.sqrt(np.clip(np.diag(result.covariance), 0, None))
    # downstream, residual_variance is the residuals' variance over the *assumed* noise
    result.residual_variance = (float(np.sum(assumed_r[ok] ** 2)) / result.dof
                                if result.dof > 0 else float("nan"))
    lab = groups.labels.reshape(-1)
    count = np.bincount(lab[ok.reshape(-1)], minlength=G)
    if G == 1 and levels.use is not None and np.array_equal(levels.use, ok):
        # one group: the hat matrix does not depend on its level, and these are the rows of
        # the last Helmert step: its matrix and redundancy
        S, red = levels.S, levels.red
    elif levels.estimated.any():
        S, red = helmert_matrix(L, G_, groups.labels, ok, G)
    else:   # no level estimated: its matrix would give no standard deviation
        S, red = None, redundancies(L, G_, groups.labels, ok, G)
    sigma = groups.assumed * np.sqrt(levels.theta)
    std = np.full(G, np.nan)
    est = np.flatnonzero(levels.estimated)
    if est.size:
        with np.errstate(all="ignore"):
            inv = np.linalg.pinv(S[np.ix_(est, est)], hermitian=True)
        std[est] = sigma[est] * np.sqrt(np.clip(np.diag(inv), 0, None) / 2.0)
    status = ["held" if levels.held[c] else "assumed" if levels.guessed[c]
              else "at most" if levels.bounded[c] else "estimated" for c in range(G)]
    result.noise = NoiseEstimate(list(groups.keys), list(groups.names), list(groups.kinds),
                                 groups.assumed.copy(), sigma, std, red, count, status,
                                 levels.iterations, levels.capacity.copy())
    result.outliers, result.weighted, result.weighted_residuals = test, weighted, weighted_r
    result.used, result.robust = used, bool(robust)
    # downstream, residuals are "measured - predicted over the assumed noise" for every problem
    result.residuals = assumed_r
    weighted.evaluations = None     # the problem handed out evaluates afresh
    return result


def helmert_matrix(L, G, labels, use, n_groups: int):
    """Helmert's matrix ``S_cd = sum_{i in c, j in d} M_ij^2`` of the residual-maker
    ``M = I - H`` and the groups' redundancies ``sum_{i in c} M_ii``.

    ``E[sum_{i in c} r_i^2] = sum_d S_cd phi_d`` when group ``d``'s true variance is
    ``phi_d`` times the one the residuals are whitened by: solving ``S phi = q`` is Helmert's
    variance-component estimate; ``2 S^-1`` its covariance.

    Parameters
    ----------
    L, G : ndarray
        :func:`hat_factors`.
    labels : ndarray of int, shape (K, m)
        Group of each residual.
    use : ndarray of bool, shape (K, m)
        Residuals counted (rows used, finite).
    n_groups : int
        Number of groups.

    Returns
    -------
    S : ndarray, shape (n_groups, n_groups)
    redundancy : ndarray, shape (n_groups,)
    """
    E, Ef, Gf, h, red = _redundancy_parts(L, G, labels, use, n_groups)
    # between any two residuals: (G_i . G_j)^2 summed over groups = tr(T_c T_d)
    # (T_c = G^T diag(E_c) G by matrix products: the three-operand einsum loops in C over
    # every residual and pair of directions, ~10x slower)
    T = np.stack([(Gf * Ef[:, c, None]).T @ Gf for c in range(n_groups)])
    S = np.einsum("crs,dsr->cd", T, T)
    if L is not None:
        # within a measurement the local unknowns add A = L L^T: (A + B)^2 - B^2 = A^2 + 2AB
        A = np.einsum("kid,kjd->kij", L, L)
        B = np.einsum("kir,kjr->kij", G, G)
        X = A * A + 2.0 * A * B
        S = S + np.einsum("kic,kij,kjd->cd", E, X, E)
    S = S + np.diag(Ef.T @ (1.0 - 2.0 * h))
    return S, red


def redundancies(L, G, labels, use, n_groups: int) -> np.ndarray:
    """The groups' redundancies ``sum_{i in c} M_ii`` alone: those of
    :func:`helmert_matrix`, without its matrix.

    Parameters
    ----------
    L, G, labels, use, n_groups
        As :func:`helmert_matrix`.

    Returns
    -------
    ndarray, shape (n_groups,)
        The redundancies.
    """
    return _redundancy_parts(L, G, labels, use, n_groups)[-1]


def _redundancy_parts(L, G, labels, use, n_groups: int):
    """Group indicators ``E`` (K, m, G) and flat ``Ef``, flat global factors ``Gf``, the
    leverages ``h`` and the groups' redundancies."""
    K, m = labels.shape
    E = np.zeros((K, m, n_groups))
    E[np.arange(K)[:, None], np.arange(m)[None, :], labels] = 1.0
    E *= np.asarray(use, bool)[..., None]
    Ef = E.reshape(K * m, n_groups)
    Gf = G.reshape(K * m, -1)
    h = np.sum(Gf**2, axis=1)
    if L is not None:
        h = h + np.sum(L.reshape(K * m, -1) ** 2, axis=1)
    h = np.clip(h, 0.0, 1.0)
    return E, Ef, Gf, h, Ef.T @ (1.0 - h)


#: a level is at least this share of the assumed one (std): exact (simulated) data would drive
#: it to the rounding of the residuals, where no fit converges; there it is "at most" this
MIN_LEVEL = 1e-3

#: at most this factor of change of a variance in one step (a level assumed far too small has
#: almost no redundancy at first: one step must not jump to infinity)
MAX_STEP = 1e4


def _helmert_step(S, red, q, free) -> np.ndarray:
    """Variance ratios ``phi`` of one step: Helmert's ``S phi = q`` for the free groups (the
    others held at 1); Förstner's ``q / red`` where that is not positive."""
    phi = np.ones(len(q))
    if not free.any():
        return phi
    f = np.flatnonzero(free)
    rhs = q[f] - S[np.ix_(f, ~free)].sum(axis=1)
    try:
        sol = np.linalg.solve(S[np.ix_(f, f)], rhs)
    except np.linalg.LinAlgError:
        sol = np.full(len(f), -1.0)
    fallback = q[f] / np.maximum(red[f], 1e-300)
    sol = np.where(np.isfinite(sol) & (sol > 0), sol, fallback)
    sol = np.where(sol > 0, sol, 1.0)
    phi[f] = np.clip(sol, 1.0 / MAX_STEP, MAX_STEP)
    return phi


@dataclass
class _Levels:
    """Variance factors of the groups and which are held (given) or guessed (too little
    redundancy: kept at the assumed level)."""

    theta: np.ndarray
    held: np.ndarray
    guessed: np.ndarray
    iterations: int = 0
    S: np.ndarray | None = None
    capacity: np.ndarray | None = None
    #: redundancies and rows used (K, m) of the last Helmert step (with ``S``)
    red: np.ndarray | None = None
    use: np.ndarray | None = None
    bounded: np.ndarray | None = None

    def __post_init__(self):
        if self.capacity is None:
            self.capacity = np.full(len(self.theta), np.nan)
        if self.bounded is None:
            self.bounded = np.zeros(len(self.theta), bool)

    @property
    def estimated(self) -> np.ndarray:
        return ~(self.held | self.guessed | self.bounded)


def _refit(weighted: Weighted, state, rtol, options, absolute_sigma: bool = False,
           fitted=None):
    """The estimator on the reweighted problem from ``state``. A state that is already the
    optimum up to rounding (exact data, a converged fit reweighted) may admit no step that
    lowers the cost on the first try: that is convergence, not a failure.

    ``fitted``: a fit that ended at ``state`` (see :func:`fit`). When ``weighted`` is its
    problem unchanged (every level at its assumed value, every row in: each factor exactly
    1) and the settings are its own, the refit would start where that fit found its
    Gauss-Newton step negligible and take only that step: ``fitted`` is the result (a copy).
    """
    if fitted is not None:
        again = _same_fit(weighted, state, rtol, options, absolute_sigma, fitted)
        if again is not None:
            return again
    first = state is None
    result = levenberg_marquardt(weighted, rtol=rtol, state=state,
                                 absolute_sigma=absolute_sigma, **options)
    if not first and result.status == 3 and result.nit == 1:
        result.status, result.success = 2, True
        result.message = "cost cannot decrease beyond rounding (converged)"
    return result


def _same_fit(weighted: Weighted, state, rtol, options, absolute_sigma, fitted):
    """A copy of ``fitted`` as the fit of ``weighted`` from ``state`` (:func:`_refit`), or
    None when that is not the same fit."""
    lin = getattr(fitted, "_linear", None)
    if (lin is None or state is None or state is not fitted.state or lin.state is not state
            or fitted.status != 1 or lin.problem is not weighted.problem
            or not np.all(weighted.factor == 1.0)
            or lin.settings != settings_of(rtol, absolute_sigma, **options)):
        return None
    again = dataclasses.replace(
        fitted, x=fitted.x.copy(), residuals=np.array(fitted.residuals, float),
        covariance=fitted.covariance.copy(), std=fitted.std.copy(), **blank_details())
    # its factors are those of the reweighted problem (each factor 1: the same Jacobian)
    again._linear = Linearisation(weighted, state, lin.shape, lin.qr, lin.U, lin.s,
                                  lin.settings, lin.fitted)
    return again


def _estimate_levels(problem, groups: NoiseGroups, levels: _Levels, kept, state, rtol,
                     options, evaluations=None, fitted=None):
    """Helmert's iteration to convergence (see the module docstring), updating ``levels``
    in place. First, each group's *capacity* (its redundancy were its level far above the
    others') decides whether the data can check it at all: below :data:`MIN_REDUNDANCY` it
    keeps its assumed level. A Helmert step that lowers the REML likelihood (it can overshoot
    into another basin when a group starts with almost no redundancy) is replaced by
    Förstner's smaller one from the previous levels. Returns the last fit's state."""
    G = len(groups.keys)
    lab = groups.labels.reshape(-1)
    # which groups the data can check depends on the rows used: decided afresh (a round
    # that left many rows out must not keep a level assumed once they are back)
    levels.guessed[:] = False
    levels.bounded[:] = False
    previous = None         # (theta, likelihood, state, q, red) of the last accepted levels
    for it in range(VCE_MAX_ITER):
        if not levels.estimated.any():
            return state
        weighted = Weighted(problem, groups, levels.theta, kept, evaluations=evaluations)
        result = _refit(weighted, state, rtol, options, fitted=fitted)
        levels.iterations += 1
        L, Gf, logdet = _linearised(weighted, result)
        likelihood = _reml(weighted, result, logdet)
        if previous is not None and likelihood < previous[1] - 1e-9 * abs(previous[1]):
            theta0, _, state0, q0, red0 = previous
            step = np.ones(G)
            f = levels.estimated & (red0 > 0)
            step[f] = np.clip(q0[f] / red0[f], 1.0 / MAX_STEP, MAX_STEP)
            levels.theta = theta0 * step
            state = state0
            previous = (theta0, -np.inf, state0, q0, red0)  # accept the next step whatever
            continue
        state = result.state
        if it == 0:
            # a group is estimable when the data could check it: its redundancy were
            # its level far above the others' (not at the assumed level, where a group
            # assumed far too precise is fitted almost exactly)
            for c in np.flatnonzero(levels.estimated):
                if G == 1:      # one group: scaling its level scales every row alike, and
                    # leaves the hat matrix as it is
                    h = _leverages(L, Gf).reshape(-1)
                else:
                    theta = levels.theta.copy()
                    theta[c] *= 1e6
                    alone = Weighted(problem, groups, theta, kept, evaluations=evaluations)
                    h = _leverages(*hat_factors(alone, result)).reshape(-1)
                use = kept[groups.ids.reshape(-1)] & (lab == c)
                levels.capacity[c] = float(np.sum(1.0 - h[use]))
            levels.guessed |= levels.estimated & (levels.capacity < MIN_REDUNDANCY)
            levels.theta[levels.guessed] = 1.0
            if not levels.estimated.any():
                return state
        r = np.asarray(result.residuals, float).reshape(-1)
        use = kept[groups.ids.reshape(-1)] & np.isfinite(r)
        S, red = helmert_matrix(L, Gf, groups.labels, use.reshape(groups.labels.shape), G)
        q = np.bincount(lab[use], r[use] ** 2, minlength=G)
        previous = (levels.theta.copy(), likelihood, state, q, red)
        new = levels.theta * _helmert_step(S, red, q, levels.estimated)
        # a group the others' levels leave little redundancy (below MIN_REDUNDANCY) and whose
        # level keeps falling (by 5 % or more per step) is heading for the boundary: the
        # data fit it ever more exactly and bound its level from above only; held there
        bound = levels.estimated & (red < MIN_REDUNDANCY) & (new < 0.95 * levels.theta)
        floor = levels.estimated & (new <= MIN_LEVEL**2)
        new[floor] = MIN_LEVEL**2
        bound |= floor
        new[bound] = levels.theta[bound]
        levels.bounded |= bound
        levels.S, levels.red, levels.use = S, red, use.reshape(groups.labels.shape)
        step = new / levels.theta
        change = float(np.max(np.abs(np.log(step)), initial=0.0))
        levels.theta = new
        if change < VCE_TOL:
            break
        if G == 1 and not bound.any() and 1.0 / MAX_STEP < step[0] < MAX_STEP:
            # one group: its new level scales every residual alike, which moves no optimum
            # and leaves the hat matrix as it is; the fit at the new level is this one, and
            # its step would be exactly 1 (converged) - counted, not refitted
            levels.iterations += 1
            break
    return state
