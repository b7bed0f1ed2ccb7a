"""What a command is allowed to do: e-stop latch, stop, deadman and the command watchdog.

Pure logic on a clock the caller passes: the agent passes its **monotonic wall clock**, so
the watchdog fires on time even when the control loop falls behind, its steps fail, or the
process was frozen (robot time would have stopped with it).

The rules (also in ``docs/protocol.md`` terms):

* ``estop=True`` halts everything in place — joints and base brake with the fastest
  jerk-limited stop — and **latches**, in the name of its sender. Wildcard puts on
  ``{prefix}/robot/*/command`` reach every robot, so one message stops the fleet. While
  latched every command is ignored except a release: a Command with ``release=True`` (and
  ``estop=False``). Ordinary commands, even with the deadman held, never release it, so a
  client that keeps streaming cannot undo an e-stop somebody else pressed.
* **A latch is its sender's.** Like the buttons of a cell's e-stop circuit, each sender's
  e-stop is a latch of its own, and only that sender's release clears it; the robot moves
  again when no latch is left. A release without a sender clears nothing. An e-stop without
  a sender (which a deployment with access control never delivers: the router vouches for
  every sender) is nobody's, so any named sender may release it. A latch whose sender is
  gone is cleared by restarting the agent, at the robot. The release only clears latches;
  its parts and drive are *not* executed, so the robot moves again only on the next command.
* **A release clears only an e-stop sent before it** (by the sender's clock, ``sent_ns``).
  Each copy of a release is sent again until every robot answers, and copies from a session
  that has ended can still be under way on another path; one arriving after its sender's next
  e-stop would otherwise clear that e-stop while ``kinesphere estop`` reported it latched.
* **An e-stop always latches.** The robot names :data:`MAX_LATCHES` senders' latches; the
  e-stop of one more sender while they are all held latches the one :data:`OVERFLOW` latch
  instead (no latch is ever evicted to make room). Nobody can say whose that latch is, so no
  release clears it: only restarting the agent, at the robot. A fleet e-stop in force comes
  back after the restart (``estops.py``), each in its sender's name.
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
from dataclasses import dataclass, field

from kinesphere.protocol import ANONYMOUS, OVERFLOW, Command

DRIVE_TTL_S = 0.5
"""Watchdog for a Drive sent with ``ttl_ms=0``: a base never drives on a single message."""
MAX_LATCHES = 16
"""Senders whose e-stops a robot latches by name; past them, :data:`OVERFLOW` latches."""


OVERFLOW_WORDS = f"more senders than the {MAX_LATCHES} it names (only a restart clears theirs)"
"""The :data:`OVERFLOW` latch in people's words."""


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
    """E-stop latches (and who latched each) and command watchdog; times are seconds."""

    deadline: float | None = None
    latches: list[str] = field(default_factory=list)
    """The senders whose e-stops are latched, first first."""
    latched_ns: dict[str, int] = field(default_factory=dict)
    """Per latch, the ``sent_ns`` of the newest e-stop it holds (its sender's clock)."""

    @property
    def estopped(self) -> bool:
        return bool(self.latches)

    @property
    def estop_by(self) -> str:
        """Who latched the e-stop ("" when not latched; the first of several)."""
        return self.latches[0] if self.latches else ""

    @property
    def overflowed(self) -> bool:
        """Whether the :data:`OVERFLOW` latch is held (only a restart clears it)."""
        return OVERFLOW in self.latches

    def holders(self) -> str:
        """Every latch's sender, for people."""
        return ", ".join(OVERFLOW_WORDS if s == OVERFLOW else s for s in self.latches)

    def latch(self, sender: str, sent_ns: int = 0) -> str:
        """Latch ``sender``'s e-stop (``""``: anonymous) sent at ``sent_ns``; the latch it
        holds now: its own, or :data:`OVERFLOW` when :data:`MAX_LATCHES` others are held
        (never evicted)."""
        who = sender or ANONYMOUS
        if who not in self.latches:
            if who == OVERFLOW or len(self.latches) - self.overflowed >= MAX_LATCHES:
                who = OVERFLOW
            if who not in self.latches:
                self.latches.append(who)
        self.latched_ns[who] = max(sent_ns, self.latched_ns.get(who, 0))
        return who

    def predates(self, cmd: Command) -> str | None:
        """The latch whose e-stop release ``cmd`` was sent before (its sender's own, or the
        nobody's latch it could clear), which stays; None when there is none."""
        for latch in (cmd.sender, ANONYMOUS):
            if latch in self.latches and cmd.sent_ns < self.latched_ns.get(latch, 0):
                return latch
        return None

    def on_command(self, cmd: Command, now: float) -> Verdict:
        """Classify ``cmd`` received at ``now`` and arm or disarm the watchdog."""
        if cmd.estop:
            self.latch(cmd.sender, cmd.sent_ns)
            self.deadline = None
            return Verdict.ESTOP
        if self.estopped:
            if cmd.release and cmd.sender and cmd.sender != OVERFLOW:
                for latch in (cmd.sender, ANONYMOUS):  # nobody's latch: any named sender
                    if latch in self.latches and cmd.sent_ns >= self.latched_ns[latch]:
                        self.latches.remove(latch)
                        del self.latched_ns[latch]
                if not self.latches:
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
