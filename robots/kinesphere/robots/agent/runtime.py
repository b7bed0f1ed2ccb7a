"""The robot agent: commands in, acks and RobotState out, a real-time control loop in between.

Threads: Zenoh callbacks only decode and put into the inbox (``inbox.py``: bounded, e-stops in
a lane of their own, never blocking the network); the resolver's worker does the blocking
databank queries; the control loop alone touches the Controller and its
:class:`~kinesphere.robots.agent.body.Body`. Each step it handles every e-stop first, then the
other commands in arrival order, runs the watchdog, steps, and publishes state every
``1/state_rate`` s of robot time. Commands whose poses are cached are applied in the very step
that drains them. Whatever fails in a step (a command, a trajectory, the body) is reported in
the state; the loop never stops stepping and publishing.

Clocks: robot time (the loop's own, paced by ``speed``: 1 = real time, k = k times faster, 0 =
as fast as possible) drives the trajectories. The watchdog, the lease and command expiry use
the monotonic wall clock, so they fire even when steps fail or the process was frozen.

What the robot does with each command is ``conduct.py``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import msgspec
import numpy as np
import zenoh

from kinesphere.closing import Startable
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.protocol import (
    MAX_TEXT,
    AckStage,
    Command,
    FleetEstop,
    Payload,
    RobotState,
    Status,
    decode,
    encode_into,
)
from kinesphere.ratelog import RateLog
from kinesphere.robots.agent.acks import UrgentOut
from kinesphere.robots.agent.bodies import make_body
from kinesphere.robots.agent.body import Body
from kinesphere.robots.agent.conduct import SETTLE_S as SETTLE_S
from kinesphere.robots.agent.conduct import Conduct
from kinesphere.robots.agent.controller import BLOCKED_TOL as BLOCKED_TOL
from kinesphere.robots.agent.controller import Controller
from kinesphere.robots.agent.estops import FleetBoard, latch_command
from kinesphere.robots.agent.guard import make_guard
from kinesphere.robots.agent.inbox import Inbox, clocks, received
from kinesphere.robots.agent.ledger import Ledger
from kinesphere.robots.agent.options import AgentOptions as AgentOptions
from kinesphere.robots.agent.pacing import LoopStats, Wake, run_paced
from kinesphere.robots.agent.presence import Claim
from kinesphere.robots.agent.resolver import Resolver
from kinesphere.zconfig import undeclare

log = logging.getLogger(__name__)



class Agent(Startable):
    """One robot: a body and its Controller, safety rules, lease, databank resolver, Zenoh face.

    ``body`` defaults to ``options.body`` made for ``platform`` (``body.py``'s registry).
    ``wake`` is set whenever something arrives for the loop (a fleet host shares one among its
    robots); ``phase`` shifts the steps that publish state (a fleet host groups them);
    ``stats`` are the loop's (a fleet host's, shared by its robots; else this agent's own);
    ``notify`` is called whenever something arrives for this robot (default: ``wake.set``; a
    fleet host also notes the robot, ``needs_cycle``); ``ledger``: where its robot time is
    kept, row ``slot`` (a fleet host's, shared by its robots; default its own).
    """

    def __init__(
        self, platform: str, robot_id: str, session: zenoh.Session,
        options: AgentOptions | None = None, body: Body | None = None,
        wake: Wake | None = None, phase: int = 0, stats: LoopStats | None = None,
        notify: Callable[[], None] | None = None, board: FleetBoard | None = None,
        ledger: Ledger | None = None, slot: int = 0,
    ) -> None:
        self.options = options or AgentOptions()
        self.keys = Keys(self.options.prefix)
        self.keys.command(robot_id)  # validates the id as a key segment
        self.robot_id = robot_id
        self.session = session
        if body is None:
            body = make_body(self.options.body, platform, 1.0 / self.options.control_rate,
                             session=session, options=self.options, robot_id=robot_id)
        self.controller = Controller(body, self.options.margin, make_guard(body, platform),
                                     ledger, slot)
        self.platform = self.controller.platform.name
        self.resolver = Resolver(session, self.platform, self.keys, self.options.query_timeout_s)
        self.inbox = Inbox(wake, notify)
        if self.controller.guard is not None:
            self.controller.guard.notify = notify
        self.conduct = Conduct(robot_id, self.controller, self.resolver,
                               self.inbox.put_resolved, self.options.max_translation_m,
                               self.options.speed)
        self.stats = LoopStats() if stats is None else stats
        self.last_state: RobotState | None = None
        self._ratelog = RateLog(log)
        self._state_seq = 0
        self._joint_names = list(self.controller.joint_names)
        self._groups = list(self.options.groups)
        """Lists every state carries as they are (never changed: made once)."""
        self.publish_every = self.options.publish_every
        """Steps between two published states."""
        self.phase = phase
        """Offsets the steps that publish state: a fleet host publishes its robots' states in
        groups spread over the steps (``fleet.state_steps``)."""
        self._followed_only = False
        """The step in flight was taken by a fleet host's followers alone (:meth:`follow`)."""
        self._entities: list[Any] = []
        self._publisher: Any = None
        self._payload = bytearray()
        """The encoded state, rewritten in place for each one (Zenoh copies it on ``put``)."""
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.board = board
        """The process's fleet e-stops (``estops.py``); the agent's own when none is given."""
        self._own_board = board is None
        self._claim: Claim | None = None
        self._urgent: UrgentOut | None = None

    # --- lifetime ------------------------------------------------------------------------------

    def declare(self) -> None:
        """Claim the robot id (``id_taken`` when another agent runs it), latch every fleet
        e-stop in force, then subscribe to commands, declare the state and ack publishers and
        the liveliness token."""
        s = self.session
        self._claim = Claim(s, self.keys, self.robot_id, self.platform)
        self._claim.take()
        if self.board is None:
            self.board = FleetBoard(s, self.keys)
            self.board.declare()
            self.board.sync()
        self.board.follow(self.latch_fleet)
        for rec in self.board.in_force():  # before any command: the first step latches
            self.latch_fleet(rec)
        self.conduct.board = self.board
        keys = [self.keys.command(self.robot_id)]
        keys += [self.keys.group_command(g) for g in self.options.groups]
        self._entities = [s.declare_subscriber(Keys.subscribed(k), self._on_sample)
                          for k in keys]
        drop = zenoh.CongestionControl.DROP
        self._publisher = s.declare_publisher(self.keys.state(self.robot_id),
                                              congestion_control=drop)
        acks = s.declare_publisher(self.keys.ack(self.robot_id), congestion_control=drop)
        urgent = s.declare_publisher(self.keys.ack(self.robot_id),
                                     congestion_control=zenoh.CongestionControl.BLOCK,
                                     priority=zenoh.Priority.REAL_TIME, express=True)
        self._urgent = UrgentOut(urgent.put, self.robot_id)
        self.conduct.acks.publish, self.conduct.acks.publish_urgent = acks.put, self._urgent
        self._entities += [self._publisher, acks, urgent]
        self._entities.append(s.liveliness().declare_token(self.keys.alive_robot(self.robot_id)))
        self.resolver.start()
        if self._own_board:
            self.board.start()
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
        self.inbox.wake.set()  # a loop waiting for its next slot looks at once
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self.resolver.close()
        self.conduct.acks.flush()  # what the last step had to say
        if self._urgent is not None:
            self._urgent.close()
        undeclare(*reversed(self._entities))
        self._entities = []
        if self._own_board and self.board is not None:
            self.board.close()
        if self._claim is not None:
            self._claim.release()
        self._publisher = self.conduct.acks.publish = self.conduct.acks.publish_urgent = None
        if self.controller.guard is not None:
            self.controller.guard.close()
        self.controller.body.close()
        log.info("agent %s down after %d steps (%d slips)", self.robot_id, self.stats.steps,
                 self.stats.slips)

    # --- network callbacks (Zenoh threads) -----------------------------------------------------

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            key = str(sample.key_expr)
            self.receive(sample.payload, self.keys.sender_of(key), key)
        except KinesphereError as exc:  # a key below .../command that names no sender
            self._ratelog(exc.code, "agent %s: command refused: %s", self.robot_id, exc)
            self.inbox.put_bad(exc)
        except Exception as exc:  # never a traceback in Zenoh's callback thread
            self._ratelog("receive", "agent %s: command not queued: %r", self.robot_id, exc)

    def receive(self, payload: Payload, signer: str = "", key: str = "") -> None:
        """Queue an encoded Command for the next control step (any thread; never blocks);
        ``key`` is where it was put (a fleet e-stop or release is remembered).

        ``signer`` is the sender the command's key names (:meth:`Keys.sender_of`): with the
        deploy's access control only that operator's certificate may put there, so it is who
        sent it, and a payload naming anyone else is refused. A command without a signer
        (the plain key, a lab machine without access control) is who its payload says."""
        try:
            cmd = decode(payload, Command)
            if signer and cmd.sender != signer:
                if cmd.sender:
                    raise KinesphereError(
                        "malformed", f"command says sender {cmd.sender!r} on the key of "
                        f"{signer!r}: a sender speaks only for itself")
                cmd = msgspec.structs.replace(cmd, sender=signer)
        except KinesphereError as exc:
            self._ratelog(exc.code, "agent %s: command refused: %s", self.robot_id, exc)
            self.inbox.put_bad(exc)
            return
        self.inbox.put(received(cmd, self.stats.begun))
        if self.board is not None:
            self.board.heard(cmd, key)

    def latch_fleet(self, rec: FleetEstop) -> None:
        """A fleet e-stop in force that this robot did not hear: latch it in the next step,
        ahead of any command (any thread)."""
        self.inbox.put(received(latch_command(rec), self.stats.begun))

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
            self.conduct.set(Status.ERROR, f"internal: control step failed: {exc!r}")

        wake = None if self.options.strict_period else self.inbox.wake
        run_paced(step, period, stopped, self.stats, f"agent {self.robot_id}", failed, wake)

    def tick(self) -> None:
        """One control cycle: e-stops, commands, watchdog and lease, one step, state when due.

        Each part is guarded on its own: a failing step still lets the watchdog, the state
        and the next commands through, and leaves the body held where it is.
        """
        failure = self.begin_step()
        if failure is None:
            try:
                self.controller.body.step()
            except Exception as exc:
                failure = exc
        self.end_step(failure)
        self.stats.steps += 1
        if self.due():
            self.publish()

    def begin_step(self) -> Exception | None:
        """The cycle up to the body's step: e-stops, commands, timers, the trajectories
        commanded to the body. Returns what failed there (the body must not step then)."""
        self.stats.begin(clocks()[0])
        failure = self.react()
        return failure if failure is not None else self.actuate()

    def needs_cycle(self) -> bool:
        """Whether the next step needs the whole cycle (:meth:`react`, :meth:`actuate`,
        :meth:`end_step`): something arrived, the guard has a verdict or a leg, a motion's
        ``moving`` is to say. A fleet host asks after each step and does less for a robot
        that needs none of it, until something arrives for it (``notify``) or a timer runs
        out (``Conduct.deadline``): :meth:`follow` and :meth:`followed` while it moves or a
        motion's end is to say, else nothing but robot time (``Controller.elapse``)."""
        return (self.inbox.waiting or not self.controller.unattended
                or not self.conduct.quiet())

    @property
    def at_rest(self) -> bool:
        """Nothing moves and nothing is to say about a motion: until something arrives, a
        step is robot time and physics alone."""
        return not self.controller.moving and self.conduct.settled

    @property
    def ledgered(self) -> bool:
        """Whether the end of a glide (:meth:`glided`) is only robot time and a note that the
        robot moved, unless something touches: no way still being checked, no timed motion
        to track. A fleet host then ends the glides of all such robots at once
        (``Ledger.glided``)."""
        guard = self.controller.guard
        return (guard is None or not guard.unchecked) and self.conduct.untimed

    def follow(self) -> Exception | None:
        """A step with nothing to react to (:meth:`needs_cycle`), up to the body's step: the
        trajectories forward (a fleet host's followers took their steps already, unless one
        is planned here: ``follow.py``), their setpoints to the body. Returns what failed
        (the body must not step then)."""
        ctrl = self.controller
        self._followed_only = ctrl.followed
        try:
            ctrl.command()
        except Exception as exc:
            return exc
        return None

    def followed(self) -> bool:
        """The end of a :meth:`follow` step whose body stepped: contacts, robot time, and all
        :meth:`end_step` says when a trajectory was stepped here, ended or was halted.
        True when the robot still moves and nothing changed (the next step is such a step
        again); else ask :meth:`needs_cycle` and :attr:`at_rest`."""
        ctrl = self.controller
        ctrl.finish()  # the guard watches for contacts
        if self._followed_only and ctrl.moving and ctrl.followed:
            self.conduct.followed()  # nothing else can have changed
            return True
        return self._went_on()

    def glided(self) -> bool:
        """:meth:`followed` for a step in which a fleet host handed the followers' setpoint to
        the body itself (``Controller.glides``; a moving base's step too): while the motion is
        still the followers' alone (the guard halted nothing) the step went as planned."""
        ctrl = self.controller
        ctrl.finish()  # the guard watches for contacts
        if ctrl.glides:
            self.conduct.followed()
            return True
        return self._went_on()

    def _went_on(self) -> bool:
        """The end of a lean step that did more than follow (or was halted): what
        :meth:`end_step` says; whether the next step may be lean again."""
        conduct = self.conduct
        changed = conduct.after_step()
        conduct.acks.flush()
        return not changed and self.controller.moving  # a base stepped here, a joint plan

    def react(self) -> Exception | None:
        """The first part of :meth:`begin_step` once the step is counted (``stats.begun``):
        e-stops, commands, timers, the guard's verdicts (a fleet host then follows every
        robot's trajectories at once, then :meth:`actuate`s each)."""
        conduct = self.conduct
        conduct.ticks = self.stats.begun
        now_ns = clocks()[0]
        stall = self.stats.stall  # the loop's: frozen, or a step hung
        if stall is not None:
            conduct.ordering.stalled(*stall)
        drained = self.inbox.drain()
        for item in drained.estops:
            conduct.handle(item, now_ns)
        for item in drained.superseded:
            conduct.acks.send(item.cmd, AckStage.SUPERSEDED, "a newer command arrived before "
                              "this one was acted on")
        for any_item in drained.items:
            conduct.handle(any_item, now_ns)
        conduct.watch(now_ns / 1e9)
        try:
            self.controller.guide()
        except Exception as exc:
            conduct.acks.flush()
            return exc
        return None

    def actuate(self) -> Exception | None:
        """The rest of :meth:`begin_step`: the trajectories forward, their setpoints to the
        body, what that says (``moving``)."""
        conduct = self.conduct
        try:
            self.controller.command()
        except Exception as exc:
            conduct.acks.flush()
            return exc
        conduct.commanded()
        conduct.acks.flush()
        return None

    def end_step(self, failure: Exception | None) -> None:
        """The cycle after the body's step (``failure``: what :meth:`begin_step` or the body
        raised): faults, acks. The state follows when :meth:`due`."""
        conduct = self.conduct
        if failure is None:
            self.controller.finish()
            conduct.step_worked()
        else:
            conduct.step_failed(failure)
        conduct.after_step()
        conduct.acks.flush()

    def due(self) -> bool:
        """Whether this step publishes the state (every ``1/state_rate`` s, shifted by
        ``phase``)."""
        return (self.stats.begun + self.phase) % self.publish_every == 0

    # --- state -----------------------------------------------------------------------------------

    @property
    def latencies(self) -> deque[tuple[int, int, int]]:
        """(seq, sent_ns, first moving step ns) per pose command applied."""
        return self.conduct.latencies

    def status(self) -> tuple[str, str]:
        """The status and detail to publish now."""
        status: tuple[str, str] = self.conduct.status()
        return status

    def publish(self) -> RobotState:
        """Say the robot's state now: :meth:`compose_state`, then :meth:`put_state`."""
        state = self.compose_state()
        self.put_state()
        return state

    def compose_state(self) -> RobotState:
        """The robot's state now, kept as ``last_state`` and encoded for :meth:`put_state`
        (a fleet host composes the states due in a step first, then puts them one after the
        other: Zenoh sends them in one batch)."""
        ctrl, conduct = self.controller, self.conduct
        status, detail = conduct.status()
        self._state_seq += 1
        now = ctrl.reading()  # read once for all three (as ``q``, ``qd``, ``base_pose``)
        clamped = ctrl.joints.clamped
        state = RobotState(
            robot_id=self.robot_id, platform=self.platform, seq=self._state_seq,
            stamp_ns=time.time_ns(), joint_names=self._joint_names, q=now.q.tolist(),
            qd=now.qd.tolist(), base_pose=list(now.base_pose), status=status,
            last_command_seq=conduct.ordering.last_seq, detail=detail[:MAX_TEXT],
            clamped=sorted(clamped) if clamped else [], groups=self._groups,
            lease_holder=conduct.lease.holder, estop_by=conduct.safety.estop_by,
            substitutions=conduct.acks.substitutions, dropped=conduct.ordering.dropped,
        )
        self.last_state = state
        if self._publisher is not None:
            encode_into(state, self._payload)
        return state

    def put_state(self) -> None:
        """Put the state :meth:`compose_state` encoded last."""
        if self._publisher is not None:
            try:
                self._publisher.put(self._payload)
            except zenoh.ZError as exc:  # session closing or congested: the loop goes on
                log.debug("state not published: %s", exc)

    def cost_percentiles(self) -> tuple[float, float]:
        """Median and p99 step cost in seconds over the recent steps."""
        costs = np.fromiter(self.stats.costs_s, dtype=float)
        if costs.size == 0:
            return 0.0, 0.0
        return float(np.median(costs)), float(np.percentile(costs, 99))
