"""Hand a calibration to the controller: each controller's parameter format, the values that
leave the least position error (fitted over a workspace), and import of a controller's current
values as a machine file.

Formats register themselves in :data:`~pkmcal.export.base.FORMATS` (one module per controller
family); ``pkmcal export`` and ``pkmcal import`` look them up by name.
"""

from .base import (
    FORMATS,
    ControllerFormat,
    ControllerParameters,
    controller_format,
    load_formats,
    register_format,
)
from .fitting import ExportResult, export, export_workspace, fit_controller, position_errors

__all__ = ["FORMATS", "ControllerFormat", "ControllerParameters", "ExportResult",
           "controller_format", "export", "export_workspace", "fit_controller", "load_formats",
           "position_errors", "register_format"]
