"""Each joint's transform from its parent link to its child link, for any joint values.

That is ``origin x motion(q)`` per joint, what robot_state_publisher computes from a URDF and a
joint state (and what a drawing of the body moves by): a revolute or continuous joint turns
about its axis, a prismatic one slides along it, a mimic joint follows its leader
(``multiplier x leader + offset``), and every other joint (fixed, and floating or planar ones,
which kdl_parser and so robot_state_publisher also hold fixed) keeps its origin. Computed for
all joints at once with numpy: yourdfpy's full forward kinematics costs about a millisecond
per body, too much for a view of eight robots at 30 frames per second or a bridge relaying
every state. Each link's pose in the root's frame (:meth:`JointFrames.link_poses`) chains
them in one pass over the tree, parents first: work linear in the links, which
:func:`~kinesphere.eurdf.load_eurdf` bounds.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from kinesphere.eurdf import Eurdf

Array = npt.NDArray[np.float64]
_MOVING = ("revolute", "continuous", "prismatic")


def quat_mul(a: Array, b: Array) -> Array:
    """Hamilton products of quaternions ``(w, x, y, z)``, row by row."""
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=1)


def quat_of(matrix: Array) -> Array:
    """The unit quaternion ``(w, x, y, z)`` of a rotation matrix (Shepperd's method)."""
    m = matrix
    t = np.trace(m)
    if t > 0:
        s = np.sqrt(t + 1.0) * 2
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k]) * 2
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    out = np.asarray(q, dtype=float)
    return out / np.linalg.norm(out)  # type: ignore[no-any-return]


def matrix_of(q: Array) -> Array:
    """The rotation matrix of a unit quaternion ``(w, x, y, z)``."""
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


class JointFrames:
    """The joints of an eURDF (every joint, in URDF order) and their transforms for any ``q``
    given in :attr:`joint_names` order (the joints of P)."""

    def __init__(self, eurdf: Eurdf) -> None:
        self.joint_names: tuple[str, ...] = eurdf.joint_names
        joints = list(eurdf.urdf.joint_map.values())
        self.root: str = eurdf.root_link
        self.names = tuple(str(j.name) for j in joints)
        self.parents = tuple(str(j.parent) for j in joints)
        self.children = tuple(str(j.child) for j in joints)
        n = len(joints)
        self._origin_q = np.zeros((n, 4))
        self._origin_p = np.zeros((n, 3))
        self._origin_r = np.zeros((n, 3, 3))
        self._axis = np.zeros((n, 3))
        self.revolute = np.zeros(n, dtype=bool)
        self.prismatic = np.zeros(n, dtype=bool)
        # each joint's value is source value x multiplier + offset (mimic joints follow another)
        self.source = np.zeros(n, dtype=int)
        self._multiplier = np.zeros(n)
        self._offset = np.zeros(n)
        index = {name: i for i, name in enumerate(self.joint_names)}
        for i, j in enumerate(joints):
            origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
            self._origin_r[i] = origin[:3, :3]
            self._origin_q[i] = quat_of(origin[:3, :3])
            self._origin_p[i] = origin[:3, 3]
            if j.type in _MOVING:
                axis = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), float)
                self._axis[i] = axis / np.linalg.norm(axis)
                self.revolute[i] = j.type != "prismatic"
                self.prismatic[i] = j.type == "prismatic"
                source, mult, off = j.name, 1.0, 0.0
                if j.mimic is not None:
                    source = j.mimic.joint
                    mult = 1.0 if j.mimic.multiplier is None else float(j.mimic.multiplier)
                    off = 0.0 if j.mimic.offset is None else float(j.mimic.offset)
                if source in index:
                    self.source[i], self._multiplier[i], self._offset[i] = index[source], mult, off
        self.moving = self.revolute | self.prismatic
        """Which joints move with ``q`` (robot_state_publisher's /tf; the rest /tf_static)."""
        self._order = _tree_order(self.root, self.parents, self.children)

    def vector(self, joints: Mapping[str, float], default: Mapping[str, float] | None = None
               ) -> Array:
        """Joint values in :attr:`joint_names` order; missing ones from ``default`` or 0."""
        base = default or {}
        return np.array([joints.get(n, base.get(n, 0.0)) for n in self.joint_names], float)

    def q_from(self, names: Sequence[str], q: Sequence[float],
               default: Mapping[str, float] | None = None) -> Array:
        """A RobotState's ``q`` (in its own ``joint_names`` order) in this order."""
        if tuple(names) == self.joint_names:
            return np.asarray(q, dtype=float)
        return self.vector(dict(zip(names, q, strict=True)), default)

    def transforms(self, q: Array) -> tuple[Array, Array]:
        """``(wxyz, xyz)`` of every joint's child frame in its parent's frame, for ``q``."""
        value = q[self.source] * self._multiplier + self._offset if q.size else self._offset
        half = 0.5 * np.where(self.revolute, value, 0.0)
        motion = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * self._axis],
                                axis=1)
        wxyz = quat_mul(self._origin_q, motion)
        slide = np.where(self.prismatic, value, 0.0)[:, None] * self._axis
        xyz = self._origin_p + np.einsum("nij,nj->ni", self._origin_r, slide)
        return wxyz, xyz

    def link_poses(self, q: Array) -> dict[str, Array]:
        """Every link's 4x4 pose in the root link's frame for ``q``: the joint transforms
        chained once over the tree, parents first."""
        wxyz, xyz = self.transforms(q)
        poses = {self.root: np.eye(4)}
        for i in self._order:
            local = np.eye(4)
            local[:3, :3] = matrix_of(wxyz[i])
            local[:3, 3] = xyz[i]
            poses[self.children[i]] = poses[self.parents[i]] @ local
        return poses


def _tree_order(root: str, parents: Sequence[str], children: Sequence[str]) -> list[int]:
    """Joint indices parents first (a URDF may list a child's joint before its parent's)."""
    below: dict[str, list[int]] = {}
    for i, parent in enumerate(parents):
        below.setdefault(parent, []).append(i)
    order: list[int] = []
    stack = [root]
    while stack:
        for i in below.get(stack.pop(), []):
            order.append(i)
            stack.append(children[i])
    return order


PIVOT_REACH = 0.05
"""metres: a joint location's pivot must lie this close to every one of its axes, else it is
its first joint's anchor."""
_PULL = 1e-6  # a whisper toward the first anchor: picks the point on a lone or shared axis


def pivot(anchors: Sequence[Array], axes: Sequence[Array]) -> Array:
    """The point a joint location turns about: nearest (least squares) to all of its joints'
    axis lines ``(anchor, unit axis)``; the first anchor when the group has one joint or the
    lines miss the point by more than :data:`PIVOT_REACH` (two parallel pitch joints).

    Why: a shoulder's pitch and roll axes meet at the shoulder, but Baxter's elbow group starts
    with a roll 27 cm before the bend, and its pivot is at the elbow, where a person puts it.
    """
    first = np.asarray(anchors[0], dtype=float)
    if len(anchors) < 2:
        return first
    lhs, rhs = _PULL * np.eye(3), _PULL * first
    for p, a in zip(anchors, axes, strict=True):
        proj = np.eye(3) - np.outer(a, a)
        lhs = lhs + proj
        rhs = rhs + proj @ p
    point = np.linalg.solve(lhs, rhs)
    far = max(float(np.linalg.norm((point - p) - ((point - p) @ a) * a))
              for p, a in zip(anchors, axes, strict=True))
    return np.asarray(point if far <= PIVOT_REACH else first)
