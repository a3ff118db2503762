"""The robustness benchmark: every filter on scenes it was not tuned on, worst case beside typical.

The demo's numbers come from one kind of scene (two people about 1 m away, found by the oracle
detector). This module runs the filters over many sequences, each also rendered without its
movers (the same camera path: the reference the filters should approach), and reports per
sequence and filter (``docs/robustness.md``):

* ATE RMSE (m, SE(3) alignment), its ratio to ``none`` on the same sequence and to the reference
  without movers; frames lost; loops accepted (a path that does not revisit a place must accept
  none);
* per-keypoint precision and recall of the dynamic verdict against the renderer's truth
  (:class:`~dynslam_lab.experiments.scoring.KeypointScorer`);
* milliseconds per frame (median of the whole system and of screening);
* the movers' image coverage (mean and maximum over the frames, from the renderer's statistics);
* the kind of scene: the room's surface style (``flat``, ``noise``, ``pattern``, ``photo``; ``office`` for the
  office presets) and the camera's motion, from the renderer's ``synthetic.json``. The markdown splits every
  filter's results by both (:func:`by_kind`): failures cluster by kind of room (``geometry``'s in plain,
  ``flat`` rooms; docs/robustness.md), and a median over all scenes hides that.

The filters (:data:`FILTERS`): ``none``; ``geometry`` without a detector; ``full`` with the oracle
detector (which names people only, never a box or a cart); ``full`` with an ONNX detector when a
model is given; ``oracle`` (perfect masks of every moving instance). Runs are built by
:func:`dynslam_lab.pipeline.build_pipeline` and run by :func:`dynslam_lab.runs.run_sequence`;
:func:`run_one` is the one place that does it (``dynslam ablation`` uses it too). Each finished run
leaves ``row.json`` in its folder, so an interrupted benchmark resumes where it stopped.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from ..config import Config, config_to_dict
from ..datasets import stress
from ..datasets.synthetic import PRESETS, synthetic_sequence
from ..datasets.tum import TumSequence
from ..pipeline import build_pipeline
from ..runs import run_sequence
from ..runs.layout import atomic_write
from .scoring import KeypointScorer

__all__ = ["SequenceSpec", "root_specs", "FILTERS", "REFERENCE", "run_one", "resumable_run", "run_robustness", "summarise", "robustness_markdown",
           "robustness_plot", "TARGETS", "TARGET_COVERAGE", "ATE_BOUND_M", "REFERENCE_LOST_SHARE", "by_kind", "scene_kind", "synthetic_specs",
           "synthetic_root"]

#: Filter label -> (``--filters``, ``--detector``); ``full+onnx`` is added when a model is given.
FILTERS: dict[str, tuple[str, str]] = {
    "none": ("none", "none"),
    "geometry": ("geometry", "none"),
    "full+oracle": ("full", "oracle"),
    "oracle masks": ("oracle", "none"),
}
#: Measures where a smaller value is worse (the keypoint scores); for every other one a larger value is.
_LOW_IS_WORSE = ("precision", "recall", "precision_at_rest_ok", "precision_away", "recall_away")

#: Label of the run on the sequence without movers (filter ``none``).
REFERENCE = "no movers"

#: The targets of issue 16, as (filter label, column, bound, description).
TARGETS = (
    ("geometry", "ate_rmse_m", 0.05, "geometry without a detector: ATE <= 0.05 m"),
    ("geometry", "ate_vs_none", 0.2, "geometry: ATE <= 20% of none"),
    ("geometry", "precision", 0.9, "geometry: keypoint precision >= 0.9"),
    ("geometry", "recall", 0.9, "geometry: keypoint recall >= 0.9"),
    ("oracle masks", "ate_vs_reference", 2.0, "perfect masks: ATE <= 2x the path without movers"),
    ("full+oracle", "ate_vs_oracle", 1.5, "full with the oracle detector: ATE <= 1.5x perfect masks"),
)


#: Issue 16 asks for geometry's ATE target "on scenes whose movers cover up to 45% of the image": the largest
#: image share of the movers (``coverage_max``) that scopes the geometry ATE targets. The markdown reports them
#: on every sequence and on those in scope.
TARGET_COVERAGE = 0.45

#: The ATE bound of issue 16 (m): the "within" column of the tables by kind of scene.
ATE_BOUND_M = 0.05

#: A run on the path without movers that loses more than this share of its frames is named under the targets:
#: the static world alone does not track there (a plain room whose only texture is on its movers).
REFERENCE_LOST_SHARE = 0.5


@dataclass(frozen=True)
class SequenceSpec:
    """A sequence of the benchmark: a name, its folder, and the folder of the same camera path
    without movers (None when there is none)."""

    name: str
    root: Path
    reference: Path | None = None


def root_specs(roots: str) -> list[SequenceSpec]:
    """One :class:`SequenceSpec` per folder of the comma-separated ``roots`` (a benchmark's ``--roots``: sequences in
    the TUM layout, named by their folder); a name that is not a folder is a ValueError naming it."""
    specs = []
    for r in (r.strip() for r in roots.split(",") if r.strip()):
        root = Path(r)
        if not root.is_dir():
            raise ValueError(f"--roots: {root} is not a folder")
        specs.append(SequenceSpec(root.name, root))
    return specs


def synthetic_specs(names, n_frames: int | None = None, seed: int = 0) -> list[SequenceSpec]:
    """Rendered (cached) synthetic sequences with their references without movers.

    ``names``: stress scenes (:data:`~dynslam_lab.datasets.stress.STRESS_SUITE`, or ``random_N``: the
    scene drawn from seed N; reference: the same scene ``without_movers()``) or office presets (reference:
    ``static_MOTION``, the office without people on the same camera path, when the renderer has it).
    """
    out = []
    for name in names:
        p = _stress_preset(name, n_frames)
        if p is not None:
            out.append(SequenceSpec(name, synthetic_sequence(p), synthetic_sequence(p.without_movers())))
        elif name in PRESETS:
            ref = f"static_{PRESETS[name].motion}"
            ref_root = synthetic_sequence(ref, n_frames=n_frames, seed=seed) if ref in PRESETS and ref != name else None
            out.append(SequenceSpec(name, synthetic_sequence(name, n_frames=n_frames, seed=seed), ref_root))
        else:
            raise _unknown_sequence(name)
    return out


def synthetic_root(name: str, n_frames: int | None = None, seed: int = 0) -> Path:
    """The rendered (cached) folder of one synthetic sequence, named as for :func:`synthetic_specs`, without
    rendering its reference."""
    p = _stress_preset(name, n_frames)
    if p is not None:
        return synthetic_sequence(p)
    if name in PRESETS:
        return synthetic_sequence(name, n_frames=n_frames, seed=seed)
    raise _unknown_sequence(name)


def _unknown_sequence(name: str) -> ValueError:
    return ValueError(f"unknown synthetic sequence {name!r}; stress scenes: {list(stress.STRESS_SUITE)}, random_N "
                      f"(a stress scene drawn from seed N), office presets: {list(PRESETS)}")


def _stress_preset(name: str, n_frames: int | None) -> stress.StressPreset | None:
    """The stress scene ``name`` of the suite, or for ``random_N`` the scene drawn from seed N (as ``dynslam synth
    random --seed N``); None for any other name. ``n_frames`` None keeps the preset's length."""
    length = {} if n_frames is None else {"n_frames": int(n_frames)}
    head, _, tail = name.partition("_")
    if head == "random" and tail.isdigit():
        return stress.random_scene_preset(int(tail), name=name, **length)
    if name in stress.STRESS_SUITE:
        return replace(stress.STRESS_SUITE[name], **length)
    return None


