"""The room's image and depth as a witness of the camera's pose: docs/robustness.md, "The room's image as a witness".

The measurement is ``dynslam_lab.experiments.room_witness`` (notebook 10 plots it); this prints it.

When a textured mover that was mapped at rest starts slowly, the feature pose follows it a few millimetres a frame,
along the slide that plain walls leave free. This measures, frame by frame, whether the static room, its depth and
its image edges together, would have told where the camera was. For each frame ``t`` of a run
(``dynslam_lab.pipeline.build_pipeline``, any filter), the frame is aligned to frame ``t - offset``. The alignment
starts from the run's relative pose between the two. It uses the hybrid RGB-D terms of Steinbruecker et al. (2011):
point-to-plane depth (``geometry.depth_alignment.DenseTerm``) and intensity (``PhotometricTerm``) at
``1 / scale`` resolution. Gauss-Newton with Huber weights (``align_depth``) and a weak prior to the start. Which
pixels take part (``--pixels``):

* ``planes``: the pixels on the large planes of each frame's depth that nothing lies behind (``large_planes``,
  ``bounding_planes``: the walls, floor and ceiling; a mover standing on the floor is not on them, the face of a
  large box has the wall behind it), at least ``--margin`` px from every other pixel (a mover's edge runs through
  the pixels just beside it). No truth is used. A mover flat against a wall is still taken for the wall.
* ``oracle``: every pixel off the instances the renderer moves at some time (``moving.txt``), in both frames (a
  mover still at rest in the earlier frame is left out too): what the witness could do with perfect segmentation.
* ``all``: every pixel with depth.

Prints one row per frame: the run's error against the truth (relative to the earlier frame), the witness's error,
and the witness's cost ratio (the photometric cost at the run's pose over the cost at the witness's pose: how loudly
the room says the run is off). A summary follows. ``--out`` writes ``room_witness.csv``.

Usage::

    python benchmarks/room_witness.py random_401 --frames 40 --from-frame 10
    python benchmarks/room_witness.py SEQDIR --pixels oracle --filters geometry --out OUT
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from pathlib import Path

import numpy as np

from dynslam_lab.experiments.room_witness import PIXELS


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sequence", help="a synthetic scene name (random_N, a stress or office preset) or a rendered folder")
    ap.add_argument("--frames", type=int, default=60, help="frames run (a scene name: rendered with this many)")
    ap.add_argument("--from-frame", type=int, default=0, help="first frame printed and summarised")
    ap.add_argument("--offset", type=int, default=16, help="the earlier frame is this many frames back (step 3c's farthest)")
    ap.add_argument("--pixels", choices=PIXELS, default="planes", help="which pixels take part (module docstring)")
    ap.add_argument("--filters", default="geometry", help="the run's filter")
    ap.add_argument("--detector", default="none", help="the run's detector")
    ap.add_argument("--scale", type=int, default=2, help="image reduction of the photometric term")
    ap.add_argument("--margin", type=int, default=3, help="'planes': px (of the reduced image) kept from other pixels")
    ap.add_argument("--out", default=None, help="folder for room_witness.csv (default: a temporary folder)")
    args = ap.parse_args(argv)
    if args.offset < 1 or args.frames <= args.offset or args.scale < 1 or args.margin < 0:
        ap.error("--offset >= 1, --frames > --offset, --scale >= 1 and --margin >= 0 required")

    from dynslam_lab.config import Config
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.experiments.robustness import synthetic_root
    from dynslam_lab.experiments.room_witness import measure_witness
    from dynslam_lab.pipeline import build_pipeline

    root = Path(args.sequence)
    if not root.is_dir():
        try:
            root = synthetic_root(args.sequence, n_frames=args.frames)
        except ValueError as exc:
            ap.error(f"{args.sequence}: not a folder, nor a synthetic scene ({exc})")
    seq = TumSequence(root)
    system = build_pipeline(Config(), seq.camera, detector=args.detector, filters=args.filters, loop_closing=False)
    rows = []
    print(f"| frame | earlier | run mm | run deg | witness mm | witness deg | cost ratio |  ({root.name}, "
          f"{args.filters}, pixels: {args.pixels})")
    print("|---|---|---|---|---|---|---|")
    try:
        for r in measure_witness(seq, system, args.frames, args.offset, args.pixels, args.scale, args.margin,
                                 args.from_frame):
            rows.append((r.frame, r.earlier, r.run_mm, r.run_deg, r.witness_mm, r.witness_deg, r.cost_ratio))
            print(f"| {r.frame} | {r.earlier} | {r.run_mm:.1f} | {r.run_deg:.2f} | {r.witness_mm:.1f} | "
                  f"{r.witness_deg:.2f} | {r.cost_ratio:.2f} |")
    except (FileNotFoundError, ValueError) as exc:
        ap.error(str(exc))
    if not rows:
        print("no frame with a pose and an earlier frame with one: nothing measured", file=sys.stderr)
        return 1
    a = np.array([r[2:] for r in rows], np.float64)
    print(f"\n{len(rows)} frames: run error median {np.median(a[:, 0]):.1f} mm (max {a[:, 0].max():.1f}); "
          f"witness median {np.median(a[:, 2]):.1f} mm (max {a[:, 2].max():.1f}); the witness closer to the truth on "
          f"{int((a[:, 2] < a[:, 0]).sum())} frames; cost ratio median {np.nanmedian(a[:, 4]):.2f}")
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="room_witness_"))
    out.mkdir(parents=True, exist_ok=True)
    from dynslam_lab.runs.folder import atomic_write

    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="") as fh:
            wr = csv.writer(fh)
            wr.writerow(["frame", "earlier", "run_mm", "run_deg", "witness_mm", "witness_deg", "cost_ratio"])
            wr.writerows(rows)

    atomic_write(out / "room_witness.csv", write)
    print(f"wrote {out / 'room_witness.csv'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
