"""The streaming loop over real Zenoh, driven by posted pygame events: content, rate and TTL
of the stream, deadman, final stops, targets and groups, e-stop, catalogue-driven cycling."""

from __future__ import annotations

import statistics
from collections.abc import Iterator
from contextlib import contextmanager

import msgspec
import pygame
import pytest
import zenoh

from kinesphere import zconfig
from kinesphere.clients import targets as tg
from kinesphere.clients.gamepad import mapfile
from kinesphere.clients.gamepad.inputs import pad
from kinesphere.clients.gamepad.limbs import CatalogueCache, Selection, pairs_of
from kinesphere.clients.gamepad.teleop import Teleop, run
from kinesphere.clients.link import RobotLink
from kinesphere.clients.options import TeleopOptions
from kinesphere.laban import Direction
from kinesphere.protocol import Catalogue, LimbEntry, SpatialCommand
from support.clients import (
    CommandInbox,
    FakeRobot,
    Pad,
    Script,
    await_catalogue,
    client_link,
    databank_service,
    fake_catalogue,
    kind,
    sentinel,
)
from support.network import OWN_KEYS, Hub
from support.wait import WAIT_S

ROBOTS = ("r1", "r2", "r3")


@pytest.fixture
def inboxes(hub: Hub) -> Iterator[dict[str, CommandInbox]]:
    session, _ = hub
    boxes = {r: CommandInbox(session, OWN_KEYS.command(r)) for r in ROBOTS}
    yield boxes
    for b in boxes.values():
        b.close()


@pytest.fixture
def link(hub: Hub, inboxes: dict[str, CommandInbox]) -> Iterator[RobotLink]:
    _, endpoint = hub
    with client_link(endpoint) as lk:
        assert lk.wait_subscribers([OWN_KEYS.command(r) for r in ROBOTS], WAIT_S) == []
        yield lk


def teleop(link: RobotLink, target: tg.Target, options: TeleopOptions | None = None) -> Teleop:
    return Teleop(link, mapfile.load(), target, options or TeleopOptions())


def settle(link: RobotLink, boxes: dict[str, CommandInbox]) -> None:
    """Everything sent so far has arrived at every robot."""
    sentinel(link, [OWN_KEYS.command(r) for r in boxes], list(boxes.values()))


@pytest.mark.realtime  # the gamepad's ticks at 30 Hz, no gap past the TTL, by the clock
def test_stream_content_rate_ttl_and_final_stop(
    link: RobotLink, inboxes: dict[str, CommandInbox], inp: pad.PygameInput
) -> None:
    p = Pad()

    def press() -> None:
        p.plug()
        p.deadman()
        p.right(-1.0, 0.0)  # stick left
        p.axis(pygame.CONTROLLER_AXIS_TRIGGERLEFT, 1.0)  # low
        p.left(0.0, -1.0)  # drive forward

    script = Script(inp, {0: press, 30: lambda: p.deadman(False), 34: lambda: None})
    op = teleop(link, tg.robot("r1"), TeleopOptions(rate_hz=30.0, ttl_ms=300))
    run(op, script, finished=lambda: script.finished)
    settle(link, inboxes)
    got = [g for g in inboxes["r1"].got if g.cmd.sender != "sentinel"]
    stream, final = got[:-2], got[-2:]
    assert len(stream) == 30
    for g in stream:
        c = g.cmd
        assert c.deadman and not c.stop and not c.estop and c.ttl_ms == 300
        assert c.parts == [SpatialCommand("limb_11", "distal_11", "left-low", 3.0)]
        assert c.drive is not None and (c.drive.direction, c.drive.speed) == ("forward-middle", 0.5)
        assert (c.drive.forward, c.drive.left, c.drive.yaw) == (0.5, 0.0, 0.0)
        assert c.sender == op.seq.sender
    assert [g.cmd.seq for g in got] == list(range(32))
    assert [kind(g.cmd) for g in final] == ["let go", "lease release"], "at exit: lease back"
    assert final[0].cmd.parts == [] and final[0].cmd.drive is None
    gaps = [b.at - a.at for a, b in zip(stream, stream[1:], strict=False)]
    assert statistics.median(gaps) == pytest.approx(1 / 30, abs=0.006)
    assert stream[-1].at - stream[0].at == pytest.approx(29 / 30, abs=0.1)
    assert max(gaps) < 0.3, "the stream never pauses longer than the TTL"
    assert inboxes["r2"].commands() == [] and inboxes["r3"].commands() == []


