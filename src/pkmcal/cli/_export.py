"""``pkmcal export`` and ``pkmcal import``: a calibration in a controller's own parameter file,
and a controller's current values as a machine file (:mod:`pkmcal.export`)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
from rich.markup import escape

from ..calibration.run import json_safe as _finite_or_none
from ..errors import InputError
from ..io.atomic import atomic_write_bytes, atomic_write_text, is_stream, read_input_text
from ..paths import path_text, recorded_path
from ..units import format_quantity
from ._commands import (
    _machine_inputs,
    _table,
    check_outputs,
    commit_outputs,
    load_machine_arg,
)
from ._console import console


def _um(value) -> str:
    """A length in m, for people (um below 1 mm, then mm); ``-`` for None."""
    return "-" if value is None else format_quantity(value, "length")


def export_record(result, calibrated: str, output: Path, nominal: str | None) -> dict:
    """The JSON record beside the written file: the result and where it came from."""
    record = {"calibrated": path_text(calibrated),
              "nominal": None if nominal is None else path_text(nominal),
              "file": path_text(output)}
    record.update(result.as_dict())
    return _finite_or_none(record)


def _bed_hand_over(fmt, result, machine, ws, text: str) -> dict:
    """A printer's export: the nozzle's height error at the bed and 50 and 100 mm above it,
    and the bed mesh that carries what the values cannot hold at the bed where the
    controller applies one from its file (:mod:`pkmcal.export.bed_mesh`). ``text``: the
    file with the mesh (None: none handed over); ``mesh``: what to tell the user."""
    from ..export.bed_mesh import PROFILE, bed_correction, layer_errors, print_radius_of

    out: dict = {"text": None}
    if getattr(ws, "surface", None) is None or not np.any(ws.surface):
        return out
    radius = print_radius_of(machine)
    height = fmt.bed_mesh_height(text)
    correction = bed_correction(fmt, result.params, machine, radius, height=height)
    meshed = fmt.with_bed_mesh(text, result.params, machine)
    out["layers"] = layer_errors(fmt, result.params, machine, radius,
                                 correction if meshed is not None else None)
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
    or an existing directory; a LinuxCNC format only)."""
    from ..export.linuxcnc_config import LinuxCNCKinematics

    text = str(output)
    path = Path(text)
    directory = text.endswith(("/", os.sep)) or (path.is_dir() and not is_stream(path))
    if directory and not isinstance(fmt, LinuxCNCKinematics):
        raise InputError(f"-o {text}: names a directory; {fmt.name} writes one file (a "
                         "configuration directory is written for the linuxcnc-* formats): "
                         "give a file name")
    return path, directory


def _machine_and_inputs(machine_spec: str, nominal: str | None, workspace: str | None):
    """The machine of ``machine_spec`` and the files export reads (never to be overwritten):
    the machine files, an existing ``--workspace`` file and the calibration's report the
    calibrated file pins."""
    inputs = _machine_inputs(machine_spec) + (_machine_inputs(nominal) if nominal else [])
    if workspace is not None and Path(workspace).exists():
        inputs.append(Path(workspace))
    machine = load_machine_arg(machine_spec)
    # the calibration's report, which the calibrated file pins, is an input too
    pinned = _pinned_report(machine, machine_spec)
    if pinned is not None:
        inputs.append(pinned)
    return machine, inputs


