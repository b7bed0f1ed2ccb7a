"""The gamepad's side of control leases and acks, over real Zenoh against robots that answer as
agents do: take on engage (--take) or with the take button, keep alive between gestures only
where we hold the lease, give it back on leaving; refusals and answers reach the view."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pygame
import pytest

from kinesphere.clients import targets as tg
from kinesphere.clients.gamepad import mapfile
from kinesphere.clients.gamepad.inputs import pad
from kinesphere.clients.gamepad.lease import KEEPALIVE_S
from kinesphere.clients.gamepad.teleop import Teleop
from kinesphere.clients.link import RobotLink
from kinesphere.clients.options import TeleopOptions
from kinesphere.protocol import AckStage, Command
from support.clients import Pad, Reply, StandIn, client_link, kind, sentinel, usual
from support.network import OWN_KEYS, Hub
from support.wait import WAIT_S


@pytest.fixture
def robot(hub: Hub) -> Iterator[StandIn]:
    r = StandIn(hub[0], "l1")
    yield r
    r.close()


@pytest.fixture
def link(hub: Hub, robot: StandIn) -> Iterator[RobotLink]:
    with client_link(hub[1], sender="carol") as lk:
        assert lk.wait_subscribers([OWN_KEYS.command("l1")], WAIT_S) == []
        assert lk.wait_for(lambda k: "l1" in k.states(), WAIT_S)
        yield lk


def settle(link: RobotLink, robot: StandIn) -> list[str]:
    sentinel(link, [OWN_KEYS.command("l1")], [robot])
    return [kind(c) for c in robot.commands()]


def test_take_on_engage_then_keep_alive_only_while_held_and_release_on_exit(
    link: RobotLink, robot: StandIn, inp: pad.PygameInput
) -> None:
    op = Teleop(link, mapfile.load(), tg.robot("l1"), TeleopOptions(), take=True)
    p = Pad()
    p.deadman()
    p.right(0.0, -1.0)
    t = 100.0
    for _ in range(2):
        assert op.tick(inp.poll(), t).engaged
        t += 1 / 30
    p.deadman(False)
    op.tick(inp.poll(), t)
    assert settle(link, robot) == ["move", "move", "let go"]
    first, second = robot.commands()[:2]
    assert (first.lease, second.lease) == ("take", ""), "take on the first command only"

    for _ in range(3):  # idle, but the robot does not say we hold it: nothing to renew
        t += KEEPALIVE_S
        op.tick(inp.poll(), t)
    assert settle(link, robot) == ["move", "move", "let go"]

    robot.lease_holder = "carol"
    assert link.wait_for(lambda k: k.states()["l1"].state.lease_holder == "carol", WAIT_S)
    for step in (0.0, KEEPALIVE_S / 2, KEEPALIVE_S / 2, KEEPALIVE_S):
        t += step
        op.tick(inp.poll(), t)
    assert settle(link, robot)[3:] == ["lease acquire"] * 3, "renewed once a second"

    p.deadman()
    assert op.tick(inp.poll(), t).engaged
    assert robot.wait(lambda g: g.cmd.seq == op.seq.seq - 1, "the engage").cmd.lease == "take"
    op.shutdown()
    assert settle(link, robot)[-2:] == ["let go", "lease release"]


def leasing(robot: StandIn) -> Callable[[Command], list[Reply]]:
    """A robot's lease in brief: free or taken -> granted; held by another -> lease_held."""

    def answer(cmd: Command) -> list[Reply]:
        if cmd.estop or cmd.stop or cmd.release:
            return usual(cmd)
        if cmd.lease == "take" or not robot.lease_holder:
            robot.lease_holder = cmd.sender
        if robot.lease_holder != cmd.sender:
            return [(AckStage.REJECTED, "lease_held",
                     f"{robot.lease_holder} holds this robot's lease", [])]
        return usual(cmd)

    return answer


def test_a_refusal_for_another_operators_lease_is_shown_and_the_take_button_takes_over(
    hub: Hub, inp: pad.PygameInput
) -> None:
    robot = StandIn(hub[0], "l2")
    robot.answer = leasing(robot)
    robot.lease_holder = "dave"
    try:
        with client_link(hub[1], sender="carol") as link:
            assert link.wait_for(lambda k: "l2" in k.states(), WAIT_S)
            op = Teleop(link, mapfile.load(), tg.robot("l2"))
            p = Pad()
            p.deadman()
            p.right(0.0, -1.0)
            assert op.tick(inp.poll()).engaged
            assert link.wait_for(lambda k: "l2" in k.last_answers(), WAIT_S)
            view = op.tick(inp.poll())
            assert view.notice == ("l2 refuses your commands: dave holds this robot's lease; "
                                   "press Back to take control")
            assert view.answers["l2"].ack.code == "lease_held"
            p.tap(pygame.CONTROLLER_BUTTON_BACK)
            view = op.tick(inp.poll())
            assert view.message == "taking control of l2"
            took = robot.wait(lambda g: g.cmd.lease == "take", "the take-over").cmd.seq

            def obeyed(k: RobotLink) -> bool:
                a = k.last_answers()["l2"].ack
                return a.seq > took and a.stage in (AckStage.ACCEPTED, AckStage.REACHED)

            assert link.wait_for(obeyed, WAIT_S), "our commands are obeyed again"
            assert op.tick(inp.poll()).notice == ""
            assert robot.lease_holder == "carol"
    finally:
        robot.close()
