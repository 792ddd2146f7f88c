"""3-RPR planar parallel robot: three prismatic legs between revolute pivots (SPEC 8).

Leg i (i = 1, 2, 3) joins the base pivot ``A_i = (x, y)`` (base frame, a revolute joint about
z) and the platform pivot ``B_i = (x, y)`` (platform frame, a revolute joint about z); its
prismatic actuator sets the leg's length. The platform lives in the plane ``z = 0`` of the
base frame: its pose is ``x, y`` and the rotation ``phi`` about z, i.e. ``P = (x, y, 0)`` and
``R = Rz(phi)``; it moves along the pose coordinates ``(x, y, rz)`` (``pose_space = (0, 1,
5)``: the pose Jacobian has the six columns ``[dP, dOmega]`` of every machine, those of z, rx
and ry are zero in the plane).

Reading convention (as a Stewart leg's, SPEC 2.4): the leg length is

    L_i = |P + R B_i - A_i| = l0_i + gain_i q_i

with ``l0_i`` the length at zero reading (a cylinder's retracted length, the encoder's zero)
and ``gain_i`` the length per unit of reading (1: the reading is the leg's travel in the
file's length unit; readings are lengths, ``q1_mm..q3_mm``, converted to metres). So each leg
has 6 parameters, ``leg{i}.base.x/y``, ``leg{i}.platform.x/y``, ``leg{i}.l0`` (m) and
``leg{i}.gain`` (a ratio): 18 in all. Inverse kinematics is closed form, ``q_i = (L_i - l0_i)
/ gain_i``; forward kinematics is Newton on it in ``(x, y, phi)`` from home
(:meth:`Machine.fk`).

Frame motions (what no measurement of the machine alone can see): a rigid motion of the base
frame in its plane (moving the three base pivots together: 2 translations, the rotation about
z) and one of the platform frame in its plane (moving the three platform pivots together).
A tracker sees neither: its own frame absorbs the first, the target's place on the platform
the second (with 18 + 6 + 3 unknowns, 20 combinations are identifiable from points: the
target's height and the tracker frame's height move together as well).

The machine file (SPEC 6)::

    pkmcal: 1
    machine: planar_3rpr
    units: {length: mm, angle: deg}
    legs:                                    # exactly 3: L = l0 + gain * reading
      - {base: [0.0, 500.0], platform: [-100.0, 0.0], l0: 300.0, gain: 1.0}
      - {base: [-433.0127, -250.0], platform: [50.0, -86.6025], l0: 300.0, gain: 1.0}
      - {base: [433.0127, -250.0], platform: [50.0, 86.6025], l0: 300.0, gain: 1.0}
    home: [0.0, 0.0, 0.0]                    # x, y, phi (rotation about z)

``l0`` is in the file's length unit; ``gain`` is a ratio (length per length of reading);
a leg without ``l0``/``gain`` reads its length (``l0 = 0``, ``gain = 1``). Every machine file
may add the instrument sections (``tracker``, ``ballbar``, ``bed``), ``joint_limits`` and
``calibration``; :mod:`pkmcal.io.machine_file` adds them to :data:`FILE_FORMAT`.
"""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic import Field, field_validator
from pydantic_core import PydanticCustomError

from ..kinematics import matrix_from_euler, matrix_from_rotvec
from ..parameters import ParameterSet
from ..units import ANGLE, LENGTH
from .base import FrameMotion, Machine, ParameterSubset
from .file_format import MachineFormat, Number, StrictModel, Vector2

LEG_FIELDS = ("base.x", "base.y", "platform.x", "platform.y", "l0", "gain")
LEG_KINDS = ("length",) * 5 + ("ratio",)
#: largest |gain| of a file (a reading that is a thousandth of the length it moves, or 1000x)
MAX_GAIN = 1e3


