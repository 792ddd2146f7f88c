"""Starting a calibration far from the machine: continuation, pose multi-starts, rows left out.

The maximum-likelihood problems start every per-measurement pose from the forward kinematics
of its readings with the machine file's geometry. With build errors of the size of seed 000's
Table 1 (2-4 mm, up to 4 deg) on a geometry other than the default one, that start can be tens
of millimetres off for some rows, and Levenberg-Marquardt then stops in a local minimum: a
wrong geometry whose residuals are many times the noise. Two things go wrong:

- *Wrong pose branches.* The least-squares forward kinematics of a row (all readings and the
  link) has more than one local minimum near the edge of the workspace; Newton from the home
  pose may land in one that is not the pose the readings came from, even with the true
  geometry. :func:`sphere_pose_candidates` therefore starts each row from several poses (the
  home pose, and the square five-readings-plus-link solutions for every choice of the left-out
  reading) and keeps the pose that explains its readings best. With the calibrated geometry,
  the rows still left out also start from the poses of the fitted rows with the nearest
  readings (:func:`neighbour_poses`: near the edge of the workspace the pose the readings came
  from can have a narrow basin that no start from home reaches); the outlier rounds then
  bring back those it explains.
- *Ill-conditioned rows.* A row whose pose moves far for a small geometry error is a strongly
  non-linear residual, and a few of them bend the first Gauss-Newton steps into a wrong
  valley. :func:`continuation_solve` first fits the geometry to the rows whose start poses
  are the least sensitive to the geometry (:func:`start_sensitivity`), re-starts every row's
  pose with that geometry, then fits all rows; when the chi-square test of the residuals
  (:func:`~pkmcal.estimation.acceptance.residual_test`) still fails, it fits again without the
  rows with the largest residuals, re-starts those, and refits all (a few rounds), keeping the
  best solution found.

Rows whose readings no pose on the sphere explains with the start geometry are not fitted in
the first pass but retried with the improved geometry; those still unexplained at the end are
left out and named (``dropped_rows`` and a warning in the result's
:class:`ConstraintLinkSection`).

The plain fit runs first and is returned when its residuals pass the test, so a calibration
that starts close (the default machine) costs what it did.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...errors import InputError
from ...estimation.acceptance import (
    MAX_NOISE_FACTOR,
    residual_test,
)
from ...estimation.distributions import chi2_ppf
from ...paths import path_text
from .problems import SphereState, solve_sphere_poses

__all__ = ["StartReport", "continuation_solve", "neighbour_poses", "sphere_pose_candidates",
           "start_sensitivity"]

#: a row's start pose must explain its readings to within this share of the machine's
#: characteristic length (RMS over the readings): plausible geometric errors stay below it
START_TOL = 0.05
#: share of the rows (the least sensitive) fitted first by the continuation
SUBSET_SHARE = 0.5
#: share of the rows kept (the smallest residuals) in a trimmed round
TRIM_KEEP = 0.5
#: trimmed rounds after the continuation when the residual test still fails
TRIM_ROUNDS = 6
#: rows left out above this share of the data make the calibration an error
MAX_LEFT_OUT = 0.25
#: when re-starting the poses with a fitted geometry, a row whose residual norm (in units of
#: the reading noise) exceeds this factor times the median row's, and this floor, is not fitted
OUTLIER_FACTOR = 8.0
OUTLIER_FLOOR = 8.0
#: a left-out row starts again from the poses of this many fitted rows with the nearest
#: readings (8 miss a row of tests/test_global_start.py's six-leg seed 12; 16 find it)
NEIGHBOURS = 16


@dataclass
class StartReport:
    """What the start strategy did (:attr:`ConstraintLinkSection.start` of a calibration
    result).

    Attributes
    ----------
    strategy : str
        ``"direct"`` (the plain fit passed the residual test), ``"continuation"`` (the
        fallback found a solution that passes), or ``"best effort"`` (nothing passed: the
        solution with the smallest residuals is returned and the residual test flags it).
    attempts : list of dict
        Every fit tried: ``stage``, ``rows`` fitted, ``noise_factor`` (residual RMS / assumed
        noise) and ``passed``.
    retried_rows : ndarray of int
        File rows whose start pose could not be found with the machine file's geometry and
        were fitted after a first fit of the other rows.
    dropped_rows : ndarray of int
        File rows left out of the result: no pose on the constraint sphere explains their
        readings even with the calibrated geometry.
    warnings : list of str
        Sentences for the user (rows left out and why).
    kept : ndarray of bool, shape (K,), optional
        The rows in the returned fit (None before the strategy has run).
    readmitted_rows : ndarray of int
        File rows the strategy left out that the outlier test brought back (:meth:`readmit`).
    left_out_poses : tuple of ndarray, optional
        ``(P (k, 3), R (k, 3, 3))``: the best pose on the constraint sphere of each row left out,
        with the returned fit's geometry (where the outlier rounds start them).
    """

    strategy: str = "direct"
    attempts: list = field(default_factory=list)
    retried_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    dropped_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    warnings: list = field(default_factory=list)
    kept: np.ndarray | None = None
    readmitted_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    left_out_poses: tuple | None = None

    def readmit(self, still_out, file_rows) -> None:
        """Only the left-out rows in ``still_out`` stay out: the outlier test found the others
        consistent with the noise once the geometry was calibrated (rows the start strategy
        left out are its first candidates, not its verdict).

        Parameters
        ----------
        still_out : array_like of bool, shape (K,)
            Rows left out of the final fit (over all the data's rows).
        file_rows : array_like of int, shape (K,)
            The data's file rows.
        """
        if self.kept is None:
            return
        out = ~self.kept & np.asarray(still_out, bool)
        back = ~self.kept & ~out
        if not back.any():
            return
        old = _left_out_text(self.dropped_rows, len(self.kept))
        self.warnings = [w for w in self.warnings if w != old]
        self.kept = ~out
        self.readmitted_rows = np.asarray(file_rows)[back]
        self.dropped_rows = np.asarray(file_rows)[out]
        if self.dropped_rows.size:
            self.warnings.insert(0, _left_out_text(self.dropped_rows, len(self.kept)))

    @property
    def fallback(self) -> bool:
        """Whether the plain fit was not enough (continuation or rows retried)."""
        return self.strategy != "direct" or self.retried_rows.size > 0

    def as_dict(self) -> dict:
        """The report as JSON-ready values.

        Returns
        -------
        dict
            ``strategy``, ``fallback``, ``attempts``, ``retried_rows``, ``dropped_rows``,
            ``readmitted_rows``, ``warnings``.
        """
        return {"strategy": self.strategy, "fallback": self.fallback,
                "attempts": list(self.attempts),
                "retried_rows": [int(v) for v in self.retried_rows],
                "dropped_rows": [int(v) for v in self.dropped_rows],
                "readmitted_rows": [int(v) for v in self.readmitted_rows],
                "warnings": list(self.warnings)}


def _rows_text(rows) -> str:
    rows = [int(v) for v in rows]
    return ", ".join(map(str, rows[:20])) + (f" and {len(rows) - 20} more" if len(rows) > 20
                                             else "")


def _reading_rms(machine, um, q, P, R, Lc):
    """RMS reading residual of each row at poses projected onto the sphere, m (inf where a
    reading cannot be reached)."""
    norm = np.linalg.norm(P, axis=-1)
    P = P * (Lc / np.where(norm > 0, norm, 1.0))[:, None]
    with np.errstate(invalid="ignore", over="ignore"):
        qc = machine.ik(P, R, um)
        rms = np.sqrt(np.mean((qc - q) ** 2, axis=-1))
    return np.where(np.isfinite(rms), rms, np.inf), P


def neighbour_poses(machine, um, q, link_length, P, R, rms, neighbours):
    """Rows started again from the poses of explained rows with the nearest readings.

    Near the edge of the workspace the least-squares forward kinematics of a row has a wide
    basin around a wrong pose (tens of millimetres off, its residual hundreds of times the
    noise) and a narrow one around the pose the readings came from: home and the square
    systems land in the wide one, even with the true geometry. A row whose readings are close
    to another's has its pose close too, so the poses of the rows with the nearest readings
    that are explained start near it: Newton on the square systems (five readings and the
    link) from there stays on that assembly mode, and least squares on all readings polishes
    the pose. Each row keeps the best pose found.

    Parameters
    ----------
    machine : Machine
        The machine (with a constraint link).
    um : array_like or None
        Its parameter vector (internal units); None for the machine's own.
    q : ndarray, shape (K, n_joints)
        Joint readings of the rows to pose again, m.
    link_length : float
        Constraint-link length ``Lc``, m.
    P, R, rms : ndarray
        The rows' poses so far and their RMS reading residuals, m (inf: no pose).
    neighbours : tuple of ndarray
        ``(q (k, n_joints), P (k, 3), R (k, 3, 3))`` of explained rows (e.g. the rows of a
        fit); each row starts from the :data:`NEIGHBOURS` nearest.

    Returns
    -------
    P, R, rms : ndarray
        The poses, improved where a neighbour's start explains the readings better.
    """
    from scipy.spatial import cKDTree


    P, R, rms = np.array(P, float), np.array(R, float), np.array(rms, float)
    q_ref, P_ref, R_ref = (np.asarray(a, float) for a in neighbours)
    K = len(q)
    if not K or not len(q_ref):
        return P, R, rms
    k = min(NEIGHBOURS, len(q_ref))
    spread = np.std(np.concatenate([q_ref, q]), axis=0)
    spread = np.where(spread > 0, spread, 1.0)
    _, nn = cKDTree(q_ref / spread).query(q / spread, k=k)
    nn = np.reshape(nn, (-1, k)).ravel()                      # (K x k,): row j, neighbour c
    n = q.shape[1]
    # from each neighbour's pose: the square systems (five readings and the link, for every
    # reading left out: Newton stays on the neighbour's assembly mode, where least squares
    # on all readings slides into the wide basin), then least squares on all readings; and
    # least squares directly
    qk = np.repeat(q, k, axis=0)
    with np.errstate(invalid="ignore", over="ignore"):
        sq = solve_sphere_poses(machine, um, np.tile(qk, (n, 1)), link_length,
                                np.repeat(np.arange(n), len(qk)),
                                start=(np.tile(P_ref[nn], (n, 1)),
                                       np.tile(R_ref[nn], (n, 1, 1))), max_iter=40)
        q_all = np.tile(qk, (n + 1, 1))
        fk = solve_sphere_poses(machine, um, q_all, link_length, None,
                                start=(np.concatenate([P_ref[nn], sq.P]),
                                       np.concatenate([R_ref[nn], sq.R])), max_iter=40)
    new, Pn = _reading_rms(machine, um, q_all, fk.P, fk.R, link_length)
    # candidates of row j: j*k .. j*k+k-1 in each of the n + 1 blocks
    new = new.reshape(n + 1, K, k).transpose(1, 0, 2).reshape(K, -1)
    pick = np.argmin(new, axis=1)
    best = new[np.arange(K), pick]
    better = best < rms
    block, col = np.divmod(pick, k)
    flat = (block * len(qk) + np.arange(K) * k + col)[better]
    P[better], R[better], rms[better] = Pn[flat], fk.R[flat], best[better]
    return P, R, rms


def sphere_pose_candidates(machine, um, q, link_length, starts=(), neighbours=None):
    """For each row, the pose on ``|P| = link_length`` that best explains its readings among
    several starts.

    Starts: the home pose; the square systems of five readings and the link from home, for
    every choice of the reading left out; and any ``starts`` given. Each is polished by least
    squares on all readings and the link (:func:`~pkmcal.instruments.constraint_link.
    solve_sphere_poses`), and the pose with the smallest RMS reading residual is kept. With
    ``neighbours`` (rows a fit explains), every row also starts from the poses of the
    neighbours with the nearest readings (:func:`neighbour_poses`).

    Parameters
    ----------
    machine : Machine
        The machine (a Hexa Slide, a six-leg platform: any with a constraint link).
    um : array_like or None
        Its parameter vector (internal units); None for the machine's own.
    q : ndarray, shape (K, n_joints)
        Joint readings, m.
    link_length : float
        Constraint-link length ``Lc``, m.
    starts : sequence of tuple, optional
        Further ``(P (K, 3), R (K, 3, 3))`` start poses (e.g. the poses of an earlier fit).
    neighbours : tuple of ndarray, optional
        ``(q, P, R)`` of rows a fit explains, whose poses also start these rows
        (:func:`neighbour_poses`). Only with a calibrated geometry: with a geometry still far
        off, more starts let rows settle on a wrong assembly mode that this geometry explains
        better and lead the continuation astray.

    Returns
    -------
    P : ndarray, shape (K, 3)
        Positions on the sphere, m.
    R : ndarray, shape (K, 3, 3)
        Orientations.
    rms : ndarray, shape (K,)
        RMS reading residual of each row at its pose, m (inf where no start gave a pose).
    """

    q = np.asarray(q, float)
    K, n = q.shape
    if K == 0:
        return np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0)
    # the square systems for every reading left out, in one batch (n K poses)
    qq = np.tile(q, (n, 1))
    sq = solve_sphere_poses(machine, um, qq, link_length, np.repeat(np.arange(n), K),
                            max_iter=40)
    P0, R0 = machine.home
    P0 = np.asarray(P0, float)
    norm = np.linalg.norm(P0)
    P0 = link_length * (P0 / norm if norm > 0 else np.array([0, 0, 1.0]))
    Ps = [np.broadcast_to(P0, (K, 3)), *(np.asarray(P, float) for P, _ in starts), sq.P]
    Rs = [np.broadcast_to(np.asarray(machine.home[1], float), (K, 3, 3)),
          *(np.asarray(R, float) for _, R in starts), sq.R]
    P_all, R_all = np.concatenate(Ps), np.concatenate(Rs)
    m = len(P_all) // K
    # each start polished by least squares on all readings and the link, in one batch
    with np.errstate(invalid="ignore", over="ignore"):
        fk = solve_sphere_poses(machine, um, np.tile(q, (m, 1)), link_length, None,
                                start=(P_all.copy(), R_all.copy()), max_iter=40)
    rms, P = _reading_rms(machine, um, np.tile(q, (m, 1)), fk.P, fk.R, link_length)
    pick = np.argmin(rms.reshape(m, K), axis=0) * K + np.arange(K)
    if neighbours is None:
        return P[pick], fk.R[pick], rms[pick]
    return neighbour_poses(machine, um, q, link_length, P[pick], fk.R[pick], rms[pick],
                           neighbours)


def start_sensitivity(problem, state) -> np.ndarray:
    """How far each row's pose moves per unit of scaled geometry error, at a state.

    The per-row least-squares pose is a function of the geometry; its derivative is
    ``-pinv(J_l) J_g`` (local and global Jacobians of the row's residuals, global columns
    scaled). Rows where this is large are where a start with the machine file's geometry is
    far and the residual most non-linear. Local coordinates that are lengths are divided by
    the machine's characteristic length (the sphere problems: 2 tangent lengths, 3 angles).

    Parameters
    ----------
    problem : BlockProblem
        A problem with local unknowns (``local_dof > 0``).
    state : object
        A state of it.

    Returns
    -------
    ndarray, shape (K,)
        Frobenius norm of the scaled sensitivity of each row's pose.
    """
    _, Jg, Jl = problem.evaluate(state)
    free = np.asarray(problem.parameters.free, bool)
    G = Jg[..., free] * np.asarray(problem.scales, float)[free]
    S = -np.linalg.pinv(Jl) @ G                                   # (K, d, n_free)
    lengths = getattr(problem, "local_lengths", 2)
    S[:, :lengths] /= problem.machine.characteristic_length()
    return np.linalg.norm(S, axis=(1, 2))


def _noise_factor(result) -> float:
    test = residual_test(result)
    return test.noise_factor if np.isfinite(test.ratio) else 0.0





def _median_noise_factor(result) -> float:
    """The residuals' typical size over the assumed noise, from their median (robust to a few
    gross errors), corrected for the unknowns fitted (``dof / N``)."""
    r = np.asarray(result.residuals, float).ravel()
    r = r[np.isfinite(r)]
    dof = int(getattr(result, "dof", 0) or 0)
    if not r.size or dof <= 0:
        return 0.0
    return float(np.sqrt(np.median(r**2) / (chi2_ppf(0.5, 1) * dof / r.size)))


def continuation_solve(problem, solve, direct=None, noise_known: bool = True) -> tuple:
    """Solve a constraint-link maximum-likelihood problem from a far start.

    Parameters
    ----------
    problem : ConstraintLinkML
        The problem on all rows (its parameters' values are the start geometry).
    solve : callable
        ``solve(problem, state) -> CalibrationResult`` (Levenberg-Marquardt with the caller's
        options).
    direct : CalibrationResult, optional
        The plain fit, when already made (it is then not repeated).
    noise_known : bool, optional
        False: the noise level will be estimated from the residuals. A fit passes when its
        median residual is within ``MAX_NOISE_FACTOR`` of the assumed noise (not on the
        chi-square test against the assumed noise, which data noisier than assumed fail);
        when the plain fit of all rows does not, the fallback runs, and the plain fit is kept
        unless the fallback's median residual is ``MAX_NOISE_FACTOR`` times smaller (a wrong
        geometry; otherwise the data are merely noisier than assumed, or a few rows wrong).

    Returns
    -------
    result : CalibrationResult
        The solution that passes the residual test, else the one with the smallest residuals.
    problem : ConstraintLinkML
        The problem of that solution (its data: the rows kept).
    report : StartReport
        What was done.

    Raises
    ------
    InputError
        When more than :data:`MAX_LEFT_OUT` of the rows (or too few to identify the geometry)
        can be explained by no pose, even with the best geometry found.
    """

    report = StartReport()
    data = problem.data
    machine = problem.machine
    scale = machine.characteristic_length()
    u0 = problem.parameters.values.copy()
    um0, Lc0 = problem.split(u0)
    K = len(data)

    def sub_problem(mask):
        sub = type(problem).__new__(type(problem))
        sub.__dict__.update(problem.__dict__)
        sub.data = data.subset(mask)
        if hasattr(problem, "_reading_sigma") and np.ndim(problem._reading_sigma) == 2:
            sub._reading_sigma = problem._reading_sigma[mask]
        return sub

    def record(stage, result, rows):
        nf = _noise_factor(result)
        # accepted unless alarming (the warning's rule): residuals a little above the assumed
        # noise are a noise that is a little off (simulated 2 um, assumed 1 um), not a wrong
        # geometry; the fallback (slower, and it leaves out rows far above the others) must not
        # run for that
        if noise_known:
            passed = not residual_test(result).alarming
        else:
            # the noise level will be estimated: a typical (median) residual within
            # MAX_NOISE_FACTOR of the assumed noise passes (a few gross errors do not move
            # it; the outlier test names them); else the fallback runs, and the plain fit is
            # kept unless it finds a geometry that explains the rows far better
            passed = bool(result.success) and _median_noise_factor(result) <= MAX_NOISE_FACTOR
        report.attempts.append({"stage": stage, "rows": int(rows),
                                "noise_factor": float(nf), "passed": passed})
        return passed

    def fit(mask, u, P, R, stage):
        sub = sub_problem(mask)
        state = SphereState(u.copy(), P[mask].copy(), R[mask].copy())
        result = solve(sub, state)
        return result, sub, record(stage, result, mask.sum())

    sigma = float(np.mean(problem.sigma))

    def restart(u, P, R):
        """Every row's pose re-started with geometry ``u``; the rows it explains: within
        START_TOL of the size, and not far beyond the others (a row whose pose the starts
        miss, or a wrong row, would bend the fit: it is retried later or left out)."""
        um, Lc = problem.split(u)
        P, R, rms = sphere_pose_candidates(machine, um, data.q, Lc, starts=[(P, R)])
        ok = rms < START_TOL * scale
        if ok.any():
            z = rms * np.sqrt(data.q.shape[1]) / sigma           # ~ whitened norm of the row
            ok &= z <= max(OUTLIER_FLOOR, OUTLIER_FACTOR * float(np.median(z[ok])))
        return P, R, ok

    def fit_all(u, P, R, stage):
        """Re-start every pose with ``u`` and fit the rows explained; once more if the
        fitted geometry explains rows the start geometry did not."""
        P, R, ok = restart(u, P, R)
        if not _enough(ok, problem):
            return None
        result, sub, passed = fit(ok, u, P, R, stage)
        consider(result, sub, ok, passed)
        P1, R1 = P.copy(), R.copy()
        P1[ok], R1[ok] = result.state.P, result.state.R
        P2, R2, ok2 = restart(result.x, P1, R1)
        if passed and (ok2 & ~ok).any() and _enough(ok2, problem):
            result, sub, passed = fit(ok2, result.x, P2, R2, stage + ", rows retried")
            consider(result, sub, ok2, passed)
            P1, R1, ok = P2.copy(), R2.copy(), ok2
            P1[ok], R1[ok] = result.state.P, result.state.R
        return result, sub, ok, P1, R1

    # 1. start poses: the plain least-squares forward kinematics from home; multi-start only
    #    where it does not explain the readings
    fk = solve_sphere_poses(machine, um0, data.q, Lc0)
    rms, P = _reading_rms(machine, um0, data.q, fk.P, fk.R, Lc0)
    R = fk.R
    ok = rms < START_TOL * scale
    if not ok.all():
        Pm, Rm, rmsm = sphere_pose_candidates(machine, um0, data.q[~ok], Lc0)
        P[~ok], R[~ok] = Pm, Rm
        ok[~ok] = rmsm < START_TOL * scale
    started = ok.copy()
    best = None                                   # (noise factor, result, problem, mask)

    def consider(result, sub, mask, passed):
        nonlocal best
        nf = _noise_factor(result)
        if result.success or best is None:
            # passing fits: the one with the most rows; else the smallest residuals
            key = (not passed, not result.success, -int(mask.sum()) if passed else 0, nf)
            if best is None or key < best[0]:
                best = (key, result, sub, mask.copy())

    plain = None            # the plain fit of every row (unknown noise: kept unless beaten)
    if direct is not None and ok.all():
        consider(direct, problem, ok, record("direct", direct, K))
        plain = (direct, problem, ok.copy())
    elif _enough(ok, problem):
        result, sub, passed = fit(ok, u0, P, R, "direct")
        consider(result, sub, ok, passed)
        if ok.all():
            plain = (result, sub, ok.copy())
        if passed and not ok.all():
            # rows without a start pose: re-started with the fitted geometry, all refitted
            P1, R1 = P.copy(), R.copy()
            P1[ok], R1[ok] = result.state.P, result.state.R
            fit_all(result.x, P1, R1, "all rows, re-started")
    if best is not None and not best[0][0]:
        return _finish(best, report, data, started, "direct")

    # 2. continuation: the least sensitive rows first, every pose re-started with their
    #    geometry, then all rows
    # (poses of step 1: with the machine file's geometry, the pose that explains the readings
    # best is often on a wrong branch; the multi-start waits for a better geometry)
    ok = started.copy()
    sens = np.full(K, np.inf)
    if ok.any():
        sens[ok] = start_sensitivity(sub_problem(ok), SphereState(u0.copy(), P[ok], R[ok]))
    k = min(int(ok.sum()), max(int(SUBSET_SHARE * K), _min_rows(problem, 1.5)))
    first = np.zeros(K, bool)
    first[np.argsort(sens)[:k]] = True
    first &= ok
    current = best
    if _enough(first, problem):
        r1, _, _ = fit(first, u0, P, R, "well-conditioned rows")
        P1, R1 = P.copy(), R.copy()
        P1[first], R1[first] = r1.state.P, r1.state.R
        done = fit_all(r1.x, P1, R1, "all rows after continuation")
        if done is not None:
            current = (None, done[0], done[1], done[2])
            P, R = done[3], done[4]

    # 3. trimmed rounds: refit without the rows with the largest residuals, re-start them
    for round_ in range(TRIM_ROUNDS):
        if best is None or not best[0][0] or current is None:
            break
        _, result, sub, mask = current
        rows = np.flatnonzero(mask)
        chi = np.sum(np.asarray(result.residuals) ** 2, axis=-1)
        keep = np.zeros(K, bool)
        keep_n = max(int(TRIM_KEEP * rows.size), _min_rows(problem, 1.5))
        keep[rows[np.argsort(chi)[:keep_n]]] = True
        if not _enough(keep, problem):
            break
        P1, R1 = P.copy(), R.copy()
        P1[rows], R1[rows] = result.state.P, result.state.R
        r1, _, _ = fit(keep, result.x, P1, R1, f"trimmed round {round_ + 1}")
        P1[keep], R1[keep] = r1.state.P, r1.state.R
        done = fit_all(r1.x, P1, R1, f"all rows after trimmed round {round_ + 1}")
        if done is None:
            break
        current = (None, done[0], done[1], done[2])
        P, R = done[3], done[4]

    if best is None:
        raise InputError(f"{path_text(data.source)}: no pose on the constraint sphere (Lc = "
                         f"{Lc0 * 1e3:.6g} mm) reproduces the readings of "
                         f"{int((~started).sum())} row(s): {_rows_text(data.rows[~started])}")
    if (not noise_known and plain is not None and plain[0].success
            and _median_noise_factor(plain[0])
            <= MAX_NOISE_FACTOR * _median_noise_factor(best[1])):
        # no geometry explains the typical row far better: the data are noisier than
        # assumed, or a few rows are wrong (the outlier test names them)
        result, sub, mask = plain
        return _finish(((False,), result, sub, mask), report, data, started, "direct")
    return _finish(best, report, data, started,
                   "continuation" if not best[0][0] else "best effort")


def _left_out_text(rows, K: int) -> str:
    """The warning for the rows left out (file rows ``rows`` of ``K``)."""
    return (f"{len(rows)} of {K} row(s) left out: with the calibrated geometry the best pose "
            "found on the constraint sphere leaves residuals more than "
            f"{OUTLIER_FACTOR:g} times the other rows' (and the noise's): rows "
            f"{_rows_text(rows)}. Usual causes: poses near another assembly mode of the loop, "
            "where the forward kinematics have several solutions, or wrong rows (readings "
            "taken without the link, another passive joint, a typing error)")


def _min_rows(problem, redundancy: float = 1.0) -> int:
    """Rows needed to identify the geometry (``redundancy`` equations per identifiable
    parameter)."""
    n_id = int(problem.parameters.free.sum()) - 6
    per_row = problem.machine.n_joints - problem.local_dof
    return int(np.ceil(redundancy * n_id / max(per_row, 1)))


def _enough(mask, problem) -> bool:
    return int(np.sum(mask)) >= _min_rows(problem)


def _finish(best, report, data, started, strategy):
    _, result, problem, mask = best
    report.strategy = strategy
    report.retried_rows = data.rows[~started & mask]
    report.dropped_rows = data.rows[~mask]
    report.kept = np.asarray(mask, bool).copy()
    K = len(data)
    if report.dropped_rows.size:
        what = _left_out_text(report.dropped_rows, K)
        if report.dropped_rows.size > MAX_LEFT_OUT * K:
            raise InputError(f"{path_text(data.source)}: {what}; that is more than "
                             f"{MAX_LEFT_OUT:.0%} of the rows: check the data and the "
                             "machine file (constraint_link.length, home, chains)")
        # readings that no pose explains even with the calibrated geometry are bad input
        um, Lc = problem.split(result.x)
        P, R, rms = sphere_pose_candidates(
            problem.machine, um, data.q[~mask], Lc,
            neighbours=(data.q[mask], result.state.P, result.state.R))
        report.left_out_poses = (P, R)
        gross = rms >= START_TOL * problem.machine.characteristic_length()
        if gross.any():
            rows = data.rows[~mask][gross]
            raise InputError(f"{path_text(data.source)}: no pose on the constraint sphere (Lc = "
                             f"{data.link_length * 1e3:.6g} mm) reproduces the readings of "
                             f"{rows.size} row(s): {_rows_text(rows)}")
        report.warnings.append(what)
    if report.retried_rows.size:
        report.warnings.append(
            f"{report.retried_rows.size} row(s) had no start pose with the machine file's "
            f"geometry and were fitted after a first fit of the others: rows "
            f"{_rows_text(report.retried_rows)}")
    return result, problem, report
