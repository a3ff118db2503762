# %% [markdown]
# # Solutions of notebook 01 · Data and cameras

# %% exercise="01.1"
cam = frame.camera
z = float(frame.depth[300, 400])
answer = z * np.array([(400 - cam.cx) / cam.fx, (300 - cam.cy) / cam.fy, 1.0])

# %% exercise="01.2"
answer = len(associate(rgb_ts, depth_ts, max_diff=0.005))

# %% exercise="01.3"
X_w = np.array([0.5, 0.8, 0.9])
R, t = T[:3, :3], T[:3, 3]
x, y, z = R.T @ (X_w - t)
cam = frame.camera
answer = np.array([cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy])
