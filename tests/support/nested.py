"""Measuring where body segments point, independently of the solver that posed them.

The ECL points segments with mink on the platform's MuJoCo model. These helpers read the
same eURDF with yourdfpy (another reader of the URDF, another kinematics) and measure:

* a segment runs from a joint location's pivot (the point nearest all of its joint axes, the
  paper's origin) to the next location's pivot, or to the limb's tip link (the frame the URDF
  puts at the hand); its direction is in the body frame (the root link: x forward, y left);
* whether the body *can* point two segments at once at all: a sampled witness, a
  configuration inside the joint limits that touches nothing (MuJoCo's contact detection)
  and points both within a bound. Sampling uses a batched forward kinematics of the same
  URDF numbers, checked against yourdfpy's own.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache

import mujoco
import numpy as np
import yourdfpy

from kinesphere.laban import Direction
from kinesphere.platforms.mjcf import PlatformModel, platform_model
from kinesphere.platforms.platform import Platform, load_platform

PIVOT_REACH = 0.05
"""metres: a location whose axes do not meet this closely is measured from its first joint."""


def unit(d: Direction) -> np.ndarray:
    v = np.asarray(d.vector, dtype=float)
    return np.asarray(v / np.linalg.norm(v))


def degrees(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Angles in degrees between rows of unit vectors (or two vectors)."""
    return np.asarray(np.degrees(np.arccos(np.clip(np.sum(u * v, axis=-1), -1.0, 1.0))))


