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


def _leftovers(dest):
    return sorted(p.name for p in dest.parent.iterdir() if p.name != dest.name)


def _interrupt(http_server, name, data, dest, cut):
    """Serve ``data`` as ``name`` and let a download to ``dest`` be cut after ``cut`` bytes."""
    http_server.files[name] = data
    http_server.cut_after[name] = cut
    with pytest.raises(DownloadError, match="interrupted.*run again to resume"):
        download(http_server.url + name, dest, progress=False)
    assert dest.with_name(dest.name + ".part").is_file() and not dest.exists()


def test_resume_restarts_when_the_file_changed_on_the_server(http_server, tmp_path):
    """If-Range carries the ETag of the partial copy; a changed file comes back whole (200)."""
    old, new = _payload(80_000, seed=6), _payload(80_000, seed=7)
    dest = tmp_path / "f.bin"
    _interrupt(http_server, "f.bin", old, dest, 30_000)
    http_server.files["f.bin"] = new
    res = download(http_server.url + "f.bin", dest, progress=False)
    assert http_server.requests[-1] == ("f.bin", "bytes=30000-")
    assert http_server.if_ranges[-1] == f'"{hashlib.sha256(old).hexdigest()[:16]}"'
    assert res.resumed_from == 0 and dest.read_bytes() == new
    assert _leftovers(dest) == []  # no .part, no .part.json


def test_server_ignoring_if_range_is_caught_by_the_etag(http_server, tmp_path):
    old, new = _payload(80_000, seed=8), _payload(80_000, seed=9)
    http_server.ignore_if_range = True
    dest = tmp_path / "g.bin"
    _interrupt(http_server, "g.bin", old, dest, 30_000)
    http_server.files["g.bin"] = new
    n = len(http_server.requests)
    res = download(http_server.url + "g.bin", dest, progress=False)
    # The 206 carries the new file's ETag: the part is dropped and the file fetched afresh.
    assert http_server.requests[n:] == [("g.bin", "bytes=30000-"), ("g.bin", None)]
    assert res.resumed_from == 0 and dest.read_bytes() == new


def test_without_validators_a_changed_size_restarts(http_server, tmp_path):
    """A server with no ETag or Last-Modified (so no If-Range): the total size tells the change."""
    http_server.send_etag = False
    old = _payload(80_000, seed=10)
    dest = tmp_path / "h.bin"
    _interrupt(http_server, "h.bin", old, dest, 30_000)
    longer = _payload(90_000, seed=11)
    http_server.files["h.bin"] = longer
    res = download(http_server.url + "h.bin", dest, progress=False)
    assert res.resumed_from == 0 and dest.read_bytes() == longer
    # A file now shorter than the part: 416 with another total, restart again.
    dest2 = tmp_path / "h2.bin"
    _interrupt(http_server, "h.bin", old, dest2, 70_000)
    short = _payload(50_000, seed=12)
    http_server.files["h.bin"] = short
    n = len(http_server.requests)
    res = download(http_server.url + "h.bin", dest2, progress=False)
    assert http_server.requests[n:] == [("h.bin", "bytes=70000-"), ("h.bin", None)]
    assert res.resumed_from == 0 and dest2.read_bytes() == short and _leftovers(dest2) == ["h.bin"]


def test_part_of_another_url_or_longer_than_the_file_is_discarded(http_server, tmp_path):
    a, b = _payload(40_000, seed=13), _payload(40_000, seed=14)
    http_server.files["b.bin"] = b
    dest = tmp_path / "x.bin"
    _interrupt(http_server, "a.bin", a, dest, 10_000)
    res = download(http_server.url + "b.bin", dest, progress=False)  # same file name, other URL
    assert http_server.requests[-1] == ("b.bin", None)
    assert res.resumed_from == 0 and dest.read_bytes() == b
    # A part file with no record (an older downloader) longer than the file: 416, then restart.
    dest2 = tmp_path / "y.bin"
    dest2.with_name("y.bin.part").write_bytes(b"\0" * 50_000)
    res = download(http_server.url + "a.bin", dest2, progress=False)
    assert res.resumed_from == 0 and dest2.read_bytes() == a


def test_two_interruptions_then_complete(http_server, tmp_path):
    data = _payload(200_000, seed=15)
    dest = tmp_path / "i.bin"
    for cut in (50_000, 60_000):
        _interrupt(http_server, "i.bin", data, dest, cut)
    assert dest.with_name("i.bin.part").stat().st_size == 110_000
    res = download(http_server.url + "i.bin", dest, sha256=hashlib.sha256(data).hexdigest(), progress=False)
    assert res.resumed_from == 110_000 and dest.read_bytes() == data and _leftovers(dest) == []


def test_existing_file_is_verified_not_trusted(http_server, tmp_path):
    data = _payload(5000, seed=16)
    http_server.files["j.bin"] = data
    sha = hashlib.sha256(data).hexdigest()
    dest = tmp_path / "j.bin"
    assert download(http_server.url + "j.bin", dest, progress=False).existing is False
    again = download(http_server.url + "j.bin", dest, sha256=sha, progress=False)
    assert again.existing and again.sha256 == sha
    dest.write_bytes(data[:-1] + bytes([data[-1] ^ 1]))  # damaged on disk, same size
    n = len(http_server.requests)
    with pytest.raises(ChecksumError, match=rf"SHA-256 mismatch.*removed .*j\.bin"):
        download(http_server.url + "j.bin", dest, sha256=sha, progress=False)
    assert not dest.exists() and len(http_server.requests) == n
