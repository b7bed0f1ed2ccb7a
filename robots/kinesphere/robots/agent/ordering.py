"""In which order the agent acts on commands, and which it drops: the rules in one place.

1. **Plausible.** A ``sent_ns`` more than :data:`MAX_CLOCK_AHEAD_S` ahead of the robot's clock
   is ``malformed`` (a sender's broken clock, or a message made to outrank every later one).
2. **Stale.** Per ``(sender, session)``, a command whose ``seq`` is not above the newest seen
   from that pair is stale: dropped, acknowledged ``stale``. A fresh session starts a new
   order. Version-1 senders send no session: for them a command is stale only if it is also
   no later by ``sent_ns``, so a restarted client (seq from 0, a newer clock) counts. A
   ``seq`` more than :data:`SEQ_WINDOW` past the pair's newest (or past it for a pair's first
   command) is stale too and is not remembered: nobody can push a session's order to the end
   of the numbers and silence it (a client told ``stale`` starts a new session).
3. **Expired.** A command whose TTL (``ttl_ms``; 0.5 s for a drive without one; none for
   ``ttl_ms: 0``) ran out before the robot acts on it is dropped, acknowledged ``expired``.
   Its age is the time since receipt on the robot's monotonic clock, plus how much later than
   the quickest command of its sender's clock it arrived: ``(received - sent_ns)`` minus the
   smallest such difference seen from that ``(sender, clock)`` (``Command.clock`` names the
   sender's host clock; without it, the session's). That needs no synchronised clocks (a
   constant offset between sender and robot cancels) and catches commands that queued up
   while the robot was frozen (SIGSTOP, a stalled host), which Zenoh delivers only when it
   runs again, so their receipt time alone looks fresh, whichever session they belong to:
   the offset is the clock's, learnt from its first command. A clock heard for the first
   time has no offset yet: if its command arrived during (or just after) a stall of the
   control loop, the stall counts as its age. A clock that steps back by more than a TTL
   has its commands expire until they have been late for :data:`REBASE_S`, then the robot
   takes its new offset (a backlog after a stall arrives at once, never for that long).
4. Rules 2 and 3 never drop an e-stop, a stop or a deadman release: those only stop motion.
   Stale and expired commands are counted (``RobotState.dropped``).
5. **Waiting.** A command whose pose is not cached waits for the databank under a ticket. Any
   later command that moves or halts the robot overtakes it; the databank's answer to an
   overtaken ticket is dropped.
6. **Acted on.** ``last_seq`` (``RobotState.last_command_seq``) is the last command acted on:
   at once for commands that need no pose, on resolution for those that do.

The pair and clock tables are bounded by count, and each entry by the protocol's name
lengths, so by bytes too (least recently heard entries are forgotten first).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import NamedTuple

from kinesphere.errors import KinesphereError
from kinesphere.lru import Lru
from kinesphere.protocol import Command
from kinesphere.robots.agent.safety import DRIVE_TTL_S

MAX_SENDERS = 1024
"""``(sender, session)`` pairs remembered (each at most 2 x 64 characters: ~0.3 MB in all)."""
MAX_CLOCK_AHEAD_S = 60.0
"""How far a command's ``sent_ns`` may lie ahead of the robot's clock."""
SEQ_WINDOW = 1 << 20
"""How far past its session's newest a ``seq`` may jump (9.7 h of a 30 Hz stream)."""
REBASE_S = 2.0
"""How long a clock's commands must all arrive late before the robot takes its new offset."""
STALL_GRACE_S = 0.25
"""After a stall of the control loop, how long a command of an unknown clock may still have
queued during it (the network thread and the loop wake in either order)."""

log = logging.getLogger(__name__)


class Received(NamedTuple):
    """A decoded command with the robot's clocks at receipt, in ns: monotonic, and the wall
    clock (taken from the monotonic one, so a stepped system clock does not age commands),
    and the step during which it arrived. (A named tuple: one is made per command in the
    network callback, on the way to the command's first step.)"""

    cmd: Command
    mono_ns: int
    wall_ns: int
    tick: int = 0
    """The agent's step count when it arrived."""


@dataclass(frozen=True)
class Waiting:
    """A command waiting for the databank: its ticket, and the base heading at receipt (a
    translation is in the body frame of the moment the command arrived)."""

    ticket: int
    cmd: Command
    yaw: float | None


def ttl_s(cmd: Command) -> float:
    """The command's time to live in s (0: none); a drive always has one."""
    ttl = cmd.ttl_ms / 1000.0
    return DRIVE_TTL_S if cmd.drive is not None and ttl <= 0.0 else ttl


def _exempt(cmd: Command) -> bool:
    """Commands that only stop motion are never dropped (rule 4)."""
    return cmd.estop or cmd.stop or not cmd.deadman


@dataclass
class _Pair:
    seq: int
    sent_ns: int


@dataclass
class _Clock:
    """What the robot knows of one sender's clock."""

    transit_ns: int
    """The smallest ``received - sent_ns`` seen from it (rule 3)."""
    late_since_ns: int | None = None
    """Receipt (monotonic) of the first of an unbroken run of commands expired by it."""


