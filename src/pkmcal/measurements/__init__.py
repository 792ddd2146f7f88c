"""Measurement types: data containers, simulation and the frames each cannot fix."""

from .constraint_link import ConstraintLinkData, sample_sphere_poses, simulate_constraint_link
from .deviations import RANDOM_DEVIATION, random_deviations
from .tracker import (
    TRACKER_GRID_SPACING,
    TrackerData,
    TrackerNoise,
    default_tracker_pose,
    grid_points,
    neighbour_pairs,
    simulate_tracker,
)

__all__ = ["RANDOM_DEVIATION", "TRACKER_GRID_SPACING", "ConstraintLinkData", "TrackerData",
           "TrackerNoise", "default_tracker_pose", "grid_points", "random_deviations",
           "neighbour_pairs", "sample_sphere_poses", "simulate_constraint_link",
           "simulate_tracker"]
