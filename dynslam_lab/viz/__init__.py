"""Views of a run: matplotlib figures (``plots``), ipywidgets helpers (``widgets``) and the
viser 3D scene (``viser_scene``, what ``dynslam view`` serves). See ``docs/views.md``.

Submodules are imported on use (``from dynslam_lab.viz.plots import plot_trajectories``)
so that importing the package does not pull in matplotlib, ipywidgets or viser.
"""
