"""A fleet host: robots of several platforms in one process, one loop, one Zenoh session.

Each robot must stay a robot of its own: obey only its commands, keep its own e-stop latch,
state stream and acks, and be held alone when its body fails. Real Zenoh, the real databank,
MuJoCo bodies stepped by the fleet's loop (physics on a helper thread as in deployment).
"""

from __future__ import annotations

import signal
import subprocess
import sys
from contextlib import ExitStack
from functools import partial
from pathlib import Path

import numpy as np
import pytest

from kinesphere import zconfig
from kinesphere.cli import main
from kinesphere.deploy.watch import watch_alive
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.mjcf import platform_model
from kinesphere.protocol import Ack, SpatialCommand
from kinesphere.robots.agent.fleet import (
    FleetHost,
    RobotSpec,
    check_fleet,
    load_fleet_file,
    parse_robot,
)
from kinesphere.robots.agent.mujoco_body import MujocoBody
from kinesphere.robots.agent.runtime import AgentOptions
from kinesphere.services.ecl.measure import Fk, angle_deg
from support.agents import (
    AckWatch,
    CommandSender,
    DatabankProcess,
    far,
    joints_close,
    newer_than,
    robots_alive,
    running_fleet_host,
)
from support.files import refused
from support.network import KEYS, Hub
from support.paths import ROOT
from support.wait import WAIT_S

ROBOTS = [RobotSpec("baxter", "f-baxter"), RobotSpec("nao", "f-nao"),
          RobotSpec("youbot", "f-youbot", ("bases",))]


def _ack_at(robot_id: str, stage: str, ack: Ack) -> bool:
    return (ack.robot_id, ack.stage) == (robot_id, stage)


