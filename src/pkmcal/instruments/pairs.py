"""Distances between two platform points: the nozzle at two sets of readings (SPEC 8).

A row holds two sets of joint readings ``q_a``, ``q_b`` and the distance ``d`` measured
between the platform points there: ``d = |x(q_a) - x(q_b)|`` with ``x = P + R c`` (``c`` the
point on the platform, the nozzle tip at the platform origin by default). Features of a
printed object measured with a caliper are such distances (Klipper's ``DELTA_ANALYZE``: the
object ``docs/prints/calibrate_size.stl`` printed at known stable positions, its distances
``distanceN`` between ``distanceN_pos1`` and ``distanceN_pos2``). The instrument has no
unknown of its own and sees no frame: a rigid motion of the base frame changes no distance.

Klipper's test object as the standard plan (``klippy/extras/delta_calibrate.py``,
``measurements_to_distances``): six directions at 210, 270, 330, 30, 90, 150 deg; the
centre pillar's ridge at ``4.5 mm`` and the outer pillars at ``65 mm`` (ridge ``69.5 mm``);
six distances from the inner ridge to the outer ridge along each direction, and six between
the ridges of the outer pillars, from the pillar at one direction along the direction two
steps further on.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..machines.reach import (
    bed_height,
)
from ..parameters import ParameterSet
from ..paths import path_text
from .base import Instrument, StandardPlan, _noise_model_arg, has_column, reachable
from .data import InstrumentData
from .experiment import MOUNTING_ERROR
from .models import NuisanceModel
from .problem import InstrumentProblem

#: default noise of a distance between two points of a printed part (a caliper), m
PAIR_SIGMA = 20e-6
#: the directions of Klipper's calibration object, deg (``MeasureAngles``)
MEASURE_ANGLES = (210.0, 270.0, 330.0, 30.0, 90.0, 150.0)
#: its outer pillars' radius and the ridge's offset, mm (``MeasureOuterRadius``,
#: ``MeasureRidgeRadius``)
OUTER_RADIUS, RIDGE_RADIUS = 65.0, 4.5


def klipper_object_pairs(scale: float = 1.0, height: float = 0.0) -> tuple[np.ndarray, str]:
    """The 12 point pairs of Klipper's ``DELTA_ANALYZE`` object, m.

    Parameters
    ----------
    scale : float, optional
        The object's scale (``DELTA_ANALYZE SCALE``).
    height : float, optional
        The height of the points above the bed, m.

    Returns
    -------
    pairs : ndarray, shape (12, 2, 3)
        First and second point of each distance, m.
    words : str
        The plan in words.
    """
    a = np.radians(MEASURE_ANGLES)
    xy = np.column_stack([np.cos(a), np.sin(a)])
    inner = xy * RIDGE_RADIUS * scale
    outer = xy * (OUTER_RADIUS + RIDGE_RADIUS) * scale
    start = xy * OUTER_RADIUS * scale
    shifted = np.roll(xy, -2, axis=0)
    first = shifted * RIDGE_RADIUS * scale + start
    second = shifted * (OUTER_RADIUS + RIDGE_RADIUS) * scale + start
    a_pts = np.concatenate([inner, first]) * 1e-3
    b_pts = np.concatenate([outer, second]) * 1e-3
    z = np.full((12, 1), float(height))
    pairs = np.stack([np.hstack([a_pts, z]), np.hstack([b_pts, z])], 1)
    return pairs, ("Klipper's DELTA_ANALYZE object (calibrate_size.stl): 6 centre-to-outer and "
                   "6 outer-to-outer ridge distances")


class PairDistanceModel(NuisanceModel):
    """``d = |x_a - x_b|``, the distance between the platform point at two poses.

    Rows of :meth:`residuals` come in two halves: the first ``K`` poses are the rows' first
    positions, the last ``K`` their second (see :class:`PairProblem`).

    Parameters
    ----------
    point : array_like, shape (3,), optional
        The point on the platform, m (default the platform origin, a printer's nozzle tip).
    """

    kind = "pair-distances"
    #: what its measurements are, in words (noise groups, outlier rows)
    quantity = "distances between two nozzle positions"
    size = 1
    words: dict = {}

    def __init__(self, point=None):
        self.point = np.zeros(3) if point is None else np.asarray(point, float).reshape(3)
        super().__init__(ParameterSet([], [], np.zeros(0)))

    def points(self, P, R) -> np.ndarray:
        """``P + R c`` per pose."""
        return np.asarray(P, float) + np.einsum("kij,j->ki", np.asarray(R, float), self.point)

    def residuals(self, state, P, R, measured, group, jacobian=True):
        K = len(P) // 2
        x = self.points(P, R)
        v = x[:K] - x[K:]
        d = np.linalg.norm(v, axis=-1)
        e = measured[:K, :1] - d[:, None]
        if not jacobian:
            return e, None, None
        n = v / np.where(d > 0, d, 1.0)[:, None]
        from ..kinematics import skew

        Rc = x - np.asarray(P, float)
        # de/dx_a = -n, de/dx_b = +n; dx/dOmega = -skew(R c)
        g = np.concatenate([-n, n])
        de_dpose = np.concatenate([g, -np.einsum("ki,kij->kj", g, skew(Rc))], -1)[:, None, :]
        return e, de_dpose, np.zeros((K, 1, 0))

    def predict(self, state, P, R, group):
        return -self.residuals(state, P, R, np.zeros((len(P), 1)), group, False)[0]

    def start(self, P, R, measured, group, source="<data>"):
        return self


class PairProblem(InstrumentProblem):
    """The instrument problem of two-point distances: two forward kinematics per row.

    ``data.q`` holds the two reading sets side by side (``(K, 2 n_joints)``); the state's
    poses are the first positions followed by the second (``(2K, 3)``); a row's derivatives
    are the sums over its two poses (:class:`~pkmcal.instruments.problem.InstrumentProblem`
    with :attr:`readings_per_row` 2).
    """

    readings_per_row = 2


def pair_data(q_a, q_b, d, rows=None, source: str = "<data>") -> InstrumentData:
    """Two-point distance data from the two reading sets and the distances (SI).

    Parameters
    ----------
    q_a, q_b : array_like, shape (K, n_joints)
        Readings at the first and second point, internal units.
    d : array_like, shape (K,)
        Measured distances, m.
    rows : array_like of int, optional
        Row (or line) numbers for messages.
    source : str, optional
        Where the data come from.

    Returns
    -------
    InstrumentData
        ``kind="pair-distances"``, ``q`` of shape ``(K, 2 n_joints)``.
    """
    q = np.hstack([np.atleast_2d(np.asarray(q_a, float)), np.atleast_2d(np.asarray(q_b, float))])
    return InstrumentData("pair-distances", q, np.asarray(d, float).reshape(-1, 1), None,
                          None if rows is None else np.asarray(rows, int), source)


PairDistanceModel.problem_class = PairProblem


class PairDistance(Instrument):
    """Distances between the platform point at two sets of readings (a caliper on a printed
    part, Klipper's DELTA_ANALYZE object): :mod:`pkmcal.instruments.pairs`. A plan's poses
    come in pairs, rows ``2k`` and ``2k + 1`` one distance."""

    name = "pair-distances"
    aliases = ("caliper", "two-point-distances")
    words = ("distances between the nozzle at two sets of readings (a caliper on a printed "
             "part; Klipper's DELTA_ANALYZE object)")
    plan_size = 24
    columns = ("the readings at two nozzle positions q1_<unit>.. and q1b_<unit>.. and the "
               "distance between them, distance_mm (a caliper on a printed part)")
    priority = 5

    singular = "two-point distance"
    plural = "two-point distances"
    residual_words = "distances between the two nozzle positions, measured - predicted"
    advice = "measure distances in several directions and at several heights"

    def detect(self, header):
        return has_column(header, "q1b") and has_column(header, "distance")

    def fit_model(self, machine, data):
        """No unknown of its own: :class:`PairDistanceModel` of the nozzle tip."""
        return PairDistanceModel()

    def noise_text(self, noise):
        return f"distances {noise.sigma * 1e6:.4g} um (std)"

    def applies(self, machine):
        return None

    def default_noise(self):
        from .models import IsotropicNoise

        return IsotropicNoise(PAIR_SIGMA)

    def describe_noise(self, noise):
        return f"distance {noise.sigma * 1e6:.4g} um (std)"

    def noise_arg(self, text, machine, allow_zero: bool = False):
        """The noise of ``--noise`` (text with a unit, an SI number or a noise model; None:
        the default); ``allow_zero``: 0 gives exact data (False), as ``simulate`` takes it.

        Raises
        ------
        InputError
            Naming ``--noise``: not a length, not above 0, or beyond the machine's scale.
        """
        return _noise_model_arg(self, text, machine, "a measured distance", allow_zero)

    def candidates(self, machine, n, rng, setup=None):
        raise InputError("pair-distances: poses are chosen in pairs (one distance each); "
                         "pose selection picks single poses - use the standard plan, "
                         "Klipper's DELTA_ANALYZE object (--scenario pair-distances)")

    def standard_plan(self, machine, n, seed, setup=None):

        pairs, words = klipper_object_pairs(height=bed_height(machine))
        if n != 2 * len(pairs):
            return StandardPlan(words, reason=f"Klipper's object has {len(pairs)} distances "
                                              f"({2 * len(pairs)} poses), not {n} poses")
        P = pairs.reshape(-1, 3)
        return StandardPlan(words, P, np.broadcast_to(np.eye(3), (len(P), 3, 3)).copy())

    def planned_data(self, machine, P, R, rows, source, group=None, setup=None):

        if len(P) % 2:
            raise InputError(f"{path_text(source)}: "
                             f"{len(P)} poses; two-point distances take them in "
                             "pairs")
        q = reachable(machine, P, R, rows, source)
        d = np.linalg.norm(P[0::2] - P[1::2], axis=-1)
        return pair_data(q[0::2], q[1::2], d, np.asarray(rows)[0::2], source)

    def simulate(self, machine, true, n, noise, rng, truth, *, setup=None, poses=None,
                 mounting_error=MOUNTING_ERROR):
        """Klipper's object printed by the nominal model's commands on the true machine and
        measured: each distance between the true nozzle positions of the commanded pair,
        plus the noise (``noise`` an ``IsotropicNoise``, default :data:`PAIR_SIGMA`; False:
        exact). ``n`` must be the plan's poses (24); ``poses`` and ``mounting_error`` do not
        apply (the object is the plan, the nozzle no mounting).

        Returns
        -------
        tuple
            ``(data, true, truth)`` as :func:`~pkmcal.instruments.simulate.simulate_scenario`.
        """

        plan = self.standard_plan(machine, n, 0)
        if not plan.available:
            raise InputError(f"--poses {n}: {plan.reason}")
        q = reachable(machine, plan.P, plan.R, np.arange(1, len(plan.P) + 1), "the plan")
        fk = true.fk(q)
        if not fk.converged.all():
            raise InputError("the true machine cannot reach the plan's points")
        d = np.linalg.norm(fk.P[0::2] - fk.P[1::2], axis=-1)
        model = self.default_noise() if noise is None else noise
        if model is not False and model is not None:
            d = d + model.sample(d[:, None], rng)[:, 0]
        data = pair_data(q[0::2], q[1::2], d, None, "<simulated>")
        truth.update(poses=plan.name, rows=[
            ("object", f"printed at the nominal model's commands; the distances of the true "
                       f"nozzle positions, {d.min() * 1e3:.6g}..{d.max() * 1e3:.6g} mm")])
        return data, true, truth

    def simulate_arguments(self, machine, noise, **flags):
        model = self.noise_arg(noise, machine, allow_zero=True)
        return model, ("exact" if model is False else self.describe_noise(model)), {}

    data_columns = ("distance",)

    def problem(self, machine, data, noise=None, setup=None, **start):

        return PairProblem(machine, data, PairDistanceModel(),
                           self.default_noise() if noise is None else noise)

    measurement_words = ("distances between the nozzle at two sets of readings (no unknown of "
                         "their own)")

    reading_sets = ("", "b")
    value_columns = (("distance", "length"),)
    positive_values = True

    def from_columns(self, readings, values, rows, source):
        return pair_data(readings[0], readings[1], values[:, 0], rows, source)


#: this module's instrument (:data:`~pkmcal.instruments.registry.INSTRUMENT_MODULES`)
INSTRUMENT = PairDistance()
