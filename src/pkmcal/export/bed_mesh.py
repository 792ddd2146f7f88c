"""What a firmware's kinematics cannot hold at the bed, handed over as a bed mesh (issue 35).

An export fits the firmware's parameters to the calibrated machine (:func:`~pkmcal.export.
base.fit_controller`); what those values leave of the nozzle's height above the bed (a
leaning tower, unequal radii, the bed's tilt where the firmware has none) is a smooth surface
over the print disk. A firmware that applies a bed mesh can carry it: the mesh value at
(x, y) is the height at which the firmware must place the nozzle to touch the bed there, i.e.
minus the height error its values leave (:func:`bed_correction`). It is handed over only
when it is larger than the probe's own repeatability (:data:`MESH_MIN`); the error at the bed
and 50 and 100 mm above it with and without the mesh is reported (:func:`layer_errors`).

Formats: Klipper's ``[bed_mesh NAME]`` profile in the SAVE_CONFIG block
(:func:`klipper_profile_text`, :func:`with_klipper_profile`; ``bed_mesh.py`` ``save_profile``
writes ``version``, ``points`` (rows by ascending y, ``%.6f``), then ``min_x, max_x, min_y,
max_y, x_count, y_count, mesh_x_pps, mesh_y_pps, algo, tension``), loaded with
``BED_MESH_PROFILE LOAD=pkmcal``; Marlin's ``M421`` lines (:func:`marlin_mesh_gcode`);
RepRapFirmware's ``heightmap.csv`` (:func:`reprapfirmware_heightmap`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..instruments.probe import bed_of
from ..io.klipper_data import EXPORTED_PROFILE
from ..machines.base import Machine

#: a correction smaller than this (RMS over the print disk, m) is not handed over: the probe's
#: repeatability (:data:`~pkmcal.instruments.probe.PROBE_SIGMA`)
MESH_MIN = 10e-6
#: nodes per side of the handed-over mesh (odd: the centre is a node)
MESH_COUNT = 11
#: heights above the bed at which the export reports the nozzle's height error, m
LAYERS = (0.0, 0.05, 0.1)
#: the profile's name in the firmware (never the user's own profiles; the Klipper reader
#: leaves it out of the data)
PROFILE = EXPORTED_PROFILE


@dataclass
class BedCorrection:
    """A bed mesh that carries what the firmware's values leave at the bed.

    Attributes
    ----------
    x, y : ndarray
        The nodes' coordinates, m (rows by ascending y, each by ascending x).
    z : ndarray, shape (len(y), len(x))
        The mesh values, m: the height at which the firmware must place the nozzle to touch
        the bed there (minus the height error its values leave).
    inside : ndarray of bool, same shape
        Nodes within the print radius (those outside hold the surface where the firmware
        reaches them, else copies of their row's outermost one, as Klipper fills a round
        bed's rows).
    radius : float
        The print disk's radius, m.
    rms : float
        RMS of the values at the nodes inside, m.
    """

    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    inside: np.ndarray
    radius: float
    rms: float

    @property
    def worth_it(self) -> bool:
        """Whether the correction is larger than the probe's repeatability (handed over)."""
        return bool(self.rms > MESH_MIN)

    def at(self, xy) -> np.ndarray:
        """The mesh interpolated bilinearly at (x, y) (m), clamped to its extent."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        fx = np.interp(xy[:, 0], self.x, np.arange(len(self.x)))
        fy = np.interp(xy[:, 1], self.y, np.arange(len(self.y)))
        i0 = np.clip(np.floor(fx).astype(int), 0, len(self.x) - 2)
        j0 = np.clip(np.floor(fy).astype(int), 0, len(self.y) - 2)
        tx, ty = fx - i0, fy - j0
        z = self.z
        return ((1 - ty) * ((1 - tx) * z[j0, i0] + tx * z[j0, i0 + 1])
                + ty * ((1 - tx) * z[j0 + 1, i0] + tx * z[j0 + 1, i0 + 1]))


def print_radius_of(machine: Machine, setups=None) -> float:
    """The print disk's radius, m: the machine's ``print_radius``, else its probing radius
    (:func:`~pkmcal.machines.reach.probe_radius`, over the bed of the set-ups ``setups``)."""
    from ..machines.reach import probe_radius

    bed = bed_of(setups)
    return float(getattr(machine, "print_radius", None)
                 or probe_radius(machine, None if bed is None else bed.plane))


def _plane_z(bed, xy) -> np.ndarray:
    """The bed's plane (the set-up ``bed``; 0 without one): the frame the firmware commands
    in."""
    b = np.zeros(3) if bed is None else np.asarray(bed.plane, float)
    return b[0] + b[1] * xy[:, 0] + b[2] * xy[:, 1]


def _height_errors(fmt, params, machine: Machine, xy, height: float,
                   setups=None) -> np.ndarray:
    """The nozzle's height error (m) above the bed (of the set-ups ``setups``) when the
    firmware commands ``height`` above it: what its values leave of the kinematics, minus the
    bed's own shape beside the plane (:func:`~pkmcal.machines.base.bed_height_at`: a bed
    higher there is touched that much earlier)."""
    from .fitting import position_errors

    xy = np.asarray(xy, float).reshape(-1, 2)
    bed = bed_of(setups)
    plane = _plane_z(bed, xy)
    P = np.column_stack([xy, plane + height])
    shape = (np.zeros(len(xy)) if bed is None else bed.height_at(xy)) - plane
    return position_errors(fmt, params, machine, P)[:, 2] - shape


def bed_correction(fmt, params, machine: Machine, radius: float,
                   count: int = MESH_COUNT, height: float = 0.0,
                   setups=None) -> BedCorrection | None:
    """The mesh that carries the height error ``params`` leave at the bed over the print
    disk (see the module docstring).

    Parameters
    ----------
    fmt : ControllerFormat
        The firmware.
    params : ControllerParameters
        Its fitted values.
    machine : Machine
        The calibrated machine.
    radius : float
        The print disk's radius, m.
    count : int, optional
        Nodes per side.
    height : float, optional
        The nozzle's height above the bed at which the mesh describes the bed, m: 0, or the
        probe's trigger height where the firmware's own meshes are probed there (a Klipper
        mesh holds the bed as seen with the nozzle ``z_offset`` above it; a leaning tower
        makes the error the values leave change with height).
    setups : Setups, optional
        The experiment's set-ups: the bed (:class:`~pkmcal.instruments.probe.BedSetup`, its
        plane and surface); none: a flat bed at z = 0.

    Returns
    -------
    BedCorrection or None
        None when no node inside the disk can be commanded.
    """
    x = np.linspace(-radius, radius, count)
    y = np.linspace(-radius, radius, count)
    X, Y = np.meshgrid(x, y)
    inside = X**2 + Y**2 <= radius**2 * (1 + 1e-9)
    # every node the firmware can reach (the corners too: the interpolation between the last
    # node inside and the first outside needs the surface there, not a copy)
    with np.errstate(all="ignore"):
        z = -_height_errors(fmt, params, machine, np.column_stack([X.ravel(), Y.ravel()]),
                            float(height), setups).reshape(X.shape)
    ok = np.isfinite(z)
    if not (ok & inside).any():
        return None
    for j in range(len(y)):                       # a row's ends: copies (Klipper's filler)
        cols = np.flatnonzero(ok[j])
        if not len(cols):
            continue
        z[j, :cols[0]] = z[j, cols[0]]
        z[j, cols[-1] + 1:] = z[j, cols[-1]]
        gaps = ~np.isfinite(z[j])
        if gaps.any():
            z[j, gaps] = np.interp(x[gaps], x[cols], z[j, cols])
    rows = np.flatnonzero(ok.any(axis=1))
    for j in range(len(y)):                       # rows outside: the nearest row inside
        if j not in rows:
            z[j] = z[rows[np.argmin(np.abs(rows - j))]]
    ok &= inside
    return BedCorrection(x, y, z, inside, float(radius),
                         float(np.sqrt(np.mean(z[ok] ** 2))))


def layer_errors(fmt, params, machine: Machine, radius: float,
                 correction: BedCorrection | None = None, layers=LAYERS,
                 n: int = 200, setups=None) -> list[dict]:
    """The nozzle's height error over the print disk at the bed and above it.

    Parameters
    ----------
    fmt, params, machine, radius
        As :func:`bed_correction`.
    correction : BedCorrection, optional
        A mesh the firmware applies (its value added to every commanded height, as Klipper
        does without fade).
    layers : sequence of float, optional
        Heights above the bed, m.
    n : int, optional
        Points per layer (a sunflower pattern on the disk).
    setups : Setups, optional
        As :func:`bed_correction`.

    Returns
    -------
    list of dict
        Per layer: ``height_mm``, ``rms_um``, ``max_um`` of the error, and with a
        correction ``mesh_rms_um`` / ``mesh_max_um``.
    """
    k = np.arange(n) + 0.5
    rho = radius * np.sqrt(k / n)
    phi = k * np.pi * (3.0 - np.sqrt(5.0))
    xy = np.column_stack([rho * np.cos(phi), rho * np.sin(phi)])
    out = []
    for h in layers:
        e = _height_errors(fmt, params, machine, xy, float(h), setups)
        ok = np.isfinite(e)
        row = {"height_mm": float(h) * 1e3, "points": int(ok.sum()),
               "rms_um": float(np.sqrt(np.mean(e[ok] ** 2))) * 1e6 if ok.any() else None,
               "max_um": float(np.max(np.abs(e[ok]))) * 1e6 if ok.any() else None}
        if correction is not None:
            m = e[ok] + correction.at(xy[ok])
            row["mesh_rms_um"] = float(np.sqrt(np.mean(m**2))) * 1e6 if ok.any() else None
            row["mesh_max_um"] = float(np.max(np.abs(m))) * 1e6 if ok.any() else None
        out.append(row)
    return out


# -- the firmwares' formats -----------------------------------------------------------------


def klipper_profile_lines(correction: BedCorrection, name: str = PROFILE) -> list[str]:
    """The profile as Klipper's SAVE_CONFIG writes it (``#*#`` lines, mm)."""
    mm = 1e3
    lines = [f"#*# [bed_mesh {name}]", "#*# version = 1", "#*# points ="]
    for row in correction.z:
        lines.append("#*# \t" + ", ".join(f"{v * mm:.6f}" for v in row))
    lines += [f"#*# min_x = {correction.x[0] * mm:.6f}",
              f"#*# max_x = {correction.x[-1] * mm:.6f}",
              f"#*# min_y = {correction.y[0] * mm:.6f}",
              f"#*# max_y = {correction.y[-1] * mm:.6f}",
              f"#*# x_count = {len(correction.x)}", f"#*# y_count = {len(correction.y)}",
              "#*# mesh_x_pps = 2", "#*# mesh_y_pps = 2", "#*# algo = bicubic",
              "#*# tension = 0.2"]
    return lines


