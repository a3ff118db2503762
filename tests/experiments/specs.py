"""The tiny sweep of the tests: 2 seeds of an 8-frame preset x 2 epipolar thresholds (the sequences of
notebooks/11_sweeps.py too: one cache entry each)."""

TINY = """
[sweep]
name = "tiny"
filters = ["geometry"]
loop_closing = false

[[sequences]]
preset = "walking_xyz"
n_frames = 8
seeds = [0, 1]

[grid]
"screening.epipolar.threshold_px" = [0.5, 2.0]
"""
