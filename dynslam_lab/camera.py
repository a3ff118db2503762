"""Pinhole camera model with radial-tangential distortion, and the intrinsics presets
of the TUM RGB-D and Bonn RGB-D Dynamic datasets.

Projection of a point ``X_c = (x, y, z)`` in the camera frame (metres) to pixels::

    u = fx * x / z + cx,    v = fy * y / z + cy

Back-projection of pixel ``(u, v)`` with depth ``z`` (metres)::

    X_c = z * ((u - cx) / fx, (v - cy) / fy, 1)

Distortion (OpenCV order ``k1, k2, p1, p2, k3``) applies to raw pixels only: the TUM
depth and colour images of the ROS-recorded sequences are already registered, and the
published values are used by :meth:`PinholeCamera.undistort_points` for feature pixels.

References
----------
Sturm et al., "A Benchmark for the Evaluation of RGB-D SLAM Systems", IROS 2012
(intrinsics at https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats).
Palazzolo et al., "ReFusion", IROS 2019 (Bonn RGB-D Dynamic dataset intrinsics).
"""

from __future__ import annotations

import json
import logging
import re
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

__all__ = ["PinholeCamera", "CAMERA_PRESETS", "camera_for_sequence", "preset_from_name", "image_size_error"]


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of one RGB-D camera.

    Attributes
    ----------
    fx, fy : focal lengths in pixels.
    cx, cy : principal point in pixels.
    width, height : image size in pixels.
    dist : distortion ``(k1, k2, p1, p2, k3)``, OpenCV order; zeros = none.
    depth_scale : depth image units per metre (5000 for TUM and Bonn 16-bit PNGs).
    name : preset name, for messages.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int = 640
    height: int = 480
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    depth_scale: float = 5000.0
    name: str = "custom"

    def __post_init__(self) -> None:
        for attr in ("fx", "fy"):
            if not np.isfinite(getattr(self, attr)) or getattr(self, attr) <= 0:
                raise ValueError(f"PinholeCamera.{attr} must be a positive number, got {getattr(self, attr)!r}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"PinholeCamera image size must be positive, got {self.width}x{self.height}")
        if len(self.dist) != 5:
            raise ValueError(f"PinholeCamera.dist needs 5 values (k1, k2, p1, p2, k3), got {len(self.dist)}")
        if self.depth_scale <= 0:
            raise ValueError(f"PinholeCamera.depth_scale must be positive (units per metre), got {self.depth_scale}")

    # ------------------------------------------------------------------ matrices
    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """Distortion vector ``(5,)`` for OpenCV calls."""
        return np.asarray(self.dist, dtype=np.float64)

    @property
    def has_distortion(self) -> bool:
        return any(abs(d) > 0 for d in self.dist)

    def with_(self, **changes) -> "PinholeCamera":
        """A copy with some fields changed (``dataclasses.replace``)."""
        return replace(self, **changes)

    def scaled(self, factor: float) -> "PinholeCamera":
        """The camera of an image resized by ``factor`` (e.g. 0.5 for half resolution)."""
        return replace(
            self,
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
            width=int(round(self.width * factor)),
            height=int(round(self.height * factor)),
        )

    # ------------------------------------------------------------ projections
    def project(self, points_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project camera-frame points ``(N, 3)`` (metres) to pixels.

        Returns ``(uv, z)``: pixels ``(N, 2)`` and depths ``(N,)``. Points with ``z <= 0``
        get ``nan`` pixels. No distortion is applied (features are undistorted first).
        """
        P = np.asarray(points_c, dtype=np.float64)
        if P.ndim != 2 or P.shape[1] != 3:
            raise ValueError(f"project expects points of shape (N, 3), got {P.shape}")
        z = P[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_z = np.where(z > 0, 1.0 / z, np.nan)
        uv = np.empty((len(P), 2))
        uv[:, 0] = self.fx * P[:, 0] * inv_z + self.cx
        uv[:, 1] = self.fy * P[:, 1] * inv_z + self.cy
        return uv, z

    def backproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Back-project pixels ``(N, 2)`` with depths ``(N,)`` (metres) to camera points ``(N, 3)``."""
        uv = np.asarray(uv, dtype=np.float64)
        d = np.asarray(depth, dtype=np.float64)
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise ValueError(f"backproject expects pixels of shape (N, 2), got {uv.shape}")
        if d.shape != (len(uv),):
            raise ValueError(f"backproject expects depth of shape ({len(uv)},), got {d.shape}")
        out = np.empty((len(uv), 3))
        out[:, 0] = (uv[:, 0] - self.cx) / self.fx * d
        out[:, 1] = (uv[:, 1] - self.cy) / self.fy * d
        out[:, 2] = d
        return out

    def backproject_depth(self, depth: np.ndarray, stride: int = 1) -> np.ndarray:
        """Back-project a whole depth image ``(H, W)`` (metres) to an ``(H', W', 3)`` point grid.

        Pixels without depth (0 or nan) give ``nan`` points. ``stride`` subsamples rows/columns.
        """
        depth = np.asarray(depth)
        if depth.ndim != 2:
            raise ValueError(f"backproject_depth expects an (H, W) depth image, got shape {depth.shape}")
        d = depth[::stride, ::stride].astype(np.float64)
        d = np.where(d > 0, d, np.nan)
        u = np.arange(0, depth.shape[1], stride)[None, :]
        v = np.arange(0, depth.shape[0], stride)[:, None]
        x = (u - self.cx) / self.fx * d
        y = (v - self.cy) / self.fy * d
        return np.stack([x, y, d], axis=-1)

    def undistort_points(self, uv: np.ndarray) -> np.ndarray:
        """Remove lens distortion from pixel coordinates ``(N, 2)``; identity when ``dist`` is zero."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if not self.has_distortion or len(uv) == 0:
            return uv.copy()
        und = cv2.undistortPoints(uv.reshape(-1, 1, 2), self.K, self.dist_coeffs, P=self.K)
        return und.reshape(-1, 2)

    def in_image(self, uv: np.ndarray, border: float = 0.0) -> np.ndarray:
        """Boolean ``(N,)``: pixel inside the image, at least ``border`` pixels from its edge."""
        uv = np.asarray(uv)
        return (
            np.isfinite(uv).all(axis=1)
            & (uv[:, 0] >= border)
            & (uv[:, 1] >= border)
            & (uv[:, 0] <= self.width - 1 - border)
            & (uv[:, 1] <= self.height - 1 - border)
        )


# Published intrinsics. TUM: https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats
# ("Intrinsic Camera Calibration of the Kinect"); fr3 images are already undistorted.
CAMERA_PRESETS: dict[str, PinholeCamera] = {
    "tum_fr1": PinholeCamera(517.3, 516.5, 318.6, 255.3, dist=(0.2624, -0.9531, -0.0054, 0.0026, 1.1633), name="tum_fr1"),
    "tum_fr2": PinholeCamera(520.9, 521.0, 325.1, 249.7, dist=(0.2312, -0.7849, -0.0033, -0.0001, 0.9172), name="tum_fr2"),
    "tum_fr3": PinholeCamera(535.4, 539.2, 320.1, 247.6, name="tum_fr3"),
    "bonn": PinholeCamera(542.822841, 542.576870, 315.593520, 237.756098, name="bonn"),
    # The ROS default of the TUM tools, used where no preset fits (and by the synthetic renderer).
    "default": PinholeCamera(525.0, 525.0, 319.5, 239.5, name="default"),
}


_DEFAULT_SAID: set[str] = set()  # folders already warned about (camera_for_sequence's default)


def preset_from_name(name: str) -> str | None:
    """The preset a sequence folder's name picks: ``...bonn...`` -> ``bonn``, ``...freiburg3...`` or ``...fr3...`` ->
    ``tum_fr3`` (1-3); None when it names none."""
    name = name.lower()
    if "bonn" in name:
        return "bonn"
    m = re.search(r"(?:freiburg|fr)([123])", name)
    return f"tum_fr{m.group(1)}" if m else None


def image_size_error(shape: tuple[int, ...], camera: PinholeCamera, where: str) -> str | None:
    """The message for an image of ``shape`` (``(h, w, ...)``) that is not the ``camera``'s size (its intrinsics would
    be wrong), naming ``where`` it came from; None when the sizes agree."""
    h, w = shape[:2]
    if (h, w) == (camera.height, camera.width):
        return None
    return (f"{where}: image is {w}x{h} but the camera '{camera.name}' is {camera.width}x{camera.height} "
            "(its intrinsics would be wrong): fix camera.json or pass another --camera")


def camera_for_sequence(path: str | Path, override: str | PinholeCamera | None = None) -> PinholeCamera:
    """Pick the intrinsics of a sequence from its folder name.

    ``rgbd_dataset_freiburg3_walking_xyz`` -> ``tum_fr3``; ``fr1_...`` -> ``tum_fr1``;
    ``rgbd_bonn_...`` -> ``bonn``; a folder holding a ``camera.json`` (written by the
    synthetic renderer) uses that file. ``override`` (a preset name or a camera) wins. Otherwise
    the ``default`` preset, with a warning (once per folder): its intrinsics are a guess.
    """
    if isinstance(override, PinholeCamera):
        return override
    if isinstance(override, str):
        if override not in CAMERA_PRESETS:
            raise ValueError(f"unknown camera preset {override!r}; choose one of {sorted(CAMERA_PRESETS)}")
        return CAMERA_PRESETS[override]
    path = Path(path)
    cam_json = path / "camera.json"
    if cam_json.is_file():
        return load_camera_json(cam_json)
    preset = preset_from_name(path.name)
    if preset is not None:
        return CAMERA_PRESETS[preset]
    cam = CAMERA_PRESETS["default"]
    if str(path) not in _DEFAULT_SAID:  # once per folder: the intrinsics are a guess
        _DEFAULT_SAID.add(str(path))
        logging.getLogger(__name__).warning(
            "%s: no camera.json and no preset in the folder's name (freiburg1-3, fr1-3, bonn): using the 'default' "
            "camera (fx %g, fy %g, cx %g, cy %g, %dx%d, depth_scale %g); write camera.json or pass --camera if these "
            "are not its intrinsics", path, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, cam.depth_scale)
    return cam


def load_camera_json(path: str | Path) -> PinholeCamera:
    """Read a camera from a JSON file with the fields of :class:`PinholeCamera`."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read camera JSON ({exc})") from exc
    known = {f for f in PinholeCamera.__dataclass_fields__}
    unknown = set(data) - known
    if unknown:
        raise ValueError(f"{path}: unknown camera fields {sorted(unknown)}")
    if "dist" in data:
        data["dist"] = tuple(float(x) for x in data["dist"])
    try:
        return PinholeCamera(**data)
    except TypeError as exc:
        raise ValueError(f"{path}: {exc}") from exc


def save_camera_json(camera: PinholeCamera, path: str | Path) -> None:
    """Write a camera as JSON (read back by :func:`load_camera_json`)."""
    d = asdict(camera)
    d["dist"] = list(camera.dist)
    Path(path).write_text(json.dumps(d, indent=2) + "\n")
