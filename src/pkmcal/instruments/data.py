"""Measurements of any instrument: joint readings and what the instrument read, per row."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass
class InstrumentData:
    """Joint readings and instrument measurements, one row per measurement.

    Attributes
    ----------
    kind : str
        ``"points"`` or ``"distances"``.
    q : ndarray, shape (K, n_joints)
        Joint readings, internal units (m, rad).
    values : ndarray, shape (K, size)
        Measured values, SI units (points: ``mx, my, mz``; distances: ``d``).
    group : ndarray of int, shape (K,), optional
        0-based target (points) or setup (distances) of each row; default all 0.
    rows : ndarray of int, shape (K,), optional
        File row numbers for messages; default 1..K.
    source : str, optional
        File name, for messages.
    true_P, true_R : ndarray, optional
        Poses of a simulation, else None.
    weights : tuple, optional
        ``(noise model, words)``: the relative weights the data's source fits them with (a
        firmware's saved calibration data: Klipper's DELTA_CALIBRATE weighs its distances
        against its heights), held unless the user gives the noise; None: the instrument's
        default, estimated.
    """

    kind: str
    q: np.ndarray
    values: np.ndarray
    group: np.ndarray | None = None
    rows: np.ndarray | None = None
    source: str = "<data>"
    true_P: np.ndarray | None = None
    true_R: np.ndarray | None = None
    weights: tuple | None = None

    def __post_init__(self):
        self.q = np.atleast_2d(np.asarray(self.q, float))
        self.values = np.asarray(self.values, float).reshape(len(self.q), -1)
        self.group = (np.zeros(len(self.q), int) if self.group is None
                      else np.asarray(self.group, int))
        if self.rows is None:
            self.rows = np.arange(1, len(self.q) + 1)

    def __len__(self) -> int:
        return len(self.q)

    @property
    def n_groups(self) -> int:
        """Number of targets / setups (the largest group index + 1)."""
        return int(self.group.max()) + 1 if len(self.group) else 1

    def subset(self, mask) -> InstrumentData:
        """The rows selected by a boolean mask or index array.

        Parameters
        ----------
        mask : array_like of bool or int
            Rows to keep.

        Returns
        -------
        InstrumentData
            The selected rows, same source and kind.
        """
        def pick(a):
            return None if a is None else a[mask]

        new = InstrumentData(self.kind, self.q[mask], self.values[mask], self.group[mask],
                             self.rows[mask], self.source, pick(self.true_P),
                             pick(self.true_R), self.weights)
        # what a reader attached (notes, a session's name, a mesh's free height ...) stays
        named = {f.name for f in fields(InstrumentData)}
        new.__dict__.update({k: v for k, v in self.__dict__.items() if k not in named})
        return new
