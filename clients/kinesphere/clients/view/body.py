"""A body to draw: the eURDF of a :class:`BodyModel` as link geometry and joint transforms.

Everything comes from the message: the eURDF text (validated and bounded by
:func:`~kinesphere.eurdf.load_eurdf`) and the mesh files the databank sent with it. No file
of this machine is ever read, whatever a mesh's name says (absolute, ``../``, ``file://``): a
mesh the message does not carry is not drawn. Shapes are built per ``<visual>`` (primitives
with trimesh, meshes from their bytes) in their link's frame. Moving the drawing only needs
each joint's transform from its parent link to its child link, ``origin x motion(q)``:
:class:`kinesphere.joint_frames.JointFrames`, the same computation the ROS 2 bridge publishes
on /tf; the neutral body's extent walks the tree once (``JointFrames.link_poses``). Every step
is linear in the links (a library's scene graph multiplied whole chains per shape: ~n^4, 66 s
for a 250-link chain).
"""

from __future__ import annotations

import copy
import io
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
import trimesh

from kinesphere.eurdf import load_eurdf
from kinesphere.joint_frames import JointFrames
from kinesphere.protocol import BodyModel
from kinesphere.urdf_tree import UrdfGeometry, UrdfMaterial, UrdfRobot, UrdfShape

Array = npt.NDArray[np.float64]
MAX_FACES: Final = 1_000_000
"""Triangles drawn per body, meshes and primitives together; meshes past it are left out."""
MESH_TYPES: Final = {".stl": "stl", ".obj": "obj"}
"""Mesh files a body may carry (what ``platform new`` writes), by suffix."""


@dataclass(frozen=True)
class Shape:
    """One piece of geometry, its vertices already in its link's frame."""

    link_path: str
    """The scene path of the link it rides on, relative to the robot's root."""
    name: str
    mesh: trimesh.Trimesh


def scene_name(name: str) -> str:
    """``name`` as one segment of a scene path: no ``/`` (it would nest), printable, short."""
    return re.sub(r"[^A-Za-z0-9_.\-]", "_", name)[:64] or "_"


