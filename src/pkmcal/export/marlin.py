"""Marlin's linear Delta: ``M665 H L R X Y Z A B C`` and ``M666 X Y Z`` G-code lines.

Read in Marlin's source (``MarlinFirmware/Marlin``):

- ``Marlin/src/gcode/calibrate/M665.cpp`` (2.0.9 and later, 2.1): ``H`` delta height
  (``delta_height``), ``L`` diagonal rod (``delta_diagonal_rod``), ``R`` delta radius, ``S``
  segments per second (not kinematics: not written), ``X Y Z`` the tower angle trims
  (``delta_tower_angle_trim``, deg), ``A B C`` the diagonal rod trims
  (``delta_diagonal_rod_trim``, mm); ``M665_report`` (what ``M503`` prints) writes ``M665 L R
  H S X Y Z A B C`` under the heading ``Delta settings: ... XYZ<tower angle trim> ABC<rod
  trim>``.
- The letters differ between versions (see :func:`marlin_m665_letters`). Marlin 1.1.x
  (``Marlin/Marlin_main.cpp`` ``gcode_M665``, 1.1.9) and early 2.0.x (``M665.cpp`` before the
  rod trims) read ``M665 H L R S B X Y Z``: ``B`` is ``delta_calibration_radius`` (the radius
  ``G33`` probes at, not kinematics), there are no rod trims (``recalc_delta_settings`` takes
  ``DELTA_DIAGONAL_ROD_TRIM_TOWER`` from ``Configuration.h``), and ``A``, ``C`` are not read;
  ``configuration_store.cpp`` (``M503``) prints ``M665 L R H S B X Y Z`` under the heading
  ``Delta settings: ... B<calibration radius> XYZ<tower angle corrections>``. Marlin 1.1.9's
  own G-code list in ``Marlin_main.cpp`` still names older letters (``A B C`` rod trims, ``I J K``
  tower angle trims) that its ``gcode_M665`` no longer reads.
- ``Marlin/src/module/delta.cpp`` ``recalc_delta_settings``: tower ``i`` at ``(cos(base_i +
  trim_i), sin(base_i + trim_i)) (delta_radius + DELTA_RADIUS_TRIM_TOWER_i)`` with ``base`` 210,
  330, 90 deg; ``delta_diagonal_rod_2_tower_i = (delta_diagonal_rod + rod_trim_i)^2``. The
  per-tower radius trims ``DELTA_RADIUS_TRIM_TOWER`` are compile-time (``Configuration.h``),
  not a G-code: this format takes them as 0.
- ``Marlin/src/module/delta.h`` ``DELTA_Z``: the carriage height for a position is ``z +
  sqrt(delta_diagonal_rod_2_tower_i - |tower_i - (x, y)|^2)``.
- ``Marlin/src/gcode/calibrate/M666.cpp``: ``M666 X Y Z`` the endstop adjustments
  (``delta_endstop_adj``, mm); a positive value is refused ("M666 offsets must be <= 0");
  Marlin 1.1.9's ``gcode_M666`` ignores it silently (``value * Z_HOME_DIR <= 0``).
- ``Marlin/src/module/motion.cpp`` ``homeaxis`` (DELTA): after each carriage reaches its
  endstop it moves ``delta_endstop_adj`` further (down, for a negative value) when that is more
  than ``MIN_STEPS_PER_SEGMENT`` steps; ``home_delta`` then declares the nozzle at ``(0, 0,
  delta_height)`` (``set_axis_is_at_home``; ``delta_height - probe.offset.z`` in builds with a
  bed probe: this format writes for ``M851 Z0``) and the planner takes the carriage heights
  from the inverse kinematics there: ``delta_height + sqrt(rod_i^2 - radius_i^2)``.
- ``Marlin/src/gcode/calibrate/G33.cpp``: ``G33`` normalises the endstop adjustments so the
  largest is 0 (into ``delta_height``) and the angle trims to sum 0.

So the carriage of tower ``i`` at its endstop stands at ``H - adj_i + sqrt(rod_i^2 - R^2)`` in
Marlin's coordinates: Klipper's ``position_endstop`` is ``H - adj_i``, and the travel down
from the endstop for a target is ``H - adj_i + sqrt(rod_i^2 - R^2) - DELTA_Z_i``.

Degenerate values, fixed in the fit
-----------------------------------
Only ``H - adj_i`` enters: ``H`` is fixed (the adjustments are free) and the text writes the
equivalent normalised values (largest adjustment 0, as G33 leaves them; Marlin accepts no
positive one). Only ``L + A``, ``L + B``, ``L + C`` enter: ``L`` is fixed at the calibrated
machine's mean arm length, the trims free, and the text writes ``L`` as the mean of the three
rods (the trims about it). Everything else is free, all three angle trims
included (the calibrated frame is fixed: a turn of the three towers moves the print).

The controller's coordinates are the bed's as in :mod:`pkmcal.export.klipper` (``z = 0`` the
bed; a tilt against the towers is folded into the values as far as they hold it and the rest
counted in the remaining error, for bed levelling, ``G29``). Not modelled: adjustments
smaller than ``MIN_STEPS_PER_SEGMENT`` steps, which Marlin does not move; a hotend offset;
``M206``/``G92`` shifts; ``M851 Z`` (the values are read for ``M851 Z0``).

What people paste
-----------------
:meth:`MarlinDelta.parse` reads a G-code file, an ``M503`` report (``echo:  M665 ...``) and a
host's terminal log (OctoPrint ``Recv: echo:  M665 ...``, with or without the ``serial.log``
time stamp; Pronterface ``SENDING:``): lines the host sent (``Send:``, ``SENDING:``, ``>>>``)
are not the firmware's values and are skipped (:func:`host_line`). A letter the firmware does
not read is harmless and is passed over with a note (:meth:`MarlinDelta.read` returns them); a
letter whose meaning pkmcal cannot take (``M665 I J K``) or cannot tell (``M665 B`` of an
unknown version) is refused, naming the file, line and letter.
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import InputError
from ..machines.base import Machine
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
from .gcode_text import gcode_line_kind, gcode_lines, gcode_words, host_line
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

#: Marlin's tower angles before the trims (``recalc_delta_settings``), deg
BASE_ANGLES = np.array([210.0, 330.0, 90.0])
_ABC = "abc"
_LENGTH_KEYS = {"H", "L", "R", "A", "B", "C"}


#: ``M665`` letters of Marlin 2.0.9+ / 2.1 (``M665.cpp``): letter -> (parameter, kind)
M665_LETTERS_2 = {"H": "delta_height", "L": "delta_diagonal_rod", "R": "delta_radius",
                  "X": "delta_tower_angle_trim_a", "Y": "delta_tower_angle_trim_b",
                  "Z": "delta_tower_angle_trim_c", "A": "delta_diagonal_rod_trim_a",
                  "B": "delta_diagonal_rod_trim_b", "C": "delta_diagonal_rod_trim_c"}
#: ``M665`` letters of Marlin 1.1.x and early 2.0.x (``Marlin_main.cpp`` ``gcode_M665``)
M665_LETTERS_1 = {k: v for k, v in M665_LETTERS_2.items() if k not in "ABC"}
#: M503 headings: the version's letters (configuration_store.cpp / settings.cpp)
_HEADING_1 = re.compile(r"B\s*<\s*calibration radius", re.I)
_HEADING_2 = re.compile(r"ABC\s*<\s*rod", re.I)
#: M115's firmware name (``FIRMWARE_NAME:Marlin 1.1.9``)
_FIRMWARE = re.compile(r"FIRMWARE_NAME:\s*Marlin\s+(?:bugfix-)?(\d+)\.(\d+)", re.I)


def marlin_m665_letters(text: str) -> tuple[str | None, str]:
    """Which Marlin the text's ``M665`` lines come from, as far as the text says.

    Evidence, first found wins: an ``M503`` heading (``B<calibration radius>``: Marlin 1.1.x /
    early 2.0.x, ``configuration_store.cpp``; ``ABC<rod trim>``: 2.0.9+, ``settings.cpp``),
    then ``M115``'s ``FIRMWARE_NAME:Marlin 1.x`` (1.x) or ``2.1`` and later (rod trims), then an
    ``M665`` line with ``A`` or ``C`` (only the rod-trim versions read them).

    Parameters
    ----------
    text : str
        The pasted text.

    Returns
    -------
    letters : {'1', '2'} or None
        ``'1'``: ``B`` is the calibration radius, no rod trims; ``'2'``: ``A B C`` are the rod
        trims; None: the text does not say.
    why : str
        The evidence in words.
    """
    for n, raw in enumerate(text.splitlines(), 1):
        line = host_line(raw)[0]
        if _HEADING_1.search(line):
            return "1", f"line {n}: M503's heading names B<calibration radius> (Marlin 1.1.x)"
        if _HEADING_2.search(line):
            return "2", f"line {n}: M503's heading names ABC<rod trim> (Marlin 2.x)"
    for n, raw in enumerate(text.splitlines(), 1):
        m = _FIRMWARE.search(raw)
        if m and (int(m.group(1)), int(m.group(2))) < (2, 0):
            return "1", f"line {n}: M115 says Marlin {m.group(1)}.{m.group(2)}"
        if m and (int(m.group(1)), int(m.group(2))) >= (2, 1):
            return "2", f"line {n}: M115 says Marlin {m.group(1)}.{m.group(2)}"
    for n, _, rest in gcode_lines(text, ("M665",)):
        letters = {w[0].upper() for w in rest.split() if w[:1].isalpha()}
        letters |= {c.upper() for c in re.findall(r"(?<![A-Za-z])([AaCc])[-+]?[0-9.]", rest)}
        if letters & {"A", "C"}:
            return "2", f"line {n}: M665 gives A or C (rod trims: Marlin 2.x)"
    return None, "nothing in the text says which Marlin"


class MarlinDelta(ControllerFormat):
    """Marlin ``DELTA``: ``M665`` / ``M666`` (see the module docstring)."""

    name = "marlin"
    machine_kind = "linear_delta"
    machine_words = "linear Delta printer"
    words = ("Marlin delta (Marlin/src/module/delta.cpp, gcode/calibrate/M665.cpp, M666.cpp): "
             "M665 H L R X Y Z A B C, M666 X Y Z")
    suffix = ".gcode"

    NAMES = (["delta_height", "delta_diagonal_rod", "delta_radius"]
             + [f"delta_tower_angle_trim_{t}" for t in _ABC]
             + [f"delta_diagonal_rod_trim_{t}" for t in _ABC]
             + [f"delta_endstop_adj_{t}" for t in _ABC] + list(BED))
    KINDS = ["length"] * 3 + ["angle"] * 3 + ["length"] * 6 + list(BED_KINDS)
    #: H (degenerate with the adjustments), L (with the rod trims) and the bed
    FIXED = np.array([True, True] + [False] * 10 + [True] * 3)

    def values(self, H, L, R, trims, rod_trims, adj, bed) -> ControllerParameters:
        """Marlin's values from their parts (SI).

        Parameters
        ----------
        H : float
            ``delta_height``, m.
        L : float
            ``delta_diagonal_rod``, m.
        R : float
            ``delta_radius``, m.
        trims : array_like, shape (3,)
            Tower angle trims, rad.
        rod_trims : array_like, shape (3,)
            Diagonal rod trims, m.
        adj : array_like, shape (3,)
            Endstop adjustments, m.
        bed : array_like, shape (3,)
            The bed (``bed.z`` m, ``bed.tilt_x``, ``bed.tilt_y``).

        Returns
        -------
        ControllerParameters
            The values.
        """
        v = np.concatenate([[H, L, R], trims, rod_trims, adj, bed]).astype(float)
        return ControllerParameters(list(self.NAMES), v, list(self.KINDS), self.FIXED.copy())

    def initial(self, machine: Machine, setups=None) -> ControllerParameters:
        """Marlin's values read off a linear Delta (exact for vertical towers of one radius).

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
            ``R`` the mean tower radius, ``L`` the mean arm with the trims the differences,
            the angle trims against 210, 330, 90 deg, ``H`` and the adjustments normalised
            (largest 0).
        """
        bed = setups_bed(setups)
        R = float(np.mean(machine.firmware_values()["radius"]))
        arms, angles, E = controller_endstops(machine, R, bed[0])
        L = float(np.mean(arms))
        trims = np.radians(wrap_degrees(np.degrees(angles) - BASE_ANGLES))
        H = float(np.min(E))
        return self.values(H, L, R, trims, arms - L, H - E, bed)

    def ik(self, params: ControllerParameters, P, R=None) -> np.ndarray:
        """Marlin's carriage travels down from the endstops for nozzle targets.

        Parameters
        ----------
        params : ControllerParameters
            Marlin's values.
        P : ndarray, shape (K, 3)
            Targets in the calibrated frame, m.
        R : ndarray, optional
            Ignored (the effector does not rotate).

        Returns
        -------
        ndarray, shape (K, 3)
            Travels, m; NaN where a rod cannot reach.
        """
        v = params.values
        H, L, radius = v[0], v[1], v[2]
        trims, rods, adj, bed = v[3:6], L + v[6:9], v[9:12], v[12:15]
        Pc = np.array(P, float).reshape(-1, 3)
        # heights above the bed (its tilt folded into the values as far as they hold it)
        Pc[:, 2] -= bed[0] + bed[1] * Pc[:, 0] + bed[2] * Pc[:, 1]
        towers = tower_positions(radius, np.radians(BASE_ANGLES) + trims)
        tops = H - adj + np.sqrt(rods**2 - radius**2)
        return vertical_tower_travel(towers, rods, tops, Pc)

    @staticmethod
    def normalised(v):
        """``H`` and the adjustments with the largest adjustment 0 (as G33 leaves them).

        Parameters
        ----------
        v : ndarray
            Marlin's values (SI).

        Returns
        -------
        H : float
            ``delta_height``, m.
        adj : ndarray, shape (3,)
            Endstop adjustments (<= 0), m.
        """
        top = float(np.max(v[9:12]))
        return v[0] - top, v[9:12] - top

    def text(self, params: ControllerParameters, machine: Machine,
             setups=None) -> str:
        """The G-code lines (mm, deg).

        Parameters
        ----------
        params : ControllerParameters
            Marlin's values.
        machine : Machine
            The machine they are for.
        setups : Setups, optional
            Unused (the values hold the bed: none of the experiment's set-ups is read).

        Returns
        -------
        str
            ``M665 H L R X Y Z A B C`` and ``M666 X Y Z`` with comments.
        """
        v = params.values
        H, adj = self.normalised(v)
        rods = v[1] + v[6:9]
        L = round(float(np.mean(rods)) * 1e3, 6) * 1e-3     # trims about their mean
        bed = v[12:15]
        mm = (lambda x: f"{x * 1e3:.6f}")  # noqa: E731
        deg = (lambda x: f"{np.degrees(x):.9f}")  # noqa: E731
        lines = [f"; pkmcal export --to marlin: {machine.name or 'linear Delta'}",
                 "; Marlin delta (module/delta.cpp), Marlin 2.0.9+ letters (A B C the rod "
                 "trims; Marlin 1.1.x has them at compile time, DELTA_DIAGONAL_ROD_TRIM_TOWER, "
                 "and reads M665 B as the calibration radius); send, then M500 to store them "
                 "in EEPROM",
                 "; H is the nozzle height at home for M851 Z0; z = 0 is the bed at the centre"
                 + (f"; the bed's tilt against the towers (dz/dx {bed[1]:.6g}, dz/dy "
                    f"{bed[2]:.6g}) is folded into these values as far as they hold it, the "
                    "rest counted in the remaining error (bed levelling, G29, corrects it)"
                    if np.any(bed[1:] != 0) else ""),
                 bed_text(bed, ";"),
                 "M665 " + " ".join([f"H{mm(H)}", f"L{mm(L)}", f"R{mm(v[2])}"]
                                    + [f"{k}{deg(v[3 + i])}" for i, k in enumerate("XYZ")]
                                    + [f"{k}{mm(rods[i] - L)}" for i, k in enumerate("ABC")]),
                 "M666 " + " ".join(f"{k}{mm(adj[i])}" for i, k in enumerate("XYZ"))]
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
            ``(name, value in words)``: the written (normalised) words, mm and deg, then the bed.
        """
        v = params.values
        H, adj = self.normalised(v)
        rods = v[1] + v[6:9]
        L = round(float(np.mean(rods)) * 1e3, 6) * 1e-3
        out = [("M665 H", f"{H * 1e3:.6f} mm"), ("M665 L", f"{L * 1e3:.6f} mm"),
               ("M665 R", f"{v[2] * 1e3:.6f} mm")]
        out += [(f"M665 {k}", f"{np.degrees(v[3 + i]):.9f} deg") for i, k in enumerate("XYZ")]
        out += [(f"M665 {k}", f"{(rods[i] - L) * 1e3:.6f} mm") for i, k in enumerate("ABC")]
        out += [(f"M666 {k}", f"{adj[i] * 1e3:.6f} mm") for i, k in enumerate("XYZ")]
        return out + bed_values(v[12:15])

    def parse(self, text: str, source: str) -> ControllerParameters:
        """Marlin's values: :meth:`read`, its notes kept as ``params.notes``."""
        params, notes = self.read(text, source)
        params.notes = notes
        return params

    def read(self, text: str, source: str) -> tuple[ControllerParameters, list[str]]:
        """Marlin's values and notes on what was passed over.

        Later lines override earlier ones, as Marlin executes them; ``H``, ``L`` and ``R``
        are required (their defaults are compile-time), the trims and adjustments default to
        0. The ``M665`` letters are those of the version the text shows
        (:func:`marlin_m665_letters`): Marlin 2.x ``H L R S X Y Z A B C`` (``M665.cpp``), Marlin
        1.1.x ``H L R S B X Y Z`` with ``B`` the calibration radius (``Marlin_main.cpp``
        ``gcode_M665``). Where the text does not say, ``B`` is read as 1.1.x's calibration
        radius only on a line in 1.1.x's ``M503`` order (``B`` after ``S``, before ``X``, no
        ``A`` or ``C``); any other ``B`` alone is refused. Host lines are handled by
        :func:`host_line`.

        Parameters
        ----------
        text : str
            The file's text.
        source : str
            Its name, for messages.

        Returns
        -------
        params : ControllerParameters
            The values, SI; Marlin 1.1.x's ``M665 B`` (``delta_calibration_radius``, where
            ``G33`` probes) as ``extras["probe_radius"]``, m, where the parameters have
            ``extras``.
        notes : list of str
            Letters passed over (``S``; 1.1.x's ``B``; letters Marlin does not read), each with
            the file and line.

        Raises
        ------
        InputError
            Naming the file, line and letter of a value that is not a number, a positive
            endstop adjustment (Marlin refuses it), ``I J K`` (early 1.1 tower angle trims, not
            taken), a ``B`` whose meaning the text does not settle, a missing ``H``, ``L`` or
            ``R``, a value that cannot be meant (:func:`~pkmcal.export.klipper.
            check_printer_values`: a rod trim or adjustment beyond 10 % of the printer's
            size), a radius not > 0 or a rod not longer than the radius.
        """
        refuse_foreign_text(text, source, gcode_line_kind, "Marlin G-code",
                            "M665 / M666 lines, as M503 prints them")
        version, why = marlin_m665_letters(text)
        got: dict = {}
        notes: list[str] = []
        extras: dict = {}
        extras_lines: dict = {}
        for n, code, rest in gcode_lines(text, ("M665", "M666")):
            words = gcode_words(rest, source, n, code)
            if code == "M666":
                for letter, word in words.items():
                    if letter not in "XYZ":
                        notes.append(f"{source}: line {n}: M666 {letter}: not a delta endstop "
                                     "adjustment (M666.cpp reads X Y Z): ignored")
                        continue
                    value = finite_number(word, source, n, f"M666 {letter}")
                    if value > 0:
                        raise InputError(f"{source}: line {n}: M666 {letter}: {word} is "
                                         "positive; Marlin's endstop adjustments must be <= 0 "
                                         "(M666.cpp)")
                    got[("M666", letter)] = (value * 1e-3, n)
                continue
            letters = self._m665_letters(words, version, why, source, n, notes)
            for letter, word in words.items():
                if letter == "B" and "B" not in letters:       # 1.1.x: where G33 probes
                    extras["probe_radius"] = finite_number(word, source, n, "M665 B") * 1e-3
                    extras_lines["probe_radius"] = n
                if letter not in letters:
                    continue
                value = finite_number(word, source, n, f"M665 {letter}")
                scale = 1e-3 if letter in _LENGTH_KEYS else np.pi / 180
                got[("M665", letter)] = (value * scale, n)
        for k in "HLR":
            if ("M665", k) not in got:
                raise InputError(f"{source}: M665 {k}: missing (no M665 line sets it; Marlin's "
                                 "default is in the firmware's Configuration.h)")

        def g(code, k):
            return got.get((code, k), (0.0, 0))[0]

        H, L, R = g("M665", "H"), g("M665", "L"), g("M665", "R")
        rods = L + np.array([g("M665", k) for k in "ABC"])
        params = self.values(H, L, R, [g("M665", k) for k in "XYZ"],
                             [g("M665", k) for k in "ABC"], [g("M666", k) for k in "XYZ"],
                             read_bed(text, source))
        params.origins.update(bed_origins(text, source))
        for (code, letter), (_, n) in got.items():
            name = (f"delta_endstop_adj_{_ABC['XYZ'.index(letter)]}" if code == "M666"
                    else M665_LETTERS_2[letter])
            params.origins[name] = Origin(source, f"{code} {letter}", n)
        for key, n in extras_lines.items():
            params.origins[key] = Origin(source, "M665 B", n)
        mm = (lambda x: f"{x * 1e3:g} mm")  # noqa: E731
        deg = (lambda x: f"{np.degrees(x):g} deg")  # noqa: E731
        check_printer_values(
            params, source, ["delta_height", "delta_diagonal_rod", "delta_radius"],
            dimensions=[(n, mm) for n in self.NAMES[:3]],
            corrections=[(n, mm) for n in self.NAMES[6:12]],
            turns=[(n, deg) for n in self.NAMES[3:6]], radius=R)
        if not R > 0:
            raise InputError(f"{origin_of(params, 'delta_radius')}: the radius ({mm(R)}) "
                             "must be > 0")
        for i, t in enumerate(_ABC):
            if not rods[i] > R:
                raise InputError(
                    f"{origin_of(params, 'delta_diagonal_rod', f'delta_diagonal_rod_trim_{t}')}"
                    f": tower {t.upper()}'s diagonal rod ({mm(rods[i])}) must be longer than "
                    f"the radius ({where([params.origins['delta_radius']])}: {mm(R)})")
        if isinstance(getattr(params, "extras", None), dict):
            params.extras.update(extras)
        return params, notes

    def machine_keys(self, params: ControllerParameters) -> dict:
        """The source map of an import (see :meth:`ControllerFormat.machine_keys`).

        Parameters
        ----------
        params : ControllerParameters
            Marlin's values.

        Returns
        -------
        dict
            ``delta_radius`` from ``M665 R``; arm ``i`` from ``L`` and its rod trim; tower
            angle ``i`` from its trim; ``position_endstop`` ``i`` from ``H``, ``M666``'s
            adjustment and the bed's height.
        """
        return linear_delta_keys(
            ["delta_radius"],
            [["delta_diagonal_rod", f"delta_diagonal_rod_trim_{t}"] for t in _ABC],
            [[f"delta_tower_angle_trim_{t}"] for t in _ABC],
            [["delta_height", f"delta_endstop_adj_{t}", "bed.z"] for t in _ABC])

    @staticmethod
    def _m665_letters(words: dict, version, why: str, source: str, n: int,
                      notes: list) -> set:
        """The letters of one ``M665`` line to read as kinematics (see :meth:`read`); notes
        and refusals for the others."""
        where = f"{source}: line {n}: M665"
        for k in "IJK":
            if k in words:
                raise InputError(f"{where} {k}: a tower angle trim letter of early Marlin 1.1 "
                                 "(I J K; Marlin_main.cpp's G-code list), which Marlin 1.1.9 "
                                 "and 2.x no longer read; give the trims as X Y Z")
        order = list(words)
        if version is None and "B" in words and not {"A", "C"} & set(words):
            before_x = "X" not in words or order.index("B") < order.index("X")
            after_s = "S" in words and order.index("S") < order.index("B")
            if not (before_x and after_s):
                raise InputError(
                    f"{where} B: Marlin 1.1.x reads B as the calibration radius (not "
                    "kinematics), Marlin 2.x as tower B's diagonal rod trim, and nothing in "
                    "the text says which Marlin this is; paste M503's heading line with it, "
                    "or give A and C too (2.x), or leave B out (1.1.x)")
            version, why = "1", f"line {n}: B follows S and precedes X, as 1.1.x's M503 prints"
        table = M665_LETTERS_1 if version == "1" else M665_LETTERS_2
        for letter in words:
            if letter in table:
                continue
            if letter == "S":
                notes.append(f"{where} S: segments per second (motion planning, not "
                             "kinematics): ignored")
            elif letter == "B" and version == "1":
                notes.append(f"{where} B: Marlin 1.1.x's delta_calibration_radius (where G33 "
                             f"probes, not kinematics; {why}): not a kinematic value")
            elif version == "1" and letter in "AC":
                notes.append(f"{where} {letter}: not read by Marlin 1.1.x ({why}): ignored")
            else:
                notes.append(f"{where} {letter}: not an M665 letter of Marlin's delta "
                             "(M665.cpp): ignored")
        return set(table)

    def to_machine(self, params: ControllerParameters, like: Machine | None = None) -> Machine:
        """A linear Delta with Marlin's values (vertical towers, one radius).

        Parameters
        ----------
        params : ControllerParameters
            Marlin's values.
        like : Machine, optional
            Name and home pose come from it.

        Returns
        -------
        Machine
            The :class:`~pkmcal.machines.LinearDelta`: arms ``L + A|B|C``, angles 210, 330,
            90 deg plus the trims, ``position_endstop`` ``H - adj``.
        """
        v = params.values
        return linear_delta_machine(v[2], v[1] + v[6:9], np.radians(BASE_ANGLES) + v[3:6],
                                    v[0] - v[9:12], self.imported_bed(params), like,
                                    "linear Delta (imported from Marlin)", params.extras)

    def imported_bed(self, params: ControllerParameters) -> np.ndarray:
        """The bed the values hold, ``(height m, tilt_x, tilt_y)``: Marlin's z is the height
        above the bed, its values the printer in the bed's frame, square (a tilt named in the
        pkmcal comment is folded in already).

        Parameters
        ----------
        params : ControllerParameters
            Marlin's values.

        Returns
        -------
        ndarray, shape (3,)
            The plane.
        """
        return np.array([params.values[12], 0.0, 0.0])

    def holds_measurements(self, path, head: str) -> bool:
        """A pasted probe report (:mod:`pkmcal.export.firmware_reports`)."""
        from .firmware_reports import holds_probe_report

        return holds_probe_report(path, head, "marlin")

    def read_measurements(self, paths: list, machine: Machine) -> list:
        """The report's probe heights through the firmware's kinematics
        (:func:`~pkmcal.export.firmware_reports.probe_report_data`)."""
        from .firmware_reports import probe_report_file_data

        return probe_report_file_data(paths, machine)


MARLIN = register_format(MarlinDelta())
