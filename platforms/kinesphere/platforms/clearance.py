"""Motion that does not hit itself: joint-space paths checked against the robot's own geometry.

The ECL checks its stored poses, not the way between them, and two limbs of one robot can meet
on the way (Baxter's right arm crossing to Left-High brushes the resting left arm). Before a
move, :meth:`Clearance.route` samples the straight joint-space path from where the joints are
to the target against the MuJoCo model's collision geometry (kinematics only: ``mj_kinematics``
and ``mj_collision`` every PATH_STEP radians of the largest joint motion). When it touches,
the move goes via waypoints, tried in a fixed order: the moving joints' neutral, the proximal
or the distal half of the moving joints first, then a short seeded search in the space of the
moving joints, last through neutral (the moving joints', then also every joint below them).
Every leg of a route is clear; a target no route reaches is refused with the link pair that
touches. Deterministic: the same start and goal give the same route.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from kinesphere.platforms.mjcf import PlatformModel, robot_contacts

PATH_STEP = 0.05
"""rad (or m) of the largest joint motion between two checked samples of a leg."""
SEARCH_TRIES = 24
"""Random waypoints tried from the start (then as many after the moving joints' neutral)."""
SEARCH_SPREAD = 0.6
"""rad: how far a random waypoint strays from the straight way to the goal."""
SEARCH_SEED = 13
STILL = 1e-6


@dataclass(frozen=True)
class Touch:
    """Two links touching ``at`` a fraction of the way along a leg (0: at its start)."""

    link_a: str
    link_b: str
    at: float

    def __str__(self) -> str:
        return f"{self.link_a}/{self.link_b} touch {self.at:.0%} of the way"


class Clearance:
    """Self-collision checks of one platform's joint-space paths, on a private MjData.

    Joint vectors are in P order (``platform.joint_names``); the base stays at the origin and
    mimic joints follow their leaders, as in the robot's own model.
    """

    def __init__(self, pm: PlatformModel, margin: float = 0.01) -> None:
        self.pm = pm
        self.model = pm.model
        self.data = mujoco.MjData(pm.model)
        plat = pm.platform
        names = plat.joint_names
        self.joint_names = names
        self._qadr = np.array([pm.qpos_index[j] for j in names], dtype=int)
        self._qpos = pm.neutral_qpos()
        index = {j: i for i, j in enumerate(names)}
        self._mimics = [(pm.qpos_index[m.joint], index[m.leader], m)
                        for m in plat.eurdf.mimics.values()]
        self.neutral = self._qpos[self._qadr].copy()
        lims = [plat.eurdf.limits[j] for j in names]
        lo = np.array([lim.lower for lim in lims])
        hi = np.array([lim.upper for lim in lims])
        finite = np.isfinite(lo) & np.isfinite(hi)
        self.lower = np.where(finite, lo + margin, self.neutral - np.pi)
        self.upper = np.where(finite, hi - margin, self.neutral + np.pi)
        # below[i]: the joints on the bodies below joint i's (what turns when it turns)
        m = self.model
        body = np.array([m.jnt_bodyid[m.joint(j).id] for j in names])
        self._below = np.array([[j != i and self._descends(int(body[j]), int(body[i]))
                                 for j in range(len(names))] for i in range(len(names))],
                               dtype=bool).reshape(len(names), len(names))

    def touching(self, q: np.ndarray, allowed: frozenset[tuple[str, str]] = frozenset()
                 ) -> tuple[str, str] | None:
        """The first pair of links in contact at ``q`` (names sorted), or None."""
        m, data = self.model, self.data
        qpos = self._qpos
        qpos[self._qadr] = q
        for adr, leader, mimic in self._mimics:
            qpos[adr] = mimic.value(float(q[leader]))
        data.qpos[:] = qpos
        mujoco.mj_kinematics(m, data)
        mujoco.mj_collision(m, data)
        for a, b in robot_contacts(m, data):
            pair = (a, b) if a <= b else (b, a)
            if pair not in allowed:
                return pair
        return None

    def leg(self, a: np.ndarray, b: np.ndarray,
            allowed: frozenset[tuple[str, str]] = frozenset()) -> Touch | None:
        """Where the straight way from ``a`` to ``b`` first touches (``allowed`` pairs, already
        touching where a motion starts, may stay in contact), or None when it is clear."""
        span = float(np.max(np.abs(b - a), initial=0.0))
        steps = max(1, int(np.ceil(span / PATH_STEP)))
        for k in range(steps + 1):
            t = k / steps
            pair = self.touching(a + t * (b - a), allowed)
            if pair is not None:
                return Touch(pair[0], pair[1], t)
        return None

    def path(self, points: np.ndarray, allowed: frozenset[tuple[str, str]] = frozenset()
             ) -> Touch | None:
        """Where the path through ``points`` (rows of joint vectors, joined by straight
        pieces) first touches, or None: checked every PATH_STEP of the largest joint motion
        along it and at its end, as :meth:`leg` checks one straight way (``at``: the share of
        that motion gone)."""
        if len(points) < 2:  # it stays where it starts
            return None
        along = np.concatenate(([0.0], np.cumsum(np.max(np.abs(np.diff(points, axis=0)),
                                                         axis=1, initial=0.0))))
        total = float(along[-1])
        steps = max(1, int(np.ceil(total / PATH_STEP)))
        marks = np.linspace(0.0, total, steps + 1)[1:]
        piece = np.clip(np.searchsorted(along, marks, side="right") - 1, 0, len(points) - 2)
        span = along[piece + 1] - along[piece]
        share = np.divide(marks - along[piece], span, out=np.ones_like(span), where=span > 0)
        samples = points[piece] + share[:, None] * (points[piece + 1] - points[piece])
        for k, q in enumerate(samples, start=1):
            pair = self.touching(q, allowed)
            if pair is not None:
                return Touch(pair[0], pair[1], k / steps)
        return None

    def route(self, a: np.ndarray, b: np.ndarray) -> list[np.ndarray] | Touch:
        """Waypoints from ``a`` to ``b`` (the last is ``b``), each leg clear; or the touch that
        blocks the direct way when no route is found (see the module)."""
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        direct = self.leg(a, b, self.contacts(a))
        if direct is None:
            return [b]
        found = self._search(a, b)
        if found is not None:
            return found
        # through the moving joints' neutral, each half planned on its own: a stored pose is
        # reachable from neutral, so two stored poses of one limb are joined this way
        home = self._home(a, b)
        if np.allclose(home, a) or np.allclose(home, b):
            return direct
        for via in (home, self._home(a, b, below=True)):
            back, ahead = self._search(via, a), self._search(via, b)
            if back is not None and ahead is not None:
                return [*(list(reversed(back[:-1]))), via, *ahead]
        return direct

    def _home(self, a: np.ndarray, b: np.ndarray, below: bool = False) -> np.ndarray:
        """``a`` with the joints that move on the way to ``b`` at neutral; ``below``: and every
        joint beneath them (two poses of a forearm may share a folded elbow that neutral does
        not have: each was planned from neutral, so they are joined there)."""
        moving = np.abs(b - a) > STILL
        if below:
            moving = moving | self._below[moving].any(axis=0)
        home = a.copy()
        home[moving] = self.neutral[moving]
        return home

    def _descends(self, body: int, ancestor: int) -> bool:
        while body > 0:
            if body == ancestor:
                return True
            body = int(self.model.body_parentid[body])
        return False

    def _search(self, a: np.ndarray, b: np.ndarray) -> list[np.ndarray] | None:
        """The direct way or the first clear one through the candidate waypoints, or None."""
        start = self.contacts(a)
        if self.leg(a, b, start) is None:
            return [b]
        for vias in self._vias(a, b):
            found = self._through(a, vias, b, start)
            if found is not None:
                return found
        return None

    def contacts(self, q: np.ndarray) -> frozenset[tuple[str, str]]:
        """Every pair in contact at ``q``: a motion may start touching and move apart."""
        self.touching(q)
        return frozenset((x, y) if x <= y else (y, x)
                         for x, y in robot_contacts(self.model, self.data))

    def _through(self, a: np.ndarray, vias: list[np.ndarray], b: np.ndarray,
                 start: frozenset[tuple[str, str]]) -> list[np.ndarray] | None:
        points = [a, *vias, b]
        for i in range(len(points) - 1):
            if self.leg(points[i], points[i + 1], start if i == 0 else frozenset()) is not None:
                return None
        return [*vias, b]

    def _vias(self, a: np.ndarray, b: np.ndarray) -> list[list[np.ndarray]]:
        """Candidate waypoint lists, cheapest ideas first (deterministic)."""
        moving = np.abs(b - a) > STILL
        idx = np.flatnonzero(moving)
        home = self._home(a, b)
        half = len(idx) // 2 or 1
        proximal, distal = a.copy(), a.copy()
        proximal[idx[:half]] = b[idx[:half]]
        distal[idx[half:]] = b[idx[half:]]
        out: list[list[np.ndarray]] = [[home], [proximal], [distal], [home, proximal],
                                       [home, distal]]
        rng = np.random.default_rng(SEARCH_SEED)
        lo, hi = self.lower[moving], self.upper[moving]
        for origin in (a, home):
            for _ in range(SEARCH_TRIES):
                w = origin.copy()  # near the way from here to the goal, off to one side
                u = rng.uniform(0.2, 0.8)
                w[moving] = np.clip(origin[moving] + u * (b[moving] - origin[moving])
                                    + rng.normal(0.0, SEARCH_SPREAD, len(idx)), lo, hi)
                out.append([w] if origin is a else [home, w])
        return out
