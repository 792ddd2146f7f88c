"""Targets given in the measuring instrument's frame.

A calibration fixes the machine only up to the frames its data cannot see: with a laser tracker
the origin of the Delta's base frame (a common shift of every ``db - da``), with motion capture
a rigid motion of the base and of the platform frame. Targets written in the calibrated base
frame then land off by that unknown motion (millimetres), although the commands are right up
to it. Targets written in the instrument's frame do not have the problem: the instrument saw
the machine, and the calibration estimated where it stands (the calibrated file's ``tracker``
or ``measurement_frames``), so instrument-frame targets are converted to base-frame poses
with the same estimate and land where the instrument will measure them.

Each frame maps base-frame poses to instrument-frame poses, ``measure(P, R, delta)``, with its
parameters perturbed by ``delta`` in the calibration's own convention (rotation increments on
the left, then the translation), so that the calibration's covariance over the machine and
frame parameters can be propagated to the targets.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..kinematics import matrix_from_rotvec


@dataclass(frozen=True)
class TrackerFrame:
    """Targets are positions of a target on the platform in the tracker's frame (points).

    A target row ``m`` (tracker frame) asks for the platform pose that puts the target ``c``
    (platform frame) there: ``P + R c = A m + a`` with ``(A, a) = base_from_tracker``. A
    platform that rotates keeps its home orientation, or takes the target row's orientation,
    given in the tracker frame (the base-frame orientation is ``A Rt``).

    Attributes
    ----------
    R : ndarray, shape (3, 3)
        Rotation ``A`` of ``base_from_tracker`` (``x_base = A m + a``).
    t : ndarray, shape (3,)
        Translation ``a`` of ``base_from_tracker``, m.
    targets : ndarray, shape (K, 3)
        Places of the targets on the platform, m, platform frame.
    estimated : bool, optional
        The calibration estimated the targets' places (its covariance has
        ``target<k>.x/y/z``); False when the machine file fixes them (a Delta's reflector).
    home_R : ndarray, shape (3, 3) or None, optional
        Orientation of a platform that rotates when a target gives none (home); None for a
        platform that only translates.
    group : ndarray of int, shape (n,) or None, optional
        0-based target of each target row (column ``target``); None: target 1 for every row.
    """

    R: np.ndarray
    t: np.ndarray
    targets: np.ndarray
    estimated: bool = False
    home_R: np.ndarray | None = None
    group: np.ndarray | None = None

    instrument = "tracker"

    @property
    def names(self) -> tuple[str, ...]:
        """The calibration's names of the frame parameters, in ``delta`` order: the tracker
        pose (rotation increments, translation), then the estimated targets' places."""
        out = ("tracker.rx", "tracker.ry", "tracker.rz", "tracker.x", "tracker.y", "tracker.z")
        if self.estimated:
            out += tuple(f"target{g + 1}.{c}" for g in range(len(self.targets)) for c in "xyz")
        return out

    @property
    def description(self) -> str:
        """The targets' frame in words."""
        if not self.estimated and self.home_R is None:
            return "reflector positions in the laser tracker's frame"
        return "target positions in the tracker's frame"

    def with_group(self, group) -> TrackerFrame:
        """This frame for target rows of the given targets.

        Parameters
        ----------
        group : array_like of int, shape (n,) or None
            0-based target of each row; None: target 1.

        Returns
        -------
        TrackerFrame
            A copy with ``group`` set.
        """
        return replace(self, group=None if group is None else np.asarray(group, int))

    def _placed(self, n: int, targets=None) -> np.ndarray:
        targets = self.targets if targets is None else targets
        group = np.zeros(n, int) if self.group is None else self.group
        if len(targets) == 1:
            group = np.zeros(n, int)
        return targets[group]

    def to_base(self, Pt, Rt=None):
        """Platform poses (base frame) whose target is at the target rows.

        Parameters
        ----------
        Pt : array_like, shape (n, 3)
            Target positions, m, tracker frame.
        Rt : array_like, shape (n, 3, 3) or None
            Platform orientations in the tracker frame (a platform that rotates); None: the
            home orientation. Ignored by a platform that only translates.

        Returns
        -------
        P : ndarray, shape (n, 3)
            Platform positions, m, base frame.
        R : ndarray, shape (n, 3, 3) or None
            Platform orientations, base frame; None for a platform that only translates.
        """
        Pt = np.atleast_2d(np.asarray(Pt, float))
        c = self._placed(len(Pt))
        x = Pt @ self.R.T + self.t
        if self.home_R is None:
            return x - c, None
        if Rt is None:
            Rb = np.broadcast_to(self.home_R, (len(Pt), 3, 3)).copy()
        else:
            Rb = self.R @ np.asarray(Rt, float)
        return x - np.einsum("kij,kj->ki", Rb, c), Rb

    def measure(self, P, R=None, delta=None):
        """Tracker-frame target positions (and orientations) of platform poses.

        Parameters
        ----------
        P : array_like, shape (n, 3)
            Platform positions, m, base frame.
        R : array_like, shape (n, 3, 3) or None
            Platform orientations (ignored by a platform that only translates).
        delta : array_like, optional
            Perturbation of the frame parameters (:attr:`names` order): rotation increment
            (left), translation (m), then the estimated targets' places (m).

        Returns
        -------
        Pt : ndarray, shape (n, 3)
            Target positions, m, tracker frame.
        Rt : ndarray, shape (n, 3, 3) or None
            Platform orientations in the tracker frame; None for a platform that only
            translates.
        """
        Rf, t, targets = self.R, self.t, self.targets
        if delta is not None:
            d = np.asarray(delta, float)
            Rf, t = matrix_from_rotvec(d[:3]) @ Rf, t + d[3:6]
            if self.estimated:
                targets = targets + d[6:].reshape(targets.shape)
        P = np.atleast_2d(np.asarray(P, float))
        c = self._placed(len(P), targets)
        if self.home_R is None:
            return (P + c - t) @ Rf, None
        R = np.asarray(R, float)
        return (P + np.einsum("kij,kj->ki", R, c) - t) @ Rf, Rf.T @ R


@dataclass(frozen=True)
class MocapFrames:
    """Targets are marker poses in the motion-capture frame (Stewart, full pose).

    Attributes
    ----------
    frames : MeasurementFrames
        ``mocap_from_base`` and ``platform_from_marker`` of the calibrated file.
    """

    frames: object

    names = tuple(f"{f}.{c}" for f in ("mocap_from_base", "platform_from_marker")
                  for c in ("rx", "ry", "rz", "x", "y", "z"))
    description = "marker poses in the motion-capture frame"
    instrument = "pose"

    def with_group(self, group) -> MocapFrames:
        """This frame (marker poses have no target numbers).

        Parameters
        ----------
        group : array_like of int or None
            Ignored.

        Returns
        -------
        MocapFrames
            ``self``.
        """
        return self

    def to_base(self, Pt, Rt):
        """Platform poses (base frame) whose marker is at the target poses.

        Parameters
        ----------
        Pt : array_like, shape (K, 3)
            Marker positions, m, motion-capture frame.
        Rt : array_like, shape (K, 3, 3)
            Marker orientations in the motion-capture frame.

        Returns
        -------
        P : ndarray, shape (K, 3)
            Platform positions, m, base frame.
        R : ndarray, shape (K, 3, 3)
            Platform orientations.
        """
        return self.frames.platform(Pt, Rt)

    def measure(self, P, R, delta=None):
        """Marker poses in the motion-capture frame of platform poses.

        Parameters
        ----------
        P : array_like, shape (K, 3)
            Platform positions, m, base frame.
        R : array_like, shape (K, 3, 3)
            Platform orientations.
        delta : array_like, shape (12,), optional
            Perturbation of ``mocap_from_base`` then ``platform_from_marker``: rotation
            increment (left) and translation (m) each.

        Returns
        -------
        Pm : ndarray, shape (K, 3)
            Marker positions, m.
        Rm : ndarray, shape (K, 3, 3)
            Marker orientations.
        """
        frames = self.frames
        if delta is not None:
            (A, a), (B, c) = frames.mocap_from_base, frames.platform_from_marker
            d = np.asarray(delta, float)
            frames = type(frames)((matrix_from_rotvec(d[0:3]) @ A, a + d[3:6]),
                                  (matrix_from_rotvec(d[6:9]) @ B, c + d[9:12]))
        return frames.measured(P, R)


def instrument_frames(machine, setups) -> dict:
    """The instrument frames a calibrated machine file carries, by instrument.

    Parameters
    ----------
    machine : Machine
        A calibrated machine (its own target, :meth:`~pkmcal.machines.Machine.tracker_target`,
        if it has one).
    setups : Setups
        Its set-ups: the tracker's (frame and targets) and the motion-capture frames.

    Returns
    -------
    dict
        ``{"tracker": TrackerFrame, "pose": MocapFrames}``, the ones it has, in that order;
        empty for a machine without instrument frames (a constraint-link or ballbar
        calibration: a ballbar has no frame to give targets in).
    """
    out = {}
    tracker = setups.get("tracker")
    if tracker is not None:
        R, t = tracker.base_from_tracker
        known = machine.tracker_target()
        targets = tracker.targets
        if known is not None:
            targets, estimated = np.asarray(known, float).reshape(1, 3), False
        elif targets is None:
            targets, estimated = np.zeros((1, 3)), False
        else:
            targets, estimated = np.asarray(targets, float).reshape(-1, 3), True
        home_R = (np.asarray(machine.home[1], float)
                  if machine.rotates else None)
        out["tracker"] = TrackerFrame(np.asarray(R, float), np.asarray(t, float), targets,
                                      estimated, home_R)
    frames = setups.get("pose")
    if frames is not None and len(machine.pose_space) == 6:
        out["pose"] = MocapFrames(frames)
    return out


def target_frame(machine, setups, instrument: str | None = None):
    """The instrument frame a calibrated machine file carries, or None.

    Parameters
    ----------
    machine : Machine
        A calibrated machine.
    setups : Setups
        Its set-ups (the tracker's or the motion-capture frames).
    instrument : {'tracker', 'pose'}, optional
        Which one; default the first it has (tracker, then pose).

    Returns
    -------
    TrackerFrame or MocapFrames or None
        None when the file has no (such) instrument frame (e.g. a constraint-link
        calibration).
    """
    frames = instrument_frames(machine, setups)
    if instrument is not None:
        return frames.get(instrument)
    return next(iter(frames.values()), None)
