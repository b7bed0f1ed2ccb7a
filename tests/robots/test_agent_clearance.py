"""Motion that does not hit itself: every stored pose reachable without a contact, waypoints
when the straight way touches, and a contact nobody planned halts the joints with its pair
named. Real MuJoCo models, real Ruckig, the shipped databanks."""

from __future__ import annotations

import time
from functools import cache
from typing import Any

import mujoco
import numpy as np
import pytest

from kinesphere.platforms.clearance import PATH_STEP, Clearance, Touch
from kinesphere.platforms.mjcf import platform_model, robot_contacts
from kinesphere.protocol import SpatialCommand
from kinesphere.robots.agent.controller import Controller
from kinesphere.robots.agent.guard import CHECK_GAP_S, CHECKING, UNCHECKED_S, Guard, make_guard
from kinesphere.robots.agent.mujoco_body import MujocoBody
from kinesphere.services.ecl.ecl import Ecl
from support.agents import (
    AckWatch,
    CommandSender,
    DatabankProcess,
    joints_close,
    running_agent,
)
from support.network import Hub
from support.wait import WAIT_S

DT = 0.002
ARTICULATED = ("baxter", "nao", "youbot", "packbot")


@cache
def ecl(name: str) -> Ecl:
    return Ecl.open(name)


class Sampler:
    """This test's own check of a straight joint-space way: kinematics and collision detection
    at PATH_STEP, on a fresh MjData of the platform's model (mimic joints following)."""

    def __init__(self, name: str) -> None:
        pm = platform_model(name)
        self.model, self.data = pm.model, mujoco.MjData(pm.model)
        names = pm.platform.joint_names
        self.qpos = pm.neutral_qpos()
        self.adr = np.array([pm.qpos_index[j] for j in names])
        self.mimics = [(pm.qpos_index[m.joint], names.index(m.leader), m)
                       for m in pm.platform.eurdf.mimics.values()]

    def contacts_along(self, a: np.ndarray, b: np.ndarray) -> list[tuple[str, str]]:
        m, data = self.model, self.data
        found: list[tuple[str, str]] = []
        steps = max(1, int(np.ceil(float(np.max(np.abs(b - a), initial=0.0)) / PATH_STEP)))
        for t in np.linspace(0.0, 1.0, steps + 1):
            q = a + t * (b - a)
            self.qpos[self.adr] = q
            for adr, leader, mimic in self.mimics:
                self.qpos[adr] = mimic.value(float(q[leader]))
            data.qpos[:] = self.qpos
            mujoco.mj_kinematics(m, data)
            mujoco.mj_collision(m, data)
            found += robot_contacts(m, data)
        return found


def answer(name: str, row: dict[str, Any]) -> dict[str, float]:
    """The joints the databank answers for a stored row (a leg's with its stance leg's)."""
    return ecl(name).query(row["limb"], row["origin"], row["direction"], row["size"]).joints


