"""The 3D scene of a run in viser: trajectories, keyframes, sparse and dense maps, loops.

What ``dynslam view OUTDIR`` shows and what a notebook embeds with :func:`show_inline`:

* the estimated trajectory (red) and the ground truth (blue, aligned to the estimate with
  Umeyama/Horn, so both share the estimate's world frame);
* every keyframe as a wireframe frustum (orange), all of them in *one* line-segment set,
  and image frustums with the keyframe thumbnails for up to ``max_image_frustums`` evenly
  spaced keyframes;
* the sparse map points (their colour, or green) and the keypoints judged dynamic (magenta);
* the dense static map ``map.ply``;
* loop edges between keyframe centres (green);
* a playback slider stepping through the tracked frames: a white frustum at the frame's
  pose, and the thumbnail of the newest keyframe at or before it.

Everything goes to the browser in a few large messages (one point cloud per layer, one
line-segment set per polyline family, the path thinned to ``max_path_points``), and in stages,
so that the first picture does not wait for the large layers (``benchmarks/view_startup.py``):

1. at once: the trajectories, loop edges, the playback frustum and the GUI;
2. ``defer_layers`` seconds after the first browser connects: the keyframes (wireframes and
   thumbnails) and the sparse map;
3. ``defer_dense`` seconds later: the dense map, which :func:`load_run` can leave on disk
   (``dense=False``) to be read in the background while the server already answers.

Conventions: poses ``T_w_c`` map camera to world (OpenCV camera axes: x right, y down,
z forward, which is also viser's frustum convention). Quaternions are ``x y z w`` in TUM
files and ``w x y z`` in viser: :func:`wxyz_from_matrix` is the only conversion. The server
binds to ``127.0.0.1`` unless a host is given on purpose (viser's default, ``0.0.0.0``,
would expose the scene to the network).
"""

from __future__ import annotations

import dataclasses
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
    "build_scene",
    "start_viewer",
    "play_loop",
    "show_inline",
    "free_port",
    "COLORS",
]

#: RGB colours of the layers (uint8).
COLORS = {
    "estimate": (230, 40, 30),
    "ground_truth": (30, 90, 230),
    "keyframe": (255, 150, 0),
    "current": (20, 20, 20),
    "static": (60, 180, 75),
    "dynamic": (220, 0, 220),
    "loop": (0, 200, 0),
}