def _metadata(root: Path) -> dict:
    """A rendered sequence's ``synthetic.json`` as a dict; empty when there is none or it does not parse (a real
    sequence)."""
    try:
        meta = json.loads((Path(root) / "synthetic.json").read_text())
    except (OSError, ValueError):
        return {}
    return meta if isinstance(meta, dict) else {}


def _coverage(meta: dict) -> tuple[float, float]:
    """Mean and maximum image fraction covered by moving instances (the ``stats`` of :func:`_metadata`)."""
    stats = meta.get("stats") or {}
    return float(stats.get("moving_cover_mean", float("nan"))), float(stats.get("moving_cover_max", float("nan")))


def _kind(meta: dict) -> tuple[str, str]:
    """``(room, camera)`` from :func:`_metadata` (:func:`scene_kind`)."""
    preset = meta.get("preset") or {}
    if not isinstance(preset, dict):
        return "-", "-"
    room = str(preset.get("style") or ("office" if meta.get("kind") == "office" else "-"))
    return room, str(preset.get("motion") or "-")


def scene_kind(root: Path) -> tuple[str, str]:
    """``(room, camera)`` of a rendered sequence (``synthetic.json``): the stress scene's room surface style
    (``flat``, ``noise``, ``pattern``, ``photo``) or ``office`` for an office preset, and the camera's motion
    (``static``, ``xyz``, ``rpy``, ``halfsphere``, ...); ``("-", "-")`` for a sequence the renderer did not make."""
    return _kind(_metadata(root))


