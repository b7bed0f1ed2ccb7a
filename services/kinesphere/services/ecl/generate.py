"""Algorithm 1 of the paper, automated: the super-user's manual poses become mink IK solves.

For every VSAM entry (limb l, origin o) and every pull d the limb alone moves (everything else
stays at neutral, the base at the origin, a joint that also drives a mimic joint outside the
limb at neutral too) so that its distal end goes from o toward d. o is the pivot of the joint
location (``kinesphere.platforms.frames``), the distal end the limb's tip (NAO's head: its gaze
point).

* far (k_smax): the tip is pulled toward a point far out on the ray ``o + t * d`` (4 spans,
  so the pull is nearly parallel to d and the IK maximises the reach along d) with a light
  posture task toward neutral. If that ends pointing elsewhere (a local optimum, e.g. a
  flipper pointing exactly away from d), it is tried once more via the half-way direction.
* smaller sizes (``chains``): near, mid, ... are steps from neutral toward far along d, an IK
  chain on the ray or arc, else the straight joint-space segment to far.

A direction is kept only if it is honest: the far tip lies within COS_FAR of d (cosine of d and
tip - origin; 0.85 is about 32 degrees), the tip advances along d from neutral through every
size, no joint flips between sizes, and no pose touches another part of the robot, dips below
the floor or topples (``balance``: the whole-body centre of mass stays over what still touches
the floor), and the agent's planner finds a way from neutral to every size that touches nothing
(``kinesphere.platforms.clearance``). Everything else is dropped and reported, toppling apart
("unstable").
Among honest chains the one pointing best (highest mean cosine) whose f_SB interpolation
(straight in joint space between sizes) stays clear is kept; if none stays clear, the pull is
kept and the report names what its path touches. A smaller size that reaches past far shows
far was a local optimum: far climbs on from there (CLIMBS times at most) instead of the
direction being dropped for a millimetre.
The same inputs give the same rows: no randomness, no clock, fixed iteration caps, values
rounded to ROUND_DIGITS.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from kinesphere.laban import Direction
from kinesphere.platforms.mjcf import platform_model
from kinesphere.platforms.platform import load_platform
from kinesphere.services.ecl.arcs import halfway
from kinesphere.services.ecl.balance import Balance
from kinesphere.services.ecl.chains import (
    COS_FAR,
    COS_SIZE,
    ROUND_DIGITS,
    Beyond,
    LimbPose,
    Sizes,
    measure,
    rounded,
)
from kinesphere.services.ecl.ik import LimbSolver
from kinesphere.services.ecl.store import PoseRow
from kinesphere.services.ecl.vsam import Vsam, VsamEntry, load_vsam

__all__ = ["COS_FAR", "COS_SIZE", "GENERATOR_VERSION", "ROUND_DIGITS", "EntryReport",
           "GenerationReport", "generate", "generate_entry", "pulls", "report_meta"]

GENERATOR_VERSION = "mink-ik-2"
MIN_SPAN = 0.01  # metres: a distal end closer than this to its origin cannot point anywhere
MIN_TRAVEL = 0.05  # the far tip must move toward d by 5% of the limb's span
FAR_TARGET = 4.0  # spans out along d: far enough that pulling toward it maximises reach
FAR_ITERATIONS = 200
CLIMBS = 2

Progress = Callable[[str, int, int], None]
"""progress(label, done, total): called once per direction."""


@dataclass
class EntryReport:
    """What one (limb, origin) pair got: kept pulls, why the others were dropped (toppling
    apart, in ``unstable``), and kept pulls whose f_SB interpolation (straight in joint space
    between sizes) touches something on the way although every stored pose is clean."""

    limb: str
    origin: str
    kept: list[str] = field(default_factory=list)
    dropped: dict[str, str] = field(default_factory=dict)
    unstable: dict[str, str] = field(default_factory=dict)
    paths: dict[str, str] = field(default_factory=dict)


@dataclass
class GenerationReport:
    """One platform's run: what each pair got, how many rows, how long it took."""

    platform: str
    generator_version: str
    entries: list[EntryReport]
    rows: int
    seconds: float


@dataclass(frozen=True)
class _Drop:
    reason: str
    unstable: bool = False


