"""Measurement types: data containers, simulation and the frames each cannot fix."""

from .constraint_link import ConstraintLinkData, sample_sphere_poses, simulate_constraint_link

__all__ = ["ConstraintLinkData", "sample_sphere_poses", "simulate_constraint_link"]
