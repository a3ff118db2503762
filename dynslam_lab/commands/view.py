"""``dynslam view``: the 3D scene of a run in the browser (viser).

Example::

    dynslam view runs/walking_xyz                 # http://127.0.0.1:8080
    dynslam view runs/walking_xyz --port 8090 --gt data/walking_xyz/groundtruth.txt

Shows the estimated and ground-truth trajectories, keyframe frustums with thumbnails, the
sparse map (static / dynamic), the dense map ``map.ply``, loop edges, and a playback slider.
The server listens on 127.0.0.1 only, unless ``--host`` says otherwise.
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "view",
        help="show a run's trajectories, keyframes and maps in the browser (viser)",
        description=(
            "Start a viser server showing the run folder OUTDIR written by 'dynslam run': "
            "trajectories, keyframe frustums with thumbnails, sparse and dense maps, loop edges, "
            "and a playback slider. Open the printed address in a browser; Ctrl+C stops."
        ),
    )
    p.add_argument("outdir", metavar="OUTDIR", help="output folder of 'dynslam run'")
    p.add_argument("--port", type=int, default=8080, help="TCP port (default 8080; the next free one if taken)")
    p.add_argument(
        "--host", default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only; 0.0.0.0 exposes the scene to the network)",
    )
    p.add_argument("--gt", default=None, metavar="FILE",
                   help="ground-truth trajectory (TUM format); default: the sequence's groundtruth.txt if known")
    p.add_argument("--max-dense-points", type=int, default=1_000_000, metavar="N",
                   help="send at most N points of map.ply (random subset; default 1,000,000)")
    p.add_argument("--timeout", type=float, default=None, metavar="S",
                   help="stop the server after S seconds (for scripts and tests; default: run until Ctrl+C)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys
    import threading
    import time
    from pathlib import Path

    from ..errors import UsageError
    from ..runs import verify_run
    from ..viz.viser_scene import SceneConfig, load_run, play_loop, start_viewer

    if not 0 < args.port < 65536:
        raise UsageError(f"--port must be in 1..65535, got {args.port}")
    if args.max_dense_points < 0:
        raise UsageError(f"--max-dense-points must be >= 0, got {args.max_dense_points}")
    if args.timeout is not None and not args.timeout >= 0:
        raise UsageError(f"--timeout must be >= 0 seconds, got {args.timeout}")
    t0 = time.perf_counter()
    data = load_run(args.outdir, ground_truth=args.gt, dense=False)  # map.ply is read in the background
    summary_file = Path(args.outdir) / "summary.json"
    if summary_file.is_file():  # sizes only: hashing map.ply would slow the start-up
        for problem in verify_run(args.outdir, hashes=False)[:5]:
            print(f"dynslam view: warning: {problem}", file=sys.stderr)
    t_load = time.perf_counter() - t0
    server, handles = start_viewer(data, port=args.port, host=args.host,
                                   config=SceneConfig(max_dense_points=args.max_dense_points))
    print(
        f"dynslam view: {args.outdir}: {len(data.trajectory) if data.trajectory is not None else 0} poses, "
        f"{data.n_keyframes} keyframes, "
        f"{0 if data.map_xyz is None else len(data.map_xyz)} map points, "
        f"{data.dense_count} dense points "
        f"(loaded in {t_load:.2f} s, first layers sent in {handles.build_seconds:.2f} s; keyframes, "
        f"sparse and dense maps follow once a browser connects)"
    )
    print(f"dynslam view: open http://{server.get_host()}:{server.get_port()}/  (Ctrl+C to stop)", flush=True)
    stop = threading.Event()
    player = threading.Thread(target=play_loop, args=(handles, stop), daemon=True)
    player.start()
    try:
        deadline = None if args.timeout is None else time.monotonic() + args.timeout
        reported = False
        while deadline is None or time.monotonic() < deadline:
            if not reported and handles.wait_complete(0.2):
                reported = True
                for err in handles.errors:
                    print(f"dynslam view: a layer was not shown: {err}", file=sys.stderr, flush=True)
                print("dynslam view: all layers sent (seconds per stage: "
                      + ", ".join(f"{x:.2f}" for x in handles.stage_seconds) + ")", flush=True)
            elif reported:
                time.sleep(0.2)
    finally:
        stop.set()
        handles.close()
        server.stop()
    return 0