def _write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: tmp.write_text(text))


def _finite(v) -> float:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return float("nan")
    return v if math.isfinite(v) else float("nan")


def run_one(seq: TumSequence, run_dir: str | Path, config: Config, filters: str, detector: str = "none",
            loop_closing: bool = True, max_frames: int | None = None, progress: bool = False,
            scorer: KeypointScorer | None = None) -> dict:
    """One SLAM run, scored: ATE, lost frames, loops, keypoint precision/recall, ms per frame.

    Returns a dict with ``ate_rmse_m, tracked, lost, frames, keyframes, loops, precision, recall,
    precision_at_rest_ok, precision_away, recall_away, tp, fp, fn, fn_without_depth, ms_per_frame, screen_ms, run_dir``
    (nan where not measured: no ground truth, no truth masks, no screening); ``precision_at_rest_ok`` counts keeping
    a mover at rest out as right; ``precision_away`` / ``recall_away`` score only the keypoints beyond 4 px of every
    moving outline (:mod:`.scoring`). Pass a fresh ``scorer`` to read more of the scores afterwards (its
    split of the false positives, per frame).
    """
    system = build_pipeline(config, seq.camera, detector=detector, filters=filters, loop_closing=loop_closing)
    scorer = KeypointScorer() if scorer is None else scorer
    summary = run_sequence(seq, run_dir, system, max_frames=max_frames, progress=progress, on_frame=scorer)
    ate = (summary.get("ate") or {}).get("rmse")
    screen = np.asarray(scorer.screen_ms, float)
    total = (summary.get("timing_median_ms") or {}).get("total")
    has_truth = bool(scorer.per_frame)
    s = scorer.score
    return {
        "ate_rmse_m": _finite(ate),
        "tracked": int(summary.get("tracked", 0)),
        "lost": int(summary.get("lost", 0)),
        "frames": int(summary.get("frames", 0)),
        "keyframes": int(summary.get("keyframes", 0)),
        "loops": int(summary.get("loops", 0)),
        "precision": _finite(s.precision) if has_truth else float("nan"),
        "recall": _finite(s.recall) if has_truth else float("nan"),
        "precision_at_rest_ok": _finite(scorer.precision_at_rest_ok) if has_truth else float("nan"),
        "precision_away": _finite(scorer.away_from_outlines.precision) if has_truth else float("nan"),
        "recall_away": _finite(scorer.away_from_outlines.recall) if has_truth else float("nan"),
        "tp": s.tp, "fp": s.fp, "fn": s.fn, "fn_without_depth": scorer.fn_without_depth,
        "ms_per_frame": _finite(total),
        "screen_ms": float(np.nanmedian(screen)) if filters != "none" and np.isfinite(screen).any() else float("nan"),
        "run_dir": str(run_dir),
    }


