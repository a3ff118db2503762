# %% [markdown]
# # Solutions of notebook 07 · The whole screening chain and its ablation

# %% exercise="07.1"
ate = df.set_index("filter")["ate_rmse_m"]
answer = 100 * (ate["none"] - ate["geometry"]) / ate["none"]

# %% exercise="07.2"
table, _ = screen_frame(4, "full", 1.0, 4.0, 0.7)
truth = truth_dynamic(frames[4], table.uv)
tp = (table.dynamic & truth).sum()
answer = (tp / table.dynamic.sum(), tp / truth.sum())

# %% exercise="07.3"
# geometry: it judges every keypoint by its motion; full looks near the detections, and the
# degraded detector misses most walkers.
answer = df[df["filter"] != "oracle"].set_index("filter")["recall"].idxmax()
