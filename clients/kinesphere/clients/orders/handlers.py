"""``send``, ``play``, ``estop`` and ``lease``: commands that wait for the robots' answers.

Each finds whom it addresses (:func:`~kinesphere.clients.orders.answers.addressed`), sends,
waits up to ``--timeout`` for every addressed robot's acks, prints one line per robot on stdout
(what it did, substitutions, refusals with their code, or "NO ACKNOWLEDGEMENT") and a summary on
stderr, and exits 0 only when every addressed robot accepted: 1 when any refused, was blocked or
did not answer, or when nobody was there to answer. An e-stop that reaches nobody is a loud
failure.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from kinesphere import hints, zconfig
from kinesphere.clients import targets
from kinesphere.clients.link import (
    RobotLink,
    Sequencer,
    link_for,
    operator_id,
    reachable,
    signals,
)
from kinesphere.clients.options import TeleopOptions
from kinesphere.clients.orders import answers, notated, phrases, score_play
from kinesphere.clients.orders.answers import Outcome
from kinesphere.errors import KinesphereError
from kinesphere.protocol import AckStage, LeaseAction, SpatialCommand

ESTOP_RESEND_S = 0.1
"""``kinesphere estop`` puts its e-stop at once, then again every 0.1 s while a robot known
alive has not acknowledged it (it latches, so copies are harmless), until all did or the
timeout; ``--release`` likewise while an addressed robot has not answered (a robot released
already answers a second release ``accepted``)."""
KEEPALIVE_S = 1.0
"""``lease --hold`` renews the lease this often (robots free a lease after 3 s of silence)."""


class _Interrupt:
    """Set by SIGINT or SIGTERM: the stream ends early and the robots are let go."""

    def __init__(self) -> None:
        self.set = False

    def __call__(self) -> None:
        self.set = True


@contextmanager
def _addressing(
    args: argparse.Namespace, target: targets.Target, ttl_ms: int
) -> Iterator[tuple[RobotLink, list[str], list[str], Sequencer]]:
    """``(link, keys, robots, seq)``: the link, the target's keys once someone listens, the
    robots it addresses, and the link's Sequencer."""
    with link_for(args) as link:
        keys = reachable(link, target, args.wait)
        yield link, keys, answers.addressed(link, target), link.sequencer(ttl_ms)


def _finish(found: dict[str, Outcome], timeout: float, what: str, sent: int = 1) -> int:
    answers.report(found, timeout, sent)
    print(answers.summary(found, what), file=sys.stderr)
    return answers.exit_code(found)


def _parse_parts(words: list[str]) -> list[SpatialCommand]:
    if len(words) % 4:
        raise KinesphereError(
            "malformed", f"parts come in fours (LIMB ORIGIN DIRECTION SIZE), got {len(words)} words"
        )
    return [phrases.parse_part(" ".join(words[i : i + 4]), "send") for i in range(0, len(words), 4)]


def send(args: argparse.Namespace) -> int:
    parts = _parse_parts(args.parts)
    drive = phrases.make_drive(args.drive[0], args.drive[1], "--drive") if args.drive else None
    if not parts and drive is None:
        raise KinesphereError("malformed", "nothing to send: give L O D S parts and/or --drive")
    target = targets.parse_target(args.target)
    hold = args.hold
    ttl = args.ttl_ms if args.ttl_ms is not None else (TeleopOptions.ttl_ms if hold else 0)
    stop = _Interrupt()
    with _addressing(args, target, ttl) as (link, keys, robots, seq):
        first = seq.seq
        with signals(stop):
            link.put(keys, seq.command(parts, drive))
            if hold:
                end = time.monotonic() + hold
                while time.monotonic() < end and not stop.set:
                    time.sleep(min(1.0 / args.rate, max(0.0, end - time.monotonic())))
                    link.put(keys, seq.command(parts, drive))
                link.put(keys, seq.let_go())
        last = seq.seq - 1
        found = answers.wait(link, first, robots, args.timeout, lambda o: o.final_for(last))
    return _finish(found, args.timeout, f"the command ({seq.seq - first} sent)", seq.seq - first)