class Ordering:
    """Stale commands, the one waiting for the databank, the last acted on."""

    def __init__(self, max_senders: int = MAX_SENDERS) -> None:
        self.last_seq = -1
        self.dropped = 0
        """Commands dropped as stale or expired since start."""
        self.max_senders = max_senders
        self._pairs: Lru[tuple[str, str], _Pair] = Lru(max_senders)
        self._clocks: Lru[tuple[str, str], _Clock] = Lru(max_senders)
        self._stall: tuple[int, int] | None = None
        self._ticket = 0
        self._waiting: Waiting | None = None

    def __len__(self) -> int:
        return len(self._pairs)

    def stalled(self, start_ns: int, end_ns: int) -> None:
        """The control loop did not run from ``start_ns`` to ``end_ns`` (monotonic): what
        arrived meanwhile from a clock never heard may be that old (rule 3)."""
        self._stall = (start_ns, end_ns)

    def admit(self, item: Received, now_ns: int) -> KinesphereError | None:
        """Rules 1 to 4 for a command processed at ``now_ns`` (monotonic): None to act on it,
        else why it is dropped. A command that is not stale becomes its pair's newest."""
        cmd = item.cmd
        exempt = _exempt(cmd)
        ahead = (cmd.sent_ns - item.wall_ns) / 1e9
        if ahead > MAX_CLOCK_AHEAD_S:  # an e-stop is obeyed all the same, but not remembered
            return None if exempt else KinesphereError(
                "malformed", f"sent_ns lies {ahead:.0f} s ahead of the robot's clock (at most "
                f"{MAX_CLOCK_AHEAD_S:g} s): check the sender's clock")
        pair = self._pairs.get((cmd.sender, cmd.session))
        newest = -1 if pair is None else pair.seq
        if cmd.seq > newest + SEQ_WINDOW:  # obeyed if it only stops, never remembered
            if exempt:
                return None
            self.dropped += 1
            return KinesphereError("stale", f"seq {cmd.seq} jumps more than {SEQ_WINDOW} past "
                                   f"{newest} in this session: start a new session")
        if pair is None:
            pair = self._pairs.put((cmd.sender, cmd.session), _Pair(-1, 0))
        if cmd.seq <= pair.seq and (cmd.session or cmd.sent_ns <= pair.sent_ns):
            if not exempt:
                self.dropped += 1
                return KinesphereError("stale", f"seq {cmd.seq} is not newer than {pair.seq} "
                                       f"from {cmd.sender or 'this sender'}")
        else:
            pair.seq, pair.sent_ns = cmd.seq, cmd.sent_ns
        age_ns = (now_ns - item.mono_ns) + self._lateness(item)
        ttl = ttl_s(cmd)
        if ttl > 0.0 and age_ns / 1e9 > ttl and not exempt:
            self.dropped += 1
            return KinesphereError("expired", f"{age_ns / 1e6:.0f} ms old, ttl "
                                   f"{ttl * 1e3:.0f} ms")
        return None

    def _lateness(self, item: Received) -> int:
        """How much later than its clock's quickest command ``item`` arrived, in ns (rule 3)."""
        cmd = item.cmd
        transit = item.wall_ns - cmd.sent_ns
        key = (cmd.sender, cmd.clock or f"session:{cmd.session}")
        clock = self._clocks.get(key)
        if clock is None:
            self._clocks.put(key, _Clock(transit))
            stall = self._stall
            if stall is not None and stall[0] < item.mono_ns <= stall[1] + STALL_GRACE_S * 1e9:
                return stall[1] - stall[0]
            return 0
        clock.transit_ns = min(clock.transit_ns, transit)
        late = transit - clock.transit_ns
        ttl = ttl_s(cmd)
        if ttl <= 0.0 or _exempt(cmd):
            return late
        if late / 1e9 <= ttl:
            clock.late_since_ns = None
        elif clock.late_since_ns is None:
            clock.late_since_ns = item.mono_ns
        elif (item.mono_ns - clock.late_since_ns) / 1e9 >= REBASE_S:
            log.info("the clock of %s stepped back by %.1f s: its commands are timed from its "
                     "new offset", cmd.sender or "a sender", late / 1e9)
            clock.transit_ns, clock.late_since_ns = transit, None
            return 0
        return late

    def acted(self, seq: int) -> None:
        """Rule 6: ``seq`` was acted on (moved, halted, or rejected with an error)."""
        self.last_seq = seq

    def wait(self, cmd: Command, yaw: float | None) -> tuple[int, Waiting | None]:
        """Rule 5: ``cmd`` waits for the databank; its ticket and the command it overtook."""
        overtaken = self.overtake()
        self._waiting = Waiting(self._ticket, cmd, yaw)
        return self._ticket, overtaken

    def overtake(self) -> Waiting | None:
        """Rule 5: whatever waits no longer applies (returned, for its acknowledgement)."""
        self._ticket += 1
        overtaken, self._waiting = self._waiting, None
        return overtaken

    def answer(self, ticket: int) -> Waiting | None:
        """The command the answer to ``ticket`` is for, or None when it was overtaken."""
        waiting = self._waiting
        if waiting is None or waiting.ticket != ticket:
            return None
        self._waiting = None
        return waiting

    @property
    def waiting(self) -> Waiting | None:
        return self._waiting