def test_nothing_moves_without_the_deadman(
    link: RobotLink, inboxes: dict[str, CommandInbox], inp: pad.PygameInput
) -> None:
    p = Pad()
    op = teleop(link, tg.robot("r1"))
    p.right(0.0, -1.0)
    p.left(1.0, 0.0)
    for _ in range(5):
        view = op.tick(inp.poll())
        assert not view.engaged
    settle(link, inboxes)
    assert inboxes["r1"].commands() == []


def test_without_a_deadman_a_deflected_stick_streams(
    link: RobotLink, inboxes: dict[str, CommandInbox], inp: pad.PygameInput
) -> None:
    p = Pad()
    op = teleop(link, tg.robot("r1"), TeleopOptions(deadman_required=False))
    op.tick(inp.poll())  # centred: nothing
    p.right(0.0, 1.0)  # stick down: back
    op.tick(inp.poll())
    op.tick(inp.poll())
    p.right(0.0, 0.0)
    op.tick(inp.poll())
    settle(link, inboxes)
    cmds = inboxes["r1"].commands()
    assert [c.parts[0].direction for c in cmds[:2]] == ["back-middle"] * 2
    assert [kind(c) for c in cmds] == ["move", "move", "let go"]


def test_a_centred_stick_holds_until_pushed_then_its_return_is_neutral(
    link: RobotLink, inboxes: dict[str, CommandInbox], inp: pad.PygameInput
) -> None:
    """Pressing the deadman with the stick centred moves nothing: the commands carry no part
    (the limb holds, as a zero command holds in MoveIt Servo). After a push, the stick's return
    to the centre is the limb's neutral pose (the stick is a position); a new press of the
    deadman starts holding again."""
    p = Pad()
    p.plug()
    op = teleop(link, tg.robot("r1"))
    p.deadman()
    views = [op.tick(inp.poll()) for _ in range(3)]  # centred
    assert all(v.engaged and v.stick_holds for v in views)
    p.right(-1.0, 0.0)  # pushed left
    op.tick(inp.poll())
    p.right(0.0, 0.0)  # back to the centre
    back = op.tick(inp.poll())
    assert back.engaged and not back.stick_holds
    p.deadman(False)
    op.tick(inp.poll())
    p.deadman()
    again = op.tick(inp.poll())  # pressed anew, centred: holds again
    assert again.stick_holds
    settle(link, inboxes)
    cmds = [c for c in inboxes["r1"].commands() if kind(c) == "move"]
    assert [[(x.direction, x.size) for x in c.parts] for c in cmds] == [
        [], [], [], [("left-middle", 3.0)], [("place-middle", 0.0)], []]


def test_a_target_nobody_has_says_so_and_names_who_is_alive(
    hub: tuple[zenoh.Session, str], link: RobotLink, inp: pad.PygameInput,
    pygame_up: None,
) -> None:
    """``--target yb-9`` when only yb-1 exists: after a moment the HUD says the commands
    reach nobody, in the target's place and the deadman banner, and names who is alive."""
    session, _ = hub
    robot = FakeRobot(session, "yb-1", "youbot")
    robot.state()
    assert link.wait_for(lambda lk: "yb-1" in lk.states(), WAIT_S)
    p = Pad()
    p.plug()
    p.deadman()
    op = teleop(link, tg.robot("yb-9"))
    t0 = 1000.0
    first = op.tick(inp.poll(), now=t0)
    assert first.engaged and not first.unheard, "a moment to be heard"
    later = op.tick(inp.poll(), now=t0 + 1.5)
    assert later.unheard and later.notice.startswith(
        "no robot 'yb-9' is heard: your commands reach nobody (live: ")
    assert "yb-1" in later.notice and "did you mean 'yb-1'?" in later.notice
    from kinesphere.clients.gamepad import hud

    surf = pygame.Surface(hud.SIZE)
    layout = hud.render(surf, later, hud.load_fonts())
    assert {d.colour for d in layout["target"]} == {hud.BAD}
    assert [d.text for d in layout["deadman"]] == ["deadman held: streaming to NOBODY"]
    assert layout["answer"][0].text == "nobody answers: no robot heard"
    zconfig.undeclare(robot.pub)


