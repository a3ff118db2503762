"""``run_sequence`` and ``dynslam run``: the OUTDIR layout, a bad frame that does not end the
run, evaluation against ground truth, TOML overrides and clear errors."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from dynslam_lab.cli import main
from dynslam_lab.config import Config
from dynslam_lab.datasets.tum import TumSequence
from dynslam_lab.evaluation.trajectory import Trajectory, read_tum_trajectory, write_tum_trajectory
from dynslam_lab.pipeline import build_pipeline
from dynslam_lab.runs import run_sequence
from dynslam_lab.slam.system import System
from tests.slam import scene


@pytest.fixture(scope="module")
def seqdir(tmp_path_factory):
    """A TUM-layout copy of 24 rendered frames; the colour image of frame 12 is corrupt."""
    root = tmp_path_factory.mktemp("seq")
    (root / "rgb").mkdir()
    (root / "depth").mkdir()
    frames = scene.frames(40, "xyz")[:24]
    rgb_lines, depth_lines = [], []
    for f in frames:
        ts = f"{1000 + f.timestamp:.6f}"
        cv2.imwrite(str(root / "rgb" / f"{ts}.png"), cv2.cvtColor(f.rgb, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(root / "depth" / f"{ts}.png"), np.round(f.depth * 5000).astype(np.uint16))
        rgb_lines.append(f"{ts} rgb/{ts}.png")
        depth_lines.append(f"{ts} depth/{ts}.png")
    (root / "rgb" / f"{1000 + frames[12].timestamp:.6f}.png").write_bytes(b"not a png")
    (root / "rgb.txt").write_text("# colour\n" + "\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("# depth\n" + "\n".join(depth_lines) + "\n")
    gt = Trajectory(1000 + np.array([f.timestamp for f in frames]), np.stack([f.T_w_c_gt for f in frames]))
    write_tum_trajectory(gt, root / "groundtruth.txt")
    return root


def test_run_sequence_writes_layout_and_survives_a_bad_frame(seqdir, tmp_path):
    seq = TumSequence(seqdir, camera="default")
    out = tmp_path / "run"
    summary = run_sequence(seq, out, build_pipeline(Config(), seq.camera), progress=False, flush_every=5)
    for name in ("trajectory.txt", "timing.csv", "summary.json", "keyframes.npz", "map_points.npz", "dynamic_points.npz"):
        assert (out / name).is_file(), name
    assert summary["frames"] == 24 and summary["processed"] == 24 and summary["complete"]
    assert summary["lost_frames"] == [12] and summary["tracked"] == 23
    assert "frame 12" in summary["errors"][0] and "cannot decode" in summary["errors"][0]
    traj = read_tum_trajectory(out / "trajectory.txt")
    assert len(traj) == 23 and 1000 + 12 / 30.0 not in np.round(traj.timestamps, 6)
    # ATE from evaluation.evaluate, against the ground truth beside the sequence
    assert summary["ate"]["rmse"] < 0.01 and summary["ate"]["n"] == 23
    timing = np.genfromtxt(out / "timing.csv", delimiter=",", names=True)
    assert len(timing) == 24 and np.isnan(timing["total"][12]) and np.all(timing["orb"][timing["frame"] != 12] > 0)
    kf = np.load(out / "keyframes.npz")
    assert set(kf.files) == {"ids", "frame_index", "timestamps", "poses", "loop_edges"}
    assert kf["poses"].shape == (len(kf["ids"]), 4, 4) and kf["frame_index"][0] == 0
    mp = np.load(out / "map_points.npz")
    assert mp["xyz"].shape[0] == summary["map_points"] > 500 and mp["rgb"].dtype == np.uint8
    assert mp["n_obs"].min() >= 1
    assert sorted(p.name for p in (out / "thumbs").glob("*.jpg")) == sorted(f"{i}.jpg" for i in kf["ids"])
    assert cv2.imread(str(out / "thumbs" / "0.jpg")).shape == (120, 160, 3)
    saved = json.loads((out / "summary.json").read_text())
    assert saved["lost_frames"] == [12] and saved["config"]["orb"]["n_features"] == 1000
    assert saved["schema_version"] == 1 and saved["pipeline"] == {"detector": "none", "filters": "none", "loop_closing": True}


def test_cli_run_prints_the_depth_noise_the_screener_measured(seqdir, tmp_path, capsys):
    """With a screener the run measures the depth noise of its first frames (docs/robustness.md "Another depth
    sensor") and says what it read: this test scene's depth has no noise and reads about 0 (nothing scaled)."""
    out = tmp_path / "geo"
    assert main(["run", str(seqdir), "--out", str(out), "--max-frames", "6", "--filters", "geometry", "--no-loop",
                 "--quiet"]) == 0
    printed = json.loads(capsys.readouterr().out.splitlines()[0])
    s = json.loads((out / "summary.json").read_text())
    assert printed["depth_noise_ratio"] == round(s["depth_noise_ratio"], 2)
    assert 0.0 <= s["depth_noise_ratio"] < 0.2 and s["config"]["screening"]["depth_noise"]["frames"] == 5


def test_cli_run_with_toml_override_and_errors(seqdir, tmp_path, capsys):
    cfg = tmp_path / "c.toml"
    cfg.write_text("[orb]\nn_features = 800\n[tracking]\nmin_local_inliers = 25\n")
    out = tmp_path / "cli"
    rc = main(["run", str(seqdir), "--out", str(out), "--max-frames", "6", "--config", str(cfg), "--no-loop",
               "--quiet", "--camera", "default"])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["frames"] == 6 and s["tracked"] == 6
    assert s["config"]["orb"]["n_features"] == 800 and s["config"]["tracking"]["min_local_inliers"] == 25
    assert '"tracked": 6' in capsys.readouterr().out
    bad = tmp_path / "bad.toml"
    bad.write_text("[tracking]\nbogus = 1\n")
    assert main(["run", str(seqdir), "--out", str(tmp_path / "x"), "--config", str(bad), "--quiet"]) == 1
    assert "tracking.bogus: unknown parameter" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "missing"), "--out", str(tmp_path / "y"), "--quiet"]) == 1
    assert "sequence folder not found" in capsys.readouterr().err


