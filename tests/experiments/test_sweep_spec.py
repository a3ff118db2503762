"""The sweep spec: parsing, ranges, bad keys named, and the hash that names each run."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from dynslam_lab import __version__
from dynslam_lab.config import config_to_dict
from dynslam_lab.datasets.synthetic import cache_key, synthetic_sequence
from dynslam_lab.experiments.sweep_spec import expand_values, load_spec, run_id
from tests.experiments.specs import TINY

BASE = TINY.replace('filters = ["geometry"]', 'filters = ["geometry", "full"]\nmax_frames = 8')


def _spec(tmp_path, text=BASE, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return load_spec(p)


def test_plan_counts_detectors_and_order(tmp_path):
    spec = _spec(tmp_path)
    tasks = spec.tasks(tmp_path / "out")
    assert len(tasks) == 2 * 2 * 2  # seeds x filters x thresholds
    # auto detector: the oracle where the synthetic truth exists, and none for a filter without a detection stage
    assert {t.detector for t in tasks if t.filters == "geometry"} == {"none"}
    assert {t.detector for t in tasks if t.filters == "full"} == {"oracle"}
    assert [(t.sequence.seed, t.filters, t.params[0][1]) for t in tasks[:4]] == [
        (0, "geometry", 0.5), (0, "geometry", 2.0), (0, "full", 0.5), (0, "full", 2.0)]
    assert all(t.run_dir == str((tmp_path / "out" / "runs" / t.run_id).resolve()) for t in tasks)
    assert all(t.sequence.max_frames == 8 for t in tasks)
    assert tasks[0].config().screening.epipolar.threshold_px == 0.5
    assert tasks[1].config().screening.epipolar.threshold_px == 2.0


def test_ranges():
    assert expand_values({"start": 1, "stop": 5, "num": 5}, "k") == [1, 2, 3, 4, 5]
    assert all(isinstance(v, int) for v in expand_values({"start": 1, "stop": 5, "num": 5}, "k"))
    np.testing.assert_allclose(expand_values({"start": 0.5, "stop": 2.0, "num": 4}, "k"), np.linspace(0.5, 2.0, 4))
    np.testing.assert_allclose(expand_values({"start": 0.1, "stop": 10.0, "num": 3, "scale": "log"}, "k"), [0.1, 1.0, 10.0])
    assert expand_values({"start": 1, "stop": 4, "num": 3}, "k") == [1.0, 2.5, 4.0]  # not integers: floats
    assert expand_values([0.1 * 3, "a"], "k") == [0.3, "a"]  # rounded to 12 digits: 0.30000000000000004 -> 0.3
    for bad, msg in [({"start": 1, "stop": 2}, "range is"), ({"start": 1, "stop": 2, "num": 0}, "num must be"),
                     ({"start": 0, "stop": 2, "num": 3, "scale": "log"}, "log range"), ([], "empty"),
                     (3.0, "expected a list"), ([1, 1], "appears twice")]:
        with pytest.raises(ValueError, match=f"^k: .*{msg}"):
            expand_values(bad, "k")


def test_nested_and_dotted_keys_are_the_same_runs(tmp_path):
    a = _spec(tmp_path, BASE + '\n[config]\n"tracking.pnp_min_inliers" = 20\n', "a.toml")
    nested = BASE.replace('"screening.epipolar.threshold_px" = [0.5, 2.0]', "screening.epipolar.threshold_px = [0.5, 2.0]")
    b = _spec(tmp_path, nested + "\n[config.tracking]\npnp_min_inliers = 20\n", "b.toml")
    assert [t.run_id for t in a.tasks(tmp_path)] == [t.run_id for t in b.tasks(tmp_path)]
    assert a.tasks(tmp_path)[0].config().tracking.pnp_min_inliers == 20


@pytest.mark.parametrize("edit,message", [
    (('"screening.epipolar.threshold_px"', '"screening.epipolar.threshhold_px"'),
     r"s\.toml: \[grid\] screening\.epipolar\.threshhold_px = 0\.5: config\.screening\.epipolar\.threshhold_px: unknown parameter"),
    (('"screening.epipolar.threshold_px"', '"screening.epipolr.threshold_px"'),
     r"\[grid\] screening\.epipolr\.threshold_px = 0\.5: config\.screening\.epipolr: unknown parameter"),
    (("[0.5, 2.0]", '[0.5, "x"]'), r"\[grid\] screening\.epipolar\.threshold_px = 'x': .*expected a number"),
    (("[0.5, 2.0]", "[0.5, -1.0]"), r"\[grid\] screening\.epipolar\.threshold_px = -1\.0: .*threshold_px .*must be > 0"),
    (("[0.5, 2.0]", "{start = 1, stop = 2}"), r"\[grid\] screening\.epipolar\.threshold_px: a range is"),
    (('"walking_xyz"', '"walking_xyzz"'), r"\[\[sequences\]\] #1: unknown synthetic preset 'walking_xyzz'"),
    (("seeds = [0, 1]", "seeds = [0, 1]\nframes = 3"), r"\[\[sequences\]\] #1: unknown keys \['frames'\]"),
    (("seeds = [0, 1]", 'seeds = [0, 1]\npath = "x"'), r"#1: give exactly one of preset"),
    (("seeds = [0, 1]", "seeds = [0, 0]"), r"#1 seeds: a seed appears twice"),
    (('"geometry", "full"', '"geometry", "ful"'), r"\[sweep\] filters: .*unknown filter or stage \['ful'\]"),
    (("loop_closing = false", "loop_closing = false\nworkers = 2"), r"\[sweep\] unknown keys \['workers'\]"),
    (("loop_closing = false", 'loop_closing = false\ndetectors = ["yolo"]'), r"\[sweep\] detectors: unknown detector spec 'yolo'"),
    (("loop_closing = false", 'loop_closing = false\ndetectors = ["onnx:nope.onnx"]'), r"\[sweep\] detectors: detector model .*nope\.onnx not found"),
    (("[grid]", "[gird]"), r"unknown sections \['gird'\]"),
    (("[grid]", '[dask]\nscheduler = "8786"\n[grid]'), r"\[dask\] scheduler: expected an address"),
    (("[grid]", '[config]\n"tracking.min_inlier" = 3\n[grid]'), r"\[config\] config\.tracking\.min_inlier: unknown parameter"),
])
def test_bad_specs_name_the_key(tmp_path, edit, message):
    old, new = edit
    assert old in BASE
    with pytest.raises(ValueError, match=message):
        _spec(tmp_path, BASE.replace(old, new, 1))


def test_bad_files_and_filters_without_detector(tmp_path):
    with pytest.raises(ValueError, match=r"missing\.toml: sweep spec not found"):
        load_spec(tmp_path / "missing.toml")
    with pytest.raises(ValueError, match=r"s\.toml: invalid TOML"):
        _spec(tmp_path, "[sweep\n")
    with pytest.raises(ValueError, match=r"\[\[sequences\]\] must list at least one sequence"):
        _spec(tmp_path, "[sweep]\nfilters = ['none']\n")
    with pytest.raises(ValueError, match=r"#1: .*sequence folder not found"):
        _spec(tmp_path, "[[sequences]]\npath = 'nowhere'\n")
    # a filter judging keypoints from detections with the detector forced to none: named at planning
    spec = _spec(tmp_path, BASE.replace("loop_closing = false", 'loop_closing = false\ndetectors = ["none"]'))
    with pytest.raises(ValueError, match=r"run walking_xyz full .*filter 'full' runs \['semantic', 'depth_ransac'\]"):
        spec.tasks(tmp_path)


def test_run_id_is_the_hash_of_the_inputs(tmp_path):
    spec = _spec(tmp_path)
    task = spec.tasks(tmp_path)[0]
    # an independent hash of what must name the run: sequence, filter, detector, whole config, version
    cfg = config_to_dict(task.config())
    del cfg["detection"]["num_threads"]
    inputs = {
        "sequence": {"kind": "synthetic", "preset": "walking_xyz", "n_frames": 8, "seed": 0,
                     "cache_key": cache_key("walking_xyz", 8, 0)},
        "max_frames": 8, "filters": "geometry", "detector": {"spec": "none"}, "loop_closing": False,
        "config": json.loads(json.dumps(cfg)), "dynslam_lab": __version__,
    }
    expected = hashlib.sha256(json.dumps(inputs, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:16]
    assert task.inputs == inputs
    assert task.run_id == run_id(inputs) == expected
    # the same spec gives the same names; any input changes the name
    assert [t.run_id for t in _spec(tmp_path, BASE, "again.toml").tasks(tmp_path)] == [t.run_id for t in spec.tasks(tmp_path)]
    ids = {t.run_id for t in spec.tasks(tmp_path)}
    assert len(ids) == 8
    changed = _spec(tmp_path, BASE + "\n[config]\n\"orb.n_features\" = 900\n", "orb.toml")  # a parameter not swept
    assert ids.isdisjoint(t.run_id for t in changed.tasks(tmp_path))
    assert run_id({**inputs, "dynslam_lab": "0.0.0"}) != expected
    # the detector's threads set its speed, not its output: not part of the name
    threads = _spec(tmp_path, BASE + "\n[config]\n\"detection.num_threads\" = 3\n", "threads.toml")
    assert [t.run_id for t in threads.tasks(tmp_path)] == [t.run_id for t in spec.tasks(tmp_path)]
    # combinations that are the same run (two detector specs meaning the oracle; any detector for the
    # geometry filter, which uses none) are planned once
    dup = _spec(tmp_path, BASE.replace("loop_closing = false", 'loop_closing = false\ndetectors = ["auto", "oracle"]'), "dup.toml")
    assert [t.run_id for t in dup.tasks(tmp_path)] == [t.run_id for t in spec.tasks(tmp_path)]
    with pytest.raises(ValueError, match="value 0.5 appears twice"):  # 0.5 and 0.50000000000001 name one run
        _spec(tmp_path, BASE.replace("[0.5, 2.0]", "[0.5, 2.0, 0.50000000000001]"), "dup2.toml")


def test_folder_sequence_identity(tmp_path):
    root = synthetic_sequence("walking_xyz", n_frames=8, seed=0)
    text = f"[sweep]\nfilters = ['geometry']\n[[sequences]]\npath = '{root}'\nname = 'wxyz'\n"
    spec = _spec(tmp_path, text)
    (task,) = spec.tasks(tmp_path)
    assert task.sequence.label == "wxyz" and task.sequence.has_truth()
    ident = task.inputs["sequence"]
    assert ident["path"] == str(root) and ident["kind"] == "folder"
    h = hashlib.sha256()
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "camera.json"):
        h.update(name.encode() + b"\0" + (root / name).read_bytes() + b"\0")
    assert ident["listing_sha256"] == h.hexdigest()
