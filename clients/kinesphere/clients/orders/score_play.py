"""``kinesphere play SCORE.json``: a Labanotation score performed by every addressed body.

A LabanotationSuite score (:mod:`kinesphere.scores`) is cast onto each robot through its body
vocabulary (:mod:`kinesphere.casting`: the head, both upper arms, both forearms; a part the
body lacks is said once and skipped), then played keyframe by keyframe:

1. **Check.** Each keyframe's parts are asked of the databank per chain (the head; an upper
   arm with its forearm) before anything moves: a chain the body cannot point where written
   is left out of that keyframe's command and reported (``direction_unavailable`` and why),
   so the other parts still play. ``--check`` prints this and the casting, and stops there.
2. **Upbeat.** The first keyframe is the starting pose: every robot goes there as fast as it
   can, and the score's clock starts once all have arrived (or ``--timeout`` passed).
3. **Keyframes.** Each later keyframe is one compound command per robot (its own parts; for
   a base that turns, the score's ``rotation`` as a heading from where it faced at the
   start), streamed at ``--rate`` until the keyframe's time, each copy telling the robot how
   long it has left to arrive (``Command.arrive_ms``): the trajectory meets the keyframe's
   time where the robot's limits allow, and the robot says how late it is otherwise.
   The last keyframe is held until every robot has arrived (or ``--timeout`` passed).
4. **Notated back.** Each robot is measured on the pose it held for each keyframe: the last
   state it reported while acting on the keyframe's commands (:class:`Held`), so a late body
   is measured where the next keyframe found it. The measure and the notation are
   :mod:`kinesphere.clients.orders.notated`'s.

Times follow the score's ``start time`` (divided by ``--speed``). Commands go to each robot's
own key: bodies differ in what they perform.
"""

from __future__ import annotations

import bisect
import math
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from kinesphere.casting import Casting, Role, cast
from kinesphere.clients.link import RobotLink, Sequencer
from kinesphere.clients.orders import answers
from kinesphere.clients.orders.notated import KeyframeReport, RobotReport, measure
from kinesphere.errors import KinesphereError
from kinesphere.eurdf import load_eurdf
from kinesphere.pointing import Pointing
from kinesphere.protocol import (
    MAX_TTL_MS,
    Ack,
    BodyModel,
    CompoundRequest,
    Pose,
    RobotState,
    SpatialCommand,
    encode,
)
from kinesphere.query import get_one, pose_query
from kinesphere.scores import Gesture, Keyframe, Score, load_score

SUFFIX = ".json"
QUERY_TIMEOUT_S = 10.0
"""How long one check of a keyframe's chain may take (a cold databank compiles the body)."""
SNAPSHOT_S = 0.25
"""How long to wait, after a keyframe's last command, for a state acting on it."""


def shipped() -> list[str]:
    """Names of the scores that come with the client (LabanotationSuite gestures)."""
    root = resources.files("kinesphere.clients.orders").joinpath("scores")
    return sorted(p.name[: -len(SUFFIX)] for p in root.iterdir() if p.name.endswith(SUFFIX))


def is_score(ref: str) -> bool:
    """Whether ``play REF`` names a score (a .json file, or a shipped score's name)."""
    return ref.endswith(SUFFIX) or (Path(ref).name == ref and ref in shipped())


def load(ref: str) -> Score:
    """A score from a file path or a shipped score's name (``big2`` or ``big2.json``)."""
    path = Path(ref)
    if path.is_file():
        return load_score(path)
    name = path.name[: -len(SUFFIX)] if path.name.endswith(SUFFIX) else path.name
    if path.parent != Path(".") or name not in shipped():
        raise KinesphereError(
            "malformed", f"no score file {ref}; shipped scores: {', '.join(shipped())}")
    res = resources.files("kinesphere.clients.orders").joinpath(f"scores/{name}{SUFFIX}")
    with resources.as_file(res) as p:
        return load_score(p)