def status_of(link: RobotLink, robot_id: str) -> str | None:
    seen = link.states().get(robot_id)
    return seen.state.status if seen else None


def engage(op: Teleop, inp: pad.PygameInput, p: Pad, ticks: int = 2) -> None:
    p.deadman()
    p.right(0.0, -1.0)
    for _ in range(ticks):
        assert op.tick(inp.poll()).engaged


def test_group_and_all_reach_every_intended_robot_and_no_other(
    hub: Hub, link: RobotLink, inboxes: dict[str, CommandInbox],
    inp: pad.PygameInput,
) -> None:
    session, _ = hub
    # what r1 and r2, run with --group arms, hear
    arms = CommandInbox(session, OWN_KEYS.group_command("arms"))
    try:
        assert link.wait_subscribers([OWN_KEYS.group_command("arms")], WAIT_S) == []
        p = Pad()
        op = teleop(link, tg.parse_target("group:arms"))
        engage(op, inp, p)
        p.deadman(False)
        op.tick(inp.poll())
        sentinel(link, [OWN_KEYS.group_command("arms"), *(OWN_KEYS.command(r) for r in ROBOTS)],
                 [arms, *inboxes.values()])
        cmds = arms.commands()
        assert [kind(c) for c in cmds] == ["move", "move", "let go"]
        assert {g.key for g in arms.got} == {OWN_KEYS.group_command("arms")}
        for r in ROBOTS:
            assert inboxes[r].commands() == [], "robots hear a group only on the group's key"
    finally:
        arms.close()

    op.target = tg.ALL
    engage(op, inp, p)
    p.deadman(False)
    op.tick(inp.poll())
    settle(link, inboxes)
    for r in ROBOTS:
        last = [g for g in inboxes[r].got if g.cmd.sender != "sentinel"][-3:]
        assert [g.key for g in last] == [OWN_KEYS.command("*")] * 3
        assert [kind(g.cmd) for g in last] == ["move", "move", "let go"]


def test_target_button_cycles_robots_then_the_groups_they_report_then_all(
    hub: Hub, link: RobotLink, inp: pad.PygameInput
) -> None:
    session, _ = hub
    for r in ROBOTS:
        FakeRobot(session, r, "fakebot", ["arms"] if r != "r3" else ["tail", "arms"]).state()
    assert link.wait_for(lambda lk: set(lk.states()) >= set(ROBOTS), WAIT_S)
    op = teleop(link, tg.robot("r1"))
    p = Pad()
    seen = []
    for _ in range(6):
        p.tap(pygame.CONTROLLER_BUTTON_Y)
        view = op.tick(inp.poll())
        seen.append((view.target.spelling, view.members))
    assert seen == [
        ("r2", ["r2"]), ("r3", ["r3"]), ("group:arms", ["r1", "r2", "r3"]),
        ("group:tail", ["r3"]), ("all", ["r1", "r2", "r3"]), ("r1", ["r1"]),
    ]


def test_switching_target_stops_the_old_one(
    link: RobotLink, inboxes: dict[str, CommandInbox], inp: pad.PygameInput
) -> None:
    p = Pad()
    op = teleop(link, tg.robot("r3"))
    engage(op, inp, p, ticks=1)
    p.tap(pygame.CONTROLLER_BUTTON_Y)  # no robots heard: the cycle offers only all
    view = op.tick(inp.poll())
    assert view.engaged and view.target == tg.ALL
    settle(link, inboxes)
    r3 = inboxes["r3"].commands()
    assert [kind(c) for c in r3] == ["move", "let go", "lease release", "move"], (
        "let go and give the lease back, then all's move")
    assert len(inboxes["r1"].commands()) == 1


