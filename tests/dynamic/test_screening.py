"""The screener chain on a two-layer scene with a moving person (truth by construction)."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.dynamic.config import ScreeningConfig
from dynslam_lab.dynamic.oracle import truth_dynamic
from dynslam_lab.experiments.scoring import KeypointScore, ScoringScreener, score_keypoints
from dynslam_lab.dynamic.screening import OracleScreener, Screener, build_screener, parse_filters
from dynslam_lab.features.orb import extract_features
from tests.dynamic.scenes import two_layer_frames


@pytest.fixture(scope="module")
def frames():
    out = []
    for frame, mask, dets in two_layer_frames(3):
        out.append((frame, mask, dets, extract_features(frame.gray).uv.astype(float)))
    return out


def _run(name, frames, config=None):
    s = build_screener(name, config)
    tables = [s.screen(f, uv, d) for f, _, d, uv in frames]
    return s, tables


def test_filter_names_and_errors():
    assert build_screener("none") is None
    assert isinstance(build_screener("oracle"), OracleScreener)
    assert parse_filters("geometry") == ("epipolar", "multiview", "multiframe", "temporal", "regions")
    assert parse_filters("flow, semantic") == ("semantic", "flow")  # run order
    assert "restoration" in parse_filters("full")
    with pytest.raises(ValueError, match="--filters 'yolo'"):
        build_screener("yolo")
    with pytest.raises(ValueError, match="full_stages"):
        ScreeningConfig(full_stages=("semantic", "magic"))


@pytest.mark.parametrize("name", ["semantic", "depth_ransac", "full", "oracle"])
def test_presets_find_the_person(frames, name):
    _, tables = _run(name, frames)
    frame, mask, _, uv = frames[-1]
    truth = truth_dynamic(frame, uv)
    s = score_keypoints(tables[-1].dynamic, truth)
    assert truth.sum() > 50
    assert s.recall >= 0.95
    assert s.precision >= 0.9
    t = tables[-1]
    assert t.region_mask is not None and t.region_mask.shape == mask.shape
    assert (t.region_mask & mask).sum() / mask.sum() > 0.9
    df = t.to_dataframe()
    assert len(df) == len(uv) and set(df.loc[df.dynamic, "reason"]) <= {"semantic", "depth_ransac", "epipolar",
                                                                         "multiview", "multiframe", "flow", "temporal",
                                                                         "regions", "oracle"}


def test_geometry_alone_finds_the_moving_person_without_a_detector(frames):
    s = build_screener("geometry")
    tables = [s.screen(f, uv, None) for f, _, _, uv in frames]
    assert not tables[0].dynamic.any()  # no previous frame yet
    frame, mask, _, uv = frames[-1]
    truth = truth_dynamic(frame, uv)
    # keypoints near the person's outline see occlusions; judge the interior and the far wall
    from scipy.ndimage import binary_dilation, binary_erosion

    inner = binary_erosion(mask, iterations=8)
    far = ~binary_dilation(mask, iterations=20)
    r, c = uv[:, 1].round().astype(int), uv[:, 0].round().astype(int)
    assert tables[-1].dynamic[inner[r, c]].mean() > 0.8  # the rest: LK lost them (no verdict)
    assert tables[-1].dynamic[far[r, c]].mean() < 0.05
    assert truth[inner[r, c]].all()
    assert {"epipolar", "multiview"} <= set(tables[-1].stages)
    assert "lk" in tables[-1].timings_ms


def test_reset_forgets_the_previous_frame(frames):
    s = build_screener("geometry")
    (f0, _, _, uv0), (f1, _, _, uv1) = frames[0], frames[1]
    s.screen(f0, uv0)
    assert "epipolar" in s.screen(f1, uv1).stages
    s.reset()
    assert "epipolar" not in s.screen(f1, uv1).stages


def test_scoring_wrapper_accumulates(frames):
    sc = ScoringScreener(build_screener("semantic"))
    for f, _, d, uv in frames:
        sc.screen(f, uv, d)
    assert len(sc.per_frame) == 3
    assert sc.score.tp == sum(s.tp for s in sc.per_frame)
    assert sc.score.recall == 1.0
    none = ScoringScreener(None)
    for f, _, d, uv in frames:
        none.screen(f, uv, d)
    assert none.score.tp == 0 and none.score.recall == 0.0 and np.isnan(none.score.precision)
    assert KeypointScore(1, 1, 2, 0).to_dict()["recall"] == pytest.approx(1 / 3)


def test_restoration_gives_back_a_person_that_fills_the_view():
    frames = two_layer_frames(2, box=(20, 20, 620, 460))  # the "person" covers nearly the whole image
    cfg = ScreeningConfig()
    s = Screener(("semantic", "restoration"), cfg)
    f, mask, d = frames[1]
    uv = extract_features(f.gray).uv.astype(float)
    t = s.screen(f, uv, d)
    assert t.restored.any() and t.static.mean() >= cfg.restoration.delta_1
    assert set(t.reason[t.restored]) == {"restored"}


def test_config_tree_takes_toml_style_overrides():
    from dynslam_lab.config import config_to_dict, with_overrides

    cfg = with_overrides(ScreeningConfig(), {"depth_ransac": {"var_threshold": 1.0}, "multiview": {"depth_m": 0.2},
                                             "full_stages": ["semantic", "epipolar", "level_rule"]})
    assert cfg.depth_ransac.var_threshold == 1.0 and cfg.multiview.depth_m == 0.2
    assert parse_filters("full", cfg) == ("semantic", "epipolar", "level_rule")
    d = config_to_dict(cfg)
    assert d["epipolar"]["threshold_px"] == 1.0 and d["flow"]["factor"] == 2.0
    with pytest.raises(ValueError, match="screening.depth_ransac.nthre"):
        with_overrides(ScreeningConfig(), {"depth_ransac": {"nthre": 1.0}}, where="screening")


# ----------------------------------------------------------------- stages as functions (issue 11 item 5)
def _gt_contexts(frames):
    """Contexts as the SLAM system would give them, with the true poses."""
    from dynslam_lab.dynamic.context import ScreeningContext
    from dynslam_lab.geometry.se3 import se3_inv

    poses, out = {}, []
    for f, _, _, uv in frames:
        feats = extract_features(f.gray)
        out.append(ScreeningContext(se3_inv(f.T_w_c_gt), dict(poses), descriptors=feats.descriptors, octave=feats.octave))
        poses[float(f.timestamp)] = f.T_w_c_gt
    return out


def test_every_stage_adds_its_own_column_and_changes_no_other(frames):
    from dynslam_lab.dynamic.history import FrameHistory
    from dynslam_lab.dynamic.stages import STAGE_FUNCTIONS, FrameWork, ScreenerMemory
    from dynslam_lab.dynamic.temporal import MovingMapPoints

    cfg = ScreeningConfig()
    s = build_screener("full", cfg)
    ctxs = _gt_contexts(frames)
    for (f, _, d, uv), ctx in zip(frames[:-1], ctxs[:-1]):
        s.screen(f, uv, d, context=ctx)  # memory of the earlier frames
    f, _, d, uv = frames[-1]
    mem = s.memory
    mem.history.update_poses(ctxs[-1].poses)
    w = FrameWork(f, uv, d, ctxs[-1], cfg, mem)
    for name, fn in STAGE_FUNCTIONS.items():
        before = {k: v.copy() for k, v in w.stages.items()}
        fn(w)
        assert set(w.stages) - set(before) <= {name}, name
        for k, v in before.items():
            assert np.array_equal(w.stages[k], v), f"{name} changed the column {k}"
    assert isinstance(mem.history, FrameHistory) and isinstance(mem.moving_points, MovingMapPoints)
    assert isinstance(w.memory, ScreenerMemory)


def test_the_screener_runs_with_the_config_it_shows():
    cfg = ScreeningConfig()
    assert build_screener("full", cfg).config is cfg
    dr = build_screener("depth_ransac", cfg)
    # YOLO-SLAM's "D + G" works on boxes: the preset says so in the configuration it runs with
    assert dr.config.semantic.use_masks is False and cfg.semantic.use_masks is True
    assert dr.config.depth_ransac == cfg.depth_ransac
    assert build_screener("semantic,depth_ransac", cfg).config is cfg


def test_detection_stages_refuse_to_run_without_detections(frames):
    f, _, _, uv = frames[0]
    for name in ("semantic", "depth_ransac", "full"):
        with pytest.raises(ValueError, match="judge keypoints from detections"):
            build_screener(name).screen(f, uv, None)
    from dynslam_lab.detection.detections import Detections

    t = build_screener("depth_ransac").screen(f, uv, Detections.empty(f.shape, source="test"))
    assert not t.dynamic.any()


def test_geometry_with_the_slam_context_finds_the_person(frames):
    s = build_screener("geometry")
    tables = [s.screen(f, uv, None, context=c) for (f, _, _, uv), c in zip(frames, _gt_contexts(frames))]
    f, mask, _, uv = frames[-1]
    score = score_keypoints(tables[-1].dynamic, truth_dynamic(f, uv))
    # measured 0.88 / 0.94 at the default 64 growth steps (the region grown from the person's edges reaches a
    # few wall cells of continuous depth beside it)
    assert score.recall >= 0.85 and score.precision >= 0.9
    assert {"multiframe", "temporal", "regions"} <= set(tables[-1].stages)
    assert tables[-1].timings_ms["lk"] > 0 and "reference_pose" in tables[-1].timings_ms
    assert s.uses_context and s.history_length == ScreeningConfig().multiframe.history_length + 1


def test_the_grid_evidence_of_the_last_frame_is_kept_for_figures(frames):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dynslam_lab.dynamic.plots import REASON_COLOURS, draw_grid, draw_table

    s = build_screener("geometry")
    for (f, _, _, uv), c in zip(frames, _gt_contexts(frames)):
        t = s.screen(f, uv, None, context=c)
    g = s.last_grid
    assert {"depth", "fresh", "static", "vanished", "region"} <= set(g)
    assert g["region"].shape == g["depth"].shape == (f.shape[0] // 4, f.shape[1] // 4)
    # the grown region lies on the moving "person" (a flat rectangle sliding in its own plane: its depth agrees
    # with the earlier frames away from its edges, so growth from the edges covers part of it)
    m = frames[-1][1]
    mask = m.reshape(m.shape[0] // 4, 4, m.shape[1] // 4, 4).any(axis=(1, 3))  # cells touching the person
    # (the scene's depth step between the wall halves at x = 320 stays put while their textures shift: a real
    # geometric inconsistency, found as such; judged away from it)
    away = np.ones_like(mask)
    away[:, 70:90] = False
    assert (g["region"] & mask).sum() > 0.1 * mask.sum()
    # 64 growth steps (the default) trade precision for recall: 31% of the region lies on the wall and floor cells
    # of continuous depth beside the person (8 steps: under 10%); the effect on whole runs is measured in
    # docs/robustness.md ("Region growth: 8 or 64 steps")
    assert (g["region"] & ~mask & away).sum() < 0.35 * g["region"].sum()
    assert set(t.reason.astype(str)) <= set(REASON_COLOURS)
    fig, (a, b) = plt.subplots(1, 2)
    draw_grid(a, f.rgb, g["fresh"], g["static"], g["region"], g["vanished"], "grid")
    draw_table(b, f.rgb, t, "table")
    plt.close(fig)


def test_keypoints_without_depth_on_the_outline_follow_the_person_with_the_silhouette_option():
    """``regions.silhouette_px``: with the sensor's depth lost in a 3 px band around the person's outline, keypoints
    there get no depth verdict; the option judges them by their flow and adds only keypoints without depth."""
    import cv2

    from dataclasses import replace

    from dynslam_lab.config import with_overrides

    band = np.ones((7, 7), np.uint8)
    frames = []
    for frame, mask, dets in two_layer_frames(6, person_shift_px=(3.0, 5.0)):
        m = mask.astype(np.uint8)
        ring = cv2.dilate(m, band).astype(bool) & ~cv2.erode(m, band).astype(bool)
        frame = replace(frame, depth=np.where(ring, 0.0, frame.depth).astype(np.float32))
        frames.append((frame, mask, dets, extract_features(frame.gray).uv.astype(float)))
    contexts = _gt_contexts(frames)

    def tables(config):
        s = build_screener("geometry", config)
        return [s.screen(f, uv, None, context=c) for (f, _, _, uv), c in zip(frames, contexts)]

    n_added = 0
    on_config = with_overrides(ScreeningConfig(), {"regions": {"silhouette_px": 8.0}})
    for (f, _, _, uv), off, on in zip(frames, tables(ScreeningConfig()), tables(on_config)):
        added = on.dynamic & ~off.dynamic
        assert not (off.dynamic & ~on.dynamic).any()  # the option only adds
        r, c = np.rint(uv[added, 1]).astype(int), np.rint(uv[added, 0]).astype(int)
        assert not (f.depth[r, c] > 0).any()  # ... keypoints without depth
        assert truth_dynamic(f, uv)[added].all()  # ... on the person
        n_added += int(added.sum())
    # measured: 12 over the six frames (the person 4-6 px a frame off the camera's flow; at 12 px LK loses nearly
    # all of them: their windows hold the person and the wall). The wall's keypoints without depth follow the
    # camera and stay static.
    assert n_added >= 8
