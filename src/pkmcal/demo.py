"""The main job on the embedded defaults, no input needed (``pkmcal demo``).

Every case runs with fixed seeds and states them with its settings (:attr:`DemoResult.settings`,
printed first by ``pkmcal demo`` and written to ``summary.json``).

Seed 000 section 4 on our default Hexa Slide (:func:`hexaslide_case`, seed
:data:`HEXASLIDE_SEED`: seed 0 of the table on the researcher's page): the true machine is
nominal + Table 1 deviations; constraint-link data are simulated; the maximum-likelihood
calibration identifies the geometry; accuracy over the 0.1 m workspace cube is compared before
and after; then the paper's Fig. 5 (accuracy vs encoder noise) and Fig. 6 (accuracy vs error in
the assumed link length) are reproduced as plots.

Seed 001 on our default Delta (:func:`delta_demo`): random errors of about 1 mm / 0.5 deg
(fixed seed), a laser tracker 2.5 m away (:func:`default_tracker_pose`) measures the 3x3x3
grid with Leica-type noise; the errors are identified jointly with the tracker pose and with
the paper's two-step method; both are checked on held-out points (a 4x4x3 grid offset from
the calibration grid) and by the distance ratio of neighbouring points (the paper's Fig. 6).

Seed 003 on the embedded cubic 6-UPU device (:func:`clearance_demo`): the paper's case study,
the platform on a circle r = 100 mm at z = 410 mm at 10 rad/s, 4.8 kg, 500 N cutting force
down, joint clearance c_b = 10 um; the link forces (Fig. 6) and the pose errors (Fig. 7) along
the circle, as ``pkmcal errors cubic`` computes them.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class DemoResult:
    """What the demo found: its settings (seeds, noise, poses, deviations), table rows
    ``(quantity, before, after)``, files, notes."""

    rows: list[tuple[str, str, str]] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    figures: dict = field(default_factory=dict)
    settings: list[str] = field(default_factory=list)


NOISE_LEVELS = (0.1e-6, 0.3e-6, 1e-6, 3e-6, 10e-6)
LC_ERRORS = (1e-6, 3e-6, 10e-6, 30e-6, 100e-6)
#: simulated calibrations per value of Figs. 5 and 6
SWEEP_RUNS = 10

#: the Hexa Slide case (seed 000 section 4): seed of the simulated measurements (the
#: researcher's page's table quotes seeds 0-9; the demo runs this one), measurement poses,
#: encoder noise (m; simulated and assumed), workspace poses of the accuracy figures and
#: their seed
HEXASLIDE_SEED = 0
HEXASLIDE_POSES = 150
HEXASLIDE_NOISE = 2e-6
WORKSPACE_POSES = 500
WORKSPACE_SEED = 0


def hexaslide_case(seed: int = HEXASLIDE_SEED) -> dict:
    """The demo's Hexa Slide case: the default machine + seed 000's Table 1 deviations,
    :data:`HEXASLIDE_POSES` constraint-link poses simulated with ``rng=seed`` noise-free and
    with :data:`HEXASLIDE_NOISE` of encoder noise, each calibrated by maximum likelihood (told
    that noise); accuracy over :data:`WORKSPACE_POSES` poses of the 0.1 m cube (seed
    :data:`WORKSPACE_SEED`), after aligning the frames the data cannot fix.

    Parameters
    ----------
    seed : int, optional
        Seed of the simulated measurements.

    Returns
    -------
    dict
        ``nominal``, ``true``, ``data0``, ``res0``, ``data``, ``res``, ``before``, ``acc0``,
        ``acc`` (:class:`~pkmcal.analysis.AccuracyReport`), ``aligned0``, ``scales``.
    """
    from .analysis import pose_accuracy
    from .calibration import calibrate_constraint_link
    from .identifiability import CONSTRAINT_LINK_GAUGES, align_gauge
    from .instruments.constraint_link import simulate_constraint_link
    from .machines import default_hexaslide, paper_table1_deviations

    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    scales = nominal.parameters.scales(nominal.characteristic_length())
    ws = {"n": WORKSPACE_POSES, "rng": WORKSPACE_SEED}
    before = pose_accuracy(true, nominal, align=False, **ws)
    # 1. noise-free data: the paper's Table 2 check
    data0 = simulate_constraint_link(true, HEXASLIDE_POSES, rng=seed)
    res0 = calibrate_constraint_link(nominal, data0)
    aligned0, _ = align_gauge(nominal, res0.x[:-1], true.u, CONSTRAINT_LINK_GAUGES, scales)
    # 2. encoder noise: the realistic case
    data = simulate_constraint_link(true, HEXASLIDE_POSES, noise_m=HEXASLIDE_NOISE, rng=seed)
    res = calibrate_constraint_link(nominal, data, sigma_m=HEXASLIDE_NOISE)
    return {"nominal": nominal, "true": true, "scales": scales, "before": before,
            "data0": data0, "res0": res0, "aligned0": aligned0,
            "acc0": pose_accuracy(true, res0.machine, **ws),
            "data": data, "res": res, "acc": pose_accuracy(true, res.machine, **ws)}


def hexaslide_settings(seed: int = HEXASLIDE_SEED) -> str:
    """The Hexa Slide case's settings in words (what :func:`hexaslide_case` simulates).

    Parameters
    ----------
    seed : int, optional
        Seed of the simulated measurements.

    Returns
    -------
    str
        One line.
    """
    return (f"Hexa Slide: seed {seed}; true machine = embedded default + seed 000 Table 1 "
            f"deviations; {HEXASLIDE_POSES} constraint-link poses (35 deg tilt, 25 deg "
            f"rotation), noise-free and with {HEXASLIDE_NOISE * 1e6:g} um encoder noise "
            "(simulated and assumed); maximum-likelihood calibration; accuracy over "
            f"{WORKSPACE_POSES} poses in the 0.1 m cube around home, orientations within "
            f"+/-10 deg (seed {WORKSPACE_SEED})")


def run_demo(outdir: Path, quick: bool = False, rng=HEXASLIDE_SEED,
             progress: Callable[[str, int], Callable[[], None]] | None = None) -> DemoResult:
    """Run the demo, write its files to ``outdir`` and return the summary.

    ``rng`` is the seed of the Hexa Slide case's measurements (:func:`hexaslide_case`) and of
    its Figs. 5 and 6; ``progress(description, total)`` may return a callback called once per
    calibration. The settings of every case are in :attr:`DemoResult.settings`.
    """
    from .analysis.sweeps import constraint_link_sweep
    from .estimation.acceptance import residual_verdict
    from .identifiability import CONSTRAINT_LINK_GAUGES, align_gauge
    from .io.atomic import atomic_write_text, output_directory
    from .io.csv_io import write_joints
    from .io.machine_file import save_machine
    from .report import plots

    outdir = output_directory(outdir)
    seed = int(rng)
    case = hexaslide_case(seed)
    nominal, true, scales = case["nominal"], case["true"], case["scales"]
    before, acc0, acc = case["before"], case["acc0"], case["acc"]
    aligned0, data, res = case["aligned0"], case["data"], case["res"]
    noise = HEXASLIDE_NOISE
    out = DemoResult()
    out.settings.append(hexaslide_settings(seed))
    um, mm, urad = 1e6, 1e3, 1e6
    out.rows += [
        ("mean position error (noise-free data)", f"{before.position_mean * mm:.3f} mm",
         f"{acc0.position_mean:.2e} m"),
        ("max position error (noise-free data)", f"{before.position_max * mm:.3f} mm",
         f"{acc0.position_max:.2e} m"),
        ("mean orientation error (noise-free data)", f"{before.orientation_mean:.2e} rad",
         f"{acc0.orientation_mean:.2e} rad"),
        ("max parameter error, gauge-aligned (noise-free)",
         f"{np.max(np.abs(nominal.u - true.u) / scales):.2e} (scaled)",
         f"{np.max(np.abs(aligned0 - true.u) / scales):.2e} (scaled)"),
        (f"mean position error ({noise * um:g} um noise)", f"{before.position_mean * mm:.3f} mm",
         f"{acc.position_mean * um:.2f} um"),
        (f"max position error ({noise * um:g} um noise)", f"{before.position_max * mm:.3f} mm",
         f"{acc.position_max * um:.2f} um"),
        (f"mean orientation error ({noise * um:g} um noise)",
         f"{before.orientation_mean * urad:.0f} urad", f"{acc.orientation_mean * urad:.1f} urad"),
        (f"RMS joint residual ({noise * um:g} um noise)", "",
         f"{np.sqrt(np.mean(res.residuals**2)) * noise * um:.2f} um"),
    ]
    out.notes.append(f"identifiable: {res.rank} of {int(res.parameters.free.sum())} parameter "
                     "directions; not identifiable from constraint-link data:")
    out.notes += [f"  {d.dimension} x {d.name}" for d in res.unidentifiable]
    out.notes.append("accuracy is compared after aligning the frames the data cannot fix "
                     "(SPEC 5)")
    out.notes.append(f"Hexa Slide, {noise * um:g} um noise: residual test "
                     f"{residual_verdict(res).sentence()}")

    # files: data, truth, calibrated machine, report
    passive = {"passive": data.passive + 1}
    out.files.append(write_joints(outdir / "constraint_link_data.csv", data.q, "mm", passive)
                     or outdir / "constraint_link_data.csv")
    save_machine(nominal, outdir / "nominal.yaml")
    save_machine(true, outdir / "true.yaml")
    save_machine(res.machine, outdir / "calibrated.yaml",
                 calibration={"method": "ml", "data": "constraint_link_data.csv",
                              "noise_um": noise * um, "identifiable": res.rank})
    out.files += [outdir / "nominal.yaml", outdir / "true.yaml", outdir / "calibrated.yaml"]

    # 3. seed 000 Figs. 5 and 6: the Monte-Carlo engine (pkmcal montecarlo), on every core
    rng = np.random.default_rng(seed)
    seeds = 1 if quick else SWEEP_RUNS
    workers = 1 if quick else None
    levels = NOISE_LEVELS[::2] if quick else NOISE_LEVELS
    lc_errs = LC_ERRORS[::2] if quick else LC_ERRORS
    out.settings.append(
        f"Hexa Slide Figs. 5 and 6: {seeds} simulated calibration(s) per value (random "
        f"stream of seed {seed}), {HEXASLIDE_POSES} poses; encoder noise "
        + ", ".join(f"{v * um:g}" for v in levels) + " um; link-length errors "
        + ", ".join(f"{v * um:g}" for v in lc_errs) + " um (noise-free)")
    cb = progress("Fig. 5: accuracy vs encoder noise", len(levels) * seeds) if progress else None
    fig5 = constraint_link_sweep(nominal, true, "noise", levels, seeds=seeds, rng=rng,
                                 progress=cb, workers=workers)
    cb = (progress("Fig. 6: accuracy vs error in Lc", 2 * len(lc_errs) * seeds)
          if progress else None)
    fig6 = constraint_link_sweep(nominal, true, "link_length_error", lc_errs, seeds=seeds,
                                 rng=rng, progress=cb, workers=workers)
    fig6_est = constraint_link_sweep(nominal, true, "link_length_error", lc_errs, seeds=seeds,
                                     rng=rng, estimate_link_length=True, progress=cb,
                                     workers=workers)
    out.files.append(plots.plot_sweep(
        fig5, outdir / "fig5_accuracy_vs_noise.png", "encoder noise (std) [um]",
        "Seed 000 Fig. 5: calibrated accuracy vs encoder noise (150 poses)"))
    out.files.append(plots.plot_sweep(
        fig6, outdir / "fig6_accuracy_vs_link_length_error.png",
        "error in the assumed constraint-link length [um]",
        "Seed 000 Fig. 6: calibrated accuracy vs link-length error (noise-free)",
        extra=fig6_est, extra_label="maximum likelihood, Lc estimated"))
    sd = res.std[:-1]
    aligned, _ = align_gauge(nominal, res.x[:-1], true.u, CONSTRAINT_LINK_GAUGES, scales)
    out.files.append(plots.plot_parameter_errors(
        nominal.parameters.names, nominal.u - true.u, aligned - true.u, sd,
        outdir / "parameter_errors.png", 1.0, "|deviation| [m or rad]"))
    out.files.append(plots.plot_residuals(res.residuals * noise * um,
                                          outdir / "residuals.png"))
    out.figures = {"fig5": fig5, "fig6": fig6, "fig6_lc_estimated": fig6_est}
    delta = delta_demo(outdir, out)
    clearance = clearance_demo(outdir, out, samples=CLEARANCE_QUICK_SAMPLES if quick
                               else CLEARANCE_CASE["samples"])
    summary = {
        "settings": out.settings, "seed": seed, "rows": out.rows, "notes": out.notes,
        "delta": delta, "clearance": clearance,
        "fig5_noise": [p.__dict__ for p in fig5],
        "fig6_link_length_error": [p.__dict__ for p in fig6],
        "fig6_link_length_error_lc_estimated": [p.__dict__ for p in fig6_est],
    }
    path = atomic_write_text(outdir / "summary.json",
                             json.dumps(summary, indent=2, allow_nan=False))
    out.files.append(path)
    return out


#: seed of the Delta demo's random errors, grid noise and held-out noise
DELTA_SEED = 1
#: held-out validation grid of the Delta demo: shape, spacing (m), offset of its centre (m)
HELD_OUT_GRID = ((4, 4, 3), (0.1, 0.1, 0.04), (0.0, 0.0, 0.02))


def delta_demo(outdir: Path, out: DemoResult, seed: int = DELTA_SEED) -> dict:
    """Seed 001 on the default Delta; appends rows, notes and files to ``out`` and returns
    the numbers (for ``summary.json``)."""
    from .calibration import calibrate_tracker, distance_ratios, predict_tracker_points
    from .instruments.setups import Setups
    from .instruments.tracker import (
        TRACKER_GRID_SPACING,
        TrackerNoise,
        TrackerSection,
        TrackerSetup,
        default_tracker_pose,
        grid_points,
        neighbour_pairs,
        simulate_tracker,
        tracker_noise_arg,
    )
    from .io.csv_io import write_tracker
    from .io.machine_file import save_machine
    from .machines import default_delta
    from .machines.deviations import random_deviations
    from .report import plots

    rng = np.random.default_rng(seed)
    nominal = default_delta()
    true = nominal.with_parameters(nominal.u + random_deviations(nominal, rng))
    pose = default_tracker_pose()
    length, angle = nominal.RANDOM_DEVIATION
    out.settings.append(
        f"Delta: seed {seed}; true machine = embedded default + random errors (uniform within "
        f"+/-{length * 1e3:g} mm, +/-{np.degrees(angle):g} deg); 27 tracker points on the "
        "3x3x3 grid (150/150/40 mm) at home, tracker noise "
        f"{tracker_noise_arg(None, allow_none=False)[1]}, tracker 2.5 m away; held-out: a "
        f"{'x'.join(map(str, HELD_OUT_GRID[0]))} grid")
    true.name = "simulated true Delta (random errors, seed 1) with the true tracker pose"
    noise = TrackerNoise()
    shape = (3, 3, 3)
    data = simulate_tracker(true, nominal, grid_points(nominal.home[0], TRACKER_GRID_SPACING,
                                                       shape), pose, noise, rng=rng)
    joint = calibrate_tracker(nominal, data, noise)
    two = calibrate_tracker(nominal, data, noise, joint=False)

    # held-out points: true tracker points (noise-free) and their measurement (noisy)
    h_shape, h_spacing, h_offset = HELD_OUT_GRID
    held = simulate_tracker(true, nominal, grid_points(nominal.home[0] + np.array(h_offset),
                                                       h_spacing, h_shape),
                            pose, noise=None, rng=rng)
    held_m = held.m + noise.sample(held.m, rng)

    def rms_error(machine, registration):
        pred = predict_tracker_points(machine, held.q, registration)
        return float(np.sqrt(np.mean(np.sum((pred - held.m) ** 2, axis=-1))))

    start = joint.section(TrackerSection).start_registration
    err = {"before": rms_error(nominal, start),
           "joint": rms_error(joint.machine, joint.section(TrackerSection).registration),
           "two_step": rms_error(two.machine, two.section(TrackerSection).registration)}
    pairs, h_pairs = neighbour_pairs(shape), neighbour_pairs(h_shape)
    ratios = {
        "calibration": {name: distance_ratios(m, data.q, data.m, pairs) for name, m in
                        (("before", nominal), ("joint", joint.machine),
                         ("two_step", two.machine))},
        "held_out": {name: distance_ratios(m, held.q, held_m, h_pairs) for name, m in
                     (("before", nominal), ("joint", joint.machine),
                      ("two_step", two.machine))},
    }
    spread = {grid: {k: float(np.std(v)) for k, v in r.items()} for grid, r in ratios.items()}
    um = 1e6
    n_held = len(held)
    out.rows += [
        (f"Delta: held-out RMS position error ({n_held} points), joint",
         f"{err['before'] * 1e3:.3f} mm", f"{err['joint'] * um:.1f} um"),
        (f"Delta: held-out RMS position error ({n_held} points), two-step (seed 001)",
         f"{err['before'] * 1e3:.3f} mm", f"{err['two_step'] * um:.1f} um"),
        ("Delta: distance-ratio spread (std), calibration grid, joint / two-step",
         f"{spread['calibration']['before']:.3f} %",
         f"{spread['calibration']['joint']:.3f} % / {spread['calibration']['two_step']:.3f} %"),
        ("Delta: distance-ratio spread (std), held-out grid, joint / two-step",
         f"{spread['held_out']['before']:.3f} %",
         f"{spread['held_out']['joint']:.3f} % / {spread['held_out']['two_step']:.3f} %"),
        ("Delta: RMS tracker residual, joint / two-step", "",
         f"{_rms_norm(joint, data) * um:.1f} um / {_rms_norm(two, data) * um:.1f} um"),
    ]
    free = int(joint.parameters.free.sum())
    out.notes.append(f"Delta: identifiable {joint.rank} of {free} parameter directions (27 leg "
                     "errors + 6 tracker pose); not identifiable from tracker points:")
    out.notes += [f"  {d.dimension} x {d.name}" for d in joint.unidentifiable]
    out.notes.append(
        f"Delta: {len(data)} points on the 3x3x3 grid (150/150/40 mm) at home, Leica-type "
        f"noise, tracker 2.5 m away; held-out: a {'x'.join(map(str, h_shape))} grid (100/100/40 "
        "mm) 20 mm higher; position errors are tracker-frame distances (model + its "
        "registration vs the true reflector), 'before' = nominal model with the closed-form "
        "registration")

    calibrated = joint.machine
    calibrated.name = "default Delta, calibrated from delta_tracker_data.csv (joint)"
    out.files.append(write_tracker(outdir / "delta_tracker_data.csv", data.q, data.m))
    for name, machine, meta, setups in (
            ("delta_nominal.yaml", nominal, None, None),
            ("delta_true.yaml", true, None, Setups({"tracker": TrackerSetup(pose)})),
            ("delta_calibrated.yaml", calibrated,
             {"method": "tracker-joint", "data": "delta_tracker_data.csv",
              "identifiable": joint.rank, "free_parameters": free},
             Setups({"tracker": TrackerSetup(joint.section(TrackerSection).registration)}))):
        out.files.append(save_machine(machine, outdir / name, calibration=meta,
                                      setups=setups))
    out.files.append(plots.plot_distance_ratio(
        [(f"calibration grid 3x3x3 ({len(pairs)} pairs)",
          {"before calibration": (ratios["calibration"]["before"], "--"),
           "after, joint": (ratios["calibration"]["joint"], "-"),
           "after, two-step": (ratios["calibration"]["two_step"], ":")}),
         (f"held-out grid {'x'.join(map(str, h_shape))} ({len(h_pairs)} pairs)",
          {"before calibration": (ratios["held_out"]["before"], "--"),
           "after, joint": (ratios["held_out"]["joint"], "-"),
           "after, two-step": (ratios["held_out"]["two_step"], ":")})],
        outdir / "delta_distance_ratio.png",
        "Seed 001 Fig. 6: distance ratio of neighbouring points, default Delta"))
    return {
        "held_out_rms_position_error_m": err,
        "distance_ratio_std_percent": spread,
        "identifiable": int(joint.rank), "free_parameters": free,
        "unidentifiable": [d.as_dict() for d in joint.unidentifiable],
        "true_tracker_pose": {"rotation": pose[0].tolist(), "translation_m": pose[1].tolist()},
    }


#: seed 003 case study (SPEC 2.3): circle radius (m), height (m), angular speed (rad/s),
#: samples, platform mass (kg), cutting force (N), joint clearance c_b (m)
CLEARANCE_CASE = {"radius": 0.1, "height": 0.41, "omega": 10.0, "samples": 360, "mass": 4.8,
                  "cutting_force": (0.0, 0.0, -500.0), "clearance": 10e-6}
#: samples on the circle in quick mode (every 5 deg: 90 and 270 deg are still samples)
CLEARANCE_QUICK_SAMPLES = 72


def clearance_demo(outdir: Path, out: DemoResult, samples: int = CLEARANCE_CASE["samples"]
                   ) -> dict:
    """Seed 003 on the embedded cubic 6-UPU device: link forces and clearance pose errors
    along the paper's circle; appends notes and files to ``out`` and returns the numbers (for
    ``summary.json``).

    Writes ``cubic_errors.csv`` (the columns of ``pkmcal errors``, SPEC 6), its
    ``cubic_errors_envelope.csv`` and the plots ``cubic_link_forces.png`` (Fig. 6) and
    ``cubic_pose_errors.png`` (Fig. 7).
    """
    from .analysis import errors as err
    from .machines import cubic_6upu
    from .report import plots

    case = CLEARANCE_CASE
    machine = cubic_6upu()
    out.settings.append(
        f"cubic 6-UPU: no random draw; circle r = {case['radius'] * 1e3:g} mm at z = "
        f"{case['height'] * 1e3:g} mm, {case['omega']:g} rad/s, {samples} samples, "
        f"{case['mass']:g} kg, {-case['cutting_force'][2]:g} N cutting force, clearance "
        f"{case['clearance'] * 1e6:g} um")
    path = err.circle_trajectory(case["radius"], case["height"], case["omega"], samples)
    cb = case["clearance"]
    result = err.trajectory_errors(machine, path, case["mass"], case["cutting_force"], cb)
    f, e = result.forces, result.errors
    angle = np.degrees(path.angle)
    um = 1e6

    def crossings(values) -> list[float]:
        return [float(c) for c in err.zero_crossings(angle, values, 360.0)]

    def at(values) -> str:
        return ", ".join(f"{c:.1f}" for c in values) + " deg" if values else "nowhere"

    links = [{"min_N": float(f[:, i].min()), "max_N": float(f[:, i].max()),
              "changes_side_deg": crossings(f[:, i])} for i in range(6)]
    pose = {name: {"min": float(e.dx[:, j].min() * um), "max": float(e.dx[:, j].max() * um),
                   "changes_sign_deg": crossings(e.dx[:, j])}
            for j, name in enumerate(err.ERROR_COMPONENTS)}
    n_und = int(np.any(e.undetermined, axis=1).sum())
    fc = case["cutting_force"]
    out.notes.append(
        f"cubic 6-UPU (seed 003, as pkmcal errors cubic): circle r = {case['radius'] * 1e3:g} "
        f"mm at z = {case['height'] * 1e3:g} mm, {case['omega']:g} rad/s, {samples} samples; "
        f"{case['mass']:g} kg, {-fc[2]:g} N cutting force down, joint clearance c_b = "
        f"{cb * um:g} um")
    for i, link in enumerate(links):
        side = (f"changes side at {at(link['changes_side_deg'])}"
                if link["changes_side_deg"] else
                "compression all along" if link["max_N"] < 0 else
                "tension all along" if link["min_N"] > 0 else "no change of side")
        out.notes.append(f"  link {i + 1} force (tension +): {link['min_N']:.1f} .. "
                         f"{link['max_N']:.1f} N, {side}")
    out.notes.append(
        f"cubic: dx changes sign at {at(pose['dx']['changes_sign_deg'])} (links 4-5 change "
        f"side at {at(links[3]['changes_side_deg'])}), dy at "
        f"{at(pose['dy']['changes_sign_deg'])} (link 6 at {at(links[5]['changes_side_deg'])})")
    out.notes.append(
        "cubic: position error " + ", ".join(
            f"{n} {pose[n]['min']:.1f} .. {pose[n]['max']:.1f} um" for n in ("dx", "dy", "dz"))
        + f"; 2 c_b = {2 * cb * um:g} um"
        + (f"; {n_und} of {samples} samples with a link force within 1 N of zero (envelope "
           "in cubic_errors_envelope.csv)" if n_und else ""))

    out.files += err.write_errors_csv(outdir / "cubic_errors.csv", result,
                                      outdir / "cubic_errors_envelope.csv")
    out.files.append(plots.plot_link_forces(
        angle, f, outdir / "cubic_link_forces.png",
        title="Seed 003 Fig. 6: leg forces on the circle, cubic 6-UPU (tension positive)",
        undetermined=e.undetermined))
    out.files.append(plots.plot_pose_errors(
        angle, e.dx, e.dx_min, e.dx_max, outdir / "cubic_pose_errors.png",
        title=f"Seed 003 Fig. 7: pose error from joint clearance {cb * um:g} um, cubic 6-UPU"))
    return {
        "case": {**case, "samples": samples, "cutting_force": list(fc)},
        "link_forces_N": links, "pose_error_um_urad": pose,
        "samples_with_undetermined_side": n_und,
    }


def _rms_norm(result, data) -> float:
    """RMS 3-D distance measured - predicted over the points a tracker calibration used."""
    from .calibration import predict_tracker_points
    from .instruments.tracker import TrackerSection

    section = result.section(TrackerSection)
    keep = section.kept
    pred = predict_tracker_points(result.machine, data.q[keep], section.registration)
    return float(np.sqrt(np.mean(np.sum((data.m[keep] - pred) ** 2, axis=-1))))
