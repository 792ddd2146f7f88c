"""Hexa Slide Mechanism, 6-PUS (seed 000, SPEC 2.1).

Chain i: a slider moves along a straight rail from ``A0_i`` (base frame) in the direction
``a_i = [cos(alpha) cos(beta), sin(alpha) cos(beta), sin(beta)]``; the slider's universal joint
carries a link of length ``l_i`` to the spherical joint ``B_i`` (platform frame). Joint value
``q_i`` = slider travel from ``A0_i``. Nine parameters per chain, 54 in all, registered as
``chain{i}.b.x/y/z``, ``chain{i}.a0.x/y/z``, ``chain{i}.alpha``, ``chain{i}.beta``, ``chain{i}.l``.

Inverse kinematics (seed 000 eq. 1-9), with ``d = P + R B - A0``::

    q = a.d - sqrt(l^2 - |d|^2 + (a.d)^2)

Derivatives (SPEC appendix A), with link vector ``n = d - q a`` and ``s = a.n`` (> 0 on the
working branch): ``dq/dP = n/s``, ``dq/dOmega = (R B) x n / s``, ``dq/dB = R^T n / s``,
``dq/dA0 = -n/s``, ``dq/dl = -l/s``, ``dq/da = -q d/s`` (projected on ``da/dalpha``,
``da/dbeta``).

The machine file (SPEC 6)::

    pkmcal: 1
    machine: hexaslide
    name: any text
    units: {length: mm, angle: deg}
    constraint_link: {length: 300.0}
    home: [0.0, 0.0, 300.0, 0.0, 0.0, 0.0]      # x, y, z, psi, theta, phi (file units)
    chains:                                    # exactly 6
      - {a0: [451.05, -164.17, -400.0], alpha: 160.0, beta: 70.0, b: [84.85, -84.85, 0.0], l: 450.0}

with the instrument sections ``tracker`` (with ``targets``), ``ballbar``, ``bed`` and
``measurement_frames`` (:data:`FILE_FORMAT`; :mod:`pkmcal.io.machine_file` reads and writes
them).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field

from ..parameters import ParameterSet
from ..units import LENGTH
from .base import Machine
from .file_format import (
    Ballbar,
    BedPlane,
    ConstraintLink,
    MachineFileHead,
    MachineFormat,
    MeasurementFramesSection,
    Number,
    Pose6,
    Positive,
    StrictModel,
    TrackerSection,
    Vector3,
    factors,
    home_pose,
)

CHAIN_FIELDS = ("b.x", "b.y", "b.z", "a0.x", "a0.y", "a0.z", "alpha", "beta", "l")
CHAIN_KINDS = ("length",) * 6 + ("angle", "angle", "length")


def hexaslide_parameters(b, a0, alpha, beta, l) -> ParameterSet:
    """Registry of a Hexa Slide from per-chain arrays (internal units: m, rad).

    Parameters
    ----------
    b : array_like, shape (6, 3)
        Platform joint positions ``B_i``, m (platform frame).
    a0 : array_like, shape (6, 3)
        Rail start points ``A0_i``, m (base frame).
    alpha : array_like, shape (6,)
        Rail azimuths, rad.
    beta : array_like, shape (6,)
        Rail elevations, rad.
    l : array_like, shape (6,)
        Link lengths, m.

    Returns
    -------
    ParameterSet
        54 parameters ``chain{i}.b.x`` ... ``chain{i}.l``, chain by chain.
    """
    b, a0 = np.asarray(b, float).reshape(6, 3), np.asarray(a0, float).reshape(6, 3)
    values = np.column_stack([b, a0, np.asarray(alpha, float), np.asarray(beta, float),
                              np.asarray(l, float)]).reshape(-1)
    names = [f"chain{i + 1}.{f}" for i in range(6) for f in CHAIN_FIELDS]
    return ParameterSet(names, CHAIN_KINDS * 6, values)


def rail_direction(alpha, beta):
    """Unit rail direction ``a`` (..., 3) of seed 000 eq. 3."""
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    return np.stack([ca * cb, sa * cb, sb], -1)


def slider_link_solve(dx, dy, dz, ax, ay, az, l):
    """Closed-form inverse kinematics of ``n`` slider-link chains at ``N`` poses at once.

    A slider moves from ``A0`` along the unit direction ``a``; a link of length ``l`` joins it
    to the point ``A0 + d``. The slider travel is ``q = a.d - sqrt(l^2 - |d|^2 + (a.d)^2)``
    (seed 000 eq. 1-9): the root with the link's end ahead of the slider along ``a``
    (``s = a.n > 0``). Shared by every machine built of such chains (Hexa Slide, linear Delta).

    Parameters
    ----------
    dx, dy, dz : ndarray, shape (n, N)
        Components of ``d`` (link end minus rail start), chain by chain; contiguous rows.
    ax, ay, az : ndarray, shape (n, 1)
        Components of the unit rail direction ``a``.
    l : ndarray, shape (n,)
        Link lengths.

    Returns
    -------
    q : ndarray, shape (n, N)
        Slider travel; NaN where the point is out of reach or the chain is singular.
    inv_s : ndarray, shape (n, N)
        ``1 / s`` with ``s = a.n``.
    nx, ny, nz : ndarray, shape (n, N)
        ``n / s``, the link vector ``n = d - q a`` over ``s``: ``dq/dd = n / s``,
        ``dq/dA0 = -n / s``, ``dq/da = -q n / s`` (on directions normal to ``a``),
        ``dq/dl = -l / s``.
    """
    ad = dx * ax
    ad += dy * ay
    ad += dz * az
    rad = (l * l)[:, None] + ad * ad
    rad -= dx * dx
    rad -= dy * dy
    rad -= dz * dz
    with np.errstate(invalid="ignore"):
        s = np.sqrt(rad)                                    # = a.n
    s[~(s > 0)] = np.nan                                    # singular or unreachable
    q = ad - s
    inv_s = 1.0 / s
    nx = (dx - q * ax) * inv_s                              # n / s, link vector n = d - q a
    ny = (dy - q * ay) * inv_s
    nz = (dz - q * az) * inv_s
    return q, inv_s, nx, ny, nz


class HexaSlide(Machine):
    """6-PUS Hexa Slide machine; see the module docstring for the model.

    Parameters
    ----------
    parameters : ParameterSet
        The 54 chain parameters (:func:`hexaslide_parameters`).
    home : tuple of ndarray, optional
        ``(P, R)`` pose of the working assembly mode; default: :meth:`default_home`.
    name : str, optional
        Free-text name of the machine.
    constraint_link_length : float, optional
        Length of the constraint link (from the base origin O to the platform origin), m, when
        the machine is used with one.
    """

    kind = "hexaslide"
    #: the instrument of its source paper (seed 000): the calibrations' default scenario
    default_instrument = "constraint-link"
    joints_read_words = "sliders read"
    actuation_words = "a Hexa Slide moves fixed-length legs with sliders on rails"
    n_joints = 6
    pose_dof = 6
    DEFAULT_DEVIATIONS = "paper-table1"

    def paper_deviations(self):
        """Seed 000 Table 1's build errors (:func:`paper_table1_deviations`).

        Returns
        -------
        ndarray, shape (n_params,)
            Deviations, internal units.
        """
        return paper_table1_deviations(self.parameters)

    def __init__(self, parameters: ParameterSet, home=None, name: str = "",
                 constraint_link_length: float | None = None):
        super().__init__(parameters, home, name)
        self.constraint_link_length = constraint_link_length
        p = parameters
        self._ib = np.stack([p.indices(f"chain{i + 1}.b") for i in range(6)])
        self._ia0 = np.stack([p.indices(f"chain{i + 1}.a0") for i in range(6)])
        self._ial = np.array([p.index(f"chain{i + 1}.alpha") for i in range(6)])
        self._ibe = np.array([p.index(f"chain{i + 1}.beta") for i in range(6)])
        self._il = np.array([p.index(f"chain{i + 1}.l") for i in range(6)])
        self._chain_index = np.concatenate(                     # (6, 9) in CHAIN_FIELDS order
            [self._ib, self._ia0, self._ial[:, None], self._ibe[:, None], self._il[:, None]], -1)

    # -- geometry -------------------------------------------------------------------------
    def chains(self, u=None):
        """Per-chain parameter arrays, the chains along the first axis.

        Parameters
        ----------
        u : array_like, shape (54,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        b : ndarray, shape (6, 3)
            Platform joints, m.
        a0 : ndarray, shape (6, 3)
            Rail start points, m.
        alpha : ndarray, shape (6,)
            Rail azimuths, rad.
        beta : ndarray, shape (6,)
            Rail elevations, rad.
        l : ndarray, shape (6,)
            Link lengths, m.
        """
        u = self.u if u is None else np.asarray(u, float)
        return u[self._ib], u[self._ia0], u[self._ial], u[self._ibe], u[self._il]

    def characteristic_length(self) -> float:
        return float(np.mean(self.chains()[4]))

    def default_home(self):
        """Platform origin above O on the constraint sphere (or at the mean link length).

        Returns
        -------
        P : ndarray, shape (3,)
            ``(0, 0, Lc)`` with the constraint-link length ``Lc``, else the mean link length, m.
        R : ndarray, shape (3, 3)
            The identity.
        """
        b, a0, alpha, beta, l = self.chains()
        height = self.constraint_link_length or float(np.mean(l))
        P = np.array([0.0, 0.0, height])
        return P, np.eye(3)

    # -- validation -----------------------------------------------------------------------
    def geometry_problems(self, home_given: bool = True) -> list[tuple[tuple, str]]:
        """Degenerate chains (see :meth:`Machine.geometry_problems`).

        Refused: two chains that are the same chain (the same rail line and direction,
        platform joint and link length, within 1e-6 of the machine's size or 1e-6 rad: their
        equations coincide, the Jacobian is singular everywhere); all six platform joints at
        one point (nothing holds the orientation); the given home out of reach; a joint
        Jacobian singular at home (e.g. links along their rails' normal planes, or six links
        parallel to six parallel rails).

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
        b, a0, alpha, beta, l = self.chains()
        with np.errstate(all="ignore"):
            a = rail_direction(alpha, beta)
            tol = 1e-6 * self.characteristic_length()
            for j in range(6):
                for i in range(j):
                    d = a0[j] - a0[i]
                    off_line = np.linalg.norm(d - (d @ a[i]) * a[i])
                    if (a[i] @ a[j] >= np.cos(1e-6) and off_line <= tol
                            and np.linalg.norm(b[i] - b[j]) <= tol and abs(l[i] - l[j]) <= tol):
                        return [(("chains", j), f"the same chain as chains[{i}] (the same rail "
                                 "a0, alpha, beta, the same platform joint b and link length "
                                 "l): the two sliders move together and only five chains "
                                 "hold the platform; check the chains' values")]
            if np.all(np.linalg.norm(b - b.mean(0), axis=-1) <= tol):
                return [(("chains",), "all six platform joints b are at one point: nothing "
                         "holds the platform's orientation; check the chains' b")]
        bad, singular = self._home_check()
        if bad.size:
            if not home_given:
                return []             # the default home is a guess: FK finds its own start
            return [(("home",), f"the pose cannot be reached by chain(s) "
                     f"{', '.join(str(i + 1) for i in bad)} (link too short for the distance "
                     "between rail and platform joint); check home and chains")]
        if singular:
            at = "at home" if home_given else "at the default home (0, 0, constraint link " \
                "length or mean link length)"
            return [(("home",) if home_given else ("chains",),
                     f"the six chains do not hold the platform {at}: the joint Jacobian is "
                     "singular there (e.g. each link square to its rail, or the links parallel "
                     "to parallel rails); check the chains"
                     + (" and home" if home_given else ", or give a home pose where they do"))]
        return []

    # -- kinematics -----------------------------------------------------------------------
    def ik_jacobians(self, P, R, u=None, want_du: bool = True):
        b, a0, alpha, beta, l = self.chains(u)
        ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
        ax, ay, az = (ca * cb)[:, None], (sa * cb)[:, None], sb[:, None]   # rail a, (6, 1)
        P = np.asarray(P, float)
        R = np.asarray(R, float)
        shape = np.broadcast_shapes(P.shape[:-1], R.shape[:-2])
        N = int(np.prod(shape))
        # Chain-first layout: every per-chain quantity is a contiguous (6, N) array, so the
        # arithmetic runs on long vectors without einsum or cross-product overhead.
        Pt = np.broadcast_to(P, shape + (3,)).reshape(N, 3).T
        R2 = np.broadcast_to(R, shape + (3, 3)).reshape(N, 3, 3)
        rbx, rby, rbz = (b @ R2[:, i, :].T for i in range(3))   # R B_i, (6, N) each
        dx = rbx + (Pt[0] - a0[:, 0:1])                          # d = P + R B - A0
        dy = rby + (Pt[1] - a0[:, 1:2])
        dz = rbz + (Pt[2] - a0[:, 2:3])
        q, inv_s, nx, ny, nz = slider_link_solve(dx, dy, dz, ax, ay, az, l)
        Jt = np.empty((6, 6, N))                                # (chain, [dP, dOmega], pose)
        Jt[:, 0], Jt[:, 1], Jt[:, 2] = nx, ny, nz
        np.subtract(rby * nz, rbz * ny, out=Jt[:, 3])           # (R B) x n / s
        np.subtract(rbz * nx, rbx * nz, out=Jt[:, 4])
        np.subtract(rbx * ny, rby * nx, out=Jt[:, 5])
        q_out = q.T.reshape(shape + (6,))
        dq_dpose = Jt.transpose(2, 0, 1).reshape(shape + (6, 6))
        if not want_du:
            return q_out, dq_dpose, None
        cols = np.empty((N, 6, 9))                              # CHAIN_FIELDS order
        for j in range(3):                                      # dq/dB = R^T n / s
            cols[:, :, j] = (R2[:, 0, j:j + 1] * nx.T + R2[:, 1, j:j + 1] * ny.T
                             + R2[:, 2, j:j + 1] * nz.T)
        cols[:, :, 3], cols[:, :, 4], cols[:, :, 5] = -nx.T, -ny.T, -nz.T   # dq/dA0
        f = -q * inv_s                                          # dq/da = -q d / s
        cols[:, :, 6] = (f * (dy * (ca * cb)[:, None] - dx * (sa * cb)[:, None])).T
        cols[:, :, 7] = (f * (dz * cb[:, None] - (dx * (ca * sb)[:, None]
                                                  + dy * (sa * sb)[:, None]))).T
        cols[:, :, 8] = (-l[:, None] * inv_s).T                 # dq/dl
        dq_du = np.zeros((N, 6, len(self.parameters)))
        dq_du[:, np.arange(6)[:, None], self._chain_index] = cols
        return q_out, dq_dpose, dq_du.reshape(shape + (6, len(self.parameters)))

    # -- frames ---------------------------------------------------------------------------
    def transform_base(self, u, G, t=None):
        """Chains in a base frame rotated by ``G`` (and moved: ``a0' = G a0 + t``).

        Parameters
        ----------
        u : array_like, shape (54,)
            Parameter vector (internal units).
        G : array_like, shape (3, 3)
            Rotation from the old to the new base frame.
        t : array_like, shape (3,), optional
            Translation of the new base frame, m.

        Returns
        -------
        ndarray, shape (54,)
            The transformed parameter vector.
        """
        u = np.array(u, float)
        b, a0, alpha, beta, l = self.chains(u)
        a = rail_direction(alpha, beta) @ np.asarray(G).T
        u[self._ia0] = a0 @ np.asarray(G).T + (0.0 if t is None else np.asarray(t, float))
        new_alpha = np.arctan2(a[:, 1], a[:, 0])
        u[self._ial] = alpha + (new_alpha - alpha + np.pi) % (2 * np.pi) - np.pi
        u[self._ibe] = np.arcsin(np.clip(a[:, 2], -1, 1))
        return u

    def transform_platform(self, u, C, t=None):
        """Platform joints in a re-oriented (and moved) platform frame: ``b' = C^T (b - t)``.

        Parameters
        ----------
        u : array_like, shape (54,)
            Parameter vector (internal units).
        C : array_like, shape (3, 3)
            Rotation of the new platform frame relative to the old one.
        t : array_like, shape (3,), optional
            Origin of the new platform frame in the old one, m.

        Returns
        -------
        ndarray, shape (54,)
            The transformed parameter vector.
        """
        u = np.array(u, float)
        b = self.chains(u)[0] - (0.0 if t is None else np.asarray(t, float))
        u[self._ib] = b @ np.asarray(C)                   # rows: (C^T b)^T = b^T C
        return u


def default_hexaslide() -> HexaSlide:
    """The embedded default geometry of SPEC 2.1 (ours; the paper's figure is not in the text).

    Chain ``2k + s + 1`` (k = 0, 1, 2; s = 0, 1): ``g = 120k -/+ 20``, ``gb = 120k -/+ 45`` deg
    (minus for s = 0); ``A0 = (480 cos g, 480 sin g, -400)`` mm, ``alpha = g + 180``,
    ``beta = 70`` deg, ``B = (120 cos gb, 120 sin gb, 0)`` mm, ``l = 450`` mm, ``Lc = 300`` mm,
    home ``P = (0, 0, 300)`` mm, ``R = I``.

    Returns
    -------
    HexaSlide
        A new nominal machine.
    """
    k = np.repeat(np.arange(3), 2)
    sgn = np.tile([-1.0, 1.0], 3)
    g = np.deg2rad(120 * k + sgn * 20)
    gb = np.deg2rad(120 * k + sgn * 45)
    a0 = np.column_stack([0.48 * np.cos(g), 0.48 * np.sin(g), np.full(6, -0.4)])
    b = np.column_stack([0.12 * np.cos(gb), 0.12 * np.sin(gb), np.zeros(6)])
    alpha_deg = (120 * k + sgn * 20 + 360) % 360 - 180          # g + 180 in [-180, 180)
    alpha = np.deg2rad(alpha_deg)
    params = hexaslide_parameters(b, a0, alpha, np.full(6, np.deg2rad(70)), np.full(6, 0.45))
    return HexaSlide(params, home=(np.array([0, 0, 0.3]), np.eye(3)),
                     name="pkmcal default Hexa Slide (SPEC 2.1)", constraint_link_length=0.3)


#: Seed 000 Table 1: deviations of the true machine from nominal (m, rad), per chain 1..6.
PAPER_TABLE1 = {
    "l": [1.9e-3, 1.8e-3, 1.6e-3, -0.5e-3, -0.1e-3, -0.3e-3],
    "b.x": [-1.1e-3, -1.2e-3, -1.2e-3, 1.3e-3, 1.9e-3, 1.6e-3],
    "b.y": [-1.9e-3, 1.2e-3, 1.4e-3, 1.3e-3, 1.7e-3, -1.9e-3],
    "b.z": [3.8e-3, 3.9e-3, 3.9e-3, 3.8e-3, 4.0e-3, 3.7e-3],
    "a0.x": [-1.9e-3, -2.0e-3, -1.4e-3, 1.3e-3, -1.8e-3, -1.4e-3],
    "a0.y": [-1.8e-3, 1.1e-3, -0.8e-3, -2.6e-3, -0.6e-3, -1.4e-3],
    "a0.z": [-1.5e-3, -0.2e-3, -1.7e-3, -1.4e-3, 1.1e-3, -1.3e-3],
    "alpha": [2.4e-2, 2.4e-2, -7.0e-2, -7.0e-2, 1.8e-2, 1.8e-2],
    "beta": [-2.4e-2] * 6,
}


def paper_table1_deviations(parameters: ParameterSet) -> np.ndarray:
    """Seed 000 Table 1 as a deviation vector in the order of ``parameters``.

    Parameters
    ----------
    parameters : ParameterSet
        A Hexa Slide registry (names ``chain{i}.*``).

    Returns
    -------
    ndarray, shape (len(parameters),)
        Deviations of the true machine from nominal, m and rad; zero for parameters the
        table does not list.
    """
    du = np.zeros(len(parameters))
    for field, values in PAPER_TABLE1.items():
        for i, v in enumerate(values):
            du[parameters.index(f"chain{i + 1}.{field}")] = v
    return du


# --------------------------------------------------------------------------------------------
# The machine file section (``machine: hexaslide``)
# --------------------------------------------------------------------------------------------


class HexaSlideChain(StrictModel):
    """One 6-PUS chain: rail start ``a0``, rail angles, platform joint ``b``, link length."""

    a0: Vector3
    alpha: Number
    beta: Number
    b: Vector3
    l: Positive


class HexaSlideFile(MachineFileHead):
    """``machine: hexaslide`` (SPEC 6)."""

    machine: Literal["hexaslide"]
    constraint_link: ConstraintLink | None = None
    home: Pose6 | None = None
    chains: Annotated[list[HexaSlideChain], Field(min_length=6, max_length=6)]
    tracker: TrackerSection | None = None
    ballbar: Ballbar | None = None
    bed: BedPlane | None = None
    measurement_frames: MeasurementFramesSection | None = None


def _build(doc: HexaSlideFile, source: str) -> HexaSlide:
    fl, fa = factors(doc.units.model_dump())
    ch = doc.chains
    params = hexaslide_parameters(
        b=np.array([c.b for c in ch]) * fl,
        a0=np.array([c.a0 for c in ch]) * fl,
        alpha=np.array([c.alpha for c in ch]) * fa,
        beta=np.array([c.beta for c in ch]) * fa,
        l=np.array([c.l for c in ch]) * fl,
    )
    lc = doc.constraint_link.length * fl if doc.constraint_link is not None else None
    return HexaSlide(params, home=home_pose(doc.home, fl, fa), name=doc.name or "",
                     constraint_link_length=lc)


def _dump(machine: HexaSlide, units: dict) -> dict[str, Any]:
    fl, fa = factors(units)
    b, a0, alpha, beta, l = machine.chains()
    out: dict[str, Any] = {}
    if machine.constraint_link_length is not None:
        out["constraint_link"] = {"length": float(machine.constraint_link_length) / fl}
    out["chains"] = [
        {"a0": [float(v) / fl for v in a0[i]], "alpha": float(alpha[i]) / fa,
         "beta": float(beta[i]) / fa, "b": [float(v) / fl for v in b[i]],
         "l": float(l[i]) / fl}
        for i in range(6)
    ]
    return out


def _size(doc) -> tuple[float, str]:
    fl = LENGTH[doc.units.length]
    return float(np.median([c.l for c in doc.chains])) * fl, "the median link length l"


#: the machine file section of a Hexa Slide (:mod:`pkmcal.machines.registry`)
FILE_FORMAT = MachineFormat(
    HexaSlideFile, _build, _dump, {"chains": 6},
    hints={"chains": "a list of 6 chains {a0: [x, y, z], alpha, beta, b: [x, y, z], l}"},
    kinds={("chains", "*", "a0", "*"): "length", ("chains", "*", "b", "*"): "length",
           ("chains", "*", "l"): "dimension", ("chains", "*", "alpha"): "angle",
           ("chains", "*", "beta"): "angle", ("constraint_link", "length"): "dimension"},
    size=_size, kind=HexaSlide.kind, default=default_hexaslide)
