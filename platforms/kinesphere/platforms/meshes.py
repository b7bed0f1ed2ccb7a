"""Mesh files of a brought robot: found inside its package, checked, made readable by MuJoCo.

URDFs name meshes as ``package://PKG/path``, ``file://`` URLs or paths relative to the URDF.
A platform folder must stand on its own, so ``platform new`` copies every mesh into its
``meshes/`` folder and points the eURDF there. A package may be hostile, so a mesh is read only
where its name says it is: the real file (symlinks followed) must lie inside the package it was
found in (the ``package://`` folder, else the URDF's package or folder), must be a regular file
with a mesh suffix, and is bounded in bytes, faces and vertices; a copy is never more readable
than its source. MuJoCo reads binary STL and OBJ; an ASCII STL and an OBJ (whose texture
coordinates MuJoCo warns about, or whose normals it rejects) become binary STL, anything else
(COLLADA ``.dae`` above all, and an OBJ past MuJoCo's face limit) the convex hull of its
vertices, read by trimesh (a yourdfpy dependency). A mesh that cannot be found, or in which
trimesh finds no triangle, is replaced by a box with the link's inertia, so collision and
floor checks still have something to check.
"""

from __future__ import annotations

import hashlib
import os
import re
import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

import numpy as np

from kinesphere.errors import KinesphereError
from kinesphere.lru import Lru
from kinesphere.platforms import origins

MUJOCO_READS = (".stl", ".obj")
SUFFIXES = frozenset({".stl", ".obj", ".dae", ".ply", ".off", ".glb", ".gltf"})
MAX_BYTES = 64 * 2**20  # one mesh file
MAX_TOTAL = 512 * 2**20  # every mesh of one robot
MAX_FACES = 200_000  # MuJoCo's limit for an STL file
MIN_VERTICES = 4  # MuJoCo's least for a mesh
STAND_IN = (0.01, 0.5)  # metres: the sides of a stand-in box, clamped
MADE_BYTES = 128 * 2**20  # the STL files remembered by one process (see _MADE)

Made = tuple[str, bytes]
"""What a mesh became: ``"converted"`` or ``"hull"``, and the binary STL written."""
_MADE: Lru[tuple[str, int, int, int, int], Made] = Lru(
    1024, MADE_BYTES, lambda _key, made: len(made[1]))
"""A file's (real path, device, inode, size, modification time in ns) -> what it became: a
process that brings many robots (``make sweep``, a package's variants of one robot) reads,
converts and hulls a mesh they share once (trimesh's COLLADA reader and the hull take most of
``platform new``). Written only by this process, for files it read itself."""


def refused(message: str) -> KinesphereError:
    return KinesphereError("invalid_eurdf", message)


@dataclass
class Imported:
    """What became of a robot's meshes."""

    copied: int = 0
    converted: int = 0  # ASCII STL and OBJ written as binary STL
    hulls: int = 0
    missing: list[str] = field(default_factory=list)
    stand_ins: list[str] = field(default_factory=list)  # one line per replaced geometry


@dataclass(frozen=True)
class Found:
    path: Path  # as named (lexically), not resolved
    package: Path  # the folder it must stay inside


def locate(filename: str, urdf_dir: Path) -> Found | None:
    """Where a URDF mesh name points, with the package it must stay in; None when absent.

    ``package://PKG/rest`` is looked up in every ancestor of the URDF's folder (a folder named
    PKG, or one holding PKG) and in ``ROS_PACKAGE_PATH``.
    """
    if filename.startswith("package://"):
        pkg, _, rest = filename[len("package://"):].lstrip("/").partition("/")
        roots: list[Path] = []
        for folder in (urdf_dir, *urdf_dir.parents):
            roots += [folder] if folder.name == pkg else [folder / pkg]
        for entry in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
            if entry:
                roots += [Path(entry) / pkg, Path(entry)]
        for root in roots:
            if (root / rest).is_file():
                return Found(root / rest, root)
        return None
    if filename.startswith("file://"):
        path = Path(unquote(urlparse(filename).path))
    else:
        path = Path(filename)
    if not path.is_absolute():
        path = Path(os.path.normpath(urdf_dir / path))
        package = Path(os.path.commonpath([_package(urdf_dir), path]))
    else:
        package = _package(path.parent)
    return Found(path, package) if path.is_file() else None


def _package(folder: Path) -> Path:
    """The ROS package a folder is in (nearest ancestor with package.xml), else the folder."""
    for f in (folder, *folder.parents):
        if (f / "package.xml").is_file():
            return f
    return folder


