"""Catalog contents, fetch() end to end against a local server (interrupted, corrupt, re-run
against the manifest), and the command line."""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import tarfile
import zipfile

import numpy as np
import pytest

from data_fetch import (
    BASE_URLS,
    CATALOG,
    CatalogError,
    ChecksumError,
    CorruptArchiveError,
    UnsafeArchiveError,
    DownloadError,
    fetch,
    get_entry,
    read_manifest,
    url_for,
)
from data_fetch.__main__ import main


def test_catalog_covers_the_papers_sequences():
    for s in ("walking_xyz", "walking_static", "walking_halfsphere", "walking_rpy",
              "sitting_xyz", "sitting_static", "sitting_halfsphere", "sitting_rpy"):
        assert f"fr3_{s}" in CATALOG
    for name in ("fr1_xyz", "fr1_rpy", "fr1_desk", "fr1_desk2", "fr1_room", "fr1_360", "fr1_floor",
                 "fr2_xyz", "fr2_rpy", "fr2_desk", "fr2_desk_with_person", "fr2_pioneer_360"):
        assert name in CATALOG
    bonn = [e for e in CATALOG.values() if e.kind == "bonn"]
    assert len(bonn) >= 24
    assert url_for(CATALOG["fr3_walking_xyz"]) == (
        "https://cvg.cit.tum.de/rgbd/dataset/freiburg3/rgbd_dataset_freiburg3_walking_xyz.tgz"
    )
    assert url_for(CATALOG["bonn_balloon"]) == (
        "https://www.ipb.uni-bonn.de/html/projects/rgbd_dynamic2019/rgbd_bonn_balloon.zip"
    )
    assert url_for(CATALOG["yolox_nano"]) == (
        "https://github.com/Megvii-BaseDetection/YOLOX/releases/download/0.1.1rc0/yolox_nano.onnx"
    )
    assert "yolo export model=yolov8n-seg.pt format=onnx" in CATALOG["yolov8n_seg"].note
    assert "AGPL-3.0" in CATALOG["yolov8n_seg"].licence
    with pytest.raises(CatalogError, match="did you mean fr3_walking_xyz"):
        get_entry("fr3_walkng_xyz")


def _tgz_bytes(members=None) -> bytes:
    """A .tgz of ``(name, bytes)`` members; by default a ground truth and an rgb.txt."""
    if members is None:
        members = (("rgbd_dataset_freiburg3_walking_xyz/groundtruth.txt", b"# gt\n"),
                   ("rgbd_dataset_freiburg3_walking_xyz/rgb.txt", b"# rgb\n"))
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tf:
        for name, data in members:
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
    return buf.getvalue()


def test_fetch_tum_archive_and_manifest(http_server, tmp_path, monkeypatch):
    monkeypatch.setitem(BASE_URLS, "tum", http_server.url)
    data = _tgz_bytes()
    http_server.files["freiburg3/rgbd_dataset_freiburg3_walking_xyz.tgz"] = data
    res = fetch("fr3_walking_xyz", tmp_path, progress=False)
    assert res.sha256 == hashlib.sha256(data).hexdigest()
    assert (tmp_path / "rgbd_dataset_freiburg3_walking_xyz" / "groundtruth.txt").read_bytes() == b"# gt\n"
    assert len(res.extracted) == 2
    m = read_manifest(tmp_path)["fr3_walking_xyz"]
    assert m["sha256"] == res.sha256 and m["size"] == len(data) and m["sha256_source"] == "recorded at fetch"

    # The server's file changes: the digest recorded in the manifest catches it.
    (tmp_path / "downloads" / "rgbd_dataset_freiburg3_walking_xyz.tgz").unlink()
    http_server.files["freiburg3/rgbd_dataset_freiburg3_walking_xyz.tgz"] = data[:20] + bytes([data[20] ^ 0xFF]) + data[21:]
    with pytest.raises(ChecksumError, match="recorded in .*manifest.json"):
        fetch("fr3_walking_xyz", tmp_path, progress=False)


def test_fetch_with_catalog_checksum(http_server, tmp_path, monkeypatch):
    monkeypatch.setitem(BASE_URLS, "yolox", http_server.url)
    model = b"onnx bytes" * 1000
    http_server.files["yolox_nano.onnx"] = model
    good = dataclasses.replace(CATALOG["yolox_nano"], sha256=hashlib.sha256(model).hexdigest(), size=len(model))
    monkeypatch.setitem(CATALOG, "yolox_nano", good)
    res = fetch("yolox_nano", tmp_path, progress=False)
    assert (tmp_path / "yolox_nano.onnx").read_bytes() == model and res.extracted == []
    assert read_manifest(tmp_path)["yolox_nano"]["sha256_source"] == "catalog"

    bad = dataclasses.replace(good, sha256="f" * 64)
    monkeypatch.setitem(CATALOG, "yolox_nano", bad)
    (tmp_path / "yolox_nano.onnx").unlink()
    with pytest.raises(ChecksumError, match="SHA-256 mismatch"):
        fetch("yolox_nano", tmp_path, progress=False)
    assert not (tmp_path / "yolox_nano.onnx").exists()


