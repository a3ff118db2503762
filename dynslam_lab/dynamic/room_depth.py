"""The room's depth as a witness of the camera's pose (step 3c of :mod:`.reference_pose`; ours).

Why. The reference pose is refined on map matches. Where two movers that move together (a person
and the box they carry) hold a fifth of the matches and the static ones lie far away (3 m), the
leave-one-surface-out test of step 3b cannot single them out: left out one at a time, each is held
up by the other, and the pose slides with them along the direction the far points fix worst (a
sideways shift traded against a turn): 2 mm, then 40 mm within a few frames.

The depth image does not trade so. The large surfaces of the room (walls, floor, ceiling: every
surface holding at least ``room_depth_min_share`` of the reduced grid's depth cells) were seen by an
earlier frame too; their point-to-plane error (Chen and Medioni 1992) against that frame's depth,
with projective data association (Newcombe et al. 2011, KinectFusion)::

    e_j = n_j . (T_r_c X_j - Y_j) / sigma_j

(:class:`~dynslam_lab.geometry.depth_alignment.DenseTerm`) fixes the relative pose to a millimetre
wherever the room shows two or more non-parallel planes, whatever the texture. The alignment here
starts at the feature pose, weights the residuals with Huber's function at ``huber`` sigma (a mover
that crosses a wall's cells is down-weighted, not followed) and holds the pose weakly to the start
(``prior_m``, ``prior_deg``: a single plane fixes only three of the six directions, the rest stay
where the features put them).

What the reference pose does with it (:func:`~.reference_pose.depth_moved_surfaces`): when the
alignment lowers the room's median point-to-plane distance ``room_depth_gain`` times and the room's
own map matches agree with the aligned pose, the features had been pulled, and the surfaces whose
matches miss the aligned pose are movers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import PinholeCamera
from ..geometry.depth_alignment import DenseAlignment, DenseTerm, DepthGrid, align_depth, depth_sigma, vertex_normal_grid

__all__ = ["RoomDepth", "RoomAlignment", "room_labels", "room_points", "reference_grid", "align_room", "depth_sigma"]

RoomAlignment = DenseAlignment  # the result of align_room (geometry.depth_alignment.align_depth)


@dataclass
class RoomDepth:
    """One frame's room against an earlier frame's depth.

    X : ``(M, 3)`` camera points of the frame's reduced-grid cells on the room's surfaces (m).
    ref : the earlier frame's reduced depth as vertices and normals (stride 1 on ``camera``).
    T_r_w : ``(4, 4)`` world -> camera pose of the earlier frame.
    camera : intrinsics of the reduced grid.
    """

    X: np.ndarray
    ref: DepthGrid
    T_r_w: np.ndarray
    camera: PinholeCamera


def room_labels(small_depth: np.ndarray, cells: np.ndarray, min_share: float, labels: np.ndarray | None = None,
                prior: np.ndarray | None = None, overlap: float = 0.5) -> np.ndarray:
    """Labels of the surfaces (``cells (L,)``: reduced-grid cells of each label, label 0 = none first)
    holding at least ``min_share`` of the cells with depth of ``small_depth``: the room's walls, floor
    and large furniture. With the grid's ``labels (h, w)`` and the previous frame's dynamic region
    ``prior (h, w)`` bool, a surface lying at least ``overlap`` inside the region is left out: a large mover
    the screener has already found (a panel, a person close to the camera) is no part of the room."""
    valid = int(np.count_nonzero(small_depth > 0))
    if valid == 0:
        return np.zeros(0, np.int64)
    big = np.flatnonzero(cells >= min_share * valid)
    big = big[big > 0]
    if len(big) and labels is not None and prior is not None and prior.shape == labels.shape:
        inside = np.bincount(labels[prior], minlength=len(cells))[big]
        big = big[inside < overlap * cells[big]]
    return big


def room_points(small_depth: np.ndarray, labels: np.ndarray, room: np.ndarray, camera: PinholeCamera,
                step: int = 4) -> np.ndarray:
    """Camera points ``(M, 3)`` of every ``step``-th cell (in both directions) of the reduced depth
    ``small_depth (h, w)`` whose surface (``labels (h, w)``) is one of ``room`` (:func:`room_labels`). Every
    4th cell of a 160x120 grid gives at most 1,200 points: a pose to a fraction of a millimetre, at a few
    milliseconds for the alignment."""
    z = small_depth[::step, ::step]
    keep = np.isin(labels[::step, ::step], room) & (z > 0)
    v, u = np.nonzero(keep)
    v, u = v * step, u * step
    zk = small_depth[v, u].astype(np.float64)
    return np.stack([(u - camera.cx) * zk / camera.fx, (v - camera.cy) * zk / camera.fy, zk], axis=1)


def reference_grid(small_depth: np.ndarray, camera: PinholeCamera) -> DepthGrid:
    """The earlier frame's reduced depth as vertices and normals (:func:`~dynslam_lab.geometry.depth_alignment.vertex_normal_grid`)."""
    return vertex_normal_grid(small_depth, camera, 1)


def align_room(room: RoomDepth, T_start: np.ndarray, iterations: int = 8, huber: float = 2.0,
               prior_m: float = 0.05, prior_deg: float = 2.0, max_distance: float = 0.1,
               tol_rad: float = 1e-5, tol_m: float = 1e-4) -> RoomAlignment:
    """Gauss-Newton on the point-to-plane error of the room's points against the earlier depth, from
    ``T_start`` (world -> camera), Huber-weighted at ``huber`` sigma (:func:`depth_sigma`), with a prior of
    ``prior_m`` / ``prior_deg`` toward ``T_start``; associations farther than ``max_distance`` m are none.
    At most ``iterations`` steps, fewer once a step turns the camera by less than ``tol_rad`` and moves
    it by less than ``tol_m``."""
    if len(room.X) == 0:
        return RoomAlignment(T_start.copy(), float("nan"), float("nan"), 0)
    term = DenseTerm(room.X, depth_sigma(room.X[:, 2]), room.ref, room.T_r_w, room.camera, max_distance=max_distance,
                     T_prior=T_start, prior_sigma=(prior_m, prior_deg))
    return align_depth(term, T_start, iterations, huber, tol_rad, tol_m)

