"""Parameter registry: names such as ``chain3.alpha`` mapped to positions of one vector.

Nobody slices a parameter vector by position: machines, measurement models and reports ask the
registry (:meth:`ParameterSet.index`, :meth:`ParameterSet.indices`). Every parameter has a
*kind* that fixes its internal unit and its column scaling in identification Jacobians:

========  ==============  ===========================================
kind      internal unit   scaled by
========  ==============  ===========================================
length    m               the machine's characteristic length
angle     rad             1
ratio     1               1 (dimensionless, e.g. a gain error)
========  ==============  ===========================================
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

#: ``ratio``: a gain or other factor (its change shown relative); ``slope``: dz/dx of a plane
#: (a bed's tilt, its change shown absolute)
KINDS = ("length", "angle", "ratio", "slope")


@dataclass(frozen=True)
class Prior:
    """Build tolerances of a parameter set: Gaussian priors on linear combinations of it.

    Row ``j`` says ``matrix[j] @ u ~ N(mean[j], std[j]^2)`` (internal units): a parameter's
    tolerance about its nominal is a row with a single 1; "the three arms equal to within
    0.3 mm" is three rows of each arm minus their mean. An estimator with a prior maximises
    the posterior (SPEC 9: the rows are appended to the whitened residuals).

    Parameters
    ----------
    names : sequence of str
        One label per row (the parameter, or the combination in words).
    matrix : array_like, shape (p, n)
        Coefficients over the parameter set's ``n`` parameters.
    mean : array_like, shape (p,)
        The nominal value of each row, internal units.
    std : array_like, shape (p,)
        The tolerance (prior standard deviation) of each row, internal units, > 0.
    key : sequence of str, optional
        The machine file's key each row comes from (``tolerances.arm_trim``), for messages.
    """

    names: tuple[str, ...]
    matrix: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    key: tuple[str, ...] = ()

    def __post_init__(self):
        names = tuple(self.names)
        matrix = np.array(self.matrix, float).reshape(len(names), -1)
        mean = np.array(self.mean, float).reshape(-1)
        std = np.array(self.std, float).reshape(-1)
        key = tuple(self.key) or names
        if not (len(names) == len(mean) == len(std) == len(key)):
            raise ValueError("a prior's names, mean, std and key must have one entry per row")
        if not np.all(np.isfinite(std) & (std > 0)):
            raise ValueError("a prior's standard deviations must be finite and positive")
        for a in (matrix, mean, std):
            a.setflags(write=False)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "matrix", matrix)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)
        object.__setattr__(self, "key", key)

    def __len__(self) -> int:
        return len(self.names)

    @classmethod
    def about(cls, parameters: ParameterSet, rows) -> Prior | None:
        """A prior of rows given by parameter names, about the parameters' present values.

        Parameters
        ----------
        parameters : ParameterSet
            The set (its values are the nominal).
        rows : iterable of (label, {name: coefficient}, std, key)
            One row each; ``std`` internal units.

        Returns
        -------
        Prior or None
            None without rows.
        """
        rows = list(rows)
        if not rows:
            return None
        A = np.zeros((len(rows), len(parameters)))
        for j, (_, coefficients, _, _) in enumerate(rows):
            for name, c in coefficients.items():
                A[j, parameters.index(name)] += c
        return cls(tuple(r[0] for r in rows), A, A @ parameters.values,
                   [r[2] for r in rows], tuple(r[3] for r in rows))

    def whitened(self, values, free, scales) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The prior's rows as whitened residuals and a Jacobian in scaled free columns.

        Parameters
        ----------
        values : array_like, shape (n,)
            Parameter values.
        free : array_like of bool, shape (n,)
            The free parameters.
        scales : array_like, shape (n,)
            Column scales.

        Returns
        -------
        residuals : ndarray, shape (p',)
            ``(matrix u - mean) / std`` of the rows that involve a free parameter.
        jacobian : ndarray, shape (p', n_free)
            Their derivatives in scaled free columns.
        rows : ndarray of int, shape (p',)
            Which rows of the prior those are.
        """
        free = np.asarray(free, bool)
        A = self.matrix[:, free] * np.asarray(scales, float)[free]
        rows = np.flatnonzero(np.any(A != 0, axis=1))
        r = (self.matrix[rows] @ np.asarray(values, float) - self.mean[rows]) / self.std[rows]
        return r, A[rows] / self.std[rows, None], rows

    def extended(self, n_more: int) -> Prior:
        """The same rows over a parameter set with ``n_more`` parameters appended."""
        return Prior(self.names, np.hstack([self.matrix, np.zeros((len(self), n_more))]),
                     self.mean, self.std, self.key)


