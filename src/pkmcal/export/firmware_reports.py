"""Bed probe reports pasted from a printer's terminal, as data.

:func:`read_probe_report` reads the one documented probe output of each firmware, the probed
heights and where they were probed, in the firmware's own coordinates and sign:

Marlin: ``Bed X: <x> Y: <y> Z: <z>`` lines
    Printed by ``G30`` (``Marlin/src/gcode/probe/G30.cpp``, every probe) and by
    ``Probe::probe_at_point`` (``Marlin/src/module/probe.cpp``) when its verbose level is
    above 2 (``G29 V3``, ``G29 V4``), as by Marlin 1.1.x's ``gcode_G30`` / ``probe_pt``
    (``Marlin_main.cpp``). ``X``, ``Y`` are the probe's position (``probe_at_point`` moves the
    nozzle to it minus the probe's XY offset), in logical coordinates; ``Z`` is
    ``run_z_probe() + offset.z``: the nozzle's ``z`` when the probe triggered plus ``M851 Z``,
    i.e. the height of the bed's surface at ``(X, Y)`` in Marlin's frame (leveling off during
    ``G30`` / ``G29``). Positive: the bed is above Marlin's ``z = 0`` there. 2 decimals in
    Marlin 2.x (``SERIAL_ECHOLNPGM``'s float), 3 in 1.1.x's ``probe_pt``.

RepRapFirmware: ``G32 bed probe heights: h0 h1 ..., mean m, deviation from mean d``
    (``Bed probe heights:`` before RRF 3), printed when the last of a set of ``G30 P<i> X<x>
    Y<y> Z-99999`` commands has ``S-1`` (``Move::FinishedBedProbing`` with a negative ``S``;
    ``RandomProbePointSet::ReportProbeHeights``). Height ``i`` is ``zBedProbePoints[i]``,
    which ``GCodes4.cpp`` (``probingAtPoint4``) sets to the machine height at which the probe
    triggered (no bed compensation) minus ``G30 H`` minus the probe's trigger height (``G31
    Z``): the height of the bed's surface at the probe point, in RepRapFirmware's machine
    frame; positive: the bed is above ``z = 0`` there. The point's ``X``, ``Y`` are those of
    its ``G30 P<i>`` command (the probe's position: ``GetProbeCoordinates`` takes the probe's
    offset off), which the reply does not repeat: the text must hold the commands (``bed.g``
    pasted with the reply, or a host log's ``Send: G30 P...`` lines). Height ``i`` takes the
    ``X``, ``Y`` of the last ``G30 P<i>`` line before the reply, or, where there is none before
    it, of the first after it. 3 decimals.

Refused, naming the line: Marlin ``G33``'s output (``G33.cpp``: by default only the settings
``.Height: ... Radius:``, ``std dev:`` per iteration and ``Calibration sd:``; with ``V0`` /
``V3`` the probed heights as ``c: x: y: z: yz: zx: xy:`` at 0.01 mm, without their X/Y: points
at the calibration radius, which it does not print, at 210/330/90 and 30/150/270 deg, and for
``P4``-``P10`` averages over arcs); RepRapFirmware's ``Stopped at height <h> mm`` (``G30 S-1``
without ``P``: the machine height of the head when the probe triggered, not the bed's, at an XY
the reply does not give); ``M122``'s ``Bed probe heights:`` (without ``mean``: only the first
five points); and the two firmwares' reports in one text.

Host logs are read as in :func:`pkmcal.export.gcode_text.host_line` (OctoPrint ``Recv:`` /
``Send:``, time stamps, Marlin's ``echo:``). ``M665`` / ``M666`` lines of the same text give
the firmware values in force (:attr:`ProbeReport.values`), read by the firmware's format in
:mod:`pkmcal.export`; a value that changes between the first and the last probe line is
refused.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
#: Marlin G30 / probe_at_point (``Bed X: 0.00 Y: 0.00 Z: 0.12``)
_MARLIN_BED = re.compile(rf"^Bed X:\s*({_NUM})\s+Y:\s*({_NUM})\s+Z:\s*({_NUM})\s*$")
#: RepRapFirmware's heights reply (``G32 bed probe heights: ..., mean ..., deviation ...``)
_RRF_HEIGHTS = re.compile(r"^(?:G32 )?bed probe heights:(.*?),\s*mean\s+(\S+),\s*"
                          r"deviation from mean\s+(\S+)\s*$", re.I)
#: replies with heights that are not read (see the module docstring)
_REFUSED = (
    (re.compile(r"^(?:G33 Auto Calibrate|(?://action:notification\s+)?Checking\.\.\. AC"
                r"|\.\s*Height:|\.\s+c:\s*[-+]|Iteration\s*:\s*\d+\s+std dev:"
                r"|(?://action:notification\s+)?Calibration sd:)", re.I),
     "Marlin G33 output: G33 prints its probed heights (V0, V3 only) as c/x/y/z/yz/zx/xy at "
     "0.01 mm without their X/Y (points at the calibration radius, which it does not print; "
     "P4-P10 average arcs), otherwise only its settings and 'std dev' (G33.cpp "
     "print_calibration_results); probe with G30 X<x> Y<y> (one 'Bed X: .. Y: .. Z: ..' line "
     "per point) or G29 V3 instead"),
    (re.compile(r"^Stopped at height\s", re.I),
     "RepRapFirmware's 'Stopped at height' (G30 S-1 without P) is the head's machine height "
     "when the probe triggered, not the bed's, at an X/Y the reply does not give "
     "(GCodes4.cpp probingAtPoint7); probe with G30 P<i> X<x> Y<y> Z-99999, S-1 on the last "
     "point, and paste the 'bed probe heights' reply with those commands"),
    (re.compile(r"^Bed probe heights:(?!.*\bmean\b)", re.I),
     "an M122 diagnostics line (it shows only the first five probe points, without X/Y); "
     "paste the reply of G30 ... S-1 ('bed probe heights: ..., mean ..., deviation from "
     "mean ...') with its G30 P<i> X<x> Y<y> commands"),
)


@dataclass
class ProbeReport:
    """Probed bed heights of a pasted probe report (see the module docstring).

    Attributes
    ----------
    xy : ndarray, shape (K, 2)
        Probe positions in the firmware's coordinates, mm.
    z : ndarray, shape (K,)
        Height of the bed's surface at ``xy`` in the firmware's frame when the probe
        triggered, mm, with the sign the firmware prints (positive: above ``z = 0``).
    rows : ndarray of int, shape (K,)
        1-based line numbers of the heights in the text.
    firmware : str
        ``'marlin'`` or ``'reprapfirmware'``.
    values : ControllerParameters or None
        The firmware's values read from the text's ``M665`` / ``M666`` lines (SI, as
        :meth:`pkmcal.export.base.ControllerFormat.parse` returns them), None without such
        lines.
    source : str
        The text's name.
    notes : list of str
        What was passed over (letters of the ``M665`` / ``M666`` lines, unused ``G30 P``
        points).
    """

    xy: np.ndarray
    z: np.ndarray
    rows: np.ndarray
    firmware: str
    values: object = None
    source: str = ""
    notes: list = field(default_factory=list)

    def __post_init__(self):
        self.xy = np.asarray(self.xy, float).reshape(-1, 2)
        self.z = np.asarray(self.z, float).reshape(-1)
        self.rows = np.asarray(self.rows, int).reshape(-1)


def _number(word: str, source: str, n: int, what: str) -> float:
    """A finite number of the report, or an error naming the line and what it is."""
    from .base import finite_number

    return finite_number(word, source, n, what)


def _rrf_points(lines, source: str) -> dict:
    """``G30 P<i> X<x> Y<y>`` commands: index -> list of (line, x, y), in text order."""
    from .gcode_text import gcode_lines, gcode_words

    points: dict = {}
    for n, _, rest in gcode_lines("\n".join(lines), ("G30",), sent=True):
        words = gcode_words(rest, source, n, "G30")
        if "P" not in words:
            continue
        p = _number(words["P"], source, n, "G30 P")
        if p != int(p) or p < 0:
            raise InputError(f"{source}: line {n}: G30 P: {words['P']!r} is not a probe point "
                             "number (0, 1, ...)")
        for k in "XY":
            if k not in words:
                raise InputError(f"{source}: line {n}: G30 {k}: missing; a G30 P<i> line gives "
                                 "the point's X and Y (RepRapFirmware's GCodes2.cpp needs both)")
        xy = (_number(words["X"], source, n, "G30 X"), _number(words["Y"], source, n, "G30 Y"))
        points.setdefault(int(p), []).append((n, *xy))
    return points


def _rrf_heights(n: int, body: str, source: str) -> list[float]:
    """The heights of one RepRapFirmware reply, or an error naming the point that failed."""
    body = body.strip()
    out = []
    for i, m in enumerate(re.finditer(r"not set|probing failed|\S+", body)):
        if m.group(0) in ("not set", "probing failed"):
            raise InputError(f"{source}: line {n}: bed probe heights: point {i}: "
                             f"{m.group(0)} (RepRapFirmware's ReportProbeHeights); probe again")
        out.append(_number(m.group(0), source, n, f"bed probe heights: point {i}"))
    if not out:
        raise InputError(f"{source}: line {n}: bed probe heights: no heights")
    return out


def _values(firmware: str, text: str, source: str, first: int, last: int, notes: list):
    """The firmware values of the text's ``M665`` / ``M666`` lines (None without any), as the
    whole text leaves them; refused where a line between the first and the last probe line
    changes values already complete before it."""
    from .base import controller_format
    from .gcode_text import gcode_lines

    rows = [n for n, _, _ in gcode_lines(text, ("M665", "M666"))]
    if not rows:
        return None
    fmt = controller_format(firmware)
    params = fmt.parse(text, source)
    notes.extend(getattr(params, "notes", []))
    lines = text.splitlines()
    for row in (r for r in rows if first < r < last):
        try:
            before = fmt.parse("\n".join(lines[:row - 1]), source).values
            upto = fmt.parse("\n".join(lines[:row]), source).values
        except InputError:
            continue            # not all of L R H given yet: nothing in force changes
        if not np.allclose(before, upto, rtol=0, atol=1e-12):
            raise InputError(f"{source}: line {row}: the firmware's M665/M666 values change "
                             f"between the probe lines {first} and {last}; paste one probing "
                             "run with the values in force")
    return params


#: lines of a pasted log after the probe report's last line (or its G30 / M665 / M666 commands)
#: that are read before the rest is left: a report is one block of a log
REPORT_GAP = 1000


def read_probe_report(text: str, source: str) -> ProbeReport:
    """The probed heights of a pasted Marlin or RepRapFirmware probe report.

    One way per firmware (the module docstring gives them, their coordinates and sign, and
    the outputs refused).

    Parameters
    ----------
    text : str
        The pasted text (a terminal log, an ``M503`` report, ``bed.g`` with the reply).
    source : str
        Its name, for messages.

    Returns
    -------
    ProbeReport
        Positions and heights, mm, their line numbers, the firmware, and the firmware values
        in force when the text holds ``M665`` / ``M666`` lines.

    Raises
    ------
    InputError
        Naming the file and line: a refused output, a value that is not a number, a failed
        point, a RepRapFirmware height without its ``G30 P<i>`` command, both firmwares'
        reports in one text, or no probe report at all.
    """
    from .gcode_text import host_line

    raw_lines = text.splitlines()
    marlin, rrf = [], []
    last = 0                        # the last line of the report or of its commands
    for n, raw in enumerate(raw_lines, 1):
        if n - last > REPORT_GAP:
            # a report is a block of a pasted log: what follows a long stretch without one of
            # its lines is not read (a large file of something else is answered at once)
            raw_lines = raw_lines[:last]
            text = "\n".join(raw_lines)
            break
        if "G30" in raw or "M66" in raw:
            last = n
        line, sent = host_line(raw)
        if sent or not line:
            continue
        for pattern, why in _REFUSED:
            if pattern.search(line):
                raise InputError(f"{source}: line {n}: {why}")
        m = _MARLIN_BED.match(line)
        if m:
            last = n
            marlin.append((n, *(_number(m.group(k + 1), source, n, f"Bed {a}")
                                for k, a in enumerate("XYZ"))))
            continue
        m = _RRF_HEIGHTS.match(line)
        if m:
            last = n
            rrf.append((n, _rrf_heights(n, m.group(1), source)))
    if marlin and rrf:
        first = max(marlin[0][0], rrf[0][0])
        raise InputError(f"{source}: line {first}: both a Marlin ('Bed X:') and a "
                         "RepRapFirmware ('bed probe heights') report; paste one firmware's")
    notes: list[str] = []
    if marlin:
        rows = [r[0] for r in marlin]
        xy = [r[1:3] for r in marlin]
        z = [r[3] for r in marlin]
        firmware = "marlin"
    elif rrf:
        firmware = "reprapfirmware"
        points = _rrf_points(raw_lines, source)
        rows, xy, z = [], [], []
        used = set()
        for n, heights in rrf:
            for i, h in enumerate(heights):
                given = points.get(i, [])
                before = [p for p in given if p[0] < n]
                after = [p for p in given if p[0] > n]
                if not before and not after:
                    raise InputError(f"{source}: line {n}: bed probe heights: point {i}: no "
                                     f"'G30 P{i} X.. Y..' line gives its X and Y; paste the "
                                     "G30 commands (bed.g) with the reply")
                p = before[-1] if before else after[0]
                used.add(i)
                rows.append(n)
                xy.append(p[1:])
                z.append(h)
        unused = sorted(set(points) - used)
        if unused:
            notes.append(f"{source}: G30 P{', P'.join(map(str, unused))}: no height in the "
                         "reply: not used")
    else:
        raise InputError(f"{source}: no probe report: expected Marlin's 'Bed X: .. Y: .. Z: ..' "
                         "lines (G30, G29 V3) or RepRapFirmware's 'bed probe heights: ..., "
                         "mean ..' reply with its G30 P<i> X<x> Y<y> commands")
    values = _values(firmware, text, source, min(rows), max(rows), notes)
    return ProbeReport(np.array(xy, float), np.array(z, float), np.array(rows, int), firmware,
                       values, source, notes)


#: a text holds a firmware's probe report (its first lines are searched for its hint)
_REPORT_HINTS = {"marlin": re.compile(r"Bed X:\s*[-+.\d]", re.I),
                 "reprapfirmware": re.compile(r"bed probe heights:", re.I)}


def is_probe_report(head: str, firmware: str | None = None) -> bool:
    """Whether a text looks like a probe report of ``firmware`` (``"marlin"``,
    ``"reprapfirmware"``; None: either)."""
    hints = _REPORT_HINTS.values() if firmware is None else [_REPORT_HINTS[firmware]]
    return any(h.search(head) for h in hints)


def holds_probe_report(path, head: str, firmware: str) -> bool:
    """Whether a data file given to ``calibrate`` is a pasted probe report of ``firmware``
    (never a ``.csv`` file: a CSV file is pkmcal's own data)."""
    return not str(path).lower().endswith(".csv") and is_probe_report(head, firmware)


def probe_report_file_data(paths, machine) -> list:
    """The probe heights of a pasted probe report file (:func:`read_probe_report`,
    :func:`probe_report_data`), one data object per file."""
    from ..io.atomic import read_input_text

    return [probe_report_data(read_probe_report(read_input_text(p, "probe report"), str(p)),
                              machine) for p in paths]


def probe_report_data(report: ProbeReport, machine):
    """A probe report's points as pkmcal probe heights: carriage readings through the
    firmware's own kinematics.

    The nozzle stood above ``(x, y)`` when the probe triggered there, the bed's surface at
    the firmware's height ``z``; the firmware commanded the carriages for that point with the
    values in force: the report's ``M665``/``M666`` lines, else ``machine`` (a machine file
    imported from the firmware: ``pkmcal import``; the firmwares' delta kinematics are
    pkmcal's linear Delta with vertical towers). The readings are the firmware's inverse
    kinematics of ``(x, y, z)`` and the height above the bed is 0: a probe's z offset moves
    the nozzle vertically, every carriage by the same length, and cancels (to the towers'
    tilt times the offset, micrometres). The probe's XY offset is taken as 0 (the report
    prints the probe's position, ``M851 X Y`` is not in it): a probe beside the nozzle
    measures the bed there, the nozzle's readings are those of the point.

    Parameters
    ----------
    report : ProbeReport
        The report (:func:`read_probe_report`).
    machine : Machine
        The machine file given (a linear Delta).

    Returns
    -------
    InstrumentData
        ``kind="probe"``, rows the report's line numbers.

    Raises
    ------
    InputError
        When the firmware values cannot reach a point (naming its line).
    """
    from ..instruments import InstrumentData
    from .base import controller_format

    firmware = machine
    if report.values is not None:
        firmware = controller_format(report.firmware).to_machine(report.values)
    P = np.column_stack([report.xy, report.z]) * 1e-3
    R = np.broadcast_to(np.eye(3), (len(P), 3, 3))
    with np.errstate(all="ignore"):
        q = firmware.ik(P, R)
    bad = ~np.all(np.isfinite(q), axis=-1)
    if bad.any():
        n = int(report.rows[bad][0])
        raise InputError(f"{report.source}: line {n}: the firmware's values cannot reach this "
                         f"point ({report.xy[bad][0][0]:g}, {report.xy[bad][0][1]:g}) mm")
    data = InstrumentData("probe", q, np.zeros((len(P), 1)), None, report.rows, report.source)
    data.notes = list(report.notes)
    return data