def _before_let_go(o: answers.Outcome, let_go: int, last_step: list[int]) -> answers.Outcome:
    """What a phrase did to one robot: its answers but the let-go's and, once the robot said
    its last step's motion ended, but those of the copies still on the way then (the let-go
    ended their motions at the pose the robot had reached)."""
    end = max((a.seq for a in o.acks if a.stage in answers.ENDED and last_step
               and a.seq >= last_step[0]), default=let_go)
    return answers.Outcome(o.robot, [a for a in o.acks if a.seq != let_go and a.seq <= end]
                           or o.acks)


SCORE_ONLY = (("gesture", None), ("speed", None), ("check", False), ("report", None))
"""``play`` options that only a score takes, with their unset values."""


def play(args: argparse.Namespace) -> int:
    if score_play.is_score(args.phrase):
        return play_score(args)
    given = [name for name, unset in SCORE_ONLY if getattr(args, name, unset) != unset]
    if given:
        raise KinesphereError("malformed", f"--{given[0]} applies to a score (SCORE.json), "
                              f"not to the phrase {args.phrase}")
    phrase = phrases.load_phrase(args.phrase)
    target = targets.parse_target(args.target)
    ttl = args.ttl_ms if args.ttl_ms is not None else (phrase.ttl_ms or TeleopOptions.ttl_ms)
    stop = _Interrupt()

    def on_step(i: int, step: phrases.Step) -> None:
        note = f": {step.note}" if step.note else ""
        print(f"step {i + 1}/{len(phrase.steps)} ({step.duration:g} s){note}", file=sys.stderr)

    with _addressing(args, target, ttl) as (link, keys, robots, seq):
        link.wait_for(lambda lk: set(robots) <= set(lk.states()), answers.DISCOVERY_S)
        states = link.states()
        cannot, unchecked = phrases.unservable(link, phrase, {
            rid: states[rid].state.platform for rid in robots if rid in states})
        for platform in unchecked:
            print(f"could not check {phrase.name} on {platform}: no databank answers; playing "
                  "anyway (its robots resolve it themselves)", file=sys.stderr)
        if cannot:
            for rid, why in sorted(cannot.items()):
                print(f"{rid} ({states[rid].state.platform}): CANNOT PLAY {phrase.name}: {why}")
            print(f"{phrase.name} cannot play on {len(cannot)} of {len(robots)} robot(s) of "
                  f"{target.label}: nothing was sent", file=sys.stderr)
            return 1
        first = seq.seq
        print(f"playing {phrase.name} ({phrase.duration:g} s) on {target.label}", file=sys.stderr)

        last_step: list[int] = []  # the first command of the last step, once streamed on

        def arrived(since: int) -> bool:
            last_step[:] = [since]
            return answers.ended(link, since, robots)

        with signals(stop):
            phrases.play(link, phrase, keys, seq, rate_hz=args.rate, on_step=on_step,
                         should_stop=lambda: stop.set, arrived=arrived)
        let_go = seq.seq - 1
        found = answers.wait(link, first, robots, args.timeout, lambda o: o.final_for(let_go))
    if not stop.set:  # the let-go only ends the stream: what the phrase did is said before it
        found = {rid: _before_let_go(o, let_go, last_step) for rid, o in found.items()}
    code = _finish(found, args.timeout, f"the phrase ({seq.seq - first} commands)",
                   seq.seq - first)
    return 130 if stop.set else code


def estop(args: argparse.Namespace) -> int:
    if args.release:
        if args.target is None:
            raise KinesphereError(
                "malformed", "--release needs --target ID, group:NAME or all: say whose "
                "e-stop to release")
        with _addressing(args, targets.parse_target(args.target), 0) as (link, keys, robots, seq):
            first = seq.seq
            left = answers.deadline(args.timeout)
            link.put(keys, seq.release())
            while not link.wait_for(lambda lk: _all_answered(lk, first, robots),
                                    min(ESTOP_RESEND_S, left())) and left() > 0:
                link.put(keys, seq.release())  # an answer lost on the way: ask again
            found = answers.outcomes(link.answers(first), robots)
        for o in found.values():  # a robot without a latch accepts a release and does nothing
            released = [a for a in o.acks if a.stage == AckStage.RELEASED]
            if released:
                print(answers.line(answers.Outcome(o.robot, released), args.timeout))
            elif o.acks and all(a.stage == AckStage.ACCEPTED for a in o.acks):
                print(f"{o.robot}: not e-stopped: nothing to release")
            else:
                print(answers.line(o, args.timeout))
        print(answers.summary(found, "the release"), file=sys.stderr)
        return answers.exit_code(found)
    with link_for(args) as link:
        return _estop_all(link, args.timeout, args.prefix)


