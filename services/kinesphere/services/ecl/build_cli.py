"""The generator's commands: ``ecl build``, ``ecl report``, ``ecl render``, ``ecl compare``
and the top-level ``pose``.

Registered by ``ecl.cli`` when this module is installed. Heavy imports (mink, MuJoCo,
Pillow) happen inside the handlers, so ``kinesphere --help`` stays fast and rendering can pick
its OpenGL backend (``MUJOCO_GL``, defaulting to ``egl`` without a display) before MuJoCo loads.
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from kinesphere.errors import KinesphereError

_DB_HELP = "databank file instead of the shipped databank of the platform"


def register_build(ecl_sub: Any, top_sub: Any) -> None:
    """Add build/report/render/compare under ``ecl`` and ``pose`` at the top level."""
    b = ecl_sub.add_parser(
        "build",
        help="generate a platform's ECL with IK (the paper's Algorithm 1) and store it",
        description="Run Algorithm 1 with mink IK in the platform's MuJoCo model: every VSAM "
        "(limb, origin) pair is pulled toward each direction at each size; directions the limb "
        "cannot honestly reach are dropped and listed. The databank is replaced atomically.",
    )
    b.add_argument("platform", nargs="?", help="platform name or folder (omit with --all)")
    b.add_argument("--db", type=Path, metavar="PATH", help=_DB_HELP)
    b.add_argument("--all", action="store_true", help="build every shipped platform")
    b.add_argument("--reasons", action="store_true", help="say why each direction was dropped")
    b.add_argument(
        "--limb", action="append", metavar="LIMB",
        help="generate only this limb's VSAM entries (label or alias; repeatable): a quick "
        "first look at a brought robot. The databank then holds only those limbs",
    )
    b.set_defaults(func=_build)

    r = ecl_sub.add_parser(
        "report",
        help="quality of a databank: medians of cosine, reach fraction and joint margin",
        description="Summarise the generator's quality figures per limb and overall: cosine "
        "between the direction and the tip's offset from the origin, reach as a fraction of "
        "the limb's farthest reach, and the smallest distance to a joint limit (rad).",
    )
    r.add_argument("platform", help="platform name or folder")
    r.add_argument("--db", type=Path, metavar="PATH", help=_DB_HELP)
    r.add_argument("--rows", action="store_true", help="also print every row's figures")
    r.set_defaults(func=_report)

    s = ecl_sub.add_parser(
        "render",
        help="contact sheet of one (limb, origin) pair: 27 directions as a 3x9 grid",
        description="Render every direction of a (limb, origin) pair at one size off-screen "
        "(rows high/middle/low, columns the 9 horizontals); missing directions are greyed.",
    )
    s.add_argument("platform", help="platform name or folder")
    s.add_argument("--limb", required=True, help="limb label or alias")
    s.add_argument("--origin", required=True, help="origin label or alias")
    s.add_argument("--size", default="3", help="size (default 3, far)")
    s.add_argument("--db", type=Path, metavar="PATH", help=_DB_HELP)
    s.add_argument("-o", "--output", type=Path, required=True, help="PNG file to write")
    s.set_defaults(func=_render)

    c = ecl_sub.add_parser(
        "compare",
        help="the same command on every platform, side by side",
        description="The paper's 'same command, different bodies' figure: one (limb, origin, "
        "direction, size) rendered on each platform's shipped databank.",
    )
    _command_args(c, with_platform=False)
    c.add_argument("--platforms", help="comma-separated platforms (default: all shipped)")
    c.set_defaults(func=_compare)

    p = top_sub.add_parser(
        "pose",
        help="render one ECL pose to a PNG",
        description="Look up (limb, origin, direction, size) in the platform's ECL and render "
        "the pose off-screen.",
    )
    _command_args(p, with_platform=True)
    p.add_argument("--db", type=Path, metavar="PATH", help=_DB_HELP)
    p.set_defaults(func=_pose)


def _command_args(p: argparse.ArgumentParser, with_platform: bool) -> None:
    if with_platform:
        p.add_argument("platform", help="platform name or folder")
    p.add_argument("limb", help="limb label or alias, e.g. limb_11")
    p.add_argument("origin", help="origin label or alias, e.g. distal_11")
    p.add_argument("direction", help="Laban direction, e.g. left-high")
    p.add_argument("size", help="size: 1 near, 2 mid, 3 far, fractions, beyond")
    p.add_argument("-o", "--output", type=Path, required=True, help="PNG file to write")


def _console() -> Console:
    console = Console()
    return console if console.is_terminal else Console(width=10_000)


def _gl() -> None:
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        os.environ.setdefault("MUJOCO_GL", "egl")
    logging.getLogger("OpenGL").setLevel(logging.WARNING)  # PyOpenGL's import chatter


# --- build -------------------------------------------------------------------------------------
def _build(args: argparse.Namespace) -> int:
    from kinesphere.robots.platform import platform_names

    if args.all == bool(args.platform):
        raise KinesphereError("malformed", "give a PLATFORM or --all (not both)")
    if args.all and args.db is not None:
        raise KinesphereError("malformed", "--db names one file; it cannot be used with --all")
    if args.all and args.limb:
        raise KinesphereError("malformed", "--limb picks limbs of one platform, not --all")
    names = platform_names() if args.all else [args.platform]
    console = _console()
    for name in names:
        build_one(name, args.db, console, args.reasons, tuple(args.limb or ()))
    return 0


def build_one(
    name: str, db: Path | None, console: Console, reasons: bool = False,
    limbs: tuple[str, ...] = (),
) -> Path:
    """Generate and store one platform's databank (only ``limbs``' entries when given);
    print what was dropped."""
    from kinesphere.robots.platform import load_platform
    from kinesphere.services.ecl.generate import GENERATOR_VERSION, generate
    from kinesphere.services.ecl.store import default_db_path, write_databank
    from kinesphere.services.ecl.vsam import load_vsam

    platform = load_platform(name)
    vsam = load_vsam(platform)
    path = db if db is not None else default_db_path(platform)
    start = time.perf_counter()
    with Progress(
        TextColumn(f"[bold]{platform.name}[/]"), BarColumn(), MofNCompleteColumn(),
        TextColumn("{task.description}"), TimeElapsedColumn(),
        console=console, transient=True, disable=not console.is_terminal,
    ) as bar:
        task = bar.add_task("", total=None)

        def progress(label: str, done: int, total: int) -> None:
            bar.update(task, completed=done, total=total, description=label)

        if limbs:
            wanted = {platform.eurdf.limb(x).name for x in limbs}
            pairs = [(e.limb, e.origin) for e in vsam.entries if e.limb in wanted]
            if not pairs:
                raise KinesphereError("unknown_limb", f"{platform.name}: no VSAM entry for "
                                      f"{', '.join(limbs)} in {platform.vsam_path}")
            rows, report = generate(name, progress, only=pairs[0])
            for pair in pairs[1:]:
                more, part = generate(name, progress, only=pair)
                rows += more
                report.entries += part.entries
        else:
            rows, report = generate(name, progress)
    write_databank(path, platform, vsam, rows, GENERATOR_VERSION)
    seconds = time.perf_counter() - start
    kept = sum(len(e.kept) for e in report.entries)
    dropped = sum(len(e.dropped) for e in report.entries)
    console.print(f"{platform.name}: {len(rows)} rows, {kept} directions kept, {dropped} "
                  f"dropped, {seconds:.1f} s -> {path}", highlight=False)
    for e in report.entries:
        if e.paths:
            console.print(f"  {e.limb}/{e.origin} kept {len(e.paths)} whose interpolation path "
                          f"touches something: {', '.join(e.paths)}", highlight=False,
                          markup=False)
            if reasons:
                for slug, why in e.paths.items():
                    console.print(f"    {slug}: {why}", highlight=False, markup=False)
        if not e.dropped:
            continue
        if reasons:
            console.print(f"  {e.limb}/{e.origin} dropped:", highlight=False)
            for slug, why in e.dropped.items():
                console.print(f"    {slug}: {why}", highlight=False, markup=False)
        else:
            console.print(f"  {e.limb}/{e.origin} dropped {len(e.dropped)}: "
                          f"{', '.join(e.dropped)}", highlight=False, markup=False)
    return path


# --- report ------------------------------------------------------------------------------------
def _report(args: argparse.Namespace) -> int:
    from kinesphere.services.ecl.ecl import Ecl

    ecl = Ecl.open(args.platform, db=args.db)
    rows = [r for r in ecl.rows() if r["joints"] and r["direction"] != "place-middle"]
    console = _console()
    if not rows:
        console.print(f"{ecl.platform.name}: no generated rows (only core translations and "
                      "neutral poses)", highlight=False)
        return 0
    if args.rows:
        table = Table(title=f"{ecl.platform.name}: every generated row")
        for col in ("limb", "origin", "direction", "size", "cosine", "reach", "margin"):
            table.add_column(col, justify="left" if col in ("limb", "origin", "direction")
                             else "right")
        for r in rows:
            table.add_row(r["limb"], r["origin"], r["direction"], str(r["size"]),
                          *(_fmt(r[q]) for q in ("cosine", "reach", "margin")))
        console.print(table)
    table = Table(title=f"{ecl.platform.name} ECL quality (version {ecl.version}): medians")
    for col in ("limb", "alias", "directions", "rows", "cosine", "min cosine", "reach",
                "margin (rad)"):
        table.add_column(col, justify="left" if col in ("limb", "alias") else "right")
    aliases = {p.name: p.alias or "" for p in ecl.platform.eurdf.limbs}
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(r["limb"], []).append(r)
    for limb, items in groups.items():
        table.add_row(limb, aliases.get(limb, ""), *_summary(items))
    table.add_row("all", "", *_summary(rows), end_section=True)
    console.print(table)
    return 0


def _summary(rows: list[dict[str, Any]]) -> list[str]:
    def med(key: str) -> str:
        values = [r[key] for r in rows if r[key] is not None]
        return _fmt(statistics.median(values)) if values else "-"

    cos = [r["cosine"] for r in rows if r["cosine"] is not None]
    cells = len({(r["limb"], r["origin"], r["direction"]) for r in rows})
    return [str(cells), str(len(rows)), med("cosine"), _fmt(min(cos)) if cos else "-",
            med("reach"), med("margin")]


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"


# --- pictures ----------------------------------------------------------------------------------
def _render(args: argparse.Namespace) -> int:
    _gl()
    from kinesphere.services.ecl.ecl import Ecl
    from kinesphere.services.ecl.render import contact_sheet

    ecl = Ecl.open(args.platform, db=args.db)
    image = contact_sheet(ecl, args.limb, args.origin, args.size)
    return _save(image, args.output)


def _compare(args: argparse.Namespace) -> int:
    _gl()
    from kinesphere.robots.platform import platform_names
    from kinesphere.services.ecl.render import compare_sheet

    names = [n.strip() for n in args.platforms.split(",")] if args.platforms else platform_names()
    image = compare_sheet(args.limb, args.origin, args.direction, args.size, names)
    return _save(image, args.output)


def _pose(args: argparse.Namespace) -> int:
    _gl()
    from kinesphere.services.ecl.ecl import Ecl
    from kinesphere.services.ecl.render import pose_image

    ecl = Ecl.open(args.platform, db=args.db)
    image = pose_image(ecl, args.limb, args.origin, args.direction, args.size)
    return _save(image, args.output)


def _save(image: Any, output: Path) -> int:
    output.parent.mkdir(parents=True, exist_ok=True)
    image.save(output)
    Console(stderr=True).print(f"wrote {output} ({image.width}x{image.height})")
    return 0
