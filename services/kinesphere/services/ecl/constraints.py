"""mink building blocks for the ECL generator: the tip task and three limits.

Why custom limits: mink's CollisionAvoidanceLimit keeps only geom pairs that pass the
contype/conaffinity test and ignores the model's excluded body pairs; the generator needs
exactly the compiled model's self-collision rules, plus the floor, which the robot never
touches in simulation (so it fails that test) but which a pose must not dip below. The floor
is handled with sample points on each geom, because a single witness point per pair lets a
flat foot rotate its toe into the ground. Joint limits are mink's, kept only on the joints that
move (see ``MovingJointLimit``).
"""

from __future__ import annotations

import mink
import mujoco
import numpy as np

from kinesphere.services.ecl.measure import sample_points

MAX_STEP = 0.4  # limb spans: the point task's error is clipped so big jumps cannot fly off
CLEARANCE = 0.01  # metres kept between the limb and other geoms (less if closer at neutral)
FOLD_CLEARANCE = 0.002  # metres kept between two links of the limb itself (an elbow folding)
DETECT = 0.08  # metres at which a distance constraint becomes active (> one step)
GAIN = 0.5  # task gains below 1 damp the period-2 dither of dead-beat steps
LIMIT_GAIN = 0.85  # fraction of the remaining gap a limit lets one step close


class PointTask(mink.Task):
    """Drive a point fixed on a body to a world position (position only, clipped steps).

    The error is measured in units of ``scale`` (the limb's span), so the same weights and
    damping behave alike on a 0.2 m NAO forearm and a 1.2 m Baxter arm.
    """

    def __init__(
        self, model: mujoco.MjModel, body: int, point: np.ndarray, scale: float = 1.0
    ) -> None:
        super().__init__(cost=np.full(3, 1.0 / scale), gain=GAIN, lm_damping=1e-3)
        self.max_step = MAX_STEP * scale
        self.body = body
        self.point = point
        self.target = np.zeros(3)
        self._jac = np.zeros((3, model.nv))

    def position(self, configuration: mink.Configuration) -> np.ndarray:
        data = configuration.data
        return np.asarray(data.xpos[self.body] + data.xmat[self.body].reshape(3, 3) @ self.point)

    def compute_error(self, configuration: mink.Configuration) -> np.ndarray:
        err = self.position(configuration) - self.target
        norm = float(np.linalg.norm(err))
        return err if norm <= self.max_step else err * (self.max_step / norm)

    def compute_jacobian(self, configuration: mink.Configuration) -> np.ndarray:
        pos = self.position(configuration)
        mujoco.mj_jac(configuration.model, configuration.data, self._jac, None, pos, self.body)
        return self._jac


class OverSoleTask(mink.Task):
    """Hold the whole-body centre of mass over the middle of the stance soles (x, y).

    Both ends move: the stance leg shifts the body over its foot, which (the torso being the
    model's fixed root) shows as the foot sliding under the centre of mass. So the error is
    centre of mass minus sole centre, and its Jacobian the difference of theirs (mink's
    ComTask has a fixed target, which would roll the stance leg the wrong way).
    """

    def __init__(self, model: mujoco.MjModel, soles: list[tuple[int, np.ndarray]],
                 cost: float) -> None:
        super().__init__(cost=np.full(2, cost), gain=GAIN, lm_damping=1e-3)
        self.soles = soles
        self._jac = np.zeros((3, model.nv))
        self._com = np.zeros((3, model.nv))

    def _centre(self, data: mujoco.MjData) -> np.ndarray:
        return np.asarray(np.mean(
            [data.xpos[b] + data.xmat[b].reshape(3, 3) @ p for b, p in self.soles], axis=0))

    def compute_error(self, configuration: mink.Configuration) -> np.ndarray:
        data = configuration.data
        return np.asarray((data.subtree_com[1] - self._centre(data))[:2])

    def compute_jacobian(self, configuration: mink.Configuration) -> np.ndarray:
        model, data = configuration.model, configuration.data
        mujoco.mj_jacSubtreeCom(model, data, self._com, 1)
        sole = np.zeros_like(self._com)
        for body, point in self.soles:
            world = data.xpos[body] + data.xmat[body].reshape(3, 3) @ point
            mujoco.mj_jac(model, data, self._jac, None, world, body)
            sole += self._jac / len(self.soles)
        return np.asarray((self._com - sole)[:2])


class MovingJointLimit(mink.ConfigurationLimit):
    """mink's joint limits, kept on the DoFs ``dofs`` only.

    A joint the solve freezes is held exactly by the freezing constraint; its limit row would
    add nothing, unless its range is narrower than twice the margin kept from the limits
    (TIAGo's +-5 mm suspension joints against a 1 cm margin), where the row has no solution
    and every step of every limb fails.
    """

    def __init__(
        self, model: mujoco.MjModel, dofs: np.ndarray, gain: float, margin: float
    ) -> None:
        super().__init__(model, gain=gain, min_distance_from_limits=margin)
        indices = self.indices[np.isin(self.indices, dofs)]
        indices.setflags(write=False)
        self.indices = indices
        self.projection_matrix = np.eye(model.nv)[indices] if len(indices) else None


