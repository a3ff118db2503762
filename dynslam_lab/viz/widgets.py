"""Sliders that redraw a matplotlib figure, and a registry that tests can drive.

A notebook stage is a pure function of its parameters (a frozen config dataclass); a slider
changes one field with ``dataclasses.replace`` and the figure is drawn again::

    def draw(voxel_size=0.02, std_ratio=2.0):
        cfg = dataclasses.replace(base, voxel_size=voxel_size, sor_std_ratio=std_ratio)
        return plot_map(build(cfg))                 # returns a matplotlib Figure

    figure_explorer(draw, name="09 dense-map filters",
                    voxel_size=float_slider("voxel [m]", 0.02, 0.005, 0.1, 0.005),
                    std_ratio=float_slider("alpha", 2.0, 0.5, 4.0, 0.25))

:func:`figure_explorer` shows, in this order:

1. the figure at the controls' start values as a plain output (the *static first
   rendering*: it stays in a saved notebook and in an HTML export, where widgets do not);
2. the controls;
3. an output area where the figure is drawn again whenever a control moves.

Every explorer is recorded in :data:`REGISTRY` under its name. :func:`check_explorers` calls
each one's ``draw`` at its start values and, control by control, at two other values, and
reports whether the picture changed (text hidden, so a title that prints the value does not
count): the notebook test runs it in the kernel after the last cell, so a slider that does
nothing at its start values fails CI.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

__all__ = [
    "float_slider",
    "int_slider",
    "log_slider",
    "dropdown",
    "checkbox",
    "figure_explorer",
    "Explorer",
    "REGISTRY",
    "figure_pixels",
    "check_explorers",
]

_STYLE = {"description_width": "initial"}


def float_slider(description: str, value: float, min: float, max: float, step: float, readout_format: str = ".3g"):
    """A continuous slider (``ipywidgets.FloatSlider``) that updates when released."""
    import ipywidgets as widgets  # optional heavy dependency (only where sliders are drawn)

    if not min <= value <= max:
        raise ValueError(f"float_slider {description!r}: value {value} outside [{min}, {max}]")
    return widgets.FloatSlider(value=value, min=min, max=max, step=step, description=description,
                               continuous_update=False, readout_format=readout_format, style=_STYLE)


def log_slider(description: str, value: float, min_exp: float, max_exp: float, step: float = 0.05,
               readout_format: str = ".3g"):
    """A slider over ``10**min_exp .. 10**max_exp`` on a log scale (``ipywidgets.FloatLogSlider``)."""
    import ipywidgets as widgets  # optional heavy dependency

    if not 10**min_exp <= value <= 10**max_exp:
        raise ValueError(f"log_slider {description!r}: value {value} outside [1e{min_exp}, 1e{max_exp}]")
    return widgets.FloatLogSlider(value=value, base=10, min=min_exp, max=max_exp, step=step, description=description,
                                  continuous_update=False, readout_format=readout_format, style=_STYLE)


def int_slider(description: str, value: int, min: int, max: int, step: int = 1):
    """An integer slider (``ipywidgets.IntSlider``) that updates when released."""
    import ipywidgets as widgets  # optional heavy dependency

    if not min <= value <= max:
        raise ValueError(f"int_slider {description!r}: value {value} outside [{min}, {max}]")
    return widgets.IntSlider(value=value, min=min, max=max, step=step, description=description,
                             continuous_update=False, style=_STYLE)


def dropdown(description: str, options: Sequence, value):
    """A drop-down list (``ipywidgets.Dropdown``)."""
    import ipywidgets as widgets  # optional heavy dependency

    if value not in list(options):
        raise ValueError(f"dropdown {description!r}: value {value!r} not among {list(options)}")
    return widgets.Dropdown(options=list(options), value=value, description=description, style=_STYLE)


def checkbox(description: str, value: bool):
    """A check box (``ipywidgets.Checkbox``)."""
    import ipywidgets as widgets  # optional heavy dependency

    return widgets.Checkbox(value=bool(value), description=description, indent=False)


@dataclass
class Explorer:
    """A figure and the controls that redraw it (what :func:`figure_explorer` records).

    Attributes
    ----------
    name : registry key (notebook number and what the figure shows).
    draw : ``draw(**values) -> matplotlib Figure``.
    controls : keyword -> ipywidget.
    start : keyword -> the value each control starts at.
    probes : keyword -> the other values :func:`check_explorers` tries (two per control
        unless the control has fewer, e.g. a check box).
    widget : the ``ipywidgets.VBox`` shown (controls and live output), None headless.
    """

    name: str
    draw: Callable[..., Any]
    controls: dict[str, Any]
    start: dict[str, Any]
    probes: dict[str, list] = field(default_factory=dict)
    widget: Any = None

    def __repr__(self) -> str:
        return f"Explorer({self.name!r}, controls={list(self.controls)})"

    def figure(self, **changes):
        """The figure at the start values with ``changes`` applied (a new Figure; close it)."""
        values = {**self.start, **changes}
        fig = self.draw(**values)
        if fig is None or not hasattr(fig, "savefig"):
            raise TypeError(f"explorer {self.name!r}: draw() must return a matplotlib Figure, got {type(fig).__name__}")
        return fig


#: name -> :class:`Explorer`, filled by :func:`figure_explorer` (a re-run cell replaces its entry).
REGISTRY: dict[str, Explorer] = {}


def _default_probes(widget, start) -> list:
    """Two values other than ``start`` from a control's range: its ends, or the first
    options that differ for a drop-down, or the other state of a check box."""
    if hasattr(widget, "options"):  # Dropdown, ToggleButtons ...
        values = [v[1] if isinstance(v, tuple) else v for v in widget.options]
        return [v for v in values if v != start][:2]
    if isinstance(start, bool):
        return [not start]
    lo, hi = widget.min, widget.max
    if type(widget).__name__ == "FloatLogSlider":
        lo, hi = widget.base**lo, widget.base**hi
    others = [v for v in (lo, hi) if v != start]
    if len(others) < 2:  # the start is an end: the other end and the middle
        mid = (lo + hi) / 2
        mid = int(round(mid)) if isinstance(start, (int, np.integer)) else mid
        others = [v for v in (others + [mid]) if v != start]
    return others[:2]


def figure_explorer(draw: Callable[..., Any], name: str | None = None, probes: dict[str, Sequence] | None = None,
                    show: bool = True, **controls) -> Explorer:
    """Show a figure at the controls' start values, the controls, and a live redraw.

    Parameters
    ----------
    draw : function of the controls' values (keyword arguments) returning a matplotlib Figure.
    name : registry key (default: ``draw``'s name); use the notebook number and the subject.
    probes : keyword -> values other than the start that :func:`check_explorers` tries
        (default: two from the control's range, see :func:`_default_probes`); choose values
        where the figure must differ.
    show : display the static figure and the widget (False: register only, for tests).
    **controls : keyword -> ipywidget (``float_slider``, ``int_slider``, ``dropdown`` ...); the
        keywords are ``draw``'s arguments.

    Returns
    -------
    :class:`Explorer` (also in :data:`REGISTRY`); ``explorer.widget`` is the ``VBox`` shown.
    """
    if not controls:
        raise ValueError("figure_explorer needs at least one control")
    start = {k: w.value for k, w in controls.items()}
    given = {k: list(v) for k, v in (probes or {}).items()}
    unknown = set(given) - set(controls)
    if unknown:
        raise ValueError(f"figure_explorer: probes for unknown controls {sorted(unknown)}")
    for k, vals in given.items():
        if start[k] in vals:
            raise ValueError(f"figure_explorer: probe values of {k!r} must differ from its start value {start[k]!r}")
    explorer = Explorer(name=name or draw.__name__, draw=draw, controls=dict(controls), start=start,
                        probes={k: given.get(k) or _default_probes(w, start[k]) for k, w in controls.items()})
    REGISTRY[explorer.name] = explorer
    if not show:
        return explorer

    import ipywidgets as widgets  # optional heavy dependency
    import matplotlib.pyplot as plt  # heavy: imported on use
    from IPython.display import display  # optional: a notebook kernel's

    fig = explorer.figure()
    display(fig)  # the static first rendering: a plain image output
    plt.close(fig)
    out = widgets.Output()

    def redraw(_change=None) -> None:
        values = {k: w.value for k, w in controls.items()}
        with out:
            out.clear_output(wait=True)
            f = draw(**values)
            display(f)
            plt.close(f)

    for w in controls.values():
        w.observe(redraw, names="value")
    explorer.widget = widgets.VBox([widgets.HBox(list(controls.values()), layout=widgets.Layout(flex_flow="row wrap")),
                                    out])
    explorer.widget.redraw = redraw  # type: ignore[attr-defined]
    display(explorer.widget)
    return explorer


def figure_pixels(fig, hide_text: bool = True) -> np.ndarray:
    """The figure rendered to an ``(H, W, 4)`` uint8 array (Agg), with all text hidden.

    Titles, labels, tick labels, legends and annotations are hidden first, so two figures
    compare equal exactly when they draw the same data (a title printing a slider's value
    does not make a difference).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # heavy: imported on use
    from matplotlib.legend import Legend
    from matplotlib.text import Text

    if hide_text:
        for artist in fig.findobj(lambda a: isinstance(a, (Text, Legend))):
            artist.set_visible(False)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba()).copy()


def _differs(a: np.ndarray, b: np.ndarray, min_pixels: int) -> tuple[bool, int]:
    if a.shape != b.shape:
        return True, -1
    n = int(np.any(a != b, axis=-1).sum())
    return n >= min_pixels, n


def check_explorers(names: Sequence[str] | None = None, min_pixels: int = 10) -> list[dict]:
    """For every registered explorer and control: does the figure change when the control
    leaves its start value?

    Each explorer is drawn at its start values, then once per probe value of each control
    (the other controls at their start values); a probe *differs* when at least
    ``min_pixels`` pixels change with all text hidden (:func:`figure_pixels`).

    Returns
    -------
    one dict per control: ``explorer``, ``control``, ``start``, ``probes``, ``differs``
    (one bool per probe), ``changed_pixels``, ``error`` (a message, or None).
    """
    import matplotlib.pyplot as plt  # heavy: imported on use

    rows = []
    for name in names if names is not None else list(REGISTRY):
        ex = REGISTRY[name]
        try:
            fig = ex.figure()
            base = figure_pixels(fig)
            plt.close(fig)
        except Exception as exc:  # reported per explorer, so one broken figure does not hide the others
            rows.append({"explorer": name, "control": None, "start": None, "probes": [], "differs": [],
                         "changed_pixels": [], "error": f"{type(exc).__name__}: {exc}"})
            continue
        for key, values in ex.probes.items():
            row = {"explorer": name, "control": key, "start": _plain(ex.start[key]), "probes": [_plain(v) for v in values],
                   "differs": [], "changed_pixels": [], "error": None}
            try:
                for v in values:
                    fig = ex.figure(**{key: v})
                    d, n = _differs(base, figure_pixels(fig), min_pixels)
                    plt.close(fig)
                    row["differs"].append(d)
                    row["changed_pixels"].append(n)
            except Exception as exc:
                row["error"] = f"{type(exc).__name__}: {exc}"
            rows.append(row)
    return rows


def _plain(v):
    """A JSON-friendly form of a control value."""
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    return v if isinstance(v, (int, float, str, bool)) or v is None else repr(v)
