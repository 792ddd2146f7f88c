"""A printer's frame is its bed (SPEC 8): every position a command reads or writes as a target
or a pose of the nozzle is in the working frame, z the height above the bed of the experiment's
set-ups, consistently across select-poses (its plan and ``--from``), ik, fk, compensate and
identifiability ``--planned``. Machines whose frame is not their bed are untouched.

The printer here is the example linear Delta with a tilted bed (``bed:`` section), the case
where the base frame and the printer's frame differ by mm over the bed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pkmcal.errors import InputError
from pkmcal.instruments.probe import BedSetup
from pkmcal.instruments.setups import Setups
from pkmcal.io import load_machine_file, read_positions, write_positions
from pkmcal.workflows import compensate as compensate_workflow
from pkmcal.workflows import kinematics, planning

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
#: a bed tilted by 2 and -1.5 mm per metre: 0.2 mm across the example's 100 mm bed radius
TILT = (0.002, -0.0015)


def _printer(directory: Path) -> Path:
    path = directory / "printer.yaml"
    path.write_text((EXAMPLES / "linear_delta.yaml").read_text()
                    + f"bed: {{height: 0.0, tilt_x: {TILT[0]}, tilt_y: {TILT[1]}}}\n")
    return path


def _close(a, b, scale) -> bool:
    """Equal within 1e-9 of the magnitude compared."""
    return bool(np.allclose(a, b, rtol=0, atol=1e-9 * scale))


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """A tilted-bed printer's probe plan: (directory, machine file, plan file)."""
    d = tmp_path_factory.mktemp("frame")
    machine = _printer(d)
    plan = d / "plan.csv"
    planning.select_poses(str(machine), plan, 20, candidates=40, random_sets=1)
    return d, machine, plan


def test_a_plans_bed_points_lie_on_the_bed_in_the_written_file(planned):
    """The probe plan's points touch the bed: z = 0 in the printer's frame (in the base frame
    they lie on the tilted plane, z = tilt_x x + tilt_y y, up to 0.2 mm here)."""
    _, machine, plan = planned
    P, _ = read_positions(plan)
    tilt_z = TILT[0] * P[:, 0] + TILT[1] * P[:, 1]
    assert np.abs(tilt_z).max() > 1e-5                 # the tilt moves them measurably
    assert _close(P[:, 2], 0.0, np.abs(P).max())


def test_a_plan_compensated_lands_on_its_positions(planned):
    """select-poses -> compensate -> fk: the commands put the nozzle on the plan's positions,
    read and written in the same frame (before: compensate refused them, "below the bed")."""
    d, machine, plan = planned
    compensate_workflow.run_compensate(str(machine), plan, d / "commands.csv")
    kinematics.fk(str(machine), d / "commands.csv", d / "back.csv")
    P, _ = read_positions(plan)
    back, _ = read_positions(d / "back.csv")
    assert _close(back, P, np.abs(P).max())


def test_the_plans_joint_columns_reach_its_positions(planned):
    """The plan's q columns (joints have no frame) are the ik of its positions and fk turns
    them back into the written positions."""
    d, machine, plan = planned
    kinematics.ik(str(machine), plan, d / "joints.csv")
    kinematics.fk(str(machine), plan, d / "fk.csv")
    written = np.loadtxt(plan, delimiter=",", skiprows=1, usecols=(4, 5, 6))
    joints = np.loadtxt(d / "joints.csv", delimiter=",", skiprows=1)
    assert _close(joints, written, np.abs(written).max())
    assert _close(read_positions(d / "fk.csv")[0], read_positions(plan)[0], 0.1)


def test_ik_then_fk_round_trip_in_the_printers_frame(tmp_path):
    """Positions 5 mm above a tilted bed: ik's joints put the nozzle 5 mm above the bed plane
    in the base frame (not 5 mm above z = 0), and fk gives the file's positions back."""
    machine = _printer(tmp_path)
    xy = np.array([[0.0, 0.0], [0.06, 0.0], [0.0, -0.06], [-0.05, 0.04]])
    P = np.column_stack([xy, np.full(len(xy), 0.005)])
    write_positions(tmp_path / "targets.csv", P, "mm")
    kinematics.ik(str(machine), tmp_path / "targets.csv", tmp_path / "joints.csv")
    kinematics.fk(str(machine), tmp_path / "joints.csv", tmp_path / "back.csv")
    assert _close(read_positions(tmp_path / "back.csv")[0], P, 0.1)
    m, _ = load_machine_file(machine)
    q = np.loadtxt(tmp_path / "joints.csv", delimiter=",", skiprows=1) * 1e-3
    nozzle = m.fk(q).P                                  # the base frame
    above = nozzle[:, 2] - (TILT[0] * nozzle[:, 0] + TILT[1] * nozzle[:, 1])
    assert _close(above, 0.005, 0.1)


