# %% [markdown]
# # Solutions of notebook 08 · Loop closure

# %% exercise="08.1"
common, i0, i1 = np.intersect1d(bows[0].words, bows[1].words, return_indices=True)
answer = float(np.minimum(bows[0].weights[i0], bows[1].weights[i1]).sum())

# %% exercise="08.2"
answer = voc.n_images / np.exp(voc.idf[int(np.argmin(voc.idf))])

# %% exercise="08.3"
answer = ate(before) / ate(after)
