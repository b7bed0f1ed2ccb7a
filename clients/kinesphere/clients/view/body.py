"""A body to draw: the eURDF of a :class:`BodyModel` as link geometry and joint transforms.

yourdfpy reads the text (no files: the shapes are primitives) and gives each link's geometry.
Moving the drawing only needs each joint's transform from its parent link to its child link,
``origin x motion(q)``: :class:`kinesphere.joint_frames.JointFrames`, the same computation the
ROS 2 bridge publishes on /tf.
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
from kinesphere.joint_frames import JointFrames
from kinesphere.protocol import BodyModel

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Shape:
    """One piece of geometry, its vertices already in its link's frame."""

    link_path: str
    """The scene path of the link it rides on, relative to the robot's root."""
    name: str
    mesh: trimesh.Trimesh


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
        self.frames = JointFrames(eurdf)
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
        return self.frames.vector(joints, default)

    def q_from(self, names: Sequence[str], q: Sequence[float]) -> Array:
        """A RobotState's ``q`` (in its own ``joint_names`` order) in this body's order."""
        return self.frames.q_from(names, q, self.neutral)

    def moved_frames(self, moved_joints: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
        """Which joint frames follow one of the ``moved_joints`` (in joint_names order)."""
        if moved_joints.size == 0:
            return np.zeros(len(self.frame_paths), dtype=bool)
        return moved_joints[self.frames.source] & self.frames.moving

    def transforms(self, q: Array) -> tuple[Array, Array]:
        """``(wxyz, xyz)`` of every joint's child frame in its parent's frame, for ``q``."""
        return self.frames.transforms(q)
