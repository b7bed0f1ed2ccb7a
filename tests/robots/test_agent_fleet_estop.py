"""A fleet e-stop stays in force in the network until its sender releases it: a robot that
starts while it is in force, or that was cut off when it was sent and joins later, comes up
latched in that sender's name; after the release a new robot starts free; a robot whose copy
of the command was lost latches from the others. Real Zenoh, real agents, a real router
process for the robot that joins late."""

from __future__ import annotations

import time

from kinesphere import zconfig
from kinesphere.procs import Supervisor
from kinesphere.protocol import FleetEstops, decode
from kinesphere.robots.agent.estops import SYNC_S
from kinesphere.robots.agent.runtime import Agent, AgentOptions
from support.agents import CommandSender, StateWatch, knows, running_agent
from support.network import KEYS, Hub
from support.system import port_open
from support.wait import WAIT_S, until


def test_a_robot_started_during_a_fleet_estop_comes_up_latched(hub: Hub) -> None:
    with (zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s,
          CommandSender(s, "*", sender="officer") as fleet):
        with running_agent(hub.endpoint, "youbot", "fe-1") as (_, first):
            first.after(fleet.send(estop=True), lambda st: st.status == "estop", "the e-stop")
            with running_agent(hub.endpoint, "khepera", "fe-late") as (_, late):
                st = late.states[0]
                assert st.status == "estop" and st.estop_by == "officer", \
                    "its very first state is latched"
                assert "fleet e-stop in force" in st.detail
                assert "'kinesphere estop --release --target all --sender officer'" in st.detail
                assert all(s.last_command_seq < 0 for s in late.states), "it obeyed nothing"
                knows(s, "fe-late")
                fleet.send(release=True, deadman=True)
                late.wait(lambda st: st.status != "estop", "released by the fleet release")
                first.wait(lambda st: st.status != "estop", "released by the fleet release")
            with running_agent(hub.endpoint, "khepera", "fe-after") as (_, after):
                assert after.states[0].status != "estop", "released: a new robot starts free"


def test_a_robot_that_joins_late_latches_from_the_others(hub: Hub, sup: Supervisor) -> None:
    """It runs behind a router that is down when the e-stop goes out; when the router comes
    up, its board asks at once (a new link) and it latches without any command. Its session
    retries the router every 0.1 s (Zenoh's default backs off to 4 s: the link would form up
    to 4 s after the router is up, and only the board's ask on the new link is the claim)."""
    port = zconfig.free_port()
    behind = f"tcp/127.0.0.1:{port}"
    config = zconfig.session_config("peer", listen=[zconfig.LOOPBACK_ANY_PORT], connect=[behind])
    config.insert_json5("connect/retry", '{"period_init_ms": 100, "period_max_ms": 100}')
    with (zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s,
          zconfig.session(config=config) as cut,
          CommandSender(s, "*", sender="officer") as fleet,
          StateWatch(s, "fe-cut") as watch):
        late = Agent("khepera", "fe-cut", cut, AgentOptions(speed=1.0)).start()
        try:
            with running_agent(hub.endpoint, "youbot", "fe-2") as (_, first):
                first.after(fleet.send(estop=True), lambda st: st.status == "estop",
                            "the e-stop")
                assert late.last_state is None or late.last_state.status != "estop"
                sup.spawn("router", ["router", "--listen", behind, "--link", hub.endpoint])
                until(lambda: port_open(port), WAIT_S, "the router")
                joined = time.monotonic()
                st = watch.wait(lambda st: st.status == "estop", "the late robot latched")
                assert st.estop_by == "officer"
                assert time.monotonic() - joined < WAIT_S
                knows(s, "fe-cut")
                fleet.send(release=True, deadman=True)
                watch.wait(lambda st: st.status != "estop", "released")
        finally:
            late.close()


def test_every_robot_process_answers_what_it_knows(hub: Hub) -> None:
    """The board on ``{p}/estop/{holder}``: the e-stop in force, then its release."""
    with (zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s,
          running_agent(hub.endpoint, "khepera", "fe-3") as (agent, watch),
          CommandSender(s, "*", sender="officer") as officer):
        watch.after(officer.send(estop=True), lambda st: st.status == "estop", "the e-stop")

        def known() -> dict[str, bool]:
            out = {}
            for reply in s.get(KEYS.fleet_estops("*"), timeout=2.0):
                if reply.ok is not None:
                    board = decode(reply.ok.payload, FleetEstops)
                    if board.holder == str(agent.session.zid()):
                        out = {e.sender: e.engaged for e in board.estops}
            return out

        assert known() == {"officer": True}
        officer.send(release=True, deadman=True)
        watch.wait(lambda st: st.status != "estop", "released")
        until(lambda: known() == {"officer": False}, WAIT_S, "the release known")


def test_a_robot_whose_copy_was_lost_latches_within_a_sync(hub: Hub) -> None:
    """An e-stop that reached one robot and not another (the other's subscription dropped
    it): the other latches from the first's board within a sync period."""
    with running_agent(hub.endpoint, "khepera", "fe-4") as (a, wa), \
            running_agent(hub.endpoint, "khepera", "fe-5") as (b, wb):
        board = b.board
        assert board is not None
        board.heard = lambda cmd, key: None  # type: ignore[method-assign]
        b_receive = b.receive

        def deaf(payload: object, signer: str = "", key: str = "") -> None:
            """fe-5 hears no command at all."""

        b.receive = deaf  # type: ignore[method-assign]
        with (zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s,
              CommandSender(s, "*", sender="officer") as officer):
            knows(s, "fe-4")  # fe-5's subscriber alone would match the officer's first put
            wa.after(officer.send(estop=True), lambda st: st.status == "estop", "fe-4 latched")
            sent = time.monotonic()
            st = wb.wait(lambda st: st.status == "estop", "fe-5 latched from fe-4's board")
            assert st.estop_by == "officer" and time.monotonic() - sent < WAIT_S
            assert SYNC_S <= 1.0
            b.receive = b_receive  # type: ignore[method-assign]
            officer.send(release=True, deadman=True)
            wb.wait(lambda st: st.status != "estop", "released")
