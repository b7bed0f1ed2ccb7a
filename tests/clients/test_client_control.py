"""Who controls a robot, and what the operator is told, against real agents and a real databank:
acks reach the command line (a refusal exits 1 with its code, an e-stop is acknowledged by
every robot), two operators on one robot (only the lease holder moves it, the other is told
``lease_held``), a killed holder's lease lapses on time and the other operator gets it, and an
e-stop from the operator without the lease stops the robot at once."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from importlib import resources
from pathlib import Path

import pytest

from kinesphere import zconfig
from kinesphere.cli import main
from kinesphere.clients import targets as tg
from kinesphere.clients.gamepad.inputs import ticks
from kinesphere.clients.gamepad.lease import LEASE_TIMEOUT_S
from kinesphere.clients.gamepad.readout import Readout
from kinesphere.clients.gamepad.state import Action, ControllerState
from kinesphere.clients.gamepad.teleop import Teleop
from kinesphere.protocol import AckStage
from support.client_fleet import PB, PLATFORMS, YB, ClientFleet, Heard, operator
from support.paths import ROOT
from support.wait import WAIT_S

pytestmark = pytest.mark.processes

PERIOD = 1 / 30
HELD = frozenset({Action.DEADMAN})
LEFT_LOW = ControllerState(rx=-1.0, lt=1.0, held=HELD)  # served left-forward-low: turret +
RIGHT_LOW = ControllerState(rx=1.0, lt=1.0, held=HELD)  # served right-forward-low: turret -
LET_GO = ControllerState()


def turret(h: Heard) -> float:
    return h.state.q[h.state.joint_names.index("turret")]


def tick_together(ops: list[tuple[Teleop, ControllerState]], seconds: float) -> list[Readout]:
    """Tick every operator at 30 Hz for ``seconds``; the last operator's views."""
    views: list[Readout] = []
    end = time.monotonic() + seconds
    next_t = time.monotonic()
    while time.monotonic() < end:
        for op, cs in ops:
            views.append(op.tick(cs))
        next_t += PERIOD
        time.sleep(max(0.0, next_t - time.monotonic()))
    return views[len(ops) - 1 :: len(ops)]


def lease_of(fleet: ClientFleet, after: float) -> str:
    return fleet.track.wait(PB, lambda h: True, "a state", after=after).state.lease_holder


@pytest.fixture
def free(fleet: ClientFleet) -> Iterator[ClientFleet]:
    """The fleet with no lease held and no e-stop latched before and after the test."""
    assert main(["estop", "--release", "--target", "all", "--connect", fleet.endpoint]) == 0
    fleet.track.wait(PB, lambda h: not h.state.lease_holder and h.state.status != "estop",
                     "the lease free", after=time.monotonic())
    yield fleet
    assert main(["estop", "--release", "--target", "all", "--connect", fleet.endpoint]) == 0


def test_send_to_a_robot_that_rejects_exits_1_with_the_code(
    free: ClientFleet, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["send", PB, "limb_99", "distal_99", "left-high", "3",
                 "--connect", free.endpoint])
    assert code == 1
    out, err = capsys.readouterr()
    assert out.startswith(f"{PB}: REJECTED: unknown_limb: ")
    assert "0 of 1 robot(s) accepted" in err


def test_estop_is_acknowledged_by_every_robot_and_released_by_target(
    free: ClientFleet, capsys: pytest.CaptureFixture[str]
) -> None:
    start = time.monotonic()
    assert main(["estop", "--connect", free.endpoint, "--sender", "carol"]) == 0
    assert capsys.readouterr().out.splitlines() == [f"{r}: estopped" for r in sorted(PLATFORMS)]
    for rid in PLATFORMS:
        h = free.track.wait(rid, lambda h: h.state.status == "estop", "the e-stop", after=start)
        assert h.state.estop_by == "carol", "the state says who latched it"
    # carol's latch: another operator's release clears nothing (exit 1: nothing released)
    assert main(["estop", "--release", "--target", "all", "--connect", free.endpoint]) == 1
    assert all(line.endswith(": REJECTED: estopped: e-stop still latched by carol: each latch "
                             "clears only with its own sender's release (restarting the agent "
                             "clears it only when no fleet e-stop of that sender is in force)")
               for line in capsys.readouterr().out.splitlines())
    assert main(["estop", "--release", "--target", "all", "--connect", free.endpoint,
                 "--sender", "carol"]) == 0
    assert capsys.readouterr().out.splitlines() == [f"{r}: released" for r in sorted(PLATFORMS)]


