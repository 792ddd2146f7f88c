"""Default options on data whose noise is not the assumed one, against the true noise's bound
(issue 16, item 5).

Every machine x instrument combination of ``benchmarks/instruments.py`` (its geometries that
are none of the examples', its true machines, poses, instrument truths and its gauge-free error
in the identifiable directions) plus the probe heights of ``benchmarks/printer.py``'s linear
Delta printer (``full`` error model, 37 points) alone and in a joint fit with 60 ballbar
lengths, simulated with a noise that DIFFERS from the one the calibration assumes (the
library's default for the instrument):

- tracker (points): isotropic 7 um (the default assumes the Leica-type ``TrackerNoise()``: 5 um
  along the beam, 7.5 um + 3 um/m across it), and ``TrackerNoise()`` x 3;
- ballbar (distances): 3 um (1 um assumed);
- full poses: positions x 5 and orientations x 0.3 (100 um, 15 urad; ``FullPoseNoise()``
  assumes 20 um, 50 urad), and leg readings x 10 (20 um; 2 um assumed);
- constraint link: encoder readings x 10 (20 um; 2 um assumed);
- probe heights: x 3 (30 um; 10 um assumed), alone and with 60 ballbar lengths whose noise is
  the assumed 1 um (two files: one level each).

Each run draws fresh noise at the case's fixed poses and calibrates the same data twice from
the nominal start: with the DEFAULT options (noise levels estimated from the residuals,
``estimate_noise=True``) and with ``estimate_noise=False`` (the assumed levels held, the
covariance scaled by the residual variance: the behaviour before issue 16). Figures:

- ``RMS / CRB = sqrt(mean |e|^2 / trace C)``, ``e`` the scaled error in the identifiable
  directions (``instruments.py``'s measure: through predictions at held-out readings; the
  constraint link aligned along its frame rotations; the probe through heights at 40 held-out
  points; the joint fit through its own readings' predictions), ``C`` the Cramér-Rao bound OF
  THE TRUE NOISE (the whitened, scaled Gauss-Newton covariance at the truth, whitened by the
  true noise, restricted to the identifiable directions). The Monte-Carlo standard error of a
  ratio is ``ratio sd(|e|^2) / (2 sqrt(runs) mean(|e|^2))`` (delta method, from the runs).
- ``z2``: whether the REPORTED uncertainty is honest: the mean over the runs of ``d^T S^+ d /
  r``, ``d`` the estimate's predictions minus the truth's (held-out measurements), ``S`` their
  covariance from the covariance the calibration reports (:meth:`NoiseCase.whitened_error`):
  about 1 when the reported covariance is the error's (F(r, redundancy) with estimated levels);
  over the first :data:`Z2_RUNS` runs of a case (the check costs more than a calibration).
- ``est/true``: the mean over the runs of each estimated level over the true one.
- ``t def/fix``: median seconds per calibration with the default options over the median with
  the levels held, both timed in the same run, one after the other on the same data.

Target (issue 16): default ``RMS / CRB <= 1.05`` up to Monte-Carlo error; a case passes
(``ok``) when ``ratio - 2 se <= 1.05``, every default calibration converged and none was
refused. Runs whose calibration adjusted another number of directions than the bound's rank (a
direction whose standard deviation at the noise used exceeds ``MAX_STD`` is weak, not adjusted)
are counted and named in the table.

Usage (from the repository root)::

    .venv/bin/python benchmarks/noise.py                       # 200 runs per case
    .venv/bin/python benchmarks/noise.py --quick               # 40 runs per case
    .venv/bin/python benchmarks/noise.py --runs 200 --jobs 2 --json out.json
    .venv/bin/python benchmarks/noise.py --only delta-points:isotropic

``tests/test_noise_estimation.py`` checks the estimated levels, the reported uncertainty and
the outlier test on smaller cases of the same machinery.
"""

from __future__ import annotations

