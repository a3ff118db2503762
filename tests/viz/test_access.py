"""The viewer answers only its own page: a request whose Host is not the viewer's address
(DNS rebinding) or whose Origin is another site is refused, over HTTP and WebSocket alike."""

from __future__ import annotations

import http.client

import pytest

from dynslam_lab.viz.access import allowed_hosts, refusal
from tests.fixtures.demo_run import write_demo_run


def test_allowed_hosts_of_a_loopback_server():
    a = allowed_hosts("127.0.0.1", 8080)
    assert {"127.0.0.1:8080", "localhost:8080", "[::1]:8080"} <= a
    assert "evil.example:8080" not in a and "127.0.0.1:8081" not in a
    assert "myhost:8080" in allowed_hosts("127.0.0.1", 8080, ["myhost"])
    assert "10.0.0.5:8080" in allowed_hosts("10.0.0.5", 8080)


def test_refusal_rules():
    ok = frozenset({"127.0.0.1:8080"})
    assert refusal({"Host": "127.0.0.1:8080"}, ok) is None
    assert refusal({"Host": "127.0.0.1:8080", "Origin": "http://127.0.0.1:8080"}, ok) is None
    assert "Host" in refusal({"Host": "rebind.example:8080"}, ok)
    assert "no Host" in refusal({}, ok)
    assert "Origin" in refusal({"Host": "127.0.0.1:8080", "Origin": "http://evil.example"}, ok)
    assert "Origin" in refusal({"Host": "127.0.0.1:8080", "Origin": "null"}, ok)
    assert "Origin" in refusal({"Host": "127.0.0.1:8080", "Origin": "http://127.0.0.1:9999"}, ok)
    from websockets.datastructures import Headers

    two = Headers([("Host", "127.0.0.1:8080"), ("Host", "evil.example")])
    assert "2 Host headers" in refusal(two, ok)


@pytest.fixture(scope="module")
def viewer(tmp_path_factory):
    from dynslam_lab.viz.viser_scene import SceneConfig, start_viewer

    run = write_demo_run(tmp_path_factory.mktemp("run"), n_frames=30, keyframe_every=10, n_map_points=50,
                         n_dense_points=100)
    refused = []
    server, h = start_viewer(run, config=SceneConfig(max_image_frustums=0), log=refused.append)
    yield server.get_port(), refused, server
    h.close()
    server.stop()


def _get(port, headers):
    c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        c.putrequest("GET", "/", skip_host=True)
        for k, v in headers.items():
            c.putheader(k, v)
        c.endheaders()
        r = c.getresponse()
        return r.status, r.read()
    finally:
        c.close()


def test_http_answers_its_own_host_and_refuses_a_foreign_one(viewer):
    port, refused, _ = viewer
    status, body = _get(port, {"Host": f"127.0.0.1:{port}"})
    assert status == 200 and b"<html" in body.lower()
    assert _get(port, {"Host": f"localhost:{port}"})[0] == 200
    status, body = _get(port, {"Host": f"rebind.example:{port}"})
    assert status == 403 and b"refused" in body
    status, _ = _get(port, {"Host": f"127.0.0.1:{port}", "Origin": "http://evil.example"})
    assert status == 403
    assert any("rebind.example" in r for r in refused)


def test_websocket_from_a_foreign_origin_is_refused(viewer):
    pytest.importorskip("websockets")
    import viser
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    port, _, _ = viewer
    proto = [f"viser-v{viser.__version__}"]
    with pytest.raises(InvalidStatus) as e:
        connect(f"ws://127.0.0.1:{port}/", origin="http://evil.example", subprotocols=proto, open_timeout=10)
    assert e.value.response.status_code == 403
    # DNS rebinding: the page's own origin, but a foreign Host (a raw handshake: clients set Host themselves)
    upgrade = {"Upgrade": "websocket", "Connection": "Upgrade", "Sec-WebSocket-Version": "13",
               "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Protocol": proto[0]}
    status, _ = _get(port, {"Host": f"rebind.example:{port}", "Origin": f"http://rebind.example:{port}", **upgrade})
    assert status == 403
    status, _ = _get(port, {"Host": f"127.0.0.1:{port}", "Origin": f"http://127.0.0.1:{port}", **upgrade})
    assert status == 101, "the same handshake with the viewer's own Host and Origin is accepted"
    # the viewer's own page is let in
    with connect(f"ws://127.0.0.1:{port}/", origin=f"http://127.0.0.1:{port}", subprotocols=proto, open_timeout=10) as ws:
        assert ws.subprotocol == proto[0]


def test_the_server_hook_is_found_among_viser_coroutines(viewer):
    """The cheap lookup (viser's event-loop coroutines) finds the same websockets server as the
    heap scan, and it carries the guard."""
    import gc

    import websockets.asyncio.server as wss

    from dynslam_lab.viz.access import _from_tasks, _listens_on

    port, _, server = viewer
    fast = _from_tasks(server._websock_server._background_event_loop, wss, port)
    slow = [o for o in gc.get_objects() if isinstance(o, wss.Server) and _listens_on(o, port)]
    assert fast is not None and slow == [fast]
    assert fast.process_request.__name__ == "guarded"
