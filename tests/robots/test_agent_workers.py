"""A fleet host on every core: robots dealt to worker processes (``workers.py``).

The robots of a worker must stay robots of their own: each obeys its commands whichever worker
runs it, an e-stop reaches every worker's robots, and a worker killed takes its own robots'
liveliness with it and nothing else. Real processes (``kinesphere fleet --workers 2``), real
Zenoh through a hub, the real databank, MuJoCo bodies.
"""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path

import psutil
import pytest

from kinesphere import zconfig
from kinesphere.cli import main
from kinesphere.deploy.watch import watch_alive
from kinesphere.errors import KinesphereError
from kinesphere.protocol import SpatialCommand
from kinesphere.robots.agent.fleet import RobotSpec
from kinesphere.robots.agent.workers import check_listen, deal, share, worker_flag
from support.agents import (
    AckWatch,
    CommandSender,
    DatabankProcess,
    StateWatch,
    far,
    joints_close,
    robots_alive,
)
from support.network import KEYS, Hub
from support.paths import ROOT
from support.wait import WAIT_S

ROBOTS = {"w-baxter": "baxter", "w-nao": "nao", "w-youbot": "youbot", "w-khepera": "khepera"}


def test_robots_are_dealt_by_platform_and_a_worker_checks_its_share() -> None:
    robots = [RobotSpec(p, f"{p}-{i}") for i in range(3) for p in ("nao", "baxter", "youbot")]
    shares = deal(robots, 2)
    assert sorted(r.robot_id for s in shares for r in s) == sorted(r.robot_id for r in robots)
    for s in shares:  # a like mix: every platform in each share, by at most one more
        counts = [sum(r.platform == p for r in s) for p in ("nao", "baxter", "youbot")]
        assert min(counts) >= 1 and max(counts) - min(counts) <= 1, counts
    assert [len(s) for s in deal(robots[:2], 5)] == [1, 1]  # never an empty worker
    k, n, mine = share(robots, worker_flag(2, 2, robots))
    assert (k, n, mine) == (2, 2, shares[1])
    two = robots[:2]
    for some, flag, named in ((robots, worker_flag(1, 2, robots[:-1]), "edited"),
                              (robots, worker_flag(3, 2, robots), "K/N"),
                              (robots, "1/2", "K/N"),
                              (two, worker_flag(3, 3, two), "only 2 shares")):
        with pytest.raises(KinesphereError) as info:
            share(some, flag)
        assert named in info.value.message, flag
    with pytest.raises(KinesphereError, match="port 7448"):
        check_listen(["tcp/0.0.0.0:7448"], 2)
    check_listen(["tcp/0.0.0.0:7448"], 1)
    check_listen([zconfig.LOOPBACK_ANY_PORT], 4)


def test_worker_options_are_checked_before_anything_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fleet = tmp_path / "fleet.toml"
    fleet.write_text('[robots.a]\nplatform = "nao"\n[robots.b]\nplatform = "khepera"\n')
    for argv, named in ((["agent", "nao", "--workers", "2"], "for several robots"),
                        (["agent", "nao", "--physics-threads", "1"], "for several robots"),
                        (["fleet", str(fleet), "--workers", "0"], "at least 1"),
                        (["fleet", str(fleet), "--workers", "2", "--listen",
                          "tcp/127.0.0.1:7448"], "port 7448"),
                        (["fleet", str(fleet), "--worker", "1/2:" + "0" * 12], "edited")):
        assert main(argv) == 2, argv
        assert named in capsys.readouterr().err, argv


@contextmanager
def fleet_host(tmp_path: Path, endpoint: str) -> Iterator[subprocess.Popen[bytes]]:
    """``kinesphere fleet`` with two workers, stopped (and checked gone) at the end."""
    path = tmp_path / "fleet.toml"
    path.write_text("".join(f'[robots.{rid}]\nplatform = "{p}"\n' for rid, p in ROBOTS.items()))
    proc = subprocess.Popen(
        [sys.executable, "-m", "kinesphere.cli", "fleet", str(path), "--workers", "2",
         "--connect", endpoint, "--listen", zconfig.LOOPBACK_ANY_PORT, "--prefix", KEYS.prefix],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=WAIT_S)