import argparse
import copy
import importlib.util
import json
import os
import sys
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")      # many small SVDs: threads slow them
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from pkmcal.calibration import (  # noqa: E402
    calibrate_constraint_link,
    calibrate_full_pose,
    calibrate_probe,
)
from pkmcal.errors import InputError  # noqa: E402
from pkmcal.estimation.rank import RTOL, numerical_rank  # noqa: E402
from pkmcal.identifiability import CONSTRAINT_LINK_GAUGES, align_gauge  # noqa: E402
from pkmcal.instruments import (  # noqa: E402
    DistancesModel,
    InstrumentData,
    InstrumentProblem,
    IsotropicNoise,
    JointProblem,
    ProbeModel,
    fit_instrument,
    fit_joint,
)
from pkmcal.instruments.constraint_link import ConstraintLinkData
from pkmcal.instruments.pose import FullPoseNoise
from pkmcal.instruments.simulate import probe_trigger  # noqa: E402
from pkmcal.instruments.tracker import TrackerNoise
from pkmcal.kinematics import rotvec_from_matrix, skew  # noqa: E402

HERE = Path(__file__).resolve().parent


def _load(stem: str, name: str):
    """A sibling benchmark script as a module (once per process: the tests load them too)."""
    path = HERE / f"{stem}.py"
    module = sys.modules.get(name)
    if module is not None and Path(getattr(module, "__file__", "")).resolve() == path:
        return module
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module                      # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


instruments = _load("instruments", "instruments_bench")
printer = _load("printer", "printer_bench")

#: what the calibrations assume: the library's defaults for each instrument
ASSUMED = {
    "points": TrackerNoise(),
    "distances": IsotropicNoise(instruments.BALLBAR_SIGMA),
    "poses": instruments.POSE_NOISE,
    "constraint-link": instruments.LINK_SIGMA,
    "probe": printer.PROBE_SIGMA,
    "probe+ballbar": (printer.PROBE_SIGMA, printer.BALLBAR_SIGMA),
}
assert instruments.POSE_NOISE == FullPoseNoise()
#: ballbar lengths of the joint case (the printer's 30 leave the ballbar's level a redundancy
#: of about 9 in the joint fit, below MIN_REDUNDANCY: it would be bounded, not estimated)
JOINT_BALLBAR = 60
#: held-out poses of the pose and constraint-link cases' check of the reported covariance
HELD_POSES = 20
#: runs per case whose reported covariance is checked (z2; the check costs more than a fit)
Z2_RUNS = 50


@dataclass(frozen=True)
class Mismatch:
    """One case: a machine x instrument and the noise its data really have.

    Attributes
    ----------
    machine, instrument : str
        A key of ``instruments.COMBINATIONS``, or ``("printer", "probe")``.
    key : str
        Short name of the noise (``--only machine-instrument:key``).
    words : str
        The true noise against the assumed one, in words.
    true : object
        The true noise: a noise model (points, distances, poses) or a standard deviation, m.
    """

    machine: str
    instrument: str
    key: str
    words: str
    true: object = field(compare=False)

    @property
    def name(self) -> str:
        return f"{self.machine}-{self.instrument}:{self.key}"


def mismatches() -> list[Mismatch]:
    """Every case, in table order."""
    d = TrackerNoise()
    out = []
    for machine, inst in instruments.COMBINATIONS:
        if inst == "points":
            out += [Mismatch(machine, inst, "isotropic", "isotropic 7 um (Leica-type assumed)",
                             IsotropicNoise(7e-6)),
                    Mismatch(machine, inst, "3x", "3 x the assumed (15 um along, 22.5 um + "
                             "9 um/m across)", TrackerNoise(3 * d.distance, 3 * d.transverse,
                                                            3 * d.transverse_per_m))]
        elif inst == "distances":
            out.append(Mismatch(machine, inst, "3x", "3 um (1 um assumed)",
                                IsotropicNoise(3 * instruments.BALLBAR_SIGMA)))
        elif inst == "poses":
            p = instruments.POSE_NOISE
            out += [Mismatch(machine, inst, "pos5x-ori0.3x", "positions 100 um, orientations "
                             "15 urad (20 um, 50 urad assumed)",
                             FullPoseNoise(p.reading_m, 5 * p.position_m,
                                           0.3 * p.orientation_rad)),
                    Mismatch(machine, inst, "readings10x", "leg readings 20 um (2 um assumed)",
                             FullPoseNoise(10 * p.reading_m, p.position_m, p.orientation_rad))]
        else:
            out.append(Mismatch(machine, inst, "readings10x", "encoder readings 20 um (2 um "
                                "assumed)", 10 * instruments.LINK_SIGMA))
    out.append(Mismatch("printer", "probe", "3x", "trigger noise 30 um (10 um assumed)",
                        3 * printer.PROBE_SIGMA))
    out.append(Mismatch("printer", "probe+ballbar", "probe3x", "a joint fit of two files: "
                        "probe 30 um (10 um assumed), 60 ballbar lengths 1 um as assumed",
                        (3 * printer.PROBE_SIGMA, printer.BALLBAR_SIGMA)))
    return out


