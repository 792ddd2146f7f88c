"""A Delta robot calibrated with a laser tracker, from Python (seed 001's experiment).

Run: `.venv/bin/python examples/scripts/delta_tracker_calibration.py [delta.yaml]`

1. load the machine file (or examples/delta_default.yaml),
2. simulate seed 001's experiment: the nominal model commands a 3x3x3 grid, the true robot
   (random errors of 1 mm / 0.5 deg) goes elsewhere, a tracker measures the reflector,
3. calibrate the leg errors and the tracker pose together, look at what is identifiable,
4. check on 200 held-out points and with the distance ratio,
5. compensate a short pick-and-place path.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from pkmcal.calibration import calibrate_tracker, predict_tracker_points
from pkmcal.compensation import compensate
from pkmcal.instruments.tracker import (
    TRACKER_GRID_SPACING,
    TrackerNoise,
    default_tracker_pose,
    grid_points,
    simulate_tracker,
)
from pkmcal.io import load_machine
from pkmcal.machines.deviations import random_deviations

EXAMPLE = Path(__file__).resolve().parents[1] / "delta_default.yaml"


def main(path: str | None = None) -> dict:
    nominal = load_machine(path or EXAMPLE)
    rng = np.random.default_rng(1)
    true = nominal.with_parameters(nominal.u + random_deviations(nominal, rng))
    pose = default_tracker_pose()
    noise = TrackerNoise()

    targets = grid_points(nominal.home[0], TRACKER_GRID_SPACING, (3, 3, 3))
    data = simulate_tracker(true, nominal, targets, pose, noise, rng=rng)
    result = calibrate_tracker(nominal, data, noise)
    calibrated = result.machine
    print(f"calibration: {result.message}; {result.rank} of {int(result.parameters.free.sum())}"
          " directions identified")
    for d in result.unidentifiable:
        print(f"  not identifiable: {d.dimension} x {d.name}")

    # held-out points: where the calibrated model says the reflector is vs the tracker
    held = nominal.home[0] + rng.uniform(-1, 1, (200, 3)) * np.asarray(TRACKER_GRID_SPACING)
    q = nominal.ik(held)
    smr_true = true.fk(q).P - np.array([0.0, 0.0, true.smr_offset])
    R, t = pose
    m_true = (smr_true - t) @ R
    before = predict_tracker_points(nominal, q, pose) - m_true
    after = predict_tracker_points(calibrated, q, result.sections["tracker"].registration) - m_true
    rms = lambda e: float(np.sqrt(np.mean(np.sum(e**2, -1))))  # noqa: E731
    print(f"held-out RMS error: {rms(before) * 1e6:.0f} um before, {rms(after) * 1e6:.1f} um "
          "after")

    # compensate a path: arm angles that put the real robot on it
    path_P = nominal.home[0] + np.linspace([-0.1, 0, 0], [0.1, 0.05, 0.03], 5)
    n = len(calibrated.parameters)
    comp = compensate(calibrated, path_P, covariance=result.covariance[:n, :n],
                      nominal=nominal, null=(result.null_space * result.scales[:, None])[:n])
    print("arm commands (deg):")
    print(np.round(np.degrees(comp.q), 4))
    print(f"predicted residual {comp.position_std.max() * 1e6:.1f} um max; nominal commands "
          f"would be off by {np.nanmax(comp.uncompensated_position) * 1e6:.0f} um")
    return {"before": rms(before), "after": rms(after)}


if __name__ == "__main__":
    main(*sys.argv[1:2])
