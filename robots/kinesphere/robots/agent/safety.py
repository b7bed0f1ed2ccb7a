"""What a command is allowed to do: e-stop latch, stop, deadman and the command watchdog.

Pure logic on a clock the caller passes: the agent passes its **monotonic wall clock**, so
the watchdog fires on time even when the control loop falls behind, its steps fail, or the
process was frozen (robot time would have stopped with it).

The rules (also in ``docs/protocol.md`` terms):

* ``estop=True`` halts everything in place — joints and base brake with the fastest
  jerk-limited stop — and **latches**. Wildcard puts on ``{prefix}/robot/*/command`` reach
  every robot, so one message stops the fleet. While latched every command is ignored except
  the release: a Command with ``release=True`` (and ``estop=False``). Ordinary commands, even
  with the deadman held, never release it, so a client that keeps streaming cannot undo an
  e-stop somebody else pressed. The release only clears the latch; its parts and drive are
  *not* executed, so the robot moves again only on the next command.
* ``stop=True`` halts everything in place the same way, without latching.
* ``deadman=False`` means the operator let go: everything brakes to rest and holds; the
  command's parts and drive are ignored.
* Watchdog: after a moving command, if no newer command arrives within ``ttl_ms`` (measured
  from receipt on the wall clock), everything brakes to rest and holds. ``ttl_ms=0`` disables
  it for poses, but a Drive always has one (:data:`DRIVE_TTL_S` when the command gives none):
  the base moves only for as long as fresh commands keep arriving. Zenoh's liveliness lease is
  seconds long, so this watchdog, not liveliness, is what stops a robot whose client died.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from kinesphere.protocol import Command

ANONYMOUS = "anonymous"
"""Who a command without ``sender`` is, in ``estop_by`` and ``lease_holder``."""

DRIVE_TTL_S = 0.5
"""Watchdog for a Drive sent with ``ttl_ms=0``: a base never drives on a single message."""


class Verdict(enum.Enum):
    """What the control loop does with a command."""

    MOVE = "move"  # resolve the parts, drive the base
    ESTOP = "estop"  # halt everything, latched
    LATCHED = "latched"  # ignored: e-stop latched
    RELEASE = "release"  # latch cleared, nothing moves yet
    STOP = "stop"  # halt everything
    DEADMAN = "deadman"  # operator let go: halt and hold


@dataclass
class Safety:
    """E-stop latch (and who latched it) and command watchdog; times are seconds."""

    estopped: bool = False
    deadline: float | None = None
    estop_by: str = ""
    """The sender whose e-stop is latched ("" when not latched)."""

    def on_command(self, cmd: Command, now: float) -> Verdict:
        """Classify ``cmd`` received at ``now`` and arm or disarm the watchdog."""
        if cmd.estop:
            self.estopped = True
            self.estop_by = cmd.sender or ANONYMOUS
            self.deadline = None
            return Verdict.ESTOP
        if self.estopped:
            if cmd.release:
                self.estopped = False
                self.estop_by = ""
                return Verdict.RELEASE
            return Verdict.LATCHED
        if cmd.stop:
            self.deadline = None
            return Verdict.STOP
        if not cmd.deadman:
            self.deadline = None
            return Verdict.DEADMAN
        ttl = cmd.ttl_ms / 1000.0
        if cmd.drive is not None and ttl <= 0.0:
            ttl = DRIVE_TTL_S
        self.deadline = now + ttl if ttl > 0.0 else None
        return Verdict.MOVE

    def expired(self, now: float) -> bool:
        """True once when the watchdog runs out (the loop then halts the robot)."""
        if self.deadline is not None and now >= self.deadline:
            self.deadline = None
            return True
        return False
