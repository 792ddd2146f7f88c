"""An independent reference for Klipper's linear-delta calibration, for testing pkmcal.

Written from a reading of Klipper's sources (``klippy/configfile.py``, ``klippy/stepper.py``,
``klippy/kinematics/delta.py``, ``klippy/mathutil.py``, ``klippy/extras/delta_calibrate.py``,
upstream commit 84104bbbd7625d28b4eaaad83f4562972460ecd9).  Nothing here is copied from Klipper
(GPL); it re-states the same arithmetic in plain Python/numpy.  It deliberately does not import
pkmcal, so it can be used as an oracle.

What it covers:

* :func:`read_klipper_config` - a ``printer.cfg`` read the way Klipper reads it: ``#`` cuts a
  line anywhere, ``;`` is a comment at the start of a line or after whitespace, ``[include x]``
  is resolved relative to the including file (glob, sorted, applied in place), and the
  ``#*# SAVE_CONFIG`` block only *adds* options: any option that the main body (with its
  includes) defines wins over the same option in the block.
* :func:`step_distance` - a stepper's step distance as ``stepper.py`` derives it.
* :class:`DeltaCalibration` - towers, absolute endstops, stable position <-> cartesian.
* :func:`coordinate_descent` - Klipper's ``mathutil.coordinate_descent`` step rule.
* :func:`delta_calibrate` - ``DELTA_CALIBRATE`` / ``DELTA_ANALYZE CALIBRATE=extended``:
  the error function with probed heights, manual heights and distances.
* :func:`height_residuals` / :func:`distance_residuals` - any parameter values evaluated through
  Klipper's kinematics on the saved stable positions.

Run ``python tests/klipper_reference.py [files...]`` for the RMS table over
``../shared/data/printers/klipper_saved/*.cfg`` (beside the repository).
"""

from __future__ import annotations

import configparser
import glob
import math
import os
import re
import sys
from dataclasses import dataclass, field

import numpy as np

# ----------------------------------------------------------------------------------------------
# Config file reading (klippy/configfile.py)
# ----------------------------------------------------------------------------------------------

AUTOSAVE_HEADER = (
    "\n#*# <---------------------- SAVE_CONFIG ---------------------->\n"
    "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.\n"
    "#*#\n"
)


class KlipperConfigError(ValueError):
    """A config problem that would make Klipper refuse to start."""


def _new_parser() -> configparser.RawConfigParser:
    # Klipper: duplicated sections/options allowed (the later wins); ';' and '#' inline comments
    return configparser.RawConfigParser(strict=False, inline_comment_prefixes=(";", "#"))


def _cut_hash_comments(text: str) -> str:
    # Klipper cuts every line at its first '#', wherever it is (even inside a value)
    return "\n".join(line.split("#", 1)[0] for line in text.split("\n"))


def split_autosave(data: str) -> tuple[str, str]:
    """Return ``(regular_text, autosave_text)``, the latter without its ``#*# `` prefixes.

    Like Klipper, an autosave block that looks tampered with (a ``#*# `` line in the body, a
    second header, or a line after the header that does not start with ``#*# ``) is ignored
    entirely: the whole file is then the body and every ``#*#`` line is just a comment.
    """
    data = data.replace("\r\n", "\n")
    pos = data.find(AUTOSAVE_HEADER)
    if pos < 0:
        regular, block = data, ""
    else:
        regular, block = data[:pos], data[pos + len(AUTOSAVE_HEADER) :].strip()
    if "\n#*# " in regular or AUTOSAVE_HEADER in block:
        return data, ""
    lines = []
    for line in block.split("\n"):
        if block and (not line.startswith("#*#") or (len(line) >= 4 and line[3] != " ")):
            return data, ""
        lines.append(line[4:])
    return regular, "\n".join([""] + lines + [""])


