"""The URDF elements the roles read (links, joints, shapes, inertias, materials) as plain data.

yourdfpy is the reader of record, but importing it costs every process about 0.7 s of CPU
(it imports trimesh, hence SciPy and networkx, whose geometry we never use here). So its
parse is turned into these typed, immutable records and kept on disk by content
(:mod:`kinesphere.filecache`): a process that loads a description read before decodes it
in about a millisecond and never imports yourdfpy. The records keep yourdfpy's shapes
(``origin`` a 4x4 matrix, ``axis`` a 3-vector, ``link_map``/``joint_map``), so code reads
them as it read yourdfpy's.
"""

from __future__ import annotations

import functools
import hashlib
import io
import math
from importlib.metadata import version
from pathlib import Path
from typing import Any, Final

import msgspec
import numpy as np
import numpy.typing as npt

from kinesphere.filecache import FileCache

Array = npt.NDArray[np.float64]
CACHE: Final = FileCache("urdf", max_entries=1024, max_bytes=4 << 20, max_total=64 << 20)
"""Trees of descriptions read before, by the hash of their text and of the reader (a shipped
robot's is 10-40 kB; bodies from the network are kept too, so room for many)."""


class UrdfBox(msgspec.Struct, frozen=True):
    size: Array


class UrdfCylinder(msgspec.Struct, frozen=True):
    radius: float
    length: float


class UrdfSphere(msgspec.Struct, frozen=True):
    radius: float


class UrdfMesh(msgspec.Struct, frozen=True):
    filename: str
    scale: Array | None = None
    """One number or three, as written."""


class UrdfGeometry(msgspec.Struct, frozen=True):
    """A ``<geometry>``: exactly one of its fields is set."""

    box: UrdfBox | None = None
    cylinder: UrdfCylinder | None = None
    sphere: UrdfSphere | None = None
    mesh: UrdfMesh | None = None


class UrdfMaterial(msgspec.Struct, frozen=True):
    name: str | None = None
    rgba: Array | None = None


class UrdfShape(msgspec.Struct, frozen=True):
    """A ``<visual>`` or ``<collision>`` (a collision has no material)."""

    name: str | None = None
    origin: Array | None = None
    geometry: UrdfGeometry | None = None
    material: UrdfMaterial | None = None


class UrdfInertial(msgspec.Struct, frozen=True):
    origin: Array | None = None
    mass: float | None = None
    inertia: Array | None = None
    """The 3x3 tensor."""


class UrdfLink(msgspec.Struct, frozen=True):
    name: str
    inertial: UrdfInertial | None = None
    visuals: tuple[UrdfShape, ...] = ()
    collisions: tuple[UrdfShape, ...] = ()


class UrdfLimit(msgspec.Struct, frozen=True):
    effort: float | None = None
    velocity: float | None = None
    lower: float | None = None
    upper: float | None = None


class UrdfMimic(msgspec.Struct, frozen=True):
    """A ``<mimic>`` element as written (the eURDF's :class:`~kinesphere.eurdf.Mimic` is
    what it means once its leader is known to be a joint of P)."""

    joint: str
    multiplier: float | None = None
    offset: float | None = None


class UrdfJoint(msgspec.Struct, frozen=True):
    name: str
    type: str
    parent: str
    child: str
    origin: Array | None = None
    axis: Array | None = None
    limit: UrdfLimit | None = None
    mimic: UrdfMimic | None = None


class UrdfRobot(msgspec.Struct, frozen=True):
    name: str
    links: tuple[UrdfLink, ...]
    joints: tuple[UrdfJoint, ...]
    materials: tuple[UrdfMaterial, ...] = ()
    """The ``<material>`` elements under ``<robot>``, which visuals may name."""


class UrdfTree:
    """A parsed URDF: its robot, and its links and joints by name (in document order)."""

    def __init__(self, robot: UrdfRobot) -> None:
        self.robot = robot
        self.link_map: dict[str, UrdfLink] = {link.name: link for link in robot.links}
        self.joint_map: dict[str, UrdfJoint] = {j.name: j for j in robot.joints}

    def __eq__(self, other: object) -> bool:
        """The same elements and numbers (as yourdfpy's URDF compares; unhashable like it)."""
        if not isinstance(other, UrdfTree):
            return NotImplemented
        return _encoded(self.robot) == _encoded(other.robot)

    __hash__ = None  # type: ignore[assignment]


def read_urdf(text: str) -> UrdfTree:
    """The URDF in ``text`` as yourdfpy reads it (no meshes loaded), from the cache when this
    text was read before by this reader. yourdfpy's errors pass through unchanged."""
    key = _key(text)
    cached = CACHE.get(key)
    robot = None if cached is None else _unsealed(cached)
    if robot is None:
        robot = _parse(text)
        CACHE.put(key, _sealed(robot))
    return UrdfTree(robot)


def _sealed(robot: UrdfRobot) -> bytes:
    """A cache entry: the records, after the SHA-256 of their bytes."""
    payload = _encoded(robot)
    return hashlib.sha256(payload).digest() + payload


def _unsealed(entry: bytes) -> UrdfRobot | None:
    """The records of a cache entry, or None (the text is then read again) when the entry is
    not whole (damaged on disk, cut short, written by a run that broke) or not well formed.
    The joint limits an agent keeps to come from here: a wrong entry must never be used."""
    digest, payload = entry[:32], entry[32:]
    if hashlib.sha256(payload).digest() != digest:
        return None
    try:
        robot = _DECODER.decode(payload)
    except (msgspec.DecodeError, ValueError, TypeError):
        return None
    return robot if _well_formed(robot) else None


def _shaped(a: Array | None, *shapes: tuple[int, ...]) -> bool:
    return a is None or (a.shape in shapes and bool(np.isfinite(a).all()))


