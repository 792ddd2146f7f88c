"""What every workflow shares: the machine named on the command line, the outputs checked
before any work and written all or none, the "wrote ..." line, a silent progress, and the
groups of a file's rows (fk, compensate)."""

from __future__ import annotations

import functools
from pathlib import Path

from ..errors import stop_if_signalled
from ..instruments.setups import Setups
from ..io import load_machine_file, read_groups
from ..io.atomic import OutputSet, active_output_set, is_stream
from ..io.machine_file import DEFAULT_UNITS
from ..paths import path_text

__all__ = ["load_machine_arg", "load_machine_setups_arg", "machine_inputs",
           "check_outputs", "commit_outputs", "in_output_set", "wrote", "no_progress",
           "group_numbers"]


def load_machine_arg(spec: str):
    """The machine a command names: a machine file, or ``default`` (the embedded Hexa Slide).

    Parameters
    ----------
    spec : str
        A path, or ``"default"``.

    Returns
    -------
    Machine
        With ``file_units``, ``source`` and ``calibration_info`` set.
    """
    return load_machine_setups_arg(spec)[0]


def load_machine_setups_arg(spec: str):
    """The machine a command names and its instruments' set-ups, from one reading of the
    file (a new machine each call).

    Parameters
    ----------
    spec : str
        A path, or ``"default"`` (the embedded Hexa Slide, no set-ups).

    Returns
    -------
    machine : Machine
        As :func:`load_machine_arg`.
    setups : Setups
        The set-ups of its instrument sections (:func:`~pkmcal.io.load_machine_file`).
    """
    if spec == "default":
        from ..machines import default_hexaslide

        machine = default_hexaslide()
        machine.file_units = dict(DEFAULT_UNITS)
        machine.source = "default"
        machine.calibration_info = None
        return machine, Setups()
    return load_machine_file(spec)


def machine_inputs(spec: str) -> list[Path]:
    """The input files a machine argument names (none for ``default``)."""
    return [] if spec == "default" else [Path(spec)]


def check_outputs(outputs: list[Path], inputs: list[Path], directories=()) -> None:
    """Check a command's outputs before any work: refuse outputs whose directory is missing
    or not writable, that are directories, that coincide, or that would overwrite an input
    file (input files are never modified). With an :class:`~pkmcal.io.atomic.OutputSet`
    active (``pkmcal`` runs every command in one) they become its declared outputs, inputs
    and output directories; files read later are added to the inputs when read."""
    from ..io.atomic import OutputSet, active_output_set

    OutputSet(outputs, directories, inputs)       # the checks, at once
    active = active_output_set()
    if active is not None:
        for d in directories:
            active.add_directory(d)
        for inp in inputs:
            active.add_input(inp)
        for out in outputs:
            active.declare(out)


def in_output_set(workflow):
    """Decorate a workflow: run it in an output set of its own when none is active (a Python
    caller's), so its outputs are checked, staged and written all or none as under ``pkmcal``
    (which runs every command in one), and an output directory is created at the commit."""
    @functools.wraps(workflow)
    def run(*args, **kwargs):
        if active_output_set() is not None:
            return workflow(*args, **kwargs)
        with OutputSet():
            return workflow(*args, **kwargs)

    return run


def commit_outputs() -> list[Path]:
    """Write the staged outputs now, all or none (before saying they are written); returns
    them."""
    from ..io.atomic import active_output_set

    active = active_output_set()
    return active.commit() if active is not None else []


def wrote(output: Path, beside: Path) -> str:
    """``wrote OUT and OUT.json``; a device or pipe gets no file beside it."""
    if is_stream(output):
        return f"wrote {path_text(output)} (not a regular file: no {beside.suffix} file beside it)"
    return f"wrote {path_text(output)} and {path_text(beside)}"


def no_progress(description: str, total: int):
    """The progress protocol without a display: ``new(description, total) -> advance(n=1,
    description=None)``; advancing still stops a run that was signalled."""
    del description, total
    return lambda n=1, description=None: stop_if_signalled()


def group_numbers(path: Path, extra: dict, rows, column: str):
    """0-based groups of an optional integer column (``target``, ``setup``: 1, 2, ...) of a
    file whose rows are predicted or commanded, not fitted: any of the numbers may be absent;
    None without the column (:func:`~pkmcal.io.read_groups` with gaps)."""
    return read_groups(path, extra, rows, column, gaps=True)