def planar_3rpr_parameters(base, platform, l0=None, gain=None) -> ParameterSet:
    """The 18 parameters of a 3-RPR planar robot from its pivots and leg calibrations (SI).

    Parameters
    ----------
    base : array_like, shape (3, 2)
        Base pivots ``A_i``, m (base frame).
    platform : array_like, shape (3, 2)
        Platform pivots ``B_i``, m (platform frame).
    l0 : array_like, shape (3,) or scalar, optional
        Leg length at zero reading, m; default 0.
    gain : array_like, shape (3,) or scalar, optional
        Leg length per unit of reading (a ratio); default 1.

    Returns
    -------
    ParameterSet
        ``leg{i}.base.x`` ... ``leg{i}.gain``, leg by leg.
    """
    base = np.asarray(base, float).reshape(3, 2)
    platform = np.asarray(platform, float).reshape(3, 2)
    l0 = np.zeros(3) if l0 is None else np.broadcast_to(np.asarray(l0, float), (3,))
    gain = np.ones(3) if gain is None else np.broadcast_to(np.asarray(gain, float), (3,))
    values = np.column_stack([base, platform, l0, gain]).reshape(-1)
    names = [f"leg{i + 1}.{f}" for i in range(3) for f in LEG_FIELDS]
    return ParameterSet(names, LEG_KINDS * 3, values)


def _in_plane(v) -> np.ndarray:
    """(..., 2) points as (..., 3) points of the plane z = 0."""
    v = np.asarray(v, float)
    return np.concatenate([v, np.zeros(v.shape[:-1] + (1,))], -1)


