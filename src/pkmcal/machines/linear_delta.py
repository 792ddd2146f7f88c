"""Linear Delta 3D printer: three carriages on (nearly) vertical towers, parallelogram arms.

The effector translates (``pose_dof = 3``); the platform point is the NOZZLE TIP. Joint ``i``
reads ``q_i``, the travel of carriage ``i`` DOWN its tower from its endstop (0 at the endstop,
m), as a firmware's step count divided by steps per mm gives it.

Kinematics (the Hexa Slide chain, SPEC 2.1, one per tower)
----------------------------------------------------------
Tower ``i`` is the chain ``(a0_i, a_i, l_i, b_i)`` of the Hexa Slide: ``a0`` the carriage joint
at the endstop, ``a = [cos(alpha) cos(beta), sin(alpha) cos(beta), sin(beta)]`` the unit
direction down the tower, ``l`` the arm length, ``b`` the effector joint relative to the nozzle
tip (base axes: the effector does not rotate). With ``d = P + b - a0`` the carriage travel is
``q = a.d - sqrt(l^2 - |d|^2 + (a.d)^2)``, computed by the Hexa Slide's own routine
(:func:`~pkmcal.machines.hexaslide.slider_link_solve`). Forward kinematics intersects the three
spheres of radius ``l_i`` about ``a0_i + q_i a_i - b_i`` in closed form and takes the lower
root (the nozzle hangs below the carriages).

Parameters (what a firmware adjusts, so that a firmware's set is "these free, the rest fixed")
----------------------------------------------------------------------------------------------
Twenty parameters, internal units m and rad:

``delta_radius``, ``arm_length``
    common radius ``R`` and arm length ``L``;
``tower{i}.radius_trim``, ``tower{i}.arm_trim``
    per-tower trims: tower ``i`` has radius ``r_i = R + radius_trim_i`` and arm
    ``l_i = L + arm_trim_i``. A firmware with one radius (all three) frees ``delta_radius``
    and fixes the trims; one with per-tower arms (Klipper) frees the trims; one that adjusts
    all diagonals by one increment (RepRapFirmware) frees ``arm_length``. Common value and
    trims together are redundant (only the sums enter): ``full`` fixes the common values.
``tower{i}.angle``
    tower angle ``theta_i``, counter-clockwise from +X (Klipper's ``angle``, default 210, 330,
    90 deg);
``tower{i}.endstop``
    ``position_endstop`` of the tower in Klipper's meaning: the nozzle-to-bed distance (the
    nozzle at the centre) when that tower's carriage is at its endstop, so the carriage
    height at the endstop is ``endstop_i + sqrt(l_i^2 - r_i^2)`` (vertical tower);
``tower{i}.tilt_radial``, ``tower{i}.tilt_tangential``
    tower tilt, rad: the top of the tower leaning away from the centre, and counter-clockwise
    (towards ``e_t``). Zero for Klipper, Marlin and RepRapFirmware, which assume vertical
    towers.

The map to the chain, with ``e_r = (cos theta, sin theta, 0)``, ``e_t = (-sin theta,
cos theta, 0)``, ``e_z``, ``h_i = sqrt(l_i^2 - r_i^2)``::

    a0_i - b_i = r_i e_r + (endstop_i + h_i) e_z
    a_i = -sin(tr) cos(tt) e_r - sin(tt) e_t - cos(tr) cos(tt) e_z     (tr, tt: the tilts)
    l_i = L + arm_trim_i

so ``r_i``, ``theta_i`` are the polar coordinates of ``a0 - b`` (Klipper's tower position:
``delta_radius`` is the horizontal distance between the carriage joint line and the effector
joint line with the nozzle at the centre), and the tilt turns the tower about its carriage
joint at the endstop. The map is exact both ways: a file's ``chains`` (absolute ``a0``,
``alpha``, ``beta``, ``l``, ``b``) give ``r``, ``theta`` (``atan2``), ``endstop = (a0 - b)_z -
h``, the tilts from ``a`` in the tower's frame, and the trims against the common values.
``b`` enters the kinematics only through ``a0 - b`` (the effector does not rotate), so it is
not a parameter: it is kept as :attr:`LinearDelta.b` to write the file's chains back
(``a0 = b + ...``). With ``b = 0`` and no tilt this is Klipper's model exactly
(``klippy/kinematics/delta.py``: tower ``(cos(angle) r, sin(angle) r)``, ``abs_endstops =
position_endstop + sqrt(arm^2 - radius^2)``, carriage height ``sqrt(arm^2 - (tx - x)^2 -
(ty - y)^2) + z``; ``klippy/extras/delta_calibrate.py``: the "stable position" is the step
count since the endstop, carriage height ``abs_endstop - steps * step_dist``).

Firmware parameter sets (:attr:`LinearDelta.PARAMETER_SETS`), from the sources read
-------------------------------------------------------------------------------------
``klipper``
    Klipper ``DELTA_CALIBRATE`` / ``DELTA_ANALYZE CALIBRATE=extended``
    (``klippy/kinematics/delta.py``, ``DeltaCalibration.coordinate_descent_params``): adjusts
    ``radius``, ``angle_a``, ``angle_b``, ``endstop_a/b/c`` (the ``position_endstop`` values)
    and, only in the extended mode (when distance measurements of the printed calibration
    object exist), ``arm_a/b/c``; ``angle_c`` is never adjusted (the gauge: rotation about
    z). The basic ``DELTA_CALIBRATE`` fixes the arm lengths: that is ``klipper-basic``.
    ``klipper`` is the extended set: 3 endstops, the radius, 2 tower angles, 3 arm lengths
    (the per-tower arm trims; the common value stays).
``marlin``
    Marlin ``G33`` (``Marlin/src/gcode/calibrate/G33.cpp``, ``Marlin/src/module/delta.cpp``):
    ``P3`` and above adjust ``delta_endstop_adj`` (3, normalised so the largest is 0 with
    ``delta_height``: together one endstop per tower), ``delta_radius`` and
    ``delta_tower_angle_trim`` (3, normalised to sum zero after each iteration: the same
    machine as fixing the third, turned about z). ``G33`` never adjusts
    ``delta_diagonal_rod``, the per-tower ``delta_diagonal_rod_trim`` or the compile-time
    ``DELTA_RADIUS_TRIM_TOWER``. Set: 3 endstops, ``delta_radius``, tower 1 and 2 angles.
    (``G33 P2`` leaves the angles: the same as ``rrf-4``.)
``rrf``
    RepRapFirmware's least squares (``src/Movement/Kinematics/LinearDeltaKinematics.cpp``,
    ``DoAutoCalibration``/``ComputeDerivative``/``Adjust``): factors 0-2 the endstop
    adjustments (normalised to mean zero into ``homedHeight``: one endstop per tower), 3 the
    delta radius, 4-5 the X and Y tower angle corrections (Z is never adjusted), 6 the
    diagonal rod (one increment added to all diagonals), 7-8 the bed tilt X/Y. ``rrf`` is the
    7-factor set; the 9-factor bed tilt is the probe instrument's bed plane, estimated with
    every set (kept once, there). ``rrf-6``, ``rrf-4``, ``rrf-3``: the smaller sets.
``full``
    every tower quantity (endstop, angle, radius and arm trims, both tilts; the common
    radius and arm length are fixed: with the trims free they add nothing). No gauge is
    fixed: the estimator names the rotation about z and what the instrument cannot see.

The machine file (SPEC 6, issue 14)
-----------------------------------
The design values, in Klipper's names and meanings, and optionally the full chain of each
tower (Hexa Slide keys, SPEC 2.1, absolute values; the top-level keys stay the design)::

    pkmcal: 1
    machine: linear_delta
    units: {length: mm, angle: deg}
    delta_radius: 140.0                        # carriage joint line to effector joint line
    arm_length: 270.0                          # or a list of three
    tower_angles: [210.0, 330.0, 90.0]         # counter-clockwise from +X
    position_endstop: [300.0, 300.0, 300.0]    # nozzle-to-bed distance at each endstop
    chains:                                    # optional: exactly 3
      - {a0: [-121.2, -70.0, 518.2], alpha: 210.0, beta: -90.0, b: [0, 0, 0], l: 270.0}
    home: [0.0, 0.0, 120.0]                    # x, y, z of the nozzle

``a0`` is the carriage joint at the endstop, ``alpha``/``beta`` the direction down the tower,
``l`` the arm and ``b`` the effector joint relative to the nozzle tip; the readings
``q1_mm..q3_mm`` are the carriages' travels down from their endstops. With ``chains`` the
machine's common ``delta_radius`` and ``arm_length`` parameters take the top-level values and
the per-tower trims the differences; a file is written with ``chains`` whenever its geometry
is not exactly the design's (a calibrated file). ``print_radius`` and ``probe_radius``
(optional) are the firmware's print and probing radii.
"""

