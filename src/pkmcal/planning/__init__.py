"""Measurement planning: scenarios, planned problems, identifiability and predicted accuracy
(:mod:`.assessment`) and optimal pose selection (:mod:`.design`, the policy of
:mod:`.selection`) (SPEC 3)."""

from ..instruments.scenarios import (
    DEFAULT_PLAN_SIZE,
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
from .assessment import (
    MAP_STEPS,
    WORKSPACE_POSES,
    IdentifiabilityAnalysis,
    assess_identifiability,
    measured_problem,
    noise_model,
    prediction_summary,
    write_prediction_map,
)
from .design import (
    CRITERIA,
    Design,
    Selection,
    criterion_value,
    design_from_problem,
    random_values,
    select_poses,
)
from .selection import (
    CRITERION_WORDS,
    NO_WORSE_RTOL,
    PoseSelection,
    criterion_ratio,
    reachable_standard_plan,
    select_plan,
)

__all__ = [
    "CRITERIA", "DEFAULT_PLAN_SIZE", "Design", "SCENARIOS", "STANDARD_PLANS",
    "Selection", "StandardPlan", "candidate_poses", "candidate_set", "criterion_value",
    "default_noise",
    "describe_noise", "design_from_problem", "measurement_frames", "planned_data",
    "planned_problem", "random_values", "scenario_for", "scenario_problem", "select_poses",
    "standard_plan", "tracker_pose",
    "CRITERION_WORDS", "IdentifiabilityAnalysis", "MAP_STEPS", "NO_WORSE_RTOL",
    "PoseSelection", "WORKSPACE_POSES", "assess_identifiability", "criterion_ratio",
    "measured_problem", "noise_model", "prediction_summary", "reachable_standard_plan",
    "select_plan", "write_prediction_map",
]