def test_estop_goes_to_all_latches_and_start_releases_ours_everywhere(
    hub: Hub, link: RobotLink, inboxes: dict[str, CommandInbox],
    inp: pad.PygameInput,
) -> None:
    session, _ = hub
    robots = {r: FakeRobot(session, r, "fakebot") for r in ROBOTS}
    p = Pad()
    op = teleop(link, tg.robot("r1"))
    engage(op, inp, p)
    p.tap(pygame.CONTROLLER_BUTTON_B)
    view = op.tick(inp.poll())
    assert view.estopped and not view.engaged
    for r in ROBOTS:
        inboxes[r].wait(lambda g: g.cmd.estop and g.key == OWN_KEYS.command("*"), f"e-stop at {r}")
    robots["r1"].state("estop", estop_by=op.seq.sender)  # latched by this operator
    robots["r2"].state("estop", estop_by="gamepad-someone-else")  # by another one
    robots["r3"].state("estop")  # a robot that does not say who: ours while our e-stop stands
    assert link.wait_for(lambda lk: all(status_of(lk, r) == "estop" for r in ROBOTS), WAIT_S)
    for _ in range(3):  # deadman still held, stick still pushed: nothing goes out
        assert not op.tick(inp.poll()).engaged
    assert op.latched_by_me() == ["r1", "r3"]
    p.tap(pygame.CONTROLLER_BUTTON_START)
    view = op.tick(inp.poll())
    assert not view.estopped and not view.engaged and view.need_fresh_deadman
    assert view.message.startswith("released the e-stop of r1, r3")
    assert "still latched by others: r2" in view.message
    p.deadman(False)
    op.tick(inp.poll())
    p.deadman()
    robots["r1"].state("idle")
    assert link.wait_for(lambda lk: status_of(lk, "r1") == "idle", WAIT_S)
    assert op.tick(inp.poll()).engaged
    settle(link, inboxes)
    cmds = sorted(inboxes["r1"].commands(), key=lambda c: c.seq)  # the e-stop may overtake
    assert [kind(c) for c in cmds] == ["move", "move", "estop", "release", "move"]
    assert cmds[3].deadman and not cmds[3].parts, "a release moves nothing by itself"
    assert [c.release for c in inboxes["r3"].commands()] == [False, True]
    release = inboxes["r2"].wait(lambda g: g.cmd.release, "our release at r2")
    assert OWN_KEYS.is_fleet_command(release.key) and release.cmd.sender == op.seq.sender, \
        "every robot's key, in our name: a robot clears only our own latch (r2 keeps its other)"
    p.tap(pygame.CONTROLLER_BUTTON_START)  # nothing of ours is latched any more
    assert op.tick(inp.poll()).message.startswith("no robot reports an e-stop latched by you")


def test_unplugging_sends_a_final_stop_and_replugging_needs_the_deadman_again(
    link: RobotLink, inboxes: dict[str, CommandInbox], inp: pad.PygameInput
) -> None:
    p = Pad()
    p.plug()
    op = teleop(link, tg.robot("r1"))
    engage(op, inp, p)
    p.unplug()
    view = op.tick(inp.poll())
    assert not view.connected and not view.engaged
    inboxes["r1"].wait(lambda g: not g.cmd.deadman, "the final let-go")
    p.plug()
    p.right(0.0, -1.0)
    assert not op.tick(inp.poll()).engaged
    p.deadman()
    assert op.tick(inp.poll()).engaged
    settle(link, inboxes)
    assert [kind(c) for c in inboxes["r1"].commands()] == ["move", "move", "let go", "move"]


def test_leaving_the_loop_sends_a_final_stop(
    link: RobotLink, inboxes: dict[str, CommandInbox], inp: pad.PygameInput
) -> None:
    p = Pad()
    script = Script(inp, {0: lambda: p.deadman().right(0.0, -1.0), 3: lambda: None})
    op = teleop(link, tg.robot("r2"), TeleopOptions(rate_hz=100.0))
    run(op, script, finished=lambda: script.finished)  # ends with the deadman still held
    settle(link, inboxes)
    cmds = inboxes["r2"].commands()
    assert [kind(c) for c in cmds] == ["move"] * 4 + ["let go", "lease release"]


