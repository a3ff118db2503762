"""Open3D's RGB-D odometry, frame to frame, as a peer of ``benchmarks/peers.py``.

Open3D (Zhou, Park & Koltun, "Open3D: A Modern Library for 3D Data Processing", 2018; MIT
licence; ``pip install -e ".[peers]"``) estimates the rigid motion between two RGB-D frames
by dense direct alignment, coarse to fine over an image pyramid:

* ``--method legacy``: ``open3d.pipelines.odometry.compute_rgbd_odometry`` with the hybrid
  Jacobian (``RGBDOdometryJacobianFromHybridTerm``): photometric error of the intensity plus
  the depth (geometric) error, Steinbruecker, Sturm & Cremers 2011 ("Real-time visual odometry
  from dense RGB-D images") with the depth term of Park, Zhou & Koltun 2017 ("Colored Point
  Cloud Registration Revisited");
* ``--method tensor``: ``open3d.t.pipelines.odometry.rgbd_odometry_multi_scale`` with its
  default ``Method.Hybrid`` (the same two terms, Huber-weighted, on the tensor pipeline).

Each frame is aligned to the previous tracked frame starting from the identity, and the motions
are chained: ``T_w_t = T_w_(t-1) @ T_(t-1)_t`` (Open3D returns the source-to-target transform,
source = frame t, target = frame t-1). There is no map, no keyframe, no loop closing: it is an
odometry, so its ATE drifts while its frame-to-frame error (RPE) shows the accuracy of dense
alignment. A frame whose odometry fails (legacy returns ``success = False``; tensor a fitness of
0) counts as lost, and the next frame is aligned to the last tracked one. Both methods use the
same depth range, ``--depth-max`` (4 m, the legacy ``OdometryOption`` default).

Usage::

    python benchmarks/peer_open3d.py SEQDIR --out DIR --method legacy|tensor [--max-frames N]
    python benchmarks/peer_open3d.py --check
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np

from peer_common import (
    PeerRecorder,
    check_import,
    load_frame_images,
    package_version,
    parse_peer_args,
    peer_parser,
    read_tum_frames,
    sequence_camera,
)

METHODS = ("legacy", "tensor")


class LegacyOdometry:
    """``compute_rgbd_odometry`` with the hybrid Jacobian on legacy ``RGBDImage``s."""

    def __init__(self, o3d, camera, depth_max: float) -> None:
        self.o3d = o3d
        self.depth_scale = float(camera.depth_scale)
        self.depth_max = float(depth_max)
        self.intrinsic = o3d.camera.PinholeCameraIntrinsic(
            int(camera.width), int(camera.height), camera.fx, camera.fy, camera.cx, camera.cy
        )
        self.option = o3d.pipelines.odometry.OdometryOption(depth_max=self.depth_max)
        self.jacobian = o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm()

    def image(self, rgb: np.ndarray, depth: np.ndarray):
        o3d = self.o3d
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(rgb), o3d.geometry.Image(depth), depth_scale=self.depth_scale,
            depth_trunc=self.depth_max, convert_rgb_to_intensity=True,
        )

    def motion(self, source, target) -> np.ndarray | None:
        """``T_target_source`` (4x4), or None when the odometry fails."""
        ok, T, _info = self.o3d.pipelines.odometry.compute_rgbd_odometry(
            source, target, self.intrinsic, np.eye(4), self.jacobian, self.option
        )
        return np.asarray(T) if ok else None


class TensorOdometry:
    """``t.pipelines.odometry.rgbd_odometry_multi_scale`` (``Method.Hybrid``) on tensor ``RGBDImage``s."""

    def __init__(self, o3d, camera, depth_max: float) -> None:
        self.o3d = o3d
        self.depth_scale = float(camera.depth_scale)
        self.depth_max = float(depth_max)
        self.K = o3d.core.Tensor(camera.K, dtype=o3d.core.Dtype.Float64)

    def image(self, rgb: np.ndarray, depth: np.ndarray):
        g = self.o3d.t.geometry
        return g.RGBDImage(g.Image(rgb), g.Image(depth))

    def motion(self, source, target) -> np.ndarray | None:
        r = self.o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
            source, target, self.K, depth_scale=self.depth_scale, depth_max=self.depth_max,
            method=self.o3d.t.pipelines.odometry.Method.Hybrid,
        )
        T = r.transformation.numpy()
        return T if r.fitness > 0 and np.isfinite(T).all() else None


def run(args) -> int:
    import open3d as o3d  # MIT, optional (the "peers" extra), ~1 s to import

    frames = read_tum_frames(args.seqdir, args.max_frames)
    camera = sequence_camera(args.seqdir, args.camera)
    name = f"open3d_{args.method}"
    rec = PeerRecorder(name, Path(args.seqdir), Path(args.out), camera)
    odo = (LegacyOdometry if args.method == "legacy" else TensorOdometry)(o3d, camera, args.depth_max)
    target = None  # the last tracked frame's image
    T_w_target = np.eye(4)
    for frame in frames:
        t0 = time.perf_counter()
        try:
            bgr, depth = load_frame_images(frame)
        except Exception as exc:  # a bad frame is logged and counted lost; the run goes on
            rec.error(frame, exc)
            continue
        rgb = np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
        t = time.perf_counter()
        source = odo.image(rgb, depth)
        T_target_source = np.eye(4) if target is None else odo.motion(source, target)
        dt = time.perf_counter() - t
        if T_target_source is None:
            rec.add(frame, 1000.0 * dt, None, decode_ms=1000.0 * (t - t0))
            continue
        T_w_target = T_w_target @ T_target_source
        target = source
        rec.add(frame, 1000.0 * dt, T_w_target, decode_ms=1000.0 * (t - t0))
    settings = {"method": args.method, "depth_max_m": args.depth_max, "depth_scale": camera.depth_scale,
                "init": "identity", "open3d": package_version("open3d-cpu") or package_version("open3d")}
    summary = rec.write(settings)
    print(f"{name}: {summary['tracked']}/{summary['frames']} frames tracked, "
          f"{summary['timing_mean_ms']['total']:.1f} ms per frame (mean)")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = peer_parser(__doc__.splitlines()[0])
    ap.add_argument("--method", choices=METHODS, default="tensor", help="legacy or tensor pipeline (default tensor)")
    ap.add_argument("--depth-max", type=float, default=4.0, metavar="M", help="farthest depth used, metres (4)")
    args = parse_peer_args(ap, argv)
    if args.check:
        return check_import("open3d")
    if not args.depth_max > 0:
        ap.error(f"--depth-max must be positive, got {args.depth_max}")
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
