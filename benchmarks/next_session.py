"""The next-session test (SPEC 9, issue 35): calibrate from session A, predict session B.

For every printer of ``../shared/data/printers`` with more than one FRESH session (the
README's table: a session's meshes were probed with its saved values in force), every
chronological pair (A, B):

- **pkmcal**: as documented, in process: ``pkmcal import A/printer.cfg --from klipper``,
  ``pkmcal calibrate printer.yaml A/printer.cfg`` (defaults: A's DELTA_CALIBRATE points and
  the bed meshes the reader takes, each mesh with its own height offset), ``pkmcal export
  calibrated.yaml --to klipper -o A/printer.cfg`` (the updated file read back as Klipper
  reads it);
- the same with ``--parameters klipper`` (A's points and meshes in Klipper's own set: the
  data half alone) and from A's DELTA_CALIBRATE points alone (the path before bed meshes
  were read: 1.00x Klipper by construction);
- **Klipper**: A's saved values (what the firmware user had after session A);
- **Klipper + mesh**: A's values with A's own bed mesh loaded (the mesh interpolated at the
  nozzle's x/y as Klipper applies it: with klippy installed its own ``ZMesh``, upsampling
  included; otherwise bilinear on the saved grid, said in the output).

Each is evaluated on session B's saved carriage positions: its DELTA_CALIBRATE points
(stable positions times the step distance) and its meshes' probed points (carriage travels
recovered with B's values in force, :func:`pkmcal.io.klipper_data.mesh_travels`), through
Klipper's kinematics (the three spheres' intersection, ``get_position_from_stable``) with the
values evaluated: the nozzle's height above the bed at each trigger minus the probe's
``z_offset``, one free offset per data set (a session's endstops and a mesh's reference),
RMS over B's rows. Ratio pkmcal / Klipper per pair, median and worst; pairs at most 30 days
apart first, all pairs second.

The points-only pooled test: a printer with at least 5 DELTA_CALIBRATE sessions (Aieie78's
``klipper_saved/v400-aieie78-run*.cfg``, without meshes): sessions 1-4 calibrate (pkmcal: one
``calibrate`` of the four files; Klipper: the values in force after session 4), sessions 5-6
are predicted, one free offset per session.

Usage (from the repository root)::

    .venv/bin/python benchmarks/next_session.py               # tables; results to benchmarks/
    .venv/bin/python benchmarks/next_session.py --pairs 1     # the first pair only (the test)

Results: ``benchmarks/next_session.json`` (``--no-write`` to skip).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data" / "printers"
try:                                    # Klipper's host code, the reference where installed
    from klippy.extras.bed_mesh import ZMesh  # type: ignore
except Exception:  # noqa: BLE001 - optional reference
    ZMesh = None

from pkmcal.io.klipper_config import KlipperConfig  # noqa: E402
from pkmcal.io.klipper_data import BedMesh, DeltaValues, bed_mesh_data, delta_values  # noqa: E402

#: the fresh sessions (``shared/data/printers/README.md`` and each ``PROVENANCE.md``): file,
#: the time DELTA_CALIBRATE's values were saved (the session's date)
SESSIONS = {
    "flsun_v400_aieie78": [
        ("extra/printer-20241208_114014.cfg", "2024-12-04 22:38"),
        ("extra/printer-20241208_120036.cfg", "2024-12-08 11:42"),
        ("extra/printer-20241219_173830.cfg", "2024-12-18 21:41"),
        ("extra/printer-20241219_185441.cfg", "2024-12-19 17:38"),
        ("extra/printer-20241223_204558.cfg", "2024-12-19 18:59"),
        ("printer.cfg", "2024-12-24 17:00"),
    ],
    "flsun_v400_eeichhorn": [
        ("printer.cfg", "2023-04-04 18:54"),
        ("extra/printer-20230417_151838.cfg", "2023-04-10 09:59"),
    ],
    "flsun_v400_fzechert": [
        ("printer.cfg", "2023-12-15 00:00"),            # fresh "weakly" (0.030 vs 0.052 mm)
        ("extra/printer-4cf209b1.cfg", "2024-03-24 00:00"),
    ],
}
#: the points-only pooled test: Aieie78's DELTA_CALIBRATE sessions in order
POOLED = [f"klipper_saved/v400-aieie78-run{i}.cfg" for i in range(1, 10)]
MAX_DAYS = 30


@dataclass
class DataSet:
    """One data set of a session: carriage travels (mm) and the nozzle's height above the bed
    at each trigger (mm)."""

    name: str
    travel: np.ndarray
    height: np.ndarray


@dataclass
class Session:
    path: Path
    date: datetime
    cfg: KlipperConfig
    values: DeltaValues
    sets: list
    meshes: list          # BedMesh used (the user's own, for "Klipper + mesh")


def read_session(path: Path, date: str | None = None, meshes: bool = True) -> Session:
    """A session's data sets: its DELTA_CALIBRATE heights and the meshes the reader takes."""
    cfg = KlipperConfig.read(path)
    values = delta_values(cfg)
    sets = []
    idx = []
    opts = cfg.options("delta_calibrate")
    while f"height{len(idx)}" in opts:
        idx.append(len(idx))
    if idx:
        steps = np.array([cfg.numbers("delta_calibrate", f"height{i}_pos", 3) for i in idx])
        h = np.array([cfg.number("delta_calibrate", f"height{i}") for i in idx])
        sets.append(DataSet("DC points", steps * values.steps, h))
    used = []
    if meshes:
        data, _ = bed_mesh_data(cfg)
        for d in data:
            sets.append(DataSet(f"mesh {d.mesh.name}", d.q * 1e3, d.values[:, 0] * 1e3))
            used.append(d.mesh)
    when = datetime.strptime(date, "%Y-%m-%d %H:%M") if date else datetime.min
    return Session(path, when, cfg, values, sets, used)