def test_an_estop_reported_by_a_robot_pauses_the_stream(
    hub: Hub, link: RobotLink, inboxes: dict[str, CommandInbox],
    inp: pad.PygameInput,
) -> None:
    """Robots release a latch on any deadman command: never stream into someone's e-stop."""
    session, _ = hub
    robot = FakeRobot(session, "r1", "fakebot")
    p = Pad()
    op = teleop(link, tg.robot("r1"))
    engage(op, inp, p, ticks=1)
    robot.state("estop")
    assert link.wait_for(lambda lk: status_of(lk, "r1") == "estop", WAIT_S)
    view = op.tick(inp.poll())
    assert not view.engaged and view.remote_estop == ["r1"]
    settle(link, inboxes)
    assert [kind(c) for c in inboxes["r1"].commands()] == ["move", "let go"]


FAKEBOT = Catalogue(
    platform="fakebot",
    core=["c_1"],
    limbs=[
        LimbEntry("limb_11", "distal_11", ["left-high", "place-middle"], [1, 2, 3]),
        LimbEntry("limb_12", "distal_11", ["left-high"], [1, 2, 3]),
        LimbEntry("limb_12", "distal_12", ["left-high"], [1, 2, 3]),
        LimbEntry("limb_21", "distal_21", ["left-high", "forward-middle"], [1, 2, 3]),
        LimbEntry("c_1", "c_1", ["forward-middle"], [1, 2, 3]),
    ],
    joints=[],
    sizes=[1, 2, 3],
    aliases={"right_arm": "limb_11", "right_shoulder": "distal_11", "left_arm": "limb_21"},
    version="test",
)


def test_shoulder_cycling_follows_the_robots_catalogue(
    hub: Hub, link: RobotLink, inboxes: dict[str, CommandInbox],
    inp: pad.PygameInput,
) -> None:
    session, _ = hub
    FakeRobot(session, "r1", "fakebot").state()
    assert link.wait_for(lambda lk: "r1" in lk.states(), WAIT_S)
    with fake_catalogue(session, FAKEBOT):
        await_catalogue(link, "fakebot")
        op = teleop(link, tg.robot("r1"))
        op.tick(inp.poll())
        assert op.catalogues.arrived.wait(WAIT_S)
        view = op.tick(inp.poll())
        assert (view.limb, view.origin) == ("limb_11", "distal_11")
        assert view.aliases["limb_11"] == "right_arm"
        p = Pad()
        seen = []
        for b in ("DPAD_DOWN", "X", "X", "DPAD_DOWN", "DPAD_DOWN", "DPAD_UP"):
            p.tap(getattr(pygame, f"CONTROLLER_BUTTON_{b}"))
            v = op.tick(inp.poll())
            seen.append((v.limb, v.origin))
        assert seen == [
            ("limb_12", "distal_11"), ("limb_12", "distal_12"), ("limb_12", "distal_11"),
            ("limb_21", "distal_21"), ("limb_11", "distal_11"), ("limb_21", "distal_21"),
        ]
        engage(op, inp, p, ticks=1)
    settle(link, inboxes)
    part = inboxes["r1"].commands()[-1].parts[0]
    assert (part.limb, part.origin, part.direction) == ("limb_21", "distal_21", "forward-middle")


def test_groups_of_different_platforms_offer_the_shared_pairs_first() -> None:
    other = msgspec.structs.replace(FAKEBOT, platform="otherbot", limbs=FAKEBOT.limbs[2:])
    assert pairs_of([FAKEBOT, other]) == [("limb_12", "distal_12"), ("limb_21", "distal_21")]
    lone = msgspec.structs.replace(
        FAKEBOT, platform="lone", limbs=[LimbEntry("limb_31", "distal_31", [], [1])]
    )
    assert pairs_of([other, lone])[0] == ("limb_12", "distal_12"), "no pair shared: the union"
    assert pairs_of([]) == [("limb_11", "distal_11")]
    sel = Selection()
    sel.update(pairs_of([FAKEBOT]))
    sel.limb, sel.origin = "limb_12", "distal_12"
    sel.update(pairs_of([other]))
    assert (sel.limb, sel.origin) == ("limb_12", "distal_12"), "a still valid choice is kept"