def test_a_phrase_a_body_cannot_play_fails_before_anything_moves(
    free: ClientFleet, capsys: pytest.CaptureFixture[str]
) -> None:
    """tour_guide's third step opens both arms: the youBot and the PackBot each answer
    right_arm and left_arm with their only arm, so the step asks one limb two things (a
    conflict). play asks each platform's databank first, names the step, and sends
    nothing."""
    start = time.monotonic()
    code = main(["play", "tour_guide", "--target", "all", "--connect", free.endpoint,
                 "--sender", "tourist"])
    out, err = capsys.readouterr()
    assert code == 1
    lines = out.splitlines()
    assert [ln.split(":")[0] for ln in lines] == [f"{PB} (packbot)", f"{YB} (youbot)"]
    assert all("CANNOT PLAY tour-guide: step 3 (right_arm right_shoulder right-forward-low 2 "
               "+ left_arm left_shoulder left-forward-low 2): conflict: " in ln
               for ln in lines), out
    assert "cannot play on 2 of 2 robot(s) of all robots: nothing was sent" in err
    assert "playing" not in err
    for rid in PLATFORMS:  # no command from 'tourist' was ever acted on
        h = free.track.wait(rid, lambda h: True, "a state", after=time.monotonic())
        assert h.state.lease_holder != "tourist"
    assert all(h.state.lease_holder != "tourist" for r in PLATFORMS
               for h in free.track.since(r, start))


QUICK = (1.0, 0.2)
"""left_high's step durations in the quick copy: its last step ends long before the youBot
can be back at neutral (its written 2.5 s might not)."""


