"""Build tolerances as a prior (SPEC 9, issue 35): the estimator's maximum a posteriori fit.

- On a linear problem the estimator with a prior gives the closed-form posterior mean and
  covariance ``(J^T J + A^T A / s^2)^-1``; the rank it reports is the data's alone.
- A direction the data do not see stays at its nominal, is labelled ``prior-held`` and carries
  its prior standard deviation; a direction the data fix is ``measured``.
- A linear Delta's default tolerances reach the fit from the machine file, can be overridden
  there (errors name ``tolerances.KEY``) and survive the parameter-set choice.
"""

import numpy as np
import pytest

from pkmcal.errors import InputError
from pkmcal.estimation.estimator import levenberg_marquardt
from pkmcal.parameters import ParameterSet, Prior


class Linear:
    """Whitened residuals ``r = J u - y`` (one row per measurement), no local unknowns."""

    local_dof = 0
    cost_floor = 0.0

    def __init__(self, J, y, parameters):
        self.J, self.y, self.parameters = np.asarray(J, float), np.asarray(y, float), parameters
        self.scales = np.ones(len(parameters))

    def initial_state(self):
        return self.parameters.values.copy()

    def global_values(self, state):
        return np.asarray(state, float)

    def evaluate(self, state, jacobian=True):
        r = (self.J @ state - self.y)[:, None]
        return r, (self.J[:, None, :] if jacobian else None), None

    def retract(self, state, du, dl):
        return state + du


def _problem(rng, n_rows=20, blind=True):
    J = rng.normal(size=(n_rows, 3))
    if blind:
        J[:, 2] *= 1e-3                 # the third parameter: barely seen by the data
    truth = np.array([1.0, -2.0, 0.5])
    y = J @ truth + rng.normal(size=n_rows)
    nominal = np.array([0.8, -1.5, 0.3])
    params = ParameterSet(["a", "b", "c"], ["length"] * 3, nominal)
    prior = Prior.about(params, [("a", {"a": 1.0}, 0.5, "tolerances.a"),
                                 ("b", {"b": 1.0}, 0.5, "tolerances.b"),
                                 ("c", {"c": 1.0}, 0.2, "tolerances.c")])
    return Linear(J, y, params.with_prior(prior)), J, y, nominal


def test_map_is_the_closed_form_posterior_and_rank_counts_the_data_alone():
    rng = np.random.default_rng(1)
    problem, J, y, nominal = _problem(rng)
    res = levenberg_marquardt(problem, absolute_sigma=True)
    P = np.diag(1.0 / np.array([0.5, 0.5, 0.2]) ** 2)
    C = np.linalg.inv(J.T @ J + P)
    mean = C @ (J.T @ y + P @ nominal)
    assert np.allclose(res.x, mean, rtol=1e-9, atol=1e-9 * np.abs(mean).max())
    assert np.allclose(res.covariance, C, rtol=1e-9, atol=1e-12)
    assert res.rank == 3 and res.null_space.shape[1] == 0
    summary = {row.name: row for row in res.prior_summary()}
    assert summary["c"].label == "prior-held" and summary["c"].data_share < 0.01
    assert summary["c"].posterior_std == pytest.approx(np.sqrt(C[2, 2]), rel=1e-9)
    assert summary["a"].label == "measured"
    assert summary["a"].data_share == pytest.approx(1 - C[0, 0] / 0.25, rel=1e-9)
    assert summary["c"].key == "tolerances.c"


def test_a_gauge_stays_at_the_start_and_the_prior_does_not_act_on_it():
    """A direction no measurement changes is a gauge (SPEC appendix A): the data's rank
    counts it out, the step never moves along it, its std is 0 (minimum norm), and the report
    calls it unidentifiable, not prior-held."""
    rng = np.random.default_rng(3)
    problem, J, y, nominal = _problem(rng)
    J[:, 2] = 0.0
    start = nominal + [0.0, 0.0, 0.7]            # 3.5 prior std off its nominal
    problem = Linear(J, y, problem.parameters.with_values(start))
    res = levenberg_marquardt(problem, absolute_sigma=True)
    assert res.rank == 2 and res.adjusted == 2
    assert res.null_space.shape[1] == 1 and abs(abs(res.null_space[2, 0]) - 1) < 1e-12
    assert res.x[2] == start[2] and res.std[2] == 0.0
    P = np.diag(1.0 / np.array([0.5, 0.5]) ** 2)
    J2 = J[:, :2]
    mean = np.linalg.solve(J2.T @ J2 + P, J2.T @ y + P @ nominal[:2])
    assert np.allclose(res.x[:2], mean, rtol=1e-9)
    summary = {row.name: row for row in res.prior_summary()}
    assert summary["c"].label == "unidentifiable"


def test_without_a_prior_the_fit_is_unchanged():
    rng = np.random.default_rng(2)
    problem, J, y, _ = _problem(rng, blind=False)
    plain = Linear(J, y, problem.parameters.with_prior(None))
    res = levenberg_marquardt(plain, absolute_sigma=True)
    assert np.allclose(res.x, np.linalg.lstsq(J, y, rcond=None)[0], rtol=1e-9)
    assert res.prior_summary() == [] and res.fitted is None


