"""The planning helpers other CLI modules still import from here (``cli/_export.py``:
:func:`workspace_arg`); identifiability and select-poses live in
:mod:`pkmcal.workflows.planning`."""

from ..workflows.planning import workspace_arg

__all__ = ["workspace_arg"]
