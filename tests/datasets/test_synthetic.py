"""The synthetic renderer: trackable images, exact poses, truthful masks, Kinect-like depth, caching."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from dynslam_lab.camera import CAMERA_PRESETS
from dynslam_lab.datasets import TumSequence, read_file_list
from dynslam_lab.datasets import synthetic as syn
from dynslam_lab.datasets.synthetic import (
    PRESETS,
    SyntheticRenderer,
    camera_pose,
    disparity_step,
    nguyen_sigma,
    render_frame,
    render_sequence,
    synthetic_sequence,
)
from dynslam_lab.datasets.tum import read_moving
from dynslam_lab.geometry.se3 import rotation_angle_deg, se3_inv

N_SEQ = 6  # frames of the short sequences written to disk


@pytest.fixture(scope="module")
def sequences(tmp_path_factory):
    """Short sequences on disk, rendered once for the module."""
    root = tmp_path_factory.mktemp("synthetic")
    out = {}
    for name in ("static_xyz", "static_rpy", "walking_xyz", "sitting_static"):
        out[name] = render_sequence(name, root / name, n_frames=N_SEQ, seed=3, progress=False)
    return out


# ----------------------------------------------------------------------------- presets
def test_presets_mirror_tum_fr3():
    required = {
        "walking_xyz", "walking_static", "walking_rpy", "walking_halfsphere", "sitting_xyz", "sitting_static",
        "sitting_rpy", "sitting_halfsphere", "static_xyz", "static_halfsphere", "static_rpy", "loop",
    }
    assert required <= set(PRESETS)
    for name, p in PRESETS.items():
        assert p.name == name
        assert name.split("_")[-1] in (p.motion, "loop")
    with pytest.raises(ValueError, match="unknown synthetic preset 'walking_fast'"):
        syn.get_preset("walking_fast")
    with pytest.raises(ValueError, match="n_frames"):
        SyntheticRenderer("static_xyz", n_frames=0)
    with pytest.raises(ValueError, match="lens distortion"):
        syn.ScenePreset("x", "static", "xyz", camera="tum_fr1")
    with pytest.raises(ValueError, match="motion"):
        syn.ScenePreset("x", "static", "zigzag")


def test_frame_times_are_30hz_on_the_100hz_grid():
    t = syn.frame_times(31)
    assert t[0] == 0 and abs(t[-1] - 1.0) < 1e-12
    assert np.allclose(np.round(t * 100), t * 100)
    assert set(np.round(np.diff(t) * 1000).astype(int)) == {30, 40}


def test_camera_paths_move_as_described():
    def travel(motion, T=10.0):
        ts = np.linspace(0, T, 301)
        P = np.stack([camera_pose(motion, t, T) for t in ts])
        pos = P[:, :3, 3]
        ang = rotation_angle_deg(np.einsum("ji,njk->nik", P[0, :3, :3], P[:, :3, :3]))
        return np.ptp(pos, axis=0), ang.max()

    ext, ang = travel("static")
    assert ext.max() < 0.01 and ang < 0.5
    ext, ang = travel("xyz")
    assert 0.4 < ext.max() < 1.0 and ang < 5
    ext, ang = travel("rpy")
    assert ext.max() < 0.1 and 15 < ang < 50
    ext, ang = travel("halfsphere")
    assert 0.4 < ext.max() < 1.1
    # the loop closes: last pose = first pose, after going round the room
    T = 20.0
    A, B, M = (camera_pose("loop", t, T) for t in (0.0, T, T / 2))
    assert np.allclose(A, B, atol=1e-9)
    assert np.linalg.norm(A[:3, 3] - M[:3, 3]) > 1.5
    assert rotation_angle_deg(A[:3, :3].T @ M[:3, :3]) > 150


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_camera_stays_in_the_room_and_clear_of_objects(name):
    r = SyntheticRenderer(name, 0)
    for i in range(0, r.n_frames, 60):
        t = r.times[i]
        c = r.pose(t)[:3, 3]
        assert np.all(c > syn.sc.ROOM_MIN + 0.3) and np.all(c < syn.sc.ROOM_MAX - 0.3), f"{name} frame {i}: camera at {c}"
        for k, (lo, hi) in r.scene.instance_bounds(t, margin=0.25).items():
            assert not np.all((c > lo) & (c < hi)), f"{name} frame {i}: camera inside instance {k} {r.instances[k]}"


# ------------------------------------------------------------------------ image content
@pytest.mark.parametrize("preset,frames", [("walking_xyz", (0, 45)), ("sitting_rpy", (20,)), ("static_halfsphere", (60,)), ("loop", (150, 400))])
def test_orb_finds_many_keypoints_spread_over_the_image(preset, frames):
    orb = cv2.ORB_create(1000)
    for i in frames:
        f = render_frame(preset, i)
        gray = cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY)
        kps = orb.detect(gray, None)
        assert len(kps) > 500, f"{preset} frame {i}: only {len(kps)} ORB keypoints"
        uv = np.array([k.pt for k in kps])
        cells = np.histogram2d(uv[:, 1], uv[:, 0], bins=(4, 4), range=((0, 480), (0, 640)))[0]
        assert (cells >= 5).sum() >= 11, f"{preset} frame {i}: keypoints bunched in few cells\n{cells}"


def test_people_cover_a_realistic_share_of_walking_frames():
    r = SyntheticRenderer("walking_xyz", 0)
    shares, cut = [], 0
    for i in range(0, 300, 25):
        f = r.render(i, noise=False)
        people = np.isin(f.instance_mask, [1, 2])
        shares.append(people.mean())
        cut += bool(people[:, 0].any() or people[:, -1].any())
    shares = np.array(shares)
    assert (shares > 0.1).sum() >= 4, shares  # like TUM fr3/walking: people fill much of many frames
    assert shares.max() < 0.6, shares
    assert cut >= 2  # and are sometimes partly out of view


# -------------------------------------------------------------------------- the layout
def test_tum_loader_reads_the_sequence(sequences):
    root = sequences["walking_xyz"]
    seq = TumSequence(root)
    assert len(seq) == N_SEQ
    assert seq.camera == CAMERA_PRESETS["default"]
    r = SyntheticRenderer("walking_xyz", 3, N_SEQ)
    rgb_ts, _ = read_file_list(root / "rgb.txt")
    d_ts, _ = read_file_list(root / "depth.txt")
    dt = np.abs(d_ts - rgb_ts)
    assert np.all((dt > 0.0019) & (dt < 0.0091))  # depth stamps a few ms off: association is exercised
    gt_t, _ = read_file_list(root / "groundtruth.txt")
    assert np.allclose(np.diff(gt_t), 0.01, atol=1e-5)  # 100 Hz
    inst = json.loads((root / "instances.json").read_text())
    assert inst["1"] == {"class": "person", "motion": "walking"} and inst["2"]["motion"] == "walking"
    assert {v["class"] for v in inst.values()} >= {"person", "chair", "dining table", "tv", "book"}
    for i in (0, N_SEQ - 1):
        f = seq[i]
        assert abs(f.timestamp - (syn.T0 + r.times[i])) < 1e-6
        assert np.allclose(f.T_w_c_gt, r.pose(r.times[i]), atol=2e-6)  # exact pose of the colour frame
        assert f.rgb.shape == (480, 640, 3) and f.depth.dtype == np.float32
        assert f.instance_mask is not None and f.instance_mask.max() > 2
        assert set(np.unique(f.instance_mask)) <= {0} | {int(k) for k in inst}
        ok = f.depth > 0
        assert 0.75 < ok.mean() < 0.97
        assert f.depth[ok].min() >= 0.4 and f.depth[ok].max() <= 8.0


def test_depth_png_is_16bit_5000_per_metre(sequences):
    root = sequences["static_xyz"]
    d_ts, rows = read_file_list(root / "depth.txt")
    raw = cv2.imread(str(root / rows[0][0]), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.shape == (480, 640)
    f = SyntheticRenderer("static_xyz", 3, N_SEQ).render(0)
    assert np.array_equal(raw, np.round(f.depth * 5000).astype(np.uint16))


def test_masks_agree_with_depth_and_instances():
    r = SyntheticRenderer("walking_xyz", 0)
    for i in (0, 90):
        f = r.render(i, noise=False)
        bounds = r.scene.instance_bounds(r.times[i], margin=0.01)
        pts = CAMERA_PRESETS["default"].backproject_depth(f.depth_true).reshape(-1, 3)
        Pw = pts @ f.T_w_c[:3, :3].T + f.T_w_c[:3, 3]
        ids = f.instance_mask.ravel()
        for k in np.unique(ids):
            if k == 0:
                continue
            lo, hi = bounds[k]
            inside = np.all((Pw[ids == k] >= lo) & (Pw[ids == k] <= hi), axis=1)
            assert inside.all(), f"frame {i}: {np.sum(~inside)} pixels of instance {k} lie outside it"
        # room pixels (id 0) do not lie inside a person
        for k in (1, 2):
            lo, hi = bounds[k]
            core_lo, core_hi = lo + 0.15, hi - 0.15
            inside = np.all((Pw[ids == 0] > core_lo) & (Pw[ids == 0] < core_hi), axis=1)
            assert inside.sum() == 0
    # every depth discontinuity of the exact depth separates instances or parts; in the noisy
    # depth, discontinuities are holes (no reading) like on a Kinect
    f = r.render(0)
    z = f.depth_true
    jump = np.abs(np.diff(z, axis=1)) > 0.1 * z[:, 1:]
    near_edge = np.zeros_like(z, bool)
    near_edge[:, 1:] |= jump
    near_edge[:, :-1] |= jump
    assert (f.depth[near_edge] == 0).mean() > 0.9
    assert (f.depth[~near_edge] == 0).mean() < 0.15


def test_moving_txt_matches_the_movers(sequences):
    root = sequences["walking_xyz"]
    moving = read_moving(root)
    seq = TumSequence(root)
    assert len(moving) == N_SEQ and sorted(moving) == pytest.approx(list(seq.timestamps))
    assert moving[min(moving)] == set()  # the first frame has no previous frame
    r = SyntheticRenderer("walking_xyz", 3, N_SEQ)
    static_ids = {i for i, (_, m) in r.instances.items() if m == "static"}
    for k in range(1, N_SEQ):
        ts = seq.timestamps[k]
        assert moving[ts] & static_ids == set()
        # independent check: pose the scene at the previous frame's time, view it from this
        # frame's camera; an instance whose pixels change has moved
        now = r.render(k, noise=False)
        before = r.render(k, noise=False, t_scene=r.times[k - 1])
        changed = set()
        for i in set(np.unique(now.instance_mask)) | set(np.unique(before.instance_mask)):
            if i == 0:
                continue
            # compare the depth where both renders see instance i (a static object may be
            # uncovered or hidden by a walker, but its own surface stays put)
            both = (now.instance_mask == i) & (before.instance_mask == i)
            if both.any() and np.abs(now.depth_true[both] - before.depth_true[both]).max() > 1e-4:
                changed.add(int(i))
        assert changed <= moving[ts], f"frame {k}: {changed - moving[ts]} changed but not listed as moving"
        visible_people = {i for i in (1, 2) if (now.instance_mask == i).sum() > 300}
        assert visible_people <= changed
    # nothing moves in a static scene
    for ids in read_moving(sequences["static_xyz"]).values():
        assert ids == set()


def test_sitting_people_move_a_little_and_a_book_is_moved():
    r = SyntheticRenderer("sitting_static", 0)
    book = [i for i, (c, m) in r.instances.items() if m == "moved"]
    assert len(book) == 1 and r.instances[book[0]][0] == "book"
    disp = r.scene.displacement(1.0, 1.03)
    assert 0.001 < disp[1] < 0.03 and 0.001 < disp[2] < 0.03  # gestures: mm to cm per frame
    assert disp[book[0]] == 0.0  # the book rests ...
    assert r.scene.displacement(2.0, 2.03)[book[0]] > 0.001  # ... until it is pushed


# --------------------------------------------------------------------------- geometry
@pytest.mark.parametrize("name", ["static_xyz", "static_rpy"])
def test_pnp_between_consecutive_frames_recovers_the_true_motion(sequences, name):
    seq = TumSequence(sequences[name])
    K = seq.camera.K
    orb = cv2.ORB_create(1000)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    for k in range(N_SEQ - 1):
        f1, f2 = seq[k], seq[k + 1]
        kp1, d1 = orb.detectAndCompute(f1.gray, None)
        kp2, d2 = orb.detectAndCompute(f2.gray, None)
        m = matcher.match(d1, d2)
        uv1 = np.array([kp1[x.queryIdx].pt for x in m])
        uv2 = np.array([kp2[x.trainIdx].pt for x in m])
        z = f1.depth[uv1[:, 1].round().astype(int), uv1[:, 0].round().astype(int)]
        ok = z > 0
        X1 = seq.camera.backproject(uv1[ok], z[ok])
        found, rvec, tvec, inl = cv2.solvePnPRansac(X1, uv2[ok], K, None, reprojectionError=2.0, iterationsCount=200,
                                                    flags=cv2.SOLVEPNP_ITERATIVE)
        assert found and len(inl) > 100
        R, _ = cv2.Rodrigues(rvec)
        T_est = np.eye(4)
        T_est[:3, :3], T_est[:3, 3] = R, tvec.ravel()
        T_true = se3_inv(f2.T_w_c_gt) @ f1.T_w_c_gt  # T_c2_c1
        dt = np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])
        dr = rotation_angle_deg(T_est[:3, :3].T @ T_true[:3, :3])
        assert dt < 0.01 and dr < 0.5, f"{name} {k}->{k + 1}: {dt * 100:.2f} cm, {dr:.3f} deg"


# ------------------------------------------------------------------------ depth model
def test_depth_noise_follows_the_kinect_model():
    res, zs, sig = [], [], []
    for preset, i in (("loop", 0), ("static_xyz", 0)):
        r = SyntheticRenderer(preset, 5)
        f = r.render(i)
        ok = (f.depth > 0) & (f.depth_true > 0)
        cos = np.abs((f.normal * syn.sc.camera_rays(r.camera)).sum(-1)) / np.linalg.norm(syn.sc.camera_rays(r.camera), axis=-1)
        res.append((f.depth - f.depth_true)[ok])
        zs.append(f.depth_true[ok])
        sig.append(nguyen_sigma(f.depth_true[ok], np.arccos(np.clip(cos[ok], 0, 1))))
        # disparity is quantised in 1/8 px: f b / z is a multiple of 1/8 (f = 580 px, the IR camera)
        disp = 580.0 * 0.075 / f.depth[ok].astype(np.float64)
        assert np.abs(disp * 8 - np.round(disp * 8)).max() < 1e-3
        assert f.depth[ok].min() >= 0.4 and f.depth[ok].max() <= 8.0
    res, zs, sig = map(np.concatenate, (res, zs, sig))
    assert zs.max() - zs.min() > 3.0
    for lo, hi in ((0.6, 1.5), (1.5, 2.5), (2.5, 3.5), (3.5, 4.5)):
        sel = (zs >= lo) & (zs < hi)
        assert sel.sum() > 2000
        ratio = res[sel].std() / np.sqrt(np.mean(sig[sel] ** 2))
        assert 0.85 < ratio < 1.15, f"{lo}-{hi} m: std ratio {ratio:.3f}"
        assert abs(res[sel].mean()) < 0.15 * res[sel].std()
    # the quantisation step of the model: 2.9 mm at 1 m, grows with z^2
    assert disparity_step(1.0) == pytest.approx(1.0 * 0.125 / (580 * 0.075))
    assert disparity_step(3.0) == pytest.approx(0.0259, abs=2e-4)  # steps of 2.5-2.8 cm at 3 m in TUM fr3 depth
    assert nguyen_sigma(0.4) == pytest.approx(0.0012)
    assert nguyen_sigma(2.4) == pytest.approx(0.0012 + 0.0019 * 4)


def test_projector_shadow_falls_left_of_foreground_objects():
    r = SyntheticRenderer("walking_xyz", 0)
    f = r.render(0)
    z = f.depth_true
    step = z[:, 1:] - z[:, :-1]  # negative where the right pixel is nearer: a left edge of an object
    rows, cols = np.nonzero(step < -1.0)
    left = f.depth[rows, np.clip(cols - 2, 0, 639)]  # background just left of the edge
    rows, cols = np.nonzero(step > 1.0)  # right edges of objects
    right = f.depth[rows, np.clip(cols + 5, 0, 639)]
    assert (left == 0).mean() > 0.8
    assert (right == 0).mean() < 0.35


def test_projector_shadow_has_the_width_of_the_disparity_jump():
    # a board at 1.5 m in front of a wall at 3 m: background columns hidden from a projector
    # b = 7.5 cm to the right span f b (1/z_near - 1/z_far) = 580 * 0.075 * (1/1.5 - 1/3) = 14.5 px
    z = np.full((60, 200), 3.0, np.float32)
    z[:, 100:150] = 1.5
    params = syn.DepthNoise(dropout_rate=0.0)
    d = syn.kinect_depth(z, np.ones_like(z), 525.0, params, np.random.default_rng(0))
    row = d[30]
    left_holes = 100 - np.flatnonzero(row[:100] > 0).max() - 1  # hole run left of the board's edge
    assert 14 <= left_holes <= 16  # pixels 86..99 (centres inside the 14.5 px shadow), edge margin inside it
    right_holes = np.flatnonzero(row[150:] > 0).min()  # only the edge margin on the lit side
    assert right_holes <= 2
    assert np.all(d[:, 100 + 2 : 150 - 2] > 0)  # the board itself is measured
    with_shadow_off = syn.kinect_depth(z, np.ones_like(z), 525.0, syn.DepthNoise(dropout_rate=0.0, shadow=False),
                                       np.random.default_rng(0))
    assert (with_shadow_off[30, :100] == 0).sum() <= 2


def test_rendering_is_deterministic_given_the_seed():
    a = render_frame("walking_rpy", 5, seed=1)
    b = render_frame("walking_rpy", 5, seed=1)
    c = render_frame("walking_rpy", 5, seed=2)
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth)
    assert np.array_equal(a.instance_mask, b.instance_mask)
    assert not np.array_equal(a.depth, c.depth)


# ------------------------------------------------------------------------------ cache
def test_cache_renders_once_and_never_leaves_half_sequences(tmp_path, monkeypatch):
    p1 = synthetic_sequence("static_rpy", n_frames=2, seed=0, cache_dir=tmp_path)
    assert (p1 / "synthetic.json").is_file() and len(list((p1 / "rgb").iterdir())) == 2

    def boom(*args, **kwargs):
        raise RuntimeError("must not render again")

    monkeypatch.setattr(syn, "render_sequence", boom)
    assert synthetic_sequence("static_rpy", n_frames=2, seed=0, cache_dir=tmp_path) == p1
    # another length is another key: the render is attempted, fails, and leaves nothing behind
    with pytest.raises(RuntimeError, match="must not render again"):
        synthetic_sequence("static_rpy", n_frames=3, seed=0, cache_dir=tmp_path)
    assert sorted(x.name for x in tmp_path.iterdir()) == [p1.name]
    assert syn.cache_key("static_rpy", 2, 0) != syn.cache_key("static_rpy", 2, 1)


def test_cache_dir_from_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("DYNSLAM_CACHE", str(tmp_path))
    assert syn._cache_root(None) == tmp_path / "synthetic"


def test_read_moving_reports_bad_lines(tmp_path):
    (tmp_path / "moving.txt").write_text("# c\n1.0 1 2\n2.0\n3.0 x\n")
    with pytest.raises(ValueError, match=r"moving.txt:4"):
        read_moving(tmp_path)
    (tmp_path / "moving.txt").write_text("1.0 1 2\n2.0\n")
    assert read_moving(tmp_path) == {1.0: {1, 2}, 2.0: set()}
    with pytest.raises(FileNotFoundError, match="moving.txt"):
        read_moving(tmp_path / "nowhere")


# -------------------------------------------------------------------------------- CLI
def test_cli_lists_and_renders(tmp_path, capsys):
    from dynslam_lab.cli import main

    assert main(["synth", "--list"]) == 0
    out = capsys.readouterr().out
    assert "walking_xyz" in out and "loop" in out
    assert main(["synth", "static_rpy", str(tmp_path / "s"), "--frames", "2", "--quiet"]) == 0
    assert len(TumSequence(tmp_path / "s")) == 2
    assert main(["synth", "no_such_preset", str(tmp_path / "x")]) == 1
    assert "unknown preset" in capsys.readouterr().err


def test_cli_synth_never_overwrites_a_users_files(tmp_path, capsys):
    """A folder holding someone's rgb.txt, or a file, is refused and left as it was; --force replaces
    only a sequence synth itself wrote."""
    from dynslam_lab.cli import main

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "rgb.txt").write_text("my own list\n")
    assert main(["synth", "static_rpy", str(mine), "--frames", "2", "--quiet"]) == 2
    assert (mine / "rgb.txt").read_text() == "my own list\n" and sorted(p.name for p in mine.iterdir()) == ["rgb.txt"]
    assert main(["synth", "static_rpy", str(mine), "--frames", "2", "--quiet", "--force"]) == 2
    assert (mine / "rgb.txt").read_text() == "my own list\n"
    a_file = tmp_path / "file"
    a_file.write_text("x")
    assert main(["synth", "static_rpy", str(a_file), "--frames", "2", "--quiet"]) == 2
    assert a_file.read_text() == "x"
    out = tmp_path / "seq"
    assert main(["synth", "static_rpy", str(out), "--frames", "2", "--quiet"]) == 0
    assert main(["synth", "static_rpy", str(out), "--frames", "3", "--quiet"]) == 2
    assert main(["synth", "static_rpy", str(out), "--frames", "3", "--quiet", "--force"]) == 0
    assert len(TumSequence(out)) == 3
    capsys.readouterr()


def test_truth_views_rebuild_the_renderer_from_the_sequence():
    """truth_views: the stored frame, its true pose (ground truth file), the exact depth of a fresh
    renderer, and the mask of the instances instances.json calls moving."""
    from dynslam_lab.datasets.synthetic import SyntheticRenderer, moving_instances, synthetic_sequence, truth_views
    from dynslam_lab.datasets.tum import TumSequence

    root = synthetic_sequence("walking_xyz", 30, 0)
    seq = TumSequence(root)
    movers = moving_instances(root)
    assert movers and all(seq.instance_classes[m] == "person" for m in movers)
    views = truth_views(root, [4, 20])
    rf = SyntheticRenderer("walking_xyz", 0, 30).render(20, noise=False)
    f, T, mask = views[1]
    assert f.index == 20
    np.testing.assert_array_equal(f.depth, rf.depth_true)
    np.testing.assert_allclose(T, seq.gt_pose(20), atol=1e-5)
    np.testing.assert_array_equal(mask, np.isin(seq[20].instance_mask, movers))
