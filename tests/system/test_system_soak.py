"""The closed loop under load: two operators, four robots, the databank killed and restarted
twice, e-stops in between (issue 11's soak; bounded, loopback).

``kinesphere up``'s topology (a router child serving nothing else, everything its clients).
Operator A streams to robots 1 and 2, operator B to robots 3 and 4 (arm poses through the
databank on the youBot and the PackBot, drives on the Kheperas), each now and then trying a
robot the other holds. Twice a third operator who holds no lease runs ``kinesphere estop``
(which waits for every robot's ack and exits 0 only when each latched) and then ``kinesphere
estop --release --target all``. Counted: commands sent, acked (any stage), lost (no ack at
all); refusals by code; e-stops and releases sent and acked by every robot; state samples of
a robot moving without a lease holder (must be 0). ``make soak`` runs it SCALE times longer.
"""

from __future__ import annotations

import random
import threading
import time
import uuid
from collections import Counter, defaultdict

import pytest
import zenoh

from kinesphere import protocol as pr
from kinesphere.cli import main
from kinesphere.deploy.hub import client_args, start_hub
from kinesphere.deploy.watch import StateRecorder, watch_alive
from kinesphere.keyexpr import KEYS
from kinesphere.procs import Supervisor
from kinesphere.query import get_one
from kinesphere.zconfig import close_session, undeclare
from support.soak import SCALE, FloodTally
from support.system import databank_args
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

ROBOTS = {"yb": "youbot", "k1": "khepera", "pb": "packbot", "k2": "khepera"}
HOLDS = {"A": ("yb", "k1"), "B": ("pb", "k2")}
DURATION_S = 14.0 * SCALE
RATE_HZ = 10.0
TTL_MS = 600
ACK_WAIT_S = 10.0
"""After the run: how long a command may still be waiting for its ack before it is lost."""
OFFICER = "soak-officer"
"""The third operator, who holds no lease and e-stops everyone with ``kinesphere estop``."""


