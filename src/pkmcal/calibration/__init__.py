"""Estimators: the shared block Levenberg-Marquardt and the calibration methods built on it."""

from ..estimation.estimator import (
    BlockProblem,
    CalibrationResult,
    levenberg_marquardt,
    reduce_local,
)
from ..estimation.registration import register_points
from .constraint_link import (
    METHODS,
    ConstraintLinkFK,
    ConstraintLinkIK,
    ConstraintLinkIKExplicit,
    ConstraintLinkML,
    calibrate_constraint_link,
    solve_sphere_poses,
)
from .distances import calibrate_distances
from .full_pose import (
    FullPoseErrors,
    FullPoseIK,
    FullPoseML,
    align_to,
    calibrate_full_pose,
    estimate_frames,
    full_pose_errors,
    gauge_free_error,
)
from .probe import calibrate_probe, poorly_determined
from .run import (
    KINDS,
    Calibration,
    CalibrationNotConverged,
    MeasurementKind,
    calibrate,
    measurement_kind,
    register_kind,
    supported_kinds,
)
from .start import StartReport, continuation_solve, sphere_pose_candidates, start_sensitivity
from .tracker import (
    TrackerProblem,
    calibrate_tracker,
    distance_ratios,
    predict_tracker_points,
    prediction_covariance,
)
from .validation import constraint_link_reading_rms, holdout_split

__all__ = ["METHODS", "BlockProblem", "CalibrationResult", "ConstraintLinkFK",
           "ConstraintLinkIK", "ConstraintLinkIKExplicit", "ConstraintLinkML", "FullPoseErrors",
           "FullPoseIK", "FullPoseML", "align_to", "calibrate_full_pose", "estimate_frames",
           "full_pose_errors", "gauge_free_error",
           "calibrate_constraint_link", "levenberg_marquardt", "reduce_local",
           "solve_sphere_poses", "TrackerProblem", "calibrate_tracker", "distance_ratios",
           "predict_tracker_points", "prediction_covariance", "register_points",
           "constraint_link_reading_rms", "holdout_split", "StartReport", "continuation_solve",
           "sphere_pose_candidates", "start_sensitivity", "KINDS", "Calibration",
           "CalibrationNotConverged", "MeasurementKind", "calibrate", "measurement_kind",
           "register_kind", "supported_kinds", "calibrate_distances", "calibrate_probe",
           "poorly_determined"]
