# %% [markdown]
# # Solutions of notebook 00 · Quickstart
#
# Each cell replaces the exercise cell with the same id (`exercise="..."`) in
# `notebooks/00_quickstart.py`.

# %% exercise="00.1"
d = ate["none"].est_positions - ate["none"].gt_positions
answer = float(np.sqrt(np.mean(np.sum(d**2, axis=1))))

# %% exercise="00.2"
answer = float(ate["none"].timestamps[np.argmax(ate["none"].errors)])

# %% exercise="00.3"
# The estimate's world is the first camera (position 0, z forward, y down); the ground truth's
# is the room (z up), with the first camera about a metre from its origin: without alignment
# the error measures the distance between the two frames, not the tracking.
answer = compute_ate(seq.groundtruth, raw["none"], align="none").stats.rmse