def case_names() -> list[str]:
    return [m.name for m in mismatches()]


# -- one case --------------------------------------------------------------------------------


class NoiseCase:
    """A case of ``instruments.py`` (or the printer's probe cases) with data of another noise.

    Parameters
    ----------
    mismatch : Mismatch
        The case.
    seed : int, optional
        Seed of the machine's deviations, the poses and the held-out readings (as in
        ``instruments.py``).
    poses : int, optional
        Poses per run (ballbar lengths for ``probe+ballbar``) instead of the case's own
        number (the tests use smaller problems).
    """

    def __init__(self, mismatch: Mismatch, seed: int = 0, poses: int | None = None):
        self.mismatch = mismatch
        self.name = mismatch.name
        self.instrument = mismatch.instrument
        self.true_noise = mismatch.true
        if self.instrument in ("probe", "probe+ballbar"):
            self.case = printer.ProbeCase("full", sigma=ASSUMED["probe"], seed=seed)
            self.n_poses = len(self.case.P)
            self._held_pinv = np.linalg.pinv(self.case.J_held, rcond=1e-10)
            if self.instrument == "probe+ballbar":
                self.joint = printer.JointCase(self.case, n=poses or JOINT_BALLBAR,
                                               sigma=printer.BALLBAR_SIGMA)
                self.n_poses += len(self.joint.bar)
                self._joint_J = printer.whitened_jacobian(self.joint.problem)
                self._joint_pinv = np.linalg.pinv(self._joint_J, rcond=1e-10)
        else:
            self.case = _sized_case(mismatch.machine, self.instrument, seed, poses)
            self.n_poses = self.case.n_poses
        self.true_levels = self._true_levels()

    # -- the truth ----------------------------------------------------------------------------
    def _true_levels(self) -> dict:
        """The true standard deviation of each noise group the calibration estimates, SI."""
        t = self.true_noise
        if self.instrument == "points":
            if isinstance(t, IsotropicNoise):
                return {"along": t.sigma, "across": t.sigma}
            # the across group's level is the RMS over the points (TrackerNoise.groups)
            _, _, _, levels, _ = t.groups(self.case.exact.values)
            return {"along": float(levels[0]), "across": float(levels[1])}
        if self.instrument == "distances":
            return {"distances": t.sigma}
        if self.instrument == "poses":
            return {"reading": t.reading_m, "position": t.position_m,
                    "orientation": t.orientation_rad}
        if self.instrument == "constraint-link":
            return {"reading": float(t)}
        if self.instrument == "probe+ballbar":
            return {"probe.csv:probe": float(t[0]), "bar.csv:distances": float(t[1])}
        return {"probe": float(t)}

    def simulate(self, rng):
        """Data of the experiment with the TRUE noise (``probe+ballbar``: both files)."""
        c, t = self.case, self.true_noise
        if self.instrument in ("points", "distances", "poses"):
            return c.simulate(t, rng)
        if self.instrument == "constraint-link":
            q = c.q_true + float(t) * rng.standard_normal(c.q_true.shape)
            return ConstraintLinkData(q, c.true.constraint_link_length, c.passive)
        probe_sigma = float(t[0] if self.instrument == "probe+ballbar" else t)
        eps = probe_sigma * rng.standard_normal(len(c.P))
        q, _ = probe_trigger(c.true, c.nominal, c.P, c.R, c.bed, eps)
        probe = InstrumentData("probe", q, np.zeros((len(q), 1)), source="probe.csv")
        if self.instrument == "probe":
            return probe
        bar = self.joint.bar
        return probe, InstrumentData("distance", bar.q, bar.values + float(t[1])
                                     * rng.standard_normal(bar.values.shape), bar.group,
                                     source="bar.csv")

    def fit(self, data, estimate_noise=True, start: str = "nominal", noise=None, **options):
        """Calibrate with the ASSUMED noise (the library's defaults for the instrument).

        Parameters
        ----------
        data : object
            :meth:`simulate`'s.
        estimate_noise : bool or collection of str, optional
            Passed on (True: the default options).
        start : {"nominal", "truth"}, optional
            The start geometry: the nominal machine (the benchmark), or the true one (the
            estimate then differs from the truth in the identifiable directions only, to first
            order: its covariance is expressed in the truth's gauge).
        noise : object, optional
            The noise to assume instead of the library's default (as the instrument's
            ``noise`` argument; ``probe+ballbar``: a pair of standard deviations, m).
        **options
            Passed on (``robust``, ...).
        """
        c = self.case
        assumed = ASSUMED[self.instrument] if noise is None else noise
        machine = {"nominal": c.nominal, "truth": c.true}[start]
        kw = dict(estimate_noise=estimate_noise, **options)
        if self.instrument in ("points", "distances"):
            return fit_instrument(machine, data, c.model, assumed, **kw)
        if self.instrument == "poses":
            return calibrate_full_pose(machine, data, method="ml", noise=assumed, **kw)
        if self.instrument == "constraint-link":
            return calibrate_constraint_link(machine, data, method="ml", sigma_m=assumed, **kw)
        if self.instrument == "probe":
            return calibrate_probe(machine, data, IsotropicNoise(float(assumed)), **kw)
        probe, bar = data
        return fit_joint(machine, [(probe, ProbeModel(), IsotropicNoise(float(assumed[0]))),
                                   (bar, DistancesModel(self.joint.k),
                                    IsotropicNoise(float(assumed[1])))], **kw)

    # -- the bound of the true noise ----------------------------------------------------------
    def bound(self):
        """Cramér-Rao bound at the truth with the TRUE noise (scaled, free coordinates), as
        ``instruments.Bound``."""
        c, t = self.case, self.true_noise
        if self.instrument in ("points", "distances"):
            problem = InstrumentProblem(c.true, c.exact, c.model.with_start(c.truth), t)
            r, J, _ = problem.evaluate(problem.initial_state())
            assert np.abs(r).max() < 1e-6                      # the truth fits exact data
            free = problem.parameters.free
            Js = (J[..., free] * problem.scales[free]).reshape(-1, int(free.sum()))
            return _bound_of(Js)
        if self.instrument == "probe":
            return _bound_of(c.J * (ASSUMED["probe"] / float(t)))
        if self.instrument == "probe+ballbar":
            parts = self.joint.problem.parts
            true = JointProblem(c.true, [(p.data, p.model, IsotropicNoise(float(s)))
                                         for p, s in zip(parts, t, strict=True)],
                                self.joint.problem.labels)
            return _bound_of(printer.whitened_jacobian(true))
        if self.instrument == "poses":
            crb = calibrate_full_pose(c.true, c.simulate(None), method="ml", noise=t,
                                      frames=instruments.FRAMES, absolute_sigma=True)
            n = len(crb.scales)
        else:
            crb = calibrate_constraint_link(c.true, c.simulate(None), sigma_m=float(t),
                                            absolute_sigma=True)
            n = len(c.nominal.parameters)
        free = crb.parameters.free[:n]
        sc = crb.scales[:n]
        C = (crb.covariance[:n, :n] / np.outer(sc, sc))[np.ix_(free, free)]
        return instruments.Bound(C, crb.null_space[:n][free], int(crb.rank), int(free.sum()))

    def error(self, result, bound) -> np.ndarray:
        """Scaled error of an estimate in the identifiable directions (gauge-free)."""
        if self.instrument == "probe":
            return self._held_pinv @ (self.case.held_heights(result) / self.case.sigma)
        if self.instrument == "probe+ballbar":
            # the exact data's residuals at the estimate, mapped back through the truth's
            # Jacobian: r(estimate) = J e to first order, e in the row space of J
            r, _, _ = self.joint.problem.evaluate(copy.deepcopy(result.state), False)
            return self._joint_pinv @ r.ravel()
        return self.case.error(result, bound)

    # -- the reported uncertainty -------------------------------------------------------------
    def whitened_error(self, result) -> tuple[float, int]:
        """How the error compares with the covariance the calibration REPORTS, gauge-free.

        Predictions ``h`` of held-out measurements (held-out readings of the instrument's
        case; the joint fit: its own readings; poses and the constraint link: the platform
        poses the forward kinematics give at held-out readings, through the estimated
        measurement frames) by the estimate and by the truth; ``J`` their Jacobian AT THE
        ESTIMATE, where the reported covariance ``C`` is defined. With ``d = h(estimate) -
        h(truth)`` and ``S = J C J^T`` (rank ``r``, the adjusted directions):
        ``t = d^T S^+ d / r``, about chi-square(r) / r - or F(r, redundancy) with levels
        estimated - when ``C`` is the estimate's covariance. Predictions do not see the
        unidentifiable directions: the estimate's gauge is its own (the constraint link's
        truth is first moved along its two frame rotations to the estimate's).

        Returns
        -------
        t : float
            ``d^T S^+ d / r``.
        r : int
            The adjusted directions.
        """
        r_adj = int(result.rank) - int(result.weak)
        C = np.asarray(result.covariance, float)
        if self.instrument in ("points", "distances", "probe"):
            problem = (self.case.held_problem if self.instrument == "probe"
                       else self.case._held_problem)
            state = problem.initial_state()             # the truth's poses: FK starts
            state.u = np.array(result.state.u, float)
            state.nuisance = copy.deepcopy(result.state.nuisance)
            d, J = _residuals_and_jacobian(problem, state)
            free = np.asarray(result.parameters.free, bool)
            return _statistic(-d, J[:, free], C[np.ix_(free, free)], r_adj), r_adj
        if self.instrument == "probe+ballbar":
            d, J = _residuals_and_jacobian(self.joint.problem, copy.deepcopy(result.state))
            free = np.asarray(result.parameters.free, bool)
            return _statistic(-d, J[:, free], C[np.ix_(free, free)], r_adj), r_adj
        if self.instrument == "poses":
            return self._pose_statistic(result, C, r_adj), r_adj
        return self._link_statistic(result, C, r_adj), r_adj

    def _held_readings(self):
        if not hasattr(self, "_q_held"):
            c = self.case
            if self.instrument == "poses":
                P, R = c.held_out[0][:HELD_POSES], c.held_out[1][:HELD_POSES]
            else:
                from pkmcal.instruments.simulate import sample_workspace_poses

                P, R = sample_workspace_poses(c.nominal, HELD_POSES, np.random.default_rng(99))
            self._q_held = c.nominal.ik(P, R)
        return self._q_held

    def _pose_statistic(self, result, C, r_adj, jacobian=None):
        """Marker poses at held-out readings through the estimated frames (positions over the
        assumed position noise, rotations from the estimate's over the orientation noise); the
        Jacobian in the estimator's coordinates (legs, then increments on the left of the frame
        rotations and the frame translations) at the estimate."""
        c = self.case
        q = self._held_readings()
        n = len(c.nominal.parameters)
        u = np.array(result.x[:n], float)
        frames = result.sections["pose"].frames
        (A, _), (B, b) = frames.mocap_from_base, frames.platform_from_marker
        noise = ASSUMED["poses"]
        w = np.array([noise.position_m] * 3 + [noise.orientation_rad] * 3)
        fk = c.nominal.with_parameters(u).fk(q)
        assert fk.converged.all()
        Pm, Rm = frames.measured(fk.P, fk.R)
        true = c.true.fk(q)
        assert true.converged.all()
        Pt, Rt = instruments.FRAMES.measured(true.P, true.R)
        d = (np.concatenate([Pm - Pt, rotvec_from_matrix(Rm @ np.swapaxes(Rt, -1, -2))], -1)
             / w).ravel()
        J = self._pose_jacobian(u, fk.P, fk.R, A, B, b) if jacobian is None else jacobian
        J = (J / np.tile(w, len(q))[:, None])
        free = np.asarray(result.parameters.free, bool)
        return _statistic(d, J[:, free], C[np.ix_(free, free)], r_adj)

    def _pose_jacobian(self, u, P, R, A, B, b) -> np.ndarray:
        """d(marker position, marker rotation increment) / d(legs, frame increments), one row
        per component (K * 6), unscaled. From the inverse kinematics' Jacobians:
        ``d(P, Omega) / du = -(dq/dpose)^-1 dq/du`` (``Omega`` on the left); ``Pm = A (P + R b)
        + a``, ``Rm = A R B``."""
        _, Jx, Ju = self.case.nominal.ik_jacobians(P, R, u)
        dx = -np.linalg.solve(Jx, Ju)                              # (K, 6, n)
        K, n = len(P), Ju.shape[-1]
        Rb = np.einsum("kij,j->ki", R, b)
        J = np.zeros((K, 6, n + 12))
        # legs: dPm = A (dP - [R b]x dOmega), rotation increment A dOmega
        J[:, :3, :n] = np.einsum("ij,kjn->kin", A, dx[:, :3] - np.einsum(
            "kij,kjn->kin", skew(Rb), dx[:, 3:]))
        J[:, 3:, :n] = np.einsum("ij,kjn->kin", A, dx[:, 3:])
        # mocap frame: rotation on the left of A, then its translation
        J[:, :3, n:n + 3] = -skew(np.einsum("ij,kj->ki", A, P + Rb))
        J[:, 3:, n:n + 3] = np.eye(3)
        J[:, :3, n + 3:n + 6] = np.eye(3)
        # marker frame: rotation on the left of B (Rm's increment A R eps), its translation
        J[:, 3:, n + 6:n + 9] = np.einsum("ij,kjl->kil", A, R)
        J[:, :3, n + 9:n + 12] = np.einsum("ij,kjl->kil", A, R)
        return J.reshape(K * 6, n + 12)

    def _link_statistic(self, result, C, r_adj):
        """Platform poses at held-out readings (positions over the characteristic length,
        rotations from the estimate's); the truth moved along the two frame rotations to the
        estimate's gauge; the Jacobian ``d(P, Omega) / du = -(dq/dpose)^-1 dq/du``."""
        c = self.case
        q = self._held_readings()
        n = len(c.nominal.parameters)
        scales = np.asarray(result.scales, float)[:n]
        u = np.array(result.x[:n], float)
        u_true, _ = align_gauge(c.nominal, c.true.u, u, CONSTRAINT_LINK_GAUGES, scales)
        L = c.nominal.characteristic_length()
        fk, true = c.nominal.with_parameters(u).fk(q), c.nominal.with_parameters(u_true).fk(q)
        assert fk.converged.all() and true.converged.all()
        d = np.concatenate([(fk.P - true.P) / L, rotvec_from_matrix(
            fk.R @ np.swapaxes(true.R, -1, -2))], -1).ravel()
        _, Jx, Ju = c.nominal.ik_jacobians(fk.P, fk.R, u)
        dx = -np.linalg.solve(Jx, Ju)
        dx[:, :3] /= L
        J = dx.reshape(len(q) * 6, n)
        free = np.asarray(result.parameters.free, bool)[:n]
        return _statistic(d, J[:, free], C[:n, :n][np.ix_(free, free)], r_adj)


