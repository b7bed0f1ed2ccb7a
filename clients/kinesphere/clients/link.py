"""The client's Zenoh side: put commands, watch robots and their acks, read catalogues.

One :class:`RobotLink` per client process; :func:`link_for` opens it from a command's Zenoh
options, :func:`reachable` waits until the robots addressed listen, :func:`signals` lets
SIGTERM end a command's work so its final stop still goes out (every operator command uses
these three). Commands go through publishers cached per key (a
stream at 30 Hz should not re-resolve its key every tick) with express delivery and blocking
congestion control: a stop or an e-stop must never be dropped to make room. Robot states,
liveliness and the acks robots send for this client's commands arrive on Zenoh's threads and
are kept behind a lock, bounded, for the loop and the HUD.

Who the client is: ``sender`` names the operator (``$KINESPHERE_SENDER``, else ``user@host``,
unless given: robots lease control to a sender, so every process of one operator shares it;
with the deploy's access control it must be the name in the operator's certificate) and
``session`` this process (robots order commands per ``(sender, session)``, so a restarted
client starts afresh; told ``stale``, the link starts a fresh session, since someone or
something put its session's order past its own). Every command is put under a key that ends
with the sender's name (:meth:`Keys.signed`): the router lets a certificate put only under its
own name, and robots take the sender from the key. ``clock`` names this host's clock until
it reboots, so robots time a new session by what they learnt of its offset.

Zenoh's link lease is 10 s, so liveliness only tells who exists; safety comes from each
command's ``ttl_ms``, which the robot enforces itself.
"""

from __future__ import annotations

import argparse
import getpass
import hashlib
import logging
import os
import re
import signal
import socket
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from types import FrameType
from typing import TypeVar

import zenoh

from kinesphere import zconfig
from kinesphere.clients import targets as tg
from kinesphere.errors import KinesphereError, did_you_mean
from kinesphere.keyexpr import Keys
from kinesphere.lru import Lru
from kinesphere.protocol import (
    MAX_NAME,
    Ack,
    Catalogue,
    Command,
    Drive,
    LeaseAction,
    Pose,
    RobotState,
    SpatialCommand,
    decode,
    encode,
)
from kinesphere.query import get_one, pose_query
from kinesphere.signals import handle_signals

log = logging.getLogger(__name__)
T = TypeVar("T")
URGENT = zenoh.Priority.REAL_TIME


ACKS_PER_ROBOT = 256
"""Acks kept per robot (a 30 Hz stream's last ~4 s with an accepted and a final stage each)."""
MAX_ROBOTS = 1024
"""Robots whose states and acks are kept; the least recently heard are forgotten first."""


def _segment(text: str) -> str:
    """``text`` made a valid key segment and name: no ``/ * $ ? #`` or spaces, no leading
    ``@``, at most :data:`MAX_NAME` characters."""
    clean = re.sub(r"[/*$?#\s]+", "_", text).lstrip("@")
    return clean[:MAX_NAME] or "operator"


SENDER_ENV = "KINESPHERE_SENDER"
"""The default sender, when set (an operator's certificate name)."""
SESSIONS_KEPT = 8
"""Earlier sessions of a link whose acks still count (commands in flight when it renewed)."""


def operator_id() -> str:
    """This operator's default sender: ``$KINESPHERE_SENDER``, else ``user@host``."""
    named = os.environ.get(SENDER_ENV, "").strip()
    if named:
        return _segment(named)
    try:
        user = getpass.getuser()
    except (KeyError, OSError):  # no passwd entry (containers)
        user = "operator"
    return _segment(f"{user}@{socket.gethostname().split('.')[0]}")


def host_clock() -> str:
    """This host's clock until it reboots (the kernel's boot id, else the host name), as a
    short digest: ``Command.clock``."""
    try:
        with open("/proc/sys/kernel/random/boot_id", encoding="ascii") as f:
            boot = f.read(64).strip()
    except OSError:
        boot = ""
    return hashlib.sha256(f"{socket.gethostname()}/{boot}".encode()).hexdigest()[:16]