def check(found: Found, name: str) -> Path:
    """The real file behind a found mesh, refused if it leaves its package, is no regular
    mesh file or is too large."""
    real = Path(os.path.realpath(found.path))
    package = Path(os.path.realpath(found.package))
    if real != package and package not in real.parents:
        raise refused(f"mesh {name}: {found.path} leads to {real}, outside its package "
                      f"{found.package}; a mesh is never read from outside it")
    if found.path.suffix.lower() not in SUFFIXES or real.suffix.lower() not in SUFFIXES:
        raise refused(f"mesh {name}: {real.name} is not a mesh file "
                      f"({', '.join(sorted(SUFFIXES))})")
    st = real.stat()
    if not real.is_file():
        raise refused(f"mesh {name}: {real} is not a regular file")
    if st.st_size > MAX_BYTES:
        raise refused(f"mesh {name}: {st.st_size} bytes; a mesh may have at most {MAX_BYTES}")
    return real


def import_meshes(robot: ET.Element, urdf_dir: Path, folder: Path) -> Imported:
    """Copy or convert every ``<mesh>`` of ``robot`` into ``folder/meshes`` and point the
    elements there (relative names); replace the ones not found by stand-ins."""
    out_dir = folder / "meshes"
    done: dict[Path, str] = {}
    result = Imported()
    total = 0
    for link in robot.findall("link"):
        for kind in ("collision", "visual"):
            for k, item in enumerate(list(link.findall(kind))):
                mesh = item.find("geometry/mesh")
                if mesh is None:
                    continue
                name = mesh.get("filename") or ""
                found = locate(name, urdf_dir)
                if found is None:
                    result.missing.append(name)
                    result.stand_ins.append(_stand_in(link, item, kind, k, name, "not found"))
                    continue
                real = check(found, name)
                if real not in done:
                    total += real.stat().st_size
                    if total > MAX_TOTAL:
                        raise refused(f"meshes of more than {MAX_TOTAL} bytes in all")
                    out_dir.mkdir(exist_ok=True)
                    done[real] = _write(real, name, out_dir, result)
                if done[real]:
                    mesh.set("filename", f"meshes/{done[real]}")
                else:
                    result.stand_ins.append(_stand_in(link, item, kind, k, name, "unreadable"))
    return result


def _write(real: Path, name: str, out_dir: Path, result: Imported) -> str:
    """Write one mesh into ``out_dir`` as MuJoCo reads it; the file name written, or "" for a
    format trimesh reads no triangle of (a COLLADA file of an unsupported kind)."""
    stem = re.sub(r"[^A-Za-z0-9_.-]", "_", real.stem)[:40] or "mesh"
    digest = hashlib.sha1(str(real).encode()).hexdigest()[:8]
    st = real.stat()
    mode = st.st_mode & 0o644 | 0o600
    suffix = real.suffix.lower()
    if suffix == ".stl" and _binary_stl_faces(real, name) is not None:
        target = out_dir / f"{stem}_{digest}.stl"
        _copy(real, target, mode)
        result.copied += 1
    else:
        key = (str(real), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
        kind, data = _MADE.get(key) or _MADE.put(key, _convert(real, name, suffix))
        if not data:
            return ""
        target = out_dir / f"{stem}_{digest}{'_hull' if kind == 'hull' else ''}.stl"
        _write_new(target, mode, data)
        result.converted += kind == "converted"
        result.hulls += kind == "hull"
    return target.name


def _convert(real: Path, name: str, suffix: str) -> Made:
    """A mesh MuJoCo cannot read as it is, as binary STL: an ASCII STL or an OBJ that fits
    converted, anything else the convex hull of its vertices (no STL: fewer than
    MIN_VERTICES of them)."""
    if suffix in MUJOCO_READS and _fits(mesh := _load(real, name), name, suffix):
        return "converted", _stl(mesh, name)
    points = _load(real, name).vertices if suffix in MUJOCO_READS else _points(real, name)
    if len(points) < MIN_VERTICES:
        return "hull", b""
    return "hull", _stl(_hull(points, name), name)


def _binary_stl_faces(path: Path, name: str) -> int | None:
    """The face count of a binary STL (checked against MuJoCo's bounds), or None when the
    file is ASCII STL."""
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(84)
    if len(head) < 84:
        return None
    faces = int(struct.unpack("<I", head[80:84])[0])
    if size != 84 + 50 * faces:
        return None
    _bounded(name, faces, 3 * faces)
    return faces


def _fits(mesh: Any, name: str, suffix: str) -> bool:
    """An ASCII STL past MuJoCo's face limit is refused like a binary one; an OBJ is hulled."""
    if suffix == ".stl":
        _bounded(name, len(mesh.faces), len(mesh.vertices))
    return len(mesh.faces) <= MAX_FACES


def _bounded(name: str, faces: int, vertices: int) -> None:
    if faces > MAX_FACES:
        raise refused(f"mesh {name}: {faces} faces; MuJoCo reads at most {MAX_FACES} "
                      "(simplify it, e.g. with a decimation filter)")
    if vertices < MIN_VERTICES or faces < 1:
        raise refused(f"mesh {name}: {vertices} vertices; a mesh needs at least {MIN_VERTICES}")


def _load(src: Path, name: str, strict: bool = True) -> Any:
    """A mesh file read by trimesh; a STL or OBJ (``strict``) with fewer than MIN_VERTICES is
    refused, other formats are hulled if they hold enough."""
    import trimesh

    try:
        loaded: Any = trimesh.load(src, force="mesh", skip_materials=True)
        vertices = len(loaded.vertices)
    except Exception as exc:  # trimesh and its loaders raise assorted types
        raise refused(f"cannot read mesh {name}: {exc}") from None
    if strict:
        _bounded(name, 1, vertices)
    return loaded


def _points(src: Path, name: str) -> np.ndarray:
    """Every vertex of a scene file (COLLADA, glTF, ...) where its scene graph puts it: all a
    hull needs, without merging the parts' materials and textures (seconds per file)."""
    import trimesh

    try:
        scene: Any = trimesh.load(src, force="scene", skip_materials=True)
        parts = [trimesh.transform_points(scene.geometry[geometry].vertices, transform)
                 for transform, geometry in (scene.graph[node]
                                             for node in scene.graph.nodes_geometry)
                 if hasattr(scene.geometry[geometry], "vertices")]
    except Exception as exc:  # trimesh and its loaders raise assorted types
        raise refused(f"cannot read mesh {name}: {exc}") from None
    return np.vstack(parts) if parts else np.zeros((0, 3))


def _hull(points: np.ndarray, name: str) -> Any:
    import trimesh

    try:
        return trimesh.convex.convex_hull(np.asarray(points, dtype=float))
    except Exception as exc:  # qhull refuses flat or degenerate point sets
        raise refused(f"cannot make a convex hull of mesh {name}: {exc}") from None


def _stl(mesh: Any, name: str) -> bytes:
    _bounded(name, len(mesh.faces), len(mesh.vertices))
    data: bytes = mesh.export(file_type="stl")
    return data


def _write_new(target: Path, mode: int, data: bytes) -> None:
    fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, mode)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)


