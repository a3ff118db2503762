"""End to end: ``dynslam view`` serves the scene, headless Chromium renders it (WebGL via
SwiftShader), and the screenshot shows the estimated trajectory where the initial camera
sees it (projection computed here from the run's data, independently of the browser)."""

from __future__ import annotations

import re
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.fixtures.browser import HeadlessChromium, colour_pixels, find_chromium
from tests.fixtures.demo_run import write_demo_run
from dynslam_lab.viz.viser_scene import COLORS, free_port, initial_view, load_run

WIN_W, WIN_H = 1000, 700
VISER_DEFAULT_FOV_Y = np.deg2rad(75.0)  # viser's initial camera field of view (vertical)


def _red_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of the estimate's colour, outside the GUI panel and the software-WebGL notice."""
    return colour_pixels(img, COLORS["estimate"], 60)


def _expected_pixels(run) -> np.ndarray:
    """Project the estimated path with the viewer's initial camera (look-at, 75 deg fov)."""
    eye, target, up = initial_view(run)
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R_c_w = np.stack([right, down, fwd])
    f = (WIN_H / 2) / np.tan(VISER_DEFAULT_FOV_Y / 2)
    X = (run.trajectory.positions - eye) @ R_c_w.T
    return np.stack([f * X[:, 0] / X[:, 2] + WIN_W / 2, f * X[:, 1] / X[:, 2] + WIN_H / 2], axis=1)


@pytest.mark.slow
def test_dynslam_view_renders_the_trajectory(tmp_path):
    if find_chromium() is None:
        pytest.skip("headless Chromium not installed (Debian package 'chromium'; .ci/run installs it)")
    outdir = write_demo_run(tmp_path / "run", n_frames=150, keyframe_every=10, n_map_points=300, n_dense_points=3000)
    (outdir / "dynamic_points.npz").unlink()  # keep the view of the path unobstructed
    port = free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "dynslam_lab", "view", str(outdir), "--port", str(port), "--timeout", "120"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    counts = []

    def drawn(img):  # the path is on screen and the picture has settled (same count twice)
        counts.append(int(_red_mask(img).sum()))
        return len(counts) >= 2 and counts[-1] > 200 and abs(counts[-1] - counts[-2]) <= 0.02 * counts[-1]

    try:
        t0 = time.monotonic()
        lines = []
        while time.monotonic() - t0 < 60:
            line = server.stdout.readline()
            if not line and server.poll() is not None:
                break
            lines.append(line)
            if "open http://" in line:
                break
        urls = [m.group(0) for ln in lines for m in [re.search(r"http://127\.0\.0\.1:\d+/", ln)] if m]
        assert urls, "dynslam view did not report a loopback address:\n" + "".join(lines)
        with HeadlessChromium(WIN_W, WIN_H) as browser:
            img, n_shots = browser.poll_screenshots(urls[-1], drawn, timeout=90)
            browser.save(img, tmp_path / "shot.png")
    finally:
        server.terminate()
        server.wait(timeout=20)
        server.stdout.close()
    assert img is not None and img.shape[:2] == (WIN_H, WIN_W)
    ys, xs = np.nonzero(_red_mask(img))
    assert len(xs) > 200, f"only {len(xs)} trajectory-coloured pixels after {n_shots} screenshots: the scene did not render"
    expected = _expected_pixels(load_run(outdir))
    # distance of every red pixel to the projected path (dense resampling of the polyline)
    t = np.linspace(0, 1, 20)[:, None, None]
    dense = (expected[:-1] * (1 - t) + expected[1:] * t).reshape(-1, 2)
    d = np.min(np.hypot(xs[:, None] - dense[None, :, 0], ys[:, None] - dense[None, :, 1]), axis=1)
    print(f"{n_shots} screenshots; red pixels: {len(xs)}, distance to projected path: median {np.median(d):.1f} px, "
          f"90% {np.percentile(d, 90):.1f} px")
    assert np.mean(d < 15) > 0.9, f"red pixels away from the projected path: median {np.median(d):.1f} px"
    # and the visible path is drawn: most projected samples have a red pixel nearby
    vis = (dense[:, 0] > 5) & (dense[:, 0] < WIN_W - 365) & (dense[:, 1] > 165) & (dense[:, 1] < WIN_H - 5)
    samples = dense[vis][::10]
    near = (np.hypot(xs[None] - samples[:, :1], ys[None] - samples[:, 1:]) < 6).any(axis=1)
    print(f"projected samples with a red pixel within 6 px: {near.mean():.2f}")
    assert vis.sum() > 50 and near.mean() > 0.5


def _orange_mask(img: np.ndarray) -> np.ndarray:
    return colour_pixels(img, COLORS["keyframe"], 50)


@pytest.mark.slow
def test_browser_connection_streams_the_later_layers(tmp_path):
    """The first picture has the trajectories but no keyframes; the browser's connection starts
    the stream, and the keyframe frustums (orange) appear in a later picture without any call
    from the test."""
    if find_chromium() is None:
        pytest.skip("headless Chromium not installed (Debian package 'chromium'; .ci/run installs it)")
    from dynslam_lab.viz.viser_scene import SceneConfig, start_viewer

    outdir = write_demo_run(tmp_path / "run", n_frames=150, keyframe_every=10, n_map_points=300, n_dense_points=3000)
    server, h = start_viewer(outdir, config=SceneConfig(defer_layers=3.0, defer_dense=0.5))
    try:
        assert "keyframes" not in h.nodes
        with HeadlessChromium(WIN_W, WIN_H) as browser:
            shots = []

            def keyframes_drawn(img):
                shots.append((int(_red_mask(img).sum()), int(_orange_mask(img).sum())))
                return shots[-1][1] > 300

            img, n = browser.poll_screenshots(f"http://127.0.0.1:{server.get_port()}/", keyframes_drawn, timeout=90)
        red_first = [i for i, (r, _) in enumerate(shots) if r > 200]
        print("screenshots (red, orange pixels):", shots)
        assert red_first, "the trajectory never appeared"
        assert shots[red_first[0]][1] < 50, "keyframes were drawn in the first picture: they should come later"
        assert shots[-1][1] > 300, "the keyframes never arrived: the browser's connection did not start the stream"
        assert h.wait_complete(30) and "dense" in h.nodes and h.errors == []
    finally:
        h.close()
        server.stop()
