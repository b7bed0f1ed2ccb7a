"""The gamepad client against real robots: the databank and two agents (a PackBot and a youBot)
run as processes on loopback, the client in this process reads posted pygame events.

The sweep gesture makes the base translate while the arm sweeps sideways, at the same time;
letting go of the deadman stops within the TTL; a direction no body has a pose near drives the
base alone (through SDL's joystick path); a killed client's robots stop by themselves;
group targets reach only their members; the e-stop halts everyone.
"""

from __future__ import annotations

import math
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import pygame
import pytest

from kinesphere import zconfig
from kinesphere.clients import targets as tg
from kinesphere.clients.gamepad.inputs import ticks
from kinesphere.clients.gamepad.readout import Readout
from kinesphere.clients.gamepad.state import Action, ControllerState
from kinesphere.clients.gamepad.teleop import run
from kinesphere.laban import Direction
from support.client_fleet import (
    PB,
    PLATFORMS,
    TTL_MS,
    YB,
    ClientFleet,
    Heard,
    at_rest,
    operator,
    speeds,
)
from support.clients import Pad, Script, VirtualPad
from support.paths import ROOT

pytestmark = [pytest.mark.processes, pytest.mark.realtime]

LEFT, RIGHT = 90, 100
"""Ticks at 30 Hz of the sweep's strokes. The first one unfolds the arm from its stowed neutral
(the joints move synchronised, so the turret turns slowly, ~0.2 rad/s); the second swings the
unfolded arm across, from beside the robot on its left to its right (3.2 rad), at up to the
turret's 1 rad/s."""


def assert_sweep(fleet: ClientFleet, t0: float, released: float) -> None:
    """The PackBot sweep as the operator means it: the turret swings across the front of the
    robot, out to its left then its right (perpendicular to the path, as the paper's sweep),
    while the base advances; after the deadman is let go the robot holds within the TTL and
    comes to rest."""
    halted = fleet.track.wait(PB, lambda h: h.state.status in ("stopped", "holding"),
                              "the stop", after=released)
    assert halted.at - released < TTL_MS / 1000
    rest = at_rest(PB, fleet.track, halted.at)
    hs = [h for h in fleet.track.since(PB, t0) if h.at <= rest.at]
    turret = [h.state.q[h.state.joint_names.index("turret")] for h in hs]
    tqd = [h.state.qd[h.state.joint_names.index("turret")] for h in hs]
    v = dict(speeds(hs))
    both = [h.state.stamp_ns / 1e9 for h, w in zip(hs, tqd, strict=True)
            if abs(w) > 0.05 and v.get(h.state.stamp_ns / 1e9, 0.0) > 0.05]
    assert both and max(both) - min(both) > 1.0, "base and arm move at the same time"
    peak = max(range(len(turret)), key=lambda i: turret[i])
    assert turret[peak] > 0.5, "the arm swept left of forward (turret positive)"
    assert min(turret[peak:]) < -0.6, "then right of forward"
    assert max(map(abs, turret)) < math.pi / 2 + 0.1, "in front or beside, never behind"
    (x0, y0, yaw0), (x1, y1, _) = hs[0].state.base_pose, rest.state.base_pose
    advance = (x1 - x0) * math.cos(yaw0) + (y1 - y0) * math.sin(yaw0)
    assert advance > 0.5, "the base drove forward"
    after = [h for h in fleet.track.since(PB, rest.at)]
    assert after and all(h.state.status in ("stopped", "holding") for h in after[:10])


