"""The answer of a calibration, as a person asks it (issue 36): did it work, how accurate is
the machine now, what changed, what to run next.

:func:`calibration_outcome` reads a :class:`~pkmcal.calibration.Calibration` and returns the
report's ``outcome`` section (JSON-ready; lengths in um, angles in the machine file's unit):

* ``verdict``: the residual test's verdict (:func:`~pkmcal.estimation.acceptance.report_verdict`
  of the report; never "converged" above a failed test);
* ``accuracy``: the machine's accuracy with the machine file's values and with the calibrated
  ones, predicted over its workspace (a printer: the nozzle's height above the bed over its print
  disk) - before: how far the values in force put the tool from where the calibrated model says
  it goes (:func:`~pkmcal.analysis.accuracy.pose_errors`), with the uncertainty of that figure;
  after: the calibrated model's own 1-sigma error from the parameters' covariance
  (:func:`~pkmcal.analysis.prediction.pose_sensitivity`) - and the held-out rows' RMS where the
  calibration kept some out;
* ``same_as_running``: whether the calibrated values equal the machine file's within their
  uncertainty (the result is what the machine already runs);
* ``changes``: the largest changes in the machine file's own terms (per tower with a
  firmware's values: the firmware's keys at its own digits);
* ``next``: the commands to run next;
* ``map``: the data of the report's pictures (a printer's bed: probe points with their
  residuals before and after, the predicted height error over the print disk with the values in
  force and its uncertainty with the new ones; other machines: the workspace's points with
  their error before and after).
"""

from __future__ import annotations

import math

import numpy as np

from ..estimation.acceptance import (
    FAILED_SMALL,
    NOT_TESTED,
    PASSED,
    VERDICT_WORDS,
    report_verdict,
)
from ..instruments.probe import bed_plane
from ..machines.reach import default_workspace
from .accuracy import pose_errors
from .prediction import align_out, pose_sensitivity

__all__ = ["calibration_outcome", "headline"]

#: points of the workspace the accuracy is predicted at
POINTS = 400
#: grid of the bed map (points along x and y)
BED_GRID = 61
#: a calibrated value within this many standard deviations of the machine file's counts as
#: unchanged
UNCHANGED_SIGMA = 1.0


def _um(v) -> float | None:
    v = float(v) * 1e6
    return v if math.isfinite(v) else None


def _stats(v) -> dict:
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    if not v.size:
        return {"rms": None, "max": None}
    return {"rms": _um(np.sqrt(np.mean(v**2))), "max": _um(np.max(np.abs(v)))}


def _covariance(report, n: int) -> np.ndarray | None:
    cov = report.get("covariance") or {}
    C = np.asarray(cov.get("matrix") or [], float)
    return C if C.shape == (n, n) and np.all(np.isfinite(C)) else None


def _sigma(S, C, N=None) -> np.ndarray:
    """1-sigma of ``S du`` per point and coordinate, (K, d), ``du ~ (0, C)``; with the
    unidentifiable directions ``N`` (n, z) what they do to the poses (changes of frames the
    data cannot see) is aligned out first, as in :func:`~pkmcal.analysis.prediction.align_out`.
    """
    S = np.nan_to_num(np.asarray(S, float))
    w, V = np.linalg.eigh((C + C.T) / 2)
    E = S @ (V * np.sqrt(np.clip(w, 0.0, None)))
    if N is not None and N.size:
        E = align_out(E, S @ N)
    return np.sqrt(np.sum(E**2, axis=-1))


def _height_above_bed(bed, P) -> np.ndarray:
    """Heights of positions ``P`` above the bed plane ``bed`` (``(height, tilt_x, tilt_y)``;
    None: z = 0)."""
    b = np.zeros(3) if bed is None else np.asarray(bed, float)
    return P[:, 2] - (b[0] + b[1] * P[:, 0] + b[2] * P[:, 1])


def _on_bed(bed, xy) -> np.ndarray:
    """Points on the bed plane ``bed`` at ``xy``."""
    b = np.zeros(3) if bed is None else np.asarray(bed, float)
    return np.column_stack([xy, b[0] + b[1] * xy[:, 0] + b[2] * xy[:, 1]])


def _probe_data(problem) -> list:
    """The data of a calibration's problem (one file or the parts of a joint fit) whose
    instrument measures heights above the bed (:func:`~pkmcal.instruments.registry.
    measures_bed_height`)."""
    from ..instruments.registry import measures_bed_height as heights

    parts = getattr(problem, "parts", None) or [problem]
    return [p.data for p in parts if getattr(p, "data", None) is not None and heights(p.data)]