def _parse_with_includes(text, filename, parser, visited):
    path = os.path.abspath(filename)
    if path in visited:
        raise KlipperConfigError(f"recursive include of {filename}")
    visited.add(path)
    pending: list[str] = []

    def flush():
        chunk = _cut_hash_comments("\n".join(pending))
        if chunk.strip():
            parser.read_string(chunk, filename)
        pending.clear()

    for raw in text.split("\n"):
        line = raw.split("#", 1)[0]
        match = configparser.RawConfigParser.SECTCRE.match(line)
        header = match.group("header") if match else None
        if header is not None and header.startswith("include "):
            flush()  # everything before the include applies first, then the include, in place
            spec = header[len("include ") :].strip()
            pattern = os.path.join(os.path.dirname(filename), spec)
            names = sorted(glob.glob(pattern))
            if not names and not glob.has_magic(pattern):
                raise KlipperConfigError(f"include file {pattern!r} does not exist")
            for name in names:
                with open(name, encoding="utf-8") as handle:
                    sub = handle.read().replace("\r\n", "\n")
                _parse_with_includes(sub, name, parser, visited)
        else:
            pending.append(line)
    flush()
    visited.discard(path)


_OPTION_NAME = re.compile("[A-Za-z0-9_]*")


def _drop_duplicated_options(autosave: str, regular: configparser.RawConfigParser) -> str:
    # Klipper comments out every autosave option (with its continuation lines) that the body
    # defines: the body wins.  Option names compare case-insensitively, section names exactly.
    out, section, dropping = [], None, False
    for line in autosave.split("\n"):
        bare = line.split("#", 1)[0].split(";", 1)[0].rstrip()
        if not bare:
            out.append(line)
            continue
        if bare[0].isspace():
            out.append("#" + line if dropping else line)
            continue
        dropping = False
        if bare[0] == "[":
            section = bare[1:-1].strip()
            out.append(line)
            continue
        option = _OPTION_NAME.match(bare).group(0)
        if section is not None and regular.has_option(section, option):
            dropping = True
            out.append("#" + line)
        else:
            out.append(line)
    return "\n".join(out)


@dataclass
class KlipperConfig:
    """The effective config (``sections``) plus what came from where."""

    sections: dict[str, dict[str, str]]
    body: dict[str, dict[str, str]]
    autosave: dict[str, dict[str, str]]
    overridden: list[tuple[str, str, str, str]] = field(default_factory=list)
    """``(section, option, body_value, ignored_autosave_value)`` where the body won."""

    def get(self, section, option, default=None):
        return self.sections.get(section, {}).get(option.lower(), default)

    def getfloat(self, section, option, default=None):
        value = self.get(section, option)
        return default if value is None else float(value)


def _as_dict(parser):
    return {s: dict(parser.items(s)) for s in parser.sections()}


def read_klipper_config(path: str | None = None, *, text: str | None = None) -> KlipperConfig:
    """Read a ``printer.cfg`` with Klipper's precedence rules (see module docstring)."""
    if text is None:
        with open(path, encoding="utf-8") as handle:
            text = handle.read()
    filename = path or "printer.cfg"
    regular_text, autosave_text = split_autosave(text)
    body = _new_parser()
    _parse_with_includes(regular_text, filename, body, set())
    autosave_all = _new_parser()
    autosave_all.read_string(_cut_hash_comments(autosave_text), "*AUTOSAVE*")
    kept = _drop_duplicated_options(autosave_text, body)
    body_dict = _as_dict(body)
    effective = _new_parser()
    effective.read_dict(body_dict)
    effective.read_string(_cut_hash_comments(kept), "*AUTOSAVE*")
    overridden = []
    for section in autosave_all.sections():
        for option, value in autosave_all.items(section):
            if body.has_option(section, option):
                overridden.append((section, option, body.get(section, option), value))
    return KlipperConfig(_as_dict(effective), body_dict, _as_dict(autosave_all), overridden)


# ----------------------------------------------------------------------------------------------
# Step distance (klippy/stepper.py: parse_step_distance, parse_gear_ratio, MCU_stepper)
# ----------------------------------------------------------------------------------------------


def gear_ratio_factor(text: str | None) -> float:
    """``"80:16, 60:16"`` -> 80/16 * 60/16; absent -> 1."""
    result = 1.0
    if text is None or not text.strip():
        return result
    for pair in text.split(","):
        parts = [p.strip() for p in pair.split(":")]
        if len(parts) != 2:
            raise KlipperConfigError(f"bad gear_ratio {text!r}")
        result *= float(parts[0]) / float(parts[1])
    return result


