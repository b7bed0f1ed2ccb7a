"""A usable neutral pose for a brought robot: zero unless zero leaves a limb few directions.

The zero pose of many arms is stretched straight (an iiwa pointing up, a UR5 lying flat): at
such a pose the tip cannot start moving along most directions, and the ECL generator's
inverse kinematics, starting there, keeps few pulls. Each limb (not a hand, not a leg that
bears the robot) is scored by how many of Laban's 26 directions its tip can start moving
along: a direction is *open* when the limb's position Jacobian moves the tip along it by at
least OPEN of its span per radian and the tip has ROOM of its span still to go that way (a
stretched limb has none along itself, a tip near the floor none below it).

A short deterministic search scores every pair of the limb's joints bent by the BENDS (both
signs, inside the limits, touching nothing zero did not touch, never below the robot's lowest
point), which also measures how far out the tip can get. When zero stretches the limb to
STRETCHED of that, or opens fewer than WANTED directions, the most open pose that keeps the
tip within READY of it is proposed (fewest joints bent among equals; ties keep the first in
the fixed order). The caller says what was chosen and why, and ``--neutral zero`` keeps zero.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import mujoco
import numpy as np

from kinesphere.eurdf import Eurdf
from kinesphere.laban import Direction
from kinesphere.platforms.frames import pivot
from kinesphere.platforms.mjcf import ROBOT_CONTYPE
from kinesphere.platforms.stance import bearing_geoms, lowest

OPEN = 0.25  # of the span per radian: the tip can start along a direction this fast ...
ROOM = 0.3  # ... and has this share of the span still to go along it
STRETCHED = 0.85 # of its farthest reach: a limb this stretched at zero is singular ...
READY = 0.8  # ... and a proposed neutral keeps its tip at most this far out
WANTED = 22  # of 26 directions open at zero: fewer (or a stretched limb) and one is proposed
GAIN = 3  # the search's pose is proposed when it opens at least this many more
BENDS = (0.5, 1.0, 1.5)  # rad, both signs
MARGIN = 0.05  # rad kept from every joint limit
KNEE = 0.3  # rad a straight standing leg's knee is bent by (half as much at hip and ankle)
STRAIGHT = 0.97  # a leg whose foot is this share of its length from its hip is straight


@dataclass(frozen=True)
class Proposal:
    """What the search proposes for one limb."""

    limb: str
    alias: str | None
    zero_open: int
    open: int
    joints: dict[str, float]  # the limb's bent joints (empty: zero is kept)
    stretched: bool = False  # zero stretches the limb out as far as it goes

    def __str__(self) -> str:
        name = f"{self.limb} ({self.alias})" if self.alias else self.limb
        why = "stretched out, singular" if self.stretched else "few directions"
        if not self.joints:
            return f"{name}: zero keeps {self.zero_open} of 26 directions open"
        bent = ", ".join(f"{j} = {v:g}" for j, v in self.joints.items())
        return (f"{name}: zero is {why} ({self.zero_open} of 26 directions open); "
                f"proposed {bent} ({self.open} of 26 open)")


@dataclass(frozen=True)
class Score:
    open: int  # directions open
    soft: float  # each direction's share of openness, summed
    reach: float  # metres from the origin to the tip


class _Limb:
    """One limb of a compiled model, scored at candidate poses."""

    def __init__(self, model: mujoco.MjModel, eurdf: Eurdf, limb: str, base: np.ndarray,
                 floor: float) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.base = base
        self.floor = floor
        part = eurdf.limb(limb)
        self.joints = eurdf.limb_joints(limb)
        self.qadr = np.array([model.jnt_qposadr[model.joint(j).id] for j in self.joints])
        self.dofs = np.array([model.jnt_dofadr[model.joint(j).id] for j in self.joints])
        lims = [eurdf.limits[j] for j in self.joints]
        self.lower = np.array([lim.lower + MARGIN for lim in lims])
        self.upper = np.array([lim.upper - MARGIN for lim in lims])
        self.tip = model.body(eurdf.tip_link(limb)).id
        self.distal = eurdf.origin(str(part.distal)).joints
        links = set(part.links)
        self.geoms = [g for g in bearing_geoms(model)
                      if model.body(int(model.geom_bodyid[g])).name in links]
        self.directions = np.array([np.asarray(d.vector) / np.linalg.norm(d.vector)
                                    for d in Direction.pulls()])
        self._jac = np.zeros((3, model.nv))
        self._masks = _moving_pairs(model, [int(model.jnt_bodyid[model.joint(j).id])
                                            for j in self.joints])
        self.touching_at_zero = self._contacts(base)
        self.span = self._span()

    def pose(self, values: np.ndarray) -> np.ndarray:
        q = self.base.copy()
        q[self.qadr] = np.clip(values, self.lower, self.upper)
        return q

    def _forward(self, q: np.ndarray) -> None:
        self.data.qpos[:] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)

    def _contacts(self, q: np.ndarray) -> set[tuple[int, int]]:
        self._forward(q)
        m = self.model
        saved = m.geom_contype.copy(), m.geom_conaffinity.copy()
        m.geom_contype[:], m.geom_conaffinity[:] = self._masks
        try:
            mujoco.mj_collision(m, self.data)
        finally:
            m.geom_contype[:], m.geom_conaffinity[:] = saved
        bodies = self.model.geom_bodyid[self.data.contact.geom[: self.data.ncon]]
        return {(min(a, b), max(a, b)) for a, b in bodies.tolist()}

    def _span(self) -> float:
        self._forward(self.base)
        origin = pivot(self.model, self.data, self.distal)
        anchors = [self.data.xanchor[self.model.joint(j).id] for j in self.joints]
        points = [origin, *anchors, self.data.xpos[self.tip]]
        return max(sum(float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(points)),
                   1e-3)

    def _dips(self) -> bool:
        """Whether a shape dips below the robot's lowest point: only shapes whose bounding
        sphere reaches that low are measured exactly."""
        geoms = np.asarray(self.geoms, dtype=int)
        low = self.data.geom_xpos[geoms, 2] - self.model.geom_rbound[geoms]
        near = geoms[low < self.floor - 1e-3]
        return any(lowest(self.model, self.data, int(g)) < self.floor - 1e-3 for g in near)

    def open(self, q: np.ndarray) -> Score | None:
        """How open the limb is at ``q``; None if the pose touches something zero does not
        or dips below the robot's lowest point."""
        if self._contacts(q) - self.touching_at_zero:
            return None
        if self._dips():
            return None
        tip = self.data.xpos[self.tip]
        offset = tip - pivot(self.model, self.data, self.distal)
        mujoco.mj_jac(self.model, self.data, self._jac, None, tip, self.tip)
        speed = np.linalg.norm(self.directions @ self._jac[:, self.dofs], axis=1) / self.span
        room = 1.0 - (self.directions @ offset) / self.span
        down = -self.directions[:, 2]  # below the tip the floor ends the way sooner
        above = (tip[2] - self.floor) / self.span
        room = np.where(down > 0, np.minimum(room, above / np.maximum(down, 1e-9)), room)
        quality = np.minimum(speed / OPEN, 1.0) * np.minimum(room / ROOM, 1.0)
        return Score(int(((speed >= OPEN) & (room >= ROOM)).sum()), float(quality.sum()),
                     float(np.linalg.norm(offset)))


