"""Bring your own robot over every URDF of three public collections installed from PyPI
(example-robot-data, pybullet's ``pybullet_data``, the Robotics Toolbox's ``rtb-data``), as a
user does it: ``platform new`` -> ``describe`` -> ``ecl build``. Nobody tuned anything on
these files, and none is left out by name: a file that cannot be imported is refused with
one error line, which is what the callers assert.

Two callers: ``tests/platforms/test_byor_collections.py`` (in ``make test``: every URDF
imported and described, a small sample built) and ``make sweep`` (``python -m
support.sweep``: every robot built, one ``ecl build`` of the first limb of each of its chains,
and the coverage table printed: what was found against the anatomy, pulls kept per limb,
times). Rows are plain dicts so that worker processes can hand them back.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import multiprocessing
import re
import statistics
import sys
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from support.byor import collections

Row = dict[str, Any]
OBJECTS = "random_urdfs"  # pybullet's 1000 random objects: each must be refused
PULLS = 26
MENDED = re.compile(r"^  mended: (.*)$", re.M)
WRITTEN = re.compile(r"<!-- mended by platform new: (.*?) -->")


def urdfs(objects: bool = True) -> list[tuple[str, str, Path]]:
    """(collection, relative path, file) for every URDF of the three collections, sorted;
    without pybullet's random objects when ``objects`` is false."""
    out = []
    for col, root in collections().items():
        for path in sorted(root.rglob("*.urdf")):
            rel = str(path.relative_to(root))
            if objects or not rel.startswith(OBJECTS):
                out.append((col, rel, path))
    return out


@functools.cache
def _parser() -> argparse.ArgumentParser:
    from kinesphere.cli import build_parser

    return build_parser()


def run(args: list[str]) -> tuple[int, str, str, str | None]:
    """A CLI command in this process: exit code, stdout, stderr, and a traceback if any (the
    command line's parser is built once per process: thousands of commands run here)."""
    from kinesphere.cli import main

    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(args, _parser())
    except BaseException:  # a traceback is what the sweep exists to catch
        return -1, out.getvalue(), err.getvalue(), traceback.format_exc()
    return code, out.getvalue(), err.getvalue(), None


def import_one(k: int, col: str, rel: str, urdf: Path, parent: Path) -> Row:
    """``platform new`` then ``describe`` of one URDF; what happened, and for a platform made
    its base, its chains' first limbs (label -> alias) and what makes it one robot."""
    from kinesphere.platforms.platform import load_platform

    name = f"{col}{k:04d}"
    row: Row = {"col": col, "rel": rel, "name": name}
    start = time.perf_counter()
    code, out, err, tb = run(["platform", "new", name, "--urdf", str(urdf), "--dir",
                              str(parent)])
    row.update(code=code, out=out, err=err, traceback=tb, new_s=time.perf_counter() - start)
    if code != 0:
        return row
    folder = parent / name
    code, _, _, tb = run(["describe", str(folder)])
    row.update(describe=code, describe_tb=tb)
    plat = load_platform(str(folder))
    e = plat.eurdf
    row["base"] = plat.base.kind
    vsam = (folder / "vsam.toml").read_text()
    row["chains"] = {p.name: p.alias or "" for p in e.limbs
                     if p.index[1] == 1 and _listed(vsam, p.name)}
    mass = sum(float(link.inertial.mass) for link in e.urdf.robot.links
               if link.inertial is not None and link.inertial.mass)
    # ur5_robot and ur5_joint_limited_robot are one robot; ur3 and ur5 share joint names only
    row["family"] = (col, str(Path(rel).parent), *sorted(e.limits), f"{mass:.1f}")
    return row


def _listed(vsam: str, limb: str) -> bool:
    """Whether vsam.toml lists ``limb`` in an entry that is not commented out."""
    return any(re.match(rf'\s*limb\s*=\s*"{re.escape(limb)}"', ln)
               for ln in vsam.splitlines())


