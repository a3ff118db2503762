"""Ablation of the screening stages: one SLAM run per filter, ATE and keypoint scores in a table.

The papers' component tables compare the same system with parts switched on and off:
YOLO-SLAM (Wu et al. 2022) Table 3 (ORB-SLAM2 / D / G / D + G) and Chang et al. (Chang et al. 2021) Table I
(ORB-SLAM2 / only YOLACT / only multi-view geometry / all). :func:`run_ablation` does the same
with our filters (``none``, ``semantic``, ``depth_ransac``, ``geometry``, ``full`` and, on
synthetic sequences, ``oracle`` = perfect masks) and reports per filter and sequence:

* ATE RMSE (m) after SE(3) alignment and its improvement over ``none``
  (``(ATE_none - ATE) / ATE_none``, the papers' "improvement");
* per-keypoint precision and recall of the dynamic verdict against the synthetic truth
  (:mod:`dynslam_lab.experiments.scoring`), which none of the papers could measure on TUM;
* tracked/lost frames and the median screening time per frame.

Results go to ``OUTDIR/ablation.csv`` (one row per run) and ``OUTDIR/ablation.md`` (ATE table
like the papers, then the detailed table); each run keeps its own folder ``OUTDIR/SEQ/FILTER``.
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from ..config import Config
from ..datasets.tum import TumSequence
from ..dynamic.screening import FILTERS
from ..runs import atomic_write
from .robustness import run_one

__all__ = ["DEFAULT_FILTERS", "run_ablation", "ablation_markdown"]

DEFAULT_FILTERS = ("none", "semantic", "depth_ransac", "geometry", "full", "oracle")

#: Filters that use no detector (the detector is not even run for them).
_NO_DETECTOR = {"none", "geometry", "oracle"}


def _has_truth(seq) -> bool:
    return (Path(seq.root) / "masks").is_dir()


def run_ablation(
    seqdirs,
    outdir: str | Path,
    filters=DEFAULT_FILTERS,
    detector: str = "auto",
    config: Config | None = None,
    max_frames: int | None = None,
    loop_closing: bool = False,
    progress: bool = True,
    camera: str | None = None,
):
    """Run every filter on every sequence; return the results as a pandas DataFrame.

    Parameters
    ----------
    seqdirs : one sequence folder or a list of them (TUM layout).
    outdir : folder for ``ablation.csv``, ``ablation.md`` and one run folder per (sequence, filter).
    filters : filter names (see :func:`dynslam_lab.dynamic.screening.build_screener`).
    detector : detector spec for the filters that need one; ``"auto"`` = ``oracle`` on synthetic
        sequences (instance masks present) and an error elsewhere.
    config : root :class:`~dynslam_lab.config.Config` (defaults when None); every run is built
        from it by :func:`~dynslam_lab.pipeline.build_pipeline`.
    max_frames : frames per run (None = all).
    loop_closing : run the loop closer too.
    camera : camera preset override.

    Returns
    -------
    DataFrame with columns ``sequence, filter, ate_rmse_m, improvement_pct, precision, recall,
    precision_away, recall_away, fn_without_depth, tracked, lost, frames, loops, screen_median_ms, run_dir`` (each run by
    :func:`dynslam_lab.experiments.robustness.run_one`, as the robustness benchmark does).
    """
    if isinstance(seqdirs, (str, Path)):
        seqdirs = [seqdirs]
    filters = [str(f).strip().lower() for f in filters]
    for f in filters:
        if f not in FILTERS and "," not in f:
            raise ValueError(f"ablation: unknown filter {f!r}; choose from {list(FILTERS)} or a comma-separated stage list")
    config = config if config is not None else Config()
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    sequences = [TumSequence(d, camera=camera) for d in seqdirs]
    specs = {seq.root: _detector_spec(seq, detector) for seq in sequences}
    for seq in sequences:  # check before the first (long) run
        need = [f for f in filters if f not in _NO_DETECTOR]
        if need and specs[seq.root] in (None, "none"):
            raise ValueError(
                f"ablation: filters {need} need a detector for {seq.root} (no synthetic masks there); "
                "pass --detector onnx:MODEL or cache:DIR"
            )
    rows = []
    for seq in sequences:
        truth = _has_truth(seq)
        for name in filters:
            if name == "oracle" and not truth:
                continue  # perfect masks exist only for synthetic sequences
            det_spec = "none" if name in _NO_DETECTOR else specs[seq.root]
            run_dir = outdir / seq.name / name.replace(",", "+")
            r = run_one(seq, run_dir, config, name, det_spec, loop_closing, max_frames, progress)
            rows.append({
                "sequence": seq.name,
                "filter": name,
                "ate_rmse_m": r["ate_rmse_m"],
                "precision": r["precision"] if truth else float("nan"),
                "recall": r["recall"] if truth else float("nan"),
                "precision_away": r["precision_away"] if truth else float("nan"),
                "recall_away": r["recall_away"] if truth else float("nan"),
                "fn_without_depth": r["fn_without_depth"] if truth else float("nan"),
                "tracked": r["tracked"],
                "lost": r["lost"],
                "frames": r["frames"],
                "loops": r["loops"],
                "screen_median_ms": r["screen_ms"],
                "run_dir": r["run_dir"],
            })
    df = pd.DataFrame(rows)
    if len(df):
        base = df[df["filter"] == "none"].set_index("sequence")["ate_rmse_m"]
        df["improvement_pct"] = [
            100.0 * (base[s] - a) / base[s] if s in base.index and base[s] > 0 else float("nan")
            for s, a in zip(df["sequence"], df["ate_rmse_m"])
        ]
        cols = ["sequence", "filter", "ate_rmse_m", "improvement_pct", "precision", "recall", "precision_away",
                "recall_away", "fn_without_depth", "tracked", "lost", "frames", "loops", "screen_median_ms", "run_dir"]
        df = df[cols]
    atomic_write(outdir / "ablation.csv", lambda tmp: df.to_csv(tmp, index=False))
    atomic_write(outdir / "ablation.md", lambda tmp: tmp.write_text(ablation_markdown(df)))
    return df


def _detector_spec(seq: TumSequence, detector: str | None) -> str | None:
    if detector == "auto":
        return "oracle" if _has_truth(seq) else None
    return detector


def _fmt(v, digits=4) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return "-" if not math.isfinite(v) else f"{v:.{digits}f}"
    return str(v)


def _count(v) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else str(int(v))


def ablation_markdown(df) -> str:
    """The ablation as markdown: ATE RMSE per filter (rows) and sequence (columns), like YOLO-SLAM
    Table 3 / Chang et al. 2021 Table I, then every measured column."""
    if len(df) == 0:
        return "# Ablation\n\n(no runs)\n"
    seqs = list(dict.fromkeys(df["sequence"]))
    filters = list(dict.fromkeys(df["filter"]))
    lines = ["# Ablation of the screening stages", "", "ATE RMSE (m), improvement over `none` in brackets.", ""]
    lines.append("| filter | " + " | ".join(seqs) + " |")
    lines.append("|---|" + "---|" * len(seqs))
    for f in filters:
        cells = []
        for s in seqs:
            r = df[(df["filter"] == f) & (df["sequence"] == s)]
            if len(r) == 0:
                cells.append("-")
                continue
            r = r.iloc[0]
            imp = r["improvement_pct"]
            cells.append(_fmt(r["ate_rmse_m"]) + ("" if f == "none" or not math.isfinite(imp) else f" ({imp:+.1f}%)"))
        lines.append(f"| {f} | " + " | ".join(cells) + " |")
    lines += ["", "Per-keypoint precision / recall of the dynamic verdict against the synthetic truth (`P away` / "
              "`R away`: only the keypoints beyond 4 px of every moving outline; `FN no depth`: the misses without "
              "depth), tracking, and screening time (median ms per frame).", ""]
    cols = ["sequence", "filter", "ate_rmse_m", "improvement_pct", "precision", "recall", "precision_away",
            "recall_away", "fn_without_depth", "tracked", "lost", "frames", "screen_median_ms"]
    heads = {"precision_away": "P away", "recall_away": "R away", "fn_without_depth": "FN no depth"}
    cols = [c for c in cols if c in df]  # tables written before a column existed still render
    lines.append("| " + " | ".join(heads.get(c, c) for c in cols) + " |")
    lines.append("|---" * len(cols) + "|")
    for _, r in df.iterrows():
        cells = [_count(r[c]) if c == "fn_without_depth" else _fmt(r[c], 1 if c in ("improvement_pct", "screen_median_ms") else 3)
                 for c in cols]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
