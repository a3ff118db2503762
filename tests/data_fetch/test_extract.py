"""Safe extraction: good archives extract; malicious members are refused before any write;
corrupt or truncated archives are named and leave nothing behind."""

from __future__ import annotations

import io
import stat
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from data_fetch.extract import CorruptArchiveError, UnsafeArchiveError, safe_extract


def _tar(path: Path, members: list[tuple[tarfile.TarInfo, bytes | None]]) -> Path:
    with tarfile.open(path, "w:gz") as tf:
        for info, data in members:
            if data is not None:
                info.size = len(data)
                tf.addfile(info, io.BytesIO(data))
            else:
                tf.addfile(info)
    return path


def _file(name: str, data: bytes = b"x") -> tuple[tarfile.TarInfo, bytes]:
    return tarfile.TarInfo(name), data


def _link(name: str, target: str, kind=tarfile.SYMTYPE) -> tuple[tarfile.TarInfo, None]:
    info = tarfile.TarInfo(name)
    info.type = kind
    info.linkname = target
    return info, None


def test_good_tgz(tmp_path):
    d = tarfile.TarInfo("seq")
    d.type = tarfile.DIRTYPE
    arc = _tar(tmp_path / "ok.tgz", [
        (d, None),
        _file("seq/rgb.txt", b"# rgb\n1.0 rgb/1.0.png\n"),
        _file("seq/rgb/1.0.png", b"\x89PNG"),
        _link("seq/latest.png", "rgb/1.0.png"),
    ])
    out = tmp_path / "out"
    files = safe_extract(arc, out)
    assert sorted(p.relative_to(out.resolve()).as_posix() for p in files) == ["seq/rgb.txt", "seq/rgb/1.0.png"]
    assert (out / "seq/rgb.txt").read_bytes().startswith(b"# rgb")
    assert (out / "seq/latest.png").is_symlink()


def test_good_zip(tmp_path):
    arc = tmp_path / "ok.zip"
    with zipfile.ZipFile(arc, "w") as zf:
        zf.writestr("rgbd_bonn_crowd/groundtruth.txt", "1 0 0 0 0 0 0 1\n")
        zf.writestr("rgbd_bonn_crowd/rgb/1.png", b"png")
    files = safe_extract(arc, tmp_path / "out")
    assert len(files) == 2
    assert (tmp_path / "out/rgbd_bonn_crowd/groundtruth.txt").read_text().startswith("1 0")


@pytest.mark.parametrize(
    "members, message",
    [
        ([_file("ok.txt"), _file("../evil.txt")], "contains '..'"),
        ([_file("/tmp/evil_abs.txt")], "absolute path"),
        ([_file("a/../../evil.txt")], "contains '..'"),
        ([_link("escape", "/etc")], "points outside"),
        ([_link("up", "../../..")], "points outside"),
        ([_link("hard", "/etc/passwd", tarfile.LNKTYPE)], "points outside"),
    ],
    ids=["dotdot", "absolute", "nested-dotdot", "symlink-abs", "symlink-up", "hardlink"],
)
def test_malicious_tar_refused(tmp_path, members, message):
    arc = _tar(tmp_path / "bad.tgz", members)
    out = tmp_path / "deep" / "out"
    with pytest.raises(UnsafeArchiveError, match=message) as exc:
        safe_extract(arc, out)
    assert "bad.tgz" in str(exc.value)
    assert list(out.iterdir()) == []  # nothing extracted, not even the good member
    assert not (tmp_path / "deep" / "evil.txt").exists() and not (tmp_path / "evil.txt").exists()


