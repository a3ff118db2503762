"""Resumable HTTP(S) download with a progress bar, size and SHA-256 checks.

A download writes to ``FILE.part`` and notes what it is fetching in ``FILE.part.json`` (the
URL, the total size, and the server's ``ETag`` / ``Last-Modified`` validators). If the part
file exists from an interrupted attempt, the request asks only for the missing bytes
(``Range: bytes=N-``) with ``If-Range`` set to the validator, so a server whose file changed
since sends the whole new file instead. A ``206 Partial Content`` answer continues the file;
a ``200`` restarts it. The part file is thrown away and the download restarted cleanly when
it cannot belong to the file being fetched: it was started from another URL, it is longer
than the file, or the server's answer to the range request (start, total size, validator)
does not fit it. Only a complete, verified file is renamed to its final name, so a
half-written file never looks finished.

Checks: the byte count against ``Content-Length`` / ``Content-Range`` and, when the caller
knows them, against the expected size and SHA-256 (also for a file already on disk, so a
re-run verifies it). A checksum mismatch removes the file (it cannot be resumed into a
correct one) and raises :class:`ChecksumError`.
Being offline (DNS failure, refused connection) raises :class:`DownloadError` with
``cannot reach HOST: are you offline?``. A server that accepts the connection and then sends
nothing for ``timeout`` seconds is a different failure and says so: ``HOST did not answer
within S s`` before the response, ``transfer stalled ... after N bytes`` during it (the part
file is kept: run again to resume); ``python -m data_fetch get --timeout S`` sets ``S``.
"""

from __future__ import annotations

