"""Where a pose points and whether the body stands in it, by forward kinematics in MuJoCo.

One definition of what a stored pose *means*, shared by the generator (what it aims at and
records), ``ecl audit`` and the tests: it takes joint values (a stored row) and the platform's
compiled model, and nothing from the IK that made them, so a measurement cannot inherit a
generator's mistake.

* The **origin** of a joint location is its pivot at the neutral pose
  (:func:`kinesphere.platforms.frames.pivot`); the **tip** is the distal end of the limb's tip
  link (:func:`tip_point`). A pose's **offset** is tip - origin in the body frame (x forward,
  y left, z up); its **bearing** is the offset's direction, compared with a Laban direction by
  the cosine.
* A pose is **statically stable** by the margin from the whole-body centre of mass (ground
  projection) to the edge of the support polygon: the convex hull of every robot point within
  TOUCH of the floor (sample points of the collision geoms, :func:`samples`). A legged base
  (``kind = "legged"``, a brought walker) abstracts walking: the gait that moves the base
  also shifts the body over the feet still down when one leg gestures, so its support is what
  touches the floor in the pose together with its stance at neutral (a quadruped giving a
  paw, not a quadruped toppling because one foot is up); reaching past that stance still
  topples.
"""

from __future__ import annotations

from collections.abc import Mapping

import mujoco
import numpy as np

from kinesphere.laban import Direction
from kinesphere.platforms.frames import pivot
from kinesphere.platforms.mjcf import PlatformModel

TOUCH = 0.003  # metres: a point of the robot this close to the floor bears weight
HONEST = 0.85
"""The cosine at which a bearing points toward a direction (about 32 degrees): what a stored
far pose must reach, and what makes a pull one the neutral pose already points at."""
TIE = 0.01  # metres: geom ends this close to the farthest one count as the same end


def tip_point(model: mujoco.MjModel, body: int) -> np.ndarray:
    """The distal end of a link, in its body frame.

    Each collision geom offers the two ends of its main axis; the end farthest from the body
    origin wins, and ends within TIE metres of it are averaged, so a symmetric link (a pair
    of flippers on one axle) gets its end on the plane of symmetry, not on one side. A
    zero-size frame (no collision geometry) is its own end: the body origin.
    """
    ends: list[np.ndarray] = []
    for g in range(model.ngeom):
        if model.geom_bodyid[g] != body or model.geom_contype[g] == 0:
            continue
        centre, size, kind = model.geom_pos[g], model.geom_size[g], model.geom_type[g]
        rot = _rotation(model, g)
        if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            norm = float(np.linalg.norm(centre))
            axis = centre / norm if norm > 1e-9 else np.array([0.0, 0.0, 1.0])
            half = float(size[0])
        elif kind == mujoco.mjtGeom.mjGEOM_BOX:
            k = int(np.argmax(size))
            axis, half = rot[:, k], float(size[k])
        else:  # cylinder, capsule, ellipsoid: the local z axis
            cap = float(size[0]) if kind == mujoco.mjtGeom.mjGEOM_CAPSULE else 0.0
            axis, half = rot[:, 2], float(size[1]) + cap
        ends += [centre + axis * half, centre - axis * half]
    if not ends:
        return np.zeros(3)
    norms = np.array([float(np.linalg.norm(e)) for e in ends])
    chosen = [e for e, n in zip(ends, norms, strict=True) if n >= norms.max() - TIE]
    return np.asarray(np.mean(chosen, axis=0))


