"""Output folders as transactions: fresh, locked, written atomically, replaced only when ours.

Every command that writes a folder of results (``dynslam run``, ``ablation``, ``demo``,
``detect --save-dir``; the lead applies the same to ``synth`` and ``vocab build``) opens it as
an :class:`OutputFolder`::

    with OutputFolder(out, kind="run", force=args.force) as folder:
        folder.write_text("notes.txt", "...")          # temp file + rename
        folder.write("table.csv", lambda tmp: df.to_csv(tmp))

The rules (``docs/reliability.md``, each with its test):

1. **Fresh folder.** ``out`` must not exist, or be an empty folder. A file, or a folder holding
   anything, is refused (:class:`OutputFolderError`, exit code 2) and nothing in it is touched.
2. **Marker.** On opening, the folder gets ``.dynslam-output.json``: its kind (``run``,
   ``ablation``, ...), a fresh id, the time, the tool version. A folder without it was not made
   by dynslam_lab.
3. **Journal.** Every file written through the folder is first listed in
   ``.dynslam-output.files`` (one relative path a line, appended before the file exists), and
   on closing whatever else appeared in the folder is added. The journal is therefore always a
   superset of what this writer made, even after ``kill -9``.
4. **Replace only what is ours.** ``force=True`` replaces a previous output *of the same kind*
   recognised by its marker: it deletes the files its journal lists (and our temporary files),
   and refuses, deleting nothing, when the folder holds any other file (a user's own). Nested
   output folders (an ablation's runs) are judged by their own marker and journal.
5. **One writer.** ``.dynslam-output.lock`` is held with ``flock`` while the folder is open; a
   second writer gets :class:`FolderLockedError` naming the process that holds it. The lock is
   the kernel's: it goes when its process dies, so a crashed run never leaves a stale lock. The
   lock file itself stays (deleting it would let two writers lock two different files).
6. **Atomic files.** :func:`atomic_write` writes a temporary file beside the target and renames
   it: a reader (or a crash) never sees half a file. It returns the file's size and SHA-256,
   which a run's ``summary.json`` lists so that a reader can tell the files belong to it.
"""

from __future__ import annotations

import datetime as _dt
import fcntl  # POSIX advisory locks (dynslam_lab runs on Linux and macOS)
import hashlib
import json
import os
import socket
import tempfile
from pathlib import Path
from typing import Callable

from .. import __version__
from ..errors import UsageError

__all__ = [
    "MARKER",
    "JOURNAL",
    "LOCK",
    "OutputFolder",
    "OutputFolderError",
    "FolderLockedError",
    "atomic_write",
    "file_record",
    "read_marker",
    "check_output_file",
]

MARKER = ".dynslam-output.json"
JOURNAL = ".dynslam-output.files"
LOCK = ".dynslam-output.lock"
_OWN = (MARKER, JOURNAL, LOCK)


class OutputFolderError(UsageError):
    """The output folder cannot be used: not empty, not ours, a file, not writable (exit code 2)."""


class FolderLockedError(OutputFolderError):
    """Another process is writing into the output folder."""


def file_record(path: str | Path) -> dict:
    """``{"size": bytes, "sha256": hex}`` of a file, read in chunks."""
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
            size += len(block)
    return {"size": size, "sha256": h.hexdigest()}


def _file_mode() -> int:
    """Permissions of a new file under the process's umask (mkstemp's own 0600 would hide results)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


_MODE = _file_mode()


def _is_temp(name: str) -> bool:
    """Temporary files of :func:`atomic_write` (``.NAME.XXXX.tmp``)."""
    return name.startswith(".") and name.endswith(".tmp")


def atomic_write(path: str | Path, write: Callable[[Path], None]) -> dict:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it to ``path``.

    Returns the :func:`file_record` (size, SHA-256) of what was written. The temporary file is
    removed when ``write`` fails or is interrupted; ``path`` then still holds its old content.
    """
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        write(tmp_path)
        record = file_record(tmp_path)
        os.chmod(tmp_path, _MODE)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()
    return record