def test_a_phrase_ends_with_its_robots_where_it_says(
    free: ClientFleet, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """left_high ends 'back to neutral': play goes on until the youBot is there, then says it
    reached it (not 'holding: deadman released'); the robot is at rest at its neutral pose.
    Played as a copy with shorter steps (:data:`QUICK`), so the robot is still on its way
    when the last step's time runs out: play has to go on after it."""
    shipped = resources.files("kinesphere.clients.orders").joinpath("phrases/left_high.toml")
    durations = iter(QUICK)
    quick = re.sub(r"(?m)^duration = .*$", lambda _m: f"duration = {next(durations)}",
                   shipped.read_text(encoding="utf-8"))
    assert next(durations, None) is None, "left_high no longer has two steps"
    phrase = tmp_path / "left_high.toml"
    phrase.write_text(quick, encoding="utf-8")
    code = main(["play", str(phrase), "--target", YB, "--connect", free.endpoint])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert out.startswith(f"{YB}: reached") and len(out.splitlines()) == 1, out
    end = time.monotonic()
    rest = free.track.wait(YB, lambda h: True, "a state", after=end)
    assert max(map(abs, rest.state.qd)) < 0.01, "at rest when play returns"
    neutral = {"arm_joint_1": 2.9496, "arm_joint_2": 1.1345, "arm_joint_3": -2.0482,
               "arm_joint_4": 2.389, "arm_joint_5": 2.9234}  # platform.toml
    q = dict(zip(rest.state.joint_names, rest.state.q, strict=True))
    assert all(abs(q[j] - v) < 0.02 for j, v in neutral.items()), q


@contextmanager
def alice_and_bob(free: ClientFleet) -> Iterator[tuple[Teleop, Teleop]]:
    """Two operators of the PackBot, each on a session of their own: alice, then bob."""
    with (operator(free, tg.robot(PB), sender="alice") as (alice, _),
          operator(free, tg.robot(PB), sender="bob") as (bob, _)):
        yield alice, bob


def test_two_operators_only_the_lease_holder_moves_the_robot(
    free: ClientFleet, pygame_up: None
) -> None:
    with alice_and_bob(free) as (alice, bob):
        t0 = time.monotonic()
        tick_together([(alice, LEFT_LOW)], 0.2)  # alice engages first: the lease is hers
        views = tick_together([(alice, LEFT_LOW), (bob, RIGHT_LOW)], 2.0)
        assert lease_of(free, time.monotonic()) == "alice"
        refusal = bob.link.last_answers()[PB].ack
        assert (refusal.stage, refusal.code, refusal.lease_holder) == (
            AckStage.REJECTED, "lease_held", "alice")
        assert "alice" in views[-1].notice and "press K to take control" in views[-1].notice
        mine = alice.link.last_answers()[PB].ack
        assert mine.stage != AckStage.REJECTED, mine
        tick_together([(alice, LET_GO), (bob, LET_GO)], 0.2)
        alice.shutdown()
        bob.shutdown()
    hs = free.track.since(PB, t0)
    assert max(map(turret, hs)) > 0.3, "alice's left-forward-low moved the arm"
    assert min(map(turret, hs)) > -0.05, "bob's right-forward-low never did"


@pytest.mark.realtime  # the lease lapses LEASE_TIMEOUT_S after its holder died, by the clock
def test_a_killed_holders_lease_lapses_on_time_and_the_other_operator_gets_it(
    free: ClientFleet, pygame_up: None, tmp_path: Path
) -> None:
    rec = tmp_path / "alice.mcap"
    ticks.save(rec, [(k / 10, LEFT_LOW) for k in range(600)])  # a minute
    start = time.monotonic()
    alice = subprocess.Popen(
        [sys.executable, "-m", "kinesphere.cli", "gamepad", "--replay", str(rec), "--headless",
         "--target", PB, "--sender", "alice", "--connect", free.endpoint,
         "--listen", zconfig.LOOPBACK_ANY_PORT],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    try:
        free.track.wait(PB, lambda h: h.state.lease_holder == "alice" and h.state.status
                        == "moving", "alice in control", after=start)
        with operator(free, tg.robot(PB), sender="bob") as (bob, _):
            tick_together([(bob, RIGHT_LOW)], 0.5)
            assert bob.link.last_answers()[PB].ack.code == "lease_held"
            alice.send_signal(signal.SIGKILL)
            killed = time.monotonic()
            alice.wait()
            got = None
            while got is None and time.monotonic() - killed < LEASE_TIMEOUT_S + WAIT_S:
                tick_together([(bob, RIGHT_LOW)], PERIOD)
                last = bob.link.last_answers()[PB]
                if last.ack.stage != AckStage.REJECTED:
                    got = last.at
            bob.tick(LET_GO)
            bob.shutdown()
    finally:
        if alice.poll() is None:
            alice.kill()
            alice.wait()
    assert got is not None, "bob never got the lease"
    lapse = got - killed
    assert LEASE_TIMEOUT_S - 0.4 < lapse < LEASE_TIMEOUT_S + 1.0, lapse
    assert free.track.wait(PB, lambda h: h.state.lease_holder == "bob", "bob's lease",
                           after=killed)


@pytest.mark.realtime  # "at once": the robot reports the e-stop within 0.3 s of the press
def test_an_estop_from_the_operator_without_the_lease_stops_the_robot_at_once(
    free: ClientFleet, pygame_up: None
) -> None:
    with alice_and_bob(free) as (alice, bob):
        start = time.monotonic()
        tick_together([(alice, LEFT_LOW)], 1.0)
        assert lease_of(free, time.monotonic()) == "alice"
        free.track.wait(PB, lambda h: h.state.status == "moving", "alice moving it", after=start)
        pressed = time.monotonic()
        view = bob.tick(ControllerState(pressed=frozenset({Action.ESTOP})))
        assert view.estopped
        halted = free.track.wait(PB, lambda h: h.state.status == "estop", "the e-stop",
                                 after=pressed)
        assert halted.at - pressed < 0.3
        assert halted.state.estop_by == "bob"
        tick_together([(alice, LEFT_LOW)], 0.3)  # alice streams on: refused, latched
        refusal = alice.link.last_answers()[PB].ack
        assert (refusal.stage, refusal.code) == (AckStage.REJECTED, "estopped")
        assert bob.latched_by_me() == sorted(PLATFORMS), "bob's e-stop stopped every robot"
        view = bob.tick(ControllerState(pressed=frozenset({Action.RELEASE})))
        assert view.message == f"released the e-stop of {', '.join(sorted(PLATFORMS))}"
        free.track.wait(PB, lambda h: h.state.status != "estop", "released",
                        after=time.monotonic())
        alice.tick(LET_GO)
        alice.shutdown()
        bob.shutdown()
