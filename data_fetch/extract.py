"""Safe extraction of .tgz / .tar.gz / .zip archives.

An archive is data from the network: a member named ``/etc/passwd`` or
``../../.bashrc``, a symbolic link pointing outside the destination (followed by a member
written "through" it), or a device node could write anywhere the user can. Every member is
checked *before* anything is written, and the whole archive is refused when one is unsafe:

* absolute names (``/x``, ``C:\\x``) and names with a ``..`` component;
* names that resolve outside the destination folder;
* symbolic or hard links whose target resolves outside the destination;
* device files, FIFOs and other special members (only regular files, folders and
  in-tree links are extracted).

For tar archives Python's own ``filter="data"`` (PEP 706) is applied on top as a second line
of defence where the interpreter has it.

A corrupt or truncated archive (a bad CRC in a zip member, a gzip stream that ends early or
fails its CRC-32 check) raises :class:`CorruptArchiveError` naming the archive. Members are
first extracted into a hidden staging folder beside them (``DEST/.NAME.extracting``) and
moved into place only when the whole archive has been read and checked, so a corrupt
archive leaves nothing half-extracted in ``DEST``. For a ``.tgz`` the gzip stream is read to
its end, because its CRC-32 and length sit in the last eight bytes.
"""

from __future__ import annotations

import gzip
import lzma
import os
import shutil
import stat
import tarfile
import zipfile
import zlib
from pathlib import Path, PurePosixPath, PureWindowsPath

__all__ = ["UnsafeArchiveError", "CorruptArchiveError", "safe_extract", "check_member_name"]


class UnsafeArchiveError(ValueError):
    """The archive contains a member that would be written outside the destination."""


class CorruptArchiveError(ValueError):
    """The archive is damaged or truncated (bad checksum, early end of data)."""


#: What the readers raise on damaged data: zip CRC or structure errors, tar header errors,
#: a compressed stream that ends early (EOFError) or fails its check (gzip, zlib, lzma).
_CORRUPT = (zipfile.BadZipFile, tarfile.TarError, EOFError, zlib.error, gzip.BadGzipFile, lzma.LZMAError)


def check_member_name(name: str, dest: Path, archive: str | Path) -> Path:
    """Resolved target path of member ``name`` inside ``dest``; raises if unsafe.

    Parameters
    ----------
    name : member name as stored in the archive.
    dest : destination folder (resolved).
    archive : archive path, for the message.
    """
    if not name:
        raise UnsafeArchiveError(f"{archive}: member with an empty name")
    if name.startswith(("/", "\\")) or PureWindowsPath(name).drive:
        raise UnsafeArchiveError(f"{archive}: member {name!r} has an absolute path")
    parts = PurePosixPath(name.replace("\\", "/")).parts
    if ".." in parts:
        raise UnsafeArchiveError(f"{archive}: member {name!r} contains '..'")
    target = (dest / name).resolve()
    if target != dest and dest not in target.parents:
        raise UnsafeArchiveError(f"{archive}: member {name!r} would be written outside {dest}")
    return target


def _inside(path: Path, dest: Path) -> bool:
    return path == dest or dest in path.parents


def _check_tar(tf: tarfile.TarFile, dest: Path, archive: Path) -> list[tarfile.TarInfo]:
    members = tf.getmembers()
    for m in members:
        target = check_member_name(m.name, dest, archive)
        if m.issym():
            link = (target.parent / m.linkname).resolve()
            if m.linkname.startswith("/") or not _inside(link, dest):
                raise UnsafeArchiveError(
                    f"{archive}: symbolic link {m.name!r} -> {m.linkname!r} points outside {dest}"
                )
        elif m.islnk():
            link = (dest / m.linkname).resolve()
            if m.linkname.startswith("/") or ".." in PurePosixPath(m.linkname).parts or not _inside(link, dest):
                raise UnsafeArchiveError(f"{archive}: hard link {m.name!r} -> {m.linkname!r} points outside {dest}")
        elif not (m.isfile() or m.isdir()):
            raise UnsafeArchiveError(f"{archive}: member {m.name!r} is a device or special file")
    return members


def _check_zip(zf: zipfile.ZipFile, dest: Path, archive: Path) -> list[zipfile.ZipInfo]:
    infos = zf.infolist()
    for info in infos:
        check_member_name(info.filename, dest, archive)
        mode = info.external_attr >> 16
        if mode and stat.S_IFMT(mode) not in (0, stat.S_IFREG, stat.S_IFDIR):
            kind = "symbolic link" if stat.S_ISLNK(mode) else "special file"
            raise UnsafeArchiveError(f"{archive}: member {info.filename!r} is a {kind}; refused")
    return infos


def _move_into(staging: Path, dest: Path) -> None:
    """Move every entry extracted into ``staging`` to the same relative place in ``dest``."""
    for root, dirs, files in os.walk(staging):
        rel = Path(root).relative_to(staging)
        (dest / rel).mkdir(parents=True, exist_ok=True)
        for name in files + [d for d in dirs if (Path(root) / d).is_symlink()]:
            os.replace(Path(root) / name, dest / rel / name)


def safe_extract(archive: str | Path, dest: str | Path) -> list[Path]:
    """Extract a .tgz/.tar.gz/.tar/.zip archive into ``dest`` after checking every member.

    Parameters
    ----------
    archive : path of the archive.
    dest : destination folder (created).

    Returns
    -------
    list of Path
        The extracted regular files.

    Raises
    ------
    UnsafeArchiveError
        A member is absolute, contains ``..``, escapes ``dest`` (directly or through a link),
        or is a device/special file. Nothing is extracted in that case.
    CorruptArchiveError
        The archive is damaged or truncated. Nothing is extracted in that case.
    ValueError
        The file is not a tar or zip archive (or is damaged beyond recognition).
    """
    archive = Path(archive)
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    dest = dest.resolve()
    staging = dest / f".{archive.name}.extracting"
    try:
        if zipfile.is_zipfile(archive):
            with zipfile.ZipFile(archive) as zf:
                infos = _check_zip(zf, dest, archive)
                shutil.rmtree(staging, ignore_errors=True)
                zf.extractall(staging, members=infos)
                files = [dest / i.filename for i in infos if not i.is_dir()]
        elif tarfile.is_tarfile(archive):
            with tarfile.open(archive, "r:*") as tf:
                members = _check_tar(tf, dest, archive)
                shutil.rmtree(staging, ignore_errors=True)
                if hasattr(tarfile, "data_filter"):
                    tf.extractall(staging, members=members, filter="data")
                else:  # pragma: no cover - Python without PEP 706
                    tf.extractall(staging, members=members)
                # Read a compressed stream to its end: gzip checks its CRC-32 and length there.
                while tf.fileobj.read(1 << 20):
                    pass
                files = [dest / m.name for m in members if m.isfile()]
        else:
            raise ValueError(f"{archive}: not a tar or zip archive (or one damaged beyond recognition)")
        if staging.exists():
            _move_into(staging, dest)
    except getattr(tarfile, "FilterError", ()) as exc:  # PEP 706's filter refused a member we let through
        raise UnsafeArchiveError(f"{archive}: {exc}; nothing was extracted") from None
    except _CORRUPT as exc:
        raise CorruptArchiveError(
            f"{archive}: corrupt or truncated archive ({exc.__class__.__name__}: {exc}); nothing was extracted"
        ) from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return files
