"""The gamepad's side of the control lease (robots obey one operator at a time).

A robot leases itself to the first sender whose motion command finds the lease free, keeps it
while that sender keeps talking and frees it after :data:`LEASE_TIMEOUT_S` of silence
(``docs/protocol.md``, "Control leases"). The gamepad therefore acquires on engage (its first
command does), keeps the lease alive between gestures with a lease-only command every
:data:`KEEPALIVE_S` on the robots that name it as their holder, and gives it back when it
leaves a target or exits. With ``--take`` (or the take button) it takes the lease over from
another operator explicitly; the robot logs it and tells the previous holder.
"""

from __future__ import annotations

from collections.abc import Mapping

from kinesphere.clients import targets as tg
from kinesphere.clients.link import RobotLink, Seen, Sequencer
from kinesphere.protocol import AckStage, LeaseAction

LEASE_TIMEOUT_S = 3.0
"""The robots' lease expiry (the agent's ``LEASE_TIMEOUT_S``)."""
KEEPALIVE_S = 1.0
"""How often an idle gamepad renews the leases it holds: well within the expiry."""


class LeaseKeeper:
    """Acquire (or take) on engage, keep alive while idle, release on leaving a target."""

    def __init__(self, link: RobotLink, seq: Sequencer, take: bool = False) -> None:
        self.link = link
        self.seq = seq
        self.take = take
        self.fresh = True
        """The next engaged command starts an engagement (it carries ``take`` with --take)."""
        self._used: set[tg.Target] = set()
        self._renewed = float("-inf")

    def action_for_command(self, target: tg.Target) -> LeaseAction:
        """The lease action of the next motion command to ``target`` (engaged)."""
        first = self.fresh
        self.fresh = False
        self._used.add(target)
        return LeaseAction.TAKE if first and self.take else LeaseAction.NONE

    def held(self, targeted: Mapping[str, Seen]) -> list[str]:
        """The targeted robots that say this operator holds their lease."""
        me = self.seq.sender
        return sorted(r for r, seen in targeted.items() if seen.state.lease_holder == me)

    def idle(self, target: tg.Target, targeted: Mapping[str, Seen], now: float) -> None:
        """Between gestures: renew the lease on the robots that say we hold it."""
        self.fresh = True
        if now - self._renewed >= KEEPALIVE_S and self.held(targeted):
            self.link.put(target.keys(self.link.keys), self.seq.lease(LeaseAction.ACQUIRE))
            self._renewed = now

    def take_over(self, target: tg.Target) -> None:
        """Take the lease of ``target``'s robots from whoever holds it (the take button)."""
        self._used.add(target)
        self.link.put(target.keys(self.link.keys), self.seq.lease(LeaseAction.TAKE))

    def release(self, target: tg.Target, targeted: Mapping[str, Seen]) -> None:
        """Give ``target``'s lease back if this operator used it or a robot says we hold it."""
        if target in self._used or self.held(targeted):
            self.link.put(target.keys(self.link.keys), self.seq.lease(LeaseAction.RELEASE))
        self._used.discard(target)
        self.fresh = True

    def refused(self, targeted: Mapping[str, Seen]) -> dict[str, str]:
        """Targeted robots whose newest answer to us is a ``lease_held`` refusal: why."""
        return {
            rid: answer.ack.detail or f"{answer.ack.lease_holder} holds this robot's lease"
            for rid, answer in self.link.last_answers().items()
            if rid in targeted
            and answer.ack.stage == AckStage.REJECTED
            and answer.ack.code == "lease_held"
        }
