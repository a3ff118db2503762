# %% [markdown]
# # Solutions of notebook 05 · Geometry against motion

# %% exercise="05.1"
i = np.flatnonzero(matched)[0]
a, b, c = ep.F @ np.array([uv_prev[i, 0], uv_prev[i, 1], 1.0])
answer = abs(a * uv[i, 0] + b * uv[i, 1] + c) / np.hypot(a, b)

# %% exercise="05.2"
e, m = checks(1.0, 4.0, 0.1)
answer = int(((e.dynamic != m.dynamic) & matched).sum())

# %% exercise="05.3"
cfg = FlowConfig()
fr = flow_regions(cur.gray, prev.gray, person, cur.depth, cur.camera, mv.T_c_p, cfg)
answer = max(cfg.factor * fr.mean_flow_px, cfg.min_flow_px)
