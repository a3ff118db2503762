"""features stage of dynslam_lab: ORB extraction spread over image and pyramid, and matching."""

from .matching import (
    TH_HIGH,
    TH_LOW,
    Matches,
    check_descriptors,
    hamming_distance,
    hamming_pairs,
    hamming_words,
    knn2,
    match_descriptors,
    orientation_consistent,
    search_by_projection,
)
from .orb import Features, OrbConfig, extract_features, level_quotas, region_quotas, scale_factors

__all__ = [
    "Features",
    "OrbConfig",
    "extract_features",
    "level_quotas",
    "region_quotas",
    "scale_factors",
    "TH_LOW",
    "TH_HIGH",
    "Matches",
    "check_descriptors",
    "hamming_distance",
    "hamming_pairs",
    "hamming_words",
    "knn2",
    "match_descriptors",
    "orientation_consistent",
    "search_by_projection",
]
