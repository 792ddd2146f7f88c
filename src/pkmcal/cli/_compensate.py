"""``pkmcal compensate``'s work lives in :mod:`pkmcal.workflows.compensate`; the name
:func:`calibration_report_path` stays importable from here for ``cli._report`` until that
imports it from the workflows."""

from ..workflows.compensate import calibration_report_path

__all__ = ["calibration_report_path"]
