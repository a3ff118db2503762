# %% [markdown]
# # Solutions of notebook 10 · When screening fails

# %% exercise="10.1"
moving = np.isin(frame.instance_mask, sorted(frame.moving_ids or ()))  # pixels of instances moving in frame 7
answer = float(moving.mean())

# %% exercise="10.2"
z_p, z_j = 3.5, 3.65
tau = max(0.1, 0.01 * z_p**2)  # 0.1225 m: beyond sqrt(0.1 / 0.01) = 3.16 m the quadratic term decides
answer = z_j - z_p - tau  # +0.0275 m: the earlier frame saw through the point

# %% exercise="10.3"
row = df[(df["filter"] == "geometry") & (df["sequence"] == "cart_static")].iloc[0]
answer = row["tp"] / (row["tp"] + row["fp"])
