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
where the features put them). The room's own map matches may join the sum (``features``,
:class:`~dynslam_lab.geometry.depth_alignment.ReprojectionTerm`): a wall and the floor leave a slide along
both free, which their features fix. Which surfaces are the room: :func:`room_labels` (an object standing
in the room that carries more than its share of the keypoints is not, :func:`front_share`).

What the reference pose does with it (:func:`~.reference_pose.depth_moved_surfaces`): when the
alignment lowers the room's median point-to-plane distance ``room_depth_gain`` times and the room's
own map matches agree with the aligned pose, the features had been pulled, and the surfaces whose
matches miss the aligned pose are movers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..camera import PinholeCamera
from ..geometry.depth_alignment import DenseAlignment, DenseTerm, DepthGrid, ReprojectionTerm, align_depth, depth_sigma, vertex_normal_grid

__all__ = ["RoomDepth", "RoomAlignment", "front_share", "room_labels", "room_points", "reference_grid", "align_room", "depth_sigma"]

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


def front_share(small_depth: np.ndarray, labels: np.ndarray, n_labels: int, rel: float) -> np.ndarray:
    """``(n_labels,)`` share of each surface's depth-step outline on which it is the nearer side.

    Across every pair of neighbouring cells of ``labels (h, w)`` (label 0 = none) with depth on both sides and
    a depth step (``|z_a - z_b| >= rel * min(z_a, z_b)``), the nearer label counts one edge in front, the
    farther one edge behind; the share is ``front / (front + behind)``, 0 where a surface has no step on its
    outline. An object standing in the room (a box, a person, a pillar) is in front along most of its outline;
    the room's shell (walls, floor, ceiling) is behind what stands before it. Creases (a box on the floor)
    join no depth step and count for neither.
    """
    z = np.asarray(small_depth, np.float32)
    lab = np.asarray(labels)
    front = np.zeros(n_labels, np.int64)
    behind = np.zeros(n_labels, np.int64)
    for za, zb, la, lb in ((z[:, 1:], z[:, :-1], lab[:, 1:], lab[:, :-1]), (z[1:], z[:-1], lab[1:], lab[:-1])):
        step = (za > 0) & (zb > 0) & (la != lb) & (la > 0) & (lb > 0) & (np.abs(za - zb) >= rel * np.minimum(za, zb))
        a_near = step & (za < zb)
        b_near = step & (zb < za)
        front += np.bincount(la[a_near], minlength=n_labels)[:n_labels] + np.bincount(lb[b_near], minlength=n_labels)[:n_labels]
        behind += np.bincount(lb[a_near], minlength=n_labels)[:n_labels] + np.bincount(la[b_near], minlength=n_labels)[:n_labels]
    total = front + behind
    return np.divide(front, total, out=np.zeros(n_labels), where=total > 0)


def room_labels(small_depth: np.ndarray, cells: np.ndarray, min_share: float, labels: np.ndarray | None = None,
                prior: np.ndarray | None = None, overlap: float = 0.5, max_front: float = 1.0,
                step_rel: float = 0.04, keypoint_labels: np.ndarray | None = None) -> np.ndarray:
    """Labels of the surfaces (``cells (L,)``: reduced-grid cells of each label, label 0 = none first)
    holding at least ``min_share`` of the cells with depth of ``small_depth``: the room's walls, floor
    and large furniture. With the grid's ``labels (h, w)``:

    * a surface in front of its neighbours along more than ``max_front`` of its depth-step outline
      (:func:`front_share`, steps of ``step_rel``) is an object standing in the room, not its shell. With the
      surface label of every keypoint ``keypoint_labels (N,)``, such an object is left out when it holds a
      larger share of the keypoints than of the cells with depth: the depth is to witness against the
      features, and an object that carries more than its share of them is the one that pulls them when it
      moves (a textured box mapped at rest that starts to move; aligned with the rest, it would pull the
      room's depth too). A plain piece of furniture stays: its sides fix what the walls and floor leave free.
      Without ``keypoint_labels`` every such object is left out (``max_front`` 1 = keep all);
    * with the previous frame's dynamic region ``prior (h, w)`` bool, a surface lying at least ``overlap``
      inside the region is left out: a large mover the screener has already found (a panel, a person close
      to the camera) is no part of the room.
    """
    valid = int(np.count_nonzero(small_depth > 0))
    if valid == 0:
        return np.zeros(0, np.int64)
    big = np.flatnonzero(cells >= min_share * valid)
    big = big[big > 0]
    if len(big) and labels is not None and max_front < 1:
        front = front_share(small_depth, labels, len(cells), step_rel)[big] > max_front
        if keypoint_labels is not None and len(keypoint_labels):
            kp_share = np.bincount(np.asarray(keypoint_labels, np.int64), minlength=len(cells))[big] / len(keypoint_labels)
            front &= kp_share > cells[big] / valid
        big = big[~front]
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
               tol_rad: float = 1e-5, tol_m: float = 1e-4, features: ReprojectionTerm | None = None,
               sigma_scale: float = 1.0) -> RoomAlignment:
    """Gauss-Newton on the point-to-plane error of the room's points against the earlier depth, from
    ``T_start`` (world -> camera), Huber-weighted at ``huber`` sigma (:func:`depth_sigma` times ``sigma_scale``, the
    depth's noise in units of that model), with a prior of
    ``prior_m`` / ``prior_deg`` toward ``T_start``; associations farther than ``max_distance`` m are none.
    At most ``iterations`` steps, fewer once a step turns the camera by less than ``tol_rad`` and moves
    it by less than ``tol_m``. ``features``: the room's own map matches, fitted with the depth
    (:func:`~dynslam_lab.geometry.depth_alignment.align_depth`)."""
    if len(room.X) == 0:
        return RoomAlignment(T_start.copy(), float("nan"), float("nan"), 0)
    term = DenseTerm(room.X, depth_sigma(room.X[:, 2]) * sigma_scale, room.ref, room.T_r_w, room.camera, max_distance=max_distance,
                     T_prior=T_start, prior_sigma=(prior_m, prior_deg))
    return align_depth(term, T_start, iterations, huber, tol_rad, tol_m, features)