def test_cli_get_bonn_zip_and_export(http_server, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(BASE_URLS, "bonn", http_server.url)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("rgbd_bonn_crowd/groundtruth.txt", "1 0 0 0 0 0 0 1\n")
    http_server.files["rgbd_bonn_crowd.zip"] = buf.getvalue()
    assert main(["get", "bonn_crowd", "--dest", str(tmp_path), "--quiet"]) == 0
    assert "extracted 1 files" in capsys.readouterr().out
    assert (tmp_path / "rgbd_bonn_crowd" / "groundtruth.txt").is_file()
    assert json.loads((tmp_path / "manifest.json").read_text())["bonn_crowd"]["extracted_files"] == 1

    assert main(["get", "yolov8n_seg", "--dest", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "yolo export model=yolov8n-seg.pt format=onnx" in out and "AGPL-3.0" in out
    assert not (tmp_path / "yolov8n-seg.onnx").exists()


def test_cli_errors(tmp_path, monkeypatch, capsys):
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    monkeypatch.setitem(BASE_URLS, "tum", f"http://127.0.0.1:{port}/")
    assert main(["get", "fr1_xyz", "--dest", str(tmp_path), "--quiet"]) == 1
    assert "are you offline?" in capsys.readouterr().err
    assert main(["get", "nonsense"]) == 1
    assert "not in the catalog" in capsys.readouterr().err
    assert main(["list", "--kind", "model"]) == 0
    assert "yolox_tiny" in capsys.readouterr().out
    assert main(["info", "bonn_crowd3"]) == 0
    assert "rgbd_bonn_crowd3.zip" in capsys.readouterr().out


TGZ = "freiburg3/rgbd_dataset_freiburg3_walking_xyz.tgz"
ARCHIVE = "downloads/rgbd_dataset_freiburg3_walking_xyz.tgz"


def _big_tgz(seed=0) -> bytes:
    """A sequence-like .tgz of incompressible members (~120 kB), so transfers can be cut."""
    rng = np.random.default_rng(seed)
    return _tgz_bytes([(f"rgbd_dataset_freiburg3_walking_xyz/rgb/{i}.png",
                        rng.integers(0, 256, 40_000, dtype=np.uint8).tobytes()) for i in range(3)])


def test_rerun_verifies_the_archive_against_the_manifest(http_server, tmp_path, monkeypatch):
    monkeypatch.setitem(BASE_URLS, "tum", http_server.url)
    data = _big_tgz()
    http_server.files[TGZ] = data
    first = fetch("fr3_walking_xyz", tmp_path, progress=False)
    n = len(http_server.requests)
    again = fetch("fr3_walking_xyz", tmp_path, progress=False)
    assert len(http_server.requests) == n  # nothing downloaded again
    assert again.sha256 == first.sha256 == hashlib.sha256(data).hexdigest()
    assert "already downloaded; matches" in again.message and "manifest.json" in again.message
    assert read_manifest(tmp_path)["fr3_walking_xyz"]["sha256_source"] == "manifest"

    # The archive is damaged on disk (same size): the re-run names it and the manifest, removes it.
    archive = tmp_path / ARCHIVE
    archive.write_bytes(data[:1000] + bytes([data[1000] ^ 1]) + data[1001:])
    with pytest.raises(ChecksumError, match=r"SHA-256 mismatch.*walking_xyz\.tgz.*manifest\.json"):
        fetch("fr3_walking_xyz", tmp_path, progress=False)
    assert not archive.exists() and len(http_server.requests) == n
    # The next run downloads it again and checks the download against the manifest.
    res = fetch("fr3_walking_xyz", tmp_path, progress=False)
    assert len(http_server.requests) == n + 1 and res.sha256 == first.sha256
    assert archive.read_bytes() == data


def test_interrupted_fetch_resumes_then_extracts(http_server, tmp_path, monkeypatch):
    monkeypatch.setitem(BASE_URLS, "tum", http_server.url)
    data = _big_tgz(seed=1)
    http_server.files[TGZ] = data
    http_server.cut_after[TGZ] = 50_000
    with pytest.raises(DownloadError, match="run again to resume"):
        fetch("fr3_walking_xyz", tmp_path, progress=False)
    assert read_manifest(tmp_path) == {}  # nothing recorded for a partial file
    assert not (tmp_path / "rgbd_dataset_freiburg3_walking_xyz").exists()
    res = fetch("fr3_walking_xyz", tmp_path, progress=False)
    assert http_server.requests[-1] == (TGZ, "bytes=50000-")
    assert res.sha256 == hashlib.sha256(data).hexdigest() and len(res.extracted) == 3
    assert read_manifest(tmp_path)["fr3_walking_xyz"]["size"] == len(data)


def test_corrupt_archive_is_named_removed_and_not_recorded(http_server, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(BASE_URLS, "tum", http_server.url)
    data = _big_tgz(seed=2)
    http_server.files[TGZ] = data[:60_000] + bytes([data[60_000] ^ 0xFF]) + data[60_001:]
    with pytest.raises(CorruptArchiveError, match=r"rgbd_dataset_freiburg3_walking_xyz\.tgz: corrupt or truncated"):
        fetch("fr3_walking_xyz", tmp_path, progress=False)
    assert not (tmp_path / ARCHIVE).exists() and read_manifest(tmp_path) == {}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["downloads"]  # nothing half-extracted
    # The command line says the same and exits 1; once the server is right, a re-run works.
    assert main(["get", "fr3_walking_xyz", "--dest", str(tmp_path), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "corrupt or truncated archive" in err and "run again" in err
    http_server.files[TGZ] = data
    assert main(["get", "fr3_walking_xyz", "--dest", str(tmp_path), "--quiet"]) == 0
    assert read_manifest(tmp_path)["fr3_walking_xyz"]["sha256"] == hashlib.sha256(data).hexdigest()


def test_a_stalled_server_is_named_and_the_timeout_is_the_users(http_server, tmp_path, monkeypatch, capsys):
    """Issue 13 item 11: not "are you offline?" after 30 s, but what stalled, after --timeout."""
    monkeypatch.setitem(BASE_URLS, "tum", http_server.url)
    data = _big_tgz(seed=3)
    http_server.files[TGZ] = data
    http_server.stall_before.add(TGZ)
    assert main(["get", "fr3_walking_xyz", "--dest", str(tmp_path), "--quiet", "--timeout", "0.3"]) == 1
    err = capsys.readouterr().err
    assert f"127.0.0.1:{http_server.port} did not answer within 0.3 s" in err and "--timeout" in err
    assert "offline" not in err
    http_server.stall_before.clear()
    http_server.stall_after[TGZ] = 30_000
    with pytest.raises(DownloadError, match=r"transfer stalled: no data for 0\.3 s after 30000 bytes; run again to resume"):
        fetch("fr3_walking_xyz", tmp_path, progress=False, timeout=0.3)
    del http_server.stall_after[TGZ]
    res = fetch("fr3_walking_xyz", tmp_path, progress=False, timeout=5)  # resumes where it stalled
    assert http_server.requests[-1] == (TGZ, "bytes=30000-") and res.sha256 == hashlib.sha256(data).hexdigest()
    with pytest.raises(SystemExit) as exc:  # a usage error, like argparse's own
        main(["get", "fr3_walking_xyz", "--dest", str(tmp_path), "--timeout", "0"])
    assert exc.value.code == 2


def test_a_link_chain_in_a_fetched_archive_plants_nothing(http_server, tmp_path, monkeypatch):
    """Issue 13 item 4 end to end: a chain built in two steps leaves no link in the destination."""
    monkeypatch.setitem(BASE_URLS, "tum", http_server.url)
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tf:
        for name, kind, target in (("root", tarfile.SYMTYPE, "a/up/../.."), ("a", tarfile.DIRTYPE, ""),
                                   ("a/up", tarfile.SYMTYPE, "x/.."), ("a/x", tarfile.SYMTYPE, "..")):
            info = tarfile.TarInfo(name)
            info.type, info.linkname = kind, target
            tf.addfile(info)
    http_server.files[TGZ] = buf.getvalue()
    dest = tmp_path / "data"
    with pytest.raises(UnsafeArchiveError, match=r"'root' -> 'a/up/\.\./\.\.' points through another link \(a/up\)"):
        fetch("fr3_walking_xyz", dest, progress=False)
    assert not any(p.is_symlink() for p in dest.rglob("*")) and read_manifest(dest) == {}
    assert main(["get", "fr3_walking_xyz", "--dest", str(dest), "--quiet"]) == 1
