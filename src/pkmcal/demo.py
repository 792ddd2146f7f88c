"""The main job on the embedded default, no input needed (``pkmcal demo``).

Seed 000 section 4 on our default Hexa Slide: the true machine is nominal + Table 1 deviations;
constraint-link data are simulated; the maximum-likelihood calibration identifies the geometry;
accuracy over the 0.1 m workspace cube is compared before and after; then the paper's Fig. 5
(accuracy vs encoder noise) and Fig. 6 (accuracy vs error in the assumed link length) are
reproduced as plots.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class DemoResult:
    """What the demo found: table rows ``(quantity, before, after)``, files, notes."""

    rows: list[tuple[str, str, str]] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    figures: dict = field(default_factory=dict)


NOISE_LEVELS = (0.1e-6, 0.3e-6, 1e-6, 3e-6, 10e-6)
LC_ERRORS = (1e-6, 3e-6, 10e-6, 30e-6, 100e-6)


def run_demo(outdir: Path, quick: bool = False, rng=0,
             progress: Callable[[str, int], Callable[[], None]] | None = None) -> DemoResult:
    """Run the demo, write its files to ``outdir`` and return the summary.

    ``progress(description, total)`` may return a callback called once per calibration.
    """
    from .analysis import pose_accuracy, workspace_poses
    from .analysis.sweeps import constraint_link_sweep
    from .calibration import calibrate_constraint_link
    from .identifiability import CONSTRAINT_LINK_GAUGES, align_gauge
    from .io.csv_io import write_joints
    from .io.machine_file import save_machine
    from .machines import default_hexaslide, paper_table1_deviations
    from .measurements import simulate_constraint_link
    from .report import plots

    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(rng)
    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    scales = nominal.parameters.scales(nominal.characteristic_length())
    P, R = workspace_poses(true.home[0], n=500, rng=rng)
    out = DemoResult()

    before = pose_accuracy(true, nominal, P, R, align=False)
    # 1. noise-free data: the paper's Table 2 check
    data0 = simulate_constraint_link(true, 150, rng=rng)
    res0 = calibrate_constraint_link(nominal, data0)
    aligned0, _ = align_gauge(nominal, res0.x[:-1], true.u, CONSTRAINT_LINK_GAUGES, scales)
    acc0 = pose_accuracy(true, res0.extras["machine"], P, R)
    # 2. 2 um encoder noise: the realistic case
    noise = 2e-6
    data = simulate_constraint_link(true, 150, noise_m=noise, rng=rng)
    res = calibrate_constraint_link(nominal, data, sigma_m=noise)
    acc = pose_accuracy(true, res.extras["machine"], P, R)
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
        ("RMS joint residual (2 um noise)", "",
         f"{np.sqrt(np.mean(res.residuals**2)) * noise * um:.2f} um"),
    ]
    out.notes.append(f"identifiable: {res.rank} of {int(res.parameters.free.sum())} parameter "
                     "directions; not identifiable from constraint-link data:")
    out.notes += [f"  {d.dimension} x {d.name}" for d in res.extras["unidentifiable"]]
    out.notes.append("accuracy is compared after aligning the frames the data cannot fix "
                     "(SPEC 5)")

    # files: data, truth, calibrated machine, report
    passive = {"passive": data.passive + 1}
    out.files.append(write_joints(outdir / "constraint_link_data.csv", data.q, "mm", passive)
                     or outdir / "constraint_link_data.csv")
    save_machine(nominal, outdir / "nominal.yaml")
    save_machine(true, outdir / "true.yaml")
    save_machine(res.extras["machine"], outdir / "calibrated.yaml",
                 calibration={"method": "ml", "data": "constraint_link_data.csv",
                              "noise_um": noise * um, "identifiable": res.rank})
    out.files += [outdir / "nominal.yaml", outdir / "true.yaml", outdir / "calibrated.yaml"]

    # 3. seed 000 Figs. 5 and 6
    seeds = 1 if quick else 3
    levels = NOISE_LEVELS[::2] if quick else NOISE_LEVELS
    lc_errs = LC_ERRORS[::2] if quick else LC_ERRORS
    cb = progress("Fig. 5: accuracy vs encoder noise", len(levels) * seeds) if progress else None
    fig5 = constraint_link_sweep(nominal, true, "noise", levels, seeds=seeds, rng=rng,
                                 progress=cb)
    cb = (progress("Fig. 6: accuracy vs error in Lc", 2 * len(lc_errs) * seeds)
          if progress else None)
    fig6 = constraint_link_sweep(nominal, true, "link_length_error", lc_errs, seeds=seeds,
                                 rng=rng, progress=cb)
    fig6_est = constraint_link_sweep(nominal, true, "link_length_error", lc_errs, seeds=seeds,
                                     rng=rng, estimate_link_length=True, progress=cb)
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
    summary = {
        "rows": out.rows, "notes": out.notes,
        "fig5_noise": [p.__dict__ for p in fig5],
        "fig6_link_length_error": [p.__dict__ for p in fig6],
        "fig6_link_length_error_lc_estimated": [p.__dict__ for p in fig6_est],
    }
    path = outdir / "summary.json"
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(summary, indent=2))
    tmp.replace(path)
    out.files.append(path)
    return out