def _copy(src: Path, target: Path, mode: int) -> None:
    fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, mode)
    with os.fdopen(fd, "wb") as out, src.open("rb") as inp:
        while chunk := inp.read(1 << 20):
            out.write(chunk)


def _stand_in(link: ET.Element, item: ET.Element, kind: str, k: int, name: str,
              why: str) -> str:
    """Replace a missing mesh with the box of the link's inertia (a solid box of its mass and
    principal moments, on its principal axes), or drop it when the link has no inertia."""
    lname = link.get("name")
    box = inertia_box(link)
    geometry = item.find("geometry")
    assert geometry is not None
    if box is None:
        link.remove(item)
        return f"link {lname}: {kind} {k} mesh {name} {why}; dropped (no inertia to size it)"
    sides, frame = box
    for child in list(geometry):
        geometry.remove(child)
    ET.SubElement(geometry, "box", size=" ".join(f"{s:.4g}" for s in sides))
    origins.write(item, frame)
    return (f"link {lname}: {kind} {k} mesh {name} {why}; stand-in box "
            f"{' x '.join(f'{s:.3g}' for s in sides)} m from its inertia")


def inertia_box(link: ET.Element) -> tuple[list[float], np.ndarray] | None:
    """The solid box with a link's mass and principal moments of inertia (sides clamped to
    STAND_IN), and its frame in the link's frame; None without a usable inertia."""
    inertial = link.find("inertial")
    mass_el = inertial.find("mass") if inertial is not None else None
    tensor_el = inertial.find("inertia") if inertial is not None else None
    if inertial is None or mass_el is None or tensor_el is None:
        return None
    mass = float(mass_el.get("value") or 0.0)
    if mass <= 0:
        return None
    i = {k: float(tensor_el.get(k) or 0.0) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
    tensor = np.array([[i["ixx"], i["ixy"], i["ixz"]], [i["ixy"], i["iyy"], i["iyz"]],
                       [i["ixz"], i["iyz"], i["izz"]]])
    moments, axes = np.linalg.eigh(tensor)
    if np.linalg.det(axes) < 0:
        axes[:, 0] *= -1
    m1, m2, m3 = moments
    squares = 6.0 / mass * np.array([m2 + m3 - m1, m1 + m3 - m2, m1 + m2 - m3])
    sides = [float(np.clip(np.sqrt(max(s, 0.0)), *STAND_IN)) for s in squares]
    frame = origins.read(inertial)
    frame[:3, :3] = frame[:3, :3] @ axes
    return sides, frame