class PairDistanceLimit(mink.Limit):
    """Keep listed geom pairs apart, like mink's CollisionAvoidanceLimit.

    The caller lists the pairs (the compiled model's collision rules). A row is what mink's
    ``compute_contact_normal_jacobian`` makes, the same operations on the same numbers (the
    generated rows are bit for bit the same), only gathered: MuJoCo fills one buffer per pair
    in the loop and numpy does the rest for all pairs at once. A TIAGo arm keeps ~450 pairs
    within reach at every step, and Python's overhead per pair was most of its build.
    """

    def __init__(
        self, model: mujoco.MjModel, data: mujoco.MjData, pairs: list[tuple[int, int]],
        folding: frozenset[int] = frozenset(),
    ) -> None:
        self.model = model
        self.pairs = np.array(pairs, dtype=int).reshape(-1, 2)
        self._rsum = model.geom_rbound[self.pairs[:, 0]] + model.geom_rbound[self.pairs[:, 1]]
        fromto = np.zeros(6)
        # pairs already close at neutral keep half that gap; two links of the limb itself
        # (bodies in ``folding``) only FOLD_CLEARANCE, so an elbow folds as far as it bends
        self._clearance = np.array([
            min(FOLD_CLEARANCE if {int(model.geom_bodyid[a]), int(model.geom_bodyid[b])}
                <= folding else CLEARANCE,
                0.5 * mujoco.mj_geomDistance(model, data, int(a), int(b), CLEARANCE * 2,
                                             fromto))
            for a, b in self.pairs
        ])
        self._geoms = [(int(a), int(b), int(model.geom_bodyid[a]), int(model.geom_bodyid[b]))
                       for a, b in self.pairs]
        n = len(self._geoms)
        self._fromto = np.zeros((n, 6))
        self._jac1 = np.zeros((n, 3, model.nv))
        self._jac2 = np.zeros((n, 3, model.nv))

    def compute_qp_inequalities(
        self, configuration: mink.Configuration, dt: float
    ) -> mink.Constraint:
        model, data = self.model, configuration.data
        xpos = data.geom_xpos
        g1, g2 = self.pairs[:, 0], self.pairs[:, 1]
        gap = np.linalg.norm(xpos[g1] - xpos[g2], axis=1) - self._rsum
        distance, jac = mujoco.mj_geomDistance, mujoco.mj_jac
        fromto, jac1, jac2, geoms = self._fromto, self._jac1, self._jac2, self._geoms
        kept: list[int] = []
        dists: list[float] = []
        for idx in np.flatnonzero(gap <= DETECT).tolist():
            a, b, body_a, body_b = geoms[idx]
            k = len(kept)
            ft = fromto[k]
            dist = distance(model, data, a, b, DETECT, ft)
            if dist >= DETECT - 1e-12:
                continue
            jac(model, data, jac2[k], None, ft[3:], body_b)
            jac(model, data, jac1[k], None, ft[:3], body_a)
            kept.append(idx)
            dists.append(dist)
        if not kept:
            return mink.Constraint()
        k = len(kept)
        normal = fromto[:k, 3:] - fromto[:k, :3]
        for row in normal:
            mujoco.mju_normalize3(row)
        rel = jac2[:k] - jac1[:k]
        rows = (normal[:, None, :] @ rel)[:, 0, :]
        d = np.array(dists)
        rows[d >= 0] *= -1.0  # apart: closing in is bounded; inside: so is going deeper
        bounds = np.maximum(d - self._clearance[kept], 0.0) * LIMIT_GAIN / dt
        return mink.Constraint(G=rows, h=bounds)


class FloorLimit(mink.Limit):
    """Keep sample points of the limb's geoms at or above z = 0 (corners, rims, lowest points)."""

    def __init__(self, model: mujoco.MjModel, geoms: list[int]) -> None:
        self.bodies, self.points, self.offsets = sample_points(model, geoms)
        self._jac = np.zeros((3, model.nv))

    def compute_qp_inequalities(
        self, configuration: mink.Configuration, dt: float
    ) -> mink.Constraint:
        if len(self.bodies) == 0:
            return mink.Constraint()
        data = configuration.data
        rot = data.xmat[self.bodies].reshape(-1, 3, 3)
        world = data.xpos[self.bodies] + np.einsum("nij,nj->ni", rot, self.points)
        height = world[:, 2] - self.offsets
        rows, bounds = [], []
        for i in np.where(height < DETECT)[0]:
            mujoco.mj_jac(configuration.model, data, self._jac, None, world[i], self.bodies[i])
            rows.append(-self._jac[2].copy())  # -dz <= gain * height: never below the floor
            bounds.append(max(float(height[i]), 0.0) * LIMIT_GAIN / dt)
        if not rows:
            return mink.Constraint()
        return mink.Constraint(G=np.vstack(rows), h=np.array(bounds))
