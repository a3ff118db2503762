"""ORB extraction with and without the keypoint budget: CPU milliseconds per frame, one thread.

The budget (``extract_features(..., region=, region_share=)``, docs/robustness.md "ORB budget")
splits the 1,000 keypoints between a dynamic region and the rest of the image. Its cost against the
plain extraction is what this prints (docs/speed.md): per frame the region is the renderer's moving
pixels grown by ``orb.prior_dilate_px`` (what the screener's prior region looks like), with the
region's share of a screening filter (``orb.prior_region_share``, 0.25) and of perfect masks
(``orb.truth_region_share``, 0), and how many OpenCV detections each budgeted frame needed.
Frames are decoded before timing; OpenCV runs on one thread; best of ``--repeat`` passes.

Usage::

    python benchmarks/orb_speed.py                          # walking_xyz, every 10th of 300 frames
    python benchmarks/orb_speed.py --preset crowd_rpy --frames 240 --step 5
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="walking_xyz", help="synthetic preset with movers (default walking_xyz)")
    ap.add_argument("--frames", type=int, default=300, help="frames rendered (default 300)")
    ap.add_argument("--step", type=int, default=10, help="use every STEP-th frame (default 10)")
    ap.add_argument("--repeat", type=int, default=3, help="timed passes; the best is shown (default 3)")
    args = ap.parse_args(argv)
    if args.step < 1 or args.repeat < 1:
        ap.error("--step and --repeat must be >= 1")

    import cv2

    from dynslam_lab.datasets.synthetic import synthetic_sequence
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.dynamic.oracle import moving_mask
    from dynslam_lab.features.orb import OrbConfig, budget_candidates, extract_features, region_quotas

    cv2.setNumThreads(1)
    cfg = OrbConfig()
    seq = TumSequence(synthetic_sequence(args.preset, n_frames=args.frames))
    frames = [seq[i] for i in range(0, len(seq), args.step)]
    grow = np.ones((2 * cfg.prior_dilate_px + 1,) * 2, np.uint8)
    pairs = []
    for f in frames:
        mask = moving_mask(f)
        if mask is not None and mask.any():
            pairs.append((f.gray, cv2.dilate(mask.astype(np.uint8), grow) > 0))
    if not pairs:
        raise SystemExit(f"error: {args.preset} has no moving pixels in the frames used")

    def best_ms(fn) -> float:
        times = []
        for _ in range(args.repeat):
            t0 = time.process_time()
            for gray, region in pairs:
                fn(gray, region)
            times.append(time.process_time() - t0)
        return 1e3 * min(times) / len(pairs)

    plain = best_ms(lambda g, r: extract_features(g, cfg))
    print(f"{args.preset}: {len(pairs)} frames with movers, region {100 * np.mean([r.mean() for _, r in pairs]):.0f} % "
          f"of the image (mean)\n")
    print("| extraction | region share | ms per frame | ratio to plain | OpenCV detections per frame (frames) |")
    print("|---|---|---|---|---|")
    print(f"| plain | - | {plain:.1f} | 1.00 | 1 |")
    for label, share in (("budget, screened prior", cfg.prior_region_share), ("budget, perfect masks", cfg.truth_region_share)):
        ms = best_ms(lambda g, r: extract_features(g, cfg, region=r, region_share=share))
        dets = np.bincount([budget_candidates(g, cfg, r, region_quotas(r, cfg, share)[0])[3] for g, r in pairs])
        counts = ", ".join(f"{k}: {n}" for k, n in enumerate(dets) if n)
        print(f"| {label} | {share:g} | {ms:.1f} | {ms / plain:.2f} | {counts} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
