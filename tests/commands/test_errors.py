"""The CLI's one error boundary and honest exit codes (issue 13, items 6, 7, 9, 10, 11).

Every case is a hostile input a careful user tried: each must end with exit code 1 (data) or 2
(usage) and one line naming the file or option and the problem, never a traceback; runs whose
configuration cannot work stop once instead of failing every frame."""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS, save_camera_json
from dynslam_lab.cli import main
from dynslam_lab.config import Config, load_config
from dynslam_lab.errors import UsageError
from dynslam_lab.mapping.ply import PlyError, read_ply
from dynslam_lab.runs import verify_run
from dynslam_lab.slam.tracking import TrackingConfig
from tests.fixtures.demo_run import write_demo_run
from tests.runs.sequences import write_sequence

RUN = ["--quiet", "--no-loop", "--camera", "default"]


def _one_line(err: str, *needles: str) -> None:
    """stderr holds one error line (warnings of the run logger aside) with every needle, no traceback."""
    assert "Traceback" not in err, err
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("dynslam ")]
    assert len(lines) == 1, err
    for n in needles:
        assert n in lines[0], (n, lines[0])


@pytest.fixture(scope="module")
def seqs(tmp_path_factory):
    root = tmp_path_factory.mktemp("seqs")
    return {
        "good": write_sequence(root / "good", n=8),
        "depth8": write_sequence(root / "depth8", n=8, depth_bits=8),
        "sizes": write_sequence(root / "sizes", n=8, depth_size=(240, 320)),
        "flat": write_sequence(root / "flat", n=8, flat=True),
        "gt_elsewhere": write_sequence(root / "gt_elsewhere", n=8, gt_offset=100.0),
    }


# ----------------------------------------------------------------------- item 6: exit codes
@pytest.mark.parametrize("case, extra, needle", [
    ("depth8", [], "depth image must be 16-bit"),
    ("sizes", [], "depth size (240, 320) differs from colour size (480, 640)"),
    ("good", ["--detector", "oracle", "--filters", "semantic"], "the oracle detector needs a synthetic frame"),
    ("good", ["--detector", "cache:EMPTY", "--filters", "semantic"], "no cached detections for frame 0"),
])
def test_an_error_on_every_frame_is_one_stop(seqs, tmp_path, capsys, caplog, case, extra, needle):
    (tmp_path / "EMPTY").mkdir()
    extra = [e.replace("EMPTY", str(tmp_path / "EMPTY")) for e in extra]
    out = tmp_path / "out"
    assert main(["run", str(seqs[case]), "--out", str(out), *RUN, *extra]) == 1
    err = capsys.readouterr().err
    _one_line(err, "the first 5 frames all failed with the same error", needle)
    assert caplog.text.count(needle) == 1  # logged once for frame 0, then the stop: not once per frame
    s = json.loads((out / "summary.json").read_text())
    assert s["state"] == "failed" and s["processed"] == 5 and s["tracked"] == 0 and verify_run(out) == []


def test_no_tracked_frame_and_negative_thresholds_exit_non_zero(seqs, tmp_path, capsys):
    assert main(["run", str(seqs["flat"]), "--out", str(tmp_path / "flat"), *RUN]) == 1
    _one_line(capsys.readouterr().err, "no frame of", "was tracked (8 processed)")
    toml = tmp_path / "neg.toml"
    for field, value in (("min_depth", "-1"), ("pnp_iterations", "-1"), ("kf_max_frames", "-3")):
        toml.write_text(f"[tracking]\n{field} = {value}\n")
        assert main(["run", str(seqs["good"]), "--out", str(tmp_path / field), "--config", str(toml), *RUN]) == 1
        _one_line(capsys.readouterr().err, "neg.toml", f"TrackingConfig.{field} must be")
        assert not (tmp_path / field).exists()  # refused before anything is written