def step_distance(options: dict[str, str]) -> float:
    """The step distance (mm/step) of a linear-delta stepper section.

    Current Klipper: ``rotation_distance / (full_steps_per_rotation * microsteps * gearing)``,
    ``full_steps_per_rotation`` defaulting to 200 and required to be a multiple of 4; the
    delta rails never use radians, so ``rotation_distance`` is required.  Klipper before
    2021-10-24 (commit eea0137bf) also accepted a plain ``step_distance`` when no
    ``rotation_distance`` was given; that is honoured here for old configs.
    """
    rd = options.get("rotation_distance")
    if rd is None:
        if options.get("step_distance") is not None:
            return float(options["step_distance"])
        raise KlipperConfigError("rotation_distance missing")
    rotation = float(rd)
    if not rotation > 0:
        raise KlipperConfigError("rotation_distance must be above 0")
    microsteps = int(options["microsteps"])
    full_steps = int(options.get("full_steps_per_rotation", "200"))
    if microsteps < 1 or full_steps < 1 or full_steps % 4:
        raise KlipperConfigError("bad microsteps/full_steps_per_rotation")
    return rotation / (full_steps * microsteps * gear_ratio_factor(options.get("gear_ratio")))


# ----------------------------------------------------------------------------------------------
# Trilateration (klippy/mathutil.py) - vectorised over points, same operation order
# ----------------------------------------------------------------------------------------------


def _trilaterate(c1, c2, c3, r2):
    """Lower intersection of three spheres (centres ``c*`` as (x, y, z) arrays, radii^2 ``r2``).

    Follows the textbook (Wikipedia) construction with the same operation order as Klipper so
    that the result is bit-for-bit identical; returns ``(x, y, z)`` arrays (NaN where the
    spheres do not meet).
    """
    s21 = [c2[k] - c1[k] for k in range(3)]
    s31 = [c3[k] - c1[k] for k in range(3)]
    d = np.sqrt(s21[0] ** 2 + s21[1] ** 2 + s21[2] ** 2)
    inv_d = 1.0 / d
    ex = [s * inv_d for s in s21]
    i = ex[0] * s31[0] + ex[1] * s31[1] + ex[2] * s31[2]
    vey = [s31[k] - ex[k] * i for k in range(3)]
    inv_n = 1.0 / np.sqrt(vey[0] ** 2 + vey[1] ** 2 + vey[2] ** 2)
    ey = [v * inv_n for v in vey]
    ez = [
        ex[1] * ey[2] - ex[2] * ey[1],
        ex[2] * ey[0] - ex[0] * ey[2],
        ex[0] * ey[1] - ex[1] * ey[0],
    ]
    j = ey[0] * s31[0] + ey[1] * s31[1] + ey[2] * s31[2]
    x = (r2[0] - r2[1] + d**2) / (2.0 * d)
    y = (r2[0] - r2[2] - x**2 + (x - i) ** 2 + j**2) / (2.0 * j)
    with np.errstate(invalid="ignore"):
        z = -np.sqrt(r2[0] - x**2 - y**2)
    return tuple(c1[k] + (ex[k] * x + (ey[k] * y + ez[k] * z)) for k in range(3))


# ----------------------------------------------------------------------------------------------
# Delta geometry (klippy/kinematics/delta.py: DeltaCalibration)
# ----------------------------------------------------------------------------------------------

AXES = "abc"
DEFAULT_ANGLES = (210.0, 330.0, 90.0)


