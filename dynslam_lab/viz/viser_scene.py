"""The 3D scene of a run in viser: trajectories, keyframes, sparse and dense maps, loops.

What ``dynslam view OUTDIR`` shows and what a notebook embeds with :func:`show_inline`, in the
colours of every other figure (:mod:`dynslam_lab.viz.colors`, listed in the on-screen legend):

* the estimated trajectory (red) and the ground truth (near-black, aligned to the estimate with
  Umeyama/Horn, so both share the estimate's world frame);
* every keyframe as a wireframe frustum (orange), all of them in *one* line-segment set,
  and image frustums with the keyframe thumbnails for up to ``max_image_frustums`` evenly
  spaced keyframes;
* the sparse map points (their colour, or green) and the keypoints judged dynamic (magenta):
  only those of the frames within ``dynamic_window`` of the playback frame, all on demand;
* the dense static map ``map.ply``;
* loop edges between keyframe centres (teal);
* a playback slider stepping through the tracked frames: a blue frustum at the frame's pose,
  and the thumbnail of the newest keyframe at or before it.

Everything goes to the browser in a few large messages (one point cloud per layer, one
line-segment set per polyline family, the path thinned to ``max_path_points``), and in stages,
so that the first picture does not wait for the large layers (``benchmarks/view_startup.py``):

1. at once: the trajectories, loop edges, the playback frustum, the GUI and the legend;
2. ``defer_layers`` seconds after the first browser connects: the keyframes (wireframes and
   thumbnails), the sparse map, the dynamic points of the current window, and the dense map
   when it has at most ``preview_dense_points`` points (a demo-size run);
3. for a larger dense map, ``defer_dense`` seconds later a seeded subset of
   ``preview_dense_points``, and ``defer_dense`` seconds after that all of it (up to
   ``max_dense_points``). :func:`load_run` can leave ``map.ply`` on disk (``dense=False``) to
   be read in the background while the server already answers.

The initial camera frames the whole scene (path and maps) with viser's 75 degree field of view.
The server binds to ``127.0.0.1`` unless a host is given on purpose, and answers only requests
whose ``Host`` is its own address and whose ``Origin``, if any, is its own page
(:mod:`dynslam_lab.viz.access`): other web pages and DNS-rebinding attacks are refused.

Conventions: poses ``T_w_c`` map camera to world (OpenCV camera axes: x right, y down,
z forward, which is also viser's frustum convention). Quaternions are ``x y z w`` in TUM
files and ``w x y z`` in viser: :func:`wxyz_from_matrix` is the only conversion.
"""

from __future__ import annotations

import dataclasses
import html
import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..evaluation.ate import align_trajectory
from ..evaluation.sync import associate_trajectories
from ..evaluation.trajectory import Trajectory, read_tum_trajectory
from ..geometry.se3 import matrix_to_quat_xyzw
from ..mapping.ply import read_ply
from ..runs.layout import read_run
from .access import guard_viser_server
from .colors import PALETTE, hex_color

__all__ = [
    "SceneConfig",
    "RunData",
    "SceneHandles",
    "load_run",
    "wxyz_from_matrix",
    "frustum_segments",
    "polyline_segments",
    "scene_bounds",
    "initial_view",
    "dynamic_pose_index",
    "build_scene",
    "start_viewer",
    "play_loop",
    "show_inline",
    "free_port",
    "COLORS",
    "VIEWER_FOV_Y",
]

#: RGB colours (uint8) of the layers: the shared palette of :mod:`dynslam_lab.viz.colors`.
COLORS = {k: PALETTE[k] for k in ("estimate", "ground_truth", "keyframe", "current", "static", "dynamic", "loop")}
#: viser's vertical field of view of the initial camera (radians), used to frame the scene.
VIEWER_FOV_Y = float(np.deg2rad(75.0))