def run_export(machine_spec: str, to: str, output, nominal: str | None = None,
               workspace: str | None = None, seed: int = 0) -> int:
    """``pkmcal export``: fit the controller's values, write FILE and FILE.json (or, for a
    LinuxCNC format and ``-o DIR/``, a configuration directory with its record)."""
    from ..export import ControllerFormat, controller_format, export

    fmt = controller_format(to, "--to")
    output, directory = _output_target(fmt, output)
    if directory:
        return _export_configuration(fmt, machine_spec, output, nominal, workspace, seed)
    # no record beside /dev/null or a pipe (as calibrate writes no report beside them)
    record_path = None if is_stream(output) else output.with_name(output.name + ".json")
    machine, inputs = _machine_and_inputs(machine_spec, nominal, workspace)
    # onto an existing controller file: saved as the controller saves (the previous file kept
    # beside it, dated), where the format knows how; read before anything is written
    existing = backup = None
    if not is_stream(output) and output.is_file() \
            and type(fmt).update is not ControllerFormat.update:
        from ..io.klipper_config import backup_name

        existing = read_input_text(output, f"{fmt.name} file", register=False)
        backup = backup_name(output)
        try:                        # the backup is the previous file byte for byte (a BOM)
            previous = output.read_bytes()
        except OSError as exc:
            raise InputError(f"{path_text(output)}: "
                             f"cannot be read ({exc.strerror or exc})") from None
    check_outputs([output] + ([record_path] if record_path is not None else [])
                  + ([backup] if backup is not None else []), inputs)
    before = _checked_machines(fmt, machine, machine_spec, nominal)
    ws = _workspace(machine, workspace, seed)
    result = export(fmt, machine, ws.P, ws.R, nominal=before, workspace=ws.description,
                    surface=ws.surface, existing=existing, source=str(output))
    hand_over = _bed_hand_over(fmt, result, machine, ws, result.text)
    if existing is not None and backup is not None:
        atomic_write_bytes(backup, previous)
    atomic_write_text(output, hand_over["text"] or result.text)
    if record_path is not None:
        record = export_record(result, machine_spec, output, nominal)
        record.update({k: v for k, v in hand_over.items() if k != "text"})
        atomic_write_text(record_path, json.dumps(_finite_or_none(record), indent=2) + "\n")
    commit_outputs()
    _print_result(fmt, result, ws, before, nominal, backup, output, hand_over)
    out = console()
    out.print(f"wrote {path_text(output)}"
              + (f" and {path_text(record_path)}" if record_path else "")
              + (f" (previous {path_text(output.name)} kept as {path_text(backup.name)})"
                 if backup else ""),
              markup=False)
    return 0


def _workspace(machine, workspace: str | None, seed: int):
    """The export's workspace: ``--workspace``, else a printer's own, else the machine's."""
    from ._planning import workspace_arg

    own = getattr(machine, "print_workspace", None)
    return (own(rng=seed) if workspace is None and callable(own)
            else workspace_arg(workspace, machine, seed))


def _checked_machines(fmt, machine, machine_spec: str, nominal: str | None):
    """The calibrated machine checked against the format; ``--nominal``'s machine (or None),
    checked too."""
    why = fmt.applies(machine)
    if why is not None:
        raise InputError(f"--to {fmt.name}: {path_text(machine_spec)}: {why}")
    before = None
    if nominal is not None:
        before = load_machine_arg(nominal)
        why = fmt.applies(before)
        if why is not None:
            raise InputError(f"--nominal {nominal}: {why}")
        if before.kind != machine.kind:
            raise InputError(f"--nominal {nominal}: a {before.kind} machine, but "
                             f"{path_text(machine_spec)} is a {machine.kind} machine")
    return before


def _export_configuration(fmt, machine_spec: str, directory: Path, nominal: str | None,
                          workspace: str | None, seed: int) -> int:
    """``pkmcal export --to linuxcnc-... -o DIR/``: a LinuxCNC configuration that starts
    (:func:`~pkmcal.export.linuxcnc_config.configuration`) and ``export.json``, all in one
    atomic output set."""
    from ..export import export
    from ..export.linuxcnc_config import CONFIG_FILES, configuration

    record_path = directory / "export.json"
    paths = [directory / name for name in CONFIG_FILES] + [record_path]
    machine, inputs = _machine_and_inputs(machine_spec, nominal, workspace)
    check_outputs(paths, inputs, [directory])
    before = _checked_machines(fmt, machine, machine_spec, nominal)
    ws = _workspace(machine, workspace, seed)
    result = export(fmt, machine, ws.P, ws.R, nominal=before, workspace=ws.description,
                    surface=ws.surface)
    files = configuration(fmt, result, machine, ws)
    for name, text in files.items():
        atomic_write_text(directory / name, text)
    atomic_write_text(record_path, json.dumps(export_record(
        result, machine_spec, directory / "kinematics.hal", nominal), indent=2) + "\n")
    commit_outputs()
    _print_result(fmt, result, ws, before, nominal, None, directory)
    console().print(f"wrote the LinuxCNC configuration {path_text(directory)}: "
                    f"{', '.join(files)} and export.json (start it with: linuxcnc "
                    f"{path_text(directory / 'machine.ini')})", markup=False)
    return 0


def _print_result(fmt, result, ws, before, nominal, backup, output: Path,
                  hand_over: dict | None = None) -> None:
    """The export's table: format, workspace, errors, values written."""
    out = console()
    table = _table("", "", show_header=False)
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
        table.add_row("bed mesh", escape(hand_over["mesh"]))
    if backup is not None:
        table.add_row("updated", f"{path_text(output)} as the controller saves its values "
                                 "(previous "
                                 f"file kept as {path_text(backup.name)})")
    out.print(table)
    for note in result.notes:           # the controller's frame, a relabelling of joints
        out.print(f"note: {note}", markup=False)
    values = _table("value", "written", title="Values written (the controller's units)")
    for name, text in fmt.values_text(result.params):
        # a Klipper key's [section] is text, not markup
        values.add_row(escape(name), escape(text))
    out.print(values)