from __future__ import annotations

import functools
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, Strict, field_validator
from pydantic_core import PydanticCustomError

from ..errors import InputError
from ..kinematics import matrix_from_rotvec
from ..parameters import ParameterSet
from ..units import LENGTH
from .base import (
    FKResult,
    FrameMotion,
    Machine,
    ModelCandidate,
    ParameterSubset,
    closed_form_positions_fk,
)
from .file_format import (
    Ballbar,
    BedPlane,
    MachineFileHead,
    MachineFormat,
    Number,
    Positive,
    TrackerPose,
    Vector3,
    factors,
    show,
    vector,
)
from .hexaslide import HexaSlideChain, rail_direction, slider_link_solve

TOWER_FIELDS = ("endstop", "angle", "radius_trim", "arm_trim", "tilt_radial", "tilt_tangential")
TOWER_KINDS = ("length", "angle", "length", "length", "angle", "angle")
#: Klipper's default tower angles (``klippy/kinematics/delta.py``), rad
DEFAULT_TOWER_ANGLES = np.deg2rad([210.0, 330.0, 90.0])

_ENDSTOPS = ("tower1.endstop", "tower2.endstop", "tower3.endstop")
_ARM_TRIMS = ("tower1.arm_trim", "tower2.arm_trim", "tower3.arm_trim")
_TWO_ANGLES = ("tower1.angle", "tower2.angle")


def linear_delta_parameters(delta_radius, arm_length, tower_angles, endstops, radius_trim=0.0,
                            arm_trim=0.0, tilt_radial=0.0, tilt_tangential=0.0) -> ParameterSet:
    """Registry of a linear Delta (internal units: m, rad); see the module docstring.

    Parameters
    ----------
    delta_radius : float
        Common radius ``R``, m.
    arm_length : float
        Common arm length ``L``, m.
    tower_angles : array_like, shape (3,)
        Tower angles, rad.
    endstops : array_like, shape (3,)
        ``position_endstop`` per tower, m.
    radius_trim, arm_trim : array_like, shape (3,) or float, optional
        Per-tower trims of radius and arm length, m.
    tilt_radial, tilt_tangential : array_like, shape (3,) or float, optional
        Tower tilts, rad.

    Returns
    -------
    ParameterSet
        ``delta_radius``, ``arm_length``, then ``tower{i}.endstop`` ... ``tilt_tangential``
        tower by tower (20 parameters).
    """
    cols = [np.broadcast_to(np.asarray(v, float), (3,)) for v in
            (endstops, tower_angles, radius_trim, arm_trim, tilt_radial, tilt_tangential)]
    values = np.concatenate([[float(delta_radius), float(arm_length)],
                             np.column_stack(cols).reshape(-1)])
    names = ["delta_radius", "arm_length"] + [f"tower{i + 1}.{f}" for i in range(3)
                                              for f in TOWER_FIELDS]
    return ParameterSet(names, ("length", "length") + TOWER_KINDS * 3, values)


@functools.cache
def _up(n: int) -> np.ndarray:
    """``n`` rows of the vertical (0, 0, 1), read-only (shared)."""
    up = np.zeros((n, 3))
    up[:, 2] = 1.0
    up.flags.writeable = False
    return up


