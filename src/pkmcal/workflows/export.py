"""``pkmcal export`` and ``pkmcal import`` as library functions: a calibration in a
controller's own parameter file (or a whole configuration directory, for a format that writes
one), and a controller's current values as a machine file (:mod:`pkmcal.export`).

Both read their inputs, check their outputs before any work, write all or none and return a
:class:`~pkmcal.report.summary.Summary`; problems with the input raise
:class:`~pkmcal.errors.InputError`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..export import ControllerFormat, controller_format, export
from ..export.base import load_formats
from ..export.bed_mesh import PROFILE, bed_correction, layer_errors, print_radius_of
from ..export.fitting import carry_like, carry_like_setups
from ..instruments.flow import json_safe
from ..instruments.probe import bed_plane
from ..io.atomic import atomic_write_bytes, atomic_write_text, is_stream, read_input_text
from ..io.klipper_config import backup_name
from ..io.machine_file import (
    MachineFileError,
    key_path_text,
    machine_to_text,
    parse_machine,
    save_machine,
)
from ..paths import path_text, recorded_path
from ..report.summary import Summary
from ..units import format_quantity
from .common import (
    check_outputs,
    commit_outputs,
    in_output_set,
    load_machine_setups_arg,
    machine_inputs,
)

__all__ = ["run_export", "run_import", "export_record"]


def _um(value) -> str:
    """A length in m, for people (um below 1 mm, then mm); ``-`` for None."""
    return "-" if value is None else format_quantity(value, "length")


def export_record(result, calibrated: str, output: Path, nominal: str | None) -> dict:
    """The JSON record written beside an export: the result and where it came from.

    Parameters
    ----------
    result : ExportResult
        The export.
    calibrated : str
        The calibrated machine's file (or ``default``).
    output : Path
        The file the values are written to.
    nominal : str or None
        ``--nominal``'s machine file.

    Returns
    -------
    dict
        JSON-ready (non-finite numbers as None).
    """
    record = {"calibrated": path_text(calibrated),
              "nominal": None if nominal is None else path_text(nominal),
              "file": path_text(output)}
    record.update(result.as_dict())
    return json_safe(record)


@in_output_set
def run_export(machine_spec: str, to: str, output, nominal: str | None = None,
               workspace: str | None = None, seed: int = 0) -> Summary:
    """``pkmcal export``: fit the controller's values to a calibrated machine and write them
    as the controller's file FILE with the record FILE.json; for a format that writes whole
    configurations (:attr:`~pkmcal.export.base.ControllerFormat.configuration_files`) and
    ``output`` naming a directory (a name ending in '/' or an existing directory), a
    configuration that starts, with ``export.json``.

    Onto an existing controller file of a format that saves as the controller saves
    (:meth:`~pkmcal.export.base.ControllerFormat.update`), the values are saved into it and
    the previous file is kept beside it, dated. A printer whose bed the calibration measured
    gets a bed mesh for what the values cannot hold at the bed, where its file takes one.

    Parameters
    ----------
    machine_spec : str
        The calibrated machine file, or ``default``.
    to : str
        The format's name (``--to``).
    output : str or Path
        The file (or configuration directory) to write.
    nominal : str, optional
        The machine file of the controller's current values: their error is reported too.
    workspace : str, optional
        ``--workspace``: a box ``X0,X1,Y0,Y1,Z0,Z1`` with units or a CSV of points; default a
        printer's own print volume, else the machine's default workspace.
    seed : int
        Seed of the sampled workspace poses.

    Returns
    -------
    Summary
        The format, workspace, errors and the values written, then the "wrote ..." line.

    Raises
    ------
    InputError
        A machine, option or existing file that does not fit (nothing is written).
    """
    fmt = controller_format(to, "--to")
    output, directory = _output_target(fmt, output)
    if directory:
        return _export_configuration(fmt, machine_spec, output, nominal, workspace, seed)
    # no record beside /dev/null or a pipe (as calibrate writes no report beside them)
    record_path = None if is_stream(output) else output.with_name(output.name + ".json")
    machine, setups, inputs = _machine_and_inputs(machine_spec, nominal, workspace)
    # onto an existing controller file: saved as the controller saves (the previous file kept
    # beside it, dated), where the format knows how; read before anything is written
    existing = backup = None
    if not is_stream(output) and output.is_file() \
            and type(fmt).update is not ControllerFormat.update:
        existing = read_input_text(output, f"{fmt.name} file", register=False)
        backup = backup_name(output)
        try:                        # the backup is the previous file byte for byte (a BOM)
            previous = output.read_bytes()
        except OSError as exc:
            raise InputError(f"{path_text(output)}: "
                             f"cannot be read ({exc.strerror or exc})") from None
    check_outputs([output] + ([record_path] if record_path is not None else [])
                  + ([backup] if backup is not None else []), inputs)
    before, before_setups = _checked_machines(fmt, machine, machine_spec, nominal)
    ws = _workspace(machine, workspace, seed, setups)
    result = export(fmt, machine, ws.P, ws.R, nominal=before, workspace=ws.description,
                    surface=ws.surface, existing=existing, source=str(output), setups=setups,
                    nominal_setups=before_setups)
    hand_over = _bed_hand_over(fmt, result, machine, ws, result.text, setups)
    if existing is not None and backup is not None:
        atomic_write_bytes(backup, previous)
    atomic_write_text(output, hand_over["text"] or result.text)
    if record_path is not None:
        record = export_record(result, machine_spec, output, nominal)
        record.update({k: v for k, v in hand_over.items() if k != "text"})
        atomic_write_text(record_path, json.dumps(json_safe(record), indent=2) + "\n")
    commit_outputs()
    summary = _result_summary(fmt, result, ws, before, nominal, backup, output, hand_over)
    summary.line(f"wrote {path_text(output)}"
                 + (f" and {path_text(record_path)}" if record_path else "")
                 + (f" (previous {path_text(output.name)} kept as {path_text(backup.name)})"
                    if backup else ""))
    return summary


def _bed_hand_over(fmt, result, machine, ws, text: str, setups) -> dict:
    """A printer's export: the nozzle's height error at the bed (of the set-ups ``setups``)
    and 50 and 100 mm above it, and the bed mesh that carries what the values cannot hold at
    the bed where the controller applies one from its file (:mod:`pkmcal.export.bed_mesh`).
    ``text``: the file with the mesh (None: none handed over); ``mesh``: what to tell the
    user."""
    out: dict = {"text": None}
    if getattr(ws, "surface", None) is None or not np.any(ws.surface):
        return out
    radius = print_radius_of(machine, setups)
    height = fmt.bed_mesh_height(text)
    correction = bed_correction(fmt, result.params, machine, radius, height=height,
                                setups=setups)
    meshed = fmt.with_bed_mesh(text, result.params, machine, setups)
    out["layers"] = layer_errors(fmt, result.params, machine, radius,
                                 correction if meshed is not None else None, setups=setups)
    if meshed is not None:
        out["text"] = meshed
        out["mesh"] = (f"[bed_mesh {PROFILE}] written to the SAVE_CONFIG block (RMS "
                       f"{correction.rms * 1e6:.3g} um over the print disk: what the values "
                       "cannot hold at the bed, seen as your own meshes see it, with the "
                       f"nozzle {height * 1e3:.4g} mm up at the probe's trigger); load it "
                       f"with BED_MESH_PROFILE LOAD={PROFILE} (e.g. in your PRINT_START after "
                       "homing); your own profiles are unchanged")
    elif correction is not None and correction.worth_it:
        out["mesh"] = (f"the values leave {correction.rms * 1e6:.3g} um RMS at the bed that "
                       f"a bed mesh could carry; {fmt.name} takes none from this file (a "
                       "Klipper printer.cfg needs a [bed_mesh] section)")
    return out


def _output_target(fmt, output) -> tuple[Path, bool]:
    """``-o``: the path and whether it names a configuration directory (a name ending in '/'
    or an existing directory; a format that writes configurations only)."""
    text = str(output)
    path = Path(text)
    directory = text.endswith(("/", os.sep)) or (path.is_dir() and not is_stream(path))
    if directory and not fmt.configuration_files:
        writers = [name for name, f in load_formats().items() if f.configuration_files]
        raise InputError(f"-o {text}: names a directory; {fmt.name} writes one file (a "
                         f"configuration directory is written for {', '.join(writers)}): "
                         "give a file name")
    return path, directory


def _machine_and_inputs(machine_spec: str, nominal: str | None, workspace: str | None):
    """The machine of ``machine_spec``, its set-ups (a printer's bed) and the files export
    reads (never to be overwritten): the machine files, an existing ``--workspace`` file and
    the calibration's report the calibrated file pins."""
    inputs = machine_inputs(machine_spec) + (machine_inputs(nominal) if nominal else [])
    if workspace is not None and Path(workspace).exists():
        inputs.append(Path(workspace))
    machine, setups = load_machine_setups_arg(machine_spec)
    # the calibration's report, which the calibrated file pins, is an input too
    pinned = _pinned_report(machine, machine_spec)
    if pinned is not None:
        inputs.append(pinned)
    return machine, setups, inputs


def _pinned_report(machine, machine_spec: str) -> Path | None:
    """The JSON report a calibrated machine file names beside it (None: none named)."""
    name = (getattr(machine, "calibration_info", None) or {}).get("report")
    if not isinstance(name, str) or not name.strip() or Path(name).name != name \
            or machine_spec == "default":
        return None
    return recorded_path(Path(machine_spec).parent, name)         # recorded by path_text


def _workspace(machine, workspace: str | None, seed: int, setups):
    """The export's workspace: ``--workspace``, else a printer's own (on the bed of the
    set-ups ``setups``), else the machine's."""
    from .planning import workspace_arg

    own = getattr(machine, "print_workspace", None)
    return (own(rng=seed, bed=bed_plane(setups)) if workspace is None and callable(own)
            else workspace_arg(workspace, machine, seed, setups))


def _checked_machines(fmt, machine, machine_spec: str, nominal: str | None):
    """The calibrated machine checked against the format; ``--nominal``'s machine (or None),
    checked too, and its set-ups (or None)."""
    why = fmt.applies(machine)
    if why is not None:
        raise InputError(f"--to {fmt.name}: {path_text(machine_spec)}: {why}")
    before = before_setups = None
    if nominal is not None:
        before, before_setups = load_machine_setups_arg(nominal)
        why = fmt.applies(before)
        if why is not None:
            raise InputError(f"--nominal {nominal}: {why}")
        if before.kind != machine.kind:
            raise InputError(f"--nominal {nominal}: a {before.kind} machine, but "
                             f"{path_text(machine_spec)} is a {machine.kind} machine")
    return before, before_setups


def _export_configuration(fmt, machine_spec: str, directory: Path, nominal: str | None,
                          workspace: str | None, seed: int) -> Summary:
    """``pkmcal export --to FORMAT -o DIR/``: the format's configuration that starts
    (:meth:`~pkmcal.export.base.ControllerFormat.configuration`) and ``export.json``, all in
    one atomic output set."""
    record_path = directory / "export.json"
    paths = [directory / name for name in fmt.configuration_files] + [record_path]
    machine, setups, inputs = _machine_and_inputs(machine_spec, nominal, workspace)
    check_outputs(paths, inputs, [directory])
    before, before_setups = _checked_machines(fmt, machine, machine_spec, nominal)
    ws = _workspace(machine, workspace, seed, setups)
    result = export(fmt, machine, ws.P, ws.R, nominal=before, workspace=ws.description,
                    surface=ws.surface, setups=setups, nominal_setups=before_setups)
    files = fmt.configuration(result, machine, ws)
    for name, text in files.items():
        atomic_write_text(directory / name, text)
    atomic_write_text(record_path, json.dumps(export_record(
        result, machine_spec, directory / fmt.configuration_values_file, nominal),
        indent=2) + "\n")
    commit_outputs()
    summary = _result_summary(fmt, result, ws, before, nominal, None, directory)
    summary.line(f"wrote {fmt.configuration_words} {path_text(directory)}: "
                 f"{', '.join(files)} and export.json (start it with: "
                 f"{fmt.configuration_start(directory)})")
    return summary


def _result_summary(fmt, result, ws, before, nominal, backup, output: Path,
                    hand_over: dict | None = None) -> Summary:
    """The export's table (format, workspace, errors), its notes and the values written."""
    summary = Summary()
    table = summary.pairs()
    table.add_row("format", fmt.name)
    table.add_row("workspace", f"{ws.description} ({len(ws.P)} poses)")
    if result.height_rms is not None:
        table.add_row("nozzle height error", f"RMS {_um(result.height_rms)}, max "
                      f"{_um(result.height_max)} above the bed over the print disk, through "
                      "the controller's kinematics (what its values cannot hold, the bed's "
                      "tilt included, and rounding)")
    table.add_row("remaining error", f"RMS {_um(result.remaining_rms)}, max "
                                      f"{_um(result.remaining_max)} (position, what the "
                                      "controller cannot represent, and rounding)")
    if before is not None:
        table.add_row("error of --nominal", f"RMS {_um(result.before_rms)}, max "
                                           f"{_um(result.before_max)} (the values of {nominal})"
                      + ("" if result.before_height_rms is None else
                         f"; nozzle height RMS {_um(result.before_height_rms)}, max "
                         f"{_um(result.before_height_max)}"))
    if result.left_out:
        table.add_row("left out", result.left_out)
    for row in (hand_over or {}).get("layers", []):
        mesh = ("" if row.get("mesh_rms_um") is None else
                f"; with the mesh RMS {row['mesh_rms_um']:.3g} um, max "
                f"{row['mesh_max_um']:.3g} um")
        table.add_row(f"height error {row['height_mm']:g} mm up",
                      f"RMS {row['rms_um']:.3g} um, max {row['max_um']:.3g} um over the print "
                      f"disk{mesh}")
    if (hand_over or {}).get("mesh"):
        table.add_row("bed mesh", hand_over["mesh"])
    if backup is not None:
        table.add_row("updated", f"{path_text(output)} as the controller saves its values "
                                 "(previous "
                                 f"file kept as {path_text(backup.name)})")
    for note in result.notes:           # the controller's frame, a relabelling of joints
        summary.line(f"note: {note}")
    values = summary.table("value", "written", title="Values written (the controller's units)")
    for name, text in fmt.values_text(result.params):
        values.add_row(name, text)
    return summary


@in_output_set
def run_import(path: Path, source_format: str, output: Path, like: str | None = None) -> Summary:
    """``pkmcal import``: a controller file's values (or a configuration's, for a format
    that reads one: :meth:`~pkmcal.export.base.ControllerFormat.read_controller_file`) as a
    pkmcal machine file.

    Parameters
    ----------
    path : Path
        The controller's file, or configuration (an INI file or its directory).
    source_format : str
        The format's name (``--from``).
    output : Path
        The machine file to write.
    like : str, optional
        A machine file to take what the controller's file does not hold from (name, home,
        units, joint limits, effector offsets).

    Returns
    -------
    Summary
        The import's notes and what was written.

    Raises
    ------
    InputError
        A file that cannot be read, or values that do not make a working machine, named by
        the controller file's keys and lines (nothing is written).
    """
    fmt = controller_format(source_format, "--from")
    path = Path(path)
    check_outputs([output], [path] + (machine_inputs(like) if like else []))
    params, home, name = fmt.read_controller_file(path)
    model, like_setups = load_machine_setups_arg(like) if like is not None else (None, None)
    if model is not None and fmt.machine_kind and model.kind != fmt.machine_kind:
        raise InputError(f"--like {like}: a {model.kind} machine; {fmt.name} files describe a "
                         f"{fmt.machine_words} (machine: {fmt.machine_kind})")
    machine = carry_like(fmt.to_machine(params, model), model)
    # what --like carried (a tracker's set-up) and the set-ups the values state (a
    # printer's bed)
    setups = carry_like_setups(machine, like_setups)
    setups = setups.merged(fmt.imported_setups(params))
    if model is None and home is not None:      # a configuration's own
        machine.home = home
    if model is None and name:
        machine.name = name
    _check_imported(fmt, params, machine, setups, path, like)
    save_machine(machine, output, getattr(machine, "file_units", None), setups=setups)
    commit_outputs()
    summary = Summary()
    for note in getattr(params, "notes", None) or []:       # letters passed over, and why
        summary.line(f"note: {note}")
    summary.line(f"{len(params.values)} {fmt.name} values of {path_text(path)} written to "
                 f"{path_text(output)} as a {machine.kind} machine file")
    return summary


#: machine-file keys an import takes from ``--like`` (:func:`~pkmcal.export.fitting.carry_like`)
_LIKE_KEYS = ("name", "units", "joint_limits", "smr_offset", "tracker")


def _check_imported(fmt, params, machine, setups, path: Path, like: str | None) -> None:
    """Validate an imported machine as its machine file is validated (schema, magnitudes,
    geometry, joint limits) and name a problem in the user's terms: the controller file's
    keys and lines that make the machine-file key concerned (the format's source map,
    :meth:`~pkmcal.export.base.ControllerFormat.imported_key`), or ``--like``'s key."""
    units = getattr(machine, "file_units", None)
    try:
        parse_machine(machine_to_text(machine, units, setups=setups), str(path))
        return
    except MachineFileError as exc:
        key, what = exc.key, exc.what
        if exc.stage == "geometry":
            # the home an import makes is its default home unless --like gave one: say so
            problems = machine.geometry_problems(home_given=like is not None)
            if problems:
                key, what = problems[0]
    place = None
    if like is not None and key and (key[0] in _LIKE_KEYS or key[0] == "home"):
        place = f"--like {like}: {key_path_text(key)}"          # what --like gave
    if place is None:
        place = fmt.imported_key(params, key)
    if place is None:
        raise InputError(f"{path_text(path)}: the imported values do not make a working machine "
                         f"({key_path_text(key)} of its machine file): {what}") from None
    raise InputError(f"{place}: {what} (the imported machine's {key_path_text(key)})") from None
