"""Safe extraction of .tgz / .tar.gz / .zip archives.

An archive is data from the network: a member named ``/etc/passwd`` or
``../../.bashrc``, a symbolic link pointing outside the destination (followed by a member
written "through" it), or a device node could write anywhere the user can. Every member is
checked *before* anything is written, and the whole archive is refused when one is unsafe:

* absolute names (``/x``, ``C:\\x``) and names with a ``..`` component;
* names that resolve outside the destination folder;
* device files, FIFOs and other special members (only regular files, folders and
  in-tree links are extracted);
* links, judged against the *final* tree (what the destination will hold once every member is
  extracted, plus the links already in it), never against the tree as it is when checking,
  which an archive can change member by member:

  - nothing is written *through* a link: a member whose path has a link as a parent
    (``d -> /etc`` then ``d/passwd``) is refused;
  - a symbolic link's target must be relative, and is followed component by component from
    the link's folder: it must never step above the destination (``..`` past its root) and
    never pass *through* another link (``up -> x/..`` with ``x -> .`` elsewhere in the
    archive, or any chain of links built in several steps, however deep). It may *end* on
    another link, which is itself checked by the same rule, so every chain ends inside;
  - a hard link must name a regular file member of the archive, inside, not through a link.

  After extraction every link is resolved once more on disk (``os.path.realpath``) as a
  second check; a link found to lead outside is removed and the archive refused.

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


def _parts(name: str) -> tuple[str, ...]:
    """Path components of a member name, without ``.`` and empty ones."""
    return tuple(p for p in PurePosixPath(name.replace("\\", "/")).parts if p not in ("", "."))


class _FinalTree:
    """The links the destination will hold after extraction: the archive's and those already on disk."""

    def __init__(self, members: list[tarfile.TarInfo], dest: Path) -> None:
        self.dest = dest
        self.links = {_parts(m.name) for m in members if m.issym() or m.islnk()}
        self.files = {_parts(m.name) for m in members if m.isfile()}

    def is_link(self, parts: tuple[str, ...]) -> bool:
        return parts in self.links or (self.dest.joinpath(*parts).is_symlink() if parts else False)

    def first_link_above(self, parts: tuple[str, ...]) -> tuple[str, ...] | None:
        """The first proper prefix of ``parts`` that is a link, or None."""
        for k in range(1, len(parts)):
            if self.is_link(parts[:k]):
                return parts[:k]
        return None

    def follow(self, start: tuple[str, ...], target: str) -> tuple[str, ...] | str:
        """Where ``target`` leads from folder ``start``, or why it is refused (a string)."""
        here = list(start)
        comps = [c for c in target.replace("\\", "/").split("/") if c not in ("", ".")]
        for i, c in enumerate(comps):
            if c == "..":
                if not here:
                    return "points outside"
                here.pop()
                continue
            here.append(c)
            if i < len(comps) - 1 and self.is_link(tuple(here)):
                return f"points through another link ({'/'.join(here)})"
        return tuple(here)


def _check_tar(tf: tarfile.TarFile, dest: Path, archive: Path) -> list[tarfile.TarInfo]:
    members = tf.getmembers()
    tree = _FinalTree(members, dest)
    for m in members:
        check_member_name(m.name, dest, archive)
        parts = _parts(m.name)
        via = tree.first_link_above(parts)
        if via is not None:
            raise UnsafeArchiveError(
                f"{archive}: member {m.name!r} would be written through the link {'/'.join(via)!r}"
            )
        if m.issym():
            if m.linkname.startswith(("/", "\\")) or PureWindowsPath(m.linkname).drive:
                raise UnsafeArchiveError(f"{archive}: symbolic link {m.name!r} -> {m.linkname!r} points outside {dest}")
            end = tree.follow(parts[:-1], m.linkname)
            if isinstance(end, str):
                raise UnsafeArchiveError(f"{archive}: symbolic link {m.name!r} -> {m.linkname!r} {end} of {dest}")
        elif m.islnk():
            target = _parts(m.linkname)
            if m.linkname.startswith("/") or ".." in PurePosixPath(m.linkname).parts or not target:
                raise UnsafeArchiveError(f"{archive}: hard link {m.name!r} -> {m.linkname!r} points outside {dest}")
            if tree.first_link_above(target) is not None or target not in tree.files:
                raise UnsafeArchiveError(
                    f"{archive}: hard link {m.name!r} -> {m.linkname!r} does not name a regular file of the archive"
                )
        elif not (m.isfile() or m.isdir()):
            raise UnsafeArchiveError(f"{archive}: member {m.name!r} is a device or special file")
    return members


def _check_links_on_disk(names: list[str], dest: Path, archive: Path) -> None:
    """Second line of defence: every extracted link, resolved by the OS, stays inside ``dest``."""
    for name in names:
        p = dest / name
        if p.is_symlink() and not _inside(Path(os.path.realpath(p)), dest):
            p.unlink()
            raise UnsafeArchiveError(f"{archive}: symbolic link {name!r} resolves outside {dest}; removed it")


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
    links: list[str] = []  # symbolic links extracted (tar only: zip links are refused)
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
                links = [m.name for m in members if m.issym()]
        else:
            raise ValueError(f"{archive}: not a tar or zip archive (or one damaged beyond recognition)")
        if staging.exists():
            _move_into(staging, dest)
        _check_links_on_disk(links, dest, archive)
    except getattr(tarfile, "FilterError", ()) as exc:  # PEP 706's filter refused a member we let through
        raise UnsafeArchiveError(f"{archive}: {exc}; nothing was extracted") from None
    except _CORRUPT as exc:
        raise CorruptArchiveError(
            f"{archive}: corrupt or truncated archive ({exc.__class__.__name__}: {exc}); nothing was extracted"
        ) from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return files
