"""Every instrument on every machine it applies to through the commands (issue 13.5):
``simulate --scenario``, ``identifiability`` on the simulated file, ``select-poses`` and
``montecarlo``; refusals with the registry's reason."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from clitools import assert_input_error, digest, run
from pkmcal.identifiability import identifiability_report
from pkmcal.instruments.registry import INSTRUMENTS, instrument
from pkmcal.instruments.simulate import simulate_scenario
from pkmcal.io import load_machine, read_distances, read_points
from pkmcal.planning import planned_problem, standard_plan

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _hexaslide(tmp: Path) -> Path:
    return EXAMPLES / "hexaslide_default.yaml"


def _delta(tmp: Path) -> Path:
    return EXAMPLES / "delta_default.yaml"


def _stewart(tmp: Path) -> Path:
    """The cubic 6-UPU with a constraint link added (a temp copy)."""
    text = (EXAMPLES / "cubic_6upu.yaml").read_text()
    path = tmp / "cubic_link.yaml"
    path.write_text(text + "constraint_link: {length: 410.0}\n")
    return path


def _modified(tmp: Path) -> Path:
    """A Hexa Slide that is not the example: struts 470 mm, rails at 68 deg, link 310 mm."""
    text = (EXAMPLES / "hexaslide_default.yaml").read_text()
    text = text.replace("beta: 70.0", "beta: 68.0").replace("l: 450.0", "l: 470.0")
    text = text.replace("constraint_link: {length: 300.0}", "constraint_link: {length: 310.0}")
    text = text.replace("home: [0.0, 0.0, 300.0,", "home: [0.0, 0.0, 310.0,")
    path = tmp / "hexaslide_modified.yaml"
    path.write_text(text)
    return path


MACHINES = {"hexaslide": _hexaslide, "delta": _delta, "stewart": _stewart,
            "modified": _modified}
#: the scenarios of each machine, as typed (aliases too)
CASES = [(m, s) for m, ss in (("hexaslide", ("constraint-link", "points", "pose", "distance")),
                              ("delta", ("tracker", "distances")),
                              ("stewart", ("constraint-link", "points", "poses", "ballbar")),
                              ("modified", ("points", "pose", "distance", "constraint-link")))
         for s in ss]


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    return tmp_path_factory.mktemp("scenarios")


def _count(text: str) -> int:
    return int(re.search(r"(\d+) of \d+ free parameter directions identifiable", text).group(1))


@pytest.mark.parametrize("name,scenario", CASES, ids=[f"{m}-{s}" for m, s in CASES])
def test_simulate_identify_select_montecarlo(tmp, name, scenario):
    spec = MACHINES[name](tmp)
    machine = load_machine(spec)
    canonical = instrument(scenario).name
    work = tmp / f"{name}-{canonical}"
    work.mkdir()
    extra = {"tracker": ["--targets", "2"] if machine.pose_dof == 6 else [],
             "distance": ["--setups", "3"]}.get(canonical, [])
    before = digest(spec)
    sim = run("simulate", spec, "--scenario", scenario, "--seed", "3", *extra,
              "--truth", "true.yaml", "-o", "data.csv", cwd=work)
    assert sim.returncode == 0, sim.stdout + sim.stderr
    assert digest(spec) == before
    assert (work / "data.csv").exists() and (work / "true.yaml").exists()
    header = (work / "data.csv").read_text().splitlines()[0]
    if canonical == "tracker" and machine.pose_dof == 6:
        assert header.endswith(",target") and "mx_mm" in header
        assert set(read_points(work / "data.csv", machine).group) == {0, 1}
    if canonical == "distance":
        assert "d_mm" in header and header.endswith(",setup")
        assert len(read_distances(work / "data.csv", machine)) == 90
    load_machine(work / "true.yaml")                     # the truth loads back

    # identifiability of the file: the count of the library's planned problem (standard plan)
    ident = run("identifiability", spec, "data.csv", "--json", cwd=work)
    assert ident.returncode == 0, ident.stdout + ident.stderr
    report = json.loads(ident.stdout)
    assert report["measurement"] == canonical
    plan = standard_plan(machine, canonical)
    group = plan.group
    if canonical == "tracker" and machine.pose_dof == 6:
        group = np.arange(len(plan.P)) % 2
    problem = planned_problem(machine, canonical, plan.P, plan.R, group=group)
    expected = identifiability_report(problem)
    assert report["identifiable"] == expected.identifiable
    words = run("identifiability", spec, "data.csv", cwd=work)
    assert words.returncode == 0, words.stderr
    assert _count(words.stdout) == expected.identifiable
    assert "not identifiable" in words.stdout              # the frames, in words
    # without data, the scenario's standard plan: the same count
    planned = run("identifiability", spec, "--scenario", scenario, "--json", cwd=work)
    assert planned.returncode == 0, planned.stderr
    if not (canonical == "tracker" and machine.pose_dof == 6):
        assert json.loads(planned.stdout)["identifiable"] == expected.identifiable

    # select-poses, small, keeping the setup / target column; the plan analysed again
    n = {"constraint-link": 60, "tracker": 30, "pose": 20, "distance": 70}[canonical]
    sel = run("select-poses", spec, "--scenario", scenario, *extra, "-n", n, "--candidates",
              150, "--random-sets", 3, "-o", "plan.csv", "--json", cwd=work)
    assert sel.returncode == 0, sel.stdout + sel.stderr
    plan_header = (work / "plan.csv").read_text().splitlines()[0]
    if canonical == "distance":
        assert plan_header.endswith(",setup")
    if canonical == "tracker" and machine.pose_dof == 6:
        assert plan_header.endswith(",target")
    again = run("identifiability", spec, "plan.csv", "--planned", "--scenario", scenario,
                *extra, "--json", cwd=work)
    assert again.returncode == 0, again.stdout + again.stderr
    assert json.loads(again.stdout)["identifiable"] == json.loads(sel.stdout)["identifiable"]

    # montecarlo, two runs
    mc = run("montecarlo", spec, "--scenario", scenario, "--vary", "noise=1um", "--runs", 2,
             "--workers", 1, "-q", "-o", "mc", cwd=work)
    assert mc.returncode == 0, mc.stdout + mc.stderr
    summary = json.loads((work / "mc" / "summary.json").read_text())
    assert summary["settings"]["scenario"] == canonical
    assert summary["summary"][0]["ok"] == 2


def test_delta_refuses_pose_and_constraint_link(tmp):
    delta = _delta(tmp)
    for scenario, words in (("pose", "platform only translates"),
                            ("poses", "platform only translates"),
                            ("constraint-link", "the constraint link takes one degree")):
        reason = INSTRUMENTS[instrument(scenario).name].applies(load_machine(delta))
        assert reason and words in reason
        for args in (("simulate", delta, "--scenario", scenario, "-o", "x.csv"),
                     ("identifiability", delta, "--scenario", scenario),
                     ("select-poses", delta, "--scenario", scenario, "-n", 10, "-o", "x.csv"),
                     ("montecarlo", delta, "--scenario", scenario, "--vary", "noise=1um",
                      "-o", "mc")):
            proc = run(*args, cwd=tmp)
            assert_input_error(proc, f"--scenario {scenario}", "does not apply", words)
            assert not (tmp / "x.csv").exists()


def test_options_of_other_scenarios_are_refused(tmp):
    hexa = _hexaslide(tmp)
    cases = [
        (("simulate", hexa, "--scenario", "pose", "--setups", 2, "-o", "x.csv"),
         ("--setups", "--scenario distance")),
        (("simulate", hexa, "--scenario", "distance", "--targets", 2, "-o", "x.csv"),
         ("--targets",)),
        (("simulate", hexa, "--scenario", "points", "--grid", "3x3x3", "-o", "x.csv"),
         ("--grid", "--poses")),
        (("simulate", _delta(tmp), "--scenario", "points", "--targets", 2, "-o", "x.csv"),
         ("one target only",)),
        (("simulate", hexa, "--scenario", "distance", "--radius", "-5mm", "-o", "x.csv"),
         ("--radius",)),
        (("identifiability", hexa, "--scenario", "pose", "--radius", "80mm"),
         ("--radius", "distance")),
    ]
    for args, words in cases:
        assert_input_error(run(*args, cwd=tmp), *words)
        assert not (tmp / "x.csv").exists()


def test_library_simulation_carries_the_true_instrument():
    machine = load_machine(EXAMPLES / "hexaslide_default.yaml")
    data, true, truth = simulate_scenario(machine, "distances", 30, rng=1, setups=2,
                                          length=0.12, circles=True)
    assert data.kind == "distances" and data.n_groups == 2 and len(data) == 30
    assert len(truth["setup"]) == 2 and np.allclose(truth["length"], 0.12)
    assert truth["true_setups"]["distance"] is truth["setup"]
    planned = np.array([p for p, _ in truth["planned_setups"]])
    actual = np.array([p for p, _ in truth["setup"]])
    assert 0 < np.max(np.abs(actual - planned)) <= 1e-3
    data, true, truth = simulate_scenario(machine, "points", 12, rng=1, targets=3)
    assert data.n_groups == 3 and truth["setup"].targets.shape == (3, 3)
    assert set(truth["true_setups"]) == {"tracker"}
