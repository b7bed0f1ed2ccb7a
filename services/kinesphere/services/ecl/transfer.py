"""JSON export and import of a whole databank, for super-users to review, edit and restore.

The JSON mirrors the tables (k_ids, p_ids, meta) so export -> import -> export gives the same
bytes. An import is checked as strictly as a build (labels, VSAM pairs, joint limits, NULLs
outside the limb) before anything is written, and is then swapped in atomically.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.platform import Platform
from kinesphere.services.ecl.db import META_KEYS, QUALITY, Quality, Tables
from kinesphere.services.ecl.store import check_joints, check_support
from kinesphere.services.ecl.vsam import vsam_from_dict

FORMAT = "kinesphere-ecl"
FORMAT_VERSION = 2
READS = (1, 2)  # version 1: quality without the tip columns, no support


def to_json(tables: Tables) -> str:
    """The export text: stable key order, one trailing newline."""
    quality = {(q[0], q[1]): q[2:] for q in tables.quality}
    support = {(p, k): values for p, k, values in tables.support}
    pose = []
    for p_id, k_id, values in tables.pose:
        q = quality.get((p_id, k_id))
        entry: dict[str, Any] = {
            "k_id": k_id,
            "p_id": p_id,
            "joints": {j: v for j, v in zip(tables.joints, values, strict=True) if v is not None},
            "quality": None if q is None else dict(zip(QUALITY, q, strict=True)),
        }
        held = support.get((p_id, k_id))
        if held is not None:
            entry["support"] = {j: v for j, v in zip(tables.joints, held, strict=True)
                                if v is not None}
        pose.append(entry)
    doc = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "meta": dict(sorted(tables.meta.items())),
        "joints": list(tables.joints),
        "vsam": [{"k_id": k, "limb": li, "origin": o, "direction": d}
                 for k, o, li, d in tables.vsam],
        "pose": pose,
    }
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def write_json(path: str | Path, tables: Tables) -> Path:
    out = Path(path)
    out.write_text(to_json(tables), encoding="utf-8")
    return out


def read_json(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise KinesphereError("unavailable", f"no such file: {p}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise KinesphereError("malformed", f"{p} is not JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise KinesphereError("malformed", f"{p} is not a kinesphere ECL export")
    if doc.get("format_version") not in READS:
        raise KinesphereError(
            "incompatible_version",
            f"{p} has format_version {doc.get('format_version')!r}; this reads "
            f"{', '.join(map(str, READS))}",
        )
    return doc


def tables_from_json(plat: Platform, doc: dict[str, Any]) -> Tables:
    """Validate an export against the platform and turn it back into tables."""
    meta = doc.get("meta")
    if not isinstance(meta, dict) or not all(
        isinstance(k, str) and isinstance(v, str) for k, v in meta.items()
    ):
        raise KinesphereError("malformed", "export 'meta' must map names to strings")
    missing = [k for k in META_KEYS if k not in meta]
    if missing:
        raise KinesphereError("malformed", f"export meta lacks {', '.join(missing)}")
    if meta["platform"] != plat.name:
        raise KinesphereError(
            "malformed", f"export is for {meta['platform']!r}, not {plat.name!r}"
        )
    joints = tuple(plat.eurdf.joint_names)
    if doc.get("joints") != list(joints) or json.loads(meta["joints"]) != list(joints):
        raise KinesphereError(
            "incompatible_version", f"export joints differ from {plat.name}'s P: {list(joints)}"
        )
    vsam = vsam_from_dict(json.loads(meta["vsam"]), plat, source="export meta vsam")
    e = plat.eurdf
    vsam_rows: dict[int, tuple[int, str, str, str]] = {}
    for i, row in enumerate(_list(doc, "vsam"), start=1):
        k_id = _pos_int(row.get("k_id"), f"vsam entry {i} k_id")
        limb_name = _str(row.get("limb"), f"vsam entry {i} limb")
        limb = e.origin(limb_name).name if limb_name in e.C else e.limb(limb_name).name
        origin = e.origin(_str(row.get("origin"), f"vsam entry {i} origin")).name
        d = Direction.parse(_str(row.get("direction"), f"vsam entry {i} direction"))
        entry = vsam.entry(limb, origin)
        if entry is None:
            raise KinesphereError("unknown_origin", f"vsam entry {i}: ({limb}, {origin}) is "
                                  "not a pair of the VSAM")
        if d not in entry.directions:
            raise KinesphereError("direction_unavailable", f"vsam entry {i}: {d.slug} is not in "
                                  f"the VSAM for ({limb}, {origin})")
        cell = (k_id, origin, limb, d.slug)
        if k_id in vsam_rows or any(r[1:] == cell[1:] for r in vsam_rows.values()):
            raise KinesphereError("malformed", f"vsam entry {i} repeats k_id or cell {cell}")
        vsam_rows[k_id] = cell
    pose: dict[tuple[int, int], tuple[float | None, ...]] = {}
    quality: list[Quality] = []
    support: dict[tuple[int, int], tuple[float | None, ...]] = {}
    for i, row in enumerate(_list(doc, "pose"), start=1):
        k_id = _pos_int(row.get("k_id"), f"pose entry {i} k_id")
        p_id = _pos_int(row.get("p_id"), f"pose entry {i} p_id")
        if k_id not in vsam_rows:
            raise KinesphereError("malformed", f"pose entry {i}: k_id {k_id} has no vsam entry")
        if (p_id, k_id) in pose:
            raise KinesphereError("malformed", f"pose entry {i}: ({p_id}, {k_id}) repeats")
        raw = row.get("joints")
        if not isinstance(raw, dict):
            raise KinesphereError("malformed", f"pose entry {i}: joints must be an object")
        limb = vsam_rows[k_id][2]
        if limb in e.C:
            if raw:
                raise KinesphereError("malformed", f"pose entry {i}: core rows have no joints")
            values: dict[str, float] = {}
        else:
            try:
                values = check_joints(plat, limb, raw)
            except KinesphereError as exc:
                raise KinesphereError(exc.code, f"pose entry {i}: {exc.message}") from None
        pose[(p_id, k_id)] = tuple(values.get(j) for j in joints)
        q = row.get("quality")
        if q is not None:
            if not isinstance(q, dict) or not set(QUALITY[:3]) <= set(q) <= set(QUALITY):
                raise KinesphereError("malformed", f"pose entry {i}: quality needs {QUALITY}")
            c, r, m, x, y, z = (_opt_float(q.get(k), f"pose entry {i} {k}") for k in QUALITY)
            quality.append((p_id, k_id, c, r, m, x, y, z))
        held = row.get("support")
        if held is not None:
            if not isinstance(held, dict) or limb in e.C:
                raise KinesphereError("malformed", f"pose entry {i}: support must be an "
                                      "object of a limb's pose")
            try:
                kept = check_support(plat, limb, held)
            except KinesphereError as exc:
                raise KinesphereError(exc.code, f"pose entry {i}: {exc.message}") from None
            support[(p_id, k_id)] = tuple(kept.get(j) for j in joints)
    return Tables(
        dict(sorted(meta.items())),
        joints,
        tuple(vsam_rows[k] for k in sorted(vsam_rows)),
        tuple((p, k, pose[(p, k)]) for p, k in sorted(pose, key=lambda pk: (pk[1], pk[0]))),
        tuple(sorted(quality, key=lambda r: (r[1], r[0]))),
        tuple((p, k, support[(p, k)]) for p, k in sorted(support, key=lambda pk: (pk[1], pk[0]))),
    )


def _list(doc: dict[str, Any], key: str) -> list[dict[str, Any]]:
    items = doc.get(key)
    if not isinstance(items, list) or not all(isinstance(x, dict) for x in items):
        raise KinesphereError("malformed", f"export {key!r} must be a list of objects")
    return items


def _pos_int(v: object, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise KinesphereError("malformed", f"{what} must be a positive integer, got {v!r}")
    return v


def _str(v: object, what: str) -> str:
    if not isinstance(v, str):
        raise KinesphereError("malformed", f"{what} must be a string, got {v!r}")
    return v


def _opt_float(v: object, what: str) -> float | None:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise KinesphereError("malformed", f"{what} must be a number or null, got {v!r}")
    return float(v)
