"""Measurement planning: scenarios, planned problems and optimal pose selection (SPEC 3)."""

from .design import (
    CRITERIA,
    Design,
    Selection,
    criterion_value,
    design_from_problem,
    random_values,
    select_poses,
)
from .scenarios import (
    DEFAULT_PLAN_SIZE,
    SCENARIO_OF,
    SCENARIOS,
    STANDARD_PLANS,
    StandardPlan,
    candidate_poses,
    candidate_set,
    default_noise,
    describe_noise,
    measurement_frames,
    planned_data,
    planned_problem,
    scenario_for,
    scenario_problem,
    standard_plan,
    tracker_pose,
)

__all__ = [
    "CRITERIA", "DEFAULT_PLAN_SIZE", "Design", "SCENARIOS", "SCENARIO_OF", "STANDARD_PLANS",
    "Selection", "StandardPlan", "candidate_poses", "candidate_set", "criterion_value",
    "default_noise",
    "describe_noise", "design_from_problem", "measurement_frames", "planned_data",
    "planned_problem", "random_values", "scenario_for", "scenario_problem", "select_poses",
    "standard_plan", "tracker_pose",
]
