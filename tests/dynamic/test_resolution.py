"""The screening at another image size (``ScreeningConfig.for_width``, docs/robustness.md "Another resolution"):
the pixel extents scale with the image width and nothing else does; at 640 px wide nothing changes; on a half-size
copy of the walking scene ``geometry`` keeps the pose that it loses with the extents of 640 px."""

from __future__ import annotations

import dataclasses
from dataclasses import replace

import pytest

from dynslam_lab.dynamic.config import ScreeningConfig
from dynslam_lab.dynamic.screening import build_screener

SCALED = {
    ("multiframe", "factor"), ("multiframe", "min_filter_px"), ("reference", "search_radius_px"),
    ("reference", "gate_px"), ("epipolar", "border_px"), (None, "geometry_mask_margin_px"), (None, "reference_width"),
}


def _flat(cfg) -> dict:
    out = {}
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v):
            out.update({(f.name, g.name): getattr(v, g.name) for g in dataclasses.fields(v)})
        else:
            out[(None, f.name)] = v
    return out


def test_for_width_scales_the_extents_and_nothing_else():
    cfg = ScreeningConfig()
    assert cfg.for_width(640) is cfg and replace(cfg, reference_width=0).for_width(320).multiframe.factor == 4
    base = _flat(cfg)
    for width, s in ((320, 0.5), (960, 1.5), (1280, 2.0)):
        scaled = _flat(cfg.for_width(width))
        changed = {k for k in base if scaled[k] != base[k]}
        assert changed == SCALED, width
        assert scaled[("multiframe", "factor")] == round(4 * s) and scaled[("multiframe", "min_filter_px")] == round(2 * s)
        assert scaled[("reference", "gate_px")] == pytest.approx(6.0 * s)
        assert scaled[("reference", "search_radius_px")] == pytest.approx(8.0 * s)
        assert scaled[("epipolar", "border_px")] == pytest.approx(20.0 * s)
        assert scaled[(None, "geometry_mask_margin_px")] == round(10 * s)
        assert scaled[(None, "reference_width")] == width  # the values are those of this width now
        once = cfg.for_width(width)
        assert once.for_width(width) is once  # scaling again changes nothing
    assert cfg.for_width(100).multiframe.factor == 1  # never below one pixel a cell
    with pytest.raises(ValueError, match="reference_width"):
        ScreeningConfig(reference_width=-1)


def test_the_screener_runs_with_the_configuration_of_the_frame_width_and_follows_a_new_one():
    s = build_screener("geometry")
    assert s.config_for(640) is s.config
    assert s.config_for(320).multiframe.factor == 2 and s.config_for(320) is s.config_for(320)
    s.config = replace(s.config, reference=replace(s.config.reference, gate_px=4.0))  # a notebook's slider
    assert s.config_for(320).reference.gate_px == pytest.approx(2.0)


@pytest.mark.slow
def test_geometry_keeps_the_pose_on_half_size_images(tmp_path):
    """``walking_xyz`` at 320x240 (60 frames, no loop closing): the people walk ~4 px a frame there, inside the 6 px
    gate of the reference pose set for 640 px, where the pose follows them from the first frame (ATE 0.138 m when
    measured; 0.036 m since step 3b leaves a surface out in one Gauss-Newton step, which holds the room better);
    with the extents scaled to the image it stays on the room (0.028 m)."""
    from dynslam_lab.config import Config
    from dynslam_lab.datasets.camera_effects import CameraEffects, apply_camera_effects
    from dynslam_lab.datasets.synthetic import synthetic_sequence
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.pipeline import build_pipeline
    from dynslam_lab.runs import run_sequence

    half = apply_camera_effects(synthetic_sequence("walking_xyz", n_frames=60, seed=0), tmp_path / "half",
                                CameraEffects(scale=0.5))
    ate = {}
    for width in (640, 0):
        cfg = Config()
        cfg = replace(cfg, screening=replace(cfg.screening, reference_width=width))
        seq = TumSequence(half)
        assert seq.camera.width == 320
        system = build_pipeline(cfg, seq.camera, filters="geometry", loop_closing=False)
        summary = run_sequence(seq, tmp_path / f"run_{width}", system, progress=False)
        ate[width] = summary["ate"]["rmse"]
        recorded = summary["config"]["screening"]  # what the stages ran with, at this image's width
        assert recorded["multiframe"]["factor"] == (2 if width else 4)
        assert recorded["reference"]["gate_px"] == (3.0 if width else 6.0)
    assert ate[640] < 0.05 and ate[640] < ate[0], ate
