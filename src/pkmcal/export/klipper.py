"""Klipper's ``delta`` kinematics: a ``printer.cfg`` fragment for a linear Delta printer.

Read in Klipper's source (``Klipper3d/klipper``, ``klippy/kinematics/delta.py``,
``DeltaKinematics.__init__`` and ``DeltaCalibration``):

- ``[printer] delta_radius`` is ONE radius for the three towers (there is no per-stepper
  radius); tower ``i`` stands at ``(cos(angle_i) r, sin(angle_i) r)``, ``angle`` per
  ``[stepper_a|b|c]`` in degrees (defaults 210, 330, 90);
- ``arm_length`` per stepper (``stepper_b`` and ``stepper_c`` default to ``stepper_a``'s);
- ``position_endstop`` per stepper (``b``, ``c`` default to ``a``'s); the carriage height at the
  endstop is ``abs_endstop = position_endstop + sqrt(arm^2 - delta_radius^2)``;
- the carriage height for a nozzle position is ``sqrt(arm^2 - (tx - x)^2 - (ty - y)^2) + z``
  (``DeltaCalibration.calc_stable_position``: steps since the endstop are ``(abs_endstop -
  height) / step_dist``), so the travel down from the endstop is ``abs_endstop - height``;
- ``SAVE_CONFIG`` writes the values with ``%.6f`` into the ``#*#`` block at the end of
  ``printer.cfg`` (``DeltaCalibration.save_state``) and comments out the same options in the
  sections above it; where both define an option, Klipper uses the sections' value
  (``klippy/configfile.py``, ``_strip_duplicates``). ``pkmcal export -o printer.cfg`` onto an
  existing config does the same (:meth:`KlipperDelta.update`), keeping the previous file as a
  dated backup.

``print_radius`` and ``minimum_z_position`` are not kinematics: the fragment leaves them as the
user has them. Klipper cannot hold tower tilts or per-tower radii: :func:`fit_controller` finds
the values that leave the least position error.

The controller's coordinates
----------------------------
Klipper's ``z = 0`` is the bed. A calibrated machine file with a ``bed`` section (a probe
calibration, its set-up :class:`~pkmcal.instruments.probe.BedSetup` ``(height, tilt_x,
tilt_y)`` beside the machine: the bed is the plane ``z = height + tilt_x x + tilt_y y`` of
the calibrated frame; a printer's probe calibration holds its height at 0, SPEC 8) puts
Klipper's z = 0 on the bed: the controller's target ``(x, y, z)`` is the calibrated frame's
``(x, y, z + height + tilt_x x + tilt_y y)``, a height above
the bed. Klipper's values cannot hold a tilt of the bed against the towers: the fit folds
into them what they can hold of it and the remaining error counts the rest (``bed_mesh``
corrects it). The bed is carried in the values as three fixed entries (``bed.z``,
``bed.tilt_x``, ``bed.tilt_y``) and written as a ``# pkmcal bed:`` comment, which
:meth:`KlipperDelta.parse` reads back.

Stepper order
-------------
Klipper's forward kinematics (``mathutil.trilateration``: the home position at ``G28``, the
positions read back from the steppers) takes the effector below the carriages only when
``stepper_a -> b -> c`` run counter-clockwise. A printer whose towers run clockwise is written
relabelled (:func:`stepper_order`: ``stepper_a`` its tower 1, ``stepper_b`` tower 3,
``stepper_c`` tower 2), the export's note and the file's comments naming each stepper's tower;
the fixed values ``stepper_a.tower``... keep the map, so that the readings come back in the
machine's order. An import takes the towers in Klipper's order.

This module also holds the helpers the Marlin and RepRapFirmware formats share
(:func:`vertical_tower_travel`, :func:`controller_endstops`, :func:`linear_delta_machine`).
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from ..machines.linear_delta import LinearDelta, linear_delta
from .base import (
    ControllerFormat,
    ControllerParameters,
    Origin,
    finite_number,
    register_format,
    setups_bed,
)

#: the largest length a printer's config can mean, mm (10 m)
SANE_LENGTH = 1e4
#: the bed entries every linear-Delta format carries (fixed): height m, slopes dz/dx, dz/dy
BED = ("bed.z", "bed.tilt_x", "bed.tilt_y")
BED_KINDS = ("length", "slope", "slope")
#: the tower letters of Klipper's steppers
TOWERS = "abc"
#: ``# pkmcal bed: height=<mm> tilt_x=<dz/dx> tilt_y=<dz/dy>`` (any comment character)
BED_COMMENT = re.compile(r"pkmcal bed:\s*height=(\S+)\s+tilt_x=(\S+)\s+tilt_y=(\S+)")


def bed_text(bed, comment: str) -> str:
    """The ``pkmcal bed:`` comment line (height in mm).

    Parameters
    ----------
    bed : array_like, shape (3,)
        ``(height m, tilt_x, tilt_y)``.
    comment : str
        The comment character (``#`` or ``;``).

    Returns
    -------
    str
        The line.
    """
    h, tx, ty = (float(v) for v in bed)
    return f"{comment} pkmcal bed: height={h * 1e3:.6f} tilt_x={tx:.12g} tilt_y={ty:.12g}"


def read_bed(text: str, source: str) -> np.ndarray:
    """The ``pkmcal bed:`` comment of a controller file (zeros without one).

    Parameters
    ----------
    text : str
        The file's text.
    source : str
        Its name, for messages.

    Returns
    -------
    ndarray, shape (3,)
        ``(height m, tilt_x, tilt_y)``.

    Raises
    ------
    InputError
        When a value of the comment is not a number.
    """
    bed = np.zeros(3)
    for n, line in enumerate(text.splitlines(), 1):
        m = BED_COMMENT.search(line)
        if m:
            for k, key in enumerate(("height", "tilt_x", "tilt_y")):
                bed[k] = finite_number(m.group(k + 1), source, n, f"pkmcal bed {key}")
            bed[0] *= 1e-3
    return bed


def entry_origin(entry, section: str, key: str) -> Origin:
    """The :class:`~pkmcal.export.base.Origin` of a Klipper option
    (:class:`~pkmcal.io.klipper_config.Entry`): its file, ``[section] key`` and line.

    Parameters
    ----------
    entry : Entry
        The option as read.
    section, key : str
        Its section and name.

    Returns
    -------
    Origin
        ``printer.cfg: [printer] delta_radius (line 3)`` in words.
    """
    return Origin(entry.file, f"[{section}] {key}", entry.line,
                  "SAVE_CONFIG block" if entry.autosave else "")


def bed_origins(text: str, source: str) -> dict:
    """Where the ``pkmcal bed:`` comment stands (the source map of the bed entries).

    Parameters
    ----------
    text : str
        The file's text.
    source : str
        Its name.

    Returns
    -------
    dict
        ``bed.z``, ``bed.tilt_x``, ``bed.tilt_y`` -> :class:`~pkmcal.export.base.Origin`
        (the last comment, as :func:`read_bed` reads it); empty without one.
    """
    out: dict = {}
    for n, line in enumerate(text.splitlines(), 1):
        if BED_COMMENT.search(line):
            for name, key in zip(BED, ("height", "tilt_x", "tilt_y"), strict=True):
                out[name] = Origin(source, f"pkmcal bed: {key}", n)
    return out


def linear_delta_keys(radius, arms, angles, endstops, bed=BED) -> dict:
    """The source map of a linear-Delta import (:meth:`ControllerFormat.machine_keys`).

    Parameters
    ----------
    radius : sequence of str
        The values that make ``delta_radius``.
    arms, angles, endstops : sequence of 3 sequences of str
        Per tower, the values that make its ``arm_length``, ``tower_angles`` entry and
        ``position_endstop``.
    bed : sequence of 3 str, optional
        The values that make the ``bed`` section's ``height``, ``tilt_x``, ``tilt_y``.

    Returns
    -------
    dict
        Machine-file key path -> value names; the default home (the nozzle at the centre
        below the endstops) is made by the endstops, arms and radius.
    """
    keys: dict = {("delta_radius",): list(radius),
                  ("arm_length",): [n for tower in arms for n in tower],
                  ("print_radius",): ["print_radius"], ("probe_radius",): ["probe_radius"],
                  ("bed",): list(bed)}
    for i in range(3):
        keys[("arm_length", i)] = list(arms[i])
        keys[("tower_angles", i)] = list(angles[i])
        keys[("position_endstop", i)] = list(endstops[i])
    for k, name in zip(("height", "tilt_x", "tilt_y"), bed, strict=True):
        keys[("bed", k)] = [name]
    keys[("home",)] = ([n for tower in endstops for n in tower] + list(radius)
                       + keys[("arm_length",)])
    return keys


def check_printer_values(params, source: str, size_names, dimensions=(), corrections=(),
                         turns=(), slopes=(), radius: float = 0.0, spreads=()) -> None:
    """Refuse values of a printer's controller file that cannot be meant, naming the file's
    key and line (:func:`~pkmcal.export.base.refuse_implausible`), before anything is
    computed with them; the bounds are relative to the printer's size, as a machine file's.

    The size is the median of ``size_names``' magnitudes (a radius, an arm, a height: one
    absurd value does not set it). A dimension is at most
    :data:`~pkmcal.limits.MAX_LENGTH_RATIO` times the size; a correction of one (a rod trim,
    an endstop adjustment) at most ``OPTION_SCALE["error"]`` (10 %) of it; a tower's angle
    trim may move the tower sideways (``radius x trim``) and a bed tilt raise the bed at the
    towers' radius (``radius x slope``) by no more than that either.

    Parameters
    ----------
    params : ControllerParameters
        The values read (SI) with their origins.
    source : str
        The file's name.
    size_names : sequence of str
        Values whose magnitudes' median is the printer's size.
    dimensions, corrections, turns, slopes : sequence of (name, shown)
        Values by kind; ``shown`` formats the value as the file writes it.
    radius : float, optional
        The towers' radius, m (the lever of the angle trims and tilts).
    spreads : sequence of (names, what, shown)
        Per-tower values of one quantity (Klipper's three arm lengths): one may differ from
        their median by no more than a correction.

    Raises
    ------
    InputError
        For the first value beyond its bound.
    """
    from ..limits import MAX_LENGTH, MAX_LENGTH_RATIO
    from ..plausibility import OPTION_SCALE
    from .base import refuse_implausible

    v = params.as_dict()
    with np.errstate(all="ignore"):
        size = float(np.median([abs(v[n]) for n in size_names]))
    origins = getattr(params, "origins", {})
    named = [origins[n].key if n in origins else n for n in size_names]
    size_text = f"{size * 1e3:.6g} mm, the median of {', '.join(dict.fromkeys(named))}"
    top = min(MAX_LENGTH, MAX_LENGTH_RATIO * size)
    for name, shown in dimensions:
        if not abs(v[name]) <= top:
            refuse_implausible(params, name, shown(v[name]), f"more than {MAX_LENGTH_RATIO:g} "
                               f"times the printer's size ({size_text})", source)
    error = OPTION_SCALE["error"] * size
    scale = f"{OPTION_SCALE['error']:.0%} of the printer's size ({size_text})"
    for name, shown in corrections:
        if not abs(v[name]) <= error:
            refuse_implausible(params, name, shown(v[name]), f"a correction of more than "
                               f"{scale}", source)
    for names, what, shown in spreads:
        middle = float(np.median([v[n] for n in names]))
        for name in names:
            if not abs(v[name] - middle) <= error:
                refuse_implausible(params, name, shown(v[name]), f"{what} {shown(middle)} of "
                                   f"the other towers by more than {scale}", source)
    lever = abs(radius) if abs(radius) > 0 else size
    for name, shown in turns:
        if not abs(v[name]) * lever <= error:
            refuse_implausible(params, name, shown(v[name]), "it would move the tower "
                               f"sideways by more than {scale}", source)
    for name, shown in slopes:
        if not abs(v[name]) * lever <= error:
            refuse_implausible(params, name, shown(v[name]), "the bed would rise at the "
                               f"towers' radius by more than {scale}", source)


def bed_values(bed) -> list[tuple[str, str]]:
    """The bed entries for a printed table.

    Parameters
    ----------
    bed : array_like, shape (3,)
        ``(height m, tilt_x, tilt_y)``.

    Returns
    -------
    list of tuple
        ``(name, value in words)``.
    """
    h, tx, ty = (float(x) for x in bed)
    return [("bed height (pkmcal, fixed)", f"{h * 1e3:.6f} mm"),
            ("bed tilt dz/dx (pkmcal, fixed)", f"{tx:.9g}"),
            ("bed tilt dz/dy (pkmcal, fixed)", f"{ty:.9g}")]


def vertical_tower_travel(towers, arms, tops, P) -> np.ndarray:
    """Carriage travel down from the endstop on vertical towers (the firmwares' delta IK).

    Carriage height ``z + sqrt(arm^2 - (tx - x)^2 - (ty - y)^2)`` (Klipper, Marlin's
    ``DELTA_Z``, RepRapFirmware's ``Transform`` without tilt), travel ``top - height``.

    Parameters
    ----------
    towers : array_like, shape (3, 2)
        Tower positions (x, y), m.
    arms : array_like, shape (3,)
        Arm (diagonal rod) lengths, m.
    tops : array_like, shape (3,)
        Carriage heights at the endstops, m (the controller's coordinates).
    P : array_like, shape (K, 3)
        Nozzle targets in the controller's coordinates, m.

    Returns
    -------
    ndarray, shape (K, 3)
        Travels, m; NaN where an arm cannot reach.
    """
    P = np.asarray(P, float).reshape(-1, 3)
    T = np.asarray(towers, float)
    dx = T[None, :, 0] - P[:, 0:1]
    dy = T[None, :, 1] - P[:, 1:2]
    with np.errstate(invalid="ignore"):
        height = P[:, 2:3] + np.sqrt(np.asarray(arms, float)[None] ** 2 - dx * dx - dy * dy)
    return np.asarray(tops, float)[None] - height


def tower_positions(radius, angles) -> np.ndarray:
    """Towers at one radius and their angles: ``(cos(angle) r, sin(angle) r)``.

    Parameters
    ----------
    radius : float or array_like, shape (3,)
        Radius, m.
    angles : array_like, shape (3,)
        Tower angles, rad.

    Returns
    -------
    ndarray, shape (3, 2)
        Tower positions, m.
    """
    a = np.asarray(angles, float)
    r = np.broadcast_to(np.asarray(radius, float), a.shape)
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def controller_endstops(machine: LinearDelta, radius: float, height: float = 0.0):
    """A linear Delta's values on vertical towers of one radius: arms, angles, and the
    ``position_endstop`` (Klipper's meaning) keeping each carriage's height at its endstop.

    With its own radius ``r_i`` tower ``i``'s carriage at the endstop is at ``endstop_i +
    sqrt(l_i^2 - r_i^2)``; a controller with one radius ``R`` puts it at ``E_i + sqrt(l_i^2 -
    R^2)``, so ``E_i = endstop_i + sqrt(l_i^2 - r_i^2) - sqrt(l_i^2 - R^2) - height`` (heights
    above the bed at ``height``).

    Parameters
    ----------
    machine : LinearDelta
        The machine.
    radius : float
        The controller's common radius, m.
    height : float, optional
        The bed's height at the z axis (the controller's z = 0), m.

    Returns
    -------
    arms : ndarray, shape (3,)
        Arm lengths, m.
    angles : ndarray, shape (3,)
        Tower angles, rad.
    endstops : ndarray, shape (3,)
        ``E_i``, m.
    """
    v = machine.firmware_values()
    l, r = np.asarray(v["arm_length"]), np.asarray(v["radius"])
    pe, theta = np.asarray(v["position_endstop"]), np.asarray(v["angle"])
    E = pe + np.sqrt(l * l - r * r) - np.sqrt(l * l - radius * radius) - height
    return l, theta, E


def stepper_order(angles) -> np.ndarray:
    """Which of the machine's towers (legs) are Klipper's ``stepper_a, b, c``.

    Klipper's delta forward kinematics (``mathutil.trilateration``, which sets the home
    position at ``G28`` and reads positions back from the steppers) takes the root below the
    towers' carriages (the arms' elbows) only when ``a -> b -> c`` runs counter-clockwise
    seen from above; on a clockwise order it returns the mirror image above them. So a
    clockwise machine is relabelled: ``stepper_a`` is its first tower, ``stepper_b`` its
    third, ``stepper_c`` its second.

    Parameters
    ----------
    angles : array_like, shape (3,)
        The towers' (legs') angles about +Z, rad, in the machine's order.

    Returns
    -------
    ndarray of int, shape (3,)
        The machine's tower index (0-based) of ``stepper_a``, ``stepper_b``, ``stepper_c``.
    """
    a = np.asarray(angles, float)
    x, y = np.cos(a), np.sin(a)
    turn = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0])
    return np.array([0, 1, 2]) if turn > 0 else np.array([0, 2, 1])


def config_to_update(existing: str, source: str, kinematics: str, what: str,
                     fold_case: bool = False):
    """An existing ``printer.cfg`` read to save values into (``update`` of the Klipper
    formats), refused unless its ``[printer] kinematics`` is ``kinematics``.

    Parameters
    ----------
    existing : str
        The file's text.
    source : str
        Its name, for messages.
    kinematics : str
        The kinematics the format writes (``delta``).
    what : str
        The config in words (``delta printer's config``), for the message.
    fold_case : bool
        Compare the file's kinematics in lower case.

    Returns
    -------
    KlipperConfig
        The file read (Klipper's precedence and includes).

    Raises
    ------
    InputError
        When the file is of other (or no) kinematics.
    """
    from ..io.klipper_config import KlipperConfig

    cfg = KlipperConfig.read(source, existing)
    kin = cfg.entry("printer", "kinematics")
    value = None if kin is None else kin.value.strip()
    if value is None or (value.lower() if fold_case else value) != kinematics:
        raise InputError(f"{source}: exists and is not a Klipper {what} ([printer] "
                         f"kinematics: {kinematics}); choose another output name (a new "
                         "file gets the values as a fragment)")
    return cfg


def order_problem(angles, word: str) -> str | None:
    """Why towers (legs) at these angles cannot be ordered for Klipper (None: they can).

    Parameters
    ----------
    angles : array_like, shape (3,)
        The angles, rad.
    word : str
        ``tower`` or ``leg``.

    Returns
    -------
    str or None
        The reason: three points on one line have no turning sense.
    """
    a = np.asarray(angles, float)
    x, y = np.cos(a), np.sin(a)
    turn = (x[1] - x[0]) * (y[2] - y[0]) - (y[1] - y[0]) * (x[2] - x[0])
    if abs(turn) < 1e-9:
        return (f"the {word}s at {', '.join(f'{np.degrees(v):g}' for v in a)} deg do not turn "
                "about the centre (two at one angle); Klipper's kinematics need three "
                f"{word}s around it")
    return None


def relabel_note(order, angles, word: str) -> str | None:
    """The note of a relabelled stepper order (:func:`stepper_order`), None when none.

    Parameters
    ----------
    order : array_like of int, shape (3,)
        The machine's tower index of ``stepper_a, b, c``.
    angles : array_like, shape (3,)
        The towers' angles in the machine's order, rad.
    word : str
        ``tower`` or ``leg`` (the machine file's word).

    Returns
    -------
    str or None
        Which tower each stepper is, and why.
    """
    order = np.asarray(order, int)
    if np.array_equal(order, [0, 1, 2]):
        return None
    deg = np.degrees(np.asarray(angles, float))
    mine = ", ".join(f"{word} {i + 1} at {deg[i]:g} deg" for i in range(3))
    which = ", ".join(f"stepper_{t} is {word} {order[k] + 1} ({deg[order[k]]:g} deg)"
                      for k, t in enumerate(TOWERS))
    return (f"the machine's {word}s run clockwise ({mine}); Klipper's forward kinematics "
            "(mathutil.trilateration: the home position at G28) needs stepper_a -> "
            "stepper_b -> stepper_c counter-clockwise, so the file relabels them: "
            f"{which}. Wire each {word}'s motor and endstop to its stepper's section")


def wrap_degrees(angle):
    """An angle in degrees brought into (-180, 180].

    Parameters
    ----------
    angle : array_like
        Angles, deg.

    Returns
    -------
    ndarray
        The same angles, in (-180, 180].
    """
    a = np.asarray(angle, float)
    return 180.0 - (180.0 - a) % 360.0


def linear_delta_machine(radius: float, arms, angles, endstops, bed,
                         like: Machine | None = None, name: str = "",
                         extras: dict | None = None) -> LinearDelta:
    """A pkmcal linear Delta from a controller's values (vertical towers, one radius).

    Parameters
    ----------
    radius : float
        Common radius, m.
    arms : array_like, shape (3,)
        Arm lengths, m.
    angles : array_like, shape (3,)
        Tower angles, rad.
    endstops : array_like, shape (3,)
        ``position_endstop`` (Klipper's meaning: the nozzle's height above the bed at the
        centre when the tower's carriage is at its endstop), m.
    bed : array_like, shape (3,)
        ``(height, tilt_x, tilt_y)`` of the bed in the machine's frame: the endstops are
        raised by the height (the bed itself is a set-up beside the machine,
        :func:`bed_setups`).
    like : Machine, optional
        Name and home pose come from it.
    name : str, optional
        Name when ``like`` gives none.
    extras : dict, optional
        ``print_radius`` and ``probe_radius`` (m) the controller's file holds
        (:attr:`~pkmcal.export.base.ControllerParameters.extras`): kept on the machine.

    Returns
    -------
    LinearDelta
        The machine.
    """
    bed = np.asarray(bed, float).reshape(3)
    arms = np.asarray(arms, float).reshape(3)
    one = bool(np.all(arms == arms[0]))
    m = linear_delta(float(radius), float(arms[0]) if one else arms,
                     np.asarray(angles, float).reshape(3),
                     np.asarray(endstops, float).reshape(3) + bed[0],
                     home=None if like is None else like.home,
                     name=(like.name if like is not None and like.name else name))
    for key, value in (extras or {}).items():
        if key in ("print_radius", "probe_radius"):
            setattr(m, key, float(value))
    return m


class KlipperDelta(ControllerFormat):
    """Klipper ``kinematics: delta`` (see the module docstring)."""

    name = "klipper"
    machine_kind = "linear_delta"
    machine_words = "linear Delta printer"
    words = ("Klipper delta kinematics (klippy/kinematics/delta.py): [printer] delta_radius, "
             "[stepper_a|b|c] arm_length, angle, position_endstop")
    suffix = ".cfg"

    NAMES = (["delta_radius"] + [f"arm_length_{t}" for t in TOWERS]
             + [f"angle_{t}" for t in TOWERS] + [f"position_endstop_{t}" for t in TOWERS]
             + list(BED) + [f"stepper_{t}.tower" for t in TOWERS])
    KINDS = (["length"] * 4 + ["angle"] * 3 + ["length"] * 3 + list(BED_KINDS)
             + ["number"] * 3)

    def values(self, radius, arms, angles, endstops, bed,
               towers=(1, 2, 3)) -> ControllerParameters:
        """Klipper's values from their parts (SI, in stepper order), the bed and the
        steppers' towers fixed.

        Parameters
        ----------
        radius : float
            ``delta_radius``, m.
        arms : array_like, shape (3,)
            ``arm_length`` a, b, c, m.
        angles : array_like, shape (3,)
            ``angle`` a, b, c, rad.
        endstops : array_like, shape (3,)
            ``position_endstop`` a, b, c, m.
        bed : array_like, shape (3,)
            The bed (``bed.z`` m, ``bed.tilt_x``, ``bed.tilt_y``).
        towers : array_like of int, shape (3,), optional
            The machine's tower (1-based) of ``stepper_a, b, c`` (:func:`stepper_order`).

        Returns
        -------
        ControllerParameters
            The values.
        """
        v = np.concatenate([[radius], arms, angles, endstops, bed, towers]).astype(float)
        return ControllerParameters(list(self.NAMES), v, list(self.KINDS),
                                    np.arange(len(v)) >= 10)

    def initial(self, machine: Machine, setups=None) -> ControllerParameters:
        """Klipper's values read off a linear Delta (exact for vertical towers of one radius).

        Parameters
        ----------
        machine : Machine
            A linear Delta.
        setups : Setups, optional
            The experiment's set-ups: the bed (:func:`setups_bed`) Klipper's z = 0 is on.

        Returns
        -------
        ControllerParameters
            ``delta_radius`` the mean tower radius; arms and angles per tower;
            ``position_endstop`` keeping each carriage's height at its endstop, above the bed.
        """
        bed = setups_bed(setups)
        R = float(np.mean(machine.firmware_values()["radius"]))
        arms, angles, E = controller_endstops(machine, R, bed[0])
        order = stepper_order(angles)      # counter-clockwise, as Klipper's FK needs
        return self.values(R, arms[order], angles[order], E[order], bed, order + 1)

    def layout_problem(self, machine: Machine) -> str | None:
        """Towers with no turning sense (two at one angle) cannot be ordered for Klipper.

        Parameters
        ----------
        machine : Machine
            A linear Delta.

        Returns
        -------
        str or None
            The reason.
        """
        return order_problem(machine.firmware_values()["angle"], "tower")

    def export_notes(self, params: ControllerParameters, machine: Machine,
                     P=None) -> list[str]:
        """The towers' relabelling when they run clockwise (:func:`relabel_note`).

        Parameters
        ----------
        params : ControllerParameters
            The values written.
        machine : Machine
            The machine.
        P : ndarray, optional
            The workspace (unused).

        Returns
        -------
        list of str
            The notes.
        """
        note = relabel_note(self.order(params), machine.firmware_values()["angle"], "tower")
        return [] if note is None else [note]

    @staticmethod
    def order(params: ControllerParameters) -> np.ndarray:
        """The machine's tower index (0-based) of ``stepper_a, b, c``.

        Parameters
        ----------
        params : ControllerParameters
            Klipper's values.

        Returns
        -------
        ndarray of int, shape (3,)
            The indices.
        """
        return np.rint(params.values[13:16]).astype(int) - 1

    def ik(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """Klipper's carriage travels down from the endstops for nozzle targets.

        Parameters
        ----------
        params : ControllerParameters
            Klipper's values.
        P : ndarray, shape (K, 3)
            Targets in the calibrated frame, m.
        R : ndarray, optional
            Ignored (the effector does not rotate).

        Returns
        -------
        ndarray, shape (K, 3)
            Travels per tower (the machine's order), m; NaN where an arm cannot reach.
        """
        v = params.values
        radius, arms, angles, pe, bed = v[0], v[1:4], v[4:7], v[7:10], v[10:13]
        order = self.order(params)
        Pc = np.array(P, float).reshape(-1, 3)
        # Klipper's z is the height above the bed: the bed's plane (height and tilt) of the
        # calibrated frame is its z = 0; what Klipper's values cannot fold in of the tilt is
        # in the remaining error
        Pc[:, 2] -= bed[0] + bed[1] * Pc[:, 0] + bed[2] * Pc[:, 1]
        tops = pe + np.sqrt(arms**2 - radius**2)
        travel = vertical_tower_travel(tower_positions(radius, angles), arms, tops, Pc)
        q = np.empty_like(travel)
        q[:, order] = travel
        return q

    def text(self, params: ControllerParameters, machine: Machine,
             setups=None) -> str:
        """The ``printer.cfg`` fragment (mm, deg).

        Parameters
        ----------
        params : ControllerParameters
            Klipper's values.
        machine : Machine
            The machine they are for.
        setups : Setups, optional
            Unused (the values hold the bed: none of the experiment's set-ups is read).

        Returns
        -------
        str
            ``[printer]`` and ``[stepper_a|b|c]`` sections with the kinematic keys.
        """
        v = params.values
        bed = v[10:13]
        lines = [f"# pkmcal export --to klipper: {machine.name or 'linear Delta'}",
                 "# Klipper delta kinematics (klippy/kinematics/delta.py). To use it: pkmcal "
                 "export --to klipper -o printer.cfg onto your printer.cfg saves these values "
                 "as Klipper's SAVE_CONFIG does; or copy them into the #*# SAVE_CONFIG block "
                 "and delete the same keys from the sections above it (Klipper uses the "
                 "main sections' values where both have one)",
                 "# z = 0 is the bed" + (
                     f"; the bed's tilt against the towers (dz/dx {bed[1]:.6g}, dz/dy "
                     f"{bed[2]:.6g}) is folded into these values as far as they can hold it, "
                     "the rest counted in the remaining error (bed_mesh corrects it)"
                     if np.any(bed[1:] != 0) else ""),
                 bed_text(bed, "#")]
        order = self.order(params)
        if not np.array_equal(order, [0, 1, 2]):
            lines += [f"# stepper_{t} is tower {order[k] + 1} of the machine file (relabelled "
                      "counter-clockwise for Klipper)" for k, t in enumerate(TOWERS)]
        lines += ["[printer]", "kinematics: delta", f"delta_radius: {v[0] * 1e3:.6f}"]
        for i, t in enumerate(TOWERS):
            lines += ["", f"[stepper_{t}]", f"arm_length: {v[1 + i] * 1e3:.6f}",
                      f"angle: {np.degrees(v[4 + i]):.9f}",
                      f"position_endstop: {v[7 + i] * 1e3:.6f}"]
        return "\n".join(lines) + "\n"

    def saved_values(self, params: ControllerParameters) -> dict:
        """The options ``DeltaCalibration.save_state`` writes, as it formats them (``%.6f``).

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        dict
            ``{(section, option): text}``, mm and deg.
        """
        v = params.values
        out = {("printer", "delta_radius"): f"{v[0] * 1e3:.6f}"}
        for i, t in enumerate(TOWERS):
            out[(f"stepper_{t}", "angle")] = f"{np.degrees(v[4 + i]):.6f}"
            out[(f"stepper_{t}", "arm_length")] = f"{v[1 + i] * 1e3:.6f}"
            out[(f"stepper_{t}", "position_endstop")] = f"{v[7 + i] * 1e3:.6f}"
        return out

    def update(self, existing: str, params: ControllerParameters, machine: Machine,
               source: str) -> str | None:
        """``printer.cfg`` with the values saved as Klipper's ``SAVE_CONFIG`` saves them
        (:func:`~pkmcal.io.klipper_config.save_config_text`: the body kept, the same options
        in the body commented out, the auto-save block rewritten with its other options).

        Raises
        ------
        InputError
            When the file is not a Klipper delta config, or an ``[include]`` file defines one
            of the values (Klipper refuses to save it then).
        """
        from ..io.klipper_config import save_config_text

        cfg = config_to_update(existing, source, "delta", "delta printer's config",
                               fold_case=True)
        return save_config_text(existing, self.saved_values(params), source, cfg)

    def values_text(self, params: ControllerParameters) -> list[tuple[str, str]]:
        """The values as the written file has them, for a printed table.

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        list of tuple
            ``(name, value in words)``: the file's keys, mm and deg, then the bed.
        """
        v = params.values
        out = [("[printer] delta_radius", f"{v[0] * 1e3:.6f} mm")]
        for i, t in enumerate(TOWERS):
            out += [(f"[stepper_{t}] arm_length", f"{v[1 + i] * 1e3:.6f} mm"),
                    (f"[stepper_{t}] angle", f"{np.degrees(v[4 + i]):.9f} deg"),
                    (f"[stepper_{t}] position_endstop", f"{v[7 + i] * 1e3:.6f} mm")]
        return out + bed_values(v[10:13])

    #: a printer.cfg with its backups: one printer's sessions (SPEC 9)
    measurements_together = True

    def holds_measurements(self, path, head: str) -> bool:
        """A Klipper config (:func:`~pkmcal.io.klipper_data.is_klipper_config`)."""
        from ..io.klipper_data import is_klipper_config

        return is_klipper_config(path, head)

    def read_measurements(self, paths: list, machine: Machine) -> list:
        """A config's saved DELTA_CALIBRATE points and meshes
        (:func:`~pkmcal.io.klipper_data.read_klipper_data`); several configs as sessions,
        the same saved points counted once
        (:func:`~pkmcal.io.klipper_data.klipper_sessions`)."""
        from ..io.klipper_data import klipper_sessions, read_klipper_data

        if len(paths) > 1:
            return klipper_sessions(paths, machine).data
        return read_klipper_data(paths[0], machine)

    def bed_mesh_height(self, text: str) -> float:
        """The probe's ``z_offset`` (m, 0 when none or below the nozzle): Klipper's own
        meshes hold the bed as seen with the nozzle that far above it, and so does pkmcal's."""
        from ..io.klipper_config import KlipperConfig
        from ..io.klipper_data import probe_offsets

        try:
            return max(probe_offsets(KlipperConfig.read("printer.cfg", text))[2] * 1e-3, 0.0)
        except InputError:
            return 0.0

    def with_bed_mesh(self, text: str, params: ControllerParameters,
                      machine: Machine, setups=None) -> str | None:
        """``printer.cfg`` with ``[bed_mesh pkmcal]`` in its SAVE_CONFIG block (never the
        user's own profiles), when the file has a ``[bed_mesh]`` section (Klipper loads
        profiles only then) and the correction is worth it (:mod:`.bed_mesh`)."""
        from .bed_mesh import bed_correction, print_radius_of, with_klipper_profile

        if not re.search(r"(?m)^\[bed_mesh\]", text):
            return None
        correction = bed_correction(self, params, machine, print_radius_of(machine, setups),
                                    height=self.bed_mesh_height(text), setups=setups)
        if correction is None or not correction.worth_it:
            return None
        return with_klipper_profile(text, correction)

    def parse(self, text: str, source: str) -> ControllerParameters:
        """Klipper's values from a ``printer.cfg`` (or a fragment), as Klipper resolves them.

        Reads ``[printer] delta_radius`` and ``[stepper_a|b|c] arm_length``, ``angle``,
        ``position_endstop`` with Klipper's defaults (``b``, ``c`` take ``a``'s arm length and
        endstop; angles 210, 330, 90) and Klipper's precedence
        (:class:`~pkmcal.io.klipper_config.KlipperConfig`: ``[include]`` files where they
        stand, the body over the ``#*#`` SAVE_CONFIG block); also ``[printer] print_radius``
        and ``[delta_calibrate] radius`` (kept in the machine file).

        Parameters
        ----------
        text : str
            The file's text.
        source : str
            Its name, for messages (includes are resolved beside it).

        Returns
        -------
        ControllerParameters
            The values, SI.

        Raises
        ------
        InputError
            Naming the file, line and key of a value that is not a number, or the key missing.
        """
        from ..io.klipper_config import KlipperConfig

        cfg = KlipperConfig.read(source, text)
        kin = cfg.entry("printer", "kinematics")
        if kin is not None and kin.value.strip().lower() != "delta":
            raise InputError(f"{kin.where('printer', 'kinematics')}: {kin.value.strip()!r}; "
                             "this format reads Klipper's delta kinematics (kinematics: delta)")

        def get(sec, key, default=None):
            if cfg.entry(sec, key) is None and default is None:
                raise InputError(f"{source}: [{sec}] {key}: missing (Klipper's delta "
                                 "kinematics need it)")
            return cfg.number(sec, key, default)

        def sane(sec, key, value, low, high, what):
            # a number that cannot be meant, named in the user's file (not as a key of the
            # machine file written from it)
            if not low <= value <= high:
                e = cfg.entry(sec, key)
                where = e.where(sec, key) if e is not None else f"{source}: [{sec}] {key}"
                raise InputError(f"{where}: {value:g} mm cannot be meant "
                                 f"({what} between {low:g} and {high:g})")
            return value

        radius = get("printer", "delta_radius")
        if not radius > 0:
            e = cfg.entry("printer", "delta_radius")
            raise InputError(f"{entry_origin(e, 'printer', 'delta_radius').text_in_file()}: "
                             f"{e.value.strip()} must be > 0 (the delta radius)")
        sane("printer", "delta_radius", radius, 1.0, SANE_LENGTH, "a delta radius")
        arm_a = get("stepper_a", "arm_length")
        pe_a = get("stepper_a", "position_endstop")
        arms = np.array([arm_a] + [get(f"stepper_{t}", "arm_length", arm_a) for t in "bc"])
        pe = np.array([pe_a] + [get(f"stepper_{t}", "position_endstop", pe_a) for t in "bc"])
        angles = np.array([get(f"stepper_{t}", "angle", d)
                           for t, d in zip(TOWERS, (210.0, 330.0, 90.0), strict=True)])
        for i, t in enumerate(TOWERS):
            sec = f"stepper_{t}"
            sane(sec if cfg.entry(sec, "arm_length") else "stepper_a", "arm_length", arms[i],
                 1.0, SANE_LENGTH, "an arm length")
            sane(sec if cfg.entry(sec, "position_endstop") else "stepper_a", "position_endstop",
                 pe[i], -SANE_LENGTH, SANE_LENGTH, "a nozzle height")
            if not -720.0 <= angles[i] <= 720.0:
                e = cfg.entry(sec, "angle")
                raise InputError(f"{e.where(sec, 'angle')}: {angles[i]:g} deg cannot be meant "
                                 "(a tower angle between -720 and 720)")
        for i, t in enumerate(TOWERS):
            if not arms[i] > radius:
                sec = f"stepper_{t}" if cfg.entry(f"stepper_{t}", "arm_length") else "stepper_a"
                e = cfg.entry(sec, "arm_length")
                raise InputError(f"{e.where(sec, 'arm_length')}: {arms[i]:g} mm must exceed "
                                 f"delta_radius ({radius:g} mm)")
        params = self.values(radius * 1e-3, arms * 1e-3, np.radians(angles), pe * 1e-3,
                             read_bed(text, source))
        params.origins.update(bed_origins(text, source))
        mm = (lambda x: f"{x * 1e3:g} mm")  # noqa: E731
        params.origins["delta_radius"] = entry_origin(cfg.entry("printer", "delta_radius"),
                                                      "printer", "delta_radius")
        for t, default in zip(TOWERS, (210.0, 330.0, 90.0), strict=True):
            for key, name in (("arm_length", "arm_length"), ("position_endstop",
                                                             "position_endstop")):
                sec = f"stepper_{t}" if cfg.entry(f"stepper_{t}", key) else "stepper_a"
                params.origins[f"{name}_{t}"] = entry_origin(cfg.entry(sec, key), sec, key)
            e = cfg.entry(f"stepper_{t}", "angle")
            params.origins[f"angle_{t}"] = (
                entry_origin(e, f"stepper_{t}", "angle") if e is not None else
                Origin(source, f"[stepper_{t}] angle", None, f"not set: Klipper's {default:g}"))
        for key, (sec, opt) in (("print_radius", ("printer", "print_radius")),
                                ("probe_radius", ("delta_calibrate", "radius"))):
            if cfg.entry(sec, opt) is not None:
                params.extras[key] = cfg.number(sec, opt, above=0.0) * 1e-3
                params.origins[key] = entry_origin(cfg.entry(sec, opt), sec, opt)
        check_printer_values(
            params, source, ["delta_radius", "arm_length_a", "position_endstop_a"],
            spreads=[([f"{key}_{t}" for t in TOWERS], f"differs from the {words}", mm)
                     for key, words in (("arm_length", "arm length"),
                                        ("position_endstop", "endstop height"))])
        return params

    def machine_keys(self, params: ControllerParameters) -> dict:
        """The source map of an import (see :meth:`ControllerFormat.machine_keys`).

        Parameters
        ----------
        params : ControllerParameters
            Klipper's values.

        Returns
        -------
        dict
            Each machine-file key from the option of the same meaning (``delta_radius``,
            and per stepper ``arm_length``, ``angle``, ``position_endstop`` with the bed's
            height).
        """
        return linear_delta_keys(["delta_radius"], [[f"arm_length_{t}"] for t in TOWERS],
                                 [[f"angle_{t}"] for t in TOWERS],
                                 [[f"position_endstop_{t}", "bed.z"] for t in TOWERS])

    def to_machine(self, params: ControllerParameters, like: Machine | None = None) -> Machine:
        """A linear Delta with Klipper's values (vertical towers, one radius).

        Parameters
        ----------
        params : ControllerParameters
            Klipper's values.
        like : Machine, optional
            Name and home pose come from it.

        Returns
        -------
        Machine
            The :class:`~pkmcal.machines.LinearDelta`, the endstops raised by a ``pkmcal
            bed`` comment's height (the bed: :meth:`imported_setups`).
        """
        v = params.values
        back = np.argsort(self.order(params))          # the machine's tower order
        return linear_delta_machine(v[0], v[1:4][back], v[4:7][back], v[7:10][back],
                                    self.imported_bed(params), like,
                                    "linear Delta (imported from Klipper)", params.extras)

    def imported_bed(self, params: ControllerParameters) -> np.ndarray:
        """The bed the values hold, ``(height m, tilt_x, tilt_y)``: Klipper's z is the height
        above the bed, its values the printer in the bed's frame, square (a tilt named in the
        pkmcal comment is folded in already).

        Parameters
        ----------
        params : ControllerParameters
            Klipper's values.

        Returns
        -------
        ndarray, shape (3,)
            The plane.
        """
        return np.array([params.values[10], 0.0, 0.0])


KLIPPER = register_format(KlipperDelta())
