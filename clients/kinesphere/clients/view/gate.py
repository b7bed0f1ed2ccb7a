"""Who may open the view: the Host of every request and the Origin of the websocket.

The scene streams the whole fleet to whoever opens the websocket, and a browser lets any web
page open a websocket to any address: without a check, a page the operator happens to visit
could read the fleet (the websocket's ``Origin`` names that page), and a name the attacker
controls re-pointed at 127.0.0.1 (DNS rebinding) reaches a view that listens on loopback only
(the ``Host`` header names it). So every request must name a host this view answers to
(loopback names, the address it serves on, this machine's names when it serves on every
interface, and the hosts of ``--allow-origin``), and a websocket must come from the page's own
origin (``Origin`` = ``http(s)://`` + ``Host``) or an allowed one, speaking this viser's
protocol. Refusals are ``403`` with the reason.

Peers can also make the server log: viser's websocket library logs a traceback for every
connection that fails its handshake (a bare TCP connection) or sends a frame viser cannot
read. The server's log lines go through :class:`OneLinePerPeer`: one line per peer address
per interval, the exception's name and message instead of its traceback.

A value of the wrong shape in a peer's message makes viser warn with the whole value as the
warning's text, and Python's warnings registry keeps every distinct text for the life of the
process (measured: 1,000 such frames kept 1.1 MB, each also printed): those warnings are
ignored while the view serves (:func:`ignore_peer_values`).

viser builds its websocket server inside its own thread and exposes no hook, so
:func:`guarding` hands viser a ``serve`` that adds the check in front of viser's own request
handler and the logger (websockets' documented ``process_request`` and ``logger`` options),
only while the view constructs its server.
"""

from __future__ import annotations

import http
import logging
import socket
import warnings
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any, Final
from urllib.parse import urlsplit

from kinesphere.errors import KinesphereError
from kinesphere.ratelog import RateLog

log = logging.getLogger(__name__)
web_log = logging.getLogger("kinesphere.clients.view.web")
"""The websocket server's own lines (handshakes, connections), one per peer per interval."""
LOOPBACK: Final = frozenset({"localhost", "127.0.0.1", "::1"})
EVERY_S: Final = 10.0
"""Interval of the per-peer log lines."""
ANY: Final = frozenset({"", "0.0.0.0", "::"})
PEER_VALUES: Final = "viser.infra._messages"
"""The module whose warnings quote a peer's values (module text)."""


def origin_of(text: str) -> str:
    """``scheme://host[:port]`` of an ``--allow-origin`` value, lower case; malformed if it
    is not an http(s) origin."""
    parts = urlsplit(text.strip().lower())
    if parts.scheme not in ("http", "https") or not parts.hostname or parts.path.strip("/") \
            or parts.query or parts.fragment or parts.username:
        raise KinesphereError("malformed", f"--allow-origin {text!r:.80} is not an origin such "
                              "as http://lab-pc:8080")
    return f"{parts.scheme}://{parts.netloc}"


def _hostname(host: str) -> str:
    """The name in a ``Host`` header (``[::1]:8080`` -> ``::1``), lower case."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1:host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def _machine_names() -> set[str]:
    """This machine's names and addresses as its resolver knows them."""
    names = {socket.gethostname().lower(), socket.getfqdn().lower()}
    try:
        _, aliases, addresses = socket.gethostbyname_ex(socket.gethostname())
        names.update(a.lower() for a in aliases)
        names.update(addresses)
    except OSError:
        pass
    return names


def peer_of(connection: Any) -> str:
    """The address (without port) a connection comes from; ``?`` when unknown."""
    try:
        address = connection.remote_address
        return str(address[0]) if address else "?"
    except Exception:  # a connection already closed
        return "?"