def _moving_pairs(model: mujoco.MjModel, bodies: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Collision masks under which only pairs with a shape that the limb's joints move are
    checked: every other pair stands still while the limb moves, so it touches at every
    candidate as at zero, and skipping it changes no answer (a humanoid's legs and torso are
    most of its shapes)."""
    moving = np.zeros(model.nbody, dtype=bool)
    for b in range(model.nbody):  # parents come before their children
        moving[b] = b in bodies or (b > 0 and moving[model.body_parentid[b]])
    robot = (model.geom_contype & ROBOT_CONTYPE) != 0  # the floor never meets the robot
    in_limb = moving[model.geom_bodyid]
    contype = np.where(robot, np.where(in_limb, 12, 4), 0).astype(model.geom_contype.dtype)
    conaffinity = np.where(robot, np.where(in_limb, 12, 8), 0).astype(
        model.geom_conaffinity.dtype)
    return contype, conaffinity  # still / still: 4 & 8 = 0, moving / any: 12 & 8 != 0


def propose(model: mujoco.MjModel, eurdf: Eurdf, qpos: np.ndarray, limbs: list[str],
            floor: float) -> list[Proposal]:
    """A proposal for each of ``limbs`` at the full pose ``qpos`` (zero, kept off the limits)
    of a model whose root sits still; ``floor`` the robot's lowest point there."""
    out = []
    for name in limbs:
        limb = _Limb(model, eurdf, name, qpos, floor)
        alias = eurdf.limb(name).alias
        zero = limb.base[limb.qadr]
        at_zero = limb.open(limb.base)
        scored = _candidates(limb, zero) if len(limb.joints) >= 2 else []
        farthest = max([s.reach for _, s in scored] + [at_zero.reach if at_zero else 0.0])
        zero_open = at_zero.open if at_zero is not None else 0
        stretched = at_zero is None or at_zero.reach >= STRETCHED * farthest
        usable = [(q, s) for q, s in scored if s.reach <= READY * farthest]
        if not usable or (zero_open >= WANTED and not stretched):
            out.append(Proposal(name, alias, zero_open, zero_open, {}, stretched))
            continue
        q, best = max(usable, key=lambda c: (c[1].open, round(c[1].soft, 1),
                                             -float(np.abs(c[0] - zero).sum())))
        if best.open < zero_open + (0 if stretched else GAIN):
            out.append(Proposal(name, alias, zero_open, zero_open, {}, stretched))
            continue
        bent = {j: round(float(v), 3) for j, v, z in zip(limb.joints, q, zero, strict=True)
                if abs(v - z) > 1e-9}
        out.append(Proposal(name, alias, zero_open, best.open, bent, stretched))
    return out


def _candidates(limb: _Limb, zero: np.ndarray) -> list[tuple[np.ndarray, Score]]:
    """Every pair of the limb's joints bent by the BENDS (in a fixed order), scored; poses
    that touch or dip are left out. Then the best is improved one joint at a time."""
    steps = [s * b for b in BENDS for s in (-1.0, 1.0)]
    out: list[tuple[np.ndarray, Score]] = []
    for i, j in itertools.combinations(range(len(zero)), 2):
        for a, b in itertools.product(steps, steps):
            q = zero.copy()
            q[i] += a
            q[j] += b
            q = np.clip(q, limb.lower, limb.upper)
            score = limb.open(limb.pose(q))
            if score is not None:
                out.append((q, score))
    return out


def stance(model: mujoco.MjModel, eurdf: Eurdf, qpos: np.ndarray, legs: list[str]
           ) -> dict[str, float]:
    """Knees bent by KNEE where a standing leg is straight at zero (a humanoid's, Bolt's): a
    straight leg cannot start lifting its foot. The leg's pitch joints (about the body's y
    axis) bend hip, knee and ankle by -a, 2a, -a about y, so the foot stays flat and under the
    hip, the knee bent the way its limits allow; legs that are already bent keep zero."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    out: dict[str, float] = {}
    for leg in legs:
        joints = eurdf.limb_joints(leg)
        ids = [model.joint(j).id for j in joints]
        anchors = [data.xanchor[i].copy() for i in ids]
        tip = data.xpos[model.body(eurdf.tip_link(leg)).id]
        points = [*anchors, tip]
        length = sum(float(np.linalg.norm(b - a)) for a, b in itertools.pairwise(points))
        if length <= 0 or float(np.linalg.norm(tip - anchors[0])) < STRAIGHT * length:
            continue
        pitch = [(j, float(data.xaxis[i][1])) for j, i in zip(joints, ids, strict=True)
                 if abs(float(data.xaxis[i][1])) > 0.9]
        if len(pitch) < 2:
            continue
        knee, along = pitch[1]
        lim = eurdf.limits[knee]
        sign = 1.0 if lim.upper >= -lim.lower else -1.0  # the way the knee's limits open
        bend = sign * KNEE  # about the knee's own axis; about y it is bend * along
        about_y = {knee: 2 * bend * along}
        for j, _ in (pitch[0], *pitch[2:3]):
            about_y[j] = -bend * along
        for j, y in about_y.items():
            axis = dict(pitch)[j]
            value = y / axis
            limit = eurdf.limits[j]
            if not limit.lower <= value <= limit.upper:
                break
            out[j] = round(value, 4)
        else:
            continue
        for j in about_y:
            out.pop(j, None)
    return out