@dataclass(frozen=True)
class SceneConfig:
    """What the viewer draws and how big (units: metres unless noted)."""

    frustum_scale: float = 0.08  # metres from apex to image plane of keyframe frustums (ours)
    trajectory_thickness: float = 3.0  # screen pixels of trajectory lines (ours)
    point_size_sparse: float = 0.02  # metres (ours)
    point_size_dense: float = 0.012  # metres (ours; ~ the dense map's 2 cm voxels)
    max_dense_points: int = 1_000_000  # dense points sent at most, random subset with seed=0 (ours)
    preview_dense_points: int = 150_000  # dense points sent with the keyframes (all of a demo-size map; ours)
    max_image_frustums: int = 40  # keyframes shown with their thumbnail at start-up (ours)
    dynamic_window: int = 15  # frames either side of the playback frame whose dynamic points are drawn (ours)
    defer_layers: float = 2.0  # seconds after the first browser connects before keyframes and maps are sent (ours)
    defer_dense: float = 2.0  # seconds after those before a large dense map is sent whole (ours; both 0 = all at once)
    max_path_points: int = 3000  # trajectory vertices drawn at most, evenly spaced (playback keeps all; ours)
    fov_y: float = float(2 * np.arctan(240 / 525))  # radians, vertical field of view of frustums, 49 deg (Kinect, f = 525 px)
    aspect: float = 4 / 3  # width / height of frustums (640 x 480)
    gui: bool = True  # add the playback slider, layer toggles and legend (False for a static notebook embed)

    def __post_init__(self) -> None:
        for name in ("frustum_scale", "trajectory_thickness", "point_size_sparse", "point_size_dense", "fov_y", "aspect"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SceneConfig.{name} must be > 0, got {getattr(self, name)}")
        for name in ("max_dense_points", "preview_dense_points", "max_image_frustums", "dynamic_window",
                     "defer_layers", "defer_dense"):
            if getattr(self, name) < 0:
                raise ValueError(f"SceneConfig.{name} must be >= 0, got {getattr(self, name)}")
        if self.max_path_points < 2:
            raise ValueError(f"SceneConfig.max_path_points must be >= 2, got {self.max_path_points}")


@dataclass
class RunData:
    """Everything of a run folder the viewer draws (missing parts are None).

    Attributes
    ----------
    outdir : the run folder.
    trajectory : estimated trajectory (``trajectory.txt``).
    ground_truth : ground truth aligned into the estimate's world frame, or None.
    kf_ids, kf_frame_index, kf_poses, kf_timestamps : keyframes (``keyframes.npz``):
        ``(K,)``, ``(K,)``, ``(K, 4, 4)`` ``T_w_c``, ``(K,)`` seconds (None when absent).
    loop_edges : ``(L, 2)`` keyframe ids.
    map_xyz, map_rgb : sparse map points ``(M, 3)`` metres, ``(M, 3)`` uint8 (``map_points.npz``).
    dynamic_xyz, dynamic_frame : ``(D, 3)`` keypoints judged dynamic and ``(D,)`` the frame
        index each was seen in (``dynamic_points.npz``; the frames may be absent: None).
    dense_xyz, dense_rgb : dense static map (``map.ply``); None until read when
        :func:`load_run` was told ``dense=False`` (then :meth:`load_dense` reads it).
    dense_path, dense_count : ``map.ply`` and its number of points (from its header).
    thumbs : keyframe id -> thumbnail path (``thumbs/KFID.jpg``).
    """

    outdir: Path
    trajectory: Trajectory | None = None
    ground_truth: Trajectory | None = None
    kf_ids: np.ndarray | None = None
    kf_frame_index: np.ndarray | None = None
    kf_poses: np.ndarray | None = None
    kf_timestamps: np.ndarray | None = None
    loop_edges: np.ndarray | None = None
    map_xyz: np.ndarray | None = None
    map_rgb: np.ndarray | None = None
    dynamic_xyz: np.ndarray | None = None
    dynamic_frame: np.ndarray | None = None
    dense_xyz: np.ndarray | None = None
    dense_rgb: np.ndarray | None = None
    dense_path: Path | None = None
    dense_count: int = 0
    thumbs: dict[int, Path] = field(default_factory=dict)
    summary: dict = field(default_factory=dict)

    @property
    def n_keyframes(self) -> int:
        return 0 if self.kf_ids is None else len(self.kf_ids)

    def load_dense(self) -> None:
        """Read ``map.ply`` now if it was left on disk (no-op otherwise)."""
        if self.dense_xyz is None and self.dense_path is not None:
            self.dense_xyz, self.dense_rgb = read_ply(self.dense_path)


# ---------------------------------------------------------------------------- loading
def load_run(outdir: str | Path, ground_truth: str | Path | Trajectory | None = None, dense: bool = True) -> RunData:
    """Read a run folder (:func:`dynslam_lab.runs.read_run`) for the viewer.

    Parameters
    ----------
    outdir : the run folder; at least one of ``trajectory.txt``, ``keyframes.npz``,
        ``map_points.npz``, ``map.ply`` must be there.
    ground_truth : a TUM ground-truth file or :class:`Trajectory`; when None, the
        ``groundtruth.txt`` of the sequence named in ``summary.json`` (key ``sequence``) or
        ``OUTDIR/groundtruth.txt`` is used if present. It is aligned (SE(3), Umeyama) into the
        estimate's frame.
    dense : read ``map.ply`` now (True), or check its header only and leave the points for
        :meth:`RunData.load_dense` (False: what ``dynslam view`` does, so that the server
        starts before a large map is read).
    """
    contents = read_run(outdir)
    if contents.empty:
        raise FileNotFoundError(
            f"{contents.outdir}: nothing to show (no trajectory.txt, keyframes.npz, map_points.npz or map.ply)"
        )
    run = RunData(outdir=contents.outdir, summary=contents.summary, trajectory=contents.trajectory,
                  dense_path=contents.dense_path, dense_count=contents.dense_count, thumbs=contents.thumbs)
    kf = contents.keyframes
    if kf is not None:
        K = len(kf["ids"])
        run.kf_ids = kf["ids"].astype(np.int64)
        run.kf_frame_index = kf["frame_index"].astype(np.int64)
        run.kf_poses = kf["poses"].astype(np.float64)
        if "timestamps" in kf and kf["timestamps"].shape == (K,):
            run.kf_timestamps = kf["timestamps"].astype(np.float64)
        run.loop_edges = kf["loop_edges"].astype(np.int64)
    if contents.map_points is not None:
        run.map_xyz = contents.map_points["xyz"].astype(np.float64)
        rgb = contents.map_points.get("rgb")
        run.map_rgb = rgb.reshape(-1, 3).astype(np.uint8) if rgb is not None else None
    if contents.dynamic_points is not None:
        run.dynamic_xyz = contents.dynamic_points["xyz"].astype(np.float64)
        fr = contents.dynamic_points.get("frame")
        if fr is not None and fr.reshape(-1).shape == (len(run.dynamic_xyz),):
            run.dynamic_frame = fr.reshape(-1).astype(np.int64)
    if dense and run.dense_path is not None:
        run.load_dense()
    gt = _find_ground_truth(run.outdir, run.summary, ground_truth)
    if gt is not None and run.trajectory is not None:
        gt_a, est_a = associate_trajectories(gt, run.trajectory)
        if len(gt_a) >= 3:
            _, a = align_trajectory(est_a, gt_a, "se3")  # S maps estimate -> ground truth
            S = np.eye(4)
            S[:3, :3], S[:3, 3] = a.R, a.t
            gt = gt.transformed(np.linalg.inv(S))
    run.ground_truth = gt
    return run


def _find_ground_truth(outdir: Path, summary: dict, given) -> Trajectory | None:
    if isinstance(given, Trajectory):
        return given
    if given is not None:
        return read_tum_trajectory(given)
    candidates = [outdir / "groundtruth.txt"]
    seq = summary.get("sequence")
    if isinstance(seq, str):
        candidates.insert(0, Path(seq) / "groundtruth.txt")
    for c in candidates:
        if c.is_file():
            return read_tum_trajectory(c)
    return None


# ------------------------------------------------------------------------ geometry
def wxyz_from_matrix(R: np.ndarray) -> np.ndarray:
    """viser quaternion ``(w, x, y, z)`` of rotation matrices ``(3, 3)`` or ``(N, 3, 3)``.

    The one place where the TUM/scipy order ``x y z w`` becomes viser's ``w x y z``.
    """
    q = np.asarray(matrix_to_quat_xyzw(np.asarray(R, dtype=np.float64)))
    return np.concatenate([q[..., 3:4], q[..., :3]], axis=-1)


def polyline_segments(points: np.ndarray, max_points: int | None = None) -> np.ndarray:
    """Consecutive points ``(N, 3)`` as line segments ``(N - 1, 2, 3)``.

    With ``max_points``, a longer path is first thinned to that many evenly spaced vertices
    (first and last kept), one segment between each two.
    """
    P = np.asarray(points, dtype=np.float64)
    if max_points is not None and len(P) > max_points >= 2:
        P = P[np.unique(np.linspace(0, len(P) - 1, max_points).round().astype(np.int64))]
    return np.stack([P[:-1], P[1:]], axis=1)


def frustum_segments(poses: np.ndarray, fov_y: float, aspect: float, scale: float) -> np.ndarray:
    """Wireframe frustums of camera poses as line segments, 8 per camera.

    Parameters
    ----------
    poses : ``(K, 4, 4)`` ``T_w_c``.
    fov_y : vertical field of view (radians); ``aspect`` = width / height.
    scale : distance from the apex to the image rectangle (metres).

    Returns
    -------
    ``(8 K, 2, 3)`` segments: apex to the four corners, then the rectangle.
    """
    T = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    hy = scale * np.tan(fov_y / 2)
    hx = hy * aspect
    local = np.array([[0, 0, 0], [-hx, -hy, scale], [hx, -hy, scale], [hx, hy, scale], [-hx, hy, scale]])
    W = np.einsum("kij,pj->kpi", T[:, :3, :3], local) + T[:, None, :3, 3]  # (K, 5, 3)
    a = [0, 0, 0, 0, 1, 2, 3, 4]
    b = [1, 2, 3, 4, 2, 3, 4, 1]
    return np.stack([W[:, a], W[:, b]], axis=2).reshape(-1, 2, 3)


def scene_bounds(run: RunData) -> tuple[np.ndarray, float]:
    """Centre ``(3,)`` and radius (metres) of the sphere the initial view frames.

    The centre is that of the box holding the camera path and the bulk of the maps (2nd to
    98th percentile per axis, so stray points do not shrink the view); the radius holds the
    whole path, and at least half of that box (the path's surroundings fill the picture, the far
    walls may be cut), and at least 0.75 m (a desk-sized view).
    """
    path = run.trajectory.positions if run.trajectory is not None else (
        run.kf_poses[:, :3, 3] if run.kf_poses is not None else None)
    boxes = [] if path is None or not len(path) else [(path.min(axis=0), path.max(axis=0))]
    box = _map_box(run)
    if box is not None:
        boxes.append(box)
    if not boxes:
        return np.zeros(3), 1.0
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    centre = (lo + hi) / 2
    r_path = 1.1 * float(np.linalg.norm(path - centre, axis=1).max()) if boxes and path is not None and len(path) else 0.0
    return centre, max(r_path, 0.5 * float(np.linalg.norm(hi - lo)) / 2, 0.75)


def _up_direction(run: RunData) -> np.ndarray:
    """World 'up' guessed as the mean of the cameras' -y axes (cameras are held upright)."""
    poses = run.trajectory.poses if run.trajectory is not None else run.kf_poses
    if poses is None or len(poses) == 0:
        return np.array([0.0, 0.0, 1.0])
    up = -poses[:, :3, 1].mean(axis=0)
    n = np.linalg.norm(up)
    return up / n if n > 1e-6 else np.array([0.0, 0.0, 1.0])


def initial_view(run: RunData, fov_y: float = VIEWER_FOV_Y) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the viewer's camera starts: ``(eye (3,), look_at (3,), up (3,))`` in metres.

    It looks at the centre of :func:`scene_bounds` from far enough that its sphere fits the
    vertical field of view ``fov_y``: from behind and above the cameras, 35 degrees
    down, along the direction they look on average; for paths whose cameras look all around
    (a loop), from the side and 55 degrees above. The eye stays inside the mapped space (the
    2nd-98th percentile box of the maps, less 5 cm): a room's walls or ceiling between the eye
    and the scene would hide it, so the eye comes closer along the same line of sight.
    """
    centre, radius = scene_bounds(run)
    up = _up_direction(run)
    poses = run.trajectory.poses if run.trajectory is not None else run.kf_poses
    fwd = np.zeros(3) if poses is None or len(poses) == 0 else poses[:, :3, 2].mean(axis=0)
    fwd = fwd - (fwd @ up) * up  # horizontal part of the mean viewing direction
    if np.linalg.norm(fwd) > 0.3:
        horizontal, down = fwd / np.linalg.norm(fwd), np.deg2rad(35.0)
    else:
        side = np.cross(up, [1.0, 0.0, 0.0])
        if np.linalg.norm(side) < 1e-3:
            side = np.cross(up, [0.0, 1.0, 0.0])
        horizontal, down = -side / np.linalg.norm(side), np.deg2rad(55.0)
    view = np.cos(down) * horizontal - np.sin(down) * up  # unit viewing direction
    distance = 1.05 * radius / np.sin(fov_y / 2)
    box = _map_box(run)
    if box is not None:
        # stay inside the mapped space (a room's walls or ceiling between the eye and the scene
        # would hide it): come closer along the same line of sight
        lo, hi = box[0] + 0.05, box[1] - 0.05
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(view > 1e-9, (centre - lo) / view, np.where(view < -1e-9, (centre - hi) / view, np.inf))
        distance = float(np.clip(np.min(t), 0.5, distance)) if np.all(lo < hi) else distance
    return centre - distance * view, centre, up


def _map_box(run: RunData) -> tuple[np.ndarray, np.ndarray] | None:
    """2nd and 98th percentiles ``(3,)`` per axis of the maps' points (an even subset), or None."""
    maps = [x for x in (run.map_xyz, run.dense_xyz) if x is not None and len(x)]
    if not maps:
        return None
    P = np.concatenate([m[:: max(1, len(m) // 50_000)] for m in maps])  # percentiles of 1e6 points cost 0.1 s
    P = P[np.isfinite(P).all(axis=1)]
    return (np.percentile(P, 2, axis=0), np.percentile(P, 98, axis=0)) if len(P) else None


def dynamic_pose_index(run: RunData) -> np.ndarray | None:
    """``(D,)`` index into the trajectory of the pose nearest each dynamic point's frame, or None.

    The frames are sequence indices; their times are interpolated from the keyframes' frame
    indices and timestamps (a line fitted through them: a constant frame rate), else the
    trajectory index is taken to be the frame index (every frame tracked).
    """
    if run.dynamic_frame is None or run.trajectory is None or len(run.trajectory) == 0:
        return None
    frames = run.dynamic_frame.astype(np.float64)
    n = len(run.trajectory)
    kf_i, kf_t = run.kf_frame_index, run.kf_timestamps
    if kf_i is not None and kf_t is not None and len(np.unique(kf_i)) >= 2 and np.isfinite(kf_t).all():
        slope, offset = np.polyfit(kf_i.astype(np.float64), kf_t, 1)
        t = offset + slope * frames
        stamps = run.trajectory.timestamps
        j = np.clip(np.searchsorted(stamps, t), 1, n - 1) if n > 1 else np.zeros(len(t), np.int64)
        if n > 1:
            j = np.where(np.abs(stamps[j - 1] - t) <= np.abs(stamps[j] - t), j - 1, j)
        return j.astype(np.int64)
    return np.clip(frames, 0, n - 1).astype(np.int64)


# --------------------------------------------------------------------------- scene
@dataclass
class SceneHandles:
    """Handles of what :func:`build_scene` added, for notebooks and tests.

    Attributes
    ----------
    nodes : layer name -> viser scene handle; layers of the later stages (``keyframes``,
        ``kf<ID>`` thumbnails, ``sparse``, ``dynamic``, ``dense``) appear once sent.
    slider, play : the playback GUI controls (None without GUI).
    legend : the legend's GUI handle (None without GUI); ``legend_rows`` its (name, colour) rows.
    dynamic : the dynamic points' window (:class:`DynamicWindow`), or None.
    build_seconds : time :func:`build_scene` took (the first stage only).
    frame_poses : ``(N, 4, 4)`` poses the playback steps through.
    on_frame : callback moving the playback to a frame index.
    deferred : the stages not sent yet, in order: ``(delay seconds, [send callables])``.
    visible : layer name -> whether its "Show" box is ticked (applied to late layers too).
    stage_seconds : time each sent stage took (``first``, then one entry per later stage).
    """

    nodes: dict = field(default_factory=dict)
    slider: object | None = None
    play: object | None = None
    legend: object | None = None
    legend_rows: list = field(default_factory=list)
    dynamic: "DynamicWindow | None" = None
    build_seconds: float = 0.0
    frame_poses: np.ndarray | None = None
    on_frame: Callable[[int], None] | None = None
    deferred: list[tuple[float, list[Callable[[], None]]]] = field(default_factory=list)
    visible: dict[str, bool] = field(default_factory=dict)
    stage_seconds: list[float] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _complete: threading.Event = field(default_factory=threading.Event, repr=False)
    _stop: threading.Event = field(default_factory=threading.Event, repr=False)
    _stream_started: bool = field(default=False, repr=False)

    def close(self) -> None:
        """Stop sending held-back stages (call before stopping the server)."""
        self._stop.set()

    def send_next_stage(self) -> bool:
        """Send the next held-back stage now; False when everything has been sent."""
        with self._lock:
            if not self.deferred:
                self._complete.set()
                return False
            _, sends = self.deferred.pop(0)
            t = time.perf_counter()
            for send in sends:
                try:
                    send()
                except Exception as exc:  # one broken layer (a corrupt map.ply) must not stop the viewer
                    self.errors.append(f"{getattr(send, '__name__', 'layer')}: {exc}")
            self.stage_seconds.append(time.perf_counter() - t)
            if not self.deferred:
                self._complete.set()
            return True

    def add_deferred(self) -> None:
        """Send every held-back stage now (keyframes, sparse and dense maps)."""
        while self.send_next_stage():
            pass

    def wait_complete(self, timeout: float | None = None) -> bool:
        """Block until every stage has been sent; False if ``timeout`` (s) ran out first."""
        return self._complete.wait(timeout)

    def stream(self) -> None:
        """Send the held-back stages one after another, each after its delay, until
        :meth:`close` (the target of :meth:`start_stream`'s thread)."""
        while True:
            with self._lock:
                if not self.deferred:
                    self._complete.set()
                    return
                delay = self.deferred[0][0]
            if self._stop.wait(delay):
                return
            self.send_next_stage()

    def start_stream(self) -> None:
        """Start sending the held-back stages in a background thread (once; later calls do nothing)."""
        with self._lock:
            if self._stream_started:
                return
            self._stream_started = True
        threading.Thread(target=self.stream, name="dynslam-view-stream", daemon=True).start()

    def layer(self, key: str, handle) -> None:
        """Record a node added for layer ``key`` and give it the layer's visibility."""
        self.nodes[key] = handle
        group = "keyframes" if key.startswith("kf") else key
        if not self.visible.get(group, True):
            handle.visible = False

    def set_visible(self, group: str, on: bool) -> None:
        """Show or hide a layer (``keyframes`` includes the thumbnail frustums)."""
        self.visible[group] = bool(on)
        for key, node in list(self.nodes.items()):
            if key == group or (group == "keyframes" and key.startswith("kf")):
                node.visible = bool(on)

    def set_frame(self, i: int) -> None:
        """Move the playback to frame ``i`` (what the slider does)."""
        if self.slider is not None:
            self.slider.value = int(i)
        elif self.on_frame is not None:
            self.on_frame(int(i))


class DynamicWindow:
    """The dynamic keypoints of the frames near the playback frame, or all of them on demand.

    Points are kept sorted by the trajectory index of their frame (:func:`dynamic_pose_index`),
    so a window is one slice. Without frame information every point is always shown.
    """

    def __init__(self, xyz: np.ndarray, pose_index: np.ndarray | None, window: int):
        if pose_index is None:
            self.xyz, self.pose = np.asarray(xyz, np.float32), None
        else:
            order = np.argsort(pose_index, kind="stable")
            self.xyz, self.pose = np.asarray(xyz, np.float32)[order], np.asarray(pose_index)[order]
        self.window = int(window)
        self.show_all = self.pose is None
        self.frame = 0
        self.node = None

    def points(self) -> np.ndarray:
        """``(n, 3)`` float32 points shown now."""
        if self.show_all:
            return self.xyz
        a = np.searchsorted(self.pose, self.frame - self.window, side="left")
        b = np.searchsorted(self.pose, self.frame + self.window, side="right")
        return self.xyz[a:b]

    def set_frame(self, i: int) -> None:
        self.frame = int(i)
        self.push()

    def set_show_all(self, on: bool) -> None:
        self.show_all = bool(on) or self.pose is None
        self.push()

    def push(self) -> None:
        """Send the current points to the node (once it exists)."""
        if self.node is not None:
            self.node.points = self.points()
            self.node.colors = np.array(COLORS["dynamic"], np.uint8)


def _thumb(path: Path) -> np.ndarray | None:
    import cv2  # heavy: only once thumbnails are drawn (keeps `dynslam view`'s start short)

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _some(a) -> bool:
    return a is not None and len(a) > 0


def _add_paths(scene, run: RunData, config: SceneConfig, h: SceneHandles) -> None:
    """Stage 1: the trajectories and loop edges (small, and what the first picture shows)."""
    for key, traj in (("ground_truth", run.ground_truth), ("estimate", run.trajectory)):
        if traj is not None and len(traj) >= 2:
            h.layer(key, scene.add_line_segments(
                f"/trajectory/{key}", polyline_segments(traj.positions, config.max_path_points).astype(np.float32),
                COLORS[key], thickness=config.trajectory_thickness, thickness_units="screen"))
    if run.kf_poses is not None and _some(run.loop_edges):
        pos_of = {int(i): p for i, p in zip(run.kf_ids, run.kf_poses[:, :3, 3])}
        edges = [(pos_of[int(a)], pos_of[int(b)]) for a, b in run.loop_edges if int(a) in pos_of and int(b) in pos_of]
        if edges:
            h.layer("loops", scene.add_line_segments("/loops", np.asarray(edges, np.float32), COLORS["loop"],
                                                     thickness=4.0, thickness_units="screen"))


def _keyframe_sender(scene, run: RunData, config: SceneConfig, h: SceneHandles) -> Callable[[], None]:
    """Stage 2: every keyframe's wireframe (one segment set) and some thumbnail frustums."""
    def send_keyframes() -> None:
        segs = frustum_segments(run.kf_poses, config.fov_y, config.aspect, config.frustum_scale)
        h.layer("keyframes", scene.add_line_segments("/keyframes/wireframes", segs.astype(np.float32),
                                                     COLORS["keyframe"], thickness=1.5, thickness_units="screen"))
        K = len(run.kf_poses)
        show = np.unique(np.linspace(0, K - 1, min(K, config.max_image_frustums)).round().astype(int))
        wxyz = wxyz_from_matrix(run.kf_poses[:, :3, :3])
        for k in show:
            path = run.thumbs.get(int(run.kf_ids[k]))
            img = _thumb(path) if path is not None else None
            if img is None:
                continue
            h.layer(f"kf{int(run.kf_ids[k])}", scene.add_camera_frustum(
                f"/keyframes/thumbs/{int(run.kf_ids[k])}", fov=config.fov_y, aspect=config.aspect,
                scale=config.frustum_scale, image=img, wxyz=wxyz[k], position=run.kf_poses[k, :3, 3],
                color=COLORS["keyframe"], thickness=1.5, thickness_units="screen"))
    return send_keyframes


def _points_sender(scene, run: RunData, config: SceneConfig, h: SceneHandles) -> Callable[[], None]:
    """Stage 2: the sparse map and the dynamic points of the current window."""
    def send_points() -> None:
        if _some(run.map_xyz):
            colors = run.map_rgb if run.map_rgb is not None else np.array(COLORS["static"], np.uint8)
            h.layer("sparse", scene.add_point_cloud("/map/sparse_static", run.map_xyz.astype(np.float32), colors,
                                                    point_size=config.point_size_sparse, point_shading="flat"))
        if h.dynamic is not None:
            node = scene.add_point_cloud("/map/sparse_dynamic", h.dynamic.points(), np.array(COLORS["dynamic"], np.uint8),
                                         point_size=config.point_size_sparse * 1.5, point_shading="flat")
            h.dynamic.node = node
            h.layer("dynamic", node)
    return send_points


def _dense_senders(scene, run: RunData, config: SceneConfig, h: SceneHandles, background: bool):
    """Stage 2 (a preview of at most ``preview_dense_points``) and, for a larger map, stage 3 (all
    of it, up to ``max_dense_points``). With ``background``, a ``map.ply`` still on disk is read
    in a thread started now."""
    loader, load_errors = None, []
    if background and run.dense_xyz is None:
        def read_dense() -> None:
            try:
                run.load_dense()
            except Exception as exc:  # reported by the sender, in the dense layer's place
                load_errors.append(exc)

        loader = threading.Thread(target=read_dense, name="dynslam-view-read-map.ply", daemon=True)
        loader.start()

    def dense_points(limit: int):
        if loader is not None:
            loader.join()
        if load_errors:
            raise load_errors[0]
        run.load_dense()  # no-op when already read
        xyz, rgb = run.dense_xyz, run.dense_rgb
        if len(xyz) > limit:
            idx = np.sort(np.random.default_rng(0).choice(len(xyz), limit, replace=False))
            xyz, rgb = xyz[idx], (None if rgb is None else rgb[idx])
        return xyz, rgb

    def send(limit: int) -> None:
        xyz, rgb = dense_points(limit)
        colors = rgb if rgb is not None else np.array([150, 150, 150], np.uint8)
        h.layer("dense", scene.add_point_cloud("/map/dense", xyz.astype(np.float32), colors,
                                               point_size=config.point_size_dense, point_shape="square",
                                               point_shading="flat"))

    n = run.dense_count if run.dense_xyz is None else len(run.dense_xyz)
    full = min(n, config.max_dense_points)

    def send_dense_preview() -> None:
        send(min(full, config.preview_dense_points))

    def send_dense() -> None:
        send(full)

    if full <= config.preview_dense_points:
        return send_dense, None
    return send_dense_preview, send_dense


def _add_playback(server, run: RunData, config: SceneConfig, h: SceneHandles) -> None:
    """The playback: a frustum at the frame's pose, the newest keyframe's thumbnail, the dynamic
    window; with GUI, the Frame slider and the Play box."""
    scene = server.scene
    if run.trajectory is not None and len(run.trajectory):
        poses, stamps = run.trajectory.poses, run.trajectory.timestamps
    elif _some(run.kf_poses):
        poses = run.kf_poses
        stamps = np.arange(len(poses), dtype=float)
    else:
        return
    h.frame_poses = poses
    current = scene.add_camera_frustum("/playback/current", fov=config.fov_y, aspect=config.aspect,
                                       scale=config.frustum_scale * 1.5, color=COLORS["current"],
                                       wxyz=wxyz_from_matrix(poses[0, :3, :3]), position=poses[0, :3, 3],
                                       thickness=3.0, thickness_units="screen")
    h.nodes["current"] = current
    kf_stamps = run.kf_timestamps if run.trajectory is not None else None
    thumb_node: dict[str, object] = {}

    def show_keyframe(i: int) -> None:
        if run.kf_poses is None or not run.thumbs:
            return
        if kf_stamps is not None and np.isfinite(kf_stamps).all():
            k = int(np.searchsorted(kf_stamps, stamps[i] + 1e-6)) - 1
        else:
            k = int(min(i, len(run.kf_poses) - 1))
        path = run.thumbs.get(int(run.kf_ids[k])) if k >= 0 else None
        img = _thumb(path) if path is not None else None
        if img is None:
            return
        node = thumb_node.get("h")
        if node is None:
            thumb_node["h"] = scene.add_camera_frustum(
                "/playback/keyframe", fov=config.fov_y, aspect=config.aspect, scale=config.frustum_scale * 1.5,
                image=img, wxyz=wxyz_from_matrix(run.kf_poses[k, :3, :3]), position=run.kf_poses[k, :3, 3],
                color=COLORS["keyframe"], thickness=3.0, thickness_units="screen")
        else:
            node.image = img
            node.wxyz = wxyz_from_matrix(run.kf_poses[k, :3, :3])
            node.position = run.kf_poses[k, :3, 3]

    def on_frame(i: int) -> None:
        i = int(np.clip(i, 0, len(poses) - 1))
        current.wxyz = wxyz_from_matrix(poses[i, :3, :3])
        current.position = poses[i, :3, 3]
        if h.dynamic is not None:
            h.dynamic.set_frame(i)
        show_keyframe(i)

    h.on_frame = on_frame
    if config.gui:
        h.slider = server.gui.add_slider("Frame", min=0, max=max(len(poses) - 1, 1), step=1, initial_value=0)
        h.play = server.gui.add_checkbox("Play", initial_value=False)
        h.slider.on_update(lambda _event: on_frame(h.slider.value))


_LAYER_LABELS = {
    "estimate": "estimated trajectory",
    "ground_truth": "ground truth (aligned)",
    "keyframes": "keyframes",
    "current": "playback frame",
    "loops": "loop edges",
    "sparse": "sparse map (own colours)",
    "dynamic": "keypoints judged dynamic",
    "dense": "dense map (own colours)",
}
_LAYER_COLOUR = {"keyframes": "keyframe", "current": "current", "loops": "loop", "sparse": "static",
                 "dense": None, "estimate": "estimate", "ground_truth": "ground_truth", "dynamic": "dynamic"}


def _add_controls(server, h: SceneHandles, present: list[str], config: SceneConfig) -> None:
    """Layer toggles, the all-dynamic-points box, and the legend (colours of this scheme)."""
    gui = server.gui
    for key in ("dense", "sparse", "dynamic", "ground_truth", "estimate", "keyframes", "loops"):
        if key in present:
            cb = gui.add_checkbox(f"Show {key.replace('_', ' ')}", initial_value=True)
            cb.on_update(lambda _event, key=key, cb=cb: h.set_visible(key, cb.value))
    if h.dynamic is not None and h.dynamic.pose is not None:
        every = gui.add_checkbox("Dynamic: all frames", initial_value=False)
        every.on_update(lambda _event: h.dynamic.set_show_all(every.value))
    rows = []
    for key in ("estimate", "ground_truth", "current", "keyframes", "loops", "sparse", "dynamic", "dense"):
        if key not in present:
            continue
        label = _LAYER_LABELS[key]
        if key == "dynamic" and h.dynamic is not None and h.dynamic.pose is not None:
            label += f" (frames within {config.dynamic_window} of the playback frame)"
        colour = _LAYER_COLOUR[key]
        rows.append((label, hex_color(colour) if colour else "#969696"))
    h.legend_rows = rows
    cells = "".join(
        f'<div style="display:flex;align-items:center;gap:6px;font-size:12px;margin:2px 0">'
        f'<span style="display:inline-block;width:14px;height:14px;background:{c};border:1px solid #555"></span>'
        f"{html.escape(label)}</div>" for label, c in rows)
    with gui.add_folder("Legend", order=0.0):  # first in the panel, above the playback controls
        h.legend = gui.add_html(f"<div>{cells}</div>")


def build_scene(server, run: RunData, config: SceneConfig | None = None) -> SceneHandles:
    """Add a run's layers (and the playback GUI and legend) to a viser server.

    The trajectories, loop edges, playback frustum, GUI and legend are sent at once. With the GUI
    on and a delay configured, the keyframes, sparse map, dynamic window and a demo-size dense
    map follow ``config.defer_layers`` seconds after the first browser connects; a larger dense
    map comes as a preview ``config.defer_dense`` seconds after them and whole as much later (a
    ``map.ply`` left on disk by
    ``load_run(..., dense=False)`` is read in a background thread meanwhile); otherwise
    (notebook embeds) everything is sent before this returns. :meth:`SceneHandles.add_deferred`
    sends what is left at any time.

    Parameters
    ----------
    server : ``viser.ViserServer``.
    run : from :func:`load_run`.
    config : :class:`SceneConfig`.

    Returns
    -------
    SceneHandles (node handles by name, the slider, build time in seconds).
    """
    config = config or SceneConfig()
    t0 = time.perf_counter()
    h = SceneHandles()
    scene = server.scene
    if run.trajectory is None and run.kf_poses is None and run.map_xyz is None:
        run.load_dense()  # the dense map is all there is: it sets the view
    scene.set_up_direction(tuple(_up_direction(run)))
    eye, target, up = initial_view(run)
    server.initial_camera.fov = VIEWER_FOV_Y
    server.initial_camera.position = tuple(eye)
    server.initial_camera.look_at = tuple(target)
    server.initial_camera.up = tuple(up)
    streaming = config.gui and (config.defer_layers > 0 or config.defer_dense > 0)
    if _some(run.dynamic_xyz):
        h.dynamic = DynamicWindow(run.dynamic_xyz, dynamic_pose_index(run), config.dynamic_window)

    _add_paths(scene, run, config, h)
    stage2, stage3 = [], []  # (stage4: below)
    if _some(run.kf_poses):
        stage2.append(_keyframe_sender(scene, run, config, h))
    if _some(run.map_xyz) or h.dynamic is not None:
        stage2.append(_points_sender(scene, run, config, h))
    stage4 = []
    has_dense = (_some(run.dense_xyz) or run.dense_count > 0) and config.max_dense_points > 0
    if has_dense:
        preview, full = _dense_senders(scene, run, config, h, background=streaming)
        if full is None:  # a demo-size map: with the keyframes
            stage2.append(preview)
        else:  # a large one: a preview after the keyframes, then all of it
            stage3.append(preview)
            stage4.append(full)
    for delay, sends in ((config.defer_layers, stage2), (config.defer_dense, stage3), (config.defer_dense, stage4)):
        if sends:
            h.deferred.append((delay, sends))
    _add_playback(server, run, config, h)
    if config.gui:
        later = {"keyframes": _some(run.kf_poses), "sparse": _some(run.map_xyz), "dynamic": h.dynamic is not None,
                 "dense": has_dense}
        _add_controls(server, h, list(h.nodes) + [k for k, there in later.items() if there], config)

    h.build_seconds = time.perf_counter() - t0
    h.stage_seconds.append(h.build_seconds)
    if not h.deferred:
        h._complete.set()  # nothing held back: complete without waiting for a browser
    if not streaming:
        h.add_deferred()
    else:
        # The first browser starts the stream (viser calls this once the page has reported its
        # camera, i.e. the 3D canvas is up); later browsers get the layers sent so far at once.
        server.on_client_connect(lambda _client: h.start_stream())
    return h


# ---------------------------------------------------------------------------- servers
def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` right now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def open_server(host: str = "127.0.0.1", port: int | None = None, verbose: bool = False, extra_hosts=(), log=None):
    """A started ``viser.ViserServer`` that answers only its own page (:mod:`dynslam_lab.viz.access`).

    Parameters
    ----------
    host, port : where to listen (port None: a free one).
    extra_hosts : more ``Host`` names to accept (when listening on a network address on purpose).
    log : called with a line for every refused request.
    """
    import viser  # optional heavy dependency (only the viewer needs it)

    server = viser.ViserServer(host=host, port=port if port is not None else free_port(host), verbose=verbose)
    guard_viser_server(server, extra_hosts=extra_hosts, log=log)
    return server


def start_viewer(run: RunData | str | Path, port: int | None = None, host: str = "127.0.0.1",
                 config: SceneConfig | None = None, verbose: bool = False, extra_hosts=(), log=None):
    """Start a guarded viser server on ``host:port`` and build the run's scene in it.

    Returns ``(server, handles)``; stop with ``handles.close()`` and ``server.stop()``.
    """
    if not isinstance(run, RunData):
        run = load_run(run, dense=False)  # a large map.ply is read while the first layers are on screen
    server = open_server(host, port, verbose, extra_hosts, log)
    handles = build_scene(server, run, config)
    return server, handles


def play_loop(handles: SceneHandles, stop: threading.Event, fps: float = 15.0) -> None:
    """Advance the playback slider while its 'Play' box is ticked, until ``stop`` is set."""
    while not stop.wait(1.0 / fps):
        if handles.play is not None and handles.play.value and handles.slider is not None:
            n = handles.slider.max + 1
            handles.slider.value = (int(handles.slider.value) + 1) % n


def show_inline(run: RunData | str | Path, height: int = 500, config: SceneConfig | None = None):
    """Build the run's scene and embed it in a notebook cell (a static snapshot, no GUI).

    Uses viser's ``server.scene.show()``, which serialises the scene into the notebook's
    HTML; ipywidgets (not viser's GUI) own the parameters in notebooks. Without GUI there is no
    playback, so every dynamic point is shown. Returns the server (stopped: the embedded page
    needs no live connection).
    """
    config = dataclasses.replace(config or SceneConfig(), gui=False)
    server, handles = start_viewer(run, config=config)
    if handles.dynamic is not None:
        handles.dynamic.set_show_all(True)
    server.scene.show(height=height)
    server.stop()
    return server
