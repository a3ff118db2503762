# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 02 · ORB features and tracking
#
# The tracker of ORB-SLAM2 (Mur-Artal and Tardos, T-RO 2017) in RGB-D mode, step by step:
#
# 1. **ORB features** spread over the image and a scale pyramid (`features.orb`);
# 2. **matching** two frames: Hamming distance, ratio test, rotation consistency (`features.matching`);
# 3. **PnP-RANSAC**: the pose of a frame from 3D points (depth of the first frame) and their pixels;
# 4. **a short sequence tracked** by the whole system, estimated against true trajectory.
#
# The data is a short synthetic sequence (two people walking in an office, rendered with ground
# truth poses and instance masks). Here the people are removed with their *true* masks, a
# stand-in for the screening stage of notebooks 04-07. See `docs/tracking.md`.

# %%
import matplotlib.pyplot as plt
import numpy as np
from ipywidgets import IntSlider, FloatSlider, interactive

from dynslam_lab.config import Config
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.evaluation import align_trajectory, compute_ate
from dynslam_lab.features.matching import hamming_distance, match_descriptors, orientation_consistent
from dynslam_lab.features.orb import OrbConfig, extract_features, level_quotas
from dynslam_lab.geometry.se3 import se3_inv, transform_points
from dynslam_lab.slam.system import System
from dynslam_lab.geometry.pnp import pnp_ransac

seq = TumSequence(synthetic_sequence("walking_xyz", n_frames=30, seed=0))
f0, f1 = seq[0], seq[12]
print(seq, "| camera", seq.camera.name, "| frames", len(seq))

# %% [markdown]
# ## 1. ORB features over a pyramid and a grid
#
# `n_features` keypoints are shared among the 8 pyramid levels as a geometric series
# `n_s ∝ (1/1.2)^s`, and inside a level over a grid of cells, strongest corners first. Plain ORB
# keeps the globally strongest corners, which cluster on the most textured objects.

# %%
cfg = Config()
print("per-level quotas:", level_quotas(cfg.orb))