class DeltaCalibration:
    """Klipper's delta calibration state: radius, tower angles, arms, endstops, step distances."""

    def __init__(self, radius, angles, arms, endstops, stepdists):
        self.radius = float(radius)
        self.angles = [float(a) for a in angles]
        self.arms = [float(a) for a in arms]
        self.endstops = [float(e) for e in endstops]
        self.stepdists = [float(s) for s in stepdists]
        self.towers = []
        for angle in self.angles:
            rad = math.radians(angle)
            self.towers.append((math.cos(rad) * self.radius, math.sin(rad) * self.radius))
        r2 = self.radius**2
        # carriage height when the effector is at (0, 0, 0) plus the endstop position
        self.abs_endstops = [
            e + math.sqrt(a**2 - r2) for e, a in zip(self.endstops, self.arms, strict=True)
        ]

    # --- parameter dictionaries as used by the coordinate descent --------------------------
    def coordinate_descent_params(self, is_extended):
        adjust = ("radius", "angle_a", "angle_b", "endstop_a", "endstop_b", "endstop_c")
        if is_extended:
            adjust += ("arm_a", "arm_b", "arm_c")
        params = {"radius": self.radius}
        for k, axis in enumerate(AXES):
            params["angle_" + axis] = self.angles[k]
            params["arm_" + axis] = self.arms[k]
            params["endstop_" + axis] = self.endstops[k]
            params["stepdist_" + axis] = self.stepdists[k]
        return adjust, params

    def new_calibration(self, params):
        return DeltaCalibration(
            params["radius"],
            [params["angle_" + a] for a in AXES],
            [params["arm_" + a] for a in AXES],
            [params["endstop_" + a] for a in AXES],
            [params["stepdist_" + a] for a in AXES],
        )

    def as_params(self):
        return self.coordinate_descent_params(True)[1]

    # --- kinematics ------------------------------------------------------------------------
    def positions_from_stable(self, stable):
        """Cartesian positions (n x 3) of stable positions (n x 3 steps since the endstop)."""
        s = np.asarray(stable, dtype=float).reshape(-1, 3)
        centres = []
        for k in range(3):
            tz = self.abs_endstops[k] - s[:, k] * self.stepdists[k]
            tx = np.full_like(tz, self.towers[k][0])
            ty = np.full_like(tz, self.towers[k][1])
            centres.append((tx, ty, tz))
        x, y, z = _trilaterate(*centres, [a**2 for a in self.arms])
        return np.column_stack([x, y, z])

    def get_position_from_stable(self, stable_position):
        pos = self.positions_from_stable([stable_position])[0]
        if np.isnan(pos).any():
            raise ValueError("math domain error")
        return [float(v) for v in pos]

    def calc_stable_position(self, coord):
        out = []
        for k in range(3):
            tx, ty = self.towers[k]
            carriage = (
                math.sqrt(self.arms[k] ** 2 - (tx - coord[0]) ** 2 - (ty - coord[1]) ** 2)
                + coord[2]
            )
            out.append((self.abs_endstops[k] - carriage) / self.stepdists[k])
        return out

    def __repr__(self):
        return (
            f"DeltaCalibration(radius={self.radius!r}, angles={self.angles!r}, "
            f"arms={self.arms!r}, endstops={self.endstops!r}, stepdists={self.stepdists!r})"
        )


def delta_from_config(config: KlipperConfig) -> DeltaCalibration:
    """The calibration Klipper's ``DeltaKinematics.get_calibration`` would return."""
    sections = [config.sections.get("stepper_" + a, {}) for a in AXES]
    radius = float(config.sections["printer"]["delta_radius"])
    arm_a = float(sections[0]["arm_length"])
    arms = [float(s.get("arm_length", arm_a)) for s in sections]
    end_a = float(sections[0]["position_endstop"])
    endstops = [float(s.get("position_endstop", end_a)) for s in sections]
    angles = [float(s.get("angle", d)) for s, d in zip(sections, DEFAULT_ANGLES, strict=True)]
    stepdists = [step_distance(s) for s in sections]
    for arm in arms:
        if not arm > radius:
            raise KlipperConfigError("arm_length must be above delta_radius")
    return DeltaCalibration(radius, angles, arms, endstops, stepdists)


# ----------------------------------------------------------------------------------------------
# Saved calibration data (klippy/extras/delta_calibrate.py)
# ----------------------------------------------------------------------------------------------

