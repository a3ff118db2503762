"""Run a notebook headless, cell by cell, with a deadline per cell that cannot idle.

Used by the notebook test (``tests/test_notebooks.py``) and the HTML gallery
(``docs/gallery/build.py``). Why not ``nbclient``: after a cell that opens widgets, its
wait for the kernel's reply can sit on an already-delivered message until the whole cell
timeout runs out (jupyter/nbclient issue 312). Here every wait is a short poll (at most
``poll_seconds``) of the IOPub and shell channels, repeated until the cell's deadline, so a
missed wake-up costs one poll, never the timeout; widget messages (``comm_*``) are not waited
for at all.

The kernel runs with matplotlib's *inline* backend (as in JupyterLab), so every figure a
cell shows becomes an ``image/png`` output that :func:`count_images` can count.

Cell metadata this module and the test read (jupytext: ``# %% figures=2``):

* ``figures`` - number of images the cell promises;
* ``exercise`` - id of an exercise cell (the reader's answer; ``notebooks/solutions/`` holds
  a cell with the same id that :func:`substitute_solutions` puts in its place);
* ``check`` - id of the exercise this cell checks.
"""

from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from queue import Empty

__all__ = [
    "CellError",
    "CellTimeout",
    "KernelSession",
    "execute_notebook",
    "read_notebook",
    "count_images",
    "sections",
    "substitute_solutions",
    "exercise_cells",
]

_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")


class CellError(RuntimeError):
    """A cell raised; the message names the cell and carries the kernel's traceback."""


class CellTimeout(CellError):
    """A cell ran past its deadline (the kernel is interrupted)."""


def read_notebook(path: str | Path):
    """A jupytext percent ``.py`` (or an ``.ipynb``) as an ``nbformat`` notebook."""
    import jupytext  # optional dependency (the test and notebooks extras)

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such notebook")
    return jupytext.read(p)


def _output_from_msg(msg):
    from nbformat.v4 import output_from_msg  # optional dependency (test and notebooks extras)

    return output_from_msg(msg)


@dataclass
class CellRun:
    """Result of one code cell: its outputs (nbformat) and seconds taken."""

    outputs: list = field(default_factory=list)
    seconds: float = 0.0

    @property
    def stdout(self) -> str:
        return "".join(o.get("text", "") for o in self.outputs if o.get("output_type") == "stream"
                       and o.get("name") == "stdout")


class KernelSession:
    """One IPython kernel (inline matplotlib) running code with per-cell deadlines.

    Use as a context manager; ``run(code, timeout)`` returns a :class:`CellRun` or raises
    :class:`CellError` / :class:`CellTimeout`.
    """

    def __init__(self, cwd: str | Path, env: dict | None = None, kernel_name: str = "python3",
                 poll_seconds: float = 0.25, startup_timeout: float = 120.0, abort_retries: int = 3):
        self.cwd = str(cwd)
        self.poll_seconds = float(poll_seconds)
        self.abort_retries = int(abort_retries)
        self.kernel_name = kernel_name
        self.startup_timeout = startup_timeout
        base = dict(os.environ if env is None else env)
        # the inline backend, as in JupyterLab (MPLBACKEND=Agg would make every figure vanish)
        base["MPLBACKEND"] = "module://matplotlib_inline.backend_inline"
        base.setdefault("PYDEVD_DISABLE_FILE_VALIDATION", "1")
        self.env = base
        self.km = self.kc = None

    def __enter__(self) -> "KernelSession":
        from jupyter_client.manager import start_new_kernel  # optional dependency (ipykernel's)

        self.km, self.kc = start_new_kernel(startup_timeout=self.startup_timeout, kernel_name=self.kernel_name,
                                            cwd=self.cwd, env=self.env)
        return self

    def __exit__(self, *exc) -> None:
        try:
            if self.kc is not None:
                self.kc.stop_channels()
        finally:
            if self.km is not None:
                self.km.shutdown_kernel(now=True)

    def run(self, code: str, timeout: float, label: str = "cell") -> CellRun:
        """Execute ``code``; collect outputs until the kernel is idle and has replied.

        Every wait is a poll of at most ``poll_seconds``; past ``timeout`` seconds the kernel
        is interrupted and :class:`CellTimeout` raised. A request the kernel aborted unexecuted
        (status ``aborted``: right after an error or an interrupt, ipykernel discards the requests
        that reach it before it stops aborting, a race under load) is sent again, at most
        ``abort_retries`` times; then :class:`CellError`.
        """
        t0 = time.monotonic()
        for _ in range(self.abort_retries + 1):
            result, content = self._execute(code, t0 + float(timeout), float(timeout), label)
            if content.get("status") != "aborted":
                break
            time.sleep(self.poll_seconds)
        else:
            raise CellError(f"{label}: the kernel aborted the request {self.abort_retries + 1} times\n{code[:300]}")
        result.seconds = time.monotonic() - t0
        if content.get("status") == "error":
            tb = _ANSI.sub("", "\n".join(content.get("traceback", [])))
            raise CellError(f"{label} raised {content.get('ename')}: {content.get('evalue')}\n{tb}")
        return result

    def _execute(self, code: str, deadline: float, timeout: float, label: str) -> tuple[CellRun, dict]:
        """One execute request: its outputs and its reply's content (:meth:`run`; ``timeout`` for the message)."""
        kc, km = self.kc, self.km
        msg_id = kc.execute(code, store_history=True, allow_stdin=False, stop_on_error=True)
        result = CellRun()
        display_index: dict[str, list[int]] = {}
        idle, reply = False, None
        while not (idle and reply is not None):
            if time.monotonic() > deadline:
                km.interrupt_kernel()
                self._drain(msg_id, reply is not None, 10.0)  # so that the next cell is not aborted with this one
                raise CellTimeout(f"{label}: still running after {timeout:.0f} s (kernel interrupted)\n{code[:300]}")
            if not idle:
                try:
                    msg = kc.get_iopub_msg(timeout=self.poll_seconds)
                except Empty:
                    if not km.is_alive():
                        raise CellError(f"{label}: the kernel died\n{code[:300]}") from None
                    msg = None
                if msg is not None and msg["parent_header"].get("msg_id") == msg_id:
                    idle = self._handle(msg, result, display_index)
            if reply is None:
                try:
                    m = kc.get_shell_msg(timeout=0 if not idle else self.poll_seconds)
                except Empty:
                    m = None
                if m is not None and m["parent_header"].get("msg_id") == msg_id:
                    reply = m
        return result, reply["content"]

    def _drain(self, msg_id: str, replied: bool, seconds: float) -> None:
        """After an interrupt: wait (at most ``seconds``) for the interrupted request's reply."""
        end = time.monotonic() + seconds
        while not replied and time.monotonic() < end:
            try:
                m = self.kc.get_shell_msg(timeout=self.poll_seconds)
            except Empty:
                continue
            replied = m["parent_header"].get("msg_id") == msg_id

    @staticmethod
    def _handle(msg, result: CellRun, display_index: dict) -> bool:
        """Record one IOPub message; True when it says the kernel is idle."""
        kind = msg["msg_type"]
        content = msg["content"]
        if kind == "status":
            return content.get("execution_state") == "idle"
        if kind in ("stream", "display_data", "execute_result", "error"):
            out = _output_from_msg(msg)
            result.outputs.append(out)
            did = content.get("transient", {}).get("display_id")
            if did:
                display_index.setdefault(did, []).append(len(result.outputs) - 1)
        elif kind == "update_display_data":
            did = content.get("transient", {}).get("display_id")
            for i in display_index.get(did, []):
                result.outputs[i]["data"] = content["data"]
                result.outputs[i]["metadata"] = content.get("metadata", {})
        elif kind == "clear_output":
            result.outputs.clear()
            display_index.clear()
        return False  # comm_open / comm_msg (widgets), execute_input: nothing to wait for


