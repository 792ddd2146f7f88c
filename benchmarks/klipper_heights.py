"""Held-out bed heights: pkmcal's Klipper path against Klipper's own DELTA_CALIBRATE.

The issue's goal: "A benchmark on simulated printers with 30+ points shows held-out heights at
or below Klipper's algorithm's."

Each simulated printer is a linear Delta that Klipper's model cannot represent exactly:

- the config in force (what the firmware uses) is the nominal printer: ``delta_radius`` 140
  mm, arms 280 mm (2:1 as a Kossel; 250 mm cannot reach the print disk's edge), towers at 210,
  330, 90 deg, ``position_endstop`` 300 mm, ``print_radius`` 120 mm, ``[delta_calibrate]
  radius`` 100 mm, ``[probe] z_offset`` 1.25 mm, 40 mm / (200 x 16) steps;
- the true printer (:func:`~pkmcal.machines.linear_delta.linear_delta`) differs by uniform
  random errors within: per-tower endstops +-1 mm, the radius +-0.5 mm, each tower angle
  +-0.3 deg, each arm +-0.3 mm (not in Klipper's basic set), each tower's radial and
  tangential tilt +-0.5 mrad (``tower{i}.tilt_radial`` / ``tilt_tangential``; Klipper has
  none), and a bed tilted against the towers by up to 1 mrad in a random direction (the bed is
  ``z = gx x + gy y`` in the true printer's frame; Klipper has none).

Probing is simulated as the firmware does it: it commands the point's (x, y) and moves down
vertically *in its own kinematics* (the config in force); the carriages travel what the
firmware's inverse kinematics give; the true nozzle is where the true printer's forward
kinematics put those travels; the probe triggers when the true nozzle is ``z_offset + e``
above the true bed (``e`` Gaussian trigger noise). The saved stable position is the travel in
steps since each endstop, ``%.3f`` as Klipper saves it; the saved height is ``z_offset``
(``probe_finalize``).

Calibration data: the centre and hexagonal rings within the probe radius (37 = 3 rings, 61 =
4, 91 = 5). Held-out: random points, uniform on the print disk (radius 120 mm, beyond the
probed 100 mm as a printer prints there), probed the same way with fresh noise, and once more
without noise (the true model error alone).

Klipper: the reference port of ``DELTA_CALIBRATE`` (``tests/klipper_reference.py``, basic set:
3 endstops, radius, angles a and b; coordinate descent) started from the config in force.
pkmcal: the documented path, in process: ``pkmcal import printer.cfg --from klipper``,
``pkmcal calibrate ... --parameters klipper-basic``, ``pkmcal export --to klipper`` (the
values fitted over the calibrated machine's print workspace, the bed tilt folded in).
``--cli`` runs the three commands as subprocesses instead and reads the updated
``printer.cfg`` back with the reference's config reader (slower; same figures).

Both give Klipper values; each is evaluated by the reference's ``height_residuals`` (Klipper's
kinematics on the saved stable positions) on the held-out points and on the calibration
points; RMS per printer, then the ratio pkmcal / Klipper. ``--bed-tilt`` passes pkmcal
calibrate's option (default: pkmcal's default, ``auto``).

Two diagnostics on the noise-free held-out points (``model``, ``z-fit`` columns; not what a
user gets): pkmcal's calibrated machine and bed plane themselves, before the export, and
:func:`heights_fold_in`, Klipper's basic values fitted to that machine's bed heights only.
They tell the calibration's share of the error from the export's.

Usage (from the repository root)::

    .venv/bin/python benchmarks/klipper_heights.py                       # 50 printers, 37 pts
    .venv/bin/python benchmarks/klipper_heights.py --points 61 --noise 20um
    .venv/bin/python benchmarks/klipper_heights.py --without bed,tilts   # which error hurts

``tests/test_klipper_benchmark.py`` runs a small case.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import klipper_reference as ref  # noqa: E402
from pkmcal.machines.linear_delta import linear_delta  # noqa: E402

# --- the config in force (nominal printer), mm / deg --------------------------------------------
RADIUS = 140.0
ARM = 280.0
ANGLES = (210.0, 330.0, 90.0)
ENDSTOP = 300.0
PRINT_RADIUS = 120.0
PROBE_RADIUS = 100.0
Z_OFFSET = 1.25
ROTATION_DISTANCE, FULL_STEPS, MICROSTEPS = 40.0, 200, 16
STEPDIST = ROTATION_DISTANCE / (FULL_STEPS * MICROSTEPS)

#: the true printer's errors: uniform within +- these (mm, deg, mrad); the bed tilt's size is
#: uniform in [0, BED_TILT] mrad, its direction uniform
ERRORS = {"endstops": 1.0, "radius": 0.5, "angles": 0.3, "arms": 0.3, "tilts": 0.5}
BED_TILT = 1.0
COMPONENTS = tuple(ERRORS) + ("bed",)


@dataclass
class Truth:
    machine: object          # pkmcal LinearDelta (SI)
    bed: np.ndarray          # (gx, gy): true bed z = gx x + gy y


def config_in_force() -> ref.DeltaCalibration:
    return ref.DeltaCalibration(RADIUS, ANGLES, [ARM] * 3, [ENDSTOP] * 3, [STEPDIST] * 3)


def draw_truth(rng, without=()) -> Truth:
    """A true printer: nominal + uniform errors (components in ``without`` left out)."""
    def u(name, size=None):
        scale = 0.0 if name in without else ERRORS[name]
        return rng.uniform(-scale, scale, size)

    radius = RADIUS + u("radius")
    arms = ARM + u("arms", 3)
    angles = np.array(ANGLES) + u("angles", 3)
    endstops = ENDSTOP + u("endstops", 3)
    m = linear_delta(radius * 1e-3, arms * 1e-3, np.radians(angles), endstops * 1e-3)
    p, values = m.parameters, m.parameters.values.copy()
    for i in range(3):
        for what in ("tilt_radial", "tilt_tangential"):
            values[p.index(f"tower{i + 1}.{what}")] = u("tilts") * 1e-3
    m = m.with_parameters(values)
    size = 0.0 if "bed" in without else rng.uniform(0.0, BED_TILT) * 1e-3
    direction = rng.uniform(0.0, 2 * np.pi)
    return Truth(m, size * np.array([math.cos(direction), math.sin(direction)]))


def firmware_travel(cfg: ref.DeltaCalibration, xyz) -> np.ndarray:
    """Carriage travels down from the endstops (mm) the firmware commands for (x, y, z)."""
    xyz = np.asarray(xyz, float)
    out = np.empty((len(xyz), 3))
    for k in range(3):
        tx, ty = cfg.towers[k]
        height = np.sqrt(cfg.arms[k] ** 2 - (tx - xyz[:, 0]) ** 2 - (ty - xyz[:, 1]) ** 2)
        out[:, k] = cfg.abs_endstops[k] - (height + xyz[:, 2])
    return out


def probe(truth: Truth, cfg: ref.DeltaCalibration, xy, noise_mm: float, rng):
    """Saved (height, stable position) pairs of probing at the commanded ``xy`` (mm).

    The firmware moves down along its own vertical at the commanded (x, y); the probe
    triggers where the true nozzle is ``z_offset + e`` above the true bed.
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    target = Z_OFFSET + (rng.normal(0.0, noise_mm, len(xy)) if noise_mm > 0 else 0.0)
    z = np.full(len(xy), Z_OFFSET)
    gx, gy = truth.bed
    for _ in range(50):
        travel = firmware_travel(cfg, np.column_stack([xy, z]))
        P, ok = truth.machine.fk_positions(travel * 1e-3)
        if not ok.all():
            raise RuntimeError("a probe point is out of the true printer's reach")
        P = P * 1e3
        gap = P[:, 2] - (gx * P[:, 0] + gy * P[:, 1]) - target
        z = z - gap                     # d(nozzle z)/d(commanded z) = 1 to ~1e-3
        if np.max(np.abs(gap)) < 1e-10:
            break
    travel = firmware_travel(cfg, np.column_stack([xy, z]))
    steps = np.round(travel / STEPDIST, 3)              # Klipper saves "%.3f"
    return [(Z_OFFSET, list(s)) for s in steps]


