"""What data can and cannot identify: gauges, rank, named null directions, observability."""

from ..estimation.rank import MAX_STD, RTOL, Rank, numerical_rank, rank_rule, weak_words
from .analysis import (
    IdentifiabilityReport,
    NullDirection,
    NullGroup,
    analyze,
    name_null_space,
    name_weak_directions,
    observability_indices,
    weak_directions,
)
from .gauge import (
    BASE_ROTATION_ABOUT_O,
    CONSTRAINT_LINK_GAUGES,
    PLATFORM_ROTATION_ABOUT_P,
    Gauge,
    align_gauge,
    apply_gauges,
    gauge_generators,
    gauge_groups,
    transport_covariance,
)
from .report import (
    correlated_pairs,
    identifiability_report,
    minimal_identifiable_set,
    problem_null_groups,
)

__all__ = [
    "BASE_ROTATION_ABOUT_O", "CONSTRAINT_LINK_GAUGES", "Gauge", "IdentifiabilityReport",
    "NullDirection", "NullGroup", "PLATFORM_ROTATION_ABOUT_P", "align_gauge", "analyze",
    "apply_gauges", "gauge_generators", "gauge_groups", "name_null_space",
    "name_weak_directions",
    "observability_indices", "transport_covariance",
    "MAX_STD", "RTOL", "Rank", "numerical_rank", "rank_rule", "weak_directions", "weak_words",
    "correlated_pairs", "identifiability_report", "minimal_identifiable_set",
    "problem_null_groups",
]
