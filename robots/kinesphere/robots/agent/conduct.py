"""What the robot does with each command: admit it, check the lease and the safety rules, move
or halt, and tell the sender (``Ack``) at every stage.

The control loop (``runtime.py``) hands over every inbox item and calls :meth:`Conduct.after_step`
after each step; nothing here runs in another thread. The rules themselves live with their
logic: ordering and expiry in ``ordering.py``, safety in ``safety.py``, the control lease in
``lease.py``, acknowledgements in ``acks.py``. Order of the checks for a command: dropped if
stale or expired (acked ``stale``/``expired``); while an e-stop is latched, refused as
``estopped`` (only an e-stop or a release goes further); refused if another sender holds the
lease (``lease_held``); then the safety verdict (e-stop, release, stop, deadman); then a
lease-only command is answered ``leased`` and anything else moves.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable, Hashable

from kinesphere import hints
from kinesphere.errors import KinesphereError
from kinesphere.lru import Lru
from kinesphere.protocol import (
    ANONYMOUS,
    OVERFLOW,
    AckStage,
    Command,
    LeaseAction,
    Pose,
    Status,
)
from kinesphere.ratelog import RateLog
from kinesphere.robots.agent.acks import Acks, Due, Meaning, Motion
from kinesphere.robots.agent.base import drive_base
from kinesphere.robots.agent.controller import BLOCKED_TOL, Controller
from kinesphere.robots.agent.estops import FLEET_SESSION, FleetBoard
from kinesphere.robots.agent.inbox import Resolved
from kinesphere.robots.agent.lease import Lease, holder_name
from kinesphere.robots.agent.ordering import Ordering, Received
from kinesphere.robots.agent.pacing import WARN_EVERY_S
from kinesphere.robots.agent.resolver import PartsKey, PoseAnswer, Resolver, parts_key
from kinesphere.robots.agent.safety import Safety, Verdict
from kinesphere.robots.agent.status import reported_status
from kinesphere.robots.agent.trajectory import Aim, Clamp

log = logging.getLogger(__name__)

AIMS_KEPT = 256
"""Compiled poses kept (:meth:`Conduct._aim`; a few hundred bytes each, oldest dropped)."""
SETTLE_S = 0.2
"""Robot time the servos get after a trajectory ends before the body is held to it."""
_DRIVE = ("drive",)
"""The target of a motion that only drives the base."""


class Conduct:
    """One robot's response to commands, and the status it reports (module text)."""

    def __init__(
        self, robot_id: str, controller: Controller, resolver: Resolver,
        on_resolved: Callable[[int, PoseAnswer], None], max_translation_m: float,
        time_scale: float = 1.0,
    ) -> None:
        self.robot_id = robot_id
        self.controller = controller
        self.platform = controller.platform.name
        self.resolver = resolver
        self.max_translation_m = max_translation_m
        self.time_scale = time_scale if time_scale > 0 else 1.0
        """Robot seconds per second of the senders' clocks (the loop's ``speed``; an unpaced
        loop counts as 1): a command's ``arrive_ms`` is in the sender's time."""
        self._on_resolved = on_resolved
        self.safety = Safety()
        self.lease = Lease()
        self.ordering = Ordering()
        self.acks = Acks(robot_id, lambda: self.lease.holder)
        self.acks.late = self._late
        self.latencies: deque[tuple[int, int, int]] = deque(maxlen=10_000)
        """(seq, sent_ns, ns when the first setpoint toward it went to the body) per pose
        command applied."""
        self.estop_lag: deque[int] = deque(maxlen=1000)
        """Per e-stop: control steps begun from its receipt to its handling (1: the next)."""
        self.ticks = 0
        """The control loop's step count (set by the loop)."""
        self._holders: dict[str, Command] = {}  # the lease holder's last command
        self._status: str = Status.IDLE
        self._detail = "no command yet"
        self._fault = ""
        self._failed_at = -1e9
        self._body_fault = False
        self._ratelog = RateLog(log)
        self.wall: Callable[[], float] = time.monotonic
        """The host's clock the senders' seconds go by (a test sets its own)."""
        self._aims: Lru[int, tuple[Pose, Aim]] = Lru(AIMS_KEPT)
        self._started: tuple[Command, Pose, PartsKey, list[Clamp], Due | None] | None = None
        """The move started this step, its status and acks not yet said (:meth:`_settle`)."""
        self._waiting_due: Due | None = None
        """When the command waiting for the databank is to arrive (robot seconds)."""
        self.board: FleetBoard | None = None
        """The process's fleet e-stops (set by the agent): an e-stop in force there is
        released for every robot at once (the hint says ``--target all``)."""

    def watch(self, now: float) -> None:
        """The wall-clock timers: an expired lease frees, an expired watchdog holds."""
        self.lease.expire(now)
        if self.safety.expired(now) and self.controller.moving:
            self.halt(Status.HOLDING, "no new command within ttl_ms: holding", AckStage.HOLDING)

    def quiet(self) -> bool:
        """Whether the next step needs nothing of the conduct before the body's step but its
        timers (:meth:`deadline`): nothing said and not flushed, no motion whose ``moving``
        is still to say, no body fault to clear (``Agent.needs_cycle``)."""
        motion = self.acks.motion
        return not (self._started is not None or self.acks.pending or self._body_fault
                    or (motion is not None and not motion.moved))

    @property
    def untimed(self) -> bool:
        """No motion with a due time to track (``arrive_ms``) and the host's own clock: all
        :meth:`followed` does is note that the robot moved (``Ledger.glided``)."""
        motion = self.acks.motion
        return (motion is None or motion.due is None) and self.wall is time.monotonic

    @property
    def settled(self) -> bool:
        """No motion whose end is still to say (:meth:`after_step`; a drive ends only when
        replaced)."""
        motion = self.acks.motion
        return motion is None or motion.target == _DRIVE

    def deadline(self) -> float:
        """When :meth:`watch` next has something to do (monotonic s; inf: never, until a
        command arrives): the watchdog, the lease's expiry."""
        watchdog = self.safety.deadline
        lease = self.lease.expires
        return min(math.inf if watchdog is None else watchdog, lease)

    def followed(self) -> None:
        """A step along a followed trajectory went as planned: all :meth:`after_step` would
        have done (a fleet host's lean step, ``Agent.followed``)."""
        self._moved()
        motion = self.acks.motion
        if motion is not None and motion.due is not None:  # else nothing to track: no call
            self._track(True)

    def _moved(self) -> None:
        """The joints or base moved in the step just taken: it is when they last moved (the
        controller's ledger keeps it, so a fleet host notes it for all gliding robots at
        once: ``Ledger.glided``)."""
        ctrl = self.controller
        ledger, slot = ctrl.ledger, ctrl.slot
        ledger.moved[slot] = ledger.steps[slot]
        ledger.moved_wall[slot] = self.wall()

    @property
    def _moved_at(self) -> float:
        """Robot time when the joints or base last moved."""
        ctrl = self.controller
        return float(ctrl.ledger.moved[ctrl.slot]) * ctrl.dt

    def servos_settled(self) -> bool:
        """Whether the servos had their time (:data:`SETTLE_S` of robot time) since the
        joints or base last moved."""
        return self.controller.time - self._moved_at >= SETTLE_S

    @property
    def _moved_wall(self) -> float:
        """:attr:`wall` when the joints or base last moved."""
        ctrl = self.controller
        return float(ctrl.ledger.moved_wall[ctrl.slot])

    def _track(self, under_way: bool) -> None:
        """A timed motion under way (or braked while the guard finds a way): when it would
        arrive, as planned now (:meth:`_late` of one replaced before it arrived)."""
        motion, ctrl = self.acks.motion, self.controller
        if motion is None or motion.due is None or not motion.moved:
            return
        guard = ctrl.guard
        if under_way or (guard is not None and (guard.legs or guard.pending)):
            left = max(ctrl.remaining, ctrl.dt)
            motion.eta = Due(ctrl.time + left, self.wall() + left / self.time_scale)

    def commanded(self) -> None:
        """The step's setpoints went to the body: the first toward a new target is the moment
        the robot started moving for that command (``moving``; the latency probe)."""
        now_ns = time.time_ns()
        self._settle()
        first = self.acks.stepped()
        if first is not None:
            self.latencies.append((first.seq, first.sent_ns, now_ns))

    def after_step(self) -> bool:
        """After each step: faults, the first step of a motion, the end of one. Whether
        anything changed (a fault, a motion's end)."""
        ctrl = self.controller
        moving = ctrl.moving
        if moving:
            self._moved()
        changed = False
        self._track(moving)
        fault = ctrl.fault()
        if fault != self._fault:
            self._fault, changed = fault, True
            if fault:
                self.acks.end(AckStage.BLOCKED, fault)
                self.set(Status.ERROR, f"{fault} and holding")
        motion = self.acks.motion
        if (motion is not None and motion.moved and motion.target != _DRIVE
                and not moving and self.servos_settled() and not ctrl.deciding):
            changed = True
            why = ctrl.blocked(BLOCKED_TOL)
            if why:
                self.acks.end(AckStage.BLOCKED, why)
            elif ctrl.joints.clamped:
                self.acks.end(AckStage.CLAMPED,
                              "clamped " + ", ".join(sorted(ctrl.joints.clamped)))
            else:
                self.acks.end(AckStage.REACHED)
        return changed

    def step_failed(self, exc: Exception) -> None:
        """A step raised (a bug, or a body that failed): hold the body and say so."""
        self._settle()
        now = time.monotonic()
        if isinstance(exc, KinesphereError):  # the body says what is wrong with it
            detail = f"body: {exc.message}; holding"
            self._body_fault = True
        else:
            detail = f"internal: control step failed: {exc!r}; holding"
        if now - self._failed_at > WARN_EVERY_S:
            self._failed_at = now
            if isinstance(exc, KinesphereError):
                log.warning("agent %s: %s", self.robot_id, detail)
            else:
                log.exception("agent %s: control step failed", self.robot_id)
        self._overtake()
        self.acks.end(AckStage.BLOCKED, detail)
        self.set(Status.ERROR, detail)
        try:
            self.controller.fail_safe()
        except Exception:
            log.debug("fail-safe hold failed too", exc_info=True)

    def step_worked(self) -> None:
        """A step after failed ones went through (e.g. joint states arrive again): say so,
        and keep holding until a new command."""
        if self._body_fault:
            self._body_fault = False
            self.set(Status.HOLDING, "body working again; holding until a new command")

    def handle(self, item: Received | KinesphereError | Resolved, now_ns: int) -> None:
        """Act on one inbox item; whatever goes wrong is reported, never raised into the loop."""
        self._settle()
        cmd: Command | None = None
        try:
            if isinstance(item, Resolved):
                waiting = self.ordering.answer(item.ticket)
                if waiting is None:
                    return  # overtaken by a newer command, a stop or an e-stop
                cmd = waiting.cmd
                self.ordering.acted(cmd.seq)
                if isinstance(item.answer, KinesphereError):
                    raise item.answer
                self._apply_pose(item.answer, waiting.yaw, cmd, due=self._waiting_due)
            elif isinstance(item, KinesphereError):
                raise item
            else:
                cmd = item.cmd
                self._command(item, now_ns)
        except KinesphereError as exc:
            self._rejected(exc, cmd)
        except Exception as exc:  # a bug must not take the robot's control loop down
            log.exception("agent %s: %s failed", self.robot_id, self._what(cmd))
            self._rejected(KinesphereError("internal", repr(exc)), cmd)

    @staticmethod
    def _what(cmd: Command | None) -> str:
        return "command" if cmd is None else f"command {cmd.seq} from {cmd.sender or '?'}"

    def _rejected(self, exc: KinesphereError, cmd: Command | None) -> None:
        """A command the robot could not act on: the sender is told, the status says why."""
        if cmd is not None:
            self.ordering.acted(cmd.seq)
            self.acks.send(cmd, AckStage.REJECTED, exc.message, code=exc.code)
        self._ratelog(exc.code, "agent %s: %s rejected: %s", self.robot_id, self._what(cmd),
                      exc)
        if exc.code == "unavailable":
            self.set(Status.DATABANK_UNREACHABLE,
                      f"{self._what(cmd)}: {exc.message}; holding last pose")
        else:
            self.set(Status.ERROR, f"{self._what(cmd)}: {exc.code}: {exc.message}")

    def _command(self, item: Received, now_ns: int) -> None:
        cmd = item.cmd
        dropped = self.ordering.admit(item, now_ns)
        if dropped is not None:
            if dropped.code != "malformed":  # stale or expired: counted, told, not an error
                log.debug("%s dropped: %s", self._what(cmd), dropped)
                self.acks.send(cmd, AckStage.REJECTED, dropped.message, code=dropped.code)
                return
            raise dropped
        if self.safety.estopped and not (cmd.estop or cmd.release):
            self.lease.touch(cmd, now_ns / 1e9)  # latched: refused as such, whoever holds it
        else:
            lease = self.lease.check(cmd, now_ns / 1e9)
            if not lease.allowed:
                self.acks.send(cmd, AckStage.REJECTED, f"{lease.holder} holds this robot's "
                               "lease", code="lease_held")
                return
            if lease.holder == holder_name(cmd):
                self._taken(lease.taken_from, cmd)
        verdict = self.safety.on_command(cmd, item.mono_ns / 1e9)
        if (verdict is not Verdict.MOVE or not cmd.parts) and cmd.session != FLEET_SESSION:
            self.ordering.acted(cmd.seq)  # acted on now; poses count once resolved
        if verdict is Verdict.ESTOP:
            self.estop_lag.append(self.ticks - item.tick)
            by = cmd.sender or ANONYMOUS
            fleet = self.board is not None and self.board.engaged(cmd.sender)
            what = "fleet e-stop" if fleet else "e-stop"
            if cmd.session == FLEET_SESSION:
                what += " in force (sent before this robot heard it)"
            if by == OVERFLOW or by not in self.safety.latches:  # held by the overflow latch
                how = "only restarting its agent at the robot releases it"
            else:
                release = hints.release_estop("all" if fleet else self.robot_id,
                                              "" if by == ANONYMOUS else by)
                each = " (each holder releases their own)" if len(self.safety.latches) > 1 \
                    else ""
                how = f"release with '{release}'{each}"
            self.halt(Status.ESTOP, f"{what} from {self.safety.holders()}; {how}",
                      AckStage.SUPERSEDED)
            log.warning("agent %s: %s by %s (seq %d)", self.robot_id, what, by, cmd.seq)
            self.acks.send(cmd, AckStage.ESTOPPED)
        elif verdict is Verdict.LATCHED:
            self.acks.send(cmd, AckStage.REJECTED, self._latched(cmd), code="estopped")
        elif verdict is Verdict.RELEASE:
            self.set(Status.IDLE, "e-stop released; send a command to move")
            log.warning("agent %s: e-stop released by %s (seq %d)", self.robot_id,
                        cmd.sender, cmd.seq)
            self.acks.send(cmd, AckStage.RELEASED)
        elif verdict is Verdict.STOP:
            self.halt(Status.STOPPED, "stop command", AckStage.SUPERSEDED)
            self.acks.send(cmd, AckStage.STOPPED)
        elif verdict is Verdict.DEADMAN:
            self.halt(Status.HOLDING, "deadman released: holding", AckStage.HOLDING)
            self.acks.send(cmd, AckStage.HOLDING, "deadman released")
        elif cmd.lease is not LeaseAction.NONE and not cmd.parts and cmd.drive is None:
            holder = self.lease.holder
            self.acks.send(cmd, AckStage.LEASED,
                           f"lease {cmd.lease}: " + (f"held by {holder}" if holder else "free"))
        else:
            self._move(cmd, self._due(cmd, now_ns - item.mono_ns))

    def _due(self, cmd: Command, age_ns: int) -> Due | None:
        """When ``cmd`` is to arrive: ``arrive_ms`` after it was sent (its age here counts as
        gone), None when it sets no time."""
        if cmd.arrive_ms <= 0:
            return None
        left = max(0.0, cmd.arrive_ms / 1e3 - age_ns / 1e9)
        return Due(self.controller.time + left * self.time_scale, self.wall() + left)

    def _late(self, motion: Motion, planned: bool) -> int:
        """Milliseconds (the sender's) by which ``motion`` arrives after its due time: as
        planned when it starts, else as it went; a motion replaced before it arrived by when
        it would have arrived, as last planned (a route around a contact: its waypoints too).
        Late by either clock: the robot's own, or the host's when the loop fell behind."""
        ctrl = self.controller
        due = motion.due
        if due is None:
            return 0
        if planned:  # the plan, in the robot's time (the host's has not passed yet)
            late = (ctrl.time + ctrl.remaining - due.robot) / self.time_scale
            return round(max(0.0, late) * 1e3)
        now = self.wall()
        if motion.eta.robot > ctrl.time:  # replaced under way
            arrival = motion.eta
        elif ctrl.moving:
            arrival = Due(ctrl.time, now)
        else:
            arrival = Due(self._moved_at, self._moved_wall)
        step = ctrl.dt / self.time_scale
        late = max(0.0, (arrival.robot - due.robot) / self.time_scale - step,
                   arrival.wall - due.wall - step)
        return round(late * 1e3)

    def _latched(self, cmd: Command) -> str:
        """Why ``cmd`` is refused while an e-stop is latched."""
        holders = self.safety.holders()
        if not cmd.release:
            return f"e-stop latched by {holders}; only a release is obeyed"
        if not cmd.sender:
            return f"e-stop latched by {holders}; a release must name its sender"
        blocking = self.safety.predates(cmd)
        if blocking == ANONYMOUS:
            return (f"e-stop still latched by {holders}: this release was stamped (by "
                    f"{cmd.sender}'s clock) before the unnamed e-stop was (by its sender's "
                    "clock, which may be another host's), so it does not clear it; release "
                    "again once this host's clock has passed that e-stop's time")
        if blocking:
            return (f"e-stop still latched by {holders}: this release was sent before "
                    f"{cmd.sender}'s latest e-stop (by its sender's clock), so it does not "
                    "clear it; release again")
        return (f"e-stop still latched by {holders}: each latch clears only with its own "
                "sender's release (restarting the agent clears it only when no fleet e-stop "
                "of that sender is in force)")

    def _taken(self, previous: str, cmd: Command) -> None:
        """Remember the holder's last command; tell a holder whose lease was taken over."""
        if previous:
            last = self._holders.pop(previous, None)
            if last is not None:
                self.acks.send(last, AckStage.REJECTED, f"lease taken over by {cmd.sender or '?'}",
                          code="lease_held")
        self._holders = {self.lease.holder: cmd}

    def _move(self, cmd: Command, due: Due | None = None) -> None:
        ctrl = self.controller
        base = ctrl.base
        if cmd.heading is not None:
            if base is None:
                raise KinesphereError("cannot_translate", f"{self.platform} has a fixed base: "
                                      "it cannot turn to a heading")
            if cmd.drive is not None:
                raise KinesphereError("malformed", "a command turns the base to a heading or "
                                      "drives it, not both")
        driving = ""
        if cmd.drive is not None:
            driving = drive_base(base, cmd.drive, self.platform)
            self.set(Status.MOVING, driving)
        elif base is not None and base.driving:
            base.stop()
            if self.acks.motion is not None and self.acks.motion.target == _DRIVE:
                self.acks.end(AckStage.SUPERSEDED, "the drive ended")
        if not cmd.parts:
            if cmd.drive is not None:
                self.acks.follow(cmd, _DRIVE)
            elif cmd.heading is not None and base is not None:
                self._overtake()
                base.turn_to(cmd.heading, self._duration(due))
                self.acks.follow(cmd, ("heading", cmd.heading), due=due)
            self.acks.send(cmd, AckStage.ACCEPTED, driving)
            return
        key = parts_key(cmd.parts)
        hit = self.resolver.cached(key)
        yaw = ctrl.commanded_base_yaw()
        if hit is not None:
            self._overtake()
            self.ordering.acted(cmd.seq)
            self._apply_pose(hit, yaw, cmd, key, due)
        else:
            ticket, overtaken = self.ordering.wait(cmd, yaw)
            self._waiting_due = due
            if overtaken is not None:
                self.acks.send(overtaken.cmd, AckStage.SUPERSEDED, "a newer command arrived first")
            self.resolver.submit(ticket, key, self._on_resolved)

    def _duration(self, due: Due | None) -> float | None:
        """Robot seconds from now until ``due`` (None: as fast as the limits allow)."""
        return None if due is None else max(0.0, due.robot - self.controller.time)

    def _apply_pose(self, pose: Pose, yaw: float | None, cmd: Command,
                    key: PartsKey | None = None, due: Due | None = None) -> None:
        ctrl = self.controller
        key = parts_key(cmd.parts) if key is None else key
        if pose.platform != self.platform:
            raise KinesphereError("internal", f"databank answered for {pose.platform!r}")
        if pose.translation is not None:
            far = math.hypot(*pose.translation[:2])
            if not far <= self.max_translation_m:
                raise KinesphereError(
                    "size_out_of_range", f"the pose translates the base {far:.4g} m; this "
                    f"robot moves at most {self.max_translation_m:g} m per command")
        try:  # checked by the guard, waypoints if needed
            clamps = ctrl.move(self._aim(pose), self._duration(due))
        except (KeyError, ValueError) as exc:
            raise KinesphereError(
                "internal", f"databank pose has joints {self.platform} cannot take: {exc}"
            ) from None
        refused = ctrl.guard.fault if ctrl.guard is not None else ""
        if refused:  # the target the guard halted or refused, again: said again, not retried
            meaning = Meaning.of(pose)
            self.acks.follow(cmd, _target(key, cmd), meaning)
            self.acks.send(cmd, AckStage.ACCEPTED, meaning=meaning)
            self.acks.end(AckStage.BLOCKED, refused)
            self.set(Status.ERROR, f"{refused} and holding")
            return
        if pose.translation is not None and ctrl.base is not None and not ctrl.base.driving:
            ctrl.base.translate(pose.translation, yaw)
        if cmd.heading is not None and ctrl.base is not None:
            ctrl.base.turn_to(cmd.heading, self._duration(due))
        self._started = (cmd, pose, key, clamps, due)

    def _settle(self) -> None:
        """Say what the move started this step is: status, followed motion, ``accepted``.

        Deferred from :meth:`_apply_pose` until the first setpoint went to the body
        (:meth:`commanded`), or until anything else the robot does next (another command, a
        halt, a failed step) could depend on it; so this bookkeeping never delays a command's
        first step, and the acks keep their order.
        """
        started, self._started = self._started, None
        if started is None:
            return
        cmd, pose, key, clamps, due = started
        beyond = [c for c in clamps if c.beyond]
        if beyond:
            detail = "clamped " + ", ".join(f"{c.joint} {c.requested:+.4f}->{c.target:+.4f}"
                                             for c in beyond)
            log.info("agent %s: %s", self.robot_id, detail)
        else:
            detail = f"to {pose.limb}/{pose.origin}/{pose.direction}/{pose.size:g}"
        self.set(Status.MOVING, detail)
        meaning = Meaning.of(pose)
        self.acks.follow(cmd, _target(key, cmd), meaning, due)
        self.acks.send(cmd, AckStage.ACCEPTED, detail, meaning=meaning)

    def _aim(self, pose: Pose) -> Aim:
        """``pose`` compiled for this robot's joints, once per pose: the resolver hands out
        the same Pose for every hit on its cache, so a repeated or alternating command skips
        the per-joint checks and clamps on its way to the first setpoint."""
        entry = self._aims.peek(id(pose))
        if entry is not None and entry[0] is pose:  # the entry holds the pose: its id is its own
            return entry[1]
        aim = self.controller.joints.aim(pose.joints)
        self._aims.put(id(pose), (pose, aim))
        return aim

    def _overtake(self) -> None:
        overtaken = self.ordering.overtake()
        if overtaken is not None:
            self.acks.send(overtaken.cmd, AckStage.SUPERSEDED, "a newer command arrived first")

    def halt(self, status: str, detail: str, stage: AckStage) -> None:
        self._settle()
        self._overtake()  # a pose still waiting for the databank no longer applies
        self.acks.end(stage, detail)
        self.controller.halt()
        self.set(status, detail)

    def set(self, status: str, detail: str) -> None:
        self._status, self._detail = status, detail

    def status(self) -> tuple[str, str]:
        """The status and detail to publish now (precedence: :func:`reported_status`)."""
        ctrl = self.controller
        reported: tuple[str, str] = reported_status(
            self._status, self._detail, estopped=self.safety.estopped,
            reachable=self.resolver.reachable, last_error=self.resolver.last_error,
            moving=ctrl.moving or ctrl.deciding, clamped=bool(ctrl.joints.clamped),
            settled=self.servos_settled,
            blocked=ctrl.blocked,  # its tolerance is BLOCKED_TOL
        )
        return reported


def _target(key: PartsKey, cmd: Command) -> Hashable:
    """What a motion goes to: the parts, and the heading when the command turns the base
    (a keyframe that only turns is another motion)."""
    return key if cmd.heading is None else (key, cmd.heading)
