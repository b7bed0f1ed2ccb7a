"""The answer to ``{p}/ecl/{platform}/body``: a platform's body, so viewers need no files.

A viewer on an operator's laptop has only the core installed, yet must draw every robot it
sees. The databank already holds each served platform's description (it reads the eURDF for
the ECL), so it answers with the eURDF text as it is on disk, the neutral pose, the base kind
and the mesh files the text's ``<visual>`` elements name (a brought robot's ``meshes/``): a
viewer never reads a file of its own machine for them, so a user-built platform shows its
meshes wherever the view runs. Only files inside the platform's folder are sent (a name that
is absolute, a URL, or leaves the folder, through ``..`` or a symlink, is not), STL and OBJ
only, each at most :data:`~kinesphere.protocol.MAX_MESH_BYTES` and all together within the
message's bound; what is left out is logged once. The answer never changes while the process
runs, so it is built once per platform.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Final

from kinesphere.errors import KinesphereError
from kinesphere.platforms.platform import Platform
from kinesphere.protocol import MAX_BODY_PAYLOAD, MAX_MESH_BYTES, MAX_MESHES, BodyModel, encode

log = logging.getLogger(__name__)
MESH_SUFFIXES: Final = (".stl", ".obj")
"""Mesh files a body carries (what ``platform new`` writes)."""
MESH_BUDGET: Final = MAX_BODY_PAYLOAD - 2 * 1024 * 1024
"""Bytes of mesh files one body carries (the rest of the message bound is the text's)."""


def body_model(platform: Platform) -> BodyModel:
    """The BodyModel of ``platform``, read from its eURDF file and folder (once)."""
    path = platform.eurdf.path
    if path is None:
        raise KinesphereError("internal", f"{platform.name}: eURDF has no file to send")
    key = (platform.name, str(path), platform.eurdf.sha256)
    with _LOCK:
        body = _BUILT.get(key)
        if body is None:
            body = _BUILT[key] = _built(platform, path)
    return body


_BUILT: dict[tuple[str, str, str], BodyModel] = {}
"""Bodies built, by platform, file and content (one per platform a process serves)."""
_LOCK = threading.Lock()


def _built(platform: Platform, path: Path) -> BodyModel:
    body = BodyModel(
        platform=platform.name,
        eurdf=path.read_text(encoding="utf-8"),
        base_kind=platform.base.kind,
        neutral=dict(platform.neutral),
        version=platform.eurdf.sha256,
        meshes=meshes(platform, path.parent),
    )
    size = len(encode(body))
    if size > MAX_BODY_PAYLOAD:  # receivers would refuse it: say so here instead
        raise KinesphereError(
            "internal", f"{platform.name}: body of {size} bytes exceeds {MAX_BODY_PAYLOAD}"
        )
    return body


def meshes(platform: Platform, folder: Path) -> dict[str, bytes]:
    """The mesh files ``platform``'s visuals name, by the name the eURDF gives them."""
    root = folder.resolve()
    names = dict.fromkeys(
        str(v.geometry.mesh.filename)
        for link in platform.eurdf.urdf.robot.links for v in link.visuals
        if v.geometry is not None and v.geometry.mesh is not None)
    out: dict[str, bytes] = {}
    left: list[str] = []
    total = 0
    for name in names:
        data = _inside(root, name)
        if data is None or len(out) >= MAX_MESHES or total + len(data) > MESH_BUDGET:
            left.append(name)
            continue
        out[name] = data
        total += len(data)
    if left:
        log.warning("body of %s: %d mesh file(s) not sent (outside %s, not STL/OBJ, over "
                    "%d bytes each or %d in all): %s", platform.name, len(left), root,
                    MAX_MESH_BYTES, MESH_BUDGET, ", ".join(left[:5]))
    return out


def _inside(root: Path, name: str) -> bytes | None:
    """The bytes of mesh ``name`` if it is a regular STL/OBJ file inside ``root``."""
    if ":" in name or name.startswith(("/", "\\")) or not name.lower().endswith(MESH_SUFFIXES):
        return None
    try:
        path = (root / name).resolve()
        if not path.is_relative_to(root) or not path.is_file():
            return None
        if path.stat().st_size > MAX_MESH_BYTES:
            return None
        with path.open("rb") as f:
            data = f.read(MAX_MESH_BYTES + 1)
    except OSError:
        return None
    return data if len(data) <= MAX_MESH_BYTES else None