def test_sweep_gesture_translates_the_base_while_the_arm_sweeps(
    fleet: ClientFleet, pygame_up: None
) -> None:
    """Posted events (what a pad would send): deadman + LT + right stick left, then right,
    left stick forward."""
    p = Pad()
    released: list[float] = []

    def sweep_left() -> None:
        p.plug()
        p.deadman()
        p.axis(pygame.CONTROLLER_AXIS_TRIGGERLEFT, 1.0)  # low
        p.right(-1.0, 0.0)  # arm: left-low, far
        p.left(0.0, -0.6)  # base: forward

    def let_go() -> None:
        released.append(time.monotonic())
        p.deadman(False)

    with operator(fleet, tg.robot(PB)) as (op, inp):
        assert (op.selection.limb, op.selection.origin) == ("limb_11", "distal_11")
        t0 = time.monotonic()
        script = Script(inp, {0: sweep_left, LEFT: lambda: p.right(1.0, 0.0),  # right-low
                              LEFT + RIGHT: let_go, LEFT + RIGHT + 1: lambda: None})
        run(op, script, finished=lambda: script.finished)
    assert_sweep(fleet, t0, released[0])


@dataclass(frozen=True)
class SdlRun:
    views: list[Readout]
    t0: float  # the device opened, before the first press
    released: float  # the deadman let go


def through_sdl(fleet: ClientFleet, robot: str, steps: dict[int, Callable[[VirtualPad], object]],
                release_at: int) -> SdlRun:
    """Play ``steps`` (tick -> what to do on the pad) on an SDL virtual GameController
    driving a gamepad client aimed at ``robot``, let go of the deadman at ``release_at``."""
    released: list[float] = []
    with operator(fleet, tg.robot(robot)) as (op, inp):
        vpad = VirtualPad()
        try:
            op.tick(inp.poll())  # SDL reports the device; the client opens it, nothing held

            def let_go() -> None:
                released.append(time.monotonic())
                vpad.deadman(False)

            t0 = time.monotonic()
            script = Script(inp, {**{k: partial(step, vpad) for k, step in steps.items()},
                                  release_at: let_go, release_at + 1: lambda: None})
            views: list[Readout] = []
            run(op, script, draw=views.append, finished=lambda: script.finished)
        finally:
            vpad.unplug()
    return SdlRun(views, t0, released[0])


def test_sweep_gesture_through_sdls_real_joystick_path(fleet: ClientFleet, pygame_up: None) -> None:
    """The same gesture from an SDL virtual GameController: SDL's device, mapping and event
    path, as a USB pad would drive it."""

    def sweep_left(vpad: VirtualPad) -> None:
        vpad.deadman()
        vpad.axis(pygame.CONTROLLER_AXIS_TRIGGERLEFT, 1.0)
        vpad.right(-1.0, 0.0)
        vpad.left(0.0, -0.6)

    done = through_sdl(fleet, PB, {0: sweep_left, LEFT: lambda vpad: vpad.right(1.0, 0.0)},
                       release_at=LEFT + RIGHT)
    engaged = [v for v in done.views if v.engaged]
    assert engaged and {v.source for v in engaged} == {"controller"}, "the SDL device drove it"
    sent = [(v.asked or v.intent.direction, v.intent.direction) for v in engaged]
    assert (Direction.LEFT_LOW, Direction.LEFT_LOW) in sent  # as asked: no substitute
    assert (Direction.RIGHT_LOW, Direction.RIGHT_LOW) in sent
    assert all(d in (Direction.LEFT_LOW, Direction.RIGHT_LOW) for _, d in sent)
    assert_sweep(fleet, done.t0, done.released)


