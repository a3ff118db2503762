"""Frame-to-frame accuracy of tracking: dynslam's RPE against Open3D's RGB-D odometry.

Issue 17: Open3D's legacy ``compute_rgbd_odometry`` (hybrid photometric + depth term, frame to
frame, chained) reaches ~2 mm RPE on static synthetic scenes. This prints, per sequence, the RPE
(1 frame, translation RMSE in mm, rotation RMSE in deg) and the ATE (mm) of dynslam (filters
``none``, loop closing on) and of Open3D when it is installed (``pip install open3d``), plus the
worst case and the median over sequences. ``--set section.field=value`` changes the dynslam config
(experiments).

    python benchmarks/tracking_rpe.py                                  # 3 static presets x 2 seeds, 120 frames
    python benchmarks/tracking_rpe.py --presets static_xyz --seeds 0 --frames 60 --no-open3d
    python benchmarks/tracking_rpe.py --set orb.subpixel=false
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np


def _config(sets: list[str]):
    from dynslam_lab.config import Config

    cfg = Config()
    for s in sets:
        key, value = s.split("=", 1)
        section, name = key.split(".")
        sub = getattr(cfg, section)
        old = getattr(sub, name)
        v = {"true": True, "false": False}.get(value.lower(), value) if isinstance(old, bool) else type(old)(value)
        cfg = replace(cfg, **{section: replace(sub, **{name: v})})
    return cfg


def run_dynslam(seq, frames, cfg):
    from dynslam_lab.pipeline import build_pipeline
    from dynslam_lab.threads import blas_single_thread

    system = build_pipeline(cfg, seq.camera)
    t0 = time.perf_counter()
    with blas_single_thread():
        for f in frames:
            system.process(f)
    return system.trajectory(), (time.perf_counter() - t0) / len(frames)


def run_open3d(seq, frames):
    import open3d as o3d  # optional heavy dependency (the peer)

    from dynslam_lab.evaluation.trajectory import Trajectory

    cam = seq.camera
    K = o3d.camera.PinholeCameraIntrinsic(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
    option = o3d.pipelines.odometry.OdometryOption()
    jac = o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm()

    def rgbd(f):
        return o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.ascontiguousarray(f.rgb)), o3d.geometry.Image(f.depth.astype(np.float32)),
            depth_scale=1.0, depth_trunc=8.0, convert_rgb_to_intensity=True)

    poses = [np.eye(4)]
    prev = rgbd(frames[0])
    t0 = time.perf_counter()
    for f in frames[1:]:
        cur = rgbd(f)
        ok, T_prev_cur, _ = o3d.pipelines.odometry.compute_rgbd_odometry(cur, prev, K, np.eye(4), jac, option)
        poses.append(poses[-1] @ (T_prev_cur if ok else np.eye(4)))
        prev = cur
    return Trajectory(np.array([f.timestamp for f in frames]), np.stack(poses)), (time.perf_counter() - t0) / len(frames)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="+", default=["static_xyz", "static_rpy", "static_halfsphere"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--no-open3d", action="store_true", help="dynslam only")
    ap.add_argument("--set", action="append", default=[], help="dynslam config override section.field=value")
    args = ap.parse_args()

    from dynslam_lab.datasets.synthetic import synthetic_sequence
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.evaluation.tables import evaluate

    cfg = _config(args.set)
    systems = ["dynslam"] + ([] if args.no_open3d else ["open3d"])
    rows = []
    print(f"RPE 1 frame (trans RMSE mm / rot RMSE deg), ATE RMSE mm; {args.frames} frames; dynslam --set {args.set}")
    print(f"| {'sequence':<24} | {'system':<8} | {'RPE mm':>7} | {'RPE deg':>7} | {'ATE mm':>7} | {'ms/frame':>8} |")
    print(f"|{'-' * 26}|{'-' * 10}|{'-' * 9}|{'-' * 9}|{'-' * 9}|{'-' * 10}|")
    for preset in args.presets:
        for seed in args.seeds:
            seq = TumSequence(synthetic_sequence(preset, n_frames=args.frames, seed=seed))
            frames = [seq[i] for i in range(len(seq))]
            for name in systems:
                traj, dt = run_dynslam(seq, frames, cfg) if name == "dynslam" else run_open3d(seq, frames)
                ev = evaluate(seq.groundtruth, traj, align="se3")
                r = {"seq": f"{preset} s{seed}", "system": name, "rpe": 1e3 * ev["rpe"]["trans"]["rmse"],
                     "rot": ev["rpe"]["rot"]["rmse"], "ate": 1e3 * ev["ate"]["rmse"], "ms": 1e3 * dt}
                rows.append(r)
                print(f"| {r['seq']:<24} | {name:<8} | {r['rpe']:7.2f} | {r['rot']:7.3f} | {r['ate']:7.2f} | {r['ms']:8.1f} |", flush=True)
    print()
    for name in systems:
        v = [r for r in rows if r["system"] == name]
        print(f"{name}: RPE median {np.median([r['rpe'] for r in v]):.2f} mm, worst {max(r['rpe'] for r in v):.2f} mm; "
              f"ATE median {np.median([r['ate'] for r in v]):.2f} mm, worst {max(r['ate'] for r in v):.2f} mm")


if __name__ == "__main__":
    main()