@dataclass
class Performer:
    """One addressed robot: how the score is cast on it, its body for measuring, and what
    was sent and said for each keyframe."""

    robot: str
    platform: str
    key: str
    casting: Casting
    pointing: Pointing | None
    refused: dict[tuple[str, int], dict[str, str]] = field(default_factory=dict)
    """(gesture, keyframe index) -> column -> why the databank cannot perform it."""
    start_yaw: float = 0.0
    report: RobotReport = field(init=False)

    def __post_init__(self) -> None:
        c = self.casting
        self.report = RobotReport(
            self.robot, self.platform,
            {r.column: _role_words(r) for r in c.roles}, dict(c.skipped), c.turns)

    def command_parts(self, g: Gesture, kf: Keyframe) -> list[SpatialCommand]:
        refused = self.refused.get((g.name, kf.index), {})
        return self.casting.parts(kf, [r for r in self.casting.roles
                                       if r.column not in refused])

    def heading(self, kf: Keyframe) -> float | None:
        return self.start_yaw + math.radians(kf.turn_deg) if self.casting.turns else None

    @property
    def idle(self) -> bool:
        """Nothing of a score to perform (no part, no turning base): nothing is sent."""
        return not self.casting.roles and not self.casting.turns


def _role_words(r: Role) -> str:
    end = f" up to {r.end}" if not r.end.startswith("limb_") else ""
    note = f"; {r.note}" if r.note else ""
    return f"{r.limb} from {r.origin} ({r.start}{end}{note})"


def cast_robots(link: RobotLink, robots: Sequence[str], timeout: float) -> list[Performer]:
    """A Performer per robot, from its platform's catalogue and body model (once per
    platform); ``unavailable`` naming the robot whose platform no databank serves."""
    bodies: dict[str, tuple[Casting, Pointing | None]] = {}
    out = []
    for robot in robots:
        platform = link.platform_of(robot)
        if platform is None:
            raise KinesphereError("unavailable", f"{robot} reports no state: its platform is "
                                  "unknown")
        if platform not in bodies:
            cat = link.catalogue(platform, timeout)
            casting = cast(platform, cat.vocabulary, cat.base_kind, cat.sizes)
            model = get_one(link.session, link.keys.body(platform), BodyModel,
                            timeout=timeout, no_answer=f"no databank sends {platform}'s body")
            bodies[platform] = (casting, Pointing(load_eurdf(model.eurdf)))
        casting, pointing = bodies[platform]
        out.append(Performer(robot, platform, link.keys.command(robot), casting, pointing))
    return out


def casting_lines(performers: Iterable[Performer]) -> list[str]:
    """What each body performs of a score: one block per robot."""
    lines = []
    for p in performers:
        c = p.casting
        lines.append(f"{p.robot} ({p.platform}):")
        for column, words in p.report.performs.items():
            lines.append(f"  {column:12s} performed by {words}")
        for column, why in c.skipped.items():
            lines.append(f"  {column:12s} not performed: {why}")
        lines.append("  rotation     " + ("turns its base" if c.turns
                                           else "not performed: a fixed base"))
    return lines


def check(link: RobotLink, performers: Sequence[Performer], gestures: Sequence[Gesture],
          timeout: float = QUERY_TIMEOUT_S) -> None:
    """Ask the databank for every keyframe's chains on every platform once (module, step 1);
    what it refuses is kept in each performer's ``refused``. Also warms its caches: each
    keyframe's whole command is asked once too, as the robot will ask it (a chain is pointed
    with the ones before it placed, so the chains alone are not that answer)."""
    done: dict[tuple[str, str, int], dict[str, str]] = {}
    for p in performers:
        for g in gestures:
            for kf in g.keyframes:
                key = (p.platform, g.name, kf.index)
                if key not in done:
                    done[key] = _refusals(link, p, kf, timeout)
                    _warm(link, p.platform, p.command_parts(g, kf), timeout)
                if done[key]:
                    p.refused[(g.name, kf.index)] = done[key]


def _warm(link: RobotLink, platform: str, parts: list[SpatialCommand], timeout: float) -> None:
    """Ask the databank for ``parts`` together, for its cache only (what it says was said by
    the chains already)."""
    if len(parts) < 2:
        return
    key, payload = pose_query(link.keys, platform, parts)
    try:
        get_one(link.session, key, Pose, payload, timeout=timeout, retry=True)
    except KinesphereError as exc:
        if exc.code == "unavailable":
            raise


def _refusals(link: RobotLink, p: Performer, kf: Keyframe, timeout: float) -> dict[str, str]:
    out: dict[str, str] = {}
    for chain in p.casting.chains():
        request = CompoundRequest(parts=p.casting.parts(kf, chain))
        try:
            get_one(link.session, link.keys.compound(p.platform), Pose, encode(request),
                    timeout=timeout, retry=True)
        except KinesphereError as exc:
            if exc.code == "unavailable":
                raise
            out.update({r.column: f"{exc.code}: {exc.message}" for r in chain})
    return out