MEASURE_WEIGHT = 0.5  # how much a distance counts against a height
MEASURE_ANGLES = (210.0, 270.0, 330.0, 30.0, 90.0, 150.0)
MEASURE_OUTER_RADIUS = 65.0
MEASURE_RIDGE_RADIUS = 5.0 - 0.5


@dataclass
class CalibrationData:
    """Saved ``[delta_calibrate]`` points: (height, stable), (height, stable), (dist, s1, s2)."""

    probe_heights: list = field(default_factory=list)
    manual_heights: list = field(default_factory=list)
    distances: list = field(default_factory=list)
    stepdists: list | None = None


def _floats3(text):
    values = [float(v) for v in text.split(",")]
    if len(values) != 3:
        raise KlipperConfigError(f"expected 3 values, got {text!r}")
    return values


def calibration_data_from_config(config: KlipperConfig, stepdists=None) -> CalibrationData:
    """Read ``heightN``/``manual_heightN``/``distanceN`` like Klipper: stop at the first gap."""
    sec = config.sections.get("delta_calibrate", {})
    data = CalibrationData(stepdists=list(stepdists) if stepdists is not None else None)
    for prefix, target in (("height", data.probe_heights), ("manual_height", data.manual_heights)):
        for i in range(999):
            if f"{prefix}{i}" not in sec:
                break
            target.append((float(sec[f"{prefix}{i}"]), _floats3(sec[f"{prefix}{i}_pos"])))
    for i in range(999):
        if f"distance{i}" not in sec:
            break
        data.distances.append(
            (
                float(sec[f"distance{i}"]),
                _floats3(sec[f"distance{i}_pos1"]),
                _floats3(sec[f"distance{i}_pos2"]),
            )
        )
    return data


def measurements_to_distances(measured, calib: DeltaCalibration):
    """DELTA_ANALYZE: caliper readings on calibrate_size.stl -> (dist, stable1, stable2) list.

    ``measured`` has keys CENTER_DISTS (6), CENTER_PILLAR_WIDTHS (3), OUTER_DISTS (6),
    OUTER_PILLAR_WIDTHS (6) and optionally SCALE (1).
    """
    scale = measured.get("SCALE", [1.0])[0]
    cpw = measured["CENTER_PILLAR_WIDTHS"]
    center_widths = [cpw[0], cpw[2], cpw[1], cpw[0], cpw[2], cpw[1]]
    center_dists = [d - w for d, w in zip(measured["CENTER_DISTS"], center_widths, strict=True)]
    outer_pairs = zip(measured["OUTER_DISTS"], measured["OUTER_PILLAR_WIDTHS"], strict=True)
    outer_dists = [d - w for d, w in outer_pairs]
    dirs = [(math.cos(math.radians(a)), math.sin(math.radians(a))) for a in MEASURE_ANGLES]
    inner = MEASURE_RIDGE_RADIUS * scale
    outer = (MEASURE_OUTER_RADIUS + MEASURE_RIDGE_RADIUS) * scale
    result = []
    for dist, (cx, cy) in zip(center_dists, dirs, strict=True):
        p1 = calib.calc_stable_position((cx * inner, cy * inner, 0.0))
        p2 = calib.calc_stable_position((cx * outer, cy * outer, 0.0))
        result.append((dist, p1, p2))
    centre = MEASURE_OUTER_RADIUS * scale
    shifted = dirs[2:] + dirs[:2]
    for dist, (sx, sy), (ax, ay) in zip(outer_dists, dirs, shifted, strict=True):
        p1 = calib.calc_stable_position((ax * inner + sx * centre, ay * inner + sy * centre, 0.0))
        p2 = calib.calc_stable_position((ax * outer + sx * centre, ay * outer + sy * centre, 0.0))
        result.append((dist, p1, p2))
    return result


# ----------------------------------------------------------------------------------------------
# Coordinate descent (klippy/mathutil.py) and the DELTA_CALIBRATE error function
# ----------------------------------------------------------------------------------------------


