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
"""

from __future__ import annotations

import stat
import tarfile
import zipfile
from pathlib import Path, PurePosixPath, PureWindowsPath

__all__ = ["UnsafeArchiveError", "safe_extract", "check_member_name"]


class UnsafeArchiveError(ValueError):
    """The archive contains a member that would be written outside the destination."""


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
    ValueError
        The file is not a tar or zip archive.
    """
    archive = Path(archive)
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    dest = dest.resolve()
    if zipfile.is_zipfile(archive):
        with zipfile.ZipFile(archive) as zf:
            infos = _check_zip(zf, dest, archive)
            zf.extractall(dest, members=infos)
            return [dest / i.filename for i in infos if not i.is_dir()]
    if tarfile.is_tarfile(archive):
        with tarfile.open(archive, "r:*") as tf:
            members = _check_tar(tf, dest, archive)
            if hasattr(tarfile, "data_filter"):
                tf.extractall(dest, members=members, filter="data")
            else:  # pragma: no cover - Python without PEP 706
                tf.extractall(dest, members=members)
            return [dest / m.name for m in members if m.isfile()]
    raise ValueError(f"{archive}: not a tar or zip archive")