def ring_points(n: int) -> np.ndarray:
    """The centre and hexagonal rings within the probe radius: 1 + 3 m (m + 1) points."""
    rings = next((m for m in range(1, 20) if 1 + 3 * m * (m + 1) == n), None)
    if rings is None:
        valid = ", ".join(str(1 + 3 * m * (m + 1)) for m in range(2, 7))
        raise SystemExit(f"--points {n}: the centre and hexagonal rings give {valid}")
    pts = [(0.0, 0.0)]
    for k in range(1, rings + 1):
        r = PROBE_RADIUS * k / rings
        for j in range(6 * k):
            a = math.radians(90.0) + 2 * math.pi * j / (6 * k)
            pts.append((r * math.cos(a), r * math.sin(a)))
    return np.array(pts)


def disk_points(n: int, rng) -> np.ndarray:
    rho = PRINT_RADIUS * np.sqrt(rng.uniform(0.0, 1.0, n))
    a = rng.uniform(0.0, 2 * np.pi, n)
    return np.column_stack([rho * np.cos(a), rho * np.sin(a)])


def config_text(probes) -> str:
    """The printer.cfg a user has after DELTA_CALIBRATE saved its points (not yet applied)."""
    lines = ["[printer]", "kinematics: delta", f"delta_radius: {RADIUS}",
             f"print_radius: {PRINT_RADIUS}", ""]
    for t, angle in zip("abc", ANGLES, strict=True):
        lines += [f"[stepper_{t}]", f"rotation_distance: {ROTATION_DISTANCE}",
                  f"microsteps: {MICROSTEPS}", f"arm_length: {ARM}",
                  f"position_endstop: {ENDSTOP}", f"angle: {angle}", ""]
    lines += ["[delta_calibrate]", f"radius: {PROBE_RADIUS}", "", "[probe]",
              f"z_offset: {Z_OFFSET}", ""]
    block = ["#*# <---------------------- SAVE_CONFIG ---------------------->",
             "#*# DO NOT EDIT THIS BLOCK OR BELOW. The contents are auto-generated.", "#*#",
             "#*# [delta_calibrate]"]
    for i, (h, s) in enumerate(probes):
        block += [f"#*# height{i} = {h:.6f}",
                  f"#*# height{i}_pos = {s[0]:.3f},{s[1]:.3f},{s[2]:.3f}"]
    return "\n".join(lines + block) + "\n"