def coordinate_descent(adj_params, params, error_func, *, threshold=1e-5, max_rounds=10000):
    """Klipper's coordinate descent: each parameter in turn tries +step then -step.

    Every parameter starts with step 1.0; a step that lowers the error is kept and grows by
    1.1, otherwise the parameter is restored and its step shrinks by 0.9.  Stops when the sum of
    steps is <= 1e-5 or after 10000 rounds.  Returns ``(params, best_error, rounds)``.
    """
    params = dict(params)
    step = {name: 1.0 for name in adj_params}
    best = error_func(params)
    rounds = 0
    while sum(step.values()) > threshold and rounds < max_rounds:
        rounds += 1
        for name in adj_params:
            start = params[name]
            improved = False
            for trial in (start + step[name], start - step[name]):
                params[name] = trial
                err = error_func(params)
                if err < best:
                    best = err
                    step[name] *= 1.1
                    improved = True
                    break
            if not improved:
                params[name] = start
                step[name] *= 0.9
    return params, best, rounds


INVALID_ERROR = 9999999999999.9  # what Klipper's error function returns on a math domain error


def _arrays(data: CalibrationData):
    heights = list(data.manual_heights) + list(data.probe_heights)
    hz = np.array([h for h, _ in heights], dtype=float)
    hs = np.array([s for _, s in heights], dtype=float).reshape(-1, 3)
    dd = np.array([d for d, _, _ in data.distances], dtype=float)
    d1 = np.array([s for _, s, _ in data.distances], dtype=float).reshape(-1, 3)
    d2 = np.array([s for _, _, s in data.distances], dtype=float).reshape(-1, 3)
    return hz, hs, dd, d1, d2


def make_error_function(calib: DeltaCalibration, data: CalibrationData, *, use_distances=True):
    """Klipper's ``delta_errorfunc`` for ``calculate_params(probe_heights, distances)``.

    Heights are manual heights followed by probed heights; their squared errors are summed and
    multiplied by ``z_weight = len(distances) / (MEASURE_WEIGHT * len(probe_heights))`` (1 without
    distances - note: probed heights only in the denominator), then the squared distance errors
    are added.
    """
    hz, hs, dd, d1, d2 = _arrays(data)
    if not use_distances:
        dd, d1, d2 = dd[:0], d1[:0], d2[:0]
    z_weight = 1.0
    if len(dd):
        z_weight = len(dd) / (MEASURE_WEIGHT * len(data.probe_heights))

    def error(params):
        trial = calib.new_calibration(params)
        z = trial.positions_from_stable(hs)[:, 2] if len(hs) else np.zeros(0)
        total = 0.0
        for r in (z - hz).tolist():
            total += r**2
        total *= z_weight
        if len(dd):
            p1 = trial.positions_from_stable(d1)
            p2 = trial.positions_from_stable(d2)
            dist = np.sqrt(
                (p1[:, 0] - p2[:, 0]) ** 2 + (p1[:, 1] - p2[:, 1]) ** 2 + (p1[:, 2] - p2[:, 2]) ** 2
            )
            for r in (dist - dd).tolist():
                total += r**2
        if math.isnan(total):
            return INVALID_ERROR
        return total

    return error, z_weight


@dataclass
class CalibrationResult:
    calibration: DeltaCalibration
    params: dict
    adjusted: tuple
    error: float
    rounds: int
    z_weight: float


def delta_calibrate(calib: DeltaCalibration, data: CalibrationData, *, extended=None):
    """Run Klipper's DELTA_CALIBRATE analysis starting from ``calib``.

    ``extended=None`` behaves like Klipper (distances present -> 9 parameters with distances);
    ``extended=False`` is the basic 6-parameter fit on heights only (distances ignored);
    ``extended=True`` requires distances.
    """
    if extended is None:
        extended = bool(data.distances)
    if extended and not data.distances:
        raise ValueError("extended calibration needs distances")
    error, z_weight = make_error_function(calib, data, use_distances=extended)
    adjust, start = calib.coordinate_descent_params(extended)
    params, best, rounds = coordinate_descent(adjust, start, error)
    return CalibrationResult(calib.new_calibration(params), params, adjust, best, rounds, z_weight)


# ----------------------------------------------------------------------------------------------
# Residuals of arbitrary parameter values
# ----------------------------------------------------------------------------------------------


