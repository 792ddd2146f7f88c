"""A Hexa Slide calibrated with a constraint link, from Python (the library behind `pkmcal`).

Run: `.venv/bin/python examples/scripts/hexaslide_self_calibration.py [machine.yaml]`

1. load the machine file (or the embedded default),
2. plan: predicted accuracy of 150 random poses vs 150 chosen ones (no measurement yet),
3. simulate the measurements on a "true" machine (nominal + the paper's Table 1 errors),
4. calibrate (maximum likelihood), compare the accuracy before and after,
5. compensate: joint commands for target poses with the predicted residual error,
6. save the calibrated machine file (it loads back).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from pkmcal.analysis import pose_accuracy
from pkmcal.analysis.prediction import pose_error_operator
from pkmcal.calibration import calibrate_constraint_link
from pkmcal.compensation import compensate
from pkmcal.instruments.constraint_link import ConstraintLinkData
from pkmcal.io import load_machine, save_machine
from pkmcal.machines import default_hexaslide, paper_table1_deviations
from pkmcal.planning import (
    candidate_poses,
    criterion_value,
    design_from_problem,
    planned_problem,
    random_values,
    select_poses,
)

NOISE = 2e-6          # encoder noise, m


def main(path: str | None = None, n_poses: int = 150, candidates: int = 1000) -> dict:
    nominal = load_machine(path) if path else default_hexaslide()

    # 2. plan: the information of each candidate pose, the predicted accuracy of a choice
    P, R = candidate_poses(nominal, "constraint-link", candidates, rng=0)
    problem = planned_problem(nominal, "constraint-link", P, R, noise=NOISE)
    design = design_from_problem(problem)
    from pkmcal.analysis import workspace_poses

    Pw, Rw = workspace_poses(nominal.home[0], n=300, rng=1)
    A = pose_error_operator(nominal, design, Pw, Rw, problem.n_machine).A
    chosen = select_poses(design, n_poses, "d").index
    predicted = np.sqrt(criterion_value(design.information(chosen), "pose", A))
    random_median = np.median(np.sqrt(random_values(design, n_poses, 30, "pose", A, rng=2)))
    print(f"plan: {design.rank} identifiable directions; predicted RMS position error "
          f"{predicted * 1e6:.2f} um with the chosen poses, {random_median * 1e6:.2f} um "
          "for the median random set")

    # 3. measure (here: simulate) the chosen poses on the true machine
    true = nominal.with_parameters(nominal.u + paper_table1_deviations(nominal.parameters))
    rng = np.random.default_rng(3)
    q = true.ik(P[chosen], R[chosen])
    data = ConstraintLinkData(q + NOISE * rng.standard_normal(q.shape),
                              nominal.constraint_link_length, np.arange(n_poses) % 6)

    # 4. calibrate
    result = calibrate_constraint_link(nominal, data, sigma_m=NOISE)
    calibrated = result.machine
    before = pose_accuracy(true, nominal)
    after = pose_accuracy(true, calibrated)
    print(f"calibration: {result.message}; {result.rank} directions identified")
    print(f"position error (mean over the workspace, frames aligned): "
          f"{before.position_mean * 1e6:.1f} um before, {after.position_mean * 1e6:.2f} um after")

    # 5. compensate: commands for targets, with the predicted residual error
    targets_P = nominal.home[0] + np.array([[0.0, 0.0, 0.0], [0.02, -0.01, 0.01]])
    targets_R = np.broadcast_to(np.eye(3), (2, 3, 3))
    n = len(calibrated.parameters)
    comp = compensate(calibrated, targets_P, targets_R, result.covariance[:n, :n],
                      nominal=nominal, null=(result.null_space * result.scales[:, None])[:n])
    for k in range(2):
        print(f"target {k + 1}: q = {np.round(comp.q[k] * 1e3, 4)} mm, predicted residual "
              f"{comp.position_std[k] * 1e6:.2f} um (nominal commands would be off by "
              f"{comp.uncompensated_position[k] * 1e6:.0f} um)")

    # 6. save the calibrated machine file; it loads back
    out = Path(tempfile.mkdtemp()) / "calibrated.yaml"
    save_machine(calibrated, out)
    assert np.allclose(load_machine(out).u, calibrated.u, rtol=1e-9, atol=1e-12)
    print(f"wrote {out}")
    return {"predicted": predicted, "random_median": random_median,
            "before": before.position_mean, "after": after.position_mean}


if __name__ == "__main__":
    main(*sys.argv[1:2])