def _probe_points(nominal, calibrated, problem, bed) -> dict | None:
    """Probe points (x, y, mm) and their height residuals (measured - predicted, um) with the
    values in force (the bed plane fitted alone, as the before figure of the calibration) and
    with the calibrated values (and the calibrated bed plane ``bed``)."""
    data = _probe_data(problem)
    if not data:
        return None
    xs, ys, before, after = [], [], [], []
    for d in data:
        q = np.asarray(d.q, float)
        z = np.asarray(d.values, float).reshape(len(q), -1)[:, 0]
        fk = calibrated.fk(q)
        P = np.where(fk.converged[:, None], fk.P, np.nan)
        after.append(z - _height_above_bed(bed, P))
        fk0 = nominal.fk(q)
        P0 = np.where(fk0.converged[:, None], fk0.P, np.nan)
        ok = np.all(np.isfinite(P0), axis=1)
        r0 = np.full(len(q), np.nan)
        if ok.sum() >= 3:
            # the values in force with the bed plane fitted alone (heights along z)
            A = np.column_stack([np.ones(ok.sum()), P0[ok, 0], P0[ok, 1]])
            coef = np.linalg.lstsq(A, P0[ok, 2] - z[ok], rcond=None)[0]
            r0[ok] = z[ok] - (P0[ok, 2] - A @ coef)
        before.append(r0)
        xs.append(P[:, 0])
        ys.append(P[:, 1])
    def cat(v, f):
        return [None if not np.isfinite(x) else float(x) * f for x in np.concatenate(v)]
    return {"x_mm": cat(xs, 1e3), "y_mm": cat(ys, 1e3), "before_um": cat(before, 1e6),
            "after_um": cat(after, 1e6)}


def _bed_accuracy(nominal, calibrated, C, problem, workspace, bed) -> tuple[dict, dict]:
    """The printer's accuracy (nozzle height above the bed over the print disk) and its map;
    ``bed``: the calibrated bed plane (the calibration's set-ups)."""
    P = workspace.P[workspace.surface] if workspace.surface is not None else workspace.P
    radius = float(np.max(np.hypot(P[:, 0], P[:, 1])))
    g = np.linspace(-radius, radius, BED_GRID)
    X, Y = np.meshgrid(g, g)
    inside = (np.hypot(X, Y) <= radius).ravel()
    xy = np.column_stack([X.ravel(), Y.ravel()])[inside]
    target = _on_bed(bed, xy)
    eye = np.broadcast_to(np.eye(3), (len(xy), 3, 3))
    with np.errstate(all="ignore"):
        # the values in force command the nozzle to their z = 0; the calibrated model says
        # where it goes
        q = nominal.ik(np.column_stack([xy, np.zeros(len(xy))]), eye)
        fk = calibrated.fk(np.where(np.all(np.isfinite(q), -1)[:, None], q,
                                    calibrated.ik(*calibrated.home)))
    ok = fk.converged & np.all(np.isfinite(q), -1)
    before = np.where(ok, _height_above_bed(bed, fk.P), np.nan)
    sigma = np.full(len(xy), np.nan)
    if C is not None:
        S = pose_sensitivity(calibrated, target, eye)
        sigma = _sigma(S[:, 2:3], C)[:, 0]
    full = np.full(inside.size, np.nan)
    grid_before, grid_after = full.copy(), full.copy()
    grid_before[inside], grid_after[inside] = before * 1e6, sigma * 1e6
    accuracy = {
        "quantity": "nozzle height above the bed",
        "where": f"the print disk (radius {radius * 1e3:.3g} mm, {int(ok.sum())} points)",
        "basis": "predicted",
        "unit": "um",
        "before": {**_stats(before), "lowest": _um(np.nanmin(before)) if ok.any() else None,
                   "highest": _um(np.nanmax(before)) if ok.any() else None,
                   "std": _um(np.sqrt(np.nanmean(sigma**2))) if C is not None else None},
        "after": {**_stats(sigma), "what": "1-sigma uncertainty of the calibrated values"},
    }
    pmap = {"kind": "bed", "unit": "um", "radius_mm": radius * 1e3,
            "grid_mm": (g * 1e3).tolist(),
            "before_um": [None if not np.isfinite(v) else float(v) for v in grid_before],
            "after_std_um": [None if not np.isfinite(v) else float(v) for v in grid_after]}
    points = _probe_points(nominal, calibrated, problem, bed) if problem is not None else None
    if points:
        pmap["points"] = points
    return accuracy, pmap


