"""Instruments as measurement models over any machine: points, distances, probe heights (and
their data).

Each instrument is a :class:`~pkmcal.instruments.models.NuisanceModel` (``readings -> predicted
measurement`` with its own unknowns and noise model); one problem
(:class:`~pkmcal.instruments.problem.InstrumentProblem`) puts any of them on any
:class:`~pkmcal.machines.Machine` into the shared estimator.
"""

from .data import InstrumentData
from .joint import JointContributions, JointProblem, JointState, file_labels, fit_joint
from .models import (
    DistancesModel,
    IsotropicNoise,
    NuisanceModel,
    NuisanceState,
    PointsModel,
    ProbeModel,
    sphere_centre,
)
from .predict import (
    InstrumentPrediction,
    choose_instrument,
    fitted_instruments,
    instrument_name,
    predict_instrument,
)
from .problem import InstrumentProblem, InstrumentState, fit_instrument, frame_motion_groups

__all__ = ["DistancesModel", "InstrumentData", "InstrumentProblem", "InstrumentState",
           "IsotropicNoise", "NuisanceModel", "NuisanceState", "PointsModel", "ProbeModel",
           "fit_instrument", "frame_motion_groups", "sphere_centre", "InstrumentPrediction",
           "choose_instrument", "fitted_instruments", "instrument_name", "predict_instrument",
           "JointContributions", "JointProblem", "JointState", "file_labels", "fit_joint"]