def _pinned_report(machine, machine_spec: str) -> Path | None:
    """The JSON report a calibrated machine file names beside it (None: none named)."""
    name = (getattr(machine, "calibration_info", None) or {}).get("report")
    if not isinstance(name, str) or not name.strip() or Path(name).name != name \
            or machine_spec == "default":
        return None
    return recorded_path(Path(machine_spec).parent, name)         # recorded by path_text


def run_import(path: Path, source_format: str, output: Path, like: str | None = None) -> int:
    """``pkmcal import``: a controller file's values as a pkmcal machine file."""
    from ..export import controller_format
    from ..export.fitting import carry_like
    from ..io.machine_file import save_machine

    fmt = controller_format(source_format, "--from")
    check_outputs([output], [path] + (_machine_inputs(like) if like else []))
    params, home, name = _read_controller_file(fmt, path)
    model = load_machine_arg(like) if like is not None else None
    if model is not None and fmt.machine_kind and model.kind != fmt.machine_kind:
        raise InputError(f"--like {like}: a {model.kind} machine; {fmt.name} files describe a "
                         f"{fmt.machine_words} (machine: {fmt.machine_kind})")
    machine = carry_like(fmt.to_machine(params, model), model)
    if model is None and home is not None:      # a LinuxCNC configuration's own
        machine.home = home
    if model is None and name:
        machine.name = name
    _check_imported(fmt, params, machine, path, like)
    units = getattr(machine, "file_units", None)
    save_machine(machine, output, units)
    commit_outputs()
    out = console()
    for note in getattr(params, "notes", None) or []:       # letters passed over, and why
        out.print(f"note: {note}", markup=False)
    out.print(f"{len(params.values)} {fmt.name} values of {path_text(path)} written to "
              f"{path_text(output)} "
              f"as a {machine.kind} machine file", markup=False)
    return 0


def _read_controller_file(fmt, path: Path):
    """The values of a controller file, and a home pose and name where it holds them; for a
    LinuxCNC format also of a configuration: its INI (``.ini``, or the one INI of a
    directory) with the HAL files it names, ``[TRAJ] HOME`` and ``[EMC] MACHINE``."""
    from ..export.linuxcnc_config import (
        LinuxCNCKinematics,
        configuration_home,
        parse_configuration,
    )

    configuration = isinstance(fmt, LinuxCNCKinematics) and (path.is_dir()
                                                             or path.suffix == ".ini")
    if not configuration:
        return fmt.parse(read_input_text(path, f"{fmt.name} file"), str(path)), None, None
    if path.is_dir():
        inis = sorted(path.glob("*.ini"))
        if len(inis) != 1:
            raise InputError(f"{path_text(path)}: a LinuxCNC configuration directory with "
                             f"{len(inis)} INI files; name the one LinuxCNC starts with")
        path = inis[0]
    text = read_input_text(path, "LinuxCNC INI file")
    params = parse_configuration(
        fmt, text, path_text(path),
        lambda name: read_input_text(path.parent / name, "LinuxCNC HAL file"))
    return (params, *configuration_home(fmt, params, text, path_text(path)))


#: machine-file keys an import takes from ``--like`` (:func:`~pkmcal.export.fitting.carry_like`)
_LIKE_KEYS = ("name", "units", "joint_limits", "smr_offset", "tracker")


def _check_imported(fmt, params, machine, path: Path, like: str | None) -> None:
    """Validate an imported machine as its machine file is validated (schema, magnitudes,
    geometry, joint limits) and name a problem in the user's terms: the controller file's
    keys and lines that make the machine-file key concerned (the format's source map,
    :meth:`~pkmcal.export.base.ControllerFormat.imported_key`), or ``--like``'s key."""
    from ..io.machine_file import (
        MachineFileError,
        machine_to_text,
        parse_machine,
    )
    from ..io.machine_file import key_path_text as _key_path

    units = getattr(machine, "file_units", None)
    try:
        parse_machine(machine_to_text(machine, units), str(path))
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
        place = f"--like {like}: {_key_path(key)}"          # what --like gave
    if place is None:
        place = fmt.imported_key(params, key)
    if place is None:
        raise InputError(f"{path_text(path)}: the imported values do not make a working machine "
                         f"({_key_path(key)} of its machine file): {what}") from None
    raise InputError(f"{place}: {what} (the imported machine's {_key_path(key)})") from None
