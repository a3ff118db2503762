# %% [markdown]
# # Solutions of notebook 09 · Maps and 3D views

# %% exercise="09.1"
answer = len(np.unique(np.floor(xyz0 / 0.05).astype(np.int64), axis=0))

# %% exercise="09.2"
L = 3 * np.log(0.7 / 0.3)  # below the clamp logit(0.97) = 3.48
answer = 1 / (1 + np.exp(-L))

# %% exercise="09.3"
answer = map_quality(maps["without masks or filters"].xyz, views).dynamic_fraction
