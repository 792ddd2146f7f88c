"""Efficiency of every instrument on every machine against the Cramér-Rao bound (issue 13.6).

For each combination machine x instrument - Hexa Slide, Delta and Stewart platform x points
(laser tracker, several targets), distances (ballbar, several mountings) and poses (motion
capture; not the Delta, whose platform does not rotate), plus the constraint link on the Hexa
Slide and the Stewart platform - on a geometry that is none of the examples' (other radii,
lengths, leg angles; a non-cubic hexapod), with a true machine = nominal + random deviations:

- **noise-free recovery**: one calibration from the nominal start on exact data; the largest
  scaled error in the identifiable directions (should be ~1e-12);
- **efficiency**: ``runs`` calibrations from the nominal start with fresh noise at fixed poses;
  ``ratio = sqrt(mean |e|^2 / trace C)``, ``e`` the scaled error in the identifiable
  directions, ``C`` the Cramér-Rao bound there (the whitened, scaled Gauss-Newton covariance at
  the truth with the true noise); ``chi2 = mean(e^T C^+ e) / rank`` (1 for an efficient,
  unbiased estimator); ``k_eff = trace(C)^2 / |C|_F^2``, the number of directions that carry
  the trace: the ratio's own Monte-Carlo spread is about ``1 / sqrt(2 runs k_eff)``.

The error in the identifiable directions, gauge-free:

- points, distances and poses: through predictions. An estimate and the truth predict the
  instrument's readings at *held-out* joint readings; an unidentifiable change (a frame motion
  absorbed by the instrument's unknowns, ...) changes no prediction, exactly. The scaled error
  is ``e = pinv(J) W (h(estimate) - h(truth))``, ``J`` the whitened, scaled Jacobian of the
  predictions at the truth (the problem's own for points and distances, central differences
  in the estimator's frame coordinates for poses): to first order the projection of the error
  on the orthogonal complement of the null space, and insensitive to the finite gauge offset
  between estimate and truth (a linear projection of ``estimate - truth`` is not: its second
  order term, ~(2 mm)^2, exceeds 1e-9).
- constraint link: the estimate is aligned to the truth along the two frame rotations
  (:func:`~pkmcal.identifiability.align_gauge`, nonlinear) and projected (as
  ``pkmcal.bench.cramer_rao_efficiency``).

Usage (from the repository root)::

    .venv/bin/python benchmarks/instruments.py                    # 100 runs per combination
    .venv/bin/python benchmarks/instruments.py --runs 200 --json out.json
    .venv/bin/python benchmarks/instruments.py --only stewart-points

``tests/test_instrument_efficiency.py`` runs the same cases.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")      # many small SVDs: threads slow them
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from pkmcal.calibration import calibrate_constraint_link, calibrate_full_pose  # noqa: E402
from pkmcal.estimation.rank import RTOL, numerical_rank  # noqa: E402
from pkmcal.identifiability import CONSTRAINT_LINK_GAUGES, align_gauge  # noqa: E402
from pkmcal.instruments import (  # noqa: E402
    DistancesModel,
    InstrumentData,
    InstrumentProblem,
    IsotropicNoise,
    PointsModel,
    fit_instrument,
)
from pkmcal.instruments.constraint_link import (
    ConstraintLinkData,
    sample_sphere_poses,  # noqa: E402
)
from pkmcal.instruments.pose import FullPoseNoise, MeasurementFrames, simulate_full_pose
from pkmcal.instruments.simulate import sample_workspace_poses, simulate_instrument  # noqa: E402
from pkmcal.instruments.tracker import TrackerNoise
from pkmcal.kinematics import matrix_from_rotvec, rotvec_from_matrix  # noqa: E402
from pkmcal.machines import Delta, HexaSlide, Stewart  # noqa: E402
from pkmcal.machines.deviations import random_deviations
from pkmcal.machines.hexaslide import hexaslide_parameters  # noqa: E402
from pkmcal.machines.stewart import stewart_parameters  # noqa: E402

# -- geometries that are not the examples ---------------------------------------------------


def hexaslide() -> HexaSlide:
    """Rails from radius 500 mm at z = -410 mm (pairs at 120k -/+ 22 deg), 68 deg elevation,
    struts 460 mm, platform joints at radius 125 mm (120k -/+ 43 deg), link and home 310 mm."""
    k, s = np.repeat(np.arange(3), 2), np.tile([-1.0, 1.0], 3)
    g, gb = np.deg2rad(120 * k + s * 22), np.deg2rad(120 * k + s * 43)
    a0 = np.column_stack([0.5 * np.cos(g), 0.5 * np.sin(g), np.full(6, -0.41)])
    b = np.column_stack([0.125 * np.cos(gb), 0.125 * np.sin(gb), np.zeros(6)])
    alpha = (g + 2 * np.pi) % (2 * np.pi) - np.pi                 # rails point inwards
    params = hexaslide_parameters(b, a0, alpha, np.full(6, np.deg2rad(68)), np.full(6, 0.46))
    return HexaSlide(params, home=(np.array([0.0, 0.0, 0.31]), np.eye(3)),
                     name="benchmark Hexa Slide", constraint_link_length=0.31)


def delta() -> Delta:
    """a = 230, b = 55, l1 = 340, l2 = 870 mm, legs at 85 / 185 / -95 deg, SMR 22 mm."""
    return Delta(0.23, 0.055, 0.34, 0.87, np.deg2rad([85.0, 185.0, -95.0]), smr_offset=0.022,
                 home=(np.array([0.0, 0.0, -0.8]), np.eye(3)), name="benchmark Delta")


def stewart() -> Stewart:
    """A non-cubic Gough platform: base joints at radius 310 mm (pairs 120k -/+ 14 deg),
    platform joints at radius 170 mm, 20 mm below the platform origin (pairs 120k + 60 -/+ 47
    deg), home 380 mm above the base; readings are leg lengths."""
    k, s = np.repeat(np.arange(3), 2), np.tile([-1.0, 1.0], 3)
    gb, gp = np.deg2rad(120 * k + s * 14), np.deg2rad(120 * k + 60 + s * 47)
    base = np.column_stack([0.31 * np.cos(gb), 0.31 * np.sin(gb), np.zeros(6)])
    platform = np.column_stack([0.17 * np.cos(gp), 0.17 * np.sin(gp), np.full(6, -0.02)])
    machine = Stewart(stewart_parameters(base, platform),
                      home=(np.array([0.0, 0.0, 0.38]), np.eye(3)), name="benchmark Stewart")
    machine.constraint_link_length = 0.38        # a link from the base origin to the platform's
    return machine


MACHINES = {"hexaslide": hexaslide, "delta": delta, "stewart": stewart}

# -- instruments: true unknowns and noise -----------------------------------------------------

#: laser tracker 1.9 m from the machine, turned 200 deg about Z and tilted; two targets
TRACKER_R = matrix_from_rotvec([0.0, 0.0, np.deg2rad(200.0)]) @ matrix_from_rotvec([0.05, -0.03,
                                                                                     0.0])
TRACKER_T = np.array([1.7, -0.8, 0.25])
TARGETS = np.array([[0.045, 0.02, 0.035], [-0.04, 0.05, 0.03]])
#: ballbar mountings: pivot offsets from home (base frame) and balls on the platform
PIVOTS = np.array([[0.12, 0.03, -0.16], [-0.08, 0.11, -0.14], [-0.05, -0.12, -0.17],
                   [0.02, 0.0, -0.2]])
BALLS = np.array([[0.03, 0.01, 0.02], [-0.02, 0.03, 0.015], [0.01, -0.035, 0.025],
                  [0.0, 0.0, 0.03]])
BALLBAR_SIGMA = 1e-6
#: motion capture frames (base origin 1.4 m away, turned 110 deg; marker turned 60 deg)
FRAMES = MeasurementFrames(
    (matrix_from_rotvec([0.0, 0.0, np.deg2rad(110.0)]) @ matrix_from_rotvec([0.03, 0.0, 0.0]),
     np.array([1.4, 0.3, -0.2])),
    (matrix_from_rotvec([0.0, np.deg2rad(60.0), 0.0]), np.array([-0.015, 0.02, 0.04])))
POSE_NOISE = FullPoseNoise(2e-6, 20e-6, 50e-6)
LINK_SIGMA = 2e-6

#: (machine, instrument) -> poses per run and number of targets / setups
COMBINATIONS = {
    ("hexaslide", "points"): dict(poses=60, groups=2),
    ("hexaslide", "distances"): dict(poses=120, groups=4),
    ("hexaslide", "poses"): dict(poses=40),
    ("hexaslide", "constraint-link"): dict(poses=120),
    ("delta", "points"): dict(poses=40, groups=1),
    ("delta", "distances"): dict(poses=80, groups=4),
    ("stewart", "points"): dict(poses=60, groups=2),
    ("stewart", "distances"): dict(poses=120, groups=4),
    ("stewart", "poses"): dict(poses=40),
    ("stewart", "constraint-link"): dict(poses=120),
}
NOT_APPLICABLE = {("delta", "poses"): "the Delta's platform does not rotate: a pose adds "
                                      "nothing a point does not give (use points)"}


def combination_names():
    return [f"{m}-{i}" for m, i in COMBINATIONS]


# -- one combination --------------------------------------------------------------------------


@dataclass
class Bound:
    """Cramér-Rao bound in scaled coordinates: covariance, null space, rank."""

    C: np.ndarray
    N: np.ndarray
    rank: int
    n_free: int

    @property
    def k_eff(self) -> float:
        return float(np.trace(self.C) ** 2 / np.sum(self.C**2))


class Case:
    """A nominal machine, its true machine, the instrument's truth and fixed poses.

    Parameters
    ----------
    machine, instrument : str
        A key of :data:`COMBINATIONS`.
    seed : int, optional
        Seed of the deviations, the poses and the held-out readings.
    """

    def __init__(self, machine: str, instrument: str, seed: int = 0):
        self.name = f"{machine}-{instrument}"
        self.instrument = instrument
        setup = COMBINATIONS[(machine, instrument)]
        rng = np.random.default_rng(seed)
        self.nominal = MACHINES[machine]()
        self.true = self.nominal.with_parameters(self.nominal.u
                                                 + random_deviations(self.nominal, rng))
        self.true.constraint_link_length = getattr(self.nominal, "constraint_link_length", None)
        n = setup["poses"]
        self.n_poses = n
        if instrument in ("points", "distances"):
            self._setup_instrument(setup["groups"], n, rng)
        elif instrument == "poses":
            self.poses = sample_workspace_poses(self.nominal, n, rng)
            self.held_out = sample_workspace_poses(self.nominal, 60, rng)
        elif instrument == "constraint-link":
            Lc = self.true.constraint_link_length
            self.P, self.R = sample_sphere_poses(self.true, Lc, n, rng)
            self.q_true = self.true.ik(self.P, self.R)
            self.passive = np.arange(n) % 6
        else:
            raise ValueError(instrument)

    # -- points and distances -------------------------------------------------------------
    def _setup_instrument(self, groups, n, rng):
        if self.instrument == "points":
            self.model = PointsModel(groups)
            self.noise = TrackerNoise()
            truth = self.model.initial()
            truth.rotations = [TRACKER_R]
            truth.values[0:3] = rotvec_from_matrix(TRACKER_R)
            truth.values[3:6] = TRACKER_T
            truth.values[6:] = TARGETS[:groups].ravel()
        else:
            self.model = DistancesModel(groups)
            self.noise = IsotropicNoise(BALLBAR_SIGMA)
            truth = self.model.initial()
            home = self.nominal.home[0]
            for g in range(groups):
                truth.values[self.model._ip[g]] = home + PIVOTS[g]
                truth.values[self.model._ib[g]] = BALLS[g]
        self.truth = truth
        self.P, self.R = sample_workspace_poses(self.nominal, n, rng)
        self.group = np.arange(n) % groups
        P, R = sample_workspace_poses(self.nominal, 100, rng)
        self.q_held = self.nominal.ik(P, R)
        self.group_held = np.arange(100) % groups
        self.exact = self.simulate(None)
        # the truth as a model state and the Jacobian of its predictions at held-out readings
        truth_model = self.model.with_start(truth)
        held = InstrumentData(self.model.kind, self.q_held,
                              truth_model.predict(truth, *self._true_poses(self.q_held),
                                                  self.group_held), self.group_held)
        self._held_problem = InstrumentProblem(self.true, held, truth_model, self.noise)
        self._held_state = self._held_problem.initial_state()
        self._held_truth = held.values
        self._exact_problem = InstrumentProblem(self.true, self.exact, truth_model, self.noise)

    def _true_poses(self, q):
        fk = self.true.fk(q)
        assert fk.converged.all()
        return fk.P, fk.R

    # -- simulation and fit ---------------------------------------------------------------
    def simulate(self, noise="true", rng=None):
        """Data of the experiment (exact with ``noise=None``)."""
        if self.instrument in ("points", "distances"):
            noise = self.noise if noise == "true" else noise
            return simulate_instrument(self.true, self.nominal, self.model, self.truth, self.P,
                                       self.R, self.group, noise, rng)
        if self.instrument == "poses":
            noise = POSE_NOISE if noise == "true" else noise
            return simulate_full_pose(self.true, self.poses, FRAMES, noise, rng)
        sigma = LINK_SIGMA if noise == "true" else 0.0
        rng = np.random.default_rng(rng)
        q = self.q_true + sigma * rng.standard_normal(self.q_true.shape)
        return ConstraintLinkData(q, self.true.constraint_link_length, self.passive)

    def fit(self, data):
        """Calibrate the nominal machine from ``data`` (the library's ML method)."""
        if self.instrument in ("points", "distances"):
            return fit_instrument(self.nominal, data, self.model, self.noise)
        if self.instrument == "poses":
            return calibrate_full_pose(self.nominal, data, method="ml", noise=POSE_NOISE)
        return calibrate_constraint_link(self.nominal, data, method="ml", sigma_m=LINK_SIGMA)

    # -- the bound --------------------------------------------------------------------------
    def bound(self) -> Bound:
        """Cramér-Rao bound at the truth with the true noise (scaled, free coordinates)."""
        if self.instrument in ("points", "distances"):
            problem = self._exact_problem
            r, J, _ = problem.evaluate(problem.initial_state())
            assert np.abs(r).max() < 1e-6                      # the truth fits exact data
            free = problem.parameters.free
            Js = (J[..., free] * problem.scales[free]).reshape(-1, int(free.sum()))
            _, s, Vt = np.linalg.svd(Js, full_matrices=True)
            rank = numerical_rank(s, RTOL)
            C = (Vt[:rank].T / s[:rank] ** 2) @ Vt[:rank]
            return Bound(C, Vt[rank:].T, rank, int(free.sum()))
        if self.instrument == "poses":
            crb = calibrate_full_pose(self.true, self.simulate(None), method="ml",
                                      noise=POSE_NOISE, frames=FRAMES, absolute_sigma=True)
            n = len(crb.scales)
        else:
            exact = self.simulate(None)
            crb = calibrate_constraint_link(self.true, exact, sigma_m=LINK_SIGMA,
                                            absolute_sigma=True)
            n = len(self.nominal.parameters)
        free = crb.parameters.free[:n]
        sc = crb.scales[:n]
        C = (crb.covariance[:n, :n] / np.outer(sc, sc))[np.ix_(free, free)]
        return Bound(C, crb.null_space[:n][free], int(crb.rank), int(free.sum()))

    # -- error in the identifiable directions -----------------------------------------------
    def error(self, result, bound: Bound) -> np.ndarray:
        """Scaled error of an estimate in the identifiable directions (module docstring)."""
        if self.instrument in ("points", "distances"):
            return self._instrument_error(result, bound)
        if self.instrument == "poses":
            return self._pose_error(result, bound)
        n = len(self.nominal.parameters)
        scales = result.scales[:n]
        ua, _ = align_gauge(self.nominal, result.x[:n], self.true.u, CONSTRAINT_LINK_GAUGES,
                            scales)
        e = ((ua - self.true.u) / scales)[result.parameters.free[:n]]
        return e - bound.N @ (bound.N.T @ e)

    def _instrument_error(self, result, bound):
        problem = self._held_problem
        estimate = result.problem.predict(result.state, self.q_held, self.group_held)
        W = problem.W
        delta = np.einsum("kij,kj->ki", W, estimate - self._held_truth).ravel()
        if not hasattr(self, "_held_pinv"):
            _, J, _ = problem.evaluate(self._held_state)
            free = problem.parameters.free
            Js = (J[..., free] * problem.scales[free]).reshape(-1, int(free.sum()))
            self._check_null_space(Js, bound)
            self._held_pinv = np.linalg.pinv(Js, rcond=1e-10)
        return -self._held_pinv @ delta           # residual = measured - h: J = -dh/dx

    def _check_null_space(self, Js, bound):
        """The held-out readings see exactly the directions the calibration data see."""
        s = np.linalg.svd(Js, compute_uv=False)
        assert numerical_rank(s, RTOL) == bound.rank, (numerical_rank(s, RTOL), bound.rank)
        assert np.abs(Js @ bound.N).max() <= 1e-5 * s[0]

    def _pose_predictions(self, machine, frames):
        P, R = self.held_out
        fk = machine.fk(self.nominal.ik(P, R))
        assert fk.converged.all()
        return frames.measured(fk.P, fk.R)

    def _pose_error(self, result, bound):
        """Predictions of marker poses at held-out readings, mapped back through the central
        difference Jacobian in the estimator's coordinates (legs, then increments on the left
        of the frame rotations and the frame translations)."""
        Pt, Rt = self._pose_predictions(self.true, FRAMES)
        Pe, Re = self._pose_predictions(result.machine, result.sections["pose"].frames)
        w = np.array([POSE_NOISE.position_m] * 3 + [POSE_NOISE.orientation_rad] * 3)

        def diff(Pa, Ra):
            return (np.concatenate([Pa - Pt, rotvec_from_matrix(Ra @ np.swapaxes(Rt, -1, -2))],
                                   -1) / w).ravel()

        if not hasattr(self, "_pose_pinv"):
            n = len(self.nominal.parameters)
            scales = result.scales
            free = result.parameters.free
            (A, a), (B, c) = FRAMES.mocap_from_base, FRAMES.platform_from_marker

            def predict(x):
                u = self.true.u + x[:n]
                frames = MeasurementFrames((matrix_from_rotvec(x[n:n + 3]) @ A, a + x[n + 3:n + 6]),
                                           (matrix_from_rotvec(x[n + 6:n + 9]) @ B,
                                            c + x[n + 9:n + 12]))
                return diff(*self._pose_predictions(self.true.with_parameters(u), frames))

            h = 1e-5                  # forward kinematics converge to 1e-12: not smaller
            cols = []
            for j in np.flatnonzero(free):
                dx = np.zeros(len(scales))
                dx[j] = h * scales[j]
                cols.append((predict(dx) - predict(-dx)) / (2 * h))
            Js = np.column_stack(cols)
            self._check_null_space(Js, bound)
            self._pose_pinv = np.linalg.pinv(Js, rcond=1e-10)
        return self._pose_pinv @ diff(Pe, Re)


def run(machine: str, instrument: str, runs: int = 100, seed: int = 0, case=None,
        bound=None) -> dict:
    """Noise-free recovery and ``runs`` noisy calibrations of one combination.

    ``case`` and ``bound``: the combination's :class:`Case` with this ``seed`` and its
    :meth:`Case.bound`, when the caller has them already (default: made here).

    Returns
    -------
    dict
        ``rank``, ``free``, ``poses``, ``runs``, ``noise_free_error`` (largest scaled error in
        the identifiable directions), ``ratio`` (RMS error / CRB), ``chi2`` (mean whitened
        squared error per identifiable direction), ``k_eff``, ``median_s`` (seconds per
        calibration), ``success`` (all converged, none weak), ``unidentifiable`` (what the
        library names, with dimensions), ``errors`` and ``C`` (arrays).
    """
    case = Case(machine, instrument, seed) if case is None else case
    bound = case.bound() if bound is None else bound
    exact = case.fit(case.simulate(None))
    e0 = case.error(exact, bound)
    C_pinv = np.linalg.pinv(bound.C, rcond=1e-10, hermitian=True)
    rng = np.random.default_rng(seed + 1000)
    errors, seconds, success, ranks = [], [], [], []
    for _ in range(runs):
        data = case.simulate("true", rng)
        t0 = time.perf_counter()
        res = case.fit(data)
        seconds.append(time.perf_counter() - t0)
        errors.append(case.error(res, bound))
        success.append(bool(res.success) and res.weak == 0)
        ranks.append(int(res.rank))
    errors = np.array(errors)
    chi2 = np.einsum("ki,ij,kj->k", errors, C_pinv, errors)
    return {"combination": case.name, "rank": bound.rank, "free": bound.n_free,
            "poses": case.n_poses, "runs": runs,
            "noise_free_error": float(np.abs(e0).max()),
            "ratio": float(np.sqrt(np.mean(np.sum(errors**2, 1)) / np.trace(bound.C))),
            "chi2": float(np.mean(chi2) / bound.rank), "k_eff": bound.k_eff,
            "median_s": float(np.median(seconds)),
            "success": bool(all(success) and set(ranks) == {bound.rank}),
            "unidentifiable": {d.name: d.dimension for d in exact.unidentifiable},
            "errors": errors, "C": bound.C}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100, help="noisy calibrations per "
                        "combination (default 100)")
    parser.add_argument("--json", help="write the figures to this file")
    parser.add_argument("--only", action="append", choices=combination_names(),
                        help="run only this combination (repeatable)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    rows = []
    header = (f"{'combination':<27} {'identifiable':>12} {'poses':>5} {'runs':>4} "
              f"{'RMS/CRB':>7} {'chi2/r':>6} {'k_eff':>5} {'median s':>8} "
              f"{'noise-free':>10}  ok")
    print(header)
    print("-" * len(header))
    for (m, i) in COMBINATIONS:
        name = f"{m}-{i}"
        if args.only and name not in args.only:
            continue
        out = run(m, i, args.runs, args.seed)
        ok = out["success"] and abs(out["ratio"] - 1) <= 0.1 and out["noise_free_error"] < 1e-9
        print(f"{name:<27} {out['rank']:>5} of {out['free']:<4} {out['poses']:>5} "
              f"{out['runs']:>4} {out['ratio']:>7.3f} {out['chi2']:>6.3f} "
              f"{out['k_eff']:>5.1f} {out['median_s']:>8.4f} {out['noise_free_error']:>10.1e}"
              f"  {'yes' if ok else 'NO'}", flush=True)
        rows.append({k: v for k, v in out.items() if k not in ("errors", "C")} | {"ok": ok})
    for (m, i), why in NOT_APPLICABLE.items():
        print(f"{m}-{i:<20} n/a: {why}")
    print("\nunidentifiable (named by the library from the noise-free fit):")
    for row in rows:
        print(f"  {row['combination']:<27} " + "; ".join(
            f"{name} ({dim})" for name, dim in row["unidentifiable"].items()))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"runs": args.runs, "seed": args.seed, "results": rows,
                       "not_applicable": {f"{m}-{i}": w for (m, i), w in
                                          NOT_APPLICABLE.items()}}, f, indent=2)
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