def resumable_run(root: Path, run_dir: Path, config: Config, fingerprint: str, filters: str, detector: str,
                  loop_closing: bool, max_frames: int | None, resume: bool, progress: bool = False) -> dict:
    """:func:`run_one` on the sequence at ``root``, or its row from ``run_dir/row.json`` when ``resume`` and that
    run was finished with the same sequence, filters, detector, frames, loop closing and configuration
    (``fingerprint``); a fresh row is saved there."""
    key = {"sequence": str(root), "filters": filters, "detector": detector, "max_frames": max_frames,
           "loop_closing": loop_closing, "config": fingerprint}
    row_path = run_dir / "row.json"
    if resume and row_path.is_file():
        try:
            saved = json.loads(row_path.read_text())
            if saved.get("key") == key:
                return saved["row"]
        except (OSError, ValueError, KeyError):
            pass
    row = run_one(TumSequence(root), run_dir, config, filters, detector, loop_closing, max_frames, progress)
    _write_text(row_path, json.dumps({"key": key, "row": row}, indent=1))
    return row


def _filters(onnx_model: str | Path | None, only=None, what: str = "robustness",
             also: tuple[str, ...] = (REFERENCE,)) -> dict[str, tuple[str, str]]:
    """Filter label -> ``(--filters, --detector)``: :data:`FILTERS`, with ``full+onnx`` when ``onnx_model`` is given
    (which must exist), restricted to the labels ``only`` when given; a label neither there nor in ``also`` is an error
    naming ``what`` asked for it."""
    out = dict(FILTERS)
    if onnx_model is not None:
        model = Path(onnx_model)
        if not model.is_file():
            raise FileNotFoundError(f"{model}: ONNX model not found (--model)")
        out = {**{k: v for k, v in out.items() if k != "oracle masks"}, "full+onnx": ("full", f"onnx:{model}"),
               "oracle masks": FILTERS["oracle masks"]}
    if only is not None:
        unknown = [f for f in only if f not in out and f not in also]
        if unknown:
            raise ValueError(f"{what}: unknown filters {unknown}; choose from {list(out) + list(also)}"
                             + ("" if onnx_model is not None else " (full+onnx needs an ONNX model)"))
        out = {k: v for k, v in out.items() if k in only}
    return out


def run_robustness(sequences, outdir: str | Path, config: Config | None = None, onnx_model: str | Path | None = None,
                   filters=None, max_frames: int | None = None, loop_closing: bool = True, progress: bool = False,
                   resume: bool = True, on_run=None) -> pd.DataFrame:
    """Run every filter (and the reference without movers) on every sequence; write the tables.

    Parameters
    ----------
    sequences : :class:`SequenceSpec` list.
    outdir : gets ``robustness.csv``, ``robustness.md``, ``robustness.png`` and one run folder per
        (sequence, filter).
    config : root configuration of every run (defaults when None).
    onnx_model : an ONNX detector for the ``full+onnx`` filter (skipped when None).
    filters : labels to run (default all of :data:`FILTERS`, ``full+onnx`` and :data:`REFERENCE`).
    max_frames : frames per run (None = all).
    loop_closing : run the loop closer (its accepted loops are counted).
    resume : reuse the ``row.json`` of runs already finished with the same configuration.
    progress : a progress bar per run.
    on_run : called as ``on_run(row)`` after each run (a dict of the row), e.g. to print a line.

    Returns
    -------
    DataFrame, one row per run: ``sequence, filter, detector, room, camera, coverage_mean, coverage_max`` and
    the columns of :func:`run_one`, then ``ate_vs_none``, ``ate_vs_reference``, ``ate_vs_oracle``.
    """
    config = config if config is not None else Config()
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    specs = _filters(onnx_model, filters)
    want_reference = filters is None or REFERENCE in filters
    fingerprint = json.dumps(config_to_dict(config), sort_keys=True, default=str)
    rows = []
    for spec in sequences:
        meta = _metadata(spec.root)  # read once: coverage and kind of scene
        cov_mean, cov_max = _coverage(meta)
        room, camera = _kind(meta)
        jobs = [(label, spec.root, f, d) for label, (f, d) in specs.items()]
        if want_reference and spec.reference is not None:
            jobs.append((REFERENCE, spec.reference, "none", "none"))
        for label, root, filt, det in jobs:
            run_dir = outdir / spec.name / label.replace(" ", "_").replace("+", "_")
            row = resumable_run(root, run_dir, config, fingerprint, filt, det, loop_closing, max_frames, resume, progress)
            rows.append({"sequence": spec.name, "filter": label, "detector": det, "room": room, "camera": camera,
                         "coverage_mean": cov_mean, "coverage_max": cov_max, **row})
            if on_run is not None:
                on_run(rows[-1])
    df = _derived(pd.DataFrame(rows))
    _write_text(outdir / "robustness.csv", df.to_csv(index=False))
    _write_text(outdir / "robustness.md", robustness_markdown(df))
    if len(df):
        robustness_plot(df, outdir / "robustness.png")
    return df


