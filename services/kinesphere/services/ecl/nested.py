"""Nested limbs pointed together: an upper arm and its forearm, a leg and its shin.

A command may name a limb and a limb inside it (Motif and Labanotation give the upper arm and
the forearm each a direction). Stored rows cannot answer that: each row moves one limb from
the neutral pose, so the forearm's row points where told only while the upper arm hangs at
neutral. Here the parts of one chain become *segments*, each from its origin's pivot to the
next named part's origin (or to its own ``end`` location, or to the limb's tip), and one mink
solve on the platform's model turns all of the outermost limb's joints so that every segment
points along its own direction in the body frame, inside the joint limits, touching nothing.

How, deterministically (no randomness, no clock, fixed caps):

1. Seeds. The direction a segment points, seen from the body its location hangs on, depends
   only on the location's own joints: a grid over them is tabulated once per segment. A query
   reads the tables from the outermost segment in: a few grid points for it (the best, and
   among those as good the most different ones, so that a segment turning about itself leaves
   its inner segments every way to go), then for each the best points of the next segment, in
   the frame the outer ones leave it in; points whose segments touch something are skipped.
2. Refinement. Differential IK (one :class:`SegmentTask` per segment, a light posture task
   toward neutral, the limits and contact constraints of
   :class:`~kinesphere.services.ecl.ik.LimbSolver`): a few steps from each of the best seeds,
   then the best of them until the segments stop turning.
3. Rest. A second solve from neutral, with a heavier posture pull, may offer another way of
   pointing that keeps the joints nearer neutral: it is taken when it points as well within a
   few degrees (:meth:`ChainSolver._restful`), so a part that points alike in many ways is not
   left turned far round, with every way to and from it sweeping through the body.

Sizes follow the rule of a part whose length cannot change, the one the generator's swinging
limbs follow too (:func:`kinesphere.services.ecl.arcs.swing`): the segment turns from its
neutral direction toward the requested one by ``size / k_smax`` of the angle (far points
exactly; a segment already pointing that way holds neutral at near and the sizes above share
the turn, as a stored limb resting along its direction does); Place-Middle is the neutral
direction.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import mink
import mujoco
import numpy as np

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.lru import Lru
from kinesphere.platforms.frames import pivot
from kinesphere.platforms.mjcf import PlatformModel
from kinesphere.services.ecl.arcs import swing
from kinesphere.services.ecl.balance import Balance
from kinesphere.services.ecl.constraints import GAIN
from kinesphere.services.ecl.ik import LimbSolver
from kinesphere.services.ecl.measure import points_along, tip_point
from kinesphere.substitution import MAX_ANGLE_DEG

GRID_POINTS = 1600
"""Grid points per segment table (spread over the location's joints): ~4 degrees of each of
two joints' typical range, tabulated once in ~50 ms."""
GRID_JOINTS = 4
"""Joints of a location the grid spans at most (a palm's many finger joints stay at neutral):
the table never holds more than about 2 * GRID_POINTS points."""
CANDIDATES = 3
"""Seeds kept per segment: the best grid point and the next best ones that differ from it."""
SCAN = 400
"""Grid points looked at per segment and seed, best first, for clean candidates."""
TIE_DEG = 3.0
"""Grid points pointing this close to the best one count as equally good."""
DISTINCT = 0.5
"""Radians (largest joint difference) that make two grid points different seeds."""
REFINED = 4
"""Seeds tried at most (TRIAL steps each), best first, while none is within GOOD_DEG."""
TRIAL = 10
"""Differential IK steps a seed gets before the best one is refined further."""
GOOD_DEG = 2.0
"""A trial whose every segment is this close needs no other seed."""
ITERATIONS = 60
"""Differential IK steps of the refinement at most."""
SETTLED_DEG = 0.05
"""The refinement stops when no segment turned more than this in a step."""
POSTURE = 0.01
"""Posture weight per radian, against 1 per unit of direction error (about a radian)."""
RESTFUL = 20.0
"""How many times heavier the posture weighs in the second solve, from neutral
(:meth:`ChainSolver._restful`)."""
NEAR_DEG = 4.0
"""Degrees a pose nearer neutral may point worse than the best found and still be chosen."""
SOLUTIONS = 4096
"""Solutions remembered per platform at most."""
SOLUTION_BYTES = 16 << 20
"""Bytes of remembered solutions per platform at most: a key holds the placed joints of the
rest of the body, up to every joint of a large brought robot."""
ENTRY_BYTES = 96
"""What one joint value, segment or angle of a remembered solution costs, about (name, float,
tuple slot): the measure the byte bound counts in."""
Placed = tuple[tuple[str, float], ...]
"""Joint values of the rest of the body a solution was found with (empty: all neutral)."""


@dataclass(frozen=True)
class Segment:
    """One named part of a chain: from ``origin``'s pivot to ``end``'s pivot (a deeper joint
    location), or to the limb's tip when ``end`` is None; pointed toward ``direction``."""

    limb: str
    origin: str
    end: str | None
    direction: Direction
    size: float


@dataclass(frozen=True)
class Solution:
    """The outermost limb's joints and, per segment, the angle in degrees between where it
    points and where it was sent (its direction turned by its size); ``measured``, per
    segment, the angle between where it points and the direction asked (what
    ``Pose.measured_angle`` reports; None for Place-Middle, which has no bearing);
    ``topples`` says why the pose would tip a standing body over (:mod:`balance`), None when
    it stands."""

    joints: dict[str, float]
    angles: tuple[float, ...]
    topples: str | None = None
    measured: tuple[float | None, ...] = ()


class _Point:
    """A point fixed on a body (``body`` 0: the world), with its Jacobian."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, body: int,
                 world: np.ndarray) -> None:
        self.model, self.body = model, body
        rot = data.xmat[body].reshape(3, 3)
        self.local = rot.T @ (world - data.xpos[body])
        self._jac = np.zeros((3, model.nv))

    def position(self, data: mujoco.MjData) -> np.ndarray:
        return np.asarray(data.xpos[self.body] + data.xmat[self.body].reshape(3, 3) @ self.local)

    def jacobian(self, data: mujoco.MjData) -> np.ndarray:
        if self.body:
            mujoco.mj_jac(self.model, data, self._jac, None, self.position(data), self.body)
        return self._jac


class SegmentTask(mink.Task):
    """Point the segment from ``start`` to ``end`` along ``target`` (a world unit vector).

    The error is the unit segment minus the target, so it is measured in radians for small
    angles whatever the segment's length; its Jacobian is the tangent part of the end's
    motion relative to the start's, over the length.
    """

    def __init__(self, start: _Point, end: _Point) -> None:
        super().__init__(cost=np.ones(3), gain=GAIN, lm_damping=1e-3)
        self.start, self.end = start, end
        self.target = np.array([1.0, 0.0, 0.0])

    def unit(self, data: mujoco.MjData) -> tuple[np.ndarray, float]:
        v = self.end.position(data) - self.start.position(data)
        n = max(float(np.linalg.norm(v)), 1e-9)
        return v / n, n

    def compute_error(self, configuration: mink.Configuration) -> np.ndarray:
        u, _ = self.unit(configuration.data)
        return np.asarray(u - self.target)

    def compute_jacobian(self, configuration: mink.Configuration) -> np.ndarray:
        data = configuration.data
        u, n = self.unit(data)
        rel = self.end.jacobian(data) - self.start.jacobian(data)
        return np.asarray((np.eye(3) - np.outer(u, u)) @ rel / n)


@dataclass(frozen=True)
class _Table:
    """A segment's grid: location joint values and the unit directions they give, in the
    frame of the body the location hangs on."""

    body: int
    joints: np.ndarray  # indices into the limb solver's joints
    values: np.ndarray  # (n, len(joints))
    units: np.ndarray  # (n, 3)


def sized(neutral: np.ndarray, d: Direction, size: float, sizes: Sequence[float]
          ) -> np.ndarray:
    """Where a segment (a part of fixed length, unit ``neutral`` bearing) points at ``size``:
    the swing rule of the stored sizes too (:func:`kinesphere.services.ecl.arcs.swing`, far
    being ``d`` itself): turned toward ``d`` by ``size / k_smax`` of the angle, over the top
    from the opposite direction; a segment already pointing that way holds neutral at the
    smallest size. Place-Middle is the neutral direction."""
    if d is Direction.PLACE_MIDDLE:
        return neutral
    v = np.asarray(d.vector, dtype=float)
    v = v / np.linalg.norm(v)
    return swing(neutral, v, size, sizes, points_along(neutral, v)).offset


def degrees(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, float(a @ b)))))


def _measured(unit: np.ndarray, d: Direction) -> float | None:
    """Degrees between a segment's bearing (a unit vector, body frame) and the direction
    asked; None for Place-Middle (no bearing to compare)."""
    if d is Direction.PLACE_MIDDLE:
        return None
    v = np.asarray(d.vector, dtype=float)
    return round(degrees(unit, v / np.linalg.norm(v)), 3)


class ChainSolver:
    """The nested parts of one outermost limb: its joints, limits and contacts (from a
    :class:`LimbSolver`), one table per segment shape, reused for every query."""

    def __init__(self, pm: PlatformModel, limb: str, origin: str,
                 max_angle: float = MAX_ANGLE_DEG) -> None:
        self.pm = pm
        self.max_angle = max_angle
        """Degrees past which a segment is refused: a pose nearer neutral never crosses it."""
        self.limb = LimbSolver(pm, limb, origin)
        ls = self.limb
        self.model = pm.model
        self.data = ls.config.data
        dofs = [pm.dof_index[j] for j, go in zip(ls.joints, ls.moving, strict=True) if go]
        self._posture = np.zeros(self.model.nv)
        self._posture[dofs] = POSTURE
        ls.config.update(ls.neutral)
        self._origin = ls.origin.copy()
        self._points: dict[str, _Point] = {}
        self._tables: dict[tuple[str, str | None, str], _Table] = {}
        self._scratch = mujoco.MjData(self.model)
        self.balance = Balance(pm)

    # -- the points segments run between ---------------------------------------------------------
    def _at_neutral(self) -> mujoco.MjData:
        self.limb.config.update(self.limb.neutral)
        return self.data

    def point(self, name: str, first: bool = False) -> _Point:
        """A location's pivot (``distal_*``), fixed on the body its first joint hangs on (the
        world for the chain's own origin), or a limb's tip (``limb_*``)."""
        key = f"{name}/{first}"
        hit = self._points.get(key)
        if hit is not None:
            return hit
        m, e = self.model, self.pm.platform.eurdf
        data = self._at_neutral()
        if name.startswith("limb_"):
            body = m.body(e.tip_link(name)).id
            world = data.xpos[body] + data.xmat[body].reshape(3, 3) @ tip_point(m, body)
        else:
            joints = e.origin(name).joints
            world = self._origin if first else pivot(m, data, joints)
            body = 0 if first else int(m.jnt_bodyid[m.joint(joints[0]).id])
        p = self._points[key] = _Point(m, data, body, np.asarray(world))
        return p

    def tasks(self, segments: Sequence[Segment]) -> list[SegmentTask]:
        return [SegmentTask(self.point(s.origin, first=i == 0), self.point(end))
                for i, (s, end) in enumerate(zip(segments, self.ends(segments), strict=True))]

    # -- seeds --------------------------------------------------------------------------------
    def _table(self, seg: Segment, task: SegmentTask, end: str) -> _Table:
        """The segment's directions over a grid of its location's moving joints, in the frame
        of the body the location hangs on (computed once per segment shape)."""
        key = (seg.origin, seg.end, end)
        hit = self._tables.get(key)
        if hit is not None:
            return hit
        ls, m, e = self.limb, self.model, self.pm.platform.eurdf
        idx = [ls.joints.index(j) for j in e.origin(seg.origin).joints
               if j in ls.joints and ls.moving[ls.joints.index(j)]][:GRID_JOINTS]
        lo, hi = ls.lower[idx], ls.upper[idx]
        lo = np.where(np.isfinite(lo), lo, -math.pi)
        hi = np.where(np.isfinite(hi), hi, math.pi)
        per = max(2, int(round(GRID_POINTS ** (1.0 / max(len(idx), 1)))))
        axes = [np.linspace(a, b, per) for a, b in zip(lo, hi, strict=True)]
        values = (np.array(np.meshgrid(*axes, indexing="ij")).reshape(len(idx), -1).T
                  if idx else np.zeros((1, 0)))
        base = ls.neutral[ls.qadr].copy()
        data = self._scratch
        body = int(m.body_parentid[m.jnt_bodyid[m.joint(e.origin(seg.origin).joints[0]).id]])
        units = np.empty((len(values), 3))
        for k, v in enumerate(values):
            q = base.copy()
            q[idx] = v
            data.qpos[:] = ls.full_q(q)
            mujoco.mj_kinematics(m, data)
            u, _ = task.unit(data)
            units[k] = data.xmat[body].reshape(3, 3).T @ u
        table = self._tables[key] = _Table(body, np.array(idx, dtype=int), values, units)
        return table

    def _best(self, table: _Table, target_world: np.ndarray, q: np.ndarray,
              placed: frozenset[int] | None) -> list[np.ndarray]:
        """Up to CANDIDATES limb joint vectors: ``q`` with grid points of the table that point
        best toward ``target_world`` (as seen from the table's body in configuration ``q``)
        and touch nothing with the ``placed`` bodies (None: the whole limb, and the floor).

        The first is the best; the others are the ones farthest from those picked (in joint
        space) among the grid points within TIE_DEG of the best, so a segment that points
        alike in many ways (one that turns about itself) leaves its inner segments every way
        to go; then, if too few, the next best that differ by more than DISTINCT."""
        ls, data = self.limb, self._scratch
        data.qpos[:] = ls.full_q(q)
        mujoco.mj_kinematics(self.model, data)
        local = data.xmat[table.body].reshape(3, 3).T @ target_world
        cosines = table.units @ local
        order = np.argsort(-cosines, kind="stable")
        tie = math.cos(math.radians(min(degrees(table.units[order[0]], local) + TIE_DEG, 180.0)))
        ties = order[: int(np.count_nonzero(cosines >= tie))]
        step = max(1, len(ties) // SCAN)  # an even spread of a large tie, the best first
        near = [int(k) for k in ties[::step]]
        order = order[:SCAN]
        picked: list[int] = []
        out: list[np.ndarray] = []

        def clean(k: int) -> bool:
            nq = q.copy()
            nq[table.joints] = table.values[k]
            if self._touches(nq, placed):
                return False
            picked.append(k)
            out.append(nq)
            return True

        while near and len(out) < CANDIDATES:
            if not picked:
                k = near.pop(0)
            else:
                gaps = [min(float(np.max(np.abs(table.values[k] - table.values[p])))
                            for p in picked) for k in near]
                i = int(np.argmax(gaps))
                if gaps[i] <= DISTINCT:
                    break
                k = near.pop(i)
            clean(k)
        for k in order:
            if len(out) == CANDIDATES:
                break
            if all(float(np.max(np.abs(table.values[k] - table.values[p]))) > DISTINCT
                   for p in picked):
                clean(int(k))
        return out

    def _touches(self, values: np.ndarray, bodies: frozenset[int] | None) -> bool:
        """Whether ``bodies`` touch anything (None: the limb's full check, floor included)."""
        if bodies is None:
            return self.limb.collides(self.limb.full_q(values)) is not None
        m, data = self.model, self._scratch
        data.qpos[:] = self.limb.full_q(values)
        mujoco.mj_kinematics(m, data)
        mujoco.mj_collision(m, data)
        pairs = m.geom_bodyid[data.contact.geom[: data.ncon]]
        return bool(np.isin(pairs, list(bodies)).any())

    def _placed(self, segments: Sequence[Segment], ends: list[str]) -> list[frozenset[int] | None]:
        """Per segment, the bodies placed once it is: its own and the outer ones' (the
        links between its origin and its end); None for the last (the whole limb)."""
        m, e = self.model, self.pm.platform.eurdf
        out: list[frozenset[int] | None] = []
        placed: set[str] = set()
        for seg, end in zip(segments, ends, strict=True):
            links = set(e.limb(seg.limb).links)
            inner = next((p for p in e.limbs if p.distal == end), None)
            placed |= links - set(inner.links) if inner is not None else links
            out.append(frozenset(m.body(n).id for n in placed))
        out[-1] = None
        return out

    def _seeds(self, segments: Sequence[Segment], tasks: list[SegmentTask],
               targets: list[np.ndarray]) -> list[np.ndarray]:
        ends = self.ends(segments)
        seeds = [self.limb.neutral[self.limb.qadr].copy()]
        for i, (seg, placed) in enumerate(zip(segments, self._placed(segments, ends),
                                              strict=True)):
            table = self._table(seg, tasks[i], ends[i])
            keep = CANDIDATES if i == 0 else 2  # the outermost segment branches most
            # a seed whose next segment finds no clean grid point is kept as it is
            seeds = [nq for q in seeds
                     for nq in self._best(table, targets[i], q, placed)[:keep] or [q]]
        return seeds

    @staticmethod
    def ends(segments: Sequence[Segment]) -> list[str]:
        """Where each segment ends: its own end, the next part's origin, or its limb's tip."""
        return [s.end if s.end is not None else (
            segments[i + 1].origin if i + 1 < len(segments) else s.limb)
            for i, s in enumerate(segments)]

    # -- solving ------------------------------------------------------------------------------
    def _score(self, tasks: list[SegmentTask], targets: list[np.ndarray], q: np.ndarray,
               ) -> tuple[float, float]:
        data = self._scratch
        data.qpos[:] = self.limb.full_q(q)
        mujoco.mj_kinematics(self.model, data)
        angles = [degrees(t.unit(data)[0], g) for t, g in zip(tasks, targets, strict=True)]
        return max(angles), sum(angles)

    def neutral_units(self, tasks: list[SegmentTask]) -> list[np.ndarray]:
        data = self._at_neutral()
        rot = self.limb.body_rot
        return [rot.T @ t.unit(data)[0] for t in tasks]

    def solve(self, segments: Sequence[Segment], sizes: Sequence[float]) -> Solution:
        ls = self.limb
        tasks = self.tasks(segments)
        rot = ls.body_rot
        targets = [rot @ sized(n, s.direction, s.size, sizes)
                   for n, s in zip(self.neutral_units(tasks), segments, strict=True)]
        seeds = self._seeds(segments, tasks, targets) or [ls.neutral[ls.qadr].copy()]
        seeds.sort(key=lambda q: self._score(tasks, targets, q))
        # a few steps from each seed, best first, unless one is already where told; then the
        # best of them all the way
        tried = []
        for seed in seeds[:REFINED]:
            found = self._refine(tasks, targets, seed, TRIAL)
            tried.append((self._score(tasks, targets, found), found))
            if tried[-1][0][0] <= GOOD_DEG:
                break
        _, best = min(tried, key=lambda t: t[0])
        values = self._restful(tasks, targets, self._refine(tasks, targets, best, ITERATIONS))
        data = self._scratch
        data.qpos[:] = ls.full_q(values)
        mujoco.mj_kinematics(self.model, data)
        units = [t.unit(data)[0] for t in tasks]
        angles = tuple(round(degrees(u, g), 3) for u, g in zip(units, targets, strict=True))
        measured = tuple(_measured(rot.T @ u, s.direction) for u, s in zip(units, segments,
                                                                            strict=True))
        joints = {j: round(float(v), 6) for j, v in zip(ls.joints, values, strict=True)}
        return Solution(joints, angles, self.balance.check(ls.full_q(values)), measured)

    def _restful(self, tasks: list[SegmentTask], targets: list[np.ndarray],
                 values: np.ndarray) -> np.ndarray:
        """``values`` as they stand, or another way of pointing nearer neutral: solved from
        neutral with the posture RESTFUL times heavier, it is chosen when it differs by more
        than DISTINCT somewhere (not the same pose pulled toward neutral), moves no joint as far
        from neutral, points within NEAR_DEG as well (never past the refusal bound where
        ``values`` is within it) and stands wherever ``values`` stands.

        Where a part points alike in many ways (a straight forearm turning about the upper
        arm, a wrist about itself) the seeds may find it turned far round: NAO's hanging arms
        came out with the elbow and wrist yawed ~3 rad from neutral, so every straight way to
        and from them swept the hand through the thigh."""
        ls = self.limb
        home = ls.neutral[ls.qadr]
        best = self._stood(values)
        calm = self._stood(self._refine(tasks, targets, home.copy(), ITERATIONS, RESTFUL))
        worst, worst_calm = self._score(tasks, targets, best)[0], self._score(tasks, targets,
                                                                             calm)[0]
        if (np.max(np.abs(calm - best)) > DISTINCT
                and np.max(np.abs(calm - home)) < np.max(np.abs(best - home))
                and worst_calm <= worst + NEAR_DEG
                and (worst_calm <= self.max_angle or worst > self.max_angle)
                and (self.balance.check(ls.full_q(calm)) is None
                     or self.balance.check(ls.full_q(best)) is not None)):
            return calm
        return best

    def _stood(self, values: np.ndarray) -> np.ndarray:
        """``values`` as they stand: a leg lifted so far that the body would topple on the
        foot left down gets its stance leg carrying the body over that foot, by the support
        rule of stored leg rows (:meth:`LimbSolver.balanced`: a centre-of-mass task, the sole
        flat on the floor, the pointed segments still); anything that stands, or has no stance
        leg, as it is. What still topples is refused by :meth:`Nested.solve`."""
        ls = self.limb
        if not ls.stance or self.balance.check(ls.full_q(values)) is None:
            return values
        return ls.balanced(values)

    def _refine(self, tasks: list[SegmentTask], targets: list[np.ndarray], start: np.ndarray,
                iterations: int, posture: float = 1.0) -> np.ndarray:
        ls = self.limb
        for t, g in zip(tasks, targets, strict=True):
            t.target = g
        ls.posture.set_cost(self._posture * posture)
        ls.posture.set_target(ls.neutral)
        q = ls.full_q(start)
        ls.config.update(q)
        values = start.copy()
        before = [t.unit(ls.config.data)[0] for t in tasks]
        for _ in range(iterations):
            found = ls.ik_step([*tasks, ls.posture], ls.limits, ls.constraints)
            if found is None:
                break
            nxt = ls.clean(values, found[1])
            if nxt is None:
                break
            values = nxt
            ls.config.update(ls.full_q(values))
            now = [t.unit(ls.config.data)[0] for t in tasks]
            turned = max(degrees(a, b) for a, b in zip(now, before, strict=True))
            before = now
            if turned < SETTLED_DEG:
                break
        return values


class Nested:
    """Every nested solve of one platform: a :class:`ChainSolver` per outermost limb, made
    when first asked, and the solutions already found (bounded, least recently used first
    out). One solve at a time (the databank runs them on one worker thread anyway)."""

    def __init__(self, pm: PlatformModel, sizes: Sequence[int],
                 max_angle: float = MAX_ANGLE_DEG) -> None:
        self.pm = pm
        self.sizes = tuple(sizes)
        """The VSAM's sizes, near to far (k_smax): a segment's size rule."""
        self.max_angle = max_angle
        self._chains: dict[tuple[str, str], ChainSolver] = {}
        self._solutions: Lru[tuple[tuple[Segment, ...], Placed], Solution] = Lru(
            SOLUTIONS, SOLUTION_BYTES, solution_bytes)
        self._lock = threading.Lock()
        self.solves = 0
        """Solves computed (not remembered), for tests and benches."""

    def _placed(self, segments: Sequence[Segment], placed: Mapping[str, float] | None
                ) -> Placed:
        """The joints of the rest of the body that stand away from neutral (those of the
        chain's own limb are its to choose), as a cache key."""
        if not placed:
            return ()
        own = set(self.pm.platform.eurdf.limb_joints(segments[0].limb))
        neutral = self.pm.platform.neutral
        return tuple(sorted((j, v) for j, v in placed.items()
                            if j not in own and v != neutral.get(j, 0.0)))

    def solve(self, segments: Sequence[Segment], placed: Mapping[str, float] | None = None
              ) -> Solution:
        """The joints pointing every segment where told, touching nothing of the body as
        ``placed`` stands it (joint values of other limbs; neutral elsewhere), or
        ``direction_unavailable`` naming the segment that stays more than ``max_angle``
        degrees away."""
        key = (tuple(segments), self._placed(segments, placed))
        with self._lock:
            hit = self._solutions.get(key)
            if hit is None:
                outer = segments[0]
                chain = self._chains.get((outer.limb, outer.origin))
                if chain is None:
                    chain = self._chains[(outer.limb, outer.origin)] = ChainSolver(
                        self.pm, outer.limb, outer.origin, self.max_angle)
                with chain.limb.placing(dict(key[1])):
                    hit = chain.solve(segments, self.sizes)
                self.solves += 1
                self._solutions.put(key, hit)
        for s, angle in zip(segments, hit.angles, strict=True):
            if angle > self.max_angle:
                raise KinesphereError(
                    "direction_unavailable", f"{_named(s)} points {angle:.0f} degrees away "
                    f"from {s.direction.slug} at best (with the other parts where told); more "
                    f"than {self.max_angle:g} degrees is another movement",
                )
        if hit.topples is not None:
            raise KinesphereError(
                "direction_unavailable", f"{', '.join(map(_named, segments))} pointed so would "
                f"tip the body over ({hit.topples})",
            )
        return hit


def _named(s: Segment) -> str:
    return f"{s.limb} from {s.origin}" + (f" to {s.end}" if s.end else "")


def solution_bytes(key: tuple[tuple[Segment, ...], Placed], solution: Solution) -> int:
    """What a remembered solution costs, about: its placed joints, segments, joints and
    angles, :data:`ENTRY_BYTES` each."""
    segments, placed = key
    items = len(segments) + len(placed) + len(solution.joints) + len(solution.angles)
    return ENTRY_BYTES * (items + len(solution.measured) + 1)
