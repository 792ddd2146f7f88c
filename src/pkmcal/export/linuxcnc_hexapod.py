"""LinuxCNC ``genhexkins``: a six-strut platform (pkmcal ``machine: stewart``) as HAL lines.

What genhexkins computes, as read in LinuxCNC's own source (``src/emc/kinematics/
genhexkins.c`` and ``genhexkins.h``, the posemath functions ``pmRpyMatConvert`` and
``pmMatCartMult`` of ``src/libnml/posemath/_posemath.c``, the sample
``configs/sim/axis/vismach/hexapod-sim/kinematics.hal`` and the ``scale`` component
``src/hal/components/scale.comp``):

- HAL input pins ``genhexkins.base.N.x|y|z`` (strut N's base joint ``b_N``, base = world
  coordinates) and ``genhexkins.platform.N.x|y|z`` (its platform joint ``a_N``, platform
  coordinates), ``N = 0..5`` (0-based: pkmcal's leg ``N + 1``), set with ``setp``; lengths in
  the machine units of the INI (``[TRAJ] LINEAR_UNITS``).
- Inverse kinematics: joint ``N`` = strut length ``|t + R a_N - b_N|`` with ``t`` = X, Y, Z
  and ``R = Rz(C) Ry(B) Rx(A)`` (``pmRpyMatConvert`` with roll = A, pitch = B, yaw = C, in
  degrees; the matrix's columns are the images of the axes, ``pmMatCartMult`` multiplies
  ``R a``): not pkmcal's Euler order (``R = RY(theta) RX(psi) RZ(phi)``). The rotation
  matrix is the same object in both, so the values below need no conversion; only poses
  typed as angles do (:func:`linuxcnc_abc`).
- ``genhexkins.spindle-offset`` and ``genhexkins.tool-offset`` are added to the z of every base
  and platform joint; ``genhexkins.screw-lead`` (non-zero) adds a strut-length correction for
  non-captive screws. The file sets spindle-offset and screw-lead to 0 (pkmcal's model has
  neither); import folds a spindle or tool offset it finds into the joints' z.
- ``scale``: pins ``in``, ``gain``, ``offset``, ``out`` with ``out = in * gain + offset``.

The machine is represented exactly: base and platform joints are pkmcal's ``b_i``, ``p_i``;
a leg's reading ``r`` (the drive's unit, e.g. ``rev``) gives the strut length
``L = l0 + gain r``. genhexkins commands and expects strut lengths, so each joint gets two
``scale`` instances: ``strut-reading.N`` on the command path (strut length -> the drive's
reading: gain ``1/gain``, offset ``-l0/gain``) and ``strut-length.N`` on the feedback path (the
drive's reading -> strut length: gain ``gain``, offset ``l0``, the issue's ``out = in * gain +
offset``). Lengths are written in mm (the machine units must be mm), 12 significant digits
(1e-8 mm below 10 m), gains 15; the remaining error is rounding.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from .base import (
    ControllerFormat,
    ControllerParameters,
    Origin,
    hal_line_kind,
    refuse_foreign_text,
    register_format,
)
from .linuxcnc_config import LinuxCNCKinematics

#: mm: the unit of every length written (LinuxCNC machine units = the INI's LINEAR_UNITS)
MM = 1e-3
#: the HAL instance names of the joint conversions (``scale`` components)
FEEDBACK = "strut-length"
COMMAND = "strut-reading"
_AXES = "xyz"


def parameter_names() -> list[str]:
    """The genhexkins values in order: base joints, platform joints, per joint the scale.

    Returns
    -------
    list of str
        ``base.N.x`` ... ``platform.N.z`` (N = 0..5), then ``strut.N.gain`` and
        ``strut.N.offset`` (the feedback instance: strut length = offset + gain reading).
    """
    return ([f"base.{i}.{c}" for i in range(6) for c in _AXES]
            + [f"platform.{i}.{c}" for i in range(6) for c in _AXES]
            + [n for i in range(6) for n in (f"strut.{i}.gain", f"strut.{i}.offset")])


_KINDS = ["length"] * 36 + ["ratio", "length"] * 6


@dataclass
class GenhexParameters(ControllerParameters):
    """genhexkins values (SI, gains in pkmcal's internal unit) and the legs' reading unit.

    Attributes
    ----------
    reading_unit : str
        The unit of the drives' readings (pkmcal's ``readings: {unit}``): a length unit
        (the gain is then a ratio) or another word such as ``rev`` (m per unit).
    """

    reading_unit: str = "mm"

    def with_values(self, values) -> GenhexParameters:
        """A copy with new values (the reading unit kept).

        Parameters
        ----------
        values : array_like, shape (84,)
            The values, SI.

        Returns
        -------
        GenhexParameters
            The copy.
        """
        return GenhexParameters(list(self.names), np.asarray(values, float), list(self.kinds),
                                self.fixed.copy(), dict(self.extras), dict(self.origins),
                                reading_unit=self.reading_unit)

    def legs(self):
        """The values as pkmcal's leg arrays.

        Returns
        -------
        base, platform : ndarray, shape (6, 3)
            Joints, m.
        l0, gain : ndarray, shape (6,)
            Strut length at reading 0 (m) and per reading unit (internal units).
        """
        v = self.values
        return (v[:18].reshape(6, 3), v[18:36].reshape(6, 3), v[37:48:2].copy(),
                v[36:48:2].copy())


def _reading_factor(unit: str) -> float:
    from ..units import LENGTH

    return LENGTH.get(unit, 1.0)


def _num(v: float, digits: int) -> str:
    text = f"{float(v):.{digits}g}"
    return "0" if text in ("0", "-0") else text


def _written(values, digits: int) -> np.ndarray:
    """``values`` rounded as :func:`_num` writes them."""
    v = np.asarray(values, float)
    return np.array([float(_num(x, digits)) for x in v.reshape(-1)]).reshape(v.shape)


def linuxcnc_abc(R) -> np.ndarray:
    """LinuxCNC's A, B, C (deg) of orientations: ``R = Rz(C) Ry(B) Rx(A)``.

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        Platform orientations (pkmcal's matrices, base frame).

    Returns
    -------
    ndarray, shape (..., 3)
        A, B, C in degrees (B within +/-90).
    """
    R = np.asarray(R, float)
    a = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    b = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    c = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.degrees(np.stack([a, b, c], -1))


def linuxcnc_rotation(abc) -> np.ndarray:
    """Orientations of LinuxCNC's A, B, C (deg): ``R = Rz(C) Ry(B) Rx(A)`` (the inverse of
    :func:`linuxcnc_abc`).

    Parameters
    ----------
    abc : array_like, shape (..., 3)
        A, B, C in degrees.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rotation matrices.
    """
    a, b, c = np.moveaxis(np.radians(np.asarray(abc, float)), -1, 0)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    return np.stack([np.stack([cc * cb, cc * sb * sa - sc * ca, cc * sb * ca + sc * sa], -1),
                     np.stack([sc * cb, sc * sb * sa + cc * ca, sc * sb * ca - cc * sa], -1),
                     np.stack([-sb, cb * sa, cb * ca], -1)], -2)


class GenhexkinsFormat(LinuxCNCKinematics, ControllerFormat):
    """LinuxCNC ``genhexkins`` with one ``scale`` pair per joint (see the module docstring)."""

    kins_module = "genhexkins"
    kins_joints = 6
    coordinates = "X Y Z A B C"
    joint_type = "LINEAR"
    motor_words = (f"the strut length (mm); the drive's command is {COMMAND}.N.out and its "
                   f"feedback goes to {FEEDBACK}.N.in, in the drive's reading unit (the scale "
                   "pair of kinematics.hal converts).")

    def controller_joints(self, params: ControllerParameters, q) -> np.ndarray:
        """Strut lengths (mm) of the machine's readings: ``l0 + gain q``.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        q : array_like, shape (K, 6)
            Readings, internal units.

        Returns
        -------
        ndarray, shape (K, 6)
            mm.
        """
        _, _, l0, g = _as_genhex(params).legs()
        return (l0 + g * np.asarray(q, float).reshape(-1, 6)) / MM

    def machine_readings(self, params: ControllerParameters, J) -> np.ndarray:
        """Readings of strut lengths (mm): the inverse of :meth:`controller_joints`.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        J : array_like, shape (K, 6)
            Strut lengths, mm.

        Returns
        -------
        ndarray, shape (K, 6)
            Readings, internal units.
        """
        _, _, l0, g = _as_genhex(params).legs()
        return (np.asarray(J, float).reshape(-1, 6) * MM - l0) / g

    def controller_world(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """X, Y, Z (mm) and A, B, C (deg, :func:`linuxcnc_abc`) of calibrated poses.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        P : array_like, shape (K, 3)
            Positions, m.
        R : array_like, shape (K, 3, 3), optional
            Orientations; default the identity.

        Returns
        -------
        ndarray, shape (K, 6)
            World coordinates.
        """
        P = np.asarray(P, float).reshape(-1, 3)
        R = np.broadcast_to(np.eye(3), (len(P), 3, 3)) if R is None else np.asarray(R, float)
        return np.column_stack([P / MM, linuxcnc_abc(R)])

    def calibrated_pose(self, params: ControllerParameters, X):
        """Poses of LinuxCNC's X, Y, Z, A, B, C (see :meth:`controller_world`).

        Parameters
        ----------
        params : ControllerParameters
            The values.
        X : array_like, shape (K, 6)
            World coordinates.

        Returns
        -------
        P : ndarray, shape (K, 3)
            m.
        R : ndarray, shape (K, 3, 3)
            Orientations.
        """
        X = np.asarray(X, float).reshape(-1, 6)
        return X[:, :3] * MM, linuxcnc_rotation(X[:, 3:])

    def home_offsets(self, params: ControllerParameters) -> np.ndarray:
        """0: the scale pair makes the motor position the strut length.

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        ndarray, shape (6,)
            Zeros.
        """
        return np.zeros(6)

    def with_home_offsets(self, params: ControllerParameters, offsets: dict
                          ) -> ControllerParameters:
        """The values with the INI's ``HOME_OFFSET``: a joint is its feedback scale's strut
        length plus it, so it is added to the scale's offset (``l0``).

        Parameters
        ----------
        params : ControllerParameters
            The HAL file's values.
        offsets : dict
            Joint -> ``(HOME_OFFSET mm, Origin)``.

        Returns
        -------
        ControllerParameters
            The values.
        """
        params = _as_genhex(params)
        v = params.values.copy()
        for j, (value, _) in offsets.items():
            v[37 + 2 * j] += value * MM
        out = params.with_values(v)
        for j, (value, origin) in offsets.items():
            if value:
                out.origins[f"strut.{j}.offset"] = origin
        return out

    def joint_nets(self, j: int) -> tuple[list[str], str, str]:
        """Joint ``j`` through its scale pair: the command to ``strut-reading.j``, the
        feedback from ``strut-length.j``; the drive between them.

        Parameters
        ----------
        j : int
            The joint.

        Returns
        -------
        lines : list of str
            The two fixed nets.
        command, feedback : str
            The drive's pins.
        """
        return ([f"net j{j}-strut-cmd joint.{j}.motor-pos-cmd => {COMMAND}.{j}.in",
                 f"net j{j}-strut-fb {FEEDBACK}.{j}.out => joint.{j}.motor-pos-fb"],
                f"{COMMAND}.{j}.out", f"{FEEDBACK}.{j}.in")

    name = "linuxcnc-genhexkins"
    words = ("LinuxCNC genhexkins (hexapods): setp lines of the base and platform joints "
             "(mm) and a HAL scale instance per joint and direction between strut length and "
             "the drive's reading (LinuxCNC src/emc/kinematics/genhexkins.c)")
    suffix = ".hal"
    exact = True
    #: the machine type genhexkins drives (six struts between base and platform joints)
    machine_kind = "stewart"

    def applies(self, machine: Machine) -> str | None:
        """Why genhexkins cannot hold ``machine`` (None for a six-strut platform).

        Parameters
        ----------
        machine : Machine
            The machine.

        Returns
        -------
        str or None
            The reason in words.
        """
        kind = getattr(machine, "kind", type(machine).__name__)
        if kind == self.machine_kind:
            return None
        how = getattr(machine, "actuation_words", None)
        if how is not None:
            return (f"{how}; genhexkins' joints are the lengths of six struts between a base "
                    f"and a platform joint (a pkmcal machine: {self.machine_kind})")
        return (f"genhexkins drives six struts between base and platform joints (a pkmcal "
                f"machine: {self.machine_kind}), not a {kind} machine")

    def initial(self, machine: Machine, setups=None) -> GenhexParameters:
        """The values of a Stewart machine (exact).

        Parameters
        ----------
        machine : Machine
            A :class:`~pkmcal.machines.stewart.Stewart`.
        setups : Setups, optional
            Unused (no set-up of the experiment enters these values).

        Returns
        -------
        GenhexParameters
            Joints and scales, SI.
        """
        why = self.applies(machine)
        if why is not None:
            raise InputError(f"--to {self.name}: {why}")
        b, p, l0, g = machine.legs()
        unit = getattr(machine, "reading_unit", "m")
        f = _reading_factor(unit)
        # the values as written (lengths 12, gains 15 significant digits in the file's units):
        # the error export reports is that of the file
        b, p, l0 = (_written(v / MM, 12) * MM for v in (b, p, l0))
        g = _written(g * f / MM, 15) * MM / f
        values = np.concatenate([b.reshape(-1), p.reshape(-1),
                                 np.column_stack([g, l0]).reshape(-1)])
        return GenhexParameters(parameter_names(), values, list(_KINDS), reading_unit=unit)

    def values_text(self, params: ControllerParameters) -> list[tuple[str, str]]:
        """Per strut: base and platform joints (mm) and the feedback scale.

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        list of tuple
            ``(HAL name, values in words)``, 18 rows.
        """
        params = _as_genhex(params)
        b, a, l0, g = params.legs()
        unit = params.reading_unit
        gain = g * _reading_factor(unit) / MM
        rows = [(f"genhexkins.base.{i}", " ".join(f"{v / MM:.6f}" for v in b[i]) + " mm")
                for i in range(6)]
        rows += [(f"genhexkins.platform.{i}", " ".join(f"{v / MM:.6f}" for v in a[i]) + " mm")
                 for i in range(6)]
        rows += [(f"{FEEDBACK}.{i}", f"gain {gain[i]:.9g} mm/{unit}, offset "
                  f"{l0[i] / MM:.6f} mm") for i in range(6)]
        return rows

    def ik(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """The readings genhexkins commands: strut lengths through the command scales.

        Parameters
        ----------
        params : ControllerParameters
            The values (:class:`GenhexParameters`).
        P : ndarray, shape (K, 3)
            Target positions, m.
        R : ndarray, shape (K, 3, 3), optional
            Target orientations; default the identity.

        Returns
        -------
        ndarray, shape (K, 6)
            Readings (pkmcal's internal units).
        """
        b, a, l0, g = _as_genhex(params).legs()
        P = np.asarray(P, float)
        R = np.broadcast_to(np.eye(3), (len(P), 3, 3)) if R is None else np.asarray(R, float)
        L = np.linalg.norm(P[:, None, :] + np.einsum("kij,nj->kni", R, a) - b, axis=-1)
        return (L - l0) / g

    def text(self, params: ControllerParameters, machine: Machine,
             setups=None) -> str:
        """The ``.hal`` file: genhexkins' joints and the per-joint scale instances.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        machine : Machine
            The machine (its name).
        setups : Setups, optional
            Unused (no set-up of the experiment enters these values).

        Returns
        -------
        str
            HAL lines, lengths in mm.
        """
        params = _as_genhex(params)
        b, a, l0, g = params.legs()
        unit = params.reading_unit
        f = _reading_factor(unit)
        gain = g * f / MM                      # mm of strut per reading unit
        off = l0 / MM
        name = " ".join(str(getattr(machine, "name", "") or "").split())
        lines = [
            "# LinuxCNC genhexkins values of a calibrated six-strut platform, written by "
            "pkmcal export --to linuxcnc-genhexkins",
        ]
        if name:
            lines.append(f"# machine: {name}")
        lines += [
            "# Lengths in mm: LinuxCNC's machine units must be mm ([TRAJ] LINEAR_UNITS = mm).",
            "# World frame = the calibrated file's base frame; platform joints in its platform "
            "frame.",
            "# Orientation A, B, C (deg): R = Rz(C) Ry(B) Rx(A) (genhexkins), not pkmcal's "
            "psi/theta/phi order.",
            f"# pkmcal: readings {unit}",
            "",
            "# Base joints (world coordinates), strut N = pkmcal's leg N+1",
        ]
        for i in range(6):
            lines += [f"setp genhexkins.base.{i}.{c} {_num(b[i, k] / MM, 12)}"
                      for k, c in enumerate(_AXES)]
        lines.append("# Platform joints (platform coordinates)")
        for i in range(6):
            lines += [f"setp genhexkins.platform.{i}.{c} {_num(a[i, k] / MM, 12)}"
                      for k, c in enumerate(_AXES)]
        lines += [
            "# pkmcal's model has no origin shift and no screw-lead strut correction",
            "setp genhexkins.spindle-offset 0",
            "setp genhexkins.screw-lead 0",
            "",
            f"# genhexkins' joints are strut lengths (mm); the drives read {unit}: "
            "strut length = offset + gain * reading",
            f"#   {FEEDBACK}.N (feedback): reading -> strut length (gain mm/{unit}, offset mm)",
            f"#   {COMMAND}.N (command): strut length -> reading (gain {unit}/mm, offset "
            f"{unit})",
            "# If the configuration loads scale already, add these names to its loadrt line.",
            "loadrt scale names=" + ",".join([f"{FEEDBACK}.{i}" for i in range(6)]
                                             + [f"{COMMAND}.{i}" for i in range(6)]),
        ]
        lines += [f"addf {FEEDBACK}.{i} servo-thread" for i in range(6)]
        lines += [f"addf {COMMAND}.{i} servo-thread" for i in range(6)]
        for i in range(6):
            lines += [f"setp {FEEDBACK}.{i}.gain {_num(gain[i], 15)}",
                      f"setp {FEEDBACK}.{i}.offset {_num(off[i], 15)}",
                      f"setp {COMMAND}.{i}.gain {_num(1.0 / gain[i], 15)}",
                      f"setp {COMMAND}.{i}.offset {_num(-off[i] / gain[i], 15)}"]
        lines += [
            "# Connect each joint N, e.g. (the drive's pins are your configuration's):",
            f"#   net jN-strut-cmd joint.N.motor-pos-cmd => {COMMAND}.N.in",
            f"#   net jN-reading-cmd {COMMAND}.N.out => <drive N position command, {unit}>",
            f"#   net jN-reading-fb <drive N position feedback, {unit}> => {FEEDBACK}.N.in",
            f"#   net jN-strut-fb {FEEDBACK}.N.out => joint.N.motor-pos-fb",
        ]
        return "\n".join(lines) + "\n"

    def parse(self, text: str, source: str) -> GenhexParameters:
        """The values of a ``.hal`` file: genhexkins' ``setp`` lines and the scale instances.

        Base and platform joints must all be set (genhexkins' compiled-in defaults are not
        assumed). Without ``strut-length.N`` / ``strut-reading.N`` instances the joints read
        strut lengths (gain 1, offset 0); without the ``# pkmcal: readings UNIT`` line the
        readings are in mm. ``genhexkins.spindle-offset`` and ``tool-offset`` are folded into
        the joints' z; a non-zero ``screw-lead`` is refused.

        Parameters
        ----------
        text : str
            The file's text.
        source : str
            Its name, for messages.

        Returns
        -------
        GenhexParameters
            The values, SI.

        Raises
        ------
        InputError
            Naming the file, line and pin of what cannot be read.
        """
        from ..units import LENGTH

        refuse_foreign_text(text, source, hal_line_kind, "HAL",
                            "setp genhexkins.PIN VALUE lines")
        found: dict[str, tuple[float, int]] = {}
        unit = "mm"
        for n, raw in enumerate(text.splitlines(), 1):
            m = re.match(r"^\s*#\s*pkmcal:\s*readings\s+(\S+)\s*$", raw)
            if m:
                unit = m.group(1)
                continue
            words = raw.split("#", 1)[0].split()
            if not words or words[0] != "setp":
                continue
            if len(words) != 3:
                raise InputError(f"{source}: line {n}: expected 'setp PIN VALUE', got "
                                 f"{raw.strip()!r}")
            pin, value = words[1], words[2]
            if not pin.startswith(("genhexkins.", f"{FEEDBACK}.", f"{COMMAND}.")):
                continue
            try:
                v = float(value)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise InputError(f"{source}: line {n}: {pin}: expected a number, got {value!r}")
            found[pin] = (v, n)

        def get(pin, default=None):
            if pin in found:
                return found[pin][0]
            if default is None:
                raise InputError(f"{source}: {pin} is not set (genhexkins' compiled-in "
                                 "default is not assumed; every base and platform joint must "
                                 "be set)")
            return default

        lead = found.get("genhexkins.screw-lead")
        if lead is not None and lead[0] != 0.0:
            raise InputError(f"{source}: line {lead[1]}: genhexkins.screw-lead {lead[0]:g}: "
                             "the strut-length correction of non-captive screws is not in "
                             "pkmcal's model; set it to 0")
        dz = get("genhexkins.spindle-offset", 0.0) + get("genhexkins.tool-offset", 0.0)
        b = np.array([[get(f"genhexkins.base.{i}.{c}") for c in _AXES] for i in range(6)])
        a = np.array([[get(f"genhexkins.platform.{i}.{c}") for c in _AXES] for i in range(6)])
        b[:, 2] += dz
        a[:, 2] += dz
        for pin, (_, n) in found.items():
            m = re.match(r"^genhexkins\.(base|platform)\.(\d+)\.", pin)
            if m and int(m.group(2)) > 5:
                raise InputError(f"{source}: line {n}: {pin}: genhexkins has struts 0..5")
        gain, off = np.ones(6), np.zeros(6)
        for i in range(6):
            fb = [found.get(f"{FEEDBACK}.{i}.{k}") for k in ("gain", "offset")]
            cmd = [found.get(f"{COMMAND}.{i}.{k}") for k in ("gain", "offset")]
            if fb[0] is not None:
                if fb[0][0] == 0.0:
                    raise InputError(f"{source}: line {fb[0][1]}: {FEEDBACK}.{i}.gain: must "
                                     "not be 0 (strut length per reading unit)")
                gain[i], off[i] = fb[0][0], fb[1][0] if fb[1] is not None else 0.0
                if cmd[0] is not None:
                    cg, co = cmd[0][0], cmd[1][0] if cmd[1] is not None else 0.0
                    if not (abs(cg * gain[i] - 1.0) <= 1e-9 and abs(co * gain[i] + off[i])
                            <= 1e-9 * max(1.0, abs(off[i]))):
                        raise InputError(
                            f"{source}: line {cmd[0][1]}: {COMMAND}.{i} (gain {cg:.10g}, "
                            f"offset {co:.10g}) is not the inverse of {FEEDBACK}.{i} (gain "
                            f"{gain[i]:.10g}, offset {off[i]:.10g}): command and feedback "
                            "would disagree on the strut length")
            elif cmd[0] is not None:
                if cmd[0][0] == 0.0:
                    raise InputError(f"{source}: line {cmd[0][1]}: {COMMAND}.{i}.gain: must "
                                     "not be 0")
                gain[i] = 1.0 / cmd[0][0]
                off[i] = -(cmd[1][0] if cmd[1] is not None else 0.0) * gain[i]
        g_int = gain * MM / _reading_factor(unit)
        if unit not in LENGTH and not re.match(r"^[A-Za-z][A-Za-z0-9_/]*$", unit):
            raise InputError(f"{source}: '# pkmcal: readings {unit}': not a unit name")
        values = np.concatenate([b.reshape(-1) * MM, a.reshape(-1) * MM,
                                 np.column_stack([g_int, off * MM]).reshape(-1)])
        params = GenhexParameters(parameter_names(), values, list(_KINDS), reading_unit=unit)
        for pin, (_, n) in found.items():
            name = pin.split(".", 1)[1] if pin.startswith("genhexkins.") else None
            m = re.match(rf"^(?:{FEEDBACK}|{COMMAND})\.(\d+)\.(gain|offset)$", pin)
            if m:
                name = f"strut.{m.group(1)}.{m.group(2)}"
                if pin.startswith(COMMAND) and name in params.origins:
                    continue                # the feedback instance states it
            if name is not None:
                params.origins[name] = Origin(source, f"setp {pin}", n)
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
            Each leg's ``base`` and ``platform`` joint from genhexkins' pins (z with the
            spindle and tool offsets), its ``l0`` and ``gain`` from the scale instances.
        """
        keys: dict = {("home",): [f"platform.{i}.z" for i in range(6)]}
        for i in range(6):
            for side in ("base", "platform"):
                for k, c in enumerate(_AXES):
                    keys[("legs", i, side, k)] = [f"{side}.{i}.{c}"] + (
                        ["spindle-offset", "tool-offset"] if c == "z" else [])
            keys[("legs", i, "l0")] = [f"strut.{i}.offset"]
            keys[("legs", i, "gain")] = [f"strut.{i}.gain"]
        return keys

    def to_machine(self, params: ControllerParameters, like: Machine | None = None) -> Machine:
        """A Stewart machine with genhexkins' joints and the scales' ``l0`` / ``gain``.

        Parameters
        ----------
        params : ControllerParameters
            The values.
        like : Machine, optional
            A six-strut machine to take the name, home pose, file units and joint limits from
            (genhexkins holds none of them); default: the default home (platform centred above
            the base), mm and degrees.

        Returns
        -------
        Machine
            The :class:`~pkmcal.machines.stewart.Stewart`.
        """
        from ..machines.stewart import Stewart, stewart_parameters

        params = _as_genhex(params)
        b, a, l0, g = params.legs()
        home = None
        name = "imported from LinuxCNC genhexkins"
        units = {"length": "mm", "angle": "deg"}
        if like is not None:
            why = self.applies(like)
            if why is not None:
                raise InputError(f"--like: {why}")
            home = like.home
            name = getattr(like, "name", "") or name
            units = dict(getattr(like, "file_units", None) or units)
        machine = Stewart(stewart_parameters(b, a, l0, g), home=home, name=name,
                          reading_unit=params.reading_unit)
        machine.reading_unit_declared = True
        machine.file_units = units
        if like is not None and getattr(like, "joint_limits", None) is not None:
            machine.joint_limits = like.joint_limits
        return machine


def _as_genhex(params: ControllerParameters) -> GenhexParameters:
    """``params`` as :class:`GenhexParameters` (a plain copy reads its joints as lengths)."""
    if isinstance(params, GenhexParameters):
        return params
    return GenhexParameters(list(params.names), params.values, list(params.kinds),
                            params.fixed.copy())


register_format(GenhexkinsFormat())
