"""Resumable download against a local HTTP server: full, resumed, checksum, offline."""

from __future__ import annotations

import hashlib
import socket

import numpy as np
import pytest

from data_fetch.download import ChecksumError, DownloadError, download, sha256_file


def _payload(n=300_000, seed=0) -> bytes:
    return np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()


def test_full_download(http_server, tmp_path):
    data = _payload()
    http_server.files["a.bin"] = data
    sha = hashlib.sha256(data).hexdigest()
    res = download(http_server.url + "a.bin", tmp_path / "a.bin", size=len(data), sha256=sha, progress=False)
    assert res.path.read_bytes() == data
    assert res.sha256 == sha == sha256_file(res.path)
    assert res.resumed_from == 0 and res.size == len(data)
    assert not (tmp_path / "a.bin.part").exists()
    # A second call finds the verified file and does not download again.
    n_req = len(http_server.requests)
    again = download(http_server.url + "a.bin", tmp_path / "a.bin", sha256=sha, progress=False)
    assert again.sha256 == sha and len(http_server.requests) == n_req


def test_resume_after_interruption(http_server, tmp_path):
    data = _payload(seed=1)
    http_server.files["b.bin"] = data
    http_server.cut_after["b.bin"] = 123_457
    dest = tmp_path / "sub" / "b.bin"
    with pytest.raises(DownloadError, match="interrupted.*run again to resume"):
        download(http_server.url + "b.bin", dest, progress=False)
    part = dest.with_name("b.bin.part")
    assert part.stat().st_size == 123_457 and not dest.exists()
    res = download(http_server.url + "b.bin", dest, sha256=hashlib.sha256(data).hexdigest(), progress=True)
    assert res.resumed_from == 123_457
    assert http_server.requests[-1] == ("b.bin", "bytes=123457-")
    assert dest.read_bytes() == data and not part.exists()


def test_server_without_range_support_restarts(http_server, tmp_path):
    data = _payload(seed=2)
    http_server.files["c.bin"] = data
    http_server.ignore_range = True
    dest = tmp_path / "c.bin"
    dest.with_name("c.bin.part").write_bytes(b"garbage that is not the start of the file")
    res = download(http_server.url + "c.bin", dest, progress=False)
    assert res.resumed_from == 0 and dest.read_bytes() == data


def test_complete_part_file_is_416(http_server, tmp_path):
    data = _payload(1000, seed=3)
    http_server.files["d.bin"] = data
    dest = tmp_path / "d.bin"
    dest.with_name("d.bin.part").write_bytes(data)
    res = download(http_server.url + "d.bin", dest, size=len(data), progress=False)
    assert dest.read_bytes() == data and res.size == len(data)


def test_checksum_mismatch_removes_file(http_server, tmp_path):
    http_server.files["e.bin"] = _payload(5000, seed=4)
    dest = tmp_path / "e.bin"
    with pytest.raises(ChecksumError, match="SHA-256 mismatch"):
        download(http_server.url + "e.bin", dest, sha256="0" * 64, progress=False)
    assert not dest.exists() and not dest.with_name("e.bin.part").exists()
    with pytest.raises(ChecksumError, match="catalog expects 10"):
        download(http_server.url + "e.bin", dest, size=10, progress=False)


def test_http_404(http_server, tmp_path):
    with pytest.raises(DownloadError, match="HTTP 404"):
        download(http_server.url + "missing.bin", tmp_path / "m.bin", progress=False)


def test_offline_message(tmp_path):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens on this port now: connection refused, like being offline
    with pytest.raises(DownloadError, match=rf"cannot reach 127\.0\.0\.1:{port}: are you offline\?"):
        download(f"http://127.0.0.1:{port}/x.tgz", tmp_path / "x.tgz", progress=False)


def test_resume_through_redirect(http_server, tmp_path):
    """GitHub release assets answer with a 302 to a storage host: Range must survive it."""
    data = _payload(50_000, seed=5)
    http_server.files["storage/yolox_nano.onnx"] = data
    http_server.redirects["releases/download/yolox_nano.onnx"] = "/storage/yolox_nano.onnx"
    http_server.cut_after["storage/yolox_nano.onnx"] = 20_000
    url = http_server.url + "releases/download/yolox_nano.onnx"
    with pytest.raises(DownloadError, match="interrupted"):
        download(url, tmp_path / "m.onnx", progress=False)
    res = download(url, tmp_path / "m.onnx", progress=False)
    assert res.resumed_from == 20_000 and (tmp_path / "m.onnx").read_bytes() == data
    assert http_server.requests[-1] == ("storage/yolox_nano.onnx", "bytes=20000-")