class LinearDelta(Machine):
    """Linear Delta printer with the per-tower Hexa Slide chain; see the module docstring.

    Parameters
    ----------
    parameters : ParameterSet
        The 20 parameters (:func:`linear_delta_parameters`).
    b : array_like, shape (3, 3), optional
        Effector joints relative to the nozzle tip, m (base axes); default 0. Only ``a0 - b``
        enters the kinematics: ``b`` is carried for the file's ``chains``.
    nominal : dict, optional
        The design values of the machine file's top level (SI): ``delta_radius``,
        ``arm_length`` (float or (3,)), ``tower_angles`` (3,), ``position_endstop`` (3,);
        default: taken from ``parameters``.
    home : tuple of ndarray, optional
        ``(P, R)`` start pose; default: :meth:`default_home`.
    name : str, optional
        Free-text name of the machine.
    """

    kind = "linear_delta"
    #: a printer calibrates from its bed probe (Klipper DELTA_CALIBRATE, Marlin G33, RRF G32)
    default_instrument = "probe"
    n_joints = 3
    pose_dof = 3
    #: random deviations of simulated true machines (m, rad): endstops, radius and arms off
    #: by up to 1 mm, towers leaning and turned by up to 0.3 deg
    RANDOM_DEVIATION = (1e-3, float(np.deg2rad(0.3)))
    joint_quantity = "length"
    #: the tracker's reflector below the nozzle tip, m: 0 (:meth:`tracker_target`)
    smr_offset = 0.0
    #: the bed's height in the base frame, m: Klipper's coordinates put the bed at z = 0 (the
    #: probe instrument's planned points lie on it)
    bed_height = 0.0
    #: a printer's frame is its bed (SPEC 8): z = 0 the probed bed, z up its normal; probe
    #: heights hold the bed's height at 0 (the endstops carry it) and estimate its tilt only
    #: where the data tell it from the parameter set
    frame_is_bed = True
    working_frame_words = "the printer's frame: z is the height above its bed"

    PARAMETER_SETS = {
        "klipper": ParameterSubset(
            _ENDSTOPS + ("delta_radius",) + _TWO_ANGLES + _ARM_TRIMS,
            "Klipper DELTA_CALIBRATE with DELTA_ANALYZE (extended): position_endstop of the "
            "three towers, delta_radius, the angles of towers 1 and 2 (tower 3's fixes the "
            "rotation about z) and the three arm lengths; with heights alone, as Klipper, "
            "klipper-basic", without_lengths="klipper-basic"),
        "klipper-basic": ParameterSubset(
            _ENDSTOPS + ("delta_radius",) + _TWO_ANGLES,
            "Klipper DELTA_CALIBRATE (basic, heights only): the three endstops, delta_radius "
            "and the angles of towers 1 and 2; the arm lengths are fixed", kinds=("probe",)),
        "marlin": ParameterSubset(
            _ENDSTOPS + ("delta_radius",) + _TWO_ANGLES,
            "Marlin G33 (P3 and above): endstop adjustments with the delta height (one "
            "endstop per tower), delta_radius and the tower angle trims (normalised to sum "
            "zero by Marlin: tower 3's fixed here, the same machine turned about z); G33 "
            "never adjusts the diagonal rod"),
        "rrf": ParameterSubset(
            _ENDSTOPS + ("delta_radius",) + _TWO_ANGLES + ("arm_length",),
            "RepRapFirmware 7-factor (the 9-factor bed tilt is the probe's bed plane): the "
            "endstop adjustments with the homed height, delta radius, X and Y tower angle "
            "corrections (Z fixed) and one increment of all diagonal rods"),
        "rrf-6": ParameterSubset(
            _ENDSTOPS + ("delta_radius",) + _TWO_ANGLES,
            "RepRapFirmware 6-factor: endstops, delta radius, X and Y tower angle corrections"),
        "rrf-4": ParameterSubset(
            _ENDSTOPS + ("delta_radius",),
            "RepRapFirmware 4-factor (and Marlin G33 P2): endstops and delta radius"),
        "rrf-3": ParameterSubset(_ENDSTOPS, "RepRapFirmware 3-factor: the endstops only"),
        "full": ParameterSubset(
            tuple(f"tower{i + 1}" for i in range(3)),
            "every tower quantity: endstop, angle, radius and arm (the trims; the common "
            "delta_radius and arm_length are fixed, redundant with them) and both tilts"),
    }

    def __init__(self, parameters: ParameterSet, b=None, nominal: dict | None = None,
                 home=None, name: str = ""):
        super().__init__(parameters, home, name)
        p = parameters
        self.b = np.zeros((3, 3)) if b is None else np.array(b, float).reshape(3, 3)
        self._iR, self._iL = p.index("delta_radius"), p.index("arm_length")
        self._idx = np.stack([[p.index(f"tower{i + 1}.{f}") for f in TOWER_FIELDS]
                              for i in range(3)])                         # (3, 6)
        if nominal is None:
            u = p.values
            nominal = {"delta_radius": float(u[self._iR]), "arm_length": float(u[self._iL]),
                       "tower_angles": u[self._idx[:, 1]].copy(),
                       "position_endstop": u[self._idx[:, 0]].copy()}
        self.nominal = nominal
        #: True when the geometry came from a file's ``chains`` (messages name those keys)
        self.from_chains = False

    # -- geometry -------------------------------------------------------------------------
    def towers(self, u=None):
        """Per-tower values of the firmware parameters, the towers along the first axis.

        Parameters
        ----------
        u : array_like, shape (20,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        endstop : ndarray, shape (3,)
            ``position_endstop``, m.
        theta : ndarray, shape (3,)
            Tower angles, rad.
        r : ndarray, shape (3,)
            Tower radii ``delta_radius + radius_trim``, m.
        l : ndarray, shape (3,)
            Arm lengths ``arm_length + arm_trim``, m.
        tilt_radial, tilt_tangential : ndarray, shape (3,)
            Tower tilts, rad.
        """
        u = self.u if u is None else np.asarray(u, float)
        e = u[self._idx]
        return (e[:, 0], e[:, 1], u[self._iR] + e[:, 2], u[self._iL] + e[:, 3], e[:, 4],
                e[:, 5])

    def _frames(self, theta):
        # filled in place, not np.stack / np.broadcast_to: this runs at every evaluation
        # of a fit, and their overhead was most of its time (the same values)
        c, s = np.cos(theta), np.sin(theta)
        er, et = np.zeros((len(c), 3)), np.zeros((len(c), 3))
        er[:, 0], er[:, 1] = c, s
        et[:, 0], et[:, 1] = -s, c
        return er, et, _up(len(c))

    def _geometry(self, u=None):
        """``c = a0 - b`` (3, 3), ``a`` (3, 3), ``l`` (3,) and intermediate values."""
        pe, theta, r, l, tr, tt = self.towers(u)
        er, et, ez = self._frames(theta)
        with np.errstate(invalid="ignore"):
            h = np.sqrt(l * l - r * r)
        c = r[:, None] * er + (pe + h)[:, None] * ez
        ar, at, az = -np.sin(tr) * np.cos(tt), -np.sin(tt), -np.cos(tr) * np.cos(tt)
        a = ar[:, None] * er + at[:, None] * et + az[:, None] * ez
        return c, a, l, (r, h, er, et, ez, ar, at, tr, tt)

    def chains(self, u=None):
        """The Hexa Slide chain of each tower (file keys of ``chains``), absolute values.

        Parameters
        ----------
        u : array_like, shape (20,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        a0 : ndarray, shape (3, 3)
            Carriage joints at the endstops, m.
        alpha, beta : ndarray, shape (3,)
            Direction down each tower (azimuth, elevation), rad; for a vertical tower
            ``beta = -90 deg`` and ``alpha`` the tower angle.
        l : ndarray, shape (3,)
            Arm lengths, m.
        b : ndarray, shape (3, 3)
            Effector joints relative to the nozzle tip, m.
        """
        c, a, l, extra = self._geometry(u)
        theta = self.towers(u)[1]
        alpha = np.where(np.hypot(a[:, 0], a[:, 1]) > 0, np.arctan2(a[:, 1], a[:, 0]), theta)
        vertical = (extra[7] == 0) & (extra[8] == 0)
        alpha = np.where(vertical, theta, alpha)
        # atan2, not arcsin: well conditioned near -90 deg (nearly vertical towers)
        beta = np.where(vertical, -np.pi / 2, np.arctan2(a[:, 2], np.hypot(a[:, 0], a[:, 1])))
        return c + self.b, alpha, beta, l.copy(), self.b.copy()

    def parameters_from_chains(self, a0, alpha, beta, l, b=None, u=None) -> np.ndarray:
        """Parameter vector of given chains (the inverse of :meth:`chains`).

        The common ``delta_radius`` and ``arm_length`` keep their values in ``u``; the trims
        take the differences.

        Parameters
        ----------
        a0 : array_like, shape (3, 3)
            Carriage joints at the endstops, m.
        alpha, beta : array_like, shape (3,)
            Direction down each tower, rad.
        l : array_like, shape (3,)
            Arm lengths, m.
        b : array_like, shape (3, 3), optional
            Effector joints; default :attr:`b`.
        u : array_like, shape (20,), optional
            Where the common values (and the branch of the tower angles) come from; default
            :attr:`u`.

        Returns
        -------
        ndarray, shape (20,)
            The parameters, internal units.
        """
        b = self.b if b is None else np.asarray(b, float).reshape(3, 3)
        a = rail_direction(np.asarray(alpha, float), np.asarray(beta, float))
        # beta = -90 deg: cos(beta) is 6e-17, not 0; a vertical tower has no tilt
        a[np.hypot(a[:, 0], a[:, 1]) < 1e-15] = [0.0, 0.0, -1.0]
        return self._from_geometry(np.asarray(a0, float) - b, a, np.asarray(l, float), u)

    def _from_geometry(self, c, a, l, u=None):
        u = np.array(self.u if u is None else u, float)
        theta_old = u[self._idx[:, 1]]
        r = np.hypot(c[:, 0], c[:, 1])
        theta = np.arctan2(c[:, 1], c[:, 0])
        theta = theta_old + (theta - theta_old + np.pi) % (2 * np.pi) - np.pi
        er, et, ez = self._frames(theta)
        with np.errstate(invalid="ignore"):
            h = np.sqrt(l * l - r * r)
        ar, at, az = (np.sum(a * e, -1) for e in (er, et, ez))
        tt = -np.arcsin(np.clip(at, -1, 1))
        tr = np.arctan2(-ar, -az)
        u[self._idx] = np.column_stack([c[:, 2] - h, theta, r - u[self._iR], l - u[self._iL],
                                        tr, tt])
        return u

    # -- build tolerances (SPEC 9) ----------------------------------------------------------
    #: default build tolerances (prior standard deviations, m and rad) per machine-file key
    #: of ``tolerances:``; see :meth:`tolerance_rows` for what each holds
    DEFAULT_TOLERANCES = {
        "delta_radius": 5e-3,          # the mean tower radius about the file's delta_radius
        "arm_length": 5e-3,            # the mean arm about the file's arm_length
        "tower_angle": float(np.deg2rad(1.0)),   # each tower's angle about its nominal
        "radius_trim": 0.5e-3,         # each tower's radius against the mean of the three
        "arm_trim": 0.3e-3,            # each arm against the mean of the three (matched rods)
        "tower_tilt": float(np.deg2rad(0.2)),    # each tilt (radial, tangential) about 0
        "endstop": None,               # effectively free: an endstop is adjusted, not built
    }
    _TOLERANCE_KINDS = {"delta_radius": "length", "arm_length": "length",
                        "tower_angle": "angle", "radius_trim": "length",
                        "arm_trim": "length", "tower_tilt": "angle", "endstop": "length"}

    def model_candidates(self, fixes_lengths: bool) -> list[ModelCandidate]:
        """Klipper's own set (its DELTA_CALIBRATE: basic from heights, the nine with
        distances), with the bed square to the towers as Klipper takes it and with the bed's
        tilt, and the per-tower model (every tower quantity) with the build tolerances
        holding what the data do not see (its arms from heights alone among them).

        Parameters
        ----------
        fixes_lengths : bool
            Whether the data fix a length (distances): Klipper's nine, else its basic six.

        Returns
        -------
        list of ModelCandidate
            The candidates, Klipper's own set first.
        """
        own = "klipper" if fixes_lengths else "klipper-basic"
        out = [ModelCandidate(own, "square", f"Klipper's own set ({own}), the bed square to "
                              "the towers as the firmware takes it"),
               ModelCandidate(own, "estimate", f"Klipper's own set ({own}) and the bed's "
                              "tilt")]
        out.append(ModelCandidate("full", "auto", "the per-tower model (endstop, angle, "
                                  "radius and arm, both tilts of each tower) with the build "
                                  "tolerances as a prior, the bed's tilt where the data tell "
                                  "it"))
        return out

    def default_tolerances(self) -> dict[str, float]:
        """:data:`DEFAULT_TOLERANCES` (the machine file's ``tolerances:`` keys; ``endstop``
        has none by default: the data fix the endstops, a printer's owner adjusts them).

        Returns
        -------
        dict
            ``{key: std}``, m and rad (None: no prior).
        """
        return dict(self.DEFAULT_TOLERANCES)

    def tolerance_kinds(self) -> dict[str, str]:
        return dict(self._TOLERANCE_KINDS)

    #: a build error is named as an action when the data measured it (``measured``) and it
    #: is this many of its standard deviations from the nominal
    ACTION_SIGMAS = 2.0

    def build_error_words(self, rows) -> list[str]:
        """A leaning tower (both tilts) and a tower whose carriage line sits off the common
        radius: no firmware holds them (Klipper, Marlin and RepRapFirmware take vertical
        towers and one radius); named where the data measured them, with their uncertainty,
        in millimetres over the tower's travel.

        Parameters
        ----------
        rows : list
            The prior's summary rows (:func:`~pkmcal.estimation.estimator.prior_summary`:
            name, value, posterior std, label).

        Returns
        -------
        list of str
            One sentence per tower quantity the data measured.
        """
        by = {r.name: r for r in rows}
        letters = "ABC"
        pe = self.towers()[0]
        out = []
        for i in range(3):
            tower = f"tower {letters[i]} (tower{i + 1})"
            rail = float(pe[i])
            for field, toward in (("tilt_radial", ("away from the centre",
                                                   "toward the centre")),
                                  ("tilt_tangential", ("counter-clockwise (seen from above)",
                                                       "clockwise (seen from above)"))):
                r = by.get(f"tower{i + 1}.{field}")
                if r is None or r.label != "measured" or not np.isfinite(r.posterior_std):
                    continue
                change = r.value - r.mean
                if abs(change) < self.ACTION_SIGMAS * r.posterior_std:
                    continue
                words = toward[0] if change > 0 else toward[1]
                out.append(f"{tower} leans {np.degrees(abs(change)):.2g} +- "
                           f"{np.degrees(r.posterior_std):.1g} deg {words}: "
                           f"{abs(np.tan(change)) * rail * 1e3:.2g} mm over "
                           f"{rail * 1e3:.0f} mm of travel; no firmware holds it: plumb the "
                           "tower (shim its foot or top)")
            r = by.get(f"tower{i + 1}.radius_trim (against the mean of the three)")
            if r is not None and r.label == "measured" and np.isfinite(r.posterior_std) \
                    and abs(r.value - r.mean) >= self.ACTION_SIGMAS * r.posterior_std:
                change = r.value - r.mean
                out.append(f"{tower}'s carriage line sits {abs(change) * 1e3:.2g} +- "
                           f"{r.posterior_std * 1e3:.1g} mm "
                           f"{'further out' if change > 0 else 'further in'} than the mean of "
                           "the three; the firmware has one radius: check the tower's "
                           "rail and carriage mounting")
        return out

    def tolerance_rows(self, tolerances: dict[str, float]) -> list:
        """The prior's rows of a linear Delta (:meth:`Machine.tolerance_rows`).

        ``delta_radius`` and ``arm_length`` hold the MEAN tower radius / arm (common value
        plus the mean trim: only the sums enter, so the prior does not depend on which of the
        two a parameter set frees); ``radius_trim`` and ``arm_trim`` hold each tower's radius
        / arm against the mean of the three (three rows of rank 2: a tower differs from the
        others, whatever the common value); ``tower_angle`` each tower's angle about its
        nominal; ``tower_tilt`` each tilt about 0 (vertical towers); ``endstop`` each
        ``position_endstop`` about its nominal.

        Parameters
        ----------
        tolerances : dict
            Key -> tolerance (one standard deviation, SI; None: that key holds nothing).

        Returns
        -------
        list
            The rows (:meth:`~pkmcal.parameters.Prior.about`).
        """
        rows = []
        third = 1.0 / 3.0
        for common, trim in (("delta_radius", "radius_trim"), ("arm_length", "arm_trim")):
            if common in tolerances:
                coefficients = {common: 1.0}
                coefficients.update({f"tower{i + 1}.{trim}": third for i in range(3)})
                rows.append((f"{common} (mean of the towers)", coefficients,
                             tolerances[common], f"tolerances.{common}"))
            if trim in tolerances:
                for i in range(3):
                    coefficients = {f"tower{j + 1}.{trim}": (1.0 if j == i else 0.0) - third
                                    for j in range(3)}
                    rows.append((f"tower{i + 1}.{trim} (against the mean of the three)",
                                 coefficients, tolerances[trim], f"tolerances.{trim}"))
        for key, fields in (("tower_angle", ("angle",)), ("endstop", ("endstop",)),
                            ("tower_tilt", ("tilt_radial", "tilt_tangential"))):
            if key in tolerances:
                for i in range(3):
                    for f in fields:
                        rows.append((f"tower{i + 1}.{f}", {f"tower{i + 1}.{f}": 1.0},
                                     tolerances[key], f"tolerances.{key}"))
        return rows

    def characteristic_length(self) -> float:
        return float(np.mean(self.towers()[3]))

    def default_home(self):
        """The nozzle above the bed centre at 40 % of the lowest endstop height.

        Returns
        -------
        P : ndarray, shape (3,)
            ``(0, 0, 0.4 min(position_endstop))``, m.
        R : ndarray, shape (3, 3)
            The identity.
        """
        return np.array([0.0, 0.0, 0.4 * float(np.min(self.towers()[0]))]), np.eye(3)

    def tracker_target(self) -> np.ndarray:
        """The tracker's target: the nozzle tip (any other place on a translating effector is
        the same up to the tracker's translation).

        Returns
        -------
        ndarray, shape (3,)
            Zeros.
        """
        return np.zeros(3)

    #: the firmware's print radius and probing radius, m (a machine file's ``print_radius``,
    #: ``probe_radius``; None: not given)
    print_radius = None
    probe_radius = None
    #: height of the print volume an export is judged over, m (capped by the print radius)
    PRINT_HEIGHT = 0.1
    #: where a firmware's configuration keeps each tower's values (Klipper's sections; the
    #: reports name the towers' firmware values by them)
    TOWER_SECTIONS = ("stepper_a", "stepper_b", "stepper_c")

    def print_workspace(self, n: int = 500, rng=0, bed=None):
        """Where a printer prints: the print disk on the bed and the volume above it.

        Half the points lie on the bed (the plane ``bed``, z = 0 without one)
        within the print radius (:attr:`print_radius`; else the probing radius, else the
        reachable disk of the probe instrument), half in the cylinder above it up to
        :attr:`PRINT_HEIGHT` (at most the radius); points the machine cannot reach (no
        real inverse kinematics, past its endstops, :meth:`physical_limits`) are dropped.

        Parameters
        ----------
        n : int, optional
            Number of points drawn.
        rng : int or numpy.random.Generator, optional
            Seed.
        bed : array_like, shape (3,), optional
            The bed plane ``(height m, tilt_x, tilt_y)`` of the experiment's set-ups
            (:class:`~pkmcal.instruments.probe.BedSetup`); None: z = 0.

        Returns
        -------
        Workspace
            With ``surface`` marking the points on the bed.
        """
        from .reach import Workspace, probe_radius

        rng = np.random.default_rng(rng)
        radius = self.print_radius or probe_radius(self, bed)
        words = (f"print radius {radius * 1e3:.6g} mm" if self.print_radius
                 else f"radius {radius * 1e3:.6g} mm")
        height = min(self.PRINT_HEIGHT, radius)
        m = n // 2
        rho = radius * np.sqrt(rng.uniform(0.0, 1.0, n))
        a = rng.uniform(0.0, 2 * np.pi, n)
        z = np.concatenate([np.zeros(m), rng.uniform(0.0, height, n - m)])
        plane = np.zeros(3) if bed is None else np.asarray(bed, float).reshape(3)
        x, y = rho * np.cos(a), rho * np.sin(a)
        P = np.column_stack([x, y, z + plane[0] + plane[1] * x + plane[2] * y])
        R = np.broadcast_to(np.eye(3), (n, 3, 3))
        with np.errstate(all="ignore"):
            q = self.ik(P, R)
            ok = np.all(np.isfinite(q), axis=-1) & self.within_physical_limits(P, R, q,
                                                                                bed=bed)
        surface = np.arange(n) < m
        P, surface = P[ok], surface[ok]
        if not surface.any():
            from ..errors import InputError

            raise InputError(f"{self.source or 'the machine'}: no point of the print disk "
                             f"({words}) can be reached; check print_radius")
        return Workspace(P, np.broadcast_to(np.eye(3), (len(P), 3, 3)),
                         f"the print disk on the bed ({words}) and the volume up to "
                         f"{height * 1e3:.6g} mm above it",
                         (P.min(axis=0), P.max(axis=0)), surface)

    def firmware_values(self, u=None) -> dict:
        """What a firmware's configuration holds, per tower, in SI units.

        Parameters
        ----------
        u : array_like, shape (20,), optional
            Parameter vector; default :attr:`u`.

        Returns
        -------
        dict
            ``radius``, ``arm_length``, ``angle``, ``position_endstop``, ``tilt_radial``,
            ``tilt_tangential``: lists of 3 (m, rad).
        """
        pe, theta, r, l, tr, tt = self.towers(u)
        return {"radius": r.tolist(), "arm_length": l.tolist(), "angle": theta.tolist(),
                "position_endstop": pe.tolist(), "tilt_radial": tr.tolist(),
                "tilt_tangential": tt.tolist()}

    def identifiable_combinations(self, u=None) -> dict:
        """Each tower's radius and arm length: only common value plus trim enters the model.

        Parameters
        ----------
        u : array_like, shape (20,), optional
            Parameter vector; default :attr:`u`.

        Returns
        -------
        dict
            ``description``, ``radius`` and ``arm_length`` per tower (m).
        """
        v = self.firmware_values(u)
        return {"description": "per tower: radius = delta_radius + radius_trim and arm length "
                               "= arm_length + arm_trim (only these sums enter the model)",
                "radius": v["radius"], "arm_length": v["arm_length"]}

    # -- validation -----------------------------------------------------------------------
    def geometry_problems(self, home_given: bool = True) -> list[tuple[tuple, str]]:
        """Degenerate towers (see :meth:`Machine.geometry_problems`).

        Refused: an arm not longer than its tower's radius (the arms cannot reach the centre
        and the carriage height at the endstop ``sqrt(arm^2 - radius^2)`` is not real); a
        tower whose direction down does not point down; two towers at the same angle (within
        1e-6 rad: they act alike and the effector is free to move); the home pose out of reach
        or singular.

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
        pe, theta, r, l, tr, tt = self.towers()
        chains = self.from_chains
        for i in range(3):
            if not l[i] > r[i] > 0:
                key = ("chains", i, "l") if chains else ("arm_length",)
                return [(key, f"the arm of tower {i + 1} ({self._length_text(l[i])}) is not "
                         f"longer than the tower's radius ({self._length_text(r[i])}): the "
                         "arms cannot reach the centre and the carriage height at the endstop, "
                         "sqrt(arm^2 - radius^2), is not real; check arm_length and "
                         "delta_radius" + (" and the chains" if chains else ""))]
        _, a, _, _ = self._geometry()
        for i in range(3):
            if not a[i, 2] < -1e-3:
                return [(("chains", i, "beta"), f"the direction down tower {i + 1} does not "
                         "point down (beta must be below 0, -90 deg for a vertical tower); "
                         "check alpha and beta")]
        for j in range(3):
            for i in range(j):
                gap = abs((theta[j] - theta[i] + np.pi) % (2 * np.pi) - np.pi)
                if gap < 1e-6:
                    key = ("chains", j) if chains else ("tower_angles", j)
                    return [(key, f"towers {i + 1} and {j + 1} stand at the same angle "
                             f"({np.degrees(theta[i]):.6g} deg): they act alike and the "
                             "effector is free to move; the towers must stand at three "
                             "different angles, e.g. 210, 330, 90 deg")]
        bad, singular = self._home_check()
        if bad.size:
            if not home_given:
                return [(("position_endstop",), "the default home (the nozzle at the centre, "
                         "40 % of the lowest endstop height) cannot be reached by tower(s) "
                         f"{', '.join(str(i + 1) for i in bad)}; give a home pose or check "
                         "the dimensions")]
            return [(("home",), "the position cannot be reached by tower(s) "
                     f"{', '.join(str(i + 1) for i in bad)} (the arm cannot span the distance "
                     "from the tower to the effector); check home and the dimensions")]
        reach = self.reachability(*self.home)
        if not reach.ok[0] and home_given:
            return [(("home",), f"the nozzle at {self.pose_text(self.home[0])} cannot be "
                     f"reached: {reach.reasons[0]} (home must lie between the bed and the "
                     "endstops, which are the top of the carriages' travel)")]
        if singular:
            return [(("home",) if home_given else ("tower_angles",),
                     "the three arms do not hold the effector "
                     + ("at home" if home_given else "at the default home")
                     + ": the joint Jacobian is singular there (e.g. the towers on one line); "
                     "check the tower angles" + (" and home" if home_given else ""))]
        return []

    # -- physical limits ------------------------------------------------------------------
    def bed_z(self, P, bed=None) -> np.ndarray:
        """Height of the bed below nozzle positions, base frame: the bed plane of the
        experiment's set-ups (``bed``, a calibrated file's) or :attr:`bed_height`.

        Parameters
        ----------
        P : array_like, shape (K, 3)
            Nozzle positions, m.
        bed : array_like, shape (3,), optional
            The bed plane ``(height m, tilt_x, tilt_y)``
            (:class:`~pkmcal.instruments.probe.BedSetup`); None: :attr:`bed_height`.

        Returns
        -------
        ndarray, shape (K,)
            The bed's z under each position, m.
        """
        P = np.asarray(P, float).reshape(-1, 3)
        if bed is None:
            return np.full(len(P), float(self.bed_height))
        h, tx, ty = (float(v) for v in bed)
        return h + tx * P[:, 0] + ty * P[:, 1]

    def physical_limits(self, P, R, q, u=None, bed=None) -> list:
        """A printer's own limits: each carriage at or below its endstop (``q_i >= 0``: the
        joint reads the travel down from the endstop, the endstop is the top of the tower)
        and the nozzle at or above the bed (below it the carriages would drive the nozzle
        into the bed; the arms' geometry ends there for printing).

        Parameters
        ----------
        P : ndarray, shape (K, 3)
            Nozzle positions, m (base frame).
        R : ndarray, shape (K, 3, 3)
            Ignored (translation-only effector).
        q : ndarray, shape (K, 3)
            Carriage travels down from the endstops at ``P``, m.
        u : array_like, shape (20,), optional
            Unused: the endstops are where ``q = 0`` whatever the parameters.
        bed : array_like, shape (3,), optional
            The bed plane of the experiment's set-ups (:meth:`bed_z`).

        Returns
        -------
        list of PhysicalLimit
            Three endstop limits (excess ``-q_i``) and the bed (excess: the bed's height
            minus the nozzle's).
        """
        from .base import PhysicalLimit

        P = np.asarray(P, float).reshape(-1, 3)
        q = np.asarray(q, float).reshape(-1, 3)
        limits = [PhysicalLimit(-q[:, i], f"tower {i + 1}'s carriage {{amount}} above "
                                "its endstop", joint=i)
                  for i in range(3)]
        limits.append(PhysicalLimit(self.bed_z(P, bed) - P[:, 2],
                                    "the nozzle {amount} below the bed"))
        return limits

    # -- kinematics -----------------------------------------------------------------------
    def ik_jacobians(self, P, R=None, u=None, want_du: bool = True):
        """Carriage travels and their derivatives at nozzle positions.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Nozzle positions, m.
        R : array_like, optional
            Ignored (translation-only effector).
        u : array_like, shape (20,), optional
            Parameter vector (internal units); default: :attr:`u`.
        want_du : bool, optional
            Also compute the derivatives with respect to the parameters.

        Returns
        -------
        q : ndarray, shape (..., 3)
            Travel of each carriage down from its endstop, m; NaN where unreachable.
        dq_dpose : ndarray, shape (..., 3, 6)
            Derivatives with respect to ``[dP, dOmega]``; the rotation columns are zero.
        dq_du : ndarray, shape (..., 3, 20) or None
            Derivatives with respect to the parameters; None unless ``want_du``.
        """
        c, a, l, (r, h, er, et, ez, ar, at, tr, tt) = self._geometry(u)
        P = np.asarray(P, float)
        shape = P.shape[:-1]
        N = int(np.prod(shape))
        Pt = P.reshape(N, 3).T
        dx = Pt[0] - c[:, 0:1]                                   # d = P + b - a0, (3, N)
        dy = Pt[1] - c[:, 1:2]
        dz = Pt[2] - c[:, 2:3]
        q, inv_s, nx, ny, nz = slider_link_solve(dx, dy, dz, a[:, 0:1], a[:, 1:2], a[:, 2:3], l)
        J = np.zeros((N, 3, 6))
        J[:, :, 0], J[:, :, 1], J[:, :, 2] = nx.T, ny.T, nz.T
        q_out = q.T.reshape(shape + (3,))
        dq_dpose = J.reshape(shape + (3, 6))
        if not want_du:
            return q_out, dq_dpose, None

        def dot(v):                                              # (n/s) . v_i, (3, N)
            return nx * v[:, 0:1] + ny * v[:, 1:2] + nz * v[:, 2:3]

        with np.errstate(invalid="ignore", divide="ignore"):
            dc_dr = er - (r / h)[:, None] * ez                    # c = r e_r + (pe + h) e_z
            dc_dl = (l / h)[:, None] * ez
        da_dtheta = ar[:, None] * et - at[:, None] * er
        ctr, str_, ctt, stt = np.cos(tr), np.sin(tr), np.cos(tt), np.sin(tt)
        da_dtr = (-ctr * ctt)[:, None] * er + (str_ * ctt)[:, None] * ez
        da_dtt = (str_ * stt)[:, None] * er - ctt[:, None] * et + (ctr * stt)[:, None] * ez
        dq_dr = -dot(dc_dr)
        dq_dl = -l[:, None] * inv_s - dot(dc_dl)
        cols = np.stack([
            -nz,                                                 # endstop: c_z += 1
            -r[:, None] * dot(et) - q * dot(da_dtheta),          # angle
            dq_dr,                                               # radius trim
            dq_dl,                                               # arm trim
            -q * dot(da_dtr),                                    # tilt radial
            -q * dot(da_dtt),                                    # tilt tangential
        ], -1)                                                   # (3, N, 6) TOWER_FIELDS
        dq_du = np.zeros((N, 3, len(self.parameters)))
        towers = np.arange(3)
        dq_du[:, towers[:, None], self._idx] = cols.transpose(1, 0, 2)
        dq_du[:, :, self._iR] = dq_dr.T
        dq_du[:, :, self._iL] = dq_dl.T
        return q_out, dq_dpose, dq_du.reshape(shape + (3, len(self.parameters)))

    def ik(self, P, R=None, u=None) -> np.ndarray:
        """Carriage travels at nozzle positions; NaN where unreachable.

        Parameters
        ----------
        P : array_like, shape (..., 3)
            Nozzle positions, m.
        R : array_like, optional
            Ignored (translation-only effector).
        u : array_like, shape (20,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        ndarray, shape (..., 3)
            Carriage travels down from the endstops, m.
        """
        return self.ik_jacobians(P, R, u, want_du=False)[0]

    def fk(self, q, u=None, start=None, tol: float = 1e-9, max_iter: int = 0,
           raise_on_failure: bool = False) -> FKResult:
        """Closed-form forward kinematics: the lower intersection of the three arm spheres.

        Parameters
        ----------
        q : array_like, shape (K, 3)
            Carriage travels down from the endstops, m.
        u : array_like, shape (20,), optional
            Parameter vector (internal units); default: :attr:`u`.
        start : object, optional
            Accepted for the :class:`Machine` interface; unused.
        tol : float, optional
            Accepted for the :class:`Machine` interface; unused.
        max_iter : int, optional
            Accepted for the :class:`Machine` interface; unused.
        raise_on_failure : bool, optional
            Raise instead of returning rows that could not be solved.

        Returns
        -------
        FKResult
            Nozzle positions (K, 3), m, with ``R = I``; ``converged`` False where the spheres do
            not meet or their centres are collinear; residual 0 or inf; ``iterations`` 0.

        Raises
        ------
        ConvergenceError
            With ``raise_on_failure``, when a row could not be solved.
        """
        return closed_form_positions_fk(self, q, u, raise_on_failure)

    def fk_positions(self, q, u=None):
        """Nozzle positions and a validity mask from the three-sphere intersection.

        Sphere ``i``: centre ``a0_i + q_i a_i - b_i`` (the carriage joint, shifted by the
        effector joint's offset), radius ``l_i``. Subtracting sphere 1 from spheres 2 and 3
        gives two planes; their line ``p0 + s m`` (``m = n2 x n3``) meets sphere 1 in two points,
        of which the lower one is the nozzle.

        Parameters
        ----------
        q : array_like, shape (..., 3)
            Carriage travels, m.
        u : array_like, shape (20,), optional
            Parameter vector (internal units); default: :attr:`u`.

        Returns
        -------
        P : ndarray, shape (..., 3)
            Nozzle positions, m; NaN where not valid.
        ok : ndarray of bool, shape (...)
            False where the spheres do not meet or their centres are (nearly) collinear.
        """
        q = np.asarray(q, float)
        c, a, l, _ = self._geometry(u)
        t = np.moveaxis(q, -1, 0)                                # (3, ...)
        col = (3,) + (1,) * (t.ndim - 1)
        cx = c[:, 0].reshape(col) + t * a[:, 0].reshape(col)
        cy = c[:, 1].reshape(col) + t * a[:, 1].reshape(col)
        cz = c[:, 2].reshape(col) + t * a[:, 2].reshape(col)
        x1, y1, z1 = cx[0], cy[0], cz[0]
        ax, ay, az = cx[1] - x1, cy[1] - y1, cz[1] - z1          # n2 = c2 - c1
        bx, by, bz = cx[2] - x1, cy[2] - y1, cz[2] - z1          # n3 = c3 - c1
        r1 = l[0] ** 2
        s1 = x1 * x1 + y1 * y1 + z1 * z1 - r1
        b2 = 0.5 * (cx[1] ** 2 + cy[1] ** 2 + cz[1] ** 2 - l[1] ** 2 - s1)
        b3 = 0.5 * (cx[2] ** 2 + cy[2] ** 2 + cz[2] ** 2 - l[2] ** 2 - s1)
        lx, ly, lz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx   # m = n2 x n3
        g = lx * lx + ly * ly + lz * lz
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            # e = p0 - c1 with p0 = (b2 (n3 x m) + b3 (m x n2)) / |m|^2 on both planes
            ex = (b2 * (by * lz - bz * ly) + b3 * (ly * az - lz * ay)) / g - x1
            ey = (b2 * (bz * lx - bx * lz) + b3 * (lz * ax - lx * az)) / g - y1
            ez = (b2 * (bx * ly - by * lx) + b3 * (lx * ay - ly * ax)) / g - z1
            B = lx * ex + ly * ey + lz * ez
            C = ex * ex + ey * ey + ez * ez - r1
            disc = B * B - g * C
            s = (-B - np.copysign(np.sqrt(disc), lz)) / g        # the lower root
            P = np.stack([x1 + ex + s * lx, y1 + ey + s * ly, z1 + ez + s * lz], -1)
            scale = ax * ax + ay * ay + az * az + bx * bx + by * by + bz * bz
            ok = (g > 1e-12 * scale**2) & (disc >= 0) & np.all(np.isfinite(P), -1)
        return np.where(ok[..., None], P, np.nan), ok

    # -- frames ---------------------------------------------------------------------------
    def transform_base(self, u, G, t=None):
        """Parameters with the towers moved by one rigid motion: ``a0 - b -> G (a0 - b) + t``,
        ``a -> G a``.

        The towers are measured from the effector joints (``a0 - b``), so this moves the
        machine together with its effector; no reading changes.

        Parameters
        ----------
        u : array_like, shape (20,)
            Parameter vector (internal units).
        G : array_like, shape (3, 3)
            Rotation.
        t : array_like, shape (3,), optional
            Translation, m.

        Returns
        -------
        ndarray, shape (20,)
            The transformed parameter vector (common values kept, the trims change).
        """
        G = np.asarray(G, float)
        c, a, l, _ = self._geometry(u)
        c = c @ G.T + (0.0 if t is None else np.asarray(t, float))
        return self._from_geometry(c, a @ G.T, l, u)

    def transform_platform(self, u, C, t=None):
        """The nozzle point moved to ``t`` on the effector (the effector does not rotate).

        Parameters
        ----------
        u : array_like, shape (20,)
            Parameter vector (internal units).
        C : array_like, shape (3, 3)
            Must be the identity.
        t : array_like, shape (3,), optional
            New platform point in the old platform frame, m.

        Returns
        -------
        ndarray, shape (20,)
            The transformed parameter vector.

        Raises
        ------
        NotImplementedError
            For a rotation: the effector does not rotate.
        """
        if not np.allclose(np.asarray(C, float), np.eye(3), rtol=0, atol=1e-15):
            raise NotImplementedError("the effector of a linear Delta does not rotate")
        return self.transform_base(u, np.eye(3), t)

    def frame_motions(self, u=None) -> list[FrameMotion]:
        """The linear Delta's invisible combinations, each in words.

        A rigid motion of the machine (the towers with the effector) split into what an
        instrument may absorb separately: the rotation about z (the three tower angles
        together), the vertical translation (the three endstops together: a probe's bed
        height absorbs it), the horizontal translation and the tilt (a probe's bed tilt
        absorbs them); and the common radius and arm length against their trims (only the
        sums enter: no measurement sees them).

        Parameters
        ----------
        u : array_like, shape (20,), optional
            Parameter vector to linearise at; default :attr:`u`.

        Returns
        -------
        list of FrameMotion
            The motions.
        """
        u = self.u if u is None else np.asarray(u, float)
        n = len(self.parameters)
        hr, ht = 1e-6, 1e-6 * self.characteristic_length()

        def rot(k):
            w = np.zeros(3)
            w[k] = hr
            return (self.transform_base(u, matrix_from_rotvec(w))
                    - self.transform_base(u, matrix_from_rotvec(-w))) / (2 * hr)

        def shift(k):
            t = np.zeros(3)
            t[k] = ht
            return (self.transform_base(u, np.eye(3), t)
                    - self.transform_base(u, np.eye(3), -t)) / (2 * ht)

        out = [
            FrameMotion("rotation about z", "turning the three towers together about the "
                        "vertical axis (the three tower angles by one angle): only their "
                        "differences are seen (a firmware fixes one tower angle)",
                        np.column_stack([rot(2)])),
            FrameMotion("vertical translation", "raising the three towers together (the "
                        "three endstops by one length)", np.column_stack([shift(2)])),
            FrameMotion("horizontal translation", "moving the three towers together "
                        "sideways (each tower's radius and angle)",
                        np.column_stack([shift(0), shift(1)])),
            FrameMotion("tilt of the towers", "tilting the three towers together about a "
                        "horizontal axis (their tilts, radii and endstops)",
                        np.column_stack([rot(0), rot(1)])),
        ]
        for common, trim, what in (("delta_radius", "radius_trim", "radius"),
                                   ("arm_length", "arm_trim", "arm length")):
            T = np.zeros((n, 1))
            T[self.parameters.index(common), 0] = 1.0
            for i in range(3):
                T[self.parameters.index(f"tower{i + 1}.{trim}"), 0] = -1.0
            out.append(FrameMotion(f"{common} with the {trim}s",
                                   f"{common} up and the three {trim}s down by the same "
                                   f"length: only their sums, each tower's {what}, enter "
                                   "the model", T))
        return out


def linear_delta(delta_radius: float, arm_length, tower_angles=DEFAULT_TOWER_ANGLES,
                 position_endstop=(0.3, 0.3, 0.3), chains=None, home=None,
                 name: str = "", tolerances=None) -> LinearDelta:
    """A linear Delta from its design values (a machine file's top level), SI units.

    Parameters
    ----------
    delta_radius : float
        Horizontal distance from the carriage joint line to the effector joint line, m.
    arm_length : float or array_like, shape (3,)
        Arm length (one, or one per tower), m.
    tower_angles : array_like, shape (3,), optional
        Tower angles, rad; default Klipper's 210, 330, 90 deg.
    position_endstop : array_like, shape (3,), optional
        Klipper's ``position_endstop`` per tower, m.
    chains : tuple, optional
        ``(a0 (3, 3), alpha (3,), beta (3,), l (3,), b (3, 3))``: the full chain of each
        tower (absolute values, m and rad); default: the design values.
    home : tuple of ndarray, optional
        ``(P, R)`` start pose.
    name : str, optional
        Free-text name.
    tolerances : dict or "default" or None, optional
        Build tolerances as a prior about the design values (:meth:`Machine.with_tolerances`;
        a machine file's ``tolerances:`` section, ``"default"`` when it has none); None
        (default here): no prior, a fit is maximum likelihood.

    Returns
    -------
    LinearDelta
        The machine; the common ``delta_radius`` and ``arm_length`` parameters are the design
        values (the mean of three arm lengths), with ``chains`` the means of the towers'
        radii and arms; the trims are the differences.

    Raises
    ------
    InputError
        When an array does not hold 3 values.
    """
    arms = np.broadcast_to(np.asarray(arm_length, float), (3,)).copy()
    angles = np.asarray(tower_angles, float).reshape(-1)
    pe = np.asarray(position_endstop, float).reshape(-1)
    if angles.shape != (3,) or pe.shape != (3,) or np.ndim(arm_length) > 1:
        raise InputError("a linear Delta has 3 towers: give 3 tower angles, 3 endstops and "
                         "one arm length or 3")
    common = float(arms[0]) if np.all(arms == arms[0]) else float(np.mean(arms))
    params = linear_delta_parameters(delta_radius, common, angles, pe, arm_trim=arms - common)
    nominal = {"delta_radius": float(delta_radius),
               "arm_length": float(arm_length) if np.ndim(arm_length) == 0 else arms.copy(),
               "tower_angles": angles.copy(), "position_endstop": pe.copy()}
    machine = LinearDelta(params, nominal=nominal, home=home, name=name)
    if chains is not None:
        a0, alpha, beta, l, b = chains
        machine.b = np.array(b, float).reshape(3, 3)
        u = machine.parameters_from_chains(a0, alpha, beta, l)
        p = machine.parameters
        r, arms = u[p.index("delta_radius")] + u[p.indices(["tower1.radius_trim",
                                                            "tower2.radius_trim",
                                                            "tower3.radius_trim"])], \
            u[p.index("arm_length")] + u[p.indices(list(_ARM_TRIMS))]
        u = linear_delta_parameters(
            np.mean(r), np.mean(arms), *(u[machine._idx[:, k]] for k in (1, 0)),
            radius_trim=r - np.mean(r), arm_trim=arms - np.mean(arms),
            tilt_radial=u[machine._idx[:, 4]], tilt_tangential=u[machine._idx[:, 5]]).values
        machine.parameters = machine.parameters.with_values(u)
        machine.from_chains = True
    if tolerances is not None:
        # about the design values of the top level (the towers vertical, the trims 0: what
        # the machine was built to be), whatever the chains hold
        design = machine.with_parameters(params.values).with_tolerances(tolerances)
        machine.parameters = machine.parameters.with_prior(design.parameters.prior)
        machine.tolerances = design.tolerances
    return machine


def default_linear_delta() -> LinearDelta:
    """A Kossel-size printer (Klipper's defaults for the angles): ``delta_radius`` 140 mm,
    arms 270 mm, endstops 300 mm, towers at 210, 330, 90 deg, vertical, no effector offset.

    Returns
    -------
    LinearDelta
        A new machine.
    """
    return linear_delta(0.14, 0.27, DEFAULT_TOWER_ANGLES, (0.3, 0.3, 0.3),
                        name="pkmcal default linear Delta (Kossel size)")


# --------------------------------------------------------------------------------------------
# The machine file section (``machine: linear_delta``)
# --------------------------------------------------------------------------------------------


class LinearDeltaFile(MachineFileHead):
    """``machine: linear_delta``: the design values (Klipper's names and meanings) and,
    optionally, the full chain of each tower (Hexa Slide keys, absolute values)."""

    machine: Literal["linear_delta"]
    delta_radius: Positive
    arm_length: Any                            # one number or 3: checked by _arm_lengths
    tower_angles: Vector3
    #: nozzle-to-bed distances at the endstops: above the bed
    position_endstop: Annotated[list[Annotated[float, Strict(), Field(
        allow_inf_nan=False, gt=0)]], Field(min_length=3, max_length=3)]
    chains: Annotated[list[HexaSlideChain], Field(min_length=3, max_length=3)] | None = None
    tracker: TrackerPose | None = None
    ballbar: Ballbar | None = None
    bed: BedPlane | None = None
    #: the firmware's print radius and probing radius (Klipper's [printer] print_radius,
    #: [delta_calibrate] radius): the export's and the probe plan's disk
    print_radius: Positive | None = None
    probe_radius: Positive | None = None
    #: build tolerances (prior standard deviations in the file's units) overriding
    #: :data:`LinearDelta.DEFAULT_TOLERANCES` per key (null: that quantity has no prior), or
    #: ``none``: no prior at all
    tolerances: dict[str, Positive | None] | Literal["none"] | None = None
    home: list[Number] | None = None

    @field_validator("arm_length")
    @classmethod
    def _arm_lengths(cls, value):
        items = value if isinstance(value, list) else [value]
        if isinstance(value, list) and len(value) != 3:
            raise PydanticCustomError(
                "arm_lengths", "expected one number or a list of 3 (one per tower), got "
                "{n} numbers", {"n": len(value)})
        for x in items:
            if isinstance(x, bool) or not isinstance(x, (int, float)):
                raise PydanticCustomError(
                    "arm_lengths", "not a number: {value} (one arm length, or a list of 3)",
                    {"value": show(x)})
            if not np.isfinite(x) or x <= 0:
                raise PydanticCustomError(
                    "arm_lengths", "an arm length must be a finite number > 0, got {value}",
                    {"value": show(x)})
        return value

    @field_validator("home")
    @classmethod
    def _position_home(cls, value):
        if value is None:
            return value
        if len(value) not in (3, 6):
            raise PydanticCustomError(
                "home_length", "expected 3 numbers [x, y, z] (the effector does not rotate), "
                "got {n}", {"n": len(value)})
        if len(value) == 6 and any(abs(v) > 1e-9 for v in value[3:]):
            raise PydanticCustomError(
                "home_rotation", "the effector does not rotate: psi, theta, phi must be 0, got "
                "{angles}; write home: [x, y, z]", {"angles": value[3:]})
        return value


def _build(doc: LinearDeltaFile, source: str) -> LinearDelta:
    fl, fa = factors(doc.units.model_dump())
    arms = doc.arm_length
    arms = [float(v) * fl for v in arms] if isinstance(arms, list) else float(arms) * fl
    chains = None
    if doc.chains is not None:
        ch = doc.chains
        chains = (np.array([c.a0 for c in ch], float) * fl,
                  np.array([c.alpha for c in ch], float) * fa,
                  np.array([c.beta for c in ch], float) * fa,
                  np.array([c.l for c in ch], float) * fl,
                  np.array([c.b for c in ch], float) * fl)
    home = None
    if doc.home is not None:
        home = (np.asarray(doc.home[:3], float) * fl, np.eye(3))
    tolerances = doc.tolerances
    if isinstance(tolerances, dict):
        kinds = LinearDelta._TOLERANCE_KINDS
        tolerances = {k: (None if v is None else
                          float(v) * (fa if kinds.get(k) == "angle" else fl))
                      for k, v in tolerances.items()}
    machine = linear_delta(doc.delta_radius * fl, arms, np.asarray(doc.tower_angles, float) * fa,
                           np.asarray(doc.position_endstop, float) * fl, chains=chains,
                           home=home, name=doc.name or "",
                           tolerances="default" if tolerances is None else tolerances)
    for key in ("print_radius", "probe_radius"):
        value = getattr(doc, key)
        if value is not None:
            setattr(machine, key, float(value) * fl)
    return machine


def _dump(machine: LinearDelta, units: dict) -> dict[str, Any]:
    """The top level (the design values, as read) and, when the geometry is not exactly the
    design's, the chains."""
    fl, fa = factors(units)
    # the top level holds the machine's own values (a calibrated file shows its calibrated
    # radius, arms, angles and endstops, not the design's); the chains what they cannot
    pe, theta, _, l, _, _ = machine.towers()
    radius = float(machine.u[machine.parameters.index("delta_radius")])
    arms = float(l[0]) if np.all(l == l[0]) else np.asarray(l, float)
    out: dict[str, Any] = {
        "delta_radius": radius / fl,
        "arm_length": (float(arms) / fl if np.ndim(arms) == 0
                       else [float(v) / fl for v in np.asarray(arms)]),
        "tower_angles": [float(v) / fa for v in theta],
        "position_endstop": [float(v) / fl for v in pe],
    }
    for key in ("print_radius", "probe_radius"):
        value = getattr(machine, key, None)
        if value is not None and not callable(value):
            out[key] = float(value) / fl
    tolerances = getattr(machine, "tolerances", None)
    if tolerances == "none":
        out["tolerances"] = "none"
    elif tolerances:
        kinds = LinearDelta._TOLERANCE_KINDS
        out["tolerances"] = {k: (None if v is None else
                                 float(v) / (fa if kinds.get(k) == "angle" else fl))
                             for k, v in tolerances.items()}
    design = linear_delta(radius, arms, theta, pe)
    if (getattr(machine, "from_chains", False) or np.any(machine.b != 0)
            or not np.array_equal(machine.u, design.u)):
        a0, alpha, beta, l, b = machine.chains()
        out["chains"] = [
            {"a0": vector(a0[i], fl), "alpha": float(alpha[i]) / fa,
             "beta": float(beta[i]) / fa, "b": vector(b[i], fl), "l": float(l[i]) / fl}
            for i in range(3)]
    return out


def _size(doc) -> tuple[float, str]:
    fl = LENGTH[doc.units.length]
    arms = doc.arm_length if isinstance(doc.arm_length, list) else [doc.arm_length]
    with np.errstate(all="ignore"):
        return (float(np.median([doc.delta_radius, float(np.median(arms)),
                                 float(np.median(doc.position_endstop))])) * fl,
                "the median of delta_radius, arm_length and position_endstop")


#: the machine file section of a linear Delta printer (:mod:`pkmcal.machines.registry`)
FILE_FORMAT = MachineFormat(
    LinearDeltaFile, _build, _dump, {"chains": 3}, home_text="[x, y, z]",
    hints={
        "delta_radius": "the horizontal distance from the carriage joint line to the effector "
                        "joint line, e.g. delta_radius: 140.0",
        "arm_length": "the arm (diagonal rod) length, one or one per tower, e.g. arm_length: "
                      "270.0",
        "tower_angles": "the tower angles counter-clockwise from +X, e.g. tower_angles: [210, "
                        "330, 90]",
        "position_endstop": "the nozzle-to-bed distance at each tower's endstop (Klipper's "
                            "position_endstop), e.g. position_endstop: [300, 300, 300]",
        "chains": "a list of 3 chains {a0: [x, y, z], alpha, beta, b: [x, y, z], l}",
        "print_radius": "the radius of the printable disk on the bed (Klipper's print_radius), "
                        "e.g. print_radius: 120.0",
        "probe_radius": "the radius of the probing pattern (Klipper's [delta_calibrate] "
                        "radius), e.g. probe_radius: 100.0",
        "tolerances": "build tolerances (prior standard deviations) per quantity, e.g. "
                      "tolerances: {arm_trim: 0.2, tower_tilt: 0.1} (keys delta_radius, "
                      "arm_length, tower_angle, radius_trim, arm_trim, tower_tilt, endstop; "
                      "null: no prior), or tolerances: none",
    },
    kinds={
        ("delta_radius",): "dimension", ("arm_length",): "dimension",
        ("arm_length", "*"): "length", ("print_radius",): "length",
        ("probe_radius",): "length", ("tower_angles", "*"): "angle",
        ("position_endstop", "*"): "length", ("chains", "*", "a0", "*"): "length",
        ("chains", "*", "b", "*"): "length", ("chains", "*", "l"): "dimension",
        ("chains", "*", "alpha"): "angle", ("chains", "*", "beta"): "angle",
    },
    size=_size, kind=LinearDelta.kind, default=default_linear_delta)
