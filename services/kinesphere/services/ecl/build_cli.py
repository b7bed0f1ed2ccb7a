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

from kinesphere.cliargs import Subcommands, add_bodies, add_json, add_output, command
from kinesphere.errors import KinesphereError
from kinesphere.services.ecl.console import table_console
from kinesphere.services.options import (
    SHEET_SIZE,
    add_cell,
    add_platform,
    add_spatial_words,
)


def register_build(ecl_sub: Subcommands, top_sub: Subcommands) -> None:
    """Add build/report/render/compare under ``ecl`` and ``pose`` at the top level."""
    b = command(ecl_sub, "build", _build)
    add_platform(b, omit="omit with --all")
    b.add_argument("--all", action="store_true", help="build every shipped platform")
    b.add_argument("--reasons", action="store_true", help="say why each direction was dropped")
    b.add_argument(
        "--limb", action="append", metavar="LIMB",
        help="generate only this limb's VSAM entries (label or alias; repeatable): a quick "
        "first look at a brought robot. The databank then holds only those limbs",
    )
    b.add_argument("--jobs", type=int, metavar="N",
                   help="worker processes, one (limb, origin) pair each (default: one per core)")

    r = command(ecl_sub, "report", _report)
    add_platform(r)
    r.add_argument("--rows", action="store_true",
                   help="also print every row's figures and why each unstable pull toppled")

    a = command(ecl_sub, "audit", _audit)
    add_platform(a)
    add_json(a, "every figure")

    v = command(ecl_sub, "coverage", _coverage)
    add_bodies(v)

    s = command(ecl_sub, "render", _render)
    add_platform(s)
    add_cell(s, required=True, direction=False)
    s.add_argument("--size", default=str(SHEET_SIZE), help=f"size (default {SHEET_SIZE}, far)")
    add_output(s, "the PNG file")

    c = command(ecl_sub, "compare", _compare)
    add_spatial_words(c)
    add_output(c, "the PNG file")
    add_bodies(c)

    p = command(top_sub, "pose", _pose)
    add_platform(p)
    add_spatial_words(p)
    add_output(p, "the PNG file")


def _gl() -> None:
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
        os.environ.setdefault("MUJOCO_GL", "egl")
    logging.getLogger("OpenGL").setLevel(logging.WARNING)  # PyOpenGL's import chatter


# --- build -------------------------------------------------------------------------------------
def _build(args: argparse.Namespace) -> int:
    """generate a platform's ECL with IK (the paper's Algorithm 1) and store it

    Run Algorithm 1 with mink IK in the platform's MuJoCo model: every VSAM (limb, origin) pair is
    pulled toward each direction at each size; directions the limb cannot honestly reach, or only by
    toppling, are dropped and listed. Pairs are generated in parallel (one process per core); the
    output is the same as a serial run's. The databank is replaced atomically; the wall time is
    printed.
    """
    from kinesphere.platforms.platform import platform_names
    from kinesphere.services.ecl.parallel import default_workers, generate_many

    if args.all == bool(args.platform):
        raise KinesphereError("malformed", "give a PLATFORM or --all (not both)")
    if args.all and args.db is not None:
        raise KinesphereError("malformed", "--db names one file; it cannot be used with --all")
    if args.all and args.limb:
        raise KinesphereError("malformed", "--limb picks limbs of one platform, not --all")
    if args.jobs is not None and args.jobs < 1:
        raise KinesphereError("malformed", f"--jobs must be at least 1, got {args.jobs}")
    names = platform_names() if args.all else [args.platform]
    workers = args.jobs or default_workers()
    console = table_console()
    start = time.perf_counter()
    with Progress(
        TextColumn("[bold]generating[/]"), BarColumn(), MofNCompleteColumn(),
        TextColumn("{task.description}"), TimeElapsedColumn(),
        console=console, transient=True, disable=not console.is_terminal,
    ) as bar:
        task = bar.add_task("", total=None)

        def done(platform: str, entry: Any, finished: int, total: int) -> None:
            bar.update(task, completed=finished, total=total,
                       description=f"{Path(platform).name} {entry.limb}/{entry.origin}")

        built = generate_many(names, workers, done, tuple(args.limb or ()))
    for name in names:
        store_built(name, built[name], args.db, console, args.reasons)
    wall = time.perf_counter() - start
    work = sum(b.report.seconds for b in built.values())
    console.print(f"built {len(names)} platform{'s' if len(names) > 1 else ''} in {wall:.1f} s "
                  f"wall time with {workers} process{'es' if workers > 1 else ''} "
                  f"({work:.1f} s of generation)", highlight=False)
    return 0