def test_symlink_then_write_through_it_refused(tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    arc = _tar(tmp_path / "bad.tgz", [_link("d", str(outside)), _file("d/pwned.txt", b"x")])
    with pytest.raises(UnsafeArchiveError):
        safe_extract(arc, tmp_path / "out")
    assert not (outside / "pwned.txt").exists()


@pytest.mark.parametrize("kind", [tarfile.CHRTYPE, tarfile.BLKTYPE, tarfile.FIFOTYPE])
def test_device_files_refused(tmp_path, kind):
    info = tarfile.TarInfo("dev/thing")
    info.type = kind
    arc = _tar(tmp_path / "dev.tgz", [(info, None)])
    with pytest.raises(UnsafeArchiveError, match="device or special"):
        safe_extract(arc, tmp_path / "out")


def test_malicious_zip_refused(tmp_path):
    arc = tmp_path / "bad.zip"
    with zipfile.ZipFile(arc, "w") as zf:
        zf.writestr("fine.txt", "ok")
        zf.writestr("../evil.txt", "x")
    with pytest.raises(UnsafeArchiveError, match="contains '..'"):
        safe_extract(arc, tmp_path / "out")
    assert not (tmp_path / "evil.txt").exists() and not (tmp_path / "out" / "fine.txt").exists()

    arc2 = tmp_path / "link.zip"
    with zipfile.ZipFile(arc2, "w") as zf:
        info = zipfile.ZipInfo("link")
        info.external_attr = (stat.S_IFLNK | 0o777) << 16
        zf.writestr(info, "/etc/passwd")
    with pytest.raises(UnsafeArchiveError, match="symbolic link"):
        safe_extract(arc2, tmp_path / "out2")


def test_not_an_archive(tmp_path):
    p = tmp_path / "x.tgz"
    p.write_bytes(b"plain text, not an archive")
    with pytest.raises(ValueError, match="not a tar or zip"):
        safe_extract(p, tmp_path / "out")


def _random_members(n=4, size=40_000, seed=0):
    rng = np.random.default_rng(seed)  # incompressible: a flipped byte lands in member data
    return [(f"seq/rgb/{i}.png", rng.integers(0, 256, size, dtype=np.uint8).tobytes()) for i in range(n)]


def _flip(data: bytes, k: int) -> bytes:
    return data[:k] + bytes([data[k] ^ 0xFF]) + data[k + 1:]


def _good_tgz(path: Path) -> bytes:
    _tar(path, [_file(name, data) for name, data in _random_members()])
    return path.read_bytes()


def _good_zip(path: Path) -> bytes:
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, data in _random_members(seed=1):
            zf.writestr(name, data)
    return path.read_bytes()


@pytest.mark.parametrize(
    "make, damage",
    [
        (_good_tgz, lambda b: b[: len(b) // 2]),  # cut short: the gzip stream ends early
        (_good_tgz, lambda b: _flip(b, len(b) // 2)),  # a flipped byte in member data: CRC-32
        (_good_tgz, lambda b: _flip(b, len(b) - 6)),  # the CRC-32 in the gzip trailer itself
        (_good_zip, lambda b: _flip(b, len(b) // 3)),  # a member's data: its CRC-32
    ],
    ids=["tgz-truncated", "tgz-flipped-data", "tgz-flipped-crc", "zip-flipped-data"],
)
def test_corrupt_archive_names_the_file_and_extracts_nothing(tmp_path, make, damage):
    arc = tmp_path / ("seq.zip" if make is _good_zip else "seq.tgz")
    arc.write_bytes(damage(make(arc)))
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("the user's own file")
    with pytest.raises(CorruptArchiveError, match=rf"{arc.name}: corrupt or truncated archive"):
        safe_extract(arc, out)
    assert sorted(p.name for p in out.iterdir()) == ["mine.txt"]  # no partial members, no staging folder


def test_truncated_zip_is_not_an_archive(tmp_path):
    arc = tmp_path / "seq.zip"
    arc.write_bytes(_good_zip(arc)[:30_000])  # the central directory is gone
    with pytest.raises(ValueError, match=r"seq\.zip: not a tar or zip archive \(or one damaged"):
        safe_extract(arc, tmp_path / "out")


def test_extract_again_over_a_previous_extraction(tmp_path):
    arc = tmp_path / "seq.tgz"
    _good_tgz(arc)
    out = tmp_path / "out"
    first = safe_extract(arc, out)
    (out / "seq" / "rgb" / "0.png").write_bytes(b"edited")
    (out / "seq" / "results.txt").write_text("kept")
    again = safe_extract(arc, out)
    assert first == again and len(again) == 4
    members = dict(_random_members())
    assert all((out / name).read_bytes() == data for name, data in members.items())
    assert (out / "seq" / "results.txt").read_text() == "kept"
    assert sorted(p.name for p in out.iterdir()) == ["seq"]


def _dir(name: str) -> tuple[tarfile.TarInfo, None]:
    info = tarfile.TarInfo(name)
    info.type = tarfile.DIRTYPE
    return info, None


_DEEP = "/".join(f"d{i}" for i in range(12))


@pytest.mark.parametrize(
    "members, message",
    [
        # up -> x/.. before x -> ..: root resolves to the destination's grand-parent, then /
        ([_link("root", "a/up/../.."), _dir("a"), _link("a/up", "x/.."), _link("a/x", "..")],
         r"'root' -> 'a/up/\.\./\.\.' points through another link \(a/up\)"),
        ([_dir("a"), _link("a/up", "x/.."), _link("a/x", ".."), _link("root", "a/up/../..")],
         r"'a/up' -> 'x/\.\.' points through another link \(a/x\)"),
        # twelve levels deep: s climbs back twelve folders, root climbs twelve more through it
        ([_link("root", _DEEP + "/s/" + "../" * 12), _dir(_DEEP), _link(_DEEP + "/s", "../" * 12)],
         r"'root' -> 'd0/d1/.*' points through another link \(d0/d1/d2/d3/d4/d5/d6/d7/d8/d9/d10/d11/s\)"),
        # a link to a link's inside, and a member written through an in-tree link
        ([_link("l", "seq"), _dir("seq"), _link("m", "l/rgb")], r"'m' -> 'l/rgb' points through another link \(l\)"),
        ([_dir("seq"), _link("l", "seq"), _file("l/x.txt")], r"'l/x\.txt' would be written through the link 'l'"),
        # hard links: only to a regular file of the archive
        ([_link("h", "nowhere", tarfile.LNKTYPE)], "does not name a regular file of the archive"),
    ],
    ids=["two-step", "two-step-ordered", "twelve-deep", "link-through-link", "file-through-link", "hardlink-missing"],
)
def test_link_chains_are_judged_against_the_final_tree(tmp_path, members, message):
    """Issue 13 item 4: links that are harmless one by one but escape together are refused, and
    nothing (no link, no folder) is planted in the destination."""
    arc = _tar(tmp_path / "chain.tgz", members)
    out = tmp_path / "x" / "y" / "out"
    with pytest.raises(UnsafeArchiveError, match=message):
        safe_extract(arc, out)
    assert list(out.iterdir()) == []


def test_links_chained_inside_the_tree_are_fine(tmp_path):
    arc = _tar(tmp_path / "ok.tgz", [_dir("seq"), _file("seq/rgb/1.png", b"png"), _link("seq/latest", "rgb/1.png"),
                                     _link("newest", "seq/latest"), _link("seq/up", "../seq/rgb")])
    out = tmp_path / "out"
    safe_extract(arc, out)
    assert (out / "newest").read_bytes() == b"png" and (out / "seq" / "up" / "1.png").read_bytes() == b"png"


def test_a_link_already_in_the_destination_is_not_written_through(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (tmp_path / "elsewhere").mkdir()
    (out / "data").symlink_to(tmp_path / "elsewhere")  # left by someone else
    arc = _tar(tmp_path / "a.tgz", [_file("data/evil.txt")])
    with pytest.raises(UnsafeArchiveError, match="member 'data/evil.txt' would be written (outside|through)"):
        safe_extract(arc, out)
    assert list((tmp_path / "elsewhere").iterdir()) == []