def _derived(df: pd.DataFrame) -> pd.DataFrame:
    """Ratios of each run's ATE to ``none``, to the reference without movers and to perfect masks."""
    if len(df) == 0:
        return df
    by = {(s, f): a for s, f, a in zip(df["sequence"], df["filter"], df["ate_rmse_m"])}

    def ratio(s, a, other):
        b = by.get((s, other), float("nan"))
        return a / b if b and math.isfinite(b) and b > 0 and math.isfinite(a) else float("nan")

    df = df.copy()
    df["ate_vs_none"] = [ratio(s, a, "none") for s, a in zip(df["sequence"], df["ate_rmse_m"])]
    df["ate_vs_reference"] = [ratio(s, a, REFERENCE) for s, a in zip(df["sequence"], df["ate_rmse_m"])]
    df["ate_vs_oracle"] = [ratio(s, a, "oracle masks") for s, a in zip(df["sequence"], df["ate_rmse_m"])]
    return df


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    """Per filter over the sequences: the worst and the typical (median) value of each measure.

    Worst is the largest ATE, ratio, lost frames, loops and time, and the smallest precision and recall.
    """
    cols_hi = ["ate_rmse_m", "ate_vs_none", "ate_vs_reference", "ate_vs_oracle", "lost", "loops", "ms_per_frame", "screen_ms"]
    cols_lo = list(_LOW_IS_WORSE)
    out = []
    for label, g in df.groupby("filter", sort=False):
        row = {"filter": label, "sequences": len(g)}
        for c in cols_hi + cols_lo:  # (tables of runs made before a column was added lack it)
            v = pd.to_numeric(g[c], errors="coerce") if c in g else pd.Series(dtype=float)
            worst = v.min() if c in cols_lo else v.max()
            row[f"{c} worst"] = float(worst) if v.notna().any() else float("nan")
            row[f"{c} typical"] = float(v.median()) if v.notna().any() else float("nan")
        out.append(row)
    return pd.DataFrame(out)


def by_kind(df: pd.DataFrame, column: str) -> pd.DataFrame:
    """Per filter and value of ``column`` (``room`` or ``camera``): how many sequences, how many within
    :data:`ATE_BOUND_M` of ATE, the median and the worst ATE, the median keypoint precision and recall. Filters in
    the order they first appear, values sorted."""
    if len(df) == 0 or column not in df:
        return pd.DataFrame(columns=["filter", column, "sequences", "within", "ate_median", "ate_worst",
                                     "precision_median", "recall_median"])
    out = []
    for label in pd.unique(df["filter"]):
        g = df[df["filter"] == label]
        for value in sorted(pd.unique(g[column].astype(str))):
            h = g[g[column].astype(str) == value]
            ate = pd.to_numeric(h["ate_rmse_m"], errors="coerce")
            p, r = (pd.to_numeric(h[c], errors="coerce") for c in ("precision", "recall"))
            out.append({"filter": label, column: value, "sequences": len(h), "within": int((ate <= ATE_BOUND_M).sum()),
                        "ate_median": float(ate.median()) if ate.notna().any() else float("nan"),
                        "ate_worst": float(ate.max()) if ate.notna().any() else float("nan"),
                        "precision_median": float(p.median()) if p.notna().any() else float("nan"),
                        "recall_median": float(r.median()) if r.notna().any() else float("nan")})
    return pd.DataFrame(out)