#: the header of Klipper's SAVE_CONFIG block (``configfile.py``)
_BLOCK_HEADER = ("#*# <---------------------- SAVE_CONFIG ---------------------->",
                 "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.",
                 "#*#")


def with_klipper_profile(text: str, correction: BedCorrection, name: str = PROFILE) -> str:
    """``printer.cfg`` text with the profile in its SAVE_CONFIG block: a profile of that
    name replaced (only pkmcal's: the user's own profiles are kept), else appended.

    Parameters
    ----------
    text : str
        The file (as ``export`` updated it).
    correction : BedCorrection
        The mesh.
    name : str, optional
        The profile's name.

    Returns
    -------
    str
        The new text.
    """
    lines = text.splitlines()
    out, skip = [], False
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("#*# [") and stripped.endswith("]"):
            skip = stripped == f"#*# [bed_mesh {name}]"
        elif not stripped.startswith("#*#"):
            skip = False
        if not skip:
            out.append(line)
    while out and out[-1].strip() == "":
        out.pop()
    if not any(line.startswith("#*#") for line in out):
        out += ["", *_BLOCK_HEADER]
    elif out[-1].strip() == "#*#" and len(out) >= 2 and "DO NOT EDIT" not in out[-2]:
        out.pop()
    out += klipper_profile_lines(correction, name)
    return "\n".join(out) + "\n"


