"""The slider registry: a control that changes the data is seen to act, one that changes only a
title is not; default probe values; the static first rendering."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ipywidgets")
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from dynslam_lab.viz import widgets as W  # noqa: E402


def _line(slope=1.0, label="x"):
    fig, ax = plt.subplots(figsize=(3, 2))
    ax.plot([0, 1], [0, slope])
    ax.set_ylim(-3, 3)
    ax.set_title(f"slope {slope} {label}")
    return fig


@pytest.fixture(autouse=True)
def _clean_registry():
    W.REGISTRY.clear()
    yield
    W.REGISTRY.clear()
    plt.close("all")


def test_a_control_that_moves_the_data_differs_and_a_title_only_control_does_not():
    W.figure_explorer(_line, name="acts", show=False, slope=W.float_slider("slope", 1.0, -2.0, 2.0, 0.5),
                      label=W.dropdown("label", ["x", "y", "z"], "x"))
    rows = {r["control"]: r for r in W.check_explorers()}
    assert rows["slope"]["differs"] == [True, True] and rows["slope"]["probes"] == [-2.0, 2.0]
    assert rows["label"]["differs"] == [False, False], "a title change is not a change of the figure"
    assert rows["label"]["probes"] == ["y", "z"]


def test_figure_pixels_hides_text_and_sees_one_changed_marker():
    def dots(k=0):
        fig, ax = plt.subplots(figsize=(3, 2))
        c = np.array(["g"] * 5, dtype=object)
        c[k] = "r"
        ax.scatter(np.arange(5), np.zeros(5), c=list(c), s=30)
        ax.set_title(f"k = {k}")
        return fig

    a, b = W.figure_pixels(dots(0)), W.figure_pixels(dots(3))
    assert a.shape == b.shape and a.dtype == np.uint8
    changed = np.any(a != b, axis=-1).sum()
    assert 10 < changed < 0.05 * a.shape[0] * a.shape[1]
    same = np.any(W.figure_pixels(dots(2)) != W.figure_pixels(dots(2)), axis=-1).sum()
    assert same == 0


def test_default_probes():
    s = W.int_slider("n", 0, 0, 10)
    assert W._default_probes(s, 0) == [10, 5]
    log = W.log_slider("mu", 1.0, -1, 1)
    assert np.allclose(W._default_probes(log, 1.0), [0.1, 10.0])
    assert W._default_probes(W.checkbox("on", True), True) == [False]


def test_probes_must_differ_from_the_start_and_name_known_controls():
    with pytest.raises(ValueError, match="differ from its start"):
        W.figure_explorer(_line, show=False, probes={"slope": [1.0, 2.0]}, slope=W.float_slider("s", 1.0, 0, 2, 0.5))
    with pytest.raises(ValueError, match="unknown controls"):
        W.figure_explorer(_line, show=False, probes={"nope": [1]}, slope=W.float_slider("s", 1.0, 0, 2, 0.5))


def test_draw_must_return_a_figure():
    W.figure_explorer(lambda a=1: None, name="none", show=False, a=W.int_slider("a", 1, 0, 2))
    (row,) = W.check_explorers()
    assert row["error"].startswith("TypeError")


def test_static_first_rendering_is_a_plain_image_output(monkeypatch):
    shown = []
    monkeypatch.setattr("IPython.display.display", lambda obj, **kw: shown.append(obj))
    ex = W.figure_explorer(_line, name="shown", slope=W.float_slider("slope", 1.0, -2.0, 2.0, 0.5))
    assert hasattr(shown[0], "savefig"), "the first thing shown is the figure itself (plain output)"
    assert shown[1] is ex.widget
    ex.controls["slope"].value = 2.0  # a move redraws into the widget's output area
    assert len(ex.widget.children[1].outputs) <= 1