def _residuals_and_jacobian(problem, state):
    """A problem's whitened residuals and Jacobian, one row per residual component."""
    r, J, _ = problem.evaluate(state)
    return r.ravel(), J.reshape(r.size, -1)


def _statistic(d, J, C, r: int) -> float:
    """``d^T S^+ d / r`` with ``S = J C J^T`` restricted to its ``r`` largest eigenvalues."""
    S = J @ C @ J.T
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    top = np.argsort(w)[::-1][:r]
    z = V[:, top].T @ d
    return float(np.sum(z**2 / w[top])) / r


def _sized_case(machine: str, instrument: str, seed: int, poses: int | None):
    """``instruments.Case`` with ``poses`` poses instead of its combination's number (its
    table entry swapped for the construction and put back)."""
    if poses is None:
        return instruments.Case(machine, instrument, seed)
    key = (machine, instrument)
    saved = instruments.COMBINATIONS[key]
    instruments.COMBINATIONS[key] = {**saved, "poses": int(poses)}
    try:
        return instruments.Case(machine, instrument, seed)
    finally:
        instruments.COMBINATIONS[key] = saved


def _bound_of(Js: np.ndarray):
    """``instruments.Bound`` of a whitened, scaled Jacobian."""
    _, s, Vt = np.linalg.svd(Js, full_matrices=True)
    rank = numerical_rank(s, RTOL)
    C = (Vt[:rank].T / s[:rank] ** 2) @ Vt[:rank]
    return instruments.Bound(C, Vt[rank:].T, rank, Js.shape[1])


