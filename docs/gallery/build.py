"""Build the HTML gallery of the notebooks: run each one, export it to static HTML.

Usage (from the clone, with the ``[notebooks]`` extra installed)::

    python docs/gallery/build.py                    # all notebooks -> docs/gallery/html/
    python docs/gallery/build.py 00 04 --out /tmp/g  # some of them, elsewhere

Each notebook runs headless exactly as in the notebook test (``dynslam_lab.viz.notebook_exec``:
the inline backend, a deadline per cell), with the reader's blank exercises; the executed
notebook is exported with nbconvert's ``lab`` template. Widgets do not survive a static
export: every slider figure has its static first rendering (``docs/notebooks.md``), and the
widget itself is replaced by a one-line note. ``index.html`` lists the notebooks with their
"What you will learn" and first figure.

The output (about 1 MB per notebook, images embedded) is not committed: ``docs/gallery/html/``
is ignored by git. The script writes only into a folder it created (marked by a
``.dynslam-gallery`` file) and replaces each page atomically.
"""

from __future__ import annotations

import argparse
import base64
import html
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOKS = ROOT / "notebooks"
MARKER = ".dynslam-gallery"
WIDGET_MIME = "application/vnd.jupyter.widget-view+json"
NOTE = "(interactive controls here: open the notebook with `dynslam notebooks` to move them)"


def _atomic_write(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.chmod(tmp, 0o644)  # pages are read by a web server or a browser, not only by us
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _prepare_out(out: Path) -> None:
    if out.exists() and any(out.iterdir()) and not (out / MARKER).is_file():
        raise SystemExit(f"build.py: {out} exists and was not made by this script (no {MARKER}); choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    (out / MARKER).write_text("HTML gallery of the dynslam_lab notebooks (docs/gallery/build.py)\n")


def _strip_widgets(nb) -> int:
    """Replace widget views (no state in a static page) by a short note; returns how many."""
    from nbformat.v4 import new_output  # the [notebooks] extra

    n = 0
    for cell in nb.cells:
        if cell.cell_type != "code":
            continue
        outs = []
        for o in cell.get("outputs", []):
            if WIDGET_MIME in o.get("data", {}):
                n += 1
                outs.append(new_output("display_data", data={"text/markdown": f"*{NOTE}*", "text/plain": NOTE}))
            else:
                outs.append(o)
        cell.outputs = outs
    return n


def _thumbnail(png_b64: str, width: int = 480) -> str:
    """A base64 PNG shrunk to ``width`` pixels (the index page stays small)."""
    import cv2  # heavy: only for the index page

    img = cv2.imdecode(np.frombuffer(base64.b64decode(png_b64), np.uint8), cv2.IMREAD_COLOR)
    if img is None or img.shape[1] <= width:
        return png_b64
    small = cv2.resize(img, (width, round(img.shape[0] * width / img.shape[1])), interpolation=cv2.INTER_AREA)
    return base64.b64encode(cv2.imencode(".png", small)[1].tobytes()).decode("ascii")


def _summary(nb) -> tuple[str, str, str | None]:
    """Title, the "What you will learn" text, and the first figure (base64 PNG) of a notebook."""
    first = nb.cells[0].source if nb.cells else ""
    title = next((ln.lstrip("# ").strip() for ln in first.splitlines() if ln.startswith("#")), "notebook")
    m = re.search(r"What you will learn\**:?\s*(.*?)(\n\s*\n|$)", first, re.S)  # the list, to the first blank line
    learn = m.group(1).strip().replace("`", "") if m else ""
    img = next((o["data"]["image/png"] for c in nb.cells if c.cell_type == "code"
                for o in c.get("outputs", []) if "image/png" in o.get("data", {})), None)
    return title, learn, (None if img is None else _thumbnail(img))


def build(names: list[str], out: Path, timeout: float) -> int:
    from nbconvert import HTMLExporter  # the [notebooks] extra

    from dynslam_lab.viz.notebook_exec import count_images, execute_notebook, read_notebook  # after sys.path is set (main)

    paths = sorted(NOTEBOOKS.glob("[0-9][0-9]_*.py"))
    if names:
        paths = [p for p in paths if any(p.stem.startswith(n.zfill(2)) or p.stem == n for n in names)]
        if not paths:
            raise SystemExit(f"build.py: no notebook matches {names}")
    _prepare_out(out)
    exporter = HTMLExporter(template_name="lab")
    cards, failed = [], 0
    for p in paths:
        t0 = time.perf_counter()
        nb = read_notebook(p)
        try:
            nb, _ = execute_notebook(nb, cwd=p.parent, timeout_per_cell=timeout)
        except Exception as exc:  # one failing notebook must not stop the gallery
            failed += 1
            print(f"{p.stem}: FAILED: {str(exc).splitlines()[0]}", file=sys.stderr)
            continue
        widgets = _strip_widgets(nb)
        body, _ = exporter.from_notebook_node(nb)
        _atomic_write(out / f"{p.stem}.html", body)
        images = sum(count_images(c) for c in nb.cells if c.cell_type == "code")
        title, learn, img = _summary(nb)
        cards.append((p.stem, title, learn, img, images))
        print(f"{p.stem}: {images} figures, {widgets} widgets replaced, {time.perf_counter() - t0:.1f} s "
              f"-> {out / (p.stem + '.html')}", flush=True)
    _atomic_write(out / "index.html", _index(cards))
    print(f"gallery: {len(cards)} notebooks in {out / 'index.html'}" + (f", {failed} failed" if failed else ""))
    return 1 if failed else 0


def _index(cards) -> str:
    items = []
    for stem, title, learn, img, n in cards:
        thumb = f'<img src="data:image/png;base64,{img}" alt="first figure of {html.escape(stem)}">' if img else ""
        items.append(f'<a class="card" href="{html.escape(stem)}.html">{thumb}<h2>{html.escape(title)}</h2>'
                     f'<p>{html.escape(learn)}</p><p class="n">{n} figures</p></a>')
    return ("<!doctype html><html><head><meta charset='utf-8'><title>dynslam_lab notebooks</title><style>"
            "body{font-family:sans-serif;margin:2em;max-width:1200px}"
            ".grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(320px,1fr));gap:1.2em}"
            ".card{border:1px solid #ccc;border-radius:6px;padding:.8em;color:inherit;text-decoration:none}"
            ".card img{width:100%;max-height:220px;object-fit:contain}.card h2{font-size:1.1em}"
            ".card p{font-size:.9em;white-space:pre-line}.n{color:#777}</style></head><body>"
            "<h1>dynslam_lab notebooks</h1><p>Static renderings of the notebooks (run with "
            "<code>dynslam notebooks</code> to move the sliders). Built by <code>docs/gallery/build.py</code>.</p>"
            f"<div class='grid'>{''.join(items)}</div></body></html>")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("notebooks", nargs="*", help="numbers or stems (default: all)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "gallery" / "html", help="output folder")
    ap.add_argument("--timeout", type=float, default=600, help="seconds per cell (default 600)")
    args = ap.parse_args()
    return build(args.notebooks, args.out, args.timeout)


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    sys.exit(main())
