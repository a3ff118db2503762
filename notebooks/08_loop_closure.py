# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 08 · Loop closure
#
# A camera that walks around a room and comes back believes, after a few hundred frames, that
# it is somewhere else: every pose was estimated from the previous one and the small errors
# add up (*drift*). **Loop closing** (ORB-SLAM2, Mur-Artal and Tardós 2017, Sec. V) recognises
# the place, measures where the camera really is relative to the old keyframe, and spreads the
# correction over the whole trajectory. This notebook takes it apart:
#
# 1. the **vocabulary of binary words** that turns an image into a sparse vector (DBoW2,
#    Gálvez-López and Tardós 2012),
# 2. a **similarity matrix** over the keyframes of a synthetic loop: the loop is a bright
#    off-diagonal spot,
# 3. a **detected loop** and its verified matches (3D-3D RANSAC, RGB-D has metric scale),
# 4. the **pose graph** before and after optimisation.
#
# See `docs/loop_closing.md` for the equations and parameters.

# %%
import dataclasses

import ipywidgets as widgets
import matplotlib.pyplot as plt
import numpy as np
from IPython.display import display

from dynslam_lab.datasets import TumSequence
from dynslam_lab.datasets.synthetic import synthetic_sequence
from dynslam_lab.features.orb import OrbConfig, extract_features
from dynslam_lab.geometry.align import umeyama_alignment
from dynslam_lab.geometry.se3 import make_pose, relative_pose, se3_inv, so3_exp
from dynslam_lab.slam.frame import keypoint_depths
from dynslam_lab.slam.keyframe_database import KeyframeDatabase
from dynslam_lab.slam.loop_closing import LoopClosingConfig, verify_loop
from dynslam_lab.slam.pose_graph import optimize_pose_graph
from dynslam_lab.slam.vocabulary import bow_score_many, default_vocabulary

# %% [markdown]
# ## 1. The vocabulary
#
# ORB descriptors are 256-bit strings. The vocabulary is a tree: the training descriptors are
# split into $k$ clusters by k-majority (the centre of a cluster is the bitwise majority of its
# members), each cluster again into $k$, down to a few levels. The leaves are the **words**. A
# descriptor finds its word by walking down the tree, always to the nearest child in Hamming
# distance. Each word has an inverse document frequency $\mathrm{idf}_i = \log(N / N_i)$: words
# that occur in every training image say little about the place.

# %%
voc = default_vocabulary()
print(voc)
per_level = np.bincount(voc.level[voc.word_node], minlength=voc.depth + 1)
fig, ax = plt.subplots(1, 2, figsize=(11, 3.2))
ax[0].bar(np.arange(len(per_level)), per_level)
ax[0].set_xlabel("tree level of the word"); ax[0].set_ylabel("words"); ax[0].set_title("where the leaves are")
ax[1].hist(voc.idf, bins=40)
ax[1].set_xlabel("idf = log(N / N_i)"); ax[1].set_title("word weights")
plt.show()

# %% [markdown]
# ## 2. Keyframes of a synthetic loop
#
# The synthetic `loop` preset walks the camera around the office and back to its start. We
# take every few frames as a keyframe, extract ORB features, keep the **static** ones (the
# renderer's instance masks tell us which keypoints lie on people: people must not make two
# places look alike) and compute each keyframe's bag-of-words vector.

# %%
N_FRAMES, STRIDE = 90, 3
seq = TumSequence(synthetic_sequence("loop", N_FRAMES, 0), stride=STRIDE)
orb = OrbConfig(n_features=1000)
kfs = []
for fr in seq:
    feats = extract_features(fr.gray, orb)
    dyn = fr.dynamic_mask()
    ui = np.clip(np.round(feats.uv[:, 0]).astype(int), 0, fr.shape[1] - 1)
    vi = np.clip(np.round(feats.uv[:, 1]).astype(int), 0, fr.shape[0] - 1)
    static = np.ones(len(feats), bool) if dyn is None else ~dyn[vi, ui]
    z = keypoint_depths(fr.depth, feats.uv, 0.1, 8.0)
    pts = fr.camera.backproject(feats.uv.astype(float), z)
    kfs.append(dict(frame=fr, feats=feats.select(static), pts=pts[static], T_gt=fr.T_w_c_gt))
bows = [voc.bow(k["feats"].descriptors) for k in kfs]
print(f"{len(kfs)} keyframes, {np.mean([len(k['feats']) for k in kfs]):.0f} static features each, "
      f"{np.mean([len(b) for b in bows]):.0f} words each")

