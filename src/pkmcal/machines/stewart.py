"""Gough–Stewart platforms: six legs of variable length between joint pairs (SPEC 2.4).

Leg i joins the base joint ``b_i`` (base frame) and the platform joint ``p_i`` (platform frame);
its length is ``L_i = |t + R p_i - b_i|``. A real leg reports a reading ``r_i`` in its own unit
(mm, encoder counts, motor revolutions): ``L_i = l0_i + gain_i r_i``, so each leg has 8
parameters — ``leg{i}.base.x/y/z``, ``leg{i}.platform.x/y/z``, ``leg{i}.l0`` (length at zero
reading) and ``leg{i}.gain`` (length per reading unit) — 48 in all. Readings in a length unit
are converted to metres (gain 1 means "the reading is the length"); readings in any other unit
(``rev``, ``counts``) stay in that unit and the gain carries metres per unit.

The cubic 6-UPU device of seed 003 is one instance (``examples/cubic_6upu.yaml``). Notation
of seed 003 eq. 1-10: ``s_i = R p_i``, ``w_i = t + s_i - b_i = l_i z_i``,
``J_p`` row i = ``[z_i^T, (s_i x z_i)^T]``, ``J_s`` row i = ``[z_i^T R, -z_i^T]`` on
``[dp_i (platform frame), db_i]``.
"""

from __future__ import annotations

import numpy as np

from ..kinematics import matrix_from_euler
from ..parameters import ParameterSet
from .base import FKResult, Machine

LEG_FIELDS = ("base.x", "base.y", "base.z", "platform.x", "platform.y", "platform.z", "l0",
              "gain")
LEG_KINDS = ("length",) * 7 + ("ratio",)


def stewart_parameters(base, platform, l0=None, gain=None) -> ParameterSet:
    """Registry of a six-leg platform from (6, 3) joint arrays and (6,) l0, gain (SI)."""
    base = np.asarray(base, float).reshape(6, 3)
    platform = np.asarray(platform, float).reshape(6, 3)
    l0 = np.zeros(6) if l0 is None else np.broadcast_to(np.asarray(l0, float), (6,))
    gain = np.ones(6) if gain is None else np.broadcast_to(np.asarray(gain, float), (6,))
    values = np.column_stack([base, platform, l0, gain]).reshape(-1)
    names = [f"leg{i + 1}.{f}" for i in range(6) for f in LEG_FIELDS]
    return ParameterSet(names, LEG_KINDS * 6, values)