def test_the_frame_conversions_invert_each_other_on_a_printer_only(tmp_path):
    """``targets_from_base`` undoes ``targets_in_base`` on a printer with a tilted bed off
    z = 0; a hexapod's positions pass unchanged even beside a bed set-up."""
    printer, _ = load_machine_file(_printer(tmp_path))
    hexapod, _ = load_machine_file(EXAMPLES / "cubic_6upu.yaml")
    setups = Setups({"probe": BedSetup(0.003, *TILT)})
    rng = np.random.default_rng(1)
    P = rng.uniform(-0.1, 0.1, (8, 3))
    base = setups.targets_in_base(printer, P)
    assert _close(base[:, 2] - P[:, 2], 0.003 + TILT[0] * P[:, 0] + TILT[1] * P[:, 1], 0.1)
    assert _close(setups.targets_from_base(printer, base), P, 0.1)
    assert not setups.working_frame_is_base(printer)
    assert np.array_equal(setups.targets_from_base(hexapod, P), P)
    assert np.array_equal(setups.targets_in_base(hexapod, P), P)
    assert setups.working_frame_is_base(hexapod)
    assert Setups().working_frame_is_base(printer)


def test_a_hexapods_plan_and_kinematics_stay_in_its_base_frame(tmp_path):
    """On a hexapod (its frame is not a bed) the plan's positions are those the selection
    computed, ik of them gives the plan's joint columns and fk the positions back."""
    from pkmcal.planning import scenario_for, select_plan

    spec = str(EXAMPLES / "cubic_6upu.yaml")
    plan = tmp_path / "plan.csv"
    planning.select_poses(spec, plan, 12, candidates=30, random_sets=1)
    machine, setups = load_machine_file(spec)
    kind = scenario_for(machine, None)
    sel = select_plan(machine, kind, 12, noise=planning.noise_model(kind, None, None, machine),
                      candidates=30, random_sets=1, seed=0,
                      workspace=planning.workspace_arg(None, machine, 0),
                      joint_bounds=planning.joint_bounds(machine, None)[0],
                      setup=planning.planning_setup(machine, kind, None, None, None,
                                                    setups.get(kind)))
    written = np.loadtxt(plan, delimiter=",", skiprows=1, usecols=(0, 1, 2)) * 1e-3
    assert _close(written, sel.P, 1.0)
    kinematics.ik(spec, plan, tmp_path / "joints.csv")
    kinematics.fk(spec, tmp_path / "joints.csv", tmp_path / "back.csv")
    back = np.loadtxt(tmp_path / "back.csv", delimiter=",", skiprows=1, usecols=(0, 1, 2))
    assert _close(back * 1e-3, written, 1.0)


def test_a_workspace_file_is_in_the_printers_frame(tmp_path):
    """``--workspace POINTS.csv``: a printer's points are heights above its tilted bed; a
    point just above the bed where the tilt lowers it is taken, one just below refused, the
    row and the position as given named."""
    machine = _printer(tmp_path)
    m, setups = load_machine_file(machine)
    points = tmp_path / "ws.csv"
    P = np.array([[0.0, 0.0, 0.005], [0.09, 0.0, 0.00001], [-0.05, 0.04, 0.002]])
    write_positions(points, P, "mm")
    ws = planning.workspace_arg(str(points), m, 0, setups=setups)
    above = ws.P[:, 2] - (TILT[0] * ws.P[:, 0] + TILT[1] * ws.P[:, 1])
    assert _close(above, P[:, 2], 0.1)
    write_positions(points, P * [1, 1, -1], "mm")
    with pytest.raises(InputError, match=r"row\(s\) 2, 3, 4: .*row 2 at \(0, 0, -5\) mm"):
        planning.workspace_arg(str(points), m, 0, setups=setups)