class Planar3RPR(Machine):
    """3-RPR planar parallel robot; see the module docstring.

    Parameters
    ----------
    parameters : ParameterSet
        The 18 leg parameters (:func:`planar_3rpr_parameters`).
    home : tuple of ndarray, optional
        ``(P, R)`` pose of the working assembly mode (``P[2] = 0``, ``R`` a rotation about z);
        default: :meth:`default_home`.
    name : str, optional
        Free-text name of the machine.
    """

    kind = "planar_3rpr"
    n_joints = 3
    #: three degrees of freedom: x, y and the rotation about z (:attr:`POSE_SPACE`)
    pose_dof = 3
    POSE_SPACE = (0, 1, 5)
    joint_quantity = "length"
    default_instrument = "tracker"
    PARAMETER_SETS = {
        "offsets": ParameterSubset(
            ("leg1.l0", "leg2.l0", "leg3.l0"),
            "the legs' length offsets l0 alone (the actuators' zero: a homing calibration); "
            "pivots and gains held"),
        "kinematic": ParameterSubset(
            tuple(f"leg{i}.{f}" for i in (1, 2, 3) for f in ("base", "platform", "l0")),
            "pivots and length offsets; the gains held (encoders trusted per unit)"),
    }

    def __init__(self, parameters: ParameterSet, home=None, name: str = ""):
        super().__init__(parameters, home, name)
        p = parameters
        self._ia = np.stack([p.indices(f"leg{i + 1}.base") for i in range(3)])
        self._ib = np.stack([p.indices(f"leg{i + 1}.platform") for i in range(3)])
        self._il0 = np.array([p.index(f"leg{i + 1}.l0") for i in range(3)])
        self._ig = np.array([p.index(f"leg{i + 1}.gain") for i in range(3)])

    # -- geometry -------------------------------------------------------------------------
    def legs(self, u=None):
        """Per-leg parameter arrays, the legs along the first axis.

        Parameters
        ----------
        u : array_like, shape (18,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        base : ndarray, shape (3, 2)
            Base pivots ``A_i``, m.
        platform : ndarray, shape (3, 2)
            Platform pivots ``B_i``, m (platform frame).
        l0 : ndarray, shape (3,)
            Leg lengths at zero reading, m.
        gain : ndarray, shape (3,)
            Leg length per unit of reading.
        """
        u = self.u if u is None else np.asarray(u, float)
        return u[self._ia], u[self._ib], u[self._il0], u[self._ig]

    def characteristic_length(self) -> float:
        """The larger mean radius of the base and of the platform pivots about their centre, m
        (at least 1 mm)."""
        a, b, _, _ = self.legs()
        return float(max(np.mean(np.linalg.norm(a - a.mean(0), axis=-1)),
                         np.mean(np.linalg.norm(b - b.mean(0), axis=-1)), 1e-3))

    def parameter_scales(self) -> np.ndarray:
        """Lengths by the characteristic length; a gain by its own size (a relative change).

        Returns
        -------
        ndarray, shape (18,)
            Column scale of each parameter (1 for a zero gain).
        """
        s = self.parameters.scales(self.characteristic_length())
        g = np.abs(self.u[self._ig])
        s[self._ig] = np.where(g > 0, g, 1.0)
        return s

    def reading_sigma(self, sigma_length: float) -> np.ndarray:
        """Standard deviation of each reading for a reading noise stated as a leg length.

        Parameters
        ----------
        sigma_length : float
            Reading noise as a leg length, m.

        Returns
        -------
        ndarray, shape (3,)
            ``sigma_length / |gain|`` per leg (nominal gains).
        """
        return float(sigma_length) / np.abs(self.legs()[3])

    def default_home(self):
        """The platform's pivot centre on the base pivots' centre, not rotated.

        Returns
        -------
        P : ndarray, shape (3,)
            Home position, m (z = 0).
        R : ndarray, shape (3, 3)
            The identity.
        """
        a, b, _, _ = self.legs()
        return _in_plane(a.mean(0) - b.mean(0)), np.eye(3)

    # -- validation -----------------------------------------------------------------------
    def geometry_problems(self, home_given: bool = True) -> list[tuple[tuple, str]]:
        """Degenerate legs (see :meth:`Machine.geometry_problems`).

        Refused: two legs between the same pivots (within 1e-6 of the machine's size); a home
        off the plane z = 0 or turned out of it; legs that do not hold the platform at home
        (concurrent or parallel leg lines: a singular Jacobian; a leg of zero length).

        Parameters
        ----------
        home_given : bool, optional
            True when the home pose was given (the file's ``home``), False when it is
            :meth:`default_home`.

        Returns
        -------
        list of tuple
            ``(key_path, what)``, most specific first; empty when the geometry can work.
        """
        a, b, _, _ = self.legs()
        tol = 1e-6 * self.characteristic_length()
        for j in range(3):
            for i in range(j):
                if np.linalg.norm(a[i] - a[j]) <= tol and np.linalg.norm(b[i] - b[j]) <= tol:
                    return [(("legs", j), f"the same leg as legs[{i}] (the same base and "
                             "platform pivots): only two legs hold the platform; check the "
                             "legs' base and platform")]
        P, R = self.home
        if abs(float(P[2])) > tol or not np.allclose(R[2], [0.0, 0.0, 1.0], atol=1e-9):
            return [(("home",), "a planar platform's home lies in the plane z = 0, turned "
                     "about z only")]
        _, singular = self._home_check()
        if singular:
            key, what = (("home",), "at home") if home_given else \
                (("legs",), "at the default home (the platform's pivot centre on the base's)")
            return [(key, f"the three legs do not hold the platform {what} (their lines meet "
                     "in one point or are parallel, or a leg has zero length); check the "
                     "pivots and home")]
        return []

    def in_plane(self, P, R) -> np.ndarray:
        """Where poses lie in the platform's plane: ``z = 0``, turned about z only.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m.
        R : array_like, shape (..., 3, 3)
            Platform orientations.

        Returns
        -------
        ndarray of bool, shape (...)
            True for poses of the plane (within 1e-9 of the machine's size and 1e-9 rad).
        """
        P, R = np.asarray(P, float), np.asarray(R, float)
        return ((np.abs(P[..., 2]) <= 1e-9 * self.characteristic_length())
                & (np.abs(R[..., 2, 2] - 1.0) <= 1e-12))

    def working_mode(self, P, R, u=None) -> np.ndarray:
        """Poses of the working mode (:meth:`Machine.working_mode`) that lie in the plane.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m.
        R : array_like, shape (..., 3, 3)
            Platform orientations.
        u : array_like, shape (18,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        ndarray of bool, shape (...)
            True where the pose can be commanded.
        """
        return super().working_mode(P, R, u) & self.in_plane(P, R)

    # -- kinematics -----------------------------------------------------------------------
    def leg_vectors(self, P, R, u=None):
        """Leg vectors, rotated platform pivots and leg lengths at poses.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m (z = 0 in the plane).
        R : array_like, shape (..., 3, 3)
            Platform orientations (rotations about z in the plane).
        u : array_like, shape (18,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        w : ndarray, shape (..., 3, 3)
            ``w_i = P + R B_i - A_i``, m.
        s : ndarray, shape (..., 3, 3)
            ``s_i = R B_i``, m.
        L : ndarray, shape (..., 3)
            Leg lengths ``|w_i|``, m.
        """
        a, b, _, _ = self.legs(u)
        s = np.einsum("...ij,kj->...ki", np.asarray(R, float), _in_plane(b))
        w = np.asarray(P, float)[..., None, :] + s - _in_plane(a)
        return w, s, np.linalg.norm(w, axis=-1)

    def ik_jacobians(self, P, R, u=None, want_du: bool = True):
        """Readings at poses and their derivatives (:meth:`Machine.ik_jacobians`).

        ``q = (L - l0) / gain``; with ``z_i = w_i / L_i`` the unit leg vector,
        ``dq/dP = z / gain``, ``dq/dOmega = (R B) x z / gain`` (z, rx, ry columns vanish in
        the plane), ``dq/dA = -z_xy / gain``, ``dq/dB = (R^T z)_xy / gain``,
        ``dq/dl0 = -1 / gain`` and ``dq/dgain = -q / gain``.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m (base frame).
        R : array_like, shape (..., 3, 3)
            Platform orientations.
        u : array_like, shape (18,), optional
            Parameter vector (internal units); default: :attr:`u`.
        want_du : bool, optional
            Also compute the derivatives with respect to the parameters.

        Returns
        -------
        q : ndarray, shape (..., 3)
            Readings, m.
        dq_dpose : ndarray, shape (..., 3, 6)
            Derivatives with respect to ``[dP, dOmega]``.
        dq_du : ndarray, shape (..., 3, 18) or None
            Derivatives with respect to the parameters; None unless ``want_du``.
        """
        _, _, l0, g = self.legs(u)
        w, s, L = self.leg_vectors(P, R, u)
        with np.errstate(invalid="ignore", divide="ignore"):
            z = w / L[..., None]
        q = (L - l0) / g
        zg = z / g[:, None]
        dq_dpose = np.concatenate([zg, np.cross(s, zg)], -1)
        if not want_du:
            return q, dq_dpose, None
        R = np.asarray(R, float)
        cols = np.concatenate([
            -zg[..., :2],                                                   # d q / d A
            np.einsum("...ji,...kj->...ki", R, zg)[..., :2],                # d q / d B
            np.broadcast_to(-1.0 / g[:, None], q.shape + (1,)),             # d q / d l0
            (-q / g)[..., None],                                            # d q / d gain
        ], -1)
        idx = np.concatenate([self._ia, self._ib, self._il0[:, None], self._ig[:, None]], -1)
        dq_du = np.zeros(q.shape + (len(self.parameters),))
        dq_du[..., np.arange(3)[:, None], idx] = cols
        return q, dq_dpose, dq_du

    def lengths(self, q, u=None) -> np.ndarray:
        """Leg lengths for readings: ``l0 + gain q``.

        Parameters
        ----------
        q : array_like, shape (..., 3)
            Readings, m.
        u : array_like, shape (18,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        ndarray, shape (..., 3)
            Leg lengths, m.
        """
        _, _, l0, g = self.legs(u)
        return l0 + g * np.asarray(q, float)

    def _fk_system(self, q, P, R, u):
        """Newton system of :meth:`Machine.fk` in leg lengths (m): ``gain (q(pose) - q)``."""
        g = self.legs(u)[3]
        qc, J, _ = self.ik_jacobians(P, R, u, want_du=False)
        return (qc - q) * g, J * g[:, None]

    # -- frames ---------------------------------------------------------------------------
    def _plane_motion(self, G, t) -> tuple[np.ndarray, np.ndarray]:
        """``(G (2, 2), t (2,))`` of a rigid motion of the plane; ValueError for one that
        takes the plane z = 0 out of itself (not expressible by pivots in the plane)."""
        G = np.asarray(G, float)
        t = np.zeros(3) if t is None else np.asarray(t, float)
        if (np.max(np.abs(G[2, :2])) > 1e-12 or np.max(np.abs(G[:2, 2])) > 1e-12
                or abs(t[2]) > 1e-12 * self.characteristic_length()):
            raise ValueError("a planar machine's frames move in their plane only (rotations "
                             "about z, translations along x and y)")
        return G[:2, :2], t[:2]

    def transform_base(self, u, G, t=None):
        """Base pivots in a base frame turned by ``G`` about z and moved: ``A' = G A + t``.

        Parameters
        ----------
        u : array_like, shape (18,)
            Parameter vector (internal units).
        G : array_like, shape (3, 3)
            Rotation about z from the old to the new base frame.
        t : array_like, shape (3,), optional
            Translation of the new base frame, m (z = 0).

        Returns
        -------
        ndarray, shape (18,)
            The transformed parameter vector (only the base pivots change).

        Raises
        ------
        ValueError
            For a rotation or translation out of the plane.
        """
        G2, t2 = self._plane_motion(G, t)
        u = np.array(u, float)
        u[self._ia] = self.legs(u)[0] @ G2.T + t2
        return u

    def transform_platform(self, u, C, t=None):
        """Platform pivots in a platform frame turned by ``C`` about z and moved:
        ``B' = C^T (B - t)``.

        Parameters
        ----------
        u : array_like, shape (18,)
            Parameter vector (internal units).
        C : array_like, shape (3, 3)
            Rotation about z of the new platform frame relative to the old one.
        t : array_like, shape (3,), optional
            Origin of the new platform frame in the old one, m (z = 0).

        Returns
        -------
        ndarray, shape (18,)
            The transformed parameter vector (only the platform pivots change).

        Raises
        ------
        ValueError
            For a rotation or translation out of the plane.
        """
        C2, t2 = self._plane_motion(C, t)
        u = np.array(u, float)
        u[self._ib] = (self.legs(u)[1] - t2) @ C2
        return u

    def frame_motions(self, u=None) -> list[FrameMotion]:
        """Rigid motions of the base frame and of the platform frame in their plane.

        Each has three generators: the rotation about z, the translations along x and y
        (:meth:`transform_base`, :meth:`transform_platform`; the rotation by central
        differences, exact for these linear maps up to rounding).

        Parameters
        ----------
        u : array_like, shape (18,), optional
            Parameter vector to linearise at; default :attr:`u`.

        Returns
        -------
        list of FrameMotion
            The base's, then the platform's.
        """
        u = self.u if u is None else np.asarray(u, float)
        h = 1e-6
        out = []
        for name, what, transform in (
                ("rigid motion of the base frame in its plane", "moving the three base "
                 "pivots by one rigid motion of the plane (the rotation about z, 2 "
                 "translations)", self.transform_base),
                ("rigid motion of the platform frame in its plane", "moving the three "
                 "platform pivots by one rigid motion of the plane (the rotation about z, 2 "
                 "translations)", self.transform_platform)):
            w = np.array([0.0, 0.0, h])
            cols = [(transform(u, matrix_from_rotvec(w)) - transform(u, matrix_from_rotvec(-w)))
                    / (2 * h)]
            for k in range(2):
                t = np.zeros(3)
                t[k] = 1.0
                cols.append(transform(u, np.eye(3), t=t) - transform(u, np.eye(3)))
            out.append(FrameMotion(name, what, np.column_stack(cols)))
        return out


