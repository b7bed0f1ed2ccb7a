"""``kinesphere estop`` cannot miss a live robot: eight robots on two fleet hosts behind a
``kinesphere router``, two operators flooding every robot with pose commands, the CPU loaded
by busy processes; e-stop after e-stop, each one must list all eight robots (exit 0, every
robot latched as its own state then says) or exit 1 naming the ones it could not confirm. It
never exits 0 while a robot did not latch. Halfway through, a robot started while an e-stop is
in force comes up latched without hearing it. ``make soak`` runs SCALE times the rounds (200
at its default), each printing the confirm times (p50, p99).
"""

from __future__ import annotations

import re
import statistics
import subprocess
import sys
import time

import pytest

from kinesphere import zconfig
from kinesphere.cli import main
from kinesphere.procs import Supervisor
from support.agents import StateWatch
from support.soak import SCALE, FloodTally
from support.system import Observer, databank_args, router_hub
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

PLATFORMS = ("baxter", "nao", "youbot", "packbot")
HOSTS = {"host-a": [f"{p}:a-{p}" for p in PLATFORMS], "host-b": [f"{p}:b-{p}" for p in PLATFORMS]}
ROBOTS = sorted(spec.split(":")[1] for specs in HOSTS.values() for spec in specs)
ROUNDS = 10 * SCALE
BURNERS = 1 if SCALE == 1 else 2
OFFICER = "flood-officer"
CONFIRMED = re.compile(r"E-STOP confirmed by all (\d+) live robot\(s\) in ([\d.]+) s")


def estop_round(capsys: pytest.CaptureFixture[str], endpoint: str, obs: Observer,
                tally: FloodTally, times: list[float]) -> None:
    """One ``kinesphere estop`` as a Zenoh client of the router: all eight listed and latched
    (by their own states), or exit 1; then the release."""
    capsys.readouterr()
    began = time.time_ns()
    code = main(["estop", "--mode", "client", "--connect", endpoint, "--sender", OFFICER,
                 "--timeout", "5"])
    out, err = capsys.readouterr()
    lines = out.splitlines()
    named = {ln.split(":")[0] for ln in lines}
    if code == 0:
        assert sorted(lines) == [f"{r}: estopped" for r in ROBOTS], out + err
        took = CONFIRMED.search(err)
        assert took is not None and int(took[1]) == len(ROBOTS), err
        times.append(float(took[2]))
        tally.add("all 8 confirmed")

        def latched() -> bool:  # the robots' own word, independent of the command's count
            s = obs.states.snapshot()
            return all(r in s and s[r].stamp_ns > began and s[r].status == "estop"
                       and s[r].estop_by == OFFICER for r in ROBOTS)

        until(latched, WAIT_S, "every robot's own state to say it latched",
              explain=obs.describe)
    else:
        assert code == 1, out + err
        assert "NOT CONFIRMED" in err and set(ROBOTS) <= named, out + err
        tally.add("exit 1 naming the unconfirmed")
    released = main(["estop", "--release", "--target", "all", "--mode", "client", "--connect",
                     endpoint, "--sender", OFFICER])
    said = capsys.readouterr()
    assert released == 0, (f"the release (exit {released}):\n{said.out}{said.err}"
                           f"the e-stop before it (exit {code}):\n{out}{err}{obs.describe()}")


def test_estop_lists_every_robot_or_exits_1_under_load(
    sup: Supervisor, capsys: pytest.CaptureFixture[str]
) -> None:
    endpoint = router_hub(sup)
    join = ["--connect", endpoint, "--listen", zconfig.LOOPBACK_ANY_PORT]
    sup.spawn("databank", ["databank", "serve", *databank_args(list(PLATFORMS)), *join])
    for host, specs in HOSTS.items():
        sup.spawn(host, ["agent", *(a for s in specs for a in ("--robot", s)), *join])
    obs = Observer(mode="client", connect=[endpoint])
    burners: list[subprocess.Popen[bytes]] = []
    tally = FloodTally("estop flood")
    times: list[float] = []
    try:
        obs.wait_alive(set(ROBOTS), databank=True, sup=sup)
        for name, direction in (("flood-1", "left-high"), ("flood-2", "right-high")):
            sup.spawn(name, ["send", "all", "limb_11", "distal_11", direction, "3", "--for",
                             "3600", "--rate", "100", "--sender", name, *join])
        burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                   for _ in range(BURNERS)]
        until(lambda: any(st.status == "moving" for st in obs.states.snapshot().values()),
              WAIT_S, "the flood moving robots", guard=sup.check)
        for i in range(ROUNDS):
            sup.check()
            if i == ROUNDS // 2:
                late_robot_comes_up_latched(sup, capsys, endpoint, join, obs, tally)
            tally.sent += 1
            estop_round(capsys, endpoint, obs, tally, times)
    finally:
        for b in burners:
            b.kill()
            b.wait()
        obs.close()
    if times:
        tally.extra["confirm p50"] = f"{statistics.median(times):.2f} s"
        tally.extra["confirm p99"] = f"{sorted(times)[int(0.99 * (len(times) - 1))]:.2f} s"
    tally.report()
    assert sum(tally.codes.values()) == ROUNDS


def late_robot_comes_up_latched(sup: Supervisor, capsys: pytest.CaptureFixture[str],
                                endpoint: str, join: list[str], obs: Observer,
                                tally: FloodTally) -> None:
    """An e-stop in force, then a robot starts: its first state is latched in the officer's
    name; the release reaches it too. It leaves before the next round (eight robots)."""
    capsys.readouterr()
    assert main(["estop", "--mode", "client", "--connect", endpoint, "--sender", OFFICER,
                 "--timeout", "5"]) in (0, 1)
    capsys.readouterr()
    watch = StateWatch(obs.session, "late-1")
    try:
        sup.spawn("late", ["agent", "khepera", "--id", "late-1", *join])
        watch.wait(lambda st: True, "the late robot's first state")
        first = watch.states[0]
        assert first.status == "estop" and first.estop_by == OFFICER, first
    finally:
        watch.close()
    tally.extra["started during an e-stop, came up latched"] = "yes"
    assert main(["estop", "--release", "--target", "all", "--mode", "client", "--connect",
                 endpoint, "--sender", OFFICER]) == 0
    capsys.readouterr()
    until(lambda: getattr(obs.states.last("late-1"), "status", "") != "estop", WAIT_S,
          "the late robot released")
    sup.stop("late")
    until(lambda: "late-1" not in obs.alive.robots, WAIT_S, "the late robot gone")
    obs.states.tracks.pop("late-1", None)
