"""No joint ever leaves its limits while the robot is commanded to every pose of its ECL.

Poses come from the real databank over Zenoh through the agent's own resolver; the
controller (real Ruckig, real MuJoCo) is stepped in this thread, faster than real time.
Each limb goes through all its poses in turn, each held for a fraction of a second before the
next arrives, so most changes are retargets mid-motion (where braking could overshoot a
limit). Between limbs the robot returns to neutral: the ECL's poses are per limb. The last
test presses two limbs into each other on purpose: the body's hard stops must hold even then.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from kinesphere import zconfig
from kinesphere.errors import KinesphereError
from kinesphere.protocol import SpatialCommand
from kinesphere.robots.agent.bodies import make_body
from kinesphere.robots.agent.controller import Controller
from kinesphere.robots.agent.resolver import Resolver, parts_key
from support.agents import DatabankProcess
from support.network import Hub
from support.wait import WAIT_S

PLATFORMS = ["baxter", "nao", "youbot", "packbot", "khepera"]
DT = 0.002
HOLD_S = 0.25
"""Robot time each pose is followed before the next command (shorter than most motions)."""
PAIR_HOLD_S = 0.4
"""Robot time each pair of arm poses is followed (without the hard stops in the MuJoCo body,
7 of 729 pairs pass a limit at 0.3 s, 62 at 0.6 s, by up to 26 mrad)."""


@pytest.mark.parametrize("platform", PLATFORMS)
def test_limits_hold_for_every_ecl_pose(
    hub: Hub, databank: DatabankProcess, platform: str
) -> None:
    _, endpoint = hub
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        resolver = Resolver(s, platform)
        assert resolver.wait_ready(WAIT_S) and resolver.refresh(), "databank reachable"
        cat = resolver.catalogue
        assert cat is not None
        sequences = [[SpatialCommand(e.limb, e.origin, d, float(size))
                      for d in e.directions for size in e.sizes] for e in cat.limbs]
        sequences += [[SpatialCommand(c, c, d, 2.0) for c in cat.core
                       for d in cat.directions_for_core]]
        parts = [p for seq in sequences for p in seq]
        ctrl = Controller(make_body("mujoco", platform, DT))
        neutral = dict(zip(ctrl.joint_names, ctrl.joints.position.tolist(), strict=True))
        limits = [ctrl.platform.eurdf.limits[j] for j in ctrl.joint_names]
        lower = np.array([lim.lower for lim in limits])
        upper = np.array([lim.upper for lim in limits])
        hold = max(1, round(HOLD_S / ctrl.dt))
        worst_sim = worst_cmd = -math.inf
        commanded = 0
        for sequence in sequences:
            ctrl.joints.retarget(neutral)
            ctrl.settle()
            for part in sequence:
                pose = resolver.resolve(parts_key([part]))
                if isinstance(pose, KinesphereError):
                    raise pose
                ctrl.joints.retarget(pose.joints)
                if pose.translation is not None and ctrl.base is not None:
                    ctrl.base.translate(pose.translation)
                commanded += 1
                for _ in range(hold):
                    ctrl.step()
                    q = np.array(ctrl.q())
                    worst_sim = max(worst_sim, float(np.max(np.maximum(lower - q, q - upper))))
                    p = ctrl.joints.position
                    worst_cmd = max(worst_cmd, float(np.max(np.maximum(lower - p, p - upper))))
        ctrl.settle()
        resolver.close()
        resolver.close()
    assert commanded == len(parts) > 0
    assert resolver.queries == len({parts_key([p]) for p in parts})
    assert worst_cmd <= 0.0, f"Ruckig went {worst_cmd} past a limit"
    assert worst_sim <= 0.0, f"the simulated robot went {worst_sim} past a limit"


def test_two_arms_pressed_together_never_pass_a_hard_limit(
    hub: Hub, databank: DatabankProcess
) -> None:
    """Every far pose of Baxter's right arm with every far pose of its left arm, retargeted
    one after another mid-motion: where the arms meet, contact pushes joints against their
    stops, and the body must hold them there (MuJoCo's soft limits alone let one 26 mrad past)."""
    _, endpoint = hub
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        resolver = Resolver(s, "baxter")
        assert resolver.wait_ready(WAIT_S) and resolver.refresh(), "databank reachable"
        cat = resolver.catalogue
        assert cat is not None
        arms = {e.limb: e for e in cat.limbs if e.limb in ("limb_11", "limb_21")}
        right, left = arms["limb_11"], arms["limb_21"]
        ctrl = Controller(make_body("mujoco", "baxter", DT))
        limits = [ctrl.platform.eurdf.limits[j] for j in ctrl.joint_names]
        lower = np.array([lim.lower for lim in limits])
        upper = np.array([lim.upper for lim in limits])
        worst_sim = worst_cmd = -math.inf
        pairs = 0
        for dr in right.directions:
            for dl in left.directions:
                pose = resolver.resolve(parts_key([
                    SpatialCommand(right.limb, right.origin, dr, 3.0),
                    SpatialCommand(left.limb, left.origin, dl, 3.0)]))
                if isinstance(pose, KinesphereError):
                    raise pose
                ctrl.joints.retarget(pose.joints)
                pairs += 1
                for _ in range(round(PAIR_HOLD_S / DT)):
                    ctrl.step()
                    q = ctrl.reading().q
                    worst_sim = max(worst_sim, float(np.max(np.maximum(lower - q, q - upper))))
                    p = ctrl.joints.position
                    worst_cmd = max(worst_cmd, float(np.max(np.maximum(lower - p, p - upper))))
        resolver.close()
    assert pairs == len(right.directions) * len(left.directions) >= 100
    assert worst_cmd <= 0.0, f"Ruckig went {worst_cmd} past a limit"
    assert worst_sim <= 0.0, f"the simulated robot went {worst_sim} past a limit"