def new_sender(kind: str) -> str:
    """A sender id unique to this process (tests and tools that must not share a lease)."""
    return f"{kind}-{uuid.uuid4().hex[:8]}"


def new_session() -> str:
    """A fresh session id: robots order commands per ``(sender, session)``."""
    return uuid.uuid4().hex[:12]


class Sequencer:
    """Builds Commands with a growing ``seq``, this sender's id and this process's session."""

    def __init__(self, sender: str, ttl_ms: int, session: str = "", clock: str = "") -> None:
        self.sender = sender
        self.session = session
        self.ttl_ms = ttl_ms
        self.clock = clock
        self.seq = 0

    def command(
        self,
        parts: Iterable[SpatialCommand] = (),
        drive: Drive | None = None,
        *,
        deadman: bool = True,
        estop: bool = False,
        stop: bool = False,
        release: bool = False,
        lease: LeaseAction = LeaseAction.NONE,
        arrive_ms: int = 0,
        heading: float | None = None,
    ) -> Command:
        cmd = Command(
            seq=self.seq,
            sent_ns=time.time_ns(),
            parts=list(parts),
            drive=drive,
            deadman=deadman,
            ttl_ms=self.ttl_ms,
            estop=estop,
            stop=stop,
            release=release,
            sender=self.sender,
            session=self.session,
            lease=lease,
            clock=self.clock,
            arrive_ms=arrive_ms,
            heading=heading,
        )
        self.seq += 1
        return cmd

    def let_go(self) -> Command:
        """The operator let go (``deadman=false``): the robot brakes to rest and holds. Like
        any motion command it is obeyed only from the lease holder, so letting go of a robot
        someone else controls does not stop their motion."""
        return self.command(deadman=False)

    def stop(self) -> Command:
        """Controlled stop of all motion, obeyed from anyone (lease or not)."""
        return self.command(deadman=False, stop=True)

    def estop(self) -> Command:
        """Emergency stop; robots latch it until a release."""
        return self.command(deadman=False, estop=True, stop=True)

    def release(self) -> Command:
        """Clears a robot's e-stop latch; robots move again only on the next command."""
        return self.command(deadman=True, release=True)

    def lease(self, action: LeaseAction) -> Command:
        """A lease-only command (``acquire``, ``take``, ``release``): moves nothing; robots
        answer ``leased`` or refuse with ``lease_held``. ``deadman`` is true: a deadman
        release would make the robot hold instead."""
        return self.command(deadman=True, lease=action)


@dataclass(frozen=True)
class AckAnswer:
    """An ack for one of this client's commands and when it arrived (monotonic seconds)."""

    ack: Ack
    at: float


@dataclass(frozen=True)
class Seen:
    """A robot's latest state and when it arrived (monotonic seconds)."""

    state: RobotState
    at: float


