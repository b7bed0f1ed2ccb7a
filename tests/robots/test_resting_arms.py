"""NAO's arms at rest (upper arm and forearm Place Low, as a Labanotation score starts and ends)
stay clear of its thighs, and so do the ways to and from rest: the score keyframes played on
the real MuJoCo body, each next one sent before the last has arrived while the guard's checks
come late (as on a loaded machine), halt nowhere on a contact.

Distances are this test's own: MuJoCo's geom distance between each arm's elbow, forearm,
wrist and hand and its own leg's hip, thigh and shin, on the platform's compiled model, along
straight joint-space ways sampled every 1% (not the generator's or the planner's checks).
"""

from __future__ import annotations

from functools import cache

import mujoco
import numpy as np
import pytest

from kinesphere.casting import Casting, cast
from kinesphere.clients.orders.score_play import load, shipped
from kinesphere.platforms.mjcf import ROBOT_CONTYPE, platform_model
from kinesphere.protocol import SpatialCommand
from kinesphere.robots.agent.controller import Controller
from kinesphere.robots.agent.guard import CHECKING, UNCHECKED_S, make_guard
from kinesphere.robots.agent.mujoco_body import MujocoBody
from kinesphere.services.ecl.ecl import Ecl
from support.wait import WAIT_S

DT = 0.002
ARM = ("{S}Elbow", "{S}ForeArm", "{s}_wrist", "{s}_gripper")
LEG = ("{S}Hip", "{S}Thigh", "{S}Tibia")
REST = [SpatialCommand(limb, origin, "place-low", 3)
        for side in ("right", "left")
        for limb, origin in ((f"{side}_upper_arm", f"{side}_shoulder"),
                             (f"{side}_forearm", f"{side}_elbow"))]


@cache
def nao() -> Ecl:
    return Ecl.open("nao")


@cache
def casting() -> Casting:
    cat = nao().catalogue()
    return cast("nao", cat.vocabulary, cat.base_kind, cat.sizes)


class Gaps:
    """The least distance between either arm and its own leg, at a pose or along a way."""

    def __init__(self) -> None:
        self.pm = pm = platform_model("nao")
        self.model, self.data = pm.model, mujoco.MjData(pm.model)
        m = self.model

        def geoms(bodies: tuple[str, ...], side: str) -> list[int]:
            names = {b.format(S=side, s=side.lower()) for b in bodies}
            return [g for g in range(m.ngeom) if m.body(m.geom_bodyid[g]).name in names
                    and m.geom_contype[g] & ROBOT_CONTYPE]

        self.pairs = [(a, b) for side in "LR" for a in geoms(ARM, side)
                      for b in geoms(LEG, side)]
        assert len(self.pairs) >= 2 * 4 * 3
        self._fromto = np.zeros(6)

    def at(self, qpos: np.ndarray) -> float:
        self.data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self.data)
        return min(float(mujoco.mj_geomDistance(self.model, self.data, a, b, 0.1, self._fromto))
                   for a, b in self.pairs)

    def along(self, a: np.ndarray, b: np.ndarray) -> float:
        return min(self.at(a + t * (b - a)) for t in np.linspace(0.0, 1.0, 101))

    def qpos(self, joints: dict[str, float]) -> np.ndarray:
        return self.pm.qpos(joints)


def keyframe_poses(score: str) -> list[dict[str, float]]:
    """What the databank answers for each keyframe of a shipped score, cast on NAO."""
    return [nao().compound(casting().parts(kf), last_wins=True).joints
            for g in load(score).gestures for kf in g.keyframes]


def test_resting_arms_and_the_ways_to_and_from_rest_keep_off_the_thighs() -> None:
    """Rest keeps the generator's centimetre, the way there from neutral keeps it too (it
    went 10 mm into a thigh), and no way from rest to a keyframe of a shipped score goes
    into a thigh more than a few millimetres (38 mm: rest had the elbow and wrist yawed
    ~3 rad from neutral, which every way out swung back through the thigh)."""
    gaps = Gaps()
    rest = gaps.qpos(nao().compound(REST).joints)
    neutral = gaps.qpos({})
    assert gaps.at(neutral) > 0.03
    assert gaps.at(rest) >= 0.009
    assert gaps.along(neutral, rest) >= 0.009
    ways = {(score, i): gaps.along(rest, gaps.qpos(joints))
            for score in shipped() for i, joints in enumerate(keyframe_poses(score))}
    assert len(ways) >= 30
    assert min(ways.values()) >= -0.003, sorted(ways.items(), key=lambda w: w[1])[:3]


@pytest.mark.parametrize(("score", "after"), [("nice", 0.12), ("nice", 0.2), ("panic", 0.2),
                                              ("panic", 0.48)])
def test_keyframes_that_overtake_each_other_under_load_touch_nothing(
    score: str, after: float,
) -> None:
    """Each next keyframe is sent ``after`` s into the last one's move (a score running
    ahead of the body, or a late keyframe starting the next move from mid-way) and every
    check of the guard comes UNCHECKED_S late, so the joints run their unchecked stretch and
    brake before each finding: no contact halts the body (before, every one of these did,
    on a wrist against a thigh)."""
    pm = platform_model("nao")
    body = MujocoBody(pm, DT)
    guard = make_guard(body, "nao")
    ctrl = Controller(body, guard=guard)
    late = round(UNCHECKED_S / DT)
    gaps = Gaps()
    least = np.inf
    try:
        for i, joints in enumerate(keyframe_poses(score)):
            with CHECKING:  # the worker waits for it: the finding comes UNCHECKED_S late
                ctrl.move(joints)
                for _ in range(late):
                    ctrl.step()
                    least = min(least, gaps.at(body.data.qpos))
            for step in range(late, 20_000):
                if guard.pending:
                    assert guard.settle(WAIT_S)
                if not (ctrl.moving or guard.pending or guard.legs):
                    break
                if i > 0 and step * DT >= after:
                    break
                ctrl.step()
                least = min(least, gaps.at(body.data.qpos))
                assert "contact" not in ctrl.fault(), (i, step, ctrl.fault())
    finally:
        guard.close()
    assert least > 0.0
