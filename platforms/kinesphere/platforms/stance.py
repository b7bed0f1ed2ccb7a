"""How a brought robot stands: which way is up, what touches the floor, how high the root is,
and what base that makes.

Everything is read from collision geometry (visual meshes are often larger or looser than
what the robot stands on; a link without any collision geometry stands on its visuals), with
the exact lowest point of each shape, so the base height puts the feet, wheels or pedestal on
the floor and the balance check of the ECL generator finds them there. A robot standing on
two or more of its limbs is **legged**: walking is abstracted as a holonomic planar base, as
NAO's is. A file whose legs point along another axis than -z (pybullet's Y-up laikago and
humanoid) is turned so z is up, by re-expressing the root link's frame.
"""

from __future__ import annotations

import copy
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import mujoco
import numpy as np

from kinesphere.eurdf import Eurdf
from kinesphere.platforms import origins

TOUCH = 0.003  # metres above the lowest point that still bears weight (as the generator's)
UP_AXES = ("z", "y", "x", "-z", "-y", "-x")
_VECTORS = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def axis_vector(up: str) -> np.ndarray:
    out: np.ndarray = np.array(_VECTORS[up.lstrip("-")])
    return -out if up.startswith("-") else out


def upright(up: str) -> np.ndarray:
    """The rotation that turns a file's ``up`` axis into +z (x forward kept where it can be)."""
    u = axis_vector(up)
    if np.allclose(u, [0, 0, 1]):
        return np.eye(3)
    if np.allclose(u, [0, 0, -1]):
        return np.diag([1.0, -1.0, -1.0])
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(u, z)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    turn: np.ndarray = np.eye(3) + k + k @ k  # Rodrigues at 90 degrees: sin 1, 1 - cos 1
    return turn


def detect_up(legs: list[np.ndarray]) -> str:
    """y or -y when every leg's tip hangs from the root along -y or +y (pybullet's Y-up
    files), else z: legs folded forward or back at zero (a Ghost quadruped) say nothing."""
    if len(legs) < 2:
        return "z"
    tips = np.array(legs)
    along = np.abs(tips[:, 1]) > 1.25 * np.abs(tips[:, [0, 2]]).max(axis=1)
    if along.all() and len(set(np.sign(tips[:, 1]))) == 1:
        return "y" if tips[0, 1] < 0 else "-y"
    return "z"


def turn_root(robot: ET.Element, rotation: np.ndarray) -> None:
    """Re-express the root link's frame turned by ``rotation``: its geometry and inertia and the
    joints leaving it; everything below follows."""
    children = {str(el.find("child").get("link")) for el in robot.findall("joint")}  # type: ignore[union-attr]
    root = next(el for el in robot.findall("link") if el.get("name") not in children)
    turn = np.eye(4)
    turn[:3, :3] = rotation
    items = [*root.findall("visual"), *root.findall("collision"), *root.findall("inertial")]
    items += [el for el in robot.findall("joint")
              if el.find("parent").get("link") == root.get("name")]  # type: ignore[union-attr]
    for el in items:
        origins.write(el, turn @ origins.read(el))


def bearing_geoms(model: mujoco.MjModel) -> list[int]:
    """Each link's collision geoms; its visual ones when it has no collision geometry (PR2's
    wheels are drawn, not collided)."""
    robot = [g for g in range(model.ngeom) if model.geom_bodyid[g] != 0]
    colliding = {int(model.geom_bodyid[g]) for g in robot if model.geom_contype[g]}
    return [g for g in robot
            if model.geom_contype[g] or int(model.geom_bodyid[g]) not in colliding]


def lowest(model: mujoco.MjModel, data: mujoco.MjData, g: int) -> float:
    """The exact height of a geom's lowest point at the current kinematics."""
    z = float(data.geom_xpos[g, 2])
    rz = data.geom_xmat[g].reshape(3, 3)[2]  # world z of each geom axis
    size = model.geom_size[g]
    kind = model.geom_type[g]
    r, h, c = float(size[0]), float(size[1]), abs(float(rz[2]))
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return z - r
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return z - c * h - r
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return z - c * h - r * float(np.sqrt(max(0.0, 1 - c * c)))
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return z - float(np.abs(rz) @ size)
    if kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        return z - float(np.linalg.norm(rz * size))
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[g]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        return z + float((model.mesh_vert[start:start + count] @ rz).min())
    return z - float(model.geom_rbound[g])


@dataclass(frozen=True)
class Stance:
    """The robot at its neutral pose with the root at the origin: how far its lowest point is
    below the root, and which links bear its weight."""

    depth: float  # the root's height above its lowest point
    feet: tuple[str, ...]  # links with geometry within TOUCH of the lowest point
    drawn: tuple[str, ...] = ()  # feet that touch with visual geometry only

    def on(self, eurdf: Eurdf) -> tuple[list[str], bool]:
        """The first-level limbs standing on the floor, and whether the core does too."""
        firsts = [p for p in eurdf.limbs if p.index[1] == 1]
        limbs = sorted({p.name for p in firsts for f in self.feet if f in p.links})
        core = any(f in p.links for p in eurdf.core for f in self.feet)
        return limbs, core


def collide_visuals(robot: ET.Element, links: tuple[str, ...]) -> None:
    """Give links that stand on the floor with visual geometry only that geometry as collision
    geometry too, so the balance check sees what the robot stands on."""
    for link in robot.findall("link"):
        if link.get("name") in links and link.find("collision") is None:
            for visual in link.findall("visual"):
                collision = ET.Element("collision")
                for child in visual:
                    if child.tag in ("origin", "geometry"):
                        collision.append(copy.deepcopy(child))
                link.insert(list(link).index(visual) + 1, collision)


def stance(model: mujoco.MjModel, qpos: np.ndarray) -> Stance:
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    geoms = bearing_geoms(model)
    if not geoms:
        return Stance(0.0, (), ())
    heights = {g: lowest(model, data, g) for g in geoms}
    low = min(heights.values())
    feet = sorted({model.body(int(model.geom_bodyid[g])).name
                   for g, h in heights.items() if h - low < TOUCH})
    drawn = sorted({model.body(int(model.geom_bodyid[g])).name for g, h in heights.items()
                    if h - low < TOUCH and not model.geom_contype[g]})
    root = float(data.xpos[1, 2])
    return Stance(root - low, tuple(feet), tuple(drawn))
