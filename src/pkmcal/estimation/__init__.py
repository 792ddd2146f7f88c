"""The bottom estimation layer every instrument and calibration uses.

Levenberg-Marquardt with local unknowns (:mod:`.estimator`), variance components
(:mod:`.variance`), the numerical rank and what it calls identifiable (:mod:`.rank`), and the
rigid registration of point sets (:mod:`.registration`). It imports nothing of pkmcal but
:mod:`pkmcal.errors`, :mod:`pkmcal.parameters` and :mod:`pkmcal.kinematics`.
"""

from .estimator import BlockProblem, CalibrationResult, levenberg_marquardt, reduce_local
from .rank import MAX_STD, RTOL, Rank, numerical_rank, rank_rule, weak_words
from .registration import register_points

__all__ = ["BlockProblem", "CalibrationResult", "levenberg_marquardt", "reduce_local",
           "MAX_STD", "RTOL", "Rank", "numerical_rank", "rank_rule", "weak_words",
           "register_points"]
