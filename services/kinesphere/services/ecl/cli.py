"""``kinesphere ecl ...``: look up, inspect and edit a platform's ECL databank.

These are the super-user's tools from the paper (store a pose for a cell, review rows, move a
databank to and from JSON) plus a local f_SB lookup. The generator's commands (build, report,
render) come from ``build_cli`` when that module is installed; both print tables through
:func:`~kinesphere.services.ecl.console.table_console`.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import msgspec
from rich.console import Console
from rich.table import Table

from kinesphere.cliargs import (
    Subcommands,
    add_json,
    add_output,
    add_timeout,
    add_zenoh_arguments,
    command,
)
from kinesphere.errors import KinesphereError
from kinesphere.protocol import Pose
from kinesphere.services.ecl.console import table_console
from kinesphere.services.options import (
    QueryOptions,
    add_cell,
    add_exact,
    add_platform,
    add_spatial_words,
)


def register(sub: Subcommands) -> None:
    """Add the ``ecl`` command and its sub-commands to the top-level parser."""
    ecl = command(
        sub, "ecl", lambda args: _usage(ecl),
        help="the Embodied Configuration Library: look up, show, record, export, import poses",
        description="Each platform's ECL maps a spatial command (limb, origin, direction, size) "
        "to a pose. These commands read and edit its SQLite databank directly (no robot or "
        "Zenoh needed). Limbs and origins accept labels or aliases (limb_11 or right_arm), "
        "directions any Laban spelling ('Left-High', 'left high').",
    )
    ecl_sub = ecl.add_subparsers(dest="ecl_command", metavar="SUBCOMMAND")

    g = command(ecl_sub, "get", _get)
    add_platform(g)
    add_spatial_words(g)
    add_json(g, "the protocol Pose")
    add_exact(g)

    r = command(ecl_sub, "record", _record)
    add_platform(r)
    add_cell(r, required=True)
    r.add_argument("--size", required=True, help="integer size (1 near, 2 mid, 3 far, ...)")
    source = r.add_mutually_exclusive_group(required=True)
    source.add_argument(
        "--joints", nargs="+", metavar="NAME=VALUE",
        help="joint values in rad (m for prismatic joints), e.g. right_s0=-0.4 right_e1=1.2",
    )
    source.add_argument(
        "--from-robot", metavar="ID",
        help="capture the limb's joints from the running agent ID (its next RobotState)",
    )
    add_timeout(r, QueryOptions.capture_timeout_s, "the robot's state with --from-robot")
    add_json(r, "the stored Pose")
    add_zenoh_arguments(r, listen=False)  # used with --from-robot only

    s = command(ecl_sub, "show", _show)
    add_platform(s)
    add_cell(s, required=False)

    x = command(ecl_sub, "export", _export)
    add_platform(x)
    add_output(x, "the JSON file")

    i = command(ecl_sub, "import", _import)
    add_platform(i)
    i.add_argument("file", type=Path, help="JSON file written by 'kinesphere ecl export'")

    try:
        from kinesphere.services.ecl.build_cli import register_build
    except ModuleNotFoundError as exc:
        if exc.name != "kinesphere.services.ecl.build_cli":
            raise
    else:
        register_build(ecl_sub, sub)


def _usage(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def _open(args: argparse.Namespace) -> Any:
    from kinesphere.services.ecl.ecl import Ecl

    return Ecl.open(args.platform, db=args.db)


def parse_joints(tokens: list[str]) -> dict[str, float]:
    """``["a=1", "b=-0.5"]`` -> ``{"a": 1.0, "b": -0.5}``; bad tokens are named."""
    out: dict[str, float] = {}
    for tok in tokens:
        raw, sep, value = tok.partition("=")
        name = raw.strip()
        if not sep or not name:
            raise KinesphereError("malformed", f"joint {tok!r} must be written NAME=VALUE")
        if name in out:
            raise KinesphereError("malformed", f"joint {name!r} is given twice")
        try:
            out[name] = float(value)
        except ValueError:
            raise KinesphereError(
                "malformed", f"joint {tok!r}: {value!r} is not a number"
            ) from None
    return out


def _get(args: argparse.Namespace) -> int:
    """f_SB: print the pose for LIMB ORIGIN DIRECTION SIZE

    Evaluate f_SB locally: integer sizes give the stored row, fractions interpolate in joint space,
    sizes past the largest stored one add a base translation (mobile platforms only), place-middle
    gives the limb's neutral pose; a direction the limb lacks is served by the nearest one it has
    within 45 degrees (and says so) unless --exact. Use 'c_1 c_1 DIRECTION SIZE' for a pure base
    translation on mobile platforms.
    """
    pose = _open(args).query(args.limb, args.origin, args.direction, args.size, args.exact)
    _print_pose(pose, args.json)
    return 0


def _record(args: argparse.Namespace) -> int:
    """store a pose given as joint values for one (limb, origin, direction, size)

    Store joint values as the pose of one cell, in one transaction; the cell's quality figures
    become unknown. Joints must belong to the limb and lie within their limits. Limb joints you
    leave out keep the cell's stored value (or neutral for a new cell). Sizes are positive integers;
    place-middle is the neutral pose and is changed in platform.toml instead.
    """
    ecl = _open(args)
    if args.from_robot:
        from kinesphere.keyexpr import Keys
        from kinesphere.services.ecl.capture import capture_state, limb_joints_of
        from kinesphere.zconfig import session_from_args

        with session_from_args(args) as session:
            plat = ecl.platform
            state = capture_state(session, args.from_robot, Keys(args.prefix), args.timeout,
                                  plat.name if plat.shipped else str(plat.folder))
        if state.platform != ecl.platform.name:
            raise KinesphereError(
                "unknown_platform",
                f"robot {args.from_robot!r} is a {state.platform}, not a {ecl.platform.name}",
            )
        eurdf = ecl.platform.eurdf
        joints = limb_joints_of(state, eurdf.limb_joints(eurdf.limb(args.limb).name))
    else:
        joints = parse_joints(args.joints)
    pose = ecl.record(args.limb, args.origin, args.direction, args.size, joints)
    _print_pose(pose, args.json)
    if not args.json:
        Console(stderr=True).print(f"stored in {ecl.db_path} (version {ecl.version})")
    return 0


def _print_pose(pose: Pose, as_json: bool) -> None:
    if as_json:
        print(msgspec.json.encode(pose).decode())
        return
    where = f"k_id {pose.k_id}" + (f", p_id {pose.p_id}" if pose.p_id is not None else "")
    console = table_console()
    console.print(f"{pose.platform}: ({pose.limb}, {pose.origin}, {pose.direction}, "
                  f"{pose.size:g})  [{where}]", highlight=False, markup=False)
    table = Table()
    table.add_column("joint")
    table.add_column("value", justify="right")
    for name, value in pose.joints.items():
        table.add_row(name, f"{value:.4f}")
    if pose.translation is not None:
        table.add_row("base translation (m)", ", ".join(f"{v:.3f}" for v in pose.translation))
    console.print(table)
    for sub in pose.substitutions:
        console.print(f"substituted: {sub.limb} has no {sub.requested}; served {sub.served} "
                      f"({sub.angle:.1f} degrees away)", highlight=False, markup=False)


def _show(args: argparse.Namespace) -> int:
    """print stored rows as a table, optionally filtered

    Print the databank's rows (k_id, size, joint values and the generator's quality figures: cosine
    to the direction, reach fraction, joint-limit margin).
    """
    ecl = _open(args)
    rows = ecl.rows(args.limb, args.origin, args.direction)
    names = {tuple(r["joints"]) for r in rows}
    per_joint = len(names) == 1
    table = Table(title=f"{ecl.platform.name} ECL ({len(rows)} rows, version {ecl.version})")
    for col in ("k_id", "limb", "origin", "direction", "size"):
        table.add_column(col, justify="right" if col in ("k_id", "size") else "left")
    joint_cols = list(next(iter(names))) if per_joint else ["joints"]
    for col in joint_cols:
        table.add_column(col, justify="right")
    for col in ("cosine", "reach", "margin"):
        table.add_column(col, justify="right")
    for r in rows:
        if per_joint:
            values = [f"{r['joints'][j]:.3f}" for j in joint_cols]
        else:
            values = [" ".join(f"{j}={v:.3f}" for j, v in r["joints"].items()) or "-"]
        quality = ["-" if r[q] is None else f"{r[q]:.3f}" for q in ("cosine", "reach", "margin")]
        table.add_row(str(r["k_id"]), r["limb"], r["origin"], r["direction"], str(r["size"]),
                      *values, *quality)
    table_console().print(table)
    return 0


def _export(args: argparse.Namespace) -> int:
    """write the whole databank to a JSON file

    Export every table (meta, vsam, pose, quality) as JSON for review or editing; 'ecl import' of
    the file restores the same content (round trip identical).
    """
    ecl = _open(args)
    out = ecl.export_json(args.output)
    Console(stderr=True).print(f"wrote {out} ({len(ecl.rows())} rows, version {ecl.version})")
    return 0


def _import(args: argparse.Namespace) -> int:
    """replace the databank with the content of a JSON export

    Validate an export against the platform (labels, VSAM pairs, joint limits, NULLs outside each
    limb) and replace the databank with it atomically; a rejected file changes nothing.
    """
    from kinesphere.platforms.platform import load_platform
    from kinesphere.services.ecl.ecl import Ecl
    from kinesphere.services.ecl.store import default_db_path

    plat = load_platform(args.platform)
    db = args.db if args.db is not None else default_db_path(plat)
    ecl = Ecl.from_json(plat, args.file, db)
    Console(stderr=True).print(f"imported {args.file} into {ecl.db_path} (version {ecl.version})")
    return 0
