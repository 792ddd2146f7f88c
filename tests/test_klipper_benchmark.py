"""Held-out bed heights of pkmcal's Klipper path against Klipper's DELTA_CALIBRATE (the issue's
"A benchmark on simulated printers with 30+ points shows held-out heights at or below
Klipper's algorithm's").

A small version of ``benchmarks/klipper_heights.py``: 6 simulated printers (seed 0), 37 probe
points, 60 held-out points on the print disk, 10 um trigger noise. Klipper's values come from
the reference port of DELTA_CALIBRATE (``tests/klipper_reference.py``), pkmcal's from the
documented path (import, ``calibrate --parameters klipper-basic``, ``export --to klipper``);
both are evaluated with Klipper's kinematics on the saved held-out stable positions.

Tolerance: 1.05 on the ratio pkmcal / Klipper of the held-out RMS (mean over printers and of
the means). Measured on the benchmark's 48 first printers in blocks of 6, a fold-in of the bed
heights alone into Klipper's basic values (the benchmark's ``heights_fold_in`` diagnostic, a
method equal to Klipper's in expectation) gives 0.976-1.012, pkmcal's calibrated model itself
0.92-1.03: 1.05 leaves that spread of a 6-printer mean and no more. With ``--bed-tilt
square`` pkmcal's values equal Klipper's (ratio 1.000). The default path (the bed's tilt
estimated, folded into Klipper's values by the export's 3D position fit over the print
volume) measured 2.1-3.1 in the same blocks (seed 0, 6 printers: 3.09).
"""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
TOLERANCE = 1.05


def _bench():
    path = ROOT / "benchmarks" / "klipper_heights.py"
    spec = importlib.util.spec_from_file_location("klipper_heights_bench", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


bench = _bench()


@pytest.fixture(scope="module")
def rows():
    return bench.run(6, points=37, held=60, noise_mm=0.010, seed=0, verbose=False,
                     diagnose=False)


def test_simulation_is_klipper_exact_without_unmodelled_errors():
    """A printer Klipper's basic model holds exactly (no arm, tower-tilt or bed-tilt error),
    probed without noise: both reproduce the held-out heights to the saved steps' rounding."""
    exact = bench.run(3, noise_mm=0.0, without=("arms", "tilts", "bed"), verbose=False,
                      diagnose=False)
    for row in exact:
        assert row["before_held"] > 0.1                  # the config in force is 0.1 mm+ off
        assert row["klipper_true"] < 5e-5                # mm
        assert row["pkmcal_true"] < 5e-5


def test_klipper_reference_fits_to_the_noise(rows):
    klipper_in = np.array([r["klipper_in"] for r in rows]) * 1e3
    assert np.all((klipper_in > 6.0) & (klipper_in < 13.0)), klipper_in


def test_pkmcal_held_out_heights_at_or_below_klippers(rows):
    s = bench.summary(rows)["held"]
    words = (f"held-out RMS: Klipper {s['klipper_mean_um']:.2f} um, pkmcal "
             f"{s['pkmcal_mean_um']:.2f} um; ratio mean {s['ratio_mean']:.3f}, of means "
             f"{s['ratio_of_means']:.3f}; pkmcal <= Klipper on {s['pkmcal_at_or_below']}/6")
    assert s["ratio_of_means"] <= TOLERANCE, words
    assert s["ratio_mean"] <= TOLERANCE, words
