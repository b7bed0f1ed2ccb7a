"""Mesh files of a brought robot: found wherever its URDF points, made readable by MuJoCo.

URDFs name meshes as ``package://PKG/path``, ``file://`` URLs or paths relative to the URDF.
A platform folder must stand on its own, so ``platform new`` copies every mesh into its
``meshes/`` folder and points the eURDF there. MuJoCo reads STL and OBJ; anything else (COLLADA
``.dae`` above all) becomes the convex hull of its vertices, which trimesh (a yourdfpy
dependency) reads. Hulls are coarse but honest for collisions and good enough for pictures.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

from kinesphere.errors import KinesphereError

MUJOCO_READS = (".stl", ".obj")


def resolve(filename: str, urdf_dir: Path) -> Path | None:
    """The file a URDF mesh name points to, or None when it cannot be found.

    ``package://PKG/rest`` is looked up in every ancestor of the URDF's folder (a folder named
    PKG, or one holding PKG) and in ``ROS_PACKAGE_PATH``.
    """
    if filename.startswith("package://"):
        pkg, _, rest = filename[len("package://") :].partition("/")
        roots: list[Path] = []
        for folder in (urdf_dir, *urdf_dir.parents):
            roots += [folder] if folder.name == pkg else [folder / pkg]
        for entry in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep):
            if entry:
                roots += [Path(entry) / pkg, Path(entry)]
        for root in roots:
            if (root / rest).is_file():
                return root / rest
        return None
    if filename.startswith("file://"):
        path = Path(unquote(urlparse(filename).path))
    else:
        path = Path(filename)
        if not path.is_absolute():
            path = urdf_dir / path
    return path if path.is_file() else None


def import_meshes(robot: ET.Element, urdf_dir: Path, folder: Path) -> tuple[int, int, list[str]]:
    """Copy or convert every ``<mesh>`` of ``robot`` into ``folder/meshes`` and point the
    elements there (relative names). Returns (copied, hulls, missing file names)."""
    out_dir = folder / "meshes"
    done: dict[Path, str] = {}
    copied = hulls = 0
    missing: list[str] = []
    for mesh in robot.iter("mesh"):
        name = mesh.get("filename") or ""
        src = resolve(name, urdf_dir)
        if src is None:
            missing.append(name)
            continue
        if src not in done:
            out_dir.mkdir(parents=True, exist_ok=True)
            digest = hashlib.sha1(str(src).encode()).hexdigest()[:8]
            if src.suffix.lower() in MUJOCO_READS:
                target = out_dir / f"{src.stem}_{digest}{src.suffix.lower()}"
                shutil.copyfile(src, target)
                copied += 1
            else:
                target = out_dir / f"{src.stem}_{digest}_hull.stl"
                _hull(src, target)
                hulls += 1
            done[src] = f"meshes/{target.name}"
        mesh.set("filename", done[src])
    return copied, hulls, missing


def _hull(src: Path, target: Path) -> None:
    import trimesh

    try:
        loaded: Any = trimesh.load(src, force="mesh")
        hull = loaded.convex_hull
    except Exception as exc:  # trimesh and its loaders raise assorted types
        raise KinesphereError("invalid_eurdf", f"cannot read mesh {src}: {exc}") from None
    hull.export(target)
