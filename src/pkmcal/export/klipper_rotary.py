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
up). So ``angle = phi``, ``shoulder_radius = a - b`` (plus the mean of ``da_x - db_x``),
``upper_arm_length = l1 + dl1``, ``lower_arm_length = l2 + dl2`` and the shoulder height is
the mean of ``da_z - db_z`` above the bed. Klipper holds one radius and one height, no
sideways offset of an arm (``da_y - db_y``) and no per-arm radius or height: the fit gives the
best values (:func:`~pkmcal.export.fitting.fit_controller`, all 14 values free).

The readings (one convention, both ways)
----------------------------------------
The machine's reading is counted from the arm's endstop: reading 0 is the arm at its endstop
(as a linear Delta's carriage travel is counted from its endstop), so the arm's actuator
offset ``dtheta`` IS the arm's angle at its endstop, Klipper's ``abs_endstop =
IK(0, 0, position_endstop)``. Klipper homes the arms to their endstops and then declares its
steppers at ``IK(home)`` (``home`` its forward kinematics of the ``abs_endstop``), so at a
target ``P`` the motor has turned ``IK(P) - abs_endstop`` from the endstop: that is the
machine's reading. Export writes ``position_endstop`` where ``dtheta`` puts the effector at
the centre; import sets ``dtheta = abs_endstop``. Nothing of it is in a comment: a
``SAVE_CONFIG`` update or an ``[include]`` carries it whole. (Files of older pkmcal exports
have ``# pkmcal bed_z_mm`` and ``# pkmcal endstop_reading_*_deg`` lines; their readings at
the endstops were 0, this convention; the lines are not read, and import says so.)

The bed (Klipper's ``z = 0``)
-----------------------------
Klipper's coordinates have the bed at ``z = 0`` and refuse moves below
``minimum_z_position`` (0); its kinematics declares the effector at ``(0, 0, 0)`` when it
starts (``set_position([0, 0, 0])``), which must therefore be reachable: out of reach the
steppers' positions are NaN and the first ``G28`` fails. The export places Klipper's ``z = 0``
at ``bed_z`` of the machine file's frame (:meth:`KlipperRotaryDelta.placed`): the file's own
``z = 0`` when every workspace target is at or above it and the centre there is reachable (a
file in Klipper's frame, as import writes it), else the workspace's lowest point; with
neither, the export is refused, naming why. Klipper's target is the machine file's ``(x, y,
z - bed_z)``; the export says so (its notes, printed and in its JSON record). Klipper also
refuses moves above ``min(position_endstop)`` and outside its radius limit
(``RotaryDeltaKinematics.check_move``): the export counts the workspace targets it would
refuse and says so.

Import writes the machine in Klipper's frame (the bed at ``z = 0``, home at the centre 50 mm
below the lowest endstop height, but at least 50 mm above the bed: the default 0.1 m workspace
cube around home stays above Klipper's bed, so that an export of the imported file keeps the
bed where it is and writes the same values). With ``--like`` it is moved into the like-file's
frame by a rule on values: its shoulders at the like-file's shoulder height (the mean of its legs'
``da_z - db_z``), its home the like-file's.

Stepper order
-------------
Klipper's forward kinematics (``mathutil.trilateration``, used for the home position at
``G28``) takes the effector below the shoulders only when ``stepper_a -> b -> c`` run
counter-clockwise. A machine whose legs run clockwise is exported relabelled: ``stepper_a`` is
leg 1, ``stepper_b`` leg 3, ``stepper_c`` leg 2; the export's note names each stepper's leg,
and the fixed values ``stepper_a.leg``... keep the map, so that the machine's readings come
back in its own order.
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


