"""Forward kinematics solved numerically for every machine: the batched (Gauss-)Newton over
full poses, the closed-form path of translating platforms, and their result (:class:`FKResult`).

Written once against :class:`~pkmcal.machines.base.Machine`'s inverse kinematics and its
derivatives; a machine class only supplies its equations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ConvergenceError
from ..kinematics import matrix_from_rotvec


@dataclass
class FKResult:
    """Batch forward kinematics: poses, per-pose convergence and iteration count.

    Attributes
    ----------
    P : ndarray, shape (K, 3)
        Platform positions, m (base frame).
    R : ndarray, shape (K, 3, 3)
        Platform orientations.
    converged : ndarray of bool, shape (K,)
        True where the solver converged for that pose.
    residual : ndarray, shape (K,)
        Largest absolute joint residual of each pose at its last evaluation, in the joints'
        internal units (m or rad); NaN or inf where the pose failed.
    iterations : int
        Newton iterations used for the slowest pose.
    """

    P: np.ndarray
    R: np.ndarray
    converged: np.ndarray
    residual: np.ndarray
    iterations: int

    def raise_if_failed(self, what: str = "forward kinematics", rows=None) -> None:
        """Raise :class:`ConvergenceError` naming (1-based) rows that did not converge.

        Parameters
        ----------
        what : str, optional
            What was being solved, the start of the error message.
        rows : array_like of int, shape (K,), optional
            Row label of each pose (e.g. line numbers of a data file); default: 1-based position
            in the batch.

        Raises
        ------
        ConvergenceError
            When any pose did not converge; the message lists up to ten row labels.
        """
        bad = np.flatnonzero(~self.converged)
        if bad.size:
            labels = (np.asarray(rows)[bad] if rows is not None else bad + 1).tolist()
            shown = ", ".join(map(str, labels[:10])) + (" ..." if len(labels) > 10 else "")
            raise ConvergenceError(
                f"{what} did not converge for {bad.size} pose(s), row(s) {shown}: "
                "the readings may be outside the workspace or on another assembly mode"
            )



def closed_form_positions_fk(machine, q, u=None,
                             raise_on_failure: bool = False) -> FKResult:
    """Forward kinematics of a translating platform from its closed-form ``fk_positions``.

    Rows are solved in chunks of :attr:`Machine.fk_chunk` (temporaries stay in cache: ~20 %
    faster on 1e6 rows); orientations are the identity, the residual 0 where solved.

    Parameters
    ----------
    machine : Machine
        A machine with ``fk_positions(q, u) -> (P (K, 3), ok (K,))``.
    q : array_like, shape (K, n_joints)
        Joint readings.
    u : array_like, shape (n_params,), optional
        Parameter vector; default the machine's.
    raise_on_failure : bool, optional
        Raise instead of returning rows that could not be solved.

    Returns
    -------
    FKResult
        Positions, identity orientations and validity.

    Raises
    ------
    ConvergenceError
        With ``raise_on_failure``, when a row could not be solved.
    """
    q = np.atleast_2d(np.asarray(q, float))
    K = len(q)
    P, ok = np.empty((K, 3)), np.empty(K, bool)
    for lo in range(0, K, machine.fk_chunk):
        P[lo:lo + machine.fk_chunk], ok[lo:lo + machine.fk_chunk] = \
            machine.fk_positions(q[lo:lo + machine.fk_chunk], u)
    result = FKResult(P, np.broadcast_to(np.eye(3), (K, 3, 3)).copy(), ok,
                      np.where(ok, 0.0, np.inf), 0)
    if raise_on_failure:
        result.raise_if_failed()
    return result


def newton_pose_solve(system, P, R, tol, max_iter, raise_on_failure=False,
                      max_step=0.05, max_rot=0.2, step_tol=None, space=None) -> FKResult:
    """Batched (Gauss-)Newton over full poses.

    Each pose is updated ``P += dP``, ``R <- exp(dOmega) R``; steps are limited to ``max_step``
    (m) and ``max_rot`` (rad) so a far start does not jump to another assembly mode. Poses stop
    iterating once converged; NaN residuals (unreachable) mark the pose as failed.
    Over-determined systems (least squares) converge on the step: ``|dx| < step_tol``.

    Parameters
    ----------
    system : callable
        ``system(idx, P, R) -> (residual (k, m), J (k, m, 6))`` evaluates the poses ``idx`` of
        the batch; ``J`` is with respect to ``[dP, dOmega]``.
    P : ndarray, shape (K, 3)
        Start positions, m; updated in place.
    R : ndarray, shape (K, 3, 3)
        Start orientations; updated in place.
    tol : float
        A pose has converged when its largest absolute residual is below ``tol``.
    max_iter : int
        Maximum iterations.
    raise_on_failure : bool, optional
        Raise instead of returning poses that did not converge.
    max_step : float, optional
        Largest position step per iteration, m.
    max_rot : float, optional
        Largest rotation step per iteration, rad.
    step_tol : float, optional
        Also converged when every component of the step is below this (least squares).
    space : sequence of int, optional
        The pose coordinates (indices into ``[dP, dOmega]``) the poses move along
        (:attr:`Machine.pose_space` of a planar platform); default: all six.

    Returns
    -------
    FKResult
        The poses (the arrays ``P`` and ``R`` passed in), convergence, residuals and the
        number of iterations run.

    Raises
    ------
    ConvergenceError
        With ``raise_on_failure``, when a pose did not converge.
    """
    K = P.shape[0]
    active = np.arange(K)
    converged = np.zeros(K, bool)
    res = np.full(K, np.inf)
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007
        everyone = active.size == K              # no gather/scatter while all poses iterate
        Pa, Ra = (P, R) if everyone else (P[active], R[active])
        r, J = system(active, Pa, Ra)
        err = np.max(np.abs(r), axis=-1)
        res[active] = err
        ok = err < tol
        converged[active[ok]] = True
        keep = ~ok & np.isfinite(err)
        if not keep.all():
            everyone = False
            active, r, J, Pa, Ra = active[keep], r[keep], J[keep], Pa[keep], Ra[keep]
        if active.size == 0:
            break
        if space is not None:
            J = J[..., space]
        if J.shape[-2] == J.shape[-1]:
            dx = -solve_batched(J, r)
        else:   # least squares by the normal equations (Newton corrects any rounding)
            Jt = np.swapaxes(J, -1, -2)
            dx = -solve_batched(Jt @ J, (Jt @ r[..., None])[..., 0])
        if space is not None:
            full = np.zeros(dx.shape[:-1] + (6,))
            full[..., space] = dx
            dx = full
        dp, dw = dx[:, :3], dx[:, 3:]
        # readings far outside the workspace (1e300) give steps whose squares overflow: an
        # infinite norm, and the step limit below then stops that pose, which fails to converge
        with np.errstate(over="ignore"):
            sp = np.sqrt(np.sum(dp * dp, axis=-1, keepdims=True))
            sw = np.sqrt(np.sum(dw * dw, axis=-1, keepdims=True))
        dp = dp * np.minimum(1.0, max_step / np.maximum(sp, 1e-300))
        dw = dw * np.minimum(1.0, max_rot / np.maximum(sw, 1e-300))
        if everyone:
            P += dp
            R[...] = matrix_from_rotvec(dw) @ R
        else:
            P[active] = Pa + dp
            R[active] = matrix_from_rotvec(dw) @ Ra
        if step_tol is not None:
            small = np.max(np.abs(dx), axis=-1) < step_tol
            converged[active[small]] = True
            active = active[~small]
            if active.size == 0:
                break
    result = FKResult(P, R, converged, res, it)
    if raise_on_failure:
        result.raise_if_failed()
    return result


def _shared_first_step(shared, q, P, R, tol, max_step=0.05, max_rot=0.2, space=None):
    """First Newton step of :meth:`Machine.fk` when every pose starts from the same pose.

    ``shared = (q0, J0)``: joints and Jacobian at the start pose (its columns along ``space``
    when given). Updates ``P``, ``R`` in place exactly as the first iteration of
    :func:`newton_pose_solve` would (poses already within ``tol`` do not move).
    """
    q0, J0 = shared
    r = q0 - q                                                     # (k, n)
    dx = -np.linalg.solve(J0, r.T).T
    if space is not None:
        full = np.zeros((len(dx), 6))
        full[:, space] = dx
        dx = full
    dx[np.max(np.abs(r), axis=-1) < tol] = 0.0
    dp, dw = dx[:, :3], dx[:, 3:]
    with np.errstate(over="ignore"):    # huge readings: an infinite norm, no step (as above)
        sp = np.sqrt(np.sum(dp * dp, axis=-1, keepdims=True))
        sw = np.sqrt(np.sum(dw * dw, axis=-1, keepdims=True))
    P += dp * np.minimum(1.0, max_step / np.maximum(sp, 1e-300))
    R[...] = matrix_from_rotvec(dw * np.minimum(1.0, max_rot / np.maximum(sw, 1e-300))) @ R


def solve_batched(J, r, min_pivot: float = 1e-6) -> np.ndarray:
    """Solve ``J[k] x[k] = r[k]`` for a batch of small square systems ``J`` (k, m, m).

    Large batches: Gaussian elimination vectorised over the batch (each step is one operation
    on contiguous arrays of all systems), with one pivot order for the whole batch (complete
    pivoting on the mean of a sample of it). A system whose pivots are not all within
    ``min_pivot`` of its largest one, or with a non-finite solution, is solved again by LAPACK.
    Small batches go to LAPACK (``numpy.linalg.solve``) directly. A singular system gets the
    minimum-norm least-squares solution.
    """
    J = np.asarray(J, float)
    r = np.asarray(r, float)
    k, m = r.shape
    if k < 256 or m < 2:
        return _lapack_solve(J, r)
    rows, cols = _pivot_order(np.mean(J[::max(1, k // 64)], axis=0))
    A = J.transpose(1, 2, 0)[rows[:, None], cols]                   # (m, m, k), permuted copy
    b = r.T[rows]                                                   # (m, k)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for i in range(m - 1):
            f = A[i + 1:, i] / A[i, i]
            A[i + 1:, i + 1:] -= f[:, None] * A[i, i + 1:]
            b[i + 1:] -= f * b[i]
        x = np.empty((m, k))
        for i in range(m - 1, -1, -1):
            acc = b[i].copy()
            for j in range(i + 1, m):
                acc -= A[i, j] * x[j]
            x[i] = acc / A[i, i]
        pivots = np.abs(A[np.arange(m), np.arange(m)])              # (m, k)
        bad = ~(np.min(pivots, axis=0) >= min_pivot * np.max(pivots, axis=0))
        bad |= ~np.all(np.isfinite(x), axis=0)
    out = np.empty((k, m))
    out[:, cols] = x.T
    if bad.any():
        out[bad] = _lapack_solve(J[bad], r[bad])
    return out


def _lapack_solve(J, r):
    try:
        return np.linalg.solve(J, r[..., None])[..., 0]
    except np.linalg.LinAlgError:  # a singular system in the batch
        return (np.linalg.pinv(J) @ r[..., None])[..., 0]


def _pivot_order(A):
    """Row and column order of Gaussian elimination with complete pivoting on ``A`` (m, m)."""
    A = np.array(A, float)
    m = len(A)
    rows, cols = np.arange(m), np.arange(m)
    for i in range(m):
        sub = np.abs(A[i:, i:])
        if not np.all(np.isfinite(sub)):
            break
        a, c = np.unravel_index(np.argmax(sub), sub.shape)
        a, c = a + i, c + i
        A[[i, a]], rows[[i, a]] = A[[a, i]], rows[[a, i]]
        A[:, [i, c]], cols[[i, c]] = A[:, [c, i]], cols[[c, i]]
        if A[i, i] != 0:
            A[i + 1:] -= np.outer(A[i + 1:, i] / A[i, i], A[i])
    return rows, cols
