"""The control lease: a robot obeys one operator at a time (after Spot's lease service).

Pure logic on the robot's monotonic clock. The rules (``docs/protocol.md``, "Control leases"):

* The lease belongs to a ``sender`` (a command without one counts as :data:`ANONYMOUS`).
* A **motion** command (deadman held: parts, a drive, or nothing, which brakes the base)
  from the holder keeps the lease; while the lease is free it acquires it; from anyone else it
  is refused with ``lease_held`` naming the holder. A deadman release (``deadman=false``)
  needs the lease too, but never acquires it: an idle operator's pad cannot hold someone
  else's robot. A command without ``session`` (a client older than leases) never acquires it
  implicitly either: it is obeyed while the lease is free and refused while another holds it,
  so clients that cannot release a lease do not lock each other out.
* ``lease: "acquire"`` asks for it (refused while another holds it), ``"take"`` takes it over
  (logged; the previous holder is told), ``"release"`` gives it back.
* Any command from the holder keeps it alive; silent for :data:`LEASE_TIMEOUT_S`, it expires.
* **E-stop, stop and e-stop release are obeyed from anyone**, lease or not: they only ever
  stop motion (a release moves nothing).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from kinesphere.protocol import ANONYMOUS, Command, LeaseAction

log = logging.getLogger(__name__)

LEASE_TIMEOUT_S = 3.0
"""A holder silent this long (robot's monotonic clock) loses the lease. A gamepad streams at
30 Hz while engaged, so 3 s is a hundred missed commands; a one-shot ``send`` keeps the robot
for 3 s after its last command."""


@dataclass(frozen=True)
class LeaseVerdict:
    """What the lease says about one command: obey it or not, and who holds it now.

    ``taken_from`` names the previous holder when this command took the lease over.
    """

    allowed: bool
    holder: str
    taken_from: str = ""


def holder_name(cmd: Command) -> str:
    return cmd.sender or ANONYMOUS


class Lease:
    """Who may move the robot now."""

    def __init__(self, timeout_s: float = LEASE_TIMEOUT_S) -> None:
        self.timeout_s = timeout_s
        self.holder = ""
        self._heard = 0.0

    def expire(self, now: float) -> str:
        """Free a lease whose holder went silent; the expired holder's name, or ""."""
        if self.holder and now - self._heard > self.timeout_s:
            gone, self.holder = self.holder, ""
            log.info("lease of %r expired after %.1f s of silence", gone, self.timeout_s)
            return gone
        return ""

    @property
    def expires(self) -> float:
        """When a silent holder loses the lease (inf while it is free)."""
        return self._heard + self.timeout_s if self.holder else math.inf

    def touch(self, cmd: Command, now: float) -> None:
        """``cmd`` was heard (and refused for another reason): it keeps its sender's lease."""
        if self.holder and self.holder == holder_name(cmd):
            self._heard = now

    def check(self, cmd: Command, now: float) -> LeaseVerdict:
        """Apply the rules above to ``cmd`` received at ``now``."""
        self.expire(now)
        who = holder_name(cmd)
        mine = self.holder == who
        if mine:
            self._heard = now
        action = cmd.lease
        if cmd.estop or cmd.stop or cmd.release:
            return LeaseVerdict(True, self.holder)
        if action is LeaseAction.RELEASE:
            if mine:
                self.holder = ""
            return LeaseVerdict(True, self.holder)
        if action is LeaseAction.TAKE and not mine:
            previous, self.holder, self._heard = self.holder, who, now
            if previous:
                log.warning("lease taken over by %r from %r", who, previous)
            return LeaseVerdict(True, who, previous)
        if not self.holder and ((cmd.deadman and cmd.session) or action is LeaseAction.ACQUIRE):
            self.holder, self._heard = who, now
            return LeaseVerdict(True, who)
        return LeaseVerdict(mine or not self.holder, self.holder)
