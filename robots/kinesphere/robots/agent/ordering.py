"""In which order the agent acts on commands: the rules in one place.

1. **Stale.** Per ``(sender, session)``, a command whose ``seq`` is not above the newest seen
   from that pair is stale and dropped; e-stop and stop never are. A fresh session starts a
   new order. Version-1 senders send no session: for them a command is stale only if it is
   also no later by ``sent_ns``, so a restarted client (seq from 0, a newer clock) counts.
   The table is bounded (least recently heard pairs forgotten first).
2. **Waiting.** A command whose pose is not cached waits for the databank under a ticket. Any
   later command that moves or halts the robot overtakes it; the databank's answer to an
   overtaken ticket is dropped.
3. **Acted on.** ``last_seq`` (``RobotState.last_command_seq``) is the last command acted on:
   at once for commands that need no pose, on resolution for those that do.
4. **Moving.** A pose applied in a control step is the ``moving`` command until that step ran
   (the latency probe of the benchmarks; the ``moving`` ack).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

from kinesphere.protocol import Command

MAX_SENDERS = 1024
"""``(sender, session)`` pairs remembered for ordering (each at most 2 x 64 characters)."""


@dataclass(frozen=True)
class Waiting:
    """A command waiting for the databank: its ticket, and the base heading at receipt (a
    translation is in the body frame of the moment the command arrived)."""

    ticket: int
    cmd: Command
    yaw: float | None


class Ordering:
    """Stale commands, the one waiting for the databank, the last acted on."""

    def __init__(self, max_senders: int = MAX_SENDERS) -> None:
        self.last_seq = -1
        self.dropped = 0
        """Commands dropped as stale since start."""
        self.max_senders = max_senders
        self._newest: OrderedDict[tuple[str, str], tuple[int, int]] = OrderedDict()
        self._ticket = 0
        self._waiting: Waiting | None = None
        self._moving: Command | None = None

    def stale(self, cmd: Command) -> bool:
        """Rule 1; a command that is not stale becomes its pair's newest."""
        pair = (cmd.sender, cmd.session)
        newest = self._newest.get(pair)
        if newest is not None and cmd.seq <= newest[0] and not (cmd.estop or cmd.stop):
            if cmd.session or cmd.sent_ns <= newest[1]:
                self.dropped += 1
                return True
        self._newest[pair] = (cmd.seq, cmd.sent_ns)
        self._newest.move_to_end(pair)
        while len(self._newest) > self.max_senders:
            self._newest.popitem(last=False)
        return False

    def acted(self, seq: int) -> None:
        """Rule 3: ``seq`` was acted on (moved, halted, or rejected with an error)."""
        self.last_seq = seq

    def wait(self, cmd: Command, yaw: float | None) -> tuple[int, Waiting | None]:
        """Rule 2: ``cmd`` waits for the databank; its ticket and the command it overtook."""
        overtaken = self.overtake()
        self._waiting = Waiting(self._ticket, cmd, yaw)
        return self._ticket, overtaken

    def overtake(self) -> Waiting | None:
        """Rule 2: whatever waits no longer applies (returned, for its acknowledgement)."""
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

    def applied(self, cmd: Command) -> None:
        """Rule 4: ``cmd``'s pose is the target from the next step on."""
        self._moving = cmd

    def stepped(self) -> Command | None:
        """Rule 4: the command whose first step just ran, once."""
        moving, self._moving = self._moving, None
        return moving
