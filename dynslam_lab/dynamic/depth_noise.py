"""How noisy is this camera's depth? Measured from the depth images, so that the depth margins follow it (ours).

The screening's depth tests compare a depth with a prediction and call a difference larger than a margin motion:
the free-space margin of the multi-frame test and the depth test of the multi-view check,
``tau = max(depth_m, depth_quadratic z^2)`` (after Chang et al. 2021, with the quadratic growth of a disparity
sensor's error, Khoshelham and Elberink 2012). Those margins were set for a Kinect-like sensor: the axial noise
model of Nguyen, Izadi and Lovell 2012,

    sigma_N(z) = 0.0012 + 0.0019 (z - 0.4)^2   [m],

which our renderer follows. A noisier sensor (a stereo camera, another renderer) crosses them everywhere on the
static room, and the room is judged moving.

**The measurement.** On a smooth surface the second difference of neighbouring depth readings along a row,
``d2 = z(u-1) - 2 z(u) + z(u+1)``, is nearly free of the surface's slope (zero on a plane seen head-on, small on any
plane at the spacing of one pixel) and holds the noise: for readings with independent noise of standard deviation
``sigma`` it is normal with standard deviation ``sqrt(6) sigma``, and the median of ``|d2|`` is
``0.6745 sqrt(6) sigma``. Normalised by the model at each reading's depth,

    ratio = median( |d2| / sigma_N(z) ) / (0.6745 sqrt(6)),

is 1 for a sensor with exactly the model's noise. The median ignores the depth edges (a small share of the
samples). :func:`depth_noise_ratio` takes it along every ``step``-th row and column of one depth image.

What it reads, measured: our renderer's Kinect (noise and disparity steps) 1.07-1.09 on every scene and frame; the
same with ``CameraEffects(depth_noise=0.005)`` (a stereo camera) 3.2-3.3; the real TUM RGB-D depth frame in the
project's data 0.0: a real Kinect's depth is smooth over neighbouring pixels (its correlation window) and changes in
disparity steps, so most second differences are exactly 0. Noise correlated over several pixels is invisible to
this measurement; it reads low, and a low reading never narrows a margin.

**What it changes.** :class:`DepthNoiseMeter` measures the first ``frames`` frames with enough readings and keeps
the median; the margins that grow with the sensor's noise scale by ``max(1, ratio / tolerance)``
(:meth:`~dynslam_lab.dynamic.config.ScreeningConfig.for_depth_noise`). At the Kinect's noise nothing changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..datasets.kinect import DepthNoise, nguyen_sigma

__all__ = ["DepthNoiseConfig", "depth_noise_ratio", "DepthNoiseMeter", "MEDIAN_ABS_D2"]

#: median of |z(u-1) - 2 z(u) + z(u+1)| in units of the readings' standard deviation, for independent normal noise
MEDIAN_ABS_D2 = 0.6744897501960817 * math.sqrt(6.0)


@dataclass(frozen=True)
class DepthNoiseConfig:
    """``[screening.depth_noise]``: the depth noise measured from the images (module docstring)."""

    frames: int = 5  # frames with enough readings measured, the median kept; 0 = never measure (margins as set); ours
    tolerance: float = 1.25  # the depth margins scale by max(1, ratio / tolerance): unchanged up to 1.25x the model's noise; ours
    step: int = 4  # every step-th row and column is measured (px); ours
    min_samples: int = 2000  # a frame with fewer second differences (depth on three neighbours) is not measured; ours

    def __post_init__(self) -> None:
        if self.frames < 0 or self.step < 1 or self.min_samples < 1:
            raise ValueError(f"DepthNoiseConfig: frames must be >= 0, step >= 1 and min_samples >= 1, got "
                             f"{self.frames}, {self.step}, {self.min_samples}")
        if not self.tolerance > 0:
            raise ValueError(f"DepthNoiseConfig.tolerance must be > 0, got {self.tolerance}")


def _second_differences(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(|d2|, z)`` along the last axis of ``z (rows, n)`` where all three readings are valid."""
    a, b, c = z[:, :-2], z[:, 1:-1], z[:, 2:]
    ok = (a > 0) & (b > 0) & (c > 0)
    bz = b[ok]
    return np.abs(a[ok] - 2.0 * bz + c[ok]), bz


def depth_noise_ratio(depth: np.ndarray, step: int = 4, min_samples: int = 2000,
                      model: DepthNoise = DepthNoise()) -> float:
    """The noise of ``depth (h, w)`` (metres, 0 = no reading) in units of the Kinect model ``sigma_N(z)`` (module
    docstring): 1 for the model's noise. NaN when fewer than ``min_samples`` second differences can be taken."""
    z = np.asarray(depth)
    if z.ndim != 2:
        raise ValueError(f"depth_noise_ratio: depth must be (h, w), got shape {z.shape}")
    # only the measured rows and columns in float64 (not the whole image)
    d_rows, z_rows = _second_differences(z[::step].astype(np.float64))
    d_cols, z_cols = _second_differences(z[:, ::step].T.astype(np.float64))
    d = np.concatenate([d_rows, d_cols])
    if len(d) < min_samples:
        return float("nan")
    zs = np.concatenate([z_rows, z_cols])
    r = d / nguyen_sigma(zs, 0.0, model)
    return float(np.median(r) / MEDIAN_ABS_D2)


class DepthNoiseMeter:
    """The depth noise of a run's first frames (:func:`depth_noise_ratio`, the median over ``config.frames``
    frames that had enough readings). ``scale`` is what the depth margins are multiplied by: 1 until a frame was
    measured, and at or below ``tolerance`` times the model's noise. A sequence whose depth stays too sparse to
    measure is tried on at most ``ATTEMPTS_PER_FRAME * config.frames`` frames, then left at scale 1."""

    #: frames tried per frame wanted, before a depth too sparse to measure is given up on
    ATTEMPTS_PER_FRAME = 4

    def __init__(self) -> None:
        self.ratios: list[float] = []
        self.attempts = 0

    def reset(self) -> None:
        self.ratios = []
        self.attempts = 0

    def wants(self, config: DepthNoiseConfig) -> bool:
        """Whether the next frame should be measured: fewer than ``config.frames`` measured, and fewer than
        ``ATTEMPTS_PER_FRAME * config.frames`` tried."""
        return len(self.ratios) < config.frames and self.attempts < self.ATTEMPTS_PER_FRAME * config.frames

    def add(self, depth: np.ndarray, config: DepthNoiseConfig) -> None:
        """Measure one frame's depth (a frame with too few readings is skipped)."""
        self.attempts += 1
        r = depth_noise_ratio(depth, config.step, config.min_samples)
        if math.isfinite(r):
            self.ratios.append(r)

    @property
    def ratio(self) -> float:
        """The median ratio measured so far (NaN before the first)."""
        return float(np.median(self.ratios)) if self.ratios else float("nan")

    def scale(self, config: DepthNoiseConfig) -> float:
        """``max(1, ratio / tolerance)`` rounded to 0.05 (1 when nothing was measured or measuring is off)."""
        if not self.ratios or config.frames == 0:
            return 1.0
        return max(1.0, round(self.ratio / config.tolerance / 0.05) * 0.05)