def default_planar_3rpr(base_radius: float = 0.5, platform_radius: float = 0.1,
                        l0: float = 0.3, offset: float = np.pi / 2) -> Planar3RPR:
    """A symmetric 3-RPR robot: base pivots at 90, 210, 330 deg on a circle, platform pivots
    turned by ``offset`` on a smaller one (the leg lines then do not meet: no singularity at
    home), legs reading their travel beyond ``l0``.

    Parameters
    ----------
    base_radius : float, optional
        Radius of the base pivots' circle, m.
    platform_radius : float, optional
        Radius of the platform pivots' circle, m.
    l0 : float, optional
        Leg length at zero reading, m (readings at home: about 0.21 m by default).
    offset : float, optional
        Angle of the platform pivots ahead of the base pivots, rad.

    Returns
    -------
    Planar3RPR
        Home at the origin, not rotated.
    """
    angles = np.deg2rad([90.0, 210.0, 330.0])
    base = base_radius * np.column_stack([np.cos(angles), np.sin(angles)])
    platform = platform_radius * np.column_stack([np.cos(angles + offset),
                                                  np.sin(angles + offset)])
    return Planar3RPR(planar_3rpr_parameters(base, platform, l0=l0, gain=1.0),
                      home=(np.zeros(3), np.eye(3)), name="3-RPR planar parallel robot")


