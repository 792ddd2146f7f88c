"""Where the tracker stands and where its targets are: the set-up of the machine file's
``tracker:`` section (:class:`TrackerSetup`), the simulations' default tracker pose and the
targets' planned places on the platform."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...kinematics import matrix_from_rotvec
from ...machines.base import Machine

#: where simulations put the tracker in the base frame (m): 2.5 m from the robot's axis, on
#: the floor 1.4 m below the base plane
TRACKER_POSITION = (2.0, -1.5, -1.4)
#: its tilt about its own y axis (rad)
TRACKER_TILT = np.deg2rad(1.0)


@dataclass(frozen=True)
class TrackerSetup:
    """A tracker's set-up (the machine file's ``tracker:`` section): its frame and the
    places of its targets on the platform.

    Attributes
    ----------
    base_from_tracker : tuple of ndarray
        ``(R (3, 3), t (3,))``: a tracker point ``m`` is ``R m + t`` in the base frame, m.
    targets : ndarray, shape (K, 3) or None
        Places of targets 1..K on the platform (platform frame), m; None: one target at the
        platform origin, or the machine's own (a Delta's reflector, ``smr_offset``).
    """

    base_from_tracker: tuple
    targets: np.ndarray | None = None

    def shifted(self, t) -> TrackerSetup:
        """The set-up seen from a base frame whose points moved by ``t`` (m)."""
        R, a = self.base_from_tracker
        return TrackerSetup((R, np.asarray(a, float) + np.asarray(t, float)), self.targets)

    def frame_shift(self, machine):
        """None: a tracker says nothing about the machine's frame."""
        return None

    def targets_in_base(self, machine, P):
        """``P`` itself: targets are not given relative to a tracker's set-up."""
        return P

    def targets_from_base(self, machine, P):
        """``P`` itself: the inverse of :meth:`targets_in_base`."""
        return P


def default_tracker_pose() -> tuple[np.ndarray, np.ndarray]:
    """The true ``base_from_tracker = (R, t)`` of simulations without a tracker in the machine file.

    The tracker stands at :data:`TRACKER_POSITION` (2.5 m from the robot's axis), its x axis
    turned about Z toward the robot's axis (143.13 deg) and tilted by :data:`TRACKER_TILT`
    (1 deg) about its y axis.

    Returns
    -------
    R : ndarray, shape (3, 3)
        Orientation of the tracker frame in the base frame.
    t : ndarray, shape (3,)
        Tracker origin in the base frame, m.
    """
    t = np.array(TRACKER_POSITION, float)
    yaw = np.arctan2(-t[1], -t[0])
    R = matrix_from_rotvec([0.0, 0.0, yaw]) @ matrix_from_rotvec([0.0, TRACKER_TILT, 0.0])
    return R, t


def tracker_pose(setup: TrackerSetup | None = None):
    """``base_from_tracker`` of the machine file's tracker set-up, else the simulations'
    default.

    Parameters
    ----------
    setup : TrackerSetup, optional
        The tracker's set-up of the machine file (None: none).

    Returns
    -------
    tuple of ndarray
        ``(R (3, 3), t (3,))``.
    """
    return default_tracker_pose() if setup is None else setup.base_from_tracker


#: where plans and simulations put an unknown target on the platform (platform frame, in
#: characteristic lengths): off the platform origin, as a reflector nest on a tool would be
TARGET_OFFSET = np.array([0.1, -0.05, -0.15])


def plan_target(machine: Machine) -> np.ndarray:
    """The target's place on the platform for plans: the machine's, else an offset one."""
    c = machine.tracker_target()
    return TARGET_OFFSET * machine.characteristic_length() if c is None else c


def planned_targets(machine: Machine, n_targets: int = 1) -> np.ndarray:
    """Planned places of ``n_targets`` tracker targets (reflector nests) on the platform.

    The machine's own target when its file gives one (a Delta's ``smr_offset``; then only one
    target makes sense); else target 1 at
    :func:`plan_target` and the others turned about the platform
    z axis by ``360 deg g / n_targets``.

    Parameters
    ----------
    machine : Machine
        The nominal machine.
    n_targets : int, optional
        Number of targets (>= 1).

    Returns
    -------
    ndarray, shape (n_targets, 3)
        Places in the platform frame, m.

    Raises
    ------
    InputError
        When ``n_targets < 1``, or several targets are asked for on a machine whose file
        gives the target's place.
    """
    n_targets = int(n_targets)
    if n_targets < 1:
        raise InputError(f"the number of targets must be >= 1, got {n_targets}")
    known = machine.tracker_target()
    if known is not None:
        if n_targets > 1:
            raise InputError(f"{getattr(machine, 'source', None) or 'the machine file'} gives "
                             "the target's place on the platform (e.g. a Delta's "
                             "smr_offset): one target only")
        return np.asarray(known, float)[None, :]
    c = plan_target(machine)
    t = 2 * np.pi * np.arange(n_targets) / n_targets
    return np.column_stack([np.cos(t) * c[0] - np.sin(t) * c[1],
                            np.sin(t) * c[0] + np.cos(t) * c[1], np.full(n_targets, c[2])])


def tracker_targets(machine: Machine, setup=None) -> tuple[np.ndarray, bool]:
    """Places of the tracker's targets on the platform, and whether they are one for all.

    Parameters
    ----------
    machine : Machine
        The machine: its :meth:`~pkmcal.machines.Machine.tracker_target` (a Delta's
        reflector, the same for every target number), else the set-up's ``targets``, else
        the platform origin.
    setup : TrackerSetup, optional
        The tracker's set-up (None: none).

    Returns
    -------
    targets : ndarray, shape (K, 3)
        Platform-frame places, m.
    shared : bool
        True when every target number is the same place (the machine file fixes it).
    """
    known = machine.tracker_target()
    if known is not None:
        return np.asarray(known, float).reshape(1, 3), True
    targets = None if setup is None else setup.targets
    if targets is None:
        return np.zeros((1, 3)), False
    return np.asarray(targets, float).reshape(-1, 3), False
