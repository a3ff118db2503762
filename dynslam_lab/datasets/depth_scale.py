"""Is the depth in metres? The depth scale checked before a run, and after it against the ground truth.

A 16-bit depth PNG holds integers; the camera's ``depth_scale`` says how many of them make a metre
(5000 for TUM RGB-D and Bonn, Sturm et al. 2012; 1000, millimetres, for many other sensors and
renderers). Nothing in the images says which: RGB-D geometry cannot see a wrong scale, because a world
scaled by ``s`` seen from a path scaled by ``s`` projects to the same pixels. A wrong scale therefore
runs without a complaint and returns a path ``s`` times too large or too small (measured: the
synthetic ``walking_xyz``, 60 frames, ``--filters none``, its 5000 units per metre read at 1000 gave an
ATE of 2.26 m, read at 25000 an ATE of 0.096 m, both with exit code 0, against 0.01 m at the right
scale). Two checks catch it (ours):

1. **Before the run** (:func:`check_depth_range`): the median depth of a few frames spread over the
   sequence, in metres at the camera's scale, must lie inside the range tracking uses
   (``tracking.min_depth`` .. ``tracking.max_depth``, 0.1-8 m by default, a structured-light or
   time-of-flight sensor's). Outside it most keypoints would have no usable depth and the run could
   not work: a :class:`~dynslam_lab.datasets.tum.DatasetError` names the file, the scale and what the
   same numbers would mean at 1000 and 5000 units per metre, before anything is written. TUM's
   ``fr3/walking_xyz`` reads 2.6 m (median) and the synthetic scenes 2.7-5 m; a scale five times too small
   (1000 for 5000) puts them at 13-25 m and is refused. Five times too large (millimetres read as 5000)
   gives 0.5-1 m, a plausible close-up: only the ground truth can tell.
2. **After the run** (:func:`depth_scale_from_trajectory`): where the sequence has ground truth, the
   estimate is aligned to it with a similarity (Umeyama 1991, Sim(3)); a scale far from 1 that
   explains the error (the Sim(3) ATE much below the rigid one and below the path's own spread) is a
   depth scale off by that factor, and the run's ``summary.json`` gets a warning with the scale that
   would fit. The test needs a path that moves (``min_path_m``): a camera at rest has no scale to measure.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .tum import DatasetError, load_depth

__all__ = ["DepthSample", "sample_depth", "depth_range_error", "check_depth_range", "ScaleCheck", "depth_scale_from_trajectory"]

COMMON_SCALES = (1000.0, 5000.0)  # units per metre of the usual 16-bit depth files: millimetres, TUM/Bonn


@dataclass(frozen=True)
class DepthSample:
    """The median depth of a few frames.

    median_m : median over the frames of each frame's median valid depth (m, at ``depth_scale``); None
        when no sampled frame has a valid depth.
    median_units : the same in the file's integer units.
    paths : the depth images read (unreadable ones are left out: the run reports them).
    depth_scale : units per metre used.
    no_depth_share : mean share of those images' pixels without depth (nan when none was read).
    """

    median_m: float | None
    median_units: float | None
    paths: tuple[Path, ...]
    depth_scale: float
    no_depth_share: float = float("nan")


def sample_depth(sequence, n_frames: int | None = None, k: int = 5) -> DepthSample:
    """Read ``k`` depth images spread evenly over the first ``n_frames`` frames of ``sequence`` (a
    :class:`~dynslam_lab.datasets.tum.TumSequence`) and take their median valid depth."""
    n = len(sequence) if n_frames is None else min(len(sequence), int(n_frames))
    scale = float(sequence.camera.depth_scale)
    if n <= 0 or k < 1:
        return DepthSample(None, None, (), scale)
    idx = np.unique(np.linspace(0, n - 1, min(k, n)).round().astype(int))
    medians, paths, holes = [], [], []
    for i in idx:
        path = sequence.depth_path(int(i))
        try:
            z = load_depth(path, scale)
        except (DatasetError, OSError):
            continue  # the run reports the frame
        has = np.isfinite(z) & (z > 0)
        if has.any():
            medians.append(float(np.median(z[has])))
            paths.append(Path(path))
            holes.append(1.0 - float(has.mean()))
    if not medians:
        return DepthSample(None, None, tuple(paths), scale)
    m = float(np.median(medians))
    return DepthSample(m, m * scale, tuple(paths), scale, float(np.mean(holes)))


def _at_common_scales(units: float) -> str:
    return ", ".join(f"{units / s:.2f} m at {s:g}" for s in COMMON_SCALES)


def depth_range_error(sample: DepthSample, sequence, min_depth: float, max_depth: float) -> str | None:
    """The message when ``sample`` (of ``sequence``: :func:`sample_depth`) lies outside ``[min_depth, max_depth]``
    metres, naming the first image read, the scale, the median in metres and in file units, what those units would
    be at 1000 and 5000 units per metre, and where to set the scale; None inside (or without depth)."""
    s = sample
    if s.median_m is None or min_depth <= s.median_m <= max_depth:
        return None
    where = Path(getattr(sequence, "root", s.paths[0].parent))
    return (
        f"{s.paths[0]}: the depth images read as {s.median_m:.2f} m (median of {len(s.paths)} frames at depth_scale "
        f"{s.depth_scale:g} units per metre, camera '{sequence.camera.name}'), outside the {min_depth:g}-{max_depth:g} m "
        f"that tracking uses (tracking.min_depth, tracking.max_depth): the depth scale is likely wrong. "
        f"The median, {s.median_units:.0f} units, would be {_at_common_scales(s.median_units)} units per metre; "
        f"set depth_scale in {where / 'camera.json'} (or pass --camera), or set tracking.min_depth / tracking.max_depth "
        f"(--config) for a sensor of another range")


def check_depth_range(sequence, n_frames: int | None, min_depth: float, max_depth: float, k: int = 5) -> DepthSample:
    """Refuse a sequence whose depth, at its camera's ``depth_scale``, lies outside ``[min_depth, max_depth]``
    metres (median of ``k`` frames; :func:`sample_depth`). Returns the sample.

    Raises
    ------
    DatasetError
        :func:`depth_range_error`'s message.
    """
    s = sample_depth(sequence, n_frames, k)
    error = depth_range_error(s, sequence, min_depth, max_depth)
    if error:
        raise DatasetError(error)
    return s


@dataclass(frozen=True)
class ScaleCheck:
    """The Sim(3) scale of the estimate against the ground truth.

    scale : ``c`` of the similarity that best maps the estimate onto the ground truth (1 = right size).
    ate_se3_m, ate_sim3_m : ATE RMSE after a rigid and after a similarity alignment (m).
    path_m : length of the ground truth's path over the associated poses (m).
    spread_m : RMS distance of those ground-truth positions from their centroid (m).
    warning : a message when the depth scale looks wrong, else None.
    """

    scale: float
    ate_se3_m: float
    ate_sim3_m: float
    path_m: float
    spread_m: float
    warning: str | None


def depth_scale_from_trajectory(gt, est, depth_scale: float, min_path_m: float = 0.1, max_ratio: float = 2.0,
                                explained: float = 0.25) -> ScaleCheck:
    """Whether the estimate ``est`` is ``max_ratio`` times or more too large or too small against the ground
    truth ``gt`` (both :class:`~dynslam_lab.evaluation.trajectory.Trajectory`, associated by timestamp).

    All of: the similarity's scale ``c`` (``gt ~ c R est + t``) lies beyond ``[1 / max_ratio, max_ratio]``; the
    similarity fits: its ATE is at most ``explained`` times the rigid ATE (the scale explains the error) and at
    most ``explained`` times the spread of the ground truth's positions (a path shrunk towards the centroid of a
    camera that hardly moved fits the rigid ATE's fraction too, not the path: a tracker that followed movers
    while the camera turned in place); the ground truth's path is at least ``min_path_m`` long (a camera at
    rest has no size to measure). The depth scale that would fit is ``depth_scale / c``: the path's size
    follows the depth's metres, which are the file's units over ``depth_scale``."""
    from ..evaluation.ate import compute_ate

    rigid = compute_ate(gt, est, align="se3")
    sim = compute_ate(gt, est, align="sim3")
    c = float(sim.alignment.scale)
    g = rigid.gt_positions
    path = float(np.linalg.norm(np.diff(g, axis=0), axis=1).sum())
    spread = float(np.sqrt(((g - g.mean(axis=0)) ** 2).sum(axis=1).mean()))
    warning = None
    fits = sim.stats.rmse <= explained * min(rigid.stats.rmse, spread)
    if path >= min_path_m and not 1.0 / max_ratio < c < max_ratio and fits:
        warning = (f"the estimated path is {1.0 / c:.2f} times the size of the ground truth's (Sim(3) alignment: ATE "
                   f"{sim.stats.rmse:.3f} m against {rigid.stats.rmse:.3f} m rigid, over {path:.2f} m of path): the depth "
                   f"scale is likely wrong; depth_scale {depth_scale:g} units per metre was used, about "
                   f"{depth_scale / c:.0f} would fit")
    return ScaleCheck(c, float(rigid.stats.rmse), float(sim.stats.rmse), path, spread, warning)
