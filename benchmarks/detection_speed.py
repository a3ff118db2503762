"""Per-model detection speed: preprocessing, network inference, decoding + NMS (+ masks).

Runs every ONNX model in ``../shared/data/models`` (or ``--models``) on the real TUM frames in
``../shared/data/tum/frames`` and prints one row per model and NMS kind with median times per
frame in milliseconds, and decode / inference as a percentage (the target is < 10 %: our
numpy after the network should cost little next to the network itself).

    python benchmarks/detection_speed.py                # all models, hard and soft NMS
    python benchmarks/detection_speed.py --repeats 20 --threads 2
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="*", type=Path, default=None, help="ONNX files (default: ../shared/data/models/*.onnx)")
    p.add_argument("--frames", nargs="*", type=Path, default=None, help="colour images (default: ../shared/data/tum/frames/*_rgb.png)")
    p.add_argument("--repeats", type=int, default=5, help="passes over the frames (default 5; median reported)")
    p.add_argument("--threads", type=int, default=0, help="onnxruntime intra-op threads (0 = its default)")
    args = p.parse_args(argv)

    import numpy as np

    from dynslam_lab.datasets import load_rgb
    from dynslam_lab.detection import DetectionConfig, OnnxDetector

    models = args.models or sorted((SHARED / "models").glob("*.onnx"))
    frames = args.frames or sorted((SHARED / "tum" / "frames").glob("*_rgb.png"))
    if not models or not frames:
        print(f"no models or frames found (looked in {SHARED})", file=sys.stderr)
        return 1
    images = [load_rgb(f) for f in frames]
    print(f"{len(images)} frames of {images[0].shape[1]}x{images[0].shape[0]}, {args.repeats} passes, "
          f"threads={args.threads or 'default'}; median ms per frame\n")
    header = f"{'model':<28}{'family':<12}{'input':>9}{'nms':>6}{'pre':>8}{'infer':>8}{'decode':>8}{'dec/inf':>9}{'dets':>6}"
    print(header)
    print("-" * len(header))
    for path in models:
        for nms in ("hard", "soft"):
            det = OnnxDetector(path, DetectionConfig(nms=nms, num_threads=args.threads))
            for img in images[:2]:  # warm-up (allocations, first-run graph optimisation)
                det.detect_image(img)
            pre, inf, dec, n = [], [], [], []
            for _ in range(args.repeats):
                for img in images:
                    d = det.detect_image(img)
                    pre.append(d.timings_ms["preprocess"])
                    inf.append(d.timings_ms["inference"])
                    dec.append(d.timings_ms["decode"])
                    n.append(len(d))
            m_pre, m_inf, m_dec = (statistics.median(v) for v in (pre, inf, dec))
            L = det.layout
            print(f"{path.name:<28}{L.family:<12}{L.input_size[1]:>5}x{L.input_size[0]:<3}{nms:>6}"
                  f"{m_pre:8.2f}{m_inf:8.2f}{m_dec:8.2f}{100 * m_dec / m_inf:8.1f}%{np.mean(n):6.1f}")
    # the suppression alone on many candidates (a crowded frame), our numpy vs OpenCV
    import cv2

    from dynslam_lab.detection import nms, soft_nms

    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 600, (1000, 2))
    boxes = np.concatenate([xy, xy + rng.uniform(20, 120, (1000, 2))], axis=1)
    scores = rng.random(1000)
    xywh = [[float(a), float(b), float(c - a), float(d - b)] for a, b, c, d in boxes]
    rows = [
        ("nms (ours)", lambda: nms(boxes, scores, 0.45)),
        ("cv2.dnn.NMSBoxes", lambda: cv2.dnn.NMSBoxes(xywh, scores.tolist(), 0.0, 0.45)),
        ("soft_nms (ours)", lambda: soft_nms(boxes, scores, 0.5, 0.3)),
    ]
    print(f"\nsuppression of 1000 random boxes (median of 20 runs, ms)")
    for name, fn in rows:
        t = []
        for _ in range(20):
            t0 = time.perf_counter()
            fn()
            t.append((time.perf_counter() - t0) * 1e3)
        print(f"  {name:<20}{statistics.median(t):8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
