"""Building an ECL databank from pose rows: validation against the platform and the VSAM.

Every row is checked before the file is touched (labels, VSAM pairs, joint limits, exactly the
limb's joints), so a bad generator run fails with the row named and the old databank serving.
Joints outside a row's limb are stored as NULL, which is what lets rows of different limbs be
joined into compound poses. The SQLite side (schema, atomic swap, reads) lives in ``db``.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import math
import numbers
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.platform import Platform
from kinesphere.services.ecl.db import Quality, Tables, Values, canon, write_tables
from kinesphere.services.ecl.vsam import Vsam
from kinesphere.sizes import parse_size

DATA_DIR = Path(__file__).resolve().parent / "data"
LIMIT_TOLERANCE = 1e-9
"""Values this close outside a joint limit are IK round-off: they are clamped, not rejected."""
@dataclass(frozen=True)
class PoseRow:
    """One stored pose: ``joints`` holds exactly the limb's joints (empty for core rows);
    ``support`` the joints of other limbs that hold the body while it does (a stance leg),
    usually none; ``tip`` where the limb's tip is (tip - origin, body frame, metres)."""

    limb: str
    origin: str
    direction: str
    size: int
    joints: dict[str, float]
    cosine: float | None = None
    reach: float | None = None
    margin: float | None = None
    support: dict[str, float] = field(default_factory=dict)
    tip: tuple[float, float, float] | None = None


def default_db_path(platform: Platform | str) -> Path:
    """A platform's own databank: package data for a shipped platform (or a bare name),
    ``FOLDER/NAME.sqlite`` for one brought in its own folder."""
    if isinstance(platform, str) or platform.shipped:
        name = platform if isinstance(platform, str) else platform.name
        return DATA_DIR / f"{name}.sqlite"
    return platform.folder / f"{platform.name}.sqlite"


def check_joints(
    platform: Platform, limb: str, joints: Mapping[str, object], *, complete: bool = True
) -> dict[str, float]:
    """Validate a limb pose: only the limb's joints, finite, inside limits; P order out.

    ``complete`` demands every joint of the limb (a generated row); a super-user edit may give
    fewer and fill the rest itself.
    """
    e = platform.eurdf
    own = e.limb_joints(limb)
    out: dict[str, float] = {}
    for name, raw in joints.items():
        if name not in own:
            raise KinesphereError(
                "malformed",
                f"joint {name!r} is not part of {limb}; its joints: {', '.join(own)}",
            )
        if isinstance(raw, bool) or not isinstance(raw, numbers.Real):
            raise KinesphereError("malformed", f"joint {name} value must be a number, got {raw!r}")
        value = float(raw)  # numpy scalars too
        lim = e.limits[name]
        if not math.isfinite(value):
            raise KinesphereError("malformed", f"joint {name} value must be finite, got {value}")
        if not lim.lower - LIMIT_TOLERANCE <= value <= lim.upper + LIMIT_TOLERANCE:
            raise KinesphereError(
                "malformed",
                f"joint {name}={value:g} is outside its limits [{lim.lower:g}, {lim.upper:g}]",
            )
        out[name] = lim.clamp(value) + 0.0  # + 0.0: no -0.0, which SQLite cannot keep
    missing = [j for j in own if j not in out]
    if complete and missing:
        raise KinesphereError("malformed", f"pose for {limb} lacks joints: {', '.join(missing)}")
    return {j: out[j] for j in own if j in out}


def check_support(platform: Platform, limb: str, joints: Mapping[str, object]
                  ) -> dict[str, float]:
    """Validate a pose's support: joints of P outside the limb, finite, inside limits."""
    e = platform.eurdf
    own = set(e.limb_joints(limb))
    out: dict[str, float] = {}
    for name, raw in joints.items():
        if name in own or name not in e.limits:
            raise KinesphereError(
                "malformed", f"support joint {name!r} must be a joint of P outside {limb}")
        if isinstance(raw, bool) or not isinstance(raw, numbers.Real):
            raise KinesphereError("malformed", f"support joint {name} must be a number")
        value, lim = float(raw), e.limits[name]
        if not (math.isfinite(value)
                and lim.lower - LIMIT_TOLERANCE <= value <= lim.upper + LIMIT_TOLERANCE):
            raise KinesphereError(
                "malformed", f"support joint {name}={value:g} is outside its limits "
                f"[{lim.lower:g}, {lim.upper:g}]")
        out[name] = lim.clamp(value) + 0.0
    return {j: out[j] for j in e.joint_names if j in out}


