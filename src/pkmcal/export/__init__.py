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
    ExportResult,
    controller_format,
    export,
    export_workspace,
    fit_controller,
    load_formats,
    position_errors,
    register_format,
)

__all__ = ["FORMATS", "ControllerFormat", "ControllerParameters", "ExportResult",
           "controller_format", "export", "export_workspace", "fit_controller", "load_formats",
           "position_errors", "register_format"]