@dataclass(frozen=True)
class ParameterSet:
    """Ordered, named parameters with kinds, values and fixed/free flags.

    Parameters
    ----------
    names : sequence of str
        Unique dotted names, e.g. ``chain1.b.x``.
    kinds : sequence of str
        ``'length'``, ``'angle'`` or ``'ratio'`` for each name.
    values : array_like, shape (n,)
        Values in internal units (m, rad).
    fixed : array_like of bool, shape (n,), optional
        True where a calibration must not change the parameter.
    prior : Prior, optional
        Build tolerances (SPEC 9): the fit is then maximum a posteriori. Kept by every
        derived set.
    """

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    values: np.ndarray
    fixed: np.ndarray = field(default=None)  # type: ignore[assignment]
    prior: Prior | None = None

    def __post_init__(self):
        names = tuple(self.names)
        kinds = tuple(self.kinds)
        values = np.array(self.values, dtype=float).reshape(-1)
        fixed = (np.zeros(len(names), bool) if self.fixed is None
                 else np.array(self.fixed, dtype=bool).reshape(-1))
        if not (len(names) == len(kinds) == len(values) == len(fixed)):
            raise ValueError("names, kinds, values and fixed must have the same length")
        if len(set(names)) != len(names):
            raise ValueError("parameter names must be unique")
        if self.prior is not None and self.prior.matrix.shape[1] != len(names):
            raise ValueError("a prior's matrix must have one column per parameter")
        bad = [k for k in kinds if k not in KINDS]
        if bad:
            raise ValueError(f"unknown parameter kind(s) {bad}; expected one of {KINDS}")
        values.setflags(write=False)
        fixed.setflags(write=False)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "kinds", kinds)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "fixed", fixed)
        object.__setattr__(self, "_lookup", {n: i for i, n in enumerate(names)})

    def __len__(self) -> int:
        return len(self.names)

    # -- lookup ---------------------------------------------------------------------------
    def index(self, name: str) -> int:
        """Position of one parameter; KeyError names the unknown parameter."""
        try:
            return self._lookup[name]  # type: ignore[attr-defined]
        except KeyError:
            raise KeyError(f"unknown parameter {name!r}") from None

    def indices(self, names: str | Iterable[str]) -> np.ndarray:
        """Positions of parameters given by full names or by a group prefix.

        ``indices("chain2.b")`` gives the three positions of ``chain2.b.x/y/z``;
        ``indices(["chain1.l", "chain2.l"])`` gives two positions.
        """
        if isinstance(names, str):
            if names in self._lookup:  # type: ignore[attr-defined]
                return np.array([self._lookup[names]])  # type: ignore[attr-defined]
            prefix = names + "."
            out = [i for i, n in enumerate(self.names) if n.startswith(prefix)]
            if not out:
                raise KeyError(f"unknown parameter or group {names!r}")
            return np.array(out)
        return np.concatenate([self.indices(n) for n in names]) if names else np.array([], int)

    def get(self, name: str) -> np.ndarray | float:
        """Value of a parameter (float) or a group (array)."""
        idx = self.indices(name)
        return float(self.values[idx[0]]) if name in self._lookup else self.values[idx]  # type: ignore[attr-defined]

    # -- derived sets ---------------------------------------------------------------------
    def with_values(self, values) -> ParameterSet:
        """Same names, flags and prior, new values."""
        return ParameterSet(self.names, self.kinds, values, self.fixed, self.prior)

    def with_fixed_mask(self, fixed) -> ParameterSet:
        """Same names, values and prior; these fixed flags (array of bool, shape (n,))."""
        return ParameterSet(self.names, self.kinds, self.values, fixed, self.prior)

    def with_prior(self, prior: Prior | None) -> ParameterSet:
        """Same names, values and flags; this prior (None: none)."""
        return ParameterSet(self.names, self.kinds, self.values, self.fixed, prior)

    def with_fixed(self, names: str | Iterable[str], fixed: bool = True) -> ParameterSet:
        """Copy with the named parameters (or groups) fixed or freed."""
        f = self.fixed.copy()
        f[self.indices(names)] = fixed
        return ParameterSet(self.names, self.kinds, self.values, f, self.prior)

    def concat(self, other: ParameterSet) -> ParameterSet:
        """This set followed by ``other`` (names must not clash; priors kept, stacked)."""
        prior = None
        if self.prior is not None or other.prior is not None:
            parts = []
            if self.prior is not None:
                parts.append(self.prior.extended(len(other)))
            if other.prior is not None:
                o = other.prior
                parts.append(Prior(o.names, np.hstack([np.zeros((len(o), len(self))),
                                                       o.matrix]), o.mean, o.std, o.key))
            prior = parts[0] if len(parts) == 1 else Prior(
                sum((p.names for p in parts), ()), np.vstack([p.matrix for p in parts]),
                np.concatenate([p.mean for p in parts]),
                np.concatenate([p.std for p in parts]), sum((p.key for p in parts), ()))
        return ParameterSet(self.names + other.names, self.kinds + other.kinds,
                            np.concatenate([self.values, other.values]),
                            np.concatenate([self.fixed, other.fixed]), prior)

    @property
    def free(self) -> np.ndarray:
        """Boolean mask of the free parameters."""
        return ~self.fixed

    def scales(self, characteristic_length: float) -> np.ndarray:
        """Column scale of each parameter: lengths by ``characteristic_length``, others by 1."""
        return np.where(np.array(self.kinds) == "length", characteristic_length, 1.0)

    # -- words ----------------------------------------------------------------------------
    def describe_direction(self, direction: Sequence[float], scales=None, top: int = 4,
                           rel: float = 0.15) -> str:
        """A direction in parameter space in words: ``"chain2.b.z - chain2.a0.z"``.

        ``direction`` is in *scaled* coordinates when ``scales`` is given (it is divided back
        for nothing: the scaled components decide which names are shown). Components below
        ``rel`` times the largest are dropped; at most ``top`` terms are listed.
        """
        d = np.asarray(direction, dtype=float)
        if scales is not None:
            d = d * 1.0  # scaled components are what carries the comparison
        big = np.max(np.abs(d)) if d.size else 0.0
        if big == 0:
            return "0"
        order = np.argsort(-np.abs(d))
        order = [i for i in order[:top] if abs(d[i]) >= rel * big]
        ref = d[order[0]]
        terms = []
        for j, i in enumerate(order):
            c = d[i] / abs(ref) * np.sign(ref)
            sign = "-" if c < 0 else "+"
            mag = abs(c)
            coef = "" if abs(mag - 1) < 0.05 else f"{mag:.2g} "
            if j == 0:
                terms.append(("-" if sign == "-" else "") + coef + self.names[i])
            else:
                terms.append(f" {sign} {coef}{self.names[i]}")
        more = " + ..." if np.sum(np.abs(d) >= rel * big) > top else ""
        return "".join(terms) + more
