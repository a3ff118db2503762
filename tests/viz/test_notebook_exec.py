"""The headless notebook runner: inline figures are counted, errors and timeouts name the
cell, a widget cell does not make the next cell idle, solutions replace exercises."""

from __future__ import annotations

import time

import pytest

pytest.importorskip("jupyter_client")
jupytext = pytest.importorskip("jupytext")

from dynslam_lab.viz.notebook_exec import (  # noqa: E402
    CellError,
    CellTimeout,
    KernelSession,
    count_images,
    execute_notebook,
    sections,
    substitute_solutions,
)

SOURCE = '''# %% [markdown]
# # T

# %% figures=2
import matplotlib.pyplot as plt
plt.plot([1, 2]); plt.show()
fig, ax = plt.subplots(); ax.plot([2, 1])

# %% [markdown]
# ## Widgets

# %%
import ipywidgets as w
from IPython.display import display
display(w.IntSlider(3))

# %%
print("after the widget")

# %% exercise="1"
answer = None

# %% check="1"
print("answer", answer)
'''


@pytest.fixture(scope="module")
def nb_path(tmp_path_factory):
    p = tmp_path_factory.mktemp("nb") / "t.py"
    p.write_text(SOURCE)
    return p


@pytest.mark.slow
def test_inline_figures_are_counted_and_widget_cells_do_not_idle(nb_path):
    nb = jupytext.read(nb_path)
    t0 = time.monotonic()
    nb, extra = execute_notebook(nb, cwd=nb_path.parent, timeout_per_cell=60, after=[("x", "print(1 + 1)")])
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert count_images(code[0]) == 2, "plt.show() and the figure left open at the end of the cell (inline backend)"
    assert count_images(code[1]) == 0
    assert code[2].outputs[0]["text"] == "after the widget\n"
    assert extra["x"].stdout == "2\n"
    # the cells after the widget did not wait: far below one cell timeout
    assert max(nb.metadata["dynslam_seconds"][1:]) < 10
    assert time.monotonic() - t0 < 60
    assert [t for t, _ in sections(nb)] == ["", "Widgets"]


@pytest.mark.slow
def test_errors_and_timeouts_name_the_cell(tmp_path):
    with KernelSession(tmp_path) as k:
        with pytest.raises(CellError, match=r"cell 7 raised ZeroDivisionError"):
            k.run("1 / 0", 30, label="cell 7")
        t0 = time.monotonic()
        with pytest.raises(CellTimeout, match="still running after 2 s"):
            k.run("import time; time.sleep(30)", 2, label="slow")
        assert time.monotonic() - t0 < 10
        assert k.run("print('alive')", 30).stdout == "alive\n", "the kernel was interrupted, not killed"


class _AbortingKernel:
    """A stand-in for a kernel client whose first ``aborts`` execute requests are aborted unexecuted
    (ipykernel's reply ``status: aborted``, no output), as after an error when a request wins the race
    against the kernel's "stop aborting" message; later requests print ``alive``."""

    def __init__(self, aborts: int):
        from queue import Queue

        self.aborts, self.sent = aborts, []
        self.iopub, self.shell = Queue(), Queue()

    def execute(self, code, **kwargs):
        msg_id = f"m{len(self.sent)}"
        self.sent.append(code)
        parent = {"msg_id": msg_id}
        aborted = len(self.sent) <= self.aborts
        if not aborted:
            self.iopub.put({"msg_type": "stream", "parent_header": parent, "header": {"msg_type": "stream"},
                            "content": {"name": "stdout", "text": "alive\n"}})
        self.iopub.put({"msg_type": "status", "parent_header": parent, "content": {"execution_state": "idle"}})
        self.shell.put({"parent_header": parent, "content": {"status": "aborted" if aborted else "ok"}})
        return msg_id

    def get_iopub_msg(self, timeout=None):
        return self.iopub.get(timeout=timeout)

    def get_shell_msg(self, timeout=None):
        return self.shell.get(timeout=timeout or 0.01)

    def is_alive(self):
        return True


@pytest.mark.parametrize("aborts", [0, 2, 4])
def test_a_request_the_kernel_aborted_is_sent_again(tmp_path, aborts):
    """An aborted reply is no result: the cell is sent again (``abort_retries`` = 3 times at most), and a
    request aborted every time is an error, never an empty output taken for the cell's."""
    k = KernelSession(tmp_path, poll_seconds=0.01)
    k.kc = k.km = _AbortingKernel(aborts)
    if aborts <= k.abort_retries:
        assert k.run("print('alive')", 5).stdout == "alive\n"
        assert len(k.kc.sent) == aborts + 1
    else:
        with pytest.raises(CellError, match="aborted the request 4 times"):
            k.run("print('alive')", 5)
    k.kc = k.km = None


def test_solutions_replace_exercises(nb_path):
    nb = jupytext.read(nb_path)
    sol = jupytext.reads('# %% exercise="1"\nanswer = 42\n', "py:percent")
    assert substitute_solutions(nb, sol) == ["1"]
    assert "answer = 42" in [c.source for c in nb.cells]
    with pytest.raises(ValueError, match="differ"):
        substitute_solutions(jupytext.read(nb_path), jupytext.reads('# %% exercise="2"\nx = 1\n', "py:percent"))