def _measured_readings(problem) -> np.ndarray | None:
    """The joint readings of the measured rows (one file or every part of a joint fit)."""
    parts = getattr(problem, "parts", None) or [problem]
    qs = [np.asarray(p.data.q, float) for p in parts
          if getattr(getattr(p, "data", None), "q", None) is not None]
    qs = [q for q in qs if q.ndim == 2]
    if not qs or len({q.shape[1] for q in qs}) != 1:
        return None
    return np.concatenate(qs)


def _measured_points(nominal, calibrated, C, N, problem) -> dict | None:
    """Per measured row: where the calibrated model puts the tool for its readings, how far
    the machine file's model is from it there (frames aligned as over the workspace), and the
    calibrated model's 1-sigma there (um)."""
    q = _measured_readings(problem) if problem is not None else None
    if q is None:
        return None
    with np.errstate(all="ignore"):
        fk = calibrated.fk(q)
        ok = fk.converged & np.all(np.isfinite(fk.P), -1)
        if ok.sum() < 3:
            return None
        P, R = fk.P[ok], fk.R[ok]
        dp, _, good, _ = pose_errors(calibrated, nominal, P, R,
                                     align=N is not None and N.size > 0)
    sigma = np.full(len(P), np.nan)
    if C is not None:
        sigma = np.sqrt(np.sum(_sigma(pose_sensitivity(calibrated, P, R), C, N)[:, :3] ** 2,
                               axis=1))

    def um(v):
        return [None if not np.isfinite(x) else float(x) * 1e6 for x in v]

    return {"before_um": um(np.where(good, dp, np.nan)), "after_um": um(sigma)}


def _workspace_accuracy(nominal, calibrated, C, N, workspace) -> tuple[dict, dict]:
    """Position error over the workspace: the machine file's model against the calibrated
    one (frames aligned where the data fix none), and the calibrated model's 1-sigma."""
    P, R = workspace.P, workspace.R
    gauge = N is not None and N.size > 0
    with np.errstate(all="ignore"):
        dp, dr, ok, _ = pose_errors(calibrated, nominal, P, R, align=gauge)
    sigma = np.full(len(P), np.nan)
    if C is not None:
        S = pose_sensitivity(calibrated, P, R)
        sigma = np.sqrt(np.sum(_sigma(S, C, N)[:, :3] ** 2, axis=1))
    accuracy = {
        "quantity": "position error",
        "where": workspace.description + f" ({int(ok.sum())} points)",
        "basis": "predicted",
        "unit": "um",
        "before": {**_stats(dp[ok]),
                   "std": _um(np.sqrt(np.nanmean(sigma**2))) if C is not None else None},
        "after": {**_stats(sigma), "what": "1-sigma uncertainty of the calibrated values"},
        **({"aligned": "frames the data cannot fix aligned first (SPEC 5)"} if gauge else {}),
    }
    pmap = {"kind": "workspace", "unit": "um",
            "x_mm": (P[:, 0] * 1e3).tolist(), "y_mm": (P[:, 1] * 1e3).tolist(),
            "z_mm": (P[:, 2] * 1e3).tolist(),
            "before_um": [None if not np.isfinite(v) else float(v) * 1e6 for v in dp],
            "after_um": [None if not np.isfinite(v) else float(v) * 1e6 for v in sigma]}
    return accuracy, pmap


def _held_out(report) -> dict | None:
    """The held-out rows' RMS before and after (one file's section, or each file's)."""
    v = report.get("validation")
    if not isinstance(v, dict):
        return None
    if v.get("before_rms") is not None:
        return {"before_rms": v["before_rms"], "after_rms": v.get("after_rms"),
                "unit": v.get("unit", "um"), "rows": v.get("held_out"), "of": v.get("of", "")}
    files = [f["validation"] for f in report.get("files") or [] if "validation" in f]
    if files:
        return {"files": [{"before_rms": f.get("before_rms"), "after_rms": f.get("after_rms"),
                           "unit": f.get("unit", "um"), "rows": f.get("held_out"),
                           "of": f.get("of", "")} for f in files]}
    return None


