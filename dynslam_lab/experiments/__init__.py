"""Experiments over whole runs: scores against the synthetic truth and the ablation tables.

This layer sits above the pipeline: it runs :func:`dynslam_lab.pipeline.build_pipeline`
systems over sequences and gathers their numbers (the papers' component tables).
"""
