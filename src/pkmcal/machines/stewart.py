"""Gough–Stewart platforms: six legs of variable length between joint pairs (SPEC 2.4).

Leg i joins the base joint ``b_i`` (base frame) and the platform joint ``p_i`` (platform frame);
its length is ``L_i = |t + R p_i - b_i|``. A real leg reports a reading ``r_i`` in its own unit
(mm, encoder counts, motor revolutions): ``L_i = l0_i + gain_i r_i``, so each leg has 8
parameters — ``leg{i}.base.x/y/z``, ``leg{i}.platform.x/y/z``, ``leg{i}.l0`` (length at zero
reading) and ``leg{i}.gain`` (length per reading unit) — 48 in all. Readings in a length unit
are converted to metres (gain 1 means "the reading is the length"); readings in any other unit
(``rev``, ``counts``) stay in that unit and the gain carries metres per unit.

A leg whose reading is not quite linear in its length (a lead screw's pitch error, a belt
that stretches, a pulley off centre) may carry the *reading curvature* extension
(:meth:`Stewart.model_extensions`): ``L_i = l0_i + gain_i r_i + curvature_i r_i^2``, six more
parameters ``leg{i}.curvature`` (m per reading unit squared) after the 48. A platform without
them is exactly the linear model (48 parameters, files unchanged); a calibration adopts them
only when they predict held-out data better (:mod:`pkmcal.calibration.extensions`).

The cubic 6-UPU device of seed 003 is one instance (``examples/cubic_6upu.yaml``). Notation
of seed 003 eq. 1-10: ``s_i = R p_i``, ``w_i = t + s_i - b_i = l_i z_i``,
``J_p`` row i = ``[z_i^T, (s_i x z_i)^T]``, ``J_s`` row i = ``[z_i^T R, -z_i^T]`` on
``[dp_i (platform frame), db_i]``.

The machine file (SPEC 6) lists the legs; ``gain`` is the file's length unit per reading unit,
``readings`` (optional, default: the file's length unit) names what the legs report::

    pkmcal: 1
    machine: stewart
    units: {length: mm, angle: deg}
    readings: {unit: rev}                      # optional: mm, m, um or any word (rev, counts)
    legs:                                      # exactly 6: L = l0 + gain * reading
      - {base: [-385.3, -140.2, 0.0], platform: [-197.4, 95.0, 0.0], l0: 640.2, gain: 75.7}
    measurement_frames:                        # optional: frames of full-pose measurements
      mocap_from_base: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], translation: [0, 0, 0]}
      platform_from_marker: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], translation: [0, 0, 0]}
    home: [0.0, 0.0, 565.0, 0.0, 0.0, 0.0]

``gain`` is always the file's length unit per reading unit: 1 when the readings are lengths in
the file's unit, 0.001 for ``length: mm`` with ``readings: {unit: counts}`` and 1 um per count
(or with ``readings: {unit: um}``), 0.001 for ``length: m`` with ``readings: {unit: mm}``
(``gain: 1`` there would mean 1 m per mm). Internally, readings in a length unit are converted
to metres (the gain is then a ratio, 1 for readings that are the length); readings in any other
unit are kept as read and the gain carries metres per unit (1e-6 for 1 um per count); ``l0`` is
always in metres. A leg may carry ``curvature`` (the file's length unit per reading unit
squared: ``L = l0 + gain r + curvature r^2``, the reading curvature a calibration adopts when
held-out data show it); when one leg has it, every leg has it (0 where absent), and a file
without it is the linear model.
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, field_validator
from pydantic_core import PydanticCustomError

from ..kinematics import matrix_from_euler
from ..parameters import ParameterSet
from ..units import LENGTH, unit_of
from .base import FKResult, Machine, ModelExtension
from .file_format import (
    Ballbar,
    BedPlane,
    ConstraintLink,
    MachineFileHead,
    MachineFormat,
    MeasurementFramesSection,
    Number,
    Pose6,
    StrictModel,
    TrackerSection,
    Vector3,
    factors,
    home_pose,
)

LEG_FIELDS = ("base.x", "base.y", "base.z", "platform.x", "platform.y", "platform.z", "l0",
              "gain")
LEG_KINDS = ("length",) * 7 + ("ratio",)


def stewart_parameters(base, platform, l0=None, gain=None, curvature=None) -> ParameterSet:
    """Registry of a six-leg platform from its joints and leg calibrations (SI).

    Parameters
    ----------
    base : array_like, shape (6, 3)
        Base joints ``b_i``, m (base frame).
    platform : array_like, shape (6, 3)
        Platform joints ``p_i``, m (platform frame).
    l0 : array_like, shape (6,) or scalar, optional
        Leg length at zero reading, m; default 0.
    gain : array_like, shape (6,) or scalar, optional
        Leg length per reading unit (m per unit; 1 for readings that are lengths); default 1.
    curvature : array_like, shape (6,) or scalar, optional
        Leg length per reading unit squared (the reading curvature extension); default: none
        (the linear legs, 48 parameters).

    Returns
    -------
    ParameterSet
        48 parameters ``leg{i}.base.x`` ... ``leg{i}.gain``, leg by leg; with ``curvature``
        six more, ``leg1.curvature`` ... ``leg6.curvature``.
    """
    base = np.asarray(base, float).reshape(6, 3)
    platform = np.asarray(platform, float).reshape(6, 3)
    l0 = np.zeros(6) if l0 is None else np.broadcast_to(np.asarray(l0, float), (6,))
    gain = np.ones(6) if gain is None else np.broadcast_to(np.asarray(gain, float), (6,))
    values = np.column_stack([base, platform, l0, gain]).reshape(-1)
    names = [f"leg{i + 1}.{f}" for i in range(6) for f in LEG_FIELDS]
    params = ParameterSet(names, LEG_KINDS * 6, values)
    if curvature is None:
        return params
    return params.concat(curvature_parameters(curvature))


def curvature_parameters(curvature=0.0, fixed=False) -> ParameterSet:
    """The six ``leg{i}.curvature`` parameters (m per reading unit squared).

    Parameters
    ----------
    curvature : array_like, shape (6,) or scalar, optional
        Values; default 0 (the linear legs).
    fixed : bool, optional
        Fixed flags.

    Returns
    -------
    ParameterSet
        Six parameters of kind ``ratio`` (scaled by :meth:`Stewart.parameter_scales`).
    """
    values = np.broadcast_to(np.asarray(curvature, float), (6,))
    return ParameterSet([f"leg{i + 1}.curvature" for i in range(6)], ("ratio",) * 6, values,
                        np.full(6, bool(fixed)))


#: the reading curvature extension in words (:meth:`Stewart.model_extensions`)
CURVATURE_WORDS = ("a per-leg reading nonlinearity: L = l0 + gain r + curvature r^2 (six "
                   "parameters leg{i}.curvature; a lead screw's pitch error, a belt that "
                   "stretches)")


class Stewart(Machine):
    """Six-leg platform (6-UPS / 6-UPU / 6-SPS); see the module docstring.

    Parameters
    ----------
    parameters : ParameterSet
        The 48 leg parameters (:func:`stewart_parameters`).
    home : tuple of ndarray, optional
        ``(P, R)`` pose of the working assembly mode; default: :meth:`default_home`.
    name : str, optional
        Free-text name of the machine.
    reading_unit : str, optional
        Unit of the leg readings in files: a length unit (readings converted to m) or another
        name such as ``rev`` or ``counts`` (readings kept in that unit).
    """

    kind = "stewart"
    #: the instrument of SPEC 2.4 (motion capture)
    default_instrument = "pose"
    chain_word = "leg"
    joint_vector_word = "leg reading"
    joints_read_words = "legs read"
    n_joints = 6
    pose_dof = 6

    def __init__(self, parameters: ParameterSet, home=None, name: str = "",
                 reading_unit: str = "m"):
        super().__init__(parameters, home, name)
        self.reading_unit = reading_unit
        p = parameters
        self._ib = np.stack([p.indices(f"leg{i + 1}.base") for i in range(6)])
        self._ip = np.stack([p.indices(f"leg{i + 1}.platform") for i in range(6)])
        self._il0 = np.array([p.index(f"leg{i + 1}.l0") for i in range(6)])
        self._ig = np.array([p.index(f"leg{i + 1}.gain") for i in range(6)])
        self._ic = (np.array([p.index(f"leg{i + 1}.curvature") for i in range(6)])
                    if "leg1.curvature" in p.names else None)

    @property
    def joint_quantity(self) -> str:
        """"length" when the readings are lengths (mm, m, ...), else "reading"."""
        return "length" if self.reading_unit in LENGTH else "reading"

    # -- geometry -------------------------------------------------------------------------
    def legs(self, u=None):
        """Per-leg parameter arrays, the legs along the first axis.

        Parameters
        ----------
        u : array_like, shape (48,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        base : ndarray, shape (6, 3)
            Base joints, m.
        platform : ndarray, shape (6, 3)
            Platform joints, m.
        l0 : ndarray, shape (6,)
            Leg lengths at zero reading, m.
        gain : ndarray, shape (6,)
            Leg length per reading unit.
        """
        u = self.u if u is None else np.asarray(u, float)
        return u[self._ib], u[self._ip], u[self._il0], u[self._ig]

    def reading_gains(self) -> np.ndarray:
        """Leg length per reading unit of each leg (``gain_i``; :meth:`legs`).

        Returns
        -------
        ndarray, shape (6,)
            The gains, m per reading unit (a ratio for readings in a length unit).
        """
        return self.legs()[3]

    def leg_joints(self, q, u=None):
        """Base joints, platform joints and lengths ``l0 + gain q`` of the six legs at the
        readings ``q`` (the linear reading model: the curvature extension is left out).

        Parameters
        ----------
        q : array_like, shape (6,)
            Readings (internal units).
        u : array_like, shape (n_params,) or (K, n_params), optional
            Parameter vector(s); default: :attr:`u`.

        Returns
        -------
        base : ndarray, shape (..., 6, 3)
            Base joints, m.
        platform : ndarray, shape (..., 6, 3)
            Platform joints, m.
        lengths : ndarray, shape (..., 6)
            Leg lengths, m.
        """
        u = self.u if u is None else np.asarray(u, float)
        return (u[..., self._ib], u[..., self._ip],
                u[..., self._il0] + u[..., self._ig] * np.asarray(q, float))

    @property
    def has_curvature(self) -> bool:
        """Whether the legs carry the reading curvature parameters (the extension)."""
        return self._ic is not None

    def curvature(self, u=None) -> np.ndarray:
        """Leg length per reading unit squared of each leg (zeros without the extension).

        Parameters
        ----------
        u : array_like, shape (n_params,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        ndarray, shape (6,)
            ``curvature_i``, m per reading unit squared.
        """
        if self._ic is None:
            return np.zeros(6)
        u = self.u if u is None else np.asarray(u, float)
        return u[self._ic]

    def with_curvature(self, curvature=0.0, fixed: bool = False) -> Stewart:
        """A copy with the reading curvature parameters (the extension), at ``curvature``.

        Parameters
        ----------
        curvature : array_like, shape (6,) or scalar, optional
            Start values, m per reading unit squared; default 0 (the same machine).
        fixed : bool, optional
            Hold them (a calibration does not change them).

        Returns
        -------
        Stewart
            The copy (every other attribute shared); this machine when it has them already.
        """
        if self._ic is not None:
            return self
        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        new.parameters = self.parameters.concat(curvature_parameters(curvature, fixed))
        new._ic = np.array([new.parameters.index(f"leg{i + 1}.curvature") for i in range(6)])
        return new

    def model_extensions(self) -> list[ModelExtension]:
        """The reading curvature of every leg (:data:`CURVATURE_WORDS`), unless present.

        Returns
        -------
        list of ModelExtension
            One candidate, ``reading curvature``; none when the legs carry it already.
        """
        if self._ic is not None:
            return []
        return [ModelExtension("reading curvature", CURVATURE_WORDS,
                               tuple(f"leg{i + 1}.curvature" for i in range(6)),
                               lambda machine: machine.with_curvature())]

    def reading_sigma(self, sigma_length: float) -> np.ndarray:
        """Standard deviation of each leg reading for a reading noise stated as a leg length.

        Parameters
        ----------
        sigma_length : float
            Reading noise as a leg length, m.

        Returns
        -------
        ndarray, shape (6,)
            ``sigma_length / |gain|`` per leg (nominal gains), in reading units.
        """
        return float(sigma_length) / np.abs(self.legs()[3])

    def characteristic_length(self) -> float:
        b, p, _, _ = self.legs()
        return float(max(np.mean(np.linalg.norm(b - b.mean(0), axis=-1)),
                         np.mean(np.linalg.norm(p - p.mean(0), axis=-1)), 1e-3))

    def parameter_scales(self) -> np.ndarray:
        """Lengths by the characteristic length; a gain by its own size (a relative change).

        Returns
        -------
        ndarray, shape (n_params,)
            Column scale of each parameter (1 for a zero gain); a curvature by
            ``gain^2 / characteristic length``.
        """
        s = self.parameters.scales(self.characteristic_length())
        g = np.abs(self.u[self._ig])
        s[self._ig] = np.where(g > 0, g, 1.0)
        if self._ic is not None:
            # the curvature that moves a leg by the characteristic length at the reading that
            # spans it (Lc / |gain|): gain^2 / Lc
            lc = self.characteristic_length()
            s[self._ic] = np.where(g > 0, g**2 / lc, 1.0 / lc)
        return s

    def default_home(self):
        """Platform centred above the base joints, orientation identity.

        The height is where the legs have the length they have in the platform's middle position:
        the mean ``l0`` (readings 0) when every ``l0`` is positive, else the mean radius of the base
        joint circle plus that of the platform joint circle.

        Returns
        -------
        P : ndarray, shape (3,)
            Home position, m.
        R : ndarray, shape (3, 3)
            The identity.
        """
        b, p, l0, _ = self.legs()
        offset = b.mean(0) - p.mean(0)
        length = np.mean(l0) if np.all(l0 > 0) else \
            np.mean(np.linalg.norm(b - b.mean(0), axis=-1)) + np.mean(
                np.linalg.norm(p - p.mean(0), axis=-1))
        horizontal = np.mean(np.linalg.norm((b - b.mean(0))[:, :2] - (p - p.mean(0))[:, :2],
                                            axis=-1))
        height = np.sqrt(max(length**2 - horizontal**2, (0.5 * length) ** 2))
        return offset + np.array([0.0, 0.0, height]), np.eye(3)

    # -- validation -----------------------------------------------------------------------
    def geometry_problems(self, home_given: bool = True) -> list[tuple[tuple, str]]:
        """Degenerate legs (see :meth:`Machine.geometry_problems`).

        Refused: two legs between the same joints (within 1e-6 of the machine's size: the
        same leg twice, the Jacobian is singular everywhere); six legs that do not hold the
        platform at home (given, or the default home: a singular leg Jacobian, e.g. six
        parallel legs or a leg of zero length), where forward kinematics starts.

        Parameters
        ----------
        home_given : bool, optional
            True when the home pose was given (the machine file's ``home``), False when it is
            :meth:`default_home`; decides which key a problem at home names.

        Returns
        -------
        list of tuple
            ``(key_path, what)``: the machine file key concerned as a path tuple and the
            problem in words, most specific first; empty when the geometry can work.
        """
        b, p, _, _ = self.legs()
        tol = 1e-6 * self.characteristic_length()
        for j in range(6):
            for i in range(j):
                if np.linalg.norm(b[i] - b[j]) <= tol and np.linalg.norm(p[i] - p[j]) <= tol:
                    return [(("legs", j), f"the same leg as legs[{i}] (the same base and "
                             "platform joints): only five legs hold the platform; check the "
                             "legs' base and platform")]
        _, singular = self._home_check()
        if singular:
            key, what = (("home",), "at home") if home_given else \
                (("legs",), "at the default home (platform centred above the base)")
            return [(key, f"the six legs do not hold the platform {what} (their directions "
                     "are linearly dependent); check the joint coordinates and home")]
        return []

    # -- kinematics -----------------------------------------------------------------------
    def leg_vectors(self, P, R, u=None):
        """Leg vectors, platform joint offsets and leg lengths at poses.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions ``t``, m.
        R : array_like, shape (..., 3, 3)
            Platform orientations.
        u : array_like, shape (48,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        w : ndarray, shape (..., 6, 3)
            ``w_i = t + R p_i - b_i``, m.
        s : ndarray, shape (..., 6, 3)
            ``s_i = R p_i``, m.
        L : ndarray, shape (..., 6)
            Leg lengths ``|w_i|``, m.
        """
        b, p, _, _ = self.legs(u)
        s = np.einsum("...ij,kj->...ki", np.asarray(R, float), p)
        w = np.asarray(P, float)[..., None, :] + s - b
        return w, s, np.linalg.norm(w, axis=-1)

    def ik_jacobians(self, P, R, u=None, want_du: bool = True):
        """Readings at poses and their derivatives (:meth:`Machine.ik_jacobians`).

        The reading solves ``l0 + gain r + curvature r^2 = L``: ``r = (L - l0) / gain``
        without the curvature, else the root nearest it,
        ``r = 2 (L - l0) / (gain + sqrt(gain^2 + 4 curvature (L - l0)))``; every derivative
        is that of the length over the slope ``dL/dr = gain + 2 curvature r``.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m (base frame).
        R : array_like, shape (..., 3, 3)
            Platform orientations.
        u : array_like, shape (n_params,), optional
            Parameter vector (internal units); default: :attr:`u`.
        want_du : bool, optional
            Also compute the derivatives with respect to the parameters.

        Returns
        -------
        r : ndarray, shape (..., 6)
            Readings (internal units); NaN where no reading gives the leg's length.
        dq_dpose : ndarray, shape (..., 6, 6)
            Derivatives with respect to ``[dP, dOmega]``: ``J_p`` over the slope.
        dq_du : ndarray, shape (..., 6, n_params) or None
            Derivatives with respect to the parameters; None unless ``want_du``.
        """
        b, p, l0, g = self.legs(u)
        w, s, L = self.leg_vectors(P, R, u)
        z = w / L[..., None]
        if self._ic is None:
            r = (L - l0) / g
            slope = np.broadcast_to(g, r.shape)
        else:
            c = self.curvature(u)
            d = L - l0
            with np.errstate(invalid="ignore"):     # no reading gives that length: NaN
                root = np.sqrt(g**2 + 4.0 * c * d)
            r = 2.0 * d / (g + np.sign(g) * root)
            slope = g + 2.0 * c * r
        zg = z / slope[..., None]
        dq_dpose = np.concatenate([zg, np.cross(s, zg)], -1)     # J_p / slope
        if not want_du:
            return r, dq_dpose, None
        R = np.asarray(R, float)
        cols = [
            -zg,                                                  # d r / d base
            np.einsum("...ji,...kj->...ki", R, zg),               # d r / d platform = R^T z/g
            (-1.0 / slope)[..., None],                            # d r / d l0
            (-r / slope)[..., None],                              # d r / d gain
        ]
        idx = [self._ib, self._ip, self._il0[:, None], self._ig[:, None]]
        if self._ic is not None:
            cols.append((-r * r / slope)[..., None])              # d r / d curvature
            idx.append(self._ic[:, None])
        dq_du = np.zeros(r.shape + (len(self.parameters),))
        dq_du[..., np.arange(6)[:, None], np.concatenate(idx, -1)] = np.concatenate(cols, -1)
        return r, dq_dpose, dq_du

    def lengths(self, r, u=None):
        """Leg lengths for readings ``r``: ``l0 + gain r`` (``+ curvature r^2``).

        Parameters
        ----------
        r : array_like, shape (..., 6)
            Leg readings (internal units: m for length readings, else the reading unit).
        u : array_like, shape (48,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        ndarray, shape (..., 6)
            Leg lengths, m.
        """
        _, _, l0, g = self.legs(u)
        r = np.asarray(r, float)
        if self._ic is None:
            return l0 + g * r
        return l0 + (g + self.curvature(u) * r) * r

    def jacobians(self, P, R, u=None):
        """Seed 003 eq. 8-10 at poses: the pose and joint Jacobians of the leg lengths.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m.
        R : array_like, shape (..., 3, 3)
            Platform orientations.
        u : array_like, shape (48,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        Jp : ndarray, shape (..., 6, 6)
            Row i ``[z_i^T, (s_i x z_i)^T]``: leg lengths with respect to ``[dP, dOmega]``.
        Js : ndarray, shape (..., 6, 6)
            Row i ``[z_i^T R, -z_i^T]``: leg i's length with respect to its own
            ``[dp_i (platform frame, 3), db_i (3)]``.
        z : ndarray, shape (..., 6, 3)
            Unit leg vectors.
        """
        w, s, L = self.leg_vectors(P, R, u)
        z = w / L[..., None]
        Jp = np.concatenate([z, np.cross(s, z)], -1)
        zR = np.einsum("...ki,...ij->...kj", z, np.asarray(R, float))
        Js = np.concatenate([zR, -z], -1)
        return Jp, Js, z

    def fk(self, q, u=None, start=None, tol: float = 1e-12, max_iter: int = 50,
           raise_on_failure: bool = False, continuation: bool = False) -> FKResult:
        """Forward kinematics by Newton (:meth:`Machine.fk`), optionally by continuation.

        Parameters
        ----------
        q : array_like, shape (K, 6)
            Leg readings (internal units).
        u : array_like, shape (48,), optional
            Parameter vector (internal units); default: :attr:`u`.
        start : tuple of array_like, optional
            ``(P0, R0)`` start pose(s); default: :attr:`home`.
        tol : float, optional
            Convergence when the largest leg-length residual ``|gain (r(pose) - q)|`` is
            below ``tol`` times the characteristic length (both in m, whatever the reading
            unit).
        max_iter : int, optional
            Maximum Newton iterations per pose.
        raise_on_failure : bool, optional
            Raise instead of returning poses that did not converge.
        continuation : bool, optional
            Solve the rows one after the other, each starting from the previous row's solution
            (trajectories: stays on the assembly branch); ``start`` must then be a single pose.

        Returns
        -------
        FKResult
            Poses, convergence and residuals (leg lengths, m); with ``continuation``,
            ``iterations`` is ``max_iter``.

        Raises
        ------
        ConvergenceError
            With ``raise_on_failure``, when a pose did not converge.
        """
        if not continuation:
            return super().fk(q, u, start, tol, max_iter, raise_on_failure)
        q = np.atleast_2d(np.asarray(q, float))
        P0, R0 = self.home if start is None else start
        Ps, Rs, ok, res = [], [], [], []
        for row in q:          # sequential by nature: each start is the previous solution
            sol = super().fk(row[None], u, (P0, R0), tol, max_iter)
            Ps.append(sol.P[0])
            Rs.append(sol.R[0])
            ok.append(sol.converged[0])
            res.append(sol.residual[0])
            if sol.converged[0]:
                P0, R0 = sol.P[0], sol.R[0]
        result = FKResult(np.array(Ps), np.array(Rs), np.array(ok), np.array(res), max_iter)
        if raise_on_failure:
            result.raise_if_failed()
        return result

    def _fk_system(self, q, P, R, u):
        """Newton system of :meth:`fk` in leg lengths (m), not in readings.

        The convergence tolerance of :meth:`Machine.fk` is a length (``tol`` times the
        characteristic length), so the residual must be one too: ``gain (r(pose) - q)`` =
        ``L(pose) - (l0 + gain q)``, with the Jacobian ``gain dr/dpose`` (= ``J_p``). In
        readings, a reading unit that is not a length (``counts``: the gain is e.g. 1e-6 m per
        count, the readings ~1e5) would put the residual's rounding (one ulp of the reading)
        far above the tolerance, and every pose would "fail" to converge. The Newton step is
        the same either way.
        """
        g = self.legs(u)[3]
        qc, J, _ = self.ik_jacobians(P, R, u, want_du=False)
        return (qc - q) * g, J * g[:, None]

    # -- frames ---------------------------------------------------------------------------
    def transform_base(self, u, G, t=None):
        """Base joints in a base frame rotated by ``G`` (and moved: ``b' = G b + t``).

        Parameters
        ----------
        u : array_like, shape (48,)
            Parameter vector (internal units).
        G : array_like, shape (3, 3)
            Rotation from the old to the new base frame.
        t : array_like, shape (3,), optional
            Translation of the new base frame, m.

        Returns
        -------
        ndarray, shape (48,)
            The transformed parameter vector (only the base joints change).
        """
        u = np.array(u, float)
        b = self.legs(u)[0] @ np.asarray(G).T
        u[self._ib] = b if t is None else b + np.asarray(t, float)
        return u

    def transform_platform(self, u, C, t=None):
        """Platform joints in a re-oriented (and moved) platform frame: ``p' = C^T (p - t)``.

        Parameters
        ----------
        u : array_like, shape (48,)
            Parameter vector (internal units).
        C : array_like, shape (3, 3)
            Rotation of the new platform frame relative to the old one.
        t : array_like, shape (3,), optional
            Origin of the new platform frame in the old one, m.

        Returns
        -------
        ndarray, shape (48,)
            The transformed parameter vector (only the platform joints change).
        """
        u = np.array(u, float)
        p = self.legs(u)[1]
        u[self._ip] = (p if t is None else p - np.asarray(t, float)) @ np.asarray(C)
        return u


def cubic_6upu(a=0.16, b=0.14, c=0.195, d=0.270, e=0.055, f=0.205, g=0.130, z1=0.130,
               z2=0.130, z3=0.280, height=0.41) -> Stewart:
    """The cubic 6-UPU device of seed 003 Table 2 (SPEC 2.3), with ``P5 = (c, e, -d)``.

    Three links along Z, two along X, one along Y. Readings are leg lengths in metres (gain 1,
    l0 0).

    Parameters
    ----------
    a, b, c, d, e, f, g : float, optional
        Table 2 dimensions of the joint layout, m.
    z1, z2, z3 : float, optional
        Heights of base joints 4, 5 and 6, m.
    height : float, optional
        Height of the home position, m.

    Returns
    -------
    Stewart
        A new nominal device with home ``((0, 0, height), I)``.
    """
    base = [(b, -a, 0), (b, a, 0), (-b, 0, 0), (-c, -e, z1), (-c, e, z2), (0, f, z3)]
    platform = [(b, -a, 0), (b, a, 0), (-b, 0, 0), (c, -e, -d), (c, e, -d), (0, -f, -g)]
    return Stewart(stewart_parameters(base, platform), home=(np.array([0, 0, height]),
                                                             matrix_from_euler([0, 0, 0])),
                   name="cubic 6-UPU parallel device (seed 003 Table 2, P5 = (c, e, -d))")


# --------------------------------------------------------------------------------------------
# The machine file section (``machine: stewart``)
# --------------------------------------------------------------------------------------------

#: units a Stewart leg may read in and that are converted to metres (data-file suffixes)
READING_LENGTH_UNITS = ("mm", "m", "um", "in")
_READING_UNIT = re.compile(r"^[A-Za-z][A-Za-z0-9]*$")


def reading_factor(unit: str) -> float:
    """SI factor of a Stewart reading unit: a length unit's factor, 1 for any other word."""
    return LENGTH[unit] if unit in LENGTH else 1.0


class Readings(StrictModel):
    """What a Stewart leg reports: ``unit`` is a length unit (mm, m, um: the reading is a
    length, converted to metres) or any other word (rev, counts, deg: kept as read; the gain
    converts it)."""

    unit: str

    @field_validator("unit")
    @classmethod
    def _unit_word(cls, value):
        if not _READING_UNIT.match(value):
            raise PydanticCustomError(
                "reading_unit", "a reading unit is one word of letters and digits (mm, rev, "
                "counts), got {value}", {"value": repr(value)})
        if value in LENGTH and value not in READING_LENGTH_UNITS:
            raise PydanticCustomError(
                "reading_unit", "{value} is a length unit the data files do not use: readings "
                "in a length unit are mm, m, um or in", {"value": repr(value)})
        quantity = unit_of(value)
        if quantity not in (None, "length", "angle"):
            raise PydanticCustomError(
                "reading_unit", "{value} is a unit of {quantity}, not of what a leg reads: a "
                "length (mm, m, um), an angle (deg, rad) or a count (rev, counts)",
                {"value": repr(value), "quantity": quantity.replace("_", " ")})
        return value


class StewartLeg(StrictModel):
    """One leg: base joint (base frame), platform joint (platform frame), length at zero
    reading ``l0`` and ``gain`` (file length unit per reading unit): ``L = l0 + gain r``.
    Without ``l0`` and ``gain`` the leg reads its length (``l0 = 0``, ``gain = 1``, SPEC 7)."""

    base: Vector3
    platform: Vector3
    l0: Number = 0.0
    gain: Number = 1.0
    curvature: Number | None = None

    @field_validator("gain")
    @classmethod
    def _nonzero_gain(cls, value):
        if value == 0:
            raise PydanticCustomError("zero_gain", "must not be 0 (length per reading unit)")
        return value


class StewartFile(MachineFileHead):
    """``machine: stewart`` (SPEC 6)."""

    machine: Literal["stewart"]
    readings: Readings | None = None
    constraint_link: ConstraintLink | None = None
    legs: Annotated[list[StewartLeg], Field(min_length=6, max_length=6)]
    tracker: TrackerSection | None = None
    ballbar: Ballbar | None = None
    bed: BedPlane | None = None
    measurement_frames: MeasurementFramesSection | None = None
    home: Pose6 | None = None


def _reading_length_unit(unit: str) -> str:
    """A file's length unit as the legs' reading unit: the data files' name of the same unit
    (``inch`` -> ``in``), which :class:`Readings` reads back when the file is written."""
    if unit in READING_LENGTH_UNITS:
        return unit
    return next((u for u in READING_LENGTH_UNITS if LENGTH[u] == LENGTH.get(unit)), unit)


def _build(doc: StewartFile, source: str) -> Stewart:
    fl, fa = factors(doc.units.model_dump())
    unit = (doc.readings.unit if doc.readings is not None
            else _reading_length_unit(doc.units.length))
    gain_factor = fl / reading_factor(unit)          # file gain -> internal gain
    legs = doc.legs
    params = stewart_parameters(
        base=np.array([leg.base for leg in legs]) * fl,
        platform=np.array([leg.platform for leg in legs]) * fl,
        l0=np.array([leg.l0 for leg in legs]) * fl,
        gain=np.array([leg.gain for leg in legs]) * gain_factor,
        # file length unit per reading unit squared -> internal
        curvature=None if all(leg.curvature is None for leg in legs) else np.array(
            [leg.curvature or 0.0 for leg in legs]) * fl / reading_factor(unit) ** 2,
    )
    machine = Stewart(params, home=home_pose(doc.home, fl, fa), name=doc.name or "",
                      reading_unit=unit)
    # without ``readings:`` the data's column suffix says the unit (SPEC 7): the first data
    # file read fixes it (csv_io.adopt_reading_unit); until then the legs read lengths
    machine.reading_unit_declared = doc.readings is not None
    machine.constraint_link_length = (doc.constraint_link.length * fl
                                      if doc.constraint_link is not None else None)
    return machine


def _dump(machine: Stewart, units: dict) -> dict[str, Any]:
    fl, _ = factors(units)
    unit = getattr(machine, "reading_unit", units["length"])
    gain_factor = fl / reading_factor(unit)
    b, p, l0, g = machine.legs()
    out: dict[str, Any] = {"readings": {"unit": unit}}
    lc = getattr(machine, "constraint_link_length", None)
    if lc is not None:
        out["constraint_link"] = {"length": float(lc) / fl}
    out["legs"] = [
        {"base": [float(v) / fl for v in b[i]], "platform": [float(v) / fl for v in p[i]],
         "l0": float(l0[i]) / fl, "gain": float(g[i]) / gain_factor}
        for i in range(6)
    ]
    if machine.has_curvature:
        for leg, c in zip(out["legs"], machine.curvature(), strict=True):
            leg["curvature"] = float(c) * reading_factor(unit) ** 2 / fl
    return out


def _size(doc) -> tuple[float, str]:
    fl = LENGTH[doc.units.length]
    with np.errstate(all="ignore"):
        norms = [float(np.linalg.norm(np.asarray(v, float) / 2)) * 2
                 for leg in doc.legs for v in (leg.base, leg.platform)]
    return float(np.median(norms)) * fl, "the median distance of the leg joints from the origin"


#: the machine file section of a six-leg platform (:mod:`pkmcal.machines.registry`)
FILE_FORMAT = MachineFormat(
    StewartFile, _build, _dump, {"legs": 6},
    hints={"legs": "a list of 6 legs {base: [x, y, z], platform: [x, y, z], l0, gain}"},
    kinds={("legs", "*", "base", "*"): "length", ("legs", "*", "platform", "*"): "length",
           ("legs", "*", "l0"): "length", ("legs", "*", "gain"): "gain",
           ("constraint_link", "length"): "dimension"},
    size=_size, kind=Stewart.kind)