def _firmware_changes(nominal, calibrated, report) -> list[dict]:
    """Per tower values of a firmware's configuration, when the machine has them."""
    values = getattr(calibrated, "firmware_values", None)
    if values is None:
        return []
    before, after = nominal.firmware_values(), values()
    units = report.get("units") or {}
    from ..units import ANGLE, LENGTH

    fl, fa = LENGTH[units.get("length", "mm")], ANGLE[units.get("angle", "deg")]
    names = getattr(calibrated, "TOWER_SECTIONS", ("tower 1", "tower 2", "tower 3"))
    out = []
    for key, kind in (("position_endstop", "length"), ("arm_length", "length"),
                      ("angle", "angle"), ("radius", "length")):
        if key == "radius" and np.ptp(before[key]) == 0 and np.ptp(after[key]) == 0:
            # one radius for every tower: the firmware's one value
            a, b = float(before[key][0]), float(after[key][0])
            out.append({"name": "delta_radius", "unit": units.get("length", ""),
                        "before": a / fl, "after": b / fl, "change": (b - a) / fl})
            continue
        for i, tower in enumerate(names):
            a, b = float(before[key][i]), float(after[key][i])
            f = fl if kind == "length" else fa
            out.append({"name": f"{tower} {key}", "unit": units.get(kind, ""),
                        "before": a / f, "after": b / f, "change": (b - a) / f})
    return out


def _changes(calibration, limit: int = 5) -> list[dict]:
    """The largest changes (scaled) of the machine's parameters that the data determine one
    by one, as the machine file names its values; where none is (a gauge moves them all), the
    largest with the null space's pivots held (:func:`~pkmcal.report.html.gauge_fixed`)."""
    from ..report.html import gauge_fixed, gauge_parameters

    report = calibration.report
    gauge = gauge_parameters(report)
    own = set(calibration.machine.parameters.names)
    params = [p for p in calibration.params if not p["fixed"] and p["name"] in own]
    top = sorted((p for p in params if p["name"] not in gauge),
                 key=lambda p: -p["scaled_change"])[:limit]
    out = [{"name": p["name"], "unit": p["unit"], "before": p["nominal"],
            "after": p["identified"], "change": p["change"], "std": p["std"]} for p in top]
    fixed = gauge_fixed(report) if not out else None
    if fixed:
        held, rows = fixed
        by_name = {p["name"]: p for p in params}
        scale = {p["name"]: p["scaled_change"] / abs(p["change"]) if p["change"] else 0.0
                 for p in params}
        rows = sorted((r for r in rows if r["name"] in by_name),
                      key=lambda r: -abs(r["change"]) * scale.get(r["name"], 0.0))[:limit]
        out = [{"name": r["name"], "unit": r["unit"], "before": by_name[r["name"]]["nominal"],
                "after": by_name[r["name"]]["nominal"] + r["change"], "change": r["change"],
                "std": r["std"], "held": held} for r in rows]
    return out


def _same_as_running(calibration) -> dict:
    """Whether every change is within :data:`UNCHANGED_SIGMA` of its standard deviation."""
    params = [p for p in calibration.params if not p["fixed"] and ":" not in p["name"]
              and p["std"] is not None and p["std"] > 0]
    if not params:
        return {"same": False}
    z = max(abs(p["change"]) / p["std"] for p in params)
    return {"same": bool(z < UNCHANGED_SIGMA), "largest_change_over_std": float(z)}


def _next_steps(calibration, output: str | None, verdict, poor: bool) -> list[dict]:
    """The commands to run next."""
    out = output or "calibrated.yaml"
    machine = calibration.calibrated
    steps = []
    levels = [g for g in (calibration.report.get("noise_model") or {}).get("groups") or []
              if g.get("status") == "estimated"]
    if verdict.status == FAILED_SMALL and len(levels) == 1:
        g = levels[0]
        steps.append({"command": f"pkmcal calibrate ... --noise {g['sigma']:.3g}{g['unit']}",
                      "why": "the residuals are a little larger than the assumed noise: if "
                             "the instrument is that noisy, say so (the estimate from these "
                             "data)"})
    elif verdict.status == FAILED_SMALL:
        steps.append({"command": "pkmcal calibrate ... --noise LEVEL",
                      "why": "the residuals are a little larger than the assumed noise: if "
                             "the instruments are that noisy, give their levels (the "
                             "report's Noise levels has the estimates)"})
    elif verdict.status not in (PASSED, NOT_TESTED):
        steps.append({"command": "pkmcal calibrate ... --parameters full",
                      "why": "the residual test failed: fit every per-tower quantity (a "
                             "leaning tower), or check the noise, the columns and units"}
                     if getattr(machine, "PARAMETER_SETS", None) else
                     {"command": "pkmcal identifiability MACHINE DATA",
                      "why": "the residual test failed: check --noise, the columns and units "
                             "and the machine file (see the warning) before using the result"})
    formats = _export_formats(machine)
    if formats:
        to = formats[0] if len(formats) == 1 else "FORMAT"
        steps.append({"command": f"pkmcal export {out} --to {to} -o FILE",
                      "why": "hand the values to the controller"
                             + (f" (FORMAT: {', '.join(formats)})" if len(formats) > 1 else "")})
    steps.append({"command": f"pkmcal compensate {out} TARGETS.csv -o COMMANDS.csv",
                  "why": "joint commands for your targets with the calibrated geometry"})
    if poor:
        steps.append({"command": f"pkmcal select-poses {out} -n 20 -o plan.csv",
                      "why": "the data determine some parameters weakly: measure where they "
                             "tell most (or add another instrument)"})
    return steps


