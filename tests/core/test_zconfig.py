"""Zenoh configs and real sessions on loopback, with multicast scouting off."""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
import zenoh

from kinesphere import protocol as pr
from kinesphere import zconfig as zc
from kinesphere.errors import KinesphereError
from support.network import OWN_KEYS


def get(config: zenoh.Config, key: str) -> object:
    return json.loads(config.get_json(key))


def test_defaults_are_peer_without_multicast() -> None:
    c = zc.session_config()
    assert get(c, "mode") == "peer"
    assert get(c, "scouting/multicast/enabled") is False
    assert get(c, "connect/endpoints") == []


def test_arguments_are_applied() -> None:
    c = zc.session_config(
        "client",
        listen=[],
        connect=["tcp/127.0.0.1:7447"],
        scouting=True,
        gossip=False,
        lease_ms=3000,
    )
    assert get(c, "mode") == "client"
    assert get(c, "connect/endpoints") == ["tcp/127.0.0.1:7447"]
    assert get(c, "scouting/multicast/enabled") is True
    assert get(c, "scouting/gossip/enabled") is False
    assert get(c, "transport/link/tx/lease") == 3000


def test_config_file_is_the_base(tmp_path: Path) -> None:
    explicit = tmp_path / "explicit.json5"
    explicit.write_text('{mode: "client", scouting: {multicast: {enabled: true}}}')
    c = zc.session_config(config_file=explicit)
    assert get(c, "mode") == "client"
    assert get(c, "scouting/multicast/enabled") is True  # the file asked for it
    assert get(zc.session_config("router", config_file=explicit), "mode") == "router"
    silent = tmp_path / "silent.json5"
    silent.write_text('{connect: {endpoints: ["tcp/127.0.0.1:7447"]}}')
    c = zc.session_config(config_file=silent)
    assert get(c, "scouting/multicast/enabled") is False  # Zenoh's default would be on
    assert get(c, "mode") == "peer"
    assert get(c, "connect/endpoints") == ["tcp/127.0.0.1:7447"]


@pytest.mark.parametrize(
    "kwargs",
    [
        {"mode": "server"},
        {"connect": ["nonsense"]},
        {"listen": ["no-protocol"]},
        {"lease_ms": 0},
        {"config_file": "/nonexistent/zenoh.json5"},
    ],
)
def test_bad_config_is_malformed(kwargs: dict[str, object]) -> None:
    config: Callable[..., object] = zc.session_config  # as a caller without types calls it
    with pytest.raises(KinesphereError) as info:
        config(**kwargs)
    assert info.value.code == "malformed"
    assert " at /" not in info.value.message  # Rust source locations are trimmed


def test_free_port_is_bindable() -> None:
    port = zc.free_port()
    assert 0 < port < 65536
    with socket.socket() as sock:
        sock.bind((zc.LOOPBACK_HOST, port))
    assert zc.loopback_endpoint(port) == f"tcp/127.0.0.1:{port}"


def test_free_ports_lie_outside_the_ephemeral_range_and_pass_over_bound_ones() -> None:
    low, high = map(int, zc.EPHEMERAL_RANGE.read_text().split())
    held = []
    try:
        for _ in range(20):  # each listening, as a router on it would be
            port = zc.free_port()
            assert not low <= port <= high, (port, low, high)
            sock = socket.socket()
            held.append(sock)
            sock.bind((zc.LOOPBACK_HOST, port))
            sock.listen()
        assert len({s.getsockname()[1] for s in held}) == len(held)
    finally:
        for sock in held:
            sock.close()


def test_a_probe_passes_over_a_port_another_process_listens_on() -> None:
    first = zc.free_port()
    ports = zc._probed_ports()
    assert ports is not None
    following = ports[(ports.index(first) + 1) % len(ports)]
    with socket.socket() as sock:  # the next port this process would probe, taken
        sock.bind((zc.LOOPBACK_HOST, following))
        sock.listen()
        assert zc.free_port() not in (first, following)


def test_taken_port_is_unavailable() -> None:
    with zc.loopback_hub() as (_hub, endpoint):
        with pytest.raises(KinesphereError) as info:
            zc.open_session(zc.session_config(listen=[endpoint], scouting=False))
        assert info.value.code == "unavailable"


