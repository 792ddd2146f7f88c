"""``pkmcal compensate --frame instrument`` on every machine with a tracker or motion-capture
frame (issue 13 item 5): tracker targets put the chosen target (column ``target``) on the
tracker-frame point, a platform that rotates keeping its home orientation or taking the rows'
(tracker-frame) orientation; marker poses in the motion-capture frame go through the
measurement frames (Hexa Slide too). The Delta's behaviour is covered by test_compensate."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, run
from pkmcal.io import save_machine, write_poses, write_positions
from pkmcal.io.csv_io import read_joints, read_readings
from pkmcal.kinematics import matrix_from_rotvec
from test_fk_instrument import calibrated

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def commands(path: Path, m) -> np.ndarray:
    if m.kind == "stewart":
        return read_readings(path, m)[0]
    return read_joints(path, m.n_joints, m.joint_quantity)[0]


def poses(m, n: int, rng, rotate: bool):
    P = m.home[0] + rng.uniform(-0.02, 0.02, (n, 3))
    R0 = np.broadcast_to(m.home[1], (n, 3, 3))
    R = matrix_from_rotvec(rng.uniform(-0.05, 0.05, (n, 3))) @ R0 if rotate else R0.copy()
    return P, R


@pytest.mark.parametrize(("case", "oriented"), [
    ("hexaslide-modified", False), ("hexaslide-modified", True), ("stewart", False),
    ("stewart", True), ("delta-modified", False)])
def test_tracker_targets(case, oriented, tmp_path):
    m, s = calibrated(case, instruments=("tracker",))
    save_machine(m, tmp_path / "cal.yaml", setups=s)
    rng = np.random.default_rng(7)
    P, R = poses(m, 9, rng, rotate=oriented)
    A, a = s["tracker"].base_from_tracker
    known = m.tracker_target()
    targets = np.atleast_2d(known if known is not None else s["tracker"].targets)
    group = np.arange(9) % len(targets)
    Pt = (P + np.einsum("kij,kj->ki", R, targets[group]) - a) @ A
    unit = m.file_units["length"]
    extra = {"target": group + 1} if len(targets) > 1 else None
    if oriented:
        write_poses(tmp_path / "t.csv", Pt, A.T @ R, unit, "deg", extra=extra)
    else:
        write_positions(tmp_path / "t.csv", Pt, unit, extra=extra)
    proc = run("compensate", "cal.yaml", "t.csv", "--frame", "instrument", "-o", "c.csv",
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "tracker's frame" in proc.stdout
    q = commands(tmp_path / "c.csv", m)
    np.testing.assert_allclose(q, m.ik(P, R), rtol=1e-9, atol=1e-11)
    if len(targets) > 1:
        head = (tmp_path / "c.csv").read_text().splitlines()[0]
        assert "target" in head.split(",")


def test_marker_poses_on_a_hexa_slide(tmp_path):
    m, s = calibrated("hexaslide-modified", instruments=("pose", "tracker"))
    save_machine(m, tmp_path / "cal.yaml", setups=s)
    P, R = poses(m, 8, np.random.default_rng(8), rotate=True)
    Pm, Rm = s["pose"].measured(P, R)
    write_poses(tmp_path / "t.csv", Pm, Rm, "mm", "deg")
    proc = run("compensate", "cal.yaml", "t.csv", "--frame", "instrument", "--instrument",
               "pose", "-o", "c.csv", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "motion-capture frame" in proc.stdout
    np.testing.assert_allclose(commands(tmp_path / "c.csv", m), m.ik(P, R), rtol=1e-9,
                               atol=1e-11)


def test_errors(tmp_path):
    m, s = calibrated("stewart-modified")
    save_machine(m, tmp_path / "all.yaml", setups=s)
    P, R = poses(m, 3, np.random.default_rng(1), rotate=False)
    write_positions(tmp_path / "t.csv", P, "m", extra={"target": [1, 2, 5]})

    def comp(*args):
        return run("compensate", *args, "-o", "c.csv", cwd=tmp_path)

    assert_input_error(comp("all.yaml", "t.csv", "--frame", "instrument"),
                       "several instrument frames", "--instrument (tracker|pose)")
    assert_input_error(comp("all.yaml", "t.csv", "--frame", "instrument", "--instrument",
                            "tracker"), "t.csv", "row 4, column target", "target 5")
    assert_input_error(comp("all.yaml", "t.csv", "--instrument", "tracker"),
                       "--instrument tracker", "only with --frame instrument")
    ballbar, s = calibrated("hexaslide", instruments=("distance",))
    save_machine(ballbar, tmp_path / "ballbar.yaml", setups=s)
    assert_input_error(comp("ballbar.yaml", "t.csv", "--frame", "instrument"),
                       "--frame instrument", "ballbar", "base frame")
    tracker, s = calibrated("hexaslide", instruments=("tracker",))
    save_machine(tracker, tmp_path / "tracker.yaml", setups=s)
    assert_input_error(comp("tracker.yaml", "t.csv", "--frame", "instrument", "--instrument",
                            "pose"), "--instrument pose", "it has: tracker")
    assert not (tmp_path / "c.csv").exists()


def test_covariance_of_the_tracker_and_its_targets():
    """The predicted error propagates the covariance of the machine, the tracker pose and the
    estimated targets' places (the calibration's names), per target row."""
    from pkmcal.compensation import compensate, instrument_frames

    m, s = calibrated("stewart-modified", instruments=("tracker",))
    frame = instrument_frames(m, s)["tracker"]
    assert frame.estimated and frame.names[6:9] == ("target1.x", "target1.y", "target1.z")
    P, R = poses(m, 6, np.random.default_rng(2), rotate=False)
    group = np.arange(6) % 3
    A, a = s["tracker"].base_from_tracker
    Pt = (P + np.einsum("kij,kj->ki", R, s["tracker"].targets[group]) - a) @ A
    names = [*m.parameters.names, *frame.names]
    n = len(names)
    C = np.zeros((n, n))
    k = names.index("target2.x")
    C[k, k] = (1e-5) ** 2                   # only target 2's x is uncertain (10 um)
    out = compensate(m, Pt, None, C, frame=frame.with_group(group), names=names)
    np.testing.assert_allclose(out.q, m.ik(P, R), rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(out.position_std, np.where(group == 1, 1e-5, 0.0), atol=1e-9)
    assert out.orientation_std is not None and np.all(out.orientation_std < 1e-9)
    with pytest.raises(ValueError, match="target3"):
        compensate(m, Pt, None, C[:n - 3, :n - 3], frame=frame.with_group(group),
                   names=names[:n - 3])
