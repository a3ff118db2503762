"""ipywidgets helpers: sliders that redraw a matplotlib figure.

A notebook stage is a pure function of its parameters (a frozen config dataclass); a
slider changes one field with ``dataclasses.replace`` and the figure is drawn again. This
module wires that up once::

    def draw(voxel_size, std_ratio):
        cfg = dataclasses.replace(base, voxel_size=voxel_size, sor_std_ratio=std_ratio)
        return plot_map(build(cfg))                 # returns a matplotlib Figure

    ui = figure_explorer(draw, voxel_size=float_slider("voxel [m]", 0.02, 0.005, 0.1, 0.005),
                         std_ratio=float_slider("alpha", 2.0, 0.5, 4.0, 0.25))
    display(ui)

The controls sit above an ``Output`` area; each change clears it and shows the new figure
(closed after display so figures do not pile up). :func:`figure_explorer` draws once at
creation, so a headless run (CI) executes ``draw`` with the defaults.
"""

from __future__ import annotations

from typing import Callable

__all__ = ["float_slider", "int_slider", "figure_explorer"]


def float_slider(description: str, value: float, min: float, max: float, step: float, readout_format: str = ".3g"):
    """A continuous slider (``ipywidgets.FloatSlider``) that updates when released."""
    import ipywidgets as widgets

    if not min <= value <= max:
        raise ValueError(f"float_slider {description!r}: value {value} outside [{min}, {max}]")
    return widgets.FloatSlider(value=value, min=min, max=max, step=step, description=description,
                               continuous_update=False, readout_format=readout_format,
                               style={"description_width": "initial"})


def int_slider(description: str, value: int, min: int, max: int, step: int = 1):
    """An integer slider (``ipywidgets.IntSlider``) that updates when released."""
    import ipywidgets as widgets

    if not min <= value <= max:
        raise ValueError(f"int_slider {description!r}: value {value} outside [{min}, {max}]")
    return widgets.IntSlider(value=value, min=min, max=max, step=step, description=description,
                             continuous_update=False, style={"description_width": "initial"})


def figure_explorer(draw: Callable[..., object], **controls):
    """Controls above a figure that ``draw(**values)`` redraws whenever a control changes.

    Parameters
    ----------
    draw : function of the controls' values returning a matplotlib Figure (or None if it
        displays by itself).
    **controls : name -> ipywidget (``float_slider``, ``int_slider``, a dropdown ...); the
        names are ``draw``'s keyword arguments.

    Returns
    -------
    ``ipywidgets.VBox`` of the controls and the output area; its ``.redraw()`` attribute
    draws again with the current values (what a change does), for scripts and tests.
    """
    import ipywidgets as widgets
    import matplotlib.pyplot as plt
    from IPython.display import display

    if not controls:
        raise ValueError("figure_explorer needs at least one control")
    out = widgets.Output()

    def redraw(**values):
        out.clear_output(wait=True)
        with out:
            fig = draw(**values)
            if fig is not None:
                display(fig)
                plt.close(fig)

    link = widgets.interactive_output(redraw, controls)
    box = widgets.VBox([widgets.HBox(list(controls.values()), layout=widgets.Layout(flex_flow="row wrap")), out, link])
    box.redraw = lambda: redraw(**{k: w.value for k, w in controls.items()})  # type: ignore[attr-defined]
    box.output = out  # type: ignore[attr-defined]
    return box