def execute_notebook(nb, cwd: str | Path, timeout_per_cell: float = 300.0, env: dict | None = None,
                     after: list[tuple[str, str]] | None = None):
    """Run every code cell of ``nb`` in order (outputs written into ``nb``, in place).

    Parameters
    ----------
    nb : an ``nbformat`` notebook (:func:`read_notebook`).
    cwd : the kernel's working directory (the notebook's folder).
    timeout_per_cell : seconds each cell may take.
    after : ``(label, code)`` run in the same kernel after the last cell (checks that need the
        notebook's state); their :class:`CellRun` results are returned.

    Returns
    -------
    ``(nb, {label: CellRun})``; ``nb.metadata["dynslam_seconds"]`` holds each cell's seconds.
    """
    seconds = []
    extra = {}
    with KernelSession(cwd, env=env) as k:
        for i, cell in enumerate(nb.cells):
            if cell.cell_type != "code" or not cell.source.strip():
                continue
            r = k.run(cell.source, timeout_per_cell, label=f"cell {i}")
            cell.outputs = r.outputs
            cell.execution_count = len(seconds) + 1
            seconds.append(round(r.seconds, 3))
        for label, code in after or []:
            extra[label] = k.run(code, timeout_per_cell, label=label)
    nb.metadata["dynslam_seconds"] = seconds
    return nb, extra


def count_images(cell, mime: str = "image/png") -> int:
    """Number of outputs of ``cell`` that carry an image."""
    return sum(1 for o in cell.get("outputs", []) if mime in o.get("data", {}))


def sections(nb) -> list[tuple[str, list]]:
    """The notebook split at level-2 headings (``## ...``): ``[(title, cells), ...]``; cells
    before the first heading form the section ``""``."""
    out: list[tuple[str, list]] = [("", [])]
    for cell in nb.cells:
        if cell.cell_type == "markdown":
            m = re.match(r"\s*##\s+(.*)", cell.source)
            if m and not cell.source.lstrip().startswith("###"):
                out.append((m.group(1).strip(), []))
        out[-1][1].append(cell)
    return [s for s in out if s[1]]


def exercise_cells(nb, key: str = "exercise") -> dict[str, int]:
    """Exercise id -> index of the cell carrying ``key`` metadata (``exercise`` or ``check``)."""
    found: dict[str, int] = {}
    for i, c in enumerate(nb.cells):
        ex = c.metadata.get(key)
        if ex is not None:
            if str(ex) in found:
                raise ValueError(f"two cells with {key}={ex!r} (cells {found[str(ex)]} and {i})")
            found[str(ex)] = i
    return found


def substitute_solutions(nb, solutions) -> list[str]:
    """Replace each exercise cell of ``nb`` by the solution cell of the same id (in place).

    Returns the exercise ids replaced; raises ``ValueError`` when an exercise has no solution
    or a solution no exercise.
    """
    ex = exercise_cells(nb)
    sol = exercise_cells(solutions)
    if set(ex) != set(sol):
        raise ValueError(f"exercises {sorted(ex)} and solutions {sorted(sol)} differ")
    for k, i in ex.items():
        nb.cells[i].source = solutions.cells[sol[k]].source
    return sorted(ex)
