"""The control loop reacts to a command as soon as it arrives, not at its next tick.

Asserted on the order of events, not on time: the loop runs slowly (4 Hz, a scheduled step
every 250 ms), a command is put right after a step, and the step that applies it must be an
early one (woken by the command) that comes before the next scheduled step. With
``strict_period`` the same command waits for the scheduled step: the test tells the two apart.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import pytest

from kinesphere import zconfig
from kinesphere.robots.agent.pacing import LoopStats, Wake, run_paced
from kinesphere.robots.agent.runtime import Agent, AgentOptions
from support.agents import CommandSender, DatabankProcess, far
from support.network import Hub
from support.wait import WAIT_S

RATE = 4.0  # Hz: a quarter of a second between scheduled steps makes the order unmistakable


@dataclass(frozen=True)
class LoopStep:
    woken: bool  # started by something arriving, not by its slot
    moved: int  # commands whose first setpoint went out so far
    status: str


class Recorder:
    """Every step of an agent's loop, in order, with a wait for the next one."""

    def __init__(self, agent: Agent) -> None:
        self.agent = agent
        self.steps: list[LoopStep] = []
        self.cond = threading.Condition()

    def __call__(self) -> None:
        a = self.agent
        with self.cond:
            self.steps.append(LoopStep(a.stats.woken, len(a.conduct.latencies), a.status()[0]))
            self.cond.notify_all()

    def after(self, n: int) -> LoopStep:
        """The first step after the first ``n`` (waiting for it)."""
        with self.cond:
            assert self.cond.wait_for(lambda: len(self.steps) > n, WAIT_S), "the loop stopped"
            return self.steps[n]

    def mark(self) -> int:
        """Wait for a step to end, then the number of steps so far (put right after this)."""
        with self.cond:
            n = len(self.steps)
            assert self.cond.wait_for(lambda: len(self.steps) > n, WAIT_S), "the loop stopped"
            return len(self.steps)


@pytest.mark.parametrize("strict", [False, True], ids=["reacts", "strict-period"])
def test_a_command_is_applied_before_the_next_scheduled_step(
    hub: Hub, databank: DatabankProcess, strict: bool
) -> None:
    session, endpoint = hub
    cat = databank.catalogue("baxter")
    poses = [far(cat, 0), far(cat, -1)]
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        agent = Agent("baxter", f"wake-{int(strict)}", s,
                      AgentOptions(control_rate=RATE, state_rate=RATE, speed=1.0,
                                   strict_period=strict))
        rec = Recorder(agent)
        stop = threading.Event()
        agent.declare()
        loop = threading.Thread(target=agent.run, args=(stop, rec), daemon=True)
        loop.start()
        op = CommandSender(session, agent.robot_id, sender="wake")
        try:
            for pose in poses:  # resolve both poses once: later commands hit the cache
                moved = len(agent.conduct.latencies)
                op.send(pose)
                deadline = time.monotonic() + WAIT_S
                while len(agent.conduct.latencies) == moved:
                    assert time.monotonic() < deadline, "the pose never moved the robot"
                    rec.mark()
            for k in range(3):
                n = rec.mark()
                moved = rec.steps[-1].moved
                op.send(poses[k % 2])
                step = rec.after(n)  # the first step after the put
                assert step.moved == moved + 1, "the first step after the put did not apply it"
                assert step.woken is not strict, rec.steps[n - 2:]
            n = rec.mark()
            op.send(estop=True)
            step = rec.after(n)
            assert step.status == "estop" and step.woken is not strict
        finally:
            op.close()
            stop.set()
            agent.close()
            loop.join(WAIT_S)


def test_the_loop_never_runs_more_than_one_step_ahead_of_its_schedule() -> None:
    """Woken again and again, the loop steps early once, then keeps to its slots."""
    period = 0.05
    starts: list[float] = []
    stats = LoopStats()
    wake = Wake()
    stop = threading.Event()

    def step() -> None:
        starts.append(time.perf_counter())
        if len(starts) >= 12:
            stop.set()

    def hammer() -> None:
        while not stop.is_set():
            wake.set()
            time.sleep(0.002)

    t = threading.Thread(target=hammer, daemon=True)
    t.start()
    run_paced(step, period, stop.is_set, stats, "test", lambda exc: None, wake)
    t.join(5)
    assert stats.early > 0
    for k, at in enumerate(starts):  # step k may start at slot k-1 at the earliest
        assert at >= starts[0] + (k - 1) * period - 1e-3, (k, at - starts[0])


def test_wake_behaves_like_an_event() -> None:
    """Set from another thread wakes a waiter; it stays set until cleared; set twice is set."""
    wake = Wake()
    assert not wake.is_set() and not wake.wait(0.01)
    wake.set()
    wake.set()  # twice: still just set
    assert wake.is_set() and wake.wait(0.0) and wake.wait(0.0)
    wake.clear()
    wake.clear()  # twice: still just clear
    assert not wake.is_set() and not wake.wait(0.01)
    waiting, woke = threading.Event(), []

    def waiter() -> None:
        waiting.set()
        woke.append(wake.wait(30.0))

    t = threading.Thread(target=waiter)
    t.start()
    assert waiting.wait(5.0)
    wake.set()
    t.join(30.0)
    assert woke == [True] and wake.is_set()
