"""Who may open ``kinesphere view``: Host and Origin checked, one log line per peer.

A real view (viser) serves on a free loopback port, fed by the test hub's session; the
tests speak to it with the websockets library and raw sockets, as another web page or a
scanner would. Before: a websocket from ``Origin: http://evil.example`` received the live
scene, and 500 bare TCP connections wrote 879 KB of tracebacks.
"""

from __future__ import annotations

import importlib
import logging
import socket
import time
import typing
import warnings
from collections.abc import Iterator

import msgspec
import pytest
import viser
import websockets.exceptions
from websockets.sync.client import connect
from websockets.typing import Origin, Subprotocol

from kinesphere import zconfig
from kinesphere.clients.view import gate
from kinesphere.clients.view.app import FleetView
from support.network import OWN_KEYS, Hub

PROTOCOL = Subprotocol(f"viser-v{viser.__version__}")
CONNECTIONS = 500


@pytest.fixture
def view(request: pytest.FixtureRequest, hub: Hub) -> Iterator[FleetView]:
    allow = getattr(request, "param", ())
    v = FleetView(hub.session, OWN_KEYS, port=zconfig.free_port(), allow_origins=allow)
    try:
        yield v
    finally:
        v.close()


def _scene(port: int, origin: str | None, host: str | None = None) -> int:
    """Bytes of scene the view sends a websocket opened with ``origin`` and ``host`` (the
    name in the URL, so in Host; the socket goes to 127.0.0.1 whatever the name) within a
    second; raises InvalidStatus when the handshake is refused."""
    got = 0
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    with connect(f"ws://{host or f'127.0.0.1:{port}'}", sock=sock,
                 origin=None if origin is None else Origin(origin),
                 subprotocols=[PROTOCOL], open_timeout=5) as ws:
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            try:
                got += len(ws.recv(timeout=max(0.01, deadline - time.monotonic())))
            except TimeoutError:
                break
    return got


def _status(exc: pytest.ExceptionInfo[websockets.exceptions.InvalidStatus]) -> int:
    return exc.value.response.status_code


def test_a_page_of_another_origin_gets_no_scene(view: FleetView) -> None:
    port = view.port
    assert _scene(port, f"http://127.0.0.1:{port}") > 0  # the view's own page
    assert _scene(port, None) > 0  # a program, not a browser: no page can drive it
    for origin in ("http://evil.example", f"http://127.0.0.1:{port + 1}", "null"):
        with pytest.raises(websockets.exceptions.InvalidStatus) as err:
            _scene(port, origin)
        assert _status(err) == 403
    assert view.gate.refused == 3


def test_a_host_name_the_view_does_not_answer_to_is_refused(view: FleetView) -> None:
    """DNS rebinding: the attacker's name re-pointed at 127.0.0.1 names itself in Host."""
    port = view.port
    host = f"evil.example:{port}"
    with pytest.raises(websockets.exceptions.InvalidStatus) as err:
        _scene(port, f"http://{host}", host)
    assert _status(err) == 403
    for name in (f"evil.example:{port}", f"localhost:{port}"):
        with socket.create_connection(("127.0.0.1", port), timeout=5) as s:
            s.sendall(f"GET / HTTP/1.1\r\nHost: {name}\r\n\r\n".encode())
            head = s.recv(64).decode(errors="replace")
        assert head.startswith("HTTP/1.1 403" if "evil" in name else "HTTP/1.1 200"), head


@pytest.mark.parametrize("view", [("http://lab-pc:8080",)], indirect=True)
def test_an_allowed_origin_opens_the_view(view: FleetView) -> None:
    port = view.port
    assert _scene(port, "http://lab-pc:8080", f"lab-pc:{port}") > 0
    with pytest.raises(websockets.exceptions.InvalidStatus):
        _scene(port, "http://lab-pc:9090", f"lab-pc:{port}")


def _quiet_lines(caplog: pytest.LogCaptureFixture) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.name.startswith(("websockets", "kinesphere.clients"
                                                            ".view", "asyncio", "viser"))]


def test_bare_connections_and_bad_frames_log_one_line_per_peer(
    view: FleetView, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    port = view.port
    for _ in range(CONNECTIONS):  # connect and leave without a word
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
    frames: list[bytes | str] = [
        b"", b"\x00", b"\xc1" * 64, "text, not bytes", msgspec.msgpack.encode([1, 2, 3]),
        msgspec.msgpack.encode({"type": "NoSuchMessage"}), msgspec.msgpack.encode(
            {"type": "ViewerCameraMessage", "wxyz": "x"}), b"\x91" * 5000,
        msgspec.msgpack.encode({"type": "GuiUpdateMessage", "id": "nope", "updates": 7}),
        bytes(range(256)) * 64,
    ]
    with warnings.catch_warnings(record=True) as heard:
        gate.ignore_peer_values()  # as the view did: pytest set its filters anew for the test
        for frame in frames:  # ten kinds of malformed frames, each on its own connection
            try:
                with connect(f"ws://127.0.0.1:{port}",
                             origin=Origin(f"http://127.0.0.1:{port}"),
                             subprotocols=[PROTOCOL], open_timeout=5) as ws:
                    ws.send(frame)
                    ws.recv(timeout=1.0)
            except (websockets.exceptions.ConnectionClosed, TimeoutError):
                pass
    assert not [w for w in heard if "[viser]" in str(w.message)], heard[:1]
    # the view still serves its own page afterwards
    assert _scene(port, f"http://127.0.0.1:{port}") > 0
    lines = _quiet_lines(caplog)
    text = "\n".join(r.getMessage() for r in lines)
    assert not any(r.exc_info for r in lines) and "Traceback" not in text, text[:2000]
    from_peer = [r for r in lines if r.levelno >= logging.INFO and "127.0.0.1" in
                 r.getMessage()]
    assert len(from_peer) <= 2, text[:2000]  # one per 10 s interval: the test takes a few s
    assert len(text) < 2000, len(text)


def test_a_peers_values_viser_warns_about_are_neither_kept_nor_printed() -> None:
    """viser's reader of a peer's message warns with the whole value it could not fit
    (``gate`` module text): ignored while the view serves, so a peer sending ever other
    values grows no registry and writes nothing. Called as viser's server calls it, on values
    a peer chose, before and after :func:`gate.ignore_peer_values`."""
    messages = importlib.import_module(gate.PEER_VALUES)
    shape = typing.Tuple[float, float, float, float]  # noqa: UP006 (viser's own annotation)

    def read(values: int) -> tuple[int, int]:
        """Warnings heard and registry entries kept for ``values`` distinct values."""
        registry = messages.__dict__.setdefault("__warningregistry__", {})
        with warnings.catch_warnings(record=True) as heard:
            for i in range(values):
                messages._prepare_for_deserialization([i, "y" * 1000], shape)
        kept = [k for k in registry if isinstance(k, tuple) and "[viser]" in str(k[0])]
        return len([w for w in heard if "[viser]" in str(w.message)]), len(kept)

    with warnings.catch_warnings():  # pytest keeps its own filters: this test's are its own
        warnings.simplefilter("default")
        assert read(50) == (50, 50)  # each value heard and kept
        gate.ignore_peer_values()
        messages.__dict__["__warningregistry__"].clear()
        assert read(200) == (0, 0)
