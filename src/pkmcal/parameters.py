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
    """

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    values: np.ndarray
    fixed: np.ndarray = field(default=None)  # type: ignore[assignment]

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
        """Same names and flags, new values."""
        return ParameterSet(self.names, self.kinds, values, self.fixed)

    def with_fixed(self, names: str | Iterable[str], fixed: bool = True) -> ParameterSet:
        """Copy with the named parameters (or groups) fixed or freed."""
        f = self.fixed.copy()
        f[self.indices(names)] = fixed
        return ParameterSet(self.names, self.kinds, self.values, f)

    def concat(self, other: ParameterSet) -> ParameterSet:
        """This set followed by ``other`` (names must not clash)."""
        return ParameterSet(self.names + other.names, self.kinds + other.kinds,
                            np.concatenate([self.values, other.values]),
                            np.concatenate([self.fixed, other.fixed]))

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