@pytest.mark.parametrize("name", ARTICULATED)
def test_every_stored_pose_is_reached_without_a_contact(name: str) -> None:
    """From neutral and from the far poses of two other directions of the same limb: the
    planner finds a way to every stored pose, and no leg of it touches anything."""
    cl = Clearance(platform_model(name))
    sampler = Sampler(name)
    index = {j: i for i, j in enumerate(cl.joint_names)}

    def at(start: np.ndarray, joints: dict[str, float]) -> np.ndarray:
        q = start.copy()
        for j, v in joints.items():
            q[index[j]] = v
        return q

    pairs: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in ecl(name).rows():
        if r["joints"]:
            pairs.setdefault((r["limb"], r["origin"]), []).append(r)
    swept = via = 0
    for rows in pairs.values():
        fars = [r for r in rows if r["size"] == 3]
        others = fars[1::max(1, len(fars) // 2)][:2]  # two other directions, far
        # what the databank answers: the limb's joints and its stance leg's (a leg's support)
        starts = [cl.neutral, *(at(cl.neutral, answer(name, r)) for r in others)]
        for i, start in enumerate(starts):
            for r in rows:
                goal = at(start, answer(name, r))
                route = cl.route(start, goal)
                assert not isinstance(route, Touch), (i, r["limb"], r["direction"], r["size"],
                                                      route)
                assert np.array_equal(route[-1], goal)
                for a, b in zip([start, *route], route, strict=False):
                    assert sampler.contacts_along(a, b) == [], (r["limb"], r["direction"],
                                                                 r["size"])
                swept += 1
                if len(route) > 1:  # a detour: this test's own sampling sees the direct way touch
                    via += 1
                    assert sampler.contacts_along(start, goal) != [], (r["limb"], r["direction"])
    assert swept >= len([r for r in ecl(name).rows() if r["joints"]])
    if name == "baxter":
        assert via > 0  # some ways cross the other arm and need waypoints


def run(ctrl: Controller, guard: Guard, limit: int = 20_000
        ) -> tuple[set[tuple[str, str]], int]:
    """Step until the move, its checks and its legs are done; contacts seen, legs taken.
    The steps run many times faster than real time: each waits for a check or route under
    way, as real time would (the worker takes milliseconds: a few steps at 500 Hz)."""
    seen: set[tuple[str, str]] = set()
    legs = 0
    for _ in range(limit):
        if guard.pending:
            assert guard.settle(WAIT_S)
        if not (ctrl.moving or guard.pending or guard.legs):
            break
        legs = max(legs, len(guard.legs))
        ctrl.step()
        seen |= set(ctrl.body.contacts())
    return seen, legs


class CountingBody(MujocoBody):
    """Baxter's MuJoCo body, counting how often the guard lists its contacts."""

    def __init__(self) -> None:
        super().__init__(platform_model("baxter"), DT)
        self.listed = 0

    def contacts(self) -> list[tuple[str, str]]:
        self.listed += 1
        return super().contacts()


def baxter() -> tuple[Controller, Guard]:
    body = CountingBody()
    guard = make_guard(body, "baxter")
    return Controller(body, guard=guard), guard


def goal_of(ctrl: Controller, joints: dict[str, float]) -> np.ndarray:
    goal = ctrl.joints.target.copy()
    for j, v in joints.items():
        goal[ctrl.joint_names.index(j)] = v
    return goal


def assert_at(ctrl: Controller, joints: dict[str, float]) -> None:
    """The body stands at ``joints`` (within 0.02 rad)."""
    got = ctrl.reading().q
    for j, v in joints.items():
        assert got[ctrl.joint_names.index(j)] == pytest.approx(v, abs=0.02), j


def test_the_right_arm_crosses_to_left_high_without_knocking_the_left_arm() -> None:
    ctrl, guard = baxter()
    try:
        left = [i for i, j in enumerate(ctrl.joint_names) if j.startswith("left_")]
        before = ctrl.reading().q.copy()
        pose = ecl("baxter").query("right_arm", "right_shoulder", "left-high", 3)
        ctrl.move(pose.joints)
        seen, _ = run(ctrl, guard)
        assert seen == set() and ctrl.fault() == "" and ctrl.blocked() == ""
        assert np.max(np.abs(ctrl.reading().q[left] - before[left])) < 0.005
    finally:
        guard.close()


def test_a_straight_way_that_touches_goes_via_waypoints() -> None:
    ctrl, guard = baxter()
    try:
        pose = ecl("baxter").query("right_arm", "right_shoulder", "left-middle", 3)
        start = ctrl.reading().q.copy()
        goal = start.copy()
        for j, v in pose.joints.items():
            goal[ctrl.joint_names.index(j)] = v
        assert isinstance(guard.clearance.leg(start, goal), Touch)  # straight: the left arm
        ctrl.move(pose.joints)
        seen, legs = run(ctrl, guard)
        assert legs >= 1 and seen == set() and ctrl.fault() == "" and ctrl.blocked() == ""
        assert_at(ctrl, pose.joints)
    finally:
        guard.close()


def test_a_contact_nobody_planned_halts_the_joints_and_names_the_links() -> None:
    """Mid-motion someone holds the left arm out into the right arm's way (the check saw it at
    rest): the contact halts every joint and the fault names the pair."""
    ctrl, guard = baxter()
    try:
        body = ctrl.body
        assert isinstance(body, MujocoBody)
        pose = ecl("baxter").query("right_arm", "right_shoulder", "left-forward-middle", 3)
        ctrl.move(pose.joints)
        for _ in range(100):  # under way, the way checked clear
            ctrl.step()
        assert ctrl.moving and ctrl.fault() == ""
        block = ecl("baxter").query("left_arm", "left_shoulder", "forward-middle", 3)
        held = {body.pm.qpos_index[j]: v for j, v in block.joints.items()}
        dofs = [body.pm.dof_index[j] for j in block.joints]

        def hold_left_arm_out(_: Controller) -> None:  # someone holds it out, into the way
            for adr, v in held.items():
                body.data.qpos[adr] = v
            body.data.qvel[dofs] = 0.0

        ctrl.on_step = hold_left_arm_out
        run(ctrl, guard)
        fault = ctrl.fault()
        assert fault.startswith("contact ") and "during motion; halted" in fault
        pair = sorted(fault.removeprefix("contact ").split(" ")[0].split("/"))
        assert pair[0].startswith("left_") and pair[1].startswith("right_"), fault
        target = [ctrl.joint_names.index(j) for j in pose.joints]
        assert np.max(np.abs(ctrl.reading().q[target] - np.array(list(pose.joints.values())))
                      ) > 0.05
        checks = guard.checks
        ctrl.move(pose.joints)  # the same target again (the stream goes on): still halted
        ctrl.step()
        assert not ctrl.moving and ctrl.fault() == fault and guard.checks == checks
        ctrl.on_step = None  # let go of the left arm; the operator lets go and presses again
        ctrl.halt()
        left = [ctrl.joint_names.index(j) for j in block.joints]
        for _ in range(5000):  # robot time: the left arm's servos take it back to its target
            if np.max(np.abs(ctrl.reading().q[left] - ctrl.joints.target[left])) < 0.01:
                break
            ctrl.step()
        run(ctrl, guard)
        ctrl.move(pose.joints)
        assert ctrl.fault() == ""
        seen, _ = run(ctrl, guard)
        assert ctrl.fault() == "" and guard.checks == checks + 1
    finally:
        guard.close()


def test_no_route_to_a_pose_inside_the_robot_is_refused_with_the_pair() -> None:
    cl = Clearance(platform_model("baxter"))
    goal = cl.neutral.copy()
    names = list(cl.joint_names)
    crossed = ecl("baxter").query("right_arm", "right_shoulder", "left-forward-middle", 3)
    other = ecl("baxter").query("left_arm", "left_shoulder", "right-forward-middle", 3)
    for j, v in {**crossed.joints, **other.joints}.items():
        goal[names.index(j)] = v
    assert cl.touching(goal) is not None  # both arms across each other: the goal itself touches
    route = cl.route(cl.neutral, goal)
    assert isinstance(route, Touch) and "/" in str(route)


def test_the_same_target_again_restarts_nothing() -> None:
    """A gamepad streams its target at 30 Hz, a flood repeats it: sent again every step, the
    move goes on exactly as if sent once, with one check and no contact listed."""
    pose = ecl("baxter").query("right_arm", "right_shoulder", "forward-middle", 3)
    paths = []
    for repeat in (False, True):
        ctrl, guard = baxter()
        try:
            assert guard.clearance.leg(ctrl.reading().q, goal_of(ctrl, pose.joints)) is None
            ctrl.move(pose.joints)
            assert guard.settle(WAIT_S)  # checked before the first step in both runs
            path = []
            for _ in range(300):
                if repeat:
                    assert ctrl.move(pose.joints) == []
                ctrl.step()
                path.append(ctrl.joints.position.copy())
            assert isinstance(ctrl.body, CountingBody) and ctrl.body.listed == 0
            run(ctrl, guard)
            paths.append(np.array(path))
            assert guard.checks == 1 and guard.skipped == 0
            assert ctrl.fault() == "" and ctrl.blocked() == ""
        finally:
            guard.close()
    assert np.array_equal(paths[0], paths[1])


def test_a_burst_of_new_targets_is_checked_for_the_newest_only() -> None:
    """A hundred targets between two steps: the worker checks the first and then the newest,
    no more often than every CHECK_GAP_S, and the arm goes to the last one untouched."""
    directions = ["forward-middle", "left-forward-middle", "forward-high", "left-middle",
                  "right-forward-low"]
    poses = [ecl("baxter").query("right_arm", "right_shoulder", d, 3) for d in directions]
    ctrl, guard = baxter()
    try:
        t0 = time.monotonic()
        for k in range(100):
            ctrl.move(poses[k % len(poses)].joints)
        last = poses[99 % len(poses)]
        seen, _ = run(ctrl, guard)
        elapsed = time.monotonic() - t0
        assert 1 <= guard.checks <= 2 + elapsed / CHECK_GAP_S and guard.checks < 25
        assert seen == set() and ctrl.fault() == "" and ctrl.blocked() == ""
        assert_at(ctrl, last.joints)
    finally:
        guard.close()


def test_a_goal_on_a_way_found_clear_needs_no_new_check() -> None:
    """Half-way back along a straight way already checked clear (a reach trigger let go a
    little): the worker answers without sampling the way again."""
    pose = ecl("baxter").query("right_arm", "right_shoulder", "forward-middle", 3)
    ctrl, guard = baxter()
    try:
        start = ctrl.reading().q.copy()
        far = goal_of(ctrl, pose.joints)
        ctrl.move(pose.joints)
        assert guard.settle(WAIT_S)  # the way checked clear before the arm sets out ...
        for _ in range(20):  # ... and the arm a little way along it
            ctrl.step()
        half = start + 0.5 * (far - start)
        ctrl.move({j: float(half[ctrl.joint_names.index(j)]) for j in pose.joints})
        seen, _ = run(ctrl, guard)
        assert guard.checks == 1 and guard.skipped == 1
        assert seen == set() and ctrl.fault() == ""
        assert np.max(np.abs(ctrl.reading().q - half)) < 0.02
    finally:
        guard.close()


class HoldOut:
    """Someone holds Baxter's left arm out while the robot moves (every step, until let go)."""

    def __init__(self, body: MujocoBody, joints: dict[str, float]) -> None:
        self.body = body
        self.held = {body.pm.qpos_index[j]: v for j, v in joints.items()}
        self.dofs = [body.pm.dof_index[j] for j in joints]
        self.active = True

    def __call__(self, ctrl: Controller) -> None:
        if self.active and ctrl.joints.moving:
            for adr, v in self.held.items():
                self.body.data.qpos[adr] = v
            self.body.data.qvel[self.dofs] = 0.0


def test_a_halted_target_sent_again_is_blocked_again_and_nothing_moves(
    hub: Hub, databank: DatabankProcess
) -> None:
    """Over the wire: the contact halt ends the command ``blocked`` with the pair; the same
    target streamed again is ``accepted`` then ``blocked`` with the same reason, never
    ``moving``, and the arm stays put; after the deadman is let go and pressed, it tries anew."""
    session, endpoint = hub
    part = ("right_arm", "right_shoulder", "left-forward-middle", 3.0)
    block = databank.query("baxter", SpatialCommand("left_arm", "left_shoulder",
                                                     "forward-middle", 3.0))
    with (AckWatch(session, "guarded") as acks,
          running_agent(endpoint, "baxter", robot_id="guarded") as (agent, watch),
          CommandSender(session, "guarded", sender="op") as op):
        body = agent.controller.body
        assert isinstance(body, MujocoBody)
        hold = HoldOut(body, block.joints)
        agent.controller.on_step = hold
        first = op.send(part)
        halted = acks.of("op", first, "blocked").detail
        assert halted.startswith("contact left_") and "during motion; halted" in halted
        hold.active = False
        right = [agent.controller.joint_names.index(j) for j in
                 databank.query("baxter", SpatialCommand(*part)).joints]
        before = np.array(watch.after(first, lambda s: s.status == "error" and max(
            map(abs, s.qd)) < 1e-3, "halted, at rest, the left arm back").q)[right]
        again = op.send(part)
        acks.of("op", again, "accepted")
        assert acks.of("op", again, "blocked").detail == halted
        after = np.array(watch.after(again, lambda s: s.status == "error", "still halted").q)
        assert "moving" not in acks.stages("op", again)
        assert np.max(np.abs(after[right] - before)) < 1e-3
        acks.of("op", op.send(deadman=False), "holding")
        retry = op.send(part)
        assert acks.of("op", retry, "reached")


def test_a_move_braked_for_a_late_check_is_not_reached_until_the_check_is_in(
    hub: Hub, databank: DatabankProcess
) -> None:
    """On a loaded host the guard's finding can come after the joints ran their unchecked
    stretch and braked to rest: resting there is not arriving. No final answer while the check
    waits (two seconds of robot time), then ``reached`` with the body at the pose."""
    session, endpoint = hub
    part = ("right_arm", "right_shoulder", "forward-middle", 3.0)
    pose = databank.query("baxter", SpatialCommand(*part))
    with (AckWatch(session, "late-check") as acks,
          running_agent(endpoint, "baxter", robot_id="late-check") as (_agent, watch),
          CommandSender(session, "late-check", sender="op") as op):
        with CHECKING:  # the worker waits for it: the finding comes when this block ends
            seq = op.send(part)
            acks.of("op", seq, "moving")
            first = watch.after(seq, lambda s: True, "a state after the command")
            rested = watch.wait(lambda s: s.seq >= first.seq + 100 and max(map(abs, s.qd)) < 1e-3,
                                "two seconds of robot time on, at rest")
            assert not joints_close(rested, pose.joints, 0.02)  # braked on the way
            assert not set(acks.stages("op", seq)) & {"reached", "clamped", "blocked"}, \
                acks.stages("op", seq)
        acks.of("op", seq, "reached")
        there = watch.wait(lambda s: joints_close(s, pose.joints, 0.02), "at the pose", start=-1)
        assert there.status == "idle", there.detail


def test_a_late_check_never_lets_the_joints_run_into_a_touch_near_the_start() -> None:
    """Back to neutral from the right upper arm Left-Middle and the forearm Left-Forward-Low,
    the straight way touches 2 % along (the right wrist meets the left forearm). When the
    finding comes within milliseconds the arm brakes before that; here it comes after the
    joints' unchecked stretch (UNCHECKED_S of robot time, as on a loaded host), and still
    they touch nothing on the way back and arrive."""
    bent = ecl("baxter").compound([
        SpatialCommand("right_upper_arm", "right_shoulder", "left-middle", 3),
        SpatialCommand("right_forearm", "right_elbow", "left-forward-low", 3)], last_wins=True)
    neutral = ecl("baxter").query("right_arm", "right_shoulder", "place-middle", 3)
    ctrl, guard = baxter()
    try:
        ctrl.move(bent.joints)
        seen, _ = run(ctrl, guard)
        assert seen == set() and ctrl.fault() == ""
        touch = guard.clearance.leg(ctrl.reading().q, goal_of(ctrl, neutral.joints))
        assert isinstance(touch, Touch) and touch.at < 0.05, touch
        with CHECKING:  # the worker waits for it: the finding comes after the stretch
            ctrl.move(neutral.joints)
            for _ in range(round(UNCHECKED_S / DT) + 500):
                ctrl.step()
                seen |= set(ctrl.body.contacts())
        more, _ = run(ctrl, guard)
        assert seen | more == set() and ctrl.fault() == "" and ctrl.blocked() == ""
        assert_at(ctrl, neutral.joints)
    finally:
        guard.close()