import hashlib
import http.client
import json
import os
import socket
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

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
    existing : True when the file was already complete on disk and only verified.
    """

    path: Path
    size: int
    sha256: str
    resumed_from: int
    existing: bool = False


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


def _content_range(value: str | None) -> tuple[int | None, int | None]:
    """``(start, total)`` of a ``Content-Range`` header (``bytes START-END/TOTAL`` or
    ``bytes */TOTAL``); None where absent or ``*``. Raises ValueError when malformed."""
    if not value:
        return None, None
    unit, _, spec = value.strip().partition(" ")
    rng, _, total_s = spec.partition("/")
    if unit != "bytes" or not total_s:
        raise ValueError(value)
    start = None if rng == "*" else int(rng.split("-")[0])
    return start, (None if total_s == "*" else int(total_s))


def _read_meta(meta_path: Path) -> dict:
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        return {}
    return meta if isinstance(meta, dict) else {}


def _write_meta(meta_path: Path, url: str, headers, total: int | None) -> dict:
    meta = {"url": url, "total": total, "etag": headers.get("ETag"), "last_modified": headers.get("Last-Modified")}
    meta_path.write_text(json.dumps(meta) + "\n")
    return meta


def _discard(*paths: Path) -> None:
    for p in paths:
        p.unlink(missing_ok=True)


def _if_range(meta: dict) -> str | None:
    """The validator for ``If-Range``: a strong ETag, else the Last-Modified date (RFC 9110 13.1.5)."""
    etag = meta.get("etag")
    if etag and not etag.startswith("W/"):
        return etag
    return meta.get("last_modified")


def _stalled(url: str, timeout: float) -> DownloadError:
    return DownloadError(
        f"{_host(url)} did not answer within {timeout:g} s (the server accepted the connection, then stalled); "
        "try again later, or wait longer with --timeout"
    )


def _open(url: str, headers: dict, timeout: float):
    """``urlopen`` with our errors; an HTTPError is returned (not raised) for the caller to judge."""
    request = urllib.request.Request(url, headers=headers)
    try:
        return urllib.request.urlopen(request, timeout=timeout)
    except urllib.error.HTTPError as exc:
        return exc
    except urllib.error.URLError as exc:
        if isinstance(exc.reason, (socket.timeout, TimeoutError)):
            raise _stalled(url, timeout) from None
        raise DownloadError(f"cannot reach {_host(url)}: are you offline? ({exc.reason})") from None
    except (socket.timeout, TimeoutError):
        raise _stalled(url, timeout) from None
    except ConnectionError as exc:
        raise DownloadError(f"cannot reach {_host(url)}: are you offline? ({exc})") from None


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
    dest : final file path (its folder is created). ``dest + ".part"`` holds partial data,
        ``dest + ".part.json"`` what it is part of.
    size : expected size in bytes, or None.
    sha256 : expected hex SHA-256, or None.
    progress : show a tqdm progress bar (on stderr).
    timeout : seconds to wait for the server's answer and for each block of data (> 0).

    Returns
    -------
    DownloadResult

    Raises
    ------
    DownloadError
        Unreachable host ("cannot reach HOST: are you offline?"), HTTP error status, or a
        transfer cut short (the ``.part`` file is kept: call again to resume).
    ChecksumError
        Size or SHA-256 mismatch, of a new download or of the file already at ``dest``
        (the file is removed).
    """
    if not timeout > 0:
        raise ValueError(f"timeout must be > 0 seconds, got {timeout}")
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    if dest.exists():
        digest = _verify(dest, size, sha256, url)
        return DownloadResult(dest, dest.stat().st_size, digest, dest.stat().st_size, existing=True)
    part = dest.with_name(dest.name + ".part")
    meta_path = dest.with_name(dest.name + ".part.json")
    def restart():  # the part file is not a prefix of this file: start afresh
        _discard(part, meta_path)
        return 0, 0, {}

    have = part.stat().st_size if part.exists() else 0
    meta = _read_meta(meta_path) if have else {}
    resumed_from = have
    if have and (
        (size is not None and have > size)
        or (meta.get("url") not in (None, url))
        or (meta.get("total") is not None and have > meta["total"])
    ):
        have, resumed_from, meta = restart()

    while True:  # at most twice: a resume attempt the server's answer rules out, then a fresh start
        headers = {"User-Agent": "dynslam_lab-data_fetch/0.1"}
        if have:
            headers["Range"] = f"bytes={have}-"
            validator = _if_range(meta)
            if validator:
                headers["If-Range"] = validator
        response = _open(url, headers, timeout)
        if isinstance(response, urllib.error.HTTPError):
            code, reason, resp_headers = response.code, response.reason, response.headers
            response.close()
            if code == 416 and have:
                # Range not satisfiable: complete if the part file is exactly the whole file.
                try:
                    _, total = _content_range(resp_headers.get("Content-Range"))
                except ValueError:
                    total = None
                if total is None:
                    total = meta.get("total", size)
                if total == have:
                    os.replace(part, dest)
                    _discard(meta_path)
                    digest = _verify(dest, size, sha256, url)
                    return DownloadResult(dest, have, digest, resumed_from)
                have, resumed_from, meta = restart()
                continue
            raise DownloadError(f"{url}: HTTP {code} {reason}")
        status = getattr(response, "status", 200)
        if status == 206:
            content_range = response.headers.get("Content-Range")
            try:
                start, total = _content_range(content_range)
            except ValueError:
                response.close()
                raise DownloadError(f"{url}: malformed Content-Range {content_range!r}") from None
            etag = response.headers.get("ETag")
            stale = (
                start != have
                or (meta.get("total") is not None and total is not None and total != meta["total"])
                or (meta.get("etag") and etag and etag != meta["etag"])
            )
            if stale:  # the server's file is not the one the part file began
                response.close()
                have, resumed_from, meta = restart()
                continue
            mode = "ab"
        else:
            have = 0
            resumed_from = 0
            length = response.headers.get("Content-Length")
            total = int(length) if length is not None else None
            mode = "wb"
            meta = _write_meta(meta_path, url, response.headers, total)
        break

    with response:
        if size is not None and total is not None and total != size:
            _discard(part, meta_path)
            raise ChecksumError(f"{url}: server announces {total} bytes, catalog expects {size}")

        bar = None
        if progress:
            bar = tqdm(total=total, initial=have, unit="B", unit_scale=True, unit_divisor=1024,
                       desc=dest.name, leave=True)
        written = have
        try:
            with open(part, mode) as fh:
                while True:
                    try:
                        block = response.read1(CHUNK)  # what has arrived: a stall keeps the bytes before it
                    except (socket.timeout, TimeoutError):
                        raise DownloadError(
                            f"{url}: transfer stalled: no data for {timeout:g} s after {written} bytes; run again to "
                            f"resume from {part} (or wait longer with --timeout)"
                        ) from None
                    except (http.client.IncompleteRead, ConnectionError) as exc:
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
    _discard(meta_path)
    digest = _verify(dest, size, sha256, url)
    return DownloadResult(dest, written, digest, resumed_from)
