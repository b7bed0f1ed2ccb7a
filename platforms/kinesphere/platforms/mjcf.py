"""Compile a platform's eURDF into a MuJoCo model with MjSpec.

Why our own builder instead of MuJoCo's URDF importer: we need position actuators on every
joint of P with gains matched to each joint's inertia, gravity compensation (real arms have
it, and it keeps position tracking honest), a driveable planar base (x, y, yaw) for mobile
platforms, and self-collision exclusions derived from the neutral pose. A brought robot's
meshes (STL, OBJ, found beside its eURDF) become mesh geoms, and its mimic joints follow their
leader through an equality constraint, as the URDF says, without an actuator of their own
(NAO's RHipYawPitch follows LHipYawPitch: one motor). Body, joint and actuator names are the
URDF's, so every role can address them by the eURDF's names.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from kinesphere.platforms.meshes import MUJOCO_READS
from kinesphere.platforms.platform import Platform, load_platform
from kinesphere.urdf_tree import UrdfJoint, UrdfLink, UrdfMimic, UrdfTree

BASE_JOINTS = ("base_x", "base_y", "base_yaw")
TIMESTEP = 0.002
ROBOT_CONTYPE = 1  # robot geoms collide with each other ...
FLOOR_CONTYPE = 2  # ... but not with the floor: the planar base is driven kinematically
TRACKING_HZ = 12.0  # bandwidth of the joint position servos
LIMIT_TIMECONST = 2 * TIMESTEP


@dataclass(frozen=True)
class PlatformModel:
    """A compiled model plus the index maps every user of it needs."""

    platform: Platform
    model: mujoco.MjModel
    qpos_index: dict[str, int]  # joint name -> qpos address (P joints and base joints)
    dof_index: dict[str, int]
    actuator_index: dict[str, int]
    excluded_pairs: tuple[tuple[str, str], ...]

    def neutral_qpos(self) -> np.ndarray:
        return self.qpos({})

    def qpos(self, joints: dict[str, float]) -> np.ndarray:
        """A full qpos: neutral, then ``joints`` (P names), mimic joints following leaders."""
        values = {**self.platform.neutral, **joints}
        q: np.ndarray = self.model.qpos0.copy()
        for joint, value in self.platform.eurdf.with_mimics(values).items():
            q[self.qpos_index[joint]] = value
        return q

    def make_data(self) -> mujoco.MjData:
        """Fresh data at the neutral pose with actuators holding it."""
        data = mujoco.MjData(self.model)
        data.qpos[:] = self.neutral_qpos()
        for joint, act in self.actuator_index.items():
            data.ctrl[act] = data.qpos[self.qpos_index[joint]]
        mujoco.mj_forward(self.model, data)
        return data


def _quat(rpy_matrix: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rpy_matrix[:3, :3]).ravel())
    return q


def _add_geoms(
    spec: mujoco.MjSpec, body: mujoco.MjsBody, link: UrdfLink, visual: bool, folder: Path
) -> None:
    items = link.visuals if visual else link.collisions
    for k, item in enumerate(items):
        g = item.geometry
        if g is None:
            continue
        origin = item.origin if item.origin is not None else np.eye(4)
        kw: dict[str, object] = {"pos": origin[:3, 3], "quat": _quat(origin)}
        if g.box is not None:
            kw.update(type=mujoco.mjtGeom.mjGEOM_BOX, size=np.asarray(g.box.size) / 2)
        elif g.cylinder is not None:
            kw.update(
                type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                size=[g.cylinder.radius, g.cylinder.length / 2, 0],
            )
        elif g.sphere is not None:
            kw.update(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[g.sphere.radius, 0, 0])
        elif g.mesh is not None and (folder / g.mesh.filename).suffix.lower() in MUJOCO_READS:
            path = folder / g.mesh.filename
            if not path.is_file():
                continue  # 'platform new' lists meshes it could not find
            mesh = spec.add_mesh(name=f"{link.name}_{'vis' if visual else 'col'}{k}",
                                 file=str(path))
            # bodies carry the URDF's inertia, so a mesh's own volume is never used: a flat
            # one (a plane, a cloth) is as good as a closed one
            mesh.inertia = mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL
            if g.mesh.scale is not None:
                mesh.scale = np.broadcast_to(np.asarray(g.mesh.scale, dtype=float), 3)
            kw.update(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=mesh.name)
        else:
            continue  # a mesh MuJoCo cannot read: 'platform new' replaces those by hulls
        geom = body.add_geom(name=f"{link.name}_{'vis' if visual else 'col'}{k}", **kw)
        geom.mass = 0.0
        if visual:
            geom.contype = geom.conaffinity = 0
            geom.group = 1
            mat = item.material
            if mat is not None and mat.rgba is not None:
                geom.rgba = mat.rgba
        else:
            geom.contype = geom.conaffinity = ROBOT_CONTYPE
            geom.group = 3
            geom.rgba = [0.5, 0.5, 0.5, 0.0 if link.visuals else 1.0]


def _principal(link: UrdfLink) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A link's inertia as MuJoCo takes it: position, orientation of the principal axes and
    the principal moments (at least 1e-6); None without a tensor worth the name."""
    inertial = link.inertial
    mass = float(inertial.mass) if inertial is not None and inertial.mass else 0.0
    if inertial is None or inertial.inertia is None or mass <= 1e-3:
        return None
    tensor = np.asarray(inertial.inertia, dtype=float)
    origin = inertial.origin if inertial.origin is not None else np.eye(4)
    rot = origin[:3, :3]
    evals, evecs = np.linalg.eigh(rot @ tensor @ rot.T)
    if np.linalg.det(evecs) < 0:
        evecs[:, 0] *= -1
    return origin[:3, 3], _quat(evecs), np.maximum(evals, 1e-6)