def show_orb(n_features=1000, grid_cols=20):
    ocfg = OrbConfig(n_features=n_features, grid_cols=grid_cols, grid_rows=max(1, grid_cols * 3 // 4))
    feats = extract_features(f0.gray, ocfg)
    plain = extract_features(f0.gray, OrbConfig(n_features=n_features, grid_cols=1, grid_rows=1))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for ax, f, title in [(axes[0], feats, f"grid {grid_cols} cells across"), (axes[1], plain, "one cell (no spreading)")]:
        ax.imshow(f0.rgb)
        sc = ax.scatter(f.uv[:, 0], f.uv[:, 1], c=f.octave, s=6, cmap="viridis", vmin=0, vmax=7)
        ax.set_title(f"{title}: {len(f)} keypoints")
        ax.axis("off")
    fig.colorbar(sc, ax=axes, label="pyramid level", shrink=0.8)
    plt.show()


interactive(show_orb, n_features=IntSlider(1000, 200, 2000, 100), grid_cols=IntSlider(20, 1, 40, 1))

# %%
show_orb()

# %% [markdown]
# ## 2. Matching two frames
#
# A descriptor has 256 bits; the distance is the number of differing bits. A match needs the
# nearest neighbour within 50 bits and clearly better than the second (`d1 < ratio · d2`); then
# the rotations `angle_1 - angle_0` of all matches vote in a 30-bin histogram and only the three
# fullest bins are kept (a camera rotates all keypoints alike). Keypoints on the people are left
# out, as the tracker does with dynamic keypoints.

# %%
feats0 = extract_features(f0.gray, cfg.orb)
feats1 = extract_features(f1.gray, cfg.orb)


def static_mask(frame, uv):
    """True where a keypoint is not on a person (ground-truth instance mask)."""
    m = frame.dynamic_mask({"person"})
    ui = np.clip(np.round(uv[:, 0]).astype(int), 0, m.shape[1] - 1)
    vi = np.clip(np.round(uv[:, 1]).astype(int), 0, m.shape[0] - 1)
    return ~m[vi, ui]


s0, s1 = static_mask(f0, feats0.uv), static_mask(f1, feats1.uv)
print(f"static keypoints: {s0.sum()} / {len(s0)} and {s1.sum()} / {len(s1)}")
D = hamming_distance(feats0.descriptors[:5], feats1.descriptors[:8])
print("Hamming distances of 5 x 8 descriptors:\n", D)


def show_matches(ratio=0.8):
    i0, i1 = np.flatnonzero(s0), np.flatnonzero(s1)
    m = match_descriptors(feats0.descriptors[i0], feats1.descriptors[i1], ratio=ratio)
    rot = orientation_consistent(feats0.angle[i0[m.idx_a]], feats1.angle[i1[m.idx_b]])
    fig, axes = plt.subplots(1, 2, figsize=(13, 4), gridspec_kw={"width_ratios": [2.2, 1]})
    canvas = np.hstack([f0.rgb, f1.rgb])
    axes[0].imshow(canvas)
    w = f0.rgb.shape[1]
    for ok, color in [(rot, "lime"), (~rot, "red")]:
        a, b = feats0.uv[i0[m.idx_a[ok]]], feats1.uv[i1[m.idx_b[ok]]]
        axes[0].plot(np.c_[a[:, 0], b[:, 0] + w].T, np.c_[a[:, 1], b[:, 1]].T, color=color, lw=0.5)
    axes[0].set_title(f"ratio {ratio:.2f}: {len(m)} matches, {int((~rot).sum())} rotation-inconsistent (red)")
    axes[0].axis("off")
    d_rot = np.mod(feats1.angle[i1[m.idx_b]] - feats0.angle[i0[m.idx_a]], 360)
    axes[1].hist(d_rot, bins=30, range=(0, 360))
    axes[1].set_xlabel("angle_1 - angle_0 (deg)")
    axes[1].set_title("rotation histogram")
    plt.show()
    return m


interactive(show_matches, ratio=FloatSlider(value=0.8, min=0.5, max=1.0, step=0.05))

# %%
matches = show_matches(0.8)

# %% [markdown]
# ## 3. PnP-RANSAC
#
# Frame 0's keypoints with depth are 3D points (`X = z K^-1 (u, v, 1)`, in frame 0's camera, which
# is our world). With their matches in frame 12, `cv2.solvePnPRansac` finds the pose of frame 12:
# the green inliers agree with one rigid motion. We compare with the true relative pose.

# %%
i0, i1 = np.flatnonzero(s0), np.flatnonzero(s1)
a, b = i0[matches.idx_a], i1[matches.idx_b]
z0 = f0.depth[np.round(feats0.uv[a, 1]).astype(int), np.round(feats0.uv[a, 0]).astype(int)]
ok = z0 > 0
X0 = seq.camera.backproject(feats0.uv[a][ok].astype(float), z0[ok])
T_c1_c0, inl = pnp_ransac(X0, feats1.uv[b][ok], seq.camera.K, reproj_px=4.0, iterations=200, seed=0)
T_true = se3_inv(f1.T_w_c_gt) @ f0.T_w_c_gt
print(f"{len(X0)} 3D-2D matches, {inl.sum()} inliers")
print("translation error (m):", np.linalg.norm(T_c1_c0[:3, 3] - T_true[:3, 3]).round(4))
uv_pred, _ = seq.camera.project(transform_points(T_c1_c0, X0))
plt.figure(figsize=(7, 5))
plt.imshow(f1.rgb)
plt.scatter(*feats1.uv[b][ok][inl].T, s=10, c="lime", label="inlier")
plt.scatter(*feats1.uv[b][ok][~inl].T, s=14, c="red", marker="x", label="outlier")
plt.legend(loc="lower right")
plt.title("PnP-RANSAC inliers in frame 12")
plt.axis("off")
plt.show()

# %% [markdown]
# ## 4. Tracking the sequence
#
# `System.process(frame)` runs the whole chain per frame: ORB, the screener (here the true masks),
# tracking by the motion model (or the reference keyframe and PnP), pose-only refinement, the
# local map, the keyframe decision, local mapping. The estimate starts at the identity; for the
# plot it is aligned to the ground truth with the best rigid motion (ATE, Sturm et al. 2012).


# %%
class TrueMaskScreener:
    """Stand-in for the screening stage: people's keypoints are dynamic (ground-truth masks)."""

    class Table:
        def __init__(self, dynamic, region_mask):
            self.dynamic, self.region_mask = dynamic, region_mask

    def screen(self, frame, uv, detections):
        return self.Table(~static_mask(frame, uv), frame.dynamic_mask({"person"}))


system = System(seq.camera, cfg, screener=TrueMaskScreener())
results = [system.process(seq[i]) for i in range(len(seq))]
est = system.trajectory()
gt = seq.groundtruth
ate = compute_ate(gt, est, align="se3")
aligned, _ = align_trajectory(est, gt.subset(np.searchsorted(gt.timestamps, est.timestamps).clip(0, len(gt) - 1)))
print(f"tracked {len(est)} / {len(seq)} frames, lost {system.lost_frames}, keyframes {len(system.map.keyframes)}, "
      f"map points {len(system.map.point_ids())}")
print(f"ATE RMSE: {1000 * ate.stats.rmse:.1f} mm")

fig, axes = plt.subplots(1, 2, figsize=(12, 4))
axes[0].plot(ate.gt_positions[:, 0], ate.gt_positions[:, 1], "k-", label="true")
axes[0].plot(ate.est_positions[:, 0], ate.est_positions[:, 1], "r--", label="estimated (aligned)")
axes[0].set_xlabel("x (m)")
axes[0].set_ylabel("y (m)")
axes[0].axis("equal")
axes[0].legend()
axes[0].set_title("camera path, top view")
stages = ["orb", "track", "local_mapping"]
ms = np.array([[r.timings_ms[s] for s in stages] for r in results])
axes[1].stackplot(np.arange(len(results)), ms.T, labels=stages)
axes[1].set_xlabel("frame")
axes[1].set_ylabel("ms")
axes[1].legend(loc="upper right")
axes[1].set_title("time per frame and stage")
plt.show()

# %%
print("per-frame: state, method, inliers, dynamic keypoints")
for r in results[:: max(1, len(results) // 8)]:
    print(f"  {r.index:3d} {r.state:12s} {r.method:20s} {r.n_inliers:4d} {r.n_dynamic:4d}{'  keyframe' if r.is_keyframe else ''}")