class Stewart(Machine):
    """Six-leg platform (6-UPS / 6-UPU / 6-SPS); see the module docstring."""

    kind = "stewart"
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

    @property
    def joint_quantity(self) -> str:
        """"length" when the readings are lengths (mm, m, ...), else "reading"."""
        from ..units import LENGTH

        return "length" if self.reading_unit in LENGTH else "reading"

    # -- geometry -------------------------------------------------------------------------
    def legs(self, u=None):
        """``(base (6,3), platform (6,3), l0 (6,), gain (6,))``."""
        u = self.u if u is None else np.asarray(u, float)
        return u[self._ib], u[self._ip], u[self._il0], u[self._ig]

    def characteristic_length(self) -> float:
        b, p, _, _ = self.legs()
        return float(max(np.mean(np.linalg.norm(b - b.mean(0), axis=-1)),
                         np.mean(np.linalg.norm(p - p.mean(0), axis=-1)), 1e-3))

    def parameter_scales(self) -> np.ndarray:
        """Lengths by the characteristic length; a gain by its own size (a relative change)."""
        s = self.parameters.scales(self.characteristic_length())
        g = np.abs(self.u[self._ig])
        s[self._ig] = np.where(g > 0, g, 1.0)
        return s

    def default_home(self):
        """Platform centred above the base joints at the height where the legs have the
        length they have in the platform's middle position (readings 0 unless l0 = 0, then
        the mean distance between the joint circles), orientation identity."""
        b, p, l0, _ = self.legs()
        offset = b.mean(0) - p.mean(0)
        length = np.mean(l0) if np.all(l0 > 0) else \
            np.mean(np.linalg.norm(b - b.mean(0), axis=-1)) + np.mean(
                np.linalg.norm(p - p.mean(0), axis=-1))
        horizontal = np.mean(np.linalg.norm((b - b.mean(0))[:, :2] - (p - p.mean(0))[:, :2],
                                            axis=-1))
        height = np.sqrt(max(length**2 - horizontal**2, (0.5 * length) ** 2))
        return offset + np.array([0.0, 0.0, height]), np.eye(3)

    # -- kinematics -----------------------------------------------------------------------
    def leg_vectors(self, P, R, u=None):
        """``w_i = t + R p_i - b_i`` (..., 6, 3), ``s_i = R p_i`` and the lengths (..., 6)."""
        b, p, _, _ = self.legs(u)
        s = np.einsum("...ij,kj->...ki", np.asarray(R, float), p)
        w = np.asarray(P, float)[..., None, :] + s - b
        return w, s, np.linalg.norm(w, axis=-1)

    def ik_jacobians(self, P, R, u=None, want_du: bool = True):
        b, p, l0, g = self.legs(u)
        w, s, L = self.leg_vectors(P, R, u)
        z = w / L[..., None]
        r = (L - l0) / g
        zg = z / g[:, None]
        dq_dpose = np.concatenate([zg, np.cross(s, zg)], -1)     # J_p / gain
        if not want_du:
            return r, dq_dpose, None
        R = np.asarray(R, float)
        cols = np.concatenate([
            -zg,                                                  # d r / d base
            np.einsum("...ji,...kj->...ki", R, zg),               # d r / d platform = R^T z/g
            np.broadcast_to(-1.0 / g, r.shape)[..., None],        # d r / d l0
            (-r / g)[..., None],                                  # d r / d gain
        ], -1)                                                    # (..., 6, 8) LEG_FIELDS
        dq_du = np.zeros(r.shape + (len(self.parameters),))
        idx = np.concatenate([self._ib, self._ip, self._il0[:, None], self._ig[:, None]], -1)
        dq_du[..., np.arange(6)[:, None], idx] = cols
        return r, dq_dpose, dq_du

    def lengths(self, r, u=None):
        """Leg lengths (..., 6) for readings ``r``: ``l0 + gain r``."""
        _, _, l0, g = self.legs(u)
        return l0 + g * np.asarray(r, float)

    def jacobians(self, P, R, u=None):
        """Seed 003 eq. 8-10 at poses: ``J_p`` (..., 6, 6) and ``J_s`` (..., 6, 6, 6) where
        ``J_s[..., i, :, :]`` maps leg i's ``[dp_i (platform frame, 3), db_i (3)]`` to ``dl_i``
        (``[z_i^T R, -z_i^T]``), and the unit vectors ``z`` (..., 6, 3)."""
        w, s, L = self.leg_vectors(P, R, u)
        z = w / L[..., None]
        Jp = np.concatenate([z, np.cross(s, z)], -1)
        zR = np.einsum("...ki,...ij->...kj", z, np.asarray(R, float))
        Js = np.concatenate([zR, -z], -1)
        return Jp, Js, z

    def fk(self, q, u=None, start=None, tol: float = 1e-12, max_iter: int = 50,
           raise_on_failure: bool = False, continuation: bool = False) -> FKResult:
        """Forward kinematics by Newton; with ``continuation`` each row starts from the
        previous row's solution (trajectories: stays on the assembly branch)."""
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

    # -- frames ---------------------------------------------------------------------------
    def transform_base(self, u, G, t=None):
        """Base joints in a base frame rotated by ``G`` (and moved: ``b' = G b + t``)."""
        u = np.array(u, float)
        b = self.legs(u)[0] @ np.asarray(G).T
        u[self._ib] = b if t is None else b + np.asarray(t, float)
        return u

    def transform_platform(self, u, C, t=None):
        """Platform joints in a re-oriented (and moved) platform frame: ``p' = C^T (p - t)``."""
        u = np.array(u, float)
        p = self.legs(u)[1]
        u[self._ip] = (p if t is None else p - np.asarray(t, float)) @ np.asarray(C)
        return u


def cubic_6upu(a=0.16, b=0.14, c=0.195, d=0.270, e=0.055, f=0.205, g=0.130, z1=0.130,
               z2=0.130, z3=0.280, height=0.41) -> Stewart:
    """The cubic 6-UPU device of seed 003 Table 2 (SPEC 2.3), with ``P5 = (c, e, -d)``: three
    links along Z, two along X, one along Y. Readings are leg lengths in metres (gain 1, l0 0).
    """
    base = [(b, -a, 0), (b, a, 0), (-b, 0, 0), (-c, -e, z1), (-c, e, z2), (0, f, z3)]
    platform = [(b, -a, 0), (b, a, 0), (-b, 0, 0), (c, -e, -d), (c, e, -d), (0, -f, -g)]
    return Stewart(stewart_parameters(base, platform), home=(np.array([0, 0, height]),
                                                             matrix_from_euler([0, 0, 0])),
                   name="cubic 6-UPU parallel device (seed 003 Table 2, P5 = (c, e, -d))")