def _all_answered(link: RobotLink, first: int, robots: list[str]) -> bool:
    """Every robot addressed (and any other that answered) said something about a command
    numbered ``first`` or later."""
    now = answers.outcomes(link.answers(first), robots)
    return bool(now) and all(o.acks for o in now.values())


def _named(link: RobotLink) -> str:
    """``link``'s sender when it is not this operator's default (a command repeating it must
    say ``--sender``), else ""."""
    return "" if link.sender == operator_id() else link.sender


def _estop_all(link: RobotLink, timeout: float, prefix: str) -> int:
    """E-stop every robot, and say so only once every robot alive has latched (module text).

    The e-stop goes out at once and again every :data:`ESTOP_RESEND_S` while a robot known
    alive has not acknowledged it. Success needs two things: discovery has settled (every
    robot with a liveliness token or a state heard is known, and nobody new turned up for a
    moment: :class:`~kinesphere.clients.orders.answers.Discovery`) and every robot known has
    acknowledged ``estopped``. A robot heard of later, even after the others all answered, must
    answer too; one that never does is named, and the exit status is 1.
    """
    seq = link.sequencer(0)
    first = seq.seq
    start = time.monotonic()
    link.estop_all(seq)  # at once: an e-stop never waits for discovery
    left = answers.deadline(timeout)
    discovery = answers.Discovery(link)
    link.alive_robots(max(0.1, left()))  # the liveliness tokens there are now, complete

    def latched(lk: RobotLink) -> set[str]:
        return {rid for rid, got in lk.answers(first).items()
                if any(a.ack.stage == AckStage.ESTOPPED for a in got)}

    def confirmed(lk: RobotLink) -> bool:
        robots = discovery.update(lk)
        return discovery.settled and robots <= latched(lk)

    while not link.wait_for(confirmed, min(ESTOP_RESEND_S, left(), discovery.wake_in() or
                                           ESTOP_RESEND_S)) and left() > 0:
        with link.changed:
            missing = discovery.update(link) - latched(link)
        if missing:
            link.estop_all(seq)  # robots discovered a moment later get a copy
    with link.changed:
        robots = discovery.update(link)
        settled = discovery.settled
    found = answers.outcomes(link.answers(first), robots)
    if not found:
        nobody = zconfig.alone(link.session)
        print(f"E-STOP REACHED NO ROBOT: nobody acknowledged it within {timeout:g} s and "
              f"{nobody or f'no robot seen alive under {prefix!r}'}", file=sys.stderr)
        return 1
    states = link.states()
    for rid, o in found.items():
        if any(a.stage == AckStage.ESTOPPED for a in o.acks):
            print(f"{rid}: estopped")
        elif o.refused:
            print(answers.line(o, timeout))
        else:
            heard = states.get(rid)
            how = (f"its last state came {time.monotonic() - heard.at:.1f} s ago"
                   if heard is not None else "it holds a liveliness token")
            print(f"{rid}: NOT CONFIRMED: alive ({how}) but no e-stop acknowledgement within "
                  f"{timeout:g} s; make sure it is stopped")
    good = sum(any(a.stage == AckStage.ESTOPPED for a in o.acks) for o in found.values())
    if good == len(found) and settled:
        took = max(a.at for got in link.answers(first).values() for a in got
                   if a.ack.stage == AckStage.ESTOPPED) - start
        print(f"E-STOP confirmed by all {good} live robot(s) in {took:.2f} s; it stays in "
              f"force for robots that start or rejoin until you release it with "
              f"'{hints.release_estop('all', _named(link))}'", file=sys.stderr)
        return 0
    why = "" if settled else (f"; discovery had not settled within {timeout:g} s, so robots "
                              "may be missing (a larger --timeout waits longer)")
    print(f"E-STOP NOT CONFIRMED: {good} of {len(found)} live robot(s) acknowledged it{why}",
          file=sys.stderr)
    return 1


