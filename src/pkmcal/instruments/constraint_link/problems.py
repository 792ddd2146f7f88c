"""The estimation problems of constraint-link data: the sphere's poses and the loop
closure each method fits (:mod:`.methods` solves them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import InputError
from ...kinematics import matrix_from_rotvec
from ...machines.base import Machine, newton_pose_solve
from ...parameters import ParameterSet
from ...paths import path_text
from .data import ConstraintLinkData

LINK = "link.length"
METHODS = ("ml", "ik", "fk")


def sphere_tangents(P):
    """Orthonormal tangent basis (K, 3, 2) of the sphere through ``P`` (K, 3), and ``P/|P|``."""
    n = P / np.linalg.norm(P, axis=-1, keepdims=True)
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    t2 = np.cross(n, t1)
    return np.stack([t1, t2], -1), n


def solve_sphere_poses(machine: Machine, u, q, link_length, passive=None, start=None,
                       tol=1e-13, max_iter=100):
    """Poses on ``|P| = link_length`` that reproduce the readings ``q``.

    With ``passive`` the passive reading is ignored and the five active ones plus the
    constraint give a square system (the paper's FK of step iii); without it all six readings
    and the constraint are solved in the least-squares sense (Gauss-Newton,
    :func:`~pkmcal.machines.newton_pose_solve`).

    Parameters
    ----------
    machine : Machine
        The machine (a Hexa Slide) whose inverse kinematics are used.
    u : array_like, shape (n_params,) or None
        Its parameter vector (internal units); None for the machine's own.
    q : ndarray, shape (K, 6)
        Joint readings, m.
    link_length : float
        Constraint-link length ``Lc``, m.
    passive : ndarray of int, shape (K,), optional
        0-based index of the passive actuator of each row.
    start : tuple of array_like, optional
        ``(P (K, 3), R (K, 3, 3))`` start poses; default: the home pose moved onto the sphere.
    tol : float, optional
        Convergence tolerance on the residuals, relative to the characteristic length.
    max_iter : int, optional
        Maximum Newton iterations.

    Returns
    -------
    FKResult
        The poses, per-row convergence and residuals (m).
    """
    K = len(q)
    if start is None:
        P0, R0 = machine.home
        P0 = np.asarray(P0, float)
        norm = np.linalg.norm(P0)
        P0 = link_length * (P0 / norm if norm > 0 else np.array([0, 0, 1.0]))
        start = (np.broadcast_to(P0, (K, 3)).copy(), np.broadcast_to(R0, (K, 3, 3)).copy())
    P, R = (np.array(start[0], float), np.array(start[1], float))
    scale = machine.characteristic_length()

    def system(idx, P, R):
        qc, J, _ = machine.ik_jacobians(P, R, u, want_du=False)
        r = qc - q[idx]
        norm = np.linalg.norm(P, axis=-1)
        rc = norm - link_length
        Jc = np.concatenate([P / norm[:, None], np.zeros_like(P)], -1)
        if passive is None:
            return (np.concatenate([r, rc[:, None]], -1),
                    np.concatenate([J, Jc[:, None, :]], -2))
        rows = np.arange(len(idx))
        r[rows, passive[idx]] = rc
        J[rows, passive[idx]] = Jc
        return r, J

    return newton_pose_solve(system, P, R, tol * scale, max_iter,
                             step_tol=None if passive is not None else 1e-9 * scale)


@dataclass
class SphereState:
    """Estimator state: global values and the per-measurement poses."""

    u: np.ndarray
    P: np.ndarray
    R: np.ndarray


class _ConstraintLinkProblem:
    """What the three methods share: parameters = machine's + ``link.length``."""

    local_dof = 0
    #: whether ``link.length`` is estimated when the caller does not say
    estimates_link_length = False
    #: the residuals are no more precise than this share of the machine's characteristic
    #: length (a few ulps of the joint values through the kinematics; an inner solve's
    #: tolerance where the residuals come from one)
    rounding = 4e-15

    def _whitening(self) -> tuple[int, np.ndarray]:
        """The number of residuals and the standard deviations that whiten them."""
        return len(self.data), self.sigma

    @property
    def cost_floor(self):
        """Cost of residuals at their precision (:attr:`rounding`, whitened): noise-free data
        fitted exactly can do no better, and the estimator stops there (a fit started at
        such an optimum finds no step that lowers its cost: converged, not stuck)."""
        n, sigma = self._whitening()
        precision = self.rounding * self.machine.characteristic_length()
        return 0.5 * n * float(np.max(precision / sigma)) ** 2

    @staticmethod
    def check_data(data: ConstraintLinkData) -> None:
        """Refuse data the method cannot use (before any fit).

        Parameters
        ----------
        data : ConstraintLinkData
            The readings.

        Raises
        ------
        InputError
            Naming the data and what is missing.
        """

    def __init__(self, machine: Machine, data: ConstraintLinkData, sigma_m=1e-6,
                 estimate_link_length: bool = False):
        if data.q.shape[1] != machine.n_joints:
            raise InputError(f"{path_text(data.source)}: "
                             f"{data.q.shape[1]} joint columns, the machine has "
                             f"{machine.n_joints} actuators")
        self.machine = machine
        self.data = data
        self.sigma = np.broadcast_to(np.asarray(sigma_m, float), (machine.n_joints,))
        link = ParameterSet([LINK], ["length"], [data.link_length],
                            fixed=[not estimate_link_length])
        self.parameters = machine.parameters.concat(link)
        self.scales = machine.scales_with(link)
        self.n_machine = len(machine.parameters)

    def global_values(self, state):
        """The global parameters of a state: machine parameters followed by ``link.length``.

        Parameters
        ----------
        state : SphereState
            An estimator state.

        Returns
        -------
        ndarray, shape (n_machine + 1,)
            Parameter values, internal units.
        """
        return state.u

    def split(self, u):
        """Split a global vector into the machine's parameters and the link length.

        Parameters
        ----------
        u : ndarray, shape (n_machine + 1,)
            Global parameter vector.

        Returns
        -------
        um : ndarray, shape (n_machine,)
            Machine parameters.
        Lc : float
            Constraint-link length, m.
        """
        return u[:self.n_machine], u[self.n_machine]

    def start_poses(self, passive=None):
        """Start poses on the constraint sphere for the start geometry.

        Parameters
        ----------
        passive : ndarray of int, shape (K,), optional
            Passive actuator of each row (square systems); None: least squares on all readings.

        Returns
        -------
        P : ndarray, shape (K, 3)
            Positions, m.
        R : ndarray, shape (K, 3, 3)
            Orientations.

        Raises
        ------
        InputError
            When no pose on the sphere explains a row's readings to within 5 % of the
            characteristic length; the rows are named.
        """
        um, Lc = self.split(self.parameters.values)
        fk = solve_sphere_poses(self.machine, um, self.data.q, Lc, passive)
        # a start pose need not be exact (the estimator refines it); it must exist and
        # explain the readings to within the size of plausible geometric errors
        bad = ~(fk.converged | (fk.residual < 0.05 * self.machine.characteristic_length()))
        if bad.any():
            rows = self.data.rows[bad]
            shown = ", ".join(map(str, rows[:10])) + (" ..." if len(rows) > 10 else "")
            raise InputError(
                f"{self.data.source}: no pose on the constraint sphere (Lc = "
                f"{Lc * 1e3:.6g} mm) reproduces the readings of {bad.sum()} row(s): {shown}")
        return fk.P, fk.R


class ConstraintLinkML(_ConstraintLinkProblem):
    """Maximum likelihood with per-pose unknowns (implicit loop); 5 local unknowns per pose.

    Global unknowns: the machine's parameters and ``link.length`` (fixed unless
    ``estimate_link_length``); local unknowns: 2 tangent and 3 rotation coordinates of each
    pose on the sphere. Residuals: all readings divided by their standard deviation.

    Parameters
    ----------
    machine : Machine
        Start geometry (a Hexa Slide); its fixed flags are kept.
    data : ConstraintLinkData
        Readings taken with the link mounted.
    sigma_m : float or array_like, optional
        Encoder noise standard deviation, m: one value or one per actuator.
    estimate_link_length : bool, optional
        Estimate ``Lc`` too (else held at ``data.link_length``).

    Raises
    ------
    InputError
        When the data's joint columns do not match the machine's actuators.
    """

    local_dof = 5

    def _whitening(self) -> tuple[int, np.ndarray]:
        return self.data.q.size, self.reading_sigma()

    def initial_state(self):
        # all six readings + the constraint in the least-squares sense: robust to a far start
        """Start state: the start geometry and poses fitted to all six readings, on the sphere.

        Returns
        -------
        SphereState
            Global values and poses.

        Raises
        ------
        InputError
            When a row's readings cannot be explained by any pose on the sphere.
        """
        P, R = self.start_poses(None)
        Lc = self.split(self.parameters.values)[1]
        P *= (Lc / np.linalg.norm(P, axis=-1))[:, None]   # exactly on the sphere
        return SphereState(self.parameters.values.copy(), P, R)

    def evaluate(self, state, jacobian=True):
        """Whitened reading residuals and their Jacobians (see :meth:`BlockProblem.evaluate`).

        Parameters
        ----------
        state : SphereState
            Global values and poses.
        jacobian : bool, optional
            Also compute the Jacobians.

        Returns
        -------
        r : ndarray, shape (K, n_joints)
            ``(IK(pose) - q) / sigma``.
        J_g : ndarray, shape (K, n_joints, n_machine + 1) or None
            Derivatives with respect to the machine parameters and ``Lc``.
        J_l : ndarray, shape (K, n_joints, 5) or None
            Derivatives with respect to the pose's tangent and rotation coordinates.
        """
        um, Lc = self.split(state.u)
        q, Jx, Ju = self.machine.ik_jacobians(state.P, state.R, um, want_du=jacobian)
        sigma = self.reading_sigma()
        r = (q - self.data.q) / sigma
        if not jacobian:
            return r, None, None
        T, n = sphere_tangents(state.P)
        JP = Jx[..., :3]
        dLc = np.einsum("kji,ki->kj", JP, n)[..., None]
        Jg = np.concatenate([Ju, dLc], -1) / sigma[..., None]
        Jl = np.concatenate([JP @ T, Jx[..., 3:]], -1) / sigma[..., None]
        return r, Jg, Jl

    def reading_sigma(self):
        """Standard deviation of every reading, (K, n_joints) or broadcastable.

        Returns
        -------
        ndarray
            Standard deviations, m: here one per actuator, shape (n_joints,).
        """
        return self.sigma

    def noise_groups(self):
        """One noise group, the encoder readings (as lengths), one measurement per pose.

        Returns
        -------
        NoiseGroups
            See :class:`~pkmcal.estimation.variance.NoiseGroups`.
        """
        from ...estimation.variance import NoiseGroups

        K, n = self.data.q.shape
        groups = NoiseGroups.single((K, n), "reading", "encoder readings",
                                    float(np.mean(self.sigma)), "length",
                                    getattr(self.data, "rows", None))
        return groups

    def retract(self, state, du, dl):
        """The state after a step: poses moved on the sphere, then projected back onto it.

        Parameters
        ----------
        state : SphereState
            Current state.
        du : ndarray, shape (n_machine + 1,)
            Step of the global parameters.
        dl : ndarray, shape (K, 5)
            Step of each pose: 2 tangent (m) and 3 rotation (rad) coordinates.

        Returns
        -------
        SphereState
            The new state.
        """
        u = state.u + du
        T, _ = sphere_tangents(state.P)
        P = state.P + np.einsum("kij,kj->ki", T, dl[:, :2])
        P *= (u[self.n_machine] / np.linalg.norm(P, axis=-1))[:, None]
        R = matrix_from_rotvec(dl[:, 2:]) @ state.R
        return SphereState(u, P, R)


class ConstraintLinkIK(ConstraintLinkML):
    """The paper's inverse-kinematics method, all chains jointly.

    The five active readings are taken as exact and the passive one carries the residual.
    Solving the five-active-plus-link loop for the pose at every step (the paper's step iii)
    fails wherever that loop has no solution for the current geometry, which stalls the
    iteration from the paper's Table 1 errors. Here the poses stay unknowns, as in ``ml``, and
    the active readings are weighted ``active_weight`` (1e3) times more than the passive one:
    the estimate equals the exact method's to a relative ``1/active_weight^2`` and the problem
    is feasible at every step. :class:`ConstraintLinkIKExplicit` is the literal form.

    Parameters
    ----------
    machine : Machine
        Start geometry (a Hexa Slide).
    data : ConstraintLinkData
        Readings with the ``passive`` column.
    sigma_m : float or array_like, optional
        Encoder noise standard deviation, m: one value or one per actuator.
    estimate_link_length : bool, optional
        Estimate ``Lc`` too.

    Raises
    ------
    InputError
        When the data have no ``passive`` column or the wrong number of joint columns.
    """

    active_weight = 1e3
    #: the active readings are taken as exact: its residuals are not the noise's
    noise_groups = None

    @staticmethod
    def check_data(data: ConstraintLinkData) -> None:
        """Refuse data without the ``passive`` column (the method needs it).

        Parameters
        ----------
        data : ConstraintLinkData
            The readings.

        Raises
        ------
        InputError
            Naming the data and the column.
        """
        if data.passive is None:
            raise InputError(f"{path_text(data.source)}: the inverse-kinematics method needs "
                             "the 'passive' column (which actuator was passive at each row)")

    def __init__(self, machine, data, sigma_m=1e-6, estimate_link_length=False):
        self.check_data(data)
        super().__init__(machine, data, sigma_m, estimate_link_length)
        weights = np.full(data.q.shape, self.active_weight)
        weights[np.arange(len(data)), data.passive] = 1.0
        self._reading_sigma = self.sigma / weights

    def reading_sigma(self):
        return self._reading_sigma


class _ImplicitPoseProblem(_ConstraintLinkProblem):
    """Methods whose poses are functions of the readings (solved inside each evaluation)."""

    #: forward kinematics inside each evaluation converge to this (times the machine's
    #: characteristic length); residuals are no more precise than that
    fk_tol = 1e-13
    rounding = fk_tol

    def _keep_solved_rows(self, fk):
        """Keep the rows whose poses the start geometry can solve (seed 000's methods need
        a start close enough); the others are left out and reported as ``dropped_rows``."""
        data = self.data
        self.dropped_rows = data.rows[~fk.converged]
        self._start = (fk.P[fk.converged], fk.R[fk.converged])
        if self.dropped_rows.size:
            self.data = data.subset(fk.converged)
        if len(self.data) == 0:
            raise InputError(f"{path_text(data.source)}: no row can be solved for a pose with the "
                             "start geometry")

    #: start values of the global unknowns (None: the machine's, ``parameters.values``)
    _u0 = None

    def initial_state(self):
        """Start state: the start geometry and the poses solved for it.

        Returns
        -------
        SphereState
            Global values and the poses of the rows kept.
        """
        u = self.parameters.values if self._u0 is None else self._u0
        return SphereState(u.copy(), *self._start)

    def retract(self, state, du, dl):
        """The state after a global step (poses are recomputed in :meth:`evaluate`).

        Parameters
        ----------
        state : SphereState
            Current state.
        du : ndarray, shape (n_machine + 1,)
            Step of the global parameters.
        dl : None
            Unused (no local unknowns).

        Returns
        -------
        SphereState
            The new state, with the old poses as warm start.
        """
        return SphereState(state.u + du, state.P, state.R)

    def _poses(self, state, constrained: bool):
        um, Lc = self.split(state.u)
        if constrained:
            fk = solve_sphere_poses(self.machine, um, self.data.q, Lc, self.data.passive,
                                    start=(state.P, state.R), tol=self.fk_tol)
        else:
            fk = self.machine.fk(self.data.q, um, start=(state.P, state.R), tol=self.fk_tol)
        state.P, state.R = fk.P, fk.R          # warm start for the next evaluation
        return fk


class ConstraintLinkIKExplicit(_ImplicitPoseProblem):
    """The paper's inverse-kinematics method literally.

    The pose comes from the five active readings and the link (forward kinematics), the
    residual is the passive reading minus its inverse kinematics, and the Jacobian is the total
    derivative ``dq_p/du + dq_p/dx dx/du`` (implicit differentiation). Rows whose pose the
    start geometry cannot solve are left out and listed in ``dropped_rows``.

    Parameters
    ----------
    machine : Machine
        Start geometry (a Hexa Slide).
    data : ConstraintLinkData
        Readings with the ``passive`` column.
    sigma_m : float or array_like, optional
        Encoder noise standard deviation, m: one value or one per actuator.
    estimate_link_length : bool, optional
        Estimate ``Lc`` too.
    start : tuple of ndarray, optional
        ``(P (K, 3), R (K, 3, 3))`` start poses for the pose solves; default: fitted to all six
        readings.

    Raises
    ------
    InputError
        When the data have no ``passive`` column, the wrong number of joint columns, or no row
        can be solved.
    """

    check_data = staticmethod(ConstraintLinkIK.check_data)

    def __init__(self, machine, data, sigma_m=1e-6, estimate_link_length=False, start=None):
        self.check_data(data)
        super().__init__(machine, data, sigma_m, estimate_link_length)
        # the five active readings + the constraint may have no solution with the start
        # geometry (seed 000's method needs a start close enough): such rows are left out
        um, Lc = self.split(self.parameters.values)
        P, R = self.start_poses(None) if start is None else start
        self._keep_solved_rows(solve_sphere_poses(machine, um, data.q, Lc, data.passive,
                                                  start=(P, R)))

    def evaluate(self, state, jacobian=True):
        """Passive-reading residuals with the poses solved from the active readings and the link.

        Parameters
        ----------
        state : SphereState
            Global values; its poses are the warm start and are updated in place.
        jacobian : bool, optional
            Also compute the Jacobian.

        Returns
        -------
        r : ndarray, shape (K, 1)
            Whitened passive-reading residuals; NaN where the pose solve failed.
        J_g : ndarray, shape (K, 1, n_machine + 1) or None
            Total derivatives with respect to the global parameters.
        J_l : None
            No local unknowns.
        """
        fk = self._poses(state, constrained=True)
        um, Lc = self.split(state.u)
        K = len(self.data)
        rows = np.arange(K)
        p = self.data.passive
        q, Jx, Ju = self.machine.ik_jacobians(fk.P, fk.R, um, want_du=jacobian)
        sig = self.sigma[p]
        r = ((q[rows, p] - self.data.q[rows, p]) / sig)[:, None]
        r = np.where(fk.converged[:, None], r, np.nan)
        if not jacobian:
            return r, None, None
        # loop equations F(x, u) = [IK_active(x, u) - q_active; |P| - Lc] = 0 (square, 6x6)
        Fx = Jx.copy()
        norm = np.linalg.norm(fk.P, axis=-1)
        Fx[rows, p] = np.concatenate([fk.P / norm[:, None], np.zeros((K, 3))], -1)
        Fu = np.concatenate([Ju, np.zeros((K, 6, 1))], -1)
        Fu[rows, p] = 0.0
        Fu[rows, p, -1] = -1.0
        dx_du = -np.linalg.solve(Fx, Fu)                                   # (K, 6, n)
        Jp = np.concatenate([Ju[rows, p], np.zeros((K, 1))], -1)
        Jg = (Jp + np.einsum("ki,kin->kn", Jx[rows, p], dx_du)) / sig[:, None]
        return r, Jg[:, None, :], None


class ConstraintLinkFK(_ImplicitPoseProblem):
    """The paper's forward-kinematics method: residual = ``|FK(q)| - Lc``, ``Lc`` estimated.

    Rows whose forward kinematics the start geometry cannot solve are left out and listed in
    ``dropped_rows``.

    Parameters
    ----------
    machine : Machine
        Start geometry (a Hexa Slide).
    data : ConstraintLinkData
        Readings taken with the link mounted.
    sigma_m : float or array_like, optional
        Encoder noise standard deviation, m; the residuals are divided by its mean.
    estimate_link_length : bool, optional
        Estimate ``Lc`` too (default True: the method needs it).
    start : SphereState, optional
        Start values of the global unknowns and poses near the solution (the ml estimate's);
        default: the machine's values and the poses solved for them.

    Raises
    ------
    InputError
        When the joint columns do not match the machine, start poses cannot be found, or no row
        can be solved.
    """

    estimates_link_length = True

    def __init__(self, machine, data, sigma_m=1e-6, estimate_link_length=True, start=None):
        super().__init__(machine, data, sigma_m, estimate_link_length)
        if start is not None:           # a state near the solution (the ml estimate's)
            self._u0 = np.asarray(start.u, float).copy()
        um, _ = self.split(self.parameters.values if self._u0 is None else self._u0)
        poses = self.start_poses(None) if start is None else (start.P, start.R)
        self._keep_solved_rows(machine.fk(data.q, um, start=poses))

    def evaluate(self, state, jacobian=True):
        """Link-length residuals ``|FK(q)| - Lc`` of the forward kinematics of all six readings.

        Parameters
        ----------
        state : SphereState
            Global values; its poses are the warm start and are updated in place.
        jacobian : bool, optional
            Also compute the Jacobian.

        Returns
        -------
        r : ndarray, shape (K, 1)
            Residuals divided by the mean encoder noise; NaN where the forward kinematics failed.
        J_g : ndarray, shape (K, 1, n_machine + 1) or None
            Total derivatives with respect to the global parameters.
        J_l : None
            No local unknowns.
        """
        fk = self._poses(state, constrained=False)
        um, Lc = self.split(state.u)
        K = len(self.data)
        norm = np.linalg.norm(fk.P, axis=-1)
        sig = float(np.mean(self.sigma))
        r = ((norm - Lc) / sig)[:, None]
        r = np.where(fk.converged[:, None], r, np.nan)
        if not jacobian:
            return r, None, None
        _, Jx, Ju = self.machine.ik_jacobians(fk.P, fk.R, um)
        dx_du = -np.linalg.solve(Jx, Ju)                                   # (K, 6, n_m)
        n = fk.P / norm[:, None]
        dnorm = np.einsum("ki,kin->kn", n, dx_du[:, :3])
        Jg = np.concatenate([dnorm, -np.ones((K, 1))], -1) / sig
        return r, Jg[:, None, :], None


PROBLEMS = {"ml": ConstraintLinkML, "ik": ConstraintLinkIK, "fk": ConstraintLinkFK}
