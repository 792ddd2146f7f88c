"""Derivatives of the instrument layer (issue 13): every measurement model's residual
derivatives and the problem's Jacobian through the forward kinematics, against central
differences of their own retractions, on geometries that are not the examples
(``benchmarks/instruments.py``), at states off the solution."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from pkmcal.instruments import (
    DistancesModel,
    InstrumentProblem,
    IsotropicNoise,
    PointsModel,
)
from pkmcal.instruments.simulate import sample_workspace_poses, simulate_instrument
from pkmcal.instruments.tracker import TrackerNoise
from pkmcal.kinematics import matrix_from_rotvec
from pkmcal.machines.deviations import random_deviations

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "instruments.py"


def _bench():
    spec = importlib.util.spec_from_file_location("instruments_bench", BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module                 # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


bench = _bench()


def _model(kind):
    """A model with nuisance values and rotation start away from zero / the identity."""
    rng = np.random.default_rng(7)
    if kind == "points":
        model = PointsModel(3)
        model.m0 = np.array([1.1, -0.4, 0.2])             # residuals formed about a centroid
        model.rotation_starts = [matrix_from_rotvec([0.3, -1.1, 2.0])]
        noise = TrackerNoise()
    else:
        model = DistancesModel(3)
        noise = IsotropicNoise(1e-6)
    values = rng.normal(size=len(model.parameters)) * 0.1
    if kind == "points":
        values[:3] = 0.0                                   # rotation increments: at the start
        values[3:6] = [1.5, -0.8, 0.3]
    else:
        for g in range(3):                                 # pivots 0.2 m below the platform
            values[model._ip[g]] += [0.0, 0.0, 0.1]
    model.parameters = model.parameters.with_values(values)
    return model, noise


def _poses(n, rng):
    P = np.array([0.0, 0.0, 0.3]) + rng.uniform(-0.1, 0.1, (n, 3))
    R = matrix_from_rotvec(rng.uniform(-0.3, 0.3, (n, 3)))
    return P, R


@pytest.mark.parametrize("kind", ["points", "distances"])
def test_model_residual_derivatives_match_central_differences(kind):
    """``de/dpose`` (``[dP, dOmega]``, rotations on the left) and ``de/dv`` (the model's own
    retraction) against central differences, three targets / setups mixed."""
    rng = np.random.default_rng(3)
    model, _ = _model(kind)
    state = model.retract(model.initial(), rng.normal(size=len(model.parameters)) * 0.05)
    K = 12
    P, R = _poses(K, rng)
    group = np.arange(K) % 3
    measured = rng.normal(size=(K, model.size)) * 0.01 + model.predict(state, P, R, group)
    e, de_dpose, de_dv = model.residuals(state, P, R, measured, group)
    h = 1e-6
    num_pose = np.zeros_like(de_dpose)
    for j in range(6):
        d = np.zeros(6)
        d[j] = h
        Pp, Pm = P + d[:3], P - d[:3]
        Rp, Rm = matrix_from_rotvec(d[3:]) @ R, matrix_from_rotvec(-d[3:]) @ R
        num_pose[..., j] = (model.residuals(state, Pp, Rp, measured, group, False)[0]
                            - model.residuals(state, Pm, Rm, measured, group, False)[0]) / (2 * h)
    assert np.abs(num_pose - de_dpose).max() <= 1e-7 * np.abs(de_dpose).max()
    num_v = np.zeros_like(de_dv)
    for j in range(len(model.parameters)):
        d = np.zeros(len(model.parameters))
        d[j] = h
        num_v[..., j] = (model.residuals(model.retract(state, d), P, R, measured, group,
                                         False)[0]
                         - model.residuals(model.retract(state, -d), P, R, measured, group,
                                           False)[0]) / (2 * h)
    assert np.abs(num_v - de_dv).max() <= 1e-7 * np.abs(de_dv).max()
    # the residual is measured - prediction
    np.testing.assert_allclose(e, measured - model.predict(state, P, R, group),
                               rtol=0, atol=1e-12 * np.abs(measured).max())


@pytest.mark.parametrize("machine", ["hexaslide", "delta", "stewart"])
@pytest.mark.parametrize("kind", ["points", "distances"])
def test_problem_jacobian_matches_central_differences(machine, kind):
    """``InstrumentProblem.evaluate``: machine columns through the forward kinematics
    (implicit function theorem) and nuisance columns, against central differences of the
    problem's retraction, at a state 1e-3 (scaled) away from the start in every direction."""
    rng = np.random.default_rng(5)
    nominal = bench.MACHINES[machine]()
    true = nominal.with_parameters(nominal.u + random_deviations(nominal, rng))
    model, noise = _model(kind)
    P, R = sample_workspace_poses(nominal, 15, rng)
    group = np.arange(15) % 3
    truth = model.initial()
    if kind == "distances":                     # pivots and balls near the workspace
        for g in range(3):
            truth.values[model._ip[g]] = nominal.home[0] + bench.PIVOTS[g]
            truth.values[model._ib[g]] = bench.BALLS[g]
    data = simulate_instrument(true, nominal, model, truth, P, R, group, noise, rng)
    problem = InstrumentProblem(nominal, data, model.with_start(truth), noise)
    n = len(problem.parameters)
    state = problem.retract(problem.initial_state(),
                            rng.normal(size=n) * 1e-3 * problem.scales, None)
    r, J, Jl = problem.evaluate(state)
    assert Jl is None and np.all(np.isfinite(r))
    eps = 1e-5                                  # forward kinematics converge to 1e-12

    def at(step):
        s = problem.retract(state, step, None)
        s.P, s.R = state.P.copy(), state.R.copy()
        return problem.evaluate(s, False)[0]

    num = np.stack([(at(e * eps * problem.scales[j]) - at(-e * eps * problem.scales[j]))
                    / (2 * eps * problem.scales[j]) for j, e in enumerate(np.eye(n))], -1)
    scale = np.abs(J * problem.scales).max()
    assert np.abs((num - J) * problem.scales).max() <= 1e-6 * scale
