# %% [markdown]
# # Solutions of notebook 06 · Motion probabilities

# %% exercise="06.1"
answer = (~on_object).sum() / len(on_object)

# %% exercise="06.2"
# m + r >= 0.5 n  ->  r = ceil(0.5 n - m)
answer = int(np.ceil(0.5 * len(uv) - (~on_object).sum()))

# %% exercise="06.3"
# After the 0.2 group delta is 0.72 < 0.8, so the next group (the people, p = 0.9) comes back too.
answer = [0.2, 0.9]
