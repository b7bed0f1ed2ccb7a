"""Who was just refused: the peers of TCP connections to the router's ports as they close.

Zenoh logs a failed TLS handshake (no certificate, another CA, plain TCP) as a warning that
names no peer, at every log level. The kernel does know: Linux announces every TCP socket it
destroys on the sock_diag netlink group ``SKNLGRP_INET_TCP_DESTROY`` (what ``ss -E`` shows;
no privilege needed), with both addresses. :class:`ClosedPeers` listens there and keeps the
recent peers of the listen ports, and the denial log claims those that closed right after a
refusal. Elsewhere (or if the group cannot be joined) peers are reported as unknown.
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Collection
from typing import Final

log = logging.getLogger(__name__)

NETLINK_SOCK_DIAG: Final = 4
SKNLGRP_INET_TCP_DESTROY: Final = 1
_HEADER = struct.Struct("=IHHII")  # nlmsghdr: length, type, flags, seq, pid
KEEP_S: Final = 10.0
"""How long a closed connection's peer stays claimable."""
MAX_KEPT: Final = 1024


def parse_destroyed(data: bytes) -> list[tuple[int, str]]:
    """(local port, ``peer ip:port``) of each socket in a sock_diag netlink datagram
    (``inet_diag_msg`` records: family, state, timer, retrans, then ports and addresses)."""
    out = []
    off = 0
    while off + _HEADER.size <= len(data):
        length = _HEADER.unpack_from(data, off)[0]
        if length < _HEADER.size or off + length > len(data):
            break
        body = data[off + _HEADER.size : off + length]
        if len(body) >= 40 and body[0] in (socket.AF_INET, socket.AF_INET6):
            family = body[0]
            sport, dport = struct.unpack_from(">HH", body, 4)
            raw = body[24 : 24 + (4 if family == socket.AF_INET else 16)]
            host = socket.inet_ntop(family, raw)
            if family == socket.AF_INET6 and host.startswith("::ffff:") and "." in host:
                host = host[7:]
            out.append((sport, f"[{host}]:{dport}" if ":" in host else f"{host}:{dport}"))
        off += (length + 3) & ~3
    return out


class ClosedPeers:
    """Peers of connections to ``ports`` that the kernel destroyed in the last KEEP_S s."""

    def __init__(self, ports: Collection[int]) -> None:
        self.ports = frozenset(ports)
        self._closed: deque[tuple[float, str]] = deque(maxlen=MAX_KEPT)
        self._cond = threading.Condition()
        self._sock: socket.socket | None = None

    def start(self) -> bool:
        """Join the destroy group on a daemon thread; False where that is not possible."""
        if not self.ports or not hasattr(socket, "AF_NETLINK"):
            return False
        try:
            sock = socket.socket(socket.AF_NETLINK, socket.SOCK_DGRAM, NETLINK_SOCK_DIAG)
            sock.bind((0, 1 << (SKNLGRP_INET_TCP_DESTROY - 1)))
        except OSError as exc:
            log.info("closed connections not watched (%s): refused peers stay unknown", exc)
            return False
        self._sock = sock
        threading.Thread(target=self._run, name="closed-peers", daemon=True).start()
        return True

    def _run(self) -> None:
        assert self._sock is not None
        while True:
            try:
                data = self._sock.recv(65536)
            except OSError:  # closed, or the receive buffer overflowed: keep listening
                if self._sock.fileno() < 0:
                    return
                continue
            now = time.monotonic()
            peers = [peer for port, peer in parse_destroyed(data) if port in self.ports]
            if peers:
                with self._cond:
                    self._closed.extend((now, p) for p in peers)
                    self._cond.notify_all()

    def claim(self, since: float, timeout: float) -> list[str]:
        """Peers closed at or after ``since`` (monotonic), waiting up to ``timeout`` s for
        one; each is returned once."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                cutoff = time.monotonic() - KEEP_S
                while self._closed and self._closed[0][0] < cutoff:
                    self._closed.popleft()
                found = [p for t, p in self._closed if t >= since]
                if found or not self._cond.wait(max(0.0, deadline - time.monotonic())):
                    break
            self._closed = deque(((t, p) for t, p in self._closed if t < since),
                                 maxlen=MAX_KEPT)
        return sorted(set(found))

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
