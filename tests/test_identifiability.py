"""Identifiability before calibrating (SPEC 3, issue 5 item 1): the library report on the three
problem types and ``pkmcal identifiability MACHINE DATA [--json]``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, digest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MACHINES = {
    "hexaslide": (EXAMPLES / "hexaslide_default.yaml", "constraint-link", 54, 48),
    "delta": (EXAMPLES / "delta_default.yaml", "tracker", 33, 21),
    "stewart": (EXAMPLES / "cubic_6upu.yaml", "pose", 60, 48),
}


@pytest.fixture(scope="module")
def data_files(tmp_path_factory):
    """``pkmcal simulate`` output of each example machine (its default scenario)."""
    from clitools import run

    d = tmp_path_factory.mktemp("ident")
    out = {}
    for kind, (machine, *_rest) in MACHINES.items():
        path = d / f"{kind}.csv"
        proc = run("simulate", machine, "--seed", "3", "-o", path, cwd=d)
        assert proc.returncode == 0, proc.stderr
        out[kind] = path
    return out


def _problem(kind, path):
    from pkmcal.calibration import (
        ConstraintLinkML,
        FullPoseML,
        TrackerProblem,
        estimate_frames,
        register_points,
    )
    from pkmcal.instruments.pose import FullPoseNoise
    from pkmcal.instruments.tracker import TrackerNoise
    from pkmcal.io import load_machine, read_constraint_link, read_full_pose, read_tracker

    machine = load_machine(MACHINES[kind][0])
    if kind == "hexaslide":
        return ConstraintLinkML(machine, read_constraint_link(path, machine), 1e-6)
    if kind == "delta":
        data = read_tracker(path, machine)
        smr = machine.fk(data.q).P - np.array([0.0, 0.0, machine.smr_offset])
        return TrackerProblem(machine, data, TrackerNoise(), register_points(data.m, smr))
    data = read_full_pose(path, machine)
    return FullPoseML(machine, data, FullPoseNoise(), estimate_frames(machine, data))


@pytest.mark.parametrize("kind", list(MACHINES))
def test_library_report(kind, data_files):
    from pkmcal.calibration import reduce_local
    from pkmcal.identifiability import identifiability_report

    _, _, n, rank = MACHINES[kind]
    problem = _problem(kind, data_files[kind])
    rep = identifiability_report(problem)
    assert (rep.parameters, rep.identifiable) == (n, rank)
    assert sum(d.dimension for d in rep.unidentifiable) == n - rank
    o = rep.observability
    assert set(o) == {"O1", "O2", "O3", "O4", "O5"}
    assert all(v > 0 for v in o.values())
    assert rep.condition_number == pytest.approx(1.0 / o["O2"])
    # the minimal set: hold n - rank parameters; the other columns have full rank
    assert len(rep.hold_fixed) == n - rank == len(set(rep.hold_fixed))
    params = problem.parameters
    r, Jg, Jl = problem.evaluate(problem.initial_state())
    free = params.free
    Jr, _, _ = reduce_local(r, Jg[..., free] * problem.scales[free], Jl)
    names = [nm for nm, f in zip(params.names, free, strict=True) if f]
    keep = [i for i, nm in enumerate(names) if nm not in rep.hold_fixed]
    s = np.linalg.svd(Jr[:, keep], compute_uv=False)
    assert len(keep) == rank and s[-1] > 1e-7 * s[0]
    # correlations: genuine pairs of free parameters beyond 0.9, largest first
    for a, b, c in rep.correlated:
        assert a in names and b in names and a != b
        assert 0.9 < abs(c) <= 1.0
    mags = [abs(c) for _, _, c in rep.correlated]
    assert mags == sorted(mags, reverse=True)
    d = rep.as_dict()
    json.dumps(d)
    assert {"parameters", "identifiable", "unidentifiable", "observability",
            "condition_number", "hold_fixed", "correlated"} <= set(d)


def test_library_names_the_constraint_link_gauges(data_files):
    from pkmcal.identifiability import (
        BASE_ROTATION_ABOUT_O,
        PLATFORM_ROTATION_ABOUT_P,
        identifiability_report,
    )

    rep = identifiability_report(_problem("hexaslide", data_files["hexaslide"]))
    assert [(d.name, d.dimension) for d in rep.unidentifiable] == [
        (BASE_ROTATION_ABOUT_O.name, 3), (PLATFORM_ROTATION_ABOUT_P.name, 3)]


def test_library_explicit_groups_and_combinations(data_files):
    """Without groups the null directions are named as parameter combinations."""
    from pkmcal.identifiability import identifiability_report

    problem = _problem("delta", data_files["delta"])
    rep = identifiability_report(problem, groups=())
    assert rep.identifiable == 21
    assert len(rep.unidentifiable) == 12
    assert all(d.dimension == 1 and "." in d.name for d in rep.unidentifiable)
    rep2 = identifiability_report(problem, groups=lambda p, s: p.null_groups(s, p.scales))
    assert [d.name for d in rep2.unidentifiable][:3] == [
        "leg1.da + leg1.db", "leg2.da + leg2.db", "leg3.da + leg3.db"]


def test_correlated_pairs_small_example():
    from pkmcal.identifiability import correlated_pairs, minimal_identifiable_set

    rng = np.random.default_rng(0)
    a = rng.normal(size=50)
    J = np.column_stack([a, a + 0.01 * rng.normal(size=50), rng.normal(size=50),
                         np.zeros(50)])
    pairs = correlated_pairs(J, 3, ["p", "q", "r", "z"])
    assert [(x, y) for x, y, _ in pairs] == [("p", "q")]
    assert pairs[0][2] < -0.9       # nearly equal columns: estimates anti-correlated
    assert list(minimal_identifiable_set(J, 3)) == [3]


@pytest.mark.parametrize("kind", list(MACHINES))
def test_cli_json(kind, data_files, cli):
    machine, measurement, n, rank = MACHINES[kind]
    before = digest(data_files[kind])
    proc = cli("identifiability", machine, data_files[kind], "--json")
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(proc.stdout)
    assert rep["parameters"] == n and rep["identifiable"] == rank
    assert rep["measurement"] == measurement
    assert sum(d["dimension"] for d in rep["unidentifiable"]) == n - rank
    assert all({"name", "dimension", "description"} <= set(d) for d in rep["unidentifiable"])
    assert set(rep["observability"]) == {"O1", "O2", "O3", "O4", "O5"}
    assert rep["condition_number"] > 1
    assert len(rep["hold_fixed"]) == n - rank
    assert all(abs(p["correlation"]) > 0.9 for p in rep["correlated"])
    assert digest(data_files[kind]) == before


def test_cli_summary_hexaslide(data_files, cli):
    proc = cli("identifiability", MACHINES["hexaslide"][0], data_files["hexaslide"])
    assert proc.returncode == 0, proc.stderr
    out = " ".join(proc.stdout.split())
    assert "48 of 54" in out
    assert "3 x rotation of the base frame about O" in out
    assert "3 x re-orientation of the platform frame about P" in out
    assert "O1 =" in out and "condition number" in out and "minimal set" in out


def test_cli_summary_delta_and_stewart(data_files, cli):
    proc = cli("identifiability", MACHINES["delta"][0], data_files["delta"])
    assert proc.returncode == 0, proc.stderr
    out = " ".join(proc.stdout.split())
    assert "21 of 33" in out and "translation of the platform frame" in out
    proc = cli("identifiability", MACHINES["stewart"][0], data_files["stewart"])
    assert proc.returncode == 0, proc.stderr
    out = " ".join(proc.stdout.split())
    assert "48 of 60" in out and "rigid motion of the base frame" in out


def test_cli_bad_input(data_files, cli, tmp_path):
    # data of another machine type: the measurement type does not fit
    proc = cli("identifiability", MACHINES["delta"][0], data_files["hexaslide"])
    assert_input_error(proc, str(data_files["hexaslide"]))
    # a non-number in a reading
    bad = tmp_path / "bad.csv"
    lines = data_files["delta"].read_text().splitlines()
    lines[2] = "abc" + lines[2][lines[2].index(","):]
    bad.write_text("\n".join(lines) + "\n")
    assert_input_error(cli("identifiability", MACHINES["delta"][0], bad), "bad.csv")
    # unknown columns
    cols = tmp_path / "cols.csv"
    cols.write_text("a,b\n1,2\n")
    assert_input_error(cli("identifiability", MACHINES["stewart"][0], cols), "cols.csv")
    # a missing file
    proc = cli("identifiability", MACHINES["stewart"][0], tmp_path / "none.csv")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr


@pytest.mark.parametrize("shape", [(300, 12), (12, 12), (5, 12)])
def test_right_singular_matches_full_svd(shape):
    """s and the whole right basis as a full SVD gives them (tall: through the QR factor)."""
    from pkmcal.identifiability.analysis import right_singular

    rng = np.random.default_rng(1)
    J = rng.normal(size=shape) @ np.diag(np.logspace(0, -4, shape[1]))   # graded columns
    J[:, -1] = J[:, 0]                                                       # one null direction
    s, Vt = right_singular(J)
    _, s_ref, Vt_ref = np.linalg.svd(J, full_matrices=True)
    assert np.allclose(s, s_ref, rtol=1e-10, atol=1e-14 * s_ref[0])
    assert Vt.shape == (shape[1], shape[1])
    assert np.allclose(Vt @ Vt.T, np.eye(shape[1]), atol=1e-12)
    rank = int(np.sum(s > 1e-9 * s[0]))
    assert rank == min(shape[0], shape[1] - 1)
    # the null directions are null, and the row space is the full SVD's (same projector)
    assert np.allclose(J @ Vt[rank:].T, 0, atol=1e-12 * s[0])
    assert np.allclose(Vt[:rank].T @ Vt[:rank], Vt_ref[:rank].T @ Vt_ref[:rank], atol=1e-9)