class Gate:
    """The check of every request to a view served on ``host`` (module text)."""

    def __init__(self, host: str, allow: Sequence[str] = (), protocol: str = "") -> None:
        self.origins = {origin_of(a) for a in allow}
        self.hosts = set(LOOPBACK) | {_hostname(urlsplit(o).netloc) for o in self.origins}
        if host.lower() in ANY:
            self.hosts |= _machine_names()
        else:
            self.hosts.add(_hostname(host))
        self.protocol = protocol
        """The websocket subprotocol a page of this view asks for (``viser-v<version>``)."""
        self.refused = 0
        self._ratelog = RateLog(log, every=EVERY_S)

    def why_not(self, headers: Any) -> str:
        """Why a request with ``headers`` is refused; ``""`` when it may go on."""
        for name in ("Host", "Origin", "Upgrade", "Sec-WebSocket-Protocol"):
            if len(headers.get_all(name)) > 1:
                return f"{name} given twice"
        host = headers.get("Host", "")
        if _hostname(host) not in self.hosts:
            return (f"Host {host!r:.80} is not a name this view answers to (run it with "
                    f"--allow-origin http://{host:.80} to allow it)")
        if headers.get("Upgrade", "").lower() != "websocket":
            return ""
        origin = headers.get("Origin")
        same = {f"http://{host}".lower(), f"https://{host}".lower()}
        if origin is not None and origin.lower() not in same and origin.lower() not in \
                self.origins:
            return (f"a websocket from the page of {origin!r:.80}, not this view's own (add "
                    "--allow-origin to trust it)")
        offered = [p.strip() for p in headers.get("Sec-WebSocket-Protocol", "").split(",")]
        if self.protocol and self.protocol not in offered:
            return f"a websocket that does not speak {self.protocol}"
        return ""

    def check(self, connection: Any, request: Any) -> Any:
        """websockets' ``process_request``: a 403 response, or None to go on."""
        try:
            why = self.why_not(request.headers)
        except Exception as exc:  # a header websockets parsed but this check cannot read
            why = f"unreadable headers ({type(exc).__name__})"
        if not why:
            return None
        self.refused += 1
        self._ratelog(peer_of(connection), "view: refused a request from %s: %s",
                      peer_of(connection), why)
        return connection.respond(http.HTTPStatus.FORBIDDEN, f"refused: {why}\n")


class OneLinePerPeer(logging.Filter):
    """At most one line (of INFO and above) per peer address per :data:`EVERY_S`, never a
    traceback."""

    def __init__(self, every: float = EVERY_S) -> None:
        super().__init__()
        self._rate = RateLog(web_log, every=every)
        self.held = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno < logging.INFO:
            return True
        connection = getattr(record, "websocket", None)
        ok, held = self._rate.allow(peer_of(connection))
        if not ok:
            self.held += 1
            return False
        text = record.getMessage()
        if connection is not None:
            text += f" (from {peer_of(connection)})"
        if record.exc_info and record.exc_info[1] is not None:
            exc = record.exc_info[1]
            text += f": {type(exc).__name__}: {str(exc)[:200]}"
        if held:
            text += f" (+{held} more in {EVERY_S:g} s)"
        record.msg, record.args = text, ()
        record.exc_info, record.exc_text, record.stack_info = None, None, None
        return True


def ignore_peer_values() -> None:
    """From now on, the warnings viser writes quoting a peer's values are ignored (module
    text); process-wide, as Python's warning filters are."""
    warnings.filterwarnings("ignore", category=UserWarning,
                            module=PEER_VALUES.replace(".", r"\."))


@contextmanager
def guarding(gate: Gate) -> Iterator[None]:
    """While inside, a websockets server started (by viser) checks every request with
    ``gate`` before its own handler and logs through :class:`OneLinePerPeer`."""
    import websockets.asyncio.server as server

    original = server.serve
    ignore_peer_values()
    if not any(isinstance(f, OneLinePerPeer) for f in web_log.filters):
        web_log.addFilter(OneLinePerPeer())

    def serve(handler: Any, *args: Any, process_request: Any = None, **kwargs: Any) -> Any:
        def checked(connection: Any, request: Any) -> Any:
            refused = gate.check(connection, request)
            if refused is not None or process_request is None:
                return refused
            return process_request(connection, request)

        kwargs.setdefault("logger", web_log)
        return original(handler, *args, process_request=checked, **kwargs)

    server.serve = serve  # type: ignore[misc,assignment]
    try:
        yield
    finally:
        server.serve = original  # type: ignore[misc]