@dataclass(frozen=True)
class SceneConfig:
    """What the viewer draws and how big (units: metres unless noted)."""

    frustum_scale: float = 0.08  # metres from apex to image plane of keyframe frustums (ours)
    trajectory_thickness: float = 3.0  # screen pixels of trajectory lines (ours)
    point_size_sparse: float = 0.02  # metres (ours)
    point_size_dense: float = 0.012  # metres (ours; ~ the dense map's 2 cm voxels)
    max_dense_points: int = 1_000_000  # dense points sent at most, random subset with seed=0 (ours)
    max_image_frustums: int = 40  # keyframes shown with their thumbnail at start-up (ours)
    defer_layers: float = 2.0  # seconds after the first browser connects before keyframes and sparse map are sent (ours)
    defer_dense: float = 2.0  # seconds after those before the dense map is sent (ours; both 0 = all at once)
    max_path_points: int = 3000  # trajectory vertices drawn at most, evenly spaced (playback keeps all; ours)
    fov_y: float = float(2 * np.arctan(240 / 525))  # radians, vertical field of view, 49 deg (Kinect, f = 525 px)
    aspect: float = 4 / 3  # width / height of frustums (640 x 480)
    gui: bool = True  # add the playback slider and layer toggles (False for a static notebook embed)

    def __post_init__(self) -> None:
        for name in ("frustum_scale", "trajectory_thickness", "point_size_sparse", "point_size_dense", "fov_y", "aspect"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SceneConfig.{name} must be > 0, got {getattr(self, name)}")
        for name in ("max_dense_points", "max_image_frustums", "defer_layers", "defer_dense"):
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
    dynamic_xyz : ``(D, 3)`` keypoints judged dynamic (``dynamic_points.npz``).
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
    """Centre ``(3,)`` and radius (metres) of the camera path (or the map when there is none)."""
    parts = [x for x in (run.trajectory.positions if run.trajectory is not None else None,
                         run.kf_poses[:, :3, 3] if run.kf_poses is not None else None) if x is not None and len(x)]
    if not parts:
        parts = [x for x in (run.map_xyz, run.dense_xyz) if x is not None and len(x)]
    if not parts:
        return np.zeros(3), 1.0
    P = np.concatenate(parts)
    lo, hi = np.percentile(P, 2, axis=0), np.percentile(P, 98, axis=0)
    return (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 0.75)  # at least a desk-sized view


def _up_direction(run: RunData) -> np.ndarray:
    """World 'up' guessed as the mean of the cameras' -y axes (cameras are held upright)."""
    poses = run.trajectory.poses if run.trajectory is not None else run.kf_poses
    if poses is None or len(poses) == 0:
        return np.array([0.0, 0.0, 1.0])
    up = -poses[:, :3, 1].mean(axis=0)
    n = np.linalg.norm(up)
    return up / n if n > 1e-6 else np.array([0.0, 0.0, 1.0])


def initial_view(run: RunData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the viewer's camera starts: ``(eye (3,), look_at (3,), up (3,))`` in metres.

    Behind and above the cameras, looking past the path's centre in the direction the cameras
    look on average (where the map is); for paths whose cameras look all around (a loop), from
    above and to the side, at the path's centre.
    """
    centre, radius = scene_bounds(run)
    up = _up_direction(run)
    poses = run.trajectory.poses if run.trajectory is not None else run.kf_poses
    fwd = np.zeros(3) if poses is None or len(poses) == 0 else poses[:, :3, 2].mean(axis=0)
    fwd = fwd - (fwd @ up) * up  # horizontal part of the mean viewing direction
    if np.linalg.norm(fwd) > 0.3:
        fwd /= np.linalg.norm(fwd)
        return centre - radius * (2.0 * fwd - 1.2 * up), centre + radius * fwd, up
    side = np.cross(up, [1.0, 0.0, 0.0])
    if np.linalg.norm(side) < 1e-3:
        side = np.cross(up, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    return centre + radius * (1.6 * up + 1.6 * side), centre, up


# --------------------------------------------------------------------------- scene
@dataclass
class SceneHandles:
    """Handles of what :func:`build_scene` added, for notebooks and tests.

    Attributes
    ----------
    nodes : layer name -> viser scene handle; layers of the later stages (``keyframes``,
        ``kf<ID>`` thumbnails, ``sparse``, ``dynamic``, ``dense``) appear once sent.
    slider, play : the playback GUI controls (None without GUI).
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


def _thumb(path: Path) -> np.ndarray | None:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    return None if img is None else cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def build_scene(server, run: RunData, config: SceneConfig | None = None) -> SceneHandles:
    """Add a run's layers (and the playback GUI) to a viser server.

    The trajectories, loop edges, playback frustum and GUI are sent at once. With the GUI on
    and a delay configured, the keyframes and sparse map follow ``config.defer_layers``
    seconds after the first browser connects and the dense map ``config.defer_dense`` seconds
    after them (a large ``map.ply`` left on disk by ``load_run(..., dense=False)`` is read in
    a background thread meanwhile); otherwise (notebook embeds) everything is sent before this
    returns. :meth:`SceneHandles.add_deferred` sends what is left at any time.

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
    server.initial_camera.position = tuple(eye)
    server.initial_camera.look_at = tuple(target)
    server.initial_camera.up = tuple(up)
    streaming = config.gui and (config.defer_layers > 0 or config.defer_dense > 0)

    def some(a) -> bool:
        return a is not None and len(a) > 0

    later = {  # the layers of the later stages that this run has
        "keyframes": some(run.kf_poses),
        "sparse": some(run.map_xyz),
        "dynamic": some(run.dynamic_xyz),
        "dense": (some(run.dense_xyz) or run.dense_count > 0) and config.max_dense_points > 0,
    }

    # ---- stage 1: the trajectories and loop edges (small, and what the first picture shows)
    for key, traj in (("ground_truth", run.ground_truth), ("estimate", run.trajectory)):
        if traj is not None and len(traj) >= 2:
            h.layer(key, scene.add_line_segments(
                f"/trajectory/{key}", polyline_segments(traj.positions, config.max_path_points).astype(np.float32),
                COLORS[key], thickness=config.trajectory_thickness, thickness_units="screen"))
    if run.kf_poses is not None and run.loop_edges is not None and len(run.loop_edges):
        pos_of = {int(i): p for i, p in zip(run.kf_ids, run.kf_poses[:, :3, 3])}
        edges = [(pos_of[int(a)], pos_of[int(b)]) for a, b in run.loop_edges if int(a) in pos_of and int(b) in pos_of]
        if edges:
            h.layer("loops", scene.add_line_segments("/loops", np.asarray(edges, np.float32), COLORS["loop"],
                                                     thickness=4.0, thickness_units="screen"))

    # ---- stage 2: keyframes and the sparse map
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

    def send_sparse() -> None:
        if later["sparse"]:
            colors = run.map_rgb if run.map_rgb is not None else np.array(COLORS["static"], np.uint8)
            h.layer("sparse", scene.add_point_cloud("/map/sparse_static", run.map_xyz.astype(np.float32), colors,
                                                    point_size=config.point_size_sparse, point_shading="flat"))
        if later["dynamic"]:
            h.layer("dynamic", scene.add_point_cloud("/map/sparse_dynamic", run.dynamic_xyz.astype(np.float32),
                                                     np.array(COLORS["dynamic"], np.uint8),
                                                     point_size=config.point_size_sparse, point_shading="flat"))

    stage2 = []
    if later["keyframes"]:
        stage2.append(send_keyframes)
    if later["sparse"] or later["dynamic"]:
        stage2.append(send_sparse)

    # ---- stage 3: the dense map (read in the background if it is still on disk)
    loader, load_errors = None, []
    if later["dense"] and streaming and run.dense_xyz is None:
        def read_dense() -> None:
            try:
                run.load_dense()
            except Exception as exc:  # reported by send_dense, in the dense layer's place
                load_errors.append(exc)

        loader = threading.Thread(target=read_dense, name="dynslam-view-read-map.ply", daemon=True)
        loader.start()

    def send_dense() -> None:
        if loader is not None:
            loader.join()
        if load_errors:
            raise load_errors[0]
        run.load_dense()  # no-op when already read
        xyz, rgb = run.dense_xyz, run.dense_rgb
        if len(xyz) > config.max_dense_points:
            idx = np.sort(np.random.default_rng(0).choice(len(xyz), config.max_dense_points, replace=False))
            xyz, rgb = xyz[idx], (None if rgb is None else rgb[idx])
        colors = rgb if rgb is not None else np.array([150, 150, 150], np.uint8)
        h.layer("dense", scene.add_point_cloud("/map/dense", xyz.astype(np.float32), colors,
                                               point_size=config.point_size_dense, point_shape="square",
                                               point_shading="flat"))

    if stage2:
        h.deferred.append((config.defer_layers, stage2))
    if later["dense"]:
        h.deferred.append((config.defer_dense, [send_dense]))

    # ---- playback: the frames of the trajectory (or the keyframes when there is none)
    if run.trajectory is not None and len(run.trajectory):
        poses, stamps = run.trajectory.poses, run.trajectory.timestamps
    elif later["keyframes"]:
        poses = run.kf_poses
        stamps = np.arange(len(poses), dtype=float)
    else:
        poses, stamps = None, None
    h.frame_poses = poses
    if poses is not None:
        current = scene.add_camera_frustum("/playback/current", fov=config.fov_y, aspect=config.aspect,
                                           scale=config.frustum_scale * 1.5, color=COLORS["current"],
                                           wxyz=wxyz_from_matrix(poses[0, :3, :3]), position=poses[0, :3, 3],
                                           thickness=3.0, thickness_units="screen")
        h.nodes["current"] = current
        kf_stamps = run.kf_timestamps if run.trajectory is not None else None
        thumb_node: dict[str, object] = {}

        def on_frame(i: int) -> None:
            i = int(np.clip(i, 0, len(poses) - 1))
            current.wxyz = wxyz_from_matrix(poses[i, :3, :3])
            current.position = poses[i, :3, 3]
            if run.kf_poses is None or not run.thumbs:
                return
            if kf_stamps is not None and np.isfinite(kf_stamps).all():
                k = int(np.searchsorted(kf_stamps, stamps[i] + 1e-6)) - 1
            else:
                k = int(min(i, len(run.kf_poses) - 1))
            if k < 0:
                return
            path = run.thumbs.get(int(run.kf_ids[k]))
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

        h.on_frame = on_frame
        if config.gui:
            gui = server.gui
            h.slider = gui.add_slider("Frame", min=0, max=max(len(poses) - 1, 1), step=1, initial_value=0)
            h.play = gui.add_checkbox("Play", initial_value=False)

            @h.slider.on_update
            def _(_event) -> None:
                on_frame(h.slider.value)

    if config.gui:
        present = set(h.nodes) | {key for key, there in later.items() if there}
        for key in ("dense", "sparse", "dynamic", "ground_truth", "estimate", "keyframes", "loops"):
            if key in present:
                cb = server.gui.add_checkbox(f"Show {key.replace('_', ' ')}", initial_value=True)
                cb.on_update(lambda _event, key=key, cb=cb: h.set_visible(key, cb.value))

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


def start_viewer(run: RunData | str | Path, port: int | None = None, host: str = "127.0.0.1",
                 config: SceneConfig | None = None, verbose: bool = False):
    """Start a viser server on ``host:port`` and build the run's scene in it.

    Returns ``(server, handles)``; stop with ``handles.close()`` and ``server.stop()``.
    """
    import viser

    if not isinstance(run, RunData):
        run = load_run(run, dense=False)  # a large map.ply is read while the first layers are on screen
    server = viser.ViserServer(host=host, port=port if port is not None else free_port(host), verbose=verbose)
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
    HTML; ipywidgets (not viser's GUI) own the parameters in notebooks. Returns the server
    (stopped: the embedded page needs no live connection).
    """
    config = dataclasses.replace(config or SceneConfig(), gui=False)
    server, handles = start_viewer(run, config=config)
    server.scene.show(height=height)
    server.stop()
    return server