def marlin_mesh_gcode(correction: BedCorrection) -> str:
    """Marlin's bilinear / UBL mesh as ``M421 I<col> J<row> Z<mm>`` lines (``M421``: set a
    single mesh point; the grid must have the firmware's GRID_MAX_POINTS and probing area),
    then ``M500`` to save them."""
    lines = ["; pkmcal: the height the firmware's values leave at the bed (load with M420 S1)"]
    for j in range(len(correction.y)):
        for i in range(len(correction.x)):
            lines.append(f"M421 I{i} J{j} Z{correction.z[j, i] * 1e3:.4f}")
    lines.append("M500")
    return "\n".join(lines) + "\n"


def reprapfirmware_heightmap(correction: BedCorrection) -> str:
    """RepRapFirmware's ``heightmap.csv`` (``G29 S1`` loads it): the header line, the
    axis line (``axis0,axis1,min0,max0,min1,max1,radius,spacing0,spacing1,num0,num1``) and
    the rows by ascending y, mm."""
    c = correction
    spacing = (c.x[1] - c.x[0]) * 1e3
    head = ("RepRapFirmware height map file v2 generated by pkmcal export, mean error 0, "
            "deviation 0")
    axes = "axis0,axis1,min0,max0,min1,max1,radius,spacing0,spacing1,num0,num1"
    values = (f"X,Y,{c.x[0] * 1e3:.2f},{c.x[-1] * 1e3:.2f},{c.y[0] * 1e3:.2f},"
              f"{c.y[-1] * 1e3:.2f},{c.radius * 1e3:.2f},{spacing:.2f},{spacing:.2f},"
              f"{len(c.x)},{len(c.y)}")
    rows = [", ".join(f"{v * 1e3:7.3f}" if c.inside[j, i] else "      0"
                      for i, v in enumerate(c.z[j])) for j in range(len(c.y))]
    return "\n".join([head, axes, values, *rows]) + "\n"
