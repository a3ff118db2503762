"""Where a filter's false positives lie: keypoints judged dynamic on static points, split by kind (movers at
rest, then the distance from the nearest moving outline) and by the stage that flagged them.

Usage::

    python benchmarks/false_positives.py --sequences crowd_rpy,panel_rpy --frames 240
    python benchmarks/false_positives.py --sequences random_113 --filters geometry,full+oracle --config before.toml
    python benchmarks/false_positives.py --roots COPY1,COPY2   # any rendered folders (e.g. camera-effect copies)

Renders (cached) each synthetic sequence (stress scenes, ``random_N``, office presets) and runs each filter
(``geometry`` = no detector; ``NAME+oracle`` with the oracle detector) without loop closing, scored against
the renderer's truth (``dynslam_lab.experiments.scoring.KeypointScorer``). Prints one markdown row per run: ATE,
keypoint precision / recall, the false positives by kind (``FP_KINDS``), the stages that flagged most of them,
the misses (false negatives) on the movers' silhouettes and inside them (``FN_KINDS``), the misses without a depth
reading, and the precision / recall of the keypoints farther than ``OUTLINE_BAND_PX`` (4 px) from every moving
outline (``KeypointScorer.away_from_outlines``). A second table gives, where the sequence has the renderer's
``coverage.csv``, the recall by the movers' image speed (``recall_by_image_speed``: px a frame, roughly), and a
third the misses by how much of their mover the frame found (none, fewer than half, half or more of its keypoints
judged dynamic), below and above 2 px a frame, with a line of totals over the scenes.
docs/robustness.md ("Where the false positives are", "Where the misses are", "What the misses are made of") reads
such tables.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", default="crowd_rpy,panel_rpy", help="comma-separated stress scenes, random_N or office presets")
    ap.add_argument("--roots", default=None, help="comma-separated folders of rendered sequences (with masks), e.g. camera-effect copies")
    ap.add_argument("--frames", type=int, default=240, help="frames rendered and run per sequence (default 240)")
    ap.add_argument("--filters", default="geometry", help="comma-separated: a filter (no detector) or FILTER+oracle")
    ap.add_argument("--config", default=None, help="a TOML file of parameters for every run")
    ap.add_argument("--out", default=None, help="folder for the run outputs (default: a temporary folder)")
    args = ap.parse_args(argv)

    from dynslam_lab.config import Config, load_config
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.experiments.robustness import root_specs, run_one, synthetic_specs
    from dynslam_lab.datasets.synthetic import read_coverage
    from dynslam_lab.experiments.scoring import FN_KINDS, FP_KINDS, IMAGE_SPEED_EDGES_PX, KeypointScorer, recall_by_image_speed

    config = load_config(args.config, Config()) if args.config else Config()
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="false_positives_"))
    if args.roots:
        try:
            specs = root_specs(args.roots)
        except ValueError as exc:
            ap.error(str(exc))
    else:
        specs = synthetic_specs([n.strip() for n in args.sequences.split(",") if n.strip()], n_frames=args.frames)
    print("| scene | filter | ATE m | P / R | " + " | ".join(f"FP {k}" for k in FP_KINDS) + " | stages (FP) | "
          + " | ".join(f"FN {k}" for k in FN_KINDS) + " | FN no depth | P / R away from outlines |")
    print("|---|---|---|---|" + "---|" * (len(FP_KINDS) + 3 + len(FN_KINDS)))
    t0 = time.time()
    speed_rows = []
    for spec in specs:
        for label in (f.strip() for f in args.filters.split(",") if f.strip()):
            filters, _, detector = label.partition("+")
            scorer = KeypointScorer()
            seq = TumSequence(spec.root)
            r = run_one(seq, out / f"{spec.name}_{label.replace('+', '_')}", config, filters,
                        detector or "none", loop_closing=False, scorer=scorer)
            kinds = scorer.fp_by_kind
            stages = ", ".join(f"{k or '?'} {v}" for k, v in scorer.fp_by_stage.most_common(3))
            away = scorer.away_from_outlines
            print(f"| `{spec.name}` | {label} | {r['ate_rmse_m']:.4f} | {r['precision']:.2f} / {r['recall']:.2f} | "
                  + " | ".join(f"{kinds[k]:,}" for k in FP_KINDS) + f" | {stages} | "
                  + " | ".join(f"{scorer.fn_by_kind[k]:,}" for k in FN_KINDS)
                  + f" | {scorer.fn_without_depth:,} | {away.precision:.2f} / {away.recall:.2f} |", flush=True)
            if (spec.root / "coverage.csv").is_file() and scorer.by_instance:
                rows = recall_by_image_speed(scorer.by_instance, read_coverage(spec.root), seq.camera.fx)
                speed_rows.append((spec.name, label, rows))
    if speed_rows:
        bins = [row["bin"] for row in speed_rows[0][2]]
        print(f"\nrecall by the movers' image speed (px a frame, roughly; bins {IMAGE_SPEED_EDGES_PX}): recall (keypoints, "
              "share of the misses)\n")
        print("| scene | filter | " + " | ".join(bins) + " |")
        print("|---|---|" + "---|" * len(bins))
        for name, label, rows in speed_rows:
            cells = [f"{row['recall']:.2f} ({row['keypoints']:,}, {100 * row['miss_share']:.0f} %)" if row["keypoints"] else "-"
                     for row in rows]
            print(f"| `{name}` | {label} | " + " | ".join(cells) + " |")
        print("\nthe misses by how much of their mover the frame found (keypoints; per frame and moving instance: no "
              "keypoint judged dynamic / fewer than half / half or more), below and above 2 px a frame, and two of the crossings\n")
        print("| scene | filter | misses | mover not found | found in part | mostly found | below 2 px a frame | 2 px or more "
              "| not found, below 2 px | in part, 2 px or more |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        total = np.zeros(8, np.int64)
        for name, label, rows in speed_rows:
            lows = (0.0, *IMAGE_SPEED_EDGES_PX)  # each row's lower edge (px a frame), in the rows' order
            slow = [r for r, low in zip(rows, lows) if low < 2.0]
            fast = [r for r, low in zip(rows, lows) if low >= 2.0]
            n_slow = sum(r["keypoints"] - r["dynamic"] for r in slow)
            n_fast = sum(r["keypoints"] - r["dynamic"] for r in fast)
            parts = [sum(r[k] for r in rows) for k in ("miss_unfound", "miss_in_part", "miss_mostly_found")]
            vals = np.array([n_slow + n_fast, *parts, n_slow, n_fast, sum(r["miss_unfound"] for r in slow),
                             sum(r["miss_in_part"] for r in fast)], np.int64)
            total += vals
            print(f"| `{name}` | {label} | " + " | ".join(f"{v:,}" for v in vals) + " |")
        if len(speed_rows) > 1:
            print("| all | | " + " | ".join(f"{v:,} ({100 * v / max(total[0], 1):.0f} %)" if i else f"{v:,}"
                                            for i, v in enumerate(total)) + " |")
    print(f"\n{len(specs)} sequences in {time.time() - t0:.0f} s; runs in {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
