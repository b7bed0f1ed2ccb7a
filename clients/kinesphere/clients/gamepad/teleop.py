"""The streaming loop: controller snapshots in, Commands out at a fixed rate.

While the operator is engaged (deadman held, or with ``--no-deadman`` anything deflected) every
tick puts one Command on the target's keys with a fresh ``seq`` and ``ttl_ms``, even when it
repeats the last one: the stream is the robot's proof that the operator is still there, and a
robot that stops hearing it holds within ``ttl_ms``. When the operator lets go, the device
disconnects, the target changes or the client exits, one final stop goes out.

E-stop goes to every robot (``{p}/robot/*/command``) and latches here too; it stays in force
for robots that start or rejoin until released. Robots clear a latch only on a release from
the sender who latched it; the release button sends one to every robot (clearing this
operator's latches and fleet e-stop, nobody else's) and names the robots it frees and those
still latched by others, with the command that releases each. The loop also stops
streaming while any targeted robot reports ``estop`` (pointless commands would only be
refused), and after an e-stop, a release or a disconnect it streams again only after the
deadman was let go and pressed anew.

A direction the selected limb has no poses for (per the targets' catalogues) is replaced by
the one :mod:`kinesphere.substitution` chooses (nearest by angle, a front request never served
from behind), and the HUD shows both, so the robot never just refuses a stick.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Protocol

from kinesphere import hints
from kinesphere.clients import targets as tg
from kinesphere.clients.gamepad.drive import Steering, base_kind, steering_for
from kinesphere.clients.gamepad.lease import LeaseKeeper
from kinesphere.clients.gamepad.limbs import (
    CatalogueCache,
    Selection,
    aliases_of,
    available_directions,
    direction_sets,
    pairs_of,
    servable,
    served,
    tips_of,
)
from kinesphere.clients.gamepad.mapfile import MapFile
from kinesphere.clients.gamepad.mapping import (
    NEUTRAL_INTENT,
    MapperState,
    map_controls,
)
from kinesphere.clients.gamepad.readout import Readout
from kinesphere.clients.gamepad.state import Action, ControllerState
from kinesphere.clients.link import RobotLink, Seen
from kinesphere.clients.options import TeleopOptions
from kinesphere.clients.report import current_answer, still_latched
from kinesphere.errors import did_you_mean
from kinesphere.laban import Direction
from kinesphere.protocol import SpatialCommand, Status

log = logging.getLogger(__name__)

RELEASE_GRACE_S = 0.5
"""After a release, ``estop`` states this young may predate it and are not a new e-stop."""
TARGET_GRACE_S = 1.0
"""How long a new target may go unheard before the HUD says nobody receives the commands
(robots' states come at 50 Hz: a live robot is heard within milliseconds)."""


class Source(Protocol):
    """Anything that yields controller snapshots: pygame input or a replayed recording."""

    def poll(self) -> ControllerState: ...


class Teleop:
    """One operator's session state; :meth:`tick` once per period, :meth:`shutdown` at exit."""

    def __init__(
        self,
        link: RobotLink,
        mapfile: MapFile,
        target: tg.Target,
        options: TeleopOptions | None = None,
        take: bool = False,
    ) -> None:
        self.link = link
        self.map = mapfile
        self.target = target
        self.options = options or TeleopOptions()
        self.seq = link.sequencer(self.options.ttl_ms)
        self.lease = LeaseKeeper(link, self.seq, take)
        self.selection = Selection()
        self.catalogues = CatalogueCache(link)
        self.mstate = MapperState()
        self.intent = NEUTRAL_INTENT
        self.steering = Steering.HOLONOMIC
        self.streaming = False
        self.estopped = False
        self.need_fresh = False
        self.released_at = float("-inf")
        self.quit = False
        self.message = ""
        self._last: float | None = None
        self._aliases: dict[str, str] = {}
        self._available: frozenset[Direction] | None = None
        self._asked: Direction | None = None
        self._limb_holds = False
        self._deflected = False
        """The stick (or a trigger) left its centre since the deadman was pressed: until it
        does, the limb holds its pose (nothing is sent for it)."""
        self._target_since: float | None = None
        self.input_name = ""
        """Which device the hands come from (the source's own description)."""

    # --- decisions ----------------------------------------------------------------------

    def _targeted(self) -> dict[str, Seen]:
        """The robots heard from that the current target reaches (by id or their groups)."""
        return {rid: seen for rid, seen in self.link.states().items()
                if self.target.includes(rid, seen.state.groups)}

    def _platforms(self) -> list[str]:
        return [seen.state.platform for _, seen in sorted(self._targeted().items())]

    def _remote_estop(self) -> list[str]:
        """Targeted robots that report a latched e-stop (not one we just released)."""
        return sorted(
            rid
            for rid, seen in self._targeted().items()
            if seen.state.status == Status.ESTOP and seen.at > self.released_at + RELEASE_GRACE_S
        )

    def latched_by_me(self) -> list[str]:
        """Robots in e-stop that this operator latched, by their own account."""
        me = self.seq.sender
        return sorted(
            rid
            for rid, seen in self.link.states().items()
            if seen.state.status == Status.ESTOP
            and (seen.state.estop_by == me or (not seen.state.estop_by and self.estopped))
        )

    def _release(self) -> None:
        """Release this operator's e-stops on every robot, and say which robots that frees.

        The release goes to every robot's key: a robot clears only this sender's latch (each
        sender's e-stop is its own), and the fleet e-stop this operator's button put in force
        ends with it, so robots that start later come up free."""
        mine = self.latched_by_me()
        others = {rid: seen.state.estop_by for rid, seen in sorted(self.link.states().items())
                  if seen.state.status == Status.ESTOP and rid not in mine}
        cmd = self.seq.release()
        self.link.put([self.link.keys.command("*")], cmd)
        self.estopped, self.need_fresh = False, True
        self.released_at = time.monotonic()
        said = (f"released the e-stop of {', '.join(mine)}" if mine
                else "no robot reports an e-stop latched by you")
        if others:
            said += "; still latched by others: " + ", ".join(
                still_latched(rid, by) for rid, by in others.items())
        self.message = said

    def _stop_stream(self) -> None:
        """The operator let go: one deadman release (obeyed only where we hold the lease)."""
        if self.streaming:
            self.link.put(self.target.keys(self.link.keys), self.seq.let_go())
            self.streaming = False

    def _leave_target(self) -> None:
        self._stop_stream()
        self.lease.release(self.target, self._targeted())

    def _presses(self, cs: ControllerState) -> None:
        if cs.was_pressed(Action.ESTOP):
            self.link.estop_all(self.seq)
            self.streaming = False
            self.estopped = self.need_fresh = True
            self.message = "E-STOP sent to all robots"
        if cs.was_pressed(Action.RELEASE) and not cs.was_pressed(Action.ESTOP):
            self._release()
        if cs.was_pressed(Action.TAKE):
            self.lease.take_over(self.target)
            self.message = f"taking control of {self.target.label}"
        if cs.was_pressed(Action.TARGET_NEXT):
            self._leave_target()
            robots = self.link.robot_groups()
            self.target = tg.cycle(self.target, robots)
            self._target_since = None
            reached = tg.members(self.target, robots)
            self.message = f"target: {self.target.label} ({', '.join(reached) or 'nobody yet'})"
        sel = self.selection
        moves: tuple[tuple[str, Callable[[int], None], int], ...] = (
            (Action.LIMB_NEXT, sel.next_limb, 1),
            (Action.LIMB_PREV, sel.next_limb, -1),
            (Action.ORIGIN_NEXT, sel.next_origin, 1),
            (Action.ORIGIN_PREV, sel.next_origin, -1),
        )
        for action, move, step in moves:
            if cs.was_pressed(action):
                move(step)
                self.message = f"limb {sel.limb} from {sel.origin}"
        if cs.was_pressed(Action.QUIT):
            self.quit = True

    def tick(self, cs: ControllerState, now: float | None = None) -> Readout:
        """Map ``cs``, handle its presses, and put this period's Command (or the final stop)."""
        now = time.monotonic() if now is None else now
        dt = 0.0 if self._last is None else now - self._last
        self._last = now
        self._presses(cs)
        cats = self.catalogues.get(self._platforms())
        self.steering = steering_for(base_kind(c) for c in cats)
        self.intent, self.mstate = map_controls(
            cs, self.mstate, dt, self.map.tuning, self.steering
        )
        self.selection.update(pairs_of(cats))
        self._aliases = aliases_of(cats)
        sets = direction_sets(cats, self.selection.limb, self.selection.origin)
        tips = tips_of(cats, self.selection.limb, self.selection.origin)
        self._available = available_directions(sets)
        asked = self.intent.direction
        snapped = served(asked, self._available, tips)
        self._asked = asked if snapped is not asked else None
        self._limb_holds = not servable(asked, sets, tips)
        if snapped is not asked:
            self.intent = replace(self.intent, direction=snapped)
        remote = self._remote_estop()
        required = self.options.deadman_required
        wants = self.intent.deadman if required else self.intent.moving
        if not cs.connected:
            self.need_fresh = True
            if self.streaming:
                self.message = "controller disconnected: stopped"
        elif not wants:
            self.need_fresh = False
        engaged = (
            cs.connected and wants and not self.need_fresh and not self.estopped and not remote
        )
        self._deflected = engaged and (self._deflected or self.intent.size > 0.0)
        if engaged:
            part = SpatialCommand(
                limb=self.selection.limb,
                origin=self.selection.origin,
                direction=self.intent.direction.slug,
                size=self.intent.size,
            )
            lease = self.lease.action_for_command(self.target)
            parts = [part] if self._deflected and not self._limb_holds else []
            cmd = self.seq.command(parts, self.intent.drive, deadman=True, lease=lease)
            self.link.put(self.target.keys(self.link.keys), cmd)
            self.streaming = True
        else:
            self._stop_stream()
            self.lease.idle(self.target, self._targeted(), now)
        if self._target_since is None:
            self._target_since = now
        return self.view(cs, engaged, remote, now)

    def view(self, cs: ControllerState, engaged: bool, remote: list[str],
             now: float | None = None) -> Readout:
        now = time.monotonic() if now is None else now
        targeted = self._targeted()
        unheard = self._unheard(targeted, now)
        presses: dict[str, str] = {a: self.map.press(a, cs.source) for a in (
            Action.RELEASE, Action.TAKE, Action.DEADMAN, Action.ESTOP)}
        answers = {}
        for rid, got in self.link.answers().items():
            ack = current_answer([a.ack for a in got])
            answers[rid] = next(a for a in reversed(got) if a.ack is ack)
        return Readout(
            target=self.target,
            limb=self.selection.limb,
            origin=self.selection.origin,
            aliases=self._aliases,
            intent=self.intent,
            engaged=engaged,
            deadman_required=self.options.deadman_required,
            estopped=self.estopped,
            remote_estop=remote,
            need_fresh_deadman=self.need_fresh and not engaged,
            connected=cs.connected,
            source=cs.source,
            robots=self.link.states(),
            seq=self.seq.seq,
            message=self.message,
            catalogue_errors=self.catalogues.errors(),
            available=self._available,
            asked=self._asked,
            limb_holds=self._limb_holds,
            members=sorted(targeted),
            sender=self.seq.sender,
            answers=answers,
            notice=unheard or self._notice(targeted, presses[Action.TAKE]),
            unheard=bool(unheard),
            stick_holds=engaged and not self._deflected,
            presses=presses,
            input_name=self.input_name or cs.source,
        )

    def _unheard(self, targeted: dict[str, Seen], now: float) -> str:
        """That nobody the target names is heard, once it had time to be: the commands reach
        nobody. Says who is alive instead."""
        since = self._target_since
        if targeted or since is None or now - since < TARGET_GRACE_S:
            return ""
        alive = self.link.robots()
        if self.target.kind == "robot":
            what = f"no robot {self.target.name!r} is heard"
            near = did_you_mean(self.target.name, alive)
        elif self.target.kind == "group":
            what, near = f"no robot of group {self.target.name!r} is heard", ""
        else:
            what, near = "no robot is heard", ""
        live = f"live: {', '.join(alive)}" if alive else "no robot is alive"
        return f"{what}: your commands reach nobody ({live}){near}"

    def _notice(self, targeted: dict[str, Seen], take: str) -> str:
        """What the operator must know now: robots that refuse us for another's lease."""
        refused = self.lease.refused(targeted)
        if not refused:
            return ""
        rid, why = next(iter(sorted(refused.items())))
        more = f" (and {len(refused) - 1} more)" if len(refused) > 1 else ""
        how = (f"press {take} to take control" if take
               else f"take control with '{hints.take_lease(rid)}'")
        return f"{rid} refuses your commands{more}: {why}; {how}"

    def shutdown(self) -> None:
        """On exit (Ctrl-C, SIGTERM too): let go if still streaming, then give the lease back."""
        self._leave_target()


def run(
    teleop: Teleop,
    source: Source,
    *,
    draw: Callable[[Readout], None] | None = None,
    record: Callable[[float, ControllerState], None] | None = None,
    finished: Callable[[], bool] | None = None,
) -> None:
    """Tick at ``rate_hz`` on absolute deadlines (no drift) until quit or ``finished()``.

    A source with a ``describe()`` says which device the hands come from (the HUD shows it).

    Falls behind gracefully: a late tick is not followed by a burst of catch-up ticks.
    The final stop is sent however the loop ends.
    """
    period = 1.0 / teleop.options.rate_hz
    start = next_t = time.monotonic()
    describe: Callable[[], str] | None = getattr(source, "describe", None)
    try:
        while not teleop.quit and not (finished is not None and finished()):
            now = time.monotonic()
            cs = source.poll()
            if describe is not None:
                teleop.input_name = describe()
            if record is not None:
                record(now - start, cs)
            view = teleop.tick(cs, now)
            if draw is not None:
                draw(view)
            next_t += period
            delay = next_t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -period:
                next_t = time.monotonic()
    finally:
        teleop.shutdown()