def build_one(folder: Path, limbs: list[str]) -> Row:
    """``ecl build`` of ``limbs`` (one process), then the pulls of Laban's 26 each (limb,
    origin) pair kept, read back from the databank written."""
    start = time.perf_counter()
    args = ["ecl", "build", str(folder), "--jobs", "1"]
    for limb in limbs:
        args += ["--limb", limb]
    code, _, err, tb = run(args)
    row: Row = {"build": code, "build_tb": tb, "build_err": err[-400:],
                "build_s": time.perf_counter() - start, "kept": {}}
    if code == 0 and tb is None:
        row["kept"] = kept(folder, limbs)
    return row


def kept(folder: Path, limbs: list[str]) -> dict[str, int]:
    """Per limb of ``limbs`` (labels), the most pulls of Laban's 26 one of its (limb, origin)
    pairs kept, read back from the folder's databank."""
    from kinesphere.laban import Direction
    from kinesphere.services.ecl.ecl import Ecl

    pulls = set(Direction.pulls())
    found: dict[str, int] = {}
    for entry in Ecl.open(str(folder)).catalogue().limbs:
        if entry.limb in limbs:  # the others are in the catalogue with their neutral only
            n = sum(Direction.parse(d) in pulls for d in entry.directions)
            found[entry.limb] = max(n, found.get(entry.limb, 0))
    return found


def _import(item: tuple[int, str, str, Path, Path]) -> Row:
    return import_one(*item)


def _build(item: tuple[Path, list[str]]) -> Row:
    return build_one(*item)


def sweep(items: list[tuple[str, str, Path]], parent: Path,
          limbs: Callable[[Row], list[str]], workers: int = 2,
          progress: Callable[[str], None] = lambda line: None) -> list[Row]:
    """Import every item, then build what ``limbs`` picks for each robot made (a file that is
    a variant of a robot built earlier shares its build), ``workers`` processes at a time."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
        rows = list(pool.map(_import, [(k, *item, parent) for k, item in enumerate(items)]))
        first: dict[tuple[str, ...], Row] = {}
        built: list[Row] = []
        for row in made(rows):
            row["limbs"] = limbs(row)
            if not row["limbs"]:
                continue
            if row["family"] in first:
                row["variant_of"] = first[row["family"]]["rel"]
            else:
                first[row["family"]] = row
                built.append(row)
        progress(f"{len(rows)} URDFs: {len(made(rows))} made, {len(built)} robots to build")
        for row, result in zip(built, pool.map(_build, [(parent / r["name"], r["limbs"])
                                                         for r in built]), strict=True):
            row.update(result)
            progress(f"built {row['col']}/{row['rel']}: {row['kept']} in "
                     f"{row['build_s']:.0f} s")
    return rows


def every_chain(row: Row) -> list[str]:
    """The first limb of each chain (an arm, a leg, a head, from its root location)."""
    return list(row["chains"])


def one_chain(row: Row) -> list[str]:
    """One chain per robot: its first arm, else its first leg, else its first chain."""
    for word in ("arm", "leg", ""):
        found = [n for n, a in row["chains"].items() if word in a]
        if found:
            return found[:1]
    return []


def made(rows: Iterable[Row]) -> list[Row]:
    return [r for r in rows if r["code"] == 0]


def reason(row: Row) -> str:
    """The one error line of a refusal, without its command's name and code."""
    line = next((ln for ln in row["err"].splitlines() if ln.startswith("error:")), "")
    line = re.sub(r"\s*\[\w+\]$", "", line.removeprefix("error: "))
    return re.sub(r"^/\S*?\.urdf: ", "", line)  # the file is the row's