def _finite(*values: float | None) -> bool:
    return all(v is None or math.isfinite(v) for v in values)


def _well_formed(robot: UrdfRobot) -> bool:
    """Every array of the shape yourdfpy gives it, every number finite, no limit upside
    down: what the roles index and trust without checking again."""
    for link in robot.links:
        i = link.inertial
        if i is not None and not (_shaped(i.origin, (4, 4)) and _shaped(i.inertia, (3, 3))
                                  and _finite(i.mass)):
            return False
        for shape in (*link.visuals, *link.collisions):
            g, m = shape.geometry, shape.material
            if not (_shaped(shape.origin, (4, 4))
                    and (m is None or _shaped(m.rgba, (4,)))
                    and (g is None or (
                        (g.box is None or _shaped(g.box.size, (3,)))
                        and (g.cylinder is None or _finite(g.cylinder.radius, g.cylinder.length))
                        and (g.sphere is None or _finite(g.sphere.radius))
                        and (g.mesh is None or _shaped(g.mesh.scale, (1,), (3,)))))):
                return False
    if not all(_shaped(m.rgba, (4,)) for m in robot.materials):
        return False
    for j in robot.joints:
        lim, mim = j.limit, j.mimic
        if not (_shaped(j.origin, (4, 4)) and _shaped(j.axis, (3,))
                and (lim is None or (_finite(lim.effort, lim.velocity, lim.lower, lim.upper)
                                     and (lim.lower is None or lim.upper is None
                                          or lim.lower <= lim.upper)))
                and (mim is None or _finite(mim.multiplier, mim.offset))):
            return False
    return True


def _key(text: str) -> str:
    h = hashlib.sha256()
    for part in (*_reader(), text.encode("utf-8")):
        h.update(len(part).to_bytes(8, "little"))
        h.update(part)
    return h.hexdigest()


@functools.cache
def _reader() -> tuple[bytes, ...]:
    """What the cached records depend on besides the text: this module's code and the
    versions of kinesphere, yourdfpy and what yourdfpy parses with (lxml, NumPy), read
    without importing them."""
    return (Path(__file__).read_bytes(),
            *(version(d).encode() for d in ("kinesphere", "yourdfpy", "lxml", "numpy")))


def _encoded(robot: UrdfRobot) -> bytes:
    return msgspec.msgpack.encode(robot, enc_hook=_encode)


def _encode(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise NotImplementedError(f"cannot encode {type(obj).__name__}")


def _decode(kind: type, obj: Any) -> Any:
    if kind is np.ndarray or getattr(kind, "__origin__", None) is np.ndarray:
        return np.asarray(obj, dtype=float)
    raise NotImplementedError(f"cannot decode {kind}")


_DECODER: Final = msgspec.msgpack.Decoder(UrdfRobot, dec_hook=_decode)


def _parse(text: str) -> UrdfRobot:
    import yourdfpy  # the costly import, paid only by a text no process has read before

    urdf = yourdfpy.URDF.load(
        io.BytesIO(text.encode("utf-8")),  # bytes: lxml refuses str with an encoding decl
        load_meshes=False,
        build_scene_graph=False,
        build_collision_scene_graph=False,
    )
    robot = urdf.robot
    return UrdfRobot(
        name=str(robot.name),
        links=tuple(_link(link) for link in robot.links),
        joints=tuple(_joint(j) for j in robot.joints),
        materials=tuple(m for m in map(_material, robot.materials) if m is not None),
    )


def _array(value: Any) -> Array | None:
    return None if value is None else np.atleast_1d(np.asarray(value, dtype=float))


def _number(value: Any) -> float | None:
    return None if value is None else float(value)


def _material(m: Any) -> UrdfMaterial | None:
    if m is None:
        return None
    rgba = None if m.color is None else _array(m.color.rgba)
    return UrdfMaterial(name=None if m.name is None else str(m.name), rgba=rgba)


def _geometry(g: Any) -> UrdfGeometry | None:
    if g is None:
        return None
    return UrdfGeometry(
        box=None if g.box is None else UrdfBox(np.asarray(g.box.size, dtype=float)),
        cylinder=None if g.cylinder is None
        else UrdfCylinder(float(g.cylinder.radius), float(g.cylinder.length)),
        sphere=None if g.sphere is None else UrdfSphere(float(g.sphere.radius)),
        mesh=None if g.mesh is None else UrdfMesh(str(g.mesh.filename), _array(g.mesh.scale)),
    )


def _shape(item: Any) -> UrdfShape:
    return UrdfShape(
        name=None if item.name is None else str(item.name),
        origin=_array(item.origin),
        geometry=_geometry(item.geometry),
        material=_material(getattr(item, "material", None)),
    )


def _link(link: Any) -> UrdfLink:
    i = link.inertial
    inertial = None if i is None else UrdfInertial(
        origin=_array(i.origin), mass=_number(i.mass), inertia=_array(i.inertia))
    return UrdfLink(
        name=str(link.name),
        inertial=inertial,
        visuals=tuple(map(_shape, link.visuals)),
        collisions=tuple(map(_shape, link.collisions)),
    )


def _joint(j: Any) -> UrdfJoint:
    lim, mim = j.limit, j.mimic
    return UrdfJoint(
        name=str(j.name),
        type=str(j.type),
        parent=str(j.parent),
        child=str(j.child),
        origin=_array(j.origin),
        axis=_array(j.axis),
        limit=None if lim is None else UrdfLimit(
            _number(lim.effort), _number(lim.velocity), _number(lim.lower), _number(lim.upper)),
        mimic=None if mim is None else UrdfMimic(
            str(mim.joint), _number(mim.multiplier), _number(mim.offset)),
    )
