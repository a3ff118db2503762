"""One builder for the whole system: every stage made from one :class:`~dynslam_lab.config.Config`.

The command line, the ablation, the sweeps, the notebooks and the benchmarks all build their
system here, so that what ``summary.json`` records (the config) is what every stage ran with,
and the stages that must agree (tracking and loop closing share the camera and the virtual
stereo baseline ``bf``) are given the same values::

    config = Config()                                   # or load_config("my.toml", Config())
    seq = TumSequence("data/rgbd_dataset_freiburg3_walking_xyz")
    system = build_pipeline(config, seq.camera, detector="oracle", filters="full")
    summary = run_sequence(seq, "runs/wxyz", system)    # dynslam_lab.runs

``detector`` is a detector spec (``none``, ``oracle``, ``onnx:PATH``, ``cache:DIR``;
:func:`~dynslam_lab.detection.build_detector`), ``filters`` a filter name or stage list
(``none``, ``semantic``, ``depth_ransac``, ``geometry``, ``full``, ``oracle``;
:func:`~dynslam_lab.dynamic.screening.build_screener`).
"""

from __future__ import annotations

from .camera import PinholeCamera
from .config import Config
from .detection import build_detector
from .dynamic.screening import build_screener, parse_filters
from .dynamic.stages import DETECTION_STAGES
from .errors import UsageError
from .slam.loop_closing import LoopCloser
from .slam.system import System

__all__ = ["build_pipeline", "detector_stages"]


def detector_stages(filters: str, config: Config) -> list[str]:
    """The stages of ``filters`` (as ``config`` defines them) that judge keypoints from detections
    (:data:`~dynslam_lab.dynamic.stages.DETECTION_STAGES`): without a detector they cannot run."""
    return [s for s in parse_filters(filters, config.screening) if s in DETECTION_STAGES]


def _check_combination(filters: str, detector: str, config: Config) -> None:
    needs = detector_stages(filters, config)
    if needs and str(detector).strip().lower() in ("", "none"):
        raise UsageError(
            f"--filters {filters!r} runs {needs}, which judge keypoints from detections, but --detector is 'none': "
            "pass --detector oracle|onnx:MODEL|cache:DIR, or use --filters geometry (no detector needed)"
        )


def build_pipeline(
    config: Config,
    camera: PinholeCamera,
    detector: str = "none",
    filters: str = "none",
    loop_closing: bool = True,
) -> System:
    """The SLAM system with every stage built from ``config``.

    Parameters
    ----------
    config : the root parameter tree; its sections configure the stages.
    camera : intrinsics of the sequence (tracking, screening and loop closing use it).
    detector : detector spec (``none``, ``oracle``, ``onnx:PATH``, ``cache:DIR``).
    filters : dynamic-feature filter name or comma-separated stage list.
    loop_closing : build the loop closer (also needs ``config.loop_closing.enabled``).

    Raises
    ------
    ValueError
        For an unknown detector or filter, or filters that need detections without a detector.
    """
    _check_combination(filters, detector, config)
    det = build_detector(detector, config.detection)
    screener = build_screener(filters, config.screening)
    closer = None
    if loop_closing and config.loop_closing.enabled:
        closer = LoopCloser(config.loop_closing, camera, config.tracking.bf)
    system = System(camera, config, detector=det, screener=screener, loop_closer=closer)
    system.description.update({"detector": str(detector), "filters": str(filters), "loop_closing": closer is not None})
    return system