def test_derived_parameter_sets_keep_the_prior():
    params = ParameterSet(["a", "b"], ["length", "angle"], [1.0, 2.0])
    prior = Prior.about(params, [("a - b", {"a": 1.0, "b": -1.0}, 0.1, "k")])
    p = params.with_prior(prior)
    for q in (p.with_values([3.0, 4.0]), p.with_fixed("a"), p.with_fixed_mask([True, False])):
        assert q.prior is prior
    both = p.concat(ParameterSet(["z"], ["length"], [0.0]))
    assert both.prior.matrix.shape == (1, 3) and both.prior.mean[0] == pytest.approx(-1.0)
    with pytest.raises(ValueError):
        Prior(["x"], [[1.0, 0.0]], [0.0], [0.0])


# -- a linear Delta ----------------------------------------------------------------------------


def test_linear_delta_default_tolerances_and_overrides(tmp_path):
    from pkmcal.io import load_machine
    from pkmcal.machines.linear_delta import linear_delta

    assert linear_delta(0.14, 0.27).parameters.prior is None     # library: none unless asked
    m = linear_delta(0.14, 0.27, tolerances="default")
    prior = m.parameters.prior
    assert prior is not None
    keys = set(prior.key)
    assert "tolerances.endstop" not in keys                      # effectively free
    assert {"tolerances.arm_trim", "tolerances.tower_tilt", "tolerances.tower_angle"} <= keys
    # the mean arm row does not depend on which of common value and trims is free
    row = prior.names.index("arm_length (mean of the towers)")
    p = m.parameters
    assert prior.matrix[row, p.index("arm_length")] == 1.0
    assert prior.matrix[row, p.index("tower2.arm_trim")] == pytest.approx(1 / 3)
    # the parameter-set choice keeps it
    assert m.with_parameter_set("klipper").parameters.prior is prior

    text = (tmp_path / "printer.yaml")
    base = ("pkmcal: 1\nmachine: linear_delta\nunits: {length: mm, angle: deg}\n"
            "delta_radius: 140.0\narm_length: 270.0\ntower_angles: [210, 330, 90]\n"
            "position_endstop: [300, 300, 300]\n")
    text.write_text(base)
    loaded = load_machine(text)
    assert loaded.parameters.prior is not None
    text.write_text(base + "tolerances: {arm_trim: 0.1, tower_tilt: null}\n")
    loaded = load_machine(text)
    prior = loaded.parameters.prior
    arm = [j for j, k in enumerate(prior.key) if k == "tolerances.arm_trim"]
    assert np.allclose(prior.std[arm], 1e-4)
    assert "tolerances.tower_tilt" not in prior.key
    text.write_text(base + "tolerances: none\n")
    assert load_machine(text).parameters.prior is None
    text.write_text(base + "tolerances: {arm_trims: 0.1}\n")
    with pytest.raises(InputError, match="tolerances.arm_trims"):
        load_machine(text)
    text.write_text(base + "tolerances: {arm_trim: -1}\n")
    with pytest.raises(InputError, match="tolerances"):
        load_machine(text)


def _leaning_printer_fit(tilt_deg, seed=0, n_points=91, sigma=5e-6):
    """A printer with default tolerances whose tower 2 leans ``tilt_deg`` toward the centre
    (radially), probed at ``n_points`` with ``sigma`` trigger noise, calibrated in the
    per-tower model."""
    from pkmcal.calibration import calibrate
    from pkmcal.instruments import InstrumentData
    from pkmcal.instruments.simulate import probe_trigger
    from pkmcal.machines.linear_delta import linear_delta
    from pkmcal.planning import standard_plan

    nominal = linear_delta(0.14, 0.27, position_endstop=(0.3, 0.3, 0.3), tolerances="default")
    p = nominal.parameters
    u = nominal.u.copy()
    u[p.index("tower2.tilt_radial")] = -np.deg2rad(tilt_deg)
    true = nominal.with_parameters(u)
    plan = standard_plan(nominal, "probe", n_points)
    rng = np.random.default_rng(seed)
    q, _ = probe_trigger(true, nominal, plan.P, plan.R, np.zeros(3),
                         sigma * rng.standard_normal(len(plan.P)))
    data = InstrumentData("probe", q, np.zeros((len(q), 1)), source="probe.csv")
    return calibrate(nominal, data, parameters="full", noise=f"{sigma * 1e6}um")


def test_a_leaning_tower_the_data_measure_is_an_action_in_the_printers_terms():
    c = _leaning_printer_fit(0.8)
    rows = {r["name"]: r for r in c.report["tolerances"]["entries"]}
    tilt = rows["tower2.tilt_radial"]
    assert tilt["label"] == "measured"
    actions = c.report["tolerances"]["actions"]
    lean = [a for a in actions if a.startswith("tower B (tower2) leans")]
    assert lean and "toward the centre" in lean[0] and "mm over 300 mm of travel" in lean[0]
    assert lean[0] in c.warnings
    # beyond three tolerances (0.2 deg): the data pull it there, and it is named
    assert "tower2.tilt_radial" in c.report["tolerances"]["pulled"]
    assert any("pull" in w and "tower2.tilt_radial" in w for w in c.warnings)


def test_a_vertical_printer_reports_no_action_and_nothing_pulled():
    c = _leaning_printer_fit(0.0)
    assert c.report["tolerances"]["actions"] == []
    assert c.report["tolerances"]["pulled"] == []