def store_built(name: str, built: Any, db: Path | None, console: Console,
                reasons: bool = False) -> Path:
    """Store one platform's generated rows atomically; print what was dropped and why."""
    from kinesphere.platforms.platform import load_platform
    from kinesphere.services.ecl.generate import GENERATOR_VERSION, report_meta
    from kinesphere.services.ecl.store import default_db_path, write_databank
    from kinesphere.services.ecl.vsam import load_vsam

    platform = load_platform(name)
    vsam = load_vsam(platform)
    path = db if db is not None else default_db_path(platform)
    report = built.report
    write_databank(path, platform, vsam, built.rows, GENERATOR_VERSION, report_meta(report))
    kept = sum(len(e.kept) for e in report.entries)
    dropped = sum(len(e.dropped) + len(e.unstable) for e in report.entries)
    console.print(f"{platform.name}: {len(built.rows)} rows, {kept} directions kept, {dropped} "
                  f"dropped, {report.seconds:.1f} s -> {path}", highlight=False)
    for e in report.entries:
        if e.paths:
            console.print(f"  {e.limb}/{e.origin} kept {len(e.paths)} whose interpolation path "
                          f"touches something: {', '.join(e.paths)}", highlight=False,
                          markup=False)
            if reasons:
                for slug, why in e.paths.items():
                    console.print(f"    {slug}: {why}", highlight=False, markup=False)
        for what, items in (("dropped", e.dropped), ("dropped for stability", e.unstable)):
            if not items:
                continue
            if reasons:
                console.print(f"  {e.limb}/{e.origin} {what}:", highlight=False)
                for slug, why in items.items():
                    console.print(f"    {slug}: {why}", highlight=False, markup=False)
            else:
                console.print(f"  {e.limb}/{e.origin} {what} {len(items)}: "
                              f"{', '.join(items)}", highlight=False, markup=False)
    return path


# --- report ------------------------------------------------------------------------------------
def _report(args: argparse.Namespace) -> int:
    """quality of a databank: size rules, pulls kept, medians of cosine, reach, margin

    Summarise the generator's quality figures per limb and overall: the size rule each limb follows
    (reach: near, mid and far are the tip's distance from the origin as growing fractions of far's,
    the bearing held; swing: the size scales the angle of the pull from neutral, for a limb whose
    extension cannot change; a leg that cannot fold along a direction swings along it), pulls kept
    of Laban's 26, cosine between the direction and the tip's offset from the origin, reach as the
    fraction of the pull a size is, the smallest distance to a joint limit (rad), the kept
    directions whose largest sizes stability removed and the directions dropped for stability (the
    whole-body centre of mass would leave the support polygon even at near). For figures measured
    independently of the generator, see 'ecl audit'.
    """
    from kinesphere.services.ecl.ecl import Ecl

    ecl = Ecl.open(args.platform, db=args.db)
    rows = [r for r in ecl.rows() if r["joints"] and r["direction"] != "place-middle"]
    console = table_console()
    if not rows and not ecl.dropped("unstable"):
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
    for col in ("limb", "alias", "size rule", "pulls of 26", "rows", "cosine", "min cosine",
                "reach", "margin (rad)", "short of far", "unstable"):
        table.add_column(col, justify="left" if col in ("limb", "alias", "size rule")
                         else "right")
    aliases = {p.name: p.alias or "" for p in ecl.platform.eurdf.limbs}
    groups: dict[str, list[dict[str, Any]]] = {e.limb: [] for e in ecl.vsam.entries
                                               if not e.is_core}
    for r in rows:
        groups.setdefault(r["limb"], []).append(r)
    unstable, short = ecl.dropped("unstable"), ecl.dropped("short")
    rules, swung = ecl.notes("size_rules"), ecl.notes("swung")

    def per_limb(notes: dict[str, Any], limb: str) -> int:
        return sum(len(v) for k, v in notes.items() if k.split("/")[0] == limb)

    for limb, items in groups.items():
        pair = next((k for k in rules if k.split("/")[0] == limb), "")
        rule = str(rules.get(pair, "-"))
        if swung.get(pair):
            rule += f" ({len(swung[pair])} swing)"
        table.add_row(limb, aliases.get(limb, ""), rule, *_summary(items),
                      str(per_limb(short, limb)), str(per_limb(unstable, limb)))
    table.add_row("all", "", "", *_summary(rows), str(sum(len(v) for v in short.values())),
                  str(sum(len(v) for v in unstable.values())), end_section=True)
    console.print(table)
    for pair, lost in unstable.items():
        if lost:
            console.print(f"{pair} dropped for stability: {', '.join(lost)}", highlight=False,
                          markup=False)
            if args.rows:
                for slug, why in lost.items():
                    console.print(f"  {slug}: {why}", highlight=False, markup=False)
    for pair, cut in short.items():
        if cut:
            sizes = ", ".join(f"{slug} ({why.split(':')[0]} up)" for slug, why in cut.items())
            console.print(f"{pair} sizes removed for stability: {sizes}", highlight=False,
                          markup=False)
    return 0


def _summary(rows: list[dict[str, Any]]) -> list[str]:
    def med(key: str) -> str:
        values = [r[key] for r in rows if r[key] is not None]
        return _fmt(statistics.median(values)) if values else "-"

    cos = [r["cosine"] for r in rows if r["cosine"] is not None]
    cells = len({(r["limb"], r["origin"], r["direction"]) for r in rows})
    if not rows:
        return ["0", "0", "-", "-", "-", "-"]
    return [str(cells), str(len(rows)), med("cosine"), _fmt(min(cos)) if cos else "-",
            med("reach"), med("margin")]


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"


