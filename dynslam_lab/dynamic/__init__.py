"""Dynamic-feature screening: which keypoints lie on things that move.

One module per method of the four papers, each runnable on one frame, chained by
:func:`~dynslam_lab.dynamic.screening.build_screener` into one per-keypoint table
(:class:`~dynslam_lab.dynamic.table.KeypointTable`):

* :mod:`.semantic` -- classes that tend to move (all seeds);
* :mod:`.depth_ransac` -- YOLO-SLAM's depth-RANSAC inside person boxes (Wu et al. 2022);
* :mod:`.epipolar` -- LK matches, RANSAC F, point-to-epipolar-line distance (Zhang et al. 2023, Chang et al. 2021 and Ge et al. 2024);
* :mod:`.multiview` -- rough PnP pose, 4 px / 0.1 m reprojection test (Chang et al. 2021);
* :mod:`.flow` -- Farneback flow with the adaptive 2 * mean threshold (Chang et al. 2021);
* :mod:`.motion_probability` -- ASG-SLAM's restoration while delta = m/n < delta_1 (Ge et al. 2024);
* :mod:`.geometric_rule` -- Zhang et al.'s high/medium/low level rule;
* :mod:`.inpainting` -- background inpainting from earlier keyframes, for display (Chang et al. 2021);
* :mod:`.oracle` -- perfect screening from the synthetic truth (and the truth lookups).

Scores against the truth and the ablation tables are experiments: :mod:`dynslam_lab.experiments`.

Submodules import OpenCV/scipy lazily where they can; import what you need from them.
"""

from .config import FILTER_PRESETS, STAGES, ScreeningConfig
from .oracle import OracleScreener
from .screening import FILTERS, Screener, build_screener, parse_filters
from .table import KeypointTable

__all__ = [
    "ScreeningConfig",
    "STAGES",
    "FILTER_PRESETS",
    "FILTERS",
    "Screener",
    "OracleScreener",
    "build_screener",
    "parse_filters",
    "KeypointTable",
]