def _to_calibration(params, stepdists):
    if isinstance(params, DeltaCalibration):
        return params
    if "angle_a" in params:  # Klipper's flat coordinate-descent dictionary
        return DeltaCalibration(
            params["radius"],
            [params["angle_" + a] for a in AXES],
            [params["arm_" + a] for a in AXES],
            [params["endstop_" + a] for a in AXES],
            [params.get("stepdist_" + a, stepdists[k]) for k, a in enumerate(AXES)],
        )
    sd = params.get("stepdists", stepdists)
    return DeltaCalibration(
        params["radius"], params["angles"], params["arms"], params["endstops"], sd
    )


def height_residuals(params, data: CalibrationData) -> np.ndarray:
    """Predicted minus saved z for every manual then probed height (mm).

    ``params`` is a :class:`DeltaCalibration`, a dict ``{radius, angles[3], arms[3],
    endstops[3] (, stepdists[3])}`` or Klipper's flat dict (``radius``, ``angle_a`` ...).
    Step distances default to ``data.stepdists``.
    """
    calib = _to_calibration(params, data.stepdists)
    hz, hs, *_ = _arrays(data)
    return calib.positions_from_stable(hs)[:, 2] - hz


def distance_residuals(params, data: CalibrationData) -> np.ndarray:
    """Predicted minus measured distance for every saved DELTA_ANALYZE distance (mm)."""
    calib = _to_calibration(params, data.stepdists)
    _, _, dd, d1, d2 = _arrays(data)
    if not len(dd):
        return np.zeros(0)
    diff = calib.positions_from_stable(d1) - calib.positions_from_stable(d2)
    return np.sqrt(diff[:, 0] ** 2 + diff[:, 1] ** 2 + diff[:, 2] ** 2) - dd


def rms(values) -> float:
    values = np.asarray(values, dtype=float)
    return float(np.sqrt(np.mean(values**2))) if values.size else float("nan")


# ----------------------------------------------------------------------------------------------
# Convenience: one saved printer.cfg
# ----------------------------------------------------------------------------------------------


@dataclass
class KlipperDataSet:
    name: str
    config: KlipperConfig
    calibration: DeltaCalibration
    data: CalibrationData


def load_data_set(path: str) -> KlipperDataSet:
    config = read_klipper_config(path)
    calib = delta_from_config(config)
    data = calibration_data_from_config(config, calib.stepdists)
    name = os.path.splitext(os.path.basename(path))[0]
    return KlipperDataSet(name, config, calib, data)


def _row(ds: KlipperDataSet):
    saved = ds.calibration
    h0, d0 = rms(height_residuals(saved, ds.data)), rms(distance_residuals(saved, ds.data))
    basic = delta_calibrate(saved, ds.data, extended=False).calibration
    hb, db = rms(height_residuals(basic, ds.data)), rms(distance_residuals(basic, ds.data))
    out = [ds.name, len(ds.data.probe_heights), len(ds.data.manual_heights)]
    out += [len(ds.data.distances), h0, d0, hb, db]
    if ds.data.distances:
        ext = delta_calibrate(saved, ds.data, extended=True).calibration
        out += [rms(height_residuals(ext, ds.data)), rms(distance_residuals(ext, ds.data))]
    else:
        out += [float("nan"), float("nan")]
    return out


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    here = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), os.pardir,
                        "shared", "data", "printers", "klipper_saved")
    paths = argv or sorted(glob.glob(os.path.join(here, "*.cfg")))
    print(
        f"{'data set':28s} {'nh':>3s} {'nm':>3s} {'nd':>3s} | {'saved h':>8s} {'saved d':>8s}"
        f" | {'basic h':>8s} {'basic d':>8s} | {'ext h':>8s} {'ext d':>8s}   (RMS, mm)"
    )
    for path in paths:
        row = _row(load_data_set(path))
        print(
            f"{row[0]:28s} {row[1]:3d} {row[2]:3d} {row[3]:3d} | "
            + " | ".join(f"{row[i]:8.4f} {row[i + 1]:8.4f}" for i in (4, 6, 8))
        )


if __name__ == "__main__":
    main()