class RobotLink:
    """Puts commands and watches robots on one Zenoh session (which the caller closes)."""

    def __init__(
        self, session: zenoh.Session, keys: Keys, *, watch: bool = True, sender: str | None = None
    ) -> None:
        self.session = session
        self.keys = keys
        self.sender = sender or operator_id()
        self.session_id = new_session()
        self.clock = host_clock()
        self.renewed = 0
        """Fresh sessions started because a robot answered ``stale``."""
        self._sessions: deque[str] = deque([self.session_id], maxlen=SESSIONS_KEPT)
        self._sequencer: Sequencer | None = None
        self._lock = threading.RLock()  # wait_for predicates read states under it
        self._publishers: dict[tuple[str, bool], zenoh.Publisher] = {}
        self._states: Lru[str, Seen] = Lru(MAX_ROBOTS)
        self._answers: Lru[str, deque[AckAnswer]] = Lru(MAX_ROBOTS)
        self._alive: set[str] = set()
        self._catalogues: dict[str, Catalogue] = {}
        self.catalogue_epoch = 0
        """Grows whenever a databank reports a recorded pose (catalogues may have changed)."""
        self.changed = threading.Condition(self._lock)
        self._subs: list[zenoh.Subscriber[None]] = []
        if watch:
            self._subs.append(session.declare_subscriber(keys.state("*"), self._on_state))
            self._subs.append(
                session.liveliness().declare_subscriber(
                    keys.alive_robot("*"), self._on_alive, history=True
                )
            )
            self._subs.append(session.declare_subscriber(keys.changed("*"), self._on_changed))
            self._subs.append(session.declare_subscriber(keys.ack("*"), self._on_ack))

    def sequencer(self, ttl_ms: int) -> Sequencer:
        """The one Sequencer of this link's sender and session, with ``ttl_ms`` from now on (a
        second one would restart ``seq``, and robots would drop its commands as stale)."""
        if self._sequencer is None:
            self._sequencer = Sequencer(self.sender, ttl_ms, self.session_id, self.clock)
        self._sequencer.ttl_ms = ttl_ms
        return self._sequencer

    def _renew(self, stale: Ack) -> None:
        """A robot says this session's order is past this link's ``seq`` (someone pushed it,
        or the robot restarted deep into a long session): go on in a fresh session, with
        ``seq`` still growing, so acks of either still tell commands apart. Under the lock."""
        if stale.session != self.session_id:
            return  # an older session's: renewed already
        self.session_id = new_session()
        self._sessions.append(self.session_id)
        self.renewed += 1
        if self._sequencer is not None:
            self._sequencer.session = self.session_id
        log.info("%s answered stale (%s): commands go on in a fresh session", stale.robot_id,
                 stale.detail)

    # --- watching -----------------------------------------------------------------------

    @staticmethod
    def _decoded(sample: zenoh.Sample, type_: type[T]) -> T | None:
        """The sample's message, or None (logged) when a peer sent something else."""
        try:
            return decode(sample.payload, type_)
        except KinesphereError as exc:
            log.debug("ignoring %s: %s", sample.key_expr, exc)
            return None

    def _on_state(self, sample: zenoh.Sample) -> None:
        st = self._decoded(sample, RobotState)
        if st is None:
            return
        with self.changed:
            self._states.put(st.robot_id, Seen(st, time.monotonic()))
            self.changed.notify_all()

    def _on_ack(self, sample: zenoh.Sample) -> None:
        ack = self._decoded(sample, Ack)
        if ack is None or ack.sender != self.sender:
            return  # undecodable, or another client's
        with self.changed:
            if ack.session not in self._sessions:
                return  # another process of this sender's
            if ack.code == "stale":
                self._renew(ack)
            box = self._answers.get(ack.robot_id)
            if box is None:
                box = self._answers.put(ack.robot_id, deque(maxlen=ACKS_PER_ROBOT))
            box.append(AckAnswer(ack, time.monotonic()))
            self.changed.notify_all()

    def answers(self, seq_from: int = 0) -> dict[str, list[AckAnswer]]:
        """Acks each robot sent for this client's commands with ``seq >= seq_from``."""
        with self._lock:
            out = {rid: [a for a in box if a.ack.seq >= seq_from]
                   for rid, box in self._answers.items()}
        return {rid: found for rid, found in out.items() if found}

    def last_answers(self) -> dict[str, AckAnswer]:
        """The newest ack of each robot for this client's commands."""
        with self._lock:
            return {rid: box[-1] for rid, box in self._answers.items() if box}

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            rid = self.keys.robot_id_of(str(sample.key_expr))
        except KinesphereError:
            return
        with self.changed:
            if sample.kind == zenoh.SampleKind.DELETE:
                self._alive.discard(rid)
            else:
                self._alive.add(rid)
            self.changed.notify_all()

    def _on_changed(self, sample: zenoh.Sample) -> None:
        with self.changed:
            self._catalogues.clear()
            self.catalogue_epoch += 1
            self.changed.notify_all()

    def states(self) -> dict[str, Seen]:
        """Latest state of every robot heard from."""
        with self._lock:
            return dict(self._states.items())

    def robots(self) -> list[str]:
        """Robot ids known alive (liveliness) or streaming state, sorted."""
        with self._lock:
            return sorted(self._alive | set(self._states))

    def robot_groups(self) -> dict[str, list[str]]:
        """Every robot known (alive or streaming state) -> the groups its state says it obeys."""
        with self._lock:
            out = {rid: list(seen.state.groups) for rid, seen in self._states.items()}
            out.update({rid: [] for rid in self._alive if rid not in out})
            return out

    def wait_for(self, predicate: Callable[[RobotLink], bool], timeout: float) -> bool:
        """Wait until ``predicate(link)`` is true (re-checked on every state, liveliness
        change or ack)."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while not predicate(self):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.changed.wait(left)
            return True

    def platform_of(self, robot_id: str) -> str | None:
        seen = self.states().get(robot_id)
        return seen.state.platform if seen else None

    # --- catalogues ---------------------------------------------------------------------

    def catalogue(self, platform: str, timeout: float = 2.0) -> Catalogue:
        """A platform's catalogue from the databank (cached); unavailable if none answers."""
        with self._lock:
            cached = self._catalogues.get(platform)
        if cached is not None:
            return cached
        cat = get_one(
            self.session,
            self.keys.catalogue(platform),
            Catalogue,
            timeout=timeout,
            no_answer=f"no databank answers for platform {platform!r}",
        )
        with self._lock:
            self._catalogues[platform] = cat
        return cat

    def pose(self, platform: str, parts: Sequence[SpatialCommand], timeout: float = 2.0
             ) -> Pose:
        """What ``parts`` mean on ``platform``, from its databank (as its robots resolve
        them); the databank's error (``unknown_limb``, ``direction_unavailable``...) raised."""
        key, payload = pose_query(self.keys, platform, parts)
        return get_one(self.session, key, Pose, payload, timeout=timeout, retry=True,
                       no_answer=f"no databank answers for platform {platform!r}")

    # --- commands -----------------------------------------------------------------------

    def publisher(self, key: str, *, urgent: bool = False) -> zenoh.Publisher:
        with self._lock:
            pub = self._publishers.get((key, urgent))
            if pub is None:
                pub = self._publishers[key, urgent] = self.session.declare_publisher(
                    key,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    priority=zenoh.Priority.REAL_TIME
                    if urgent
                    else zenoh.Priority.INTERACTIVE_HIGH,
                    express=True,
                )
            return pub

    def wait_subscribers(self, keys: Iterable[str], timeout: float) -> list[str]:
        """Declare publishers for the command ``keys`` (signed with this link's sender) and
        wait until each has a subscriber; the unmatched, as given."""
        return zconfig.unmatched(
            {key: self.publisher(Keys.signed(key, self.sender)) for key in keys}, timeout)

    def put(self, keys: Iterable[str], cmd: Command) -> None:
        """Put ``cmd`` on every command key, signed with its sender (the same seq: each robot
        sees it once)."""
        payload = encode(cmd)
        for key in keys:
            self.publisher(Keys.signed(key, cmd.sender), urgent=cmd.estop).put(payload)

    def alive_robots(self, timeout: float = 2.0) -> list[str]:
        """Every robot whose liveliness token exists now, by a liveliness query (complete
        when it returns, unlike a subscriber's history, which trickles in)."""
        found = set()
        replies = self.session.liveliness().get(self.keys.alive_robot("*"), timeout=timeout)
        for reply in replies:
            if reply.ok is not None:
                try:
                    found.add(self.keys.robot_id_of(str(reply.ok.key_expr)))
                except KinesphereError:
                    continue
        with self.changed:
            self._alive |= found
            self.changed.notify_all()
        return sorted(found)

    def estop_all(self, seq: Sequencer) -> Command:
        """E-stop every robot under the prefix, whatever the current target."""
        cmd = seq.estop()
        self.put([self.keys.command("*")], cmd)
        return cmd

    def close(self) -> None:
        """Undeclare everything this link declared (the session stays open)."""
        with self._lock:
            pubs = list(self._publishers.values())
            self._publishers.clear()
        zconfig.undeclare(*self._subs, *pubs)
        self._subs.clear()


