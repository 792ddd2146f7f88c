"""A dial indicator: one platform point's coordinate along one fixed direction (issue 38).

A dial indicator (a plunger dial, a digital indicator, a capacitive or laser displacement
sensor) stands on the machine's table and touches a point of the platform: a row holds the
joint readings and the dial's reading,

    r = d . (P + R p) + z,

``d`` the unit direction along which the reading grows (base frame), ``z`` the dial's zero
(its reading with the touched point at the base origin) and ``p`` the touched point on the
platform (platform frame). The unknowns of one mounting are the direction (two slopes
``dial.slope_u``, ``dial.slope_v`` about its start direction, ``d = (d0 + a u + b w) / |d0 + a u
+ b w|``), the zero ``dial.zero`` and, on a platform that rotates, the point ``point.x/y/z``
(on one that only translates ``d . p`` is one more zero: the point is the platform origin).

One file is one mounting; a dial moved to other directions gives one file each, fitted
together (``pkmcal calibrate MACHINE x.csv y.csv z.csv``: each file its own unknowns). Data:
the joint readings ``q1_<unit>..`` and the reading ``dial_<unit>`` (any length unit).

The start values come in closed form from the readings on the start geometry: ``r`` is linear
in the positions (``r = g . x + z``), fitted by least squares; ``d0 = g / |g|``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..kinematics import skew
from ..parameters import ParameterSet
from .base import Instrument, _noise_model_arg, _simulated_sigma, reachable
from .data import InstrumentData
from .experiment import MOUNTING_ERROR, given_poses, mm_text, noise_model, simulate_instrument
from .flow import option
from .models import IsotropicNoise, NuisanceModel
from .problem import InstrumentProblem

#: default noise of a dial reading (a digital indicator's 1 um resolution and its
#: repeatability), m
DIAL_SIGMA = 2e-6
#: half-width of a simulated dial's tilt against its planned direction (slope)
DIAL_TILT = 0.02


def _across(d) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``d`` to a right-handed orthonormal basis."""
    d = np.asarray(d, float)
    helper = np.eye(3)[int(np.argmin(np.abs(d)))]
    u = np.cross(d, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(d, u)


def planned_axis(machine) -> int:
    """The axis a planned dial reads along: z where the platform moves along it (a dial on the
    table, plunger up), else the last base axis it moves along (a planar machine's y): a
    dial along an axis the platform does not move along reads one value."""
    moves = [i for i in machine.pose_space if i < 3]
    return 2 if 2 in moves else moves[-1]


class DialModel(NuisanceModel):
    """``r = d . (P + R p) + z``: a dial indicator (see the module docstring).

    Parameters
    ----------
    direction : array_like, shape (3,), optional
        The start direction ``d0`` (base frame; normalised), default ``+z``.
    with_point : bool, optional
        The touched point ``p`` is unknown (a platform that rotates); False: the platform
        origin, held.
    """

    kind = "dial"
    #: what its measurements are, in words (noise groups, outlier rows)
    quantity = "dial readings"
    size = 1
    words = {"dial": "the dial's direction (slopes) and zero",
             "point": "the point on the platform the dial touches"}

    def __init__(self, direction=(0.0, 0.0, 1.0), with_point: bool = True):
        d0 = np.asarray(direction, float).reshape(3)
        self.direction0 = d0 / np.linalg.norm(d0)
        self.u, self.w = _across(self.direction0)
        self.with_point = bool(with_point)
        names = ["dial.slope_u", "dial.slope_v", "dial.zero"]
        kinds = ["slope", "slope", "length"]
        if self.with_point:
            names += ["point.x", "point.y", "point.z"]
            kinds += ["length"] * 3
        super().__init__(ParameterSet(names, kinds, np.zeros(len(names))))

    def direction(self, values) -> tuple[np.ndarray, float]:
        """The unit direction of the slopes in ``values`` and the length it was scaled from."""
        v = self.direction0 + values[0] * self.u + values[1] * self.w
        n = float(np.linalg.norm(v))
        return v / n, n

    def point(self, values) -> np.ndarray:
        """The touched point on the platform, m."""
        return np.asarray(values[3:6], float) if self.with_point else np.zeros(3)

    def residuals(self, state, P, R, measured, group, jacobian=True):
        values = state.values
        d, n = self.direction(values)
        Rp = np.einsum("kij,j->ki", R, self.point(values))
        x = P + Rp
        e = measured[:, :1] - (x @ d + values[2])[:, None]
        if not jacobian:
            return e, None, None
        K = len(P)
        # x = P + R p; a rotation on the left moves R p by dOmega x R p = -skew(R p) dOmega
        de_dpose = np.concatenate([np.broadcast_to(-d, (K, 3)),
                                   np.einsum("i,kij->kj", d, skew(Rp))], -1)[:, None, :]
        de_dv = np.zeros((K, 1, len(self.parameters)))
        for j, t in enumerate((self.u, self.w)):
            dd = (t - d * (d @ t)) / n                     # d(v / |v|) along t
            de_dv[:, 0, j] = -(x @ dd)
        de_dv[:, 0, 2] = -1.0
        if self.with_point:
            de_dv[:, 0, 3:6] = -np.einsum("i,kij->kj", d, R)
        return e, de_dpose, de_dv

    def start(self, P, R, measured, group, source="<data>"):
        x = P + np.einsum("kij,j->ki", R, self.point(self.parameters.values))
        r = np.asarray(measured, float)[:, 0]
        if len(r) < 4:
            raise InputError(f"{source}: {len(r)} dial reading(s); its direction and zero "
                             "need at least 4 (positions spread in three directions)")
        centre = x.mean(0)
        g, *_ = np.linalg.lstsq(x - centre, r - r.mean(), rcond=None)
        size = float(np.linalg.norm(g))
        if not size > 0:
            raise InputError(f"{source}: the dial readings do not change with the position: "
                             "no direction to start from (check the dial_ column)")
        d0 = g / size
        values = np.array(self.parameters.values, float)
        values[:2] = 0.0
        values[2] = float(np.mean(r - x @ d0))
        new = self.__class__.__new__(self.__class__)
        new.__dict__.update(self.__dict__)
        new.direction0 = d0
        new.u, new.w = _across(d0)
        new.parameters = self.parameters.with_values(values)
        return new

    def joint_section(self, nuisance, machine, calibrated, source, fl, units, frame, taken):
        d, _ = self.direction(nuisance.values)
        entry = {"dial": {"direction": d.tolist(), "zero": float(nuisance.values[2]) / fl,
                          "point": (self.point(nuisance.values) / fl).tolist(),
                          "unit": units["length"]}}
        return entry, None


def dial_data(q, readings, rows=None, source: str = "<data>") -> InstrumentData:
    """Dial data from joint readings and dial readings (SI).

    Parameters
    ----------
    q : array_like, shape (K, n_joints)
        Joint readings, internal units.
    readings : array_like, shape (K,)
        The dial's readings, m.
    rows : array_like of int, optional
        Row numbers for messages.
    source : str, optional
        Where the data come from.

    Returns
    -------
    InstrumentData
        ``kind="dial"``.
    """
    return InstrumentData("dial", np.atleast_2d(np.asarray(q, float)),
                          np.asarray(readings, float).reshape(-1, 1), None,
                          None if rows is None else np.asarray(rows, int), source)


@dataclass(frozen=True, slots=True)
class DialOptions:
    """The options of a dial indicator's calibration (:meth:`Dial.calibration_model`)."""

    touched_point: str = option(
        "auto", "--dial-point", "auto (default) estimates the point on the "
        "platform the dial touches, on a platform that rotates; origin holds it at the "
        "platform origin, the tool point of the machine file (a dial touching the tool tip): "
        "three unknowns fewer per mounting.", metavar="auto|origin",
        choices=("auto", "origin"), joint=True)


def touched_point_unknown(machine, options: DialOptions | None) -> bool:
    """Whether the touched point is an unknown: on a platform that rotates, unless
    ``--dial-point origin`` holds it at the platform origin."""
    return bool(machine.rotates) and (options is None or options.touched_point != "origin")


class Dial(Instrument):
    """A dial indicator reading one platform point along one fixed direction:
    :mod:`pkmcal.instruments.dial`."""

    name = "dial"
    aliases = ("dial-indicator", "displacement")
    words = ("a dial indicator's readings: one platform point along one fixed direction "
             "(a displacement sensor on the table)")
    plan_size = 80
    columns = ("the joint readings q1_<unit>.. and the dial's reading dial_<unit> (one "
               "mounting per file)")
    priority = 40
    singular = "dial reading"
    plural = "dial readings"
    residual_words = ("dial readings, measured - predicted (forward kinematics of the "
                      "readings)")
    advice = ("measure over the whole workspace, and along other directions (one file per "
              "mounting, fitted together)")
    measurement_words = ("dial readings along one direction (its direction, zero and the "
                         "touched point unknown)")

    def detect(self, header):
        return any(n == "dial" or n.startswith("dial_") for n in header)

    def plan_size_for(self, machine):
        """:attr:`plan_size`, or two rows per free parameter and unknown of the dial: one
        reading a pose leaves the fit little redundancy."""
        return max(self.plan_size, 2 * (int(np.sum(~machine.parameters.fixed)) + 6))

    def fit_model(self, machine, data):
        """Its direction and zero, and the touched point on a platform that rotates."""
        return DialModel(with_point=machine.rotates)

    #: its options (``pkmcal calibrate --dial-point``)
    Options = DialOptions

    def calibration_model(self, machine, data, options=None):
        """:meth:`fit_model`, the touched point held at the platform origin with
        ``--dial-point origin``."""
        return DialModel(with_point=touched_point_unknown(machine, options))

    def default_noise(self):
        return IsotropicNoise(DIAL_SIGMA)

    def describe_noise(self, noise):
        return f"dial {noise.sigma * 1e6:.4g} um (std)"

    def noise_arg(self, text, machine=None, allow_zero: bool = False):
        """The noise of ``--noise`` (text with a unit, an SI number or a noise model; None:
        the default); ``allow_zero``: 0 gives exact data (False).

        Raises
        ------
        InputError
            Naming ``--noise``: not a length, not above 0, or beyond the machine's scale.
        """
        return _noise_model_arg(self, text, machine, "a dial reading", allow_zero)

    def planned_data(self, machine, P, R, rows, source, group=None, setup=None):
        """A dial along :func:`planned_axis` (``+z``, or a planar machine's ``+y``) touching
        the platform origin, zero 0: the readings are the planned coordinates along it."""
        q = reachable(machine, P, R, rows, source)
        return dial_data(q, np.asarray(P, float)[:, planned_axis(machine)], rows, source)

    def problem(self, machine, data, noise=None, setup=None, **start):
        return InstrumentProblem(machine, data, DialModel(with_point=machine.rotates),
                                 self.default_noise() if noise is None else noise)

    def simulate(self, machine, true, n, noise, rng, truth, *, setup=None, poses=None,
                 mounting_error=MOUNTING_ERROR):
        """A dial along :func:`planned_axis` (``+z``, or a planar machine's ``+y``) tilted by
        up to :data:`DIAL_TILT`, zeroed near home (within
        ``mounting_error``), touching a point within ``mounting_error`` of the platform origin
        (a platform that rotates); ``n`` random poses around home or ``poses``; ``noise`` an
        ``IsotropicNoise`` (default :data:`DIAL_SIGMA`; False: exact).

        Returns
        -------
        tuple
            ``(data, true, truth)``; ``truth`` with ``dial`` (direction, zero, point; m).
        """
        if poses is not None:
            P, R = given_poses(poses)
            words = f"{len(P)} given poses"
        else:
            P, R, _ = self.candidates(machine, n, rng)
            words = f"{n} random poses around home"
        model = DialModel(np.eye(3)[planned_axis(machine)], with_point=machine.rotates)
        state = model.initial()
        state.values[:2] = rng.uniform(-DIAL_TILT, DIAL_TILT, 2)
        if model.with_point:
            state.values[3:6] = rng.uniform(-mounting_error, mounting_error, 3)
        d, _ = model.direction(state.values)
        P0, R0 = machine.home
        home = np.asarray(P0, float) + np.asarray(R0, float) @ model.point(state.values)
        state.values[2] = -float(d @ home) + rng.uniform(-mounting_error, mounting_error)
        data = simulate_instrument(true, machine, model, state, P, R, None,
                                   noise_model(noise, self.default_noise()), rng)
        dial = {"direction": d, "zero": float(state.values[2]),
                "point": model.point(state.values)}
        truth.update(dial=dial, poses=words, rows=[
            ("dial", f"direction ({', '.join(f'{v:.6f}' for v in d)}), zero "
                     f"{dial['zero'] * 1e3:.6g} mm, point {mm_text(dial['point'])} mm "
                     "(platform)")])
        return data, true, truth

    def simulate_arguments(self, machine, noise, **flags):
        sigma = _simulated_sigma(noise, "2um", machine)
        model = IsotropicNoise(sigma) if sigma > 0 else False
        return model, ("exact" if model is False else self.describe_noise(model)), {}

    data_columns = ("dial",)
    reading_sets = ("",)
    value_columns = (("dial", "length"),)

    def from_columns(self, readings, values, rows, source):
        return dial_data(readings[0], values[:, 0], rows, source)


#: this module's instrument (:data:`~pkmcal.instruments.registry.INSTRUMENT_MODULES`)
INSTRUMENT = Dial()
