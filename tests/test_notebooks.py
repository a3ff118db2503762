"""The notebooks (jupytext percent sources in notebooks/) teach by the standard of
docs/notebooks.md, run top to bottom, draw the figures they promise, and every slider acts.

* ``test_notebook_follows_the_standard`` (fast, no kernel): "What you will learn", a paper by
  name and an equation, a "What to look for" under every figure, >= 2 exercises with checks
  and solutions, a figure in every section, sliders only through ``figure_explorer``.
* ``test_notebook_runs_and_draws`` (slow): runs the notebook with the exercise cells replaced
  by their solutions (``notebooks/solutions/``), with matplotlib's inline backend and a
  deadline per cell (``dynslam_lab.viz.notebook_exec``), then checks that every cell shows
  exactly the images it promises (``# %% figures=N``), that every section has an image, that
  every check passes on the solution and says "not answered yet" on the blank exercise, and
  that every slider changes the figure at two values other than its start value
  (``dynslam_lab.viz.widgets.check_explorers``).
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest

from tests.conftest import SHARED_DATA

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("[0-9][0-9]_*.py"))
SOLUTIONS = ROOT / "notebooks" / "solutions"
PAPERS = ("Wu et al. 2022", "Zhang et al. 2023", "Chang et al. 2021", "Ge et al. 2024", "Mur-Artal & Tardos 2017",
          "Galvez-Lopez & Tardos 2012", "Bescos et al. 2018", "Sturm et al. 2012", "Hornung et al. 2013")
CELL_TIMEOUT = 300  # seconds per cell (the slowest cell, the ablation of 07, takes ~40 s on a busy machine)
SLIDER_CHECK = "import json\nfrom dynslam_lab.viz.widgets import check_explorers\nprint('@@' + json.dumps(check_explorers()))"


def _nb(path):
    jupytext = pytest.importorskip("jupytext")
    return jupytext.read(path)


def _figure_cells(nb):
    return [i for i, c in enumerate(nb.cells) if c.cell_type == "code" and int(c.metadata.get("figures", 0)) > 0]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_follows_the_standard(path):
    from dynslam_lab.viz.notebook_exec import exercise_cells, sections

    nb = _nb(path)
    text = "\n".join(c.source for c in nb.cells if c.cell_type == "markdown")
    code = "\n".join(c.source for c in nb.cells if c.cell_type == "code")
    assert "What you will learn" in nb.cells[0].source, "the first cell must say what the reader will learn"
    assert any(p in text for p in PAPERS), f"no paper cited by name (one of {PAPERS})"
    assert "$" in text, "no equation ($...$) in the text"
    assert not re.search(r"seed\s*0\d\d", text + code, re.I), "papers are cited by name, never by seed number"
    for bad in ("interact(", "interactive(", "interactive_output("):
        assert bad not in code, f"{bad!r}: sliders go through dynslam_lab.viz.widgets.figure_explorer (tested)"
    # a "What to look for" under every figure
    for i in _figure_cells(nb):
        nxt = nb.cells[i + 1] if i + 1 < len(nb.cells) else None
        assert nxt is not None and nxt.cell_type == "markdown" and nxt.source.lstrip().startswith("**What to look for"), \
            f"cell {i} draws a figure but the next cell is no '**What to look for**' note:\n{nb.cells[i].source[:200]}"
    # a figure in every section
    for title, cells in sections(nb):
        if title:
            assert any(int(c.metadata.get("figures", 0)) > 0 for c in cells if c.cell_type == "code"), \
                f"section {title!r} has no figure"
    # exercises: >= 2, each with a check cell and a solution
    ex, chk = exercise_cells(nb), exercise_cells(nb, "check")
    assert len(ex) >= 2, f"{len(ex)} exercises (at least 2)"
    assert set(ex) == set(chk), f"exercises {sorted(ex)} and check cells {sorted(chk)} differ"
    for k in ex:
        assert chk[k] > ex[k], f"the check of exercise {k} comes before it"
        assert "check(" in nb.cells[chk[k]].source and "None" in nb.cells[ex[k]].source, \
            f"exercise {k}: the reader's cell starts from None and the next cell calls check()"
    sol_path = SOLUTIONS / path.name
    assert sol_path.is_file(), f"no solutions file {sol_path}"
    assert set(exercise_cells(_nb(sol_path))) == set(ex), f"{sol_path.name}: solutions do not match the exercises"


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs_and_draws(path, tmp_path):
    pytest.importorskip("jupyter_client")
    from dynslam_lab.viz.notebook_exec import count_images, execute_notebook, exercise_cells, sections, \
        substitute_solutions

    nb = _nb(path)
    blank = _nb(path)
    ids = substitute_solutions(nb, _nb(SOLUTIONS / path.name))
    ex, chk = exercise_cells(blank), exercise_cells(blank, "check")
    after = [(f"blank exercise {k}", blank.cells[ex[k]].source + "\n" + blank.cells[chk[k]].source) for k in ids]
    after.append(("sliders", SLIDER_CHECK))
    # the notebooks' scratch folders (tempfile.mkdtemp) go into pytest's tmp_path, which pytest prunes
    env = dict(os.environ, TMPDIR=str(tmp_path))
    nb, extra = execute_notebook(nb, cwd=path.parent, timeout_per_cell=CELL_TIMEOUT, after=after, env=env)
    has_shared = SHARED_DATA.is_dir()

    # every cell shows exactly the images it promises (none where it promises none)
    for i, cell in enumerate(nb.cells):
        if cell.cell_type != "code":
            continue
        promised, got = int(cell.metadata.get("figures", 0)), count_images(cell)
        if cell.metadata.get("needs_shared") and not has_shared:
            promised = 0
        assert got == promised, f"cell {i} shows {got} images, promises {promised}:\n{cell.source[:300]}"
    for title, cells in sections(nb):
        needs = [c for c in cells if c.cell_type == "code" and int(c.metadata.get("figures", 0)) > 0]
        if title and (has_shared or not all(c.metadata.get("needs_shared") for c in needs)):
            assert sum(count_images(c) for c in cells if c.cell_type == "code") > 0, f"section {title!r}: no image"
    # the checks pass on the solutions
    for k in ids:
        out = "".join(o.get("text", "") for o in nb.cells[chk[k]].outputs if o.get("output_type") == "stream")
        assert f"Exercise {k}: correct" in out, f"exercise {k}: the check did not pass on the solution: {out!r}"
    print(f"{path.stem}: {sum(nb.metadata['dynslam_seconds']):.1f} s in cells; slowest "
          f"{max(nb.metadata['dynslam_seconds']):.1f} s")
    # the blank exercises say "not answered yet" (run after the last cell, in the same kernel)
    for k in ids:
        assert "not answered yet" in extra[f"blank exercise {k}"].stdout, f"exercise {k}: the blank cell's check"
    # every control changes the figure at two values other than its start value
    rows = json.loads(extra["sliders"].stdout.split("@@", 1)[1])
    bad = [r for r in rows if r["error"] or not r["differs"] or not all(r["differs"])]
    print(f"{path.stem}: {len(rows)} controls checked")
    assert not bad, "controls that do not change the figure:\n" + "\n".join(map(str, bad))


def test_notebooks_command_opens_the_py_files_as_notebooks(monkeypatch, capsys):
    """`dynslam notebooks 4` starts JupyterLab on notebooks/04_*.py with a config path whose lab
    settings make jupytext's notebook view the default for Python files (read back the way
    JupyterLab reads it, when JupyterLab is installed)."""
    from dynslam_lab.cli import main
    from dynslam_lab.commands.notebooks import find_notebook, lab_command

    nb = find_notebook("4")
    assert nb.name.startswith("04_") and nb.parent == ROOT / "notebooks"
    assert find_notebook("04_depth_ransac.py") == nb
    with pytest.raises(FileNotFoundError, match="known: 00_quickstart"):
        find_notebook("42")
    cmd, env = lab_command(nb, port=8899, no_browser=True)
    assert nb.name in cmd and "--ServerApp.port=8899" in cmd and "--no-browser" in cmd
    config_dir = env["JUPYTER_CONFIG_PATH"].split(":")[0]
    assert config_dir == str(ROOT / "notebooks" / "jupyter_config")
    settings = json.loads((ROOT / "notebooks" / "jupyter_config" / "labconfig" / "default_setting_overrides.json").read_text())
    assert settings["@jupyterlab/docmanager-extension:plugin"]["defaultViewers"]["python"] == "Jupytext Notebook"
    try:  # read back as JupyterLab's settings server does (jupyter_server: the [notebooks] extra)
        from jupyter_server.services.config.manager import ConfigManager
    except ImportError:
        ConfigManager = None
    if ConfigManager is not None:
        monkeypatch.setenv("JUPYTER_CONFIG_PATH", env["JUPYTER_CONFIG_PATH"])
        overrides = ConfigManager(config_dir_name="labconfig").get("default_setting_overrides")
        assert overrides["@jupyterlab/docmanager-extension:plugin"]["defaultViewers"]["python"] == "Jupytext Notebook"
    import importlib.util

    installed = all(importlib.util.find_spec(m) for m in ("jupyterlab", "jupytext", "ipywidgets", "ipykernel"))
    rc = main(["notebooks", "00", "--dry-run"])
    out = capsys.readouterr()
    if installed:
        assert rc == 0 and "00_quickstart.py" in out.out and "JUPYTER_CONFIG_PATH=" in out.out
    else:  # the test extra alone: a clear line naming the extra
        assert rc == 1 and 'pip install -e ".[notebooks]"' in out.err
