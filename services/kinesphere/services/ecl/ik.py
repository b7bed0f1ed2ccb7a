"""Differential IK for one limb of a platform's MuJoCo model, with mink.

Why a class per limb: Algorithm 1 needs the same constrained solve hundreds of times per
platform (one per direction and size), so the mink problem for a (limb, origin) pair is set
up once and reused: a point task on the limb's distal end, a light posture task toward neutral
(natural postures, and a unique answer for redundant arms), joint limits, a per-iteration joint
step limit, distance limits against the rest of the robot and the floor, and every other DOF
frozen exactly (mink's DofFreezingTask as an equality constraint). A step that would still
touch anything is halved or refused, so every returned pose is clean. Deterministic: no
randomness, no wall clock, only iteration caps and convergence tests.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import mink
import mujoco
import numpy as np

from kinesphere.platforms.frames import pivot
from kinesphere.platforms.mjcf import PlatformModel
from kinesphere.services.ecl.constraints import (
    GAIN,
    FloorLimit,
    MovingJointLimit,
    OverSoleTask,
    PairDistanceLimit,
    PointTask,
)
from kinesphere.services.ecl.measure import TOUCH, Fk, samples, tip_point

SOLVER = "daqp"
DAMPING = 1e-2  # Levenberg-Marquardt damping: keeps stretched (singular) arms calm
JOINT_STEP = 0.08  # rad per iteration, so no link moves farther than the detection distance
LIMIT_MARGIN = 0.01  # rad kept from every joint limit during the solve
FLOOR_TOLERANCE = 1e-3  # metres a limb geom may dip below z = 0 (rounding)
POSTURE = 0.02  # posture weight per radian, against 1 per metre of tip error
CONVERGED = 1e-3  # rad: a joint step this small everywhere counts as converged ...
SETTLED = 2e-4  # spans: ... and so does a tip that moved less (null-space creep only)
PATH_CLEARANCE = 0.0  # m kept along straight joint-space paths (0: they must not touch)
PATH_STEP = 0.05  # rad between the samples of such a path
DITHER = 0.1  # a step this close to minus the previous one means a period-2 bounce
RETRIES = (0.5, 0.25)  # fractions of a step tried when the full step would touch something
COM = 50.0  # weight per metre of the centre of mass off the stance soles' centre
STANCE_HEIGHT = 200.0  # weight per metre of a stance sole lifting or sinking ...
STANCE_TILT = 20.0  # ... and per radian of its tilting: it stays flat on the floor
BALANCE_ITERATIONS = 60
JOINED = 0.004  # metres: a link this close to its grandparent at neutral is joined to it


@dataclass(frozen=True)
class Reach:
    """Where a pose puts the limb's distal end."""

    tip: np.ndarray  # world
    offset: np.ndarray  # tip - origin, body frame


def chain_span(
    model: mujoco.MjModel, data: mujoco.MjData, origin: np.ndarray, tip: np.ndarray,
    tip_body: int, bodies: frozenset[int],
) -> float:
    """An upper bound on how far a limb's distal end can get from its origin: the length of
    the joint-anchor path from the origin to the tip (a fully stretched chain)."""
    body, anchors = tip_body, []
    while body > 0 and body in bodies:
        for j in range(model.body_jntadr[body], model.body_jntadr[body] + model.body_jntnum[body]):
            anchors.append(data.xanchor[j].copy())
        body = int(model.body_parentid[body])
    total, prev = 0.0, origin
    for p in [*reversed(anchors), tip]:
        total += float(np.linalg.norm(p - prev))
        prev = p
    return total


