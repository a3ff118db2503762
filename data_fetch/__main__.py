"""``python -m data_fetch list|info|get``: the command line of the downloader.

Examples::

    python -m data_fetch list --kind bonn
    python -m data_fetch get fr3_walking_xyz --dest ~/data/tum
    python -m data_fetch get yolox_nano --dest models
    python -m data_fetch get yolov8n_seg          # prints the export command (AGPL-3.0)
"""

from __future__ import annotations

import argparse
import sys

from .catalog import CATALOG, CatalogError, get_entry, url_for
from .download import DownloadError
from .extract import UnsafeArchiveError
from .fetch import fetch

KINDS = ("tum", "bonn", "model", "export")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m data_fetch",
        description="Fetch TUM RGB-D / Bonn RGB-D Dynamic sequences and ONNX detectors.",
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    ls = sub.add_parser("list", help="list the catalog")
    ls.add_argument("--kind", choices=KINDS, help="only entries of this kind")
    info = sub.add_parser("info", help="show one entry (URL, licence, checksum)")
    info.add_argument("name")
    get = sub.add_parser("get", help="download (and extract) one entry")
    get.add_argument("name")
    get.add_argument("--dest", default="data", help="destination folder (default ./data)")
    get.add_argument("--no-extract", action="store_true", help="keep archives packed")
    get.add_argument("--quiet", action="store_true", help="no progress bar")
    get.add_argument("--timeout", type=float, default=30.0, metavar="S",
                     help="seconds to wait for the server's answer and for each block of data (default 30)")
    return p


def _list(kind: str | None) -> int:
    rows = [e for e in CATALOG.values() if kind is None or e.kind == kind]
    width = max(len(e.name) for e in rows)
    for e in rows:
        where = "export command" if e.kind == "export" else e.path
        print(f"{e.name:<{width}}  {e.kind:<6}  {where}")
    print(f"\n{len(rows)} entries; `python -m data_fetch info NAME` for URL and licence")
    return 0


def _info(name: str) -> int:
    e = get_entry(name)
    print(f"name:    {e.name}\nkind:    {e.kind}\nlicence: {e.licence}")
    if e.kind != "export":
        print(f"url:     {url_for(e)}")
        print(f"size:    {e.size if e.size is not None else 'unknown (recorded at fetch)'}")
        print(f"sha256:  {e.sha256 or 'unknown (recorded at fetch in manifest.json)'}")
    print(f"note:    {e.note}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "list":
            return _list(args.kind)
        if args.command == "info":
            return _info(args.name)
        if args.command == "get":
            if not args.timeout > 0:
                parser.error(f"--timeout must be > 0 seconds, got {args.timeout}")
            res = fetch(args.name, args.dest, extract=not args.no_extract, progress=not args.quiet, timeout=args.timeout)
            print(res.message)
            return 0
    except (CatalogError, DownloadError, UnsafeArchiveError, ValueError, OSError) as exc:
        print(f"data_fetch: error: {exc}", file=sys.stderr)
        return 1
    parser.print_help()
    return 2


if __name__ == "__main__":
    sys.exit(main())
