"""What a tracker calibration adds to its result (:class:`TrackerSection`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ...estimation.sections import Section


@dataclass
class TrackerSection(Section):
    """What a tracker calibration adds to its result (``result.sections["tracker"]``): the
    registration (``base_from_tracker``, estimated or held) and the targets' places on the
    platform, each with its start, and the rows left out.

    Attributes
    ----------
    registration, start_registration : tuple of (ndarray (3, 3), ndarray (3,))
        ``(R, t)`` of ``base_from_tracker``, m: identified and at the start (closed form with
        the nominal model).
    targets, start_targets : ndarray, shape (n, 3)
        The targets' places on the platform (platform frame), m.
    kept : ndarray of bool
        The rows used (not left out as outliers).
    outlier_rows : ndarray of int
        The file rows left out.
    estimated : bool
        Whether the registration was estimated with the legs (joint method).
    targets_given : bool
        Whether the machine file gives the target (the reflector below the platform point).
    """

    instrument: ClassVar[str] = "tracker"
    title: ClassVar[str] = "registration"

    registration: tuple
    start_registration: tuple
    targets: np.ndarray
    start_targets: np.ndarray
    kept: np.ndarray
    outlier_rows: np.ndarray
    estimated: bool = True
    targets_given: bool = False

    def as_report(self, units=None) -> dict:
        from ...units import LENGTH

        unit = (units or {}).get("length", "mm")
        fl = LENGTH[unit]
        (R, t), (R0, t0) = self.registration, self.start_registration
        R, R0 = np.asarray(R, float), np.asarray(R0, float)
        return {
            "targets": {"given_by_machine_file": bool(self.targets_given), "unit": unit,
                        "places": (np.asarray(self.targets, float) / fl).tolist(),
                        "what": "target places on the platform (platform frame)"},
            "registration": {
                "estimated": bool(self.estimated),
                "rotation": R.tolist(), "translation": (np.asarray(t) / fl).tolist(),
                "unit": unit,
                "start": {"rotation": R0.tolist(),
                          "translation": (np.asarray(t0) / fl).tolist(),
                          "method": "closed form (SVD) with the nominal model"},
                "rotation_change_deg": float(np.degrees(np.linalg.norm(_rotvec(R @ R0.T)))),
                "translation_change": float(np.linalg.norm(np.asarray(t) - t0) / fl),
            },
        }

    def summary_rows(self, units=None) -> list:
        from ...units import LENGTH

        unit = (units or {}).get("length", "mm")
        fl = LENGTH[unit]
        rep = self.as_report(units)["registration"]
        t = ", ".join(f"{v:.6g}" for v in np.asarray(self.registration[1]) / fl)
        return [("tracker frame", ("estimated" if self.estimated else "held (two-step)")
                 + f": origin at ({t}) {unit}, turned {rep['rotation_change_deg']:.4g} deg "
                 f"and moved {rep['translation_change']:.4g} {unit} from the closed-form start"),
                ("targets", f"{len(self.targets)} place(s) on the platform"
                 + (" (machine file)" if self.targets_given else " (estimated)"))]


def _rotvec(R):
    from ...kinematics import rotvec_from_matrix

    return rotvec_from_matrix(R)
