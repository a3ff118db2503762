"""The synthetic office scene and its ray caster: one import for the parts of the renderer.

The renderer's geometry is split into modules a reader can take one at a time:

* :mod:`~dynslam_lab.datasets.shapes`: the analytic primitives (:class:`Shape`: box, room,
  capsule, cylinder, ellipsoid in a local frame) and the pose helpers (``rot_x``, ``pose``,
  ``look_at``...);
* :mod:`~dynslam_lab.datasets.raycaster`: one ray per pixel through the pinhole camera, closed-form
  intersections, the nearest hit per pixel as a :class:`GBuffer` (depth, part, face, normal,
  texture coordinates);
* :mod:`~dynslam_lab.datasets.people`: articulated people (walking and sitting gaits) and the
  other movers;
* :mod:`~dynslam_lab.datasets.office`: the office itself (room, furniture, textures, where the
  people walk or sit, the lights), built by :func:`build_office`.

Camera paths are in :mod:`~dynslam_lab.datasets.camera_paths`, the Kinect depth model in
:mod:`~dynslam_lab.datasets.kinect`, shading and sequence writing in
:mod:`~dynslam_lab.datasets.synthetic`. Every name below stays importable from here
(``from dynslam_lab.datasets.scene import raycast, build_office``).
"""

from __future__ import annotations

from .office import (
    AMBIENT,
    FILL_LIGHTS,
    LAMP,
    PERSON,
    ROOM_MAX,
    ROOM_MIN,
    VIEW_EYE,
    VIEW_TARGET,
    OfficeScene,
    TextureBank,
    build_office,
)
from .people import (
    PersonLook,
    Sitter,
    SlidingObject,
    Walker,
    heading_rotation,
    path_pose,
    person_parts,
    sitting_joints,
    walking_joints,
)
from .raycaster import NEAR, GBuffer, camera_rays, raycast
from .shapes import KINDS, Shape, look_at, pose, rot_x, rot_y, rot_z, shape_corners

__all__ = [
    "Shape",
    "GBuffer",
    "raycast",
    "camera_rays",
    "OfficeScene",
    "build_office",
    "Walker",
    "Sitter",
    "SlidingObject",
    "person_parts",
    "walking_joints",
    "sitting_joints",
    "path_pose",
    "rot_x",
    "rot_y",
    "rot_z",
    "pose",
    "look_at",
    "shape_corners",
    # also importable (module constants and helpers of the office)
    "KINDS",
    "NEAR",
    "ROOM_MIN",
    "ROOM_MAX",
    "VIEW_EYE",
    "VIEW_TARGET",
    "LAMP",
    "FILL_LIGHTS",
    "AMBIENT",
    "PERSON",
    "TextureBank",
    "PersonLook",
    "heading_rotation",
]