class AckLedger:
    """(sender, session, seq) -> robot -> stages heard; and every ack, in order."""

    def __init__(self, session: zenoh.Session) -> None:
        self.heard: list[pr.Ack] = []
        self.by_cmd: dict[tuple[str, str, int], dict[str, list[pr.Ack]]] = defaultdict(
            lambda: defaultdict(list))
        self.lock = threading.Lock()
        self.changed = threading.Condition(self.lock)
        self._sub = session.declare_subscriber(KEYS.ack("*"), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        ack = pr.decode(sample.payload.to_bytes(), pr.Ack)
        with self.changed:
            self.heard.append(ack)
            self.by_cmd[(ack.sender, ack.session, ack.seq)][ack.robot_id].append(ack)
            self.changed.notify_all()

    def of(self, sender: str, session: str, seq: int) -> dict[str, list[pr.Ack]]:
        with self.lock:
            return {r: list(a) for r, a in self.by_cmd.get((sender, session, seq), {}).items()}

    def robots_since(self, mark: int, sender: str, stage: pr.AckStage) -> set[str]:
        """Robots that acked ``stage`` to ``sender`` after the first ``mark`` acks heard."""
        with self.lock:
            return {a.robot_id for a in self.heard[mark:]
                    if a.sender == sender and a.stage == stage}

    def mark(self) -> int:
        with self.lock:
            return len(self.heard)

    def close(self) -> None:
        undeclare(self._sub)


class SoakOperator:
    """One operator's client: a sender, a session, and every command it sent (seq -> robots)."""

    def __init__(self, name: str, session: zenoh.Session) -> None:
        self.sender = f"soak-{name}"
        self.session_id = uuid.uuid4().hex[:12]
        self.z = session
        self.seq = 0
        self.sent: dict[int, tuple[str, ...]] = {}
        self.kind: dict[int, str] = {}

    def put(self, robots: tuple[str, ...], kind: str, *,
            parts: list[pr.SpatialCommand] | None = None, drive: pr.Drive | None = None,
            deadman: bool = True, stop: bool = False) -> int:
        self.seq += 1
        cmd = pr.Command(seq=self.seq, sent_ns=time.time_ns(), ttl_ms=TTL_MS,
                         sender=self.sender, session=self.session_id, deadman=deadman,
                         parts=parts or [], drive=drive, stop=stop)
        keys = [KEYS.command("*")] if len(robots) == len(ROBOTS) else [KEYS.command(r)
                                                                          for r in robots]
        for key in keys:
            self.z.put(key, pr.encode(cmd))
        self.sent[self.seq] = robots
        self.kind[self.seq] = kind
        return self.seq


def arm_poses(session: zenoh.Session, platform: str) -> list[pr.SpatialCommand]:
    """A few real arm poses from the platform's catalogue (the first limb entry)."""
    cat = get_one(session, KEYS.catalogue(platform), pr.Catalogue, timeout=WAIT_S)
    entry = next(e for e in cat.limbs if len(e.directions) >= 3)
    return [pr.SpatialCommand(entry.limb, entry.origin, d, float(s))
            for d in entry.directions[:3] for s in entry.sizes[:2]]



def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    """A client command run in-process (as an operator types it): exit code and stdout."""
    capsys.readouterr()
    code = main(list(argv))
    return code, capsys.readouterr().out


def estop_round(capsys: pytest.CaptureFixture[str], acks: AckLedger, endpoint: str,
                listed: list[int]) -> int:
    """The officer's ``kinesphere estop`` then ``estop --release --target all``; both must
    exit 0 with a line per robot, and every robot must ack each (heard here). Robots that
    acked both; ``listed`` gets how many robots ``estop`` printed (it may print fewer when it
    settles before a robot's liveliness reached it: counted, not hidden), then how many
    ``estop --release`` printed."""
    common = ("--connect", endpoint, "--mode", "client", "--sender", OFFICER,
              "--timeout", str(WAIT_S))
    mark = acks.mark()
    code, out = run_cli(capsys, "estop", *common)
    assert code == 0, out
    lines = dict(line.split(": ", 1) for line in out.splitlines())
    assert set(lines) <= set(ROBOTS) and all(v.startswith("estopped") for v in lines.values()), out
    listed.append(len(lines))  # 4, or the client missed a live robot (reported)
    until(lambda: acks.robots_since(mark, OFFICER, pr.AckStage.ESTOPPED) >= set(ROBOTS),
          WAIT_S, "every robot's e-stop ack to reach the test too")
    stopped = acks.robots_since(mark, OFFICER, pr.AckStage.ESTOPPED)
    mark = acks.mark()
    code, out = run_cli(capsys, "estop", "--release", "--target", "all", *common)
    assert code == 0, out
    lines = dict(line.split(": ", 1) for line in out.splitlines())
    assert set(lines) <= set(ROBOTS) and all(v.startswith("released") for v in lines.values()), out
    listed.append(len(lines))
    until(lambda: acks.robots_since(mark, OFFICER, pr.AckStage.RELEASED) >= set(ROBOTS),
          WAIT_S, "every robot's release ack to reach the test too")
    return len(stopped & acks.robots_since(mark, OFFICER, pr.AckStage.RELEASED))


def test_two_operators_four_robots_and_a_restarting_databank(
    sup: Supervisor, capsys: pytest.CaptureFixture[str]
) -> None:
    endpoint, z = start_hub(sup, WAIT_S)
    dbs = databank_args(sorted(set(ROBOTS.values())))
    recorder = StateRecorder(KEYS, history=False)
    alive, subs = watch_alive(z, KEYS)
    acks = AckLedger(z)
    unleased: Counter[str] = Counter()

    def watch_lease(sample: zenoh.Sample) -> None:
        recorder.on_sample(sample)
        st = recorder.snapshot().get(KEYS.robot_id_of(str(sample.key_expr)))
        if st is not None and st.status == "moving" and not st.lease_holder:
            unleased[st.robot_id] += 1

    states = z.declare_subscriber(KEYS.state("*"), watch_lease)
    try:
        db_n = 0

        def start_databank() -> None:
            nonlocal db_n
            db_n += 1
            sup.spawn("databank", ["databank", "serve", *dbs, "--replica", f"soak-{db_n}",
                                   *client_args(endpoint)])

        start_databank()
        for rid, platform in ROBOTS.items():
            sup.spawn(f"agent-{rid}", ["agent", platform, "--id", rid, "--control-rate", "250",
                                       *client_args(endpoint)])
        until(lambda: set(ROBOTS) <= alive.robots and bool(alive.databanks)
              and set(ROBOTS) <= set(recorder.snapshot()),
              WAIT_S * 2, "the databank and four robots", guard=sup.check)
        poses = {r: arm_poses(z, ROBOTS[r]) for r in ("yb", "pb")}
        ops = {name: SoakOperator(name, z) for name in HOLDS}
        rng = random.Random(11)
        restarts = [DURATION_S / 3, 2 * DURATION_S / 3]
        estops = [DURATION_S / 4, 3 * DURATION_S / 4]
        events: Counter[str] = Counter()
        estopped: list[int] = []  # per e-stop round: robots that acked the e-stop and release
        listed: list[int] = []  # robots printed by each `estop` and `estop --release`
        start = time.monotonic()
        tick = 0
        while (now := time.monotonic() - start) < DURATION_S:
            sup.check()
            if restarts and now >= restarts[0]:
                restarts.pop(0)
                sup.kill("databank")
                until(lambda: not alive.databanks, WAIT_S, "the killed databank's token to go")
                start_databank()
                events["databank restarts"] += 1
            if estops and now >= estops[0]:
                estops.pop(0)
                estopped.append(estop_round(capsys, acks, endpoint, listed))
            for name, op in ops.items():
                held = HOLDS[name]
                robot = held[tick % 2]
                if rng.random() < 0.15:  # try a robot the other operator holds
                    other = next(n for n in HOLDS if n != name)
                    robot = HOLDS[other][tick % 2]
                    events["attempts on the other's robot"] += 1
                if robot in poses:  # a new size now and then: the databank must answer it
                    part = rng.choice(poses[robot])
                    if rng.random() < 0.3:
                        part = pr.SpatialCommand(part.limb, part.origin, part.direction,
                                                 round(rng.uniform(1.0, 2.0), 3))
                    op.put((robot,), "pose", parts=[part])
                else:
                    op.put((robot,), "drive", drive=pr.Drive(
                        "forward-middle", 0.2, forward=rng.uniform(-0.3, 0.3),
                        yaw=rng.uniform(-0.3, 0.3)))
            tick += 1
            recorder.wait_for(lambda _s: False, 1.0 / RATE_HZ)  # the operators' stream rate
        for name, op in ops.items():  # let go
            op.put(HOLDS[name], "stop", deadman=False, stop=True)

        # every command acked by every robot it addressed, or lost
        deadline = time.monotonic() + ACK_WAIT_S
        tally = FloodTally("closed loop (2 operators, 4 robots, databank restarted twice)")
        stages: Counter[str] = Counter()
        lost: list[tuple[str, int, str]] = []
        for op in ops.values():
            for seq, robots in op.sent.items():
                for robot in robots:
                    tally.sent += 1
                    got = acks.of(op.sender, op.session_id, seq)
                    while robot not in got and time.monotonic() < deadline:
                        with acks.changed:
                            acks.changed.wait(0.1)
                        got = acks.of(op.sender, op.session_id, seq)
                    if robot not in got:
                        lost.append((op.sender, seq, robot))
                        tally.add("lost")
                        continue
                    tally.add("acked")
                    for a in got[robot]:
                        stages[a.code or str(a.stage)] += 1
        tally.extra = {
            "acks by stage or code": dict(sorted(stages.items())),
            "e-stops sent (kinesphere estop)": len(estopped),
            "robots that acked the e-stop and its release": sum(estopped),
            "robots listed by kinesphere estop / --release": f"{sum(listed[0::2])} / "
                                                              f"{sum(listed[1::2])} of "
                                                              f"{len(ROBOTS) * len(estopped)}",
            "robots moved without a lease": sum(unleased.values()),
            **events,
        }
        with capsys.disabled():
            tally.report()
        assert events["databank restarts"] == 2 and estopped == [len(ROBOTS)] * 2
        assert not lost, f"{len(lost)} commands never acked, e.g. {lost[:5]}"
        assert sum(unleased.values()) == 0, unleased
        assert stages["lease_held"] > 0 and stages["accepted"] > 0, stages
    finally:
        undeclare(states, *subs)
        acks.close()
        close_session(z)
