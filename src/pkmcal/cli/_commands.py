"""Implementations of the ``pkmcal`` commands (imported lazily by :mod:`pkmcal.cli`).

Every command validates its inputs and options first, computes, and writes its output files
only at the very end, atomically; problems are raised as :class:`~pkmcal.errors.InputError`
(exit code 2 in :func:`pkmcal.cli.main`).
"""

from __future__ import annotations

import datetime
import json
import math
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import (
    atomic_write_text,
    load_machine,
    machine_to_text,
    parse_machine,
    read_constraint_link,
    read_joints,
    read_poses,
    read_table,
    write_joints,
    write_poses,
)
from ..io.machine_file import DEFAULT_UNITS
from ..units import ANGLE, LENGTH, parse_quantity
from ._console import console, error, warning

# --------------------------------------------------------------------------------------------
# shared helpers
# --------------------------------------------------------------------------------------------


def load_machine_arg(spec: str):
    """The machine named on the command line: a file, or ``default`` (embedded Hexa Slide)."""
    if spec == "default":
        from ..machines import default_hexaslide

        machine = default_hexaslide()
        machine.file_units = dict(DEFAULT_UNITS)
        machine.source = "default"
        machine.calibration_info = None
        return machine
    return load_machine(spec)


def _machine_inputs(spec: str) -> list[Path]:
    return [] if spec == "default" else [Path(spec)]


def check_outputs(outputs: list[Path], inputs: list[Path]) -> None:
    """Refuse outputs whose directory is missing, that are directories, that coincide, or that
    would overwrite an input file (input files are never modified)."""
    seen: dict[str, Path] = {}
    for out in outputs:
        directory = out.parent if str(out.parent) else Path(".")
        if not directory.is_dir():
            raise InputError(f"{out}: the output directory {directory} does not exist")
        if out.is_dir():
            raise InputError(f"{out}: is a directory, expected a file name")
        key = os.path.realpath(out)
        if key in seen:
            raise InputError(f"{out}: used for two outputs ({seen[key]} and {out})")
        seen[key] = out
        for inp in inputs:
            if inp.exists() and out.exists() and os.path.samefile(inp, out):
                raise InputError(f"{out}: the output would overwrite the input file {inp}; "
                                 "choose another name")


def _units(machine) -> dict:
    return dict(getattr(machine, "file_units", None) or DEFAULT_UNITS)


def _rows_text(rows, limit: int = 10) -> str:
    rows = [int(r) for r in rows]
    return ", ".join(map(str, rows[:limit])) + (" ..." if len(rows) > limit else "")