def _as_calibration(values) -> ref.DeltaCalibration:
    """Klipper values (SI: radius, arms 3, angles 3 rad, endstops 3, ...) -> the reference's."""
    v = np.asarray(values, float)
    return ref.DeltaCalibration(v[0] * 1e3, np.degrees(v[4:7]), v[1:4] * 1e3, v[7:10] * 1e3,
                                [STEPDIST] * 3)


def model_heights(machine, data: ref.CalibrationData, setups=None) -> np.ndarray:
    """Predicted minus saved heights of a calibrated pkmcal machine itself (its own model and
    the bed plane of its set-ups, before the export to Klipper's values), mm."""
    from pkmcal.instruments.probe import bed_plane

    bed = bed_plane(setups)
    bed = np.zeros(3) if bed is None else np.asarray(bed, float)
    steps = np.array([s for _, s in data.probe_heights])
    P, _ = machine.fk_positions(steps * STEPDIST * 1e-3)
    above = P[:, 2] - (bed[0] + bed[1] * P[:, 0] + bed[2] * P[:, 1])
    return above * 1e3 - np.array([h for h, _ in data.probe_heights])


def pkmcal_values(cfg_path: Path, keep: dict | None = None,
                  bed_tilt: str | None = None) -> ref.DeltaCalibration:
    """import -> calibrate --parameters klipper-basic -> export --to klipper, in process."""
    from pkmcal.calibration.run import calibrate
    from pkmcal.export import controller_format, export
    from pkmcal.instruments.probe import bed_plane

    fmt = controller_format("klipper")
    machine = fmt.to_machine(fmt.parse(cfg_path.read_text(), str(cfg_path)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = calibrate(machine, str(cfg_path), parameters="klipper-basic", bed_tilt=bed_tilt)
    setups = cal.setups
    if keep is not None:
        keep["calibrated"], keep["setups"] = cal.calibrated, setups
    # what `pkmcal export` fits over
    ws = cal.calibrated.print_workspace(rng=0, bed=bed_plane(setups))
    result = export(fmt, cal.calibrated, ws.P, ws.R, surface=ws.surface, setups=setups)
    return _as_calibration(result.params.values)


def heights_fold_in(machine, setups=None) -> ref.DeltaCalibration:
    """DIAGNOSTIC, not pkmcal's path: Klipper's basic values (radius, angles a and b, the
    endstops; arms and angle c as imported) fitted to the calibrated machine's nozzle HEIGHT
    errors on its print disk (z only, the bed tilt folded in), instead of the export's 3D
    position errors over the print disk and the volume above it."""
    from scipy.optimize import least_squares

    from pkmcal.export import controller_format
    from pkmcal.export.fitting import position_errors
    from pkmcal.instruments.probe import bed_plane

    fmt = controller_format("klipper")
    ws = machine.print_workspace(rng=0, bed=bed_plane(setups))
    P = ws.P[ws.surface]
    params = fmt.initial(machine, setups)
    free = np.zeros(len(params.values), bool)
    free[[0, 4, 5, 7, 8, 9]] = True
    length = machine.characteristic_length()
    scale = np.where(np.array(params.kinds) == "length", length, 1.0)[free]

    def residual(x):
        v = params.values.copy()
        v[free] = x * scale
        e = position_errors(fmt, params.with_values(v), machine, P)[:, 2] / length
        return np.nan_to_num(e, nan=1.0)

    fit = least_squares(residual, params.values[free] / scale, method="trf", xtol=1e-15,
                        ftol=1e-15, gtol=1e-15)
    v = params.values.copy()
    v[free] = fit.x * scale
    return _as_calibration(v)


def pkmcal_values_cli(cfg_path: Path, bed_tilt: str | None = None) -> ref.DeltaCalibration:
    """The same as the three commands a user types; the updated printer.cfg read back."""
    exe = [str(Path(sys.executable).with_name("pkmcal"))]
    folder = cfg_path.parent
    for args in (["import", str(cfg_path), "--from", "klipper", "-o", "printer.yaml"],
                 ["calibrate", "printer.yaml", str(cfg_path), "--parameters", "klipper-basic",
                  "-o", "cal.yaml"] + (["--bed-tilt", bed_tilt] if bed_tilt else []),
                 ["export", "cal.yaml", "--to", "klipper", "-o", str(cfg_path)]):
        subprocess.run(exe + args, cwd=folder, check=True, capture_output=True)
    return ref.delta_from_config(ref.read_klipper_config(str(cfg_path)))


def one_printer(seed: int, points: int, held: int, noise_mm: float, without=(),
                use_cli: bool = False, bed_tilt: str | None = None, diagnose: bool = True,
                workdir: Path | None = None) -> dict:
    """One simulated printer: RMS heights (mm) of Klipper's and pkmcal's values and the
    diagnostics (``model_*``: pkmcal's calibrated machine itself; ``zfit_*``:
    :func:`heights_fold_in`)."""
    rng = np.random.default_rng(seed)
    truth = draw_truth(rng, without)
    cfg = config_in_force()
    calib = ref.CalibrationData(probe_heights=probe(truth, cfg, ring_points(points), noise_mm,
                                                    rng), stepdists=[STEPDIST] * 3)
    xy_held = disk_points(held, rng)
    held_noisy = ref.CalibrationData(probe_heights=probe(truth, cfg, xy_held, noise_mm, rng),
                                     stepdists=[STEPDIST] * 3)
    held_exact = ref.CalibrationData(probe_heights=probe(truth, cfg, xy_held, 0.0, rng),
                                     stepdists=[STEPDIST] * 3)

    t0 = time.perf_counter()
    klipper = ref.delta_calibrate(cfg, calib, extended=False).calibration
    t1 = time.perf_counter()
    with tempfile.TemporaryDirectory(dir=workdir) as folder:
        path = Path(folder) / "printer.cfg"
        path.write_text(config_text(calib.probe_heights))
        keep: dict = {}
        ours = (pkmcal_values_cli(path, bed_tilt) if use_cli
                else pkmcal_values(path, keep, bed_tilt))
    t2 = time.perf_counter()

    out = {"seed": seed, "bed_tilt_mrad": float(np.hypot(*truth.bed)) * 1e3,
           "t_klipper": t1 - t0, "t_pkmcal": t2 - t1}
    for who, values in (("klipper", klipper), ("pkmcal", ours)):
        out[f"{who}_in"] = ref.rms(ref.height_residuals(values, calib))
        out[f"{who}_held"] = ref.rms(ref.height_residuals(values, held_noisy))
        out[f"{who}_true"] = ref.rms(ref.height_residuals(values, held_exact))
    out["before_held"] = ref.rms(ref.height_residuals(cfg, held_exact))
    if diagnose and "calibrated" in keep:   # pkmcal's own model, before the export
        out["model_in"] = ref.rms(model_heights(keep["calibrated"], calib, keep["setups"]))
        out["model_true"] = ref.rms(model_heights(keep["calibrated"], held_exact,
                                                  keep["setups"]))
        zfit = heights_fold_in(keep["calibrated"], keep["setups"])
        out["zfit_true"] = ref.rms(ref.height_residuals(zfit, held_exact))
        out["zfit_held"] = ref.rms(ref.height_residuals(zfit, held_noisy))
        out["model_held"] = ref.rms(model_heights(keep["calibrated"], held_noisy,
                                                  keep["setups"]))
    return out


def run(printers: int = 50, points: int = 37, held: int = 60, noise_mm: float = 0.01,
        seed: int = 0, without=(), use_cli: bool = False, bed_tilt: str | None = None,
        verbose: bool = True, diagnose: bool = True) -> list[dict]:
    """``printers`` simulated printers (seeds ``seed * 100003 + k``), one row each."""
    rows = []
    for k in range(printers):
        row = one_printer(seed * 100003 + k, points, held, noise_mm, without, use_cli,
                          bed_tilt, diagnose)
        rows.append(row)
        if verbose:
            print(f"{k:4d} {row['bed_tilt_mrad']:6.2f} {row['before_held'] * 1e3:8.1f} | "
                  f"{row['klipper_in'] * 1e3:7.1f} {row['pkmcal_in'] * 1e3:7.1f} | "
                  f"{row['klipper_held'] * 1e3:7.1f} {row['pkmcal_held'] * 1e3:7.1f} "
                  f"{row['pkmcal_held'] / row['klipper_held']:6.3f} | "
                  f"{row['klipper_true'] * 1e3:7.1f} {row['pkmcal_true'] * 1e3:7.1f} "
                  f"{row['pkmcal_true'] / row['klipper_true']:6.3f} | "
                  f"{row.get('model_in', np.nan) * 1e3:6.1f} "
                  f"{row.get('model_true', np.nan) * 1e3:6.1f} "
                  f"{row.get('zfit_true', np.nan) * 1e3:6.1f}", flush=True)
    return rows


def summary(rows) -> dict:
    out = {"printers": len(rows)}
    for key in ("in", "held", "true"):
        k = np.array([r[f"klipper_{key}"] for r in rows])
        p = np.array([r[f"pkmcal_{key}"] for r in rows])
        ratio = p / k
        out[key] = {"klipper_mean_um": float(np.mean(k)) * 1e3,
                    "pkmcal_mean_um": float(np.mean(p)) * 1e3,
                    "ratio_mean": float(np.mean(ratio)), "ratio_median": float(np.median(ratio)),
                    "ratio_of_means": float(np.mean(p) / np.mean(k)),
                    "pkmcal_at_or_below": int(np.sum(p <= k))}
    k = np.array([r["klipper_true"] for r in rows])
    for key in ("model_true", "zfit_true"):
        if all(key in r for r in rows):
            p = np.array([r[key] for r in rows])
            out[key] = {"klipper_mean_um": float(np.mean(k)) * 1e3,
                        "pkmcal_mean_um": float(np.mean(p)) * 1e3,
                        "ratio_mean": float(np.mean(p / k)),
                        "ratio_median": float(np.median(p / k)),
                        "ratio_of_means": float(np.mean(p) / np.mean(k)),
                        "pkmcal_at_or_below": int(np.sum(p <= k))}
    out["t_klipper"] = float(sum(r["t_klipper"] for r in rows))
    out["t_pkmcal"] = float(sum(r["t_pkmcal"] for r in rows))
    return out


def _length_mm(text: str) -> float:
    text = text.strip().lower()
    for unit, scale in (("um", 1e-3), ("mm", 1.0)):
        if text.endswith(unit):
            return float(text[: -len(unit)]) * scale
    return float(text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--printers", type=int, default=50)
    ap.add_argument("--points", type=int, default=37, help="calibration points (37, 61, 91)")
    ap.add_argument("--held", type=int, default=60, help="held-out points per printer")
    ap.add_argument("--noise", default="10um", help="probe trigger noise (std), e.g. 10um")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--without", default="",
                    help=f"leave these errors out of the truth: {','.join(COMPONENTS)}")
    ap.add_argument("--bed-tilt", default=None, choices=("auto", "estimate", "square"),
                    help="pkmcal calibrate --bed-tilt (default: pkmcal's default, auto)")
    ap.add_argument("--cli", action="store_true",
                    help="run pkmcal import/calibrate/export as subprocesses")
    args = ap.parse_args(argv)
    without = tuple(w for w in args.without.split(",") if w)
    bad = set(without) - set(COMPONENTS)
    if bad:
        ap.error(f"--without: unknown {sorted(bad)}; choose from {','.join(COMPONENTS)}")
    noise = _length_mm(args.noise)
    print(f"{args.printers} printers, {args.points} calibration points, {args.held} held-out, "
          f"noise {noise * 1e3:g} um, seed {args.seed}"
          + (f", without {','.join(without)}" if without else "")
          + (f", --bed-tilt {args.bed_tilt}" if args.bed_tilt else ""))
    print("   # bed mrad  before | in-sample K  pkmcal |  held-out K  pkmcal  ratio |"
          "  true K  pkmcal  ratio | model  in  true  z-fit   (RMS um)")
    t0 = time.perf_counter()
    rows = run(args.printers, args.points, args.held, noise, args.seed, without, args.cli,
               args.bed_tilt)
    wall = time.perf_counter() - t0
    s = summary(rows)
    print()
    print("            Klipper um  pkmcal um  ratio mean  median  of means  pkmcal <= Klipper")
    for key, words in (("in", "in-sample"), ("held", "held-out"), ("true", "held-out true"),
                       ("model_true", "  model*"), ("zfit_true", "  z-fit*")):
        if key not in s:
            continue
        d = s[key]
        print(f"{words:14s} {d['klipper_mean_um']:8.2f} {d['pkmcal_mean_um']:9.2f} "
              f"{d['ratio_mean']:10.3f} {d['ratio_median']:7.3f} {d['ratio_of_means']:9.3f}"
              f"  {d['pkmcal_at_or_below']:3d}/{s['printers']}")
    if "model_true" in s:
        print("* diagnostics on the held-out points without noise, not pkmcal's Klipper values: "
              "model = pkmcal's\n  calibrated machine and bed itself (before the export); "
              "z-fit = Klipper's basic values\n  fitted to that machine's bed heights only "
              "(heights_fold_in)")
    print(f"\ntime {wall:.1f} s (Klipper's coordinate descent {s['t_klipper']:.1f} s, "
          f"pkmcal {s['t_pkmcal']:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
