"""For the databank tests: small databanks, raw queries, liveliness tokens, serve processes.

Everything runs on real Zenoh sessions on ``tcp/127.0.0.1:<free port>`` with multicast
scouting off. Waits are bounded retries of a real query or liveliness events, never sleeps
standing in for synchronisation.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path

import zenoh

from kinesphere import protocol as pr
from kinesphere import zconfig
from kinesphere.deploy.watch import watch_alive
from kinesphere.keyexpr import Keys
from kinesphere.platforms.platform import load_platform
from kinesphere.services.databank.service import DatabankService
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.store import PoseRow, write_databank
from kinesphere.services.ecl.vsam import load_vsam
from support.network import OWN_KEYS, peer
from support.paths import ROOT, TOY

Raw = list[tuple[bool, bytes]]


def sparse_toy_rows(offset: float = 0.0) -> list[PoseRow]:
    """Hand-made toyarm poses: three directions of the arm, one of the tail."""
    rows = []
    for i, d in enumerate(("left-high", "forward-middle", "right-low")):
        for s in (1, 2, 3):
            rows.append(PoseRow("limb_11", "distal_11", d, s, {
                "yaw": 0.1 * i + 0.01 * s + offset, "elbow": 0.3 + 0.1 * s, "wrist": -0.1 * s}))
    rows += [PoseRow("limb_21", "distal_21", "left-middle", s, {"tail_joint": 0.5 * s})
             for s in (1, 2, 3)]
    return rows


def build_toy(path: Path, offset: float = 0.0) -> Path:
    plat = load_platform(str(TOY))
    write_databank(path, plat, load_vsam(plat), sparse_toy_rows(offset), "test")
    return path


def build_baxter(path: Path) -> Path:
    """Baxter's right arm, left-high at three sizes: what docs/protocol.md's example asks."""
    plat = load_platform("baxter")
    rows = [
        PoseRow("limb_11", "distal_11", "left-high", s, {
            "right_s0": 0.2 * s, "right_s1": -0.3 * s, "right_e0": 0.1, "right_e1": 0.5 * s,
            "right_w0": 0.0, "right_w1": 0.4, "right_w2": -0.1 * s})
        for s in (1, 2, 3)
    ]
    write_databank(path, plat, load_vsam(plat), rows, "test")
    return path


@contextmanager
def serving(ecls: Mapping[str, Ecl], replica: str,
            prepare: Callable[[DatabankService], None] | None = None,
            ) -> Iterator[tuple[DatabankService, zenoh.Session, str]]:
    """A databank service in this process serving ``ecls`` under the tests' own prefix on a
    fresh loopback hub (changed first by ``prepare``, if given), and a querier joined to the
    hub: (service, querier, the hub's endpoint), once the first platform's catalogue is
    answered."""
    with zconfig.loopback_hub() as (_hub, endpoint):
        server, client = peer(endpoint), peer(endpoint)
        svc = DatabankService(server, ecls, OWN_KEYS, replica)
        if prepare is not None:
            prepare(svc)
        try:
            with svc:
                answered(client, OWN_KEYS.catalogue(next(iter(ecls))))
                yield svc, client, endpoint
        finally:
            zconfig.close_session(client)
            zconfig.close_session(server)


def raw_get(
    session: zenoh.Session,
    key: str,
    payload: bytes | None = None,
    timeout: float = 2.0,
    target: zenoh.QueryTarget | None = None,
) -> Raw:
    """Every reply to one ``get``: (ok, payload bytes)."""
    out: Raw = []
    for reply in session.get(key, payload=payload, timeout=timeout, target=target,
                             consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is not None:
            out.append((True, reply.ok.payload.to_bytes()))
        else:
            assert reply.err is not None
            out.append((False, reply.err.payload.to_bytes()))
    return out


def answered(session: zenoh.Session, key: str, payload: bytes | None = None,
             timeout: float = 10.0) -> Raw:
    """Retry ``get`` until someone replies (declarations travel asynchronously)."""
    deadline = time.monotonic() + timeout
    while True:
        replies = raw_get(session, key, payload)
        if replies or time.monotonic() > deadline:
            return replies
        time.sleep(0.02)  # pause between retries of a real query, not synchronisation


def error_code(replies: Raw) -> str:
    """The code of the single error reply."""
    assert len(replies) == 1, replies
    ok, data = replies[0]
    assert not ok, pr.decode_any(data)
    return pr.decode(data, pr.Error).code


def pose_of(replies: Raw) -> pr.Pose:
    """The single good reply, as a Pose."""
    assert len(replies) == 1, replies
    ok, data = replies[0]
    assert ok, pr.decode(data, pr.Error)
    return pr.decode(data, pr.Pose)


class Tokens:
    """Databank liveliness tokens seen by a subscriber (with history), as events: the
    product's own watch (:func:`kinesphere.deploy.watch.watch_alive`, what ``up`` and
    ``status`` see), waited on by replica name."""

    def __init__(self, session: zenoh.Session, keys: Keys = OWN_KEYS) -> None:
        self._alive, self._subs = watch_alive(session, keys)

    def wait(self, name: str, present: bool = True, timeout: float = 20.0) -> bool:
        return self._alive.wait_for(lambda a: (name in a.databanks) == present, timeout)

    def close(self) -> None:
        zconfig.undeclare(*self._subs)


def cli(*args: str) -> list[str]:
    """argv of the kinesphere CLI run as a module, like a user's shell would."""
    return [sys.executable, "-m", "kinesphere.cli", *args]


@contextmanager
def serve_process(args: Sequence[str], name: str) -> Iterator[subprocess.Popen[str]]:
    """``kinesphere databank serve ARGS --replica NAME`` as a subprocess; killed on exit."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        cli("databank", "serve", "--replica", name, *args),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env,
    )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=20)