def _finite_or_none(value):
    """JSON-safe: NaN and infinities become null, numpy scalars become Python numbers."""
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    if isinstance(value, np.ndarray):
        return _finite_or_none(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def _table(*columns, title=None, justify=None, show_header=True):
    from rich.table import Table

    table = Table(title=title, title_justify="left", show_edge=False, pad_edge=False,
                  show_header=show_header)
    for i, col in enumerate(columns):
        table.add_column(col, justify=(justify or {}).get(i, "left"))
    return table


# --------------------------------------------------------------------------------------------
# demo, bench
# --------------------------------------------------------------------------------------------


def _optional_module(name: str, what: str):
    import importlib

    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name == name:
            error(f"{what} is not available in this installation (module {name} is missing)")
            return None
        raise


def run_demo(outdir: Path) -> None:
    module = _optional_module("pkmcal.demo", "the demo")
    if module is None:
        raise SystemExit(1)
    if outdir.exists() and not outdir.is_dir():
        raise InputError(f"{outdir}: exists and is not a directory")
    outdir.mkdir(parents=True, exist_ok=True)
    result = module.run_demo(outdir)
    out = console()
    table = _table("quantity", "before calibration", "after calibration",
                   title="pkmcal demo (embedded Hexa Slide)")
    for row in result.rows:
        table.add_row(*map(str, row))
    out.print(table)
    for note in getattr(result, "notes", []) or []:
        out.print(f"note: {note}", markup=False)
    files = list(getattr(result, "files", []) or [])
    if files:
        out.print("files:")
        for f in files:
            out.print(f"  {f}", markup=False)


def run_bench(json_output: bool) -> int:
    module = _optional_module("pkmcal.bench", "the benchmark suite")
    if module is None:
        return 1
    results = list(module.run_all())
    ok = all(bool(r.get("ok")) for r in results)
    if json_output:
        print(json.dumps(_finite_or_none(results), indent=2))
        return 0 if ok else 1
    table = _table("benchmark", "value", "unit", "target", "ok", title="pkmcal bench",
                   justify={1: "right"})
    for r in results:
        value = r.get("value")
        shown = f"{value:.4g}" if isinstance(value, (int, float)) else str(value)
        table.add_row(str(r.get("name")), shown, str(r.get("unit", "")),
                      str(r.get("target", "")),
                      "[green]yes[/green]" if r.get("ok") else "[red]NO[/red]")
    console().print(table)
    return 0 if ok else 1


# --------------------------------------------------------------------------------------------
# simulate
# --------------------------------------------------------------------------------------------


def _deviations(machine, which: str, rng) -> np.ndarray:
    params = machine.parameters
    if which == "none":
        return np.zeros(len(params))
    if which == "paper-table1":
        if machine.kind != "hexaslide":
            raise InputError(f"--deviations paper-table1 applies to hexaslide machines, not "
                             f"{machine.kind}")
        from ..machines import paper_table1_deviations

        return paper_table1_deviations(params)
    kinds = np.array(params.kinds)
    size = np.where(kinds == "length", 2e-3, np.where(kinds == "angle", 0.02, 1e-3))
    return rng.uniform(-1.0, 1.0, len(params)) * size


def run_simulate(machine_spec: str, output: Path, scenario: str, poses: int, noise: str,
                 lc_error: str, seed: int, deviations: str, truth: Path | None) -> None:
    noise_m = parse_quantity(noise, "length", "--noise")
    if not noise_m >= 0:
        raise InputError(f"--noise: must be >= 0, got {noise}")
    lc_error_m = parse_quantity(lc_error, "length", "--lc-error")
    machine = load_machine_arg(machine_spec)
    check_outputs([output] + ([truth] if truth else []), _machine_inputs(machine_spec))
    if scenario != "constraint-link":
        raise InputError(f"--scenario {scenario}: not available for {machine.kind} machines yet "
                         "(available: constraint-link)")
    lc = machine.constraint_link_length
    if lc is None:
        raise InputError(f"{machine.source}: constraint_link: the machine has no constraint-link "
                         "length; add `constraint_link: {length: ...}` to the machine file")
    lc_true = lc - lc_error_m
    if not lc_true > 0:
        raise InputError(f"--lc-error: the true link length {lc_true * 1e3:.6g} mm is not "
                         "positive")
    rng = np.random.default_rng(seed)
    du = _deviations(machine, deviations, rng)
    true = machine.with_parameters(machine.u + du)
    true.constraint_link_length = lc_true
    true.name = f"simulated true machine ({deviations} deviations) of {machine.name or 'MACHINE'}"
    from ..measurements import simulate_constraint_link

    data = simulate_constraint_link(true, poses, noise_m, link_length=lc_true, rng=rng)
    units = _units(machine)
    truth_text = None
    if truth is not None:
        truth_text = machine_to_text(true, units)
        parse_machine(truth_text, str(truth))
    # outputs, at the very end
    write_joints(output, data.q, unit=units["length"], extra={"passive": data.passive + 1})
    if truth is not None:
        atomic_write_text(truth, truth_text)
    out = console()
    table = _table("", "", title="pkmcal simulate", show_header=False)
    table.add_row("machine", f"{machine.source} ({machine.kind})")
    table.add_row("scenario", f"{scenario}, {poses} poses on |P| = {lc_true / LENGTH['mm']:.6g} "
                  "mm (true link)")
    table.add_row("deviations", deviations)
    table.add_row("encoder noise", f"{noise_m * 1e6:.4g} um (seed {seed})")
    if lc_error_m:
        table.add_row("Lc error", f"machine file says {lc / LENGTH['mm']:.6g} mm, true link "
                      f"{lc_true / LENGTH['mm']:.6g} mm")
    out.print(table)
    out.print(f"wrote {output}" + (f" and {truth}" if truth else ""), markup=False)


# --------------------------------------------------------------------------------------------
# calibrate
# --------------------------------------------------------------------------------------------


def measurement_kind(path: Path, header: list[str], machine) -> str:
    """Measurement type from the columns of a data file."""
    has = lambda base: any(n == base or n.startswith(base + "_") for n in header)
    if has("mx") or has("my") or has("mz"):
        kind = "tracker"
    elif has("x") or has("y") or has("z") or "qw" in header:
        kind = "pose"
    elif has("q1"):
        kind = "constraint-link"
    else:
        raise InputError(f"{path}: cannot tell the measurement type from the columns "
                         f"({', '.join(header)}): constraint-link data need q1_mm..q"
                         f"{machine.n_joints}_mm (and optionally passive)")
    if kind != "constraint-link":
        raise InputError(f"{path}: {kind} measurements of a {machine.kind} cannot be calibrated "
                         "yet; this version calibrates from constraint-link data (q1..q"
                         f"{machine.n_joints} readings, optional passive column)")
    return kind


def _parameter_table(result, machine, link_length, units):
    """Rows of the report's parameter list, in the machine file's units."""
    fl, fa = LENGTH[units["length"]], ANGLE[units["angle"]]
    nominal_of = dict(zip(machine.parameters.names, machine.u, strict=True))
    nominal_of["link.length"] = link_length
    rows = []
    params = result.parameters
    for i, (name, kind) in enumerate(zip(params.names, params.kinds, strict=True)):
        f = fl if kind == "length" else fa if kind == "angle" else 1.0
        unit = units["length"] if kind == "length" else units["angle"] if kind == "angle" \
            else "1"
        nominal = nominal_of.get(name, float("nan"))
        fixed = bool(params.fixed[i])
        rows.append({
            "name": name, "kind": kind, "unit": unit,
            "nominal": nominal / f, "identified": result.x[i] / f,
            "change": (result.x[i] - nominal) / f,
            "std": None if fixed else result.std[i] / f,
            "fixed": fixed,
            "scaled_change": abs(result.x[i] - nominal) / result.scales[i],
        })
    return rows


def run_calibrate(machine_spec: str, data_path: Path, output: Path, method: str, noise: str,
                  estimate_lc: bool | None, json_output: bool) -> int:
    sigma = parse_quantity(noise, "length", "--noise")
    if not sigma > 0:
        raise InputError(f"--noise: must be > 0 (the standard deviation of the encoder "
                         f"noise), got {noise}")
    if output.suffix.lower() == ".json":
        raise InputError(f"{output}: the calibrated machine is a YAML file; choose a name "
                         "ending in .yaml (the JSON report is written beside it)")
    report_path = output.with_suffix(".json")
    machine = load_machine_arg(machine_spec)
    check_outputs([output, report_path], [data_path] + _machine_inputs(machine_spec))
    header, _ = read_table(data_path)
    kind = measurement_kind(data_path, header, machine)
    data = read_constraint_link(data_path, machine)

    from ..calibration import calibrate_constraint_link

    try:
        result = calibrate_constraint_link(machine, data, method=method, sigma_m=sigma,
                                           estimate_link_length=estimate_lc)
    except InputError:
        raise
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise InputError(f"{data_path}: calibration failed: {exc}") from None
    if not result.success or not np.all(np.isfinite(result.x)):
        error(f"calibration did not converge: {result.message} (after {result.nit} "
              "iterations); no file written")
        return 1

    units = _units(machine)
    fl = LENGTH[units["length"]]
    calibrated = result.extras["machine"]
    calibrated.name = f"{machine.name} (calibrated)" if machine.name else "calibrated machine"
    # FK start of the calibrated file: the input machine's home (a central pose of the working
    # assembly mode) rather than the first measured pose, which may sit at the workspace edge
    home_P, home_R = machine.home
    if np.all(np.isfinite(calibrated.ik(home_P, home_R))):
        calibrated.home = (home_P, home_R)
    date = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    params = _parameter_table(result, machine, data.link_length, units)
    r = np.asarray(result.residuals, float)
    r_m = r * sigma
    rank = int(result.rank)
    n_free = int(np.sum(result.parameters.free))
    s = np.asarray(result.singular_values, float)
    unidentifiable = list(result.extras.get("unidentifiable", []))
    dropped = [int(v) for v in np.asarray(result.extras.get("dropped_rows", []))]
    lc_index = result.parameters.names.index("link.length") \
        if "link.length" in result.parameters.names else None
    lc_estimated = lc_index is not None and not bool(result.parameters.fixed[lc_index])
    lc = float(result.extras.get("link_length", data.link_length))
    residual_what = {"ml": "all joint readings", "ik": "passive joint readings",
                     "fk": "computed link length |P| - Lc"}[method]
    report = {
        "pkmcal_report": 1,
        "command": "calibrate",
        "date": date,
        "machine_file": str(getattr(machine, "source", machine_spec)),
        "data_file": str(data_path),
        "calibrated_file": str(output),
        "measurement": kind,
        "method": method,
        "units": units,
        "measurements": len(data),
        "dropped_rows": dropped,
        "noise_sigma_um": sigma * 1e6,
        "link_length": {"value": lc / fl, "assumed": data.link_length / fl,
                        "unit": units["length"], "estimated": lc_estimated,
                        "std": params[lc_index]["std"] if lc_estimated else None},
        "convergence": {"success": bool(result.success), "status": int(result.status),
                        "message": result.message, "iterations": int(result.nit),
                        "evaluations": int(result.nfev)},
        "residuals": {
            "of": residual_what,
            "count": int(r.size),
            "rms_um": float(np.sqrt(np.mean(r_m**2)) * 1e6) if r.size else None,
            "max_abs_um": float(np.max(np.abs(r_m)) * 1e6) if r.size else None,
            "rms_per_column_um": (np.sqrt(np.mean(r_m**2, axis=0)) * 1e6).tolist()
            if r.ndim == 2 and r.shape[1] > 1 else None,
            "residual_variance": float(result.residual_variance),
            "estimated_noise_um": float(np.sqrt(result.residual_variance) * sigma * 1e6)
            if np.isfinite(result.residual_variance) else None,
            "dof": int(result.dof),
        },
        "identifiability": {
            "free_parameters": n_free,
            "identifiable": rank,
            "unidentifiable": [d.as_dict() for d in unidentifiable],
            "condition_number": float(s[0] / s[rank - 1]) if rank else None,
            "singular_values": s.tolist(),
        },
        "parameters": [{k: v for k, v in p.items() if k != "scaled_change"} for p in params],
    }
    metadata = {
        "method": method,
        "date": date,
        "data": str(data_path),
        "machine": str(getattr(machine, "source", machine_spec)),
        "measurements": len(data),
        "rms_residual_um": report["residuals"]["rms_um"],
        "identifiable": rank,
        "free_parameters": n_free,
        "unidentifiable": [f"{d.dimension} x {d.name}" for d in unidentifiable],
        "link_length_estimated": lc_estimated,
        "report": report_path.name,
    }
    yaml_text = machine_to_text(calibrated, units, calibration=metadata)
    parse_machine(yaml_text, str(output))   # the calibrated file must load back
    json_text = json.dumps(_finite_or_none(report), indent=2, allow_nan=False) + "\n"
    # outputs, at the very end
    atomic_write_text(report_path, json_text)
    atomic_write_text(output, yaml_text)

    if dropped:
        warning(f"{data_path}: {len(dropped)} row(s) left out (no pose from the five active "
                f"readings and the link with the start geometry): {_rows_text(dropped)}")
    if json_output:
        print(json_text, end="")
    else:
        _print_calibration(report, params, data_path, output, report_path, machine)
    return 0


def _print_calibration(report, params, data_path, output, report_path, machine) -> None:
    out = console()
    res, ident, conv = report["residuals"], report["identifiability"], report["convergence"]
    lc = report["link_length"]
    table = _table("", "", title=f"pkmcal calibrate: {machine.source} with {data_path}",
                   show_header=False)
    table.add_row("measurement", f"{report['measurement']}, {report['measurements']} poses")
    table.add_row("method", {"ml": "ml (maximum likelihood, all readings noisy)",
                             "ik": "ik (paper 3.4.1, inverse kinematics of the passive chain)",
                             "fk": "fk (paper 3.4.2, spread of the link length)"}
                  [report["method"]])
    table.add_row("identifiable", f"{ident['identifiable']} of {ident['free_parameters']} free "
                  "parameter directions")
    for d in ident["unidentifiable"]:
        table.add_row("not identifiable", f"{d['dimension']} x {d['name']}: {d['description']}")
    rms = res["rms_um"]
    noise = res["estimated_noise_um"]
    table.add_row("RMS residual", f"{rms:.4g} um ({res['of']}; assumed noise "
                  f"{report['noise_sigma_um']:.4g} um"
                  + (f", estimated {noise:.3g} um)" if noise is not None else ")"))
    table.add_row("convergence", f"{conv['message']} ({conv['iterations']} iterations)")
    if lc["estimated"]:
        std = f" +/- {lc['std']:.3g} {lc['unit']}" if lc["std"] is not None else ""
        table.add_row("link length Lc", f"{lc['value']:.9g} {lc['unit']} (estimated{std}; "
                      f"machine file {lc['assumed']:.9g} {lc['unit']})")
    else:
        table.add_row("link length Lc", f"{lc['value']:.9g} {lc['unit']} (fixed: machine file)")
    out.print(table)

    top = sorted((p for p in params if not p["fixed"]), key=lambda p: -p["scaled_change"])[:10]
    changes = _table("parameter", "nominal", "identified", "change", "std", "",
                     title="largest parameter changes", justify={1: "right", 2: "right",
                                                                 3: "right", 4: "right"})
    for p in top:
        micro = "um" if p["kind"] == "length" else "urad"
        f = (1e3 if p["unit"] == "mm" else 1e6) if p["kind"] == "length" else \
            (math.pi / 180 * 1e6 if p["unit"] == "deg" else 1e6)
        std = f"{p['std'] * f:.3g}" if p["std"] is not None else "fixed"
        changes.add_row(p["name"], f"{p['nominal']:.6f} {p['unit']}",
                        f"{p['identified']:.6f} {p['unit']}", f"{p['change'] * f:+.4g}", std,
                        micro)
    out.print(changes)
    if ident["unidentifiable"]:
        out.print("note: the data do not fix the directions listed as not identifiable; the "
                  "changes are the smallest ones (scaled) that fit the data, and std is for "
                  "the identifiable part.", markup=False)
    out.print(f"wrote {output} and {report_path}", markup=False)


# --------------------------------------------------------------------------------------------
# fk, ik
# --------------------------------------------------------------------------------------------


def run_fk(machine_spec: str, joints: Path, output: Path) -> None:
    machine = load_machine_arg(machine_spec)
    check_outputs([output], [joints] + _machine_inputs(machine_spec))
    q, rows, _ = read_joints(joints, machine.n_joints)
    result = machine.fk(q)
    result.raise_if_failed(what=f"{joints}: forward kinematics", rows=rows)
    units = _units(machine)
    write_poses(output, result.P, result.R, units["length"], units["angle"])
    console().print(f"{len(q)} pose(s) written to {output} ({units['length']}, "
                    f"{units['angle']})", markup=False)


def run_ik(machine_spec: str, poses: Path, output: Path) -> None:
    machine = load_machine_arg(machine_spec)
    check_outputs([output], [poses] + _machine_inputs(machine_spec))
    P, R, rows = read_poses(poses)
    q = machine.ik(P, R)
    bad = ~np.all(np.isfinite(q), axis=1)
    if bad.any():
        chains = np.flatnonzero((~np.isfinite(q[bad])).any(axis=0)) + 1
        raise InputError(f"{poses}: {int(bad.sum())} pose(s) cannot be reached by the machine "
                         f"(no real inverse kinematics, chain(s) {', '.join(map(str, chains))})"
                         f", row(s) {_rows_text(rows[bad])}")
    units = _units(machine)
    write_joints(output, q, unit=units["length"])
    console().print(f"{len(q)} joint vector(s) written to {output} ({units['length']})",
                    markup=False)