def refusal_lines(performers: Iterable[Performer], gestures: Sequence[Gesture]) -> list[str]:
    """The keyframes' cells each robot cannot perform, and why (one line per chain)."""
    lines = []
    names = {g.name: g for g in gestures}
    for p in performers:
        for (gname, index), refused in sorted(p.refused.items(),
                                              key=lambda x: (x[0][0], x[0][1])):
            kf = names[gname].keyframes[index]
            by_why: dict[str, list[str]] = {}
            for column, why in refused.items():
                by_why.setdefault(why, []).append(f"{column} {kf.cells[column]}")
            for why, cells in by_why.items():
                lines.append(f"{p.robot}: {gname} {kf.name}: {', '.join(cells)}: not "
                             f"performed ({why})")
    return lines


@dataclass
class Tempo:
    """How the score is streamed: keyframe times divided by ``speed``, ``rate_hz`` copies a
    second, each with ``ttl_ms``; ``upbeat_s`` the longest wait for the starting pose."""

    speed: float
    rate_hz: float
    ttl_ms: int
    upbeat_s: float


def play(link: RobotLink, performers: Sequence[Performer], gesture: Gesture, seq: Sequencer,
         tempo: Tempo, should_stop: Callable[[], bool] = lambda: False,
         on_keyframe: Callable[[Gesture, Keyframe, float], None] | None = None) -> None:
    """Perform one gesture (module, steps 2 to 4); the reports grow by its keyframes."""
    active = [p for p in performers if not p.idle]
    if not active:
        return
    states = link.states()
    for p in active:
        seen = states.get(p.robot)
        p.start_yaw = float(seen.state.base_pose[2]) if seen is not None else 0.0
    held = Held(active)
    first = gesture.keyframes[0]
    if on_keyframe is not None:
        on_keyframe(gesture, first, 0.0)
    _stream(link, active, gesture, first, seq, tempo, None, should_stop, held)
    t0 = time.monotonic()
    for kf in gesture.keyframes[1:]:
        if should_stop():
            break
        at = (kf.time_ms - first.time_ms) / 1e3 / tempo.speed
        if on_keyframe is not None:
            on_keyframe(gesture, kf, at)
        _stream(link, active, gesture, kf, seq, tempo, t0 + at, should_stop, held)
    else:
        if len(gesture.keyframes) > 1:  # the last pose held until every body has arrived
            _stream(link, active, gesture, gesture.keyframes[-1], seq, tempo, None,
                    should_stop, held, again=True)
    link.wait_for(lambda lk: _caught_up(lk, active, seq.seq - 1), SNAPSHOT_S)
    held.read(link)
    for kf in gesture.keyframes:
        _notate(active, gesture, kf, held)


class Held:
    """What each robot did for each keyframe, read as the commands are streamed: the pose it
    held (the last state it reported while acting on one of the keyframe's commands,
    ``RobotState.last_command_seq``) and what it said of them (:class:`Said`). A late body is
    measured where it was when the next keyframe took over, an early one where it waited; a
    slow client or network changes neither. Bounded by the keyframes of one gesture."""

    def __init__(self, active: Sequence[Performer]) -> None:
        self.firsts: list[int] = []
        """The first seq of each keyframe streamed, in order (seqs grow)."""
        self.keys: list[tuple[str, int]] = []
        self.states: dict[tuple[str, str, int], RobotState] = {}
        self.said: dict[tuple[str, str, int], Said] = {}
        self._robots = {p.robot for p in active}
        self._heard: dict[str, float] = {}
        """Robot -> when the last of its acks read arrived (monotonic)."""

    def begin(self, key: tuple[str, int], first_seq: int) -> None:
        if not self.keys or self.keys[-1] != key:
            self.firsts.append(first_seq)
            self.keys.append(key)

    def _key(self, seq: int) -> tuple[str, int] | None:
        i = bisect.bisect_right(self.firsts, seq) - 1
        return self.keys[i] if i >= 0 else None

    def read(self, link: RobotLink) -> None:
        """The states and acks that arrived since the last read."""
        for robot, seen in link.states().items():
            key = self._key(seen.state.last_command_seq)
            if robot in self._robots and key is not None:
                self.states[(robot, *key)] = seen.state
        if not self.firsts:
            return
        for robot, found in link.answers(self.firsts[0]).items():
            if robot not in self._robots:
                continue
            new = [a for a in found if a.at > self._heard.get(robot, -1.0)]
            if new:
                self._heard[robot] = new[-1].at
            for a in new:
                key = self._key(a.ack.seq)
                if key is not None:
                    self.said.setdefault((robot, *key), Said()).hear(a.ack)

    def state(self, robot: str, key: tuple[str, int]) -> RobotState | None:
        return self.states.get((robot, *key))


