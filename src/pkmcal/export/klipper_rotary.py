"""Klipper's ``rotary_delta`` kinematics: a ``printer.cfg`` fragment for a rotary Delta robot.

Read in Klipper's source and documentation (``Klipper3d/klipper``):

- ``klippy/kinematics/rotary_delta.py`` (``RotaryDeltaKinematics``, ``RotaryDeltaCalibration``):
  ``[printer] shoulder_radius`` and ``shoulder_height`` are ONE value for the three arms;
  ``[stepper_a|b|c] upper_arm_length``, ``lower_arm_length`` and ``position_endstop`` per
  stepper (``b`` and ``c`` default to ``a``'s); ``angle`` per stepper in degrees (defaults 30,
  150, 270). The stepper position is the arm angle in radians (``units_in_radians``). The
  elbow of arm ``i`` at angle ``s`` is ``((shoulder_radius + upper_arm cos s) cos(angle),
  (shoulder_radius + upper_arm cos s) sin(angle), shoulder_height + upper_arm sin s)``
  (``elbow_coord``): ``s = 0`` is the arm horizontal, positive is up. At homing the arm at its
  endstop is declared at ``abs_endstop = IK(0, 0, position_endstop)``
  (``itersolve_calc_position_from_coord``), so the motor turns ``IK(P) - abs_endstop`` from
  the endstop to reach ``P``. ``SAVE_CONFIG`` writes ``%.6f`` (``save_state``).
- ``klippy/chelper/kin_rotary_delta.c`` (``rotary_stepper_calc_position``,
  ``rotary_two_arm_calc``): the inverse kinematics the steppers follow. The effector point is
  rotated into the arm's plane (``sjx = x cos + y sin - shoulder_radius``, ``sjy = z -
  shoulder_height``, ``sjz = y cos - x sin``), the lower arm shortened to ``sqrt(lower_arm^2 -
  sjz^2)`` in that plane, and the elbow is the circle intersection with the larger ``x``
  (elbow out): ``atan2`` of it is the angle. The effector's joints are not offset from the
  effector point: the effector's radius is folded into ``shoulder_radius``.
- ``docs/Config_Reference.md`` (rotary delta section): ``shoulder_radius`` is "the radius of
  the horizontal circle formed by the three shoulder joints, minus the radius of the circle
  formed by the effector joints"; ``shoulder_height`` is "the distance of the shoulder joints
  from the bed, minus the effector toolhead height"; ``position_endstop`` is "the distance
  between the nozzle and the bed when the nozzle is in the center of the build area and the
  endstop triggers" (a length in mm, not an angle).

Map from pkmcal's Delta (seed 001, SPEC 2.2)
--------------------------------------------
Leg ``i`` of the Delta stands at ``phi_i`` with its base joint at ``(a + da_x, da_y, da_z)``
and its platform joint at ``(b + db_x, db_y, db_z)`` in the leg frame; its arm angle is
``q + dtheta`` with seed 001's ``theta`` convention, which is Klipper's (0 horizontal, positive
up). So ``angle_i = phi_i``, ``shoulder_radius = a - b`` (plus the mean of ``da_x - db_x``),
``upper_arm_length_i = l1 + dl1_i``, ``lower_arm_length_i = l2 + dl2_i`` and the shoulder height
is the mean of ``da_z - db_z`` above the bed. Klipper holds one radius and one height, no
sideways offset of an arm (``da_y - db_y``) and no per-arm radius or height: the fit gives the
best values (:func:`~pkmcal.export.base.fit_controller`, all 14 values free).

The readings (the joint convention)
-----------------------------------
The machine's reading ``q`` is seed 001's arm angle; Klipper commands the motor from the
endstop. With ``endstop_reading_i`` the machine's reading when arm ``i``'s endstop triggers,
the machine reads ``q_i = IK_i(P) - abs_endstop_i + endstop_reading_i`` at Klipper's target
``P``. pkmcal counts the readings from the endstops: ``endstop_reading = 0`` (the arm's
actuator offset ``dtheta`` then places the endstop: ``abs_endstop = dtheta`` on the machine
read directly). It is a fixed value, written as ``# pkmcal endstop_reading_a_deg`` comments;
a file without them (a printer's own config) means readings that are Klipper's stepper angles
(``endstop_reading = abs_endstop``).

The bed (Klipper's ``z = 0``)
-----------------------------
Klipper's coordinates have the bed at ``z = 0`` and the effector above it
(``shoulder_height > 0``, moves below ``minimum_z_position``, default 0, refused). A machine
file whose home is above its ``z = 0`` (a file in Klipper's frame, as :meth:`to_machine`
writes it) keeps its frame (``bed_z = 0``); pkmcal's own Delta frame (shoulders at ``z = 0``,
the platform hanging below) gets its bed ``l1 + l2`` below the shoulders, below anything the
platform reaches. Klipper's target is the calibrated frame's ``(x, y, z - bed_z)``;
``bed_z`` is a fixed value written as a ``# pkmcal bed_z_mm`` comment, which :meth:`parse`
reads back (0 without it: the file's frame is Klipper's).
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from ..machines.delta import Delta, delta_parameters
from .base import (
    ControllerFormat,
    ControllerParameters,
    Origin,
    finite_number,
    origin_of,
    register_format,
)

#: the letters of Klipper's steppers
STEPPERS = "abc"
#: Klipper's default ``angle`` per stepper, deg
DEFAULT_ANGLES = (30.0, 150.0, 270.0)
_PKMCAL = re.compile(r"^\s*#\s*pkmcal\s+(\S+)\s*=\s*(\S+)")


def two_arm_angle(dx, dy, upper2, lower2):
    """Klipper's ``rotary_two_arm_calc``: the upper arm's angle for an effector joint.

    Parameters
    ----------
    dx, dy : array_like
        Effector joint relative to the shoulder in the arm's plane (outward, up).
    upper2 : array_like
        Upper arm length squared.
    lower2 : array_like
        Lower arm length squared (shortened by the sideways offset).

    Returns
    -------
    ndarray
        The angle, rad (elbow out); NaN where the arms cannot reach.
    """
    with np.errstate(all="ignore"):
        inv_dy = 1.0 / dy
        c1 = 0.5 * inv_dy * (dx * dx + dy * dy + upper2 - lower2)
        c2 = dx * inv_dy
        scale = c2 * c2 + 1.0
        ex = c1 * c2 + np.sqrt(scale * upper2 - c1 * c1)
        ey = c1 * scale - c2 * ex
        return np.arctan2(ey, ex)


def stepper_angles(shoulder_radius, shoulder_height, angles, upper, lower, P):
    """Klipper's ``rotary_stepper_calc_position`` for each stepper and target.

    Parameters
    ----------
    shoulder_radius, shoulder_height : float
        Klipper's values, m.
    angles : array_like, shape (3,)
        ``angle`` per stepper, rad.
    upper, lower : array_like, shape (3,)
        ``upper_arm_length`` and ``lower_arm_length`` per stepper, m.
    P : array_like, shape (K, 3)
        Targets in Klipper's coordinates, m.

    Returns
    -------
    ndarray, shape (K, 3)
        Arm angles, rad; NaN where unreachable.
    """
    P = np.asarray(P, float).reshape(-1, 3)
    c, s = np.cos(angles)[None], np.sin(angles)[None]
    x, y, z = P[:, 0:1], P[:, 1:2], P[:, 2:3]
    sjz = y * c - x * s
    sjx = x * c + y * s - shoulder_radius
    sjy = z - shoulder_height
    return two_arm_angle(sjx, sjy, np.asarray(upper)[None] ** 2,
                         np.asarray(lower)[None] ** 2 - sjz * sjz)


def centre_height(shoulder_radius, shoulder_height, upper, lower, s):
    """The effector's height at the centre with an arm at angle ``s`` (Klipper's frame).

    The inverse of ``IK_i(0, 0, z) = s``: the elbow at ``shoulder_radius + upper cos s`` out
    and ``shoulder_height + upper sin s`` up, the effector ``lower`` from it, below it.

    Parameters
    ----------
    shoulder_radius, shoulder_height : float
        Klipper's values, m.
    upper, lower : array_like
        Arm lengths, m.
    s : array_like
        Arm angles, rad.

    Returns
    -------
    ndarray
        Heights, m (NaN where the lower arm cannot reach the axis).
    """
    out = shoulder_radius + upper * np.cos(s)
    with np.errstate(invalid="ignore"):
        return shoulder_height + upper * np.sin(s) - np.sqrt(lower * lower - out * out)


def pkmcal_comments(text: str, source: str) -> dict:
    """The ``# pkmcal KEY = VALUE`` lines of a controller file (numbers as written).

    Parameters
    ----------
    text : str
        The file's text.
    source : str
        Its name, for messages.

    Returns
    -------
    dict
        Key -> ``(value, line number)``.

    Raises
    ------
    InputError
        When a value is not a finite number (naming line and key).
    """
    out = {}
    for n, line in enumerate(text.splitlines(), 1):
        m = _PKMCAL.match(line)
        if m:
            out[m.group(1)] = (finite_number(m.group(2), source, n, f"pkmcal {m.group(1)}"), n)
    return out


def leg_offsets(machine: Delta) -> np.ndarray:
    """Each leg's base joint minus its platform joint, leg frame (the Delta's ``e_i``).

    Parameters
    ----------
    machine : Delta
        The machine.

    Returns
    -------
    ndarray, shape (3, 3)
        ``(a - b + da_x - db_x, da_y - db_y, da_z - db_z)`` per leg, m.
    """
    da, _, _, _, db = machine.legs()
    e = da - db
    e[:, 0] += machine.a - machine.b
    return e


class KlipperRotaryDelta(ControllerFormat):
    """Klipper ``kinematics: rotary_delta`` (see the module docstring)."""

    name = "klipper-rotary-delta"
    machine_kind = "delta"
    machine_words = "rotary Delta robot"
    words = ("Klipper rotary_delta kinematics (klippy/kinematics/rotary_delta.py, "
             "klippy/chelper/kin_rotary_delta.c): [printer] shoulder_radius, shoulder_height, "
             "[stepper_a|b|c] upper_arm_length, lower_arm_length, angle, position_endstop")
    suffix = ".cfg"

    NAMES = (["shoulder_radius", "shoulder_height"]
             + [f"upper_arm_length_{t}" for t in STEPPERS]
             + [f"lower_arm_length_{t}" for t in STEPPERS]
             + [f"angle_{t}" for t in STEPPERS]
             + [f"position_endstop_{t}" for t in STEPPERS]
             + ["bed_z"] + [f"endstop_reading_{t}" for t in STEPPERS])
    KINDS = ["length"] * 8 + ["angle"] * 3 + ["length"] * 4 + ["angle"] * 3
    #: the values Klipper holds (the rest, fixed, are pkmcal's frame and reading convention)
    N_FREE = 14

    def values(self, radius, height, upper, lower, angles, endstops, bed_z=0.0,
               readings=(0.0, 0.0, 0.0)) -> ControllerParameters:
        """Klipper's values from their parts (SI); ``bed_z`` and the readings fixed.

        Parameters
        ----------
        radius, height : float
            ``shoulder_radius``, ``shoulder_height``, m.
        upper, lower : array_like, shape (3,)
            Arm lengths per stepper, m.
        angles : array_like, shape (3,)
            ``angle`` per stepper, rad.
        endstops : array_like, shape (3,)
            ``position_endstop`` per stepper, m.
        bed_z : float, optional
            Height of Klipper's ``z = 0`` in the calibrated frame, m.
        readings : array_like, shape (3,), optional
            The machine's reading at each endstop, rad.

        Returns
        -------
        ControllerParameters
            The values.
        """
        v = np.concatenate([[radius, height], upper, lower, angles, endstops, [bed_z],
                            readings]).astype(float)
        return ControllerParameters(list(self.NAMES), v, list(self.KINDS),
                                    np.arange(len(v)) >= self.N_FREE)

    @staticmethod
    def unpack(params: ControllerParameters):
        """The parts of Klipper's values (see :meth:`values`).

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        tuple
            ``radius, height, upper (3,), lower (3,), angles (3,), endstops (3,), bed_z,
            readings (3,)``.
        """
        v = params.values
        return v[0], v[1], v[2:5], v[5:8], v[8:11], v[11:14], v[14], v[15:18]

    def initial(self, machine: Machine) -> ControllerParameters:
        """Klipper's values read off a Delta (exact without per-leg radius, height or
        sideways offset).

        Parameters
        ----------
        machine : Machine
            A Delta.

        Returns
        -------
        ControllerParameters
            ``shoulder_radius`` and ``shoulder_height`` the legs' means, arms and angles per
            leg, ``position_endstop`` where the arm's endstop angle ``dtheta`` puts the
            effector at the centre; ``bed_z`` and the readings at the endstops (0) fixed.
        """
        e = leg_offsets(machine)
        _, dth, dl1, dl2, _ = machine.legs()
        shoulder_z = float(np.mean(e[:, 2]))
        bed_z = 0.0 if float(machine.home[0][2]) > 0 else shoulder_z - (machine.l1 + machine.l2)
        radius, height = float(np.mean(e[:, 0])), shoulder_z - bed_z
        upper, lower = machine.l1 + dl1, machine.l2 + dl2
        readings = np.zeros(3)
        endstops = centre_height(radius, height, upper, lower, readings + dth)
        return self.values(radius, height, upper, lower, np.asarray(machine.leg_angles, float),
                           endstops, bed_z, readings)

    def abs_endstops(self, params: ControllerParameters) -> np.ndarray:
        """Klipper's ``abs_endstops``: the angle each arm is declared at when homed.

        Parameters
        ----------
        params : ControllerParameters
            Klipper's values.

        Returns
        -------
        ndarray, shape (3,)
            ``IK_i(0, 0, position_endstop_i)``, rad.
        """
        radius, height, upper, lower, angles, endstops, _, _ = self.unpack(params)
        P = np.column_stack([np.zeros(3), np.zeros(3), endstops])
        return np.diag(stepper_angles(radius, height, angles, upper, lower, P)).copy()

    def ik(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """The machine's readings when Klipper commands targets.

        Parameters
        ----------
        params : ControllerParameters
            Klipper's values.
        P : ndarray, shape (K, 3)
            Targets in the calibrated frame, m.
        R : ndarray, optional
            Ignored (the platform translates).

        Returns
        -------
        ndarray, shape (K, 3)
            ``IK_i(P - bed_z e_z) - abs_endstop_i + endstop_reading_i``, rad; NaN where
            Klipper cannot reach.
        """
        radius, height, upper, lower, angles, _, bed_z, readings = self.unpack(params)
        Pk = np.asarray(P, float).reshape(-1, 3) - np.array([0.0, 0.0, bed_z])
        s = stepper_angles(radius, height, angles, upper, lower, Pk)
        return s - self.abs_endstops(params)[None] + readings[None]

    def text(self, params: ControllerParameters, machine: Machine) -> str:
        """The ``printer.cfg`` fragment (mm, deg; lengths to 1e-9 mm, angles to 1e-12 deg).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        machine : Machine
            The machine they are for.

        Returns
        -------
        str
            The fragment: ``[printer]`` and ``[stepper_a|b|c]`` with the kinematic keys only
            (merge into the printer's config; pins, ``gear_ratio`` and speeds stay as they
            are), and the ``#pkmcal`` lines of the frame and reading convention.
        """
        radius, height, upper, lower, angles, endstops, bed_z, readings = self.unpack(params)
        mm = (lambda v: f"{float(v) * 1e3:.9f}")  # noqa: E731
        deg = (lambda v: f"{np.degrees(float(v)):.12f}")  # noqa: E731
        lines = [f"# pkmcal export for {machine.name or 'a rotary Delta'}: Klipper rotary_delta",
                 "# (klippy/kinematics/rotary_delta.py); merge into printer.cfg. Lengths mm,",
                 "# angles deg. Klipper's z = 0 (the bed) is at bed_z of the calibrated frame;",
                 "# the machine reads endstop_reading (seed 001's arm angle) when the arm's",
                 "# endstop triggers.",
                 f"# pkmcal bed_z_mm = {float(bed_z) * 1e3:.9f}"]
        lines += [f"# pkmcal endstop_reading_{t}_deg = {np.degrees(float(r)):.12f}"
                  for t, r in zip(STEPPERS, readings, strict=True)]
        lines += ["", "[printer]", "kinematics: rotary_delta", f"shoulder_radius: {mm(radius)}",
                  f"shoulder_height: {mm(height)}"]
        for i, t in enumerate(STEPPERS):
            lines += ["", f"[stepper_{t}]", f"position_endstop: {mm(endstops[i])}",
                      f"upper_arm_length: {mm(upper[i])}",
                      f"lower_arm_length: {mm(lower[i])}", f"angle: {deg(angles[i])}"]
        return "\n".join(lines) + "\n"

    def parse(self, text: str, source: str) -> ControllerParameters:
        """Klipper's rotary_delta values of a ``printer.cfg``, as Klipper resolves them
        (:class:`~pkmcal.io.klipper_config.KlipperConfig`: ``[include]`` files, the sections
        above the ``SAVE_CONFIG`` block over it).

        Parameters
        ----------
        text : str
            The file's text.
        source : str
            Its name, for messages.

        Returns
        -------
        ControllerParameters
            The values, SI; ``stepper_b``/``c`` arm lengths and endstops default to
            ``stepper_a``'s, angles to 30, 150, 270 deg; ``bed_z`` and the readings at the
            endstops from the ``#pkmcal`` lines, else 0 and Klipper's own angles (the
            machine's readings are Klipper's stepper angles: ``endstop_reading =
            abs_endstop``).

        Raises
        ------
        InputError
            Naming the line and key of a value that is not a number, or the key missing.
        """
        from ..io.klipper_config import KlipperConfig

        cfg = KlipperConfig.read(source, text)      # Klipper's precedence and includes
        kin = cfg.entry("printer", "kinematics")
        if kin is not None and kin.value.strip() != "rotary_delta":
            raise InputError(f"{kin.where('printer', 'kinematics')}: {kin.value.strip()!r} is "
                             "not rotary_delta (use the format of that kinematics)")

        def get(section, key, default=None):
            if cfg.entry(section, key) is not None:
                return cfg.number(section, key)
            if default is not None:
                return default
            raise InputError(f"{source}: [{section}] {key} is missing (Klipper's rotary_delta "
                             "needs it)")

        radius = get("printer", "shoulder_radius") * 1e-3
        height = get("printer", "shoulder_height") * 1e-3
        per = {}
        for key in ("upper_arm_length", "lower_arm_length", "position_endstop"):
            a = get("stepper_a", key)
            per[key] = np.array([get(f"stepper_{t}", key, a) for t in STEPPERS]) * 1e-3
        angles = np.radians([get(f"stepper_{t}", "angle", d)
                             for t, d in zip(STEPPERS, DEFAULT_ANGLES, strict=True)])
        notes = pkmcal_comments(text, source)
        bed_z = notes.get("bed_z_mm", (0.0, 0))[0] * 1e-3
        params = self.values(radius, height, per["upper_arm_length"], per["lower_arm_length"],
                             angles, per["position_endstop"], bed_z)
        from .klipper import check_printer_values, entry_origin

        for sec, key, name in ([("printer", "shoulder_radius", "shoulder_radius"),
                                ("printer", "shoulder_height", "shoulder_height")]
                               + [(f"stepper_{t}", key, f"{key}_{t}") for t in STEPPERS
                                  for key in ("upper_arm_length", "lower_arm_length",
                                              "position_endstop", "angle")]):
            at = sec if cfg.entry(sec, key) is not None or key == "angle" else "stepper_a"
            e = cfg.entry(at, key)
            params.origins[name] = (entry_origin(e, at, key) if e is not None else
                                    Origin(source, f"[{sec}] {key}", None,
                                           "not set: Klipper's default"))
        for key, (_, n) in notes.items():
            params.origins[re.sub(r"_(mm|deg)$", "", key)] = Origin(source, f"#pkmcal {key}", n)
        mm = (lambda x: f"{x * 1e3:g} mm")  # noqa: E731
        check_printer_values(params, source, ["shoulder_radius", "upper_arm_length_a",
                                              "lower_arm_length_a"],
                             dimensions=[(n, mm) for n in self.NAMES[:8] + self.NAMES[11:14]])
        ends = self.abs_endstops(params)
        for i, t in enumerate(STEPPERS):
            if not np.isfinite(ends[i]):
                raise InputError(f"{origin_of(params, f'position_endstop_{t}')}: the arm "
                                 "cannot reach the centre at that height with these arm "
                                 f"lengths ({origin_of(params, f'upper_arm_length_{t}')}, "
                                 f"{origin_of(params, f'lower_arm_length_{t}')})")
        readings = np.array([np.radians(notes[f"endstop_reading_{t}_deg"][0])
                             if f"endstop_reading_{t}_deg" in notes else ends[i]
                             for i, t in enumerate(STEPPERS)])
        params.values[15:18] = readings
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
            ``base_radius`` from ``shoulder_radius``; the arms from the steppers'
            ``upper_arm_length`` / ``lower_arm_length``; the leg angles from ``angle``; each
            leg's shoulder height, arm trims and endstop angle from its options; the home
            from the endstops.
        """
        ends = [f"position_endstop_{t}" for t in STEPPERS]
        keys = {("base_radius",): ["shoulder_radius"],
                ("upper_arm",): [f"upper_arm_length_{t}" for t in STEPPERS],
                ("forearm",): [f"lower_arm_length_{t}" for t in STEPPERS],
                ("home",): ends}
        for i, t in enumerate(STEPPERS):
            keys[("leg_angles", i)] = [f"angle_{t}"]
            keys[("legs", i, "da")] = ["shoulder_height"]
            keys[("legs", i, "dl1")] = [f"upper_arm_length_{t}"]
            keys[("legs", i, "dl2")] = [f"lower_arm_length_{t}"]
            keys[("legs", i, "dtheta")] = [f"position_endstop_{t}", f"endstop_reading_{t}",
                                           "shoulder_radius", "shoulder_height"]
        return keys

    def update(self, existing: str, params: ControllerParameters, machine: Machine,
               source: str) -> str | None:
        """``printer.cfg`` with the values saved as Klipper's ``SAVE_CONFIG`` saves them
        (:func:`~pkmcal.io.klipper_config.save_config_text`): ``shoulder_radius``,
        ``shoulder_height`` and per stepper ``angle``, ``position_endstop`` (what
        ``RotaryDeltaCalibration.save_state`` writes) and the arm lengths pkmcal fits too.
        The readings' convention is Klipper's (its stepper angles).

        Raises
        ------
        InputError
            When the file is not a Klipper rotary_delta config, or an ``[include]`` file
            defines one of the values.
        """
        from ..io.klipper_config import KlipperConfig, save_config_text

        cfg = KlipperConfig.read(source, existing)
        kin = cfg.entry("printer", "kinematics")
        if kin is None or kin.value.strip() != "rotary_delta":
            raise InputError(f"{source}: exists and is not a Klipper rotary_delta config "
                             "([printer] kinematics: rotary_delta); choose another output name "
                             "(a new file gets the values as a fragment)")
        radius, height, upper, lower, angles, endstops, _, _ = self.unpack(params)
        values = {("printer", "shoulder_radius"): f"{radius * 1e3:.6f}",
                  ("printer", "shoulder_height"): f"{height * 1e3:.6f}"}
        for i, t in enumerate(STEPPERS):
            values[(f"stepper_{t}", "angle")] = f"{np.degrees(angles[i]):.6f}"
            values[(f"stepper_{t}", "position_endstop")] = f"{endstops[i] * 1e3:.6f}"
            values[(f"stepper_{t}", "upper_arm_length")] = f"{upper[i] * 1e3:.6f}"
            values[(f"stepper_{t}", "lower_arm_length")] = f"{lower[i] * 1e3:.6f}"
        return save_config_text(existing, values, source, cfg)

    def to_machine(self, params: ControllerParameters, like: Machine | None = None) -> Machine:
        """A Delta with Klipper's values, in Klipper's frame (the bed at ``z = 0``).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        like : Machine, optional
            Platform radius ``b``, home, ``smr_offset`` and name come from it (default ``b = 0``:
            Klipper folds the effector's radius into ``shoulder_radius``).

        Returns
        -------
        Delta
            ``a = shoulder_radius + b``, ``l1``/``l2`` the mean arms with the per-stepper
            differences as ``dl1``/``dl2``, the shoulders at ``shoulder_height`` (``da.z``),
            ``dtheta = abs_endstop - endstop_reading`` (the arm's angle at reading 0), no
            other errors; home at the centre at the mean endstop height (``like``'s home,
            in Klipper's frame, when given). Its readings are
            the machine's, so :meth:`initial` of it gives the values back.
        """
        radius, height, upper, lower, angles, endstops, bed_z, readings = self.unpack(params)
        b = float(getattr(like, "platform_radius", 0.0))
        l1, l2 = float(np.mean(upper)), float(np.mean(lower))
        dth = self.abs_endstops(params) - readings
        u = np.zeros((3, 9))
        u[:, 2] = height
        u[:, 3] = dth
        u[:, 4] = upper - l1
        u[:, 5] = lower - l2
        home = (np.array([0.0, 0.0, float(np.mean(endstops))]), np.eye(3))
        if like is not None:            # --like's home, in Klipper's frame (z = 0 at bed_z)
            home = (np.asarray(like.home[0], float) - np.array([0.0, 0.0, bed_z]),
                    np.asarray(like.home[1], float))
        name = like.name if like is not None and like.name else "imported from Klipper"
        return Delta(radius + b, b, l1, l2, np.asarray(angles, float),
                     delta_parameters(u.reshape(-1)),
                     smr_offset=float(getattr(like, "smr_offset", 0.0) or 0.0), home=home,
                     name=name)


register_format(KlipperRotaryDelta())
