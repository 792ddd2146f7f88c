"""One calibration problem for every instrument model on every machine.

Readings are taken as exact (the instrument's noise dominates, as with a laser tracker or a
ballbar on encoders of a micrometre): the platform pose of each row is the machine's forward
kinematics ``x_k = FK(q_k; u)``, and the residual is the instrument's,
``W_k e_k(x_k, v)``, whitened by its noise. Derivatives with respect to the machine's
parameters go through the implicit function theorem, ``dx/du = -(dq/dx)^-1 dq/du``, so any
:class:`~pkmcal.machines.Machine` with analytic inverse-kinematics Jacobians serves. Global
unknowns: the machine's parameters followed by the model's nuisance parameters; no per-row
unknowns. The problem plugs into the shared estimator
(:func:`~pkmcal.estimation.estimator.levenberg_marquardt`).

Identifiability in words (:meth:`InstrumentProblem.null_groups`): the machine names the frame
motions it can represent (:meth:`~pkmcal.machines.Machine.frame_motions`: a rigid motion of
the base frame, of the platform frame, combinations only a sum of which enters); each one whose
effect the nuisance parameters can undo lies in the null space and is reported with what
absorbs it (``rigid motion of the base frame, absorbed by the tracker frame``). Nothing is
assumed: the groups are found in the numerical null space of the model at the estimate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..estimation.rank import RTOL, numerical_rank
from ..identifiability import NullGroup, name_null_space, name_weak_directions
from ..machines.base import Machine
from ..paths import path_text
from .data import InstrumentData
from .models import NuisanceModel, NuisanceState


@dataclass
class InstrumentState:
    """Estimator state: machine parameters, nuisance state and the poses last solved.

    Attributes
    ----------
    u : ndarray
        Machine parameters.
    nuisance : NuisanceState
        Instrument unknowns.
    P, R : ndarray
        Platform poses of the rows (warm start of the forward kinematics).
    converged : ndarray of bool, optional
        Rows whose forward kinematics converged at the last evaluation.
    dq : ndarray, shape (n_joints,), optional
        Offsets added to every reading of the rows (a session's own endstop triggers, shared
        by the files of one session: :class:`~pkmcal.instruments.joint.JointProblem`); None:
        none.
    """

    u: np.ndarray
    nuisance: NuisanceState
    P: np.ndarray
    R: np.ndarray
    converged: np.ndarray = field(default=None)  # type: ignore[assignment]
    dq: np.ndarray | None = None


class InstrumentProblem:
    """Block problem (no local unknowns) of an instrument model on a machine.

    Parameters
    ----------
    machine : Machine
        Start geometry; its fixed flags are kept.
    data : InstrumentData
        Readings and measurements.
    model : NuisanceModel
        The instrument's model with its start values (:meth:`NuisanceModel.start`).
    noise : object
        Has ``whitening(measured) -> (K, size, size)``; None: unit weights.
    fit_machine : bool, optional
        False holds every machine parameter (fits the instrument's unknowns alone).

    Raises
    ------
    InputError
        When the readings do not match the machine's joints or the start geometry's forward
        kinematics cannot reproduce some rows.
    """

    local_dof = 0
    #: sets of joint readings per row, side by side in ``data.q`` (two-point distances: 2);
    #: the poses of the rows' first sets come first, then the second sets' ...
    readings_per_row = 1
    #: :meth:`evaluate` appends the derivatives with respect to the state's reading offsets
    #: (``dq``, one per joint) after the nuisance's (set by a joint problem for the files of a
    #: session with its own offsets)
    reading_offsets = False

    def __init__(self, machine: Machine, data: InstrumentData, model: NuisanceModel, noise,
                 fit_machine: bool = True):
        m = self.readings_per_row
        if data.q.shape[1] != m * machine.n_joints:
            raise InputError(f"{path_text(data.source)}: "
                             f"{data.q.shape[1]} joint columns, the machine has "
                             f"{machine.n_joints} joints"
                             + (f" ({m} sets of them a row)" if m > 1 else ""))
        self.machine, self.data, self.model, self.noise = machine, data, model, noise
        mp = machine.parameters if fit_machine else machine.parameters.with_fixed(
            list(machine.parameters.names))
        self.parameters = mp.concat(model.parameters)
        self.scales = machine.scales_with(model.parameters)
        self.n_machine = len(mp)
        self.fit_machine = fit_machine
        K, s = len(data), model.size
        self.W = (np.broadcast_to(np.eye(s), (K, s, s)) if noise is None
                  else np.asarray(noise.whitening(data.values), float))
        fk = machine.fk(self._stacked(data.q))
        ok = self._rows_ok(fk.converged)
        if not ok.all():
            rows = data.rows[~ok]
            shown = ", ".join(map(str, rows[:10].tolist())) + (" ..." if len(rows) > 10 else "")
            raise InputError(f"{path_text(data.source)}: "
                             "no platform pose of the machine reproduces the "
                             f"readings of {len(rows)} row(s): {shown} (outside the workspace, "
                             "or a wrong joint unit)")
        self._P0, self._R0 = fk.P, fk.R
        #: forward kinematics converge to 1e-12 of the characteristic length: residuals are
        #: no more precise than that, in units of the noise
        self.cost_floor = 0.0

    def _stacked(self, q) -> np.ndarray:
        """Readings of every pose: each row's sets one below the other (first sets first)."""
        q = np.atleast_2d(np.asarray(q, float))
        n = self.machine.n_joints
        return np.concatenate([q[:, i * n:(i + 1) * n] for i in range(self.readings_per_row)])

    def _rows_ok(self, converged) -> np.ndarray:
        """Per row: every one of its poses solved."""
        return np.asarray(converged, bool).reshape(self.readings_per_row, -1).all(axis=0)

    def with_machine_fixed(self) -> InstrumentProblem:
        """A copy that holds every machine parameter (fits the instrument's unknowns alone).

        Returns
        -------
        InstrumentProblem
            A shallow copy with the machine's parameters fixed.
        """
        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        mp = self.machine.parameters.with_fixed(list(self.machine.parameters.names))
        new.parameters = mp.concat(self.model.parameters)
        new.fit_machine = False
        return new

    # -- state ----------------------------------------------------------------------------
    def initial_state(self) -> InstrumentState:
        """Start state: the machine's parameters, the model's start values and the poses.

        Returns
        -------
        InstrumentState
            The state.
        """
        return InstrumentState(self.machine.u.copy(), self.model.initial(), self._P0.copy(),
                               self._R0.copy())

    def global_values(self, state) -> np.ndarray:
        """Machine parameters followed by the nuisance values.

        Parameters
        ----------
        state : InstrumentState
            An estimator state.

        Returns
        -------
        ndarray, shape (n_machine + n_nuisance,)
            Values, internal units.
        """
        return np.concatenate([state.u, state.nuisance.values])

    def retract(self, state, du, dl):
        """The state after a global step.

        Parameters
        ----------
        state : InstrumentState
            Current state.
        du : ndarray, shape (n,)
            Global step.
        dl : None
            Unused (no local unknowns).

        Returns
        -------
        InstrumentState
            The new state (poses kept as the next forward kinematics' start).
        """
        n = self.n_machine
        return InstrumentState(state.u + du[:n], self.model.retract(state.nuisance, du[n:]),
                               state.P, state.R)

    def poses(self, state, q=None):
        """Platform poses of readings under the state's geometry (forward kinematics).

        Parameters
        ----------
        state : InstrumentState
            The state.
        q : array_like, shape (K, n_joints), optional
            Readings; default the data's (warm-started from the state's poses).

        Returns
        -------
        FKResult
            Poses and convergence.
        """
        if q is None:
            # warm start from the state's poses (another problem's state, e.g. of a subset of
            # the rows, starts from this problem's own)
            same = np.shape(state.P) == self._P0.shape
            start = (state.P, state.R) if same else (self._P0, self._R0)
            return self.machine.fk(self._shifted(self.data.q, state), state.u, start=start)
        return self.machine.fk(self._shifted(q, state), state.u)

    def _shifted(self, q, state) -> np.ndarray:
        """The stacked readings plus the state's reading offsets (when it has any)."""
        q = self._stacked(q)
        dq = getattr(state, "dq", None)
        return q if dq is None else q + np.asarray(dq, float)[None]

    def evaluate(self, state, jacobian=True):
        """Whitened residuals and their Jacobian (see :class:`BlockProblem`).

        Parameters
        ----------
        state : InstrumentState
            The state.
        jacobian : bool, optional
            Also compute the Jacobian.

        Returns
        -------
        r : ndarray, shape (K, size)
            ``W_k e_k``; NaN where the forward kinematics failed.
        J_g : ndarray, shape (K, size, n) or None
            Derivatives with respect to the global parameters.
        J_l : None
            No local unknowns.
        """
        fk = self.poses(state)
        solved = fk.converged
        if np.shape(state.P) == fk.P.shape:
            state.P = np.where(solved[:, None], fk.P, state.P)     # the next evaluation's start
            state.R = np.where(solved[:, None, None], fk.R, state.R)
        P = np.where(solved[:, None], fk.P, self._P0)
        R = np.where(solved[:, None, None], fk.R, self._R0)
        ok = self._rows_ok(solved)
        e, de_dx, de_dv = self.model.residuals(state.nuisance, P, R, self.data.values,
                                               self.data.group, jacobian)
        r = np.einsum("kij,kj->ki", self.W, e)
        r = np.where(ok[:, None], r, np.nan)
        if not jacobian:
            return r, None, None
        d = self._through_fk(state.u, P, R, de_dx)
        de_du = d.reshape(self.readings_per_row, len(ok), *d.shape[1:]).sum(axis=0)
        J = np.concatenate([de_du, de_dv], -1)
        if self.reading_offsets:
            d = self._through_readings(state.u, P, R, de_dx)
            J = np.concatenate([J, d.reshape(self.readings_per_row, len(ok),
                                             *d.shape[1:]).sum(axis=0)], -1)
        return r, np.einsum("kij,kjn->kin", self.W, J), None

    def noise_groups(self):
        """Noise groups of the whitened residuals (the noise model's ``groups``), one
        measurement per row; None without a noise model that has groups.

        Returns
        -------
        NoiseGroups or None
            See :class:`~pkmcal.estimation.variance.NoiseGroups`.
        """
        from ..estimation.variance import NoiseGroups, row_names

        groups = getattr(self.noise, "groups", None)
        if not callable(groups):
            return None
        labels, keys, names, assumed, kinds = groups(self.data.values)
        if keys == ["noise"]:       # the noise model does not know what it weighs
            keys = [self.model.kind]
            names = [getattr(self.model, "quantity", self.model.kind)]
        K, s = np.shape(labels)
        return NoiseGroups(np.asarray(labels, int), list(keys), list(names),
                           np.asarray(assumed, float), list(kinds),
                           np.repeat(np.arange(K), s).reshape(K, s),
                           row_names(self.data.rows, K))

    def _through_fk(self, u, P, R, de_dx):
        """``de/du = de/dx dx/du`` with ``dx/du = -(dq/dx)^-1 dq/du`` (implicit function)."""
        _, Jx, Ju = self.machine.ik_jacobians(P, R, u)
        cols = list(self.machine.pose_space)
        with np.errstate(all="ignore"):
            dx_du = -np.linalg.solve(np.asarray(Jx)[..., cols], Ju)      # (K, d, n_machine)
        return np.einsum("kid,kdn->kin", de_dx[..., cols], dx_du)

    def _through_readings(self, u, P, R, de_dx):
        """``de/d(dq) = de/dx dx/dq`` with ``dx/dq = (dq/dx)^-1``: a reading offset ``dq`` puts
        the joints at ``q + dq`` (forward kinematics of the shifted readings)."""
        _, Jx, _ = self.machine.ik_jacobians(P, R, u, want_du=False)
        cols = list(self.machine.pose_space)
        with np.errstate(all="ignore"):
            dx_dq = np.linalg.inv(np.asarray(Jx)[..., cols])          # (K, d, n_joints)
        return np.einsum("kid,kdn->kin", de_dx[..., cols], dx_dq)

    # -- predictions ----------------------------------------------------------------------
    def predict(self, state, q, group=None):
        """What the instrument measures for readings under a state's geometry.

        Parameters
        ----------
        state : InstrumentState
            The state (geometry and nuisance).
        q : array_like, shape (K, n_joints)
            Readings, internal units.
        group : array_like of int, shape (K,), optional
            0-based target / setup of each row; default 0.

        Returns
        -------
        ndarray, shape (K, size)
            Predicted measurements, SI units; NaN where the forward kinematics failed.
        """
        fk = self.poses(state, q)
        ok = self._rows_ok(fk.converged)
        group = np.zeros(len(ok), int) if group is None else np.asarray(group, int)
        y = self.model.predict(state.nuisance, fk.P, fk.R, group)
        return np.where(ok[:, None], y, np.nan)

    # -- words ----------------------------------------------------------------------------
    def null_space(self, state, rtol: float = RTOL) -> np.ndarray:
        """The model's numerical null space at ``state`` (scaled coordinates, fixed = 0).

        Parameters
        ----------
        state : InstrumentState
            The state to linearise at.
        rtol : float, optional
            Relative singular-value tolerance (the one rank rule).

        Returns
        -------
        ndarray, shape (n, k)
            Orthonormal unidentifiable directions.
        """
        return problem_null_space(self, state, rtol)

    def null_groups(self, state, scales, null_space=None):
        """The machine's frame motions that the data cannot see, with what absorbs them.

        Parameters
        ----------
        state : InstrumentState
            The state to linearise at.
        scales : ndarray, shape (n,)
            Column scales; the groups are returned in scaled coordinates.
        null_space : ndarray, shape (n, k), optional
            The null space when already known (an estimator result's); default: computed.

        Returns
        -------
        list of NullGroup
            One group per frame motion with directions in the null space.
        """
        N = self.null_space(state) if null_space is None else np.asarray(null_space, float)
        return frame_motion_groups(self.machine, state.u, self.parameters, self.n_machine,
                                   scales, N, self.model.words)


def instrument_problem(machine: Machine, data: InstrumentData, model: NuisanceModel, noise,
                       fit_machine: bool = True) -> InstrumentProblem:
    """The instrument problem of a model on a machine: the model's own problem class (an
    instrument whose rows need more than one pose, :mod:`pkmcal.instruments.pairs`) or
    :class:`InstrumentProblem`.

    Parameters
    ----------
    machine, data, model, noise, fit_machine
        As :class:`InstrumentProblem`.

    Returns
    -------
    InstrumentProblem
        The problem.
    """
    cls = getattr(model, "problem_class", None) or InstrumentProblem
    return cls(machine, data, model, noise, fit_machine=fit_machine)


def problem_null_space(problem, state, rtol: float = RTOL) -> np.ndarray:
    """Numerical null space of any block problem at ``state`` (local unknowns eliminated).

    Parameters
    ----------
    problem : BlockProblem
        The problem (``evaluate``, ``parameters``, ``scales``).
    state : object
        The state to linearise at.
    rtol : float, optional
        Relative singular-value tolerance (the one rank rule).

    Returns
    -------
    ndarray, shape (n, k)
        Orthonormal unidentifiable directions in scaled coordinates (fixed parameters 0).
    """
    from ..estimation.estimator import reduce_local

    r, Jg, Jl = problem.evaluate(state)
    free = problem.parameters.free
    ok = np.all(np.isfinite(r), axis=-1)
    Jr, _, _ = reduce_local(r[ok], Jg[ok][..., free] * problem.scales[free],
                            None if Jl is None else Jl[ok])
    _, s, Vt = np.linalg.svd(Jr, full_matrices=Jr.shape[0] < Jr.shape[1])  # all of Vt
    rank = numerical_rank(s, rtol)
    N = np.zeros((len(free), Vt.shape[0] - rank))
    N[free] = Vt[rank:].T
    return N


def frame_motion_groups(machine, u, parameters, n_machine, scales, N, words) -> list[NullGroup]:
    """Groups of null directions explained by the machine's frame motions (module docstring).

    Parameters
    ----------
    machine : Machine
        The machine (:meth:`~pkmcal.machines.Machine.frame_motions`).
    u : ndarray
        Machine parameters to linearise at.
    parameters : ParameterSet
        All the problem's parameters (machine's first).
    n_machine : int
        Number of machine parameters.
    scales : ndarray, shape (n,)
        Column scales.
    N : ndarray, shape (n, k)
        Null space, scaled coordinates.
    words : dict
        Nuisance prefix -> what it is in words.

    Returns
    -------
    list of NullGroup
        Groups whose tangents are null directions (scaled), each with its absorbers named.
    """
    groups = []
    if N.shape[1] == 0:
        return groups
    Nm = N[:n_machine]
    U, s, Vt = np.linalg.svd(Nm, full_matrices=True)
    keep = s > 1e-6
    Qn = U[:, :len(s)][:, keep]                       # machine parts of the null directions
    # null directions of the instrument's unknowns alone (no machine part): a frame motion's
    # lift is taken free of them, so only what must move with it is named as absorbing it
    Z = N @ Vt[int(keep.sum()):].T
    for motion in machine.frame_motions(u):
        T = np.asarray(motion.tangents, float) / scales[:n_machine, None]
        T = T[:, np.linalg.norm(T, axis=0) > 0]
        if T.shape[1] == 0 or Qn.shape[1] == 0:
            continue
        Qt, _ = np.linalg.qr(T)
        Ua, cos, _ = np.linalg.svd(Qt.T @ Qn, full_matrices=False)
        inside = Qt @ Ua[:, cos > 1 - 1e-6]           # machine directions in the projection
        if inside.shape[1] == 0:
            continue
        Y = np.linalg.lstsq(Nm, inside, rcond=None)[0]
        tangents = N @ Y
        tangents = tangents - Z @ (Z.T @ tangents)
        absorbers = _absorbers(tangents, parameters, n_machine, words)
        text = motion.description + (f"; absorbed by {absorbers}" if absorbers else
                                     "; no measurement sees it")
        groups.append(NullGroup(motion.name, text, tangents))
    if Z.shape[1]:
        groups.append(NullGroup(
            "instrument unknowns alone",
            f"{_absorbers(Z, parameters, n_machine, words)} can move together without "
            "changing a measurement (the machine's parameters stay); they are fixed only in "
            "the combination the measurements see", Z))
    return groups


def _absorbers(tangents, parameters, n_machine, words) -> str:
    """The nuisance parameters that move with null directions, in words, grouped by what they
    are (``the ballbar's pivot on the base (setup1.pivot, setup2.pivot)``)."""
    size = np.linalg.norm(tangents, axis=1)
    if not size.size or size.max() == 0:
        return ""
    names = [n for n, v in zip(parameters.names[n_machine:], size[n_machine:], strict=True)
             if v > 1e-6 * size.max()]
    groups: dict[str, list[str]] = {}
    for name in names:
        head = name.rsplit(".", 1)[0]
        key = next((k for k in words if k in head.split(".") or head.startswith(k)), None)
        label = words[key] if key is not None else head
        if head not in groups.setdefault(label, []):
            groups[label].append(head)
    # "the tracker frame", not "the tracker frame (tracker)": a head that is the word's own
    # key says nothing more
    return ", ".join(label if len(heads) == 1 and heads[0] in words
                     else f"{label} ({', '.join(heads)})" for label, heads in groups.items())


def fit_instrument(machine: Machine, data: InstrumentData, model: NuisanceModel, noise,
                   fit_machine: bool = True, rtol: float = RTOL, estimate_noise=True,
                   robust: bool = False, **options):
    """Fit an instrument model to data: start values, the instrument alone, then everything.

    The start values come from the model's closed form on the start geometry's poses
    (:meth:`NuisanceModel.start`); the instrument's unknowns are then fitted with the machine
    held, and finally (``fit_machine``) the machine's parameters join them.

    Parameters
    ----------
    machine : Machine
        Start geometry; not modified.
    data : InstrumentData
        Readings and measurements.
    model : NuisanceModel
        The instrument's model (start values are computed).
    noise : object
        Whitening (``whitening(measured)``); None: unit weights.
    fit_machine : bool, optional
        False fits the instrument alone (the "before calibration" baseline).
    rtol : float, optional
        Rank tolerance.
    estimate_noise : bool or collection of str, optional
        Estimate the noise levels from the residuals (``noise`` their prior;
        :func:`~pkmcal.estimation.variance.fit`); False holds ``noise``.
    robust : bool, optional
        Leave out the rows the outlier test names.
    **options
        Passed to :func:`~pkmcal.estimation.estimator.levenberg_marquardt` (``max_std``
        defaults to :data:`~pkmcal.estimation.rank.MAX_STD`).

    Returns
    -------
    CalibrationResult
        With ``problem``, ``machine`` (calibrated), ``model`` (at the estimate),
        ``start_model``, ``unidentifiable`` (named null and weak directions); ``noise``,
        ``outliers`` (:func:`~pkmcal.estimation.variance.fit`).

    Raises
    ------
    InputError
        When the start geometry cannot reproduce the readings, or the data cannot register the
        instrument.
    """
    from ..estimation.estimator import MAX_STD, levenberg_marquardt
    from ..estimation.variance import fit

    options = {"max_std": MAX_STD, **options}
    check = instrument_problem(machine, data, model, noise)      # raises, naming the rows
    start = model.start(check._P0, check._R0, data.values, data.group, data.source)
    alone = instrument_problem(machine, data, start, noise, fit_machine=False)
    first = levenberg_marquardt(alone, rtol=rtol, **options)
    start = start.with_start(first.state.nuisance)
    if not fit_machine:
        result, problem = first, alone
    else:
        problem = instrument_problem(machine, data, start, noise)
        result = fit(problem, estimate_noise, robust=robust, rtol=rtol, **options)
    rows = np.column_stack([data.q, data.values, data.group])
    distinct = len(np.unique(rows[np.all(np.isfinite(rows), axis=1)], axis=0))
    if distinct * model.size <= result.rank:
        # no equation left to check the fit: it would be exact whatever the noise, and its
        # covariance meaningless (copies of one row add no information)
        rows_text = (f"{len(data)} rows but {distinct} distinct" if distinct < len(data)
                     else f"{len(data)} rows")
        raise InputError(f"{path_text(data.source)}: "
                         f"{rows_text}: {distinct * model.size} equation(s) "
                         f"for the {result.rank} direction(s) they would have to fix, with "
                         "nothing left to check them; measure more"
                         + (" distinct" if distinct < len(data) else "") + " poses")
    state = result.state
    calibrated = machine.with_parameters(state.u)
    fitted = start.with_start(state.nuisance)
    groups = problem.null_groups(state, result.scales, result.null_space)
    result.problem, result.machine = problem, calibrated
    result.model, result.start_model = fitted, start
    result.unidentifiable = (name_null_space(result.null_space, problem.parameters, groups)
                             + name_weak_directions(result, problem.parameters))
    return result
