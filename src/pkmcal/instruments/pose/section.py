"""What a full-pose calibration adds to its result (:class:`PoseSection`): the measurement
frames, identified and at the start, and which were held.
"""


from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...estimation.sections import Section


@dataclass
class PoseSection(Section):
    """What a full-pose calibration adds to its result (``result.sections["pose"]``): the
    measurement frames (identified and at the start) and which were held.

    Attributes
    ----------
    frames, start_frames : MeasurementFrames
        ``mocap_from_base`` and ``platform_from_marker``, identified and at the start.
    fixed_frames : tuple of bool
        Whether each frame was held at its given value.
    origin : str
        Where the frames (or their start) came from, in words (the report's ``from``).
    """

    instrument: ClassVar[str] = "pose"
    title: ClassVar[str] = "frames"

    frames: object
    start_frames: object
    fixed_frames: tuple = (False, False)
    origin: str = ""

    def as_report(self, units=None) -> dict:
        from ...units import LENGTH

        unit = (units or {}).get("length", "mm")
        fl = LENGTH[unit]
        return {"frames": {
            "fixed": bool(any(self.fixed_frames)), "from": self.origin,
            "mocap_from_base": _frame_report(self.frames.mocap_from_base, fl, unit),
            "platform_from_marker": _frame_report(self.frames.platform_from_marker, fl, unit),
        }}

    def summary_rows(self, units=None) -> list:
        fr = self.as_report(units)["frames"]
        unit = (units or {}).get("length", "mm")
        rows = []
        for name in ("mocap_from_base", "platform_from_marker"):
            f = fr[name]
            rows.append((name, ("fixed: " if fr["fixed"] else "estimated: ")
                         + f"turned {f['rotation_angle_deg']:.4g} deg, origin at ("
                         + ", ".join(f"{v:.6g}" for v in f["translation"]) + f") {unit}"))
        return rows


def _frame_report(frame, fl: float, unit: str) -> dict:
    """A measurement frame in the report (rotation, translation in the file's unit, angle)."""
    from ...kinematics import rotation_angle

    R, t = frame
    return {"rotation": np.asarray(R, float).tolist(),
            "translation": (np.asarray(t, float) / fl).tolist(), "unit": unit,
            "rotation_angle_deg": float(np.degrees(rotation_angle(np.asarray(R, float))))}
