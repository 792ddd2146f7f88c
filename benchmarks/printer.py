"""A linear Delta printer calibrated from bed-probe heights, alone and with a ballbar (issue 14).

The printer is none of the examples': ``delta_radius`` 118 mm, arms 232 mm, endstops 262,
263.5, 261 mm, towers at 210.4, 329.7, 90.25 deg (Klipper's defaults are 210, 330, 90) and
leaning by a few hundredths of a degree. The true machine is the nominal one plus random
deviations of printer size (:func:`~pkmcal.measurements.random_deviations`: 1 mm, 0.3 deg) in
the parameters the firmware set adjusts (the others stay as assumed: a firmware's model is
then exact); the true bed is raised 0.8 mm and tilted by 1.1 and -0.7 mm/m. 37 probe points
(the centre and 3 rings), 10 um trigger noise (:data:`~pkmcal.instruments.probe.PROBE_SIGMA`).

For the ``full`` error model (18 tower parameters) and Klipper's set (9) the script reports:

- **identifiability**: the numerical rank of the probe problem (the estimator's: analytic
  Jacobian, scaled, ``RTOL``) and of a central-difference Jacobian of the same residuals with
  respect to the free parameters (scaled by ``problem.scales``, same relative tolerance), the
  named unidentifiable directions with their dimensions, and the largest residual of their
  tangents in the finite-difference Jacobian (relative to its largest singular value);
- **noise-free recovery**: one calibration from the nominal start on exact data; the largest
  scaled error in the identifiable directions, gauge-free through the heights predicted at 40
  held-out probe points (``e = pinv(J_h) (h_estimate - h_true) / sigma``, ``J_h`` the whitened,
  scaled Jacobian of those heights at the truth);
- **held-out heights**: ``runs`` calibrations with fresh trigger noise at the fixed plan; the
  RMS, over runs and the 40 held-out points, of the height the calibrated model and bed
  predict there minus the true one (0: the held-out readings are where the true nozzle
  touches the true bed), against the Cramér-Rao prediction ``sqrt(mean_k J_h,k C J_h,k^T)``
  (``C`` the bound: the whitened, scaled Gauss-Newton covariance at the truth with the true
  noise). ``k_eff = trace(C_h)^2 / |C_h|_F^2`` is the number of independent height errors
  that carry the mean; the ratio's own Monte-Carlo spread is about ``1 / sqrt(2 runs k_eff)``.
  The same at the nominal readings of the held-out points 1 mm above the nominal bed (the
  predicted height minus the true machine's height above the true bed there).

Then probe heights plus 30 ballbar lengths (3 mountings of a 100 mm bar, 1 um), one joint fit
(:func:`~pkmcal.instruments.joint.fit_joint`): each tower's arm length ``arm_length +
arm_trim_i`` (what the data fix) - its RMS error over the runs against its Cramér-Rao standard
deviation from the joint bound, and the bound from the probe heights alone.

Usage (from the repository root)::

    .venv/bin/python benchmarks/printer.py                  # 200 runs per case
    .venv/bin/python benchmarks/printer.py --runs 100 --json out.json

``tests/test_printer.py`` runs the same cases.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from functools import cached_property

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")      # many small SVDs: threads slow them
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from pkmcal.calibration import calibrate_probe  # noqa: E402
from pkmcal.estimation.rank import RTOL, numerical_rank  # noqa: E402
from pkmcal.identifiability import identifiability_report  # noqa: E402
from pkmcal.instruments import (  # noqa: E402
    DistancesModel,
    InstrumentData,
    IsotropicNoise,
    ProbeModel,
)
from pkmcal.instruments.joint import JointProblem, fit_joint  # noqa: E402
from pkmcal.instruments.probe import PROBE_SIGMA, ProbeProblem
from pkmcal.instruments.registry import instrument
from pkmcal.instruments.simulate import probe_trigger, simulate_scenario  # noqa: E402
from pkmcal.machines.deviations import random_deviations
from pkmcal.machines.linear_delta import LinearDelta, linear_delta  # noqa: E402
from pkmcal.planning import standard_plan  # noqa: E402

#: probe points: the centre and 3 rings (Klipper's 7 leave the full model underdetermined)
N_POINTS = 37
#: held-out probe points (random on the probe disk)
N_HELD = 40
#: the true bed: raised 0.8 mm, slopes 1.1 and -0.7 mm/m
TRUE_BED = np.array([8e-4, 1.1e-3, -7e-4])
#: height above the nominal bed of the second held-out set (nominal readings), m
ABOVE = 1e-3
#: ballbar lengths of the joint fit and their noise (m)
N_BALLBAR = 30
BALLBAR_SIGMA = 1e-6
#: the parameter sets studied
SETS = ("full", "klipper")
ARMS = ("tower1.arm_trim", "tower2.arm_trim", "tower3.arm_trim")


def printer() -> LinearDelta:
    """The benchmark printer (not the example): see the module docstring.

    Returns
    -------
    LinearDelta
        The nominal machine, bed at z = 0, every parameter free.
    """
    m = linear_delta(0.118, 0.232, np.deg2rad([210.4, 329.7, 90.25]), (0.262, 0.2635, 0.261),
                     home=(np.array([0.0, 0.0, 0.08]), np.eye(3)),
                     name="benchmark linear Delta (118 mm radius, 232 mm arms)")
    p, u = m.parameters, m.u.copy()
    for i, (tr, tt) in enumerate([(0.05, -0.03), (-0.04, 0.02), (0.03, 0.04)]):   # deg
        u[p.index(f"tower{i + 1}.tilt_radial")] = np.deg2rad(tr)
        u[p.index(f"tower{i + 1}.tilt_tangential")] = np.deg2rad(tt)
    m = m.with_parameters(u)
    m.bed_height = 0.0
    return m


def deviations(machine: LinearDelta, rng) -> np.ndarray:
    """Random printer-size deviations of the parameters the set frees (and of the common
    radius and arm length when their trims are free: only the sums enter)."""
    du = random_deviations(machine, rng)
    p = machine.parameters
    keep = p.free.copy()
    for common, trim in (("delta_radius", "radius_trim"), ("arm_length", "arm_trim")):
        if all(p.free[p.index(f"tower{i + 1}.{trim}")] for i in range(3)):
            keep[p.index(common)] = True
    return np.where(keep, du, 0.0)


def whitened_jacobian(problem, state=None) -> np.ndarray:
    """Whitened Jacobian of a problem, scaled by its ``scales``, free columns, one row per
    residual component."""
    state = problem.initial_state() if state is None else state
    _, J, _ = problem.evaluate(state)
    free = problem.parameters.free
    return (J[..., free] * problem.scales[free]).reshape(-1, int(free.sum()))


def bound(J: np.ndarray):
    """Rank and Cramér-Rao covariance (scaled) of a whitened, scaled Jacobian."""
    _, s, Vt = np.linalg.svd(J, full_matrices=False)
    rank = numerical_rank(s, RTOL)
    return rank, (Vt[:rank].T / s[:rank] ** 2) @ Vt[:rank]


def finite_difference_jacobian(problem, state, rel: float = 1e-6) -> np.ndarray:
    """Central differences of the whitened residuals with respect to the free parameters,
    steps ``rel * scales`` (columns per scaled unit)."""
    n = len(problem.parameters)
    cols = []
    for j in np.flatnonzero(problem.parameters.free):
        step = np.zeros(n)
        step[j] = rel * problem.scales[j]
        rp = problem.evaluate(problem.retract(state, step, None), False)[0]
        rm = problem.evaluate(problem.retract(state, -step, None), False)[0]
        cols.append(((rp - rm) / (2 * rel)).ravel())
    return np.column_stack(cols)


class ProbeCase:
    """The printer with a parameter set, a true machine and bed, the plan and held-out points.

    Parameters
    ----------
    parameter_set : str
        ``full``, ``klipper``, ... (:meth:`LinearDelta.with_parameter_set`).
    sigma : float, optional
        Probe trigger noise, m.
    seed : int, optional
        Seed of the deviations and the held-out points.
    """

    def __init__(self, parameter_set: str, sigma: float = PROBE_SIGMA, seed: int = 0):
        rng = np.random.default_rng(seed)
        self.name, self.sigma = parameter_set, sigma
        self.nominal = printer().with_parameter_set(parameter_set)
        self.du = deviations(self.nominal, rng)
        self.true = self.nominal.with_parameters(self.nominal.u + self.du)
        self.bed = TRUE_BED.copy()
        self.noise = IsotropicNoise(sigma)
        plan = standard_plan(self.nominal, "probe", N_POINTS)
        self.P, self.R = plan.P, plan.R
        P, R, _ = instrument("probe").candidates(self.nominal, N_HELD, rng)
        # held-out readings: where the true nozzle touches the true bed (true height 0), and
        # the nominal readings 1 mm above the nominal bed (true height: about 1 mm)
        self.q_held, _ = probe_trigger(self.true, self.nominal, P, R, self.bed, np.zeros(N_HELD))
        self.q_above = self.nominal.ik(P + [0.0, 0.0, ABOVE], R)
        model = self.bed_model()
        fk = self.true.fk(self.q_above)
        self.h_above = model.predict(model.initial(), fk.P, fk.R, np.zeros(N_HELD, int))[:, 0]
        self.held_problem = ProbeProblem(self.true, InstrumentData(
            "probe", self.q_held, np.zeros((N_HELD, 1))), self.bed_model(), self.noise)
        self.above_problem = ProbeProblem(self.true, InstrumentData(
            "probe", self.q_above, self.h_above[:, None]), self.bed_model(), self.noise)
        self.exact_problem = ProbeProblem(self.true, self.data(None), self.bed_model(),
                                          self.noise)

    def bed_model(self) -> ProbeModel:
        """A probe model whose start is the true bed, in the printer's frame (SPEC 8): its
        height held (the endstops carry it), its tilt estimated (``--bed-tilt estimate``:
        this printer's bed is tilted against the towers by 1.3 mm/m)."""
        model = ProbeModel(fixed=("bed.z",))
        model.parameters = model.parameters.with_values(np.array(self.bed))
        return model

    def data(self, rng) -> InstrumentData:
        """Probe data at the plan: exact (``rng`` None) or with fresh trigger noise."""
        eps = np.zeros(len(self.P)) if rng is None else \
            self.sigma * rng.standard_normal(len(self.P))
        q, _ = probe_trigger(self.true, self.nominal, self.P, self.R, self.bed, eps)
        return InstrumentData("probe", q, np.zeros((len(q), 1)), source="probe.csv")

    @cached_property
    def J(self) -> np.ndarray:
        """Whitened, scaled Jacobian of the exact data at the truth."""
        return whitened_jacobian(self.exact_problem)

    @cached_property
    def J_held(self) -> np.ndarray:
        """Whitened, scaled Jacobian of the held-out heights at the truth."""
        return whitened_jacobian(self.held_problem)

    @cached_property
    def crb(self):
        """``(rank, C)``: the Cramér-Rao bound at the truth (scaled, whitened)."""
        return bound(self.J)

    @cached_property
    def J_above(self) -> np.ndarray:
        """Whitened, scaled Jacobian of the heights 1 mm above the bed at the truth."""
        return whitened_jacobian(self.above_problem)

    def predicted_height_rms(self, above: bool = False) -> tuple[float, float]:
        """Cramér-Rao prediction of the held-out height RMS (m) and ``k_eff``; ``above``: the
        held-out points 1 mm above the bed."""
        _, C = self.crb
        Jh = (self.J_above if above else self.J_held) * self.sigma      # heights, m
        Ch = Jh @ C @ Jh.T
        return float(np.sqrt(np.trace(Ch) / len(Ch))), float(np.trace(Ch) ** 2
                                                             / np.sum(Ch * Ch))

    def held_heights(self, result) -> np.ndarray:
        """Heights the estimate predicts at the held-out readings (truth: 0), m."""
        return result.problem.predict(result.state, self.q_held)[:, 0]

    def above_errors(self, result) -> np.ndarray:
        """Heights the estimate predicts 1 mm above the bed minus the true ones, m."""
        return result.problem.predict(result.state, self.q_above)[:, 0] - self.h_above

    def scaled_error(self, result) -> float:
        """Largest scaled error in the identifiable directions, through held-out heights."""
        e = np.linalg.pinv(self.J_held, rcond=1e-10) @ (self.held_heights(result) / self.sigma)
        return float(np.abs(e).max())

    def arm_lengths(self, u) -> np.ndarray:
        """Each tower's arm length ``arm_length + arm_trim_i``, m."""
        p = self.nominal.parameters
        return u[p.index("arm_length")] + u[p.indices(list(ARMS))]

    def arm_std(self, problem, C) -> np.ndarray:
        """Cramér-Rao standard deviations of the arm lengths (m) from a scaled covariance
        over the problem's free parameters; NaN where the data do not fix them."""
        p, free = problem.parameters, problem.parameters.free
        idx = np.flatnonzero(free)
        out = []
        for trim in ARMS:
            g = np.zeros(len(p))
            for name in ("arm_length", trim):
                g[p.index(name)] = problem.scales[p.index(name)]
            g = g[idx]
            out.append(np.sqrt(g @ C @ g))
        return np.array(out)


# -- identifiability ---------------------------------------------------------------------------


def identifiability_check(case: ProbeCase, planned: bool = True) -> dict:
    """The estimator's rank and named null directions against central differences.

    ``planned``: the problem of the plan on the nominal machine and bed (what ``identifiability
    --scenario probe`` analyses, the bed flat); else the true machine, tilted bed, exact data.
    """
    if planned:
        from pkmcal.planning import planned_problem

        problem = planned_problem(case.nominal, "probe", case.P, case.R, noise=case.noise)
    else:
        problem = case.exact_problem
    state = problem.initial_state()
    Jfd = finite_difference_jacobian(problem, state)
    s = np.linalg.svd(Jfd, compute_uv=False)
    report = identifiability_report(problem)
    free = problem.parameters.free
    groups = problem.null_groups(state, problem.scales)
    T = np.column_stack([g.tangents for g in groups]) if groups else np.zeros((len(free), 0))
    leak = max((float(np.abs(Jfd @ g.tangents[free]).max() / s[0]) for g in groups),
               default=0.0)
    tangent_rank = numerical_rank(np.linalg.svd(T, compute_uv=False), 1e-6) if T.size else 0
    return {"free": int(free.sum()), "rank": report.identifiable,
            "rank_fd": numerical_rank(s, RTOL),
            "named": {d.name: d.dimension for d in report.unidentifiable},
            "tangent_rank": tangent_rank, "tangent_leak": leak}


# -- Monte Carlo ---------------------------------------------------------------------------------


def noise_free(case: ProbeCase) -> dict:
    """One calibration on exact data from the nominal start."""
    result = calibrate_probe(case.nominal, case.data(None), case.noise, bed="estimate")
    start = np.abs(case.nominal.u - case.true.u) / result.scales[:len(case.true.u)]
    return {"success": bool(result.success), "rank": int(result.rank), "weak": int(result.weak),
            "error": case.scaled_error(result), "start_error": float(start.max()),
            "held_max": float(np.abs(case.held_heights(result)).max())}


def probe_runs(case: ProbeCase, runs: int, seed: int = 7) -> dict:
    """``runs`` calibrations with fresh noise: held-out height RMS against the bound, and the
    arm lengths' errors."""
    rng = np.random.default_rng(seed)
    rank, C = case.crb
    heights, above, arms, weak, failed = [], [], [], 0, 0
    for _ in range(runs):
        result = calibrate_probe(case.nominal, case.data(rng), case.noise, bed="estimate")
        failed += not result.success
        weak += result.rank - result.weak != rank
        heights.append(case.held_heights(result))
        above.append(case.above_errors(result))
        arms.append(case.arm_lengths(result.state.u) - case.arm_lengths(case.true.u))
    predicted, k_eff = case.predicted_height_rms()
    rms = float(np.sqrt(np.mean(np.square(heights))))
    rms_above = float(np.sqrt(np.mean(np.square(above))))
    predicted_above, _ = case.predicted_height_rms(above=True)
    arms = np.array(arms)
    return {"runs": runs, "rank": rank, "failed": failed, "weak_runs": weak,
            "height_rms": rms, "height_crb": predicted, "ratio": rms / predicted,
            "k_eff": k_eff, "above_rms": rms_above, "above_crb": predicted_above,
            "above_ratio": rms_above / predicted_above,
            "arm_rms": np.sqrt(np.mean(arms ** 2, 0)).tolist(),
            "arm_bias": arms.mean(0).tolist(),
            "arm_crb": case.arm_std(case.exact_problem, C).tolist()}


class JointCase:
    """The probe case plus ballbar lengths of the same true machine."""

    def __init__(self, probe: ProbeCase, n: int = N_BALLBAR, sigma: float = BALLBAR_SIGMA,
                 seed: int = 11):
        self.probe = probe
        self.sigma = sigma
        self.bar, _, truth = simulate_scenario(probe.nominal, "distance", n, noise=False,
                                               rng=seed, deviations=probe.du)
        self.bar.source = "bar.csv"
        self.k = len(truth["setups"])
        model = DistancesModel(self.k)
        values = np.array(model.parameters.values, float)
        for g, (pv, b) in enumerate(truth["setups"]):
            values[model._ip[g]] = pv
            values[model._ib[g]] = b
        model.parameters = model.parameters.with_values(values)
        self.bar_noise = IsotropicNoise(sigma)
        self.problem = JointProblem(probe.true, [
            (probe.data(None), probe.bed_model(), probe.noise),
            (self.bar, model, self.bar_noise)], ["probe.csv", "bar.csv"])
        # the truth fits the exact data (a check on the set-up)
        r, _, _ = self.problem.evaluate(self.problem.initial_state(), False)
        assert np.abs(r).max() < 1e-5, np.abs(r).max()

    @cached_property
    def crb(self):
        """``(rank, C)`` of the joint problem at the truth."""
        return bound(whitened_jacobian(self.problem))

    def arm_crb(self) -> np.ndarray:
        """Cramér-Rao standard deviations of the arm lengths from the joint bound, m."""
        return self.probe.arm_std(self.problem, self.crb[1])

    def data(self, rng):
        """Probe and ballbar data with fresh noise."""
        bar = InstrumentData("distance", self.bar.q, self.bar.values
                             + self.sigma * rng.standard_normal(self.bar.values.shape),
                             self.bar.group, source="bar.csv")
        return self.probe.data(rng), bar

    def fit(self, probe_data, bar):
        """One joint fit from the nominal start."""
        return fit_joint(self.probe.nominal, [(probe_data, ProbeModel(fixed=("bed.z",)),
                                               self.probe.noise),
                                              (bar, DistancesModel(self.k), self.bar_noise)])


def joint_runs(case: JointCase, runs: int, seed: int = 13) -> dict:
    """``runs`` joint fits with fresh noise: arm length errors against the joint bound."""
    rng = np.random.default_rng(seed)
    rank, _ = case.crb
    arms, failed, weak = [], 0, 0
    true_arms = case.probe.arm_lengths(case.probe.true.u)
    for _ in range(runs):
        result = case.fit(*case.data(rng))
        failed += not result.success
        weak += result.rank - result.weak != rank
        arms.append(case.probe.arm_lengths(result.state.u) - true_arms)
    arms = np.array(arms)
    crb = case.arm_crb()
    rms = np.sqrt(np.mean(arms ** 2, 0))
    return {"runs": runs, "rank": rank, "failed": failed, "weak_runs": weak,
            "arm_rms": rms.tolist(), "arm_bias": arms.mean(0).tolist(),
            "arm_crb": crb.tolist(), "ratio": (rms / crb).tolist(),
            "pooled_ratio": float(np.sqrt(np.sum(rms ** 2) / np.sum(crb ** 2))),
            "probe_alone_crb": case.probe.arm_std(case.probe.exact_problem,
                                                  case.probe.crb[1]).tolist()}


# -- the table -----------------------------------------------------------------------------------


def run_all(runs: int) -> dict:
    out = {}
    for name in SETS:
        t0 = time.time()
        case = ProbeCase(name)
        row = {"identifiability": identifiability_check(case),
               "identifiability_tilted_bed": identifiability_check(case, planned=False),
               "noise_free": noise_free(case), "probe": probe_runs(case, runs)}
        joint = JointCase(case)
        row["joint"] = joint_runs(joint, runs)
        row["seconds"] = time.time() - t0
        out[name] = row
    return out


def table(out: dict) -> str:
    um = 1e6
    lines = []
    for name, row in out.items():
        ident, tilted = row["identifiability"], row["identifiability_tilted_bed"]
        nf, pr, jo = row["noise_free"], row["probe"], row["joint"]
        lines += [f"== {name}: {ident['free']} free parameters (with the bed plane), "
                  f"{N_POINTS} probe points, {PROBE_SIGMA * um:g} um trigger noise ==",
                  f"  rank: estimator {ident['rank']}, central differences {ident['rank_fd']}; "
                  f"named: {ident['named']} (tangents span {ident['tangent_rank']}, largest "
                  f"|J_fd T| / s_max {ident['tangent_leak']:.1e})",
                  f"  on the tilted true bed: rank {tilted['rank']} / fd {tilted['rank_fd']}; "
                  f"named: {tilted['named']} (tangents span {tilted['tangent_rank']})",
                  f"  noise-free: scaled error in the identifiable directions {nf['error']:.1e} "
                  f"(start {nf['start_error']:.1e}); held-out heights max "
                  f"{nf['held_max'] * 1e9:.2g} nm",
                  f"  held-out heights, {pr['runs']} runs: RMS {pr['height_rms'] * um:.3f} um, "
                  f"Cramér-Rao {pr['height_crb'] * um:.3f} um, ratio {pr['ratio']:.3f} "
                  f"(k_eff {pr['k_eff']:.1f}; failed {pr['failed']}, runs with weak "
                  f"directions {pr['weak_runs']})",
                  f"  1 mm above the bed (nominal readings): RMS {pr['above_rms'] * um:.3f} um, "
                  f"Cramér-Rao {pr['above_crb'] * um:.3f} um, ratio {pr['above_ratio']:.3f}",
                  "  arm lengths from probe heights alone: RMS error "
                  + ", ".join(f"{v * 1e3:.3f}" for v in pr["arm_rms"]) + " mm; Cramér-Rao "
                  + ", ".join(f"{v * 1e3:.3f}" for v in pr["arm_crb"]) + " mm; bias "
                  + ", ".join(f"{v * 1e3:+.3f}" for v in pr["arm_bias"]) + " mm",
                  f"  probe + {N_BALLBAR} ballbar lengths ({BALLBAR_SIGMA * um:g} um), "
                  f"{jo['runs']} joint fits: arm RMS "
                  + ", ".join(f"{v * um:.3f}" for v in jo["arm_rms"]) + " um; Cramér-Rao "
                  + ", ".join(f"{v * um:.3f}" for v in jo["arm_crb"]) + " um; ratio "
                  + ", ".join(f"{v:.3f}" for v in jo["ratio"])
                  + f" (pooled {jo['pooled_ratio']:.3f}); bias "
                  + ", ".join(f"{v * um:+.3f}" for v in jo["arm_bias"]) + " um"
                  + f"; failed {jo['failed']}, weak {jo['weak_runs']}",
                  f"  ({row['seconds']:.1f} s)"]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=200, help="noisy runs per case")
    parser.add_argument("--json", help="write the figures to this file")
    args = parser.parse_args(argv)
    out = run_all(args.runs)
    print(table(out))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
