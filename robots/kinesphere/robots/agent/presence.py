"""One robot per id: a robot says where it runs, and a second agent with a live id refuses to
start.

Two agents with one id would share its keys: both obey its commands, their states interleave
(``status`` shows one row flipping between two bodies) and ``send`` reports one answer for
two robots. So before an agent declares anything else it asks ``{p}/robot/{id}/presence``
(and the id's liveliness token, for agents that do not answer there): any answer refuses the
start (``id_taken``, exit 2) naming where the other runs. Then it answers there itself
(:class:`~kinesphere.protocol.Presence`: platform, host, pid, start time) and asks once more
a moment later (``zconfig.QUIET_S``, for a claim made at the same moment to arrive): two
agents that started together both see each other then, and the later one (by claim time,
then session id) gives way. The id is free again as soon as the first agent
leaves (its answer goes with it; a process killed outright is forgotten after Zenoh's link
lease, 10 s).
"""

from __future__ import annotations

import datetime
import logging
import os
import socket
import time

import msgspec
import zenoh

from kinesphere import zconfig
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.protocol import Presence, encode
from kinesphere.query import get_all
from kinesphere.zconfig import undeclare

log = logging.getLogger(__name__)

ASK_S = 1.0
"""How long the question "does this id run?" waits for answers."""


def where(p: Presence) -> str:
    """``youbot on host robot-pc (pid 4242), up since 10:42:07``."""
    since = datetime.datetime.fromtimestamp(p.started_ns / 1e9).strftime("%H:%M:%S")
    return f"{p.platform} on host {p.host} (pid {p.pid}), up since {since}"


def taken(robot_id: str, other: Presence | None) -> KinesphereError:
    """The refusal: where the other runs, and what to do."""
    there = (where(other) if other is not None
             else "a robot with that id holds its liveliness token")
    return KinesphereError(
        "id_taken", f"robot id {robot_id!r} is already running: {there}; give this robot "
        "another --id, or stop that one (a process killed outright frees its id within "
        "10 s)")


class Claim:
    """This process's answer for one robot id, once no other runs it (module text)."""

    def __init__(self, session: zenoh.Session, keys: Keys, robot_id: str,
                 platform: str) -> None:
        self.session = session
        self.keys = keys
        self.robot_id = robot_id
        self.me = Presence(robot_id=robot_id, platform=platform,
                           host=socket.gethostname().split(".")[0][:64], pid=os.getpid(),
                           started_ns=time.time_ns(), zid=str(session.zid()))
        self._queryable: zenoh.Queryable[None] | None = None

    def _others(self) -> list[Presence]:
        try:
            answers = get_all(self.session, self.keys.presence(self.robot_id), Presence,
                              timeout=ASK_S)
        except KinesphereError as exc:
            log.debug("presence of %s not asked: %s", self.robot_id, exc)
            return []
        return [p for p in answers if p != self.me]

    def _token_alive(self) -> bool:
        try:
            replies = self.session.liveliness().get(self.keys.alive_robot(self.robot_id),
                                                    timeout=ASK_S)
            return any(r.ok is not None for r in replies)
        except zenoh.ZError:
            return False

    def take(self) -> None:
        """Refuse if another agent runs this id, else answer for it (module text)."""
        others = self._others()
        if others:
            raise taken(self.robot_id, others[0])
        if self._token_alive():
            raise taken(self.robot_id, None)
        self.me = msgspec.structs.replace(self.me, started_ns=time.time_ns())  # claimed now
        self._queryable = self.session.declare_queryable(
            self.keys.presence(self.robot_id), self._on_query)
        time.sleep(zconfig.QUIET_S)  # a claim made at the same moment reaches us meanwhile
        first = min([self.me, *self._others()], key=lambda p: (p.started_ns, p.zid))
        if first != self.me:  # another started at the same moment, a little earlier
            self.release()
            raise taken(self.robot_id, first)

    def _on_query(self, query: zenoh.Query) -> None:
        with query:
            try:
                query.reply(self.keys.presence(self.robot_id), encode(self.me))
            except zenoh.ZError as exc:
                log.debug("presence not answered: %s", exc)

    def release(self) -> None:
        undeclare(self._queryable)
        self._queryable = None