def mesh_function(mesh: BedMesh):
    """``f(xy) -> z`` of a loaded mesh as Klipper applies it (klippy's ZMesh when installed),
    and its words."""
    if ZMesh is not None:
        try:
            p = mesh.params
            params = {"min_x": float(p["min_x"]), "max_x": float(p["max_x"]),
                      "min_y": float(p["min_y"]), "max_y": float(p["max_y"]),
                      "x_count": int(float(p["x_count"])), "y_count": int(float(p["y_count"])),
                      "mesh_x_pps": int(float(p.get("mesh_x_pps", 2))),
                      "mesh_y_pps": int(float(p.get("mesh_y_pps", 2))),
                      "algo": p.get("algo", "lagrange").strip(),
                      "tension": float(p.get("tension", 0.2))}
            try:
                z = ZMesh(params, mesh.name)
            except TypeError:
                z = ZMesh(params)
            z.build_mesh([list(map(float, r)) for r in mesh.z])
            return (lambda xy: np.array([z.calc_z(float(a), float(b)) for a, b in xy]),
                    "klippy's ZMesh (upsampled as Klipper does)")
        except Exception as exc:  # noqa: BLE001 - fall back to the saved grid
            words = f"bilinear on the saved grid (klippy's ZMesh failed: {exc})"
            return mesh.at, words
    return mesh.at, "bilinear on the saved grid (klippy not installed)"


def residuals(values: DeltaValues, session: Session, mesh=None) -> list:
    """Per data set: the nozzle's height above the bed minus the probe height at each trigger
    (mm) under ``values``, the set's mean removed; with ``mesh`` (``f(xy)``) the height the
    loaded mesh puts the bed at is subtracted."""
    out = []
    for s in session.sets:
        v = DeltaValues(values.radius, values.angles, values.arms, values.endstops,
                        session.values.steps)
        P = v.position(s.travel)
        r = P[:, 2] - s.height
        if mesh is not None:
            r = r - mesh(P[:, :2])
        r = r[np.isfinite(r)]
        out.append(r - r.mean())
    return out


def rms(parts) -> float:
    r = np.concatenate(parts)
    return float(np.sqrt(np.mean(r * r)))


