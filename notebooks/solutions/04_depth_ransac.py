# %% [markdown]
# # Solutions of notebook 04 · Depth-RANSAC

# %% exercise="04.1"
answer = np.log(1 - 0.99) / np.log(1 - 0.6**2)

# %% exercise="04.2"
x = np.array([1.00, 1.10, 1.45])
answer = float(np.mean((x - x.mean()) ** 2))
# 0.0372 m^2 > 0.43 * 0.2**2 = 0.0172 m^2: not an inlier

# %% exercise="04.3"
answer = None
for v in np.geomspace(0.01, 10, 31):
    cfg = dataclasses.replace(DepthRansacConfig(), var_threshold=v, select="front")
    dyn, _ = screen_boxes(uv, z, people.boxes, cfg, rng=0, depth_image=frame.depth)
    if score_keypoints(dyn, truth).recall >= 0.9:
        answer = v
        break
