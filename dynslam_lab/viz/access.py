"""Who may talk to the viewer: the ``Host`` and ``Origin`` checks of ``dynslam view``.

A server on ``127.0.0.1`` is reachable by every page open in the user's browser: a page from
another site can open a WebSocket to it (browsers do not apply the same-origin policy to
WebSockets, they only send an ``Origin`` header), and a *DNS-rebinding* page (a domain that
resolves to 127.0.0.1 after the page loaded) can even read its HTTP answers as same-origin.
Both are refused here, for HTTP requests and WebSocket handshakes alike:

* ``Host`` must name the server as the user reached it: a loopback name (``127.0.0.1``,
  ``localhost``, ``[::1]``) with the server's port, or, when it listens on another address on
  purpose, that address, this machine's names, or a name given in ``extra_hosts``. A rebinding
  page sends its own domain as ``Host``: refused.
* ``Origin``, when present (browsers always send it with a WebSocket), must be same-origin:
  ``http://`` plus an allowed ``Host`` value. A foreign page sends its own origin: refused.
  Requests without ``Origin`` come from programs on this machine (or a top-level navigation),
  which could read the run folder anyway.

viser serves HTTP and WebSockets from one ``websockets`` server and exposes no request hook,
so :func:`guard_viser_server` wraps the ``process_request`` of that server (found among the
coroutines of viser's event loop, else among all live objects, by its bound port) with
:func:`refusal`; if the server cannot be found (another viser version), it raises instead of
serving unguarded.
"""

from __future__ import annotations

import asyncio
import gc
import http
import inspect
import socket
from typing import Iterable, Mapping
from urllib.parse import urlsplit

__all__ = ["allowed_hosts", "refusal", "guard_viser_server", "LOOPBACK_NAMES"]

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")
_WILDCARDS = ("0.0.0.0", "::", "")


def _machine_names() -> set[str]:
    """This machine's host names and addresses (for a server bound to all interfaces)."""
    names = {socket.gethostname(), socket.getfqdn()}
    try:
        for info in socket.getaddrinfo(socket.gethostname(), None):
            addr = info[4][0]
            names.add(f"[{addr}]" if ":" in addr else addr)
    except OSError:
        pass
    return {n.lower() for n in names if n}


def allowed_hosts(host: str, port: int, extra_hosts: Iterable[str] = ()) -> frozenset[str]:
    """The ``Host`` header values (``name:port``, lower case) a server on ``host:port`` accepts.

    Loopback names always; the bind address itself when it is not a wildcard; every name and
    address of this machine when it is (``0.0.0.0``); and ``extra_hosts`` (names, with or
    without a port).
    """
    names = set(LOOPBACK_NAMES)
    h = host.strip().lower()
    if h in _WILDCARDS:
        names |= _machine_names()
    elif h not in ("127.0.0.1", "localhost", "::1"):
        names.add(f"[{h}]" if ":" in h and not h.startswith("[") else h)
    out = {f"{n}:{int(port)}" for n in names}
    for e in extra_hosts:
        e = e.strip().lower()
        out.add(e if e.rsplit(":", 1)[-1].isdigit() and not e.endswith("]") else f"{e}:{int(port)}")
    return frozenset(out)


def _single(headers: Mapping[str, str], name: str) -> str | None:
    """The one value of header ``name`` (None when absent); ValueError when it is repeated."""
    values = headers.get_all(name) if hasattr(headers, "get_all") else (
        [headers[name]] if name in headers else [])
    if len(values) > 1:
        raise ValueError(f"{len(values)} {name} headers")
    return values[0] if values else None


def refusal(headers: Mapping[str, str], allowed: frozenset[str]) -> str | None:
    """Why a request with these headers is refused, or None when it is accepted."""
    try:
        host, origin = _single(headers, "Host"), _single(headers, "Origin")
    except ValueError as exc:
        return str(exc)
    host = (host or "").strip().lower()
    if not host:
        return "no Host header"
    if host not in allowed:
        return f"Host {host!r} is not this viewer's address"
    if origin is not None:
        o = urlsplit(origin.strip().lower())
        if o.scheme not in ("http", "https") or o.netloc != host:
            return f"Origin {origin!r} is not the viewer's own page (http://{host})"
    return None


def _listens_on(obj, port: int) -> bool:
    srv = getattr(obj, "server", None)
    return any(s.getsockname()[1] == port for s in (getattr(srv, "sockets", None) or ()))


def _from_tasks(loop, wss, port: int):
    """The server held by a coroutine running on viser's event loop (cheap: a few frames)."""
    async def scan():
        for task in asyncio.all_tasks():
            coro = task.get_coro()
            while coro is not None:
                frame = getattr(coro, "cr_frame", None)
                for value in (frame.f_locals.values() if frame is not None else ()):
                    server = value.server if isinstance(value, wss.serve) else value
                    if isinstance(server, wss.Server) and _listens_on(server, port):
                        return server
                coro = getattr(coro, "cr_await", None)
        return None

    try:
        return asyncio.run_coroutine_threadsafe(scan(), loop).result(timeout=5)
    except Exception:  # a closed loop, a time-out: fall back to the heap scan
        return None


def _websockets_server(server, port: int):
    """viser's ``websockets.asyncio.server.Server`` listening on ``port``, or None: looked up in
    the coroutines of viser's event loop, else among all live objects."""
    import websockets.asyncio.server as wss  # viser's own dependency

    loop = getattr(getattr(server, "_websock_server", None), "_background_event_loop", None)
    found = _from_tasks(loop, wss, port) if loop is not None else None
    if found is not None:
        return found
    return next((o for o in gc.get_objects() if isinstance(o, wss.Server) and _listens_on(o, port)), None)


def guard_viser_server(server, extra_hosts: Iterable[str] = (), log=None) -> frozenset[str]:
    """Refuse, on a running ``viser.ViserServer``, every request that fails :func:`refusal`.

    Parameters
    ----------
    server : the started viser server (``get_host()``, ``get_port()``).
    extra_hosts : more ``Host`` names to accept (a name the user reaches the machine by).
    log : called with one line per refused request (default: nothing).

    Returns
    -------
    The accepted ``Host`` values.

    Raises
    ------
    RuntimeError : the server's request hook was not found (it is then stopped, never left open).
    """
    port = int(server.get_port())
    allowed = allowed_hosts(server.get_host(), port, extra_hosts)
    ws = _websockets_server(server, port)
    if ws is None:
        server.stop()
        raise RuntimeError(f"viewer on port {port}: could not install the Host/Origin check (unknown viser "
                           "internals); refusing to serve without it")
    inner = ws.process_request

    def check(connection, request):
        reason = refusal(request.headers, allowed)
        if reason is None:
            return None
        if log is not None:
            log(f"refused {request.path!r}: {reason}")
        return connection.respond(http.HTTPStatus.FORBIDDEN, f"dynslam view: refused: {reason}\n")

    if inner is not None and inspect.iscoroutinefunction(inner):
        async def guarded(connection, request):
            return check(connection, request) or await inner(connection, request)
    else:
        def guarded(connection, request):
            refused = check(connection, request)
            if refused is not None:
                return refused
            return inner(connection, request) if inner is not None else None

    ws.process_request = guarded
    return allowed
