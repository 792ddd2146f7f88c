"""A LinuxCNC configuration directory that starts: INI, HAL files and a README around the
kinematics values of a LinuxCNC format (``pkmcal export --to linuxcnc-... -o DIR/``).

What LinuxCNC 2.9 needs to start (read in its ``scripts/linuxcnc.in``, ``src/emc/ini/`` and the
sample configurations ``configs/sim/axis/vismach/delta/rdelta.ini`` and
``configs/sim/axis/vismach/hexapod-sim/hexapod.ini``): ``[EMC] VERSION = 1.1`` (else the
script wants to update the file with a GUI), ``[DISPLAY] DISPLAY``, ``[TASK] TASK = milltask``,
``[RS274NGC] PARAMETER_FILE``, ``[EMCMOT] EMCMOT = motmod`` and ``SERVO_PERIOD``, ``[EMCIO]``
(the tool table), ``[HAL] HALFILE`` (run in order), ``[KINS] KINEMATICS`` / ``JOINTS``,
``[TRAJ]`` (coordinates, units, velocities; genhexkins' iterative forward kinematics starts
from ``[TRAJ] HOME``), ``[AXIS_x]`` and ``[JOINT_n]`` limits and homing.

Joints, motors and readings
---------------------------
A LinuxCNC joint position is its motor position plus ``HOME_OFFSET`` (homing with
``HOME_ABSOLUTE_ENCODER = 1``: the motor's position is absolute, ``HOME_OFFSET`` is the joint
position at motor position 0). The formats say what their joints are
(:class:`LinuxCNCKinematics`): ``HOME_OFFSET`` is the calibration's joint zero (a rotary
Delta's joint at reading 0, a linear Delta's carriage height at its endstop; 0 for genhexkins,
whose HAL ``scale`` pair already turns the drive's reading into the strut length), so the
motor position is the machine's reading in the joint's unit (a Delta's with the sign of
LinuxCNC's joint) and the simulated machine starts at reading 0. ``HOME`` is the joint
position at the machine file's home pose, where homing moves.

The simulated drives are a loopback of each joint's command to its feedback (``drives.hal``):
that file is where the user's drives go.

The display is ``dummy``: LinuxCNC runs headless until Enter is pressed on its terminal (or
its standard input ends), so the directory starts as written anywhere; a program of the user
drives it through LinuxCNC's Python module ``linuxcnc`` meanwhile. ``DISPLAY = axis`` gives
the usual screen.
"""

from __future__ import annotations

from abc import abstractmethod
from pathlib import Path
from types import MappingProxyType

import numpy as np

from ..errors import InputError
from ..io.atomic import read_input_text
from ..paths import path_text
from .base import ControllerParameters, Origin, finite_number
from .fitting import ExportResult

#: the files of a configuration directory (name -> what it is)
CONFIG_FILES = {
    "machine.ini": "the INI file LinuxCNC starts with (linuxcnc machine.ini)",
    "machine.hal": "motion, the kinematics module, estop and tool loops",
    "kinematics.hal": "the calibrated kinematics values (the file of --to ... -o FILE.hal)",
    "drives.hal": "simulated drives: the place where your drives go",
    "tool.tbl": "an empty tool table",
    "README.md": "what to connect and check",
}
#: servo period, ns (1 kHz, LinuxCNC's sample configurations)
SERVO_PERIOD_NS = 1_000_000
#: default velocity (machine units per second) and acceleration, when the machine file has none
LINEAR_VELOCITY_MM_S = 100.0
LINEAR_ACCELERATION_MM_S2 = 2000.0
ANGULAR_VELOCITY_DEG_S = 90.0
ANGULAR_ACCELERATION_DEG_S2 = 1800.0
#: joint limits from the workspace: its joint range widened by this share on each side
LIMIT_MARGIN = 0.1


