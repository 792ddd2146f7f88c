"""Linear Delta printer (issue 14 item 1): kinematics, Jacobians, Klipper's endstop convention,
machine files, firmware parameter sets, a tracker calibration and the command line."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from clitools import run
from pkmcal.errors import InputError
from pkmcal.io.machine_file import load_machine, load_machine_file, machine_to_text, parse_machine
from pkmcal.machines import LinearDelta, default_linear_delta, linear_delta

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "linear_delta.yaml"


def _odd_machine(seed=3) -> LinearDelta:
    """Not the example: other radius, per-tower arms, skewed angles, tilted towers."""
    m = linear_delta(0.118, [0.231, 0.2335, 0.229], np.deg2rad([207.0, 333.0, 91.5]),
                     (0.262, 0.2655, 0.259))
    rng = np.random.default_rng(seed)
    du = np.zeros(len(m.u))
    p = m.parameters
    for i in range(1, 4):
        du[p.index(f"tower{i}.radius_trim")] = rng.uniform(-1e-3, 1e-3)
        du[p.index(f"tower{i}.tilt_radial")] = rng.uniform(-0.01, 0.01)
        du[p.index(f"tower{i}.tilt_tangential")] = rng.uniform(-0.01, 0.01)
    m = m.with_parameters(m.u + du)
    m.b = rng.uniform(-0.03, 0.03, (3, 3))
    return m


def _poses(m, n=200, seed=0):
    rng = np.random.default_rng(seed)
    P = m.home[0] + rng.uniform(-0.06, 0.06, (n, 3))
    return P


def test_fk_inverts_ik():
    m = _odd_machine()
    P = _poses(m)
    q = m.ik(P)
    assert np.all(np.isfinite(q))
    fk = m.fk(q)
    assert fk.converged.all()
    assert np.max(np.abs(fk.P - P)) < 1e-12
    assert np.allclose(m.ik(fk.P), q, rtol=0, atol=1e-12)


def test_jacobians_match_finite_differences():
    m = _odd_machine()
    P = _poses(m, 30)
    q, J, Ju = m.ik_jacobians(P, np.eye(3))
    h = 1e-7
    Jn = np.stack([(m.ik(P + h * e) - m.ik(P - h * e)) / (2 * h) for e in np.eye(3)], -1)
    assert np.max(np.abs(Jn - J[..., :3])) < 1e-7
    assert np.all(J[..., 3:] == 0)
    Jun = np.stack([(m.ik(P, u=m.u + h * e) - m.ik(P, u=m.u - h * e)) / (2 * h)
                    for e in np.eye(len(m.u))], -1)
    assert np.max(np.abs(Jun - Ju)) < 1e-7


def test_klipper_endstop_convention():
    """Klipper (klippy/kinematics/delta.py, extras/delta_calibrate.py): towers at
    (cos(angle) r, sin(angle) r), abs_endstop = position_endstop + sqrt(arm^2 - r^2), carriage
    height sqrt(arm^2 - (tx - x)^2 - (ty - y)^2) + z, steps since the endstop =
    (abs_endstop - height) / step_dist."""
    radius, arms = 0.1385, [0.2681, 0.2674, 0.2690]
    angles, endstops = [210.4, 329.7, 90.0], [0.2934, 0.2951, 0.2917]
    m = linear_delta(radius, arms, np.deg2rad(angles), endstops)
    P = _poses(m, 50, seed=4)
    expected = np.empty((len(P), 3))
    for k, (x, y, z) in enumerate(P):
        for i in range(3):
            tx, ty = (math.cos(math.radians(angles[i])) * radius,
                      math.sin(math.radians(angles[i])) * radius)
            abs_endstop = endstops[i] + math.sqrt(arms[i] ** 2 - radius ** 2)
            height = math.sqrt(arms[i] ** 2 - (tx - x) ** 2 - (ty - y) ** 2) + z
            expected[k, i] = abs_endstop - height
    assert np.allclose(m.ik(P), expected, rtol=0, atol=1e-13)
    # the nozzle at the centre at the height position_endstop puts that carriage at 0
    q = m.ik(np.array([[0.0, 0.0, endstops[1]]]))[0]
    assert abs(q[1]) < 1e-15


def test_chains_map_both_ways():
    m = _odd_machine()
    a0, alpha, beta, l, b = m.chains()
    assert np.allclose(m.parameters_from_chains(a0, alpha, beta, l, b), m.u, rtol=0, atol=1e-14)
    # a0 - b and the direction down: what the Hexa Slide chain computes
    from pkmcal.machines.hexaslide import rail_direction

    a = rail_direction(alpha, beta)
    P = _poses(m, 20)
    for i in range(3):
        d = P + b[i] - a0[i]
        ad = d @ a[i]
        q = ad - np.sqrt(l[i] ** 2 - np.sum(d * d, -1) + ad * ad)
        assert np.allclose(q, m.ik(P)[:, i], rtol=0, atol=1e-13)


def test_file_round_trip_mm_and_m(tmp_path):
    m = _odd_machine()
    m.file_units = {"length": "mm", "angle": "deg"}
    for units in ({"length": "mm", "angle": "deg"}, {"length": "m", "angle": "rad"}):
        text = machine_to_text(m, units)
        assert "chains:" in text and "position_endstop:" in text
        back = parse_machine(text)
        assert isinstance(back, LinearDelta)
        # the per-tower values exactly; the common radius is the towers' mean after loading
        for got, want in zip(back.towers(), m.towers(), strict=True):
            assert np.allclose(got, want, rtol=0, atol=1e-14)
        assert np.allclose(back.b, m.b, rtol=0, atol=1e-15)
        P = _poses(m, 10)
        assert np.allclose(back.ik(P), m.ik(P), rtol=0, atol=1e-13)
        again = parse_machine(machine_to_text(back, units))
        assert np.allclose(again.u, back.u, rtol=0, atol=1e-15)


def test_example_loads_and_design_file_has_no_chains():
    m = load_machine(EXAMPLE)
    assert m.kind == "linear_delta" and m.geometry_problems() == []
    text = machine_to_text(m)
    assert "chains" not in text
    assert parse_machine(text).u.tolist() == m.u.tolist()
    r = m.firmware_values()["radius"]
    assert np.allclose(r, 0.1325)


BASE = """pkmcal: 1
machine: linear_delta
units: {length: mm, angle: deg}
delta_radius: 140.0
arm_length: ARM
tower_angles: [210, 330, 90]
position_endstop: [300, 300, 300]
"""


@pytest.mark.parametrize("arm, words", [
    ("[270, 271]", ("arm_length", "list of 3")),
    ("'abc'", ("arm_length", "not a number")),
    ("-5", ("arm_length", "> 0")),
    ("120.0", ("arm_length", "not longer than the tower's radius")),
])
def test_bad_files_name_the_key(arm, words):
    with pytest.raises(InputError) as info:
        parse_machine(BASE.replace("ARM", arm), "m.yaml")
    for w in words:
        assert w in str(info.value)


def test_bad_chains_and_angles():
    text = BASE.replace("ARM", "270") + "chains:\n" + "".join(
        f"  - {{a0: [{x}, {y}, 500], alpha: 0, beta: {beta}, b: [0, 0, 0], l: 270}}\n"
        for x, y, beta in ((-121, -70, -90), (121, -70, 10), (0, 140, -90)))
    with pytest.raises(InputError, match=r"chains\[1\]\.beta"):
        parse_machine(text, "m.yaml")
    with pytest.raises(InputError, match=r"tower_angles\[1\].*same angle"):
        parse_machine(BASE.replace("ARM", "270").replace("[210, 330, 90]", "[210, 210, 90]"))
    with pytest.raises(InputError, match=r"chains: expected exactly 3 chains"):
        parse_machine(BASE.replace("ARM", "270") + "chains: []\n")


def test_parameter_sets_fix_what_the_firmware_fixes():
    m = default_linear_delta()
    free = {name: [n for n, f in zip(m.parameters.names, m.parameter_set(name).fixed,
                                     strict=True) if not f]
            for name in ("klipper", "klipper-basic", "marlin", "rrf", "full")}
    endstops = ["tower1.endstop", "tower2.endstop", "tower3.endstop"]
    assert sorted(free["klipper"]) == sorted(
        ["delta_radius", "tower1.angle", "tower2.angle", "tower1.arm_trim", "tower2.arm_trim",
         "tower3.arm_trim"] + endstops)
    assert sorted(free["klipper-basic"]) == sorted(free["marlin"]) == sorted(
        ["delta_radius", "tower1.angle", "tower2.angle"] + endstops)
    assert sorted(free["rrf"]) == sorted(free["marlin"] + ["arm_length"])
    assert "tower3.angle" not in free["rrf"] and len(free["full"]) == 18
    assert "delta_radius" not in free["full"]
    with pytest.raises(InputError, match="unknown parameter set"):
        m.parameter_set("smoothie")
    assert m.with_parameter_set("klipper").parameters.fixed.sum() == 20 - 9


def test_frame_motions_are_null_directions_of_the_kinematics():
    m = _odd_machine()
    P = _poses(m, 40)
    Ju = m.ik_jacobians(P)[2].reshape(-1, len(m.u))
    for motion in m.frame_motions():
        if motion.name.endswith("trims"):
            assert np.max(np.abs(Ju @ motion.tangents)) < 1e-12
    # a rigid motion of the towers moves the nozzle by the same motion: the readings at the
    # moved positions stay
    from pkmcal.kinematics import matrix_from_rotvec

    G, t = matrix_from_rotvec([0.01, -0.02, 0.03]), np.array([1e-3, -2e-3, 3e-3])
    moved = m.with_parameters(m.transform_base(m.u, G, t))
    assert np.allclose(moved.ik(P @ G.T + t), m.ik(P), rtol=0, atol=1e-13)


def test_tracker_calibration_recovers_the_truth_noise_free():
    from pkmcal.calibration import calibrate_tracker
    from pkmcal.instruments.tracker import TrackerNoise, TrackerSection, simulate_tracker

    nominal = linear_delta(0.118, [0.231, 0.2335, 0.229], np.deg2rad([207.0, 333.0, 91.5]),
                           (0.262, 0.2655, 0.259))
    true = _odd_machine(seed=5)
    true.b = np.zeros((3, 3))
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    pose = (R, np.array([1.2, -0.4, 0.3]))
    targets = _poses(nominal, 60, seed=7)
    data = simulate_tracker(true, nominal, targets, pose, noise=None, rng=1)
    result = calibrate_tracker(nominal, data, TrackerNoise())
    est = result.machine
    Re, te = result.section(TrackerSection).registration
    G = R @ Re.T
    aligned = est.with_parameters(est.transform_base(est.u, G, pose[1] - G @ te))
    L = true.characteristic_length()
    for got, want in zip(aligned.towers(), true.towers(), strict=True):
        scale = L if got is aligned.towers()[0] else 1.0
        assert np.max(np.abs(got - want)) / scale < 1e-9, (got, want)
    for key in ("radius", "arm_length", "position_endstop"):
        got = np.array(aligned.firmware_values()[key])
        assert np.max(np.abs(got - np.array(true.firmware_values()[key]))) < 1e-9 * L


def test_cli_simulate_points_and_calibrate(tmp_path):
    sim = run("simulate", EXAMPLE, "--scenario", "points", "--targets", "1", "--seed", "2",
              "--truth", "true.yaml", "-o", "data.csv", cwd=tmp_path)
    assert sim.returncode == 0, sim.stderr
    header = (tmp_path / "data.csv").read_text().splitlines()[0]
    assert header.startswith("q1_mm,q2_mm,q3_mm")
    cal = run("calibrate", EXAMPLE, "data.csv", "-o", "cal.yaml", cwd=tmp_path)
    assert cal.returncode == 0, cal.stderr
    m, setups = load_machine_file(tmp_path / "cal.yaml")
    assert m.kind == "linear_delta" and setups.get("tracker") is not None
    assert "chains:" in (tmp_path / "cal.yaml").read_text()