def test_robots_of_several_platforms_obey_their_own_commands(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    poses = {r.robot_id: far(databank.catalogue(r.platform), i % 2)
             for i, r in enumerate(ROBOTS)}
    targets = {r.robot_id: databank.query(r.platform, SpatialCommand(*poses[r.robot_id])).joints
               for r in ROBOTS}
    with running_fleet_host(endpoint, ROBOTS) as (fleet, watches), ExitStack() as stack:
        assert fleet.stepper.threads == 2
        start = {rid: w.states[-1] for rid, w in watches.items()}
        ops = {r.robot_id: stack.enter_context(
            CommandSender(session, r.robot_id, sender=f"op-{r.robot_id}")) for r in ROBOTS}
        # one robot moves; the others, stepped by the same loop, do not
        first = ROBOTS[0].robot_id
        seq = ops[first].send(poses[first])
        watches[first].after(seq, lambda st: joints_close(st, targets[first], 0.02),
                             f"{first} at its pose")
        for rid in watches.keys() - {first}:
            now = watches[rid].wait(partial(newer_than, start[rid].seq + 5), f"{rid} states")
            assert (now.last_command_seq, now.status) == (-1, "idle"), (rid, now)
        # each robot reaches its own pose for its own command
        for rid, op in ops.items():
            seq = op.send(poses[rid])
            watches[rid].after(seq, partial(joints_close, joints=targets[rid], tol=0.02),
                               f"{rid} at its pose")
        # a group command reaches its member only
        group = stack.enter_context(
            CommandSender(session, key=KEYS.group_command("bases"), sender="grp"))
        seq = group.send(poses[first], stop=True)
        watches["f-youbot"].after(seq, lambda st: st.status == "stopped", "youbot stopped")
        assert watches["f-baxter"].states[-1].status != "stopped"


def test_one_robots_estop_does_not_stop_the_others(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    robots = ROBOTS[:2]
    cats = {r.robot_id: databank.catalogue(r.platform) for r in robots}
    stopped, other = (r.robot_id for r in robots)
    with (AckWatch(session, "*") as acks,
          running_fleet_host(endpoint, robots) as (_fleet, watches),
          CommandSender(session, stopped, sender="op-s") as op_s,
          CommandSender(session, other, sender="op-o") as op_o):
        seq = op_s.send(estop=True)
        acks.of("op-s", seq, "estopped")
        watches[stopped].after(seq, lambda st: st.status == "estop" and st.estop_by == "op-s",
                               "the e-stop latched")
        pose = far(cats[other], 1)
        target = databank.query("nao", SpatialCommand(*pose)).joints
        seq_o = op_o.send(pose)
        watches[other].after(seq_o, lambda st: joints_close(st, target, 0.02),
                             "the other robot moving to its pose")
        acks.of("op-o", seq_o, "reached")
        refused = op_s.send(far(cats[stopped], 1))
        ack = acks.of("op-s", refused, "rejected")
        assert ack.code == "estopped"
        assert watches[stopped].states[-1].status == "estop"
        assert watches[other].states[-1].estop_by == ""


class CrashingMujocoBody(MujocoBody):
    """A MuJoCo body whose physics fails after ``ok`` steps (a crashed simulator)."""

    def __init__(self, platform: str, dt: float, ok: int) -> None:
        super().__init__(platform_model(platform), dt)
        self.left = ok

    def simulate(self) -> None:
        self.left -= 1
        if self.left < 0:
            raise RuntimeError("simulator crashed")
        super().simulate()


def test_a_failing_body_holds_its_robot_alone(hub: Hub) -> None:
    _session, endpoint = hub
    robots = [RobotSpec("youbot", "f-fail"), RobotSpec("khepera", "f-fine")]
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        fleet = FleetHost(robots, s, AgentOptions(speed=0.0), helpers=1)
        bad, fine = fleet.agents
        bad.controller.body = CrashingMujocoBody("youbot", bad.controller.dt, ok=50)
        fleet.declare()
        try:
            for _ in range(200):
                fleet.tick()
            fleet.complete()  # the last tick's physics ran on the helper: finish it
            status, detail = bad.status()
            assert status == "error" and "simulator crashed" in detail
            assert fine.status()[0] != "error"
            assert fine.controller.steps == 200 and bad.controller.steps == 50
            assert bad.stats.steps == fine.stats.steps == fleet.stats.steps == 200
        finally:
            fleet.close()


def test_fleet_file_and_robot_arguments(tmp_path: Path) -> None:
    good = tmp_path / "fleet.toml"
    good.write_text('prefix = "lab"\n[robots.b1]\nplatform = "baxter"\ngroups = ["arms"]\n'
                    '[robots.y1]\nplatform = "youbot"\n')
    robots, prefix = load_fleet_file(good)
    assert prefix == "lab"
    assert robots == [RobotSpec("baxter", "b1", ("arms",)), RobotSpec("youbot", "y1")]
    assert parse_robot("nao:nao-7") == RobotSpec("nao", "nao-7")
    assert parse_robot("khepera") == RobotSpec("khepera", "khepera")
    cases = {
        '[robots.b1]\nplatform = "baxter"\nspeed = 3\n': "speed",
        '[robots.b1]\ngroups = ["a"]\n': "platform",
        "robots = 3\n": "robots",
        "[robots.b1\n": "fleet file",
    }
    for text, named in cases.items():
        assert named in refused(load_fleet_file, tmp_path, text).message, text
    with pytest.raises(KinesphereError, match="no such file|No such file"):
        load_fleet_file(tmp_path / "missing.toml")
    for robots, named in (([], "at least one"),
                          ([RobotSpec("nao", "a"), RobotSpec("baxter", "a")], "twice"),
                          ([RobotSpec("nao", "a/b")], "'/'"),
                          ([RobotSpec("nao", "x" * 65)], "at most 64"),
                          ([RobotSpec("nao", "n", ("g*",))], "group")):
        with pytest.raises(KinesphereError) as info:
            check_fleet(robots)
        assert named in info.value.message
    with pytest.raises(KinesphereError, match="PLATFORM:ID"):
        parse_robot("nao:")


@pytest.mark.processes
def test_fleet_command_runs_every_robot_and_stops_on_sigterm(
    tmp_path: Path, hub: Hub
) -> None:
    session, endpoint = hub
    fleet = tmp_path / "fleet.toml"
    fleet.write_text('[robots.cli-y]\nplatform = "youbot"\n[robots.cli-k]\nplatform = "khepera"\n')
    alive, tokens = watch_alive(session, KEYS)
    try:
        for argv, ids in ((["fleet", str(fleet)], {"cli-y", "cli-k"}),
                          (["agent", "--robot", "youbot:arg-y", "--robot", "khepera:arg-k"],
                           {"arg-y", "arg-k"})):
            proc = subprocess.Popen(
                [sys.executable, "-m", "kinesphere.cli", *argv, "--connect", endpoint,
                 "--listen", zconfig.LOOPBACK_ANY_PORT],
                cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            try:
                robots_alive(alive, ids.issubset, f"{argv[0]}'s robots up")
            finally:
                proc.send_signal(signal.SIGTERM)
                _, err = proc.communicate(timeout=WAIT_S)
            assert proc.returncode == 0, err.decode(errors="replace")[-2000:]
            robots_alive(alive, ids.isdisjoint, f"{argv[0]}'s robots gone")
    finally:
        zconfig.undeclare(*tokens)


@pytest.mark.processes
def test_fleet_command_line_errors(tmp_path: Path) -> None:
    def run(*argv: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "kinesphere.cli", *argv], cwd=ROOT,
                              capture_output=True, text=True, timeout=WAIT_S)

    dup = tmp_path / "dup.toml"
    dup.write_text('[robots.a]\nplatform = "nao"\ngroups = ["x/y"]\n')
    for argv, named in ((["fleet", str(dup)], "may not contain"),
                        (["fleet", str(tmp_path / "none.toml")], "fleet file"),
                        (["agent", "nao", "--robot", "youbot:y"], "cannot be combined"),
                        (["agent", "--robot", "youbot:y", "--body", "ros2"], "simulated"),
                        (["agent"], "give a PLATFORM")):
        done = run(*argv)
        assert done.returncode != 0 and named in done.stderr, (argv, done.stderr)


def test_send_all_moves_every_body_exact_or_substituted(
    hub: Hub, databank: DatabankProcess, capsys: pytest.CaptureFixture[str]
) -> None:
    """A fleet command in a direction only some bodies keep: every robot moves, the others by
    the nearest direction they have, each robot reporting what it was served and how far from
    the request its pose points; that angle is where the robot's arm ends up pointing,
    measured by forward kinematics of the joints it reports."""
    session, endpoint = hub
    robots = [RobotSpec(p, f"s-{p}") for p in ("baxter", "nao", "packbot", "youbot")]
    pose = ("limb_11", "distal_11", "left-low", 3)
    answers = {r.robot_id: databank.query(r.platform, SpatialCommand(*pose)) for r in robots}
    served = {rid: [(s.requested, s.served) for s in a.substitutions]
              for rid, a in answers.items()}
    assert served == {"s-baxter": [], "s-youbot": [], "s-packbot": [],
                      "s-nao": [("left-low", "left-forward-low")]}
    left_low = np.array(Direction.LEFT_LOW.vector) / np.linalg.norm(Direction.LEFT_LOW.vector)
    with (AckWatch(session, "*") as acks,
          running_fleet_host(endpoint, robots) as (_fleet, watches)):
        assert main(["send", "all", *map(str, pose), "--connect", endpoint,
                     "--prefix", KEYS.prefix, "--wait", str(WAIT_S)]) == 0
        said = {ln.split(":")[0]: ln for ln in capsys.readouterr().out.splitlines()}
        for r in robots:
            rid, watch = r.robot_id, watches[r.robot_id]
            want = answers[rid].substitutions
            accepted = acks.wait(partial(_ack_at, rid, "accepted"), f"{rid} accepting the command")
            assert accepted.substitutions == want, rid
            angle = accepted.measured_angle
            assert angle is not None and angle == answers[rid].measured_angle, rid
            watch.wait(partial(joints_close, joints=answers[rid].joints, tol=0.02),
                       f"{rid} at its {answers[rid].direction} pose")
            acks.wait(partial(_ack_at, rid, "reached"), f"{rid} reaching its pose")
            moving = [st.substitutions for st in watch.states if st.status == "moving"]
            assert moving and all(subs == want for subs in moving), rid
            st = watch.states[-1]
            offset = Fk(platform_model(r.platform)).offset(
                "limb_11", "distal_11", dict(zip(st.joint_names, st.q, strict=True)))
            assert angle_deg(offset, left_low) == pytest.approx(angle, abs=2.0), rid
            pointing = f"pointing {angle:.0f}° from the request (measured)"
            assert (pointing in said[rid]) == bool(want), said[rid]