def workers(proc: subprocess.Popen[bytes]) -> dict[int, psutil.Process]:
    """The fleet host's worker processes by their number (1-based), from their command lines."""
    found = {}
    for child in psutil.Process(proc.pid).children():
        argv = child.cmdline()
        if "--worker" in argv:
            found[int(argv[argv.index("--worker") + 1].split("/")[0])] = child
    return found


def test_workers_run_robots_of_their_own_and_one_killed_takes_only_its_robots(
    tmp_path: Path, hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    specs = [RobotSpec(p, rid) for rid, p in ROBOTS.items()]
    shares = [{r.robot_id for r in s} for s in deal(specs, 2)]
    poses = {rid: far(databank.catalogue(p), 1) for rid, p in ROBOTS.items() if p != "khepera"}
    targets = {rid: databank.query(ROBOTS[rid], SpatialCommand(*pose)).joints
               for rid, pose in poses.items()}
    alive, tokens = watch_alive(session, KEYS)
    acks = AckWatch(session, "*")
    watches = {rid: StateWatch(session, rid) for rid in ROBOTS}
    ops = {rid: CommandSender(session, rid, sender=f"op-{rid}") for rid in poses}
    try:
        with fleet_host(tmp_path, endpoint) as proc:
            robots_alive(alive, lambda ids: set(ROBOTS) <= ids, "every robot up")
            pids = workers(proc)
            assert sorted(pids) == [1, 2] and len({p.pid for p in pids.values()}) == 2

            # one robot on each worker moves, each to its own pose; a third stays where it is
            one, two = (sorted(s & set(poses))[0] for s in shares)
            idle = next(rid for rid in poses if rid not in (one, two))
            before = watches[idle].wait(lambda st: True, f"a state of {idle}")
            sent = {rid: ops[rid].send(poses[rid]) for rid in (one, two)}  # both at once
            for rid, seq in sent.items():
                watches[rid].after(seq, partial(joints_close, joints=targets[rid], tol=0.02),
                                   f"{rid} at its pose")
                acks.of(f"op-{rid}", seq, "reached")
            now = watches[idle].wait(lambda st: st.seq > before.seq + 5, f"{idle} states")
            assert (now.last_command_seq, now.status) == (-1, "idle"), now

            # an e-stop from anyone reaches every worker's robots, and each latches
            assert main(["estop", "--connect", endpoint, "--prefix", KEYS.prefix,
                         "--wait", str(WAIT_S), "--timeout", "10"]) == 0
            for rid, watch in watches.items():
                watch.wait(lambda st: st.status == "estop", f"{rid} e-stopped")
            assert main(["estop", "--release", "--target", "all", "--connect", endpoint,
                         "--prefix", KEYS.prefix, "--wait", str(WAIT_S),
                         "--timeout", "10"]) == 0

            # a worker killed takes its own robots' liveliness, and only theirs
            pids[1].send_signal(signal.SIGKILL)
            pids[1].wait(WAIT_S)
            left = robots_alive(alive, lambda ids: not ids & shares[0],
                                "the killed worker's robots gone")
            assert shares[1] <= left, left
            assert proc.poll() is None, "the fleet host stops with its first worker"
            other = far(databank.catalogue(ROBOTS[two]), 0)  # the other worker's still obey
            target = databank.query(ROBOTS[two], SpatialCommand(*other)).joints
            seq = ops[two].send(other)
            watches[two].after(seq, lambda st: joints_close(st, target, 0.02),
                               f"{two} at another pose")

            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=WAIT_S)
            assert proc.returncode == 1, err.decode(errors="replace")[-2000:]
            assert "worker 1/2 exited with code -9" in err.decode(errors="replace")
            robots_alive(alive, lambda ids: not ids & set(ROBOTS), "every robot gone")
            assert not pids[2].is_running() or pids[2].status() == psutil.STATUS_ZOMBIE
    finally:
        for op in ops.values():
            op.close()
        for w in watches.values():
            w.close()
        acks.close()
        zconfig.undeclare(*tokens)
