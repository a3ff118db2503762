"""Speed of the synthetic renderer: milliseconds per 640x480 frame, by stage and preset.

Run::

    python benchmarks/render_speed.py [--frames 10] [--presets walking_xyz sitting_rpy ...] [--threads N]
    python benchmarks/render_speed.py --suite      # the office presets and every scene of the stress suite
    taskset -c 0 python benchmarks/render_speed.py --threads 1     # one core, as the target is stated

Prints one row per preset: scene build (textures + atlas, once), then the median per frame of
ray casting, texturing + shading + sensor noise (the rest of a render), a whole render, and
writing the three PNGs of a frame. Stage times are CPU time of this process
(``time.process_time``, summed over threads: busy-waiting BLAS/OpenCV worker threads inflate
it), which varies less than wall time on a shared, busy machine; the wall time of a whole
render is printed too, with the load average. ``--threads`` sets OpenCV's thread count (default:
OpenCV's own choice). The target is < 30 ms per render on one idle core; stress scenes
(``dynslam_lab.datasets.stress``) should stay within 1.5x of the office presets. ``--suite`` adds
every scene of ``STRESS_SUITE`` and ``STRESS_LOOPS`` and prints their median render time over the
office presets' median (measured in the same run, so the machine's load affects both).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from dynslam_lab.datasets import scene as sc
from dynslam_lab.datasets import stress
from dynslam_lab.datasets.synthetic import PRESETS, SyntheticRenderer, _build_scene, _build_stress_full, preset_names


def bench(preset: str, n: int) -> dict:
    _build_scene.cache_clear()
    _build_stress_full.cache_clear()
    t0 = time.perf_counter()
    r = SyntheticRenderer(preset, seed=0)
    build = time.perf_counter() - t0
    idx = np.linspace(0, r.n_frames - 1, n).astype(int)
    ray, full, write, wall = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for i in idx:
            t = r.times[i]
            parts = r.scene.parts(t)
            a = time.process_time()
            sc.raycast(parts, r.camera, r.pose(t))
            b = time.process_time()
            w0 = time.perf_counter()
            f = r.render(int(i))
            wall.append(time.perf_counter() - w0)
            c = time.process_time()
            p = Path(tmp)
            png = [cv2.IMWRITE_PNG_COMPRESSION, 1]
            cv2.imwrite(str(p / "rgb.png"), f.rgb, png)
            cv2.imwrite(str(p / "depth.png"), (f.depth * 5000).astype(np.uint16), png)
            cv2.imwrite(str(p / "mask.png"), f.instance_mask.astype(np.uint16), png)
            d = time.process_time()
            ray.append(b - a)
            full.append(c - b)
            write.append(d - c)
    med = lambda x: 1000 * float(np.median(x))  # noqa: E731
    return {"preset": preset, "parts": len(parts), "build_s": build, "raycast": med(ray), "shade+noise": med(full) - med(ray),
            "render": med(full), "write": med(write), "wall": med(wall)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10, help="frames timed per preset (default 10)")
    ap.add_argument("--presets", nargs="*", default=["walking_xyz", "sitting_rpy", "static_halfsphere", "loop", "boxes_xyz",
                                                     "crowd_rpy", "loop_photo"])
    ap.add_argument("--suite", action="store_true", help="time the office presets and every stress suite and loop scene")
    ap.add_argument("--threads", type=int, default=None, help="OpenCV threads (cv2.setNumThreads); default OpenCV's choice")
    args = ap.parse_args()
    if args.threads is not None:
        if args.threads < 1:
            raise SystemExit(f"--threads must be >= 1, got {args.threads}")
        cv2.setNumThreads(args.threads)
    if args.suite:
        args.presets = ["walking_xyz", "sitting_rpy", "static_halfsphere", "loop"] + list(stress.STRESS_PRESETS)
    known = preset_names()
    for p in args.presets:
        if p not in known:
            raise SystemExit(f"unknown preset {p!r}; choose from {', '.join(known)}")
    import os

    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores, {cv2.getNumThreads()} OpenCV threads; "
          f"CPU ms per 640x480 frame (median of {args.frames})")
    print(f"{'preset':<20} {'parts':>5} {'build s':>8} {'raycast ms':>11} {'shade+noise ms':>15} {'render ms':>10} "
          f"{'write ms':>9} {'render wall ms':>15}")
    office, other = [], []
    for p in args.presets:
        r = bench(p, args.frames)
        (office if p in PRESETS else other).append(r["render"])
        print(f"{r['preset']:<20} {r['parts']:>5} {r['build_s']:>8.2f} {r['raycast']:>11.1f} {r['shade+noise']:>15.1f} "
              f"{r['render']:>10.1f} {r['write']:>9.1f} {r['wall']:>15.1f}")
    if office and other:
        ref = float(np.median(office))
        print(f"stress scenes / office presets, render ms: median {np.median(other) / ref:.2f}x, worst {max(other) / ref:.2f}x "
              f"(office median {ref:.1f} ms); target <= 1.5x")
    print("target: render < 30 ms per 640x480 frame on one idle core (numpy + OpenCV)")


if __name__ == "__main__":
    main()