def _audit(args: argparse.Namespace) -> int:
    """what the databank's words mean on its body, measured by forward kinematics

    Measure every stored row by forward kinematics (MuJoCo on the platform's model, from the stored
    joint values alone, not the generator's quality table): per (limb, origin) pair the cosine
    between each row's bearing (tip - origin) and its direction (min / 5th percentile / median),
    each size's tip distance as a fraction of far's (median; near/far is the first), cells whose
    sizes go backwards (the tip closer, or for a swinging limb the bearing turned away, as the size
    grows), cells stopping short of far (sizes removed for stability), every missing pull asked at
    every size (served by a neighbour: how many and the worst measured angle to the request;
    refused), the pulls the neutral pose already points at and how they are answered, and the
    smallest stability margin of any row (centre of mass inside the support polygon; none on a fixed
    base).
    """
    from kinesphere.services.ecl.audit import audit, over_limit

    result = audit(args.platform, args.db)
    if args.json:
        sys.stdout.write(result.to_json() + "\n")
        return 0
    console = table_console()
    if not result.pairs:
        console.print(f"{result.platform}: no limbs in its VSAM (only core translations), "
                      "nothing to measure", highlight=False)
        return 0
    table = Table(title=f"{result.platform} audit (version {result.version}, "
                  f"{result.generator or 'unknown generator'}): measured by forward kinematics")
    for col in ("limb", "origin", "rule", "pulls", "cosine min/p5/med", "size/far", "backwards",
                "short of far", "substituted (worst)", "> 45 deg", "refused",
                "neutral directions", "min margin"):
        table.add_column(col, justify="left" if col in ("limb", "origin", "rule",
                                                        "neutral directions") else "right")
    for p in result.pairs:
        cos = "/".join(_fmt(v) for v in (p.cosine_min, p.cosine_p5, p.cosine_median))
        fractions = " ".join(f"{v:.2f}" for _, v in sorted(p.fraction.items())) or "-"
        worst = p.worst_substitution
        subs = f"{len(p.substituted)}" + (f" ({worst:.0f} deg)" if worst is not None else "")
        neutral = "; ".join(f"{d}: {how}" for d, how in p.neutral.items()) or "-"
        if result.anchored or p.margin_min is None:
            margin = "fixed base" if result.anchored else "-"
        else:
            margin = f"{p.margin_min * 100:.1f} cm" + (
                f" ({len(p.unstable)} < 1 cm)" if p.unstable else "")
        table.add_row(p.limb + (f" ({p.alias})" if p.alias else ""), p.origin, p.rule,
                      str(p.pulls), cos, fractions, str(len(p.disordered)), str(len(p.short)),
                      subs, str(len(over_limit(p))), str(len(p.refused)), neutral, margin)
    console.print(table)
    console.print("size/far: median tip distance of each stored size over far's (near first); "
                  "substituted and refused count (request, size) pairs", highlight=False)
    return 0


def _coverage(args: argparse.Namespace) -> int:
    """pulls each body keeps and the directions every body shares (markdown)

    Count, from the shipped databanks, the pulls of Laban's 26 each (limb, origin) pair keeps, and
    list the directions every platform with limb_11, limb_12, limb_13 keeps: a fleet command in one
    of those is exact on every robot.
    """
    from kinesphere.platforms.platform import platform_names
    from kinesphere.services.ecl.coverage import markdown

    sys.stdout.write(markdown(args.bodies or platform_names()))
    return 0


# --- pictures ----------------------------------------------------------------------------------
def _render(args: argparse.Namespace) -> int:
    """contact sheet of one (limb, origin) pair: 27 directions as a 3x9 grid

    Render every direction of a (limb, origin) pair at one size off-screen (rows high/middle/low,
    columns the 9 horizontals); missing directions are greyed.
    """
    _gl()
    from kinesphere.services.ecl.ecl import Ecl
    from kinesphere.services.ecl.render import contact_sheet

    ecl = Ecl.open(args.platform, db=args.db)
    image = contact_sheet(ecl, args.limb, args.origin, args.size)
    return _save(image, args.output)


def _compare(args: argparse.Namespace) -> int:
    """the same command on every platform, side by side

    The paper's 'same command, different bodies' figure: one (limb, origin, direction, size)
    rendered on each platform's shipped databank.
    """
    _gl()
    from kinesphere.platforms.platform import platform_names
    from kinesphere.services.ecl.render import compare_sheet

    image = compare_sheet(args.limb, args.origin, args.direction, args.size,
                          args.bodies or platform_names())
    return _save(image, args.output)


def _pose(args: argparse.Namespace) -> int:
    """render one ECL pose to a PNG

    Look up (limb, origin, direction, size) in the platform's ECL and render the pose off-screen.
    """
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
