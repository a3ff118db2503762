"""features stage of dynslam_lab: ORB extraction spread over image and pyramid, and matching."""

from .matching import (
    TH_HIGH,
    TH_LOW,
    Matches,
    hamming_distance,
    hamming_pairs,
    knn2,
    match_descriptors,
    orientation_consistent,
    search_by_projection,
)
from .orb import Features, OrbConfig, extract_features, level_quotas, scale_factors

__all__ = [
    "Features",
    "OrbConfig",
    "extract_features",
    "level_quotas",
    "scale_factors",
    "TH_LOW",
    "TH_HIGH",
    "Matches",
    "hamming_distance",
    "hamming_pairs",
    "knn2",
    "match_descriptors",
    "orientation_consistent",
    "search_by_projection",
]