def check_record(
    platform: Platform,
    vsam: Vsam,
    limb: str,
    origin: str,
    direction: str | Direction,
    size: object,
    joints: Mapping[str, object],
) -> tuple[str, str, Direction, int, dict[str, float]]:
    """Validate a super-user edit before anything is written: the (limb, origin) pair and the
    direction are in the VSAM, place-middle is refused, the size is one of the VSAM's sizes
    and the joints belong to the limb (:func:`check_joints`, not necessarily all of them).

    Returns the limb and origin labels, the direction, the size and the checked joints.
    """
    e = platform.eurdf
    if not isinstance(limb, str):
        raise KinesphereError("unknown_limb", f"limb must be a name, got {limb!r}")
    lname = e.limb(limb).name
    oname = e.origin(origin).name if isinstance(origin, str) else ""
    entry = vsam.entry(lname, oname)
    if entry is None:
        valid = ", ".join(x.origin for x in vsam.entries if x.limb == lname) or "none"
        raise KinesphereError(
            "unknown_origin", f"origin {origin!r} is not paired with {lname}; its origins: "
            f"{valid}",
        )
    d = Direction.parse(direction)
    if d not in entry.directions:
        raise KinesphereError(
            "direction_unavailable", f"the VSAM has no {d.slug} for ({lname}, {oname}); "
            f"it has: {', '.join(x.slug for x in entry.directions)}",
        )
    if d is Direction.PLACE_MIDDLE:
        raise KinesphereError(
            "forbidden", "place-middle is the limb's neutral pose; change [neutral] in "
            f"{platform.folder / 'platform.toml'} instead",
        )
    s = size_value(size)
    if s not in vsam.sizes:
        raise KinesphereError(
            "size_out_of_range", f"a recorded size must be one of the VSAM's sizes "
            f"{', '.join(map(str, vsam.sizes))}, got {size!r}",
        )
    if not isinstance(joints, Mapping) or not joints:
        raise KinesphereError("malformed", "record needs joints: a non-empty name -> value map")
    given = check_joints(platform, lname, joints, complete=False)
    return lname, oname, d, int(s), given


def size_value(value: object) -> float:
    """A size as a number (``far``, ``2.5``, 3); too large for a float is ``size_out_of_range``."""
    try:
        return parse_size(value)
    except OverflowError:
        raise KinesphereError("size_out_of_range", f"size {value!r} is too large") from None


def limb_neutral(platform: Platform, limb: str) -> dict[str, float]:
    """The limb's Place-Middle pose: its joints at the platform's neutral values."""
    return {j: platform.neutral.get(j, 0.0) for j in platform.eurdf.limb_joints(limb)}