def test_a_direction_no_body_has_near_drives_alone_through_sdls_joystick_path(
    fleet: ClientFleet, pygame_up: None
) -> None:
    """PackBot's arm (shipped databank) has no pose within 45 degrees of back-low (its
    shoulder cannot point below the deck behind it). From an SDL virtual GameController, right
    stick back with the low trigger while driving forward: the client sends the drive alone,
    the robot refuses nothing and drives, the arm holds."""

    def push(vpad: VirtualPad) -> None:
        vpad.deadman()
        vpad.axis(pygame.CONTROLLER_AXIS_TRIGGERLEFT, 1.0)
        vpad.right(0.0, 1.0)
        vpad.left(0.0, -0.6)

    done = through_sdl(fleet, PB, {0: push}, release_at=45)
    views = done.views
    pushed = [v for v in views if v.engaged and v.asked is None
              and v.intent.direction is Direction.BACK_LOW]
    assert len(pushed) > 30 and {v.source for v in pushed} == {"controller"}
    assert all(v.limb_holds for v in pushed), "no body serves back-low: the limb holds"
    refused = [v.answers[PB].ack for v in views if PB in v.answers
               and v.answers[PB].ack.stage == "rejected"]
    assert refused == [], "the drive alone is a command the robot obeys"
    halted = fleet.track.wait(PB, lambda h: h.state.status in ("stopped", "holding"),
                              "the stop", after=done.released)
    hs = [h for h in fleet.track.since(PB, done.t0) if h.at <= halted.at]
    forward, _, _ = body_motion(hs, halted)
    assert forward > 0.2, "it drove forward"
    names = hs[0].state.joint_names
    arm = [names.index(j) for j in ("turret", "shoulder", "elbow1", "elbow2", "tilt", "pan",
                                    "wrist")]
    assert max(abs(h.state.q[j] - hs[0].state.q[j]) for h in hs for j in arm) < 0.01


def test_a_centred_stick_holds_the_pose_through_sdls_joystick_path(
    fleet: ClientFleet, pygame_up: None
) -> None:
    """The youBot's arm pushed away from neutral, the deadman let go, then pressed again with
    the stick centred (SDL virtual GameController): the arm holds where it is; nothing sends
    it home."""

    def push(vpad: VirtualPad) -> None:
        vpad.deadman()
        vpad.right(-0.7, -0.7)  # left-forward

    def let_go(vpad: VirtualPad) -> None:
        vpad.deadman(False)
        vpad.right(0.0, 0.0)

    done = through_sdl(fleet, YB, {0: push, 45: let_go, 60: lambda vpad: vpad.deadman()},
                       release_at=105)
    held = [v for v in done.views[61:] if v.engaged]
    assert len(held) > 30 and all(v.stick_holds for v in held), "engaged, the stick centred"
    assert {v.source for v in held} == {"controller"}
    pressed = fleet.track.wait(YB, lambda h: True, "a state", after=done.t0 + 62 / 30)
    hs = [h for h in fleet.track.since(YB, pressed.at) if h.at <= done.released]
    names = hs[0].state.joint_names
    arm = [i for i, n in enumerate(names) if n.startswith("arm_joint")]
    start, before = hs[0].state.q, fleet.track.since(YB, done.t0)[0].state.q
    assert max(abs(start[i] - before[i]) for i in arm) > 0.05, "the push moved the arm"
    drift = max(abs(h.state.q[i] - start[i]) for h in hs for i in arm)
    assert drift < 0.02, f"the arm held its pose (moved {drift:.3f} rad)"


def test_deadman_release_stops_within_the_ttl(fleet: ClientFleet, pygame_up: None) -> None:
    p = Pad()
    released: list[float] = []

    def release() -> None:
        released.append(time.monotonic())
        p.deadman(False)

    with operator(fleet, tg.robot(PB)) as (op, inp):
        script = Script(inp, {0: lambda: p.deadman().left(0.0, 1.0),  # drive back
                              25: release, 26: lambda: None})
        run(op, script, finished=lambda: script.finished)
    moving = [h for h in fleet.track.since(PB, released[0] - 0.3) if h.at < released[0]]
    assert moving and moving[-1].state.status == "moving"
    halted = fleet.track.wait(PB, lambda h: h.state.status in ("stopped", "holding"),
                              "the stop", after=released[0])
    assert halted.at - released[0] < TTL_MS / 1000
    rest = at_rest(PB, fleet.track, halted.at)
    (x0, y0, _), (x1, y1, _) = halted.state.base_pose, rest.state.base_pose
    assert ((x1 - x0) ** 2 + (y1 - y0) ** 2) ** 0.5 < 1.0, "a brake, not a run-on"
    assert (rest.state.stamp_ns - halted.state.stamp_ns) / 1e9 < 3.0