def table(rows: list[Row]) -> str:
    """The coverage table: one line per URDF (pybullet's random objects as one line)."""
    lines = ["| collection | URDF | result | base | chains found (aliases) | pulls kept of 26 "
             "per limb | new s | build s |", "|---|---|---|---|---|---|---|---|"]
    objects = [r for r in rows if r["rel"].startswith(OBJECTS)]
    for r in rows:
        if r in objects:
            continue
        if r["code"] != 0:
            lines.append(f"| {r['col']} | {r['rel']} | refused: {_cell(reason(r))[:90]} | | | "
                         f"| {r['new_s']:.1f} | |")
            continue
        chains = ", ".join(a or n for n, a in r["chains"].items()) or "none"
        if r.get("variant_of"):
            kept = f"as {r['variant_of']}"
        elif r.get("kept"):
            kept = ", ".join(f"{r['chains'].get(x) or x} {n}" for x, n in r["kept"].items())
        else:
            kept = "not built" if r.get("limbs") is None else "no limb"
        build = f"{r['build_s']:.1f}" if "build_s" in r else ""
        lines.append(f"| {r['col']} | {r['rel']} | made | {r['base']} | {_cell(chains)} "
                     f"| {_cell(kept)} | {r['new_s']:.1f} | {build} |")
    if objects:
        refused = Counter(reason(r) for r in objects)
        what = "; ".join(f"{n} refused: {why}" for why, n in refused.most_common())
        lines.append(f"| pyb | {OBJECTS}/ ({len(objects)} files) | {_cell(what)} | | | | "
                     f"{sum(r['new_s'] for r in objects):.1f} in all | |")
    return "\n".join(lines) + "\n"


def _cell(text: str) -> str:
    return text.replace("|", "/")


def summary(rows: list[Row]) -> str:
    """Counts under the table: made, refused (why), built, pulls per limb, tracebacks."""
    ok = made(rows)
    refused = Counter(reason(r) for r in rows if r["code"] != 0)
    built = [r for r in ok if r.get("kept")]
    per_limb = [n for r in built for n in r["kept"].values()]
    bases = Counter(r["base"] for r in ok)
    broken = [r["rel"] for r in rows if r["traceback"] or r.get("describe_tb")
              or r.get("build_tb") or r.get("build", 0) != 0]
    kinds = ", ".join(f"{n} {b}" for b, n in bases.most_common())
    lines = [f"{len(rows)} URDFs: {len(ok)} made ({kinds}), {len(rows) - len(ok)} refused"]
    lines += [f"  refused {n}x: {why}" for why, n in refused.most_common()]
    if per_limb:
        quart = statistics.quantiles(per_limb, n=4) if len(per_limb) > 1 else per_limb * 3
        lines.append(f"{len(built)} robots built, {len(per_limb)} limbs: pulls kept of 26 "
                     f"median {statistics.median(per_limb):g} (quartiles {quart[0]:g}, "
                     f"{quart[2]:g}), {sum(n >= 8 for n in per_limb)} limbs keep at least 8, "
                     f"{sum(n == 0 for n in per_limb)} none; build "
                     f"{sum(r['build_s'] for r in built):.0f} s of work")
    lines.append(f"tracebacks or failed commands: {len(broken)}"
                 + (f" ({', '.join(broken)})" if broken else ""))
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """``make sweep``: every URDF made, every robot built, the table and the counts printed."""
    import tempfile

    parser = argparse.ArgumentParser(
        prog="make sweep", description="Bring every URDF of example-robot-data, pybullet_data "
        "and rtb-data: platform new, describe, and ecl build of the first limb of each chain "
        "(once per robot; --one: of one chain); print the coverage table and the counts.")
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--out", type=Path, help="also write the table and counts here")
    parser.add_argument("--only", default="", help="only URDFs whose path contains this")
    parser.add_argument("--one", action="store_true",
                        help="build one chain per robot (its first arm, else leg), not all")
    args = parser.parse_args(argv)
    items = [i for i in urdfs() if args.only in f"{i[0]}/{i[1]}"]
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="kinesphere-sweep-") as tmp:
        rows = sweep(items, Path(tmp), one_chain if args.one else every_chain, args.workers,
                     lambda line: print(line, file=sys.stderr, flush=True))
    text = (table(rows) + "\n" + summary(rows)
            + f"wall time {time.perf_counter() - start:.0f} s with {args.workers} workers\n")
    print(text, end="")
    if args.out is not None:
        args.out.write_text(text)
    return 1 if "tracebacks or failed commands: 0" not in text else 0


if __name__ == "__main__":
    sys.exit(main())