def write_databank(
    path: str | Path,
    platform: Platform,
    vsam: Vsam,
    rows: Iterable[PoseRow],
    generator_version: str,
    extra_meta: Mapping[str, str] | None = None,
) -> str:
    """Validate ``rows`` against the VSAM, build the databank atomically, return its digest.

    Derived rows are added when missing: every size of each core entry (all joints NULL) and
    of each ``place-middle`` cell (the limb's neutral pose). k_ids follow VSAM order, so the
    same inputs always give the same content.
    """
    if vsam.platform != platform.name:
        raise KinesphereError(
            "malformed", f"VSAM is for {vsam.platform!r}, platform is {platform.name!r}"
        )
    cells: dict[tuple[str, str, Direction], dict[int, PoseRow]] = {}
    for row in rows:
        try:
            limb, origin, d, joints = _check_row(platform, vsam, row)
        except KinesphereError as exc:
            where = f"({row.limb}, {row.origin}, {row.direction}, {row.size})"
            raise KinesphereError(exc.code, f"row {where}: {exc.message}") from None
        by_size = cells.setdefault((limb, origin, d), {})
        size = int(row.size)
        if size in by_size:
            raise KinesphereError("conflict", f"two rows for ({limb}, {origin}, {d.slug}, {size})")
        try:
            support = check_support(platform, limb, row.support)
        except KinesphereError as exc:
            where = f"({row.limb}, {row.origin}, {row.direction}, {row.size})"
            raise KinesphereError(exc.code, f"row {where}: {exc.message}") from None
        tip = None if row.tip is None or not all(map(math.isfinite, row.tip)) else (
            float(row.tip[0]) + 0.0, float(row.tip[1]) + 0.0, float(row.tip[2]) + 0.0)
        by_size[size] = dataclasses.replace(row, size=size, joints=joints, support=support,
                                            cosine=canon(row.cosine), reach=canon(row.reach),
                                            margin=canon(row.margin), tip=tip)
    for entry in vsam.entries:
        for d in entry.directions:
            if entry.is_core or d is Direction.PLACE_MIDDLE:
                joints = {} if entry.is_core else limb_neutral(platform, entry.limb)
                by_size = cells.setdefault((entry.limb, entry.origin, d), {})
                for s in vsam.sizes:
                    by_size.setdefault(s, PoseRow(entry.limb, entry.origin, d.slug, s, joints))
    names = platform.eurdf.joint_names
    vsam_rows: list[tuple[int, str, str, str]] = []
    pose_rows: list[tuple[int, int, Values]] = []
    quality_rows: list[Quality] = []
    support_rows: list[tuple[int, int, Values]] = []
    for entry in vsam.entries:
        for d in entry.directions:
            cell = cells.get((entry.limb, entry.origin, d))
            if not cell:
                continue  # the generator dropped this direction
            k_id = len(vsam_rows) + 1
            vsam_rows.append((k_id, entry.origin, entry.limb, d.slug))
            for s in sorted(cell):
                r = cell[s]
                pose_rows.append((s, k_id, tuple(r.joints.get(j) for j in names)))
                x, y, z = r.tip if r.tip is not None else (None, None, None)
                quality_rows.append((s, k_id, r.cosine, r.reach, r.margin, x, y, z))
                if r.support:
                    support_rows.append((s, k_id, tuple(r.support.get(j) for j in names)))
    meta = {
        "platform": platform.name,
        "eurdf_sha256": platform.eurdf.sha256,
        "vsam": vsam.to_json(),
        "generator_version": str(generator_version),
        "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "joints": json.dumps(list(names)),
    }
    for key, value in (extra_meta or {}).items():
        if key in meta:
            raise KinesphereError("malformed", f"extra meta key {key!r} is reserved")
        meta[str(key)] = str(value)
    tables = Tables(meta, names, tuple(vsam_rows), tuple(pose_rows), tuple(quality_rows),
                    tuple(support_rows))
    write_tables(path, tables)
    return tables.digest()


def _check_row(
    platform: Platform, vsam: Vsam, row: PoseRow
) -> tuple[str, str, Direction, dict[str, float]]:
    """Canonical (limb, origin, direction) of a row and its cleaned joint values."""
    e = platform.eurdf
    core = row.limb in e.C or row.limb in {p.alias for p in e.core if p.alias}
    limb = e.origin(row.limb).name if core else e.limb(row.limb).name
    origin = e.origin(row.origin).name
    d = Direction.parse(row.direction)
    entry = vsam.entry(limb, origin)
    if entry is None:
        valid = [x.origin for x in vsam.entries if x.limb == limb]
        raise KinesphereError(
            "unknown_origin",
            f"({limb}, {origin}) is not a VSAM pair; origins of {limb}: "
            f"{', '.join(valid) or 'none'}",
        )
    if d not in entry.directions:
        raise KinesphereError(
            "direction_unavailable", f"{d.slug} is not in the VSAM for ({limb}, {origin})"
        )
    size = row.size
    if isinstance(size, bool) or not isinstance(size, numbers.Integral) or size not in vsam.sizes:
        raise KinesphereError(
            "size_out_of_range", f"size {size!r} is not one of the VSAM sizes {vsam.sizes}"
        )
    if entry.is_core:
        if row.joints:
            raise KinesphereError("malformed", f"core row ({limb}, {d.slug}) must have no joints")
        return limb, origin, d, {}
    joints = check_joints(platform, limb, row.joints)
    if d is Direction.PLACE_MIDDLE:
        neutral = limb_neutral(platform, limb)
        if any(abs(joints[j] - neutral[j]) > LIMIT_TOLERANCE for j in neutral):
            raise KinesphereError(
                "malformed", f"place-middle of {limb} must be its neutral pose {neutral}"
            )
    return limb, origin, d, joints