# %% [markdown]
# The L1 score $s(v_1, v_2) = 1 - \tfrac12 \lVert v_1 - v_2 \rVert_1 = \sum_i \min(v_1^i, v_2^i)$
# of every pair of keyframes. Neighbours in time score high (the diagonal band); the loop shows
# as a bright spot far from the diagonal, where the camera sees the start again.

# %%
S = bow_score_many(bows, voc.n_words)
np.fill_diagonal(S, np.nan)
fig, ax = plt.subplots(figsize=(5.5, 4.6))
im = ax.imshow(S, cmap="magma")
ax.set_xlabel("keyframe"); ax.set_ylabel("keyframe"); ax.set_title("BoW similarity")
fig.colorbar(im, ax=ax, fraction=0.046)
plt.show()

# %% [markdown]
# ### Querying the database
#
# The keyframe database keeps an **inverted index** (word → keyframes containing it). A query
# scores only the keyframes that share words with it. ORB-SLAM2 then drops keyframes that are
# covisible with the query (here: the `exclude` nearest in time) and keyframes scoring below the
# query's lowest score to its covisible neighbours. Move the slider to query different keyframes.

# %%
db = KeyframeDatabase(voc.n_words)
for i, b in enumerate(bows):
    db.add(i, b)


def query(kf=len(bows) - 1, exclude=6):
    near = set(range(kf - exclude, kf + exclude + 1))
    ids, common, score = db.scores(bows[kf])
    keep = ~np.isin(ids, list(near))
    fig, ax = plt.subplots(figsize=(9, 2.8))
    ax.bar(ids[keep], score[keep], color="tab:blue", label="candidates")
    ax.bar(ids[~keep], score[~keep], color="lightgray", label="covisible (excluded)")
    ax.set_xlabel("keyframe"); ax.set_ylabel("score"); ax.set_title(f"scores of keyframe {kf}"); ax.legend()
    plt.show()


display(widgets.interactive(query, kf=widgets.IntSlider(value=len(bows) - 1, min=0, max=len(bows) - 1),
                            exclude=widgets.IntSlider(value=6, min=1, max=20)))

# %% [markdown]
# ## 3. A detected loop, verified
#
# The last keyframe's best candidate far enough in time is checked geometrically: descriptor
# matches (Hamming $\le 50$, ratio 0.75), then RANSAC over 3-point samples of the matched 3D
# points (from depth) for the rigid transform $X_q = R X_c + t$. A match is an inlier when it
# lands within $0.02 + 0.02 z$ metres. Green lines are inliers, red ones outliers.

# %%
q = len(kfs) - 1
ids, common, score = db.scores(bows[q])
far = ids < q - 10
cand = int(ids[far][np.argmax(score[far])])
cfg = LoopClosingConfig()


def verify(cfg):
    a, b = kfs[q], kfs[cand]
    return verify_loop(a["feats"].descriptors, a["pts"], b["feats"].descriptors, b["pts"], cfg,
                       angle_q=a["feats"].angle, angle_c=b["feats"].angle, rng=0)


def draw(inlier_abs=cfg.inlier_abs, inlier_rel=cfg.inlier_rel, match_ratio=cfg.match_ratio):
    c = dataclasses.replace(cfg, inlier_abs=inlier_abs, inlier_rel=inlier_rel, match_ratio=match_ratio)
    v = verify(c)
    a, b = kfs[q], kfs[cand]
    img = np.hstack([a["frame"].rgb, b["frame"].rgb])
    fig, ax = plt.subplots(figsize=(12, 4.5))
    ax.imshow(img)
    w = a["frame"].rgb.shape[1]
    ua, ub = a["feats"].uv[v.idx_q], b["feats"].uv[v.idx_c]
    for p, r, ok in zip(ua, ub, v.inliers):
        ax.plot([p[0], r[0] + w], [p[1], r[1]], "-", color="lime" if ok else "red", lw=0.6, alpha=0.8)
    ax.axis("off")
    ax.set_title(f"keyframe {q} vs {cand}: {v.n_matches} matches, {v.n_inliers} inliers -> "
                 f"{'loop accepted' if v.accepted else 'rejected'}")
    plt.show()