# --- what every operator command shares ---------------------------------------------------


@contextmanager
def link_for(args: argparse.Namespace, *, ros2: bool = False) -> Iterator[RobotLink]:
    """A watching RobotLink as ``args.sender`` on a session made from the Zenoh options
    (``ros2``: the session also carries a ROS 2 node)."""
    keys = Keys(args.prefix)
    with zconfig.session_from_args(args, ros2=ros2) as session:
        link = RobotLink(session, keys, sender=args.sender)
        try:
            yield link
        finally:
            link.close()


def reachable(link: RobotLink, target: tg.Target, wait: float) -> list[str]:
    """The target's command keys, once a robot listens on each; else unavailable, saying why:
    this session reached nobody (no router: the command that starts one), or which robots
    are alive (a robot id that is a group's name, a platform's, or near a live robot's id is
    answered with what was meant). A robot id nobody has but that names a live robot's
    platform fails at once: the user gave the platform, not the id."""
    keys = target.keys(link.keys)
    if target.kind == "robot":
        alive = link.alive_robots()
        if target.name not in alive:
            meant = _platform_named(link, target.name, alive)
            if meant:
                raise KinesphereError("unavailable", f"no robot has the id {target.name!r}: "
                                      f"{target.name} is the platform of {meant}; give "
                                      "the robot's id")
    missing = link.wait_subscribers(keys, wait)
    if not missing:
        return keys
    nobody = zconfig.alone(link.session)
    if nobody:
        raise KinesphereError("unavailable", f"no robot listens on {', '.join(missing)}: "
                              f"{nobody}")
    hint = ""
    if target.kind == "robot":
        as_group = tg.group(target.name)
        if not link.wait_subscribers(as_group.keys(link.keys), 0.5):
            hint = f"; did you mean {as_group.spelling!r} (a group)?"
        else:
            hint = did_you_mean(target.name, link.alive_robots())
    raise KinesphereError(
        "unavailable", f"no robot listens on {', '.join(missing)} (waited {wait:g} s); "
        f"{live_robots(link)}{hint}")