class BodyGeometry:
    """A platform's drawable body: shapes per link, and joint transforms for any ``q``."""

    def __init__(self, model: BodyModel) -> None:
        eurdf = load_eurdf(model.eurdf)  # validated and bounded: a broken body is refused here
        robot = eurdf.urdf.robot
        self.platform = model.platform
        self.version = model.version
        self.joint_names: tuple[str, ...] = eurdf.joint_names
        self.aliases = dict(eurdf.aliases)
        self.neutral = dict(model.neutral)
        self.frames = JointFrames(eurdf)
        self._base = self.frames.root
        self._parent = dict(zip(self.frames.children, self.frames.parents, strict=True))
        self._paths: dict[str, str] = {}
        self.frame_paths = tuple(self.path_of(child) for child in self.frames.children)
        """Scene path of each joint's child link (its frame moves with the joint)."""
        self.missing: list[str] = []
        """Mesh file names the body names but the message does not carry (not drawn)."""
        self.shapes = tuple(self._shapes(robot, model.meshes))
        low, high = self._extent()
        self.lift = max(0.0, -low)
        """Height of the root above the floor: the neutral body stands on the floor, as the
        platform's MuJoCo model does (its base height is the same clearance)."""
        self.height = high + self.lift
        """Top of the neutral body above the floor (labels go above it)."""

    def renamed(self, platform: str) -> BodyGeometry:
        """This body under another platform's name (the same content is built once)."""
        twin = copy.copy(self)
        twin.platform = platform
        return twin

    def path_of(self, frame: str) -> str:
        """A link's scene path below the robot's root: ``torso/right_upper_shoulder/...``
        (each link's path is built once, from its parent's)."""
        chain = []
        link = frame
        while link not in self._paths and link != self._base:
            chain.append(link)
            link = self._parent[link]
        path = self._paths.get(link, scene_name(self._base))
        for member in reversed(chain):
            path = self._paths[member] = f"{path}/{scene_name(member)}"
        return path

    def _shapes(self, robot: UrdfRobot, meshes: Mapping[str, bytes]) -> list[Shape]:
        materials = {m.name: m for m in robot.materials if m.name}
        out: list[Shape] = []
        faces = 0
        for link in robot.links:
            path = self.path_of(link.name)
            for k, visual in enumerate(link.visuals):
                mesh = self._geometry(visual.geometry, meshes)
                if mesh is None:
                    continue
                faces += len(mesh.faces)
                if faces > MAX_FACES:
                    self.missing.append(f"{link.name}: over {MAX_FACES} faces")
                    faces -= len(mesh.faces)
                    continue
                _paint(mesh, visual, materials)
                if visual.origin is not None:
                    mesh.apply_transform(np.asarray(visual.origin, dtype=float))
                out.append(Shape(path, f"visual{k}", mesh))
        return out

    def _geometry(self, geometry: UrdfGeometry | None, meshes: Mapping[str, bytes]
                  ) -> trimesh.Trimesh | None:
        """One ``<geometry>`` as a mesh in its visual's frame; None when nothing to draw."""
        if geometry is None:
            return None
        shape: trimesh.Trimesh
        if geometry.box is not None:
            shape = trimesh.creation.box(extents=np.asarray(geometry.box.size, float))
            return shape
        if geometry.cylinder is not None:
            shape = trimesh.creation.cylinder(radius=float(geometry.cylinder.radius),
                                              height=float(geometry.cylinder.length))
            return shape
        if geometry.sphere is not None:
            shape = trimesh.creation.icosphere(subdivisions=2,
                                               radius=float(geometry.sphere.radius))
            return shape
        if geometry.mesh is None:
            return None
        name = str(geometry.mesh.filename)
        mesh = _mesh_of(name, meshes.get(name))
        if mesh is None:
            self.missing.append(name)
            return None
        if geometry.mesh.scale is not None:
            scale = np.broadcast_to(np.asarray(geometry.mesh.scale, float), (3,))
            mesh.apply_transform(np.diag([*scale, 1.0]))
        return mesh

    def _extent(self) -> tuple[float, float]:
        """Lowest and highest point of the neutral body, in the root's frame."""
        poses = self.frames.link_poses(self.vector(self.neutral))
        by_path = {self.path_of(link): pose for link, pose in poses.items()}
        low, high = 0.0, 0.0
        for shape in self.shapes:
            world = by_path[shape.link_path]
            z = (shape.mesh.vertices @ world[:3, :3].T + world[:3, 3])[:, 2]
            if z.size:
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


def _mesh_of(name: str, data: bytes | None) -> trimesh.Trimesh | None:
    """A mesh file the message carries, read from its bytes; None if absent or unreadable."""
    kind = MESH_TYPES.get(name[name.rfind("."):].lower()) if "." in name else None
    if data is None or kind is None:
        return None
    try:
        loaded = trimesh.load(io.BytesIO(data), file_type=kind, force="mesh", process=False,
                              skip_materials=True)
    except Exception:  # trimesh's loaders raise assorted types on a broken file
        return None
    if not isinstance(loaded, trimesh.Trimesh) or not len(loaded.faces):
        return None
    vertices = np.asarray(loaded.vertices, dtype=float)
    if not np.isfinite(vertices).all() or np.abs(vertices).max() > 1e6:
        return None
    return loaded


def _paint(mesh: trimesh.Trimesh, visual: UrdfShape, materials: Mapping[str, UrdfMaterial]
           ) -> None:
    """Colour a shape as its material says: its own colour, else the colour of the robot's
    material of that name (yourdfpy's ``apply_visual_color``, on the plain records)."""
    m = visual.material
    if m is None:
        return
    rgba = m.rgba
    if rgba is None and m.name is not None and m.name in materials:
        rgba = materials[m.name].rgba
    if rgba is not None and isinstance(mesh.visual, trimesh.visual.ColorVisuals):
        mesh.visual.face_colors[:] = [int(255 * channel) for channel in rgba]
