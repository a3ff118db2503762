"""Dense depth alignment: a point-to-plane term for motion-only BA where features are few.

RGB-D tracking with ORB features fails where the image has no texture (a plain wall, a floor):
ORB finds a few dozen corners, fewer than tracking needs, yet the depth image still sees the
planes. The point-to-plane error of Chen and Medioni (1992), with the projective data association
of KinectFusion (Newcombe et al. 2011), measures how well the frame's depth points lie on the
surfaces of an earlier depth image::

    e_j = n_j . (T_r_c X_j - Y_j) / sigma_j

``X_j`` a point of the frame's depth image (camera frame), ``T_r_c`` the frame's pose relative to
the earlier ("reference") image, ``Y_j`` and ``n_j`` the vertex and unit normal of the reference
depth image at the pixel where ``T_r_c X_j`` projects, ``sigma_j`` the depth noise at ``X_j``.

In motion-only BA the frame's pose is ``T_c_w = (R, t)``, moved by ``R <- Exp(omega) R``,
``t <- t + tau`` (:mod:`dynslam_lab.slam.optimize`). With the reference pose ``T_r_w = (R_r, t_r)`` the frame's
point in the world is ``X_w = R^T (X - t)``; a step gives ``dX_w / d omega = R^T [X - t]_x`` and
``dX_w / d tau = -R^T``, so with ``m = R R_r^T n`` (the normal in the frame's camera) and
``p = X - t``::

    d e / d omega = (m x p) / sigma,     d e / d tau = -m / sigma

Our reading (ours, not ORB-SLAM2, which has no dense term): the reference is the last tracked
frame (the most overlap), or, as an option, a model fused from recent keyframes' depth
(:func:`fuse_depth_model`); the depth images may be averaged first (:func:`smooth_depth`: the Kinect's
quantised depth biases the alignment); the term joins the feature residuals of motion-only BA only when the
features fail, or keep few inliers (``TrackingConfig.dense_below_inliers``) with a pose far from the
motion prediction (``dense = "auto"``, the default, and only on frames with few keypoints while the
screening judges the scene static: ``TrackingConfig.static_scene_frames``, ``dense_max_keypoints``), so
where features are plenty (and movers may be in the depth image: the screening stage judges
keypoints, not pixels) nothing changes. Normals come from central differences of the vertex grid;
a pair with a depth jump, a missing neighbour, or a residual beyond ``max_distance`` metres is left
out; the grid of ``stride`` pixels keeps a frame to ~5,000 points. Lens distortion is ignored
(synthetic and undistorted input).

A plane's depth leaves the slide along it free. :class:`PhotometricTerm` adds the intensity residuals of
hybrid RGB-D odometry (Steinbruecker et al. 2011): where the image has an edge the slide shows there; tracking
runs it coarse to fine on reduced images (:func:`image_level`, :func:`photometric_term`) to start a
dense-tracked frame from the pose it gives (``TrackingConfig.dense_photometric_sigma``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from ..camera import PinholeCamera
from .projection import projection_jacobian
from .se3 import make_pose, skew, so3_exp, so3_log

__all__ = ["DepthGrid", "brightness_transfer", "smooth_depth", "vertex_normal_grid", "DenseTerm", "DepthSource", "fuse_depth_model", "depth_sigma",
           "DenseAlignment", "align_depth", "reduced_depth_points", "ImageLevel", "image_level", "PhotometricTerm",
           "photometric_term"]


@dataclass
class DepthGrid:
    """A depth image subsampled every ``stride`` pixels: camera-frame vertices ``V (h, w, 3)`` (nan
    where no depth) and unit normals ``N (h, w, 3)`` pointing at the camera (nan where unknown)."""

    V: np.ndarray
    N: np.ndarray
    stride: int


def vertex_normal_grid(depth: np.ndarray, camera: PinholeCamera, stride: int, max_jump: float = 0.05,
                       step: int = 1) -> DepthGrid:
    """Vertices and normals of ``depth (H, W)`` (m, 0 or nan = none) every ``stride`` pixels.

    The normal at a grid cell is ``(V[i, j+k] - V[i, j-k]) x (V[i+k, j] - V[i-k, j])`` (``k = step`` cells),
    normalised and turned to face the camera; unknown where a neighbour is missing or differs in depth by more
    than ``max_jump`` (relative) from the cell (a depth discontinuity)."""
    if step < 1:
        raise ValueError(f"vertex_normal_grid: step must be >= 1, got {step}")
    V = camera.backproject_depth(depth, stride)
    h, w = V.shape[:2]
    N = np.full_like(V, np.nan)
    k = int(step)
    if h <= 2 * k or w <= 2 * k:
        return DepthGrid(V, N, int(stride))
    # one (h - 2k, w - 2k) array per coordinate: contiguous arithmetic, twice as fast as on (h, w, 3) slices
    x, y, z = V[..., 0], V[..., 1], V[..., 2]
    rows, cols = slice(k, h - k), slice(k, w - k)
    right, left = (rows, slice(2 * k, None)), (rows, slice(None, w - 2 * k))
    down, up = (slice(2 * k, None), cols), (slice(None, h - 2 * k), cols)
    ax, ay, az = x[right] - x[left], y[right] - y[left], z[right] - z[left]
    bx, by, bz = x[down] - x[up], y[down] - y[up], z[down] - z[up]
    nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    zc = z[rows, cols]
    jump = np.maximum(np.maximum(np.abs(z[right] - zc), np.abs(z[left] - zc)),
                      np.maximum(np.abs(z[down] - zc), np.abs(z[up] - zc))) / zc
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = (jump <= max_jump * k) & (norm > 0)
        nx, ny, nz = nx / norm, ny / norm, nz / norm
        # -1 turns a normal facing away from the camera; nan where unknown
        sign = np.where(ok, np.where(nx * x[rows, cols] + ny * y[rows, cols] + nz * zc > 0, -1.0, 1.0), np.nan)
    n = N[rows, cols]
    n[..., 0], n[..., 1], n[..., 2] = nx * sign, ny * sign, nz * sign
    return DepthGrid(V, N, int(stride))


def smooth_depth(depth: np.ndarray, size: int, max_range: float = 0.1) -> np.ndarray:
    """``depth (H, W)`` (m, 0 or nan = none) averaged over ``size x size`` px windows (the mean of the valid
    pixels; float32), 0 where the window holds fewer than half its pixels valid or spans a depth range beyond
    ``max_range`` (relative) of its mean: a depth discontinuity, whose average would be a surface that is not
    there. ``size <= 1`` returns the image as float32 with 0 for none.

    Our reading: the Kinect measures disparity in 1/8 px steps, so depth comes in steps of ``z^2 q / (f b)`` (2.6
    cm at 3 m; the synthetic sensor, :mod:`~dynslam_lab.datasets.kinect`, quantises too), and point-to-plane
    alignment of two such staircases is biased towards the steps: on ``loop_pattern`` (seed 0) aligning a frame
    to the one before at the true poses, by depth alone, lands 3.8 mm / 0.048 deg off (median of 14 pairs);
    averaged over 9 x 9 px first, 0.5 mm / 0.008 deg (KinectFusion, Newcombe et al. 2011, filters the raw
    depth with a bilateral filter for the same reason)."""
    d = np.nan_to_num(np.asarray(depth, np.float32), nan=0.0)
    if size <= 1:
        return np.where(d > 0, d, 0.0).astype(np.float32)
    valid = (d > 0).astype(np.float32)
    k = (int(size), int(size))
    num = cv2.boxFilter(d * valid, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    den = cv2.boxFilter(valid, -1, k, normalize=False, borderType=cv2.BORDER_CONSTANT)
    mean = num / np.maximum(den, 1.0)
    kernel = np.ones(k, np.uint8)
    hi = cv2.dilate(np.where(d > 0, d, 0.0).astype(np.float32), kernel)
    lo = cv2.erode(np.where(d > 0, d, np.inf).astype(np.float32), kernel)
    ok = (den >= 0.5 * size * size) & (hi - lo <= max_range * mean) & (d > 0)
    return np.where(ok, mean, 0.0).astype(np.float32)


@dataclass
class DepthSource:
    """Depth samples of one earlier view for the fused reference model (:func:`fuse_depth_model`): vertices
    ``V (M, 3)`` and unit normals ``N (M, 3)`` in that view's camera frame, its pose ``T_w_c (4, 4)`` (the
    keyframe's current, optimised pose), and ``priority`` (0 first: a cell takes the samples of the lowest
    priority that reaches it)."""

    V: np.ndarray
    N: np.ndarray
    T_w_c: np.ndarray
    priority: int = 0

    @staticmethod
    def from_grid(grid: DepthGrid, T_w_c: np.ndarray, priority: int = 0) -> "DepthSource":
        """The cells of ``grid`` with a vertex and a normal."""
        V, N = grid.V.reshape(-1, 3), grid.N.reshape(-1, 3)
        ok = np.isfinite(V).all(axis=1) & np.isfinite(N).all(axis=1)
        return DepthSource(V[ok], N[ok], np.asarray(T_w_c, float), int(priority))


def fuse_depth_model(sources: list[DepthSource], T_r_w: np.ndarray, camera: PinholeCamera, stride: int,
                     band: float = 0.03, min_normal_cos: float = 0.8) -> tuple[DepthGrid, np.ndarray]:
    """A reference depth grid seen from ``T_r_w`` (every ``stride`` px), fused from the samples of earlier
    views (ours; a splatted stand-in for KinectFusion's ray-cast model, Newcombe et al. 2011).

    Each source's vertices and normals go to the reference camera with ``T_r_w T_w_c``; samples behind the
    camera, outside the image, or whose normal faces away from the reference camera are dropped. Each grid
    cell (the sample's pixel / stride, rounded, as :meth:`DenseTerm.associate` looks it up) takes the samples
    of the lowest ``priority`` that reaches it; among those, the nearest depth ``z0`` and every sample within
    ``band z0`` behind it whose normal is within ``acos(min_normal_cos)`` of the nearest one's (the same
    surface), averaged: vertex the mean, normal the normalised mean. Returns the grid (nan where no sample)
    and the number of samples fused per cell ``(h, w)``."""
    h = (camera.height + stride - 1) // stride
    w = (camera.width + stride - 1) // stride
    V = np.full((h, w, 3), np.nan)
    N = np.full((h, w, 3), np.nan)
    count = np.zeros((h, w), np.int64)
    if not sources:
        return DepthGrid(V, N, int(stride)), count
    R_r, t_r = T_r_w[:3, :3], T_r_w[:3, 3]
    Ys, Ns, Ps = [], [], []
    for s in sources:
        R_rc = R_r @ s.T_w_c[:3, :3]
        t_rc = R_r @ s.T_w_c[:3, 3] + t_r
        Ys.append(s.V @ R_rc.T + t_rc)
        Ns.append(s.N @ R_rc.T)
        Ps.append(np.full(len(s.V), s.priority, np.int64))
    Y, Nr, P = np.concatenate(Ys), np.concatenate(Ns), np.concatenate(Ps)
    z = Y[:, 2]
    front = z > 1e-6
    inv_z = 1.0 / np.where(front, z, 1.0)
    j = np.floor((camera.fx * Y[:, 0] * inv_z + camera.cx) / stride + 0.5)
    i = np.floor((camera.fy * Y[:, 1] * inv_z + camera.cy) / stride + 0.5)
    facing = np.einsum("ij,ij->i", Nr, Y) < 0
    keep = np.flatnonzero(front & facing & (i >= 0) & (i < h) & (j >= 0) & (j < w))
    if not len(keep):
        return DepthGrid(V, N, int(stride)), count
    cell = (i[keep] * w + j[keep]).astype(np.int64)
    Y, Nr, P, z = Y[keep], Nr[keep], P[keep], z[keep]
    # per cell, the first sample in (priority, depth) order is the front of the surface it sees (a z-buffer)
    key = P * 1e3 + z
    front_key = np.full(h * w, np.inf)
    np.minimum.at(front_key, cell, key)
    head_of = np.zeros(h * w, np.int64)
    is_head = key == front_key[cell]
    head_of[cell[is_head]] = np.flatnonzero(is_head)
    head = head_of[cell]
    same = (P == P[head]) & (z <= z[head] * (1.0 + band)) & (np.einsum("ij,ij->i", Nr, Nr[head]) >= min_normal_cos)
    cell, Y, Nr = cell[same], Y[same], Nr[same]
    n = np.bincount(cell, minlength=h * w)
    sv = np.stack([np.bincount(cell, Y[:, k], minlength=h * w) for k in range(3)], axis=1)
    sn = np.stack([np.bincount(cell, Nr[:, k], minlength=h * w) for k in range(3)], axis=1)
    has = n > 0
    Vf, Nf = V.reshape(-1, 3), N.reshape(-1, 3)
    Vf[has] = sv[has] / n[has, None]
    Nf[has] = sn[has] / np.linalg.norm(sn[has], axis=1, keepdims=True)
    count.reshape(-1)[:] = n
    return DepthGrid(V, N, int(stride)), count


def _to_reference(X: np.ndarray, T_r_w: np.ndarray, R: np.ndarray, t: np.ndarray, camera: PinholeCamera
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A frame's camera points ``X (M, 3)`` at the frame pose ``T_c_w = (R, t)`` seen from the reference
    ``T_r_w``: the rotation ``R_rc`` from the frame's camera to the reference's, the points there ``Y (M, 3)``,
    their pixels ``u, v (M,)`` in ``camera`` and whether they lie in front of it."""
    R_r, t_r = T_r_w[:3, :3], T_r_w[:3, 3]
    # frame camera -> world -> reference camera, in one rotation and translation
    R_rc = R_r @ R.T
    Y = X @ R_rc.T + (t_r - R_rc @ t)
    z = Y[:, 2]
    front = z > 1e-6
    inv_z = 1.0 / np.where(front, z, 1.0)
    return R_rc, Y, camera.fx * Y[:, 0] * inv_z + camera.cx, camera.fy * Y[:, 1] * inv_z + camera.cy, front


@dataclass
class DenseTerm:
    """Point-to-plane residuals of a frame's depth points ``X (M, 3)`` (camera frame, sigma ``(M,)``
    m) against a reference grid seen from ``T_r_w (4, 4)`` (module docstring)."""

    X: np.ndarray
    sigma: np.ndarray
    ref: DepthGrid
    T_r_w: np.ndarray
    camera: PinholeCamera
    max_distance: float = 0.05  # m; larger point-to-plane distances are no association
    T_prior: np.ndarray | None = None  # (4, 4) T_c_w the pose is weakly held to (the motion prediction), or None
    prior_sigma: tuple[float, float] = (0.02, 1.0)  # (m, deg) of that prior
    charged: np.ndarray | None = None  # (M,) bool: the points that cost the gate when unassociated (None: all)

    def _in_reference(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """For the pose ``T_c_w = (R, t)``: the points in the reference camera ``Y (M, 3)``, their pixels
        ``u, v (M,)`` there, and whether they lie in front of it (:func:`_to_reference`)."""
        return _to_reference(self.X, self.T_r_w, R, t, self.camera)[1:]

    def in_view(self, T_c_w: np.ndarray, margin_px: float) -> np.ndarray:
        """``(M,)`` bool: the points that ``T_c_w`` puts in front of the reference camera and at least
        ``margin_px`` inside its image (the grid's extent)."""
        _, u, v, front = self._in_reference(T_c_w[:3, :3], T_c_w[:3, 3])
        h, w = self.ref.V.shape[:2]
        s = self.ref.stride
        # the grid's cells cover [-s/2, (w - 1/2) s) px: the image as the association's rounding sees it
        lo, hi_u, hi_v = -0.5 * s + margin_px, (w - 0.5) * s - margin_px, (h - 0.5) * s - margin_px
        return front & (u >= lo) & (u < hi_u) & (v >= lo) & (v < hi_v)

    def associate(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For the pose ``T_c_w = (R, t)``: indices of the associated points, their normals ``n`` in the
        reference camera and signed distances ``d = n . (Y_r - V)`` (m)."""
        Y, u, v, front = self._in_reference(R, t)
        s = self.ref.stride
        h, w = self.ref.V.shape[:2]
        # nearest grid cell of the projection (pixel / stride, rounded)
        j = np.floor(u / s + 0.5)
        i = np.floor(v / s + 0.5)
        idx = np.flatnonzero(front & (i >= 0) & (i < h) & (j >= 0) & (j < w))
        i, j = i[idx].astype(np.int64), j[idx].astype(np.int64)
        cell = i * w + j
        V = self.ref.V.reshape(-1, 3)[cell]
        N = self.ref.N.reshape(-1, 3)[cell]
        diff = Y[idx] - V
        d = np.einsum("ij,ij->i", N, diff)
        good = np.isfinite(d) & (np.abs(d) <= self.max_distance)
        return idx[good], N[good], d[good]

    def every(self, step: int) -> "DenseTerm":
        """The same term on every ``step``-th point (the points, their sigmas and ``charged`` thinned together)."""
        if step <= 1:
            return self
        return replace(self, X=self.X[::step], sigma=self.sigma[::step],
                       charged=None if self.charged is None else self.charged[::step])

    def associated_fraction(self, T_c_w: np.ndarray) -> float:
        """The share of the points that ``T_c_w`` associates (:meth:`associate`): how much of the frame's depth
        the reference explains at that pose."""
        return len(self.associate(T_c_w[:3, :3], T_c_w[:3, 3])[0]) / len(self.X)

    def residuals(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Whitened residuals ``e (K,)`` of the associated points, their Jacobian ``(K, 6)`` in the pose
        step ``(omega, tau)`` (module docstring), and the whitened chi^2 at the gate
        ``(max_distance / sigma)^2`` of each point left without an association (of the ``charged`` points
        only, when set: a point the reference never saw is no evidence either way)."""
        idx, n, d = self.associate(R, t)
        missing = np.ones(len(self.X), bool) if self.charged is None else self.charged.copy()
        missing[idx] = False
        gate = (self.max_distance / self.sigma[missing]) ** 2
        inv_s = 1.0 / self.sigma[idx]
        R_r = self.T_r_w[:3, :3]
        m = n @ R_r @ R.T  # rows: R R_r^T n
        p = self.X[idx] - t
        J = np.empty((len(idx), 6))
        J[:, :3] = np.cross(m, p) * inv_s[:, None]
        J[:, 3:] = -m * inv_s[:, None]
        e = d * inv_s
        if self.T_prior is not None:
            e_p, J_p = self.prior_residuals(R, t)
            e, J = np.concatenate([e, e_p]), np.vstack([J, J_p])
        return e, J, gate

    def prior_residuals(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Six residuals holding ``T_c_w = (R, t)`` to ``T_prior = (R_p, t_p)``: with ``D = T T_prior^-1 =
        (R R_p^T, t - R R_p^T t_p)``, ``e = (Log(R R_p^T) / s_r, (t - q) / s_t)``, ``q = R R_p^T t_p``; to
        first order ``de/d omega = (I / s_r, [q]_x / s_t)`` and ``de/d tau = (0, I / s_t)``. It fixes the
        directions the planes leave free (a slide along a wall) when few features are matched."""
        return pose_prior_residuals(R, t, self.T_prior, self.prior_sigma)


def pose_prior_residuals(R: np.ndarray, t: np.ndarray, T_prior: np.ndarray, prior_sigma: tuple[float, float]
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Six whitened residuals holding ``T_c_w = (R, t)`` to ``T_prior`` with sigmas ``prior_sigma = (m, deg)``, and
    their Jacobian ``(6, 6)`` in the step ``(omega, tau)`` (:meth:`DenseTerm.prior_residuals` gives the formulas)."""
    s_t, s_r = prior_sigma[0], np.radians(prior_sigma[1])
    R_p, t_p = T_prior[:3, :3], T_prior[:3, 3]
    dR = R @ R_p.T
    q = dR @ t_p
    e = np.concatenate([so3_log(dR) / s_r, (t - q) / s_t])
    J = np.zeros((6, 6))
    J[:3, :3] = np.eye(3) / s_r
    J[3:, :3] = skew(q) / s_t
    J[3:, 3:] = np.eye(3) / s_t
    return e, J


@dataclass
class MotionPrior:
    """A Gaussian prior on a pose alone (ours): the term a motion-only BA takes as ``dense`` when there is no depth
    term, holding ``T_c_w`` to ``T_prior`` (the motion model's prediction) with sigmas ``prior_sigma = (m, deg)``.
    Where the features fix the pose, hundreds of them outweigh it; where they leave a direction free (points on one
    far plane: a sideways step and a small rotation look alike), it decides."""

    T_prior: np.ndarray
    prior_sigma: tuple[float, float]

    def residuals(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Whitened residuals ``e (6,)``, their Jacobian ``(6, 6)`` and no unassociated points (an empty gate):
        the interface of :meth:`DenseTerm.residuals`."""
        e, J = pose_prior_residuals(R, t, self.T_prior, self.prior_sigma)
        return e, J, np.zeros(0)


@dataclass
class ReprojectionTerm:
    """Reprojection residuals of map points ``X_w (M, 3)`` seen at pixels ``uv (M, 2)`` (intrinsics ``K``), each
    whitened by its keypoint's ``sigma (M,)`` px: the features that join a depth alignment
    (:func:`align_depth`'s ``features``).

    For ``T_c_w = (R, t)`` and the step of :func:`align_depth` (``R <- Exp(omega) R``, ``t <- t + tau``), the camera
    point ``p = R X + t`` moves by ``-[R X]_x omega + tau``: the left perturbation of
    :func:`~dynslam_lab.geometry.projection.projection_jacobian` with ``nu = tau + [t]_x omega``."""

    X_w: np.ndarray
    uv: np.ndarray
    K: np.ndarray
    sigma: np.ndarray

    def residuals(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whitened residuals ``(2M,)`` (u and v of each point in turn) and their Jacobian ``(2M, 6)``; points
        behind the camera are left out."""
        p = self.X_w @ R.T + t
        ok = p[:, 2] > 1e-6
        p, uv, s = p[ok], self.uv[ok], self.sigma[ok]
        m = len(p)
        # the left perturbation's Jacobian (geometry.projection); this step moves p by -[p - t]_x omega + tau,
        # the left one's by -[p]_x omega + nu: nu = tau + [t]_x omega
        J_left, xz, yz = projection_jacobian(p.T, self.K)
        J = np.empty((m, 2, 6))
        J[:, 0], J[:, 1] = J_left[:, :m].T, J_left[:, m:].T
        J[..., :3] += J[..., 3:] @ skew(t)
        J /= s[:, None, None]
        e = np.stack([(self.K[0, 0] * xz + self.K[0, 2] - uv[:, 0]) / s, (self.K[1, 1] * yz + self.K[1, 2] - uv[:, 1]) / s], axis=1)
        return e.reshape(-1), J.reshape(-1, 6)


@dataclass
class ImageLevel:
    """A grey image reduced by ``scale`` (an integer: 2 = half size, area average) for the photometric term: the
    image ``I (h, w)`` float32, its gradients ``gx, gy`` (grey levels per pixel of this level, Sobel / 8), its
    depth ``z (h, w)`` (m, nan where a block of the full-resolution depth is missing or spans a depth edge)
    and the camera of the level. ``invalid (h, w)`` bool (None: none): pixels whose intensity is no evidence
    as a *reference* (what the screening judged dynamic in that image): a frame's sample that lands on one is
    left out of the photometric term (:meth:`PhotometricTerm.evaluate`)."""

    I: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    z: np.ndarray
    camera: PinholeCamera
    scale: int
    invalid: np.ndarray | None = None


def image_level(gray: np.ndarray, depth: np.ndarray, camera: PinholeCamera, scale: int,
                max_depth_spread: float = 0.03) -> ImageLevel:
    """The :class:`ImageLevel` of a grey image ``gray (H, W)`` and its depth ``depth (H, W)`` (m, 0 = none) at
    ``scale``. A level pixel's depth is the mean of its ``scale x scale`` block of depth pixels when all of them
    have depth and they span at most ``max_depth_spread`` m per m of depth (a block across a silhouette has no
    one depth to warp its intensity with)."""
    s = int(scale)
    h, w = gray.shape[0] // s, gray.shape[1] // s
    I = gray[: h * s, : w * s].astype(np.float32)
    if s > 1:
        I = cv2.resize(I, (w, h), interpolation=cv2.INTER_AREA)
    gx = cv2.Sobel(I, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(I, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    d = np.asarray(depth, np.float32)[: h * s, : w * s]
    d = np.where(np.isfinite(d) & (d > 0), d, np.float32(0))
    # block statistics with OpenCV (a strided numpy reduction over (h, s, w, s) costs ~5x more): the max and min
    # over the s x s window whose top-left corner is each block's, the mean by area averaging; a block counts
    # only when every pixel has depth, i.e. when its minimum is above 0 (missing depth was set to 0 just above)
    k = np.ones((s, s), np.uint8)
    hi = cv2.dilate(d, k, anchor=(0, 0))[::s, ::s]
    lo = cv2.erode(d, k, anchor=(0, 0))[::s, ::s]
    mean = cv2.resize(d, (w, h), interpolation=cv2.INTER_AREA) if s > 1 else d
    z = np.where((lo > 0) & (hi - lo <= max_depth_spread * mean), mean, np.float32(np.nan))
    return ImageLevel(I, gx, gy, z, camera.scaled(1.0 / s), s)


@dataclass
class PhotometricTerm:
    """Intensity residuals of a frame's pixels against an earlier ("reference") image, the photometric half of
    the hybrid RGB-D odometry of Steinbruecker et al. (2011) (Park et al. 2017 use the same pair of terms)::

        e_j = (I_r(pi(T_r_c X_j)) - c_j) / sigma

    ``X_j (M, 3)`` the frame's pixels with depth (camera frame), ``c_j`` their intensities, ``I_r`` the
    reference's image at the same level (bilinear), ``pi`` its projection. With ``Y = T_r_c X`` and the step of
    :func:`align_depth` (``dY / d omega = R_rc [p]_x``, ``dY / d tau = -R_rc``, ``p = X - t``, as for
    :class:`DenseTerm`) and ``a = R_rc^T (d pi / d Y)^T grad I_r``::

        d e / d omega = (a x p) / sigma,     d e / d tau = -a / sigma

    It fixes what a plane's depth leaves free (a slide along a plain wall, the turn about its normal) wherever
    the image has an edge: a poster's border, the line where the wall meets the floor.

    With ``affine`` (the default) the frame's intensities are first carried to the reference's brightness,
    ``c_j -> a c_j + b``, by :func:`brightness_transfer` fitted on the samples at the pose being evaluated (a
    camera's auto-exposure brightens or darkens the whole image between two frames). ``a`` and ``b`` are fitted
    afresh at each evaluation, not carried as unknowns: the Jacobian above is kept (for fixed weights the pose where
    the gradient vanishes is the one with ``a, b`` among the unknowns; only the Gauss-Newton steps are shorter)."""

    X: np.ndarray
    c: np.ndarray
    ref: ImageLevel
    T_r_w: np.ndarray
    sigma: float
    affine: bool = True

    def residuals(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whitened residuals ``(K,)`` of the samples that ``(R, t)`` (``T_c_w``) puts inside the reference image
        (one pixel from its border), and their Jacobian ``(K, 6)``."""
        _, e, J = self.evaluate(R, t)
        return e, J

    def evaluate(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`residuals` with the indices ``(K,)`` of the samples they belong to."""
        cam, h, w = self.ref.camera, self.ref.I.shape[0], self.ref.I.shape[1]
        R_rc, Y, u, v, front = _to_reference(self.X, self.T_r_w, R, t, cam)
        idx = np.flatnonzero(front & (u >= 0) & (u <= w - 2) & (v >= 0) & (v <= h - 2))
        if self.ref.invalid is not None and len(idx):
            # a sample whose bilinear footprint touches a pixel the reference's screening judged dynamic: a
            # mover there, not the static scene the sample saw
            inv = self.ref.invalid
            iu, iv = u[idx].astype(np.int64), v[idx].astype(np.int64)
            bad = inv[iv, iu] | inv[iv, iu + 1] | inv[iv + 1, iu] | inv[iv + 1, iu + 1]
            idx = idx[~bad]
        if len(idx) == 0:
            return idx, np.zeros(0), np.zeros((0, 6))
        maps = (u[idx].astype(np.float32).reshape(-1, 1), v[idx].astype(np.float32).reshape(-1, 1))
        I, gx, gy = (cv2.remap(img, *maps, cv2.INTER_LINEAR).reshape(-1).astype(np.float64)
                     for img in (self.ref.I, self.ref.gx, self.ref.gy))
        Yi = Y[idx]
        iz = 1.0 / Yi[:, 2]
        # grad I_r times d pi / d Y, one row per sample
        g = np.empty((len(idx), 3))
        g[:, 0] = gx * cam.fx * iz
        g[:, 1] = gy * cam.fy * iz
        g[:, 2] = -(gx * cam.fx * Yi[:, 0] + gy * cam.fy * Yi[:, 1]) * iz * iz
        a = g @ R_rc
        p = self.X[idx] - t
        J = np.empty((len(idx), 6))
        J[:, :3] = np.cross(a, p) / self.sigma
        J[:, 3:] = -a / self.sigma
        c = self.c[idx]
        if self.affine:
            gain, bias = brightness_transfer(c, I, self.sigma)
            c = gain * c + bias
        return idx, (I - c) / self.sigma, J


def brightness_transfer(c: np.ndarray, I: np.ndarray, sigma: float, scale: float = 2.0, rounds: int = 3,
                        gain_range: tuple[float, float] = (0.5, 2.0)) -> tuple[float, float]:
    """The affine brightness transfer ``(gain, bias)`` that maps a frame's intensities ``c (K,)`` onto the
    reference's ``I (K,)`` at the same scene points, ``I ~ gain c + bias``. A camera's auto-exposure scales the
    whole image between two frames (TUM RGB-D was recorded with it on); the photometric term of Steinbruecker et
    al. (2011) assumes equal brightness, Engel et al. (2018, DSO) model the change as this affine map per pair of
    frames. Least squares, then ``rounds`` passes reweighted with Cauchy's weight ``1 / (1 + (r / (scale
    sigma))^2)`` on the residuals ``r`` of the last fit (occlusions, highlights and movers do not pull it), the
    gain held to ``gain_range``. The identity with fewer than 20 samples or no spread of intensities."""
    if len(c) < 20:
        return 1.0, 0.0
    gain, bias = 1.0, 0.0
    w = np.ones(len(c))
    s2 = (scale * sigma) ** 2
    for k in range(rounds + 1):
        if k:
            r = I - gain * c - bias
            w = 1.0 / (1.0 + r * r / s2)
        sw = w.sum()
        mc, mi = (w @ c) / sw, (w @ I) / sw
        dc = c - mc
        var = w @ (dc * dc)
        if not var > 1e-9 * sw:
            return gain, bias
        gain = float(np.clip((w @ (dc * (I - mi))) / var, *gain_range))
        bias = float(mi - gain * mc)
    return gain, bias


def photometric_term(frame_level: ImageLevel, ref_level: ImageLevel, T_r_w: np.ndarray, sigma: float,
                     min_gradient: float = 2.0, max_samples: int = 3000, exclude: np.ndarray | None = None,
                     affine: bool = True) -> PhotometricTerm | None:
    """The :class:`PhotometricTerm` of a frame's level against the reference's: the frame's pixels with depth and
    a gradient of at least ``min_gradient`` grey levels per pixel, the ``max_samples`` strongest, leaving out
    ``exclude`` (``(h, w)`` bool at the level: pixels the screening judged dynamic). None with fewer than 20."""
    mag = np.hypot(frame_level.gx, frame_level.gy)
    ok = np.isfinite(frame_level.z) & (mag >= min_gradient)
    if exclude is not None:
        ok &= ~exclude[: ok.shape[0], : ok.shape[1]]
    i, j = np.nonzero(ok)
    if len(i) < 20:
        return None
    if len(i) > max_samples:
        keep = np.argpartition(-mag[i, j], max_samples)[:max_samples]
        i, j = i[keep], j[keep]
    X = frame_level.camera.backproject(np.column_stack([j, i]), frame_level.z[i, j])
    return PhotometricTerm(X, frame_level.I[i, j].astype(np.float64), ref_level, T_r_w, float(sigma), bool(affine))


def _huber_weights(e: np.ndarray, huber: float) -> np.ndarray:
    """IRLS weights of Huber's function at ``huber`` for whitened residuals ``e``: 1 inside, ``huber / |e|`` beyond."""
    a = np.abs(e)
    return np.where(a <= huber, 1.0, huber / np.maximum(a, 1e-12))


@dataclass
class HybridTerm:
    """A frame's :class:`PhotometricTerm` with its :class:`DenseTerm` (or without one: ``depth`` None), as one term of
    motion-only BA (``slam.optimize.optimize_pose``'s ``dense``): the hybrid RGB-D odometry of Steinbruecker et al.
    (2011); each term has its own reference (tracking's refinement aligns the image to the reference keyframe's,
    the depth to the last frame's). The photometric residuals are Huber-weighted at ``huber`` (whitened units) inside the term
    (iteratively reweighted: each residual and its Jacobian row scaled by the square root of its weight at the
    current pose), so that an occlusion or a highlight stays bounded in every round of the BA, also in the last,
    which has no robust kernel of its own."""

    depth: DenseTerm | None
    photometric: PhotometricTerm
    huber: float = 2.0

    def residuals(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`DenseTerm.residuals` (none without a depth term) with the photometric rows appended (the gate of
        unassociated depth points as the depth term's)."""
        if self.depth is None:
            e, J, gate = np.zeros(0), np.zeros((0, 6)), np.zeros(0)
        else:
            e, J, gate = self.depth.residuals(R, t)
        e_p, J_p = self.photometric.residuals(R, t)
        s = np.sqrt(_huber_weights(e_p, self.huber))
        return np.concatenate([e, e_p * s]), np.vstack([J, J_p * s[:, None]]), gate


def depth_sigma(z: np.ndarray) -> np.ndarray:
    """Standard deviation (m) of a Kinect-like depth measurement at ``z`` m: 1 mm + 2 mm per m^2 (the
    quadratic growth of a disparity sensor's error, Khoshelham and Elberink 2012, rounded)."""
    return 0.001 + 0.002 * z * z


@dataclass
class DenseAlignment:
    """Result of :func:`align_depth`: the aligned ``T_c_w``, the median point-to-plane distance (m) of the
    associated points at the start and at the end, and how many points were associated at the end."""

    T_c_w: np.ndarray
    d_start: float
    d_end: float
    n: int


def median_distance(term: DenseTerm, R: np.ndarray, t: np.ndarray) -> tuple[float, int]:
    """Median point-to-plane distance (m) of the points associated under ``(R, t)``, and how many there are."""
    _, _, d = term.associate(R, t)
    return (float(np.median(np.abs(d))) if len(d) else float("nan")), len(d)


def align_depth(term: DenseTerm, T_start: np.ndarray, iterations: int = 8, huber: float = 2.0,
                tol_rad: float = 1e-5, tol_m: float = 1e-4, features: ReprojectionTerm | None = None,
                photometric: PhotometricTerm | None = None) -> DenseAlignment:
    """Gauss-Newton on ``term`` (point-to-plane, and its prior when it has one) from ``T_start`` (world ->
    camera), each residual Huber-weighted at ``huber`` (whitened units). At most ``iterations`` steps, fewer
    once a step turns the camera by less than ``tol_rad`` and moves it by less than ``tol_m``. With
    ``features`` their reprojection residuals join the sum: the directions the planes leave free (a slide
    along a wall and the floor) are then fixed by the features, not only by the prior; with ``photometric``
    (:class:`PhotometricTerm`) the image's edges fix them (hybrid RGB-D odometry)."""
    R, t = T_start[:3, :3].copy(), T_start[:3, 3].copy()
    d_start, _ = median_distance(term, R, t)
    for _ in range(iterations):
        e, J, _ = term.residuals(R, t)
        if features is not None:
            e_f, J_f = features.residuals(R, t)
            e, J = np.concatenate([e, e_f]), np.vstack([J, J_f])
        if photometric is not None:
            e_p, J_p = photometric.residuals(R, t)
            e, J = np.concatenate([e, e_p]), np.vstack([J, J_p])
        w = _huber_weights(e, huber)
        H = J.T @ (J * w[:, None])
        g = J.T @ (w * e)
        try:
            step = -np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        R = so3_exp(step[:3]) @ R
        t = t + step[3:]
        if np.linalg.norm(step[:3]) < tol_rad and np.linalg.norm(step[3:]) < tol_m:
            break
    d_end, n = median_distance(term, R, t)
    return DenseAlignment(make_pose(R, t), d_start, d_end, n)


def reduced_depth_points(depth_small: np.ndarray, camera: PinholeCamera, step: int = 1) -> tuple[PinholeCamera, np.ndarray]:
    """A depth image reduced from ``camera``'s resolution (``depth_small (h, w)``, m, 0 = none) as the dense
    alignments align it: the reduced grid's camera (as a reference, ``vertex_normal_grid(depth_small, cam, 1)``)
    and its camera points with depth, every ``step``-th cell in both directions, ``(K, 3)``."""
    cam = camera.scaled(depth_small.shape[1] / camera.width)
    X = cam.backproject_depth(depth_small)[::step, ::step].reshape(-1, 3)
    return cam, X[np.isfinite(X[:, 2])]
