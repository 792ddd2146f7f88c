"""Measurement types: data containers, simulation and the frames each cannot fix."""

from .constraint_link import ConstraintLinkData, sample_sphere_poses, simulate_constraint_link
from .deviations import RANDOM_DEVIATION, random_deviations
from .full_pose import (
    FullPoseData,
    FullPoseNoise,
    MeasurementFrames,
    default_measurement_frames,
    sample_platform_poses,
    simulate_full_pose,
)
from .tracker import (
    TRACKER_GRID_SPACING,
    TrackerData,
    TrackerNoise,
    default_tracker_pose,
    grid_points,
    neighbour_pairs,
    simulate_tracker,
)

__all__ = ["RANDOM_DEVIATION", "TRACKER_GRID_SPACING", "ConstraintLinkData", "FullPoseData",
           "FullPoseNoise", "MeasurementFrames", "TrackerData", "TrackerNoise",
           "default_measurement_frames", "default_tracker_pose", "grid_points",
           "random_deviations", "neighbour_pairs", "sample_platform_poses",
           "sample_sphere_poses", "simulate_constraint_link", "simulate_full_pose",
           "simulate_tracker"]
