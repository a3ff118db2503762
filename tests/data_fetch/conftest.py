"""A local HTTP server (127.0.0.1, free port, thread) with Range and If-Range support, for download tests."""

from __future__ import annotations

import hashlib
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest


class FileServer:
    """Serves ``files[path] = bytes``; can cut a response short to simulate an interruption."""

    def __init__(self) -> None:
        self.files: dict[str, bytes] = {}
        self.cut_after: dict[str, int] = {}  # path -> bytes sent before dropping (once)
        self.ignore_range = False
        self.ignore_if_range = False  # a server that resumes whatever the validator says
        self.send_etag = True  # ETag: a strong validator derived from the content
        self.redirects: dict[str, str] = {}  # path -> absolute path to redirect to (302)
        self.stall_before: set[str] = set()  # paths answered with silence (until close)
        self.stall_after: dict[str, int] = {}  # path -> bytes sent before falling silent (until close)
        self.release = threading.Event()  # ends every stall
        self.requests: list[tuple[str, str | None]] = []  # (path, Range header)
        self.if_ranges: list[str | None] = []  # If-Range header of each request
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args):  # keep test output clean
                pass

            def do_GET(self):
                path = self.path.lstrip("/")
                if path in server.stall_before:
                    server.release.wait(30)
                    return
                rng = self.headers.get("Range")
                server.requests.append((path, rng))
                server.if_ranges.append(self.headers.get("If-Range"))
                if path in server.redirects:
                    self.send_response(302)
                    self.send_header("Location", server.redirects[path])
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
                data = server.files.get(path)
                if data is None:
                    self.send_response(404)
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    return
                etag = f'"{hashlib.sha256(data).hexdigest()[:16]}"'
                if_range = self.headers.get("If-Range")
                if if_range and not server.ignore_if_range and if_range != etag:
                    rng = None  # the file changed since the client's partial copy: send it all (RFC 9110)
                start = 0
                if rng and not server.ignore_range:
                    start = int(rng.split("=")[1].split("-")[0])
                    if start >= len(data):
                        self.send_response(416)
                        self.send_header("Content-Range", f"bytes */{len(data)}")
                        self.send_header("Content-Length", "0")
                        self.end_headers()
                        return
                    self.send_response(206)
                    self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
                else:
                    self.send_response(200)
                body = data[start:]
                if server.send_etag:
                    self.send_header("ETag", etag)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Content-Type", "application/octet-stream")
                self.end_headers()
                if path in server.stall_after:
                    self.wfile.write(body[: server.stall_after[path]])
                    self.wfile.flush()
                    server.release.wait(30)
                    return
                cut = server.cut_after.pop(path, None)
                if cut is not None:
                    self.wfile.write(body[:cut])
                    self.wfile.flush()
                    self.close_connection = True
                    return
                self.wfile.write(body)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.port = self.httpd.server_address[1]
        self.url = f"http://127.0.0.1:{self.port}/"
        self.thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.02}, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.release.set()
        self.httpd.shutdown()
        self.httpd.server_close()
        self.thread.join(timeout=5)


@pytest.fixture
def http_server():
    srv = FileServer()
    yield srv
    srv.close()
