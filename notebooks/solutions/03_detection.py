# %% [markdown]
# # Solutions of notebook 03 · Semantic detection

# %% exercise="03.1"
inter = 5 * 5  # the overlap [5, 5, 10, 10]
answer = inter / (100 + 100 - inter)

# %% exercise="03.2"
iou = (10 - 2) * 10 / (100 + 100 - 80)  # overlap [2, 0, 10, 10] = 80
answer = 0.8 * np.exp(-(iou**2) / 0.5)

# %% exercise="03.3"
half = OracleDetector(DetectionConfig(oracle=OracleConfig(miss_rate=0.5, seed=1)))
n_true = len(OracleDetector().detect(syn))
found = [len(half.detect(dataclasses.replace(syn, index=i))) for i in range(100)]
answer = 1 - np.mean(found) / n_true