def check_output_file(path: str | Path, suffix: str, force: bool = False, option: str = "--force") -> Path:
    """Check the name of a single output file (``vocab build --out VOC.npz``) before the work.

    Refuses a folder (``--out /tmp`` once wrote ``/tmp.npz``), a name without ``suffix`` (no
    suffix is silently appended), and an existing file unless ``force``; creates the parent
    folder. Write the file itself with :func:`atomic_write`. Returns the path.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputFolderError(f"{path}: is a folder; give a file name such as {path / ('output' + suffix)}")
    if path.suffix != suffix:
        raise OutputFolderError(f"{path}: the output file name must end with {suffix}")
    if path.exists() and not force:
        raise OutputFolderError(f"{path}: exists; pass {option} to replace it, or choose another name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputFolderError(f"{path.parent}: cannot create the folder ({exc.strerror or exc})") from None
    return path


def read_marker(folder: str | Path) -> dict | None:
    """The marker of an output folder, or None when it has none (or an unreadable one)."""
    p = Path(folder) / MARKER
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not isinstance(data.get("kind"), str) or not isinstance(data.get("id"), str):
        return None
    return data


def _journal(folder: Path) -> set[str]:
    try:
        text = (folder / JOURNAL).read_text(encoding="utf-8", errors="replace")
    except OSError:
        return set()
    return {line for line in text.splitlines() if line}


def _inventory(folder: Path) -> tuple[list[Path], list[str]]:
    """Files of a marked output folder that its writers made (deletable) and the others.

    Returns ``(ours, foreign)``: paths to delete, and relative names of files no writer recorded.
    A sub-folder with its own marker is judged by its own journal.
    """
    listed = _journal(folder)
    ours: list[Path] = []
    foreign: list[str] = []
    for dirpath, dirnames, filenames in os.walk(folder):
        here = Path(dirpath)
        for d in list(dirnames):
            p = here / d
            if p.is_symlink():  # never followed: judged like a file
                dirnames.remove(d)
                filenames.append(d)
            elif read_marker(p) is not None:
                dirnames.remove(d)
                sub_ours, sub_foreign = _inventory(p)
                ours += sub_ours
                foreign += [(p / f).relative_to(folder).as_posix() for f in sub_foreign]
        for f in filenames:
            p = here / f
            rel = p.relative_to(folder).as_posix()
            if rel in _OWN or rel in listed or _is_temp(f):
                ours.append(p)
            else:
                foreign.append(rel)
    return ours, foreign


def _remove_empty_dirs(folder: Path) -> None:
    for dirpath, _, _ in os.walk(folder, topdown=False):
        if Path(dirpath) != folder:
            try:
                os.rmdir(dirpath)
            except OSError:
                pass


class OutputFolder:
    """An output folder opened as a transaction (rules in the module docstring).

    Parameters
    ----------
    path : the folder (created with its parents).
    kind : what it holds (``"run"``, ``"ablation"``, ``"demo"``, ``"detections"``, ...);
        ``force`` replaces only a previous output of the same kind.
    force : replace a previous output of this kind (only files its writers recorded).
    option : how the user asks for ``force``, for messages (``"--force"``).

    Attributes
    ----------
    id : a fresh hex id of this transaction (in the marker; a run's ``summary.json`` repeats it).
    replaced : True when a previous output was replaced.
    """

    def __init__(self, path: str | Path, kind: str, force: bool = False, option: str = "--force") -> None:
        self.path = Path(path)
        self.kind = str(kind)
        self.force = bool(force)
        self.option = option
        self.id: str | None = None
        self.replaced = False
        self._lock_fd: int | None = None
        self._journal_fd: int | None = None
        self._recorded: set[str] = set()

    # ------------------------------------------------------------------ open / close
    def __enter__(self) -> "OutputFolder":
        self.open()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        return self._lock_fd is not None

    def open(self) -> "OutputFolder":
        """Create or check the folder, take the lock, replace a previous output if asked, mark it."""
        p = self.path
        if p.exists() and not p.is_dir():
            raise OutputFolderError(f"{p}: exists and is not a folder; give the name of a new folder")
        if p.is_dir() and read_marker(p) is None and any(e.name != LOCK for e in p.iterdir()):
            self._refuse_foreign(p)  # before the lock file: a folder that is not ours gets nothing
        lock_existed = (p / LOCK).exists()
        try:
            p.mkdir(parents=True, exist_ok=True)
            fd = os.open(p / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise OutputFolderError(f"{p}: cannot write an output folder here ({exc.strerror or exc})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.read(fd, 4096).decode("utf-8", "replace").strip()
            os.close(fd)
            try:
                who = json.loads(holder)
                who = f"pid {who.get('pid')} on {who.get('host')}, since {who.get('started')}"
            except (ValueError, AttributeError):
                who = "another process"
            raise FolderLockedError(
                f"{p}: another dynslam process ({who}) is writing into this folder; "
                "wait for it to finish or choose another output folder"
            ) from None
        self._lock_fd = fd
        try:
            self._check_and_clear()
            self._mark()
        except BaseException:
            self._unlock()
            if not lock_existed:  # a refused folder is left as it was found
                (p / LOCK).unlink(missing_ok=True)
            raise
        return self

    @staticmethod
    def _refuse_foreign(p: Path) -> None:
        entries = sorted(e.name for e in p.iterdir() if e.name != LOCK)
        shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
        raise OutputFolderError(
            f"{p}: the folder is not empty ({len(entries)} entries: {shown}) and was not written by "
            "dynslam_lab; nothing was changed: choose a new or empty folder"
        )

    def _check_and_clear(self) -> None:
        p = self.path
        entries = sorted(e.name for e in p.iterdir() if e.name != LOCK)
        if not entries:
            return
        marker = read_marker(p)
        if marker is None:
            self._refuse_foreign(p)
        if marker["kind"] != self.kind:
            raise OutputFolderError(
                f"{p}: holds a previous '{marker['kind']}' output, not a '{self.kind}'; nothing was changed: "
                "choose another folder"
            )
        if not self.force:
            raise OutputFolderError(
                f"{p}: holds a previous '{self.kind}' output (created {marker.get('created', '?')}); "
                f"pass {self.option} to replace it, or choose another folder"
            )
        ours, foreign = _inventory(p)
        if foreign:
            shown = ", ".join(foreign[:5]) + (", ..." if len(foreign) > 5 else "")
            raise OutputFolderError(
                f"{p}: {self.option} would delete {len(foreign)} file(s) that dynslam_lab did not write there "
                f"({shown}); nothing was changed: move them away first"
            )
        last = [p / JOURNAL, p / MARKER]  # an interrupted --force leaves a folder still recognised as ours
        for f in [f for f in ours if f not in last and f != p / LOCK] + last:
            f.unlink(missing_ok=True)
        _remove_empty_dirs(p)
        self.replaced = True

    def _mark(self) -> None:
        self.id = os.urandom(8).hex()
        now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
        holder = {"pid": os.getpid(), "host": socket.gethostname(), "started": now, "kind": self.kind}
        os.ftruncate(self._lock_fd, 0)
        os.pwrite(self._lock_fd, json.dumps(holder).encode(), 0)
        self._journal_fd = os.open(self.path / JOURNAL, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND, 0o644)
        self._recorded = set()
        marker = {"kind": self.kind, "id": self.id, "created": now, "tool": f"dynslam_lab {__version__}",
                  "pid": os.getpid(), "host": socket.gethostname()}
        atomic_write(self.path / MARKER, lambda tmp: tmp.write_text(json.dumps(marker, indent=2) + "\n"))

    def close(self) -> None:
        """Record whatever else appeared in the folder, then release the lock."""
        if self._lock_fd is None:
            return
        try:
            if self._journal_fd is not None:
                for dirpath, dirnames, filenames in os.walk(self.path):
                    for name in filenames + [d for d in dirnames if (Path(dirpath) / d).is_symlink()]:
                        rel = (Path(dirpath) / name).relative_to(self.path).as_posix()
                        if rel not in _OWN and not _is_temp(name):
                            self.record(rel)
        finally:
            if self._journal_fd is not None:
                os.close(self._journal_fd)
                self._journal_fd = None
            self._unlock()

    def _unlock(self) -> None:
        fd, self._lock_fd = self._lock_fd, None
        if fd is None:
            return
        try:
            os.ftruncate(fd, 0)
        finally:
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)

    # ------------------------------------------------------------------ writing
    def record(self, rel: str | Path) -> None:
        """Add ``rel`` (relative to the folder) to the journal before it is written."""
        rel = Path(rel).as_posix()
        if rel in self._recorded:
            return
        if self._journal_fd is None:
            raise RuntimeError(f"{self.path}: output folder is not open")
        os.write(self._journal_fd, (rel + "\n").encode("utf-8"))
        self._recorded.add(rel)

    def file(self, rel: str | Path) -> Path:
        """Path of ``rel`` inside the folder, recorded in the journal, its parent folders made."""
        rel = Path(rel)
        if rel.is_absolute() or ".." in rel.parts:
            raise ValueError(f"{self.path}: {rel} is not a path inside the output folder")
        self.record(rel)
        target = self.path / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        return target

    def write(self, rel: str | Path, write: Callable[[Path], None]) -> dict:
        """Write ``rel`` atomically with ``write(tmp)``; returns its size and SHA-256."""
        return atomic_write(self.file(rel), write)

    def write_text(self, rel: str | Path, text: str) -> dict:
        return self.write(rel, lambda tmp: tmp.write_text(text, encoding="utf-8"))

    def write_bytes(self, rel: str | Path, data: bytes) -> dict:
        return self.write(rel, lambda tmp: tmp.write_bytes(data))

    def __repr__(self) -> str:
        state = "open" if self.is_open else "closed"
        return f"OutputFolder({str(self.path)!r}, kind={self.kind!r}, {state})"
