"""Camera effects benchmark: the filters on copies of sequences with another camera's effects.

The toolkit is judged on sequences made by other renderers and recorded by real cameras, whose images differ
from our renderer's in ways no scene layout varies: auto-exposure, motion blur, vignetting and another response
curve, more noise, another frame rate (:mod:`~dynslam_lab.datasets.camera_effects`). This module writes a copy
of each sequence with each effect (:data:`~dynslam_lab.datasets.camera_effects.EFFECT_PRESETS`, or any
:class:`~dynslam_lab.datasets.camera_effects.CameraEffects`), runs the filters on the original and on every
copy (:func:`~dynslam_lab.experiments.robustness.resumable_run`), and reports per effect and filter how many runs stay
within 0.05 m, the median and worst ATE, and the median and worst ratio of ATE to the same filter on the
original sequence (``docs/robustness.md``, "Camera effects").
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from ..config import Config, config_to_dict
from ..datasets.camera_effects import EFFECT_PRESETS, CameraEffects, apply_camera_effects, effects_record
from .robustness import ATE_BOUND_M, SequenceSpec, _filters, _fmt, _write_text, resumable_run

__all__ = ["ORIGINAL", "effect_copy", "run_camera_effects", "camera_effects_summary", "camera_effects_markdown"]

#: The effect label of the unchanged sequence.
ORIGINAL = "original"


def effect_copy(root: Path, effects: CameraEffects, folder: Path) -> Path:
    """The copy of sequence ``root`` with ``effects`` in ``folder`` (made once; a copy made from another source or
    with other effects is an error, never overwritten)."""
    if folder.exists():
        try:
            have = json.loads((folder / "camera_effects.json").read_text())
        except (OSError, ValueError):
            have = None
        if have != effects_record(root, effects):
            raise FileExistsError(f"{folder} exists and is not the copy of {root} with {effects}; remove it or choose "
                                  "another output folder")
        return folder
    return apply_camera_effects(root, folder, effects)


def run_camera_effects(sequences: list[SequenceSpec], outdir: str | Path, effects: dict[str, CameraEffects] | None = None,
                       filters: list[str] | None = None, config: Config | None = None, max_frames: int | None = None,
                       loop_closing: bool = False, resume: bool = True, on_run=None,
                       onnx_model: str | Path | None = None) -> pd.DataFrame:
    """Run ``filters`` (labels of :data:`~dynslam_lab.experiments.robustness.FILTERS`; default ``geometry`` and
    ``full+oracle``; ``full+onnx`` with ``onnx_model``) on every sequence and on its copy with each of ``effects`` (default
    :data:`EFFECT_PRESETS`). The copies go to ``outdir/sequences/``, one run folder per (sequence, effect,
    filter), each with a ``row.json`` that an interrupted benchmark resumes from; ``outdir`` gets
    ``camera_effects.csv`` and ``camera_effects.md``. Returns one row per run: ``sequence, effect, filter`` and
    the columns of :func:`~dynslam_lab.experiments.robustness.run_one`, then ``ate_vs_original``."""
    config = config if config is not None else Config()
    effects = dict(EFFECT_PRESETS if effects is None else effects)
    if ORIGINAL in effects:
        raise ValueError(f"camera effects: {ORIGINAL!r} names the unchanged sequence, not an effect")
    labels = list(filters) if filters is not None else ["geometry", "full+oracle"]
    known = _filters(onnx_model, labels, what="camera effects", also=())
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    fingerprint = json.dumps(config_to_dict(config), sort_keys=True, default=str)
    rows = []
    for spec in sequences:
        roots = {ORIGINAL: spec.root}
        for name, eff in effects.items():
            roots[name] = effect_copy(spec.root, eff, outdir / "sequences" / f"{spec.name}__{name}")
        for effect, root in roots.items():
            for label in labels:
                filt, det = known[label]
                run_dir = outdir / spec.name / effect / label.replace(" ", "_").replace("+", "_")
                row = resumable_run(root, run_dir, config, fingerprint, filt, det, loop_closing, max_frames, resume)
                rows.append({"sequence": spec.name, "effect": effect, "filter": label, **row})
                if on_run is not None:
                    on_run(rows[-1])
    df = with_ratios(pd.DataFrame(rows))
    _write_text(outdir / "camera_effects.csv", df.to_csv(index=False))
    _write_text(outdir / "camera_effects.md", camera_effects_markdown(df))
    return df


def with_ratios(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with ``ate_vs_original``: each run's ATE over the same filter's on the unchanged sequence."""
    df = df.copy()
    if not len(df):
        df["ate_vs_original"] = pd.Series(dtype=float)
        return df
    base = df[df["effect"] == ORIGINAL].set_index(["sequence", "filter"])["ate_rmse_m"]
    ref = [base.get((s, f), np.nan) for s, f in zip(df["sequence"], df["filter"])]
    with np.errstate(divide="ignore", invalid="ignore"):
        df["ate_vs_original"] = pd.to_numeric(df["ate_rmse_m"], errors="coerce").to_numpy(float) / np.asarray(ref, float)
    return df


