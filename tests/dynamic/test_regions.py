"""Region growing over depth, surface segments, the temporal prior and the screener's memory."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.dynamic.history import FrameHistory, PastFrame, reduce_depth
from dynslam_lab.dynamic.regions import (
    follows_the_mover,
    RegionConfig,
    cells_at,
    continuity_components,
    crease_continuity,
    depth_continuity,
    grow_regions,
    on_region,
    prior_on_fresh_surfaces,
    splat,
    supported_regions,
    surface_segments,
    whole_surfaces,
)
from dynslam_lab.dynamic.temporal import MovingMapPoints, TemporalConfig, warp_region
from dynslam_lab.geometry.se3 import make_pose
from tests.dynamic.scenes import CAM

GRID = CAM.scaled(0.25)


def _box_on_floor() -> np.ndarray:
    """Reduced depth of a camera 0.8 m above a floor, looking level, with a 0.5 m box 2.5 m ahead on it."""
    h, w = GRID.height, GRID.width
    v, u = np.mgrid[0:h, 0:w].astype(float)
    ray_y = (v - GRID.cy) / GRID.fy
    ray_x = (u - GRID.cx) / GRID.fx
    with np.errstate(divide="ignore"):
        z_floor = np.where(ray_y > 0, 0.8 / ray_y, 0.0)  # floor: y = 0.8 m below the camera
    z = np.where((z_floor > 0) & (z_floor < 8.0), z_floor, 6.0)  # a wall at 6 m above the horizon / far away
    # box front face at z = 2.5 m, x in [-0.25, 0.25], from the floor (y = 0.8) up to y = 0.3
    x, y = ray_x * 2.5, ray_y * 2.5
    face = (np.abs(x) <= 0.25) & (y >= 0.3) & (y <= 0.8)
    z = np.where(face, 2.5, z)
    return z.astype(np.float32), face


def test_surface_segments_separate_a_box_from_the_floor_it_stands_on():
    z, face = _box_on_floor()
    n, labels = surface_segments(z, GRID, RegionConfig().continuity_rel, RegionConfig().crease_deg)
    inner = face.copy()
    inner[:, :] = False
    rows, cols = np.nonzero(face)
    inner[rows.min() + 2 : rows.max() - 1, cols.min() + 2 : cols.max() - 1] = True
    box_labels = np.unique(labels[inner])
    assert len(box_labels) == 1 and box_labels[0] > 0  # the inner face is one surface
    floor = ~face & (z < 5.9) & (labels > 0)
    assert not np.isin(labels[floor], box_labels).any()  # no floor cell shares it
    # depth continuity alone joins them through the contact line: the crease test is what splits them
    ch, cv = depth_continuity(z, 0.04)
    _, joined = continuity_components(z > 0, (ch, cv))
    assert np.isin(joined[floor], np.unique(joined[inner])).any()


def test_a_surface_mostly_in_the_region_joins_it_whole():
    """The box of ``_box_on_floor`` with 60 % of its face in the region (its left part: the part an earlier
    frame saw at the same depth is missing) joins whole at share 0.5 and stays as it was at 0.7; a large
    surface with a strip of the region (a fifth to 45 % of it) never joins; share 1 needs the surface whole
    already."""
    z, face = _box_on_floor()
    n, labels = surface_segments(z, GRID, RegionConfig().continuity_rel, RegionConfig().crease_deg)
    cells = np.bincount(labels.ravel(), minlength=n + 1)
    box = np.bincount(labels[face]).argmax()
    on_box = labels == box
    cols = np.flatnonzero(on_box.any(axis=0))
    region = on_box & (np.arange(labels.shape[1])[None, :] < cols[0] + 0.6 * len(cols))
    big = np.argsort(cells[1:])[-2:] + 1  # the two largest surfaces: the far wall and the floor beyond the box
    other = big[big != box][0]
    strip = (labels == other) & (np.cumsum(labels == other, axis=1) <= 40)  # 40 of its cells a row
    assert 0.2 < strip.sum() / cells[other] < 0.45
    region |= strip
    share_in = region[on_box].mean()
    assert 0.5 < share_in < 0.7
    out = whole_surfaces(region, labels, cells, 0.5)
    assert out[on_box].all() and np.array_equal(out & ~on_box, region & ~on_box)  # the box whole, nothing else
    assert np.array_equal(whole_surfaces(region, labels, cells, 0.7), region)
    assert np.array_equal(whole_surfaces(out, labels, cells, 1.0), out)  # a surface already whole stays
    with pytest.raises(ValueError, match="surface_share must be in"):
        RegionConfig(surface_share=1.5)


def test_continuity_components_match_a_union_find_reference():
    rng = np.random.default_rng(0)
    mask = rng.random((20, 30)) < 0.7
    horiz = rng.random((20, 29)) < 0.6
    vert = rng.random((19, 30)) < 0.6
    n, labels = continuity_components(mask, (horiz, vert))
    parent = list(range(mask.size))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for i in range(20):
        for j in range(30):
            if j < 29 and mask[i, j] and mask[i, j + 1] and horiz[i, j]:
                parent[find(i * 30 + j)] = find(i * 30 + j + 1)
            if i < 19 and mask[i, j] and mask[i + 1, j] and vert[i, j]:
                parent[find(i * 30 + j)] = find((i + 1) * 30 + j)
    ref = np.array([find(k) for k in range(mask.size)]).reshape(20, 30)
    # same partition: each label maps to one root and back
    for lab in np.unique(labels[mask]):
        assert len(np.unique(ref[labels == lab])) == 1
    for root in np.unique(ref[mask]):
        assert len(np.unique(labels[(ref == root) & mask])) == 1
    assert (labels[~mask] == 0).all()


def test_growth_follows_continuous_depth_and_stops_at_steps_edges_and_static_cells():
    z = np.full((30, 40), 3.0, np.float32)
    z[:, 20:] = 1.5  # a depth step at column 20
    cont = depth_continuity(z, 0.04)
    seeds = np.zeros_like(z, bool)
    seeds[15, 25] = True
    grown = grow_regions(seeds, np.ones_like(seeds), cont, steps=100)
    assert grown[:, 20:].all() and not grown[:, :20].any()
    few = grow_regions(seeds, np.ones_like(seeds), cont, steps=3)
    rr, cc = np.nonzero(few)
    assert (np.abs(rr - 15) + np.abs(cc - 25)).max() == 3  # 4-neighbour steps
    allowed = np.ones_like(seeds)
    allowed[:, 28] = False  # a column of confirmed-static cells
    walled = grow_regions(seeds, allowed, cont, steps=100)
    assert not walled[:, 28:].any() and walled[:, 20:28].all()


def test_a_region_needs_fresh_evidence_joined_across_continuous_depth():
    z = np.full((20, 20), 3.0, np.float32)
    z[:, 10:] = 1.0
    cont = depth_continuity(z, 0.04)
    region = np.ones_like(z, bool)  # grown over both sides of the step (8-adjacent across it)
    fresh = np.zeros_like(region)
    fresh[5, 12:16] = True  # fresh evidence on the near side only
    kept = supported_regions(region, fresh, 3, cont)
    assert kept[:, 10:].all() and not kept[:, :10].any()
    assert not supported_regions(region, fresh, 5, cont).any()


def test_the_prior_reopens_static_cells_only_on_a_surface_with_fresh_evidence():
    # a box on the floor; last frame's region covered the box and spilled onto the floor in front of it
    # (depth is continuous through the contact line); this frame has fresh evidence on the box only, and
    # the multi-frame test confirms the floor and the box's body static (a slow mover looks static inside)
    z, face = _box_on_floor()
    cfg = RegionConfig()
    _, labels = surface_segments(z, GRID, cfg.continuity_rel, cfg.crease_deg)
    rows, cols = np.nonzero(face)
    body = face & (np.arange(face.shape[0])[:, None] < rows.max() - 1)  # the face's lowest rows blur into the floor
    floor_strip = np.zeros_like(face)
    floor_strip[rows.max() + 1 : rows.max() + 9, cols.min() : cols.max() + 1] = True
    assert (z[floor_strip] > 0).all() and not (floor_strip & face).any()
    prior = face | floor_strip
    fresh = np.zeros_like(face)
    fresh[rows.min() : rows.min() + 2, cols.min() : cols.max() + 1] = True  # the box's top edge
    static = (face & ~fresh) | floor_strip
    reopened = prior_on_fresh_surfaces(prior, fresh, labels, cfg.min_fresh_cells)
    assert reopened[body & ~fresh].all()  # the box's body stays open to growth
    assert not reopened[floor_strip].any()  # the spill on the floor does not
    cont = depth_continuity(z, cfg.continuity_rel)
    for reopen, spills in ((prior, True), (reopened, False)):
        allowed = (z > 0) & (~static | reopen)
        region = supported_regions(grow_regions(fresh, allowed | fresh, cont, cfg.steps), fresh, cfg.min_fresh_cells, cont)
        assert region[body].all()  # the whole box either way
        assert region[floor_strip].any() == spills  # the old rule kept the spill alive
    # no fresh evidence at all: the prior reopens nothing; fewer than min_fresh_cells on the box: nothing
    assert not prior_on_fresh_surfaces(prior, np.zeros_like(fresh), labels, 1).any()
    few = np.zeros_like(fresh)
    few[rows.min(), cols.min()] = True
    assert not prior_on_fresh_surfaces(prior, few, labels, 2).any()


def test_cells_and_splat_follow_the_reduced_grid():
    r, c, inside = cells_at(np.array([[0.0, 0.0], [3.4, 3.6], [639.0, 479.0], [-3.0, 5.0]]), 4, (120, 160))
    assert r.tolist()[:3] == [0, 1, 120 - 1] and c.tolist()[:3] == [0, 0, 160 - 1] and inside.tolist() == [True, True, True, False]
    cells = splat(np.array([[10.0, 10.0], [100.0, 50.0]]), np.array([True, False]), 4, (120, 160))
    assert cells.sum() == 1 and cells[2, 2]


def test_reduce_depth_is_the_block_mean_and_drops_mixed_or_empty_blocks():
    rng = np.random.default_rng(1)
    d = rng.uniform(2.0, 2.01, (48, 64)).astype(np.float32)
    d[:4, :4] = 0  # an empty block
    d[4:8, 0:2] = 1.0  # a block straddling a depth edge
    d[8:12, 0:3] = 0  # 3/4 of a block missing: 1/4 valid is enough
    small = reduce_depth(d, 4)
    ref = d.reshape(12, 4, 16, 4).mean(axis=(1, 3))
    assert small[0, 0] == 0 and small[1, 0] == 0
    assert small[2, 0] == pytest.approx(d[8:12, 3].mean(), rel=1e-5)
    assert np.allclose(small[3:, 1:], ref[3:, 1:], rtol=1e-5)


def test_crease_continuity_keeps_a_plane_whole():
    z = np.full((40, 50), 2.5, np.float32)
    h, v = crease_continuity(z, GRID, 35.0)
    assert h.all() and v.all()


def test_the_previous_region_follows_the_camera_and_skips_what_was_hidden():
    small = np.full((GRID.height, GRID.width), 2.0, np.float32)
    prev_region = np.zeros_like(small, bool)
    prev_region[50:60, 70:80] = True
    assert np.array_equal(warp_region(prev_region, np.eye(4), small, GRID), prev_region)
    # the camera moved 0.05 m to the right: a point seen at column u now was at u + fx * 0.05 / 2 before
    T_p_c = make_pose(None, np.array([0.05, 0.0, 0.0]))
    shift = GRID.fx * 0.05 / 2.0
    warped = warp_region(prev_region, T_p_c, small, GRID)
    cols = np.nonzero(warped.any(axis=0))[0]
    assert cols.min() == pytest.approx(70 - shift, abs=1) and cols.max() == pytest.approx(79 - shift, abs=1)
    # the previous frame saw something 1 m in front of those points: they were hidden, no prior
    prev_depth = np.full_like(small, 1.0)
    assert not warp_region(prev_region, np.eye(4), small, GRID, prev_depth=prev_depth).any()


def test_moving_map_points_and_history():
    mp = MovingMapPoints(3)
    mp.add([1, 2, 3])
    mp.add([4])
    assert len(mp) == 3 and mp.contains([1, 2, 4]).tolist() == [False, True, True]
    h = FrameHistory(3)
    for k in range(5):
        h.push(PastFrame(k, float(k), np.zeros((4, 4), np.uint8), np.zeros((4, 4), np.float32)))
    assert [f.index for f in h] == [2, 3, 4] and h.back(1).index == 4 and h.back(4) is None
    h.update_poses({3.0: np.eye(4), 9.0: np.eye(4)})
    assert [f.index for f in h.with_pose((1, 2))] == [3]  # frame 4 has no pose: the nearest older one stands in
    with pytest.raises(ValueError):
        TemporalConfig(dilate_cells=-1)


def test_points_seen_moving_that_stand_still_are_released():
    """``MovingMapPoints.release_still`` by hand: three frames within 5 cm of where a point first stood
    release it; a step beyond starts the count again from there; a point unseen for three frames starts
    again; points not remembered as moving are ignored."""
    mp = MovingMapPoints(10)
    mp.add([1, 2, 3])
    P = {1: [0.0, 0.0, 1.0], 2: [0.0, 0.0, 2.0], 3: [0.0, 0.0, 3.0]}

    def see(frame, pts):
        ids = list(pts)
        return mp.release_still(ids, np.array([pts[i] for i in ids]).reshape(-1, 3), 0.05, 3, frame).tolist()

    assert see(0, {1: P[1], 2: P[2], 3: P[3], 7: [0, 0, 1]}) == []  # 7 was never seen moving
    assert see(1, {1: [0.01, 0.0, 1.0], 2: [0.2, 0.0, 2.0]}) == []  # 2 stepped 20 cm: counts from there
    assert see(2, {1: [0.0, 0.03, 1.02], 2: [0.21, 0.0, 2.0], 3: P[3]}) == [1]  # 3 frames within 5 cm
    assert mp.contains([1, 2, 3]).tolist() == [False, True, True]
    assert see(3, {2: [0.2, 0.01, 2.0]}) == [2]  # seen at 1 (moved), 2, 3 around (0.2, 0, 2)
    assert see(4, {}) == [] and see(5, {}) == []  # 3 last seen at frame 2: forgotten at frame 5
    assert see(6, {3: P[3]}) == [] and see(7, {3: P[3]}) == [] and see(8, {3: P[3]}) == [3]
    assert len(mp) == 0
    with pytest.raises(ValueError, match="release"):
        TemporalConfig(release_frames=-1)


def test_convex_edges_keep_an_object_whole_and_concave_ones_cut_it_from_the_floor():
    """A box seen from above its top face: top and front meet at a convex edge (joined); the box and the
    floor meet at a concave one (cut)."""
    h, w = GRID.height, GRID.width
    v, u = np.mgrid[0:h, 0:w].astype(float)
    ry, rx = (v - GRID.cy) / GRID.fy, (u - GRID.cx) / GRID.fx
    cam_h = 1.2  # camera 1.2 m above the floor, looking level
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(ry > 0, cam_h / ry, 8.0)
        z = np.minimum(z, 8.0)
        # box: x in [-0.3, 0.3], front face at z = 2.5, back at z = 3.0, top at 0.6 m above the floor (y = 0.6)
        z_front = np.where((np.abs(rx * 2.5) <= 0.3) & (ry * 2.5 >= 0.6) & (ry * 2.5 <= cam_h), 2.5, np.inf)
        z_top = np.where(ry > 0, 0.6 / ry, np.inf)
        top = (z_top >= 2.5) & (z_top <= 3.0) & (np.abs(rx * z_top) <= 0.3)
        z_top = np.where(top, z_top, np.inf)
    zz = np.minimum(np.minimum(z, z_front), z_top).astype(np.float32)
    front, topm = np.isfinite(z_front) & (z_front <= zz + 1e-6), top & (z_top <= zz + 1e-6)
    _, labels = surface_segments(zz, GRID, 0.04, 35.0)
    inner_f = front & np.roll(front, 2, 0) & np.roll(front, -2, 0) & np.roll(front, 2, 1) & np.roll(front, -2, 1)
    inner_t = topm & np.roll(topm, 1, 0) & np.roll(topm, -1, 0) & np.roll(topm, 2, 1) & np.roll(topm, -2, 1)
    box = np.unique(np.r_[labels[inner_f], labels[inner_t]])
    assert len(box) == 1 and box[0] > 0  # top and front: one object
    floor = (labels > 0) & ~front & ~topm & (zz < 7.5)
    assert not np.isin(labels[floor], box).any()
    _, split = continuity_components(zz > 0, (depth_continuity(zz, 0.04)[0] & crease_continuity(zz, GRID, 35.0, False)[0],
                                              depth_continuity(zz, 0.04)[1] & crease_continuity(zz, GRID, 35.0, False)[1]))
    assert len(np.unique(np.r_[split[inner_f], split[inner_t]])) == 2  # without the convexity rule the edge cuts it


def test_a_keypoint_on_a_silhouette_takes_the_verdict_of_the_region_cell_at_its_depth():
    # reduced depth: a mover at 2 m in columns 2-3, the wall at 4 m elsewhere, column 4 straddles the edge (0)
    small = np.full((5, 8), 4.0, np.float32)
    small[:, 2:4] = 2.0
    small[:, 4] = 0.0
    region = np.zeros((5, 8), bool)
    region[:, 2:4] = True  # the mover's cells
    r = np.array([2, 2, 2, 2, 2])
    c = np.array([3, 4, 4, 5, 1])
    # inside the region; on the edge cell at the mover's depth; on the edge cell at the wall's depth;
    # on the wall beside the edge cell; on the wall beside the mover (its own cell has a reading)
    z = np.array([2.02, 1.98, 4.0, 4.0, 2.0])
    own = on_region(region, small, r, c, z, 0.04)
    assert own.tolist() == [True, False, False, False, False]
    near = on_region(region, small, r, c, z, 0.04, reach=1)
    assert near.tolist() == [True, True, False, False, False]
    # two cells away the edge keypoint needs reach 2
    c2 = np.array([5]); small2 = small.copy(); small2[:, 5] = 0.0
    assert not on_region(region, small2, np.array([2]), c2, np.array([2.0]), 0.04, reach=1)[0]
    assert on_region(region, small2, np.array([2]), c2, np.array([2.0]), 0.04, reach=2)[0]
    with pytest.raises(ValueError, match="edge_cells"):
        RegionConfig(edge_cells=5)


def test_a_keypoint_without_depth_is_dynamic_when_its_flow_follows_the_movers_around_it():
    # three keypoints judged dynamic with depth, moving 5 px to the right since the previous frame (uv_prev = uv - 5)
    movers = np.array([[100.0, 100.0], [110.0, 100.0], [100.0, 110.0]])
    cands = np.array([
        [105.0, 105.0],  # A: moved with them (5 px, 0.2 px off their flow): dynamic
        [106.0, 104.0],  # B: did not move (0.1 px): static, below min_px
        [104.0, 106.0],  # C: moved half as far (2.5 px): as far from the movers' flow as from standing still
        [400.0, 400.0],  # D: moved like them, but no mover within reach
        [103.0, 103.0],  # E: not matched in the previous frame
    ])
    uv = np.vstack([movers, cands])
    shift = np.array([[-5, 0], [-5, 0], [-5, 0], [-5, -0.2], [-0.1, 0], [-2.5, 0], [-5, 0], [np.nan, np.nan]])
    uv_prev = uv + shift
    static_prev = uv.copy()  # a camera at rest: a static point stays where it is
    dynamic = np.array([True] * 3 + [False] * 5)
    candidates = np.array([False] * 3 + [True] * 5)
    out = follows_the_mover(uv, uv_prev, static_prev, candidates, dynamic, reach_px=24.0, min_px=1.0, ratio=0.5)
    assert out.tolist() == [False] * 3 + [True, False, False, False, False]
    # the hypotheses by hand for C: 2.5 px from the static prediction, |(-2.5, 0) - (-5, 0)| = 2.5 px from the movers'
    loose = follows_the_mover(uv, uv_prev, static_prev, candidates, dynamic, 24.0, 1.0, ratio=0.99)
    assert loose[3] and not loose[5]
    # a moving camera: the static prediction moves too, and a keypoint that follows it is static
    static_moving = uv + np.array([-5.0, 0.0])
    out = follows_the_mover(uv, uv_prev, static_moving, candidates, dynamic, 24.0, 1.0, 0.5)
    assert not out.any()
    # fewer moving neighbours than asked: no verdict
    assert not follows_the_mover(uv, uv_prev, static_prev, candidates, dynamic, 24.0, 1.0, 0.5, min_neighbours=4).any()


def test_the_silhouette_parameters_are_checked():
    with pytest.raises(ValueError, match="silhouette_ratio"):
        RegionConfig(silhouette_ratio=1.0)
    with pytest.raises(ValueError, match="silhouette_px"):
        RegionConfig(silhouette_px=-1.0)
