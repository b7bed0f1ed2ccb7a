"""Static balance: a pose keeps the whole-body centre of mass over what still bears weight.

The paper leaves out the directions that would topple NAO. A pose is *statically stable* when
the ground projection of the whole body's centre of mass lies inside the support polygon (the
convex hull of every robot point within TOUCH of the floor: both soles, the stance sole when a
foot is lifted, a track, a pedestal) at least MARGIN inside its edge. The check is the same
for every mobile platform; on wheels or tracks it rarely bites, on one foot it decides. A fixed
base (``[base] kind = "fixed"``: Baxter's pedestal, an arm bolted to a table) is anchored and
cannot topple, so it is never checked: a Panda reaching forward is no fall.
"""

from __future__ import annotations

import mujoco
import numpy as np

from kinesphere.platforms.mjcf import PlatformModel
from kinesphere.services.ecl.constraints import samples

TOUCH = 0.003  # metres: a point of the robot this close to the floor bears weight
MARGIN = 0.01  # metres the centre of mass keeps inside the support polygon's edge


class Balance:
    """Stability checks on one platform's model (its own MjData, so callers' data is untouched)."""

    def __init__(self, pm: PlatformModel) -> None:
        m = pm.model
        floor = m.geom("floor").id
        bodies, points, radii = [], [], []
        for g in range(m.ngeom):
            if m.geom_contype[g] and g != floor:
                for p, r in samples(m, g):
                    bodies.append(int(m.geom_bodyid[g]))
                    points.append(p)
                    radii.append(r)
        self.model = m
        self.anchored = not pm.platform.base.mobile
        self._bodies = np.array(bodies, dtype=int)
        self._points = np.array(points, dtype=float).reshape(-1, 3)
        self._radii = np.array(radii, dtype=float)
        self._data = mujoco.MjData(m)

    def margin(self, qpos: np.ndarray) -> tuple[float, tuple[str, ...]]:
        """Metres from the centre of mass to the support polygon's edge (negative: outside),
        and the bodies bearing weight."""
        m, data = self.model, self._data
        data.qpos[:] = qpos
        mujoco.mj_kinematics(m, data)
        mujoco.mj_comPos(m, data)
        rot = data.xmat[self._bodies].reshape(-1, 3, 3)
        world = data.xpos[self._bodies] + np.einsum("nij,nj->ni", rot, self._points)
        down = world[:, 2] - self._radii < TOUCH
        names = tuple(sorted({m.body(int(b)).name for b in self._bodies[down]}))
        com = data.subtree_com[0, :2]
        return inside(hull(world[down, :2]), com), names

    def check(self, qpos: np.ndarray) -> str | None:
        """Why a pose would topple (centre of mass too near or past the edge), or None; always
        None on an anchored (fixed) base."""
        if self.anchored:
            return None
        margin, names = self.margin(qpos)
        if margin >= MARGIN:
            return None
        where = ", ".join(names) or "nothing"
        if margin < 0:
            return f"unstable: centre of mass {-margin * 100:.1f} cm outside the support of {where}"
        return (f"unstable: centre of mass only {margin * 100:.1f} cm inside the support of "
                f"{where} (needs {MARGIN * 100:.0f} cm)")


def hull(points: np.ndarray) -> np.ndarray:
    """Convex hull of 2-D points, counter-clockwise (Andrew's monotone chain); deterministic."""
    pts = sorted({(round(float(x), 9), round(float(y), 9)) for x, y in points})
    if len(pts) < 3:
        return np.array(pts, dtype=float).reshape(-1, 2)

    def turn(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    upper: list[tuple[float, float]] = []
    for p in pts:
        while len(lower) >= 2 and turn(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in reversed(pts):
        while len(upper) >= 2 and turn(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1], dtype=float)


def inside(polygon: np.ndarray, point: np.ndarray) -> float:
    """Signed distance from ``point`` to a counter-clockwise convex polygon's boundary:
    positive inside, negative outside (a polygon of fewer than 3 points has no inside)."""
    n = len(polygon)
    if n == 0:
        return -np.inf
    if n < 3:
        a, b = polygon[0], polygon[-1]
        return -_segment_distance(point, a, b)
    edges = np.roll(polygon, -1, axis=0) - polygon
    normals = np.stack([-edges[:, 1], edges[:, 0]], axis=1)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    signed = np.einsum("ij,ij->i", point - polygon, normals)
    if signed.min() >= 0:
        return float(signed.min())
    return -min(_segment_distance(point, polygon[i], polygon[(i + 1) % n]) for i in range(n))


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    t = 0.0 if not ab.any() else float(np.clip((p - a) @ ab / (ab @ ab), 0.0, 1.0))
    return float(np.linalg.norm(p - (a + t * ab)))
