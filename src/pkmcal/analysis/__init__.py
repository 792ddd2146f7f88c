"""Accuracy of a model over a workspace (SPEC 5); pose errors from joint clearance, leg errors
and loads (SPEC 2.3, :mod:`.errors`); tolerance analysis (:mod:`.tolerance`)."""

from .accuracy import (
    AccuracyReport,
    align_poses,
    machine_workspace,
    pose_accuracy,
    pose_errors,
    workspace_poses,
)
from .errors import (
    ClearanceErrors,
    Trajectory,
    TrajectoryErrors,
    circle_trajectory,
    clearance_errors,
    clearance_map,
    link_forces,
    platform_wrench,
    pose_error,
    trajectory_errors,
    trajectory_from_poses,
    write_errors_csv,
)
from .tolerance import (
    Tolerances,
    error_map,
    linear_covariance,
    monte_carlo,
    sensitivity,
    stewart_tolerances,
    tolerances,
    worst_case,
)

__all__ = [
    "AccuracyReport", "ClearanceErrors", "Tolerances", "Trajectory", "TrajectoryErrors",
    "align_poses", "circle_trajectory", "clearance_errors", "clearance_map", "error_map",
    "link_forces", "linear_covariance", "monte_carlo", "platform_wrench", "pose_accuracy",
    "pose_error", "pose_errors", "sensitivity", "stewart_tolerances", "tolerances",
    "trajectory_errors", "trajectory_from_poses", "workspace_poses", "worst_case",
    "machine_workspace", "write_errors_csv",
]