def _add_inertial(body: mujoco.MjsBody, link: UrdfLink, has_joint: bool) -> None:
    inertial = link.inertial
    mass = float(inertial.mass) if inertial is not None and inertial.mass else 0.0
    if mass <= 0.0:
        if not has_joint:
            return
        mass = 1e-3
    body.explicitinertial = True
    body.mass = mass
    principal = _principal(link)
    if principal is not None:
        body.ipos, body.iquat, body.inertia = principal
    else:
        body.inertia = [1e-6, 1e-6, 1e-6]


def unbalanced(urdf: UrdfTree) -> list[str]:
    """Links whose principal moments break A + B >= C: MuJoCo's balanceinertia evens them."""
    out = []
    for link in urdf.robot.links:
        principal = _principal(link)
        if principal is not None:
            a, b, c = sorted(principal[2])
            if a + b < c:
                out.append(str(link.name))
    return out


def build_spec(platform: Platform, visuals: bool = True) -> mujoco.MjSpec:
    """The platform as an editable MjSpec (no gains or exclusions yet); without its visual
    geometry when ``visuals`` is false (see :func:`platform_model`)."""
    urdf = platform.eurdf.urdf
    spec = mujoco.MjSpec()
    spec.modelname = platform.name
    spec.compiler.degree = False
    # Third-party inertias often break the triangle inequality (A + B >= C) by rounding:
    # MuJoCo's own mend sets such a body's moments to their mean ('platform new' lists them).
    spec.compiler.balanceinertia = True
    spec.option.timestep = TIMESTEP
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    world = spec.worldbody
    floor = world.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[0, 0, 0.05],
        rgba=[0.82, 0.84, 0.86, 1],
    )
    floor.contype = floor.conaffinity = FLOOR_CONTYPE
    world.add_light(
        name="sun",
        pos=[1, -1, 3],
        dir=[-0.3, 0.3, -1],
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
    )
    root_name = platform.eurdf.root_link
    root = world.add_body(name=root_name, pos=[0, 0, platform.base.height])
    if platform.base.mobile:
        for name, axis, kind in (
            ("base_x", [1, 0, 0], mujoco.mjtJoint.mjJNT_SLIDE),
            ("base_y", [0, 1, 0], mujoco.mjtJoint.mjJNT_SLIDE),
            ("base_yaw", [0, 0, 1], mujoco.mjtJoint.mjJNT_HINGE),
        ):
            j = root.add_joint(name=name, type=kind, axis=axis)
            j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
            j.damping = [1.0, 0.0, 0.0]
    folder = platform.eurdf.path.parent if platform.eurdf.path else platform.folder
    _add_inertial(root, urdf.link_map[root_name], platform.base.mobile)
    kinds = (False, True) if visuals else (False,)
    for visual in kinds:
        _add_geoms(spec, root, urdf.link_map[root_name], visual, folder)
    bodies = {root_name: root}
    mimics: list[tuple[str, UrdfMimic]] = []
    for joint in _joints_in_tree_order(urdf, root_name):
        parent = bodies[joint.parent]
        origin = joint.origin if joint.origin is not None else np.eye(4)
        body = parent.add_body(name=joint.child, pos=origin[:3, 3], quat=_quat(origin))
        bodies[joint.child] = body
        moving = joint.type in ("revolute", "prismatic", "continuous")
        if moving and joint.mimic is not None:
            # a mimic moves with its leader; one that follows no degree of freedom is rigid
            moving = joint.mimic.joint in platform.eurdf.limits
            if moving:
                mimics.append((joint.name, joint.mimic))
        if moving:
            joint_axis = joint.axis if joint.axis is not None else np.array([1.0, 0.0, 0.0])
            mj = body.add_joint(
                name=joint.name,
                type=mujoco.mjtJoint.mjJNT_SLIDE
                if joint.type == "prismatic"
                else mujoco.mjtJoint.mjJNT_HINGE,
                axis=joint_axis,
            )
            mj.armature = 0.01
            mj.damping = [0.05, 0.0, 0.0]
            if joint.type != "continuous" and joint.limit is not None and not joint.mimic:
                mj.limited = mujoco.mjtLimited.mjLIMITED_TRUE
                mj.range = [joint.limit.lower, joint.limit.upper]
                # Stiffest stable limit (time constant 2 dt): contacts between limbs then
                # push a joint at most a few mrad past its limit instead of centiradians.
                mj.solref_limit = [LIMIT_TIMECONST, 1.0]
            else:
                mj.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        body.gravcomp = 1.0
        link = urdf.link_map[joint.child]
        _add_inertial(body, link, moving)
        for visual in kinds:
            _add_geoms(spec, body, link, visual, folder)
    for name, mimic in mimics:
        eq = spec.add_equality(type=mujoco.mjtEq.mjEQ_JOINT, objtype=mujoco.mjtObj.mjOBJ_JOINT,
                               name1=name, name2=mimic.joint)
        eq.data[:5] = [mimic.offset or 0.0, mimic.multiplier or 1.0, 0.0, 0.0, 0.0]
        eq.solref = [LIMIT_TIMECONST, 1.0]  # as stiff as the joint limits: one motor, one angle
    for name in (*BASE_JOINTS[: 3 if platform.base.mobile else 0], *platform.joint_names):
        act = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=1.0, kv=0.1)
        lim = platform.eurdf.limits.get(name)
        if lim is not None and math.isfinite(lim.lower):
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.ctrlrange = [lim.lower, lim.upper]
        else:
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    return spec


