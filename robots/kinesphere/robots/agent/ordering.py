"""In which order the agent acts on commands, and which it drops: the rules in one place.

1. **Plausible.** A ``sent_ns`` more than :data:`MAX_CLOCK_AHEAD_S` ahead of the robot's clock
   is ``malformed`` (a sender's broken clock, or a message made to outrank every later one).
2. **Stale.** Per ``(sender, session)``, a command whose ``seq`` is not above the newest seen
   from that pair is stale: dropped, acknowledged ``stale``. A fresh session starts a new
   order. Version-1 senders send no session: for them a command is stale only if it is also
   no later by ``sent_ns``, so a restarted client (seq from 0, a newer clock) counts.
3. **Expired.** A command whose TTL (``ttl_ms``; 0.5 s for a drive without one; none for
   ``ttl_ms: 0``) ran out before the robot acts on it is dropped, acknowledged ``expired``.
   Its age is the time since receipt on the robot's monotonic clock, plus how much later than
   its pair's quickest command it arrived: ``(received - sent_ns)`` minus the smallest such
   difference seen from the pair. That needs no synchronised clocks (a constant offset
   between sender and robot cancels) and catches commands that queued up while the robot
   was frozen (SIGSTOP, a stalled host), which Zenoh delivers only when it runs again, so
   their receipt time alone looks fresh. The first command of a pair is judged by receipt
   alone; a sender whose clock steps back by more than a TTL starts a new session.
4. Rules 2 and 3 never drop an e-stop, a stop or a deadman release: those only stop motion.
   Stale and expired commands are counted (``RobotState.dropped``).
5. **Waiting.** A command whose pose is not cached waits for the databank under a ticket. Any
   later command that moves or halts the robot overtakes it; the databank's answer to an
   overtaken ticket is dropped.
6. **Acted on.** ``last_seq`` (``RobotState.last_command_seq``) is the last command acted on:
   at once for commands that need no pose, on resolution for those that do.

The pair table is bounded by count, and each entry by the protocol's name lengths, so by
bytes too (least recently heard pairs are forgotten first).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import NamedTuple

from kinesphere.errors import KinesphereError
from kinesphere.protocol import Command
from kinesphere.robots.agent.safety import DRIVE_TTL_S

MAX_SENDERS = 1024
"""``(sender, session)`` pairs remembered (each at most 2 x 64 characters: ~0.3 MB in all)."""
MAX_CLOCK_AHEAD_S = 60.0
"""How far a command's ``sent_ns`` may lie ahead of the robot's clock."""


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
    transit_ns: int
    """The smallest ``received - sent_ns`` seen from this pair (rule 3)."""


class Ordering:
    """Stale commands, the one waiting for the databank, the last acted on."""

    def __init__(self, max_senders: int = MAX_SENDERS) -> None:
        self.last_seq = -1
        self.dropped = 0
        """Commands dropped as stale or expired since start."""
        self.max_senders = max_senders
        self._pairs: OrderedDict[tuple[str, str], _Pair] = OrderedDict()
        self._ticket = 0
        self._waiting: Waiting | None = None

    def __len__(self) -> int:
        return len(self._pairs)

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
        key = (cmd.sender, cmd.session)
        transit = item.wall_ns - cmd.sent_ns
        pair = self._pairs.get(key)
        if pair is None:
            pair = self._pairs[key] = _Pair(-1, 0, transit)
            while len(self._pairs) > self.max_senders:
                self._pairs.popitem(last=False)
        self._pairs.move_to_end(key)
        pair.transit_ns = min(pair.transit_ns, transit)
        if cmd.seq <= pair.seq and (cmd.session or cmd.sent_ns <= pair.sent_ns):
            if not exempt:
                self.dropped += 1
                return KinesphereError("stale", f"seq {cmd.seq} is not newer than {pair.seq} "
                                       f"from {cmd.sender or 'this sender'}")
        else:
            pair.seq, pair.sent_ns = cmd.seq, cmd.sent_ns
        ttl = ttl_s(cmd)
        age = ((now_ns - item.mono_ns) + (transit - pair.transit_ns)) / 1e9
        if ttl > 0.0 and age > ttl and not exempt:
            self.dropped += 1
            return KinesphereError("expired", f"{age * 1e3:.0f} ms old, ttl {ttl * 1e3:.0f} ms")
        return None

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
