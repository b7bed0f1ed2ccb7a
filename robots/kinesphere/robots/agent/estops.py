"""Fleet e-stops in force, held by the robots themselves: a robot that starts, restarts or
reconnects while one is in force comes up latched.

An e-stop put on every robot's key (``{p}/robot/*/command``: ``kinesphere estop``, the
gamepad's e-stop button) is a **fleet e-stop**. It latches every robot that hears it; the
client that sent it exits soon after, and a robot started a minute later never heard it. So
every robot process keeps a :class:`FleetBoard`: per sender, that sender's latest fleet
e-stop or fleet release (a release put on the same key), ordered by the sender's own clock
(``sent_ns``). The board is answered on ``{p}/estop/{holder}`` (one holder per process: a
fleet host's robots share theirs) and merged from every other holder:

* at start, before the robot accepts any command (an e-stop in force latches it first);
* every :data:`SYNC_S`, and at once when the process gains a link to a router or peer (a
  reconnection: it may have missed e-stops meanwhile);

A record that is newer than what the board knew of its sender and in force latches every
robot of the process, in its sender's name, through the e-stop lane of its inbox (the same
path as a received e-stop: halted in the next step, acknowledged, logged). So a fleet e-stop
stays in force as long as one robot process that knew it runs, and a robot whose copy of the
command was lost latches within a second from the others. A newer release never unlatches a
robot by itself: only a release that reaches the robot does (what the board learns decides
only what robots that did not hear the e-stop do). Who holds the board when every robot
process has stopped: nobody; a fleet restarted whole starts unlatched.

Bounded without losing an e-stop: a board keeps :data:`MAX_FLEET_ESTOPS` records. Released
records are forgotten to make room; one in force never is. When every record is in force, the
e-stop of one more sender puts the :data:`OVERFLOW` record in force instead (in one slot kept
for it): robots latch it as their overflow latch (``safety.py``), which no release clears, and
the board never learns it released, so it stays in force until every robot process that knew
it has restarted. Names by the protocol's bounds; a reply that does not decode is ignored.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Callable

import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.protocol import (
    ANONYMOUS,
    MAX_FLEET_ESTOPS,
    OVERFLOW,
    Command,
    FleetEstop,
    FleetEstops,
    encode,
)
from kinesphere.query import get_all
from kinesphere.zconfig import undeclare

log = logging.getLogger(__name__)

SYNC_S = 1.0
"""How often a board asks the others what they know."""
LINK_CHECK_S = 0.1
"""How often a board looks for a new link (a reconnection) to ask at once."""
QUERY_S = 1.0
"""How long one round of asking waits for the others' answers."""
FLEET_SESSION = "fleet-estop"
"""The session of the e-stop a board hands its robots (in their logs and acks)."""


def newer(a: FleetEstop, b: FleetEstop | None) -> bool:
    """Whether ``a`` supersedes ``b`` (same sender): later by its clock; an e-stop wins a
    tie."""
    return b is None or a.sent_ns > b.sent_ns or (a.sent_ns == b.sent_ns and a.engaged
                                                  and not b.engaged)


def latch_command(rec: FleetEstop) -> Command:
    """The e-stop a robot acts on for a fleet e-stop in force it did not hear itself."""
    return Command(seq=0, sent_ns=rec.sent_ns, deadman=False, ttl_ms=0, estop=True, stop=True,
                   sender="" if rec.sender == ANONYMOUS else rec.sender,
                   session=FLEET_SESSION)


