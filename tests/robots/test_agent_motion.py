"""The agent's motion pieces without the network: Ruckig joints, the planar bases, safety rules.

These pin down the properties the end-to-end tests rely on, quickly and deterministically.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial

import msgspec
import numpy as np
import pytest

from kinesphere import zconfig
from kinesphere.errors import KinesphereError
from kinesphere.eurdf import JointLimit
from kinesphere.platforms.platform import BaseSpec
from kinesphere.protocol import Command, Drive
from kinesphere.robots.agent.base import (
    BaseController,
    DiffBase,
    OmniBase,
    make_base,
    wrap_angle,
)
from kinesphere.robots.agent.bodies import make_body
from kinesphere.robots.agent.controller import Controller
from kinesphere.robots.agent.options import DEFAULT_MARGIN
from kinesphere.robots.agent.otg import Otg
from kinesphere.robots.agent.runtime import SETTLE_S, Agent, AgentOptions
from kinesphere.robots.agent.safety import DRIVE_TTL_S, Safety, Verdict
from kinesphere.robots.agent.trajectory import JointTrajectory

DT = 0.002
ACC, JERK = 4.0, 40.0
LIMITS = [
    JointLimit("a", "revolute", -1.0, 1.0, 1.5),
    JointLimit("b", "revolute", -2.0, 2.0, 3.0),
    JointLimit("c", "continuous", -math.inf, math.inf, math.inf),
]


def run(traj: JointTrajectory, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pos, vel, acc = [], [], []
    for _ in range(steps):
        traj.step()
        pos.append(traj.position.copy())
        vel.append(traj.velocity.copy())
        acc.append(traj.acceleration.copy())
    return np.array(pos), np.array(vel), np.array(acc)


def test_retarget_mid_motion_is_continuous_and_jerk_limited() -> None:
    traj = JointTrajectory(LIMITS, ACC, JERK, DT, [0.0, 0.0, 0.0])
    traj.retarget({"a": 0.9, "b": -1.5, "c": 4.0})
    p1, v1, a1 = run(traj, 150)
    assert np.abs(v1[-1]).max() > 0.5, "should be well under way"
    traj.retarget({"a": -0.8, "c": -3.0})  # b keeps its target
    p2, v2, a2 = run(traj, 3000)
    pos, vel, acc = np.vstack([p1, p2]), np.vstack([v1, v2]), np.vstack([a1, a2])
    assert not traj.moving
    np.testing.assert_allclose(traj.position, [-0.8, -1.5, -3.0], atol=1e-9)
    jerk = np.abs(np.diff(acc, axis=0)) / DT
    assert jerk.max() <= JERK * (1 + 1e-6)
    assert np.abs(np.diff(vel, axis=0)).max() <= ACC * DT * (1 + 1e-6)  # no velocity jump
    assert np.abs(acc).max() <= ACC * (1 + 1e-6)
    vmax = np.array([1.5, 3.0, 1.0])  # c has no eURDF velocity: the default applies
    assert (np.abs(vel) <= vmax * (1 + 1e-6)).all()
    assert (pos[:, 0] <= 1.0).all() and (pos[:, 0] >= -1.0).all()


def off_the_line(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """The farthest any of ``points`` lies from the straight line through ``a`` and ``b``."""
    d = (b - a) / np.linalg.norm(b - a)
    rel = points - a
    return float(np.max(np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)))


def test_straight_moves_one_after_another_each_keep_to_their_line() -> None:
    """The guard checks the straight joint-space way from where the joints rest to the goal:
    a straight move that Ruckig can phase-synchronise (here one velocity limit for all joints)
    travels that line, the second and third as the first (a move that ended left ~1e-16 rad/s
    in Ruckig's input, so the next fell back to time synchronisation, off its line)."""
    even = [JointLimit(lim.name, lim.kind, lim.lower, lim.upper, 2.0) for lim in LIMITS]
    traj = JointTrajectory(even, ACC, JERK, DT, [0.0, 0.0, 0.0])
    for goal in ({"a": 0.9, "b": -1.5, "c": 0.4}, {"a": -0.7, "b": 1.2, "c": -0.3},
                 {"a": 0.2, "b": 1.9, "c": 2.0}):
        start = traj.position.copy()
        traj.retarget(goal, straight=True)
        pos, _, _ = run(traj, 3000)
        assert not traj.moving
        end = np.array(list(goal.values()))
        np.testing.assert_allclose(traj.position, end, atol=1e-9)
        assert off_the_line(pos, start, end) < 1e-9, goal


@pytest.mark.parametrize("brake_after", [0.1, 0.5, 5.0])
def test_the_course_ahead_is_where_the_steps_go_when_they_brake_then(brake_after: float) -> None:
    """What the guard checks before a move's first step: the positions the joints take if
    they brake ``brake_after`` s from now, as the steps then take them (to rest where the
    brake ends; past the plan's end, the plan's end), mid-motion too."""
    traj = JointTrajectory(LIMITS, ACC, JERK, DT, [0.0, 0.0, 0.0])
    traj.retarget({"a": 0.9, "b": -1.5, "c": 2.0})
    run(traj, 100)
    traj.retarget({"a": -0.6, "b": 1.0})
    course = traj.course(brake_after, 0.02)
    steps = round(brake_after / DT)
    pos, _, _ = run(traj, steps)
    for k, q in enumerate(course[:-1]):  # every 0.02 s, as the steps went (up to the brake)
        if 0 < k * 0.02 <= brake_after + 1e-9 and round(k * 0.02 / DT) <= len(pos):
            np.testing.assert_allclose(q, pos[round(k * 0.02 / DT) - 1], atol=1e-9)
    if traj.moving:
        traj.stop()
        while traj.moving:
            traj.step()
    np.testing.assert_allclose(course[-1], traj.position, atol=1e-9)


def test_targets_are_clamped_with_margin_and_reported() -> None:
    traj = JointTrajectory(LIMITS, ACC, JERK, DT, [0.0, 0.0, 0.0])
    clamps = traj.retarget({"a": 1.7, "b": 0.5})
    assert [c.joint for c in clamps] == ["a"]
    assert clamps[0].target == pytest.approx(1.0 - DEFAULT_MARGIN)
    assert set(traj.clamped) == {"a"}
    run(traj, 2000)
    assert traj.position[0] == pytest.approx(1.0 - DEFAULT_MARGIN)
    traj.retarget({"a": 0.0})
    assert not traj.clamped
    at_limit = traj.retarget({"b": 2.0})  # a pose at a limit: moved off it, not "clamped"
    assert at_limit[0].target == pytest.approx(2.0 - DEFAULT_MARGIN) and not at_limit[0].beyond
    assert not traj.clamped
    with pytest.raises(KeyError):
        traj.retarget({"nope": 0.0})
    with pytest.raises(ValueError):
        traj.retarget({"a": math.nan})
    assert traj.target[0] == 0.0


def test_a_compiled_aim_moves_exactly_like_the_joints_it_came_from() -> None:
    """The agent aims cached poses through :class:`Aim` (vectors): same clamps, same report,
    same Ruckig output step by step as the mapping itself; bad input is refused alike."""
    request = {"b": 2.5, "a": -0.4}  # b beyond its limit, a inside
    by_map = JointTrajectory(LIMITS, ACC, JERK, DT, [0.3, 0.0, 1.0])
    by_aim = JointTrajectory(LIMITS, ACC, JERK, DT, [0.3, 0.0, 1.0])
    aim = by_aim.aim(request)
    assert aim.names == ("b", "a") and aim.index.tolist() == [1, 0]
    assert by_map.retarget(request) == by_aim.retarget(aim)
    assert set(by_aim.clamped) == set(by_map.clamped) == {"b"}
    for _ in range(400):
        by_map.step()
        by_aim.step()
        assert by_aim.position.tolist() == by_map.position.tolist()
    assert by_aim.target.tolist() == by_map.target.tolist()
    assert by_aim.target[2] == 1.0  # a joint the pose does not name keeps its target
    with pytest.raises(KeyError):
        by_aim.aim({"nope": 0.0})
    with pytest.raises(ValueError):
        by_aim.aim({"a": math.inf})


def test_stop_brakes_in_place_within_limits() -> None:
    traj = JointTrajectory(LIMITS, ACC, JERK, DT, [0.0, 0.0, 0.0])
    traj.retarget({"a": -0.9, "b": 1.9})
    run(traj, 200)
    moving_at = traj.position.copy()
    traj.stop()
    _, vel, acc = run(traj, 1000)
    assert not traj.moving
    assert np.abs(vel[-1]).max() == 0.0
    assert np.abs(np.diff(acc, axis=0)).max() / DT <= JERK * (1 + 1e-6)
    np.testing.assert_allclose(traj.target[:2], traj.position[:2])
    assert abs(traj.position[0]) > abs(moving_at[0])  # it braked, it did not go back


OMNI = BaseSpec("omni", 0.1, max_speed=0.8, max_yaw_rate=1.0, max_acceleration=1.0, max_jerk=5.0)
DIFF = BaseSpec("diff", 0.1, max_speed=0.5, max_yaw_rate=2.0, max_acceleration=1.0, max_jerk=5.0)


def drive_base(base: BaseController, steps: int) -> np.ndarray:
    twists = []
    for _ in range(steps):
        base.step()
        twists.append(base.twist.copy())
    return np.array(twists)


def test_omni_translation_is_straight_in_the_body_frame_of_the_command() -> None:
    base = make_base(OMNI, DT)
    assert isinstance(base, OmniBase)
    base.translate([0.3, 0.4, 0.0], yaw=math.pi / 2)  # body x is world y
    twists = drive_base(base, 3000)
    assert not base.moving
    np.testing.assert_allclose(base.pose, [-0.4, 0.3, 0.0], atol=1e-9)
    speed = np.hypot(twists[:, 0], twists[:, 1])
    assert speed.max() <= OMNI.max_speed * (1 + 1e-6)
    moving = speed > 1e-6  # straight line: the velocity keeps one direction
    heading = np.arctan2(twists[moving, 1], twists[moving, 0])
    assert np.ptp(heading) < 1e-6


def test_omni_drive_cruises_until_stopped_then_brakes() -> None:
    base = make_base(OMNI, DT)
    assert base is not None
    base.drive((0.0, 1.0), 0.5)
    twists = drive_base(base, 1500)
    assert twists[-1][1] == pytest.approx(0.4)
    assert base.driving and base.moving
    base.stop()
    twists = np.vstack([twists, drive_base(base, 1500)])
    assert not base.moving and not base.driving
    assert np.abs(np.diff(twists, axis=0)).max() <= OMNI.max_acceleration * DT * (1 + 1e-6)


@pytest.mark.parametrize(("dx", "dy", "yaw"), [(0.0, 0.3, math.pi / 2), (-0.2, 0.0, 0.0),
                                               (-0.2, 0.2, -math.pi / 4)])
def test_diff_base_turns_then_drives(dx: float, dy: float, yaw: float) -> None:
    base = make_base(DIFF, DT)
    assert isinstance(base, DiffBase)
    base.translate([dx, dy, 0.0])
    drive_base(base, 6000)
    assert not base.moving
    np.testing.assert_allclose(base.pose[:2], [dx, dy], atol=1e-6)
    assert wrap_angle(base.pose[2] - yaw) == pytest.approx(0.0, abs=1e-6)


def test_diff_drive_lateral_component_turns() -> None:
    base = make_base(DIFF, DT)
    assert base is not None
    base.drive((0.0, 1.0), 1.0)  # "left" on a tank: turn left in place
    drive_base(base, 1000)
    assert base.twist[2] == pytest.approx(DIFF.max_yaw_rate)
    assert np.hypot(*base.pose[:2]) < 1e-9


def test_ruckig_failures_become_a_braked_hold_with_a_reason() -> None:
    otg = Otg(3, DT, [0.8] * 3, [1.0] * 3, [5.0] * 3)
    otg.go_to([1e4, 0.0, 0.0])  # longer than Ruckig allows: the binding raises ValueError
    assert otg.step() and "longer than Ruckig allows" in otg.fault
    assert not otg.active and otg.position.tolist() == otg.target.tolist() == [0.0] * 3
    otg.go_to([1e8, 0.0, 0.0])  # the binding raises RuckigError
    assert otg.step() and "ruckig cannot plan" in otg.fault and not otg.active
    otg.go_to([0.5, 0.0, 0.0])
    assert not otg.fault, "a new target clears the fault"

    base = make_base(OMNI, DT)
    assert isinstance(base, OmniBase)
    base.drive((1.0, 0.0), 1.0)
    for _ in range(500):
        base.step()
    base.translate([2.5e9, 0.0, 0.0])  # mid-drive, like `send ... 1e10` on a youBot
    for _ in range(2000):
        base.step()
    assert "ruckig cannot plan" in base.fault
    assert not base.moving and np.abs(base.twist).max() == 0.0 and 0.0 < base.pose[0] < 1.0


def cmd(**kw: object) -> Command:
    return msgspec.structs.replace(Command(seq=1, sent_ns=0, deadman=True, ttl_ms=0), **kw)


def test_safety_estop_latches_until_an_explicit_release() -> None:
    s = Safety()
    assert s.on_command(cmd(), 0.0) is Verdict.MOVE
    assert s.on_command(cmd(estop=True, sender="ann"), 0.1) is Verdict.ESTOP
    assert s.on_command(cmd(sender="ann"), 0.2) is Verdict.LATCHED  # a deadman stream never
    assert s.on_command(cmd(release=True, sender="ann"), 0.25) is Verdict.RELEASE  # releases
    s.on_command(cmd(estop=True, sender="ann"), 0.3)
    assert s.on_command(cmd(deadman=False, sender="ann"), 0.4) is Verdict.LATCHED
    assert s.on_command(cmd(stop=True, sender="ann"), 0.5) is Verdict.LATCHED
    assert s.estopped
    assert s.on_command(cmd(release=True, sender="ann"), 0.6) is Verdict.RELEASE
    assert not s.estopped


def test_safety_watchdog_and_deadman() -> None:
    s = Safety()
    assert s.on_command(cmd(ttl_ms=100), 1.0) is Verdict.MOVE
    assert not s.expired(1.05)
    assert s.expired(1.1) and not s.expired(1.2)  # fires once
    assert s.on_command(cmd(drive=Drive("forward", 1.0)), 2.0) is Verdict.MOVE
    assert s.expired(2.0 + DRIVE_TTL_S)  # a drive never runs without a watchdog
    s.on_command(cmd(ttl_ms=0, parts=[]), 3.0)
    assert not s.expired(100.0)  # ttl 0: one-shot pose commands are not cut short
    assert s.on_command(cmd(deadman=False), 4.0) is Verdict.DEADMAN
    assert s.on_command(cmd(stop=True), 4.0) is Verdict.STOP


def test_controller_tracks_ruckig_inside_limits() -> None:
    c = Controller(make_body("mujoco", "tests/data/toyarm", DT))
    c.joints.retarget({"yaw": 1.99, "elbow": -1.0, "wrist": 1.4})
    assert c.base is not None
    c.base.translate([0.2, 0.0, 0.0])
    c.settle(extra=250)
    lim = c.platform.eurdf.limits
    q = dict(zip(c.joint_names, c.q(), strict=True))
    assert q["yaw"] == pytest.approx(lim["yaw"].upper - DEFAULT_MARGIN, abs=2e-3)
    assert q["elbow"] == pytest.approx(-1.0, abs=2e-3)
    assert c.base_pose()[0] == pytest.approx(0.2, abs=2e-3)


BEHIND_THE_LEFT_ARM = {  # baxter's right hand reaching high to the left, across the left arm
    "right_s0": 0.853342, "right_s1": -0.55553, "right_e0": 1.354911, "right_e1": 1.745115,
    "right_w0": 1.092002, "right_w1": 1.403733, "right_w2": -0.039479,
}


def test_a_body_caught_on_itself_is_reported_not_called_at_target() -> None:
    alone = zconfig.session_config(listen=[zconfig.LOOPBACK_ANY_PORT], connect=[])
    with zconfig.session(alone) as s:
        agent = Agent("baxter", "blocked", s)
        agent.controller.joints.retarget(BEHIND_THE_LEFT_ARM)  # past the guard's planning
        agent.conduct.set("moving", "test")
        while agent.controller.moving:
            agent.tick()
        for _ in range(round(SETTLE_S / agent.controller.dt) + 1):
            agent.tick()
        status, detail = agent.status()
        agent.close()
    assert status == "error"  # the guard halts at the first contact and names the links
    assert detail.startswith("contact left_") and "/r_gripper" in detail
    assert "during motion; halted" in detail


@pytest.mark.parametrize("bad", [partial(AgentOptions, control_rate=0.0),
                                 partial(AgentOptions, state_rate=1000.0),
                                 partial(AgentOptions, speed=-1.0),
                                 partial(AgentOptions, control_rate=math.inf)])
def test_bad_options_are_user_errors(bad: Callable[[], AgentOptions]) -> None:
    with pytest.raises(KinesphereError) as err:
        bad()
    assert err.value.code == "malformed"
