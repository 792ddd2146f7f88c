"""RepRapFirmware's linear Delta: ``M665 L R H B X Y Z`` and ``M666 X Y Z A B`` lines.

Read in RepRapFirmware's source (``Duet3D/RepRapFirmware``,
``src/Movement/Kinematics/LinearDeltaKinematics.cpp``):

- ``Configure`` (``M665``): ``L`` the diagonals, one value for all towers or ``a:b:c`` one per
  tower (fewer than 3 repeat the first); ``R`` the delta radius (one for the three towers);
  ``H`` the homed height; ``B`` the printable radius (a limit, not kinematics: not written);
  ``X Y Z`` the tower angle corrections, deg. ``M666``: ``X Y Z`` the endstop adjustments, mm;
  ``A B`` the bed tilt in percent (``xTilt = A * 0.01``).
- ``Recalc``: tower A at ``-(r cos(30 + X), r sin(30 + X))``, B at ``(r cos(30 - Y), -r sin(30 -
  Y))``, C at ``(-r sin(Z), r cos(Z))``: the angles 210 + X, 330 + Y, 90 + Z deg at radius r;
  the homed carriage heights ``homedHeight + sqrt(L_i^2 - r^2) + endstopAdjustment_i``.
- ``Transform``: the carriage height for a position is ``sqrt(L_i^2 - (x - tx)^2 - (y -
  ty)^2) + z + x xTilt + y yTilt``; homing (``OnHomingSwitchTriggered``) sets each carriage at
  its endstop to its homed carriage height, so the travel down is the homed height minus that.
- ``NormaliseEndstopAdjustments``: the adjustments are made to average 0 into
  ``homedHeight``; ``WriteCalibrationParameters`` (``M500``/``config-override.g``) writes
  ``; Delta parameters``, ``M665 L<a>:<b>:<c> R H B X Y Z`` (3 decimals, ``B`` 1) and ``M666 X
  Y Z A B`` (``A B`` 2 decimals); the file holds other lines too (``M307`` heater models,
  ``G10 L2`` work offsets, ``G31`` probe offsets), which are not read here.
- ``Configure`` reads ``M665 L R B X Y Z H`` and ``M666 X Y Z`` (``U V W`` for towers 4-6, set
  up with ``M669``) and ``A B``; other letters it does not look at (harmless: passed over
  with a note, :meth:`RepRapFirmwareDelta.read`). ``M665`` with no letters replies
  ``Diagonals ..., delta radius ..., homed height ...``: that reply is not read, paste the
  ``M665`` line of ``config.g`` / ``config-override.g``.

So Klipper's ``position_endstop`` of tower ``i`` is ``H + adj_i`` (note the sign, opposite to
Marlin's), and the bed tilt is a shear: the target ``(x, y, z)`` is driven as ``(x, y, z +
xTilt x + yTilt y)`` of the towers' frame.

The bed
-------
A calibrated machine file with a ``bed`` (probe calibration: the plane ``z = height + tilt_x x
+ tilt_y y`` of the calibrated frame) gives the controller's coordinates: the target ``(x, y,
z)`` is ``z`` above the bed, the calibrated frame's ``(x, y, z + height + tilt_x x + tilt_y
y)``. RepRapFirmware's ``A`` and ``B`` hold the bed's tilt (what its 9-factor ``G32`` fits):
:meth:`RepRapFirmwareDelta.initial` starts them at the bed's slopes and the fit frees them, so
they also take whatever shear of the towers fits best. Import (:meth:`to_machine`) puts ``A``,
``B`` back as the bed's slopes (its set-up, :meth:`imported_setups`) of a machine with
vertical towers.

Degenerate values, fixed in the fit
-----------------------------------
Only ``H + adj_i`` enters: ``H`` is fixed and the text writes the equivalent normalised values
(adjustments averaging 0, as RepRapFirmware leaves them). Everything else is free: the three
diagonals, the radius, the three angle corrections (the calibrated frame is fixed) and the two
tilts. Not modelled: more than three towers (``M669``), ``M556`` axis skew, ``G92`` offsets.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
from ..paths import path_text
from .base import (
    ControllerFormat,
    ControllerParameters,
    Origin,
    origin_of,
    refuse_foreign_text,
    register_format,
    setups_bed,
    where,
)
from .gcode_text import gcode_line_kind, gcode_lines, gcode_words
from .klipper import (
    BED,
    BED_KINDS,
    bed_origins,
    bed_text,
    bed_values,
    check_printer_values,
    controller_endstops,
    finite_number,
    linear_delta_keys,
    linear_delta_machine,
    read_bed,
    tower_positions,
    vertical_tower_travel,
    wrap_degrees,
)
from .marlin import BASE_ANGLES

_XYZ = "xyz"
#: the values each letter sets (the source map of an import)
_LETTER_NAMES = {("M665", "L"): [f"diagonal_{t}" for t in _XYZ], ("M665", "R"): ["radius"],
                 ("M665", "H"): ["homed_height"], ("M666", "A"): ["x_tilt"],
                 ("M666", "B"): ["y_tilt"]}
for _k, _t in zip("XYZ", _XYZ, strict=True):
    _LETTER_NAMES[("M665", _k)] = [f"angle_correction_{_t}"]
    _LETTER_NAMES[("M666", _k)] = [f"endstop_adjustment_{_t}"]


def _override(source: str, line: int) -> tuple[Path, str]:
    """``config-override.g`` beside ``source`` (a ``config.g`` whose ``line`` runs ``M501``):
    its path and text, as RepRapFirmware loads it (``sys/config-override.g``).

    Raises
    ------
    InputError
        Naming the M501 line and the file missing beside it.
    """
    from ..io.atomic import read_input_text

    path = Path(source).parent / "config-override.g"
    if not path.is_file():
        raise InputError(f"{source}: line {line}: M501 loads config-override.g, which is not "
                         f"beside it ({path_text(path)}): the values the printer runs are "
                         "there - copy config-override.g from the printer's sys folder beside "
                         f"{Path(source).name}, or remove the M501 line if it has none")
    return path, read_input_text(path, "RepRapFirmware file")


class RepRapFirmwareDelta(ControllerFormat):
    """RepRapFirmware ``M665`` / ``M666`` (see the module docstring)."""

    name = "reprapfirmware"
    machine_kind = "linear_delta"
    machine_words = "linear Delta printer"
    words = ("RepRapFirmware linear delta (src/Movement/Kinematics/LinearDeltaKinematics.cpp): "
             "M665 L R H X Y Z, M666 X Y Z A B")
    suffix = ".g"

    NAMES = ([f"diagonal_{t}" for t in _XYZ] + ["radius", "homed_height"]
             + [f"angle_correction_{t}" for t in _XYZ]
             + [f"endstop_adjustment_{t}" for t in _XYZ] + ["x_tilt", "y_tilt"] + list(BED))
    KINDS = ["length"] * 5 + ["angle"] * 3 + ["length"] * 3 + ["ratio"] * 2 + list(BED_KINDS)
    #: homed_height (degenerate with the adjustments) and the bed
    FIXED = np.array([False] * 4 + [True] + [False] * 8 + [True] * 3)

    def values(self, diagonals, radius, H, corrections, adj, tilt, bed) -> ControllerParameters:
        """RepRapFirmware's values from their parts (SI).

        Parameters
        ----------
        diagonals : array_like, shape (3,)
            Diagonal rods, m.
        radius : float
            Delta radius, m.
        H : float
            Homed height, m.
        corrections : array_like, shape (3,)
            Tower angle corrections, rad.
        adj : array_like, shape (3,)
            Endstop adjustments, m.
        tilt : array_like, shape (2,)
            ``xTilt``, ``yTilt`` (ratios: ``A`` and ``B`` are percent).
        bed : array_like, shape (3,)
            The bed (``bed.z`` m, ``bed.tilt_x``, ``bed.tilt_y``).

        Returns
        -------
        ControllerParameters
            The values.
        """
        v = np.concatenate([diagonals, [radius, H], corrections, adj, tilt, bed]).astype(float)
        return ControllerParameters(list(self.NAMES), v, list(self.KINDS), self.FIXED.copy())

    def initial(self, machine: Machine, setups=None) -> ControllerParameters:
        """RepRapFirmware's values read off a linear Delta (exact for vertical towers of one
        radius).

        Parameters
        ----------
        machine : Machine
            A linear Delta.
        setups : Setups, optional
            The experiment's set-ups: the bed (:func:`~pkmcal.export.base.setups_bed`) the
            controller's z = 0 is on.

        Returns
        -------
        ControllerParameters
            Diagonals per tower, the mean radius, the angle corrections against 210, 330,
            90 deg, ``H`` and the adjustments normalised (mean 0), the tilts the bed's slopes.
        """
        bed = setups_bed(setups)
        R = float(np.mean(machine.firmware_values()["radius"]))
        arms, angles, E = controller_endstops(machine, R, bed[0])
        corr = np.radians(wrap_degrees(np.degrees(angles) - BASE_ANGLES))
        H = float(np.mean(E))
        return self.values(arms, R, H, corr, E - H, bed[1:], bed)

    def ik(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """RepRapFirmware's carriage travels down from the endstops for nozzle targets.

        Parameters
        ----------
        params : ControllerParameters
            RepRapFirmware's values.
        P : ndarray, shape (K, 3)
            Targets in the calibrated frame, m.
        R : ndarray, optional
            Ignored (the effector does not rotate).

        Returns
        -------
        ndarray, shape (K, 3)
            Travels, m; NaN where a diagonal cannot reach.
        """
        v = params.values
        diag, radius, H = v[0:3], v[3], v[4]
        corr, adj, tilt, bed = v[5:8], v[8:11], v[11:13], v[13:16]
        Pc = np.array(P, float).reshape(-1, 3)
        # the calibrated frame -> heights above the bed -> RepRapFirmware's tilt shear
        Pc[:, 2] += (tilt[0] - bed[1]) * Pc[:, 0] + (tilt[1] - bed[2]) * Pc[:, 1] - bed[0]
        towers = tower_positions(radius, np.radians(BASE_ANGLES) + corr)
        tops = H + adj + np.sqrt(diag**2 - radius**2)
        return vertical_tower_travel(towers, diag, tops, Pc)

    @staticmethod
    def normalised(v):
        """``H`` and the adjustments with the adjustments averaging 0 (RepRapFirmware's
        ``NormaliseEndstopAdjustments``).

        Parameters
        ----------
        v : ndarray
            RepRapFirmware's values (SI).

        Returns
        -------
        H : float
            Homed height, m.
        adj : ndarray, shape (3,)
            Endstop adjustments, m.
        """
        mean = float(np.mean(v[8:11]))
        return v[4] + mean, v[8:11] - mean

    def text(self, params: ControllerParameters, machine: Machine,
             setups=None) -> str:
        """The G-code lines (mm, deg, percent).

        Parameters
        ----------
        params : ControllerParameters
            RepRapFirmware's values.
        machine : Machine
            The machine they are for.
        setups : Setups, optional
            Unused (the values hold the bed: none of the experiment's set-ups is read).

        Returns
        -------
        str
            ``M665 L a:b:c R H X Y Z`` and ``M666 X Y Z A B`` with comments.
        """
        v = params.values
        H, adj = self.normalised(v)
        mm = (lambda x: f"{x * 1e3:.6f}")  # noqa: E731
        lines = [f"; pkmcal export --to reprapfirmware: {machine.name or 'linear Delta'}",
                 "; RepRapFirmware linear delta (LinearDeltaKinematics.cpp); for config.g or "
                 "config-override.g; B (printable radius) is left as it is",
                 "; z = 0 is the bed; A and B hold its tilt",
                 bed_text(v[13:16], ";"),
                 "M665 L" + ":".join(mm(x) for x in v[0:3]) + f" R{mm(v[3])} H{mm(H)} "
                 + " ".join(f"{k}{round(np.degrees(v[5 + i]), 9) + 0.0:.9f}"  # no "-0.0"
                            for i, k in enumerate("XYZ")),
                 "M666 " + " ".join(f"{k}{mm(adj[i])}" for i, k in enumerate("XYZ"))
                 + f" A{v[11] * 100:.9f} B{v[12] * 100:.9f}"]
        return "\n".join(lines) + "\n"

    def update(self, existing: str, params: ControllerParameters, machine: Machine,
               source: str) -> str | None:
        """``config-override.g`` (or ``config.g``) with the values saved as ``M500`` saves
        them (``LinearDeltaKinematics::WriteCalibrationParameters``): its ``M665`` and ``M666``
        lines replaced by the new ones where the first stood, every other line kept.

        Raises
        ------
        InputError
            When the file is no RepRapFirmware config file: no unindented G-code line, or
            ``[section]`` lines (a Klipper ``printer.cfg``).
        """
        lines = existing.splitlines()
        code = [i for i, line in enumerate(lines) if re.match(r"[GMT]\d", line.split(";")[0])]
        if not code or any(re.match(r"\s*\[[^]]+\]", line) or line.startswith("#*#")
                           for line in lines):
            raise InputError(f"{source}: exists and is not a RepRapFirmware config file (no "
                             "G-code line, or [sections] of a Klipper config); choose another "
                             "output name (a new file gets the values alone)")
        delta = [i for i in code if re.match(r"M66[56]\b", lines[i])]
        # pkmcal's own comment lines of an earlier export go with the lines they describe
        delta += [i for i, line in enumerate(lines)
                  if line.startswith(("; Delta parameters (pkmcal", "; pkmcal bed:"))]
        delta = sorted(set(delta))
        ours = []
        for line in self.text(params, machine).splitlines():
            if not line.startswith(("M665", "M666")):
                continue
            # letters of the file's own line that pkmcal does not write (M665 B, the
            # printable radius) are kept
            mine = set(re.findall(r"\b([A-Z])", line[4:]))
            for i in delta:
                words = lines[i].split(";")[0].split()
                if words and words[0] == line[:4]:
                    line += "".join(f" {w}" for w in words[1:] if w[:1] not in mine)
            ours.append(line)
        at = delta[0] if delta else len(lines)
        kept = [line for i, line in enumerate(lines) if i not in set(delta)]
        at -= sum(1 for i in delta if i < at)
        bed = bed_text(params.values[13:16], ";")
        new = kept[:at] + ["; Delta parameters (pkmcal export --to reprapfirmware)", bed] \
            + ours + kept[at:]
        return "\n".join(new) + "\n"

    def values_text(self, params: ControllerParameters) -> list[tuple[str, str]]:
        """The values as the written file has them, for a printed table.

        Parameters
        ----------
        params : ControllerParameters
            The values.

        Returns
        -------
        list of tuple
            ``(name, value in words)``: the written (normalised) words, mm, deg and
            percent, then the bed.
        """
        v = params.values
        H, adj = self.normalised(v)
        out = [(f"M665 L ({t})", f"{v[i] * 1e3:.6f} mm") for i, t in enumerate("abc")]
        out += [("M665 R", f"{v[3] * 1e3:.6f} mm"), ("M665 H", f"{H * 1e3:.6f} mm")]
        out += [(f"M665 {k}", f"{np.degrees(v[5 + i]):.9f} deg") for i, k in enumerate("XYZ")]
        out += [(f"M666 {k}", f"{adj[i] * 1e3:.6f} mm") for i, k in enumerate("XYZ")]
        out += [("M666 A", f"{v[11] * 100:.9f} %"), ("M666 B", f"{v[12] * 100:.9f} %")]
        return out + bed_values(v[13:16])

    def parse(self, text: str, source: str) -> ControllerParameters:
        """RepRapFirmware's values: :meth:`read`, its notes kept as ``params.notes``."""
        params, notes = self.read(text, source)
        params.notes = notes
        return params

    def read(self, text: str, source: str) -> tuple[ControllerParameters, list[str]]:
        """RepRapFirmware's values and notes on what was passed over.

        Later lines override earlier ones, as the firmware executes them; ``L``, ``R`` and
        ``H`` are required, the corrections, adjustments and tilts default to 0. Lines other
        than ``M665`` / ``M666`` (``M307``, ``G31``, ``G10``, comments) are not read; host log
        prefixes are handled as in :func:`~pkmcal.export.gcode_text.host_line`.

        Parameters
        ----------
        text : str
            The file's text.
        source : str
            Its name, for messages.

        Returns
        -------
        params : ControllerParameters
            The values, SI; ``M665 B`` (the printable radius) as ``extras["print_radius"]``, m,
            where the parameters have ``extras``.
        notes : list of str
            Letters passed over (``M665 B``, the printable radius; letters ``Configure`` does
            not read), each with the file and line.

        Raises
        ------
        InputError
            Naming the file, line and letter of a value that is not a number, more than three
            diagonals or ``M666 U V W`` (extra towers are not a linear Delta of pkmcal's), a
            missing ``L``, ``R`` or ``H``, a value that cannot be meant
            (:func:`~pkmcal.export.klipper.check_printer_values`: an adjustment beyond 10 %
            of the printer's size, a bed tilt raising the bed that much at the towers'
            radius, ``M666 A50``), a radius not > 0 or a diagonal not longer than the radius.
        """
        refuse_foreign_text(text, source, gcode_line_kind, "RepRapFirmware G-code",
                            "M665 / M666 lines, as config.g holds them")
        got: dict = {}
        notes: list[str] = []
        extras: dict = {}
        extras_lines: dict = {}

        def take(n, code, rest, source):
            for letter, word in gcode_words(rest, source, n, code).items():
                keys = "LRHXYZ" if code == "M665" else "XYZAB"
                if code == "M666" and letter in "UVW":
                    raise InputError(f"{source}: line {n}: M666 {letter}: the endstop "
                                     "adjustment of a fourth to sixth tower (M669); pkmcal's "
                                     "linear Delta has three")
                if code == "M665" and letter == "B":
                    extras["print_radius"] = finite_number(word, source, n, "M665 B") * 1e-3
                    extras_lines["print_radius"] = (n, source)
                    notes.append(f"{source}: line {n}: M665 B: the printable radius (a limit, "
                                 "not kinematics): not a kinematic value")
                    continue
                if letter not in keys:
                    notes.append(f"{source}: line {n}: {code} {letter}: not a letter "
                                 "LinearDeltaKinematics::Configure reads: ignored")
                    continue
                if code == "M665" and letter == "L":
                    parts = word.split(":")
                    if len(parts) not in (1, 3):
                        raise InputError(f"{source}: line {n}: M665 L: {len(parts)} diagonals; "
                                         "give one for all towers or one per tower (3)")
                    d = [finite_number(p, source, n, "M665 L") * 1e-3 for p in parts]
                    got[(code, letter)] = (np.array(d + [d[0]] * (3 - len(d))), n, source)
                    continue
                value = finite_number(word, source, n, f"{code} {letter}")
                if code == "M665" and letter in "XYZ":
                    value = np.radians(value)
                elif code == "M666" and letter in "AB":
                    value *= 0.01
                else:
                    value *= 1e-3
                got[(code, letter)] = (value, n, source)

        # the firmware runs config.g line by line; M501 runs config-override.g (M500's saved
        # values, beside config.g in sys/) where it stands: later lines override earlier
        for n, code, rest in gcode_lines(text, ("M665", "M666", "M501")):
            if code != "M501":
                take(n, code, rest, source)
                continue
            override, override_text = _override(source, n)
            notes.append(f"{source}: line {n}: M501: read {path_text(override)} there, as "
                         "the firmware does (its values replace those set before)")
            for m, code2, rest2 in gcode_lines(override_text, ("M665", "M666")):
                take(m, code2, rest2, path_text(override))
        for k in "LRH":
            if ("M665", k) not in got:
                raise InputError(f"{source}: M665 {k}: missing (no M665 line sets it)")

        def g(code, k):
            return got.get((code, k), (0.0, 0, source))[0]

        diag, R = g("M665", "L"), g("M665", "R")
        params = self.values(diag, R, g("M665", "H"), [g("M665", k) for k in "XYZ"],
                             [g("M666", k) for k in "XYZ"], [g("M666", k) for k in "AB"],
                             read_bed(text, source))
        params.origins.update(bed_origins(text, source))
        for (code, letter), (_, n, src) in got.items():
            for name in _LETTER_NAMES[(code, letter)]:
                params.origins[name] = Origin(src, f"{code} {letter}", n)
        for key, (n, src) in extras_lines.items():
            params.origins[key] = Origin(src, "M665 B", n)
        mm = (lambda x: f"{x * 1e3:g} mm")  # noqa: E731
        check_printer_values(
            params, source, ["diagonal_x", "radius", "homed_height"],
            dimensions=[(n, mm) for n in self.NAMES[:5]],
            corrections=[(n, mm) for n in self.NAMES[8:11]],
            turns=[(n, lambda x: f"{np.degrees(x):g} deg") for n in self.NAMES[5:8]],
            slopes=[(n, lambda x: f"{x * 100:g} %") for n in self.NAMES[11:13]], radius=R)
        if not R > 0:
            raise InputError(f"{origin_of(params, 'radius')}: the radius ({mm(R)}) must be > 0")
        for i, t in enumerate(_XYZ):
            if not diag[i] > R:
                raise InputError(f"{origin_of(params, f'diagonal_{t}')}: tower {'ABC'[i]}'s "
                                 f"diagonal ({mm(diag[i])}) must be longer than the radius "
                                 f"({where([params.origins['radius']])}: {mm(R)})")
        if isinstance(getattr(params, "extras", None), dict):
            params.extras.update(extras)
        return params, notes

    def machine_keys(self, params: ControllerParameters) -> dict:
        """The source map of an import (see :meth:`ControllerFormat.machine_keys`).

        Parameters
        ----------
        params : ControllerParameters
            RepRapFirmware's values.

        Returns
        -------
        dict
            ``delta_radius`` from ``M665 R``; arm ``i`` from ``L``; tower angle ``i`` from
            its correction; ``position_endstop`` ``i`` from ``H``, ``M666``'s adjustment and
            the bed's height; the bed's tilts from ``M666 A B``.
        """
        return linear_delta_keys(
            ["radius"], [[f"diagonal_{t}"] for t in _XYZ],
            [[f"angle_correction_{t}"] for t in _XYZ],
            [["homed_height", f"endstop_adjustment_{t}", "bed.z"] for t in _XYZ],
            bed=("bed.z", "x_tilt", "y_tilt"))

    def to_machine(self, params: ControllerParameters, like: Machine | None = None) -> Machine:
        """A linear Delta with RepRapFirmware's values (vertical towers, one radius).

        Parameters
        ----------
        params : ControllerParameters
            RepRapFirmware's values.
        like : Machine, optional
            Name and home pose come from it.

        Returns
        -------
        Machine
            The :class:`~pkmcal.machines.LinearDelta` in the towers' frame (raised by a
            ``pkmcal bed`` comment's height): ``position_endstop`` ``H + adj``; the tilts
            ``A``, ``B`` are the bed's slopes (:meth:`imported_setups`), which is what they
            mean to RepRapFirmware.
        """
        v = params.values
        return linear_delta_machine(v[3], v[0:3], np.radians(BASE_ANGLES) + v[5:8],
                                    v[4] + v[8:11], self.imported_bed(params), like,
                                    "linear Delta (imported from RepRapFirmware)",
                                    params.extras)

    def imported_bed(self, params: ControllerParameters) -> np.ndarray:
        """The bed the values hold, ``(height m, tilt_x, tilt_y)``: a ``pkmcal bed``
        comment's height, the slopes ``A``, ``B``.

        Parameters
        ----------
        params : ControllerParameters
            RepRapFirmware's values.

        Returns
        -------
        ndarray, shape (3,)
            The plane.
        """
        v = params.values
        return np.array([v[13], v[11], v[12]])

    def holds_measurements(self, path, head: str) -> bool:
        """A pasted probe report (:mod:`pkmcal.export.firmware_reports`)."""
        from .firmware_reports import holds_probe_report

        return holds_probe_report(path, head, "reprapfirmware")

    def read_measurements(self, paths: list, machine: Machine) -> list:
        """The report's probe heights through the firmware's kinematics
        (:func:`~pkmcal.export.firmware_reports.probe_report_data`)."""
        from .firmware_reports import probe_report_file_data

        return probe_report_file_data(paths, machine)


REPRAPFIRMWARE = register_format(RepRapFirmwareDelta())
