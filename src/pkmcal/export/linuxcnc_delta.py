"""LinuxCNC ``rotarydeltakins`` and ``lineardeltakins``: a ``.hal`` file of ``setp`` lines.

Read in LinuxCNC's source (``LinuxCNC/linuxcnc``, ``src/emc/kinematics/``):

``rotarydeltakins`` (``rotarydeltakins.c``, ``rotarydeltakins-common.h``, as in LinuxCNC 2.9
and its master; Debian's ``linuxcnc-uspace`` 2.9 and its Python module ``rotarydeltakins``
run the same code)
    HAL pins ``rotarydeltakins.platformradius`` (origin to a hip joint), ``.thighlength``
    (hip to knee), ``.shinlength`` (the parallelogram, knee to foot), ``.footradius`` (the
    controlled point to an ankle joint), in machine units. Joints 0, 1, 2 are hip angles in
    DEGREES, 0 with the thigh straight out, positive knee DOWN (``kinematics_forward``: knee
    at ``z = -thighlength sin(j)``). The hips: joint 0 at -90 deg (its thigh swings in the YZ
    plane on the -Y side), joint 1 at +30 deg and joint 2 at 150 deg (the forward map's knee
    of joint 1 has ``x = +sqrt(3) y``, of joint 2 ``x = -sqrt(3) y``; ``kinematics_inverse``
    turns the target by -120 deg for joint 1 and by +120 deg for joint 2). ``inverse_j0``
    takes the knee with the larger distance from the axis (knee out), its height ``b knee_y -
    a``. The world's z is up, the origin in the plane of the hips, the foot below it at
    negative z (``kinematics_forward`` takes the lower root ``(-b - sqrt(d)) / (2 a)``): the
    calibrated frame's ``(x, y, z)`` as it is, no sign change. (The 2013 version had the hips
    at -90, 150, 30 deg and z growing towards the foot; that is not the code LinuxCNC runs
    today.) Only ``platformradius - footradius`` enters: ``footradius`` is held at the
    platform radius ``b`` (fixed).

``lineardeltakins`` (``lineardeltakins.c``, ``lineardeltakins-common.h``)
    HAL pins ``lineardeltakins.R`` (effective horizontal distance bridged by the rods:
    Marlin's ``DELTA_RADIUS``, pkmcal's ``delta_radius``) and ``lineardeltakins.L`` (rod
    length). Towers 0, 1, 2 at ``(0, R)``, ``(-sin60 R, -cos60 R)``, ``(sin60 R, -cos60 R)``:
    90, 210, 330 deg. Joint ``j`` is the carriage height ``z + sqrt(L^2 - (Tx - x)^2 - (Ty -
    y)^2)`` (``kinematics_inverse``), its zero the carriage level with the world's ``z = 0``.
    (Some versions carry ``J0off`` .. ``J2off`` pins; the mainline has ``R`` and ``L`` only, so
    they are not used.)

The joints' zero (the INI's ``HOME_OFFSET``)
--------------------------------------------
A joint's position after homing is the INI's ``[JOINT_n] HOME_OFFSET`` (the joint position
of the home switch); it, not a HAL pin of the kinematics, is where LinuxCNC holds a joint's
zero. A configuration directory (``-o DIR/``, :mod:`~pkmcal.export.linuxcnc_config`) writes
it into its INI; the ``.hal`` file alone has it as comment lines (``# [JOINT_0] HOME_OFFSET =
...``) with a ``# pkmcal`` line that :meth:`parse` reads back; no HAL ``offset`` component is
wired (that would re-route the user's ``motor-pos-cmd`` nets).

- Linear Delta: pkmcal's reading is the carriage's travel down from its endstop, so the
  joint is ``HOME_OFFSET_j - q``: ``HOME_OFFSET_j`` is the carriage height at the endstop
  (fitted, one per joint; the joint's scale has the sign that makes "down" negative).
- Rotary Delta: pkmcal's reading is seed 001's arm angle (up positive, rad); the joint is
  ``joint_zero_j - deg(q)``, with ``joint_zero_j`` the joint position at reading 0 (fitted:
  it holds the arm's actuator offset ``dtheta``). With the machine's reading at the home
  switch ``q_home`` (deg), ``HOME_OFFSET_j = joint_zero_j - q_home``.

Legs and frames
---------------
Reading ``i`` of the machine goes to the LinuxCNC joint whose hip or tower angle is the
nearest to the machine's leg ``i`` (within 5 deg: :meth:`applies` refuses a machine whose legs
are not LinuxCNC's three, e.g. the 90/180/-90 deg default Delta). The assignment is
carried as fixed values (``readingN.joint``) and ``# pkmcal`` lines. The linear Delta's world
``z = 0`` is the bed of a probe-calibrated file (its ``bed`` height, fixed ``bed_z``; the
tilt is not kinematics and is left out); the rotary Delta's is the hip plane, as LinuxCNC has
it. Lengths are written in mm (``LINEAR_UNITS = mm``), 1e-9 mm digits; angles in degrees,
1e-12 deg digits.
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import InputError
from ..instruments.probe import bed_plane
from ..machines.base import Machine
from ..machines.delta import Delta, delta_parameters
from ..machines.linear_delta import linear_delta
from .base import (
    ControllerFormat,
    ControllerParameters,
    Origin,
    finite_number,
    hal_line_kind,
    refuse_foreign_text,
    register_format,
    setups_bed,
)
from .klipper_rotary import leg_offsets, pkmcal_comments
from .linuxcnc_config import LinuxCNCKinematics

#: rotarydeltakins' hip angles of joints 0, 1, 2, deg
ROTARY_HIPS = (-90.0, 30.0, 150.0)
#: lineardeltakins' tower angles of joints 0, 1, 2, deg
LINEAR_TOWERS = (90.0, 210.0, 330.0)
#: how far a machine's leg may stand from LinuxCNC's, deg
ANGLE_TOLERANCE = 5.0
_SETP = re.compile(r"^\s*setp\s+(\S+)\s+(\S+)\s*$")


def joint_of_legs(leg_angles, hips) -> np.ndarray:
    """The LinuxCNC joint of each machine leg: the one whose angle is the nearest.

    Parameters
    ----------
    leg_angles : array_like, shape (3,)
        The machine's leg angles, rad.
    hips : sequence of float
        LinuxCNC's angles of joints 0, 1, 2, deg.

    Returns
    -------
    ndarray of int, shape (3,)
        Joint per leg; -1 where no joint is within :data:`ANGLE_TOLERANCE` or two legs
        share one.
    """
    d = np.degrees(np.asarray(leg_angles, float))[:, None] - np.asarray(hips)[None]
    d = np.abs((d + 180.0) % 360.0 - 180.0)
    j = np.argmin(d, axis=1)
    ok = d[np.arange(3), j] <= ANGLE_TOLERANCE
    if len(set(j.tolist())) < 3:
        ok[:] = False
    return np.where(ok, j, -1)


def rotarydelta_joints(pfr, tl, sl, fr, P) -> np.ndarray:
    """rotarydeltakins' ``kinematics_inverse`` (``inverse_j0`` and the -/+120 deg turns).

    Parameters
    ----------
    pfr, tl, sl, fr : float
        platformradius, thighlength, shinlength, footradius (one length unit).
    P : array_like, shape (K, 3)
        Targets in LinuxCNC's world (same unit; z up, the hips at z = 0).

    Returns
    -------
    ndarray, shape (K, 3)
        Joints 0, 1, 2 (hips at -90, 30, 150 deg), deg, knee down positive; NaN where
        unreachable.
    """
    P = np.asarray(P, float).reshape(-1, 3)
    x, y, z = P[:, 0], P[:, 1], P[:, 2]

    def inverse_j0(x, y, z):
        with np.errstate(all="ignore"):
            a = 0.5 * (x * x + (y - fr) ** 2 + z * z + tl * tl - sl * sl - pfr * pfr) / z
            b = (fr - pfr - y) / z
            d = tl * tl * (b * b + 1) - (a - b * pfr) ** 2
            knee_y = (pfr + a * b + np.sqrt(d)) / (b * b + 1)
            knee_z = b * knee_y - a
            return np.degrees(np.arctan2(knee_z, knee_y - pfr))

    out = [inverse_j0(x, y, z)]
    for t in (-2 * np.pi / 3, 2 * np.pi / 3):         # joint 1 (hip at 30), joint 2 (150)
        xr = x * np.cos(t) - y * np.sin(t)
        yr = x * np.sin(t) + y * np.cos(t)
        out.append(inverse_j0(xr, yr, z))
    return np.column_stack(out)


def hal_values(text: str, source: str, prefix: str, pins, lines: dict | None = None) -> dict:
    """The ``setp PREFIX.PIN VALUE`` values of a ``.hal`` file (the last one wins).

    Parameters
    ----------
    text : str
        The file's text.
    source : str
        Its name, for messages.
    prefix : str
        The component (``rotarydeltakins``).
    pins : sequence of str
        The pins wanted.
    lines : dict, optional
        Filled with pin -> the line of its value.

    Returns
    -------
    dict
        Pin -> value as written.

    Raises
    ------
    InputError
        Naming the line and pin of a value that is not a number, or a pin missing.
    """
    refuse_foreign_text(text, source, hal_line_kind, "HAL", f"setp {prefix}.PIN VALUE lines")
    found = {}
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#")[0]
        m = _SETP.match(line)
        if m and m.group(1).startswith(prefix + "."):
            pin = m.group(1)[len(prefix) + 1:]
            if pin in pins:
                found[pin] = finite_number(m.group(2), source, n, m.group(1))
                if lines is not None:
                    lines[pin] = n
    for pin in pins:
        if pin not in found:
            raise InputError(f"{source}: setp {prefix}.{pin} is missing")
    return found


def hal_origins(source: str, prefix: str, at: dict, notes: dict) -> dict:
    """The source map of a ``.hal`` file's values: each ``setp`` pin and ``# pkmcal`` line.

    Parameters
    ----------
    source : str
        The file's name.
    prefix : str
        The component (``lineardeltakins``).
    at : dict
        Pin -> line (:func:`hal_values`).
    notes : dict
        :func:`~pkmcal.export.klipper_rotary.pkmcal_comments` of the file.

    Returns
    -------
    dict
        Value name -> :class:`~pkmcal.export.base.Origin` (a ``# pkmcal`` key's name without
        its unit suffix: ``home_offset.0``).
    """
    out = {pin: Origin(source, f"setp {prefix}.{pin}", n) for pin, n in at.items()
           if not pin.startswith("home_offset.")}
    for key, (_, n) in notes.items():
        name = re.sub(r"_(mm|deg)$", "", key)
        out[name] = Origin(source, f"# pkmcal {key}", n)
    return out


def reading_joints(notes: dict, source: str) -> np.ndarray:
    """The joint of each reading from ``# pkmcal readingN.joint`` lines, else joint ``N - 1``.

    Parameters
    ----------
    notes : dict
        :func:`~pkmcal.export.klipper_rotary.pkmcal_comments` of the file.
    source : str
        Its name, for messages.

    Returns
    -------
    ndarray, shape (3,)
        Joint numbers (as floats, the values' ``ratio`` entries).

    Raises
    ------
    InputError
        When the lines do not name joints 0, 1, 2 once each (naming the line).
    """
    joints = np.array([notes.get(f"reading{i + 1}.joint", (float(i), 0))[0] for i in range(3)])
    if sorted(joints.tolist()) != [0.0, 1.0, 2.0]:
        line = max(notes.get(f"reading{i + 1}.joint", (0, 0))[1] for i in range(3))
        raise InputError(f"{source}: line {line}: pkmcal readingN.joint: the three readings "
                         "must go to joints 0, 1 and 2, one each")
    return joints


class _LinuxCNCDelta(LinuxCNCKinematics, ControllerFormat):
    """What the two LinuxCNC Delta formats share: the values as written are read back; each
    reading of the machine is one LinuxCNC joint (``readingN.joint``), its world is the
    calibrated frame in mm (a linear Delta's shifted to its bed)."""

    #: where the readings' joints and the joints' zeros stand in the values
    _JOINTS = slice(0, 0)
    _ZEROS = slice(0, 0)

    def _scale(self) -> float:
        """LinuxCNC's joint unit per internal unit."""
        return float(np.degrees(1.0)) if self.joint_type == "ANGULAR" else 1e3

    def _bed(self, params: ControllerParameters) -> float:
        return 0.0

    def controller_joints(self, params: ControllerParameters, q) -> np.ndarray:
        """LinuxCNC's joints of the machine's readings: ``zero_j - q_i`` on reading i's
        joint j (deg or mm).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        q : array_like, shape (K, 3)
            Readings, internal units.

        Returns
        -------
        ndarray, shape (K, 3)
            Joints 0, 1, 2.
        """
        q = np.asarray(q, float).reshape(-1, 3)
        v = params.values
        joint = v[self._JOINTS].astype(int)
        J = np.empty_like(q)
        J[:, joint] = v[self._ZEROS][joint][None] - q
        return J * self._scale()

    def machine_readings(self, params: ControllerParameters, J) -> np.ndarray:
        """The machine's readings of LinuxCNC's joints (see :meth:`controller_joints`).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        J : array_like, shape (K, 3)
            Joints 0, 1, 2 (deg or mm).

        Returns
        -------
        ndarray, shape (K, 3)
            Readings, internal units.
        """
        J = np.asarray(J, float).reshape(-1, 3) / self._scale()
        v = params.values
        joint = v[self._JOINTS].astype(int)
        return v[self._ZEROS][joint][None] - J[:, joint]

    def controller_world(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """LinuxCNC's X, Y, Z (mm) of calibrated positions.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        P : array_like, shape (K, 3)
            Positions, m.
        R : array_like, optional
            Ignored.

        Returns
        -------
        ndarray, shape (K, 3)
            mm.
        """
        return (np.asarray(P, float).reshape(-1, 3) - [0.0, 0.0, self._bed(params)]) * 1e3

    def calibrated_pose(self, params: ControllerParameters, X):
        """Calibrated positions of LinuxCNC's X, Y, Z (see :meth:`controller_world`).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        X : array_like, shape (K, 3)
            mm.

        Returns
        -------
        P : ndarray, shape (K, 3)
            m.
        R : ndarray, shape (K, 3, 3)
            Identities.
        """
        P = np.asarray(X, float).reshape(-1, 3) * 1e-3 + [0.0, 0.0, self._bed(params)]
        return P, np.broadcast_to(np.eye(3), (len(P), 3, 3)).copy()

    def home_offsets(self, params: ControllerParameters) -> np.ndarray:
        """``HOME_OFFSET``: each joint's zero (the joint at reading 0).

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        ndarray, shape (3,)
            deg or mm.
        """
        return params.values[self._ZEROS] * self._scale()

    def with_home_offsets(self, params: ControllerParameters, offsets: dict
                          ) -> ControllerParameters:
        """The values with the INI's ``HOME_OFFSET`` as the joints' zeros.

        Parameters
        ----------
        params : ControllerParameters
            The HAL file's values.
        offsets : dict
            Joint -> ``(HOME_OFFSET, Origin)``, deg or mm.

        Returns
        -------
        ControllerParameters
            The values, the zeros' origins the INI's lines.
        """
        v = params.values.copy()
        zeros = v[self._ZEROS]
        for j, (value, _) in offsets.items():
            zeros[j] = value / self._scale()
        v[self._ZEROS] = zeros
        out = params.with_values(v)
        names = params.names[self._ZEROS]
        for j, (_, origin) in offsets.items():
            out.origins[names[j]] = origin
        return out


class LinuxCNCRotaryDelta(_LinuxCNCDelta):
    """LinuxCNC ``rotarydeltakins`` (see the module docstring)."""

    name = "linuxcnc-rotarydelta"
    kins_module = "rotarydeltakins"
    joint_type = "ANGULAR"
    motor_words = ("minus the machine's reading of the arm on that joint (pkmcal's arm angle, "
                   "up positive), deg: the hip angle from the joint's zero, knee down positive.")
    _JOINTS = slice(7, 10)
    _ZEROS = slice(4, 7)
    machine_kind = "delta"
    machine_words = "rotary Delta robot"
    words = ("LinuxCNC rotarydeltakins (src/emc/kinematics/rotarydeltakins-common.h): HAL "
             "pins platformradius, thighlength, shinlength, footradius; joints in deg, knee "
             "down positive; [JOINT_n] HOME_OFFSET notes")
    suffix = ".hal"

    PINS = ("platformradius", "thighlength", "shinlength", "footradius")
    NAMES = list(PINS) + [f"joint_zero.{j}" for j in range(3)] + [f"reading{i + 1}.joint"
                                                                   for i in range(3)]
    KINDS = ["length"] * 4 + ["angle"] * 3 + ["ratio"] * 3

    def values(self, pfr, tl, sl, fr, zeros, joints) -> ControllerParameters:
        """The values from their parts (SI); ``footradius`` and the leg angles fixed.

        Parameters
        ----------
        pfr, tl, sl, fr : float
            The four pins, m.
        zeros : array_like, shape (3,)
            ``joint_zero`` of joints 0, 1, 2 (the joint position at reading 0), rad.
        joints : array_like, shape (3,)
            The LinuxCNC joint of each of the machine's readings (0, 1, 2).

        Returns
        -------
        ControllerParameters
            The values.
        """
        v = np.concatenate([[pfr, tl, sl, fr], zeros, joints]).astype(float)
        fixed = np.array([False, False, False, True] + [False] * 3 + [True] * 3)
        return ControllerParameters(list(self.NAMES), v, list(self.KINDS), fixed)

    def layout_problem(self, machine: Machine) -> str | None:
        """Why rotarydeltakins' fixed hips cannot hold a Delta (None: legs where its hips are).

        Parameters
        ----------
        machine : Machine
            A Delta.

        Returns
        -------
        str or None
            The reason in words.
        """
        if np.any(joint_of_legs(machine.leg_angles, ROTARY_HIPS) < 0):
            legs = ", ".join(f"{v:g}" for v in np.degrees(machine.leg_angles))
            return ("rotarydeltakins has its hips at -90, 30 and 150 deg (joints 0, 1, 2; "
                    f"120 deg apart, joint 0 in the YZ plane); the machine's legs stand at "
                    f"{legs} deg")
        return None

    def initial(self, machine: Machine, setups=None) -> ControllerParameters:
        """The values read off a Delta (exact with LinuxCNC's legs and one radius and arm
        pair, the shoulders at ``z = 0``).

        Parameters
        ----------
        machine : Machine
            A Delta.
        setups : Setups, optional
            Unused (no set-up of the experiment enters these values).

        Returns
        -------
        ControllerParameters
            ``platformradius - footradius`` the legs' mean, ``footradius = b``; the arms'
            means; ``joint_zero = -dtheta`` per joint.
        """
        e = leg_offsets(machine)
        _, dth, dl1, dl2, _ = machine.legs()
        joint = joint_of_legs(machine.leg_angles, ROTARY_HIPS)
        zeros = np.zeros(3)
        zeros[joint] = -dth
        return self.values(float(np.mean(e[:, 0])) + machine.b, float(np.mean(machine.l1 + dl1)),
                           float(np.mean(machine.l2 + dl2)), machine.b, zeros, joint)

    def ik(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """The machine's readings when rotarydeltakins commands targets.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        P : ndarray, shape (K, 3)
            Targets in the calibrated frame, m.
        R : ndarray, optional
            Ignored.

        Returns
        -------
        ndarray, shape (K, 3)
            ``joint_zero_j - rad(joint_j)`` of each reading's joint, rad; NaN where
            unreachable.
        """
        v = params.values
        J = np.radians(rotarydelta_joints(v[0], v[1], v[2], v[3], P))
        joint = v[7:10].astype(int)
        return v[4:7][joint][None] - J[:, joint]

    def text(self, params: ControllerParameters, machine: Machine,
             setups=None) -> str:
        """The ``.hal`` file: four ``setp`` lines and the joints' ``HOME_OFFSET`` notes.

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
            The file (lengths mm, angles deg).
        """
        v = params.values
        lines = [f"# pkmcal export for {machine.name or 'a rotary Delta'}: LinuxCNC "
                 "rotarydeltakins", "# (src/emc/kinematics/rotarydeltakins-common.h). Lengths "
                 "mm (LINEAR_UNITS = mm), joints deg,", "# knee down positive; hips of joints 0, "
                 "1, 2 at -90, 30, 150 deg; LinuxCNC's world is the", "# calibrated frame "
                 "(z up, the hips at z = 0, the foot below them)."]
        lines += [f"setp rotarydeltakins.{pin} {v[k] * 1e3:.9f}"
                  for k, pin in enumerate(self.PINS)]
        lines += ["# Joint zero: the joint position at the machine's reading 0. With the "
                  "machine's reading", "# at the home switch q_home (deg, seed 001's arm "
                  "angle, up positive), the INI has:"]
        for j in range(3):
            z = np.degrees(v[4 + j])
            lines.append(f"# [JOINT_{j}] HOME_OFFSET = {z:.12f} - q_home_{j}")
        lines += [f"# pkmcal joint_zero.{j}_deg = {np.degrees(v[4 + j]):.12f}" for j in range(3)]
        lines += [f"# pkmcal reading{i + 1}.joint = {int(v[7 + i])}" for i in range(3)]
        return "\n".join(lines) + "\n"

    def parse(self, text: str, source: str) -> ControllerParameters:
        """The values of a ``.hal`` file.

        Parameters
        ----------
        text : str
            The file's text.
        source : str
            Its name, for messages.

        Returns
        -------
        ControllerParameters
            The four pins, SI; ``joint_zero`` and each reading's joint from the ``#
            pkmcal`` lines, else 0 (the readings are LinuxCNC's joints, sign changed, in
            rad) and reading ``N`` = joint ``N - 1``.

        Raises
        ------
        InputError
            Naming the line and pin of a value that is not a number or cannot be meant
            (:func:`~pkmcal.export.klipper.check_printer_values`), or a pin missing.
        """
        at: dict = {}
        pins = hal_values(text, source, "rotarydeltakins", self.PINS, at)
        notes = pkmcal_comments(text, source)
        zeros = np.radians([notes.get(f"joint_zero.{j}_deg", (0.0, 0))[0] for j in range(3)])
        params = self.values(*(pins[p] * 1e-3 for p in self.PINS), zeros,
                             reading_joints(notes, source))
        params.origins.update(hal_origins(source, "rotarydeltakins", at, notes))
        from .klipper import check_printer_values

        check_printer_values(params, source, ["platformradius", "thighlength", "shinlength"],
                             dimensions=[(n, lambda x: f"{x * 1e3:g} mm") for n in self.PINS])
        return params

    def machine_keys(self, params: ControllerParameters) -> dict:
        """The source map of an import (see :meth:`ControllerFormat.machine_keys`).

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        dict
            ``base_radius`` from ``platformradius``, ``platform_radius`` from
            ``footradius``, ``upper_arm`` from ``thighlength``, ``forearm`` from
            ``shinlength``, each leg's ``dtheta`` from its joint's zero.
        """
        joint = params.values[7:10].astype(int)
        keys = {("base_radius",): ["platformradius"], ("platform_radius",): ["footradius"],
                ("upper_arm",): ["thighlength"], ("forearm",): ["shinlength"],
                ("leg_angles",): [f"reading{i + 1}.joint" for i in range(3)],
                ("home",): list(self.PINS)}
        for i in range(3):
            keys[("legs", i, "dtheta")] = [f"joint_zero.{joint[i]}"]
        return keys

    def to_machine(self, params: ControllerParameters, like: Machine | None = None) -> Machine:
        """A Delta with rotarydeltakins' values (pkmcal's frame: z up, hips at ``z = 0``).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        like : Machine, optional
            Home, ``smr_offset`` and name come from it.

        Returns
        -------
        Delta
            ``a = platformradius``, ``b = footradius``, ``l1``, ``l2``, legs at LinuxCNC's
            hips (in the order of the readings), ``dtheta = -joint_zero``, no other errors.
        """
        v = params.values
        joint = v[7:10].astype(int)
        u = np.zeros((3, 9))
        u[:, 3] = -v[4:7][joint]
        name = like.name if like is not None and like.name else "imported from LinuxCNC"
        return Delta(v[0], v[3], v[1], v[2], np.radians(np.asarray(ROTARY_HIPS)[joint]),
                     delta_parameters(u.reshape(-1)),
                     smr_offset=float(getattr(like, "smr_offset", 0.0) or 0.0),
                     home=None if like is None else like.home, name=name)


class LinuxCNCLinearDelta(_LinuxCNCDelta):
    """LinuxCNC ``lineardeltakins`` (see the module docstring)."""

    name = "linuxcnc-lineardelta"
    kins_module = "lineardeltakins"
    joint_type = "LINEAR"
    motor_words = ("minus the machine's reading of the carriage on that joint (its travel down "
                   "from the endstop), mm: the carriage height from the endstop, up positive.")
    _JOINTS = slice(6, 9)
    _ZEROS = slice(2, 5)
    machine_kind = "linear_delta"
    machine_words = "linear Delta printer"
    words = ("LinuxCNC lineardeltakins (src/emc/kinematics/lineardeltakins-common.h): HAL "
             "pins R, L; joints are carriage heights; [JOINT_n] HOME_OFFSET notes")
    suffix = ".hal"

    NAMES = (["R", "L"] + [f"home_offset.{j}" for j in range(3)] + ["bed_z"]
             + [f"reading{i + 1}.joint" for i in range(3)])
    KINDS = ["length"] * 6 + ["ratio"] * 3

    def values(self, R, L, homes, bed_z, joints) -> ControllerParameters:
        """The values from their parts (SI); ``bed_z`` and the tower angles fixed.

        Parameters
        ----------
        R, L : float
            The two pins, m.
        homes : array_like, shape (3,)
            ``HOME_OFFSET`` of joints 0, 1, 2: the carriage height at the endstop, m.
        bed_z : float
            Height of LinuxCNC's ``z = 0`` in the calibrated frame, m.
        joints : array_like, shape (3,)
            The LinuxCNC joint of each of the machine's readings (0, 1, 2).

        Returns
        -------
        ControllerParameters
            The values.
        """
        v = np.concatenate([[R, L], homes, [bed_z], joints]).astype(float)
        return ControllerParameters(list(self.NAMES), v, list(self.KINDS), np.arange(9) >= 5)

    def _bed(self, params: ControllerParameters) -> float:
        return float(params.values[5])

    def layout_problem(self, machine: Machine) -> str | None:
        """Why lineardeltakins' fixed towers cannot hold a printer (None: towers where its are).

        Parameters
        ----------
        machine : Machine
            A linear Delta.

        Returns
        -------
        str or None
            The reason in words.
        """
        if np.any(joint_of_legs(machine.towers()[1], LINEAR_TOWERS) < 0):
            t = ", ".join(f"{v:g}" for v in np.degrees(machine.towers()[1]))
            return ("lineardeltakins has its towers at 90, 210 and 330 deg (tower 0 on +Y); "
                    f"the machine's stand at {t} deg")
        return None

    def initial(self, machine: Machine, setups=None) -> ControllerParameters:
        """The values read off a linear Delta (exact for vertical towers at LinuxCNC's
        angles with one radius and one arm length).

        Parameters
        ----------
        machine : Machine
            A linear Delta.
        setups : Setups, optional
            The experiment's set-ups: the bed (its height, ``bed_z``) z = 0 is on.

        Returns
        -------
        ControllerParameters
            ``R``, ``L`` the towers' means; ``HOME_OFFSET`` each carriage's height at its
            endstop above the bed.
        """
        pe, theta, r, l, _, _ = machine.towers()
        bed_z = float(setups_bed(setups)[0])
        joint = joint_of_legs(theta, LINEAR_TOWERS)
        homes = np.zeros(3)
        homes[joint] = pe + np.sqrt(l * l - r * r) - bed_z
        return self.values(float(np.mean(r)), float(np.mean(l)), homes, bed_z, joint)

    def ik(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """The carriages' travels down from their endstops when lineardeltakins commands
        targets.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        P : ndarray, shape (K, 3)
            Nozzle targets in the calibrated frame, m.
        R : ndarray, optional
            Ignored.

        Returns
        -------
        ndarray, shape (K, 3)
            ``HOME_OFFSET_j - joint_j`` of each reading's joint, m; NaN where unreachable.
        """
        v = params.values
        Rr, L = v[0], v[1]
        P = np.asarray(P, float).reshape(-1, 3) - np.array([0.0, 0.0, v[5]])
        T = np.array([[0.0, Rr], [-np.sin(np.pi / 3) * Rr, -0.5 * Rr],
                      [np.sin(np.pi / 3) * Rr, -0.5 * Rr]])
        with np.errstate(invalid="ignore"):
            J = P[:, 2:3] + np.sqrt(L * L - (T[None, :, 0] - P[:, 0:1]) ** 2
                                    - (T[None, :, 1] - P[:, 1:2]) ** 2)
        joint = v[6:9].astype(int)
        return v[2:5][joint][None] - J[:, joint]

    def text(self, params: ControllerParameters, machine: Machine,
             setups=None) -> str:
        """The ``.hal`` file: two ``setp`` lines and the joints' ``HOME_OFFSET`` notes.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        machine : Machine
            The machine they are for.
        setups : Setups, optional
            The experiment's set-ups: the bed, whose tilt is said in a comment.

        Returns
        -------
        str
            The file (mm).
        """
        v = params.values
        bed = bed_plane(setups)
        lines = [f"# pkmcal export for {machine.name or 'a linear Delta'}: LinuxCNC "
                 "lineardeltakins", "# (src/emc/kinematics/lineardeltakins-common.h). Lengths "
                 "mm (LINEAR_UNITS = mm); joints are", "# carriage heights, z = 0 the bed."]
        if bed is not None and (bed[1] or bed[2]):
            lines.append(f"# the bed's tilt (dz/dx {bed[1]:.6g}, dz/dy {bed[2]:.6g}) is not "
                         "kinematics: probe it into a compensation")
        lines += [f"setp lineardeltakins.R {v[0] * 1e3:.9f}",
                  f"setp lineardeltakins.L {v[1] * 1e3:.9f}",
                  "# The carriage height at the endstop (the home switch), for the INI:"]
        lines += [f"# [JOINT_{j}] HOME_OFFSET = {v[2 + j] * 1e3:.9f}" for j in range(3)]
        lines += [f"# pkmcal home_offset.{j}_mm = {v[2 + j] * 1e3:.9f}" for j in range(3)]
        lines.append(f"# pkmcal bed_z_mm = {v[5] * 1e3:.9f}")
        lines += [f"# pkmcal reading{i + 1}.joint = {int(v[6 + i])}" for i in range(3)]
        return "\n".join(lines) + "\n"

    def parse_with_home_offsets(self, text: str, source: str, offsets: dict
                                ) -> ControllerParameters:
        """The values of the kinematics' HAL file with the INI's ``HOME_OFFSET`` (the
        file then needs no ``HOME_OFFSET`` notes).

        Parameters
        ----------
        text : str
            The HAL file's text.
        source : str
            Its name.
        offsets : dict
            Joint -> ``(HOME_OFFSET mm, Origin)``.

        Returns
        -------
        ControllerParameters
            The values.
        """
        return self.parse(text, source, offsets)

    def parse(self, text: str, source: str, offsets: dict | None = None
              ) -> ControllerParameters:
        """The values of a ``.hal`` file.

        Parameters
        ----------
        text : str
            The file's text.
        source : str
            Its name, for messages.
        offsets : dict, optional
            Joint -> ``(HOME_OFFSET mm, Origin)`` of a configuration's INI: they are the
            carriage heights at the endstops (the file's notes are not read then).

        Returns
        -------
        ControllerParameters
            ``R``, ``L``, SI; ``HOME_OFFSET`` from the ``# pkmcal home_offset`` lines, else
            the ``# [JOINT_n] HOME_OFFSET`` notes (one of the two is required: the joints'
            zero is not in the kinematics); ``bed_z`` and each reading's joint from the ``#
            pkmcal`` lines, else 0 and reading ``N`` = joint ``N - 1``.

        Raises
        ------
        InputError
            Naming the line and key of a value that is not a number, or a value missing.
        """
        at: dict = {}
        pins = hal_values(text, source, "lineardeltakins", ("R", "L"), at)
        notes = pkmcal_comments(text, source)
        ini = {}
        for n, line in enumerate(text.splitlines(), 1):
            m = re.match(r"^\s*#\s*\[JOINT_([0-2])\]\s*HOME_OFFSET\s*=\s*(\S+)\s*$", line)
            if m:
                ini[int(m.group(1))] = finite_number(m.group(2), source, n,
                                              f"[JOINT_{m.group(1)}] HOME_OFFSET")
                at[f"home_offset.{m.group(1)}"] = n
        homes = []
        for j in range(3):
            if offsets is not None:
                homes.append(offsets[j][0])
            elif f"home_offset.{j}_mm" in notes:
                homes.append(notes[f"home_offset.{j}_mm"][0])
            elif j in ini:
                homes.append(ini[j])
            else:
                raise InputError(f"{source}: [JOINT_{j}] HOME_OFFSET is missing: write it as "
                                 f"'# [JOINT_{j}] HOME_OFFSET = <mm>' (the carriage height at "
                                 "the endstop)")
        params = self.values(pins["R"] * 1e-3, pins["L"] * 1e-3, np.array(homes) * 1e-3,
                             notes.get("bed_z_mm", (0.0, 0))[0] * 1e-3,
                             reading_joints(notes, source))
        params.origins.update(hal_origins(source, "lineardeltakins", at, notes))
        for j in range(3):
            if offsets is not None:
                params.origins[f"home_offset.{j}"] = offsets[j][1]
            elif f"home_offset.{j}_mm" not in notes:
                params.origins[f"home_offset.{j}"] = Origin(
                    source, f"# [JOINT_{j}] HOME_OFFSET", at[f"home_offset.{j}"])
        from .klipper import check_printer_values

        mm = (lambda x: f"{x * 1e3:g} mm")  # noqa: E731
        check_printer_values(params, source, ["R", "L", "home_offset.0"],
                             dimensions=[(n, mm) for n in self.NAMES[:6]],
                             spreads=[([f"home_offset.{j}" for j in range(3)],
                                       "differs from the home offset", mm)])
        return params

    def machine_keys(self, params: ControllerParameters) -> dict:
        """The source map of an import (see :meth:`ControllerFormat.machine_keys`).

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        dict
            ``delta_radius`` from ``R``, ``arm_length`` from ``L``, the tower angles from
            the readings' joints, ``position_endstop`` ``i`` from its joint's ``HOME_OFFSET``
            with ``R``, ``L`` and the bed's height.
        """
        from .klipper import linear_delta_keys

        joint = params.values[6:9].astype(int)
        return linear_delta_keys(
            ["R"], [["L"]] * 3, [[f"reading{i + 1}.joint"] for i in range(3)],
            [[f"home_offset.{joint[i]}", "L", "R", "bed_z"] for i in range(3)],
            bed=("bed_z", "bed_z", "bed_z"))

    def to_machine(self, params: ControllerParameters, like: Machine | None = None) -> Machine:
        """A linear Delta with lineardeltakins' values.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        like : Machine, optional
            Name and home pose come from it.

        Returns
        -------
        LinearDelta
            Vertical towers at LinuxCNC's angles (in the order of the readings), ``R``,
            ``L``, ``position_endstop = HOME_OFFSET + bed_z - sqrt(L^2 - R^2)`` in the
            calibrated frame (the bed, ``bed_z``: :meth:`imported_setups`).
        """
        v = params.values
        joint = v[6:9].astype(int)
        pe = v[2:5][joint] + v[5] - np.sqrt(v[1] ** 2 - v[0] ** 2)
        m = linear_delta(float(v[0]), float(v[1]), np.radians(np.asarray(LINEAR_TOWERS)[joint]),
                         pe, home=None if like is None else like.home,
                         name=(like.name if like is not None and like.name
                               else "imported from LinuxCNC"))
        return m

    def imported_bed(self, params: ControllerParameters) -> np.ndarray:
        """The bed ``bed_z`` of the values, untilted.

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        ndarray, shape (3,)
            The plane.
        """
        return np.array([params.values[5], 0.0, 0.0])


register_format(LinuxCNCRotaryDelta())
register_format(LinuxCNCLinearDelta())