def pkmcal_values(paths: list, data=None, parameters: str | None = None):
    """import -> calibrate (defaults) -> export --to klipper onto the last file, in process;
    the exported file read back. Returns the values, the calibration and the exported mesh
    profile's ``f(xy)`` (None without one). ``data``: the data objects to calibrate from
    instead of the files (the points-only baselines)."""
    from pkmcal.calibration.run import calibrate
    from pkmcal.export import controller_format, export
    from pkmcal.instruments.probe import bed_plane

    fmt = controller_format("klipper")
    last = Path(paths[-1])
    text = last.read_text()
    machine = fmt.to_machine(fmt.parse(text, str(last)))
    if data is None:
        data = [str(p) for p in paths] if len(paths) > 1 else str(paths[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cal = calibrate(machine, data, parameters=parameters)
    setups = cal.setups
    ws = cal.calibrated.print_workspace(rng=0, bed=bed_plane(setups))
    result = export(fmt, cal.calibrated, ws.P, ws.R, surface=ws.surface, setups=setups)
    new = fmt.update(text, result.params, cal.calibrated, str(last)) or result.text
    if MESH_HANDOVER:
        new = fmt.with_bed_mesh(new, result.params, cal.calibrated, setups) or new
    return delta_values(KlipperConfig.read(str(last), new)), cal, exported_mesh(last, new)


#: the export's mesh profile (``[bed_mesh pkmcal]``) loaded where the export hands one over
#: (``--no-mesh``: the values alone)
MESH_HANDOVER = True


def exported_mesh(path: Path, text: str):
    """``f(xy)`` of the export's ``[bed_mesh pkmcal]`` profile as Klipper applies it, or
    None when the export handed none over."""
    from pkmcal.export.bed_mesh import PROFILE
    from pkmcal.io.klipper_data import bed_meshes

    for mesh in bed_meshes(KlipperConfig.read(str(path), text)):
        if mesh.name == PROFILE:
            return mesh_function(mesh)[0]
    return None


def pair_table(sessions: dict, max_days: float | None, limit: int | None = None,
               log=print) -> list:
    rows = []
    fits: dict = {}
    meshes: dict = {}
    for printer, ss in sessions.items():
        for i, a in enumerate(ss):
            for b in ss[i + 1:]:
                days = (b.date - a.date).total_seconds() / 86400
                if max_days is not None and days > max_days:
                    continue
                if limit is not None and len(rows) >= limit:
                    return rows
                key = str(a.path)
                if key not in fits:
                    t0 = time.perf_counter()
                    values, _, mesh = pkmcal_values([a.path])
                    fits[key] = (values, mesh)
                    fits[key + ":t"] = time.perf_counter() - t0
                    fits[key + ":points"] = pkmcal_values([a.path], points_only(a.path))[0]
                    fits[key + ":klipper"] = pkmcal_values([a.path], parameters="klipper")[0]
                if key not in meshes:
                    meshes[key] = mesh_function(a.meshes[0]) if a.meshes else (None, "none")
                mf, words = meshes[key]
                k = rms(residuals(a.values, b))
                p = rms(residuals(fits[key][0], b, fits[key][1]))
                km = rms(residuals(a.values, b, mf)) if mf is not None else None
                p0 = rms(residuals(fits[key + ":points"], b))
                pk = rms(residuals(fits[key + ":klipper"], b))
                rows.append({"printer": printer, "A": str(a.path.relative_to(SHARED)),
                             "B": str(b.path.relative_to(SHARED)), "days": round(days, 2),
                             "rows_B": int(sum(len(s.travel) for s in b.sets)),
                             "klipper_mm": k, "klipper_mesh_mm": km, "pkmcal_mm": p,
                             "pkmcal_points_only_mm": p0, "ratio_points_only": p0 / k,
                             "pkmcal_klipper_set_mm": pk, "ratio_klipper_set": pk / k,
                             "ratio": p / k, "ratio_mesh": (p / km) if km else None,
                             "mesh_words": words, "fit_s": round(fits[key + ":t"], 2)})
                log(_row_text(rows[-1]))
    return rows


def _row_text(r: dict) -> str:
    km = f"{r['klipper_mesh_mm']:.4f}" if r["klipper_mesh_mm"] is not None else "   -  "
    rm = f"{r['ratio_mesh']:.2f}" if r["ratio_mesh"] is not None else "  - "
    return (f"{r['printer']:22s} {Path(r['A']).name[:26]:26s} -> {Path(r['B']).name[:26]:26s} "
            f"{r['days']:6.1f} d {r['rows_B']:4d}  K {r['klipper_mm']:.4f}  K+mesh {km}  "
            f"pkmcal {r['pkmcal_mm']:.4f}  {r['ratio']:.2f}x / {rm}x  (klipper set "
            f"{r['ratio_klipper_set']:.2f}x, points only {r['ratio_points_only']:.2f}x)")


def summary(rows: list) -> dict:
    if not rows:
        return {}
    r = np.array([x["ratio"] for x in rows])
    m = np.array([x["ratio_mesh"] for x in rows if x["ratio_mesh"] is not None])
    km = np.array([x["klipper_mesh_mm"] / x["klipper_mm"] for x in rows
                   if x["klipper_mesh_mm"] is not None])
    r0 = np.array([x["ratio_points_only"] for x in rows])
    rk = np.array([x["ratio_klipper_set"] for x in rows])
    return {"pairs": len(rows), "ratio_median": float(np.median(r)), "ratio_worst": float(r.max()),
            "ratio_points_only_median": float(np.median(r0)),
            "ratio_points_only_worst": float(r0.max()),
            "ratio_klipper_set_median": float(np.median(rk)),
            "ratio_klipper_set_worst": float(rk.max()),
            "ratio_mesh_median": float(np.median(m)) if len(m) else None,
            "ratio_mesh_worst": float(m.max()) if len(m) else None,
            "klipper_mesh_over_klipper_median": float(np.median(km)) if len(km) else None,
            "klipper_mesh_over_klipper_worst": float(km.max()) if len(km) else None}


def points_only(path) -> list:
    """A config's DELTA_CALIBRATE data alone (heights, DELTA_ANALYZE distances), as
    ``calibrate`` reads them: Klipper's own data set (the baseline before the meshes)."""
    from pkmcal.export import controller_format
    from pkmcal.io.klipper_data import delta_calibrate_data

    fmt = controller_format("klipper")
    machine = fmt.to_machine(fmt.parse(Path(path).read_text(), str(path)))
    return delta_calibrate_data(KlipperConfig.read(path), 3, machine.characteristic_length())


def pooled(log=print) -> dict:
    """Points only: the earlier DELTA_CALIBRATE sessions calibrate, the last two are
    predicted (one free offset per session). Sessions as ``calibrate`` counts them (the same
    saved heights in several backups are one session; DELTA_ANALYZE distances join the
    session of the heights they reuse)."""
    from pkmcal.export import controller_format
    from pkmcal.io.klipper_data import klipper_sessions

    paths = [SHARED / p for p in POOLED]
    fmt = controller_format("klipper")
    machine = fmt.to_machine(fmt.parse(paths[-1].read_text(), str(paths[-1])))
    every = klipper_sessions(paths, machine)
    order, files = [], {}
    for d in every.data:
        if d.kind != "probe" or getattr(d, "mesh", None) is not None:
            continue
        name = d.session or "reference"
        if name not in files:
            order.append(name)
            files[name] = Path(d.source.rsplit(" ", 1)[0])
    if len(order) < 4:
        return {}
    fit_names, test_names = order[:-2], order[-2:]
    # the files before the first predicted session's (the fitted sessions and their repeats)
    fit_paths = paths[:paths.index(files[test_names[0]])]
    fitted = klipper_sessions(fit_paths, machine)
    data = [d for d in fitted.data if getattr(d, "mesh", None) is None]
    values, cal, mesh = pkmcal_values(fit_paths, data)
    in_set = pkmcal_values(fit_paths, data, parameters="klipper")[0]
    after = delta_values(KlipperConfig.read(fit_paths[-1]))
    test = [read_session(files[n], meshes=False) for n in test_names]
    k = rms([r for s in test for r in residuals(after, s)])
    p = rms([r for s in test for r in residuals(values, s, mesh)])
    pk = rms([r for s in test for r in residuals(in_set, s)])
    out = {"sessions": order, "fit": fit_names, "fit_files": [p_.name for p_ in fit_paths],
           "test": test_names, "klipper_mm": k, "pkmcal_mm": p, "ratio": p / k,
           "pkmcal_klipper_set_mm": pk, "ratio_klipper_set": pk / k,
           "model": cal.report.get("parameter_set", {}).get("name"),
           "sessions_in_fit": cal.report.get("sessions", {}).get("sessions")}
    log(f"points only, {len(order)} sessions ({', '.join(order)}): sessions 1-{len(fit_names)} "
        f"calibrate ({len(fit_paths)} files), {', '.join(test_names)} predicted: Klipper's "
        f"values after session {len(fit_names)} {k:.4f} mm, pkmcal {p:.4f} mm ({out['model']}),"
        f" ratio {p / k:.2f}; in Klipper's set {pk:.4f} mm, {pk / k:.2f}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pairs", type=int, default=None, help="stop after this many pairs")
    ap.add_argument("--no-write", action="store_true", help="do not write the results file")
    ap.add_argument("--no-pooled", action="store_true", help="skip the points-only test")
    ap.add_argument("--no-mesh", action="store_true",
                    help="evaluate the exported values without the exported mesh profile")
    args = ap.parse_args(argv)
    global MESH_HANDOVER
    MESH_HANDOVER = not args.no_mesh
    if not SHARED.is_dir():
        print(f"skipped: {SHARED} not found (the real printers' files stay outside the "
              "project)")
        return 0
    sessions = {p: [read_session(SHARED / p / f, d) for f, d in ss]
                for p, ss in SESSIONS.items()}
    print(f"next session, pairs at most {MAX_DAYS} days apart (RMS mm over B's rows, one free "
          "offset per data set; ratio pkmcal / Klipper, / Klipper + A's mesh)")
    near = pair_table(sessions, MAX_DAYS, args.pairs)
    s_near = summary(near)
    print(json.dumps(s_near))
    result = {"date": time.strftime("%Y-%m-%d %H:%M"), "pairs_30_days": near,
              "summary_30_days": s_near}
    if args.pairs is None:
        print("\nall pairs")
        every = pair_table(sessions, None, None)
        result.update(pairs_all=every, summary_all=summary(every))
        print(json.dumps(result["summary_all"]))
        if not args.no_pooled:
            print()
            result["pooled_points_only"] = pooled()
    if not args.no_write:
        out = ROOT / "benchmarks" / "next_session.json"
        out.write_text(json.dumps(result, indent=1) + "\n")
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
