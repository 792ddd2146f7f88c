"""The printer defaults stay within 1.15x of the Cramér-Rao bound of the family the errors lie
in (issue 35, "Done when").

``benchmarks/printer_defaults.py``: the benchmark printer with the default build tolerances;
true errors in Klipper's nine parameters (endstops, radius, two angles, three arms) plus a bed
tilt; 61 probe points, 10 um trigger noise; the held-out height RMS of ``calibrate``'s defaults
(``--parameters auto``) against the bound of Klipper's nine + the bed's tilt (maximum
likelihood, at the truth). Before issue 35 the defaults fitted every parameter (``full``,
1.28x in the issue's measurement; 1.16-1.19x on these printers, measured with the
tolerances off) or Klipper's basic six (biased: 2.2-2.4x here, where the arms are off by up to
1 mm).

Power: the ratio from N runs of 40 held-out heights spreads by about ``1 / sqrt(2 N k_eff)``
(``k_eff`` ~ 5 independent height errors): ~6 % for the quick size's 24 runs, ~2.5 % for the
study's 200. Measured (study size): see the benchmark's docstring; quick: 0.93-0.98 per seed.
"""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    path = ROOT / "benchmarks" / "printer_defaults.py"
    spec = importlib.util.spec_from_file_location("printer_defaults_bench", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


bench = _bench()

#: (seeds, runs per seed, tolerance on the pooled ratio): the quick size with ~3 of its
#: spreads below 1.15 (measured ~0.95), and the study
SIZES = [pytest.param(3, 8, 1.15, id="quick"),
         pytest.param(5, 40, 1.15, id="study", marks=pytest.mark.study)]


@pytest.mark.parametrize("seeds, runs, tolerance", SIZES)
def test_defaults_within_115_percent_of_the_family_bound(seeds, runs, tolerance):
    rows = [bench.run_case(seed, runs, others=("klipper-basic",)) for seed in range(seeds)]
    auto = np.sqrt(np.mean([r["ratio"]["auto"] ** 2 for r in rows]))
    basic = np.sqrt(np.mean([r["ratio"]["klipper-basic"] ** 2 for r in rows]))
    assert auto <= tolerance, rows
    # the test has power: the model that lacks the arms and the bed is far off the bound
    assert basic > 1.5, rows
    # never below what any unbiased estimator can do by more than the prior explains
    assert auto > 0.6, rows
