"""Start-up time of ``dynslam view`` for a large run (target: first picture within 3 s for
1,000 keyframes).

Writes a demo run folder (``tests/fixtures/demo_run.py``; run from the repository root) with K keyframes, then measures

1. in process: ``load_run`` (read every file) and ``build_scene`` (send every layer);
2. the command: from launching ``dynslam view`` to its "open http://..." line (Python start,
   imports, loading, scene built, server listening);
3. the browser (when Chromium is installed): headless Chromium loading the page and
   rendering it to a screenshot, checked for trajectory-coloured pixels.

Usage::

    python benchmarks/view_startup.py                   # 1,000 keyframes
    python benchmarks/view_startup.py --keyframes 200 --dense 500000
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# the demo run and the Chromium driver are test fixtures (tests/fixtures/), not part of the package
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--keyframes", type=int, default=1000)
    ap.add_argument("--every", type=int, default=10, help="frames per keyframe (default 10)")
    ap.add_argument("--map-points", type=int, default=50_000)
    ap.add_argument("--dense", type=int, default=1_000_000, help="points of map.ply (default 1,000,000)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--keep", action="store_true", help="keep the run folder and screenshot")
    args = ap.parse_args()

    from tests.fixtures.demo_run import write_demo_run
    from dynslam_lab.viz.viser_scene import COLORS, SceneConfig, build_scene, free_port, load_run, open_server

    import viser  # noqa: F401  (imported here so that the server's start-up below excludes the import)

    tmp = Path(tempfile.mkdtemp(prefix="view_startup_"))
    try:
        t = time.perf_counter()
        run_dir = write_demo_run(tmp / "run", n_frames=args.keyframes * args.every, keyframe_every=args.every,
                                 n_map_points=args.map_points, n_dense_points=args.dense)
        print(f"demo run: {args.keyframes} keyframes, {args.keyframes * args.every} poses, "
              f"{args.map_points} map points, {args.dense} dense points (written in {time.perf_counter() - t:.1f} s)")
        rows = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            run = load_run(run_dir)
            t1 = time.perf_counter()
            server = open_server("127.0.0.1")  # viser server with the Host/Origin check
            t2 = time.perf_counter()
            build_scene(server, run, SceneConfig())
            t3 = time.perf_counter()
            server.stop()
            rows.append((t1 - t0, t2 - t1, t3 - t2))
        r = np.median(np.array(rows), axis=0)
        print("\n| step (in process, median of %d) | seconds |" % args.repeat)
        print("|---|---|")
        print(f"| load_run (read all files) | {r[0]:.3f} |")
        print(f"| start viser server (and its Host/Origin check) | {r[1]:.3f} |")
        print(f"| build_scene (send all layers) | {r[2]:.3f} |")

        from tests.fixtures.browser import HeadlessChromium, colour_pixels, find_chromium, outside_overlays

        browser = HeadlessChromium(1000, 700) if find_chromium() else None  # its own start-up is not the viewer's
        try:
            port = free_port()
            t0 = time.perf_counter()
            proc = subprocess.Popen([sys.executable, "-m", "dynslam_lab", "view", str(run_dir), "--port", str(port),
                                     "--timeout", "120"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            ready = None
            for line in proc.stdout:
                if "open http://" in line:
                    ready = time.perf_counter() - t0
                    break
            import threading

            threading.Thread(target=proc.stdout.read, daemon=True).start()  # keep the pipe drained
            print(f"\n| command | seconds |\n|---|---|\n| `dynslam view` launch -> listening, scene sent | {ready:.2f} |")
            if browser is not None:
                events: dict[str, float] = {}
                base = {}

                def masks(img):
                    px = img.astype(int)
                    grey = outside_overlays((px.max(axis=2) - px.min(axis=2) <= 2) & (px[..., 0] >= 115) & (px[..., 0] <= 225))
                    return (int(colour_pixels(img, COLORS["estimate"], 60).sum()),
                            int(colour_pixels(img, COLORS["keyframe"], 50).sum()), int(grey.sum()))

                def drawn(img):
                    t = time.perf_counter() - t0
                    r, o, g = masks(img)
                    if r > 200 and "first" not in events:
                        events["first"], base["grey"] = t, g
                    if "first" in events and o > 300 and "keyframes" not in events:
                        events["keyframes"] = t
                    if "first" in events and g > base["grey"] + 20000 and "dense" not in events:
                        events["dense"] = t
                    return len(events) == 3

                _, shots = browser.poll_screenshots(f"http://127.0.0.1:{port}/", drawn, timeout=90, interval=0.05)
                labels = {"first": "first picture (trajectories)", "keyframes": "keyframe frustums drawn",
                          "dense": "dense map drawn"}
                for key, label in labels.items():
                    v = f"{events[key]:.2f}" if key in events else "not within 90 s"
                    print(f"| `dynslam view` launch -> {label} | {v} |")
                print(f"\n(headless Chromium, SwiftShader software WebGL; {shots} screenshots polled)")
            else:
                print("(chromium not installed: time to the first picture not measured)")
            proc.terminate()
            proc.wait(timeout=20)
            proc.stdout.close()
        finally:
            if browser is not None:
                browser.close()
    finally:
        if "--keep" not in sys.argv:
            shutil.rmtree(tmp, ignore_errors=True)
        else:
            print("kept", tmp)
    return 0


if __name__ == "__main__":
    sys.exit(main())