display(widgets.interactive(draw, inlier_abs=widgets.FloatSlider(value=cfg.inlier_abs, min=0.0, max=0.1, step=0.005),
                            inlier_rel=widgets.FloatSlider(value=cfg.inlier_rel, min=0.0, max=0.1, step=0.005),
                            match_ratio=widgets.FloatSlider(value=cfg.match_ratio, min=0.5, max=1.0, step=0.05)))
ver = verify(cfg)
T_true = relative_pose(kfs[q]["T_gt"], kfs[cand]["T_gt"])
print(f"verified T_q_c: translation error {np.linalg.norm(ver.T_q_c[:3, 3] - T_true[:3, 3]) * 100:.1f} cm against ground truth")

# %% [markdown]
# ## 4. Pose graph optimisation
#
# To see the correction without running the whole system, we make a drifting odometry from the
# ground-truth relative poses with a small error per keyframe: a steady turn (yaw bias, the
# typical drift of visual odometry) plus random noise. The pose graph has one edge per consecutive pair (the odometry) and one loop
# edge with the verified relative pose. Minimising
# $\sum w_{ij} \lVert \log(Z_{ij}^{-1} T_i^{-1} T_j)^\vee \rVert^2$ with the first keyframe fixed
# bends the trajectory back onto itself. The sliders set the drift per keyframe.

# %%
T_gt = np.stack([k["T_gt"] for k in kfs])


def drift_and_close(yaw_bias_deg=0.6, rot_deg=0.2, trans_cm=0.5, seed=0):
    rng = np.random.default_rng(seed)
    T = [T_gt[0]]
    Z = []
    for k in range(1, len(T_gt)):
        # camera y points down in the synthetic office: a rotation about it is a yaw
        rot = rng.normal(0, np.radians(rot_deg), 3) + [0.0, np.radians(yaw_bias_deg), 0.0]
        err = make_pose(so3_exp(rot), rng.normal(0, trans_cm / 100, 3))
        Z.append(relative_pose(T_gt[k - 1], T_gt[k]) @ err)
        T.append(T[-1] @ Z[-1])
    T = np.stack(T)
    edges = np.array([[k - 1, k] for k in range(1, len(T))] + [[cand, q]])
    meas = np.stack(Z + [se3_inv(ver.T_q_c)])
    res = optimize_pose_graph(T, edges, meas, fixed=[0])
    return T, res.poses


def ate(T):
    a = umeyama_alignment(T[:, :3, 3], T_gt[:, :3, 3])
    return float(np.sqrt(np.mean(np.sum((a.apply(T[:, :3, 3]) - T_gt[:, :3, 3]) ** 2, axis=1))))


def show_graph(yaw_bias_deg=0.6, rot_deg=0.2, trans_cm=0.5):
    before, after = drift_and_close(yaw_bias_deg, rot_deg, trans_cm)
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    ax.plot(T_gt[:, 0, 3], T_gt[:, 1, 3], "k-", lw=2, label="ground truth")
    ax.plot(before[:, 0, 3], before[:, 1, 3], "r.-", label=f"drifting odometry (ATE {ate(before) * 100:.1f} cm)")
    ax.plot(after[:, 0, 3], after[:, 1, 3], "g.-", label=f"after pose graph (ATE {ate(after) * 100:.1f} cm)")
    ax.plot(after[[cand, q], 0, 3], after[[cand, q], 1, 3], "b-", lw=3, label="loop edge")
    ax.set_aspect("equal"); ax.set_xlabel("x (m)"); ax.set_ylabel("y (m)"); ax.legend(fontsize=8)
    ax.set_title("keyframe positions, top view")
    plt.show()


display(widgets.interactive(show_graph, yaw_bias_deg=widgets.FloatSlider(value=0.6, min=0.0, max=2.0, step=0.1),
                            rot_deg=widgets.FloatSlider(value=0.2, min=0.0, max=1.0, step=0.1),
                            trans_cm=widgets.FloatSlider(value=0.5, min=0.0, max=3.0, step=0.5)))
before, after = drift_and_close()
print(f"ATE before {ate(before) * 100:.1f} cm, after {ate(after) * 100:.1f} cm")

# %% [markdown]
# ## In the full system
#
# `dynslam run SEQDIR --out OUT` runs the same steps inside the SLAM system (`LoopCloser`):
# candidates from the keyframe database with covisibility groups, the consistency check over
# three keyframes, verification, then the pose graph over the *essential graph* (spanning tree,
# strong covisibility edges, loop edges) and the correction of every map point. `summary.json`
# counts the loops and `keyframes.npz` lists the loop edges; `--no-loop` turns loop closing off
# to compare.
