"""What the loop closer's worker sees of the map while it verifies candidates.

Verification (:func:`.verification.verify_candidate`) reads keyframe poses, the candidates' and the
query's covisible keyframes, the map points of each loop group and the keyframe centres along the
path. The frame loop keeps changing those (local BA moves poses and points, local mapping culls
keyframes and re-assigns observations), so verification off the frame loop works on a
:class:`MapView` frozen when the candidates are handed over (:func:`freeze_for_verification`, frame
loop, well under a millisecond): only what verification can read is copied.

* keyframe poses: a keyframe's pose array is never written in place (``set_pose`` replaces it), so
  holding the array freezes it without a copy; keypoints, depths, descriptors and ``static`` of a
  keyframe never change and are shared;
* ``map_point_ids`` of the loop-group keyframes: copied (local mapping writes them in place);
* covisibility of the query and of each candidate: the dictionaries the detector computed;
* position, descriptor and alive flag of the loop groups' points: copied rows.

A :class:`MapView` answers the same calls as :class:`~dynslam_lab.slam.map.Map` for those reads
(``keyframes``, ``best_covisibles``, ``xyz[ids]``, ``descriptors[ids]``, ``alive[ids]``,
``scale_factor``), so the verification code is one and the same on the live map and on a view.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping

import numpy as np

from ...geometry.se3 import se3_inv

__all__ = ["KeyframeView", "MapView", "freeze_for_verification"]


class KeyframeView:
    """A keyframe with its pose (and, for loop-group keyframes, its map-point ids) frozen; every
    other attribute is the keyframe's own (never changed after creation)."""

    __slots__ = ("_kf", "_T_w_c", "map_point_ids")

    def __init__(self, kf, map_point_ids: np.ndarray | None = None, T_w_c: np.ndarray | None = None) -> None:
        self._kf = kf
        # replaced, never written in place, by set_pose: holding the array freezes it
        self._T_w_c = kf._T_w_c if T_w_c is None else T_w_c
        self.map_point_ids = map_point_ids

    def __getattr__(self, name: str):
        return getattr(self._kf, name)

    @property
    def T_w_c(self) -> np.ndarray:
        return self._T_w_c.copy()

    @property
    def T_c_w(self) -> np.ndarray:
        return se3_inv(self._T_w_c)

    @property
    def center(self) -> np.ndarray:
        return self._T_w_c[:3, 3].copy()


class _FrozenKeyframes(Mapping):
    """``id -> KeyframeView`` of every keyframe at freeze time, the views made when first read.

    Freezing holds only the keyframe objects and their pose arrays (two dictionary copies, no
    object per keyframe), so its cost in the frame loop stays a few microseconds per hundred
    keyframes; the worker makes the views it reads (verification reads a few dozen)."""

    __slots__ = ("_kf", "_pose", "_views")

    def __init__(self, keyframes: dict, views: dict[int, KeyframeView]) -> None:
        self._kf = dict(keyframes)
        self._pose = {k: kf._T_w_c for k, kf in self._kf.items()}
        self._views = dict(views)

    def __getitem__(self, kf_id: int) -> KeyframeView:
        view = self._views.get(kf_id)
        if view is None:
            view = self._views[kf_id] = KeyframeView(self._kf[kf_id], None, self._pose[kf_id])
        return view

    def centres(self, ids) -> np.ndarray:
        """``(K, 3)`` frozen camera centres of keyframes ``ids`` (no view made: path lengths read
        every keyframe between the candidate and the query)."""
        return np.array([self._pose[k][:3, 3] for k in ids]).reshape(-1, 3)

    def __iter__(self) -> Iterator[int]:
        return iter(self._kf)

    def __len__(self) -> int:
        return len(self._kf)

    def __contains__(self, kf_id: object) -> bool:
        return kf_id in self._kf


class _Rows:
    """Rows of a per-point array for a sorted set of point ids: ``rows[ids]`` as ``array[ids]``."""

    __slots__ = ("ids", "values")

    def __init__(self, ids: np.ndarray, values: np.ndarray) -> None:
        self.ids, self.values = ids, values

    def __getitem__(self, pids) -> np.ndarray:
        pids = np.asarray(pids, np.int64)
        i = np.searchsorted(self.ids, pids)
        if len(pids) and (i.max() >= len(self.ids) or not np.array_equal(self.ids[i], pids)):
            raise KeyError("MapView: a point outside the frozen loop groups was read")
        return self.values[i]


class MapView:
    """The map as frozen for one verification job (see the module docstring)."""

    def __init__(self, keyframes: dict, covisibility: dict[int, dict[int, int]], point_ids: np.ndarray,
                 xyz: np.ndarray, descriptors: np.ndarray, alive: np.ndarray, scale_factor: float) -> None:
        self.keyframes = keyframes
        self._covisibility = covisibility
        self.xyz = _Rows(point_ids, xyz)
        self.descriptors = _Rows(point_ids, descriptors)
        self.alive = _Rows(point_ids, alive)
        self.scale_factor = scale_factor

    def covisibility(self, kf_id: int) -> dict[int, int]:
        if kf_id not in self._covisibility:
            raise KeyError(f"MapView: covisibility of keyframe {kf_id} was not frozen")
        return dict(self._covisibility[kf_id])

    def best_covisibles(self, kf_id: int, n: int | None = None, min_weight: int = 1) -> list[int]:
        """As :meth:`Map.best_covisibles`, for the query and the candidates."""
        cov = self.covisibility(kf_id)
        ids = sorted((k for k, w in cov.items() if w >= min_weight), key=lambda k: (-cov[k], k))
        return ids if n is None else ids[:n]


def freeze_for_verification(mp, query_id: int, candidate_ids: list[int], covisibility: dict[int, dict[int, int]],
                            group_size: int) -> MapView:
    """A :class:`MapView` of live map ``mp`` holding what verifying ``candidate_ids`` for keyframe
    ``query_id`` reads (frame loop). ``covisibility``: covisibility dictionaries already at hand (the
    detector's, :attr:`.detection.LoopDetector.last_covisibility`); those of the query and the
    candidates missing from it are taken from the map. ``group_size`` neighbours of each candidate form
    its loop group."""
    cov = {k: covisibility[k] if k in covisibility else mp.covisibility(k) for k in [query_id, *candidate_ids]}
    view = MapView({}, cov, np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 32), np.uint8),
                   np.zeros(0, bool), float(mp.scale_factor))
    members: set[int] = set()
    for c in candidate_ids:  # the loop group of verification.loop_group_points
        members.add(c)
        members.update(k for k in view.best_covisibles(c, group_size) if k != query_id)
    groups = {k: KeyframeView(mp.keyframes[k], mp.keyframes[k].map_point_ids.copy()) for k in members}
    view.keyframes = _FrozenKeyframes(mp.keyframes, groups)
    # the sorted distinct point ids of the groups: a mark per point id (O(points) memset, no sort or
    # hash of the ~100 k keypoints of the groups: np.unique of them was ~60 % of the loop stage)
    seen = np.zeros(len(mp.alive), bool)
    for kv in groups.values():  # loop over keyframes
        ids = kv.map_point_ids
        seen[ids[ids >= 0]] = True
    pids = np.flatnonzero(seen)
    view.xyz = _Rows(pids, mp.xyz[pids].copy())
    view.descriptors = _Rows(pids, mp.descriptors[pids].copy())
    view.alive = _Rows(pids, mp.alive[pids].copy())
    return view