def _joints_in_tree_order(urdf: UrdfTree, root: str) -> list[UrdfJoint]:
    by_parent: dict[str, list[UrdfJoint]] = {}
    for j in urdf.robot.joints:
        by_parent.setdefault(j.parent, []).append(j)
    out: list[UrdfJoint] = []
    todo = [root]
    while todo:
        link = todo.pop(0)
        for j in by_parent.get(link, []):
            out.append(j)
            todo.append(j.child)
    return out


def _tune_gains(spec: mujoco.MjSpec, model: mujoco.MjModel, qpos: np.ndarray) -> None:
    """Critically damped servos at TRACKING_HZ, from each joint's inertia at neutral."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    mass = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, mass)
    omega = 2 * math.pi * TRACKING_HZ
    for act in spec.actuators:
        dof = model.jnt_dofadr[model.joint(act.target).id]
        inertia = max(float(mass[dof, dof]), 1e-4)
        kp = inertia * omega**2
        act.set_to_position(kp=kp, kv=2 * inertia * omega)


def _collect_contacts(model: mujoco.MjModel, qpos: np.ndarray) -> set[tuple[str, str]]:
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    pairs = set()
    for c in data.contact[: data.ncon]:
        b1 = model.body(model.geom_bodyid[c.geom1]).name
        b2 = model.body(model.geom_bodyid[c.geom2]).name
        pairs.add((min(b1, b2), max(b1, b2)))
    return pairs


@functools.cache
def platform_model(name: str, visuals: bool = True) -> PlatformModel:
    """Compile (and cache) the MuJoCo model of a shipped platform.

    ``visuals=False``: the model a simulated robot steps, without the visual geometry only a
    camera sees. Visual geoms have no mass and collide with nothing, so the motion is the same
    bit for bit (a test steps both), but MuJoCo places every geom at every step: in Baxter's
    87 geoms the 43 visual ones were ~10 % of its ``mj_step``, and their meshes are not loaded
    when the agent starts."""
    platform = load_platform(name)
    spec = build_spec(platform, visuals)
    model = spec.compile()
    qpos_index = {model.joint(i).name: int(model.jnt_qposadr[i]) for i in range(model.njnt)}
    neutral = model.qpos0.copy()
    for joint, value in platform.eurdf.with_mimics(dict(platform.neutral)).items():
        neutral[qpos_index[joint]] = value
    excluded: list[tuple[str, str]] = []
    for _ in range(5):  # exclusions can only remove contacts; converge in a few passes
        pairs = _collect_contacts(model, neutral) - set(excluded)
        if not pairs:
            break
        for b1, b2 in sorted(pairs):
            spec.add_exclude(bodyname1=b1, bodyname2=b2)
            excluded.append((b1, b2))
        model = spec.compile()
    _tune_gains(spec, model, neutral)
    model = spec.compile()
    return PlatformModel(
        platform=platform,
        model=model,
        qpos_index=qpos_index,
        dof_index={model.joint(i).name: int(model.jnt_dofadr[i]) for i in range(model.njnt)},
        actuator_index={model.actuator(i).name: i for i in range(model.nu)},
        excluded_pairs=tuple(excluded),
    )


def model_of(platform: Platform) -> PlatformModel:
    """The compiled model of a loaded platform, shipped (by name) or brought (by folder)."""
    return platform_model(platform.name if platform.shipped else str(platform.folder))


def robot_contacts(model: mujoco.MjModel, data: mujoco.MjData) -> list[tuple[str, str]]:
    """Self-contacts in the current state, as body-name pairs in MuJoCo's order.

    Read from the contact array's ``geom`` column: iterating ``data.contact`` costs ~80 us in
    the bindings even when empty, holding the GIL (the guard's checks call this per sample).
    """
    if not data.ncon:
        return []
    bodies = model.geom_bodyid[data.contact.geom]
    return [(model.body(a).name, model.body(b).name) for a, b in bodies.tolist()]
