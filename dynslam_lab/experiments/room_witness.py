"""The room's image and depth as a witness of the camera's pose (docs/robustness.md, "The room's image as a witness").

When a textured mover that was mapped at rest starts slowly, the feature pose follows it a few millimetres a frame,
along the slide that plain walls leave free. The static room, its depth and its image edges together, can say where
the camera was: :func:`witness` aligns a frame to an earlier one with the hybrid RGB-D terms of Steinbruecker et al.
(2011), point-to-plane depth (:class:`~dynslam_lab.geometry.depth_alignment.DenseTerm`) and intensity
(:class:`~dynslam_lab.geometry.depth_alignment.PhotometricTerm`), over the pixels of the room only. Which pixels are
the room, without the truth: :func:`plane_pixels`, the depth's large planes (:func:`large_planes`) that nothing lies
behind (:func:`bounding_planes`: walls, floor, ceiling). :func:`measure_witness` runs a pipeline over a sequence and
yields, frame by frame, the run's error and the witness's against the truth. ``benchmarks/room_witness.py`` prints
them; notebook 10 plots them. A measurement, not a stage of the pipeline (docs/robustness.md says why).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from ..datasets.tum import read_moving
from ..geometry.depth_alignment import DenseTerm, align_depth, depth_sigma, image_level, photometric_term, vertex_normal_grid
from ..geometry.se3 import relative_pose, rotation_angle_deg

__all__ = ["PIXELS", "WitnessRow", "large_planes", "bounding_planes", "plane_pixels", "movers_of", "level_mask", "witness",
           "pose_error", "measure_witness"]

PIXELS = ("planes", "oracle", "all")


def large_planes(P: np.ndarray, min_share: float = 0.05, max_planes: int = 5, hypotheses: int = 256,
                 tol_m: float = 0.01, tol_per_m2: float = 0.004, sample: int = 3000, seed: int = 0) -> np.ndarray:
    """``(M,)`` int: the plane (1, 2, ...) each camera point of ``P (M, 3)`` lies on, 0 for none.

    Planes are taken one at a time, largest first, by RANSAC (``hypotheses`` triples, scored on at most ``sample``
    of the points left), refitted by least squares on their inliers; a point is on a plane within ``tol_m + tol_per_m2
    z^2`` m (the depth noise grows with the square of the distance). A plane must hold ``min_share`` of all points;
    at most ``max_planes``."""
    P = np.asarray(P, np.float64)
    M = len(P)
    labels = np.zeros(M, np.int64)
    if M < 3:
        return labels
    rng = np.random.default_rng(seed)
    tol = tol_m + tol_per_m2 * P[:, 2] ** 2
    left = np.arange(M)
    for k in range(1, max_planes + 1):
        if len(left) < max(min_share * M, 3):
            break
        scored = left if len(left) <= sample else rng.choice(left, sample, replace=False)
        tri = left[rng.integers(0, len(left), size=(hypotheses, 3))]
        A, B, C = P[tri[:, 0]], P[tri[:, 1]], P[tri[:, 2]]
        n = np.cross(B - A, C - A)
        norm = np.linalg.norm(n, axis=1)
        ok = norm > 1e-12
        if not ok.any():
            break
        n = n[ok] / norm[ok, None]
        d = -np.einsum("ij,ij->i", n, A[ok])
        votes = (np.abs(P[scored] @ n.T + d) < tol[scored, None]).sum(axis=0)
        best = int(np.argmax(votes))
        normal, offset = n[best], d[best]
        for _ in range(2):  # least-squares refit on the inliers, then the inliers again
            inl = left[np.abs(P[left] @ normal + offset) < tol[left]]
            if len(inl) < 3:
                break
            centre = P[inl].mean(axis=0)
            normal = np.linalg.svd(P[inl] - centre, full_matrices=False)[2][-1]
            offset = -normal @ centre
        inl = left[np.abs(P[left] @ normal + offset) < tol[left]]
        if len(inl) < min_share * M:
            break
        labels[inl] = k
        left = np.setdiff1d(left, inl, assume_unique=True)
    return labels


def bounding_planes(P: np.ndarray, labels: np.ndarray, tol_m: float = 0.01, tol_per_m2: float = 0.004,
                    max_behind: float = 0.02) -> np.ndarray:
    """The labels of :func:`large_planes` that bound the scene: seen from the camera, at most ``max_behind`` of the
    points whose rays meet the plane in front of the camera lie behind it (beyond ``tol_m + tol_per_m2 z^2``). A wall,
    the floor or the ceiling of a room has nothing behind it; the face of a large box has the wall. ``labels`` with
    the other planes set to 0."""
    out = labels.copy()
    rays = P / P[:, 2:3]
    for k in np.unique(labels[labels > 0]):
        on = labels == k
        centre = P[on].mean(axis=0)
        normal = np.linalg.svd(P[on] - centre, full_matrices=False)[2][-1]
        denom = rays @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            z_plane = (normal @ centre) / denom
        meets = np.isfinite(z_plane) & (z_plane > 0)
        behind = meets & (P[:, 2] > z_plane + tol_m + tol_per_m2 * z_plane ** 2)
        if behind.sum() > max_behind * max(int(meets.sum()), 1):
            out[on] = 0
    return out


def _centred_points(depth: np.ndarray, camera, stride: int, keep: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The camera points of ``depth``'s pixels at the centres of ``stride`` x ``stride`` cells with a reading (and
    in ``keep``, full size, when given), and ``(rows, cols)`` bool: which cells gave one."""
    h, w = depth.shape
    v, u = np.mgrid[stride // 2:h:stride, stride // 2:w:stride]
    z = depth[v, u]
    ok = z > 0 if keep is None else (z > 0) & keep[v, u]
    return camera.backproject(np.column_stack([u[ok], v[ok]]).astype(np.float64), z[ok].astype(np.float64)), ok


def plane_pixels(depth: np.ndarray, camera, shape: tuple[int, int], stride: int = 4, margin: int = 3) -> np.ndarray:
    """``shape`` bool: the pixels (of an image of ``shape``, a reduction of ``depth``'s) on the large planes of
    ``depth`` that bound the scene (:func:`large_planes`, :func:`bounding_planes`, on every ``stride``-th pixel;
    single cells off the planes closed), at least ``margin`` px of ``shape`` from every pixel that is not."""
    P, ok = _centred_points(depth, camera, stride)
    grid = np.zeros(ok.shape, np.uint8)
    grid[ok] = bounding_planes(P, large_planes(P)) > 0
    # single cells off the planes inside them are depth noise (or a missing reading), not an object: closed
    grid = cv2.morphologyEx(grid, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    mask = cv2.resize(grid, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    if margin > 0:
        mask = cv2.erode(mask, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8))
    return mask > 0


def movers_of(root: Path) -> set[int]:
    """Every instance that moves in some frame of a rendered sequence (its ``moving.txt``,
    :func:`~dynslam_lab.datasets.tum.read_moving`; a FileNotFoundError names the file when there is none)."""
    return set().union(*read_moving(root).values())


def level_mask(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``mask`` resized to ``shape`` (nearest pixel)."""
    return cv2.resize(mask.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0


def witness(frame, past, T_c_p: np.ndarray, camera, keep_frame: np.ndarray, keep_past: np.ndarray, scale: int = 2,
            iterations: int = 15, sigma: float = 4.0, stride: int = 8) -> tuple[np.ndarray, float]:
    """The pose of ``frame`` relative to ``past`` (``T_c_p``, past camera -> frame camera) by the hybrid alignment of
    the pixels ``keep_frame`` (at the level's size) to the past frame's ``keep_past`` (the rest is no reference),
    from ``T_c_p``; and the cost ratio (the robust photometric cost at ``T_c_p`` over that at the result, nan when
    the image has too few edges there)."""
    ref = image_level(past.gray, past.depth, camera, scale)
    ref.invalid = ~keep_past
    level = image_level(frame.gray, frame.depth, camera, scale)
    photo = photometric_term(level, ref, np.eye(4), sigma, exclude=~keep_frame)
    grid = vertex_normal_grid(np.where(level_mask(keep_past, past.depth.shape), past.depth, 0), camera, stride)
    X, _ = _centred_points(frame.depth, camera, stride, level_mask(keep_frame, frame.depth.shape))
    term = DenseTerm(X, 1.5 * depth_sigma(X[:, 2]), grid, np.eye(4), camera, max_distance=0.1, T_prior=T_c_p,
                     prior_sigma=(0.5, 20.0))
    result = align_depth(term, T_c_p, iterations, 2.0, photometric=photo).T_c_w

    def cost(T: np.ndarray) -> float:
        e, _ = photo.residuals(T[:3, :3], T[:3, 3])
        return float(np.mean(np.minimum(np.abs(e), 3.0) ** 2)) if len(e) else float("nan")

    ratio = cost(T_c_p) / max(cost(result), 1e-12) if photo is not None else float("nan")
    return result, ratio


def pose_error(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Translation (mm) and rotation (deg) of ``T`` against ``T_true``."""
    E = np.linalg.inv(T_true) @ T
    return 1000.0 * float(np.linalg.norm(E[:3, 3])), float(rotation_angle_deg(E[:3, :3]))


@dataclass(frozen=True)
class WitnessRow:
    """One frame of :func:`measure_witness` for one pixel set: the frame, the earlier frame, the run's and the
    witness's errors (mm, deg) of the relative pose between the two against the truth, and the witness's cost
    ratio."""

    frame: int
    earlier: int
    run_mm: float
    run_deg: float
    witness_mm: float
    witness_deg: float
    cost_ratio: float
    pixels: str = "planes"


def measure_witness(seq, system, n_frames: int, offset: int = 16, pixels: str | tuple[str, ...] = "planes",
                    scale: int = 2, margin: int = 3, first: int = 0) -> Iterator[WitnessRow]:
    """Run ``system`` (``pipeline.build_pipeline``) over the first ``n_frames`` of ``seq`` and yield a
    :class:`WitnessRow` for every frame ``t >= max(first, offset)`` where the run, the frame ``t - offset`` and the
    truth all have a pose, one per pixel set of ``pixels`` (one name or several, measured on the same run):
    ``planes`` (:func:`plane_pixels`), ``oracle`` (off every instance the renderer moves at some time,
    ``moving.txt``) or ``all``."""
    sets = (pixels,) if isinstance(pixels, str) else tuple(pixels)
    if not sets or any(p not in PIXELS for p in sets):
        raise ValueError(f"pixels must be one or more of {PIXELS}, got {pixels!r}")
    if offset < 1 or scale < 1 or margin < 0:
        raise ValueError(f"offset >= 1, scale >= 1 and margin >= 0 required, got {offset}, {scale}, {margin}")
    movers = sorted(movers_of(seq.root)) if "oracle" in sets else []
    kept: dict[int, tuple] = {}  # frame index -> (frame, estimated T_w_c, {pixel set: pixels kept at the level's size})
    for k, frame in enumerate(seq):
        if k >= n_frames:
            break
        T_w_c = system.process(frame).T_w_c
        shape = (frame.depth.shape[0] // scale, frame.depth.shape[1] // scale)
        keep = {}
        for name in sets:
            if name == "planes":
                keep[name] = plane_pixels(frame.depth, seq.camera, shape, margin=margin)
            elif name == "oracle":
                if frame.instance_mask is None:
                    raise ValueError(f"{seq.root}: pixels 'oracle' needs the renderer's instance masks")
                keep[name] = level_mask(~np.isin(frame.instance_mask, movers), shape)
            else:
                keep[name] = np.ones(shape, bool)
        kept[k] = (frame, T_w_c, keep)
        kept.pop(k - offset - 1, None)
        p = k - offset
        if p < 0 or k < first:
            continue
        past, T_w_p, keep_p = kept[p]
        if T_w_c is None or T_w_p is None or frame.T_w_c_gt is None or past.T_w_c_gt is None:
            continue
        T_c_p = relative_pose(T_w_c, T_w_p)
        T_true = relative_pose(frame.T_w_c_gt, past.T_w_c_gt)
        run_err = pose_error(T_c_p, T_true)
        for name in sets:
            T_wit, ratio = witness(frame, past, T_c_p, seq.camera, keep[name], keep_p[name], scale)
            yield WitnessRow(k, p, *run_err, *pose_error(T_wit, T_true), ratio, name)
