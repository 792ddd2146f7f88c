"""A converged calibration is checked before it is believed (issue 12, items 1-2): the
chi-square of its residuals against the assumed noise, and the size of its changes against
the machine's scale."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pkmcal.calibration import calibrate_constraint_link
from pkmcal.estimation.acceptance import (
    FAILED_ALARMING,
    FAILED_SMALL,
    MAX_LENGTH_CHANGE,
    NOT_TESTED,
    PASSED,
    ResidualVerdict,
    chi_square_test,
    noise_ratio,
    parameter_changes,
    residual_test,
    residual_verdict,
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
    assert f"{r.noise_ratio:.3g} times the assumed noise" in msg
    assert "--noise" in msg and "columns" in msg
    mild = residual_test(_calibrate(2e-6, 1e-6, 0))      # the assumed noise a little off
    assert not mild.passed and not mild.alarming
    d = r.as_dict()
    assert d["passed"] is False and d["alarming"] is True and d["dof"] == r.dof


def test_one_verdict_per_calibration():
    """passed / failed by a little / failed, each in its own words; a failed test is never
    called consistent, and the number is always sqrt(chi2/dof)."""
    verdicts = {}
    for key, noise_true in (("right", 1e-6), ("mild", 2e-6), ("far", 20e-6)):
        result = _calibrate(noise_true, 1e-6, 0)
        v = residual_verdict(result)
        test = residual_test(result)
        assert v.noise_ratio == pytest.approx(math.sqrt(test.chi2 / test.dof), rel=1e-12)
        assert v.noise_ratio == pytest.approx(noise_ratio(test.chi2, test.dof), rel=1e-12)
        verdicts[key] = v
    assert [v.status for v in verdicts.values()] == [PASSED, FAILED_SMALL, FAILED_ALARMING]
    sentences = {k: v.sentence() for k, v in verdicts.items()}
    assert sentences["right"].startswith("passed: ") and "agree" in sentences["right"]
    assert sentences["mild"].startswith("failed, by a little: ")
    assert "a little larger than assumed" in sentences["mild"]
    assert sentences["far"].startswith("failed: ")
    for key in ("mild", "far"):
        assert "agree" not in sentences[key] and "consistent" not in sentences[key]
    for v in verdicts.values():
        assert f"{v.noise_ratio:.3g} times the assumed noise" in v.sentence()
        d = v.as_dict()
        assert d["verdict"] == v.status and d["sentence"] == v.sentence()
        assert d["noise_ratio"] == pytest.approx(v.noise_ratio, rel=1e-12)
        back = ResidualVerdict.from_dict(d)         # what the HTML report reads back
        assert back.status == v.status and back.sentence() == v.sentence()


def test_a_method_that_takes_readings_as_exact_is_not_tested_unless_it_states_a_test():
    result = _calibrate(1e-6, 1e-6, 0)
    result.noise = None
    v = residual_verdict(result, "ik")
    assert v.status == NOT_TESTED and v.noise_ratio is None
    assert v.sentence().startswith("not tested: ") and "exact" in v.sentence()
    assert ResidualVerdict.from_dict(v.as_dict()).sentence() == v.sentence()
    # a test stated in the whitened model's terms is used as any other
    result.residual_test = chi_square_test(900.0, 100)
    v = residual_verdict(result, "ik")
    assert v.status == FAILED_ALARMING and v.noise_ratio == pytest.approx(3.0, rel=1e-12)
    # an older report's section (no verdict key) gives the same verdict
    old = {k: val for k, val in v.as_dict().items() if k not in ("verdict", "sentence")}
    assert ResidualVerdict.from_dict(old).sentence() == v.sentence()


def test_without_redundancy_there_is_nothing_to_test():
    class Result:
        cost, dof = 3.0, 0

    r = residual_test(Result())
    assert r.passed and r.message() == "" and r.as_dict()["chi2_per_dof"] is None
    v = residual_verdict(Result(), "ml")
    assert v.status == NOT_TESTED and "0 degrees of freedom" in v.sentence()


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
    for method in ("ml", "ik"):           # the right columns: no warning of the acceptance
        proc = run("calibrate", cubic, "p.csv", "--method", method, "-o", f"ok_{method}.yaml",
                   "-q", cwd=tmp_path)
        # (the poorly determined parameters are warned of by the rule of every calibration:
        # 60 poses fix this machine's leg lengths to about 0.5 mm, beyond 1/2500 of its size)
        warned = [w for w in proc.stderr.splitlines() if "poorly determined" not in w]
        assert proc.returncode == 0 and warned == [], proc.stderr