def test_put_reaches_subscriber_of_other_session() -> None:
    received: list[pr.Command] = []
    arrived = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        received.append(pr.decode(sample.payload, pr.Command))
        arrived.set()

    with zc.loopback_pair() as (hub, peer):
        assert [str(z) for z in peer.info.peers_zid()] == [str(hub.zid())]  # nobody else
        sub = hub.declare_subscriber(OWN_KEYS.command("*"), on_sample)
        pub = peer.declare_publisher(OWN_KEYS.command("r1"))
        assert zc.wait_matching(pub, timeout=5.0)
        cmd = pr.Command(seq=1, sent_ns=5, deadman=True, ttl_ms=200, sender="t")
        pub.put(pr.encode(cmd))
        assert arrived.wait(5.0)
        assert received == [cmd]
        zc.undeclare(pub, sub)
    assert hub.is_closed() and peer.is_closed()


def test_two_peers_talk_through_a_hub_peer() -> None:
    """Gossip lets peers joined to one hub reach each other; multicast stays off."""
    arrived = threading.Event()
    with zc.loopback_hub() as (_hub, endpoint):
        with (
            zc.session(config=zc.loopback_config(endpoint)) as a,
            zc.session(config=zc.loopback_config(endpoint)) as b,
        ):
            sub = b.declare_subscriber("kstest/x", lambda s: arrived.set())
            pub = a.declare_publisher("kstest/x")
            assert zc.wait_matching(pub, timeout=5.0)
            pub.put(b"1")
            assert arrived.wait(5.0)
            zc.undeclare(pub, sub)


def test_unconnected_session_sees_nothing() -> None:
    """With multicast off, a session that connects nowhere finds no one."""
    with (
        zc.loopback_hub() as (hub, _endpoint),
        zc.session(zc.session_config(listen=[zc.LOOPBACK_ANY_PORT], scouting=False)) as lonely,
    ):
        sub = hub.declare_subscriber("kstest/lonely")
        pub = lonely.declare_publisher("kstest/lonely")
        assert not zc.wait_matching(pub, timeout=0.5)
        assert lonely.info.peers_zid() == []
        zc.undeclare(pub, sub)


def test_queryable_answers_ok_and_err() -> None:
    pose = pr.Pose(
        platform="baxter",
        limb="limb_11",
        origin="distal_11",
        direction="left-high",
        size=2.0,
        joints={"right_s0": 0.5},
        k_id=4,
        p_id=2,
    )

    def serve(query: zenoh.Query) -> None:
        with query:  # finishes the query, or every get waits for its timeout
            parsed = OWN_KEYS.parse_pose_key(str(query.key_expr))
            if parsed.limb == pose.limb:
                query.reply(query.key_expr, pr.encode(pose))
            else:
                err = pr.Error(code="unknown_limb", message=f"no limb {parsed.limb!r}")
                query.reply_err(pr.encode(err))

    with zc.loopback_pair() as (hub, peer):
        queryable = hub.declare_queryable(OWN_KEYS.pose_wildcard("baxter"), serve)
        querier = peer.declare_querier(
            OWN_KEYS.pose_wildcard("baxter"), consolidation=zenoh.ConsolidationMode.NONE,
            timeout=5.0
        )
        assert zc.wait_matching(querier, timeout=5.0)

        key = OWN_KEYS.pose("baxter", "limb_11", "distal_11", "left-high", 2)
        replies = list(peer.get(key, consolidation=zenoh.ConsolidationMode.NONE, timeout=5.0))
        assert len(replies) == 1 and replies[0].ok is not None
        assert str(replies[0].ok.key_expr) == key
        assert pr.decode(replies[0].ok.payload, pr.Pose) == pose

        bad = OWN_KEYS.pose("baxter", "tail", "distal_11", "left-high", 2)
        replies = list(peer.get(bad, consolidation=zenoh.ConsolidationMode.NONE, timeout=5.0))
        assert len(replies) == 1 and replies[0].err is not None and replies[0].ok is None
        exc = pr.error_from_reply(replies[0].err.payload)
        assert (exc.code, exc.message) == ("unknown_limb", "no limb 'tail'")
        zc.undeclare(querier, queryable)
    assert hub.is_closed() and peer.is_closed()
