"""Six-leg platforms whose readings are not leg lengths in the file's unit (SPEC 2.4, 6).

``gain`` is the file's length unit per reading unit. Internally, readings in a length unit are
metres and the gain a ratio; readings in any other unit (``counts``) are kept as read and the
gain is in metres per unit (1e-6 m per count for ``length: mm``, ``gain: 0.001``), so the
readings are ~1e5 and one ulp of a reading is ~1e-11 counts. Forward kinematics must converge
on the leg length (m), not on the reading: with the reading residual against a tolerance in
metres every pose with a reading not exactly representable "failed" (the bug), and
``calibrate`` / ``fk`` refused pkmcal's own simulated data.

Cases: readings in counts with gain 0.001 (mm per count), in um with gain 0.001 (mm per um),
and a file in m with readings in mm and gain 0.001 (m per mm); each against the same device
with readings in mm (gain 1): simulate -> fk round trip and simulate -> calibrate recovering the
truth, through the API and through the ``pkmcal`` command.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from pkmcal.calibration import calibrate_full_pose, full_pose_errors, gauge_free_error
from pkmcal.instruments.pose import FullPoseNoise, default_measurement_frames, simulate_full_pose
from pkmcal.io import (
    load_machine,
    load_machine_file,
    machine_to_text,
    parse_machine,
    read_full_pose,
    read_readings,
)
from pkmcal.machines import cubic_6upu
from pkmcal.machines.deviations import random_deviations

#: case -> (file length unit, reading unit, file gain, internal gain, CSV reading column)
CASES = {
    "counts": ("mm", "counts", 0.001, 1e-6, "q1_counts"),    # 1 um per count, m per count
    "um": ("mm", "um", 0.001, 1.0, "q1_um"),                 # mm per um: a ratio of 1
    "m-file-mm-readings": ("m", "mm", 0.001, 1.0, "q1_mm"),  # m per mm: a ratio of 1
}
REFERENCE = ("mm", "mm", 1.0, 1.0, "q1_mm")                  # examples/cubic_6upu.yaml
GAIN = np.arange(7, 48, 8)                                   # leg{i}.gain in the 48 parameters
L0 = GAIN - 1                                                # leg{i}.l0


def stewart_file(length: str, readings: str, gain: float) -> str:
    """The cubic 6-UPU device (seed 003) as a machine file in the given units."""
    m = cubic_6upu()
    b, p, _, _ = m.legs()
    f = {"mm": 1e3, "m": 1.0}[length]
    legs = "\n".join(f"  - {{base: {[float(v) for v in b[i] * f]}, platform: "
                     f"{[float(v) for v in p[i] * f]}, l0: 0.0, gain: {gain}}}"
                     for i in range(6))
    return (f"pkmcal: 1\nmachine: stewart\nname: cubic 6-UPU\n"
            f"units: {{length: {length}, angle: deg}}\nreadings: {{unit: {readings}}}\n"
            f"legs:\n{legs}\nhome: [0.0, 0.0, {0.41 * f}, 0.0, 0.0, 0.0]\n")


def machine(case):
    """The device of ``case`` = (length unit, reading unit, gain, ...), nominal."""
    length, readings, gain, _, _ = case
    return parse_machine(stewart_file(length, readings, gain), f"{readings}.yaml")


class Setup:
    """Nominal machine, true machine (random deviations, seed 0), default frames."""

    def __init__(self, case):
        self.case = case
        self.nominal = machine(case)
        du = random_deviations(self.nominal, np.random.default_rng(0))
        self.true = self.nominal.with_parameters(self.nominal.u + du)
        self.frames = default_measurement_frames()

    def data(self, noise=None, n=60, seed=1):
        return simulate_full_pose(self.true, n, self.frames, noise, np.random.default_rng(seed))


@pytest.fixture(scope="module", params=list(CASES))
def setup(request):
    return Setup(CASES[request.param])


@pytest.fixture(scope="module")
def reference():
    return Setup(REFERENCE)


# -- loading: the gain is the file's length unit per reading unit ---------------------------------

def test_gain_is_stored_in_internal_units(setup):
    length, readings, gain, internal, _ = setup.case
    m = setup.nominal
    assert m.reading_unit == readings
    np.testing.assert_allclose(m.legs()[3], internal, rtol=1e-15)
    np.testing.assert_array_equal(m.legs()[2], 0.0)
    # saved back in the file's units: the same gain
    assert f"gain: {gain}" in machine_to_text(m)
    # the same leg lengths as the reference device for the same physical readings
    assert m.characteristic_length() == pytest.approx(cubic_6upu().characteristic_length())


# -- forward kinematics ------------------------------------------------------------------------

def test_fk_round_trip_of_simulated_readings(setup, reference):
    """Noise-free: FK of the simulated readings gives back the simulated platform poses, for
    every row, and the same poses as the reference device for the same leg lengths."""
    data = setup.data()
    fk = setup.true.fk(data.q)
    assert fk.converged.all(), f"{(~fk.converged).sum()} rows did not converge"
    # Newton stops at 1e-12 x L on the legs; the pose error is that through J^-1 (7e-13 here):
    # 1e-10 leaves room for another BLAS/CPU, a unit error is >= 1e-6
    np.testing.assert_allclose(fk.P, data.true_P, rtol=0, atol=1e-10)
    np.testing.assert_allclose(fk.R, data.true_R, rtol=0, atol=1e-10)
    # residuals are leg lengths (m), below the tolerance 1e-12 x the characteristic length
    assert np.all(fk.residual < 1e-12 * setup.true.characteristic_length())
    # the reference device (readings in mm, gain 1, the same relative deviations) reads the same
    # lengths: q_ref (m) = q * internal gain
    ref = reference.data()
    np.testing.assert_allclose(data.q * setup.case[3], ref.q, rtol=1e-13)
    np.testing.assert_allclose(fk.P, reference.true.fk(ref.q).P, rtol=0, atol=1e-10)


def test_fk_converges_on_noisy_readings(setup):
    """The user's case: default noise (2 um on the legs); before the fix 48 of 60 rows failed
    with readings in counts."""
    data = setup.data(noise=FullPoseNoise(), seed=2)
    fk = setup.nominal.fk(data.q)
    assert fk.converged.all(), f"{(~fk.converged).sum()} rows did not converge"
    # the nominal model reproduces the readings exactly at its own FK poses
    # bound: the FK's stopping tolerance (1e-12 x L, m) plus rounding of the IK (m scale)
    np.testing.assert_allclose(setup.nominal.ik(fk.P, fk.R) * setup.case[3],
                               data.q * setup.case[3], rtol=0,
                               atol=1e-12 * setup.nominal.characteristic_length() + 1e-12)


def test_fk_residual_is_a_leg_length(setup):
    """One Newton evaluation from the exact pose with one reading off by 1 mm of leg: the
    residual reported is 1e-3 (m), whatever the reading unit."""
    data = setup.data(n=3)
    q = data.q.copy()
    q[:, 2] += 1e-3 / setup.true.legs()[3][2]
    fk = setup.true.fk(q, start=(data.true_P, data.true_R), max_iter=1)
    np.testing.assert_allclose(fk.residual, 1e-3, rtol=1e-6)


# -- calibration -------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["ml", "ik"])
def test_noise_free_calibration_recovers_the_truth(setup, method):
    data = setup.data()
    res = calibrate_full_pose(setup.nominal, data, method=method)
    # residuals over the assumed noise (the fit's own cost is over the estimated levels,
    # which exact data drive to their floor)
    assert res.success and 0.5 * np.sum(res.residuals**2) < 1e-15
    assert (res.rank, int(res.parameters.free.sum())) == (48, 60)
    e = gauge_free_error(setup.nominal, res, setup.true.u, setup.frames)
    assert np.abs(e).max() < 1e-9
    # gains and l0 do not move with the frame gauges: the truth itself, in internal units
    np.testing.assert_allclose(res.x[GAIN], setup.true.u[GAIN], rtol=1e-9)
    np.testing.assert_allclose(res.x[L0], setup.true.u[L0], rtol=0, atol=1e-10)
    err = full_pose_errors(res.machine, res.sections["pose"].frames, setup.data(n=30, seed=5))
    assert err.converged.all() and np.abs(err.leg_length).max() < 1e-10


def test_noisy_calibration_equals_the_reference_in_mm(setup, reference):
    """The same noisy measurements, read in another unit with the matching gain: the same
    calibrated legs and frames (the unit label and the gain change nothing)."""
    noise = FullPoseNoise()
    data, ref = setup.data(noise, seed=3), reference.data(noise, seed=3)
    res = calibrate_full_pose(setup.nominal, data)
    res_ref = calibrate_full_pose(reference.nominal, ref)
    assert res.success and res_ref.success
    g = setup.case[3]
    lengths = np.setdiff1d(np.arange(48), GAIN)
    np.testing.assert_allclose(res.x[lengths], res_ref.x[lengths], rtol=0, atol=1e-10)
    np.testing.assert_allclose(res.x[GAIN], res_ref.x[GAIN] * g, rtol=1e-9)
    np.testing.assert_allclose(res.x[48:], res_ref.x[48:], rtol=0, atol=1e-9)
    assert res.cost == pytest.approx(res_ref.cost, rel=1e-6)


# -- the command -------------------------------------------------------------------------------

def reading_columns(path):
    return (path.read_text().splitlines()[0]).split(",")[:6]


@pytest.mark.parametrize("name", list(CASES))
def test_cli_simulate_fk_calibrate_exact_data(cli, tmp_path, name):
    """simulate (no noise at all) -> fk -> ik and simulate -> calibrate -> the true legs."""
    case = CASES[name]
    (tmp_path / "own.yaml").write_text(stewart_file(*case[:3]))
    sim = cli("simulate", "own.yaml", "--scenario", "pose", "--seed", "2", "--noise", "0um",
              "--pose-noise", "0um,0urad", "--truth", "true.yaml", "-o", "poses.csv")
    assert sim.returncode == 0, sim.stderr
    assert reading_columns(tmp_path / "poses.csv")[0] == case[4]
    true, true_setups = load_machine_file(tmp_path / "true.yaml")
    data = read_full_pose(tmp_path / "poses.csv", true)

    fk = cli("fk", "true.yaml", "poses.csv", "-o", "fk.csv")
    assert fk.returncode == 0, fk.stderr
    poses = np.loadtxt(tmp_path / "fk.csv", delimiter=",", skiprows=1)
    P, _ = true_setups["pose"].platform(data.P, data.R)     # the true platform poses
    f = {"mm": 1e3, "m": 1.0}[case[0]]
    np.testing.assert_allclose(poses[:, :3], P * f, rtol=0, atol=1e-9 * f)
    ik = cli("ik", "true.yaml", "fk.csv", "-o", "q.csv")
    assert ik.returncode == 0, ik.stderr
    back = read_readings(tmp_path / "q.csv", true)[0]
    np.testing.assert_allclose(back * case[3], data.q * case[3], rtol=0,     # FK tol + rounding
                               atol=1e-12 * true.characteristic_length() + 1e-12)

    cal = cli("calibrate", "own.yaml", "poses.csv", "--json", "-o", "cal.yaml")
    assert cal.returncode == 0, cal.stderr
    report = json.loads(cal.stdout)
    assert report["reading_unit"] == case[1]
    assert report["residuals"]["after_calibration"]["leg_length_rms"] < 1e-6       # file unit
    calibrated = load_machine(tmp_path / "cal.yaml")
    np.testing.assert_allclose(calibrated.u[GAIN], true.u[GAIN], rtol=1e-8)
    np.testing.assert_allclose(calibrated.u[L0], true.u[L0], rtol=0, atol=1e-9)


@pytest.mark.parametrize("args", [(), ("--noise", "0", "--deviations", "none")])
def test_cli_counts_as_the_user_ran_it(cli, tmp_path, args):
    """The report: examples/cubic_6upu.yaml with readings in counts and gain 0.001; simulate,
    then calibrate and fk on pkmcal's own data (failed for 48, resp. 28, rows)."""
    (tmp_path / "own.yaml").write_text(stewart_file("mm", "counts", 0.001))
    sim = cli("simulate", "own.yaml", "--scenario", "pose", *args, "-o", "poses.csv")
    assert sim.returncode == 0, sim.stderr
    cal = cli("calibrate", "own.yaml", "poses.csv", "--json", "-o", "cal.yaml")
    assert cal.returncode == 0, cal.stderr
    res = json.loads(cal.stdout)["residuals"]
    assert res["after_calibration"]["fk_failed"] == 0
    assert res["after_calibration"]["leg_length_rms"] < 0.05                        # mm
    if not args:
        assert 0.7 < res["noise_scale"] < 1.3
    for model in ("own.yaml", "cal.yaml"):
        fk = cli("fk", model, "poses.csv", "-o", "fk.csv")
        assert fk.returncode == 0, fk.stderr
        assert "60 pose(s) written" in fk.stdout


