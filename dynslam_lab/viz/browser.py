"""Screenshots of the viewer from headless Chromium, for tests and benchmarks.

Chromium runs with ``--headless`` and software WebGL (SwiftShader: ``--use-gl=swiftshader
--enable-unsafe-swiftshader``), which is what makes viser's WebGL canvas render on a
machine without a GPU. It is driven through the Chrome DevTools Protocol (a JSON websocket:
``Page.captureScreenshot``), so a caller can poll screenshots until the scene is drawn
instead of guessing a fixed delay.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["find_chromium", "HeadlessChromium", "colour_pixels", "outside_overlays"]

CHROMIUM_FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--use-gl=swiftshader", "--enable-unsafe-swiftshader", "--hide-scrollbars",
)


def outside_overlays(mask: np.ndarray) -> np.ndarray:
    """``mask`` (H, W) of a viewer screenshot with viser's own overlays cleared (in place): the GUI
    panel (top right, 360 x 320 px) and the "software WebGL rendering" notice (top left, 320 x 160 px)."""
    mask[:320, -360:] = False
    mask[:160, :320] = False
    return mask


def colour_pixels(img: np.ndarray, rgb, tol: int) -> np.ndarray:
    """Pixels of a viewer screenshot within ``tol`` (max over channels) of colour ``rgb``,
    outside viser's overlays. ``(H, W)`` bool."""
    return outside_overlays(np.abs(img.astype(int) - np.asarray(rgb, int)).max(axis=2) < tol)


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _running_in_group(pgid: int) -> bool:
    """Whether a process of group ``pgid`` still runs (zombies, which write nothing, do not count).

    Reads ``/proc`` (Linux); elsewhere asks the kernel with signal 0, which counts zombies too.
    """
    proc = Path("/proc")
    if not proc.is_dir():
        try:
            os.killpg(pgid, 0)
            return True
        except ProcessLookupError:
            return False
    for stat in proc.glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()  # after "pid (comm)": state ppid pgrp ...
        except (OSError, IndexError):
            continue  # the process ended while we looked
        if int(fields[2]) == pgid and fields[0] != "Z":
            return True
    return False


class HeadlessChromium:
    """A headless Chromium with DevTools on a loopback port; use as a context manager.

    Parameters
    ----------
    width, height : window size in pixels.
    executable : Chromium path (default :func:`find_chromium`).
    """

    def __init__(self, width: int = 1000, height: int = 700, executable: str | None = None) -> None:
        from .viser_scene import free_port

        exe = executable or find_chromium()
        if exe is None:
            raise FileNotFoundError("Chromium not found (install the 'chromium' package)")
        self.width, self.height = int(width), int(height)
        self._profile = tempfile.TemporaryDirectory(prefix="dynslam_chromium_")
        self.port = free_port()
        self.proc = subprocess.Popen(
            [exe, *CHROMIUM_FLAGS, f"--user-data-dir={self._profile.name}", f"--remote-debugging-port={self.port}",
             "--remote-debugging-address=127.0.0.1", f"--window-size={self.width},{self.height}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True,  # its own process group: close() stops the helpers it starts too
        )
        self._wait_devtools()

    def _wait_devtools(self, timeout: float = 30.0) -> None:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if self.proc.poll() is not None:
                raise RuntimeError(f"Chromium exited with code {self.proc.returncode} at start")
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/json/version", timeout=2):
                    return
            except OSError:
                time.sleep(0.1)
        raise RuntimeError(f"Chromium DevTools on port {self.port} did not answer within {timeout} s")

    def __enter__(self) -> "HeadlessChromium":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the browser and every process of its group, then delete its profile.

        Chromium's helper processes (GPU, renderer, crash handler) can outlive the main one for a
        moment and still write into the profile; deleting it before they are gone fails with
        "Directory not empty". So the whole process group is stopped and waited for first.
        """
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=20)
        pgid = self.proc.pid  # the group's id (start_new_session)
        for sig in (signal.SIGTERM, signal.SIGKILL):
            if not _running_in_group(pgid):
                break
            try:
                os.killpg(pgid, sig)
            except ProcessLookupError:
                break
            t0 = time.monotonic()
            while _running_in_group(pgid) and time.monotonic() - t0 < 5.0:
                time.sleep(0.05)
        self._profile.cleanup()

    def poll_screenshots(self, url: str, done: Callable[[np.ndarray], bool], timeout: float = 60.0,
                         interval: float = 0.2) -> tuple[np.ndarray | None, int]:
        """Open ``url`` in a new tab and take screenshots until ``done(rgb)`` is true.

        Returns ``(rgb (H, W, 3) uint8 of the last screenshot or None, screenshots taken)``;
        the last screenshot is the one that satisfied ``done`` unless ``timeout`` (s) ran out.
        """
        import cv2
        from websockets.sync.client import connect

        req = urllib.request.Request(f"http://127.0.0.1:{self.port}/json/new?{url}", method="PUT")
        with urllib.request.urlopen(req, timeout=10) as r:
            ws_url = json.load(r)["webSocketDebuggerUrl"]
        msg_id = 0
        img = None
        n = 0
        with connect(ws_url, max_size=None, open_timeout=10) as ws:

            def call(method: str, **params) -> dict:
                nonlocal msg_id
                msg_id += 1
                ws.send(json.dumps({"id": msg_id, "method": method, "params": params}))
                while True:
                    reply = json.loads(ws.recv(timeout=timeout))
                    if reply.get("id") == msg_id:
                        if "error" in reply:
                            raise RuntimeError(f"DevTools {method}: {reply['error']}")
                        return reply.get("result", {})

            # The window size includes no browser UI in headless mode, but pin the page's viewport anyway.
            call("Emulation.setDeviceMetricsOverride", width=self.width, height=self.height, deviceScaleFactor=1,
                 mobile=False)
            t0 = time.monotonic()
            while time.monotonic() - t0 < timeout:
                png = base64.b64decode(call("Page.captureScreenshot", format="png")["data"])
                n += 1
                img = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
                if done(img):
                    break
                time.sleep(interval)
        return img, n

    def save(self, img: np.ndarray, path: str | Path) -> Path:
        """Write an RGB screenshot as PNG."""
        import cv2

        cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        return Path(path)