@dataclass
class Said:
    """What a robot said of one keyframe's commands: the latest arrival it announced, the
    stages (the first :data:`STAGES_KEPT` kinds), the first refusal or block."""

    late_ms: int = 0
    stages: list[str] = field(default_factory=list)
    failed: str = ""

    def hear(self, ack: Ack) -> None:
        self.late_ms = max(self.late_ms, ack.late_ms)
        words = f"{ack.stage}{' ' + ack.detail if ack.detail else ''}"
        if words not in self.stages and len(self.stages) < STAGES_KEPT:
            self.stages.append(words)
        if not self.failed and ack.stage in answers.FAILED:
            code = f"{ack.code}: " if ack.code else ""
            self.failed = f"{ack.stage}: {code}{ack.detail}"


STAGES_KEPT = 8


def _stream(link: RobotLink, active: Sequence[Performer], g: Gesture, kf: Keyframe,
            seq: Sequencer, tempo: Tempo, due: float | None,
            should_stop: Callable[[], bool], held: Held, again: bool = False) -> None:
    """Stream ``kf``'s commands until ``due`` (monotonic), each copy with the time left; with
    no ``due`` (the upbeat, and ``again`` for the last keyframe held), as fast as the robots
    can until each has arrived or ``tempo.upbeat_s`` passed."""
    period = 1.0 / tempo.rate_hz
    parts = {p.robot: p.command_parts(g, kf) for p in active}
    first = seq.seq
    held.begin((g.name, kf.index), first)
    end = due if due is not None else time.monotonic() + tempo.upbeat_s
    while (now := time.monotonic()) < end and not should_stop():
        left = 0 if due is None else min(MAX_TTL_MS, max(1, round((due - now) * 1e3)))
        for p in active:
            cmd = seq.command(parts[p.robot], arrive_ms=left, heading=p.heading(kf))
            link.put([p.key], cmd)
        held.read(link)
        if due is None and _arrived(link, active, held.firsts[-1] if again else first):
            break
        time.sleep(max(0.0, min(period, end - time.monotonic())))
    held.read(link)


def _caught_up(link: RobotLink, active: Sequence[Performer], last: int) -> bool:
    """Whether every robot reported a state acting on command ``last`` or later."""
    seen = link.states()
    return all(p.robot in seen and seen[p.robot].state.last_command_seq >= last
               for p in active)


def _arrived(link: RobotLink, active: Sequence[Performer], first: int) -> bool:
    """Whether every robot's motion toward a command sent since ``first`` has ended."""
    return answers.ended(link, first, [p.robot for p in active])


def _notate(active: Sequence[Performer], g: Gesture, kf: Keyframe, held: Held) -> None:
    """Measure every robot on the pose it held for ``kf``."""
    for p in active:
        state = held.state(p.robot, (g.name, kf.index))
        said = held.said.get((p.robot, g.name, kf.index), Said())
        refused = {**p.refused.get((g.name, kf.index), {})}
        cells = (measure(p.pointing, p.casting, kf, state, refused)
                 if p.pointing is not None else [])
        p.report.keyframes.append(KeyframeReport(
            g.name, kf.index, kf.name, kf.time_ms, cells, state_seq=state.seq if state else -1,
            joint_names=list(state.joint_names) if state else [],
            q=list(state.q) if state else [],
            base_yaw=float(state.base_pose[2]) if state and p.casting.turns else None,
            turn_deg=kf.turn_deg, late_ms=said.late_ms, stages=said.stages, said=said.failed))


def progress(g: Gesture, kf: Keyframe, at: float) -> None:
    """One line on stderr per keyframe as it starts."""
    print(f"  keyframe {kf.index + 1}/{len(g.keyframes)} {kf.name} at {at:5.2f} s: "
          f"{kf.notation()}", file=sys.stderr)


def late_lines(performers: Sequence[Performer], g: Gesture) -> list[str]:
    """Per robot, the keyframes of ``g`` it said it reached late, and by how much."""
    lines = []
    for p in performers:
        late = [f"{k.keyframe} +{k.late_ms} ms" for k in p.report.keyframes
                if k.gesture == g.name and k.late_ms > 0]
        if late:
            lines.append(f"  {p.robot} late at {len(late)} keyframe(s): {', '.join(late)}")
    return lines
