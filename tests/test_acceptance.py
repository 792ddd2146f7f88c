"""A converged calibration is checked before it is believed (issue 12, items 1-2): the
chi-square of its residuals against the assumed noise, and the size of its changes against
the machine's scale."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pkmcal.calibration import calibrate_constraint_link
from pkmcal.estimation.acceptance import (
    MAX_LENGTH_CHANGE,
    parameter_changes,
    residual_test,
)
from pkmcal.instruments.constraint_link import simulate_constraint_link
from pkmcal.machines import default_hexaslide
from pkmcal.machines.deviations import random_deviations


def _calibrate(noise_true, noise_assumed, seed):
    rng = np.random.default_rng(seed)
    nominal = default_hexaslide()
    true = nominal.with_parameters(nominal.u + random_deviations(nominal, rng=rng))
    data = simulate_constraint_link(true, 150, noise_true, rng=rng)
    return calibrate_constraint_link(nominal, data, sigma_m=noise_assumed)


def test_honest_calibrations_pass_at_the_stated_rate():
    results = [residual_test(_calibrate(1e-6, 1e-6, seed)) for seed in range(20)]
    assert all(r.passed for r in results), [r.ratio for r in results]
    ratios = np.array([r.ratio for r in results])
    assert abs(ratios.mean() - 1) < 0.1            # chi2/dof ~ 1 with the right noise
    r = results[0]
    assert r.upper > 1 and r.dof > 100 and math.isclose(r.noise_factor, math.sqrt(r.ratio))


def test_residuals_far_above_the_assumed_noise_fail_and_alarm():
    r = residual_test(_calibrate(20e-6, 1e-6, 0))
    assert not r.passed and r.alarming
    assert 15 < r.noise_factor < 25
    msg = r.message()
    assert "x the assumed noise" in msg and "--noise" in msg and "columns" in msg
    mild = residual_test(_calibrate(2e-6, 1e-6, 0))      # the assumed noise a little off
    assert not mild.passed and not mild.alarming
    d = r.as_dict()
    assert d["passed"] is False and d["alarming"] is True and d["dof"] == r.dof


def test_without_redundancy_there_is_nothing_to_test():
    class Result:
        cost, dof = 3.0, 0

    r = residual_test(Result())
    assert r.passed and r.message() == "" and r.as_dict()["chi2_per_dof"] is None


@pytest.mark.parametrize("name,change,flagged", [
    ("chain3.l", 0.5 * MAX_LENGTH_CHANGE, False),
    ("chain3.l", 2 * MAX_LENGTH_CHANGE, True),
    ("chain2.beta", math.radians(2), False),
    ("chain2.beta", math.radians(12), True),
])
def test_sizeable_changes_are_named(name, change, flagged):
    m = default_hexaslide()
    u = m.u.copy()
    i = m.parameters.index(name)
    kind = m.parameters.kinds[i]
    u[i] += change * (m.characteristic_length() if kind == "length" else 1.0)
    pc = parameter_changes(m, m.with_parameters(u))
    assert (name in pc.suspicious) is flagged
    assert (name in pc.message()) is flagged
    if flagged:
        assert "swapped or mis-numbered columns" in pc.message()


def test_calibrate_warns_about_swapped_columns_and_not_about_the_papers_methods(tmp_path):
    from pathlib import Path

    from clitools import run

    cubic = Path(__file__).resolve().parents[1] / "examples" / "cubic_6upu.yaml"
    assert run("simulate", cubic, "--scenario", "pose", "-o", "p.csv", cwd=tmp_path
               ).returncode == 0
    lines = (tmp_path / "p.csv").read_text().splitlines()
    head = lines[0].split(",")
    head[0], head[1] = head[1], head[0]                    # q1 and q2 exchanged
    (tmp_path / "s.csv").write_text("\n".join([",".join(head), *lines[1:]]) + "\n")
    for method in ("ml", "ik"):
        proc = run("calibrate", cubic, "s.csv", "--method", method, "-o", f"{method}.yaml",
                   "-q", cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr
        assert "swapped or mis-numbered columns" in proc.stderr, proc.stderr
    for method in ("ml", "ik"):                            # the right columns: no warning
        proc = run("calibrate", cubic, "p.csv", "--method", method, "-o", f"ok_{method}.yaml",
                   "-q", cwd=tmp_path)
        assert proc.returncode == 0 and proc.stderr == "", proc.stderr
