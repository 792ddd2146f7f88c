"""The experiment's set-ups: where each instrument stood when it measured the machine.

A set-up is what an instrument's calibration fits beside the machine and a machine file keeps
in the instrument's own section: a tracker's frame and targets (``tracker:``), a ballbar's
mountings (``ballbar:``), a printer's bed (``bed:``), the motion-capture frames
(``measurement_frames:``). Each instrument declares its set-up's type in its module
(:attr:`~pkmcal.instruments.base.Instrument.Setup`) and how it is read from and written to its
section (:meth:`~pkmcal.instruments.base.Instrument.read_setup`,
:meth:`~pkmcal.instruments.base.Instrument.setup_section`); :class:`Setups` carries them, by
instrument name, next to the machine (the machine holds none of them).

Every set-up type has ``shifted(t)``: the same set-up seen from a base frame whose points all
moved by ``t`` (a base point ``p`` is ``p + t`` in the new frame), and ``frame_shift(machine)``:
the ``t`` that makes the machine's frame the set-up's own (a printer's frame is its bed, SPEC 8),
None for set-ups that say nothing about the machine's frame; and ``targets_in_base(machine, P)``
/ ``targets_from_base(machine, P)``: targets given in the machine's working frame (a printer's:
heights above its bed) in the base frame and back, ``P`` itself for set-ups that do not move
targets.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np


class Setups(Mapping):
    """The set-ups of an experiment, by instrument name (``"tracker"``, ``"pose"``,
    ``"distance"``, ``"probe"``); immutable, a :class:`~collections.abc.Mapping`.

    Parameters
    ----------
    items : mapping of str to object, optional
        Instrument name -> its set-up (None values are dropped: no set-up).

    Examples
    --------
    >>> s = Setups()
    >>> len(s), s.get("tracker")
    (0, None)
    """

    __slots__ = ("_items",)

    def __init__(self, items: Mapping[str, Any] | None = None):
        self._items = {k: v for k, v in dict(items or {}).items() if v is not None}

    def __getitem__(self, name: str):
        return self._items[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"Setups({self._items!r})"

    def __eq__(self, other) -> bool:
        if not isinstance(other, Mapping) or set(self) != set(other):
            return False
        return all(_same(self[k], other[k]) for k in self)

    __hash__ = None  # type: ignore[assignment]

    def with_setup(self, name: str, setup) -> Setups:
        """A copy with ``name``'s set-up replaced (None: removed).

        Parameters
        ----------
        name : str
            Instrument name.
        setup : object or None
            Its set-up.

        Returns
        -------
        Setups
            The new container.
        """
        items = dict(self._items)
        items[name] = setup
        return Setups(items)

    def merged(self, other: Mapping | None) -> Setups:
        """A copy with ``other``'s set-ups added (they win where both have one).

        Parameters
        ----------
        other : mapping or None
            Set-ups by instrument name.

        Returns
        -------
        Setups
            The new container.
        """
        return Setups({**self._items, **dict(other or {})})

    def shifted(self, t) -> Setups:
        """Every set-up seen from a base frame whose points moved by ``t`` (m).

        Parameters
        ----------
        t : array_like, shape (3,)
            The shift of base points, m.

        Returns
        -------
        Setups
            The new container.
        """
        t = np.asarray(t, float)
        return Setups({k: v.shifted(t) for k, v in self._items.items()})

    def frame_shift(self, machine):
        """The shift of base points that makes ``machine``'s frame its set-ups' own (a
        printer's bed at z = 0), or None.

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        ndarray, shape (3,) or None
            The first set-up's that states one.
        """
        for setup in self._items.values():
            t = setup.frame_shift(machine)
            if t is not None:
                return np.asarray(t, float)
        return None

    def targets_in_base(self, machine, P) -> np.ndarray:
        """Targets given in ``machine``'s working frame, in its base frame: the working frame
        is the base frame unless a set-up says otherwise (a printer's targets are heights
        above its bed, SPEC 8).

        Parameters
        ----------
        machine : Machine
            The machine.
        P : array_like, shape (K, 3)
            Positions, m.

        Returns
        -------
        ndarray, shape (K, 3)
            Positions in the base frame, m.
        """
        P = machine.targets_in_base(P)
        for setup in self._items.values():
            P = setup.targets_in_base(machine, P)
        return P

    def targets_from_base(self, machine, P) -> np.ndarray:
        """Positions in ``machine``'s base frame, in its working frame: the inverse of
        :meth:`targets_in_base` (a printer's positions become heights above its bed, SPEC 8;
        elsewhere ``P`` itself). What a command writes as a target or a pose of the platform.

        Parameters
        ----------
        machine : Machine
            The machine.
        P : array_like, shape (K, 3)
            Positions in the base frame, m.

        Returns
        -------
        ndarray, shape (K, 3)
            Positions in the working frame, m.
        """
        P = machine.targets_from_base(P)
        for setup in reversed(list(self._items.values())):
            P = setup.targets_from_base(machine, P)
        return P

    def working_frame_is_base(self, machine) -> bool:
        """Whether ``machine``'s working frame is its base frame with these set-ups (False
        on a printer whose bed is tilted or off z = 0: its targets are heights above it).

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        bool
            True when :meth:`targets_in_base` leaves every position as it is.
        """
        P = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        return bool(np.array_equal(self.targets_in_base(machine, P), P))


def _same(a, b) -> bool:
    """Set-ups equal value for value (arrays compared exactly)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return a.shape == b.shape and bool(np.array_equal(a, b))
    if isinstance(a, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if hasattr(a, "__dataclass_fields__"):
        return all(_same(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)
    return a == b
