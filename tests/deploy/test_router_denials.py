"""The router's denial log: bounded per identity and in total, tables pruned, TLS refusals
reported with the peer (from the kernel's notices of closed connections)."""

from __future__ import annotations

import socket
import struct
import time

from kinesphere.deploy import denials as dn
from kinesphere.deploy.router import endpoint_ports
from kinesphere.deploy.sockets import ClosedPeers, parse_destroyed
from support.clock import ManualClock

ACL = "zenoh::net::routing::interceptor::access_control"


def line(msg: str, target: str = ACL, level: str = "TRACE", thread: str = "rx-0 ThreadId(9)"
         ) -> str:
    return f"2026-01-01T00:00:00.000000Z {level} {thread} {target}: {msg}"


def deny(f: dn.DenialFilter, zid: str, cn: str | None, key: str) -> None:
    subject = f"Interface(lo)+CertCommonName({cn})+Transport(Tls)+{zid}" if cn else ""
    on = f" on {subject}" if subject else ""
    f.feed(line(f"{zid}{on} is unauthorized to Put (ingress) on {key}"))
    f.feed(line("Msg intercepted!", "zenoh::net::routing::interceptor"))


def test_a_flood_of_distinct_keys_is_bounded_per_identity() -> None:
    """Before: 3,000 distinct keys -> 3,000 lines, and per-key records never pruned."""
    clock = ManualClock()
    lines: list[str] = []
    f = dn.DenialFilter(report=lines.append, passthrough=lambda _: None, clock=clock)
    for i in range(3000):
        deny(f, "abc1", "nao-1", f"kinesphere/robot/x{i}/state")
    assert len(lines) == dn.BURST and f.denials == 3000
    assert len(f._repeats) <= dn.MAX_ENTRIES
    deny(f, "abc2", "operator", "kinesphere/ecl/x/record")  # another identity is not muted
    assert lines[-1].startswith("access denied: Put (ingress) on kinesphere/ecl/x/record by "
                                "CN=operator")
    clock.now = dn.WINDOW_S
    deny(f, "abc1", "nao-1", "kinesphere/robot/y/state")
    assert lines[-1].endswith(f"(+{3000 - dn.BURST} more denials of CN=nao-1 in 10 s)")


def test_sessions_without_certificates_share_one_total_budget() -> None:
    clock = ManualClock()
    lines: list[str] = []
    f = dn.DenialFilter(report=lines.append, passthrough=lambda _: None, clock=clock)
    for i in range(3000):
        deny(f, f"{i:x}ff", None, f"k/{i}")
    assert len(lines) <= dn.TOTAL_BURST
    assert len(f._subjects) <= dn.MAX_ENTRIES and len(f._budget) <= dn.MAX_ENTRIES


def test_tls_refusals_become_denials_naming_the_peer() -> None:
    claims: list[tuple[float, float]] = []
    answers = [["10.0.0.7:40312"], []]

    def claim(since: float, timeout: float) -> list[str]:
        claims.append((since, timeout))
        return answers.pop(0)

    lines: list[str] = []
    other: list[str] = []
    f = dn.DenialFilter(report=lines.append, passthrough=other.append, claim=claim,
                        background=False)
    f.feed(line("peer sent no certificates. Hint: increase the system open file limit.",
                dn.TLS_TARGET, "WARN", "acc-0 ThreadId(5)"))
    assert lines == ["access denied: TLS handshake refused (peer sent no certificates) from "
                     "10.0.0.7:40312"]
    f.feed(line("invalid peer certificate: BadSignature. Hint: increase the system open file "
                "limit.", dn.TLS_TARGET, "WARN", "acc-0 ThreadId(5)"))
    assert lines[-1].endswith("(invalid peer certificate: BadSignature) from an unknown peer")
    assert f.refusals == 2 and len(claims) == 2 and other == []
    # a port probe (connect, close) is no refusal: Zenoh's warning passes through
    f.feed(line("tls handshake eof. Hint: increase the system open file limit.",
                dn.TLS_TARGET, "WARN", "acc-0 ThreadId(5)"))
    assert f.refusals == 2 and "tls handshake eof" in other[-1]


def test_closed_connections_are_announced_by_the_kernel() -> None:
    """The sock_diag destroy group names both ends of every closed TCP connection."""
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        closed = ClosedPeers([port])
        assert closed.start(), "cannot join SKNLGRP_INET_TCP_DESTROY"
        try:
            since = time.monotonic()
            client = socket.create_connection(("127.0.0.1", port))
            peer = f"127.0.0.1:{client.getsockname()[1]}"
            accepted, _ = server.accept()
            client.close()
            accepted.close()
            assert closed.claim(since, timeout=10.0) == [peer]
            assert closed.claim(since, timeout=0.0) == []  # claimed once
        finally:
            closed.close()


def test_destroy_messages_parse() -> None:
    def msg(family: int, sport: int, dport: int, dst: bytes) -> bytes:
        body = bytes([family, 7, 0, 0]) + struct.pack(">HH", sport, dport) + bytes(16) + \
            dst.ljust(16, b"\0") + bytes(32)
        return struct.pack("=IHHII", 16 + len(body), 20, 0, 0, 0) + body

    data = (msg(socket.AF_INET, 7447, 40312, socket.inet_pton(socket.AF_INET, "10.0.0.7"))
            + msg(socket.AF_INET6, 7447, 80, socket.inet_pton(socket.AF_INET6, "2001:db8::1")))
    assert parse_destroyed(data) == [(7447, "10.0.0.7:40312"), (7447, "[2001:db8::1]:80")]
    assert parse_destroyed(b"\x05\x00") == []


def test_endpoint_ports() -> None:
    assert endpoint_ports(["tls/0.0.0.0:7447", "tcp/[::]:7448#iface=eth0"]) == [7447, 7448]
    assert endpoint_ports({"router": ["tcp/[::]:7447"], "peer": []}) == [7447]
