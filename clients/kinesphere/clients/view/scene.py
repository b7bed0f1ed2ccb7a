"""One robot in the viser scene: its body at the live joint state, a label, a target ghost.

The scene tree under ``/robots/{id}`` is the robot's slot (robots stand side by side), then
its odometry pose (``base_pose``), then the body's links, one frame per joint. Moving the
body sets only the frames of joints that moved since the last frame (an idle robot sends
nothing). The ghost is a second, translucent copy of the body posed at the target the
databank answers for the robot's current command, shown only while the robot moves.
"""

from __future__ import annotations

import math
from typing import Any, Final

import numpy as np
import viser

from kinesphere.clients.view.body import Array, BodyGeometry

SPACING_M: Final = 2.0
"""Distance between two robots' slots along the row."""
EPSILON: Final = 1e-4
"""rad (m): a joint moved by less than this is not sent again."""
GHOST_RGB: Final = (80, 160, 255)
GHOST_OPACITY: Final = 0.3


def yaw_wxyz(yaw: float) -> tuple[float, float, float, float]:
    return (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))


class Skeleton:
    """A body's joint frames and meshes under ``root`` (solid, or a translucent ghost)."""

    def __init__(
        self, server: viser.ViserServer, body: BodyGeometry, root: str, ghost: bool
    ) -> None:
        self.body = body
        scene = server.scene
        self.root = scene.add_frame(root, show_axes=False, position=(0.0, 0.0, body.lift))
        self.frames = [scene.add_frame(f"{root}/{path}", show_axes=False)
                       for path in body.frame_paths]
        self.meshes: list[Any] = []
        for shape in body.shapes:
            name = f"{root}/{shape.link_path}/{shape.name}"
            if ghost:
                self.meshes.append(scene.add_mesh_simple(
                    name, shape.mesh.vertices, shape.mesh.faces, color=GHOST_RGB,
                    opacity=GHOST_OPACITY, cast_shadow=False, receive_shadow=False))
            else:
                self.meshes.append(scene.add_mesh_trimesh(name, shape.mesh))
        self._q: Array | None = None

    @property
    def q(self) -> Array | None:
        """The joints last sent to the browsers (None before the first pose)."""
        return self._q

    def pose(self, q: Array) -> int:
        """Move to ``q`` (this body's joint order); returns how many frames were sent."""
        wxyz, xyz = self.body.transforms(q)
        if self._q is None:
            changed = np.arange(len(self.frames))
        else:
            moved = np.abs(q - self._q) > EPSILON
            if not moved.any():
                return 0
            # a joint frame moves when the joint it follows (itself or its mimic source) moved
            changed = np.flatnonzero(self.body.moved_frames(moved))
        for i in changed:
            frame = self.frames[i]
            frame.wxyz = wxyz[i]
            frame.position = xyz[i]
        self._q = q.copy()
        return len(changed)

    def remove(self) -> None:
        self.root.remove()


LABEL_GAP_M: Final = 0.2
"""How far above the body's highest point its label floats."""
LABEL_STEP_M: Final = 0.05
"""The label moves only when the body's top changed by more than this."""


def _matrix(wxyz: Array) -> Array:
    w, x, y, z = wxyz
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


class Top:
    """The highest point of a body at a pose (each shape as its bounding sphere), so its label
    goes above a raised arm instead of through it."""

    def __init__(self, body: BodyGeometry) -> None:
        self.body = body
        paths = body.frame_paths
        index = {p: i for i, p in enumerate(paths)}
        self._parent = [index.get(p.rpartition("/")[0], -1) for p in paths]
        self._order = sorted(range(len(paths)), key=lambda i: paths[i].count("/"))
        self._spheres = []
        for shape in body.shapes:
            v = np.asarray(shape.mesh.vertices, dtype=float)
            if v.size:
                centre = (v.min(axis=0) + v.max(axis=0)) / 2
                radius = float(np.linalg.norm(v - centre, axis=1).max())
                self._spheres.append((index.get(shape.link_path, -1), centre, radius))

    def __call__(self, q: Array) -> float:
        """Height of the body's top above the floor at ``q``."""
        wxyz, xyz = self.body.transforms(q)
        rot = np.zeros((len(self._parent), 3, 3))
        pos = np.zeros((len(self._parent), 3))
        for i in self._order:
            p = self._parent[i]
            r0, p0 = (np.eye(3), np.zeros(3)) if p < 0 else (rot[p], pos[p])
            rot[i] = r0 @ _matrix(wxyz[i])
            pos[i] = p0 + r0 @ xyz[i]
        top = 0.0
        for frame, centre, radius in self._spheres:
            z = (centre if frame < 0 else rot[frame] @ centre + pos[frame])[2]
            top = max(top, float(z) + radius)
        return top + self.body.lift


class Drawing:
    """A robot's slot in the scene: body, ghost and label."""

    def __init__(
        self, server: viser.ViserServer, robot_id: str, body: BodyGeometry, slot: int
    ) -> None:
        self.robot_id = robot_id
        self.body = body
        self.slot = slot
        root = f"/robots/{robot_id}"
        scene = server.scene
        self.place = scene.add_frame(root, show_axes=False, position=(0.0, slot * SPACING_M, 0.0))
        self.base = scene.add_frame(f"{root}/base", show_axes=False)
        self.solid = Skeleton(server, body, f"{root}/base/body", ghost=False)
        self.ghost = Skeleton(server, body, f"{root}/base/ghost", ghost=True)
        self.ghost.root.visible = False
        self.top = Top(body)
        self._label_z = body.height + LABEL_GAP_M
        self.label = scene.add_label(f"{root}/label", robot_id,
                                     position=(0.0, 0.0, self._label_z))
        self._base_pose: tuple[float, float, float] | None = None
        self._text = robot_id

    def move(self, q: Array, base_pose: tuple[float, float, float]) -> int:
        """The live joint state and odometry pose; returns how many frames were sent. The
        label rides above the body's top at this pose (a raised arm lifts it)."""
        sent = self.solid.pose(q)
        label_z = self._label_z
        if sent:
            top = self.top(q) + LABEL_GAP_M
            if abs(top - label_z) > LABEL_STEP_M:
                label_z = top
        if base_pose != self._base_pose or label_z != self._label_z:
            x, y, yaw = base_pose
            self.base.position = (x, y, 0.0)
            self.base.wxyz = yaw_wxyz(yaw)
            self.label.position = (x, y, label_z)
            self._base_pose, self._label_z = base_pose, label_z
            sent += 1
        return sent

    def show_target(self, q: Array | None, translation: tuple[float, float] = (0.0, 0.0)
                    ) -> None:
        """Pose the ghost at ``q`` (displaced by ``translation`` in the body frame), or hide."""
        visible = q is not None
        if q is not None:
            self.ghost.pose(q)
            self.ghost.root.position = (translation[0], translation[1], self.body.lift)
        if self.ghost.root.visible != visible:
            self.ghost.root.visible = visible

    def caption(self, text: str) -> None:
        if text != self._text:
            self.label.text = text
            self._text = text

    def remove(self) -> None:
        self.place.remove()
