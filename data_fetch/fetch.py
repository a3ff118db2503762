"""Fetch one catalog entry: download, verify, extract, record in the manifest.

``DEST/manifest.json`` maps each fetched name to ``{url, file, size, sha256, sha256_source,
licence, fetched_at, extracted_files}``. When the catalog knows no SHA-256 for an entry, a
later fetch of the same name is checked against the digest recorded here: a re-run verifies
the file already on disk (a damaged copy is removed and reported), and a new download is
compared with it (a changed file on the server is reported, not silently accepted).

An archive that turns out corrupt when extracted is removed (it is of no use, and a
download resumed onto a wrong prefix is the usual cause) and not recorded in the manifest;
the error names the file and says to run again.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from .catalog import Entry, get_entry, url_for
from .download import ChecksumError, download
from .extract import CorruptArchiveError, safe_extract

__all__ = ["FetchResult", "fetch", "read_manifest", "MANIFEST"]

MANIFEST = "manifest.json"


@dataclass(frozen=True)
class FetchResult:
    """Outcome of :func:`fetch`.

    Attributes
    ----------
    entry : the catalog entry.
    file : downloaded file (None for an ``export`` entry).
    sha256 : its digest (None for an ``export`` entry).
    extracted : extracted files (empty when not an archive or ``extract=False``).
    message : a human-readable line (for ``export`` entries: the command to run).
    """

    entry: Entry
    file: Path | None
    sha256: str | None
    extracted: list[Path]
    message: str


def read_manifest(dest: str | Path) -> dict:
    """The manifest of a destination folder (empty dict if none)."""
    path = Path(dest) / MANIFEST
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from None


def _write_manifest(dest: Path, manifest: dict) -> None:
    tmp = dest / (MANIFEST + ".tmp")
    tmp.write_text(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    tmp.replace(dest / MANIFEST)


def fetch(name: str, dest: str | Path = "data", extract: bool = True, progress: bool = True,
          timeout: float = 30.0) -> FetchResult:
    """Download catalog entry ``name`` into ``dest`` (and extract it if an archive).

    Parameters
    ----------
    name : catalog key (``python -m data_fetch list``).
    dest : destination folder; archives are extracted into it, the archive itself is kept
        in ``dest/downloads/``; models are written to ``dest/NAME.onnx``.
    extract : extract archives after download.
    progress : show a progress bar.
    timeout : seconds to wait for the server's answer and for each block of data.

    Returns
    -------
    FetchResult

    Raises
    ------
    CatalogError, DownloadError, ChecksumError, UnsafeArchiveError, CorruptArchiveError
    """
    entry = get_entry(name)
    if entry.kind == "export":
        return FetchResult(entry, None, None, [], f"{entry.name}: {entry.note}")
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    manifest = read_manifest(dest)
    known_sha = entry.sha256 or manifest.get(entry.name, {}).get("sha256")
    filename = Path(entry.path).name
    target = dest / "downloads" / filename if entry.is_archive else dest / filename
    url = url_for(entry)
    try:
        result = download(url, target, size=entry.size, sha256=known_sha, progress=progress, timeout=timeout)
    except ChecksumError as exc:
        if entry.sha256 is None and known_sha is not None:
            raise ChecksumError(
                f"{exc} (the digest was recorded in {dest / MANIFEST} by an earlier fetch; "
                "delete that entry to accept the new file)"
            ) from None
        raise
    extracted: list[Path] = []
    if extract and entry.is_archive:
        try:
            extracted = safe_extract(result.path, dest)
        except CorruptArchiveError as exc:
            result.path.unlink(missing_ok=True)
            raise CorruptArchiveError(f"{exc}; removed it, run again to download it afresh") from None
    manifest[entry.name] = {
        "url": url,
        "file": str(result.path.relative_to(dest)),
        "size": result.size,
        "sha256": result.sha256,
        "sha256_source": "catalog" if entry.sha256 else ("manifest" if known_sha else "recorded at fetch"),
        "licence": entry.licence,
        "fetched_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "extracted_files": len(extracted),
    }
    _write_manifest(dest, manifest)
    msg = f"{entry.name}: {result.size} bytes, sha256 {result.sha256}"
    if result.existing:
        checked = {"catalog": "matches the catalog", "manifest": f"matches {dest / MANIFEST}"}
        verdict = checked.get(manifest[entry.name]["sha256_source"], "nothing to check it against yet")
        msg += f" (already downloaded; {verdict})"
    if extracted:
        msg += f"; extracted {len(extracted)} files into {dest}"
    return FetchResult(entry, result.path, result.sha256, extracted, msg)