class FleetBoard:
    """One process's fleet e-stops (module text). ``on_latch`` callbacks run for every
    record newly in force learnt from another holder (on the board's thread)."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.session = session
        self.keys = keys
        self.holder = str(session.zid())
        self._records: OrderedDict[str, FleetEstop] = OrderedDict()
        self._lock = threading.Lock()
        self._followers: list[Callable[[FleetEstop], None]] = []
        self._queryable: zenoh.Queryable[None] | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.syncs = 0
        """Rounds of asking the others."""

    # --- what it knows ----------------------------------------------------------------------

    def in_force(self) -> list[FleetEstop]:
        """The fleet e-stops in force, oldest first."""
        with self._lock:
            return [r for r in self._records.values() if r.engaged]

    def engaged(self, sender: str) -> bool:
        """Whether ``sender`` (``""``: anonymous) has a fleet e-stop in force."""
        with self._lock:
            rec = self._records.get(sender or ANONYMOUS)
            return rec is not None and rec.engaged

    def heard(self, cmd: Command, key: str) -> None:
        """A command a robot of this process received on ``key`` (any thread): a fleet
        e-stop or a fleet release is remembered."""
        if not (cmd.estop or cmd.release) or not self.keys.is_fleet_command(key):
            return
        sender = cmd.sender or ANONYMOUS
        if cmd.estop:
            self._learn(FleetEstop(sender, True, cmd.sent_ns))
        elif cmd.sender:  # a release names its sender; it also releases nobody's e-stop
            self._learn(FleetEstop(sender, False, cmd.sent_ns))
            anonymous = self._records.get(ANONYMOUS)
            if anonymous is not None and anonymous.engaged:
                self._learn(FleetEstop(ANONYMOUS, False, max(cmd.sent_ns, anonymous.sent_ns)))

    def _learn(self, rec: FleetEstop) -> bool:
        """Keep ``rec`` if it is news; True when it puts an e-stop newly in force. A record in
        force is never forgotten (module text: the overflow record takes one past the
        bound)."""
        if rec.sender == OVERFLOW and not rec.engaged:
            return False  # nobody releases the overflow record
        with self._lock:
            old = self._records.get(rec.sender)
            if not newer(rec, old):
                return False
            if old is None and rec.sender != OVERFLOW and not self._room():
                if not rec.engaged:
                    return False  # the release of an e-stop it does not keep
                log.warning("fleet e-stops: %d senders' in force; %s's is kept as the "
                            "overflow e-stop, which only restarts clear", MAX_FLEET_ESTOPS - 1,
                            rec.sender)
                rec = FleetEstop(OVERFLOW, True, rec.sent_ns)
                old = self._records.get(OVERFLOW)
                if old is not None:
                    return False  # in force already
            self._records[rec.sender] = rec
            self._records.move_to_end(rec.sender)
            return rec.engaged and (old is None or not old.engaged)

    def _room(self) -> bool:
        """Whether a new sender's record fits (under the lock): below the bound, less the
        slot kept for the overflow record, after forgetting a released record if need be."""
        named = len(self._records) - (OVERFLOW in self._records)
        if named < MAX_FLEET_ESTOPS - 1:
            return True
        released = next((s for s, r in self._records.items() if not r.engaged), None)
        if released is None:
            return False
        del self._records[released]
        return True

    # --- sharing it -------------------------------------------------------------------------

    def follow(self, on_latch: Callable[[FleetEstop], None]) -> None:
        """Call ``on_latch`` for each fleet e-stop newly in force learnt from the others."""
        self._followers.append(on_latch)

    def declare(self) -> None:
        """Answer what this board knows on ``{p}/estop/{holder}``."""
        self._queryable = self.session.declare_queryable(
            self.keys.fleet_estops(self.holder), self._on_query)

    def _on_query(self, query: zenoh.Query) -> None:
        with query:
            with self._lock:
                known = FleetEstops(holder=self.holder, estops=list(self._records.values()))
            try:
                query.reply(self.keys.fleet_estops(self.holder), encode(known))
            except zenoh.ZError as exc:  # the asker left
                log.debug("fleet e-stops not answered: %s", exc)

    def sync(self, timeout: float = QUERY_S) -> list[FleetEstop]:
        """Ask every other holder what it knows and keep the news; the e-stops newly in force
        (each follower is told of them)."""
        fresh: list[FleetEstop] = []
        try:
            boards = get_all(self.session, self.keys.fleet_estops("*"), FleetEstops,
                             timeout=timeout)
        except KinesphereError as exc:  # the session is closing
            log.debug("fleet e-stops not asked: %s", exc)
            boards = []
        for board in boards:
            if board.holder != self.holder:
                fresh += [r for r in board.estops if self._learn(r)]
        self.syncs += 1
        for rec in fresh:
            log.warning("fleet e-stop of %s in force (sent while this process was away): "
                        "latching", rec.sender)
            for on_latch in self._followers:
                on_latch(rec)
        return fresh

    def start(self) -> None:
        """Ask the others every :data:`SYNC_S`, and at once on a new link, until
        :meth:`close`."""
        self._thread = threading.Thread(target=self._run, name="fleet-estops", daemon=True)
        self._thread.start()

    def _links(self) -> frozenset[str]:
        try:
            info = self.session.info
            return frozenset(map(str, [*info.routers_zid(), *info.peers_zid()]))
        except zenoh.ZError:
            return frozenset()

    def _run(self) -> None:
        links = self._links()
        waited = 0.0
        while not self._stop.wait(LINK_CHECK_S):
            waited += LINK_CHECK_S
            now = self._links()
            joined = bool(now - links)
            links = now
            if joined or waited >= SYNC_S:
                waited = 0.0
                self.sync()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=QUERY_S + 1.0)
        undeclare(self._queryable)
        self._queryable = None