class _StubScreener:
    """Left third of the image dynamic; a keypoint table with ``to_dataframe``."""

    resets = 0

    class Table:
        def __init__(self, uv, dynamic, shape):
            self.uv, self.dynamic = uv, dynamic
            self.region_mask = np.zeros(shape, bool)
            self.region_mask[:, : shape[1] // 3] = True

        def to_dataframe(self):
            import pandas as pd

            return pd.DataFrame({"u": self.uv[:, 0], "v": self.uv[:, 1], "dynamic": self.dynamic})

    config = Config().screening

    def reset(self):
        type(self).resets += 1

    def screen(self, frame, uv, detections):
        return self.Table(uv, uv[:, 0] < frame.camera.width / 3, frame.depth.shape)


def test_run_sequence_with_screener_saves_labels_and_dynamic_points(seqdir, tmp_path):
    import pandas as pd

    seq = TumSequence(seqdir, camera="default", max_frames=8)
    out = tmp_path / "dyn"
    summary = run_sequence(seq, out, System(seq.camera, Config(), screener=_StubScreener()), progress=False, save_labels=True)
    assert _StubScreener.resets == 1 and summary["tracked"] == 8
    labels = sorted((out / "labels").glob("*.csv"))
    assert [p.stem for p in labels] == [f"{i:06d}" for i in range(8)]
    t0 = pd.read_csv(labels[0])
    assert t0["dynamic"].any() and np.all(t0["dynamic"] == (t0["u"] < 640 / 3))
    dyn = np.load(out / "dynamic_points.npz")
    assert len(dyn["xyz"]) > 100 and set(np.unique(dyn["frame"])) == set(range(8))
    # dynamic keypoints were never made map points: world points of map lie right of the left third
    mp = np.load(out / "map_points.npz")
    uv, _ = seq.camera.project(mp["xyz"])  # frame 0 is the world frame
    assert np.mean(uv[:, 0] >= 640 / 3 - 2) > 0.95


def test_geometry_run_writes_where_the_screen_time_goes(seqdir, tmp_path):
    """``screen_timing.csv``: a row per screened frame (the corrupt frame 12 has none), the screening
    stages in pipeline order and ``total`` first; the stages' parts add up to no more than the
    screener's total, which is part of the system's ``screen`` stage in ``timing.csv``."""
    import pandas as pd

    seq = TumSequence(seqdir, camera="default", max_frames=16)
    system = build_pipeline(Config(), seq.camera, filters="geometry", loop_closing=False)
    out = tmp_path / "geo"
    summary = run_sequence(seq, out, system, progress=False)
    assert "screen_timing.csv" in json.loads((out / "summary.json").read_text())["files"]
    st = pd.read_csv(out / "screen_timing.csv")
    timing = pd.read_csv(out / "timing.csv")
    stages = [s for s in system.screener.stages if s in st.columns]
    assert list(st.columns[: len(stages) + 2]) == ["frame", *stages, "total"] and len(stages) >= 3
    assert "reference_pose" in st.columns and "lk" in st.columns  # shared products after them
    assert st["frame"].tolist() == [i for i in range(16) if i != 12]
    assert np.all(st[stages].fillna(0).sum(axis=1) <= st["total"] + 1e-3)
    screen = timing.set_index("frame").loc[st["frame"], "screen"].to_numpy()
    assert np.all(st["total"].to_numpy() <= screen + 1e-3) and np.all(st["total"] > 0)


def test_flushes_during_a_run_do_not_wait_for_the_loop_closer(seqdir, tmp_path):
    """The files written every ``flush_every`` frames show the map as it stands: only the final write
    waits for (and applies) the loop closer's pending corrections, so no frame waits for them."""
    seq = TumSequence(seqdir, camera="default")
    system = build_pipeline(Config(), seq.camera)
    processed, waits = [], []
    plain = system.finish_loop_closing

    def counting():
        waits.append(len(processed))
        plain()

    system.finish_loop_closing = counting
    summary = run_sequence(seq, tmp_path / "run", system, progress=False, flush_every=2,
                           on_frame=lambda frame, res: processed.append(frame.index))
    assert summary["complete"] and len(processed) == 23
    assert waits and all(n == 23 for n in waits)  # after the last frame only, not at the 12 flushes


def test_writes_during_a_run_wait_while_they_would_cost_more_than_their_share(seqdir, tmp_path, monkeypatch):
    """A write every ``flush_every`` frames, unless the frames since the last one took less than
    ``flush_cost_ratio`` times that write (the files grow with the run: long runs write less often)."""
    import time as _time

    from dynslam_lab.runs import runner

    plain = runner.RunRecorder.write
    during = []

    def slow_write(self, system, summary, final=False, wait=True):
        if not wait:  # the writes during the run (the last one waits for the loop closer)
            during.append(len(self.rows))
            _time.sleep(0.25)
        return plain(self, system, summary, final=final, wait=wait)

    monkeypatch.setattr(runner.RunRecorder, "write", slow_write)
    seq = TumSequence(seqdir, camera="default")
    run_sequence(seq, tmp_path / "every", build_pipeline(Config(), seq.camera), progress=False, flush_every=2,
                 flush_cost_ratio=0.0)
    # after frame 0, then after frames 1, 3, ..., 23 (the bad frame 12 has a row too, and is not a turn)
    assert during == [1] + [k + 1 for k in range(1, 24, 2)]
    during.clear()
    summary = run_sequence(seq, tmp_path / "throttled", build_pipeline(Config(), seq.camera), progress=False,
                           flush_every=2)
    # each write costs 0.25 s: the next one waits until the frames since took 20 x 0.25 = 5 s, more than the
    # whole of these 24 frames, so the first frame's write is the only one before the last
    assert summary["complete"] and during[0] == 1 and len(during) <= 2