#: the height of the default workspace below the lowest endstop of an imported machine: its
#: home (the centre of the 0.1 m workspace cube) is this far below it, m
HOME_BELOW_ENDSTOPS = 0.05
#: ... but at least this far above the bed (half the default workspace cube's side): a cube
#: reaching below Klipper's bed would make the export move the bed, and an import followed by
#: an export would not give Klipper its values back, m
HOME_ABOVE_BED = 0.05


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
             + ["bed_z"] + [f"stepper_{t}.leg" for t in STEPPERS])
    KINDS = ["length"] * 8 + ["angle"] * 3 + ["length"] * 4 + ["number"] * 3
    #: the values Klipper holds (the rest, fixed, are where its frame and steppers are on the
    #: machine)
    N_FREE = 14

    def values(self, radius, height, upper, lower, angles, endstops, bed_z=0.0,
               legs=(1, 2, 3)) -> ControllerParameters:
        """Klipper's values from their parts (SI, in stepper order); ``bed_z`` and the
        steppers' legs fixed.

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
            Height of Klipper's ``z = 0`` in the machine file's frame, m.
        legs : array_like of int, shape (3,), optional
            The machine's leg (1-based) of ``stepper_a, b, c``.

        Returns
        -------
        ControllerParameters
            The values.
        """
        v = np.concatenate([[radius, height], upper, lower, angles, endstops, [bed_z],
                            legs]).astype(float)
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
            order (3,)``, ``order`` the machine's leg index (0-based) of each stepper.
        """
        v = params.values
        return (v[0], v[1], v[2:5], v[5:8], v[8:11], v[11:14], v[14],
                np.rint(v[15:18]).astype(int) - 1)

    def layout_problem(self, machine: Machine) -> str | None:
        """Legs that have no turning sense (two at one angle) cannot be ordered for Klipper.

        Parameters
        ----------
        machine : Machine
            A Delta.

        Returns
        -------
        str or None
            The reason.
        """
        from .klipper import order_problem

        return order_problem(machine.leg_angles, "leg")

    def initial(self, machine: Machine, setups=None) -> ControllerParameters:
        """Klipper's values read off a Delta (exact without per-leg radius, height or
        sideways offset), in the machine file's frame (``bed_z = 0``).

        Parameters
        ----------
        machine : Machine
            A Delta.
        setups : Setups, optional
            Unused (no set-up of the experiment enters these values).

        Returns
        -------
        ControllerParameters
            ``shoulder_radius`` and ``shoulder_height`` the legs' means, arms and angles per
            leg (the steppers counter-clockwise, :func:`~pkmcal.export.klipper.stepper_order`),
            ``position_endstop`` where the arm at its endstop (reading 0: the angle
            ``dtheta``) puts the effector at the centre.
        """
        from .klipper import stepper_order

        e = leg_offsets(machine)
        _, dth, dl1, dl2, _ = machine.legs()
        order = stepper_order(machine.leg_angles)
        radius, height = float(np.mean(e[:, 0])), float(np.mean(e[:, 2]))
        upper, lower = (machine.l1 + dl1)[order], (machine.l2 + dl2)[order]
        endstops = centre_height(radius, height, upper, lower, dth[order])
        return self.values(radius, height, upper, lower,
                           np.asarray(machine.leg_angles, float)[order], endstops, 0.0,
                           order + 1)

    def shifted(self, params: ControllerParameters, bed_z: float) -> ControllerParameters:
        """The same machine with Klipper's ``z = 0`` at ``bed_z`` of the machine file's frame.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        bed_z : float
            The new bed height, m.

        Returns
        -------
        ControllerParameters
            ``shoulder_height`` and ``position_endstop`` measured from the new bed.
        """
        v = params.values.copy()
        dz = bed_z - v[14]
        v[1] -= dz
        v[11:14] -= dz
        v[14] = bed_z
        return params.with_values(v)

    def frame_problem(self, params: ControllerParameters, P) -> str | None:
        """Why Klipper cannot start and home with these values over these targets.

        Parameters
        ----------
        params : ControllerParameters
            The values (with their ``bed_z``).
        P : ndarray, shape (K, 3)
            Targets in the machine file's frame, m.

        Returns
        -------
        str or None
            The reason (None: the shoulders and the endstops are above the bed, every target
            at or above it, and the centre on the bed and 1 mm below it, where Klipper's
            ``home()`` declares the effector before its homing move, reachable by every arm).
        """
        radius, height, upper, lower, angles, endstops, bed_z, _ = self.unpack(params)
        z = np.asarray(P, float).reshape(-1, 3)[:, 2] - bed_z
        size = float(np.max(upper + lower))
        if not height > 0:
            return (f"the shoulders would be {height * 1e3:.6g} mm above it (Klipper's "
                    "shoulder_height must be > 0)")
        if z.size and not z.min() >= -1e-12 * size:
            return (f"a workspace target would be {-z.min() * 1e3:.6g} mm below it (Klipper "
                    "refuses moves below minimum_z_position, 0)")
        if not np.all(np.isfinite(stepper_angles(radius, height, angles, upper, lower,
                                                  np.zeros((1, 3))))):
            return ("no arm reaches the centre on the bed (Klipper declares the effector at "
                    "(0, 0, 0) when it starts: out of reach, the first G28 fails)")
        if not np.all(np.isfinite(stepper_angles(radius, height, angles, upper, lower,
                                                  np.array([[0.0, 0.0, -1e-3]])))):
            return ("no arm reaches the centre 1 mm below it (Klipper's G28 declares the "
                    "effector there before its homing move: out of reach, G28 fails)")
        if not endstops.min() >= 0:
            return (f"the effector at the centre with the arms at their endstops would be "
                    f"{endstops.min() * 1e3:.6g} mm above it (Klipper's position_endstop, its "
                    "top of travel, must be >= minimum_z_position, 0)")
        return None

    def placed(self, params: ControllerParameters, machine: Machine,
               P) -> ControllerParameters:
        """Klipper's bed placed (see the module docstring): the machine file's ``z = 0`` when
        Klipper can run the workspace with it there, else the workspace's lowest point.

        Parameters
        ----------
        params : ControllerParameters
            :meth:`initial`'s values.
        machine : Machine
            The machine.
        P : ndarray, shape (K, 3)
            The workspace's positions, m.

        Returns
        -------
        ControllerParameters
            The values with their ``bed_z``.

        Raises
        ------
        InputError
            When neither place works, naming why.
        """
        own = self.shifted(params, 0.0)
        if self.frame_problem(own, P) is None:
            return own
        low = float(np.min(np.asarray(P, float).reshape(-1, 3)[:, 2]))
        lowest = self.shifted(params, low)
        why = self.frame_problem(lowest, P)
        if why is None:
            return lowest
        raise InputError(f"--to {self.name}: Klipper's z = 0 (the bed) must be below every "
                         f"workspace target and reachable at the centre; neither the machine "
                         f"file's z = 0 ({self.frame_problem(own, P)}) nor the workspace's "
                         f"lowest point z = {low * 1e3:.6g} mm ({why}) can be it. Give a "
                         "workspace (--workspace) that Klipper can run")

    def move_limits(self, params: ControllerParameters):
        """Klipper's move limits (``RotaryDeltaKinematics.check_move``).

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        max_z : float
            ``min(position_endstop)``, m (Klipper's z).
        max_xy : float
            The radius limit, ``min(shoulder_radius + upper_arm, lower_arm -
            shoulder_radius)``, m.
        limit_z : float
            Above it the radius tapers to ``max_z - z``, m.
        """
        radius, height, upper, lower, angles, endstops, _, _ = self.unpack(params)
        ends = self.abs_endstops(params)
        elbow_z = height + upper * np.sin(ends)
        return (float(endstops.min()),
                float(min(np.min(radius + upper), np.min(lower - radius))),
                float(np.min(elbow_z - lower)))

    def export_notes(self, params: ControllerParameters, machine: Machine,
                     P=None) -> list[str]:
        """Where Klipper's frame is, how its steppers map onto the legs, and the targets
        Klipper's move limits refuse.

        Parameters
        ----------
        params : ControllerParameters
            The values written.
        machine : Machine
            The machine.
        P : ndarray, shape (K, 3), optional
            The workspace, m.

        Returns
        -------
        list of str
            The notes.
        """
        from ..units import format_quantity
        from .klipper import relabel_note

        _, _, _, _, _, _, bed_z, order = self.unpack(params)
        mm = (lambda v: format_quantity(v, "length"))  # noqa: E731
        where = ("its own z = 0: every workspace target is above it and the centre there is "
                 "reachable" if bed_z == 0 else
                 "the workspace's lowest point, as the machine file's own z = 0 is not one "
                 "Klipper can run")
        shift = (f"z {'-' if bed_z >= 0 else '+'} {abs(bed_z) * 1e3:.6f} mm" if bed_z != 0
                 else "z")
        notes = [f"Klipper's z = 0 (the bed) is at z = {bed_z * 1e3:.6f} mm of the machine "
                 f"file ({where}): Klipper's (x, y, z) is the machine file's (x, y, {shift}). "
                 "The arms' readings are counted from their endstops (reading 0: the arm at "
                 "its endstop, where Klipper homes it)"]
        note = relabel_note(order, machine.leg_angles, "leg")
        if note is not None:
            notes.append(note)
        if P is not None:
            max_z, max_xy, limit_z = self.move_limits(params)
            Pk = np.asarray(P, float).reshape(-1, 3) - np.array([0.0, 0.0, bed_z])
            r = np.hypot(Pk[:, 0], Pk[:, 1])
            z = Pk[:, 2]
            top = np.where(z > limit_z, np.minimum(max_xy, max_z - z), max_xy)
            out = (z > max_z * (1 + 1e-12)) | (r > top * (1 + 1e-12))
            if out.any():
                notes.append(
                    f"{int(out.sum())} of {len(Pk)} workspace targets are outside the moves "
                    f"Klipper allows (RotaryDeltaKinematics.check_move: z up to the lowest "
                    f"position_endstop, {mm(max_z)}, radius up to {mm(max_xy)}, less above "
                    f"{mm(limit_z)}): Klipper refuses them; the endstops (reading 0) must "
                    "trigger above the workspace for Klipper to reach it all")
        return notes

    def abs_endstops(self, params: ControllerParameters) -> np.ndarray:
        """Klipper's ``abs_endstops``: the angle each arm is declared at when homed.

        Parameters
        ----------
        params : ControllerParameters
            Klipper's values.

        Returns
        -------
        ndarray, shape (3,)
            ``IK_i(0, 0, position_endstop_i)`` per stepper, rad.
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
            Targets in the machine file's frame, m.
        R : ndarray, optional
            Ignored (the platform translates).

        Returns
        -------
        ndarray, shape (K, 3)
            Per leg (the machine's order), its stepper's ``IK(P - bed_z e_z) -
            abs_endstop``, rad: the turn from the endstop; NaN where Klipper cannot reach.
        """
        radius, height, upper, lower, angles, _, bed_z, order = self.unpack(params)
        Pk = np.asarray(P, float).reshape(-1, 3) - np.array([0.0, 0.0, bed_z])
        s = stepper_angles(radius, height, angles, upper, lower, Pk)
        q = np.empty_like(s)
        q[:, order] = s - self.abs_endstops(params)[None]
        return q

    def text(self, params: ControllerParameters, machine: Machine,
             setups=None) -> str:
        """The ``printer.cfg`` fragment (mm, deg; lengths to 1e-9 mm, angles to 1e-12 deg).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        machine : Machine
            The machine they are for.
        setups : Setups, optional
            Unused (no set-up of the experiment enters these values).

        Returns
        -------
        str
            The fragment: ``[printer]`` and ``[stepper_a|b|c]`` with the kinematic keys only
            (merge into the printer's config; pins, ``gear_ratio`` and speeds stay as they
            are); its comments say where Klipper's frame is (information only: nothing is
            read back from them).
        """
        radius, height, upper, lower, angles, endstops, bed_z, order = self.unpack(params)
        mm = (lambda v: f"{float(v) * 1e3:.9f}")  # noqa: E731
        deg = (lambda v: f"{np.degrees(float(v)):.12f}")  # noqa: E731
        lines = [f"# pkmcal export for {machine.name or 'a rotary Delta'}: Klipper rotary_delta",
                 "# (klippy/kinematics/rotary_delta.py); merge into printer.cfg. Lengths mm,",
                 "# angles deg. Klipper's z = 0 (the bed) is at z = "
                 f"{float(bed_z) * 1e3:.9f} mm of the machine file's frame; the arms' readings",
                 "# count from their endstops."]
        lines += [f"# stepper_{t} is leg {order[k] + 1} of the machine file"
                  for k, t in enumerate(STEPPERS)]
        lines += ["", "[printer]", "kinematics: rotary_delta", f"shoulder_radius: {mm(radius)}",
                  f"shoulder_height: {mm(height)}"]
        for i, t in enumerate(STEPPERS):
            lines += ["", f"[stepper_{t}]", f"position_endstop: {mm(endstops[i])}",
                      f"upper_arm_length: {mm(upper[i])}",
                      f"lower_arm_length: {mm(lower[i])}", f"angle: {deg(angles[i])}"]
        return "\n".join(lines) + "\n"

    def values_text(self, params: ControllerParameters) -> list[tuple[str, str]]:
        """The values as the written file has them, for a printed table.

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        list of tuple
            ``(name, value in words)``: the file's keys (mm, deg), then where Klipper's
            frame and steppers are on the machine (pkmcal's, not in the file's values).
        """
        radius, height, upper, lower, angles, endstops, bed_z, order = self.unpack(params)
        out = [("[printer] shoulder_radius", f"{radius * 1e3:.6f} mm"),
               ("[printer] shoulder_height", f"{height * 1e3:.6f} mm")]
        for i, t in enumerate(STEPPERS):
            out += [(f"[stepper_{t}] position_endstop", f"{endstops[i] * 1e3:.6f} mm"),
                    (f"[stepper_{t}] upper_arm_length", f"{upper[i] * 1e3:.6f} mm"),
                    (f"[stepper_{t}] lower_arm_length", f"{lower[i] * 1e3:.6f} mm"),
                    (f"[stepper_{t}] angle", f"{np.degrees(angles[i]):.9f} deg")]
        out.append(("Klipper's z = 0 in the machine file (pkmcal)", f"{bed_z * 1e3:.6f} mm"))
        out += [(f"stepper_{t} is (pkmcal)", f"leg {order[k] + 1}")
                for k, t in enumerate(STEPPERS)]
        return out

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
            The values, SI, in Klipper's frame (``bed_z = 0``), the steppers legs 1, 2, 3;
            ``stepper_b``/``c`` arm lengths and endstops default to ``stepper_a``'s, angles
            to 30, 150, 270 deg. ``# pkmcal`` lines of older exports are not read (a note
            says so).

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
        params = self.values(radius, height, per["upper_arm_length"], per["lower_arm_length"],
                             angles, per["position_endstop"])
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
        old = pkmcal_comments(text, source)
        if old:
            lines = ", ".join(f"{k} (line {n})" for k, (_, n) in old.items())
            params.notes.append(
                f"{source}: the '# pkmcal' lines of an older pkmcal export ({lines}) are not "
                "read: the machine is in Klipper's frame (the bed at z = 0; --like moves it to "
                "the like-file's shoulder height) and its readings count from the endstops, "
                "as those exports' readings did")
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
        order = self.unpack(params)[7]
        for k, t in enumerate(STEPPERS):
            i = int(order[k])
            keys[("leg_angles", i)] = [f"angle_{t}"]
            keys[("legs", i, "da")] = ["shoulder_height"]
            keys[("legs", i, "dl1")] = [f"upper_arm_length_{t}"]
            keys[("legs", i, "dl2")] = [f"lower_arm_length_{t}"]
            keys[("legs", i, "dtheta")] = [f"position_endstop_{t}", "shoulder_radius",
                                           "shoulder_height", f"upper_arm_length_{t}",
                                           f"lower_arm_length_{t}"]
        return keys

    def update(self, existing: str, params: ControllerParameters, machine: Machine,
               source: str) -> str | None:
        """``printer.cfg`` with the values saved as Klipper's ``SAVE_CONFIG`` saves them
        (:func:`~pkmcal.io.klipper_config.save_config_text`): ``shoulder_radius``,
        ``shoulder_height`` and per stepper ``angle``, ``position_endstop`` (what
        ``RotaryDeltaCalibration.save_state`` writes) and the arm lengths pkmcal fits too,
        ``%.6f``. Everything the machine needs is in these values (no comment).

        Raises
        ------
        InputError
            When the file is not a Klipper rotary_delta config, or an ``[include]`` file
            defines one of the values.
        """
        from ..io.klipper_config import save_config_text
        from .klipper import config_to_update

        cfg = config_to_update(existing, source, "rotary_delta", "rotary_delta config")
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
        """A Delta with Klipper's values: in Klipper's frame (the bed at ``z = 0``), or with
        ``like`` in its frame (the shoulders at its shoulder height).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        like : Machine, optional
            Platform radius ``b``, home, ``smr_offset``, name and frame come from it (default
            ``b = 0``: Klipper folds the effector's radius into ``shoulder_radius``).

        Returns
        -------
        Delta
            ``a = shoulder_radius + b``, ``l1``/``l2`` the mean arms with the per-stepper
            differences as ``dl1``/``dl2``, the shoulders at ``shoulder_height + bed_z``
            (``da.z``), ``dtheta = abs_endstop`` (reading 0 at the endstop), no other errors;
            the legs in the machine's order (``stepper_a.leg``...); home at the centre
            :data:`HOME_BELOW_ENDSTOPS` below the lowest endstop and at least
            :data:`HOME_ABOVE_BED` above the bed (``like``'s home when given).
            :meth:`initial` of it gives the values back (in its frame).
        """
        radius, height, upper, lower, angles, endstops, bed_z, order = self.unpack(params)
        if like is not None:          # the like-file's frame: its shoulder height
            bed_z = float(np.mean(leg_offsets(like)[:, 2])) - height
        b = float(getattr(like, "platform_radius", 0.0))
        l1, l2 = float(np.mean(upper)), float(np.mean(lower))
        u = np.zeros((3, 9))
        u[order, 2] = height + bed_z
        u[order, 3] = self.abs_endstops(params)
        u[order, 4] = upper - l1
        u[order, 5] = lower - l2
        leg_angles = np.empty(3)
        leg_angles[order] = angles
        height_home = max(float(np.min(endstops)) - HOME_BELOW_ENDSTOPS, HOME_ABOVE_BED)
        home = (np.array([0.0, 0.0, height_home + bed_z]), np.eye(3))
        if like is not None:
            home = (np.asarray(like.home[0], float), np.asarray(like.home[1], float))
        name = like.name if like is not None and like.name else "imported from Klipper"
        return Delta(radius + b, b, l1, l2, leg_angles, delta_parameters(u.reshape(-1)),
                     smr_offset=float(getattr(like, "smr_offset", 0.0) or 0.0), home=home,
                     name=name)


register_format(KlipperRotaryDelta())
