"""Measurement types: data containers, simulation and the frames each cannot fix."""

from .constraint_link import ConstraintLinkData, sample_sphere_poses, simulate_constraint_link
from .tracker import (
    TrackerData,
    TrackerNoise,
    grid_points,
    neighbour_pairs,
    simulate_tracker,
)

__all__ = ["ConstraintLinkData", "TrackerData", "TrackerNoise", "grid_points",
           "neighbour_pairs", "sample_sphere_poses", "simulate_constraint_link",
           "simulate_tracker"]