def ratio_and_se(errors: np.ndarray, C: np.ndarray) -> tuple[float, float]:
    """``sqrt(mean |e|^2 / trace C)`` and its Monte-Carlo standard error (delta method)."""
    s = np.sum(np.asarray(errors) ** 2, axis=1)
    ratio = float(np.sqrt(s.mean() / np.trace(C)))
    se = ratio * float(s.std(ddof=1)) / (2.0 * np.sqrt(len(s)) * float(s.mean()))
    return ratio, se


def run(mismatch: Mismatch | str, runs: int = 200, seed: int = 0) -> dict:
    """``runs`` calibrations of one case with the default options and with the levels held.

    Returns
    -------
    dict
        ``case``, ``noise`` (words), ``rank``, ``free``, ``poses``, ``runs``; per estimator
        (``default``, ``fixed``): ``ratio`` (RMS / CRB of the true noise), ``se``,
        ``median_s``, ``success`` (all converged at the bound's rank), ``flagged`` (mean rows
        the outlier test names); ``time_ratio`` (default / fixed median seconds); ``levels``
        per group: ``true``, ``assumed`` (SI), ``est_over_true`` (mean), ``sd_over_true``
        (spread over the runs), ``reported_std_over_true`` (mean reported std),
        ``estimated`` (fraction of runs with the status "estimated"); ``seconds`` (the case's
        wall time); ``ok``.
    """
    if isinstance(mismatch, str):
        mismatch = {m.name: m for m in mismatches()}[mismatch]
    t_case = time.perf_counter()
    case = NoiseCase(mismatch, seed)
    bound = case.bound()
    rng = np.random.default_rng([seed, zlib.crc32(mismatch.name.encode())])
    out = {k: {"errors": [], "seconds": [], "success": [], "flagged": [], "refused": [],
               "z2": [], "other_rank": []} for k in ("default", "fixed")}
    levels = {}
    for run_index in range(runs):
        data = case.simulate(rng)
        for key, estimate in (("default", True), ("fixed", False)):
            t0 = time.perf_counter()
            try:
                res = case.fit(data, estimate)
            except InputError as exc:        # a refusal counts as a failed calibration
                out[key]["seconds"].append(time.perf_counter() - t0)
                out[key]["refused"].append(str(exc))
                continue
            out[key]["seconds"].append(time.perf_counter() - t0)
            e = case.error(res, bound)
            out[key]["errors"].append(e)
            if run_index < Z2_RUNS:
                out[key]["z2"].append(case.whitened_error(res)[0])
            out[key]["success"].append(bool(res.success))
            # adjusted = rank less weak directions (the printer's full model has one; a
            # direction whose standard deviation at the noise used exceeds MAX_STD is weak)
            out[key]["other_rank"].append(int(res.rank) - int(res.weak) != bound.rank)
            test = res.outliers
            out[key]["flagged"].append(0 if test is None else len(test.flagged))
            if estimate:
                noise = res.noise
                for i, k in enumerate(noise.keys):
                    rec = levels.setdefault(k, {"sigma": [], "std": [], "status": [],
                                                "assumed": float(noise.assumed[i])})
                    rec["sigma"].append(float(noise.sigma[i]))
                    rec["std"].append(float(noise.std[i]))
                    rec["status"].append(noise.status[i])
    row = {"case": mismatch.name, "noise": mismatch.words, "rank": bound.rank,
           "free": bound.n_free, "poses": case.n_poses, "runs": runs, "k_eff": bound.k_eff}
    for key, rec in out.items():
        ratio, se = ratio_and_se(np.array(rec["errors"]), bound.C)
        row[key] = {"ratio": ratio, "se": se, "median_s": float(np.median(rec["seconds"])),
                    "success": bool(all(rec["success"]) and not rec["refused"]),
                    "other_rank": int(np.sum(rec["other_rank"])),
                    "refused": len(rec["refused"]),
                    "first_refusal": rec["refused"][0] if rec["refused"] else None,
                    "flagged": float(np.mean(rec["flagged"])),
                    "z2": float(np.mean(rec["z2"])), "z2_runs": len(rec["z2"])}
    row["time_ratio"] = row["default"]["median_s"] / row["fixed"]["median_s"]
    row["levels"] = {}
    for k, rec in levels.items():
        true = case.true_levels[k]
        sigma = np.array(rec["sigma"])
        std = np.array(rec["std"])
        row["levels"][k] = {
            "true": true, "assumed": rec["assumed"],
            "est_over_true": float(np.mean(sigma) / true),
            "sd_over_true": float(np.std(sigma, ddof=1) / true) if runs > 1 else None,
            "reported_std_over_true": (float(np.nanmean(std) / true)
                                       if np.isfinite(std).any() else None),
            "estimated": float(np.mean([s == "estimated" for s in rec["status"]]))}
    d = row["default"]
    row["ok"] = bool(d["success"] and d["ratio"] - 2 * d["se"] <= 1.05)  # converged, target
    row["seconds"] = time.perf_counter() - t_case
    return row