def gesture(fleet: ClientFleet, robot: str, press: Callable[[Pad], object], ticks: int
            ) -> tuple[list[Heard], Heard]:
    """Hold the deadman and ``press`` for ``ticks`` at 30 Hz, let go; the robot's states from
    the first tick to rest, and the state at rest. The stop is the first after the robot was
    heard moving: a robot still holding from the gesture before says so in the states that
    reach us before it acts on the first tick (it then measured nothing)."""
    p = Pad()
    with operator(fleet, tg.robot(robot)) as (op, inp):
        t0 = time.monotonic()

        def start() -> None:
            p.deadman()
            press(p)

        def let_go() -> None:
            p.deadman(False)
            p.left(0.0, 0.0)
            p.right(0.0, 0.0)
            p.button(pygame.CONTROLLER_BUTTON_DPAD_LEFT, False)

        script = Script(inp, {0: start, ticks: let_go, ticks + 1: lambda: None})
        run(op, script, finished=lambda: script.finished)
    moved = fleet.track.wait(robot, lambda h: h.state.status == "moving", "the gesture", after=t0)
    halted = fleet.track.wait(robot, lambda h: h.state.status in ("stopped", "holding"),
                              "the stop", after=moved.at)
    rest = at_rest(robot, fleet.track, halted.at)
    return [h for h in fleet.track.since(robot, t0) if h.at <= rest.at], rest


def body_motion(hs: list[Heard], rest: Heard) -> tuple[float, float, float]:
    """(forward m, left m, turned rad) from the first state to rest, in the first body frame."""
    (x0, y0, yaw0), (x1, y1, yaw1) = hs[0].state.base_pose, rest.state.base_pose
    c, s = math.cos(yaw0), math.sin(yaw0)
    dx, dy = x1 - x0, y1 - y0
    return c * dx + s * dy, -s * dx + c * dy, math.atan2(math.sin(yaw1 - yaw0),
                                                         math.cos(yaw1 - yaw0))


def test_the_gamepad_turns_a_youbot_in_place_and_drives_it_diagonally_while_its_arm_moves(
    fleet: ClientFleet, pygame_up: None
) -> None:
    hs, rest = gesture(fleet, YB, lambda p: p.button(pygame.CONTROLLER_BUTTON_DPAD_LEFT), 45)
    forward, left, turned = body_motion(hs, rest)
    assert turned > 0.3, "d-pad left turns it counter-clockwise"
    assert math.hypot(forward, left) < 0.05, "in place"

    s = math.sqrt(0.5)
    hs, rest = gesture(fleet, YB, lambda p: p.left(-s, -s).right(0.0, -1.0), 45)
    forward, left, turned = body_motion(hs, rest)
    assert forward > 0.2 and left > 0.2 and abs(forward - left) < 0.3 * forward, "diagonally"
    assert abs(turned) < 0.05
    arm = [h for h in hs if max(map(abs, h.state.qd)) > 0.05]
    drove = dict(speeds(hs))
    assert any(drove.get(h.state.stamp_ns / 1e9, 0.0) > 0.05 for h in arm), "at the same time"


def test_the_gamepad_arcs_a_packbot(fleet: ClientFleet, pygame_up: None) -> None:
    """Forward on the stick and a turn on the d-pad (or, once the catalogue says 'skid', the
    stick alone): forward and yaw together, an arc to the left."""
    hs, rest = gesture(fleet, PB,
                       lambda p: p.left(0.0, -1.0).button(pygame.CONTROLLER_BUTTON_DPAD_LEFT), 45)
    forward, left, turned = body_motion(hs, rest)
    assert forward > 0.3 and turned > 0.3 and left > 0.05, "an arc to the left"


