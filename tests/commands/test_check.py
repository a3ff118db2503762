"""`dynslam check SEQDIR`: what a run would take from a folder, with each problem a run would refuse (or only
show as a bad trajectory) named; the numbers against the test room's rendering and `dynslam run` itself."""

from __future__ import annotations

import json
import shutil

import pytest

from dynslam_lab.camera import CAMERA_PRESETS, save_camera_json
from dynslam_lab.cli import main
from dynslam_lab.datasets.check import check_sequence
from dynslam_lab.datasets.depth_scale import sample_depth
from dynslam_lab.datasets.tum import TumSequence
from tests.runs.sequences import write_sequence


@pytest.fixture(scope="module")
def seqs(tmp_path_factory):
    root = tmp_path_factory.mktemp("check")
    good = write_sequence(root / "rgbd_dataset_freiburg3_room", n=12)
    return {"good": good, "gt_elsewhere": write_sequence(root / "fr3_gt_elsewhere", n=12, gt_offset=100.0)}


def _copy(src, dst, scale=None, size=None):
    shutil.copytree(src, dst)
    if scale is not None or size is not None:
        cam = CAMERA_PRESETS["default"].with_(name="camera.json")
        cam = cam.with_(depth_scale=scale) if scale is not None else cam.with_(width=size[0], height=size[1])
        save_camera_json(cam, dst / "camera.json")
    return dst


def test_a_good_folder_is_described_and_would_run(seqs, capsys):
    assert main(["check", str(seqs["good"])]) == 0
    out = capsys.readouterr().out
    lines = {ln.split()[0]: ln for ln in out.splitlines()}
    assert "12 colour, 12 depth -> 12 pairs" in lines["frames"] and "30.0 Hz" in lines["frames"]
    assert "'tum_fr3'" in lines["camera"] and "from the folder's name" in lines["camera"]
    assert "640x480 colour and depth" in lines["images"]
    median = sample_depth(TumSequence(seqs["good"])).median_m
    assert f"median {median:.2f} m over 5 frames" in lines["depth"]
    assert "12 of 12 frames" in lines["truth"] and "masks" not in lines
    assert "a run would start (0 errors, 0 warnings)" in out
    rep = check_sequence(seqs["good"])
    assert rep.ok and [i.level for i in rep.items] == ["ok"] * 5


def test_what_a_run_would_refuse_is_an_error_and_exit_code_1(seqs, tmp_path, capsys):
    mm = _copy(seqs["good"], tmp_path / "fr3_mm", scale=1000.0)
    assert main(["check", str(mm), "--json"]) == 1
    rep = json.loads(capsys.readouterr().out)
    assert rep["ok"] is False and rep["errors"] == 1
    depth = [i for i in rep["items"] if i["topic"] == "depth"][0]
    assert depth["level"] == "error" and "depth_scale 1000 units per metre" in depth["text"]
    assert main(["run", str(mm), "--out", str(tmp_path / "o"), "--quiet", "--no-loop"]) == 1  # the run agrees
    small = _copy(seqs["good"], tmp_path / "fr3_small", size=(320, 240))
    assert main(["check", str(small)]) == 1
    assert "image is 640x480 but the camera 'camera.json' is 320x240" in capsys.readouterr().out
    assert main(["check", str(tmp_path / "nowhere")]) == 1
    assert "sequence folder not found" in capsys.readouterr().out
    assert main(["check", str(seqs["good"]), "--camera", "nope"]) == 1
    assert "unknown camera preset 'nope'" in capsys.readouterr().out


def test_warnings_a_guessed_camera_partial_truth_and_a_gap(seqs, tmp_path, capsys, caplog):
    guess = _copy(seqs["good"], tmp_path / "my_scene")
    assert main(["check", str(guess)]) == 0
    out = capsys.readouterr().out
    assert "! camera" in out and "a guess" in out and "(0 errors, 1 warning)" in out
    assert "no camera.json" not in caplog.text  # said once, in the report
    assert main(["check", str(guess), "--camera", "default"]) == 0  # named: no guess
    assert "from --camera" in capsys.readouterr().out
    assert main(["check", str(seqs["gt_elsewhere"])]) == 0
    out = capsys.readouterr().out
    assert "! truth" in out and "0 of 12 frames" in out and "ATE and RPE would cover only those frames" in out
    gap = _copy(seqs["good"], tmp_path / "fr3_gap")
    for name in ("rgb.txt", "depth.txt"):  # frames 4-8 dropped: a gap of 6 intervals
        p = gap / name
        rows = p.read_text().splitlines()
        p.write_text("\n".join(rows[:5] + rows[10:]) + "\n")
    rep = check_sequence(gap)
    frames = rep.items[0]
    assert rep.ok and frames.level == "warning" and "the largest gap is" in frames.text