class LimbSolver:
    """One (limb, origin) pair of a platform, ready for repeated IK solves."""

    def __init__(self, pm: PlatformModel, limb: str, origin: str) -> None:
        model, eurdf = pm.model, pm.platform.eurdf
        self.pm = pm
        self.model = model
        links = set(eurdf.limb(limb).links)
        stance, chain = _stance(pm, links)
        support = _actuated(pm, chain)
        # the limb's own joints first; then, for a leg that bears weight at neutral, the
        # joints of the other legs, which keep the body over the stance foot (``support``)
        self.joints = eurdf.limb_joints(limb) + support
        self.limb_count = len(eurdf.limb_joints(limb))
        self.origin_label = origin
        self.qadr = np.array([pm.qpos_index[j] for j in self.joints], dtype=int)
        self.lower = np.array([eurdf.limits[j].lower for j in self.joints])
        self.upper = np.array([eurdf.limits[j].upper for j in self.joints])
        # a joint that also drives a mimic joint outside the limb (NAO's hip yaw-pitch turns
        # both hips) would move another limb: it stays at neutral in this limb's poses
        held = {model.body(b).name for b in chain}
        self.moving = np.array([
            all(eurdf.urdf.joint_map[f].child in (links if i < self.limb_count else held)
                for f in eurdf.followers(j))
            for i, j in enumerate(self.joints)
        ], dtype=bool)
        self._mimics = [
            (pm.qpos_index[m.joint], self.joints.index(m.leader), m)
            for m in eurdf.mimics.values() if m.leader in self.joints
        ]
        dofs = [pm.dof_index[j] for j, go in zip(self.joints, self.moving, strict=True) if go]
        self._dof_adr = np.array(dofs, dtype=int)
        limb_dofs = [pm.dof_index[j] for j, go in
                     zip(self.joints[: self.limb_count], self.moving, strict=False) if go]
        support_dofs = [d for d in dofs if d not in limb_dofs]
        self.neutral = pm.neutral_qpos()
        self.config = mink.Configuration(model, self.neutral.copy())
        data = self.config.data
        tip_body = model.body(eurdf.tip_link(limb)).id
        self.tip_task = PointTask(model, tip_body, tip_point(model, tip_body))
        self.body_rot = data.xmat[model.body(eurdf.root_link).id].reshape(3, 3).copy()
        self.origin = pivot(model, data, eurdf.origin(origin).joints)
        self.limb_bodies = frozenset(model.body(name).id for name in links)
        self.bodies = self.limb_bodies | chain  # everything that moves
        self._neutral_reach = self.reach(self.neutral)
        self.span = self._span()
        scale = max(self.span, 1e-3)  # a tip on its origin cannot point; generate drops it
        self.tip_task = PointTask(model, tip_body, self.tip_task.point, scale=scale)
        self._posture_mask = np.zeros(model.nv)
        self._posture_mask[limb_dofs] = 1.0
        self._support_mask = np.zeros(model.nv)
        self._support_mask[support_dofs] = 1.0
        self.posture = mink.PostureTask(model, cost=self._posture_mask * POSTURE, gain=GAIN)
        self.posture.set_target(self.neutral)
        self._floor = model.geom("floor").id
        self._fromto = np.zeros(6)
        self._limb_geoms = np.array(
            [g for g in range(model.ngeom)
             if model.geom_contype[g] and model.geom_bodyid[g] in self.bodies],
            dtype=int,
        )
        moving = [j for j, go in zip(self.joints, self.moving, strict=True) if go]
        # the limb's solves watch the limb's geoms, the balance solves the stance legs' (a
        # frozen body's rows would be all zero): the same limits, each on what moves
        self.limits = self._limits(self.limb_bodies, moving)
        self._balance_limits = self._limits(chain, moving) if stance else []
        frozen = [i for i in range(model.nv) if i not in limb_dofs]
        self.constraints = [mink.DofFreezingTask(model, frozen)] if frozen else []
        still = [i for i in range(model.nv) if i not in support_dofs]
        self._balance_constraints = [mink.DofFreezingTask(model, still)] if still else []
        self.stance = stance
        self._balance_tasks: list[mink.Task] = []
        if stance:
            self.config.update(self.neutral)
            soles = [(body, _sole_centre(model, data, body)) for body in stance]
            self._balance_tasks.append(OverSoleTask(model, soles, COM))
            for body in stance:
                sole = mink.FrameTask(model.body(body).name, "body",
                                      position_cost=[0.0, 0.0, STANCE_HEIGHT],
                                      orientation_cost=STANCE_TILT, gain=GAIN)
                sole.set_target_from_configuration(self.config)
                self._balance_tasks.append(sole)
        self.iterations = 0
        self._path_checker()

    def _limits(self, bodies: frozenset[int], moving: list[str]) -> list[mink.Limit]:
        """Joint limits, a joint step limit, the floor and distance limits for ``bodies``."""
        model = self.model
        geoms = [int(g) for g in self._limb_geoms if model.geom_bodyid[g] in bodies]
        limits: list[mink.Limit] = [
            MovingJointLimit(model, self._dof_adr, gain=0.9, margin=LIMIT_MARGIN),
            mink.VelocityLimit(model, {j: JOINT_STEP for j in moving}),
            FloorLimit(model, geoms),
        ]
        pairs = self._distance_pairs(geoms)
        if pairs:
            limits.append(PairDistanceLimit(model, self.config.data, pairs, self.bodies))
        return limits

    def _distance_pairs(self, geoms: list[int]) -> list[tuple[int, int]]:
        """Geom pairs (limb vs robot) that MuJoCo would collide in the compiled model, but
        for a link and its grandparent already touching at neutral (NAO's hip motor in its
        torso socket): linearised, turning the joint between them looks like closing in, so
        they are left to the contact test of every step, which lets the joint turn as long as
        neither presses into the other."""
        m = self.model
        data = mujoco.MjData(m)
        data.qpos[:] = self.neutral
        mujoco.mj_kinematics(m, data)
        excluded = {frozenset(p) for p in self.pm.excluded_pairs}
        colliding = [g for g in range(m.ngeom) if m.geom_contype[g] and g != self._floor]
        weld, parent = m.body_weldid, m.body_parentid
        pairs: list[tuple[int, int]] = []
        mine = set(geoms)
        for a in geoms:
            for b in colliding:
                ba, bb = int(m.geom_bodyid[a]), int(m.geom_bodyid[b])
                if b in mine and b <= a:
                    continue  # pairs among the watched geoms once
                wa, wb = weld[ba], weld[bb]
                if wa == wb or weld[parent[wa]] == wb or weld[parent[wb]] == wa:
                    continue  # same rigid body or parent/child: MuJoCo never collides them
                if frozenset((m.body(ba).name, m.body(bb).name)) in excluded:
                    continue
                if (weld[parent[parent[wa]]] == wb or weld[parent[parent[wb]]] == wa) and (
                        mujoco.mj_geomDistance(m, data, int(a), b, JOINED, self._fromto)
                        < JOINED):
                    continue
                pairs.append((int(a), b))
        return pairs

    @contextmanager
    def placing(self, joints: Mapping[str, float]) -> Iterator[None]:
        """Within the block, the rest of the body stands as ``joints`` place it (others at
        neutral) instead of all at neutral: every pose, contact and path test of the limb
        sees it so (another arm already answered in the same compound)."""
        own = set(self.joints)
        rest = {j: v for j, v in joints.items() if j not in own and j in self.pm.qpos_index}
        if not rest:
            yield
            return
        neutral = self.neutral
        self.neutral = neutral.copy()
        for j, v in rest.items():
            self.neutral[self.pm.qpos_index[j]] = v
        try:
            yield
        finally:
            self.neutral = neutral

    # --- queries ---------------------------------------------------------------------------
    def full_q(self, values: np.ndarray) -> np.ndarray:
        """Neutral everywhere except the limb's joints (and mimic joints following them)."""
        q: np.ndarray = self.neutral.copy()
        q[self.qadr] = values
        for adr, leader, mimic in self._mimics:
            q[adr] = mimic.value(float(values[leader]))
        return q

    def reach(self, q: np.ndarray) -> Reach:
        self.config.update(q)
        tip = self.tip_task.position(self.config)
        return Reach(tip=tip, offset=self.body_rot.T @ (tip - self.origin))

    def neutral_reach(self) -> Reach:
        return self._neutral_reach

    def _span(self) -> float:
        self.config.update(self.neutral)
        return chain_span(self.model, self.config.data, self.origin,
                          self._neutral_reach.tip, self.tip_task.body, self.bodies)

    def collides(self, q: np.ndarray) -> str | None:
        """Why a pose is not allowed (a robot self-contact or a geom under the floor), or None."""
        m, data = self.model, self.config.data
        self.config.update(q)
        mujoco.mj_collision(m, data)
        for c in data.contact[: data.ncon]:
            b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
            if b1 in self.bodies or b2 in self.bodies:
                return f"contact {m.body(b1).name}/{m.body(b2).name}"
        geoms = self._limb_geoms
        for g in geoms[data.geom_xpos[geoms, 2] < m.geom_rbound[geoms] + FLOOR_TOLERANCE]:
            dist = mujoco.mj_geomDistance(m, data, self._floor, int(g), 0.05, self._fromto)
            if dist < -FLOOR_TOLERANCE:
                return f"{m.body(m.geom_bodyid[g]).name} below the floor"
        return None

    def path_touches(self, a: np.ndarray, b: np.ndarray) -> str | None:
        """Why the straight joint-space path between two limb poses is unsafe, or None.

        f_SB interpolates between stored sizes and robots move roughly straight in joint
        space, so the path must keep PATH_CLEARANCE from other links (pairs already that
        close at neutral only must not touch) and stay above the floor; sampled every
        PATH_STEP radians of the largest joint motion.
        """
        steps = max(2, int(np.ceil(float(np.max(np.abs(b - a))) / PATH_STEP)) + 1)
        m, data = self._path_model, self._path_data
        for t in np.linspace(0.0, 1.0, steps):
            q = self.full_q(a + t * (b - a))
            data.qpos[:] = q
            mujoco.mj_kinematics(m, data)
            mujoco.mj_collision(m, data)
            for c in data.contact[: data.ncon]:
                b1, b2 = int(m.geom_bodyid[c.geom1]), int(m.geom_bodyid[c.geom2])
                close = frozenset((int(c.geom1), int(c.geom2))) in self._close_at_neutral
                if (b1 in self.bodies or b2 in self.bodies) and (c.dist < 0 or not close):
                    return f"{m.body(b1).name}/{m.body(b2).name} touch {t:.0%} of the way"
            hit = self.collides(q)
            if hit is not None:
                return f"{hit} at {t:.0%} of the way"
        return None

    def _path_checker(self) -> None:
        """A private model copy whose geoms report contacts PATH_CLEARANCE early."""
        m = copy.deepcopy(self.model)
        m.geom_margin[:] = PATH_CLEARANCE
        self._path_model, self._path_data = m, mujoco.MjData(m)
        self._path_data.qpos[:] = self.neutral
        mujoco.mj_kinematics(m, self._path_data)
        mujoco.mj_collision(m, self._path_data)
        self._close_at_neutral = frozenset(
            frozenset((int(c.geom1), int(c.geom2)))
            for c in self._path_data.contact[: self._path_data.ncon]
        )

    def margin(self, values: np.ndarray) -> float:
        """Radians (or metres) to the nearest joint limit; pi when every joint is unlimited."""
        lo, hi = values - self.lower, self.upper - values
        finite = np.isfinite(lo) & np.isfinite(hi)
        if not finite.any():
            return float(np.pi)
        return float(np.min(np.minimum(lo[finite], hi[finite])))

    # --- solving ---------------------------------------------------------------------------
    def solve(
        self, start: np.ndarray, target: np.ndarray, iterations: int, posture: float = POSTURE,
        toward: np.ndarray | None = None,
    ) -> np.ndarray:
        """Move the distal end toward ``target`` (world) from ``start``; returns limb values.

        The posture task pulls toward ``toward`` (limb values), or neutral when None.
        """
        self.tip_task.target = np.asarray(target, dtype=float)
        self.posture.set_cost(self._posture_mask * posture)
        self.posture.set_target(self.neutral if toward is None else self.full_q(toward))
        q = self.full_q(start)
        self.config.update(q)
        last_tip = self.tip_task.position(self.config)
        scale = max(self.span, 1e-3)
        self.iterations = 0
        previous = np.zeros(len(self.joints))
        for _ in range(iterations):
            found = self.ik_step([self.tip_task, self.posture], self.limits, self.constraints)
            if found is None:
                break
            v, step = found
            if float(np.linalg.norm(step + previous)) < DITHER * float(np.linalg.norm(step)):
                step = step / 2  # bouncing across the optimum (a saturated, singular stretch):
                nxt = self._clean_step(q, step)  # settle half-way between the two and stop
                q = q if nxt is None else nxt
                break
            previous = step
            nxt = self._clean_step(q, step)
            if nxt is None:
                break  # every fraction of the step touches something: keep the last clean pose
            q = nxt
            self.iterations += 1
            tip = self.tip_task.position(self.config)
            moved = float(np.linalg.norm(tip - last_tip)) / scale
            last_tip = tip
            if float(np.max(np.abs(v))) < CONVERGED or moved < SETTLED:
                break
        self.config.update(q)
        return np.asarray(q[self.qadr].copy())

    def balanced(self, values: np.ndarray, iterations: int = BALANCE_ITERATIONS) -> np.ndarray:
        """``values`` with the stance legs moved so the centre of mass sits over the middle
        of the stance soles, which stay flat on the floor (OverSoleTask and a mink FrameTask
        per sole, the limb held still): how a person keeps balance on one leg. Unchanged for a
        limb without a stance (anything but a leg that bears weight at neutral)."""
        if not self.stance:
            return values
        self.posture.set_cost(self._support_mask * POSTURE)
        self.posture.set_target(self.neutral)
        q = self.full_q(values)
        self.config.update(q)
        for _ in range(iterations):
            found = self.ik_step([*self._balance_tasks, self.posture], self._balance_limits,
                                 self._balance_constraints)
            if found is None:
                break
            v, step = found
            nxt = self._clean_step(q, step)
            if nxt is None:
                break
            q = nxt
            if float(np.max(np.abs(v))) < CONVERGED:
                break
        self.config.update(q)
        return np.asarray(q[self.qadr].copy())

    def ik_step(self, tasks: Sequence[mink.Task], limits: Sequence[mink.Limit],
                constraints: Sequence[mink.Task]) -> tuple[np.ndarray, np.ndarray] | None:
        """One mink step toward ``tasks`` from the configuration as it stands: the velocity
        of every dof and the limb's step (its moving joints'), or None when mink finds no
        solution. Every IK loop of the generator and the nested solver steps through here;
        each keeps its own rule for when to stop."""
        try:
            v = mink.solve_ik(self.config, tasks, dt=1.0, solver=SOLVER, damping=DAMPING,
                              limits=limits, constraints=constraints)
        except mink.NoSolutionFound:
            return None
        step = np.zeros(len(self.joints))
        step[self.moving] = v[self._dof_adr]
        return v, step

    def clean(self, values: np.ndarray, step: np.ndarray) -> np.ndarray | None:
        """The limb's joint ``values`` advanced by ``step`` (hinge/slide only), or by a
        fraction of it (:data:`RETRIES`), clamped to the limits and free of contacts; None if
        no fraction is clean. The configuration is left at the answer."""
        for fraction in (1.0, *RETRIES):
            nxt: np.ndarray = np.clip(values + fraction * step, self.lower, self.upper)
            if self.collides(self.full_q(nxt)) is None:
                return nxt
        return None

    def _clean_step(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray | None:
        """:meth:`clean` of the limb's joints in the whole configuration ``q``."""
        values = self.clean(q[self.qadr], dq)
        return None if values is None else self.full_q(values)


def _stance(pm: PlatformModel, links: set[str]) -> tuple[tuple[int, ...], frozenset[int]]:
    """For a limb that bears weight at neutral on a mobile base (a leg): the other bodies
    bearing weight (the stance soles) and every body between them and the core (the stance
    legs), which hold the body over the soles while the limb moves; nothing for any other
    limb."""
    if not pm.platform.base.mobile:
        return (), frozenset()
    model, eurdf = pm.model, pm.platform.eurdf
    _, bearing = Fk(pm).margin(pm.neutral_qpos())
    if not set(bearing) & links:
        return (), frozenset()
    core = {name for part in eurdf.core for name in part.links}
    stance = tuple(model.body(name).id for name in bearing if name not in links)
    chain: set[int] = set()
    for body in stance:
        while body > 0 and model.body(body).name not in core:
            chain.add(body)
            body = int(model.body_parentid[body])
    return stance, frozenset(chain)


def _actuated(pm: PlatformModel, bodies: frozenset[int]) -> tuple[str, ...]:
    """The joints of P on ``bodies``, in P order."""
    model = pm.model
    names = {model.joint(j).name for b in bodies
             for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b])}
    return tuple(j for j in pm.platform.eurdf.joint_names if j in names)


def _sole_centre(model: mujoco.MjModel, data: mujoco.MjData, body: int) -> np.ndarray:
    """The middle of what a stance body rests on (its collision points within TOUCH of the
    floor at neutral), in the body's frame."""
    rot, pos = data.xmat[body].reshape(3, 3), data.xpos[body]
    down: list[np.ndarray] = []
    for g in range(model.ngeom):
        if model.geom_bodyid[g] == body and model.geom_contype[g]:
            for p, r in samples(model, g):
                if (pos + rot @ p)[2] - r < TOUCH:
                    down.append(p)
    return np.mean(down, axis=0) if down else np.zeros(3)