def _fmt(v, digits: int = 3) -> str:
    if v is None:
        return "-"
    if isinstance(v, (float, np.floating)):
        return "-" if not math.isfinite(float(v)) else f"{float(v):.{digits}f}"
    return str(v)


def robustness_markdown(df: pd.DataFrame) -> str:
    """The benchmark as markdown: the targets, worst and typical per filter, then every run."""
    if len(df) == 0:
        return "# Robustness\n\n(no runs)\n"
    lines = ["# Robustness of the dynamic-feature filters", ""]
    summ = summarise(df)
    lines += ["Worst / typical (median) over the sequences. ATE in metres; ratios to `none`, to the same path "
              "without movers, to perfect masks; P / R = keypoint precision / recall; P rest = precision when "
              "keeping a mover at rest out counts as right (false positives only on things that never move); P / R "
              "away = the keypoints beyond 4 px of every moving outline only (a corner on an outline moves with the "
              "mover on either side of it).", ""]
    head = ["filter", "n", "ATE", "ATE/none", "ATE/no movers", "ATE/oracle", "P", "R", "P rest", "P away", "R away", "lost",
            "loops", "ms/frame", "screen ms"]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|---" * len(head) + "|")
    for _, r in summ.iterrows():
        def wt(c, d=3):
            return f"{_fmt(r[f'{c} worst'], d)} / {_fmt(r[f'{c} typical'], d)}"
        lines.append("| " + " | ".join([str(r["filter"]), str(r["sequences"]), wt("ate_rmse_m", 4), wt("ate_vs_none", 2),
                                        wt("ate_vs_reference", 2), wt("ate_vs_oracle", 2), wt("precision"), wt("recall"),
                                        wt("precision_at_rest_ok"), wt("precision_away"), wt("recall_away"), wt("lost", 0),
                                        wt("loops", 0), wt("ms_per_frame", 0), wt("screen_ms", 1)]) + " |")
    lines += ["", "## Targets (issue 16)", ""]
    for label, col, bound, text in TARGETS:
        g = df[df["filter"] == label]
        v = pd.to_numeric(g[col], errors="coerce").dropna() if len(g) else pd.Series(dtype=float)
        if len(v) == 0:
            lines.append(f"- {text}: not measured")
            continue
        worse = v > bound if col not in _LOW_IS_WORSE else v < bound
        fails = [s for s, bad in zip(g.loc[v.index, "sequence"], worse) if bad]
        lines.append(f"- {text}: met on {len(v) - len(fails)} of {len(v)}"
                     + (f" (missed on: {', '.join(fails)})" if fails else ""))
        if label == "geometry" and col.startswith("ate") and "coverage_max" in g:
            cover = pd.to_numeric(g.loc[v.index, "coverage_max"], errors="coerce")
            scope = cover <= TARGET_COVERAGE
            missed = int((worse & scope).sum())
            lines.append(f"  - on the {int(scope.sum())} sequences whose movers cover at most {TARGET_COVERAGE:.0%} of the "
                         f"image (the issue's scope): met on {int(scope.sum()) - missed}")
    ref = df[df["filter"] == REFERENCE]
    lost = pd.to_numeric(ref["lost"], errors="coerce") if "lost" in ref else pd.Series(dtype=float)
    frames = pd.to_numeric(ref["frames"], errors="coerce") if "frames" in ref else pd.Series(dtype=float)
    untracked = [s for s, n_lost, n in zip(ref["sequence"], lost, frames) if n > 0 and n_lost > REFERENCE_LOST_SHARE * n]
    if untracked:  # the static world alone gives a feature-based system too little: no filter can be judged there
        lines.append(f"- the same path without movers lost more than {REFERENCE_LOST_SHARE:.0%} of its frames on: "
                     f"{', '.join(untracked)} (the static world alone does not track; the ratios to it are undefined)")
    for column, title in (("room", "room surfaces"), ("camera", "camera motion")):
        kinds = by_kind(df, column)
        if len(kinds) == 0 or set(kinds[column]) <= {"-"}:
            continue
        lines += ["", f"## By {title}", "",
                  f"Sequences, how many within {ATE_BOUND_M} m of ATE, the median and worst ATE (m), the median keypoint "
                  "precision and recall.", ""]
        head = ["filter", column, "n", f"<= {ATE_BOUND_M} m", "ATE median", "ATE worst", "P median", "R median"]
        lines.append("| " + " | ".join(head) + " |")
        lines.append("|---" * len(head) + "|")
        for _, r in kinds.iterrows():
            lines.append("| " + " | ".join([str(r["filter"]), str(r[column]), str(r["sequences"]), str(r["within"]),
                                            _fmt(r["ate_median"], 4), _fmt(r["ate_worst"], 4), _fmt(r["precision_median"]),
                                            _fmt(r["recall_median"])]) + " |")
    lines += ["", "## Every run", ""]
    cols = ["sequence", "filter", "room", "camera", "coverage_mean", "coverage_max", "ate_rmse_m", "ate_vs_none",
            "ate_vs_reference", "precision", "recall", "precision_at_rest_ok", "precision_away", "recall_away", "lost",
            "loops", "keyframes", "ms_per_frame",
            "screen_ms"]
    cols = [c for c in cols if c in df]  # tables of runs made before a column was added
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|---" * len(cols) + "|")
    digits = {"ate_rmse_m": 4, "ms_per_frame": 0, "screen_ms": 1, "coverage_mean": 2, "coverage_max": 2,
              "ate_vs_none": 2, "ate_vs_reference": 2}
    for _, r in df.iterrows():
        lines.append("| " + " | ".join(_fmt(r[c], digits.get(c, 3)) for c in cols) + " |")
    return "\n".join(lines) + "\n"