def _export_formats(machine) -> list[str]:
    from ..export import load_formats

    return [name for name, fmt in load_formats().items() if fmt.applies(machine) is None]


def headline(outcome: dict) -> str:
    """The outcome in one sentence (the console's and the HTML's first line).

    Parameters
    ----------
    outcome : dict
        The report's ``outcome`` section.

    Returns
    -------
    str
        E.g. ``"Calibration failed the residual test: ..."``.
    """
    v = outcome["verdict"]
    return v["headline"]


def calibration_outcome(calibration, output: str | None = None, n: int = POINTS,
                        rng=0, setups=None) -> dict:
    """The report's ``outcome`` section of a calibration (see the module docstring).

    Parameters
    ----------
    calibration : Calibration
        A calibration (:func:`~pkmcal.calibration.calibrate`).
    output : str, optional
        The calibrated file's name, used in the next commands.
    n : int, optional
        Points of the workspace.
    rng : int or numpy.random.Generator, optional
        Seed of the workspace points.
    setups : Setups, optional
        The set-ups of the nominal machine file: a printer's print disk lies on its bed
        (:func:`~pkmcal.instruments.probe.bed_plane`); the calibrated bed is the
        calibration's (:attr:`~pkmcal.calibration.Calibration.setups`).

    Returns
    -------
    dict
        JSON-ready: ``verdict``, ``accuracy``, ``held_out_rows``, ``same_as_running``, ``changes``,
        ``firmware``, ``next``, ``map``.
    """
    report = calibration.report
    nominal, calibrated = calibration.machine, calibration.calibrated
    verdict = report_verdict(report)
    C = _covariance(report, len(calibrated.parameters.names))
    N = np.asarray((report.get("covariance") or {}).get("null_space") or np.zeros((0, 0)),
                   float)
    N = N if C is not None and N.ndim == 2 and N.shape[0] == C.shape[0] else None
    problem = getattr(calibration.result, "problem", None)
    # a printer's print disk is the one its configuration names (the machine file's)
    own = getattr(nominal, "print_workspace", None)
    try:
        if own is not None:
            accuracy, pmap = _bed_accuracy(nominal, calibrated, C, problem,
                                           own(n=n, rng=rng, bed=bed_plane(setups)),
                                           bed_plane(calibration.setups))
        else:
            accuracy, pmap = _workspace_accuracy(nominal, calibrated, C, N,
                                                 default_workspace(calibrated, n=n, rng=rng))
            measured = _measured_points(nominal, calibrated, C, N, problem)
            if measured:
                pmap["measured_points"] = measured
    except Exception as exc:        # noqa: BLE001 - the answer's figures are best effort
        accuracy, pmap = {"quantity": "position error", "unit": "um", "basis": "none",
                          "why": f"not predicted: {exc}"}, None
    poor = bool((report.get("poorly_determined") or {}).get("parameters"))
    same = _same_as_running(calibration)
    words = VERDICT_WORDS[verdict.status]
    if verdict.status == PASSED:
        head = "Calibration passed: the residuals agree with the assumed noise"
    elif verdict.status == NOT_TESTED:
        head = f"Residuals not tested against the noise: {verdict.why}"
    elif verdict.status == FAILED_SMALL:
        head = (f"Calibration failed the residual test by a little: the residuals are "
                f"{verdict.noise_ratio:.3g} times the assumed noise (the noise is a little "
                "larger than assumed, or the model lacks a small effect)")
    else:
        head = (f"Calibration {words}: the residuals are {verdict.noise_ratio:.3g} times "
                "the assumed noise; do not use the result before checking why")
    out = {
        "verdict": {"status": verdict.status, "words": words, "headline": head,
                    "sentence": verdict.sentence()},
        "accuracy": accuracy,
        "same_as_running": same,
        "changes": _changes(calibration),
        "next": _next_steps(calibration, output, verdict, poor),
    }
    firmware = _firmware_changes(nominal, calibrated, report)
    if firmware:
        out["firmware"] = firmware
    held = _held_out(report)
    if held:
        out["held_out_rows"] = held
    if pmap is not None:
        out["map"] = pmap
    return out