def test_a_killed_client_leaves_its_robots_stopping_on_their_own(
    fleet: ClientFleet, tmp_path: Path
) -> None:
    rec = tmp_path / "drive.mcap"
    # driving only: the right stick alone (Left-Middle) is a pull PackBot's arm lacks, with no
    # stored pull within the substitution limit, so the robot would refuse the whole command
    drive = ControllerState(ly=-0.8, held=frozenset({Action.DEADMAN}))
    ticks.save(rec, [(k / 10, drive) for k in range(600)])  # a minute of driving
    client = subprocess.Popen(
        [sys.executable, "-m", "kinesphere.cli", "gamepad", "--replay", str(rec), "--headless",
         "--target", PB, "--ttl-ms", str(TTL_MS), "--connect", fleet.endpoint,
         "--listen", zconfig.LOOPBACK_ANY_PORT],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    try:
        start = time.monotonic()
        driving = fleet.track.wait(PB, lambda h: h.state.status == "moving"
                                   and h.state.last_command_seq >= 10, "the client driving",
                                   after=start)
        killed_ns = time.time_ns()  # this host's clock, which the robot stamps its states with
        client.kill()
        killed = time.monotonic()
        client.wait()
        assert fleet.track.since(PB, driving.at)[-1].state.status == "moving"
        halted = fleet.track.wait(PB, lambda h: h.state.status == "holding",
                                  "the watchdog", after=killed)
    finally:
        if client.poll() is None:
            client.kill()
            client.wait()
    assert "ttl" in halted.state.detail
    # when the robot held, by its own stamp: a state that reached a loaded test late does not
    # count its delivery (its last command came before the kill, so this is at most its watchdog)
    held_after = (halted.state.stamp_ns - killed_ns) / 1e9
    assert held_after < TTL_MS / 1000 + 0.2, f"the robot held {held_after:.2f} s after the kill"
    at_rest(PB, fleet.track, halted.at)


def test_groups_reach_their_members_only_and_estop_halts_all(fleet: ClientFleet,
                                                             pygame_up: None) -> None:
    p = Pad()
    fleet.track.wait(YB, lambda h: True, "a youbot state")
    before = fleet.track.since(YB, 0.0)[-1].state.last_command_seq  # the latest, not the first
    with operator(fleet, tg.parse_target("group:sweepers")) as (op, inp):
        assert op.tick(inp.poll()).members == [PB], "members from the agents' own states"
        p.deadman()
        p.left(0.0, -0.5)
        for _ in range(3):
            assert op.tick(inp.poll()).engaged
        sent = op.seq.seq - 1
        t = time.monotonic()
        fleet.track.wait(PB, lambda h: h.state.last_command_seq == sent, "the group's command", t)
        late = fleet.track.wait(YB, lambda h: True, "a later youbot state", after=t + 0.1)
        assert late.state.last_command_seq == before, "the youbot is not in the group"

        op.target = tg.ALL
        t = time.monotonic()
        for _ in range(6):
            op.tick(inp.poll())
        sent = op.seq.seq - 1
        for rid in PLATFORMS:
            fleet.track.wait(rid, lambda h: h.state.last_command_seq >= sent
                             and h.state.status == "moving", f"{rid} moving", t)
        p.tap(pygame.CONTROLLER_BUTTON_B)
        t = time.monotonic()
        assert op.tick(inp.poll()).estopped
        for rid in PLATFORMS:
            halted = fleet.track.wait(rid, lambda h: h.state.status == "estop", "the e-stop", t)
            assert halted.at - t < 0.3
        for _ in range(3):  # the deadman is still held: nothing may release the latch
            assert not op.tick(inp.poll()).engaged
        for rid in PLATFORMS:
            rest = at_rest(rid, fleet.track, t)
            assert rest.state.status == "estop"
        p.tap(pygame.CONTROLLER_BUTTON_START)  # release, so the fleet is usable again
        op.tick(inp.poll())
        for rid in PLATFORMS:
            fleet.track.wait(rid, lambda h: h.state.status == "idle", "released", time.monotonic())
