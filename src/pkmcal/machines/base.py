"""The machine abstraction shared by every parallel kinematic machine.

A :class:`Machine` knows its geometric parameters (a :class:`~pkmcal.parameters.ParameterSet`),
its inverse kinematics and their derivatives. Everything else — forward kinematics by Newton,
measurement models, estimators, identifiability, accuracy — is written once against this
interface, so adding a machine touches none of it.

Poses are ``(P, R)``: position ``P`` (..., 3) in m of the platform origin in the base frame and
orientation ``R`` (..., 3, 3). Pose derivatives are taken with respect to ``[dP, dOmega]``, where
``dOmega`` is a small rotation about the base axes applied on the left (``R <- exp(dOmega) R``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..kinematics import matrix_from_rotvec
from ..parameters import ParameterSet
from .fk_solve import (  # noqa: F401  (re-exported: machine modules import them from here)
    FKResult,
    _shared_first_step,
    closed_form_positions_fk,
    newton_pose_solve,
    solve_batched,
)


@dataclass
class FrameMotion:
    """A change of the machine's parameters that moves a frame without moving the machine.

    Attributes
    ----------
    name : str
        Short name, e.g. ``"rigid motion of the base frame"``.
    description : str
        What it means, in words.
    tangents : ndarray, shape (n_params, k)
        Its directions in parameter space (internal units), one column per generator.
    """

    name: str
    description: str
    tangents: np.ndarray


@dataclass(frozen=True)
class ParameterSubset:
    """A named choice of the parameters a calibration estimates, e.g. a firmware's set.

    Attributes
    ----------
    free : tuple of str
        Parameter names or group prefixes (``tower1.endstop``, ``tower2``) left free; every
        other parameter is fixed at its value.
    description : str
        What the set is, in words (the firmware and its command, what it fixes).
    without_lengths : str or None
        The set the firmware fits instead when no measurement fixes a length (heights alone:
        Klipper's DELTA_CALIBRATE holds the arms without DELTA_ANALYZE distances); None: this
        set always.
    kinds : tuple of str or None
        The measurement kinds the firmware fits this set from (Klipper's basic
        DELTA_CALIBRATE: probe heights alone); data of other kinds are left out, named. None:
        every kind.
    """

    free: tuple[str, ...]
    description: str
    without_lengths: str | None = None
    kinds: tuple[str, ...] | None = None


def bed_height_at(plane, xy, surface=None) -> np.ndarray:
    """The height (m) of a printer's bed at (x, y): its plane (height and slopes; 0 without
    one) plus its own shape (``surface``: ``(radius, values)``, a square grid over
    ``[-radius, radius]``, interpolated bilinearly, clamped to the grid).

    Parameters
    ----------
    plane : array_like, shape (3,) or None
        ``(height m, tilt_x, tilt_y)``; None: z = 0.
    xy : array_like, shape (K, 2)
        Positions, m.
    surface : tuple, optional
        ``(radius m, values (n, n) m)``, rows by ascending y.

    Returns
    -------
    ndarray, shape (K,)
        Heights, m.
    """
    xy = np.asarray(xy, float).reshape(-1, 2)
    b = np.zeros(3) if plane is None else np.asarray(plane, float)
    z = b[0] + b[1] * xy[:, 0] + b[2] * xy[:, 1]
    if surface is None:
        return z
    radius, values = float(surface[0]), np.asarray(surface[1], float)
    n = len(values)
    f = np.clip((xy + radius) / (2 * radius) * (n - 1), 0.0, n - 1.0)
    i0 = np.clip(np.floor(f).astype(int), 0, n - 2)
    t = f - i0
    ix, iy, tx, ty = i0[:, 0], i0[:, 1], t[:, 0], t[:, 1]
    return z + ((1 - ty) * ((1 - tx) * values[iy, ix] + tx * values[iy, ix + 1])
                + ty * ((1 - tx) * values[iy + 1, ix] + tx * values[iy + 1, ix + 1]))


@dataclass(frozen=True)
class ModelCandidate:
    """A model ``--parameters auto`` may choose (:meth:`Machine.model_candidates`).

    Attributes
    ----------
    parameters : str
        A named parameter set (:attr:`Machine.PARAMETER_SETS`, or ``full``).
    bed_tilt : str or None
        ``--bed-tilt`` of the candidate (a printer's bed; None: the default).
    words : str
        The model in words, for the report.
    """

    parameters: str
    bed_tilt: str | None
    words: str


@dataclass(frozen=True)
class ModelExtension:
    """A named extension of a machine's model: parameters the plain model holds at zero (or
    lacks) that a calibration may add when held-out data show the machine has them.

    Attributes
    ----------
    name : str
        Short name, e.g. ``"reading curvature"``.
    description : str
        What it models, in words.
    parameters : tuple of str
        The parameters it adds (or frees).
    apply : callable
        ``apply(machine) -> Machine``: a copy of the machine with the extension's parameters
        free, at values that leave the machine's kinematics unchanged.
    """

    name: str
    description: str
    parameters: tuple[str, ...]
    apply: Callable


@dataclass
class PhysicalLimit:
    """A limit of a machine's own hardware that poses must keep (a carriage cannot rise above
    its endstop, a nozzle cannot go below the bed); stated by each machine type in its own
    module (:meth:`Machine.physical_limits`).

    Attributes
    ----------
    excess : ndarray, shape (K,)
        How far past the limit each pose is, internal units (m or rad); 0 or below where the
        pose keeps it, NaN where it cannot be told (no real inverse kinematics).
    words : str
        The violation in words, with ``{amount}`` for the excess in the user's units, e.g.
        ``"the carriage of tower 1 would be {amount} above its endstop"``.
    quantity : str, optional
        ``"length"`` or ``"angle"``: the unit ``{amount}`` is shown in.
    joint : int or None, optional
        The 0-based joint the limit bounds (its value is shown beside the words), or None.
    """

    excess: np.ndarray
    words: str
    quantity: str = "length"
    joint: int | None = None


@dataclass
class Reachability:
    """Which poses a machine can take, and why each other one cannot
    (:meth:`Machine.reachability`).

    Attributes
    ----------
    ok : ndarray of bool, shape (K,)
        True where the pose is reachable: real inverse kinematics, in home's working mode,
        within the machine's physical limits and its ``joint_limits``.
    q : ndarray, shape (K, n_joints)
        Joint values, internal units; NaN where there is no real inverse kinematics.
    reasons : dict
        0-based pose index -> why that pose cannot be reached (the joint and by how much past
        its limit, in the machine file's units), for every pose that is not ``ok``.
    limits_only : ndarray of bool, shape (K,)
        Poses the machine could take but for the machine file's ``joint_limits`` (the joint
        values are real, in the working mode, within the physical limits).
    """

    ok: np.ndarray
    q: np.ndarray
    reasons: dict
    limits_only: np.ndarray

    @property
    def unreachable(self) -> np.ndarray:
        """0-based indices of the poses that cannot be reached, ascending.

        Returns
        -------
        ndarray of int
            The indices.
        """
        return np.flatnonzero(~self.ok)


#: a pose past a physical limit by at most this (m; rad for angles) still keeps it (rounding)
PHYSICAL_LIMIT_TOLERANCE = 1e-9


class Machine(ABC):
    """A parallel kinematic machine with geometric error parameters.

    Subclasses implement :meth:`ik_jacobians` (closed-form inverse kinematics with analytic
    derivatives), :meth:`transform_base` and :meth:`transform_platform` (re-expressing the
    geometry in rotated frames, which defines gauge freedoms), and the file schema.

    Parameters
    ----------
    parameters : ParameterSet
        The geometric parameters (names, kinds, values in internal units, fixed flags).
    home : tuple of ndarray, optional
        ``(P, R)``: a pose of the working assembly mode, position (3,) in m and orientation
        (3, 3); default: :meth:`default_home`, computed on first use.
    name : str, optional
        Free-text name of the machine (the machine file's ``name``).
    """

    #: machine type as written in files (``machine: hexaslide``)
    kind: str = ""
    #: number of actuated joints
    n_joints: int = 6
    #: pose degrees of freedom of the platform (6 = full pose, 3 = translation only or planar);
    #: which coordinates move is :attr:`pose_space` (generic code asks it, not this count)
    pose_dof: int = 6
    #: the pose coordinates the platform moves along, indices into (x, y, z, rx, ry, rz) (the
    #: columns of a pose Jacobian): every one for a platform that moves in space, ``(0, 1, 2)``
    #: for one that only translates, ``(0, 1, 5)`` for a planar one; None: from ``pose_dof``
    POSE_SPACE: tuple[int, ...] | None = None
    #: what the joint readings measure: "length" (prismatic) or "angle" (revolute)
    joint_quantity: str = "length"
    #: the instrument a machine is measured with when none is named (a registry name,
    #: :mod:`pkmcal.instruments.registry`)
    default_instrument: str = "tracker"
    #: the machine's frame is its bed (a printer: z = 0 the probed bed); see
    #: :func:`pkmcal.instruments.probe.bed_choice`
    frame_is_bed: bool = False
    #: the frame targets are given in, in words (:meth:`targets_in_base`)
    working_frame_words: str = "base frame of the calibrated model"
    #: what one chain of the machine is called in messages ("leg(s) 2, 3")
    chain_word: str = "chain"
    #: what one vector of joint values is called in messages ("12 joint vector(s)")
    joint_vector_word: str = "joint"
    #: the joints and what they read, in messages ("the sliders read about 300 mm at home")
    joints_read_words: str = "joints read"
    #: how the joints move the platform, in words, for a format or an instrument that refuses
    #: the machine for it (None: nothing to say beyond the machine type)
    actuation_words: str | None = None
    #: half-widths of the uniform random deviations of a simulated true machine: (length m,
    #: angle rad) (:func:`~pkmcal.machines.deviations.random_deviations`)
    RANDOM_DEVIATION: tuple[float, float] = (2e-3, 0.02)
    #: the deviations of simulated true machines by default (``random``, or a name
    #: :meth:`paper_deviations` knows)
    DEFAULT_DEVIATIONS: str = "random"
    #: poses per forward-kinematics chunk (temporaries stay in cache)
    fk_chunk: int = 8192
    #: named parameter subsets (:meth:`parameter_set`); ``full`` (every parameter free) is
    #: always available
    PARAMETER_SETS: dict[str, ParameterSubset] = {}

    def __init__(self, parameters: ParameterSet, home=None, name: str = ""):
        self.parameters = parameters
        self.name = name
        self._home = None if home is None else (np.asarray(home[0], float),
                                                np.asarray(home[1], float))

    def paper_deviations(self):
        """The parameter errors of a source paper's experiment for this machine type, or None.

        Returns
        -------
        ndarray, shape (n_params,) or None
            Deviations in internal units (``--deviations paper-table1``); None: there are none.
        """
        return None

    # -- geometry -------------------------------------------------------------------------
    @property
    def pose_space(self) -> tuple[int, ...]:
        """Indices into ``(x, y, z, rx, ry, rz)`` of the pose coordinates the platform moves
        along (:attr:`POSE_SPACE`; by default the first ``pose_dof``: translations alone, or
        every coordinate).

        Returns
        -------
        tuple of int
            Sorted column indices of a pose Jacobian.
        """
        if self.POSE_SPACE is not None:
            return tuple(self.POSE_SPACE)
        return tuple(range(3)) if self.pose_dof == 3 else tuple(range(6))

    @property
    def rotates(self) -> bool:
        """True when the platform's orientation moves (some of rx, ry, rz in :attr:`pose_space`)."""
        return any(i >= 3 for i in self.pose_space)

    @property
    def u(self) -> np.ndarray:
        """Current parameter vector (n_params,), internal units (m, rad)."""
        return self.parameters.values

    def with_parameters(self, values) -> Machine:
        """A copy of this machine with new parameter values (same names, home, name).

        Parameters
        ----------
        values : array_like, shape (n_params,)
            New parameter values, internal units.

        Returns
        -------
        Machine
            A shallow copy of the same class; only its :class:`ParameterSet` is replaced.
        """
        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        new.parameters = self.parameters.with_values(values)
        return new

    def model_candidates(self, fixes_lengths: bool) -> list[ModelCandidate]:
        """The models ``--parameters auto`` chooses from, the firmware's own first (always
        a candidate; the others only where the data leave enough equations to judge them).
        A machine without candidates (the default) is fitted with its parameters as they
        are.

        Parameters
        ----------
        fixes_lengths : bool
            Whether some measurement fixes a length (distances, points): a firmware fits
            more then.

        Returns
        -------
        list of ModelCandidate
            Empty here.
        """
        return []

    # -- build tolerances (SPEC 9: priors) -------------------------------------------------
    def default_tolerances(self) -> dict[str, float]:
        """Build tolerances per quantity: the machine file's ``tolerances:`` keys and their
        default prior standard deviations (internal units: m, rad). A machine without any
        (the default) is fitted by maximum likelihood alone.

        Returns
        -------
        dict
            ``{key: std}``; empty here.
        """
        return {}

    def tolerance_kinds(self) -> dict[str, str]:
        """The kind (``length`` / ``angle``) of each :meth:`default_tolerances` key (the
        machine file's units apply).

        Returns
        -------
        dict
            Key -> ``"length"`` or ``"angle"`` (empty: the machine has no tolerances).
        """
        return {}

    def tolerance_rows(self, tolerances: dict[str, float]) -> list:
        """The prior's rows for given tolerances (:meth:`~pkmcal.parameters.Prior.about`).

        Parameters
        ----------
        tolerances : dict
            ``{key: std}`` (internal units) of the quantities that carry a prior.

        Returns
        -------
        list of (label, {parameter: coefficient}, std, key)
            Empty here.
        """
        return []

    def with_tolerances(self, tolerances: dict | str | None = "default") -> Machine:
        """A copy whose parameters carry the build tolerances as a prior about their present
        values (SPEC 9).

        Parameters
        ----------
        tolerances : dict or "default" or None, optional
            ``"default"``: :meth:`default_tolerances`; a dict overrides those per key (a value
            None: that quantity has no prior); None or ``"none"``: no prior at all.

        Returns
        -------
        Machine
            The copy (this machine unchanged); :attr:`tolerances` records the overrides.

        Raises
        ------
        InputError
            For a key the machine does not know or a standard deviation that is not > 0;
            the message names ``tolerances.KEY``.
        """
        from ..errors import InputError
        from ..parameters import Prior

        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        if tolerances is None or tolerances == "none":
            new.parameters = self.parameters.with_prior(None)
            new.tolerances = "none"
            return new
        table = dict(self.default_tolerances())
        overrides = {} if tolerances == "default" else dict(tolerances)
        for key, value in overrides.items():
            if key not in table:
                known = ", ".join(table) or "none"
                raise InputError(f"tolerances.{key}: no such quantity for a "
                                 f"{self.kind or 'machine'} (known: {known})")
            if value is not None and not (np.isfinite(value) and value > 0):
                raise InputError(f"tolerances.{key}: a tolerance is a standard deviation > 0 "
                                 f"(or null: no prior), got {value!r}")
            table[key] = value
        table = {k: v for k, v in table.items() if v is not None}
        new.parameters = self.parameters.with_prior(
            Prior.about(self.parameters, self.tolerance_rows(table)))
        new.tolerances = overrides
        return new

    def build_error_words(self, rows) -> list[str]:
        """What the data determine that a firmware cannot hold, as actions in the machine's
        own terms (a leaning tower, unequal arms), from a fit's prior rows
        (:meth:`~pkmcal.estimation.estimator.CalibrationResult.prior_summary`); none here.

        Parameters
        ----------
        rows : list of PriorRow
            The fit's rows.

        Returns
        -------
        list of str
            One sentence per action.
        """
        return []

    #: the tolerances the machine's prior was built with: None (none asked for), ``"none"``,
    #: or the machine file's overrides of :meth:`default_tolerances` (a dict, maybe empty)
    tolerances = None

    @property
    def home(self) -> tuple[np.ndarray, np.ndarray]:
        """A pose of the working assembly mode ``(P, R)``: the file's, or one found.

        Position (3,) in m and orientation (3, 3). Setting it stores a copy as floats.
        """
        if self._home is None:
            self._home = self.default_home()
        return self._home

    @home.setter
    def home(self, pose) -> None:
        self._home = (np.asarray(pose[0], float), np.asarray(pose[1], float))

    @abstractmethod
    def default_home(self) -> tuple[np.ndarray, np.ndarray]:
        """A start pose of the working assembly mode when the file gives none.

        Returns
        -------
        P : ndarray, shape (3,)
            Platform position, m.
        R : ndarray, shape (3, 3)
            Platform orientation.
        """

    @abstractmethod
    def characteristic_length(self) -> float:
        """Length (m) used to scale length parameters against angles.

        Returns
        -------
        float
            The characteristic length, m.
        """

    def parameter_scales(self) -> np.ndarray:
        """Column scale of every parameter in identification Jacobians.

        Lengths are scaled by the characteristic length, angles and ratios by 1; machines with
        other kinds of parameters override this.

        Returns
        -------
        ndarray, shape (n_params,)
            Scale of each parameter.
        """
        return self.parameters.scales(self.characteristic_length())

    def scales_with(self, extra) -> np.ndarray:
        """Scales of the machine's parameters followed by those of ``extra``.

        Parameters
        ----------
        extra : ParameterSet
            Measurement-model parameters (link length, tracker pose, frames), scaled with this
            machine's characteristic length.

        Returns
        -------
        ndarray, shape (n_params + len(extra),)
            Column scales, machine parameters first.
        """
        return np.concatenate([self.parameter_scales(),
                               extra.scales(self.characteristic_length())])

    def parameter_set(self, name: str) -> ParameterSet:
        """The machine's parameters with the fixed flags of a named subset.

        ``full`` frees every parameter unless the machine defines its own ``full``; other
        names are the machine's :attr:`PARAMETER_SETS` (a linear Delta's ``klipper``,
        ``marlin``, ``rrf``).

        Parameters
        ----------
        name : str
            The subset's name.

        Returns
        -------
        ParameterSet
            Same names, kinds and values; ``fixed`` True for every parameter the subset does
            not free.

        Raises
        ------
        InputError
            For a name the machine does not know (the message lists the known ones).
        """
        from ..errors import InputError

        p = self.parameters
        sets = dict(self.PARAMETER_SETS)
        if name == "full" and "full" not in sets:
            return p.with_fixed_mask(np.zeros(len(p), bool))
        if name not in sets:
            known = ", ".join(sorted(set(sets) | {"full"}))
            raise InputError(f"unknown parameter set {name!r} for a {self.kind or 'machine'}; "
                             f"known: {known}")
        fixed = np.ones(len(p), bool)
        fixed[p.indices(list(sets[name].free))] = False
        return p.with_fixed_mask(fixed)

    def with_parameter_set(self, name: str) -> Machine:
        """A copy of this machine whose parameters carry the fixed flags of a named subset.

        Parameters
        ----------
        name : str
            The subset's name (:meth:`parameter_set`).

        Returns
        -------
        Machine
            A shallow copy; only its :class:`ParameterSet` is replaced.

        Raises
        ------
        InputError
            For an unknown name.
        """
        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        new.parameters = self.parameter_set(name)
        return new

    # -- validation -----------------------------------------------------------------------
    def geometry_problems(self, home_given: bool = True) -> list[tuple[tuple, str]]:
        """Why this geometry cannot work, for the machine file loader (empty when it can).

        Only what is really degenerate is reported: a geometry the machine cannot work with
        (duplicate chains or legs, a Jacobian singular everywhere, the home pose out of reach
        or singular), never one that is merely unusual.

        Parameters
        ----------
        home_given : bool, optional
            True when the home pose was given (the machine file's ``home``), False when it is
            :meth:`default_home`; decides which key a problem at home names.

        Returns
        -------
        list of tuple
            ``(key_path, what)``: the machine file key concerned as a path tuple
            (``("chains", 3)``, ``("home",)``) and the problem in words, most specific first.
        """
        return []

    def _length_text(self, x: float) -> str:
        """A length for a message, in the machine file's length unit when known."""
        from ..units import LENGTH

        unit = (getattr(self, "file_units", None) or {}).get("length", "m")
        return f"{float(x) / LENGTH[unit]:.6g} {unit}"

    def _home_check(self) -> tuple[np.ndarray, bool]:
        """``(unreachable, singular)`` at :attr:`home`: the 0-based joints that cannot reach
        it, and whether the joint Jacobian is singular there (rotations scaled by the
        characteristic length; smallest singular value below 1e-9 of the largest)."""
        with np.errstate(all="ignore"):
            P, R = self.home
            q, J, _ = self.ik_jacobians(P, R, want_du=False)
            bad = np.flatnonzero(~np.isfinite(np.asarray(q, float).reshape(-1)))
            if bad.size:
                return bad, True
            Js = np.array(J, float).reshape(self.n_joints, 6)
            Js[:, 3:] /= self.characteristic_length()
            Js = Js[:, list(self.pose_space)]
            if not np.all(np.isfinite(Js)):
                return bad, True
            sv = np.linalg.svd(Js, compute_uv=False)
        return bad, not sv[-1] > 1e-9 * sv[0]

    def model_extensions(self) -> list[ModelExtension]:
        """Candidate extensions of the model, tried by a calibration on held-out data.

        A calibration adopts one only when it predicts rows left out of the fit better than
        the plain model by more than the cross-validation's standard error
        (:mod:`pkmcal.calibration.extensions`). Machines with such candidates override this;
        the estimators and the command line need nothing else.

        Returns
        -------
        list of ModelExtension
            None by default.
        """
        return []

    def identifiable_combinations(self, u=None) -> dict | None:
        """Parameter combinations that are identifiable where their parts are not, in SI units.

        Parameters
        ----------
        u : array_like, shape (n_params,), optional
            Parameter vector; default :attr:`u`.

        Returns
        -------
        dict or None
            ``{"description": words, name: value (list or float), ...}``; None (the default)
            when the machine has none worth reporting.
        """
        return None

    def tracker_grid_spacing(self) -> tuple | None:
        """The spacing of a tracker grid this machine is measured on by its source paper.

        Returns
        -------
        tuple of float or None
            ``(dx, dy, dz)``, m, of a 3x3x3 grid around home (seed 001 for the Delta); None
            (the default): tracker plans are random poses around home.
        """
        return None

    def tracker_target(self) -> np.ndarray | None:
        """The place of a tracker's target on the platform when the machine file gives it.

        Returns
        -------
        ndarray, shape (3,) or None
            Platform-frame point, m; None (the default): the calibration estimates it.
        """
        return None

    def reading_gains(self) -> np.ndarray | None:
        """Length per reading unit of each joint whose readings are kept in their own unit
        (a machine with a ``reading_unit``, :meth:`joint_unit`: ``L = l0 + gain r``), or None
        (the default: the joint values are the joints' travel in the machine file's units).

        Returns
        -------
        ndarray, shape (n_joints,) or None
            The gains, m per reading unit (a ratio for readings in a length unit).
        """
        return None

    def leg_joints(self, q, u=None):
        """The legs of a machine whose chains are straight legs of variable length between a
        base joint and a platform joint (a Gough-Stewart platform): their joints and their
        lengths at the readings ``q`` (the linear reading model); None for any other machine.

        Parameters
        ----------
        q : array_like, shape (n_joints,)
            Readings (internal units).
        u : array_like, shape (n_params,) or (K, n_params), optional
            Parameter vector(s); default: :attr:`u`.

        Returns
        -------
        tuple of ndarray or None
            ``(base (..., n, 3), platform (..., n, 3), lengths (..., n))``, m, with a leading
            axis per parameter vector; None (the default): the machine has no such legs.
        """
        return None

    def reading_sigma(self, sigma_length: float) -> np.ndarray:
        """Standard deviation of each joint reading for a reading noise stated as a length.

        Prismatic joints read lengths: ``sigma_length`` itself; revolute joints: the angle
        that moves a point at the characteristic length by ``sigma_length``. Machines whose
        readings have a gain override this.

        Parameters
        ----------
        sigma_length : float
            Reading noise as a length, m.

        Returns
        -------
        ndarray, shape (n_joints,)
            Standard deviations in the joints' internal units.
        """
        s = float(sigma_length)
        if self.joint_quantity == "angle":
            s = s / self.characteristic_length()
        return np.full(self.n_joints, s)

    # -- joint limits (machine file key ``joint_limits``) -----------------------------------
    def joint_unit(self, units: dict | None = None) -> tuple[str, float]:
        """Unit of the joint values in a machine file and its SI factor.

        A Stewart's reading unit (``rev``: factor 1, readings kept as read; a length unit:
        converted to metres); otherwise the file's angle unit for revolute joints and its
        length unit for prismatic ones.

        Parameters
        ----------
        units : dict, optional
            ``{"length": ..., "angle": ...}``; default the machine's ``file_units`` (m, rad
            when it has none).

        Returns
        -------
        unit : str
            The unit name, e.g. ``"mm"``, ``"deg"`` or ``"rev"``.
        factor : float
            SI value of one unit (1 for a reading unit that is not a length).
        """
        from ..units import ANGLE, LENGTH

        reading = getattr(self, "reading_unit", None)
        if reading is not None:
            return reading, LENGTH.get(reading, 1.0)
        units = units or getattr(self, "file_units", None) or {"length": "m", "angle": "rad"}
        if self.joint_quantity == "angle":
            return units["angle"], ANGLE[units["angle"]]
        return units["length"], LENGTH[units["length"]]

    def limit_violations(self, q) -> np.ndarray:
        """Which joint values lie outside the machine's ``joint_limits``.

        Parameters
        ----------
        q : array_like, shape (..., n_joints)
            Joint values, internal units.

        Returns
        -------
        ndarray of bool, shape (..., n_joints)
            True where a value is below its ``min`` or above its ``max``; NaN (a pose that
            cannot be reached) is not a limit violation. All False without limits.
        """
        q = np.asarray(q, float)
        limits = getattr(self, "joint_limits", None)
        if limits is None:
            return np.zeros(q.shape, bool)
        lo, hi = (np.asarray(v, float) for v in limits)
        return (q < lo) | (q > hi)

    def within_limits(self, q) -> np.ndarray:
        """Where every joint value is finite and within the machine's ``joint_limits``.

        Parameters
        ----------
        q : array_like, shape (..., n_joints)
            Joint values, internal units.

        Returns
        -------
        ndarray of bool, shape (...)
            True where the joints can take these values (all finite ones without limits).
        """
        q = np.asarray(q, float)
        return np.all(np.isfinite(q), axis=-1) & ~np.any(self.limit_violations(q), axis=-1)

    def joint_limits_text(self) -> str:
        """The joint limits in words, in the machine file's units.

        Returns
        -------
        str
            E.g. ``"q1..q6 within 0..400 mm"`` or ``"q1 within -40..80 deg, q2 ..."``;
            ``"none"`` without limits.
        """
        limits = getattr(self, "joint_limits", None)
        if limits is None:
            return "none"
        unit, f = self.joint_unit()
        lo, hi = (np.asarray(v, float) / f for v in limits)
        if np.all(lo == lo[0]) and np.all(hi == hi[0]):
            return f"q1..q{self.n_joints} within {lo[0]:.6g}..{hi[0]:.6g} {unit}"
        return ", ".join(f"q{j + 1} within {a:.6g}..{b:.6g} {unit}"
                         for j, (a, b) in enumerate(zip(lo, hi, strict=True)))

    def limit_violation_text(self, q, rows=None, limit: int = 5) -> str:
        """The rows and joints whose values break the joint limits, for a message.

        Parameters
        ----------
        q : array_like, shape (K, n_joints)
            Joint values, internal units.
        rows : array_like of int, shape (K,), optional
            Row label of each vector (file line numbers); default 1..K.
        limit : int, optional
            Most rows named.

        Returns
        -------
        str
            E.g. ``"row 3: q2 = 412.5 mm above max 400 mm; row 7: q1 = -2 mm below min 0 mm"``
            (values in the machine file's units); empty when no value breaks a limit.
        """
        q = np.atleast_2d(np.asarray(q, float))
        rows = np.arange(1, len(q) + 1) if rows is None else np.asarray(rows)
        bad = self.limit_violations(q)
        which = np.flatnonzero(bad.any(axis=-1))
        if not which.size:
            return ""
        unit, f = self.joint_unit()
        lo, hi = (np.asarray(v, float) / f for v in self.joint_limits)
        parts = []
        for k in which[:limit]:
            joints = []
            for j in np.flatnonzero(bad[k]):
                v = q[k, j] / f
                side = f"below min {lo[j]:.6g}" if v < lo[j] else f"above max {hi[j]:.6g}"
                joints.append(f"q{j + 1} = {v:.6g} {unit} {side} {unit}")
            parts.append(f"row {int(rows[k])}: " + ", ".join(joints))
        more = f"; and {which.size - limit} more row(s)" if which.size > limit else ""
        return "; ".join(parts) + more

    # -- reachability ---------------------------------------------------------------------
    def physical_limits(self, P, R, q, u=None, bed=None) -> list[PhysicalLimit]:
        """The limits of the machine's own hardware at poses, beyond real inverse kinematics
        and the file's ``joint_limits`` (a linear Delta's endstops and bed); none by default.

        Each machine type states its own in its module; :meth:`reachability` applies them.

        Parameters
        ----------
        P : ndarray, shape (K, 3)
            Platform positions, m (base frame).
        R : ndarray, shape (K, 3, 3)
            Platform orientations.
        q : ndarray, shape (K, n_joints)
            Joint values at the poses (internal units; NaN where unreachable).
        u : array_like, shape (n_params,), optional
            Parameter vector (internal units); default: :attr:`u`.
        bed : array_like, shape (3,), optional
            The bed plane ``(height m, tilt_x, tilt_y)`` of the experiment's set-ups (a
            printer's bed: :class:`~pkmcal.instruments.probe.BedSetup`, the machine holds
            none); None: the machine's own nominal bed, if it has one.

        Returns
        -------
        list of PhysicalLimit
            One per limit, with each pose's excess.
        """
        return []

    def within_physical_limits(self, P, R, q=None, u=None, bed=None) -> np.ndarray:
        """Where poses keep the machine's physical limits (:meth:`physical_limits`).

        Parameters
        ----------
        P : array_like, shape (K, 3)
            Platform positions, m (base frame).
        R : array_like, shape (K, 3, 3)
            Platform orientations.
        q : array_like, shape (K, n_joints), optional
            Joint values at the poses when already computed.
        u : array_like, shape (n_params,), optional
            Parameter vector (internal units); default: :attr:`u`.
        bed : array_like, shape (3,), optional
            The bed plane ``(height m, tilt_x, tilt_y)`` of the experiment's set-ups (a
            printer's bed: :class:`~pkmcal.instruments.probe.BedSetup`, the machine holds
            none); None: the machine's own nominal bed, if it has one.

        Returns
        -------
        ndarray of bool, shape (K,)
            False where a pose is past a limit (NaN excesses, unreachable poses, count as
            within: :meth:`ik` tells those).
        """
        P = np.asarray(P, float).reshape(-1, 3)
        ok = np.ones(len(P), bool)
        with np.errstate(all="ignore"):
            limits = self.physical_limits(P, R, self.ik(P, R, u) if q is None else q, u,
                                          bed=bed)
        for limit in limits:
            ok &= ~(np.asarray(limit.excess, float) > PHYSICAL_LIMIT_TOLERANCE)
        return ok

    def _amount_text(self, x: float, quantity: str) -> str:
        """A length or angle for a message, in the machine file's unit when known."""
        from ..units import ANGLE, LENGTH

        units = getattr(self, "file_units", None) or {"length": "m", "angle": "rad"}
        unit = units.get(quantity, "m" if quantity == "length" else "rad")
        f = (LENGTH if quantity == "length" else ANGLE).get(unit, 1.0)
        return f"{float(x) / f:.6g} {unit}"

    def pose_text(self, P, R=None) -> str:
        """A pose for a message, in the machine file's units: ``"(0, 0, 400) mm"``, with the
        Euler angles for a platform that rotates (``"..., psi 0 theta 5 phi 0 deg"``).

        Parameters
        ----------
        P : array_like, shape (3,)
            Position, m.
        R : array_like, shape (3, 3), optional
            Orientation (shown for a platform that rotates).

        Returns
        -------
        str
            The pose in words.
        """
        from ..kinematics import euler_from_matrix
        from ..units import ANGLE, LENGTH

        units = getattr(self, "file_units", None) or {"length": "m", "angle": "rad"}
        fl = LENGTH.get(units.get("length", "m"), 1.0)
        text = ("(" + ", ".join(f"{float(v) / fl + 0.0:.6g}" for v in np.asarray(P, float)[:3])
                + f") {units.get('length', 'm')}")
        if R is not None and self.rotates:
            fa = ANGLE.get(units.get("angle", "rad"), 1.0)
            angles = euler_from_matrix(np.asarray(R, float)) / fa
            text += ", " + " ".join(f"{n} {a + 0.0:.6g}" for n, a in zip(
                ("psi", "theta", "phi"), angles, strict=True)) + f" {units.get('angle', 'rad')}"
        return text

    def reachability(self, P, R=None, u=None, bed=None) -> Reachability:
        """Which poses the machine can take, and why not: the one test every command that
        takes targets or a workspace applies.

        A pose is reachable when its inverse kinematics is real, it is in home's working mode
        (:meth:`working_mode`), it keeps the machine's own physical limits
        (:meth:`physical_limits`: a linear Delta's carriages below their endstops and its
        nozzle above the bed) and its joint values lie within the machine file's
        ``joint_limits``. For each other pose the first failed test is given in words: the
        chain or joint, and by how much it is past its limit, in the file's units.

        Parameters
        ----------
        P : array_like, shape (K, 3) or (3,)
            Platform positions, m (base frame).
        R : array_like, shape (K, 3, 3) or (3, 3), optional
            Platform orientations; default the identity.
        u : array_like, shape (n_params,), optional
            Parameter vector (internal units); default: :attr:`u`.
        bed : array_like, shape (3,), optional
            The bed plane ``(height m, tilt_x, tilt_y)`` of the experiment's set-ups (a
            printer's bed: :class:`~pkmcal.instruments.probe.BedSetup`, the machine holds
            none); None: the machine's own nominal bed, if it has one.

        Returns
        -------
        Reachability
            Per pose: reachable or not, the joint values and the reasons.
        """
        P = np.asarray(P, float).reshape(-1, 3)
        K = len(P)
        R = np.broadcast_to(np.eye(3), (K, 3, 3)) if R is None else \
            np.broadcast_to(np.asarray(R, float), (K, 3, 3))
        with np.errstate(all="ignore"):
            q = np.asarray(self.ik(P, R, u), float).reshape(K, self.n_joints)
            real = np.all(np.isfinite(q), axis=-1)
            mode = self.working_mode(P, R, u) & real
            limits = self.physical_limits(P, R, q, u, bed=bed)
            past = [np.asarray(lim.excess, float) > PHYSICAL_LIMIT_TOLERANCE
                    for lim in limits]
            outside = self.limit_violations(q)
        physical = mode.copy()
        for p in past:
            physical &= ~p
        ok = physical & ~np.any(outside, axis=-1)
        reasons = {}
        result = Reachability(ok, q, reasons, physical & ~ok)
        if ok.all():
            return result
        unit, f = self.joint_unit()
        P0 = np.asarray(self.home[0], float)
        far = self.MAX_REACH * self.characteristic_length()
        for k in np.flatnonzero(~ok):
            k = int(k)
            if not real[k]:
                chains = np.flatnonzero(~np.isfinite(q[k])) + 1
                reasons[k] = (f"no real inverse kinematics ({self.chain_word}(s) "
                              f"{', '.join(map(str, chains))} cannot span the distance)")
                continue
            hit = [i for i, p in enumerate(past) if p[k]]
            if hit:
                parts = []
                for i in hit:
                    lim = limits[i]
                    text = lim.words.format(amount=self._amount_text(lim.excess[k],
                                                                     lim.quantity))
                    if lim.joint is not None:
                        text += f" (q{lim.joint + 1} = {q[k, lim.joint] / f:.6g} {unit})"
                    parts.append(text)
                reasons[k] = "; ".join(parts)
                continue
            if outside[k].any():
                lo, hi = (np.asarray(v, float) / f for v in self.joint_limits)
                parts = []
                for j in np.flatnonzero(outside[k]):
                    v = q[k, j] / f
                    side = (f"{lo[j] - v:.6g} {unit} below its min {lo[j]:.6g} {unit}"
                            if v < lo[j] else f"{v - hi[j]:.6g} {unit} above its max "
                            f"{hi[j]:.6g} {unit}")
                    parts.append(f"q{j + 1} = {v:.6g} {unit}, {side}")
                reasons[k] = ("outside the joint limits of "
                              f"{getattr(self, 'source', None) or 'the machine file'}: "
                              + ", ".join(parts))
                continue
            d = float(np.linalg.norm(P[k] - P0))
            if not d <= far:
                reasons[k] = (f"{self._amount_text(d, 'length')} from home, farther than "
                              f"{self.MAX_REACH:g}x the machine's size "
                              f"({self._amount_text(far, 'length')})")
            else:
                reasons[k] = ("beyond a singularity from home (another working or assembly "
                              "mode, e.g. mirrored through the base)")
        return result

    #: a commanded pose farther than this many characteristic lengths from home is not meant
    MAX_REACH = 10.0

    def targets_in_base(self, P, bed=None) -> np.ndarray:
        """Target positions given in the machine's working frame, in its base frame.

        The working frame is the base frame, except on a machine whose frame is its bed
        (:attr:`frame_is_bed`): there a target's z is its height above the bed (the
        calibrated file's ``bed`` plane), as the firmware takes it.

        Parameters
        ----------
        P : array_like, shape (K, 3)
            Positions, m.
        bed : array_like, shape (3,), optional
            The bed plane ``(height m, tilt_x, tilt_y)`` (a calibrated file's ``bed``, its
            :class:`~pkmcal.instruments.probe.BedSetup`); None: z = 0.

        Returns
        -------
        ndarray, shape (K, 3)
            Positions in the base frame, m.
        """
        P = np.array(P, float).reshape(-1, 3)
        if self.frame_is_bed and bed is not None:
            h, tx, ty = (float(v) for v in bed)
            P[:, 2] += h + tx * P[:, 0] + ty * P[:, 1]
        return P

    def targets_from_base(self, P, bed=None) -> np.ndarray:
        """Positions in the base frame, in the machine's working frame: the inverse of
        :meth:`targets_in_base` (on a machine whose frame is its bed, z becomes the height
        above the bed plane; elsewhere ``P`` itself).

        Parameters
        ----------
        P : array_like, shape (K, 3)
            Positions in the base frame, m.
        bed : array_like, shape (3,), optional
            The bed plane ``(height m, tilt_x, tilt_y)``; None: z = 0.

        Returns
        -------
        ndarray, shape (K, 3)
            Positions in the working frame, m.
        """
        P = np.array(P, float).reshape(-1, 3)
        if self.frame_is_bed and bed is not None:
            h, tx, ty = (float(v) for v in bed)
            P[:, 2] -= h + tx * P[:, 0] + ty * P[:, 1]
        return P

    def working_mode(self, P, R, u=None) -> np.ndarray:
        """Where poses can be commanded from the working mode of :attr:`home`.

        A pose qualifies when its inverse kinematics is real, it lies within
        :attr:`MAX_REACH` characteristic lengths of home, and the joint Jacobian's determinant
        (its columns along :attr:`pose_space`) has the sign it has at home: the sign
        changes only across a singularity, which the machine cannot pass, so a pose of the
        other sign belongs to another working or assembly mode (a platform mirrored through
        the base, say) that the joints could reach only by being taken apart.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m.
        R : array_like, shape (..., 3, 3)
            Platform orientations.
        u : array_like, shape (n_params,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        ndarray of bool, shape (...)
            True where the pose can be commanded.
        """
        with np.errstate(all="ignore"):
            q, J, _ = self.ik_jacobians(P, R, u, want_du=False)
            P0, R0 = self.home
            J0 = self.ik_jacobians(P0, R0, u, want_du=False)[1]
            cols = list(self.pose_space)
            sign = np.sign(np.linalg.det(np.nan_to_num(np.asarray(J, float)[..., cols])))
            sign0 = np.sign(np.linalg.det(np.asarray(J0, float).reshape(self.n_joints, 6)[
                :, cols]))
            near = (np.linalg.norm(np.asarray(P, float) - P0, axis=-1)
                    <= self.MAX_REACH * self.characteristic_length())
            return np.all(np.isfinite(q), axis=-1) & near & (sign == sign0)

    # -- kinematics -----------------------------------------------------------------------
    @abstractmethod
    def ik_jacobians(self, P, R, u=None, want_du: bool = True):
        """Joint values and derivatives at poses ``(P, R)``.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m (base frame).
        R : array_like, shape (..., 3, 3)
            Platform orientations (ignored by translation-only platforms).
        u : array_like, shape (n_params,), optional
            Parameter vector (internal units); default: :attr:`u`.
        want_du : bool, optional
            Also compute the derivatives with respect to the parameters.

        Returns
        -------
        q : ndarray, shape (..., n_joints)
            Joint values (internal units: m or rad); NaN where a pose cannot be reached.
        dq_dpose : ndarray, shape (..., n_joints, 6)
            Derivatives with respect to ``[dP, dOmega]`` (see the module docstring).
        dq_du : ndarray, shape (..., n_joints, n_params) or None
            Derivatives with respect to the parameters; None unless ``want_du``.
        """

    def pose_conditioning(self, P, R, u=None, dq_dpose=None) -> np.ndarray:
        """Inverse condition number of the joint Jacobian at poses: near 0 at a singularity.

        The Jacobian's rotation columns are divided by the characteristic length (rotations as
        lengths) before the singular values are taken.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m.
        R : array_like, shape (..., 3, 3)
            Platform orientations.
        u : array_like, shape (n_params,), optional
            Parameter vector (internal units); default: :attr:`u`.
        dq_dpose : array_like, shape (..., n_joints, 6), optional
            The joint Jacobian when it is already computed at these poses.

        Returns
        -------
        ndarray, shape (...)
            Smallest over largest singular value of each pose's Jacobian.
        """
        J = np.array(self.ik_jacobians(P, R, u, want_du=False)[1] if dq_dpose is None
                     else dq_dpose, float)
        J[..., 3:] /= self.characteristic_length()
        sv = np.linalg.svd(J, compute_uv=False)
        return sv[..., -1] / sv[..., 0]

    def ik(self, P, R, u=None) -> np.ndarray:
        """Joint values at poses; NaN where the pose is not reachable.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m.
        R : array_like, shape (..., 3, 3)
            Platform orientations.
        u : array_like, shape (n_params,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        ndarray, shape (..., n_joints)
            Joint values, internal units (m or rad).
        """
        return self.ik_jacobians(P, R, u, want_du=False)[0]

    def fk(self, q, u=None, start=None, tol: float = 1e-12, max_iter: int = 50,
           raise_on_failure: bool = False) -> FKResult:
        """Forward kinematics by Newton on the inverse kinematics, all poses at once.

        Poses are solved in chunks of :attr:`fk_chunk`; with a single start pose the first Newton
        step is shared by the whole batch. See :func:`newton_pose_solve` for the step limits.

        Parameters
        ----------
        q : array_like, shape (K, n_joints)
            Joint values (internal units).
        u : array_like, shape (n_params,), optional
            Parameter vector (internal units); default: :attr:`u`.
        start : tuple of array_like, optional
            ``(P0, R0)`` start poses broadcastable to the batch ((3,)/(K, 3) and (3, 3)/(K, 3, 3));
            default: :attr:`home`.
        tol : float, optional
            Convergence when the largest joint residual is below ``tol`` times the characteristic
            length.
        max_iter : int, optional
            Maximum Newton iterations per pose.
        raise_on_failure : bool, optional
            Raise instead of returning poses that did not converge.

        Returns
        -------
        FKResult
            Poses, per-pose convergence and residuals.

        Raises
        ------
        ConvergenceError
            With ``raise_on_failure``, when a pose did not converge.
        """
        q = np.atleast_2d(np.asarray(q, float))
        K = q.shape[0]
        P0, R0 = self.home if start is None else start
        P0, R0 = np.asarray(P0, float), np.asarray(R0, float)
        tol_q = tol * self.characteristic_length()
        # One start pose for the whole batch: Newton's first step uses the same Jacobian for
        # every pose, so it is computed once (same step, same clamping as the first iteration
        # of newton_pose_solve).
        # a platform that moves along fewer than the six pose coordinates (a planar one) is
        # solved along its own (:attr:`pose_space`)
        space = None if len(self.pose_space) == 6 else list(self.pose_space)
        shared = None
        if P0.ndim == 1 and R0.ndim == 2 and max_iter >= 2 and K > 1:
            q0, J0, _ = self.ik_jacobians(P0, R0, u, want_du=False)
            J0s = J0 if space is None else np.asarray(J0)[..., space]
            if np.all(np.isfinite(q0)) and np.all(np.isfinite(J0)) \
                    and np.linalg.matrix_rank(J0s) == J0s.shape[-1] == J0s.shape[-2]:
                shared = (q0, J0s)
        parts = []
        # chunks keep the temporaries in cache: large batches are much faster this way
        for lo in range(0, K, self.fk_chunk) if K else [0]:
            qc = q[lo:lo + self.fk_chunk]
            k = len(qc)
            P = np.broadcast_to(P0, (K, 3))[lo:lo + k].copy()
            R = np.broadcast_to(R0, (K, 3, 3))[lo:lo + k].copy()
            iters = max_iter
            if shared is not None:
                _shared_first_step(shared, qc, P, R, tol_q, space=space)
                iters -= 1
            part = newton_pose_solve(lambda idx, P, R, qc=qc: self._fk_system(qc[idx], P, R, u),
                                     P, R, tol_q, iters, space=space)
            if shared is not None:
                part.iterations += 1
            parts.append(part)
        result = parts[0] if len(parts) == 1 else FKResult(
            np.concatenate([p.P for p in parts]), np.concatenate([p.R for p in parts]),
            np.concatenate([p.converged for p in parts]),
            np.concatenate([p.residual for p in parts]), max(p.iterations for p in parts))
        if raise_on_failure:
            result.raise_if_failed()
        return result

    def _fk_system(self, q, P, R, u):
        qc, J, _ = self.ik_jacobians(P, R, u, want_du=False)
        return qc - q, J

    # -- frames (gauge) -------------------------------------------------------------------
    def frame_motions(self, u=None) -> list[FrameMotion]:
        """The frame motions this machine's parameters can express (for identifiability words).

        By default a rigid motion of the base frame (every base-side element moved together:
        3 rotations about the base axes, 3 translations) and one of the platform frame, found
        by differentiating :meth:`transform_base` and :meth:`transform_platform` (with a
        translation ``t`` where the machine supports it). No measurement of the machine alone
        can see them; an instrument sees them unless its own unknowns (its frame, the target's
        place) absorb them. Machines with other such combinations override this.

        Parameters
        ----------
        u : array_like, shape (n_params,), optional
            Parameter vector to linearise at; default :attr:`u`.

        Returns
        -------
        list of FrameMotion
            The motions, base first.
        """
        u = self.u if u is None else np.asarray(u, float)
        h = 1e-6
        out = []
        for name, what, transform in (
                ("rigid motion of the base frame", "moving every base joint by one rigid "
                 "motion (3 rotations, 3 translations)", self.transform_base),
                ("rigid motion of the platform frame", "moving every platform joint by one "
                 "rigid motion", self.transform_platform)):
            cols = []
            try:
                for k in range(3):
                    w = np.zeros(3)
                    w[k] = h
                    cols.append((transform(u, matrix_from_rotvec(w))
                                 - transform(u, matrix_from_rotvec(-w))) / (2 * h))
                for k in range(3):
                    t = np.zeros(3)
                    t[k] = 1.0
                    cols.append(transform(u, np.eye(3), t=t) - transform(u, np.eye(3)))
            except (NotImplementedError, TypeError):
                if not cols:
                    continue
            out.append(FrameMotion(name, what, np.column_stack(cols)))
        return out

    @abstractmethod
    def transform_base(self, u, G) -> np.ndarray:
        """Parameters of the same machine expressed in a base frame rotated by ``G``.

        A base-frame vector ``v`` becomes ``G @ v``; the rotation is about the base origin O.

        Parameters
        ----------
        u : array_like, shape (n_params,)
            Parameter vector (internal units).
        G : array_like, shape (3, 3)
            Rotation from the old to the new base frame.

        Returns
        -------
        ndarray, shape (n_params,)
            The transformed parameter vector.
        """

    @abstractmethod
    def transform_platform(self, u, C) -> np.ndarray:
        """Parameters with the platform frame re-oriented: ``R' = R C``, ``p' = C^T p``.

        Parameters
        ----------
        u : array_like, shape (n_params,)
            Parameter vector (internal units).
        C : array_like, shape (3, 3)
            Rotation of the new platform frame relative to the old one.

        Returns
        -------
        ndarray, shape (n_params,)
            The transformed parameter vector.
        """
