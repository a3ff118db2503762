# %% [markdown]
# # Solutions of notebook 02 · ORB features and tracking

# %% exercise="02.1"
answer = int(np.unpackbits(feats0.descriptors[0] ^ feats1.descriptors[0]).sum())

# %% exercise="02.2"
N, f, L = 1000, 1.2, 8
q = 1 / f
n = np.round(N * (1 - q) / (1 - q**L) * q ** np.arange(L)).astype(int)
n[-1] = N - n[:-1].sum()
answer = n

# %% exercise="02.3"
T, inl = pnp_ransac(X0, uv1, seq.camera.K, reproj_px=4.0, iterations=200, seed=0)
uv_pred, _ = seq.camera.project(transform_points(T, X0[inl]))
answer = float(np.median(np.linalg.norm(uv_pred - uv1[inl], axis=1)))