def lease(args: argparse.Namespace) -> int:
    action = LeaseAction(args.action)
    target = targets.parse_target(args.target)
    stop = _Interrupt()
    with _addressing(args, target, 0) as (link, keys, robots, seq):
        first = seq.seq
        link.put(keys, seq.lease(action))
        found = answers.wait(link, first, robots, args.timeout, lambda o: o.final_for(first))
        code = _finish(found, args.timeout, f"lease {action}")
        if code or action is LeaseAction.RELEASE or not args.hold:
            return code
        print(f"holding the lease for {args.hold:g} s (Ctrl-C releases it)", file=sys.stderr)
        end = time.monotonic() + args.hold
        with signals(stop):
            while not stop.set and time.monotonic() < end:
                link.wait_for(lambda lk: stop.set, min(KEEPALIVE_S, end - time.monotonic()))
                if not stop.set and time.monotonic() < end:
                    link.put(keys, seq.lease(LeaseAction.ACQUIRE))
        last = seq.seq
        link.put(keys, seq.lease(LeaseAction.RELEASE))
        found = answers.wait(link, last, robots, args.timeout, lambda o: o.final_for(last))
    return _finish(found, args.timeout, "lease release")


def play_score(args: argparse.Namespace) -> int:
    """``play SCORE.json`` (:mod:`~kinesphere.clients.orders.score_play`): the casting and
    the cells each body cannot perform on stdout, then (unless ``--check``) the score
    performed and notated back, one line per robot; ``--report`` writes every cell."""
    score = score_play.load(args.phrase)
    gestures = [score.gesture(args.gesture)] if args.gesture else list(score.gestures)
    speed = 1.0 if args.speed is None else args.speed
    if not 0.01 <= speed <= 100:
        raise KinesphereError("malformed", f"--speed must be 0.01..100, got {speed:g}")
    report_path = Path(args.report) if args.report else None
    if report_path is not None and not report_path.parent.is_dir():
        raise KinesphereError("malformed", f"--report {report_path}: no folder "
                              f"{report_path.parent} to write it in")
    target = targets.parse_target(args.target)
    ttl = args.ttl_ms if args.ttl_ms is not None else TeleopOptions.ttl_ms
    tempo = score_play.Tempo(speed, args.rate, ttl, args.timeout)
    stop = _Interrupt()
    with link_for(args) as link:
        reachable(link, target, args.wait)
        robots = answers.addressed(link, target)
        if not robots:
            raise KinesphereError("unavailable", f"no robot answers as {target.label}")
        performers = score_play.cast_robots(link, robots, args.timeout)
        for line in score_play.casting_lines(performers):
            print(line)
        score_play.check(link, performers, gestures)
        for line in score_play.refusal_lines(performers, gestures):
            print(line)
        if args.check:
            return 0
        missing = link.wait_subscribers([p.key for p in performers], args.wait)
        if missing:
            raise KinesphereError("unavailable", f"no robot listens on {', '.join(missing)}")
        seq = link.sequencer(ttl)
        last: dict[str, int] = {}
        with signals(stop):
            try:
                for g in gestures:
                    print(f"playing {g.name} ({len(g.keyframes)} keyframes, "
                          f"{g.duration_ms / 1e3 / speed:g} s) on {target.label}",
                          file=sys.stderr)
                    score_play.play(link, performers, g, seq, tempo, lambda: stop.set,
                                    score_play.progress)
                    for line in score_play.late_lines(performers, g):
                        print(line, file=sys.stderr)
                    if stop.set:
                        break
            finally:
                for p in performers:
                    if not p.idle:
                        cmd = seq.let_go()
                        link.put([p.key], cmd)
                        last[p.robot] = cmd.seq
        let_go = min(last.values(), default=seq.seq)
        found = answers.wait(link, let_go, list(last), args.timeout,
                             lambda o: o.final_for(last.get(o.robot, -1)))
    report = notated.ScoreReport(score.source, [g.name for g in gestures], speed,
                                 [p.report for p in performers])
    for r in report.robots:
        notated.summarise(r)
        print(notated.robot_line(r))
    silent = [o for o in found.values() if not o.acks]
    for o in silent:
        print(answers.line(o, args.timeout, 0))
    if report_path is not None:
        notated.write(report, report_path)
        print(f"report written to {report_path}", file=sys.stderr)
    failed = any(k.said for r in report.robots for k in r.keyframes)
    return 130 if stop.set else int(failed or bool(silent))