def test_cli_counts_and_mm_give_the_same_calibration(cli, tmp_path):
    """Same seed, same device: readings in counts (gain 0.001 mm per count) and in mm (gain 1)
    are the same measurements, and calibrate the same legs."""
    files = {"mm": stewart_file(*REFERENCE[:3]), "counts": stewart_file(*CASES["counts"][:3])}
    for unit, text in files.items():
        (tmp_path / f"{unit}.yaml").write_text(text)
        sim = cli("simulate", f"{unit}.yaml", "--scenario", "pose", "--seed", "4", "-o",
                  f"{unit}.csv")
        assert sim.returncode == 0, sim.stderr
        cal = cli("calibrate", f"{unit}.yaml", f"{unit}.csv", "-o", f"cal_{unit}.yaml")
        assert cal.returncode == 0, cal.stderr
    mm, counts = (load_machine(tmp_path / f"cal_{u}.yaml") for u in ("mm", "counts"))
    q_mm = read_readings(tmp_path / "mm.csv", mm)[0]
    q_counts = read_readings(tmp_path / "counts.csv", counts)[0]
    np.testing.assert_allclose(q_counts * 1e-6, q_mm, rtol=1e-13)
    lengths = np.setdiff1d(np.arange(48), GAIN)
    np.testing.assert_allclose(counts.u[lengths], mm.u[lengths], rtol=0, atol=1e-10)
    np.testing.assert_allclose(counts.u[GAIN], mm.u[GAIN] * 1e-6, rtol=1e-9)
