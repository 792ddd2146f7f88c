"""The two-point distance instrument (SPEC 8): the distance between the platform point at two
sets of readings - a caliper on a printed part, Klipper's DELTA_ANALYZE object - on any
machine: the analytic Jacobian against central differences, noise-free recovery combined with
probe heights, the CSV columns and Klipper's standard object."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pkmcal.calibration.run import calibrate
from pkmcal.instruments import IsotropicNoise
from pkmcal.instruments.data import InstrumentData
from pkmcal.instruments.pairs import PairDistanceModel, PairProblem, klipper_object_pairs, pair_data
from pkmcal.instruments.problem import instrument_problem
from pkmcal.io.machine_file import load_machine
from pkmcal.machines import linear_delta

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def printer(u_shift=0.0, rng=None):
    m = linear_delta(0.1385, [0.2681, 0.2674, 0.2690], np.deg2rad([210.4, 329.7, 90.3]),
                     (0.2934, 0.2951, 0.2917))
    if rng is not None:
        p = m.parameters
        u = m.u.copy()
        for name in p.names:
            if name.startswith("tower"):
                i = p.index(name)
                u[i] += rng.normal(0, 5e-4 if p.kinds[i] == "length" else 1e-3)
        m = m.with_parameters(u)
    return m


def pairs_of(machine, pairs_xyz, rows=None, source="pairs"):
    R = np.broadcast_to(np.eye(3), (len(pairs_xyz), 3, 3))
    qa = machine.ik(pairs_xyz[:, 0], R)
    qb = machine.ik(pairs_xyz[:, 1], R)
    d = np.linalg.norm(pairs_xyz[:, 0] - pairs_xyz[:, 1], axis=-1)
    return pair_data(qa, qb, d, rows, source)


def test_klipper_object_is_delta_calibrate_s():
    pairs, words = klipper_object_pairs()
    assert pairs.shape == (12, 2, 3) and "DELTA_ANALYZE" in words
    d = np.linalg.norm(pairs[:, 0] - pairs[:, 1], axis=-1)
    # centre-to-outer: the outer ridge minus the inner ridge, 65 mm
    np.testing.assert_allclose(d[:6], 0.065, rtol=1e-12)
    assert np.all(d[6:] > 0.05)


def test_jacobian_against_central_differences():
    rng = np.random.default_rng(1)
    m = printer(rng=rng)
    P = rng.uniform(-0.06, 0.06, (10, 2, 3)) * [1, 1, 0] + [0, 0, 0.02]
    data = pairs_of(m, P)
    problem = instrument_problem(m, data, PairDistanceModel(), IsotropicNoise(2e-5))
    assert isinstance(problem, PairProblem)
    state = problem.initial_state()
    r0, J, _ = problem.evaluate(state)
    free = np.flatnonzero(problem.parameters.free)
    for j in free:
        h = 1e-7 * (problem.scales[j])
        up, down = state.u.copy(), state.u.copy()
        up[j] += h
        down[j] -= h
        s_up = problem.initial_state()
        s_up.u = up
        s_dn = problem.initial_state()
        s_dn.u = down
        fd = (problem.evaluate(s_up, False)[0] - problem.evaluate(s_dn, False)[0]) / (2 * h)
        scale = max(np.abs(J[..., j]).max(), 1e-3)
        np.testing.assert_allclose(J[..., j], fd, rtol=0, atol=1e-5 * scale)


def test_heights_and_distances_recover_the_printer_noise_free():
    """Klipper's extended set (arms free) from 37 heights and the 12 distances of Klipper's
    object at two heights: noise-free data recover the true values to 1e-9 of the size."""
    from pkmcal.instruments.registry import instrument
    from pkmcal.instruments.simulate import probe_trigger

    rng = np.random.default_rng(3)
    nominal = printer()
    true = printer(rng=rng)
    params = true.parameters
    # Klipper's model: vertical towers of one radius; tower 3's angle is the gauge (rotation
    # about z, which no height or distance sees) held as Klipper holds it
    keep = [i for i, n in enumerate(params.names)
            if "tilt" in n or "radius_trim" in n or n == "tower3.angle"]
    u = true.u.copy()
    u[keep] = nominal.u[keep]                      # Klipper's model: vertical, one radius
    true = true.with_parameters(u)
    P, R, _ = instrument("probe").candidates(nominal, 37, np.random.default_rng(4))
    q, _ = probe_trigger(true, nominal, P, R, (0.0, 0.0, 0.0), np.zeros(len(P)))
    heights = InstrumentData("probe", q, np.zeros((len(P), 1)), source="heights")
    obj, _ = klipper_object_pairs()
    both = np.concatenate([obj, obj + [0, 0, 0.03]])
    distances = pairs_of(true, both, source="distances")
    # maximum likelihood: a prior pulls noise-free data off the truth by design
    c = calibrate(nominal.with_tolerances(None), [heights, distances], parameters="klipper")
    free = np.asarray(c.calibrated.parameters.free)
    err = (c.calibrated.u - true.u)[free] / c.calibrated.parameters.scales(0.3)[free]
    assert np.abs(err).max() < 1e-9
    assert c.report["parameter_set"]["name"] == "klipper"


def test_csv_columns_and_single_file(tmp_path):
    """q1..q3 and q1b..q3b with distance_mm: calibrated alone (a caliper on any part)."""
    rng = np.random.default_rng(5)
    m = load_machine(EXAMPLES / "linear_delta.yaml")
    P = rng.uniform(-0.07, 0.07, (40, 2, 3)) * [1, 1, 0] + rng.uniform(0, 0.1, (40, 2, 1)) \
        * [0, 0, 1]
    data = pairs_of(m, P)
    lines = ["q1_mm,q2_mm,q3_mm,q1b_mm,q2b_mm,q3b_mm,distance_mm"]
    for qa, qb, d in zip(data.q[:, :3], data.q[:, 3:], data.values[:, 0], strict=True):
        lines.append(",".join(f"{v * 1e3:.9f}" for v in (*qa, *qb, d)))
    (tmp_path / "caliper.csv").write_text("\n".join(lines) + "\n")
    c = calibrate(m, tmp_path / "caliper.csv", parameters="klipper")
    assert c.kind == "pair-distances"
    assert c.report["residuals"]["rms_um"] < 1e-3
    bad = tmp_path / "bad.csv"
    bad.write_text(lines[0] + "\n" + lines[1].rsplit(",", 1)[0] + ",-3\n" + "\n".join(
        lines[2:]) + "\n")
    from pkmcal.errors import InputError

    with pytest.raises(InputError, match="row 2, column distance_mm"):
        calibrate(m, bad, parameters="klipper")
