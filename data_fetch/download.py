"""Resumable HTTP(S) download with a progress bar, size and SHA-256 checks.

A download writes to ``FILE.part``. If that file exists from an interrupted attempt, the
request asks only for the missing bytes (``Range: bytes=N-``); a server that answers
``206 Partial Content`` continues the file, one that answers ``200`` sends the whole file
again and the part file is restarted. Only a complete, verified file is renamed to its
final name, so a half-written file never looks finished.

Checks: the byte count against ``Content-Length`` / ``Content-Range`` and, when the caller
knows them, against the expected size and SHA-256. A checksum mismatch removes the file
(it cannot be resumed into a correct one) and raises :class:`ChecksumError`.
Being offline (DNS failure, refused connection) raises :class:`DownloadError` with
``cannot reach HOST: are you offline?``.
"""

from __future__ import annotations

import hashlib
import http.client
import os
import socket
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path

__all__ = ["DownloadError", "ChecksumError", "DownloadResult", "download", "sha256_file"]

CHUNK = 1 << 16  # bytes read per iteration


class DownloadError(RuntimeError):
    """The file could not be fetched (network, HTTP status, truncated transfer)."""


class ChecksumError(DownloadError):
    """The fetched file's size or SHA-256 is not the expected one."""


@dataclass(frozen=True)
class DownloadResult:
    """What :func:`download` fetched.

    Attributes
    ----------
    path : final file path.
    size : bytes.
    sha256 : hex digest of the file.
    resumed_from : bytes already on disk when this call started (0 for a fresh download).
    """

    path: Path
    size: int
    sha256: str
    resumed_from: int


def sha256_file(path: str | Path) -> str:
    """Hex SHA-256 of a file, read in chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _host(url: str) -> str:
    return urllib.parse.urlsplit(url).netloc or url


def _verify(path: Path, size: int | None, sha256: str | None, url: str) -> str:
    actual_size = path.stat().st_size
    if size is not None and actual_size != size:
        path.unlink()
        raise ChecksumError(f"{url}: expected {size} bytes, got {actual_size}; removed {path}")
    digest = sha256_file(path)
    if sha256 is not None and digest.lower() != sha256.lower():
        path.unlink()
        raise ChecksumError(f"{url}: SHA-256 mismatch (expected {sha256}, got {digest}); removed {path}")
    return digest


def download(
    url: str,
    dest: str | Path,
    size: int | None = None,
    sha256: str | None = None,
    progress: bool = True,
    timeout: float = 30.0,
) -> DownloadResult:
    """Fetch ``url`` to the file ``dest``, resuming a previous partial download.

    Parameters
    ----------
    url : http(s) URL.
    dest : final file path (its folder is created). ``dest + ".part"`` holds partial data.
    size : expected size in bytes, or None.
    sha256 : expected hex SHA-256, or None.
    progress : show a tqdm progress bar (on stderr).
    timeout : socket timeout per read (s).

    Returns
    -------
    DownloadResult

    Raises
    ------
    DownloadError
        Unreachable host ("cannot reach HOST: are you offline?"), HTTP error status, or a
        transfer cut short (the ``.part`` file is kept: call again to resume).
    ChecksumError
        Size or SHA-256 mismatch (the file is removed).
    """
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    if dest.exists():
        digest = _verify(dest, size, sha256, url)
        return DownloadResult(dest, dest.stat().st_size, digest, dest.stat().st_size)
    part = dest.with_name(dest.name + ".part")
    have = part.stat().st_size if part.exists() else 0
    if size is not None and have > size:
        part.unlink()
        have = 0
    resumed_from = have

    headers = {"User-Agent": "dynslam_lab-data_fetch/0.1"}
    if have:
        headers["Range"] = f"bytes={have}-"
    request = urllib.request.Request(url, headers=headers)
    try:
        response = urllib.request.urlopen(request, timeout=timeout)
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and have:
            # Range not satisfiable: the part file already holds the whole resource.
            exc.close()
            os.replace(part, dest)
            digest = _verify(dest, size, sha256, url)
            return DownloadResult(dest, dest.stat().st_size, digest, resumed_from)
        exc.close()
        raise DownloadError(f"{url}: HTTP {exc.code} {exc.reason}") from None
    except urllib.error.URLError as exc:
        raise DownloadError(f"cannot reach {_host(url)}: are you offline? ({exc.reason})") from None
    except (socket.timeout, TimeoutError, ConnectionError) as exc:
        raise DownloadError(f"cannot reach {_host(url)}: are you offline? ({exc})") from None

    with response:
        status = getattr(response, "status", 200)
        if status == 206:
            content_range = response.headers.get("Content-Range", "")
            # "bytes START-END/TOTAL"
            try:
                start = int(content_range.split()[1].split("-")[0])
                total_s = content_range.split("/")[-1]
                total = int(total_s) if total_s != "*" else None
            except (IndexError, ValueError):
                raise DownloadError(f"{url}: malformed Content-Range {content_range!r}") from None
            if start != have:
                raise DownloadError(f"{url}: server resumed at byte {start}, expected {have}")
            mode = "ab"
        else:
            have = 0
            resumed_from = 0
            length = response.headers.get("Content-Length")
            total = int(length) if length is not None else None
            mode = "wb"
        if size is not None and total is not None and total != size:
            raise ChecksumError(f"{url}: server announces {total} bytes, catalog expects {size}")

        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=total, initial=have, unit="B", unit_scale=True, unit_divisor=1024,
                       desc=dest.name, leave=True)
        written = have
        try:
            with open(part, mode) as fh:
                while True:
                    try:
                        block = response.read(CHUNK)
                    except (http.client.IncompleteRead, ConnectionError, socket.timeout, TimeoutError) as exc:
                        raise DownloadError(
                            f"{url}: transfer interrupted after {written} bytes ({exc.__class__.__name__}); "
                            f"run again to resume from {part}"
                        ) from None
                    if not block:
                        break
                    fh.write(block)
                    written += len(block)
                    if bar is not None:
                        bar.update(len(block))
        finally:
            if bar is not None:
                bar.close()
    if total is not None and written != total:
        raise DownloadError(
            f"{url}: transfer interrupted after {written} of {total} bytes; run again to resume from {part}"
        )
    os.replace(part, dest)
    digest = _verify(dest, size, sha256, url)
    return DownloadResult(dest, written, digest, resumed_from)
