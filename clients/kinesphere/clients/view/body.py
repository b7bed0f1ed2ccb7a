"""A body to draw: the eURDF of a :class:`BodyModel` as link geometry and joint transforms.

yourdfpy reads the text (no files: the shapes are primitives) and gives each link's geometry.
Moving the drawing only needs each joint's transform from its parent link to its child link,
``origin x motion(q)``; that is computed here for all joints at once with numpy, because the
full forward kinematics of yourdfpy costs about a millisecond per body and a view of eight
robots at 30 frames per second cannot spend that.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import trimesh
import yourdfpy

from kinesphere.errors import KinesphereError
from kinesphere.eurdf import load_eurdf
from kinesphere.protocol import BodyModel

Array = npt.NDArray[np.float64]
_MOVING = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class Shape:
    """One piece of geometry, its vertices already in its link's frame."""

    link_path: str
    """The scene path of the link it rides on, relative to the robot's root."""
    name: str
    mesh: trimesh.Trimesh


def _quat_mul(a: Array, b: Array) -> Array:
    """Hamilton products of quaternions ``(w, x, y, z)``, row by row."""
    aw, ax, ay, az = a.T
    bw, bx, by, bz = b.T
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=1)


def _quat_of(matrix: Array) -> Array:
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


class BodyGeometry:
    """A platform's drawable body: shapes per link, and joint transforms for any ``q``."""

    def __init__(self, model: BodyModel) -> None:
        eurdf = load_eurdf(model.eurdf)  # validated: a malformed body is refused here
        try:
            urdf = yourdfpy.URDF.load(io.StringIO(model.eurdf), build_scene_graph=True,
                                      load_meshes=True)
        except Exception as exc:  # yourdfpy raises assorted types
            raise KinesphereError("invalid_eurdf", f"{model.platform}: {exc}") from None
        self.platform = model.platform
        self.version = model.version
        self.joint_names: tuple[str, ...] = eurdf.joint_names
        self.aliases = dict(eurdf.aliases)
        self.neutral = dict(model.neutral)
        scene = urdf.scene
        self._parents = scene.graph.transforms.parents
        self._base = scene.graph.base_frame
        joints = list(urdf.joint_map.values())
        self.frame_paths = tuple(self.path_of(j.child) for j in joints)
        """Scene path of each joint's child link (its frame moves with the joint)."""
        n = len(joints)
        self._origin_q = np.zeros((n, 4))
        self._origin_p = np.zeros((n, 3))
        self._origin_r = np.zeros((n, 3, 3))
        self._axis = np.zeros((n, 3))
        self._revolute = np.zeros(n, dtype=bool)
        self._prismatic = np.zeros(n, dtype=bool)
        # each joint's value is source value x multiplier + offset (mimic joints follow another)
        self._source = np.zeros(n, dtype=int)
        self._multiplier = np.zeros(n)
        self._offset = np.zeros(n)
        index = {name: i for i, name in enumerate(self.joint_names)}
        for i, j in enumerate(joints):
            origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
            self._origin_r[i] = origin[:3, :3]
            self._origin_q[i] = _quat_of(origin[:3, :3])
            self._origin_p[i] = origin[:3, 3]
            if j.type in _MOVING:
                axis = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), float)
                self._axis[i] = axis / np.linalg.norm(axis)
                self._revolute[i] = j.type != "prismatic"
                self._prismatic[i] = j.type == "prismatic"
                source, mult, off = j.name, 1.0, 0.0
                if j.mimic is not None:
                    source = j.mimic.joint
                    mult = 1.0 if j.mimic.multiplier is None else float(j.mimic.multiplier)
                    off = 0.0 if j.mimic.offset is None else float(j.mimic.offset)
                if source in index:
                    self._source[i], self._multiplier[i], self._offset[i] = index[source], mult, off
        self.shapes = tuple(self._shapes(urdf))
        low, high = self._extent(urdf)
        self.lift = max(0.0, -low)
        """Height of the root above the floor: the neutral body stands on the floor, as the
        platform's MuJoCo model does (its base height is the same clearance)."""
        self.height = high + self.lift
        """Top of the neutral body above the floor (labels go above it)."""

    def path_of(self, frame: str) -> str:
        """A link's scene path below the robot's root: ``torso/right_upper_shoulder/...``."""
        chain = []
        while frame != self._base:
            chain.append(frame)
            frame = self._parents[frame]
        chain.append(self._base)
        return "/".join(reversed(chain))

    def _shapes(self, urdf: yourdfpy.URDF) -> list[Shape]:
        out = []
        for name, mesh in urdf.scene.geometry.items():
            parent = self._parents[name]
            local = mesh.copy()
            local.apply_transform(urdf.get_transform(name, parent))
            out.append(Shape(self.path_of(parent), name, local))
        return out

    def _extent(self, urdf: yourdfpy.URDF) -> tuple[float, float]:
        """Lowest and highest point of the neutral body, in the root's frame."""
        urdf.update_cfg(self.vector(self.neutral))
        low, high = 0.0, 0.0
        for name, mesh in urdf.scene.geometry.items():
            world = urdf.get_transform(name, self._base)
            z = (mesh.vertices @ world[:3, :3].T + world[:3, 3])[:, 2]
            low, high = min(low, float(z.min())), max(high, float(z.max()))
        return low, high

    def vector(self, joints: Mapping[str, float], default: Mapping[str, float] | None = None
               ) -> Array:
        """Joint values in :attr:`joint_names` order; missing ones from ``default`` or 0."""
        base = default or {}
        return np.array([joints.get(n, base.get(n, 0.0)) for n in self.joint_names], float)

    def q_from(self, names: Sequence[str], q: Sequence[float]) -> Array:
        """A RobotState's ``q`` (in its own ``joint_names`` order) in this body's order."""
        if tuple(names) == self.joint_names:
            return np.asarray(q, dtype=float)
        return self.vector(dict(zip(names, q, strict=True)), self.neutral)

    def moved_frames(self, moved_joints: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
        """Which joint frames follow one of the ``moved_joints`` (in joint_names order)."""
        if moved_joints.size == 0:
            return np.zeros(len(self.frame_paths), dtype=bool)
        return moved_joints[self._source] & (self._revolute | self._prismatic)

    def transforms(self, q: Array) -> tuple[Array, Array]:
        """``(wxyz, xyz)`` of every joint's child frame in its parent's frame, for ``q``."""
        value = q[self._source] * self._multiplier + self._offset if q.size else self._offset
        half = 0.5 * np.where(self._revolute, value, 0.0)
        motion = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * self._axis],
                                axis=1)
        wxyz = _quat_mul(self._origin_q, motion)
        slide = np.where(self._prismatic, value, 0.0)[:, None] * self._axis
        xyz = self._origin_p + np.einsum("nij,nj->ni", self._origin_r, slide)
        return wxyz, xyz
