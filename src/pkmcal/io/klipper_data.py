"""What a Klipper printer saved about its own calibration, as pkmcal data: the
``[delta_calibrate]`` heights, manual heights and DELTA_ANALYZE distances, the bed meshes
read back into carriage travels with the values in force while probing, and several saved
configs as sessions (:func:`klipper_sessions`). The file itself is read as Klipper reads it
(:mod:`pkmcal.io.klipper_config`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .klipper_config import _SECTION, KlipperConfig, _read, split_autosave

#: the tower steppers of Klipper's delta kinematics, in tower order
TOWER_STEPPERS = ("stepper_a", "stepper_b", "stepper_c")


def _indexed(cfg: KlipperConfig, prefix: str, notes: list | None = None) -> list[int]:
    """Klipper's ``prefix0``, ``prefix1``, ... up to the first missing index (later ones,
    which Klipper does not read either, named in ``notes``)."""
    out = []
    opts = cfg.options("delta_calibrate")
    while f"{prefix}{len(out)}" in opts:
        out.append(len(out))
    later = sorted(int(k[len(prefix):]) for k in opts
                   if re.fullmatch(rf"{prefix}\d+", k) and int(k[len(prefix):]) > len(out))
    if later and notes is not None:
        notes.append(f"{cfg.path}: [delta_calibrate] {prefix}{len(out)} is missing: Klipper "
                     f"reads {prefix}0..{prefix}{len(out) - 1} and not "
                     + ", ".join(f"{prefix}{k}" for k in later[:5])
                     + (" ..." if len(later) > 5 else "") + "; neither does pkmcal")
    return out


def delta_calibrate_data(cfg: KlipperConfig, n_joints: int = 3, scale: float = 1.0) -> list:
    """The measurements Klipper saved in ``[delta_calibrate]``, as pkmcal data (SI).

    Read as ``klippy/extras/delta_calibrate.py`` restores them: ``heightN`` (the probe's
    ``z_offset`` at the trigger: the nozzle's height above the bed, mm) with ``heightN_pos``
    (the "stable position": steps each carriage moved down since its endstop), then
    ``manual_heightN`` / ``manual_heightN_pos`` (DELTA_ANALYZE MANUAL_HEIGHT), and
    ``distanceN`` with ``distanceN_pos1`` / ``distanceN_pos2`` (DELTA_ANALYZE distances, mm);
    each list up to its first missing index (what follows a gap is named in the data's
    ``notes``). Steps become carriage travel with each tower stepper's
    :meth:`KlipperConfig.step_distance`.

    Parameters
    ----------
    cfg : KlipperConfig
        The config.
    n_joints : int, optional
        The machine's joints (3).
    scale : float, optional
        The machine's size, m: heights, travels and distances beyond ten times it cannot be
        meant.

    Returns
    -------
    list of InstrumentData
        Probe heights (``kind="probe"``, source ``"<path> heights"``: saved heights then
        manual heights) and two-point distances (``kind="pair-distances"``, ``"<path>
        distances"``) when saved; their rows are the config's line numbers of
        ``heightN_pos`` / ``distanceN``; each with ``notes`` (list of str); empty without a
        ``[delta_calibrate]``.

    Raises
    ------
    InputError
        Naming file, line and option: a value that is not a number or cannot be meant, a
        position without three values, steps above the endstop, a missing position; a
        stepper without its step distance; a config of other kinematics.
    """
    from ..instruments import InstrumentData
    from ..instruments.pairs import pair_data

    if not cfg.has_section("delta_calibrate"):
        return []
    kin = cfg.entry("printer", "kinematics")
    if kin is not None and kin.value.strip().lower() != "delta":
        raise InputError(f"{kin.where('printer', 'kinematics')}: {kin.value.strip()!r}: the "
                         "[delta_calibrate] data of a delta printer (kinematics: delta) "
                         "are read")
    if n_joints != 3:
        raise InputError(f"{cfg.path}: Klipper's [delta_calibrate] data are for a three-tower "
                         f"delta; the machine has {n_joints} joints")
    notes: list[str] = []
    heights = [(f"height{i}", f"height{i}_pos") for i in _indexed(cfg, "height", notes)]
    heights += [(f"manual_height{i}", f"manual_height{i}_pos")
                for i in _indexed(cfg, "manual_height", notes)]
    distances = _indexed(cfg, "distance", notes)
    if not heights and not distances:
        return []
    step = np.array([cfg.step_distance(s) for s in TOWER_STEPPERS]) * 1e-3      # m / step
    limit = 10.0 * scale

    def value(key, above=None):
        v = cfg.number("delta_calibrate", key, above=above) * 1e-3
        if not abs(v) <= limit:
            e = cfg.entry("delta_calibrate", key)
            raise InputError(f"{e.where('delta_calibrate', key)}: {e.value}: {abs(v) * 1e3:.4g} "
                             f"mm cannot be meant on this machine (more than ten times its "
                             f"size, {limit * 1e3:.4g} mm)")
        return v

    def travel(key, owner):
        if cfg.entry("delta_calibrate", key) is None:
            e = cfg.entry("delta_calibrate", owner)
            raise InputError(f"{e.where('delta_calibrate', owner)}: has no {key} (the steps "
                             "of the three carriages there)")
        q = np.array(cfg.numbers("delta_calibrate", key, 3)) * step
        e = cfg.entry("delta_calibrate", key)
        if np.any(q < 0) or not np.all(np.abs(q) <= limit):
            raise InputError(f"{e.where('delta_calibrate', key)}: {e.value}: steps since each "
                             "endstop must be >= 0 (the carriage below its endstop) and the "
                             f"travel at most {limit * 1e3:.4g} mm (ten times the machine's "
                             "size)")
        return q

    out = []
    weights = (None, None)
    if heights and distances:
        weights = klipper_weights(len(_indexed(cfg, "height")), len(distances))
    if heights:
        h = np.array([value(key) for key, _ in heights])
        q = np.array([travel(pos, key) for key, pos in heights])
        rows = [cfg.entry("delta_calibrate", pos).line for _, pos in heights]
        data = InstrumentData("probe", q, h[:, None], None, np.array(rows),
                              f"{cfg.path} heights", weights=weights[0])
        data.notes = notes
        data.parameter_set = "klipper"     # without --parameters: the set Klipper fits
        out.append(data)
    if distances:
        d = np.array([value(f"distance{i}", above=0.0) for i in distances])
        qa = np.array([travel(f"distance{i}_pos1", f"distance{i}") for i in distances])
        qb = np.array([travel(f"distance{i}_pos2", f"distance{i}") for i in distances])
        rows = [cfg.entry("delta_calibrate", f"distance{i}").line for i in distances]
        pairs = pair_data(qa, qb, d, rows, f"{cfg.path} distances")
        pairs.weights = weights[1]
        pairs.notes = [] if heights else notes
        pairs.parameter_set = "klipper"
        out.append(pairs)
    return out


#: Klipper's weight of a distance against a height (``delta_calibrate.MEASURE_WEIGHT``)
MEASURE_WEIGHT = 0.5


def klipper_weights(n_probed: int, n_distances: int) -> tuple:
    """The relative weights of Klipper's ``DELTA_CALIBRATE`` with DELTA_ANALYZE distances.

    ``calculate_params`` minimises ``z_weight * sum(height errors^2) + sum(distance
    errors^2)`` with ``z_weight = n_distances / (MEASURE_WEIGHT * n_probed)`` (probed
    heights; manual heights are weighed but not counted): as noise levels, a height's
    standard deviation is ``1 / sqrt(z_weight)`` times a distance's. The levels below keep
    the probe's default for the heights; their common scale is estimated from the residuals
    (held levels: the covariance scaled by the residual variance).

    Parameters
    ----------
    n_probed : int
        Probed heights (``heightN``).
    n_distances : int
        Distances.

    Returns
    -------
    tuple
        ``((IsotropicNoise, words), (IsotropicNoise, words))`` for the heights and the
        distances.
    """
    from ..instruments import IsotropicNoise
    from ..instruments.probe import PROBE_SIGMA

    z_weight = n_distances / (MEASURE_WEIGHT * max(n_probed, 1))
    sigma_d = PROBE_SIGMA * float(np.sqrt(z_weight))
    words = (f"weighed as Klipper's DELTA_CALIBRATE weighs them (z_weight {z_weight:.3g}: a "
             f"height's std {1 / np.sqrt(z_weight):.3g} of a distance's), their common level "
             "from the residuals")
    return ((IsotropicNoise(PROBE_SIGMA), words), (IsotropicNoise(sigma_d), words))


def is_klipper_config(path, head: str) -> bool:
    """Whether a data file is a Klipper config: a ``.cfg`` name, or sections in its first
    lines (``[printer]``, ``[stepper_a]``, ``[delta_calibrate]``, ``[include ...]``)."""
    if str(path).lower().endswith(".cfg"):
        return True
    return bool(re.search(r"^\s*(#\*#\s*)?\[(printer|stepper_[a-z]|delta_calibrate|include )",
                          head, re.M))


def read_klipper_data(path, machine) -> list:
    """A Klipper config's saved calibration data for ``machine`` (:func:`delta_calibrate_data`).

    Raises
    ------
    InputError
        When the config has no saved heights or distances (naming what it looked for).
    """
    cfg = KlipperConfig.read(path)
    data = delta_calibrate_data(cfg, machine.n_joints, machine.characteristic_length())
    notes: list[str] = []
    if data and machine.n_joints == 3:
        meshes, notes = bed_mesh_data(cfg, machine.characteristic_length())
        data += meshes
    if not data:
        raise InputError(f"{path}: no saved calibration data: Klipper's [delta_calibrate] "
                         "section (in the body or the SAVE_CONFIG block) has no height0/"
                         "height0_pos, manual_height0 or distance0 (run DELTA_CALIBRATE and "
                         "SAVE_CONFIG on the printer first)"
                         + (f"; {cfg.ignored_block}" if cfg.ignored_block else ""))
    meshes = {}
    for note in notes:
        head, _, how = note.partition(": used, ")
        if not how:
            head, _, how = note.partition(": left out:")
            how = "left out:" + how
        meshes[head.replace(f"{cfg.path}: ", f"{Path(cfg.path).name} ", 1)] = how
    if cfg.ignored_block:
        notes.append(f"{path}: {cfg.ignored_block}")
    if notes:
        data[0].notes = list(getattr(data[0], "notes", [])) + notes
    if meshes:
        data[0].sessions = {"sessions": 1, "files": [str(path)], "reference": str(path),
                            "duplicates": {}, "repeated": {}, "meshes": meshes}
    return data


# --------------------------------------------------------------------------------------------
# the values in force and the bed meshes (issue 35: everything the printer saved is data)
# --------------------------------------------------------------------------------------------

#: the largest RMS (mm, mean removed) by which a bed mesh may differ from the DELTA_CALIBRATE
#: points saved beside it and still be taken as probed with the same values: five times the
#: probe's default repeatability; meshes and points of one session of real printers agree to
#: 0.006-0.03 mm, a mesh probed with other values differs by 0.19-1.3 mm
#: (``shared/data/printers/README.md``)
MESH_AGREEMENT = 0.05


@dataclass
class DeltaValues:
    """Klipper's linear-delta values in force (``klippy/kinematics/delta.py``
    ``DeltaCalibration``), in Klipper's units (mm, deg).

    Attributes
    ----------
    radius : float
        ``delta_radius``.
    angles, arms, endstops, steps : ndarray, shape (3,)
        Per tower ``angle``, ``arm_length``, ``position_endstop`` and the step distance.
    where : str
        Where they were read (for messages).
    """

    radius: float
    angles: np.ndarray
    arms: np.ndarray
    endstops: np.ndarray
    steps: np.ndarray
    where: str = ""

    def towers(self) -> np.ndarray:
        """The towers' (x, y), mm."""
        a = np.deg2rad(np.asarray(self.angles, float))
        return self.radius * np.column_stack([np.cos(a), np.sin(a)])

    def tops(self) -> np.ndarray:
        """Each carriage's height at its endstop (``abs_endstops``), mm."""
        return np.asarray(self.endstops) + np.sqrt(np.asarray(self.arms) ** 2 - self.radius ** 2)

    def travel(self, xyz) -> np.ndarray:
        """Carriage travel down from the endstops, mm, of nozzle positions (Klipper's
        ``calc_stable_position`` times the step distance); NaN where an arm cannot reach."""
        P = np.asarray(xyz, float).reshape(-1, 3)
        T = self.towers()
        with np.errstate(invalid="ignore"):
            h = P[:, 2:3] + np.sqrt(np.asarray(self.arms)[None] ** 2
                                    - (T[None, :, 0] - P[:, :1]) ** 2
                                    - (T[None, :, 1] - P[:, 1:2]) ** 2)
        return self.tops()[None] - h

    def position(self, travel) -> np.ndarray:
        """Nozzle positions, mm, of carriage travels (Klipper's ``get_position_from_stable``:
        the three spheres' intersection below the carriages); NaN where they do not meet."""
        t = np.asarray(travel, float).reshape(-1, 3)
        T = self.towers()
        C = np.concatenate([np.broadcast_to(T, (len(t), 3, 2)),
                            (self.tops()[None] - t)[..., None]], axis=-1)   # (K, 3, 3)
        r2 = np.asarray(self.arms, float) ** 2
        out = np.full((len(t), 3), np.nan)
        for k in range(len(t)):
            out[k] = _trilaterate(C[k], r2)
        return out

    def same(self, other: DeltaValues | None) -> bool:
        """The same geometry (as saved, ``%.6f``)."""
        return other is not None and all(
            np.allclose(np.ravel(getattr(self, n)), np.ravel(getattr(other, n)), rtol=0,
                        atol=5e-7) for n in ("radius", "angles", "arms", "endstops"))


def _trilaterate(C, r2) -> np.ndarray:
    """The point at squared distances ``r2`` from the rows of ``C`` with the lower z (the
    nozzle below the carriages)."""
    p1, p2, p3 = C
    ex = p2 - p1
    d = np.linalg.norm(ex)
    ex = ex / d
    i = ex @ (p3 - p1)
    ey = p3 - p1 - i * ex
    ey = ey / np.linalg.norm(ey)
    ez = np.cross(ex, ey)
    j = ey @ (p3 - p1)
    x = (r2[0] - r2[1] + d * d) / (2 * d)
    y = (r2[0] - r2[2] + i * i + j * j) / (2 * j) - i * x / j
    z2 = r2[0] - x * x - y * y
    if not z2 >= 0:
        return np.full(3, np.nan)
    p = p1 + x * ex + y * ey
    down = -ez if ez[2] > 0 else ez
    return p + math.sqrt(z2) * down


def delta_values(cfg: KlipperConfig) -> DeltaValues:
    """The linear-delta values a config puts in force (the body's over the block's).

    Raises
    ------
    InputError
        Naming file, line and option of a value that is missing or not a number.
    """
    radius = cfg.number("printer", "delta_radius", above=0.0)
    angles, arms, ends, steps = [], [], [], []
    for i, s in enumerate(TOWER_STEPPERS):
        angles.append(cfg.number(s, "angle", (210.0, 330.0, 90.0)[i]))
        arm = cfg.entry(s, "arm_length")
        arms.append(cfg.number(s, "arm_length", above=radius) if arm is not None
                    else cfg.number("stepper_a", "arm_length", above=radius))
        ends.append(cfg.number(s, "position_endstop") if cfg.entry(s, "position_endstop")
                    else cfg.number("stepper_a", "position_endstop"))
        steps.append(cfg.step_distance(s))
    return DeltaValues(radius, np.array(angles), np.array(arms), np.array(ends),
                       np.array(steps), cfg.path)


def commented_delta_values(cfg: KlipperConfig, text: str | None = None) -> DeltaValues | None:
    """The values the body's ``#``-commented geometry lines hold (``SAVE_CONFIG`` comments out
    the body's own lines when it first saves a value: the values before that calibration),
    completed by those in force; None when the body comments out no geometry."""
    text = _read(Path(cfg.path), "Klipper config") if text is None else text
    body, _, _, _ = split_autosave(text)
    found: dict = {}
    section = None
    for line in body.replace("\r\n", "\n").split("\n"):
        m = _SECTION.match(line.strip())
        if m:
            section = m.group("header").strip()
            continue
        m = re.match(r"\s*#\s*(delta_radius|angle|arm_length|position_endstop)\s*[:=]\s*"
                     r"([-+0-9.eE]+)\s*(#.*)?$", line)
        if m and section in ("printer",) + TOWER_STEPPERS:
            try:
                found[(section, m.group(1))] = float(m.group(2))
            except ValueError:
                continue
    if not found:
        return None
    now = delta_values(cfg)
    radius = found.get(("printer", "delta_radius"), now.radius)
    angles = [found.get((s, "angle"), now.angles[i]) for i, s in enumerate(TOWER_STEPPERS)]
    arms = [found.get((s, "arm_length"), found.get(("stepper_a", "arm_length"), now.arms[i]))
            for i, s in enumerate(TOWER_STEPPERS)]
    ends = [found.get((s, "position_endstop"), now.endstops[i])
            for i, s in enumerate(TOWER_STEPPERS)]
    old = DeltaValues(radius, np.array(angles, float), np.array(arms, float),
                      np.array(ends, float), now.steps, f"{cfg.path} (the body's commented-out "
                      "geometry lines)")
    return None if old.same(now) else old


#: the profile ``pkmcal export`` writes (:data:`pkmcal.export.bed_mesh.PROFILE`): never data
EXPORTED_PROFILE = "pkmcal"


@dataclass
class BedMesh:
    """A ``[bed_mesh NAME]`` profile as Klipper saved it (``bed_mesh.py`` ``save_profile``).

    Attributes
    ----------
    name : str
        The profile's name.
    x, y : ndarray
        The nodes' coordinates (the probe's x / y), mm: ``min + j (max - min) / (count - 1)``.
    z : ndarray, shape (len(y), len(x))
        The saved values, rows by ascending y, mm.
    probed : ndarray of bool, same shape
        The nodes probed (a round bed's row ends hold copies of the row's outermost probed
        value, Klipper's filler: not probed).
    params : dict
        The profile's other options (``mesh_x_pps``, ``algo``, ``tension``, ...), as text.
    line : int
        The config line of the profile's ``points``.
    rows_line : list of int
        The config line of each row of values.
    """

    name: str
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    probed: np.ndarray
    params: dict
    line: int
    rows_line: list

    @property
    def size(self) -> str:
        """``15x15, 149 probed``."""
        return f"{len(self.x)}x{len(self.y)}, {int(self.probed.sum())} probed"

    def at(self, xy) -> np.ndarray:
        """The saved grid interpolated bilinearly at (x, y), clamped to the mesh (Klipper's
        ``calc_z`` on the saved grid, without its upsampling)."""
        xy = np.asarray(xy, float).reshape(-1, 2)

        def index(c, nodes):
            n = len(nodes)
            if n == 1:
                return np.zeros(len(c), int), np.zeros(len(c))
            d = (nodes[-1] - nodes[0]) / (n - 1)
            i = np.clip(np.floor((c - nodes[0]) / d).astype(int), 0, n - 2)
            return i, np.clip((c - nodes[i]) / d, 0.0, 1.0)

        ix, tx = index(xy[:, 0], self.x)
        iy, ty = index(xy[:, 1], self.y)
        jx = np.minimum(ix + 1, len(self.x) - 1)
        jy = np.minimum(iy + 1, len(self.y) - 1)
        z0 = self.z[iy, ix] * (1 - tx) + self.z[iy, jx] * tx
        z1 = self.z[jy, ix] * (1 - tx) + self.z[jy, jx] * tx
        return z0 * (1 - ty) + z1 * ty


def _probed_nodes(z: np.ndarray) -> np.ndarray:
    """The nodes of a saved mesh that were probed: Klipper pads each row of a round bed on both
    sides with the same number of copies of its outermost probed values (``probe_finalize``),
    so the copies are the symmetric runs of equal values at the ends of a row (a row of one
    value: its middle node). FLSUN's firmware probes beyond ``mesh_radius``: the pattern, not
    the radius, decides."""
    out = np.ones(z.shape, bool)
    nx = z.shape[1]
    for r, row in enumerate(z):
        left = 1
        while left < nx and row[left] == row[0]:
            left += 1
        right = 1
        while right < nx and row[nx - 1 - right] == row[-1]:
            right += 1
        if left == nx:
            pad = (nx - 1) // 2
        else:
            pad = min(left, right) - 1
        if pad:
            out[r, :pad] = False
            out[r, nx - pad:] = False
    return out


def bed_meshes(cfg: KlipperConfig) -> list[BedMesh]:
    """The ``[bed_mesh NAME]`` profiles of a config (as Klipper loads them: the body's over
    the block's), in file order.

    Raises
    ------
    InputError
        Naming file, line and option: a profile without ``points`` or whose rows, counts or
        extent do not match (``x_count`` values a row, ``y_count`` rows, ``min < max``).
    """
    out = []
    for section in list(cfg.body) + [s for s in cfg.autosave if s not in cfg.body]:
        if not section.startswith("bed_mesh ") or not section[9:].strip():
            continue
        name = section[9:].strip()
        e = cfg.entry(section, "points")
        if e is None:
            raise InputError(f"{cfg.path}: [{section}]: no points")
        lines = ([e.value] if e.value.strip() else []) + list(e.more)
        rows, rows_line = [], []
        for k, text in enumerate(lines):
            if not text.strip():
                continue
            try:
                rows.append([float(v) for v in text.replace(",", " ").split()])
            except ValueError:
                raise InputError(f"{e.file}: line {e.line + k + (0 if e.value.strip() else 1)}"
                                 f": [{section}] points: {text.strip()!r}: numbers separated "
                                 "by commas expected") from None
            rows_line.append(e.line + k + (0 if e.value.strip() else 1))
        nx = int(cfg.number(section, "x_count", above=0.0))
        ny = int(cfg.number(section, "y_count", above=0.0))
        if len(rows) != ny or any(len(r) != nx for r in rows) or nx < 2 or ny < 2:
            raise InputError(f"{e.where(section, 'points')}: {len(rows)} row(s) of "
                             f"{sorted({len(r) for r in rows})} value(s); x_count {nx}, "
                             f"y_count {ny} expected (at least 2 each)")
        z = np.array(rows, float)
        ext = {k: cfg.number(section, k) for k in ("min_x", "max_x", "min_y", "max_y")}
        if not (ext["min_x"] < ext["max_x"] and ext["min_y"] < ext["max_y"]) \
                or not np.all(np.isfinite(z)):
            raise InputError(f"{e.where(section, 'points')}: the extent min_x {ext['min_x']:g}"
                             f" max_x {ext['max_x']:g} min_y {ext['min_y']:g} max_y "
                             f"{ext['max_y']:g} is empty, or a value is not finite")
        x = ext["min_x"] + np.arange(nx) * (ext["max_x"] - ext["min_x"]) / (nx - 1)
        y = ext["min_y"] + np.arange(ny) * (ext["max_y"] - ext["min_y"]) / (ny - 1)
        params = {k: v.value for k, v in cfg.options(section).items() if k != "points"}
        out.append(BedMesh(name, x, y, z, _probed_nodes(z), params, e.line, rows_line))
    return out


def probe_offsets(cfg: KlipperConfig) -> tuple[float, float, float]:
    """``[probe]`` (or ``[bltouch]`` ...) ``x_offset, y_offset, z_offset``, mm (0 when
    absent)."""
    for section in ("probe", "bltouch", "smart_effector", "probe_eddy_current", "beacon",
                    "cartographer"):
        if cfg.has_section(section):
            return tuple(cfg.number(section, k, 0.0) for k in ("x_offset", "y_offset",
                                                                 "z_offset"))
    return (0.0, 0.0, 0.0)


def dc_bed_heights(cfg: KlipperConfig, values: DeltaValues):
    """The bed's height (mm) under ``values`` at the probe's x/y of each saved DELTA_CALIBRATE
    point: ``(xy (K, 2), z (K,))``; None without saved heights.

    The nozzle's position at a trigger follows from the saved stable position; the probe
    touched at nozzle + probe offset, ``heightN`` below the nozzle."""
    idx = _indexed(cfg, "height")
    if not idx:
        return None
    steps = np.array([cfg.numbers("delta_calibrate", f"height{i}_pos", 3) for i in idx])
    h = np.array([cfg.number("delta_calibrate", f"height{i}") for i in idx])
    P = values.position(steps * values.steps)
    dx, dy, _ = probe_offsets(cfg)
    return P[:, :2] + [dx, dy], P[:, 2] - h


def mesh_agreement(cfg: KlipperConfig, mesh: BedMesh, values: DeltaValues) -> float | None:
    """RMS (mm, the mean removed) of the mesh against the bed heights of the saved
    DELTA_CALIBRATE points under ``values`` (the mesh interpolated at the points' probe x/y);
    None without points."""
    found = dc_bed_heights(cfg, values)
    if found is None:
        return None
    xy, z = found
    d = z - mesh.at(xy)
    d = d[np.isfinite(d)]
    if not len(d):
        return None
    return float(np.sqrt(np.mean((d - d.mean()) ** 2)))


def mesh_travels(mesh: BedMesh, values: DeltaValues, offsets) -> tuple[np.ndarray, np.ndarray]:
    """Carriage travels (mm) at the triggers of a mesh's probed nodes, recovered with the
    values in force while probing (``bed_mesh.py`` ``probe_finalize``: a value is the toolhead
    z at the trigger minus ``z_offset`` and a reference; the nozzle stood at the node minus the
    probe's x/y offset).

    Returns
    -------
    travel : ndarray, shape (K, 3)
        mm, rows by ascending y, each by ascending x.
    index : ndarray, shape (K, 2)
        The nodes' (row, column).
    """
    dx, dy, dz = offsets
    iy, ix = np.nonzero(mesh.probed)
    nozzle = np.column_stack([mesh.x[ix] - dx, mesh.y[iy] - dy, mesh.z[iy, ix] + dz])
    return values.travel(nozzle), np.column_stack([iy, ix])


def bed_mesh_data(cfg: KlipperConfig, scale: float = 1.0, previous: DeltaValues | None = None,
                  text: str | None = None):
    """The bed meshes of a config as probe heights (pkmcal data), and why any was left out.

    Each probed node becomes one row: the carriages' travels at the trigger, recovered with
    the values in force while probing (:func:`mesh_travels`), and the probe's ``z_offset`` as
    the nozzle's height above the bed there. A mesh's absolute level is not kept
    (``zero_reference_position`` / ``relative_reference_index``): each mesh has its own free
    height offset (``free_height``). Which values were in force: a mesh that agrees with the
    DELTA_CALIBRATE points saved beside it (:func:`mesh_agreement` at most
    :data:`MESH_AGREEMENT`) was probed with the saved values; one that agrees only under the
    previous values (``previous``, else the body's commented-out lines:
    :func:`commented_delta_values`) was probed with those (saved in the same ``SAVE_CONFIG`` as
    new values) and is read with them; one that agrees with neither is left out, named.

    Parameters
    ----------
    cfg : KlipperConfig
        The config.
    scale : float, optional
        The machine's size, m (travels beyond ten times it are refused).
    previous : DeltaValues, optional
        The values in force before this config's (an earlier session's file).
    text : str, optional
        The config's text when read already.

    Returns
    -------
    data : list of InstrumentData
        ``kind="probe"``, source ``"<path> mesh NAME"``, ``free_height = True``,
        ``mesh`` (the :class:`BedMesh`), ``values_in_force`` (:class:`DeltaValues`); rows are
        the config lines of the mesh's rows.
    notes : list of str
        One line per mesh: used (and with which values) or left out and why.
    """
    from ..instruments import InstrumentData

    meshes = bed_meshes(cfg)
    if not meshes:
        return [], []
    now = delta_values(cfg)
    old = previous if previous is not None and not previous.same(now) else None
    if old is None:
        try:
            old = commented_delta_values(cfg, text)
        except InputError:
            old = None
    offsets = probe_offsets(cfg)
    data, notes = [], []
    for mesh in meshes:
        label = f"{cfg.path}: [bed_mesh {mesh.name}] ({mesh.size})"
        if mesh.name == EXPORTED_PROFILE:
            notes.append(f"{label}: left out: pkmcal export's correction for what the "
                         "firmware's values cannot hold, not a probed mesh")
            continue
        agree = mesh_agreement(cfg, mesh, now)
        before = mesh_agreement(cfg, mesh, old) if old is not None else None
        used = now
        if agree is None:
            how = "no DELTA_CALIBRATE points beside it to test which values were in force: " \
                  "read with the saved values"
        elif agree <= MESH_AGREEMENT and (before is None or agree <= before):
            how = (f"agrees with the saved DELTA_CALIBRATE points to {agree:.3f} mm"
                   + (f" ({before:.3f} mm under the previous values)" if before is not None
                      else "") + ": probed with the saved values")
        elif before is not None and before <= MESH_AGREEMENT:
            used = old
            how = (f"agrees with the saved points only under the previous values ({before:.3f}"
                   f" mm, {agree:.3f} mm under the saved ones): probed before the SAVE_CONFIG "
                   f"that saved the new values; read with the previous values ({old.where})")
        else:
            notes.append(f"{label}: left out: it differs from the DELTA_CALIBRATE points saved "
                         f"beside it by {agree:.3f} mm RMS (more than {MESH_AGREEMENT:g} mm"
                         + (f"; {before:.3f} mm under the previous values" if before is not None
                            else "; the previous values are not known")
                         + "): probed with other values than these (saved in the same "
                         "SAVE_CONFIG as new delta values?) or the printer changed since")
            continue
        travel, index = mesh_travels(mesh, used, offsets)
        q = travel * 1e-3
        bad = ~np.all(np.isfinite(q), axis=1) | np.any(q < 0, axis=1) \
            | np.any(np.abs(q) > 10 * scale, axis=1)
        if bad.all():
            notes.append(f"{label}: left out: its points cannot be reached with the values in "
                         "force")
            continue
        rows = np.array([mesh.rows_line[i] for i in index[:, 0]])
        d = InstrumentData("probe", q[~bad], np.full((int((~bad).sum()), 1), offsets[2] * 1e-3),
                           None, rows[~bad], f"{cfg.path} mesh {mesh.name}")
        d.free_height = True
        d.mesh = mesh
        d.values_in_force = used
        d.parameter_set = "klipper"
        d.notes = []
        data.append(d)
        notes.append(f"{label}: used, {int((~bad).sum())} probed points (its own height "
                     f"offset: the mesh's reference); {how}")
    return data, notes


_STAMP = re.compile(r"-(\d{8}_\d{6})(?:_\d+)?(?:\.[^.]*)?$")


def _data_key(d) -> tuple:
    """What one saved data set holds (the same points in two files are one session)."""
    return (d.kind, np.round(np.asarray(d.q, float), 12).tobytes(),
            np.round(np.asarray(d.values, float), 12).tobytes())


def _session_key(path, dc) -> tuple:
    """A file's session: its DELTA_CALIBRATE heights (DELTA_ANALYZE reuses them with new
    distances: one session), else its distances, else the file itself."""
    if dc:              # delta_calibrate_data gives the heights first, when saved
        return _data_key(dc[0])
    return ("file", str(path))


def _mesh_key(mesh: BedMesh) -> tuple:
    return (mesh.name, mesh.z.tobytes(), tuple(mesh.x), tuple(mesh.y))


@dataclass
class Sessions:
    """Several Klipper configs (``printer.cfg`` and its backups) as calibration sessions.

    Attributes
    ----------
    data : list
        The data objects (``session``: the session's name, None for the reference session,
        the newest, whose values the export updates).
    notes : list of str
        What was read, counted once, used or left out, and why.
    summary : dict
        ``sessions`` (count), ``files``, ``duplicates`` ({file: the file whose saved points
        it repeats}), ``repeated`` ({file: what it repeats, in words}), ``meshes``
        ({mesh: used / left out and why}), ``reference``.
    """

    data: list
    notes: list
    summary: dict


def klipper_sessions(paths, machine) -> Sessions:
    """Klipper configs as sessions (SPEC 9): the same saved DELTA_CALIBRATE points counted
    once; each session's DC points and the meshes probed with its values; each session but
    the newest with its own endstop offsets (the joint fit's reading offsets).

    Files are ordered by the date in Klipper's backup names (``printer-YYYYMMDD_HHMMSS.cfg``,
    the file just before the ``SAVE_CONFIG`` at that time); others come after them in the
    order given (the current ``printer.cfg`` is the newest). A mesh is tested against the
    values of its own file and of the file before it (:func:`bed_mesh_data`).

    Parameters
    ----------
    paths : sequence of path
        The configs.
    machine : Machine
        The machine (its joints and size).

    Returns
    -------
    Sessions
        The data, notes and summary (the heights of every session but the reference have
        their own height offset, ``free_height``: that session's probe ``z_offset``).

    Raises
    ------
    InputError
        Naming the file: one without saved points or meshes, or a value Klipper would refuse.
    """
    paths = [Path(p) for p in paths]
    order = sorted(range(len(paths)), key=lambda i: (
        (0, _STAMP.search(paths[i].name).group(1), i) if _STAMP.search(paths[i].name)
        else (1, "", i)))
    read = []
    for i in order:
        cfg = KlipperConfig.read(paths[i])
        dc = delta_calibrate_data(cfg, machine.n_joints, machine.characteristic_length())
        read.append((paths[i], cfg, dc))
    groups: dict = {}
    for path, cfg, dc in read:
        groups.setdefault(_session_key(path, dc), []).append(path)
    newest = read[-1][0]
    data, notes, meshes = [], [], {}
    seen: dict = {}
    duplicates: dict = {}
    repeated: dict = {}
    history: list = []
    names = {}
    for key, members in groups.items():
        names[key] = members[0].name if members[0].name not in names.values() \
            else str(members[0])
    reference = next(k for k, m in groups.items() if newest in m)
    for path, cfg, dc in read:
        key = _session_key(path, dc)
        session = None if key == reference else names[key]
        try:
            values = delta_values(cfg)
        except InputError:
            values = None
        for d in dc:
            k = _data_key(d)
            if k in seen:
                duplicates.setdefault(str(path), seen[k])
                repeated.setdefault(str(path), []).append(
                    f"its {d.source.rsplit(' ', 1)[-1]} are {Path(seen[k]).name}'s")
                continue
            seen[k] = str(path)
            d.session = session
            # its own probe z_offset: the heights of a session other than the reference are
            # as high as that session's z_offset said (a re-measured z_offset moves them all)
            d.free_height = session is not None
            data.append(d)
        previous = None if values is None else next(
            (v for v in reversed(history) if not v.same(values)), None)
        found, mesh_notes = bed_mesh_data(cfg, machine.characteristic_length(), previous)
        for d, note in zip(found, [n for n in mesh_notes if ": used," in n], strict=False):
            k = _mesh_key(d.mesh)
            if k in seen:
                continue
            seen[k] = str(path)
            d.session = session
            data.append(d)
            meshes[f"{path.name} [bed_mesh {d.mesh.name}]"] = note.split(": used, ", 1)[1]
        for note in mesh_notes:
            if ": left out:" in note:
                meshes[note.split(": left out:")[0]] = "left out:" + note.split(": left out:")[1]
                notes.append(note)
        if values is not None:
            history.append(values)
    if not data:
        raise InputError(f"{', '.join(map(str, paths))}: no saved calibration data: no "
                         "[delta_calibrate] points and no [bed_mesh NAME] profile")
    n = len(groups)
    for dup, of in duplicates.items():
        notes.append(f"{dup}: {' and '.join(repeated[dup])} (the same saved points: counted "
                     "once)")
    summary = {"sessions": n, "files": [str(p) for p, _, _ in read],
               "reference": str(newest),
               "duplicates": duplicates, "repeated": repeated, "meshes": meshes}
    if n > 1:
        notes.append(f"{len(paths)} Klipper configs: {n} sessions (the newest, "
                     f"{newest.name}, the reference; each other with its own endstop offsets, "
                     f"{machine.n_joints} unknowns each)"
                     + (f"; {len(duplicates)} file(s) repeat an earlier file's points"
                        if duplicates else ""))
    else:
        notes += [f"{k}: {v}" for k, v in meshes.items() if not v.startswith("left out")]
    for d in data:
        d.notes = []
    data[0].notes = notes
    data[0].sessions = summary
    return Sessions(data, notes, summary)