def samples(model: mujoco.MjModel, g: int) -> list[tuple[np.ndarray, float]]:
    """Points of a geom in its body frame, each with the radius to subtract from its height."""
    rot = _rotation(model, g)
    pos, size, kind = model.geom_pos[g], model.geom_size[g], model.geom_type[g]
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return [(pos.copy(), float(size[0]))]
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return [(pos + s * size[1] * rot[:, 2], float(size[0])) for s in (-1.0, 1.0)]
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        angles = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
        return [
            (pos + rot @ np.array([size[0] * np.cos(a), size[0] * np.sin(a), s * size[1]]), 0.0)
            for s in (-1.0, 1.0) for a in angles
        ]
    if kind == mujoco.mjtGeom.mjGEOM_MESH:  # its outermost vertices (see _DIRECTIONS)
        mesh = model.geom_dataid[g]
        verts = model.mesh_vert[model.mesh_vertadr[mesh]:][: model.mesh_vertnum[mesh]]
        outer = sorted({int(i) for i in np.argmax(verts @ _DIRECTIONS.T, axis=0)})
        return [(pos + rot @ verts[i], 0.0) for i in outer]
    half = size if kind == mujoco.mjtGeom.mjGEOM_BOX else np.full(3, float(np.max(size)))
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return [(pos + rot @ (s * half), 0.0) for s in signs]


def _directions() -> np.ndarray:
    """Laban's 26, and 8 directions 20 degrees off each axis: a mesh's vertices farthest along
    them outline its shape, and the rim of each flat face (a sole's on the floor) closely."""
    out = [np.array((x, y, z), dtype=float) for x in (-1, 0, 1) for y in (-1, 0, 1)
           for z in (-1, 0, 1) if (x, y, z) != (0, 0, 0)]
    tilt = np.radians(20.0)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            for a in np.linspace(0.0, 2 * np.pi, 8, endpoint=False):
                d = np.zeros(3)
                d[axis] = sign * np.cos(tilt)
                d[(axis + 1) % 3] = np.sin(tilt) * np.cos(a)
                d[(axis + 2) % 3] = np.sin(tilt) * np.sin(a)
                out.append(d)
    return np.array(out, dtype=float)


_DIRECTIONS = _directions()