class LinuxCNCKinematics:
    """What a LinuxCNC format says about its joints and world, for a configuration directory.

    A format mixes this in before :class:`~pkmcal.export.base.ControllerFormat` (``class
    F(LinuxCNCKinematics, ControllerFormat)``): it writes and reads whole configurations
    (:meth:`configuration`, :meth:`read_controller_file`).
    """

    configuration_files = MappingProxyType(CONFIG_FILES)
    configuration_values_file = "kinematics.hal"
    configuration_words = "the LinuxCNC configuration"

    #: the module of ``[KINS] KINEMATICS``
    kins_module: str = ""
    #: ``[TRAJ] COORDINATES``
    coordinates: str = "X Y Z"
    #: ``[JOINT_n] TYPE``: ``LINEAR`` (mm) or ``ANGULAR`` (deg)
    joint_type: str = "LINEAR"
    #: what the motor position of joint N is, for the README
    motor_words: str = ""
    #: the kinematics' joints (a configuration may have more, e.g. rotary axes)
    kins_joints: int = 3

    @abstractmethod
    def controller_joints(self, params: ControllerParameters, q) -> np.ndarray:
        """LinuxCNC's joint positions for the machine's readings.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        q : array_like, shape (K, n)
            The machine's readings (internal units), in the machine's order.

        Returns
        -------
        ndarray, shape (K, n)
            Joints 0..n-1 in LinuxCNC's units (mm, deg).
        """

    @abstractmethod
    def machine_readings(self, params: ControllerParameters, J) -> np.ndarray:
        """The machine's readings for LinuxCNC's joint positions (the inverse of
        :meth:`controller_joints`).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        J : array_like, shape (K, n)
            Joints in LinuxCNC's units.

        Returns
        -------
        ndarray, shape (K, n)
            Readings, internal units.
        """

    @abstractmethod
    def controller_world(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """LinuxCNC's world coordinates of poses of the calibrated frame.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        P : array_like, shape (K, 3)
            Positions, m.
        R : array_like, shape (K, 3, 3), optional
            Orientations (platforms that rotate).

        Returns
        -------
        ndarray, shape (K, len(coordinates))
            X, Y, Z in mm (and A, B, C in deg).
        """

    @abstractmethod
    def calibrated_pose(self, params: ControllerParameters, X):
        """The calibrated frame's poses of LinuxCNC's world coordinates (the inverse of
        :meth:`controller_world`).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        X : array_like, shape (K, len(coordinates))
            World coordinates (mm, deg).

        Returns
        -------
        P : ndarray, shape (K, 3)
            Positions, m.
        R : ndarray, shape (K, 3, 3)
            Orientations.
        """

    @abstractmethod
    def home_offsets(self, params: ControllerParameters) -> np.ndarray:
        """``[JOINT_n] HOME_OFFSET``: the joint position at motor position 0.

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        ndarray, shape (n,)
            LinuxCNC's units.
        """

    @abstractmethod
    def with_home_offsets(self, params: ControllerParameters, offsets: dict
                          ) -> ControllerParameters:
        """The values with the INI's ``HOME_OFFSET`` as the joints' zero (an import of a
        configuration: the INI is what LinuxCNC runs).

        Parameters
        ----------
        params : ControllerParameters
            The values of the kinematics' HAL file.
        offsets : dict
            Joint -> ``(HOME_OFFSET, Origin)`` (LinuxCNC's units).

        Returns
        -------
        ControllerParameters
            The values.
        """

    def parse_with_home_offsets(self, text: str, source: str, offsets: dict
                                ) -> ControllerParameters:
        """The values of the kinematics' HAL file with the INI's ``HOME_OFFSET``
        (:meth:`with_home_offsets` of :meth:`parse`; a format whose file alone must state
        them overrides it).

        Parameters
        ----------
        text : str
            The HAL file's text.
        source : str
            Its name.
        offsets : dict
            Joint -> ``(HOME_OFFSET, Origin)``.

        Returns
        -------
        ControllerParameters
            The values.
        """
        return self.with_home_offsets(self.parse(text, source), offsets)

    def joint_nets(self, j: int) -> tuple[list[str], str, str]:
        """How joint ``j`` reaches its drive: fixed HAL lines, the pin that carries the
        drive's command and the pin its feedback goes to.

        Parameters
        ----------
        j : int
            The joint.

        Returns
        -------
        lines : list of str
            ``net`` lines at the top of ``drives.hal``, after the kinematics' components are
            loaded (none: the joint's motor pins are the drive's).
        command, feedback : str
            HAL pins.
        """
        return [], f"joint.{j}.motor-pos-cmd", f"joint.{j}.motor-pos-fb"

    def configuration(self, result: ExportResult, machine, workspace) -> dict[str, str]:
        """The files of a LinuxCNC configuration directory that starts (:func:`configuration`).
        """
        return configuration(self, result, machine, workspace)

    def configuration_start(self, directory: Path) -> str:
        """``linuxcnc DIR/machine.ini``."""
        return f"linuxcnc {path_text(directory / 'machine.ini')}"

    def read_controller_file(self, path: Path):
        """The values of the kinematics' HAL file, or of a configuration: its INI (``.ini``,
        or the one INI of a directory) with the HAL files it names, ``[TRAJ] HOME`` and
        ``[EMC] MACHINE`` (:func:`parse_configuration`, :func:`configuration_home`); see
        :meth:`~pkmcal.export.base.ControllerFormat.read_controller_file`."""
        if not (path.is_dir() or path.suffix == ".ini"):
            return super().read_controller_file(path)
        if path.is_dir():
            inis = sorted(path.glob("*.ini"))
            if len(inis) != 1:
                raise InputError(f"{path_text(path)}: a LinuxCNC configuration directory with "
                                 f"{len(inis)} INI files; name the one LinuxCNC starts with")
            path = inis[0]
        text = read_input_text(path, "LinuxCNC INI file")
        params = parse_configuration(
            self, text, path_text(path),
            lambda name: read_input_text(path.parent / name, "LinuxCNC HAL file"))
        return (params, *configuration_home(self, params, text, path_text(path)))


def _f(v: float, digits: int = 9) -> str:
    text = f"{float(v):.{digits}f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


def _limits(values: np.ndarray, keep: np.ndarray | None = None):
    """min/max over rows, widened by :data:`LIMIT_MARGIN` of the range (and at least 1)."""
    lo, hi = np.nanmin(values, axis=0), np.nanmax(values, axis=0)
    if keep is not None:
        lo, hi = np.minimum(lo, keep.min(axis=0)), np.maximum(hi, keep.max(axis=0))
    pad = np.maximum(LIMIT_MARGIN * (hi - lo), 1.0)
    return lo - pad, hi + pad


def configuration(fmt, result: ExportResult, machine, workspace) -> dict[str, str]:
    """The files of a LinuxCNC configuration directory for an export.

    Parameters
    ----------
    fmt : ControllerFormat and LinuxCNCKinematics
        The format.
    result : ExportResult
        The export (its values as written, its ``.hal`` text).
    machine : Machine
        The calibrated machine (its name, home pose and ``joint_limits``).
    workspace : Workspace
        The export's workspace (the world limits and, without the machine file's joint limits,
        the joints').

    Returns
    -------
    dict
        File name -> text (:data:`CONFIG_FILES`).

    Raises
    ------
    InputError
        When the controller cannot command the machine's home pose.
    """
    params = result.params
    n = machine.n_joints
    home_P, home_R = (np.asarray(v, float) for v in machine.home)
    home_q = fmt.ik(params, home_P[None], home_R[None])
    home_J = fmt.controller_joints(params, home_q)[0]
    if not np.all(np.isfinite(home_J)):
        raise InputError(f"--to {fmt.name}: the machine file's home pose cannot be commanded "
                         f"with {fmt.kins_module}'s values ([TRAJ] HOME and [JOINT_n] HOME "
                         "need it); give a home inside the workspace")
    offsets = fmt.home_offsets(params)
    X = fmt.controller_world(params, workspace.P, workspace.R)
    X_home = fmt.controller_world(params, home_P[None], home_R[None])[0]
    J_ws = fmt.controller_joints(params, fmt.ik(params, workspace.P, workspace.R))
    limits = getattr(machine, "joint_limits", None)
    if limits is not None:
        ends = fmt.controller_joints(params, np.stack([np.asarray(v, float) for v in limits]))
        j_lo, j_hi = ends.min(axis=0), ends.max(axis=0)
        limit_words = "the machine file's joint_limits"
    else:
        j_lo, j_hi = _limits(J_ws, home_J[None])
        limit_words = (f"the workspace's joint range ({workspace.description}) and home, "
                       f"widened by {LIMIT_MARGIN:.0%} of it")
    x_lo, x_hi = _limits(X, X_home[None])
    angular = fmt.joint_type == "ANGULAR"
    jv, ja = ((ANGULAR_VELOCITY_DEG_S, ANGULAR_ACCELERATION_DEG_S2) if angular
              else (LINEAR_VELOCITY_MM_S, LINEAR_ACCELERATION_MM_S2))
    name = " ".join(str(getattr(machine, "name", "") or "calibrated machine").split())
    coords = fmt.coordinates.split()

    ini = [
        f"# LinuxCNC 2.9 configuration of {name}, written by pkmcal export --to {fmt.name}",
        "# Start it with: linuxcnc machine.ini   (README.md: what to connect and check)",
        "",
        "[EMC]",
        "VERSION = 1.1",
        f"MACHINE = {name}",
        "DEBUG = 0",
        "",
        "[DISPLAY]",
        "# dummy: no screen, LinuxCNC runs until Enter on its terminal (or the end of its",
        "# input); drive it with halcmd or Python's linuxcnc module. For the usual screen:",
        "# DISPLAY = axis",
        "DISPLAY = dummy",
        "POSITION_OFFSET = RELATIVE",
        "POSITION_FEEDBACK = ACTUAL",
        "",
        "[TASK]",
        "TASK = milltask",
        "CYCLE_TIME = 0.010",
        "",
        "[RS274NGC]",
        "PARAMETER_FILE = linuxcnc.var",
        "",
        "[EMCMOT]",
        "EMCMOT = motmod",
        "COMM_TIMEOUT = 1.0",
        f"SERVO_PERIOD = {SERVO_PERIOD_NS}",
        "",
        "[EMCIO]",
        "EMCIO = io",
        "CYCLE_TIME = 0.100",
        "TOOL_TABLE = tool.tbl",
        "",
        "[HAL]",
        "HALFILE = machine.hal",
        "HALFILE = kinematics.hal",
        "HALFILE = drives.hal",
        "",
        "[KINS]",
        f"KINEMATICS = {fmt.kins_module}",
        f"JOINTS = {n}",
        "",
        "[TRAJ]",
        f"COORDINATES = {fmt.coordinates}",
        "LINEAR_UNITS = mm",
        "ANGULAR_UNITS = degree",
        f"DEFAULT_LINEAR_VELOCITY = {_f(LINEAR_VELOCITY_MM_S / 2)}",
        f"MAX_LINEAR_VELOCITY = {_f(LINEAR_VELOCITY_MM_S)}",
        f"DEFAULT_LINEAR_ACCELERATION = {_f(LINEAR_ACCELERATION_MM_S2 / 2)}",
        f"MAX_LINEAR_ACCELERATION = {_f(LINEAR_ACCELERATION_MM_S2)}",
    ]
    if len(coords) > 3:
        ini += [f"DEFAULT_ANGULAR_VELOCITY = {_f(ANGULAR_VELOCITY_DEG_S / 2)}",
                f"MAX_ANGULAR_VELOCITY = {_f(ANGULAR_VELOCITY_DEG_S)}"]
    ini += ["# the machine file's home pose (genhexkins' forward kinematics starts from it)",
            "HOME = " + " ".join(_f(v) for v in X_home), ""]
    for k, c in enumerate(coords):
        lin = k < 3
        ini += [f"[AXIS_{c}]",
                f"MIN_LIMIT = {_f(x_lo[k], 6)}", f"MAX_LIMIT = {_f(x_hi[k], 6)}",
                f"MAX_VELOCITY = {_f(LINEAR_VELOCITY_MM_S if lin else ANGULAR_VELOCITY_DEG_S)}",
                "MAX_ACCELERATION = "
                + _f(LINEAR_ACCELERATION_MM_S2 if lin else ANGULAR_ACCELERATION_DEG_S2), ""]
    ini.insert(ini.index(f"[AXIS_{coords[0]}]"),
               f"# world limits: {workspace.description}, widened by {LIMIT_MARGIN:.0%}")
    ini.append(f"# joint limits: {limit_words}; HOME_OFFSET: the joint at motor position 0 "
               "(the calibration's joint zero), HOME: the joint at the home pose")
    for j in range(n):
        ini += [f"[JOINT_{j}]",
                f"TYPE = {fmt.joint_type}",
                f"MIN_LIMIT = {_f(j_lo[j], 6)}", f"MAX_LIMIT = {_f(j_hi[j], 6)}",
                f"MAX_VELOCITY = {_f(jv)}", f"MAX_ACCELERATION = {_f(ja)}",
                "FERROR = 1", "MIN_FERROR = 0.5",
                f"HOME_OFFSET = {_f(offsets[j], 12)}",
                f"HOME = {_f(home_J[j], 12)}",
                "HOME_SEARCH_VEL = 0", "HOME_LATCH_VEL = 0",
                "HOME_ABSOLUTE_ENCODER = 1",
                "HOME_SEQUENCE = 0", ""]

    hal = [f"# Motion and the kinematics module ({fmt.kins_module}) of {name}; the calibrated",
           "# values are in kinematics.hal, the drives in drives.hal.",
           "loadrt [KINS]KINEMATICS",
           "loadrt [EMCMOT]EMCMOT servo_period_nsec=[EMCMOT]SERVO_PERIOD "
           "num_joints=[KINS]JOINTS",
           "addf motion-command-handler servo-thread",
           "addf motion-controller servo-thread",
           "net estop-loop iocontrol.0.user-enable-out => iocontrol.0.emc-enable-in",
           "net tool-prep-loop iocontrol.0.tool-prepare => iocontrol.0.tool-prepared",
           "net tool-change-loop iocontrol.0.tool-change => iocontrol.0.tool-changed"]
    fixed = [line for j in range(n) for line in fmt.joint_nets(j)[0]]
    drives = (["# Each joint to its drive's path through the kinematics' HAL components (keep):"]
              + fixed + [""] if fixed else [])
    drives += ["# ==== YOUR DRIVES GO HERE ====",
              "# Simulated drives: each joint's command is looped back to its feedback (a drive",
              "# that follows exactly). Replace each 'net' line by your drive's pins, e.g.",
              "#   net jN-cmd <command pin> => hm2_.../stepgen.N.position-cmd",
              "#   net jN-fb hm2_.../stepgen.N.position-fb => <feedback pin>",
              f"# Joint N's motor position: {fmt.motor_words}"]
    for j in range(n):
        _, cmd, fb = fmt.joint_nets(j)
        drives.append(f"net j{j}-drive {cmd} => {fb}")

    files = {
        "machine.ini": "\n".join(ini) + "\n",
        "machine.hal": "\n".join(hal) + "\n",
        "kinematics.hal": result.text,
        "drives.hal": "\n".join(drives) + "\n",
        "tool.tbl": "",
        "README.md": _readme(fmt, result, name, offsets, home_J, limit_words),
    }
    return files


def _readme(fmt, result: ExportResult, name: str, offsets, home_J, limit_words) -> str:
    unit = "deg" if fmt.joint_type == "ANGULAR" else "mm"
    um = (lambda v: f"{v * 1e6:.3g} um")  # noqa: E731
    rows = "\n".join(f"| {j} | {offsets[j]:.9g} | {home_J[j]:.9g} |" for j in range(len(offsets)))
    return f"""# LinuxCNC configuration of {name}

Written by `pkmcal export --to {fmt.name}`: LinuxCNC 2.9's `{fmt.kins_module}` with the
calibrated values. Remaining position error over the workspace ({result.workspace}, {result.points}
poses), the values as written: RMS {um(result.remaining_rms)}, max {um(result.remaining_max)}.

## Start it

    linuxcnc machine.ini

`[DISPLAY] DISPLAY = dummy`: no screen; LinuxCNC runs until you press Enter in its terminal
(or its input ends). Drive it meanwhile with `halcmd`, `halshow` or a Python program using
LinuxCNC's `linuxcnc` module (estop reset, machine on, home all, MDI `G0 ...`). For the usual
screen set `DISPLAY = axis`. Run as root only with `RTAPI_UID` set to a non-root user id and
`RTAPI_FIFO_PATH` in a directory that user can write.

## Files

{chr(10).join(f"- `{k}`: {v}" for k, v in CONFIG_FILES.items())}

## What to connect

`drives.hal` loops each joint's command back to its feedback (a simulated machine). Replace
its `net` lines by your drives: the command pin to your drive's position command, your
drive's position feedback to the feedback pin. Joint N's motor position: {fmt.motor_words}

## What to check before moving the machine

- Joints ({unit}): `HOME_OFFSET` is the joint position at motor position 0 (the calibration's
  joint zero), `HOME` the joint position at the machine file's home pose; homing is
  `HOME_ABSOLUTE_ENCODER = 1` (the motor position is absolute). With home switches instead,
  set `HOME_SEARCH_VEL` / `HOME_LATCH_VEL` and add to `HOME_OFFSET` the motor position
  where the switch trips.

| joint | HOME_OFFSET | HOME |
| --- | --- | --- |
{rows}

- Joint limits: from {limit_words}; the world's (`[AXIS_*]`) from the workspace. Check them
  against your machine's travel.
- Velocities and accelerations are defaults ({LINEAR_VELOCITY_MM_S:g} mm/s,
  {ANGULAR_VELOCITY_DEG_S:g} deg/s): set your machine's.
- Units: mm and degrees (`[TRAJ] LINEAR_UNITS = mm`); the kinematics values are in mm.
- Move slowly to the home pose and a few poses of the workspace; compare with
  `pkmcal ik` of the calibrated machine file.
"""


def ini_sections(text: str) -> dict:
    """An INI text's entries: section -> list of ``(key, value, line)`` (keys may repeat,
    as ``HALFILE`` does; ``#`` and ``;`` lines are comments).

    Parameters
    ----------
    text : str
        The INI file's text.

    Returns
    -------
    dict
        The entries per section, in order.
    """
    out: dict = {}
    section = None
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            section = out.setdefault(line[1:-1].strip(), [])
        elif "=" in line and section is not None:
            key, value = (w.strip() for w in line.split("=", 1))
            section.append((key, value, n))
    return out


def parse_configuration(fmt, ini_text: str, source: str, read) -> ControllerParameters:
    """The values of a LinuxCNC configuration: its INI's ``[KINS] KINEMATICS``, the HAL file
    of its ``[HAL] HALFILE`` list that sets the kinematics' values, and the joints' ``[JOINT_n]
    HOME_OFFSET`` (LinuxCNC's default 0 where missing) as their zero.

    Parameters
    ----------
    fmt : ControllerFormat and LinuxCNCKinematics
        The format.
    ini_text : str
        The INI file's text.
    source : str
        Its name, for messages.
    read : callable
        ``read(name) -> text`` of a ``HALFILE`` entry (relative to the INI's directory).

    Returns
    -------
    ControllerParameters
        The values, their origins in the INI and the HAL file.

    Raises
    ------
    InputError
        Naming the INI's line, or the HAL file's, of what does not fit the format.
    """
    ini = ini_sections(ini_text)
    kins = [(v, n) for k, v, n in ini.get("KINS", []) if k == "KINEMATICS"]
    if not kins:
        raise InputError(f"{source}: [KINS] KINEMATICS is missing (LinuxCNC's kinematics "
                         "module)")
    words = kins[0][0].split()
    if not words or words[0] != fmt.kins_module:
        raise InputError(f"{source}: line {kins[0][1]}: [KINS] KINEMATICS = {kins[0][0]}: "
                         f"--from {fmt.name} reads {fmt.kins_module}")
    found = []
    for name, _, _ in ((v, k, n) for k, v, n in ini.get("HAL", []) if k == "HALFILE"):
        if name.startswith("LIB:") or not name.endswith(".hal"):
            continue                       # LinuxCNC's own library files, Tcl files
        text = read(name)
        if any(line.split()[:2] and line.split()[0] == "setp"
               and line.split()[1].startswith(fmt.kins_module + ".")
               for line in text.splitlines() if line.strip()):
            found.append((name, text))
    if len(found) != 1:
        what = ("none of its [HAL] HALFILE files sets" if not found else
                f"{len(found)} of its HALFILE files ({', '.join(n for n, _ in found)}) set")
        raise InputError(f"{source}: {what} {fmt.kins_module}'s values (setp "
                         f"{fmt.kins_module}.<pin>); one file must hold them")
    joints = [(v, n) for k, v, n in ini.get("KINS", []) if k == "JOINTS"]
    if not joints:
        raise InputError(f"{source}: [KINS] JOINTS is missing")
    n_joints = finite_number(joints[0][0], source, joints[0][1], "[KINS] JOINTS")
    if n_joints < fmt.kins_joints:
        raise InputError(f"{source}: line {joints[0][1]}: [KINS] JOINTS = {joints[0][0]}: "
                         f"{fmt.kins_module} has {fmt.kins_joints} joints")
    offsets = {}
    for j in range(fmt.kins_joints):
        entries = [(v, n) for k, v, n in ini.get(f"JOINT_{j}", []) if k == "HOME_OFFSET"]
        if entries:
            v, n = entries[0]
            offsets[j] = (finite_number(v, source, n, f"[JOINT_{j}] HOME_OFFSET"),
                          Origin(source, f"[JOINT_{j}] HOME_OFFSET", n))
        else:
            offsets[j] = (0.0, Origin(source, f"[JOINT_{j}] HOME_OFFSET", None,
                                      "not in the file: LinuxCNC's default 0"))
    hal_source = str(Path(source).parent / found[0][0])
    return fmt.parse_with_home_offsets(found[0][1], hal_source, offsets)


def configuration_home(fmt, params: ControllerParameters, ini_text: str, source: str):
    """The home pose and name a configuration's INI holds (``[TRAJ] HOME`` in LinuxCNC's
    world, ``[EMC] MACHINE``), for an import without ``--like``.

    Parameters
    ----------
    fmt : ControllerFormat and LinuxCNCKinematics
        The format.
    params : ControllerParameters
        The configuration's values (:func:`parse_configuration`).
    ini_text : str
        The INI file's text.
    source : str
        Its name, for messages.

    Returns
    -------
    home : tuple of ndarray or None
        ``(P, R)`` in the calibrated frame (m); None without ``[TRAJ] HOME``.
    name : str or None
        ``[EMC] MACHINE``.

    Raises
    ------
    InputError
        When ``[TRAJ] HOME`` is not one number per coordinate (naming its line).
    """
    ini = ini_sections(ini_text)
    name = next((v for k, v, _ in ini.get("EMC", []) if k == "MACHINE"), None)
    entry = next(((v, n) for k, v, n in ini.get("TRAJ", []) if k == "HOME"), None)
    if entry is None:
        return None, name
    words = entry[0].split()
    m = len(fmt.coordinates.split())
    if len(words) < m:
        raise InputError(f"{source}: line {entry[1]}: [TRAJ] HOME = {entry[0]}: expected "
                         f"{m} numbers ({fmt.coordinates})")
    X = np.array([[finite_number(w, source, entry[1], "[TRAJ] HOME") for w in words[:m]]])
    P, R = fmt.calibrated_pose(params, X)
    return (P[0], R[0]), name
