"""Identifiability of parameters from a (reduced, scaled) identification Jacobian (SPEC 3)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..estimation.rank import MAX_STD, RTOL, Rank, rank_rule, weak_words
from ..parameters import ParameterSet


@dataclass
class NullDirection:
    """One explained group of unidentifiable directions, or one unexplained direction.

    Attributes
    ----------
    name : str
        The group's name, or the direction as a parameter combination
        (``"leg2.dl1 - 0.8 leg2.dtheta"``).
    dimension : int
        Number of directions it stands for.
    description : str
        What it means, in words.
    std : float or None, optional
        A weakly identifiable direction's standard deviation (scaled units) under the assumed
        noise; None for an unidentifiable one.
    """

    name: str
    dimension: int
    description: str
    std: float | None = None

    def as_dict(self) -> dict:
        """The direction as a JSON-ready dict.

        Returns
        -------
        dict
            ``name``, ``dimension`` and ``description``.
        """
        return {"name": self.name, "dimension": self.dimension, "description": self.description}


@dataclass
class IdentifiabilityReport:
    """Rank, named unidentifiable directions and observability indices (SPEC 3).

    Attributes
    ----------
    parameters : int
        Number of free parameters (columns of the Jacobian).
    identifiable : int
        Numerical rank: the number of identifiable directions (the weak ones included), by
        :func:`~pkmcal.estimation.rank.rank_rule`.
    singular_values : ndarray
        Singular values of the scaled reduced Jacobian, largest first.
    unidentifiable : list of NullDirection, optional
        The null space in words.
    observability : dict, optional
        O1..O5 (:func:`observability_indices`).
    condition_number : float, optional
        Largest over smallest nonzero (identified) singular value; inf when nothing is
        identifiable.
    hold_fixed : list of str, optional
        A minimal identifiable set: hold these (free) parameters at their nominal values and the
        others are identifiable (QR with column pivoting; empty when not computed).
    correlated : list of tuple, optional
        Parameter pairs ``(a, b, correlation)`` with ``|correlation| > 0.9`` in the
        pseudo-inverse covariance (identifiable part), largest first.
    weak : list of NullDirection, optional
        The weakly identifiable directions (counted in ``identifiable``): standard deviation
        under the assumed noise at least ``max_std`` (scaled units); a calibration leaves them
        at their start values.
    max_std : float or None, optional
        The weak-direction threshold (None: not applied).
    """

    parameters: int
    identifiable: int
    singular_values: np.ndarray
    unidentifiable: list[NullDirection] = field(default_factory=list)
    observability: dict = field(default_factory=dict)
    condition_number: float = float("nan")
    hold_fixed: list[str] = field(default_factory=list)
    correlated: list[tuple[str, str, float]] = field(default_factory=list)
    weak: list[NullDirection] = field(default_factory=list)
    max_std: float | None = None

    @property
    def weakly_identifiable(self) -> int:
        """Number of weakly identifiable directions (a part of ``identifiable``)."""
        return len(self.weak)

    @property
    def rank(self) -> Rank:
        """The counts as a :class:`~pkmcal.estimation.rank.Rank`."""
        return Rank(self.identifiable, self.weakly_identifiable, self.parameters,
                    self.max_std)

    def as_dict(self) -> dict:
        """The report as a JSON-ready dict (without the singular values).

        Returns
        -------
        dict
            ``parameters``, ``identifiable``, ``weakly_identifiable`` (how many of the
            identifiable directions are weak), ``max_std``, ``weak`` (dicts with ``name``,
            ``std``, ``description``), ``unidentifiable`` (list of dicts), ``observability``,
            ``condition_number``, ``hold_fixed`` and ``correlated`` (dicts with ``a``, ``b``,
            ``correlation``).
        """
        return {
            "parameters": self.parameters,
            "identifiable": self.identifiable,
            "weakly_identifiable": self.weakly_identifiable,
            "max_std": self.max_std,
            "weak": [{"name": d.name, "std": d.std, "description": d.description}
                     for d in self.weak],
            "unidentifiable": [d.as_dict() for d in self.unidentifiable],
            "observability": self.observability,
            "condition_number": self.condition_number,
            "hold_fixed": list(self.hold_fixed),
            "correlated": [{"a": a, "b": b, "correlation": c} for a, b, c in self.correlated],
        }

    def summary(self, max_pairs: int = 10) -> str:
        """The report in words.

        Parameters
        ----------
        max_pairs : int, optional
            Number of correlated pairs listed; the rest are counted.

        Returns
        -------
        str
            Several lines of text.
        """
        lines = [f"{self.rank.words()}."]
        for d in self.weak:
            lines.append(f"  - weakly: {d.name}: {d.description}")
        for d in self.unidentifiable:
            lines.append(f"  - {d.dimension} x {d.name}: {d.description}")
        if self.hold_fixed:
            lines.append(f"A minimal identifiable set: hold these {len(self.hold_fixed)} "
                         "parameters at their nominal values and identify the others: "
                         + ", ".join(self.hold_fixed))
        if self.correlated:
            lines.append(f"{len(self.correlated)} parameter pair(s) correlated beyond 0.9:")
            for a, b, c in self.correlated[:max_pairs]:
                lines.append(f"  - {a} ~ {b}: {c:+.3f}")
            if len(self.correlated) > max_pairs:
                lines.append(f"  ... and {len(self.correlated) - max_pairs} more")
        return "\n".join(lines)


def observability_indices(singular_values, n_rows: int = 1) -> dict:
    """O1..O5 of SPEC 3 on the nonzero singular values ``s1 >= ... >= sL`` of scaled J.

    ``O1 = (s1...sL)^(1/L) / sqrt(m)`` (D-optimality, ``m = n_rows``), ``O2 = sL/s1``,
    ``O3 = sL``, ``O4 = sL^2/s1``, ``O5 = 1 / sum(1/si)``.

    Parameters
    ----------
    singular_values : array_like
        Singular values in decreasing order (zeros are ignored).
    n_rows : int, optional
        Number of rows ``m`` of the Jacobian.

    Returns
    -------
    dict
        ``{"O1": ..., "O5": ...}`` as floats; all 0 without a nonzero singular value.
    """
    s = np.asarray(singular_values, float)
    s = s[s > 0]
    if s.size == 0:
        return {k: 0.0 for k in ("O1", "O2", "O3", "O4", "O5")}
    return {
        "O1": float(np.exp(np.mean(np.log(s))) / np.sqrt(n_rows)),
        "O2": float(s[-1] / s[0]),
        "O3": float(s[-1]),
        "O4": float(s[-1] ** 2 / s[0]),
        "O5": float(1.0 / np.sum(1.0 / s)),
    }


@dataclass(frozen=True)
class NullGroup:
    """A known group of unidentifiable directions, in words, with its tangent vectors.

    A gauge of frame rotations gives 3 tangents; "only ``db - da`` enters" gives one per
    coordinate.

    Attributes
    ----------
    name : str
        Short name of the group.
    description : str
        What it means, in words.
    tangents : ndarray, shape (n, k)
        Directions of the full parameter vector in *scaled* coordinates (the estimator's).
    """

    name: str
    description: str
    tangents: np.ndarray


def name_null_space(null_space, parameters: ParameterSet,
                    groups: Sequence[NullGroup] = ()) -> list[NullDirection]:
    """Explain unidentifiable directions by known groups first, then in named parameters.

    A group is reported with the number of its directions that lie in the null space;
    directions no group explains are described by their largest parameter components
    (``"leg2.dl1 - 0.8 leg2.dtheta"``).

    Parameters
    ----------
    null_space : array_like, shape (n, k)
        Orthonormal directions in scaled coordinates.
    parameters : ParameterSet
        Names of the ``n`` parameters.
    groups : sequence of NullGroup, optional
        Known groups, tried in order.

    Returns
    -------
    list of NullDirection
        The groups found, then one entry per unexplained direction.
    """
    N = np.asarray(null_space, float)
    out: list[NullDirection] = []
    if N.shape[1] == 0:
        return out
    remaining = N
    if groups:
        for group in groups:
            Q, _ = np.linalg.qr(np.asarray(group.tangents, float))
            s = np.linalg.svd(N.T @ Q, compute_uv=False)   # cosines of principal angles
            dim = int(np.sum(s > 1 - 1e-3))
            if dim:
                out.append(NullDirection(group.name, dim, group.description))
        Qall, _ = np.linalg.qr(np.column_stack([g.tangents for g in groups]))
        P = remaining - Qall @ (Qall.T @ remaining)
        U, s, _ = np.linalg.svd(P, full_matrices=False)
        remaining = U[:, s > 1e-3]
    for k in range(remaining.shape[1]):
        words = parameters.describe_direction(remaining[:, k])
        out.append(NullDirection(words, 1, "this combination of parameters changes no "
                                 "measurement: only the others can be identified"))
    return out


def name_weak_directions(result, parameters: ParameterSet) -> list[NullDirection]:
    """The weakly identifiable directions of a calibration result, in words.

    Each with its standard deviation (scaled units: a fraction of the characteristic length,
    or rad). They are counted among the identifiable directions (``result.rank``).

    Parameters
    ----------
    result : CalibrationResult
        Uses ``weak_space``, ``weak_std`` and ``max_std``.
    parameters : ParameterSet
        Names of the parameters.

    Returns
    -------
    list of NullDirection
        One entry per weak direction.
    """
    return weak_directions(result.weak_space, result.weak_std, parameters,
                           getattr(result, "max_std", MAX_STD))


def weak_directions(space, std, parameters: ParameterSet,
                    max_std: float | None = MAX_STD) -> list[NullDirection]:
    """Weakly identifiable directions in words, each with its standard deviation.

    Parameters
    ----------
    space : array_like, shape (n, w)
        The directions (scaled coordinates of the full parameter vector).
    std : array_like, shape (w,)
        Their standard deviations (scaled units).
    parameters : ParameterSet
        Names of the parameters.
    max_std : float or None, optional
        The threshold they exceed.

    Returns
    -------
    list of NullDirection
        One entry per direction (``std`` set), described the same way by every command.
    """
    space = np.asarray(space, float)
    out = []
    for k in range(space.shape[1]):
        out.append(NullDirection(
            parameters.describe_direction(space[:, k]), 1,
            f"weakly identifiable: standard deviation {float(std[k]):.2g} (scaled) with these "
            f"measurements ({weak_words(max_std)}), so it is counted as identifiable but left "
            "at its start value; spread the measurements more (all three directions, wider "
            "orientations)", std=float(std[k])))
    return out


def right_singular(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values ``s`` and all ``n`` right singular vectors ``Vt`` (n, n) of ``J`` (m, n).

    For a tall ``J`` the SVD is taken of the triangular factor of its QR decomposition: the
    same ``s`` and ``Vt``, without the (m, m) left factor a full SVD of ``J`` would build.
    """
    J = np.asarray(J, float)
    R = np.linalg.qr(J, mode="r") if J.shape[0] > J.shape[1] else J
    _, s, Vt = np.linalg.svd(R, full_matrices=True)
    return s, Vt


def analyze(jacobian_scaled, parameters: ParameterSet, rtol: float = RTOL,
            groups: Sequence[NullGroup] = (),
            max_std: float | None = None) -> IdentifiabilityReport:
    """Identifiability of the free parameters from a scaled (reduced) Jacobian.

    Parameters
    ----------
    jacobian_scaled : array_like, shape (M, n_free)
        Jacobian of the free parameters, columns scaled.
    parameters : ParameterSet
        All parameters (their ``free`` mask places the columns).
    rtol : float, optional
        Singular values at or below ``rtol`` times the largest count as zero
        (:func:`~pkmcal.estimation.rank.rank_rule`).
    groups : sequence of NullGroup, optional
        Known groups that name null directions first.
    max_std : float or None, optional
        Identifiable directions with a standard deviation ``1 / s_i`` (scaled units; the rows
        whitened by the assumed noise) of at least this are reported as weakly identifiable;
        None: none is.

    Returns
    -------
    IdentifiabilityReport
        Rank, weak directions, named null space, O1..O5 and condition number (``hold_fixed``
        and ``correlated`` are left empty).
    """
    J = np.asarray(jacobian_scaled, float)
    m = max(J.shape[0], 1)
    s, Vt = right_singular(J)
    decision = rank_rule(s, rtol, max_std, parameters=J.shape[1])
    rank, adjusted = decision.identifiable, decision.adjusted
    free_idx = np.flatnonzero(parameters.free)
    N = np.zeros((len(parameters), J.shape[1] - rank))
    N[free_idx] = Vt[rank:].T
    W = np.zeros((len(parameters), rank - adjusted))
    W[free_idx] = Vt[adjusted:rank].T
    report = IdentifiabilityReport(
        parameters=int(J.shape[1]), identifiable=rank, singular_values=s,
        unidentifiable=name_null_space(N, parameters, groups),
        observability=observability_indices(s[:rank], m),
        condition_number=float(s[0] / s[rank - 1]) if rank else float("inf"),
        weak=weak_directions(W, 1.0 / s[adjusted:rank], parameters, max_std),
        max_std=max_std,
    )
    return report