def live_robots(link: RobotLink) -> str:
    """``live robots: baxter-1 (baxter), yb-1 (youbot)``, or that this client saw none alive
    (no liveliness token, no state: what it saw, not a claim about the robots)."""
    alive = link.alive_robots()
    if not alive:
        return f"no robot seen alive under {link.keys.prefix!r}"
    states = link.states()
    return "live robots: " + ", ".join(
        f"{rid} ({states[rid].state.platform})" if rid in states else rid for rid in alive)


def _platform_named(link: RobotLink, name: str, alive: list[str]) -> str:
    """The live robots whose platform is ``name`` (``yb-1 (a youbot)``), once their states
    came in (up to :data:`PLATFORM_WAIT_S`); "" when none is."""
    wanted = set(alive)
    link.wait_for(lambda lk: wanted <= set(lk.states()), PLATFORM_WAIT_S)
    states = link.states()
    of = sorted(rid for rid in alive if rid in states
                and states[rid].state.platform.casefold() == name.casefold())
    return " and ".join(f"{rid} (a {name})" for rid in of)


PLATFORM_WAIT_S = 1.0
"""How long a wrong robot id waits for the live robots' states (their platforms)."""


@contextmanager
def signals(on_stop: Callable[[], None]) -> Iterator[None]:
    """SIGTERM (and SIGINT) end the work through ``on_stop`` so the final stop still goes out."""

    def handler(signum: int, frame: FrameType | None) -> None:
        on_stop()

    with handle_signals(handler, (signal.SIGTERM, signal.SIGINT)):
        yield
