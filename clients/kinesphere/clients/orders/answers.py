"""What became of the commands a command-line client sent: per robot, from the robots' acks.

``send``, ``play``, ``estop`` and ``lease`` know whom they addressed (:func:`addressed`: the
robot named, or the live robots a group or ``all`` reaches, by liveliness and the groups in
their states), wait for those robots' acks (:func:`wait`), print one line per robot
(:func:`report`) and exit non-zero unless every addressed robot accepted (:func:`exit_code`).
A robot that never answers is reported as "no acknowledgement": the command may not have
arrived at all (no route, the router's access control, a dead robot). Rejections are counted
per code, so a phrase that a robot refuses 300 times is one line, not 300.
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import TextIO

from kinesphere import zconfig
from kinesphere.clients import targets as tg
from kinesphere.clients.link import AckAnswer, RobotLink
from kinesphere.protocol import Ack, AckStage, BodyWord, Substitution
from kinesphere.words import body_words

FINAL = frozenset({
    AckStage.REACHED, AckStage.CLAMPED, AckStage.BLOCKED, AckStage.SUPERSEDED, AckStage.HOLDING,
    AckStage.STOPPED, AckStage.ESTOPPED, AckStage.RELEASED, AckStage.LEASED, AckStage.REJECTED,
})
"""Stages after which a robot says nothing more about a command."""
ENDED = frozenset({AckStage.REACHED, AckStage.CLAMPED, AckStage.BLOCKED, AckStage.REJECTED})
"""The stages that end a motion where it will stay. A copy of a stream superseded by the next
(a pose still waiting for the databank), or a motion the watchdog held while the stream went
on, is final for that command but not for the motion: the next copy moves the robot on."""
FAILED = frozenset({AckStage.REJECTED, AckStage.BLOCKED})
"""Stages that make a command-line client exit non-zero."""
DISCOVERY_S = 1.0
"""How long to wait for the states (and so the groups) of the robots alive now."""


def addressed(link: RobotLink, target: tg.Target, timeout: float = DISCOVERY_S) -> list[str]:
    """The robots ``target`` reaches now: the robot named, or every live robot that ``all``
    or the group reaches. Live robots come from a liveliness query and the link's liveliness
    subscriber and state stream (whichever knows first); groups from their states."""
    if target.kind == "robot":
        return [target.name]
    alive = set(link.alive_robots(timeout))

    def known(lk: RobotLink) -> bool:
        states = set(lk.states())
        return bool(states) and (alive | set(lk.robots())) <= states

    link.wait_for(known, timeout)
    return tg.members(target, link.robot_groups())


class Discovery:
    """Who is alive, and whether that has settled: every robot heard of so far (liveliness,
    or a state heard since this process started), and whether nobody new turned up for
    :data:`~kinesphere.zconfig.QUIET_S` after the session's
    :func:`~kinesphere.zconfig.discovery_time`. Read it under the link's lock (in a
    :meth:`RobotLink.wait_for` predicate)."""

    def __init__(self, link: RobotLink) -> None:
        now = time.monotonic()
        self.earliest = now + zconfig.discovery_time(link.session)
        self.robots: set[str] = set()
        self._changed = now

    def update(self, link: RobotLink) -> set[str]:
        """Every robot known now (never forgets one: a robot that went away meanwhile still
        has to be accounted for)."""
        found = set(link.robots())
        if not found <= self.robots:
            self.robots |= found
            self._changed = time.monotonic()
        return self.robots

    @property
    def settled(self) -> bool:
        now = time.monotonic()
        return now >= self.earliest and now - self._changed >= zconfig.QUIET_S

    def wake_in(self) -> float:
        """Seconds until :attr:`settled` may turn true without news."""
        now = time.monotonic()
        return max(0.0, self.earliest - now, self._changed + zconfig.QUIET_S - now)


def substitution_text(subs: Iterable[Substitution]) -> str:
    return ", ".join(f"{s.requested} -> {s.served} ({s.angle:.0f}°)" for s in subs)


@dataclass
class Outcome:
    """One robot's answers to a run of commands."""

    robot: str
    acks: list[Ack] = field(default_factory=list)

    @property
    def last(self) -> Ack | None:
        return self.acks[-1] if self.acks else None

    @property
    def refused(self) -> Counter[tuple[str, str]]:
        """Rejections by (code, the first detail given for that code)."""
        first: dict[str, str] = {}
        out: Counter[tuple[str, str]] = Counter()
        for a in self.acks:
            if a.stage == AckStage.REJECTED:
                out[(a.code, first.setdefault(a.code, a.detail))] += 1
        return out

    @property
    def substitutions(self) -> list[Substitution]:
        seen: dict[tuple[str, str, str, str], Substitution] = {}
        for a in self.acks:
            for s in a.substitutions:
                seen.setdefault((s.limb, s.origin, s.requested, s.served), s)
        return list(seen.values())

    @property
    def measured_angle(self) -> float | None:
        """The largest angle between what was asked and where the robot's pose points, as its
        acks measured it (None when none did)."""
        return max((a.measured_angle for a in self.acks if a.measured_angle is not None),
                   default=None)

    @property
    def words(self) -> list[BodyWord]:
        """The body words the robot answered with another name (once each)."""
        seen: dict[tuple[str, str, str], BodyWord] = {}
        for a in self.acks:
            for w in a.words:
                seen.setdefault((w.word, w.label, w.end), w)
        return list(seen.values())

    def final_for(self, seq: int) -> bool:
        """Whether the robot said its last word about command ``seq``."""
        return any(a.seq == seq and a.stage in FINAL for a in self.acks)

    def answered(self, seq: int) -> bool:
        """Whether the robot said anything about command ``seq`` (a release of a robot that is
        not latched is simply ``accepted``)."""
        return any(a.seq == seq for a in self.acks)

    @property
    def ok(self) -> bool:
        return bool(self.acks) and not any(a.stage in FAILED for a in self.acks)