def generate(
    platform_name: str, progress: Progress | None = None, only: tuple[str, str] | None = None
) -> tuple[list[PoseRow], GenerationReport]:
    """Rows for every pull of every non-core VSAM entry (``only``: one (limb, origin))."""
    start = time.perf_counter()
    platform = load_platform(platform_name)
    entries = [e for e in load_vsam(platform).entries if not e.is_core]
    if only is not None:
        entries = [e for e in entries if (e.limb, e.origin) == only]
    total = sum(len(pulls(e)) for e in entries)
    rows: list[PoseRow] = []
    reports: list[EntryReport] = []
    for entry in entries:
        done = sum(len(pulls(e)) for e in entries[: len(reports)])

        def step(label: str, i: int, _: int, done: int = done) -> None:
            if progress is not None:
                progress(label, done + i, total)

        entry_rows, report = generate_entry(platform_name, entry.limb, entry.origin, step)
        rows.extend(entry_rows)
        reports.append(report)
    seconds = time.perf_counter() - start
    return rows, GenerationReport(platform.name, GENERATOR_VERSION, reports, len(rows), seconds)


def generate_entry(
    platform_name: str, limb: str, origin: str, progress: Progress | None = None
) -> tuple[list[PoseRow], EntryReport]:
    """Rows of one (limb, origin) pair: everything one build job does (see ``parallel``)."""
    platform = load_platform(platform_name)
    vsam = load_vsam(platform)
    entry = vsam.entry(limb, origin)
    if entry is None or entry.is_core:
        raise ValueError(f"({limb}, {origin}) is no limb entry of {platform.name}'s VSAM")
    pm = platform_model(platform_name)
    solver = LimbSolver(pm, entry.limb, entry.origin)
    sizes = Sizes(solver, Balance(pm), vsam.sizes)
    report = EntryReport(entry.limb, entry.origin)
    cells: dict[Direction, list[LimbPose]] = {}
    todo = pulls(entry)
    for i, d in enumerate(todo, start=1):
        result = _direction(solver, sizes, d)
        if isinstance(result, _Drop):
            (report.unstable if result.unstable else report.dropped)[d.slug] = result.reason
        else:
            cells[d], path = result
            report.kept.append(d.slug)
            if path is not None:
                report.paths[d.slug] = path
        if progress is not None:
            progress(f"{entry.limb}/{entry.origin} {d.slug}", i, len(todo))
    return _rows(solver, entry, vsam, cells), report


def report_meta(report: GenerationReport) -> dict[str, str]:
    """The databank's record of what was dropped (``meta.dropped``, ``meta.unstable``: JSON
    ``{"limb/origin": {direction: reason}}``), for ``ecl report`` and the coverage tables."""
    def table(attr: str) -> str:
        return json.dumps({f"{e.limb}/{e.origin}": getattr(e, attr) for e in report.entries},
                          sort_keys=True, separators=(",", ":"))

    return {"dropped": table("dropped"), "unstable": table("unstable")}


def pulls(entry: VsamEntry) -> list[Direction]:
    """Place-middle is f_SB's neutral pose and never generated."""
    return [d for d in entry.directions if d is not Direction.PLACE_MIDDLE]


def _rows(
    solver: LimbSolver, entry: VsamEntry, vsam: Vsam, cells: dict[Direction, list[LimbPose]]
) -> list[PoseRow]:
    best = max((p.proj for poses in cells.values() for p in poses), default=1.0)
    out = []
    for d, poses in cells.items():
        for size, pose in zip(vsam.sizes, poses, strict=True):
            out.append(
                PoseRow(
                    limb=entry.limb,
                    origin=entry.origin,
                    direction=d.slug,
                    size=size,
                    joints={j: float(v) for j, v in zip(solver.joints, pose.values, strict=True)},
                    cosine=rounded(pose.cosine),
                    reach=rounded(pose.proj / best),
                    margin=rounded(solver.margin(pose.values)),
                )
            )
    return out


