"""Identifiability in words for every instrument on every machine it applies to (issue 13.2).

On geometries that are none of the examples' (benchmarks/instruments.py), for each
combination of machine and instrument, the planned problem's identifiable count equals the
numerical rank of its scaled, reduced Jacobian computed here independently, the named
unidentifiable directions add up to the rest, and the frame motions are named with what
absorbs them.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from pkmcal.calibration import reduce_local
from pkmcal.errors import InputError
from pkmcal.estimation.rank import RTOL
from pkmcal.identifiability import identifiability_report
from pkmcal.planning import planned_problem, scenario_for, standard_plan

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "instruments.py"


def _bench():
    spec = importlib.util.spec_from_file_location("instruments_bench_ident", BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


bench = _bench()
SCENARIOS = ("tracker", "pose", "distance", "constraint-link")
#: (machine, scenario) -> the named groups and their dimensions
EXPECTED = {
    **{(m, s): {"rigid motion of the base frame": 6, "rigid motion of the platform frame": 6}
       for m in ("hexaslide", "stewart") for s in ("tracker", "pose", "distance")},
    **{(m, "constraint-link"): {"rotation of the base frame about O": 3,
                                "re-orientation of the platform frame about P": 3}
       for m in ("hexaslide", "stewart")},
    ("delta", "tracker"): {"leg1.da + leg1.db": 3, "leg2.da + leg2.db": 3,
                           "leg3.da + leg3.db": 3, "translation of the platform frame": 3},
    ("delta", "distance"): {"leg1.da + leg1.db": 3, "leg2.da + leg2.db": 3,
                            "leg3.da + leg3.db": 3, "translation of the platform frame": 3,
                            "instrument unknowns alone": 9},
}
#: what absorbs the frame motions, in the words of the report
ABSORBERS = {"tracker": ("the tracker frame", "the target's place on the platform"),
             "pose": ("the measurement frame", "the marker's place on the platform"),
             "distance": ("the ballbar's pivot on the base", "the ball on the platform")}


def _numerical_rank(problem):
    r, Jg, Jl = problem.evaluate(problem.initial_state())
    free = problem.parameters.free
    Jr, _, _ = reduce_local(r, Jg[..., free] * problem.scales[free], Jl)
    s = np.linalg.svd(Jr, compute_uv=False)
    return int(np.sum(s > RTOL * s[0])), int(free.sum())


@pytest.mark.parametrize("machine_name", list(bench.MACHINES))
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_identifiability_in_words(machine_name, scenario):
    machine = bench.MACHINES[machine_name]()
    if (machine_name, scenario) not in EXPECTED:
        with pytest.raises(InputError, match="does not apply"):
            scenario_for(machine, scenario)
        return
    name = scenario_for(machine, scenario)
    plan = standard_plan(machine, name, seed=3)
    problem = planned_problem(machine, name, plan.P, plan.R, group=plan.group)
    report = identifiability_report(problem)
    rank, free = _numerical_rank(problem)
    assert (report.identifiable, report.parameters) == (rank, free)
    assert sum(d.dimension for d in report.unidentifiable) == free - rank
    named = {d.name: d.dimension for d in report.unidentifiable}
    assert named == EXPECTED[(machine_name, scenario)]
    if scenario in ABSORBERS and machine.pose_dof == 6:
        words = {d.name: d.description for d in report.unidentifiable}
        base, platform = ABSORBERS[scenario]
        assert f"absorbed by {base}" in words["rigid motion of the base frame"]
        assert f"absorbed by {platform}" in words["rigid motion of the platform frame"]