# -- the table -------------------------------------------------------------------------------

HEADER = (f"{'case':<38} {'rank':>4} {'runs':>4}  {'default RMS/CRB':>15}  "
          f"{'fixed RMS/CRB':>15}  {'z2 def':>6} {'z2 fix':>6}  {'t def/fix':>9}  {'ok':<3} "
          "est/true (default)")


def line(row: dict) -> str:
    d, f = row["default"], row["fixed"]
    levels = ", ".join(f"{k} {v['est_over_true']:.2f}" for k, v in row["levels"].items())
    refused = "".join(f"; {key} refused {row[key]['refused']} of {row['runs']}"
                      for key in ("default", "fixed") if row[key]["refused"])
    refused += "".join(f"; {key}: {row[key]['other_rank']} runs adjusted another number of "
                       "directions" for key in ("default", "fixed") if row[key]["other_rank"])
    return (f"{row['case']:<38} {row['rank']:>4} {row['runs']:>4}  "
            f"{d['ratio']:>7.3f} +- {d['se']:.3f}  {f['ratio']:>7.3f} +- {f['se']:.3f}  "
            f"{d['z2']:>6.2f} {f['z2']:>6.2f}  {row['time_ratio']:>8.2f}x  "
            f"{'yes' if row['ok'] else 'NO':<3} {levels}{refused}")


