"""Start-up: nothing heavy is imported on a common path (issue 26). A check of ``sys.modules``
in a fresh interpreter, not a timing (timings are ``pkmcal bench`` (c))."""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from scipy import stats

from pkmcal.estimation.distributions import chi2_ppf, chi2_sf, f_sf, t_ppf
from pkmcal.estimation.variance import MEDIAN_CHI2_1

#: modules a calibration does not need: scipy.stats alone is ~1 s of imports (it pulls in
#: scipy.spatial, scipy.optimize, scipy.sparse and every distribution)
HEAVY = ("scipy.stats", "scipy.optimize", "scipy.spatial", "scipy.sparse", "scipy.interpolate",
         "matplotlib", "dask", "distributed", "pandas")


def _imported_after(code: str, cwd) -> list[str]:
    """Run ``code`` in a fresh interpreter; return the heavy modules it left imported."""
    probe = textwrap.dedent(code) + textwrap.dedent(f"""
        import sys
        print(repr([m for m in {HEAVY!r} if m in sys.modules]))
    """)
    proc = subprocess.run([sys.executable, "-c", probe], cwd=cwd, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return ast.literal_eval(proc.stdout.strip().splitlines()[-1])


def test_cli_import_imports_no_numerics(tmp_path):
    code = ("import sys, pkmcal.cli; bad = [m for m in ('numpy', 'scipy', 'matplotlib', 'yaml', "
            "'pydantic') if m in sys.modules]; assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=tmp_path)


@pytest.mark.parametrize("argv", [
    ["calibrate", "default", "data.csv", "-o", "cal.yaml", "--noise", "2um"],
    ["calibrate", "default", "data.csv", "-o", "cal.yaml"],      # noise estimated, outlier test
    ["fk", "default", "data.csv", "-o", "poses.csv"],
])
def test_a_calibration_path_imports_nothing_heavy(tmp_path, argv):
    """The whole command, in process: reading, calibration with its statistical tests,
    reports, writing. Their chi-square, F and t functions come from scipy.special."""
    from pkmcal.instruments.constraint_link import simulate_constraint_link
    from pkmcal.io import write_joints
    from pkmcal.io.atomic import OutputSet
    from pkmcal.machines import default_hexaslide

    data = simulate_constraint_link(default_hexaslide(), 60, noise_m=2e-6, rng=4)
    with OutputSet():
        write_joints(tmp_path / "data.csv", data.q, unit="mm",
                     extra={"passive": np.asarray(data.passive) + 1})
    heavy = _imported_after(f"""
        import contextlib, io, sys
        sys.argv = ["pkmcal", *{argv!r}]
        from pkmcal.cli import main
        with contextlib.redirect_stdout(io.StringIO()):
            try:
                main()
            except SystemExit as e:
                assert not e.code, e.code
    """, tmp_path)
    assert heavy == []


def test_distributions_are_scipy_stats():
    """pkmcal.estimation.distributions against scipy.stats (the formulas it evaluates), over
    the degrees of freedom and probabilities the tests of fit use."""
    rng = np.random.default_rng(7)
    dof = np.concatenate([[1, 2, 3, 6, 54], rng.integers(1, 5000, 20)]).astype(float)
    for q in (1e-6, 0.005, 0.025, 0.5, 0.975, 0.995, 1 - 1e-3, 1 - 1e-7):
        np.testing.assert_allclose(chi2_ppf(q, dof), stats.chi2.ppf(q, dof), rtol=1e-12)
        np.testing.assert_allclose(t_ppf(q, dof), stats.t.ppf(q, dof), rtol=1e-12)
    x = np.abs(rng.normal(size=dof.size)) * dof * 1.5
    np.testing.assert_allclose(chi2_sf(x, dof), stats.chi2.sf(x, dof), rtol=1e-12)
    np.testing.assert_allclose(f_sf(x / dof, 1.0, dof + 2), stats.f.sf(x / dof, 1.0, dof + 2),
                               rtol=1e-12)
    assert chi2_sf(0.0, 3) == 1.0 and f_sf(-1.0, 1, 5) == 1.0
    assert isinstance(chi2_ppf(0.5, 1), float) and isinstance(t_ppf(0.975, 9), float)
    assert chi2_ppf(0.5, 1) == pytest.approx(float(stats.chi2.median(1)), rel=1e-14)
    assert MEDIAN_CHI2_1 == pytest.approx(float(stats.chi2.ppf(0.5, 1)), rel=1e-14)