def sample_points(model: mujoco.MjModel, geoms: list[int]
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`samples` of several geoms as arrays: each point's body, the point in that body's
    frame, and the radius to subtract from its height."""
    bodies, points, radii = [], [], []
    for g in geoms:
        for p, r in samples(model, g):
            bodies.append(int(model.geom_bodyid[g]))
            points.append(p)
            radii.append(r)
    return (np.array(bodies, dtype=int), np.array(points, dtype=float).reshape(-1, 3),
            np.array(radii, dtype=float))


def _rotation(model: mujoco.MjModel, g: int) -> np.ndarray:
    """A geom's orientation in its body frame, as a 3x3 matrix."""
    flat = np.zeros(9)
    mujoco.mju_quat2Mat(flat, model.geom_quat[g])
    return flat.reshape(3, 3)


def cosine(v: np.ndarray, d: np.ndarray) -> float:
    """Cosine between a vector and a unit direction (0 for a zero vector)."""
    n = float(np.linalg.norm(v))
    return float(v @ d) / n if n > 1e-9 else 0.0


def points_along(v: np.ndarray, d: np.ndarray) -> bool:
    """Whether a bearing points toward a unit direction (cosine at least HONEST): what makes a
    pull one a limb already points at in its neutral pose."""
    return cosine(v, d) >= HONEST


def angle_deg(v: np.ndarray, d: np.ndarray) -> float:
    """Degrees between a vector and a unit direction (90 for a zero vector)."""
    return float(np.degrees(np.arccos(np.clip(cosine(v, d), -1.0, 1.0))))


class Fk:
    """One platform's model with its own MjData: offsets of limb tips and static balance.

    Bodies, tips and origins are looked up once; each measurement is one ``mj_kinematics``
    (plus ``mj_comPos`` for the balance) at a full configuration built from joint values with
    the platform's neutral pose everywhere else.
    """

    def __init__(self, pm: PlatformModel) -> None:
        m = pm.model
        self.pm = pm
        self.model = m
        self.eurdf = pm.platform.eurdf
        self.anchored = not pm.platform.base.mobile
        self._data = mujoco.MjData(m)
        neutral = self._kinematics(pm.neutral_qpos())
        self.body_rot = neutral.xmat[m.body(self.eurdf.root_link).id].reshape(3, 3).copy()
        self._origins: dict[str, np.ndarray] = {}
        self._tips: dict[str, tuple[int, np.ndarray]] = {}
        floor = m.geom("floor").id
        self._bodies, self._points, self._radii = sample_points(
            m, [g for g in range(m.ngeom) if m.geom_contype[g] and g != floor])
        self._neutral_offsets: dict[tuple[str, str], np.ndarray] = {}
        self._stance = np.zeros((0, 2))
        if pm.platform.base.kind == "legged":  # walking abstracted: the gait keeps its stance
            world, down = self._touching(pm.neutral_qpos())
            self._stance = world[down, :2]

    def _kinematics(self, qpos: np.ndarray) -> mujoco.MjData:
        data = self._data
        data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, data)
        return data

    def qpos(self, joints: Mapping[str, float]) -> np.ndarray:
        """A full configuration: neutral, then ``joints`` (mimic joints follow leaders)."""
        return self.pm.qpos(dict(joints))

    def origin(self, origin: str) -> np.ndarray:
        """The origin's pivot at neutral (world)."""
        if origin not in self._origins:
            data = self._kinematics(self.pm.neutral_qpos())
            self._origins[origin] = pivot(self.model, data, self.eurdf.origin(origin).joints)
        return self._origins[origin]

    def tip(self, limb: str) -> tuple[int, np.ndarray]:
        """The limb's tip: its body id and the point on it (body frame)."""
        if limb not in self._tips:
            body = self.model.body(self.eurdf.tip_link(limb)).id
            self._tips[limb] = (body, tip_point(self.model, body))
        return self._tips[limb]

    def offset_q(self, limb: str, origin: str, qpos: np.ndarray) -> np.ndarray:
        """tip - origin in the body frame, at a full configuration."""
        body, point = self.tip(limb)
        start = self.origin(origin)
        data = self._kinematics(qpos)
        tip = data.xpos[body] + data.xmat[body].reshape(3, 3) @ point
        return np.asarray(self.body_rot.T @ (tip - start))

    def offset(self, limb: str, origin: str, joints: Mapping[str, float]) -> np.ndarray:
        """tip - origin in the body frame for joint values (neutral elsewhere)."""
        return self.offset_q(limb, origin, self.qpos(joints))

    def neutral_offset(self, limb: str, origin: str) -> np.ndarray:
        """Where the limb points at the neutral pose (Place Middle)."""
        key = (limb, origin)
        if key not in self._neutral_offsets:
            self._neutral_offsets[key] = self.offset_q(limb, origin, self.pm.neutral_qpos())
        return self._neutral_offsets[key]

    def neutral_directions(self, limb: str, origin: str) -> list[Direction]:
        """The pulls the limb already points at in its neutral pose (cosine >= HONEST), in
        Laban order: a limb at rest answers these without moving (near)."""
        rest = self.neutral_offset(limb, origin)
        return [d for d in Direction.pulls() if points_along(rest, np.array(d.vector))]

    def margin(self, qpos: np.ndarray) -> tuple[float, tuple[str, ...]]:
        """Metres from the centre of mass to the support polygon's edge (negative: outside),
        and the bodies bearing weight."""
        world, down = self._touching(qpos)
        names = tuple(sorted({self.model.body(int(b)).name for b in self._bodies[down]}))
        com = self._data.subtree_com[0, :2]
        return inside(hull(np.vstack([world[down, :2], self._stance])), com), names

    def _touching(self, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every sample point in the world at ``qpos`` (centre of mass computed), and which of
        them bear weight."""
        data = self._kinematics(qpos)
        mujoco.mj_comPos(self.model, data)
        rot = data.xmat[self._bodies].reshape(-1, 3, 3)
        world = data.xpos[self._bodies] + np.einsum("nij,nj->ni", rot, self._points)
        return world, world[:, 2] - self._radii < TOUCH

    def com_margin(self, joints: Mapping[str, float]) -> float | None:
        """The stability margin of joint values (neutral elsewhere); None on a fixed base,
        which is bolted down and cannot topple."""
        return None if self.anchored else self.margin(self.qpos(joints))[0]


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