# --------------------------------------------------------------------------------------------
# The machine file section (``machine: planar_3rpr``)
# --------------------------------------------------------------------------------------------


class Planar3RPRLeg(StrictModel):
    """One leg: base pivot (base frame), platform pivot (platform frame), length at zero
    reading ``l0`` (file length unit) and ``gain`` (length per length of reading): ``L = l0 +
    gain q``. Without ``l0`` and ``gain`` the leg reads its length."""

    base: Vector2
    platform: Vector2
    l0: Number = 0.0
    gain: Number = 1.0

    @field_validator("gain")
    @classmethod
    def _plausible_gain(cls, value):
        if not 1.0 / MAX_GAIN <= abs(value) <= MAX_GAIN:
            raise PydanticCustomError(
                "gain", "must be a ratio between {lo} and {hi} in size (length per length of "
                "reading; 1: the reading is the leg's travel), got {value}",
                {"lo": f"{1.0 / MAX_GAIN:g}", "hi": f"{MAX_GAIN:g}", "value": repr(value)})
        return value


class Planar3RPRSection(StrictModel):
    """``machine: planar_3rpr``: the three legs and the home pose ``[x, y, phi]``."""

    legs: Annotated[list[Planar3RPRLeg], Field(min_length=3, max_length=3)]
    home: Annotated[list[Number], Field(min_length=3, max_length=3)] | None = None