def _run_named(args):
    name, runs, seed = args
    return run(name, runs, seed)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=None,
                        help="noisy data sets per case (default 200; 40 with --quick)")
    parser.add_argument("--quick", action="store_true", help="40 runs per case")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", action="append", choices=case_names(), metavar="CASE",
                        help="run only this case (repeatable): " + ", ".join(case_names()))
    parser.add_argument("--jobs", type=int, default=1,
                        help="cases in parallel processes (default 1)")
    parser.add_argument("--json", help="write the figures to this file")
    args = parser.parse_args(argv)
    runs = args.runs if args.runs is not None else (40 if args.quick else 200)
    names = [n for n in case_names() if not args.only or n in args.only]
    t0 = time.perf_counter()
    print(HEADER)
    print("-" * len(HEADER), flush=True)
    jobs = [(n, runs, args.seed) for n in names]
    rows = []
    if args.jobs > 1:
        import multiprocessing

        with multiprocessing.get_context("fork").Pool(args.jobs) as pool:
            for row in pool.imap(_run_named, jobs):
                print(line(row), flush=True)
                rows.append(row)
    else:
        for job in jobs:
            row = _run_named(job)
            print(line(row), flush=True)
            rows.append(row)
    wall = time.perf_counter() - t0
    print(f"\n{len(rows)} cases, {runs} runs each, {wall:.0f} s wall ({args.jobs} "
          f"process{'es' if args.jobs > 1 else ''}).")
    print("RMS/CRB: RMS error in the identifiable directions over the Cramér-Rao bound of the "
          "TRUE noise,\n  +- its Monte-Carlo standard error; default: levels estimated; fixed: "
          "levels held at the\n  assumed ones.\n"
          "z2: mean whitened squared prediction error with the REPORTED covariance (1: honest "
          f"uncertainty;\n  first {min(runs, Z2_RUNS)} runs).\n"
          "t def/fix: median seconds per calibration, default over fixed, same runs.\n"
          "ok: default ratio - 2 se <= 1.05, all default calibrations converged, none refused.")
    for row in rows:
        print(f"  {row['case']:<38} {row['noise']}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"runs": runs, "seed": args.seed, "wall_s": wall, "results": rows}, fh,
                      indent=1)
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
