"""One rank rule (issue 12 item 3): calibrate, identifiability and planning count the same.

"identifiable" is the numerical rank of the whitened, column-scaled, reduced Jacobian
(``s_i > 1e-7 s_1``); "weakly identifiable" are those of them with a standard deviation of at
least 0.1 (scaled) under the assumed noise (:mod:`pkmcal.estimation.rank`). The bug: ML
refused the real 60-pose Jugglebot file with realistic noise ("44 of 48 directions") while
``identifiability`` said 48. Both now say 48, of which 4 weakly; calibrate leaves those 4 at
the design values (adjusting them moved leg offsets by 30-49 mm and doubled the held-out leg
RMS on the 108 other poses: 1.32 mm against 0.64 mm).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pkmcal.identifiability import MAX_STD, RTOL, numerical_rank, rank_rule

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MACHINES = {
    "hexaslide": (EXAMPLES / "hexaslide_default.yaml", 54, 48),
    "delta": (EXAMPLES / "delta_default.yaml", 33, 21),
    "stewart": (EXAMPLES / "cubic_6upu.yaml", 60, 48),
}
JUGGLEBOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "jugglebot"
#: realistic motion-capture noise for the Jugglebot (the residuals of a first fit): readings
#: 0.3 mm, positions 1 mm, orientations 3 mrad
JUGGLEBOT_NOISE = ("0.3mm", "1mm,3mrad")
#: the default Stewart noise (2 um, 20 um, 50 urad) times this leaves exactly one of the 48
#: directions with a standard deviation above 0.1 (0.113; the next 0.086)
ONE_WEAK = 32.0


def _weak(entries):
    """Weak directions among a calibration's named directions (dicts or NullDirections)."""
    def text(d):
        return d["description"] if isinstance(d, dict) else d.description
    return [d for d in entries if text(d).startswith("weakly identifiable")]


def counts_everywhere(machine_path, data_path, noise=None, pose_noise=None, cli=None):
    """(identifiable, weak) from calibrate (library), identifiability (library, and the CLI
    with --json when ``cli``), the planning design and calibrate's CLI JSON."""
    from pkmcal.calibration import (
        calibrate_constraint_link,
        calibrate_full_pose,
        calibrate_tracker,
    )
    from pkmcal.identifiability import identifiability_report
    from pkmcal.io import load_machine, read_constraint_link, read_full_pose, read_tracker
    from pkmcal.planning import design_from_problem, measured_problem, noise_model

    machine = load_machine(machine_path)
    kind = {"hexaslide": "constraint-link", "delta": "tracker", "stewart": "pose"}[machine.kind]
    model = noise_model(kind, noise, pose_noise, machine)
    problem, _ = measured_problem(machine, data_path, kind, model)
    out = {}
    rep = identifiability_report(problem)
    out["identifiability"] = (rep.identifiable, rep.weakly_identifiable)
    design = design_from_problem(problem)
    sv = np.linalg.svd(design.F.reshape(-1, design.rank), compute_uv=False)
    plan = rank_rule(sv)
    out["planning"] = (design.rank, plan.weak)
    # a noise given is held, as the command line holds --noise (else it is estimated from the
    # residuals, and the weak directions are those of the estimated levels)
    est = noise is None and pose_noise is None
    if kind == "constraint-link":
        res = calibrate_constraint_link(machine, read_constraint_link(data_path, machine),
                                        sigma_m=model, estimate_noise=est)
    elif kind == "tracker":
        res = calibrate_tracker(machine, read_tracker(data_path, machine), model,
                                estimate_noise=est)
    else:
        res = calibrate_full_pose(machine, read_full_pose(data_path, machine), noise=model,
                                  estimate_noise=est)
    out["calibrate"] = (res.rank, res.weak)
    assert len(_weak(res.unidentifiable)) == res.weak
    assert res.adjusted == res.rank - res.weak
    if cli is not None:
        args = [] if noise is None else ["--noise", noise]
        args += [] if pose_noise is None else ["--pose-noise", pose_noise]
        proc = cli("identifiability", machine_path, data_path, "--json", *args)
        assert proc.returncode == 0, proc.stderr
        j = json.loads(proc.stdout)
        out["identifiability --json"] = (j["identifiable"], j["weakly_identifiable"])
        assert len(j["weak"]) == j["weakly_identifiable"]
        assert all(w["std"] >= j["max_std"] for w in j["weak"])
        # the same model everywhere: no model extension adopted by cross-validation
        plain = ["--extensions", "none"] if kind == "pose" else []
        proc = cli("calibrate", machine_path, data_path, "-o", "cal.yaml", "--json", *args,
                   *plain)
        assert proc.returncode == 0, proc.stderr
        ident = json.loads(proc.stdout)["identifiability"]
        # the report lists weak directions apart from the unidentifiable ones
        assert _weak(ident["unidentifiable"]) == []
        out["calibrate --json"] = (ident["identifiable"],
                                   len(_weak(ident["weakly_identifiable"])))
    return out


