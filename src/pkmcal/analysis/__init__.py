"""Accuracy of a model over a workspace (SPEC 5)."""

from .accuracy import AccuracyReport, align_poses, pose_accuracy, pose_errors, workspace_poses

__all__ = ["AccuracyReport", "align_poses", "pose_accuracy", "pose_errors", "workspace_poses"]
