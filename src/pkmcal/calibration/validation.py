"""Held-out validation: keep some measurements out of a calibration and test the result on them.

A calibration's own residuals flatter it (the parameters were chosen to make them small); the
residuals of measurements it never saw do not. ``pkmcal calibrate --holdout F`` uses
:func:`holdout_split` to set a random share of the rows aside, calibrates on the rest and
compares the held-out residuals of the machine file's geometry and of the calibrated one.
"""

from __future__ import annotations

from ..instruments.constraint_link import constraint_link_reading_rms
from ..instruments.flow import holdout_split

__all__ = ["constraint_link_reading_rms", "holdout_split"]