def _sequence_labels(df: pd.DataFrame, seqs: list[str]) -> list[str]:
    """Each sequence's name with ``room, camera`` under it when the rows know them (failures cluster by room:
    docs/robustness.md)."""
    kind = {}
    if "room" in df and "camera" in df:
        kind = {s: f"{r}, {c}" for s, r, c in zip(df["sequence"], df["room"], df["camera"]) if str(r) != "-"}
    return [f"{s}\n{kind[s]}" if s in kind else s for s in seqs]


def robustness_plot(df: pd.DataFrame, path: str | Path) -> Path:
    """ATE per sequence and filter (log scale; the reference without movers as a line; each sequence labelled with
    its room and camera motion when known), written to ``path``."""
    # optional heavy dependency: only the plot needs it. A Figure without pyplot: no global backend switch
    # (matplotlib.use("Agg") here turned off a notebook's inline figures after run_robustness)
    from matplotlib.figure import Figure  # heavy: only for the plot

    seqs = list(dict.fromkeys(df["sequence"]))
    labels = [f for f in dict.fromkeys(df["filter"]) if f != REFERENCE]
    fig = Figure(figsize=(max(6.0, 1.1 * len(seqs) + 2), 4.2))
    ax = fig.subplots()
    width = 0.8 / max(len(labels), 1)
    x = np.arange(len(seqs))
    for k, label in enumerate(labels):
        g = df[df["filter"] == label].set_index("sequence")
        vals = [float(g.loc[s, "ate_rmse_m"]) if s in g.index else np.nan for s in seqs]
        ax.bar(x + (k - (len(labels) - 1) / 2) * width, vals, width, label=label)
    ref = df[df["filter"] == REFERENCE].set_index("sequence")
    for i, s in enumerate(seqs):
        if s in ref.index:
            ax.hlines(float(ref.loc[s, "ate_rmse_m"]), i - 0.45, i + 0.45, colors="k", linestyles="--", linewidth=1)
    ax.axhline(0.05, color="r", linewidth=0.8, linestyle=":", label="0.05 m target")
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels(_sequence_labels(df, seqs), rotation=30, ha="right")
    ax.set_ylabel("ATE RMSE (m), log scale")
    ax.set_title("ATE per sequence and filter (dashed: same path without movers)")
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    path = Path(path)
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=110, format=path.suffix.lstrip(".") or "png"))
    return path