def _rotations(axis: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rotation matrices about ``axis`` by each angle of ``q`` (Rodrigues), (n, 3, 3)."""
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    s, c = np.sin(q)[:, None, None], np.cos(q)[:, None, None]
    return np.asarray(np.eye(3) + s * kx + (1 - c) * (kx @ kx))


@dataclass(frozen=True)
class SegmentEnds:
    """From a location's pivot (``distal_*``) to another's, or to a limb's tip link."""

    start: str
    end: str


class MeasuredBody:
    """A platform's eURDF read by yourdfpy, for measuring segments of given joint values."""

    def __init__(self, name: str) -> None:
        self.platform: Platform = load_platform(name)
        self.eurdf = self.platform.eurdf
        assert self.eurdf.path is not None
        text = self.eurdf.path.read_text(encoding="utf-8")
        self.urdf = yourdfpy.URDF.load(io.BytesIO(text.encode()), load_meshes=False,
                                       build_scene_graph=True)
        self.root = self.eurdf.root_link
        self._parent = {j.child: j for j in self.urdf.robot.joints}

    # -- one configuration, through yourdfpy ----------------------------------------------------
    def pose(self, joints: Mapping[str, float]) -> None:
        """Put the body in ``joints`` (neutral elsewhere, mimic joints following)."""
        values = self.eurdf.with_mimics({**self.platform.neutral, **joints})
        cfg = [values.get(n, 0.0) for n in self.urdf.actuated_joint_names]
        self.urdf.update_cfg(np.asarray(cfg, dtype=float))

    def _frame(self, link: str) -> np.ndarray:
        return np.asarray(self.urdf.get_transform(link, self.root))

    def _axis_line(self, joint: str) -> tuple[np.ndarray, np.ndarray]:
        j = self.urdf.joint_map[joint]
        t = self._frame(j.parent) @ j.origin
        return t[:3, 3], t[:3, :3] @ (np.asarray(j.axis, float) / np.linalg.norm(j.axis))

    def point(self, name: str) -> np.ndarray:
        """A location's pivot or a limb's tip link origin, in the body frame."""
        if name.startswith("limb_"):
            return np.asarray(self._frame(self.eurdf.tip_link(name))[:3, 3])
        lines = [self._axis_line(j) for j in self.eurdf.origin(name).joints]
        anchors, axes = np.array([p for p, _ in lines]), np.array([a for _, a in lines])
        return np.asarray(pivot(anchors[None], axes[None])[0])

    def direction(self, seg: SegmentEnds) -> np.ndarray:
        v = self.point(seg.end) - self.point(seg.start)
        return np.asarray(v / np.linalg.norm(v))

    # -- many configurations at once ----------------------------------------------------------
    def chain(self, links: Sequence[str]) -> list[yourdfpy.Joint]:
        """The joints from the root to every link of ``links``, parents first."""
        seen: dict[str, yourdfpy.Joint] = {}
        for link in links:
            path = []
            while link in self._parent:
                j = self._parent[link]
                path.append(j)
                link = j.parent
            for j in reversed(path):
                seen.setdefault(j.name, j)
        return list(seen.values())

    def batch(self, values: Mapping[str, np.ndarray], links: Sequence[str]
              ) -> dict[str, np.ndarray]:
        """Each link's frame (n, 4, 4) for n configurations: ``values`` joint -> (n,) (others
        neutral); the same URDF numbers yourdfpy reads, multiplied out in numpy."""
        n = len(next(iter(values.values())))
        neutral = self.eurdf.with_mimics(dict(self.platform.neutral))
        frames = {self.root: np.broadcast_to(np.eye(4), (n, 4, 4))}
        for j in self.chain(links):
            motion = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
            if j.type in ("revolute", "continuous", "prismatic"):
                q = values.get(j.name, np.full(n, neutral.get(j.name, 0.0)))
                axis = np.asarray(j.axis, dtype=float)
                if j.type == "prismatic":
                    motion[:, :3, 3] = q[:, None] * axis / np.linalg.norm(axis)
                else:
                    motion[:, :3, :3] = _rotations(axis, q)
            frames[j.child] = frames[j.parent] @ j.origin @ motion
        return frames

    def batch_point(self, name: str, values: Mapping[str, np.ndarray]) -> np.ndarray:
        """:meth:`point` for n configurations at once, (n, 3)."""
        if name.startswith("limb_"):
            link = self.eurdf.tip_link(name)
            return self.batch(values, [link])[link][:, :3, 3]
        joints = [self.urdf.joint_map[j] for j in self.eurdf.origin(name).joints]
        frames = self.batch(values, [j.parent for j in joints])
        anchors, axes = [], []
        for j in joints:
            t = frames[j.parent] @ j.origin
            anchors.append(t[:, :3, 3])
            axes.append(t[:, :3, :3] @ (np.asarray(j.axis, float) / np.linalg.norm(j.axis)))
        return pivot(np.stack(anchors, axis=1), np.stack(axes, axis=1))


def pivot(anchors: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """Per row, the point nearest all lines (anchor, axis): (n, k, 3) -> (n, 3); the first
    anchor when the lines miss it by more than PIVOT_REACH (a lone or parallel axes)."""
    first = anchors[:, 0]
    if anchors.shape[1] < 2:
        return np.asarray(first)
    proj = np.eye(3) - axes[..., :, None] * axes[..., None, :]  # (n, k, 3, 3)
    lhs = proj.sum(axis=1) + 1e-6 * np.eye(3)
    rhs = np.einsum("nkij,nkj->ni", proj, anchors) + 1e-6 * first
    x = np.linalg.solve(lhs, rhs[..., None])[..., 0]
    off = x[:, None] - anchors
    miss = np.linalg.norm(off - np.sum(off * axes, axis=-1, keepdims=True) * axes, axis=-1)
    return np.where((miss.max(axis=1) <= PIVOT_REACH)[:, None], x, first)


@dataclass(frozen=True)
class PairReach:
    """What a body can do with two segments: unit directions of n sampled configurations that
    touch nothing, for a witness of any pair of directions."""

    body: MeasuredBody
    limb: str
    values: dict[str, np.ndarray]
    first: np.ndarray  # (n, 3)
    second: np.ndarray

    def witness(self, d1: Direction, d2: Direction) -> float:
        """The smallest, over clean samples, of the larger of the two segments' angles."""
        worst = np.maximum(degrees(self.first, unit(d1)), degrees(self.second, unit(d2)))
        return float(worst.min())


@cache
def reach(name: str, limb: str, segments: tuple[SegmentEnds, SegmentEnds], samples: int = 30000,
          seed: int = 0) -> PairReach:
    """Sample the limb's joints uniformly inside their limits (a fixed seed: the same samples
    every run), keep the configurations MuJoCo finds free of contacts with the limb, and
    measure both segments in each."""
    body = MeasuredBody(name)
    e = body.eurdf
    rng = np.random.default_rng(seed)
    names = e.limb_joints(limb)
    values = {j: rng.uniform(e.limits[j].lower, e.limits[j].upper, samples) for j in names}
    first = _units(body, segments[0], values)
    second = _units(body, segments[1], values)
    clean = _clean(name, limb, values)
    kept = {j: v[clean] for j, v in values.items()}
    return PairReach(body, limb, kept, first[clean], second[clean])


def _units(body: MeasuredBody, seg: SegmentEnds, values: Mapping[str, np.ndarray]) -> np.ndarray:
    v = body.batch_point(seg.end, values) - body.batch_point(seg.start, values)
    return np.asarray(v / np.linalg.norm(v, axis=1, keepdims=True))


def _clean(name: str, limb: str, values: Mapping[str, np.ndarray]) -> np.ndarray:
    """Which sampled configurations keep the limb clear of the rest of the robot."""
    pm = platform_model(name)
    m, data = pm.model, mujoco.MjData(pm.model)
    of_limb = np.zeros(m.nbody, dtype=bool)  # body id -> part of the limb (a lookup, not isin)
    of_limb[[m.body(link).id for link in pm.platform.eurdf.limb(limb).links]] = True
    configurations = _qpos_rows(pm, values)
    out = np.zeros(len(configurations), dtype=bool)
    for i, qpos in enumerate(configurations):
        data.qpos[:] = qpos
        mujoco.mj_kinematics(m, data)
        mujoco.mj_collision(m, data)
        out[i] = not of_limb[m.geom_bodyid[data.contact.geom[: data.ncon]]].any()
    return out


def _qpos_rows(pm: PlatformModel, values: Mapping[str, np.ndarray]) -> np.ndarray:
    """``pm.qpos`` of every sampled configuration, (n, nq), built column by column: neutral,
    the sampled joints, every mimic joint following its leader as ``Eurdf.with_mimics`` says."""
    n = len(next(iter(values.values())))
    rows = np.tile(pm.qpos({}), (n, 1))
    given: dict[str, float | np.ndarray] = {**pm.platform.neutral, **values}
    for joint, column in values.items():
        rows[:, pm.qpos_index[joint]] = column
    for mimic in pm.platform.eurdf.mimics.values():
        if mimic.leader in given:
            rows[:, pm.qpos_index[mimic.joint]] = mimic.multiplier * given[mimic.leader] \
                + mimic.offset
    return rows