@contextmanager
def packbot_operator(session: zenoh.Session, link: RobotLink, inp: pad.PygameInput
                     ) -> Iterator[Teleop]:
    """An operator targeting a stand-in PackBot "r2", with the real PackBot databank serving
    and its catalogue already fetched."""
    FakeRobot(session, "r2", "packbot").state()
    assert link.wait_for(lambda lk: "r2" in lk.states(), WAIT_S)
    with databank_service(session, "packbot"):
        await_catalogue(link, "packbot")
        op = teleop(link, tg.robot("r2"))
        op.tick(inp.poll())
        assert op.catalogues.arrived.wait(WAIT_S)
        yield op


def test_the_sweep_goes_out_as_asked(
    hub: Hub, link: RobotLink, inboxes: dict[str, CommandInbox],
    inp: pad.PygameInput,
) -> None:
    """The PackBot arm (real databank) reaches low to either side: low + stick left sends
    left-low, stick right right-low, no substitute."""
    with packbot_operator(hub[0], link, inp) as op:
        p = Pad()
        p.deadman()
        p.axis(pygame.CONTROLLER_AXIS_TRIGGERLEFT, 1.0)
        p.right(-1.0, 0.0)
        left = op.tick(inp.poll())
        p.right(1.0, 0.0)
        right = op.tick(inp.poll())
    assert (left.limb, left.origin) == ("limb_11", "distal_11")
    assert left.asked is None and left.intent.direction is Direction.LEFT_LOW
    assert right.asked is None and right.intent.direction is Direction.RIGHT_LOW
    assert left.available is not None and Direction.LEFT_LOW in left.available
    settle(link, inboxes)
    assert [c.parts[0].direction for c in inboxes["r2"].commands()[-2:]] == [
        "left-low", "right-low"]


def test_a_direction_no_body_has_near_sends_the_drive_alone(
    hub: Hub, link: RobotLink, inboxes: dict[str, CommandInbox],
    inp: pad.PygameInput,
) -> None:
    """PackBot's arm (shipped databank) has no pose pointing within 45 degrees of back-low
    (its shoulder cannot point below the deck behind it): stick back and low while driving
    forward sends the drive alone (a robot would refuse the whole command for the part), the
    limb holds and the view says so; a servable push sends its part again."""
    with packbot_operator(hub[0], link, inp) as op:
        p = Pad()
        p.deadman()
        p.left(0.0, -0.6)  # base: forward
        p.axis(pygame.CONTROLLER_AXIS_TRIGGERLEFT, 1.0)  # low
        p.right(0.0, 1.0)  # arm: back, low
        held = op.tick(inp.poll())
        p.right(-1.0, 0.0)  # left, low: the sweep
        swept = op.tick(inp.poll())
    assert held.intent.direction is Direction.BACK_LOW and held.limb_holds
    assert held.available is not None and Direction.BACK_LOW not in held.available
    assert not swept.limb_holds and swept.intent.direction is Direction.LEFT_LOW
    settle(link, inboxes)
    drive_only, sweep = inboxes["r2"].commands()[-2:]
    assert drive_only.parts == [] and drive_only.drive is not None
    assert drive_only.drive.forward > 0
    assert [s.direction for s in sweep.parts] == ["left-low"]
    assert sweep.drive is not None and sweep.drive.forward > 0


def test_a_recorded_pose_makes_the_client_fetch_catalogues_again(
    hub: Hub, link: RobotLink
) -> None:
    session, _ = hub
    with fake_catalogue(session, FAKEBOT):
        await_catalogue(link, "fakebot")
        cache = CatalogueCache(link)
        cache.get(["fakebot"])
        assert cache.arrived.wait(WAIT_S) and cache.get(["fakebot"]) == [FAKEBOT]
        pub = session.declare_publisher(OWN_KEYS.changed("fakebot"))
        assert zconfig.wait_matching(pub, WAIT_S)
        cache.arrived.clear()
        pub.put(b"")  # the payload (the recorded Pose) does not matter here
        assert link.wait_for(lambda lk: lk.catalogue_epoch == 1, WAIT_S)
        assert cache.get(["fakebot"]) == [], "dropped, fetching again"
        assert cache.arrived.wait(WAIT_S) and cache.get(["fakebot"]) == [FAKEBOT]
        zconfig.undeclare(pub)
