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

from dataclasses import dataclass

import numpy as np

from ..kinematics import matrix_from_rotvec


@dataclass(frozen=True)
class TrackerFrame:
    """Targets are reflector (SMR) positions in the laser tracker's frame (Delta).

    Attributes
    ----------
    R : ndarray, shape (3, 3)
        Rotation of ``base_from_tracker`` (``x_base = R m + t``).
    t : ndarray, shape (3,)
        Translation of ``base_from_tracker``, m.
    smr_offset : float
        The reflector's distance below the platform point, m.
    """

    R: np.ndarray
    t: np.ndarray
    smr_offset: float

    #: the calibration's names of the frame parameters, in ``delta`` order
    names = ("tracker.rx", "tracker.ry", "tracker.rz", "tracker.x", "tracker.y", "tracker.z")
    description = "reflector positions in the laser tracker's frame"

    def to_base(self, Pt, Rt=None):
        """Platform points (base frame) whose reflector is at the targets.

        Parameters
        ----------
        Pt : array_like, shape (K, 3)
            Reflector positions, m, tracker frame.
        Rt : None
            Ignored (a Delta platform only translates).

        Returns
        -------
        P : ndarray, shape (K, 3)
            Platform points, m, base frame.
        R : None
            No orientation.
        """
        smr = np.array([0.0, 0.0, self.smr_offset])
        return np.asarray(Pt, float) @ self.R.T + self.t + smr, None

    def measure(self, P, R=None, delta=None):
        """Tracker-frame reflector positions of platform points.

        Parameters
        ----------
        P : array_like, shape (K, 3)
            Platform points, m, base frame.
        R : None
            Ignored.
        delta : array_like, shape (6,), optional
            Perturbation of the frame: rotation increment (left) and translation, m.

        Returns
        -------
        Pt : ndarray, shape (K, 3)
            Reflector positions, m, tracker frame.
        Rt : None
            No orientation.
        """
        Rf, t = self.R, self.t
        if delta is not None:
            Rf, t = matrix_from_rotvec(np.asarray(delta[:3], float)) @ Rf, t + delta[3:6]
        smr = np.array([0.0, 0.0, self.smr_offset])
        return (np.asarray(P, float) - smr - t) @ Rf, None


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


def target_frame(machine):
    """The instrument frame a calibrated machine file carries, or None.

    Parameters
    ----------
    machine : Machine
        A calibrated machine (its ``base_from_tracker`` or ``measurement_frames``).

    Returns
    -------
    TrackerFrame or MocapFrames or None
        None when the file has no instrument frame (e.g. a constraint-link calibration).
    """
    pose = getattr(machine, "base_from_tracker", None)
    if pose is not None:
        R, t = pose
        return TrackerFrame(np.asarray(R, float), np.asarray(t, float),
                            float(getattr(machine, "smr_offset", 0.0)))
    frames = getattr(machine, "measurement_frames", None)
    if frames is not None:
        return MocapFrames(frames)
    return None