def _factors(doc) -> tuple[float, float]:
    return LENGTH[doc.units.length], ANGLE[doc.units.angle]


def _build(doc, source: str) -> Planar3RPR:
    fl, fa = _factors(doc)
    legs = doc.legs
    params = planar_3rpr_parameters(
        base=np.array([leg.base for leg in legs]) * fl,
        platform=np.array([leg.platform for leg in legs]) * fl,
        l0=np.array([leg.l0 for leg in legs]) * fl,
        gain=np.array([leg.gain for leg in legs]))
    home = None
    if doc.home is not None:
        x, y, phi = doc.home
        home = (np.array([x * fl, y * fl, 0.0]), matrix_from_euler([0.0, 0.0, phi * fa]))
    return Planar3RPR(params, home=home, name=doc.name or "")


def _dump(machine: Planar3RPR, units: dict) -> dict[str, Any]:
    fl = LENGTH[units["length"]]
    a, b, l0, g = machine.legs()
    return {"legs": [{"base": [float(v) / fl for v in a[i]],
                      "platform": [float(v) / fl for v in b[i]],
                      "l0": float(l0[i]) / fl, "gain": float(g[i])} for i in range(3)]}


def _size(doc) -> tuple[float, str]:
    fl = LENGTH[doc.units.length]
    with np.errstate(all="ignore"):
        norms = [float(np.linalg.norm(np.asarray(v, float) / 2)) * 2
                 for leg in doc.legs for v in (leg.base, leg.platform)]
    return float(np.median(norms)) * fl, "the median distance of the pivots from the origin"


#: the machine file section of a 3-RPR planar robot (:mod:`pkmcal.machines.registry`)
FILE_FORMAT = MachineFormat(
    Planar3RPRSection, _build, _dump, {"legs": 3}, home_text="[x, y, phi]",
    hints={"legs": "a list of 3 legs {base: [x, y], platform: [x, y], l0, gain}"},
    kinds={("legs", "*", "base", "*"): "length", ("legs", "*", "platform", "*"): "length",
           ("legs", "*", "l0"): "length", ("home", 0): "length", ("home", 1): "length",
           ("home", 2): "angle"},
    size=_size, kind=Planar3RPR.kind, default=default_planar_3rpr)
