"""Delta robot with revolute actuators and parallelogram forearms (seed 001, SPEC 2.2).

Leg i stands at angle ``phi_i`` about Z (default 90, 180, -90 deg; any angles work, e.g. the
classic 120-degree Delta). Nominal dimensions: base radius ``a``, platform radius ``b``, upper
arm ``l1``, forearm ``l2``. The platform translates only. Simplified error model (seed 001
eq. 3): per leg ``da`` (3, base joint position), ``dtheta`` (actuator offset), ``dl1``,
``dl2``, ``db`` (3, platform joint position), all in the leg frame: 27 parameters,
``leg{i}.da.x`` ... ``leg{i}.db.z``. The nominal dimensions are constants, not parameters.

Leg equation (eq. 4-5), in the leg frame ``Rphi_i = [[c, s, 0], [-s, c, 0], [0, 0, 1]]``::

    | Rphi_i p + d_i | = l2 + dl2_i
    d_x = -(l1 + dl1) cos(theta + dtheta) - (a + da_x) + (b + db_x)
    d_y = -da_y + db_y
    d_z = -(l1 + dl1) sin(theta + dtheta) - da_z + db_z

so the platform point lies on a sphere of radius ``l2 + dl2_i`` about ``c_i = -Rphi_i^T d_i``.
Forward kinematics (eq. 6-11) intersects the three spheres in closed form: subtracting pairs
gives two planes (eq. 8), whose line is intersected with the first sphere (eq. 9-11, written
with the line's direction so no 2x2 sub-determinant can vanish). Of the two roots the one on
the platform side is taken: the lower one (Z up, the platform hangs below the base).
Inverse kinematics: ``w_x cos(t) + w_z sin(t) = K`` per leg, elbow-out root.

The machine file (SPEC 6) holds the nominal dimensions, the error parameters per leg
(optional, default 0) and, optionally, the pose of a laser tracker::

    pkmcal: 1
    machine: delta
    units: {length: mm, angle: deg}
    base_radius: 200.0
    platform_radius: 50.0
    upper_arm: 300.0
    forearm: 800.0
    leg_angles: [90.0, 180.0, -90.0]
    smr_offset: 30.0                           # optional: reflector below the platform point
    legs:                                      # optional: exactly 3, every key optional (0)
      - {da: [0.0, 0.0, 0.0], dtheta: 0.0, dl1: 0.0, dl2: 0.0, db: [0.0, 0.0, 0.0]}
    tracker: {rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], translation: [0, 0, 0]}
    home: [0.0, 0.0, -750.0]                   # x, y, z (the platform does not rotate)

A calibrated Delta file carries the identified errors in ``legs``, the identified registration
in ``tracker`` (no ``targets``: the target is the reflector, ``smr_offset``), and ``home``. A
Delta ``home`` may also be written with six numbers when the three angles are zero.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, field_validator
from pydantic_core import PydanticCustomError

from ..errors import InputError
from ..parameters import ParameterSet
from ..units import LENGTH
from .base import FKResult, Machine, closed_form_positions_fk
from .file_format import (
    Ballbar,
    BedPlane,
    MachineFileHead,
    MachineFormat,
    NonNegative,
    Number,
    Positive,
    StrictModel,
    TrackerPose,
    Vector3,
    factors,
)

LEG_FIELDS = ("da.x", "da.y", "da.z", "dtheta", "dl1", "dl2", "db.x", "db.y", "db.z")
LEG_KINDS = ("length",) * 3 + ("angle",) + ("length",) * 5
DEFAULT_LEG_ANGLES = np.deg2rad([90.0, 180.0, -90.0])


#: seed 001's tracker grid around home: dx = dy = 150 mm, dz = 40 mm (3 x 3 x 3 points), m
TRACKER_GRID_SPACING = (0.15, 0.15, 0.04)


def delta_parameters(values=None, n_legs: int = 3) -> ParameterSet:
    """Registry of the 9 error parameters per leg, ``leg{i}.da.x`` ... ``leg{i}.db.z``.

    Parameters
    ----------
    values : array_like, shape (n_legs * 9,), optional
        Values in internal units (m, rad), leg by leg in the order of ``LEG_FIELDS``;
        default: zeros.
    n_legs : int, optional
        Number of legs.

    Returns
    -------
    ParameterSet
        The named error parameters (kinds: length, except ``dtheta``, an angle).
    """
    names = [f"leg{i + 1}.{f}" for i in range(n_legs) for f in LEG_FIELDS]
    v = np.zeros(len(names)) if values is None else np.asarray(values, float)
    return ParameterSet(names, LEG_KINDS * n_legs, v)


class Delta(Machine):
    """3-leg Delta robot with the simplified error model of seed 001; see the module doc.

    Parameters
    ----------
    base_radius : float
        Nominal base radius ``a``, m.
    platform_radius : float
        Nominal platform radius ``b``, m.
    upper_arm : float
        Nominal upper-arm length ``l1``, m.
    forearm : float
        Nominal forearm length ``l2``, m.
    leg_angles : array_like, shape (3,), optional
        Angle ``phi_i`` of each leg about Z, rad; default 90, 180, -90 deg.
    parameters : ParameterSet, optional
        The 27 error parameters (:func:`delta_parameters`); default: all zero.
    smr_offset : float, optional
        Distance of the tracker reflector below the platform point, m.
    home : tuple of ndarray, optional
        ``(P, R)`` start pose for numerical solvers; default: :meth:`default_home`.
    name : str, optional
        Free-text name of the machine.

    Raises
    ------
    InputError
        When ``leg_angles`` does not hold exactly 3 angles.
    """

    kind = "delta"
    #: the instrument of its source paper (seed 001)
    default_instrument = "tracker"
    chain_word = "leg"
    joints_read_words = "arm angles are"
    n_joints = 3
    pose_dof = 3
    #: random deviations of simulated true machines (m, rad)
    RANDOM_DEVIATION = (1e-3, float(np.deg2rad(0.5)))
    joint_quantity = "angle"

    def __init__(self, base_radius: float, platform_radius: float, upper_arm: float,
                 forearm: float, leg_angles=DEFAULT_LEG_ANGLES, parameters=None,
                 smr_offset: float = 0.0, home=None, name: str = ""):
        leg_angles = np.asarray(leg_angles, float)
        if leg_angles.shape != (3,):
            raise InputError(f"a Delta has 3 legs: got {leg_angles.size} leg angles")
        super().__init__(delta_parameters() if parameters is None else parameters, home, name)
        self.a, self.b = float(base_radius), float(platform_radius)
        self.l1, self.l2 = float(upper_arm), float(forearm)
        self.leg_angles = leg_angles
        self.smr_offset = float(smr_offset)
        c, s = np.cos(leg_angles), np.sin(leg_angles)
        z, o = np.zeros(3), np.ones(3)
        #: leg frames: Rphi_i (3, 3, 3), a base vector v becomes Rphi_i @ v in leg i's frame
        self.Rphi = np.stack([np.stack([c, s, z], -1), np.stack([-s, c, z], -1),
                              np.stack([z, z, o], -1)], -2)
        self._idx = np.stack([self.parameters.indices(f"leg{i + 1}") for i in range(3)])

    # -- geometry -------------------------------------------------------------------------
    @property
    def platform_radius(self) -> float:
        """The radius ``b`` of the platform joints, m (the file's ``platform_radius``)."""
        return self.b

    def legs(self, u=None):
        """Per-leg error arrays, the legs along the first axis.

        Parameters
        ----------
        u : array_like, shape (27,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        da : ndarray, shape (3, 3)
            Base joint position errors, m (leg frame).
        dtheta : ndarray, shape (3,)
            Actuator angle offsets, rad.
        dl1 : ndarray, shape (3,)
            Upper-arm length errors, m.
        dl2 : ndarray, shape (3,)
            Forearm length errors, m.
        db : ndarray, shape (3, 3)
            Platform joint position errors, m (leg frame).
        """
        u = self.u if u is None else np.asarray(u, float)
        e = u[self._idx]                                           # (3 legs, 9) LEG_FIELDS
        return e[:, 0:3], e[:, 3], e[:, 4], e[:, 5], e[:, 6:9]

    def characteristic_length(self) -> float:
        return self.l1

    def default_home(self):
        """Below the base, at the depth where the arms are horizontal (theta = 0).

        Returns
        -------
        P : ndarray, shape (3,)
            ``(0, 0, -depth)``, m (depth ``l2`` when the arms cannot be horizontal).
        R : ndarray, shape (3, 3)
            The identity.
        """
        reach = self.l2**2 - (self.a + self.l1 - self.b) ** 2
        depth = np.sqrt(reach) if reach > 0 else self.l2
        return np.array([0.0, 0.0, -depth]), np.eye(3)

    # -- validation -----------------------------------------------------------------------
    def geometry_problems(self, home_given: bool = True) -> list[tuple[tuple, str]]:
        """Degenerate legs (see :meth:`Machine.geometry_problems`).

        Refused: two legs at the same angle (within 1e-6 rad: the two legs act alike and the
        platform is free to move); an upper arm or forearm of zero or negative length with
        its error; arms that cannot span the distance between the arm axes and the platform
        joints anywhere (``upper_arm + forearm < |base_radius - platform_radius|`` with legs
        around the axis); home (given, or the arms-horizontal default) out of reach.

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
        phi = self.leg_angles
        for j in range(3):
            for i in range(j):
                gap = abs((phi[j] - phi[i] + np.pi) % (2 * np.pi) - np.pi)
                if gap < 1e-6:
                    return [(("leg_angles", j), f"legs {i + 1} and {j + 1} stand at the same "
                             f"angle ({np.degrees(phi[i]):.6g} and {np.degrees(phi[j]):.6g} "
                             "deg): they act alike and the platform is free to move; the legs "
                             "must stand at three different angles, e.g. 90, 180, -90 deg")]
        _, _, dl1, dl2, _ = self.legs()
        for i in range(3):
            for key, nominal, error, what in (("dl1", self.l1, dl1[i], "upper arm"),
                                              ("dl2", self.l2, dl2[i], "forearm")):
                if not nominal + error > 0:
                    return [(("legs", i, key), f"the {what} of leg {i + 1} would be "
                             f"{self._length_text(nominal + error)} long (nominal "
                             f"{self._length_text(nominal)} plus the error); check {key}")]
        ring = np.sort(np.mod(phi, 2 * np.pi))
        gaps = np.diff(np.concatenate([ring, ring[:1] + 2 * np.pi]))   # between legs around Z
        surrounds = bool(np.max(gaps) <= np.pi)
        if surrounds and self.l1 + self.l2 < abs(self.a - self.b):
            return [(("forearm",), f"upper_arm ({self._length_text(self.l1)}) and forearm "
                     f"({self._length_text(self.l2)}) together are shorter than "
                     f"|base_radius - platform_radius| ({self._length_text(abs(self.a - self.b))})"
                     ": the arms cannot reach the platform joints anywhere; check the "
                     "dimensions")]
        bad, _ = self._home_check()
        if bad.size:
            key, what = (("home",), "the position") if home_given else \
                (("legs",), "the default home (arms horizontal)")
            return [(key, f"{what} cannot be reached by leg(s) "
                     f"{', '.join(str(i + 1) for i in bad)} (the forearm cannot span the "
                     "distance from the arm's circle to the platform joint); check home, the "
                     "dimensions and legs")]
        return []

    def _offsets(self, theta, u):
        """``d_i`` (..., 3 legs, 3) of eq. 5 and the leg lengths ``L2`` (3,)."""
        da, dth, dl1, dl2, db = self.legs(u)
        t = theta + dth
        L1 = self.l1 + dl1
        d = np.stack([-L1 * np.cos(t) - (self.a + da[:, 0]) + (self.b + db[:, 0]),
                      np.broadcast_to(-da[:, 1] + db[:, 1], t.shape),
                      -L1 * np.sin(t) - da[:, 2] + db[:, 2]], -1)
        return d, self.l2 + dl2

    # -- kinematics -----------------------------------------------------------------------
    def ik_jacobians(self, P, R=None, u=None, want_du: bool = True):
        """Actuator angles and their derivatives at platform positions.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m.
        R : array_like, optional
            Ignored (translation-only platform).
        u : array_like, shape (27,), optional
            Parameter vector (internal units); default: :attr:`u`.
        want_du : bool, optional
            Also compute the derivatives with respect to the parameters.

        Returns
        -------
        q : ndarray, shape (..., 3)
            Actuator angles, rad (elbow-out root); NaN where unreachable.
        dq_dpose : ndarray, shape (..., 3, 6)
            Derivatives with respect to ``[dP, dOmega]``; the rotation columns are zero.
        dq_du : ndarray, shape (..., 3, 27) or None
            Derivatives with respect to the parameters; None unless ``want_du``.
        """
        P = np.asarray(P, float)
        da, dth, dl1, dl2, db = self.legs(u)
        L1, L2 = self.l1 + dl1, self.l2 + dl2
        Rp = np.einsum("lij,...j->...li", self.Rphi, P)          # (..., 3, 3) Rphi_i p
        # w = Rphi p + d_i without the arm: |w - L1 (cos t, 0, sin t)| = L2
        w = Rp + np.stack([-(self.a + da[:, 0]) + (self.b + db[:, 0]),
                           -da[:, 1] + db[:, 1], -da[:, 2] + db[:, 2]], -1)
        K = (np.einsum("...i,...i->...", w, w) + L1**2 - L2**2) / (2 * L1)
        rho = np.hypot(w[..., 0], w[..., 2])
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.arctan2(w[..., 2], w[..., 0]) + np.arccos(K / rho)   # elbow out
        q = t - dth
        # implicit derivatives of f_i = |v_i|^2 - L2^2 with v_i = w - L1 (cos t, 0, sin t)
        ct, st = np.cos(t), np.sin(t)
        v = w - L1[:, None] * np.stack([ct, np.zeros_like(ct), st], -1)
        df_dt = 2 * L1 * (v[..., 0] * st - v[..., 2] * ct)         # (..., 3)
        df_dp = 2 * np.einsum("...li,lij->...lj", v, self.Rphi)    # (..., 3, 3)
        dq_dpose = np.concatenate([-df_dp / df_dt[..., None], np.zeros(df_dp.shape)], -1)
        if not want_du:
            return q, dq_dpose, None
        dq_du = np.zeros(q.shape + (len(self.parameters),))
        legs = np.arange(3)
        # f depends on da, db through w (dw/dda = -I, dw/ddb = +I), on dl1 through L1,
        # on dl2 through L2; q = t - dtheta with t fixed by f
        df_dda = -2 * v
        df_ddb = 2 * v
        df_dl1 = -2 * (v[..., 0] * ct + v[..., 2] * st)
        df_dl2 = np.broadcast_to(-2 * L2, df_dl1.shape)
        cols = np.concatenate([
            -df_dda / df_dt[..., None],
            np.broadcast_to(-1.0, df_dt.shape)[..., None],        # dq/ddtheta
            (-df_dl1 / df_dt)[..., None],
            (-df_dl2 / df_dt)[..., None],
            -df_ddb / df_dt[..., None],
        ], -1)                                                    # (..., 3, 9) LEG_FIELDS
        dq_du[..., legs[:, None], self._idx] = cols
        return q, dq_dpose, dq_du

    def ik(self, P, R=None, u=None) -> np.ndarray:
        """Actuator angles at platform positions; NaN where unreachable.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Platform positions, m.
        R : array_like, optional
            Ignored (translation-only platform).
        u : array_like, shape (27,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        ndarray, shape (..., 3)
            Actuator angles, rad.
        """
        return self.ik_jacobians(P, R, u, want_du=False)[0]

    def sphere_centres(self, q, u=None):
        """Centres ``c_i = -Rphi_i^T d_i`` and radii of the three leg spheres (eq. 6).

        Parameters
        ----------
        q : array_like, shape (..., 3)
            Actuator angles, rad.
        u : array_like, shape (27,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        centres : ndarray, shape (..., 3, 3)
            Sphere centre of each leg (second-last axis), m, base frame.
        radii : ndarray, shape (3,)
            Forearm lengths ``L2 = l2 + dl2``, m.
        """
        d, L2 = self._offsets(np.asarray(q, float), u)
        return -np.einsum("lji,...lj->...li", self.Rphi, d), L2

    def fk(self, q, u=None, start=None, tol: float = 1e-9, max_iter: int = 0,
           raise_on_failure: bool = False) -> FKResult:
        """Closed-form forward kinematics (seed 001 eq. 6-11), vectorized over rows of ``q``.

        Parameters
        ----------
        q : array_like, shape (K, 3)
            Actuator angles, rad.
        u : array_like, shape (27,), optional
            Parameter vector (internal units); default: :attr:`u`.
        start : object, optional
            Accepted for the :class:`Machine` interface; unused.
        tol : float, optional
            Accepted for the :class:`Machine` interface; unused.
        max_iter : int, optional
            Accepted for the :class:`Machine` interface; unused.
        raise_on_failure : bool, optional
            Raise instead of returning poses that could not be solved.

        Returns
        -------
        FKResult
            Positions (K, 3) in m with ``R = I``; ``converged`` is False where the spheres do not
            meet (unreachable) or their centres are collinear (degenerate); residual 0 or inf;
            ``iterations`` 0.

        Raises
        ------
        ConvergenceError
            With ``raise_on_failure``, when a row could not be solved.
        """
        return closed_form_positions_fk(self, q, u, raise_on_failure)

    def fk_positions(self, q, u=None):
        """Platform positions and a validity mask from the three-sphere intersection.

        The sphere centres ``c_i = -Rphi_i^T d_i`` (eq. 6) are formed per component with the
        legs as the leading axis (contiguous, no small-axis ``einsum``). Subtracting sphere 1
        from spheres 2 and 3 gives the planes ``(c_j - c_1) . p = b_j`` (eq. 8); their line
        ``p0 + s l`` with ``l = n2 x n3`` is intersected with sphere 1 (eq. 9-11). The paper
        solves eq. 8 for ``px, py`` through the 2x2 determinant ``q2``, which is ``l_z`` up to a
        factor: it vanishes exactly when both roots are at the same height. Of the two roots
        the lower one is returned (platform side).

        Parameters
        ----------
        q : array_like, shape (..., 3)
            Actuator angles, rad.
        u : array_like, shape (27,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        P : ndarray, shape (..., 3)
            Platform positions, m; NaN where not valid.
        ok : ndarray of bool, shape (...)
            False where the spheres do not meet or their centres are (nearly) collinear.
        """
        q = np.asarray(q, float)
        da, dth, dl1, dl2, db = self.legs(u)
        L2 = self.l2 + dl2
        # legs first, each leg's values contiguous: (3, ...)
        t = np.ascontiguousarray(np.moveaxis(q + dth, -1, 0))
        col = (3,) + (1,) * (t.ndim - 1)
        L1 = (self.l1 + dl1).reshape(col)
        cphi, sphi = self.Rphi[:, 0, 0].reshape(col), self.Rphi[:, 0, 1].reshape(col)
        dx = ((self.b + db[:, 0]) - (self.a + da[:, 0])).reshape(col) - L1 * np.cos(t)
        dy = (db[:, 1] - da[:, 1]).reshape(col)
        dz = (db[:, 2] - da[:, 2]).reshape(col) - L1 * np.sin(t)
        cx = sphi * dy - cphi * dx                              # c = -Rphi^T d
        cy = -sphi * dx - cphi * dy
        cz = -dz
        x1, y1, z1 = cx[0], cy[0], cz[0]
        ax, ay, az = cx[1] - x1, cy[1] - y1, cz[1] - z1          # n2 = c2 - c1
        bx, by, bz = cx[2] - x1, cy[2] - y1, cz[2] - z1          # n3 = c3 - c1
        r1 = L2[0] ** 2
        # planes (eq. 8): n_j . p = b_j = (|c_j|^2 - L2_j^2 - |c_1|^2 + L2_1^2) / 2
        s1 = x1 * x1 + y1 * y1 + z1 * z1 - r1
        b2 = 0.5 * (cx[1] ** 2 + cy[1] ** 2 + cz[1] ** 2 - L2[1] ** 2 - s1)
        b3 = 0.5 * (cx[2] ** 2 + cy[2] ** 2 + cz[2] ** 2 - L2[2] ** 2 - s1)
        lx, ly, lz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx   # l = n2 x n3
        g = lx * lx + ly * ly + lz * lz
        with np.errstate(invalid="ignore", divide="ignore"):
            # e = p0 - c1 with p0 = (b2 (n3 x l) + b3 (l x n2)) / |l|^2 on both planes
            ex = (b2 * (by * lz - bz * ly) + b3 * (ly * az - lz * ay)) / g - x1
            ey = (b2 * (bz * lx - bx * lz) + b3 * (lz * ax - lx * az)) / g - y1
            ez = (b2 * (bx * ly - by * lx) + b3 * (lx * ay - ly * ax)) / g - z1
            # sphere 1 (eq. 10-11): |e + s l|^2 = L2_1^2, i.e. g s^2 + 2 B s + C = 0
            B = lx * ex + ly * ey + lz * ez
            C = ex * ex + ey * ey + ez * ez - r1
            disc = B * B - g * C
            # the root with the smaller z = z1 + ez + s lz: the sign of sqrt opposite to lz
            s = (-B - np.copysign(np.sqrt(disc), lz)) / g
            P = np.stack([x1 + ex + s * lx, y1 + ey + s * ly, z1 + ez + s * lz], -1)
        scale = ax * ax + ay * ay + az * az + bx * bx + by * by + bz * bz
        ok = (g > 1e-12 * scale**2) & (disc >= 0) & np.all(np.isfinite(P), -1)
        return np.where(ok[..., None], P, np.nan), ok

    def fk_numerical(self, q, u=None, start=None, tol: float = 1e-13, max_iter: int = 50):
        """Newton on the three leg equations (3 unknowns), as a cross-check of :meth:`fk`.

        Parameters
        ----------
        q : array_like, shape (K, 3)
            Actuator angles, rad.
        u : array_like, shape (27,), optional
            Parameter vector (internal units); default: :attr:`u`.
        start : array_like, shape (3,) or (K, 3), optional
            Start positions, m; default: the home position.
        tol : float, optional
            Stop when every joint residual is below this, rad.
        max_iter : int, optional
            Maximum Newton iterations.

        Returns
        -------
        ndarray, shape (K, 3)
            Platform positions, m, after the last iteration (convergence is not reported).
        """
        q = np.atleast_2d(np.asarray(q, float))
        P = np.broadcast_to(self.home[0] if start is None else start, q.shape).copy()
        for _ in range(max_iter):
            qc, J, _ = self.ik_jacobians(P, want_du=False, u=u)
            r = qc - q
            if np.all(np.abs(r) < tol):
                break
            P = P - np.linalg.solve(J[..., :3], r[..., None])[..., 0]
        return P

    def identifiable_combinations(self, u=None) -> dict:
        """``db - da`` per leg (leg frame, m): only this difference enters the leg equation.

        Parameters
        ----------
        u : array_like, shape (27,), optional
            Parameter vector; default :attr:`u`.

        Returns
        -------
        dict
            ``description`` and ``leg<i>.db - leg<i>.da`` (3 values each, m).
        """
        da, _, _, _, db = self.legs(u)
        return {"description": "db - da per leg (leg frame): only this difference enters the "
                               "model, and with the tracker pose unknown only up to one "
                               "common translation of the platform",
                **{f"leg{i + 1}.db - leg{i + 1}.da": (db[i] - da[i]).tolist()
                   for i in range(3)}}

    def tracker_grid_spacing(self) -> tuple:
        """Seed 001's grid: dx = dy = 150 mm, dz = 40 mm (3x3x3 around home).

        Returns
        -------
        tuple of float
            The spacing, m.
        """
        return tuple(TRACKER_GRID_SPACING)

    def tracker_target(self) -> np.ndarray:
        """The reflector ``smr_offset`` below the platform point (seed 001), platform frame.

        Returns
        -------
        ndarray, shape (3,)
            ``(0, 0, -smr_offset)``, m.
        """
        return np.array([0.0, 0.0, -self.smr_offset])

    # -- frames ---------------------------------------------------------------------------
    def frame_motions(self, u=None):
        """The Delta's invisible combinations (seed 001 eq. 5; SPEC 2.2).

        Per leg ``da + db`` (the base joint and the platform joint shifted together: only
        ``db - da`` enters the leg equation), and a translation of the platform frame (every
        platform joint shifted by one vector ``v``, ``db_i += Rphi_i v``), which an
        instrument's frame or target absorbs. The model has no base-frame parameters.

        Parameters
        ----------
        u : array_like, shape (27,), optional
            Unused (the directions are constant).

        Returns
        -------
        list of FrameMotion
            Three leg combinations and the platform translation.
        """
        from .base import FrameMotion

        p, n = self.parameters, len(self.parameters)
        out = []
        for i in range(3):
            T = np.zeros((n, 3))
            for k, c in enumerate("xyz"):
                T[p.index(f"leg{i + 1}.da.{c}"), k] = 1.0
                T[p.index(f"leg{i + 1}.db.{c}"), k] = 1.0
            out.append(FrameMotion(
                f"leg{i + 1}.da + leg{i + 1}.db",
                "the base joint and the platform joint of the leg shifted together change "
                "nothing: only db - da enters the leg equation (seed 001 eq. 5)", T))
        T = np.zeros((n, 3))
        for i in range(3):
            T[p.indices(f"leg{i + 1}.db"), :] = self.Rphi[i]
        out.append(FrameMotion("translation of the platform frame",
                               "shifting every platform joint by the same vector", T))
        return out

    def transform_base(self, u, G):
        """Not available: the Delta error model has no base-frame parameters.

        Parameters
        ----------
        u : array_like
            Parameter vector.
        G : array_like, shape (3, 3)
            Base rotation.

        Raises
        ------
        NotImplementedError
            Always: a rotated base frame is not representable.
        """
        raise NotImplementedError("the Delta error model has no base-frame parameters: a "
                                  "rotated base frame is not representable")

    def transform_platform(self, u, C):
        """Not available: the Delta platform does not rotate.

        Parameters
        ----------
        u : array_like
            Parameter vector.
        C : array_like, shape (3, 3)
            Platform rotation.

        Raises
        ------
        NotImplementedError
            Always.
        """
        raise NotImplementedError("the Delta platform does not rotate")


def default_delta() -> Delta:
    """The embedded default Delta of SPEC 2.2 (ours).

    a = 200, b = 50, l1 = 300, l2 = 800 mm, legs at 90/180/-90 deg, SMR 30 mm below the
    platform point, home (0, 0, -750) mm, no geometric errors.

    Returns
    -------
    Delta
        A new machine.
    """
    return Delta(0.2, 0.05, 0.3, 0.8, DEFAULT_LEG_ANGLES, smr_offset=0.03,
                 home=(np.array([0.0, 0.0, -0.75]), np.eye(3)),
                 name="pkmcal default 90-degree Delta (SPEC 2.2)")


# --------------------------------------------------------------------------------------------
# The machine file section (``machine: delta``)
# --------------------------------------------------------------------------------------------


class DeltaLeg(StrictModel):
    """Error parameters of one Delta leg (seed 001 eq. 3, leg frame); every key defaults to 0."""

    da: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 0.0])
    dtheta: Number = 0.0
    dl1: Number = 0.0
    dl2: Number = 0.0
    db: Vector3 = Field(default_factory=lambda: [0.0, 0.0, 0.0])


class DeltaFile(MachineFileHead):
    """``machine: delta`` (SPEC 6)."""

    machine: Literal["delta"]
    base_radius: Positive
    platform_radius: NonNegative
    upper_arm: Positive
    forearm: Positive
    leg_angles: Vector3
    smr_offset: Number = 0.0
    legs: Annotated[list[DeltaLeg], Field(min_length=3, max_length=3)] | None = None
    tracker: TrackerPose | None = None
    ballbar: Ballbar | None = None
    bed: BedPlane | None = None
    home: list[Number] | None = None

    @field_validator("home")
    @classmethod
    def _position_home(cls, value):
        if value is None:
            return value
        if len(value) not in (3, 6):
            raise PydanticCustomError(
                "home_length", "expected 3 numbers [x, y, z] (the Delta platform does not "
                "rotate), got {n}", {"n": len(value)})
        if len(value) == 6 and any(abs(v) > 1e-9 for v in value[3:]):
            raise PydanticCustomError(
                "home_rotation", "the Delta platform does not rotate: psi, theta, phi must be "
                "0, got {angles}; write home: [x, y, z]", {"angles": value[3:]})
        return value


def _build(doc: DeltaFile, source: str) -> Delta:
    fl, fa = factors(doc.units.model_dump())
    legs = doc.legs if doc.legs is not None else [DeltaLeg() for _ in range(3)]
    factor = {"da": fl, "dtheta": fa, "dl1": fl, "dl2": fl, "db": fl}
    values = []
    for leg in legs:
        for field in LEG_FIELDS:                 # da.x, ..., dtheta, dl1, dl2, db.x, ...
            key, _, axis = field.partition(".")
            v = getattr(leg, key)
            values.append((v["xyz".index(axis)] if axis else v) * factor[key])
    home = None
    if doc.home is not None:
        home = (np.asarray(doc.home[:3], float) * fl, np.eye(3))
    return Delta(doc.base_radius * fl, doc.platform_radius * fl, doc.upper_arm * fl,
                 doc.forearm * fl, np.asarray(doc.leg_angles, float) * fa,
                 parameters=delta_parameters(values), smr_offset=doc.smr_offset * fl,
                 home=home, name=doc.name or "")


def _dump(machine: Delta, units: dict) -> dict[str, Any]:
    fl, fa = factors(units)
    da, dth, dl1, dl2, db = machine.legs()
    return {
        "base_radius": machine.a / fl,
        "platform_radius": machine.b / fl,
        "upper_arm": machine.l1 / fl,
        "forearm": machine.l2 / fl,
        "leg_angles": [float(v) / fa for v in machine.leg_angles],
        "smr_offset": machine.smr_offset / fl,
        "legs": [{"da": [float(v) / fl for v in da[i]], "dtheta": float(dth[i]) / fa,
                  "dl1": float(dl1[i]) / fl, "dl2": float(dl2[i]) / fl,
                  "db": [float(v) / fl for v in db[i]]} for i in range(3)],
    }


def _size(doc) -> tuple[float, str]:
    fl = LENGTH[doc.units.length]
    return (float(np.median([doc.base_radius, doc.upper_arm, doc.forearm])) * fl,
            "the median of base_radius, upper_arm and forearm")


#: the machine file section of a Delta robot (:mod:`pkmcal.machines.registry`)
FILE_FORMAT = MachineFormat(
    DeltaFile, _build, _dump, {"legs": 3}, home_text="[x, y, z]",
    hints={
        "base_radius": "the radius a of the actuator axes, e.g. base_radius: 200.0",
        "platform_radius": "the radius b of the platform joints, e.g. platform_radius: 50.0",
        "upper_arm": "the upper-arm length l1, e.g. upper_arm: 300.0",
        "forearm": "the parallelogram forearm length l2, e.g. forearm: 800.0",
        "leg_angles": "the azimuths of the 3 legs, e.g. leg_angles: [90.0, 180.0, -90.0]",
        "legs": "a list of 3 legs {da: [x, y, z], dtheta, dl1, dl2, db: [x, y, z]}",
    },
    kinds={
        ("base_radius",): "dimension", ("platform_radius",): "length",
        ("upper_arm",): "dimension", ("forearm",): "dimension", ("smr_offset",): "length",
        ("leg_angles", "*"): "angle", ("legs", "*", "da", "*"): "length",
        ("legs", "*", "dtheta"): "angle", ("legs", "*", "dl1"): "length",
        ("legs", "*", "dl2"): "length", ("legs", "*", "db", "*"): "length",
    },
    size=_size, kind=Delta.kind, default=default_delta)
