"""Measurement models of instruments, written once against any :class:`~pkmcal.machines.Machine`.

An instrument measures something of the platform pose ``(P, R)`` through its own unknowns
(*nuisance parameters*: the instrument's frame, the target's place on the platform, a pivot):
``y = h(P, R; v)``. A model gives the residual ``e = y_measured - h`` of every row and its
derivatives with respect to the pose (``[dP, dOmega]``, rotations on the left, as the machines'
Jacobians) and to ``v``. The machine, the estimator and the CLI never look inside: adding an
instrument is adding a model here.

Rotations among the nuisance parameters (``tracker.rx/ry/rz``) are increments about the base
axes applied on the left of their start value; derivatives are taken at the current value (the
estimator's retraction, :class:`NuisanceState`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from ..kinematics import matrix_from_rotvec, rotvec_from_matrix, skew
from ..parameters import ParameterSet
from ..paths import path_text

XYZ = ("x", "y", "z")
ROT = ("rx", "ry", "rz")


@dataclass
class NuisanceState:
    """Current nuisance values: the vector, and the rotation matrix of every rotation triple.

    Attributes
    ----------
    values : ndarray, shape (n,)
        Values; a rotation triple holds ``rotvec(R R0^T)``, the increment from its start.
    rotations : list of ndarray
        Current rotation matrix (3, 3) of each triple, in :attr:`NuisanceModel.rotation_slots`
        order.
    """

    values: np.ndarray
    rotations: list = field(default_factory=list)


class NuisanceModel(ABC):
    """A measurement model with nuisance parameters (see the module docstring).

    Subclasses set :attr:`kind`, :attr:`size`, build :attr:`parameters` and implement
    :meth:`residuals` and :meth:`start`.

    Parameters
    ----------
    parameters : ParameterSet
        The instrument's unknowns (names, kinds, start values, fixed flags).
    rotation_starts : sequence of ndarray, shape (3, 3), optional
        Start orientations of its rotation parameters (default the identity each).
    """

    #: measurement kind as users name it (``points``, ``poses``, ``distances``)
    kind: str = ""
    #: measured components per row
    size: int = 0
    #: in words, what each nuisance prefix stands for (for identifiability reports)
    words: dict = {}

    def __init__(self, parameters: ParameterSet, rotation_starts=()):
        self.parameters = parameters
        #: index of the first entry of each rotation triple
        self.rotation_slots = [parameters.index(name) for name in parameters.names
                               if name.endswith(".rx")]
        starts = list(rotation_starts) or [np.eye(3)] * len(self.rotation_slots)
        self.rotation_starts = [np.asarray(R, float) for R in starts]

    def initial(self) -> NuisanceState:
        """The start state (rotations at their start values).

        Returns
        -------
        NuisanceState
            Values and rotation matrices.
        """
        return NuisanceState(np.array(self.parameters.values, float),
                             [R.copy() for R in self.rotation_starts])

    def retract(self, state: NuisanceState, step) -> NuisanceState:
        """The state after a step (rotation triples on the left, the rest added).

        Parameters
        ----------
        state : NuisanceState
            Current state.
        step : array_like, shape (n,)
            The step.

        Returns
        -------
        NuisanceState
            The new state.
        """
        step = np.asarray(step, float)
        values = state.values + step
        rotations = []
        for i, R0, R in zip(self.rotation_slots, self.rotation_starts, state.rotations,
                            strict=True):
            Rn = matrix_from_rotvec(step[i:i + 3]) @ R
            rotations.append(Rn)
            values[i:i + 3] = rotvec_from_matrix(Rn @ R0.T)
        return NuisanceState(values, rotations)

    def with_start(self, state: NuisanceState) -> NuisanceModel:
        """A copy of this model whose start values are ``state`` (rotations re-based).

        Parameters
        ----------
        state : NuisanceState
            The new start.

        Returns
        -------
        NuisanceModel
            A shallow copy; its parameters hold the new values (rotation increments 0).
        """
        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        values = np.array(state.values, float)
        for i in self.rotation_slots:
            values[i:i + 3] = 0.0
        new.parameters = self.parameters.with_values(values)
        new.rotation_starts = [np.array(R, float) for R in state.rotations]
        return new

    #: the unknown that takes up a constant offset of every measurement of a data set (a
    #: probe's trigger height, a mesh's reference); None: the instrument has none to free
    offset_parameter: str | None = None

    def with_free_offset(self) -> NuisanceModel:
        """A copy whose :attr:`offset_parameter` is free (one free offset per data set, as
        another session's data are scored: :func:`pkmcal.calibration.check.check`); itself
        when it has none.

        Returns
        -------
        NuisanceModel
            The model.
        """
        if self.offset_parameter is None \
                or self.offset_parameter not in self.parameters.names:
            return self
        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        new.parameters = self.parameters.with_fixed([self.offset_parameter], False)
        return new

    def rotation(self, state: NuisanceState, prefix: str) -> np.ndarray:
        """Current rotation of the triple ``prefix.rx/ry/rz``.

        Parameters
        ----------
        state : NuisanceState
            The state.
        prefix : str
            The triple's prefix, e.g. ``"tracker"``.

        Returns
        -------
        ndarray, shape (3, 3)
            The rotation matrix.
        """
        return state.rotations[self.rotation_slots.index(self.parameters.index(prefix + ".rx"))]

    def vector(self, state: NuisanceState, prefix: str) -> np.ndarray:
        """Current value of the vector ``prefix.x/y/z``.

        Parameters
        ----------
        state : NuisanceState
            The state.
        prefix : str
            The vector's prefix, e.g. ``"target1"``.

        Returns
        -------
        ndarray, shape (3,)
            The value.
        """
        i = self.parameters.index(prefix + ".x")
        return state.values[i:i + 3]

    @abstractmethod
    def residuals(self, state: NuisanceState, P, R, measured, group, jacobian: bool = True):
        """Residuals ``measured - h(P, R; v)`` and their derivatives.

        Parameters
        ----------
        state : NuisanceState
            Nuisance values.
        P : ndarray, shape (K, 3)
            Platform positions, m.
        R : ndarray, shape (K, 3, 3)
            Platform orientations.
        measured : ndarray, shape (K, size)
            The measured values.
        group : ndarray of int, shape (K,)
            0-based target / setup of each row.
        jacobian : bool, optional
            Also return the derivatives.

        Returns
        -------
        e : ndarray, shape (K, size)
            Residuals (unwhitened, SI units).
        de_dpose : ndarray, shape (K, size, 6) or None
            Derivatives with respect to ``[dP, dOmega]``.
        de_dv : ndarray, shape (K, size, n) or None
            Derivatives with respect to the nuisance step (rotations on the left).
        """

    def predict(self, state: NuisanceState, P, R, group) -> np.ndarray:
        """What the instrument measures at poses ``(P, R)``.

        Parameters
        ----------
        state : NuisanceState
            Nuisance values.
        P : ndarray, shape (K, 3)
            Platform positions, m.
        R : ndarray, shape (K, 3, 3)
            Platform orientations.
        group : ndarray of int, shape (K,)
            0-based target / setup of each row.

        Returns
        -------
        ndarray, shape (K, size)
            Predicted measurements, SI units.
        """
        zero = np.zeros((len(P), self.size))
        return -self.residuals(state, P, R, zero, group, jacobian=False)[0]

    def joint_section(self, nuisance, machine, calibrated, source: str, fl: float,
                      units: dict, frame: str, taken: dict) -> tuple[dict, str | None]:
        """This file's instrument unknowns in a joint fit's report, and the set-up they give
        the calibrated machine file (put in ``taken["setups"]`` under the instrument's name,
        as the arguments of its set-up type,
        :attr:`~pkmcal.instruments.base.Instrument.Setup`).

        Parameters
        ----------
        nuisance : NuisanceState
            The fitted unknowns of this file.
        machine : Machine
            The nominal machine.
        calibrated : Machine
            The calibrated machine.
        source : str
            The data file.
        fl : float
            Metres per unit of the file's lengths.
        units : dict
            The machine file's units.
        frame : str
            The file's frame in words (a printer's bed).
        taken : dict
            Shared among the files of the fit: what earlier files already set;
            ``taken["setups"]`` (a dict) the set-ups fitted so far by instrument name (the
            arguments of its set-up type), ``taken["given"]`` (a
            :class:`~pkmcal.instruments.setups.Setups`) the experiment's set-ups as given.

        Returns
        -------
        entry : dict
            Keys added to the file's entry of the report.
        words : str or None
            The instrument section it set, in words (None: none).
        """
        return {}, None

    @abstractmethod
    def start(self, P, R, measured, group, source: str = "<data>") -> NuisanceModel:
        """A copy of this model with start values from poses of the start geometry.

        Parameters
        ----------
        P : ndarray, shape (K, 3)
            Platform positions of the readings under the start geometry, m.
        R : ndarray, shape (K, 3, 3)
            Their orientations.
        measured : ndarray, shape (K, size)
            The measured values.
        group : ndarray of int, shape (K,)
            0-based target / setup of each row.
        source : str, optional
            File name for messages.

        Returns
        -------
        NuisanceModel
            The model with closed-form start values (refined by the estimator).
        """


def _vector_parameters(prefixes, kind: str = "length", fixed=()) -> ParameterSet:
    names = [f"{p}.{c}" for p in prefixes for c in XYZ]
    fixed_set = set(fixed)
    return ParameterSet(names, [kind] * len(names), np.zeros(len(names)),
                        fixed=[n.split(".")[0] in fixed_set or n.rsplit(".", 1)[0] in fixed_set
                               for n in names])


class PointsModel(NuisanceModel):
    """A point target on the platform measured in the instrument frame (laser tracker, CMM).

    ``m = A^T (P + R c_g - a)`` with ``(A, a)`` = base_from_tracker (``tracker.rx..z``: A as
    increments on the left of the start, ``tracker.x/y/z``: a) and ``c_g`` the place of target
    ``g`` in the platform frame (``target<g>.x/y/z``), estimated unless given.

    Parameters
    ----------
    n_targets : int, optional
        Number of targets (column ``target``).
    known_target : array_like, shape (3,), optional
        The target's place on the platform when the machine file gives it (all targets);
        held fixed.
    fix_frame : bool, optional
        Hold the tracker frame at its start (seed 001's two-step method).
    """

    kind = "points"
    #: what its measurements are, in words (noise groups, outlier rows)
    quantity = "tracker points"
    size = 3
    words = {"tracker": "the tracker frame", "target": "the target's place on the platform"}

    def __init__(self, n_targets: int = 1, known_target=None, fix_frame: bool = False):
        self.n_targets = int(n_targets)
        self.known_target = None if known_target is None else np.asarray(known_target, float)
        frame = ParameterSet([f"tracker.{k}" for k in ROT + XYZ], ["angle"] * 3 + ["length"] * 3,
                             np.zeros(6), fixed=[fix_frame] * 6)
        if self.known_target is None:
            frame = frame.concat(_vector_parameters([f"target{g + 1}"
                                                     for g in range(self.n_targets)]))
        super().__init__(frame)
        self._it = (np.stack([self.parameters.indices(f"target{g + 1}")
                              for g in range(self.n_targets)])
                    if self.known_target is None else None)
        #: tracker-frame centroid of the measured points (residuals are formed about it: the
        #: points lie metres from the tracker and rounding there would limit the precision)
        self.m0 = np.zeros(3)

    def residuals(self, state, P, R, measured, group, jacobian=True):
        A = self.rotation(state, "tracker")
        a = self.vector(state, "tracker")
        c = self.targets(state)[group]                                     # (K, 3)
        Rc = np.einsum("kij,kj->ki", R, c)
        y = P + Rc - (a + A @ self.m0)                                      # no metre terms
        e = (measured - self.m0) - y @ A
        if not jacobian:
            return e, None, None
        K = len(P)
        AT = np.broadcast_to(A.T, (K, 3, 3))
        de_dpose = np.concatenate([-AT, AT @ skew(Rc)], -1)
        n = len(self.parameters)
        de_dv = np.zeros((K, 3, n))
        y_full = P + Rc - a
        de_dv[:, :, 0:3] = -AT @ skew(y_full)                              # A <- exp(w) A
        de_dv[:, :, 3:6] = AT
        if self._it is not None:
            ARt = -AT @ R                                                  # d/dc = -A^T R
            for g in range(self.n_targets):
                rows = np.flatnonzero(group == g)
                de_dv[np.ix_(rows, np.arange(3), self._it[g])] = ARt[rows]
        return e, de_dpose, de_dv

    def targets(self, state) -> np.ndarray:
        """Places of the targets on the platform (n_targets, 3), m.

        Parameters
        ----------
        state : NuisanceState
            The state.

        Returns
        -------
        ndarray, shape (n_targets, 3)
            The machine file's target for each, or the estimated places.
        """
        if self._it is None:
            return np.tile(self.known_target, (self.n_targets, 1))
        return state.values[self._it]

    def joint_section(self, nuisance, machine, calibrated, source, fl, units, frame, taken):
        R = self.rotation(nuisance, "tracker")
        t = np.array(self.vector(nuisance, "tracker"))
        targets = self.targets(nuisance)
        entry = {"registration": {"rotation": R.tolist(), "translation": (t / fl).tolist(),
                                  "unit": units["length"]},
                 "targets": {"given_by_machine_file": machine.tracker_target() is not None,
                             "places": (np.asarray(targets) / fl).tolist(),
                             "unit": units["length"]}}
        if "tracker" in taken:
            return entry, None
        taken["tracker"] = source
        taken.setdefault("setups", {})["tracker"] = (
            (R, t), None if machine.tracker_target() is not None else np.array(targets, float))
        return entry, f"tracker (frame and targets) from {source}"

    def start(self, P, R, measured, group, source="<data>"):
        from ..estimation.registration import register_points

        c = (np.zeros((self.n_targets, 3)) if self.known_target is None
             else np.tile(self.known_target, (self.n_targets, 1)))
        x = P + np.einsum("kij,kj->ki", R, c[group])
        A, a = register_points(measured, x, f"{path_text(source)}: tracker registration")
        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        values = np.array(self.parameters.values, float)
        values[3:6] = a
        if self._it is not None:
            values[self._it.ravel()] = c.ravel()
        new.parameters = self.parameters.with_values(values)
        new.rotation_starts = [A]
        new.m0 = measured.mean(0) if len(measured) else np.zeros(3)
        return new


class DistancesModel(NuisanceModel):
    """A measuring ballbar: the distance between a pivot on the base and a ball on the platform.

    ``d = |P + R b_g - p_g|`` with ``p_g`` (``setup<g>.pivot.x/y/z``, base frame) and ``b_g``
    (``setup<g>.ball.x/y/z``, platform frame) unknown per mounting ``g``.

    Parameters
    ----------
    n_setups : int, optional
        Number of mountings (column ``setup``).
    """

    kind = "distances"
    #: what its measurements are, in words (noise groups, outlier rows)
    quantity = "ballbar lengths"
    size = 1
    words = {"pivot": "the ballbar's pivot on the base", "ball": "the ball on the platform"}

    def __init__(self, n_setups: int = 1):
        self.n_setups = int(n_setups)
        prefixes = [f"setup{g + 1}.{w}" for g in range(self.n_setups) for w in ("pivot", "ball")]
        super().__init__(_vector_parameters(prefixes))
        self._ip = np.stack([self.parameters.indices([f"setup{g + 1}.pivot.{c}" for c in XYZ])
                             for g in range(self.n_setups)])
        self._ib = np.stack([self.parameters.indices([f"setup{g + 1}.ball.{c}" for c in XYZ])
                             for g in range(self.n_setups)])

    def residuals(self, state, P, R, measured, group, jacobian=True):
        p = state.values[self._ip][group]
        b = state.values[self._ib][group]
        Rb = np.einsum("kij,kj->ki", R, b)
        v = P + Rb - p
        d = np.linalg.norm(v, axis=-1)
        e = measured[:, :1] - d[:, None]
        if not jacobian:
            return e, None, None
        nvec = v / np.where(d > 0, d, 1.0)[:, None]
        K = len(P)
        de_dpose = np.concatenate([-nvec, np.einsum("ki,kij->kj", nvec, skew(Rb))],
                                  -1)[:, None, :]
        de_dv = np.zeros((K, 1, len(self.parameters)))
        nR = -np.einsum("ki,kij->kj", nvec, R)
        for g in range(self.n_setups):
            rows = np.flatnonzero(group == g)
            de_dv[rows[:, None], 0, self._ip[g][None, :]] = nvec[rows]
            de_dv[rows[:, None], 0, self._ib[g][None, :]] = nR[rows]
        return e, de_dpose, de_dv

    def joint_section(self, nuisance, machine, calibrated, source, fl, units, frame, taken):
        setups = taken.setdefault("ballbar setups", [])
        mine = [(np.array(nuisance.values[self._ip[g]]), np.array(nuisance.values[self._ib[g]]))
                for g in range(self.n_setups)]
        entry = {"setups": [{"setup": len(setups) + g + 1, "in_file": g + 1,
                             "pivot": (p / fl).tolist(), "ball": (b / fl).tolist(),
                             "unit": units["length"]} for g, (p, b) in enumerate(mine)]}
        words = (f"ballbar setups {len(setups) + 1}..{len(setups) + len(mine)} from {source}")
        setups.extend(mine)
        taken.setdefault("setups", {})["distance"] = (list(setups),)
        return entry, words

    def start(self, P, R, measured, group, source="<data>"):
        values = np.array(self.parameters.values, float)
        for g in range(self.n_setups):
            rows = group == g
            b = values[self._ib[g]]
            x = P[rows] + np.einsum("kij,j->ki", R[rows], b)
            values[self._ip[g]] = sphere_centre(x, measured[rows, 0])
        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        new.parameters = self.parameters.with_values(values)
        return new


def sphere_centre(points, radii) -> np.ndarray:
    """Centre ``p`` with ``|x_k - p| = r_k`` in the least-squares sense (linear, closed form).

    ``|x|^2 - r^2 = 2 x.p - |p|^2`` is linear in ``(p, |p|^2)``. Points on one plane (a
    ballbar circle) leave ``p`` free along the plane's normal in that linear system; the
    condition ``s = |p|^2`` then fixes it (of its two roots the one nearer the plane, the
    pivot of a circle test lying in or near the circle's plane).

    Parameters
    ----------
    points : array_like, shape (K, 3)
        Points, m.
    radii : array_like, shape (K,)
        Their distances from the centre, m.

    Returns
    -------
    ndarray, shape (3,)
        The centre, m (the points' centroid when fewer than 3 points are given).
    """
    x = np.asarray(points, float)
    r = np.asarray(radii, float)
    if len(x) < 3:
        return x.mean(0) if len(x) else np.zeros(3)
    x0 = x.mean(0)
    xc = x - x0                                    # centred: no metre-sized squares
    M = np.column_stack([2 * xc, -np.ones(len(x))])
    rhs = np.sum(xc**2, -1) - r**2
    sol, *_ = np.linalg.lstsq(M, rhs, rcond=1e-10)
    p, s = sol[:3], sol[3]
    _, sv, Vt = np.linalg.svd(xc, full_matrices=True)
    if sv[-1] <= 1e-9 * sv[0]:                     # coplanar: fix the normal component
        n = Vt[-1]
        p = p - (p @ n) * n                        # in-plane part (the plane passes x0)
        h2 = s - p @ p                             # |p + lam n|^2 = s: lam = +-sqrt(h2)
        if h2 > 0:
            p = p + np.sqrt(h2) * n
    return x0 + p


@dataclass(frozen=True)
class IsotropicNoise:
    """Independent noise of one standard deviation on every measured component, SI units.

    Attributes
    ----------
    sigma : float
        Standard deviation (m for points and distances).
    """

    sigma: float = 1e-6

    def whitening(self, measured) -> np.ndarray:
        """Whitening matrices ``I / sigma``.

        Parameters
        ----------
        measured : array_like, shape (K, s)
            Measured values (only their shape is used).

        Returns
        -------
        ndarray, shape (K, s, s)
            One per row.
        """
        K, s = np.shape(measured)
        return np.broadcast_to(np.eye(s) / self.sigma, (K, s, s))

    def groups(self, measured):
        """One noise group for every component (see :meth:`TrackerNoise.groups
        <pkmcal.instruments.tracker.TrackerNoise.groups>`).

        Parameters
        ----------
        measured : array_like, shape (K, s)
            Measured values (only their shape is used).

        Returns
        -------
        labels : ndarray of int, shape (K, s)
            All 0.
        keys, names : list of str
            ``["noise"]``, ``["measurements"]`` (the problem names them by its instrument).
        assumed : ndarray, shape (1,)
            ``sigma``.
        kinds : list of str
            ``["length"]``.
        """
        K, s = np.shape(measured)
        return (np.zeros((K, s), int), ["noise"], ["measurements"], np.array([self.sigma]),
                ["length"])

    def sample(self, measured, rng) -> np.ndarray:
        """Noise to add to measured values.

        Parameters
        ----------
        measured : array_like, shape (K, s)
            Measured values (only their shape is used).
        rng : numpy.random.Generator
            Random generator.

        Returns
        -------
        ndarray, shape (K, s)
            Noise, SI units.
        """
        return self.sigma * rng.standard_normal(np.shape(measured))


class ProbeModel(NuisanceModel):
    """Bed-probe heights: the nozzle's height above a flat bed at the probe's trigger.

    The bed is the plane ``z = b + tx x + ty y`` of the base frame (``bed.z``: its height at
    the base frame's z axis, m; ``bed.tilt_x``, ``bed.tilt_y``: its slopes dz/dx and dz/dy,
    dimensionless, as firmwares give bed tilt). A row's nozzle tip is ``x = P + R c`` (``c``
    the tip on the platform, known, default the platform origin) and the instrument measures
    its *vertical* height above the bed, along the base z axis (the direction the machine
    moves while probing):

    ``probe_z = x_z - (b + tx x_x + ty x_y)``

    (0 for a probe that triggers on nozzle contact; the probe's offset otherwise). The
    height along z is the perpendicular distance divided by the cosine of the bed's tilt: for
    a tilt of 1 mrad they differ by half a part per million of ``probe_z``. The readings are
    exact (forward kinematics); the trigger's repeatability, which moves the machine, hence
    all its readings, together along z, is noise on ``probe_z``.

    Parameters
    ----------
    tip : array_like, shape (3,), optional
        The nozzle tip in the platform frame, m; default the platform origin.
    fixed : sequence of str, optional
        Names of the bed's unknowns held at their values (``bed.z`` on a printer, whose
        frame is its bed; the tilt where the data cannot tell it).
    """

    kind = "probe"
    #: what its measurements are, in words (noise groups, outlier rows)
    quantity = "probe heights"
    size = 1
    words = {"bed": "the bed plane (height and tilt)"}
    offset_parameter = "bed.z"

    def __init__(self, tip=None, fixed=()):
        self.tip = np.zeros(3) if tip is None else np.asarray(tip, float).reshape(3)
        params = ParameterSet(["bed.z", "bed.tilt_x", "bed.tilt_y"],
                              ["length", "slope", "slope"], np.zeros(3))
        super().__init__(params.with_fixed(list(fixed)) if fixed else params)

    def tips(self, P, R) -> np.ndarray:
        """Nozzle tips of poses, base frame.

        Parameters
        ----------
        P : ndarray, shape (K, 3)
            Platform positions, m.
        R : ndarray, shape (K, 3, 3)
            Platform orientations.

        Returns
        -------
        ndarray, shape (K, 3)
            ``P + R c``, m.
        """
        return np.asarray(P, float) + np.einsum("kij,j->ki", np.asarray(R, float), self.tip)

    def residuals(self, state, P, R, measured, group, jacobian=True):
        b, tx, ty = state.values[:3]
        x = self.tips(P, R)
        h = x[:, 2] - (b + tx * x[:, 0] + ty * x[:, 1])
        e = measured[:, :1] - h[:, None]
        if not jacobian:
            return e, None, None
        K = len(P)
        n = np.broadcast_to(np.array([-tx, -ty, 1.0]), (K, 3))        # dh/dx
        Rc = x - np.asarray(P, float)
        # x = P + R c, dx/dOmega = -skew(R c): dh/dOmega = -n skew(Rc); e = measured - h
        de_dpose = np.concatenate([-n, np.einsum("ki,kij->kj", n, skew(Rc))], -1)[:, None, :]
        de_dv = np.stack([np.ones(K), x[:, 0], x[:, 1]], -1)[:, None, :]
        return e, de_dpose, de_dv

    def joint_section(self, nuisance, machine, calibrated, source, fl, units, frame, taken):
        bed = tuple(float(v) for v in nuisance.values[:3])
        entry = {"bed": {"height": bed[0] / fl, "tilt_x": bed[1], "tilt_y": bed[2],
                         "unit": units["length"], "tilt": "slopes dz/dx, dz/dy",
                         "frame": frame}}
        if "bed" in taken:
            return entry, None
        taken["bed"] = source
        given = (taken.get("given") or {}).get("probe")       # its own shape kept
        taken.setdefault("setups", {})["probe"] = (*bed, None if given is None
                                                   else given.surface)
        words = ("height and tilt" if not machine.frame_is_bed else "tilt"
                 if "estimated" in frame else "square to the towers")
        return entry, f"bed ({words}) from {source}"

    def start(self, P, R, measured, group, source="<data>"):
        """The bed plane through the tips lowered by their measured heights (least squares).

        Parameters
        ----------
        P : ndarray, shape (K, 3)
            Platform positions of the readings under the start geometry, m.
        R : ndarray, shape (K, 3, 3)
            Their orientations.
        measured : ndarray, shape (K, 1)
            Measured heights, m.
        group : ndarray of int, shape (K,)
            Unused (one bed).
        source : str, optional
            File name for messages.

        Returns
        -------
        ProbeModel
            The model with the fitted plane as start values (minimum norm when the tips lie on
            a line).
        """
        x = self.tips(P, R)
        values = np.array(self.parameters.values, float)
        free = np.asarray(self.parameters.free, bool)
        if len(x) and free.any():
            # the free part of the plane (a printer's bed is its z = 0: height held)
            x0 = x[:, :2].mean(0) if free[0] else np.zeros(2)
            A = np.column_stack([np.ones(len(x)), x[:, :2] - x0])
            rhs = x[:, 2] - measured[:, 0] - values[~free] @ np.column_stack(
                [np.ones(len(x)), x[:, :2]])[:, ~free].T
            sol, *_ = np.linalg.lstsq(A[:, free], rhs, rcond=1e-10)
            values[free] = sol
            if free[0]:
                values[0] -= (values[1:] * free[1:]) @ x0
        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        new.parameters = self.parameters.with_values(values)
        return new