def _direction(solver: LimbSolver, sizes: Sizes, direction: Direction
               ) -> tuple[list[LimbPose], str | None] | _Drop:
    """All sizes of one pull, smallest first, with what its interpolation path touches (None
    when clear); or why it is dropped."""
    d = np.array(direction.vector)
    world = solver.body_rot @ d
    if solver.span < MIN_SPAN:
        return _Drop(f"its distal end sits on the origin ({solver.span * 100:.1f} cm away)")
    neutral = solver.neutral[solver.qadr]
    far = _far(solver, neutral, d, world)
    if far.cosine < COS_FAR:  # maybe a local optimum: go round via the half-way direction
        via = halfway(solver.neutral_reach().offset, d)
        start = solver.solve(neutral, _ray(solver, solver.span, solver.body_rot @ via),
                             FAR_ITERATIONS)
        detour = _far(solver, start, d, world)
        far = detour if detour.cosine > far.cosine else far
    if far.cosine < COS_FAR:
        return _Drop(f"far cosine {far.cosine:.2f} < {COS_FAR}")
    hit = solver.collides(solver.full_q(far.values))
    if hit is not None:  # the solver keeps poses clean, so this is a safety net
        return _Drop(f"far pose collides ({hit})")
    travel = float((far.offset - solver.neutral_reach().offset) @ d)
    if travel < MIN_TRAVEL * solver.span:
        return _Drop(f"no travel toward it ({travel * 100:.1f} cm from neutral)")
    toppling = sizes.balance.check(solver.full_q(far.values))
    if toppling is not None:
        return _Drop(f"far pose: {toppling}", unstable=True)
    why = "no honest sizes"
    for _ in range(CLIMBS + 1):
        result = _chain(solver, sizes, far, d)
        if not isinstance(result, Beyond):
            return result
        why = result.reason
        better = _far(solver, result.pose.values, d, world)
        q = solver.full_q(better.values)
        if not (better.proj > far.proj and better.cosine >= COS_FAR
                and solver.collides(q) is None and sizes.balance.check(q) is None):
            break
        far = better  # far was a local optimum: climb on from the size that got farther
    return _Drop(why)


def _chain(solver: LimbSolver, sizes: Sizes, far: LimbPose, d: np.ndarray
           ) -> tuple[list[LimbPose], str | None] | _Drop | Beyond:
    """The honest chain up to ``far`` that points best (highest mean cosine), among those
    whose path is clear if any (else with what its path touches); a Beyond when the IK chain
    overshot far and nothing else was honest; else why not."""
    honest: list[list[LimbPose]] = []
    whys: list[str] = []
    beyond: Beyond | None = None
    for chain in sizes.candidates(far, d):
        if isinstance(chain, Beyond):
            beyond = beyond or chain
            continue
        why = chain if isinstance(chain, str) else sizes.check(chain, d)
        if why is not None or isinstance(chain, str):
            whys.append(str(why))
            continue
        honest.append(chain)
    touching: list[tuple[list[LimbPose], str]] = []
    for chain in sorted(honest, key=_pointing, reverse=True):  # stable: ties keep their order
        blocked = sizes.reachable(chain)
        if blocked is not None:
            whys.append(blocked)
            continue
        touched = sizes.path(chain)
        if touched is None:
            return _nudge(sizes, chain, None, d)
        touching.append((chain, touched))
    if touching:  # every pose is clean; only the way between them is not: keep, report
        return _nudge(sizes, *touching[0], d)
    if beyond is not None:
        return beyond
    unstable = [w for w in whys if "unstable" in w]
    return _Drop(unstable[0], unstable=True) if unstable else _Drop(whys[0])


def _nudge(sizes: Sizes, chain: list[LimbPose], touched: str | None, d: np.ndarray
           ) -> tuple[list[LimbPose], str | None]:
    """The chosen chain, nudged toward d when that keeps it honest and no worse on its way."""
    better = sizes.nudged(chain, d)
    if better is None or _pointing(better) <= _pointing(chain) or sizes.check(better, d):
        return chain, touched
    way = sizes.path(better)
    return (better, way) if way is None or touched is not None else (chain, touched)


def _pointing(chain: list[LimbPose]) -> float:
    """Mean cosine of a chain's sizes (the first candidate wins ties: max keeps it)."""
    return sum(p.cosine for p in chain) / len(chain)


def _far(solver: LimbSolver, start: np.ndarray, d: np.ndarray, world: np.ndarray) -> LimbPose:
    """The farthest reach toward d from ``start``: pulled toward a point far out on the ray."""
    target = _ray(solver, FAR_TARGET * solver.span, world)
    return measure(solver, solver.solve(start, target, FAR_ITERATIONS), d)


def _ray(solver: LimbSolver, t: float, world: np.ndarray) -> np.ndarray:
    return np.asarray(solver.origin + t * world)
