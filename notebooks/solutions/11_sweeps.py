# %% [markdown]
# # Solutions of notebook 11 · Parameter sweeps

# %% exercise="11.1"
answer = np.geomspace(0.25, 4.0, 5).tolist()  # start * (stop / start) ** (i / (num - 1))

# %% exercise="11.2"
sums = table.groupby(["sequence", THR])[["keypoints.tp", "keypoints.fp"]].sum()
flagged = sums["keypoints.tp"] + sums["keypoints.fp"]
answer = sums["keypoints.tp"] / flagged.where(flagged > 0)

# %% exercise="11.3"
# walking_xyz gets 3 seeds, walking_static keeps 2, and 4 values of the threshold: (3 + 2) x 4 = 20 runs.
# The 12 runs of the first spec keep their names (nothing that decides them changed): they are finished.
answer = ((3 + 2) * 4, (2 + 2) * 3)