def outcomes(answers: dict[str, list[AckAnswer]], robots: Iterable[str]) -> dict[str, Outcome]:
    """An Outcome for every addressed robot and every robot that answered anyway."""
    out = {rid: Outcome(rid) for rid in robots}
    for rid, found in answers.items():
        out.setdefault(rid, Outcome(rid)).acks.extend(a.ack for a in found)
    return dict(sorted(out.items()))


def ended(link: RobotLink, first_seq: int, robots: Iterable[str]) -> bool:
    """Whether every robot's motion toward a command numbered ``first_seq`` or later has
    ended (:data:`ENDED`: reached, clamped, blocked, or the command was refused)."""
    found = link.answers(first_seq)
    return all(any(a.ack.stage in ENDED for a in found.get(rid, [])) for rid in robots)


def wait(
    link: RobotLink,
    first_seq: int,
    robots: Iterable[str],
    timeout: float,
    done: Callable[[Outcome], bool],
) -> dict[str, Outcome]:
    """Wait until ``done`` holds for every addressed robot's answers to commands numbered
    ``first_seq`` on (and every robot that answered unaddressed), or ``timeout`` seconds; the
    outcomes either way."""
    wanted = list(robots)

    def settled(lk: RobotLink) -> bool:
        now = outcomes(lk.answers(first_seq), wanted)
        return bool(now) and all(done(o) for o in now.values())

    link.wait_for(settled, timeout)  # nobody known to address: whoever answers in time
    return outcomes(link.answers(first_seq), wanted)


def line(o: Outcome, timeout: float, sent: int = 1) -> str:
    """One robot's line: what it said, substitutions, refusals; or that it said nothing."""
    last = o.last
    if last is None:
        return (f"{o.robot}: NO ACKNOWLEDGEMENT within {timeout:g} s (the command may not have "
                "arrived: no route, access control, or the robot is down)")
    words: list[str] = []
    refused = o.refused
    for (code, detail), n in refused.items():
        count = f" {n} of {sent}" if sent > 1 else ""
        words.append(f"REJECTED{count}: {code}: {detail}")
    if not refused or last.stage != AckStage.REJECTED:
        stage = str(last.stage)
        if stage == AckStage.BLOCKED:
            stage = "BLOCKED"
        if stage in (AckStage.ACCEPTED, AckStage.MOVING):
            stage += f" (no final answer within {timeout:g} s)"
        words.insert(0, f"{stage}{': ' + last.detail if last.detail else ''}")
    said = o.words
    if said:
        words.append(f"named {body_words(said)}")
    subs = o.substitutions
    if subs:
        measured = o.measured_angle
        words.append(f"substituted {substitution_text(subs)}" + (
            f", pointing {measured:.0f}° from the request (measured)"
            if measured is not None else ""))
    if last.lease_holder:
        words.append(f"control: {last.lease_holder}")
    return f"{o.robot}: " + "; ".join(words)


def report(found: dict[str, Outcome], timeout: float, sent: int = 1,
           out: TextIO | None = None) -> None:
    """One line per robot on ``out`` (stdout)."""
    out = out or sys.stdout
    for o in found.values():
        print(line(o, timeout, sent), file=out)


def exit_code(found: dict[str, Outcome]) -> int:
    """0 when every robot accepted (and none refused or was blocked), else 1; also 1 when
    there was nobody to answer."""
    if not found or not all(o.ok for o in found.values()):
        return 1
    return 0


def summary(found: dict[str, Outcome], what: str) -> str:
    """``"2 of 3 robots accepted the command"``, or why nobody did."""
    if not found:
        return f"no robot is addressed by {what}: nobody is listening"
    good = sum(o.ok for o in found.values())
    return f"{good} of {len(found)} robot(s) accepted {what}"


def deadline(timeout: float) -> Callable[[], float]:
    """Seconds left until ``timeout`` from now, never below 0."""
    end = time.monotonic() + timeout
    return lambda: max(0.0, end - time.monotonic())