def camera_effects_summary(df: pd.DataFrame) -> pd.DataFrame:
    """Per (effect, filter): runs, how many within :data:`ATE_BOUND_M`, the median and worst ATE (m), the median
    and worst ratio to the original, frames lost (sum). The original first, then the effects in order."""
    out = []
    for (effect, label), g in df.groupby(["effect", "filter"], sort=False):
        a = pd.to_numeric(g["ate_rmse_m"], errors="coerce")
        r = pd.to_numeric(g["ate_vs_original"], errors="coerce")
        out.append({"effect": effect, "filter": label, "n": len(g), "within": int((a <= ATE_BOUND_M).sum()),
                    "ate_median": float(a.median()), "ate_worst": float(a.max()),
                    "ratio_median": float(r.median()), "ratio_worst": float(r.max()), "lost": int(g["lost"].sum())})
    s = pd.DataFrame(out, columns=["effect", "filter", "n", "within", "ate_median", "ate_worst", "ratio_median",
                                   "ratio_worst", "lost"])
    if len(s):
        order = {e: i for i, e in enumerate(dict.fromkeys([ORIGINAL, *df["effect"]]))}
        s = s.sort_values(["effect", "filter"], key=lambda c: c.map(order) if c.name == "effect" else c, kind="stable")
    return s.reset_index(drop=True)


def camera_effects_markdown(df: pd.DataFrame) -> str:
    """The summary table, then every run."""
    lines = ["# Filters under camera effects", "",
             f"Per effect and filter: runs, how many within {ATE_BOUND_M} m of ATE, the median and worst ATE (m), the "
             "median and worst ratio of ATE to the same filter on the unchanged sequence, frames lost.", "",
             "| effect | filter | n | within | ATE median | ATE worst | ratio median | ratio worst | lost |",
             "|---|---|---|---|---|---|---|---|---|"]
    for _, r in camera_effects_summary(df).iterrows():
        lines.append(f"| {r['effect']} | {r['filter']} | {r['n']} | {r['within']} | {_fmt(r['ate_median'], 4)} | "
                     f"{_fmt(r['ate_worst'], 4)} | {_fmt(r['ratio_median'], 2)} | {_fmt(r['ratio_worst'], 2)} | {r['lost']} |")
    lines += ["", "## Every run", "", "| sequence | effect | filter | ATE (m) | ratio | lost | P | R |", "|---|---|---|---|---|---|---|---|"]
    for _, r in df.iterrows():
        lines.append(f"| {r['sequence']} | {r['effect']} | {r['filter']} | {_fmt(r['ate_rmse_m'], 4)} | "
                     f"{_fmt(r['ate_vs_original'], 2)} | {r['lost']} | {_fmt(r['precision'])} | {_fmt(r['recall'])} |")
    return "\n".join(lines) + "\n"