@pytest.fixture(scope="module")
def data_files(tmp_path_factory):
    from clitools import run

    d = tmp_path_factory.mktemp("rank")
    out = {}
    for kind, (machine, *_rest) in MACHINES.items():
        path = d / f"{kind}.csv"
        proc = run("simulate", machine, "--seed", "3", "-o", path, cwd=d)
        assert proc.returncode == 0, proc.stderr
        out[kind] = path
    return out


def test_rule():
    s = np.array([1e3, 50.0, 11.0, 9.0, 1e-5])
    r = rank_rule(s)
    assert (r.identifiable, r.weak, r.adjusted, r.unidentifiable) == (4, 1, 3, 1)
    assert numerical_rank(s) == 4 and RTOL == 1e-7 and MAX_STD == 0.1
    assert rank_rule(s, max_std=None).weak == 0
    assert "4 of 5 free parameter directions identifiable, of which 1 weakly" in r.words()
    assert numerical_rank([]) == 0 and numerical_rank([0.0, 0.0]) == 0
    with pytest.raises(ValueError, match="rtol"):
        rank_rule(s, rtol=1.5)
    with pytest.raises(ValueError, match="max_std"):
        rank_rule(s, max_std=0.0)


@pytest.mark.parametrize("kind", list(MACHINES))
def test_same_counts_for_the_three_machines(kind, data_files, cli):
    machine, n, rank = MACHINES[kind]
    counts = counts_everywhere(machine, data_files[kind], cli=cli)
    assert set(counts.values()) == {(rank, 0)}, counts


def test_one_weak_direction_is_reported_the_same_way_everywhere(data_files, cli):
    """Default Stewart data with a 32x larger assumed noise: one direction's standard
    deviation (0.113 scaled) passes the threshold; every command counts 48, of which 1 weakly,
    and calibrate leaves it unadjusted."""
    noise = f"{2 * ONE_WEAK:g}um"
    pose_noise = f"{20 * ONE_WEAK:g}um,{50 * ONE_WEAK:g}urad"
    counts = counts_everywhere(MACHINES["stewart"][0], data_files["stewart"], noise,
                               pose_noise, cli=cli)
    assert set(counts.values()) == {(48, 1)}, counts
    proc = cli("identifiability", MACHINES["stewart"][0], data_files["stewart"], "--noise",
               noise, "--pose-noise", pose_noise)
    assert proc.returncode == 0, proc.stderr
    text = " ".join(proc.stdout.split())
    assert "48 of 60 free parameter directions identifiable, of which 1 weakly" in text


def test_weak_directions_are_not_refused_but_degenerate_poses_are():
    """A direction that is only weak is no reason to refuse; poses without rotation (whose
    'information' on 18 directions is the orientation noise) still are."""
    from pkmcal.calibration import calibrate_full_pose
    from pkmcal.errors import InputError
    from test_full_pose import Case

    case = Case()
    P, R = case.poses
    data = case.simulate(rng=1, poses=(P, np.broadcast_to(np.eye(3), R.shape)))
    with pytest.raises(InputError, match="orientations vary by .* within 3x their noise"):
        calibrate_full_pose(case.nominal, data)
    res = calibrate_full_pose(case.nominal, data, require_identifiable=False)
    assert res.weak > 0 and res.adjusted < 48      # reported, not fitted to the noise


@pytest.fixture(scope="module")
def jugglebot_60(tmp_path_factory):
    source = JUGGLEBOT / "validation_60_poses.csv"
    if not source.is_file():
        pytest.skip(f"the Jugglebot measurements are not at {JUGGLEBOT} (../shared)")
    from test_jugglebot import convert

    return convert(source, tmp_path_factory.mktemp("juggle") / "validation.csv")


def test_jugglebot_60_poses_realistic_noise(jugglebot_60, cli):
    """The bug report's case: 48 identifiable, of which 4 weakly, from every command."""
    counts = counts_everywhere(EXAMPLES / "jugglebot.yaml", jugglebot_60, *JUGGLEBOT_NOISE,
                               cli=cli)
    assert set(counts.values()) == {(48, 4)}, counts
