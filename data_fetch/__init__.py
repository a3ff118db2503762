"""Fetch the full TUM RGB-D and Bonn RGB-D Dynamic sequences and ONNX detectors.

``python -m data_fetch list`` shows the catalog; ``python -m data_fetch get NAME --dest DIR``
downloads one item (resumable, checked), extracts archives safely, and records what was
fetched in ``DIR/manifest.json``. The toolkit itself never needs the network: its tests
and notebooks run on synthetic sequences and on the small files in ``../shared/data``.
"""

from .catalog import BASE_URLS, CATALOG, CatalogError, Entry, get_entry, url_for
from .download import ChecksumError, DownloadError, DownloadResult, download, sha256_file
from .extract import CorruptArchiveError, UnsafeArchiveError, safe_extract
from .fetch import FetchResult, fetch, read_manifest

__all__ = [
    "BASE_URLS",
    "CATALOG",
    "CatalogError",
    "Entry",
    "get_entry",
    "url_for",
    "ChecksumError",
    "DownloadError",
    "DownloadResult",
    "download",
    "sha256_file",
    "UnsafeArchiveError",
    "CorruptArchiveError",
    "safe_extract",
    "FetchResult",
    "fetch",
    "read_manifest",
]
