"""How far the dense point-to-plane term alone puts a frame from its true pose (issue 12).

For pairs of frames of a rendered sequence (``dynslam synth``), the reference depth (one earlier frame, or
the fused model of several, :func:`~dynslam_lab.geometry.depth_alignment.fuse_depth_model`) is placed at its
true pose and the frame's depth is aligned to it by depth alone (motion-only BA with the dense term, no
features, no prior), starting at the frame's true pose. The distance of the optimum from the truth is the
term's own error: noise and the Kinect's quantised depth (steps ``z^2 q / (f b)``), which ``smooth_depth``
averages away. Prints the median and the largest position (mm) and rotation (deg) errors per setting.

    dynslam synth loop_pattern SEQ/loop_pattern_s0 --frames 300 --seed 0
    python benchmarks/dense_alignment_bias.py SEQ/loop_pattern_s0 --smooth 1 3 5 9 --gap 1
    python benchmarks/dense_alignment_bias.py SEQ/loop_pattern_s0 --smooth 1 9 --model 3     # frames i-6, i-3, i fused
"""

from __future__ import annotations

import argparse

import numpy as np


def main() -> None:
    from dynslam_lab.datasets.kinect import DepthNoise, nguyen_sigma
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.geometry.se3 import rotation_angle_deg, se3_inv
    from dynslam_lab.geometry.depth_alignment import DenseTerm, DepthSource, fuse_depth_model, smooth_depth, vertex_normal_grid
    from dynslam_lab.slam.optimize import Observations, optimize_pose

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("seq", help="a rendered sequence folder (with groundtruth.txt)")
    ap.add_argument("--smooth", type=int, nargs="+", default=[1, 9], help="smooth_depth window sizes (px; 1 = raw)")
    ap.add_argument("--gap", type=int, default=1, help="frames between the reference and the aligned frame")
    ap.add_argument("--model", type=int, default=1, help="reference frames fused (i - 3k, k < model)")
    ap.add_argument("--step", type=int, default=20, help="frames between pairs")
    args = ap.parse_args()
    seq = TumSequence(args.seq)
    gt, cam = seq.groundtruth, seq.camera

    def true_pose(i: int) -> np.ndarray:
        return gt.poses[int(np.argmin(np.abs(gt.timestamps - seq[i].timestamp)))]

    noise = DepthNoise()
    obs = Observations.from_keypoints(np.zeros((0, 2)), np.zeros(0), np.zeros(0), 400.0, 1.2)
    first = 3 * (args.model - 1)
    for size in args.smooth:
        errs = []
        for i in range(max(first, 10), len(seq) - args.gap, args.step):
            j = i + args.gap
            srcs = []
            for k in range(args.model):
                f = i - 3 * k
                g = vertex_normal_grid(smooth_depth(seq[f].depth, size), cam, 4, step=2)
                srcs.append(DepthSource.from_grid(g, true_pose(f)))
            T_j = se3_inv(true_pose(j))
            ref, _ = fuse_depth_model(srcs, T_j, cam, 8)
            X = cam.backproject_depth(smooth_depth(seq[j].depth, size), 8).reshape(-1, 3)
            X = X[np.isfinite(X).all(axis=1) & (X[:, 2] > 0.1) & (X[:, 2] < 8.0)]
            term = DenseTerm(X, 1.5 * nguyen_sigma(X[:, 2], 0.0, noise), ref, T_j, cam)
            T, _ = optimize_pose(T_j, np.zeros((0, 3)), obs, cam, 400.0, dense=term)
            D = T @ true_pose(j)
            errs.append((1e3 * np.linalg.norm(D[:3, 3]), rotation_angle_deg(D[:3, :3])))
        e = np.array(errs)
        print(f"{args.seq} smooth {size:2d} px, gap {args.gap}, model {args.model}: {len(e)} pairs, position mm median "
              f"{np.median(e[:, 0]):.2f} max {e[:, 0].max():.2f}, rotation deg median {np.median(e[:, 1]):.3f} max {e[:, 1].max():.3f}")


if __name__ == "__main__":
    main()