# ----------------------------------------------------------------------- item 7: settings
def test_settings_that_cannot_work_are_refused(seqs, tmp_path, capsys):
    assert main(["run", str(seqs["good"]), "--out", str(tmp_path / "o"), "--filters", "semantic", *RUN]) == 2
    _one_line(capsys.readouterr().err, "--filters 'semantic'", "--detector is 'none'")
    for bad in ({"min_depth": -1}, {"pnp_iterations": -1}, {"kf_max_frames": -3}, {"min_depth": 9.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            TrackingConfig(**bad)
    toml = tmp_path / "types.toml"
    for text, needle in (("[tracking]\nmin_depth = 'near'\n", "tracking.min_depth: expected a number"),
                         ("[detection]\ninput_size = [640]\n", "detection.input_size: expected a list of 2 values"),
                         ("[detection]\nnanodet_center_offset = 'x'\n", "expected a number"),
                         ("[tracking]\nmax_depth = inf\n", "expected a finite number")):
        toml.write_text(text)
        with pytest.raises(ValueError, match=re.escape(needle)):
            load_config(toml, Config())


def test_the_toml_example_of_config_loads(tmp_path):
    import dynslam_lab.config as config

    block = config.__doc__.split("by section::")[1].split("\n\n")[1]
    (tmp_path / "example.toml").write_text("\n".join(line.strip() for line in block.splitlines()) + "\n")
    cfg = load_config(tmp_path / "example.toml", Config())
    assert cfg.tracking.min_local_inliers == 20 and cfg.screening.depth_ransac.var_threshold == 0.43


def test_images_of_another_size_than_camera_json(seqs, tmp_path, capsys):
    seq = tmp_path / "seq"
    shutil.copytree(seqs["good"], seq)
    save_camera_json(CAMERA_PRESETS["default"].with_(width=320, height=240, name="camera.json"), seq / "camera.json")
    assert main(["run", str(seq), "--out", str(tmp_path / "o"), "--quiet", "--no-loop"]) == 1
    _one_line(capsys.readouterr().err, "image is 640x480 but the camera 'camera.json' is 320x240")


# ----------------------------------------------------------------------- item 9: one line, never a traceback
def test_output_folder_errors(seqs, tmp_path, capsys):
    f = tmp_path / "a_file"
    f.write_text("mine")
    assert main(["run", str(seqs["good"]), "--out", str(f), *RUN]) == 2
    _one_line(capsys.readouterr().err, "a_file: exists and is not a folder")
    assert f.read_text() == "mine"
    with pytest.raises(UsageError):  # --debug: the exception itself, with its traceback
        main(["--debug", "run", str(seqs["good"]), "--out", str(f), *RUN])
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    target = ro / "out"
    if os.access(ro, os.W_OK):  # root ignores permissions: a kernel file system refuses instead
        target = Path("/sys/dynslam_unwritable_out")
        try:
            target.mkdir()
        except OSError:
            pass
        else:
            target.rmdir()
            pytest.skip("no unwritable folder to try as this user")
    assert main(["run", str(seqs["good"]), "--out", str(target), *RUN]) == 2
    _one_line(capsys.readouterr().err, str(target), "cannot write an output folder here")


def test_malformed_run_folders_in_view(tmp_path, capsys):
    base = write_demo_run(tmp_path / "base", n_frames=20, n_map_points=50, n_dense_points=300, thumbs=False)

    def copy(name):
        return Path(shutil.copytree(base, tmp_path / name))

    (copy("npz") / "keyframes.npz").write_bytes(b"not a zip at all")
    (copy("list") / "summary.json").write_text("[1, 2, 3]\n")
    cases = [("npz", "keyframes.npz: not an npz file"), ("list", "summary.json: expected a JSON object, got list")]
    for count, needle in (("abc", "vertex count 'abc' is not a whole number"),
                          ("1e15", "vertex count '1e15' is not a whole number"),
                          ("-5", "vertex count '-5' is not a whole number")):
        ply = copy(f"ply{count}") / "map.ply"
        raw = ply.read_bytes()
        ply.write_bytes(raw.replace(b"element vertex 300\n", f"element vertex {count}\n".encode(), 1))
        cases.append((f"ply{count}", f"map.ply: " + needle))
    for name, needle in cases:
        assert main(["view", str(tmp_path / name), "--timeout", "0.1", "--port", "18181"]) == 1, name
        _one_line(capsys.readouterr().err, "dynslam view: error:", needle)
    # A well-formed count the file cannot hold: the viewer starts and its dense layer (read in the
    # background) reports it, without trying to allocate 10^15 vertices.
    ply = copy("ply_huge") / "map.ply"
    ply.write_bytes(ply.read_bytes().replace(b"element vertex 300\n", b"element vertex 1000000000000000\n", 1))
    with pytest.raises(PlyError, match="map.ply: truncated: the header announces 1000000000000000 vertices, the file "
                                       "holds data for at most 300"):
        read_ply(ply)


def test_malformed_inputs_of_run(seqs, tmp_path, capsys):
    seq = tmp_path / "seq"
    shutil.copytree(seqs["good"], seq)
    (seq / "instances.json").write_text(json.dumps({"1": {"colour": [1, 2, 3]}}))
    assert main(["run", str(seq), "--out", str(tmp_path / "o1"), *RUN]) == 1
    _one_line(capsys.readouterr().err, "instances.json: instance '1' has no \"class\" name")
    toml = tmp_path / "latin1.toml"
    toml.write_bytes("[orb]\n# réglages\nn_features = 800\n".encode("latin-1"))
    assert main(["run", str(seqs["good"]), "--out", str(tmp_path / "o2"), "--config", str(toml), *RUN]) == 1
    _one_line(capsys.readouterr().err, "latin1.toml: not UTF-8 text (byte 0xe9 at offset 9)")


def test_internal_errors_are_one_line_too(monkeypatch, capsys):
    import dynslam_lab.commands.eval as ev

    def broken(args):
        raise KeyError("class")

    monkeypatch.setattr(ev, "run", broken)
    assert main(["eval", "--gt", "g", "--est", "e"]) == 1
    _one_line(capsys.readouterr().err, "internal error: KeyError", "--debug")


# ----------------------------------------------------------------------- items 9, 10: detect
def _detect_model(tmp_path, poison: bool):
    from tests.detection.test_decode import _yolov8_head
    from tests.detection.tiny_models import write_constant_model

    head = _yolov8_head()
    if poison:  # a broken export: a non-finite box with a high score, an infinite score
        head[0, :4, 20] = [np.nan, 10, 10, 10]
        head[0, 4, 20] = 0.95
        head[0, :4, 30] = [30, 30, 10, 10]
        head[0, 4 + 2, 30] = np.inf
        head[0, :4, 40] = [30, 30, np.inf, 10]
        head[0, 4 + 3, 40] = 0.9
    return write_constant_model(tmp_path / f"v8{'_bad' if poison else ''}.onnx", {"output0": head})


def test_detect_edge_cases(tmp_path, capsys):
    model = _detect_model(tmp_path, poison=False)
    img = tmp_path / "wide.png"
    cv2.imwrite(str(img), np.full((2, 4000, 3), 90, np.uint8))
    assert main(["detect", str(img), "--model", str(model), "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["image_size"] == [2, 4000]
    blocker = tmp_path / "dets"
    blocker.write_text("a file")
    assert main(["detect", str(img), "--model", str(model), "--save-dir", str(blocker)]) == 2
    _one_line(capsys.readouterr().err, "dets: exists and is not a folder")
    save = tmp_path / "cache"
    assert main(["detect", str(img), "--model", str(model), "--save-dir", str(save)]) == 0
    assert main(["detect", str(img), "--model", str(model), "--save-dir", str(save)]) == 2  # no silent overwrite
    assert "pass --force" in capsys.readouterr().err
    assert main(["detect", str(img), "--model", str(model), "--save-dir", str(save), "--force"]) == 0


def test_detect_json_is_strict_and_non_finite_outputs_never_pass(tmp_path, capsys):
    from dynslam_lab.detection import OnnxDetector

    model = _detect_model(tmp_path, poison=True)
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), np.zeros((96, 128, 3), np.uint8))
    assert main(["detect", str(img), "--model", str(model), "--json"]) == 0
    text = capsys.readouterr().out

    def refuse(const):
        raise AssertionError(f"non-JSON constant {const} in {text}")

    rec = json.loads(text, parse_constant=refuse)
    assert [d["class"] for d in rec["detections"]] == ["person", "chair"]  # the model's finite rows, nothing else
    det = OnnxDetector(model).detect_image(np.zeros((96, 128, 3), np.uint8))
    assert np.isfinite(det.boxes).all() and np.isfinite(det.scores).all() and len(det) == 2


# ----------------------------------------------------------------------- item 11: messages
def test_evaluation_errors_and_empty_lists_are_said(seqs, tmp_path, capsys, caplog):
    out = tmp_path / "o"
    assert main(["run", str(seqs["gt_elsewhere"]), "--out", str(out), *RUN]) == 0
    # a warning of the run's logger (stderr from the command line; pytest captures it here)
    assert "evaluation against" in caplog.text and "groundtruth.txt failed: no matching timestamps" in caplog.text
    assert "no matching timestamps" in json.loads((out / "summary.json").read_text())["evaluation_error"]
    seq = tmp_path / "seq"
    shutil.copytree(seqs["good"], seq)
    (seq / "rgb.txt").write_text("# colour images\n")
    assert main(["run", str(seq), "--out", str(tmp_path / "o2"), *RUN]) == 1
    _one_line(capsys.readouterr().err, "rgb.txt: lists no frames (the file is empty or holds only comments)")
