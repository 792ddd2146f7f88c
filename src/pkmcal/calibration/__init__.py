"""Estimators: the shared block Levenberg-Marquardt and the calibration methods built on it,
and the one verdict on a calibration's residuals (:func:`residual_verdict`: do they agree with
the noise model; :func:`noise_ratio`: by how much)."""

from ..estimation.acceptance import (
    ResidualTest,
    ResidualVerdict,
    noise_ratio,
    report_verdict,
    residual_verdict,
)
from ..estimation.estimator import (
    BlockProblem,
    CalibrationResult,
    levenberg_marquardt,
    reduce_local,
)
from ..estimation.registration import register_points
from ..identifiability.determination import poorly_determined
from ..instruments.constraint_link import (
    METHODS,
    ConstraintLinkFK,
    ConstraintLinkIK,
    ConstraintLinkIKExplicit,
    ConstraintLinkML,
    StartReport,
    calibrate_constraint_link,
    continuation_solve,
    solve_sphere_poses,
    sphere_pose_candidates,
    start_sensitivity,
)
from ..instruments.distance import calibrate_distances
from ..instruments.pose import (
    FullPoseErrors,
    FullPoseIK,
    FullPoseML,
    align_to,
    calibrate_full_pose,
    estimate_frames,
    full_pose_errors,
    gauge_free_error,
)
from ..instruments.probe import calibrate_probe
from ..instruments.tracker import (
    TrackerProblem,
    calibrate_tracker,
    distance_ratios,
    predict_tracker_points,
    prediction_covariance,
)

# --parameters auto's chooser and the bed's own shape register themselves with the
# calibration flow (they read data through the flow, which therefore does not import them)
from . import bed_surface, model_choice  # noqa: F401
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
           "poorly_determined", "ResidualTest", "ResidualVerdict", "noise_ratio",
           "report_verdict", "residual_verdict"]
