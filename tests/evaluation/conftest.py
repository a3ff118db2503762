"""Synthetic trajectories for the evaluation tests (seeded, smooth, with known truth)."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.evaluation import Trajectory
from dynslam_lab.geometry.se3 import so3_exp


def smooth_trajectory(n: int = 300, rate: float = 30.0, t0: float = 1000.0, seed: int = 0) -> Trajectory:
    """A hand-held-like camera path: sums of sines in position and rotation vector."""
    rng = np.random.default_rng(seed)
    t = t0 + np.arange(n) / rate
    s = t - t0
    freq = rng.uniform(0.1, 0.6, size=(2, 3))
    phase = rng.uniform(0, 2 * np.pi, size=(2, 3))
    pos = 0.8 * np.sin(freq[0] * s[:, None] * 2 * np.pi + phase[0])
    rotvec = 0.4 * np.sin(freq[1] * s[:, None] * 2 * np.pi + phase[1])
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, :3, :3] = so3_exp(rotvec)
    P[:, :3, 3] = pos
    return Trajectory(t, P)


def perturbed(traj: Trajectory, sigma_t: float = 0.01, sigma_r: float = 0.01, seed: int = 1) -> Trajectory:
    """Add independent Gaussian noise to positions (m) and orientations (rad)."""
    rng = np.random.default_rng(seed)
    P = traj.poses.copy()
    P[:, :3, 3] += rng.normal(0, sigma_t, size=(len(traj), 3))
    P[:, :3, :3] = P[:, :3, :3] @ so3_exp(rng.normal(0, sigma_r, size=(len(traj), 3)))
    return Trajectory(traj.timestamps.copy(), P)


@pytest.fixture
def synth():
    return smooth_trajectory, perturbed
