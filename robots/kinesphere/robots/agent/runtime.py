"""The robot agent: commands in, RobotState out, a real-time control loop in between.

Threads: Zenoh callbacks only decode and append to an inbox (a deque: lock-free, never
blocks the network); the resolver's worker does the blocking databank queries; the control
loop alone touches the Controller and its :class:`~kinesphere.robots.agent.body.Body`, drains
the inbox at the start of each step and publishes state every ``1/state_rate`` s of robot time.
Commands whose poses are cached are applied in the very step that drains them. Whatever fails
in a step (a command, a trajectory, the body) is reported in the state; the loop never stops
stepping and publishing.

Clock: the loop's own simulated time drives the trajectories and the watchdog. ``speed`` sets
how it is paced (``pacing.py``): 1 = real time (wall clock), k = k times faster, 0 = as fast
as possible (tests and benchmarks).

Ordering rules are in ``ordering.py``, safety rules in ``safety.py``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.protocol import Command, Payload, Pose, RobotState, Status, decode, encode
from kinesphere.robots.agent.base import drive_base
from kinesphere.robots.agent.body import Body, make_body
from kinesphere.robots.agent.controller import BLOCKED_TOL as BLOCKED_TOL
from kinesphere.robots.agent.controller import Controller
from kinesphere.robots.agent.options import AgentOptions as AgentOptions
from kinesphere.robots.agent.ordering import Ordering
from kinesphere.robots.agent.pacing import WARN_EVERY_S, LoopStats, run_paced
from kinesphere.robots.agent.resolver import Answer, Resolver, parts_key
from kinesphere.robots.agent.safety import Safety, Verdict
from kinesphere.robots.agent.status import reported_status
from kinesphere.zconfig import undeclare

log = logging.getLogger(__name__)

SETTLE_S = 0.2
"""Robot time the servos get after a trajectory ends before the body is held to it."""


@dataclass
class _Received:
    cmd: Command


@dataclass
class _Bad:
    error: KinesphereError


@dataclass
class _Resolved:
    ticket: int
    answer: Answer


class Agent:
    """One robot: a body and its Controller, safety rules, databank resolver, Zenoh face.

    ``body`` defaults to ``options.body`` made for ``platform`` (``body.py``'s registry).
    """

    def __init__(
        self, platform: str, robot_id: str, session: zenoh.Session,
        options: AgentOptions | None = None, body: Body | None = None,
    ) -> None:
        self.options = options or AgentOptions()
        self.keys = Keys(self.options.prefix)
        self.keys.command(robot_id)  # validates the id as a key segment
        self.robot_id = robot_id
        self.session = session
        if body is None:
            body = make_body(self.options.body, platform, 1.0 / self.options.rate,
                             session=session, options=self.options, robot_id=robot_id)
        self.controller = Controller(body, self.options.margin)
        self.platform = self.controller.platform.name
        self.resolver = Resolver(session, self.platform, self.keys, self.options.query_timeout_s)
        self.safety = Safety()
        self.stats = LoopStats()
        self.latencies: deque[tuple[int, int, int]] = deque(maxlen=10_000)
        """(seq, sent_ns, first moving step ns) per pose command applied."""
        self.last_state: RobotState | None = None
        self._inbox: deque[_Received | _Bad | _Resolved] = deque()
        self.ordering = Ordering()
        self._status: str = Status.IDLE
        self._detail = "no command yet"
        self._fault = ""
        self._failed_at = -1e9
        self._body_fault = False
        self._ticks = 0
        self._state_seq = 0
        self._moved_at = 0.0
        self._publish_every = max(1, round(self.options.rate / self.options.state_rate))
        self._entities: list[Any] = []
        self._publisher: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    # --- lifetime ------------------------------------------------------------------------------

    def declare(self) -> None:
        """Subscribe to commands, declare the state publisher and liveliness token."""
        s = self.session
        keys = [self.keys.command(self.robot_id)]
        keys += [self.keys.group_command(g) for g in self.options.groups]
        self._entities = [s.declare_subscriber(k, self._on_sample) for k in keys]
        self._publisher = s.declare_publisher(
            self.keys.state(self.robot_id), congestion_control=zenoh.CongestionControl.DROP
        )
        self._entities.append(self._publisher)
        self._entities.append(s.liveliness().declare_token(self.keys.alive_robot(self.robot_id)))
        self.resolver.start()
        log.info("agent %s (%s) up: %s", self.robot_id, self.platform, keys[0])

    def start(self) -> Agent:
        """Declare and run the loop in a thread; :meth:`close` ends both."""
        self.declare()
        self._thread = threading.Thread(target=self.run, name=f"agent-{self.robot_id}",
                                        daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the loop, undeclare everything, release the body (the session stays open: the
        caller owns it)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self.resolver.close()
        undeclare(*reversed(self._entities))
        self._entities = []
        self.controller.body.close()
        log.info("agent %s down after %d steps (%d slips)", self.robot_id, self.stats.steps,
                 self.stats.slips)

    def __enter__(self) -> Agent:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- network callbacks (Zenoh threads) -----------------------------------------------------

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self.receive(sample.payload)

    def receive(self, payload: Payload) -> None:
        """Queue an encoded Command for the next control step (any thread; never blocks)."""
        try:
            self._inbox.append(_Received(decode(payload, Command)))
        except KinesphereError as exc:
            self._inbox.append(_Bad(exc))

    def _on_resolved(self, ticket: int, answer: Answer) -> None:
        self._inbox.append(_Resolved(ticket, answer))

    # --- the loop ------------------------------------------------------------------------------

    def run(self, stop: threading.Event | None = None, on_tick: Callable[[], None] | None = None
            ) -> None:
        """Step paced by ``options.speed`` until :meth:`close` (or ``stop`` is set)."""
        period = self.controller.dt / self.options.speed if self.options.speed > 0 else 0.0

        def step() -> None:
            self.tick()
            if on_tick is not None:
                on_tick()

        def stopped() -> bool:
            return self._stop.is_set() or (stop is not None and stop.is_set())

        def failed(exc: Exception) -> None:
            self._set(Status.ERROR, f"internal: control step failed: {exc!r}")

        run_paced(step, period, stopped, self.stats, f"agent {self.robot_id}", failed)

    def tick(self) -> None:
        """One control cycle: commands, watchdog, one step, and state when due.

        Each part is guarded on its own: a failing step still lets the watchdog, the state
        and the next commands through, and leaves the body held where it is.
        """
        inbox = self._inbox
        while inbox:
            self._handle(inbox.popleft())
        ctrl = self.controller
        if self.safety.expired(ctrl.time) and ctrl.moving:
            self._halt(Status.HOLDING, "no new command within ttl_ms: holding")
        try:
            ctrl.step()
        except Exception as exc:
            self._step_failed(exc)
        else:
            if self._body_fault:  # e.g. joint states arrive again: say so, keep holding
                self._body_fault = False
                self._set(Status.HOLDING, "body working again; holding until a new command")
        self._ticks += 1
        self.stats.steps += 1
        self._after_step()
        if self._ticks % self._publish_every == 0:
            self.publish()

    def _after_step(self) -> None:
        ctrl = self.controller
        if ctrl.moving:
            self._moved_at = ctrl.time
        fault = ctrl.fault()
        if fault != self._fault:
            self._fault = fault
            if fault:
                self._set(Status.ERROR, f"{fault} and holding")
        moved = self.ordering.stepped()
        if moved is not None:
            self.latencies.append((moved.seq, moved.sent_ns, time.time_ns()))

    def _step_failed(self, exc: Exception) -> None:
        """A step raised (a bug, or a body that failed): hold the body and say so."""
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
        self.ordering.overtake()
        self._set(Status.ERROR, detail)
        try:
            self.controller.fail_safe()
        except Exception:
            log.debug("fail-safe hold failed too", exc_info=True)

    # --- commands (control thread) ------------------------------------------------------------

    def _handle(self, item: _Received | _Bad | _Resolved) -> None:
        """Act on one inbox item; whatever goes wrong is reported, never raised into the loop."""
        cmd: Command | None = None
        try:
            if isinstance(item, _Resolved):
                waiting = self.ordering.answer(item.ticket)
                if waiting is None:
                    return  # overtaken by a newer command, a stop or an e-stop
                cmd = waiting.cmd
                self.ordering.acted(cmd.seq)
                if isinstance(item.answer, KinesphereError):
                    raise item.answer
                self._apply_pose(item.answer, waiting.yaw, cmd)
            elif isinstance(item, _Bad):
                raise item.error
            else:
                cmd = item.cmd
                self._command(cmd)
        except KinesphereError as exc:
            self._rejected(exc, cmd)
        except Exception as exc:  # a bug must not take the robot's control loop down
            log.exception("agent %s: %s failed", self.robot_id, self._what(cmd))
            self._rejected(KinesphereError("internal", repr(exc)), cmd)

    @staticmethod
    def _what(cmd: Command | None) -> str:
        return "command" if cmd is None else f"command {cmd.seq}"

    def _rejected(self, exc: KinesphereError, cmd: Command | None) -> None:
        if cmd is not None:
            self.ordering.acted(cmd.seq)
        self._error(exc, self._what(cmd))

    def _command(self, cmd: Command) -> None:
        if self.ordering.stale(cmd):
            log.debug("stale command %s from %r dropped", cmd.seq, cmd.sender)
            return
        ctrl = self.controller
        verdict = self.safety.on_command(cmd, ctrl.time)
        if verdict is not Verdict.MOVE or not cmd.parts:
            self.ordering.acted(cmd.seq)  # acted on now; poses count once resolved
        if verdict is Verdict.ESTOP:
            self._halt(Status.ESTOP, f"e-stop from {cmd.sender or 'a client'}; release with "
                       "a command with release=true (kinesphere estop --release)")
            log.warning("agent %s: e-stop (seq %d)", self.robot_id, cmd.seq)
        elif verdict is Verdict.LATCHED:
            self._set(Status.ESTOP, "e-stop latched; ignoring commands until one with "
                      "release=true (kinesphere estop --release)")
        elif verdict is Verdict.RELEASE:
            self._set(Status.IDLE, "e-stop released; send a command to move")
            log.warning("agent %s: e-stop released (seq %d)", self.robot_id, cmd.seq)
        elif verdict is Verdict.STOP:
            self._halt(Status.STOPPED, "stop command")
        elif verdict is Verdict.DEADMAN:
            self._halt(Status.HOLDING, "deadman released: holding")
        else:
            self._move(cmd)

    def _move(self, cmd: Command) -> None:
        ctrl = self.controller
        base = ctrl.base
        if cmd.drive is not None:
            self._set(Status.MOVING, drive_base(base, cmd.drive, self.platform))
        elif base is not None and base.driving:
            base.stop()
        if not cmd.parts:
            return
        key = parts_key(cmd.parts)
        hit = self.resolver.cached(key)
        yaw = ctrl.commanded_base_yaw()
        if hit is not None:
            self.ordering.overtake()
            self.ordering.acted(cmd.seq)
            self._apply_pose(hit, yaw, cmd)
        else:
            ticket, _ = self.ordering.wait(cmd, yaw)
            self.resolver.submit(ticket, key, self._on_resolved)

    def _apply_pose(self, pose: Pose, yaw: float | None, cmd: Command) -> None:
        ctrl = self.controller
        if pose.platform != self.platform:
            raise KinesphereError("internal", f"databank answered for {pose.platform!r}")
        try:
            clamps = ctrl.joints.retarget(pose.joints)
        except (KeyError, ValueError) as exc:
            self._error(KinesphereError(
                "internal", f"databank pose has joints {self.platform} cannot take: {exc}"),
                f"command {cmd.seq}")
            return
        if pose.translation is not None and ctrl.base is not None and not ctrl.base.driving:
            ctrl.base.translate(pose.translation, yaw)
        beyond = [c for c in clamps if c.beyond]
        if beyond:
            detail = "clamped " + ", ".join(f"{c.joint} {c.requested:+.4f}->{c.target:+.4f}"
                                             for c in beyond)
            log.info("agent %s: %s", self.robot_id, detail)
        else:
            detail = f"to {pose.limb}/{pose.origin}/{pose.direction}/{pose.size:g}"
        self._set(Status.MOVING, detail)
        self.ordering.applied(cmd)

    def _halt(self, status: str, detail: str) -> None:
        self.ordering.overtake()  # a pose still waiting for the databank no longer applies
        self.controller.halt()
        self._set(status, detail)

    def _set(self, status: str, detail: str) -> None:
        self._status, self._detail = status, detail

    def _error(self, exc: KinesphereError, what: str) -> None:
        log.warning("agent %s: %s rejected: %s", self.robot_id, what, exc)
        if exc.code == "unavailable":
            self._set(Status.DATABANK_UNREACHABLE, f"{what}: {exc.message}; holding last pose")
        else:
            self._set(Status.ERROR, f"{what}: {exc.code}: {exc.message}")

    # --- state -----------------------------------------------------------------------------------

    def status(self) -> tuple[str, str]:
        """The status and detail to publish now (precedence: :func:`reported_status`)."""
        ctrl = self.controller
        reported: tuple[str, str] = reported_status(
            self._status, self._detail, estopped=self.safety.estopped,
            reachable=self.resolver.reachable, last_error=self.resolver.last_error,
            moving=ctrl.moving, clamped=bool(ctrl.joints.clamped),
            settled=ctrl.time - self._moved_at >= SETTLE_S,
            blocked=lambda: ctrl.blocked(BLOCKED_TOL),
        )
        return reported

    def publish(self) -> RobotState:
        ctrl = self.controller
        status, detail = self.status()
        self._state_seq += 1
        state = RobotState(
            robot_id=self.robot_id, platform=self.platform, seq=self._state_seq,
            stamp_ns=time.time_ns(), joint_names=list(ctrl.joint_names), q=ctrl.q(),
            qd=ctrl.qd(), base_pose=ctrl.base_pose(), status=status,
            last_command_seq=self.ordering.last_seq, detail=detail,
            clamped=sorted(ctrl.joints.clamped),
        )
        self.last_state = state
        if self._publisher is not None:
            try:
                self._publisher.put(encode(state))
            except zenoh.ZError as exc:  # session closing or congested: the loop goes on
                log.debug("state not published: %s", exc)
        return state

    def cost_percentiles(self) -> tuple[float, float]:
        """Median and p99 step cost in seconds over the recent steps."""
        costs = np.fromiter(self.stats.costs_s, dtype=float)
        if costs.size == 0:
            return 0.0, 0.0
        return float(np.median(costs)), float(np.percentile(costs, 99))
