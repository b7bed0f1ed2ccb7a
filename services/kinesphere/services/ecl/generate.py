"""Algorithm 1 of the paper, automated: the super-user's manual poses become mink IK solves.

For every VSAM entry (limb l, origin o) and every pull d the limb alone moves (everything else
stays at neutral, the base at the origin, a joint that also drives a mimic joint outside the
limb at neutral too) so that its distal end goes from o toward d. o is the pivot of the joint
location (``kinesphere.platforms.frames``), the distal end the limb's tip (NAO's head: its gaze
point); where both are, and where a pose points, is :mod:`measure`'s definition.

* far (k_smax): the tip is pulled toward a point far out on the ray ``o + t * d`` (4 spans,
  so the pull is nearly parallel to d and the IK maximises the reach along d) with a light
  posture task toward neutral. If that ends pointing elsewhere (a local optimum, e.g. a
  flipper pointing exactly away from d), it is tried once more via the half-way direction;
  if the ray is blocked (the floor under a low pull), a limb that can fold takes the farthest
  point on the ray it reaches with its bearing held (FAR_HOLD).
* smaller sizes (``chains``): by the limb's size rule, reach (the tip on the ray at growing
  fractions of far's distance, near with the elbow bent) or swing (the bearing turning an even
  share of the way toward far per size); the rule of every pair is stored in the databank.
* a direction the neutral pose already points at (cosine >= HONEST) is never dropped: near is
  neutral and the larger sizes extend along it, or hold neutral when the limb cannot.

A direction is kept only if it is honest (``chains``: pointing, sizes in order, no flips, no
pose touching another part of the robot or the floor, every size reachable from neutral by the
agent's planner). Stability removes sizes, not directions: sizes are kept from near up while
the body stands (``balance``: the whole-body centre of mass at least 1 cm inside what still
touches the floor), so a PackBot reaching far to its side keeps near and mid; a direction
whose near would topple the body is dropped and reported ("unstable"). A kept pull whose f_SB
interpolation (straight in joint space between sizes) touches something is kept and reported.
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
    REACH,
    ROUND_DIGITS,
    LimbPose,
    Sizes,
    measure,
    rounded,
    short_of,
    size_rule,
)
from kinesphere.services.ecl.ik import LimbSolver
from kinesphere.services.ecl.store import PoseRow
from kinesphere.services.ecl.vsam import Vsam, VsamEntry, load_vsam

__all__ = ["COS_FAR", "GENERATOR_VERSION", "ROUND_DIGITS", "EntryReport", "GenerationReport",
           "generate", "generate_entry", "pulls", "report_meta"]

GENERATOR_VERSION = "mink-ik-3"
MIN_SPAN = 0.01  # metres: a distal end closer than this to its origin cannot point anywhere
FAR_TARGET = 4.0  # spans out along d: far enough that pulling toward it maximises reach
FAR_ITERATIONS = 200
FAR_HOLD = 0.9  # a blocked ray: the farthest point on it whose bearing keeps this cosine
HOLD_SCAN = (0.8, 0.6, 0.45, 0.3)  # ... tried at these fractions of the span
HOLD_REFINE = 3  # bisection steps between the farthest held fraction and the next one out
BLOCKED = 0.7  # a far pull pointing this well (or better) may be a blocked ray, not a wrong one
ON_FLOOR = 0.05  # metres: ... blocked by the floor when its tip ends this low

Progress = Callable[[str, int, int], None]
"""progress(label, done, total): called once per direction."""


@dataclass
class EntryReport:
    """What one (limb, origin) pair got: its size rule, kept pulls, why the others were
    dropped (toppling apart, in ``unstable``), the sizes stability removed from kept pulls
    (``short``), and kept pulls whose f_SB interpolation (straight in joint space between
    sizes) touches something on the way although every stored pose is clean."""

    limb: str
    origin: str
    rule: str = REACH
    rest: tuple[float, float, float] = (0.0, 0.0, 0.0)  # where the tip is at neutral
    kept: list[str] = field(default_factory=list)
    dropped: dict[str, str] = field(default_factory=dict)
    unstable: dict[str, str] = field(default_factory=dict)
    short: dict[str, str] = field(default_factory=dict)
    paths: dict[str, str] = field(default_factory=dict)
    swung: list[str] = field(default_factory=list)  # pulls a reach limb (a leg) swings


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


@dataclass(frozen=True)
class _Kept:
    """A kept pull: its sizes from near up (fewer than the VSAM's when stability removed the
    top ones), far as the limb reaches it, and what its path touches / why it is short."""

    poses: list[LimbPose]
    far: LimbPose
    touched: str | None = None
    short: str | None = None
    rule: str = REACH


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
    balance = Balance(pm)
    rule = size_rule(solver)
    sizes = Sizes(solver, vsam.sizes, rule)
    at_rest = set(balance.fk.neutral_directions(entry.limb, entry.origin))
    rest = balance.fk.neutral_offset(entry.limb, entry.origin)
    report = EntryReport(entry.limb, entry.origin, rule, (rounded(rest[0]), rounded(rest[1]),
                                                          rounded(rest[2])))
    cells: dict[Direction, _Kept] = {}
    todo = pulls(entry)
    for i, d in enumerate(todo, start=1):
        result = _direction(solver, sizes, balance, d, d in at_rest)
        if isinstance(result, _Drop):
            (report.unstable if result.unstable else report.dropped)[d.slug] = result.reason
        else:
            cells[d] = result
            report.kept.append(d.slug)
            if result.touched is not None:
                report.paths[d.slug] = result.touched
            if result.short is not None:
                report.short[d.slug] = result.short
            if result.rule != rule:
                report.swung.append(d.slug)
        if progress is not None:
            progress(f"{entry.limb}/{entry.origin} {d.slug}", i, len(todo))
    return _rows(solver, sizes, balance, entry, vsam, cells), report


def report_meta(report: GenerationReport) -> dict[str, str]:
    """The databank's record of the run, for ``ecl report``, ``ecl audit`` and the coverage
    tables, each JSON ``{"limb/origin": ...}``: ``dropped`` and ``unstable`` (direction ->
    reason), ``short`` (kept directions whose top sizes would topple -> reason) and
    ``size_rules`` ("reach" or "swing"), ``swung`` (pulls a reach limb swings: a leg that
    cannot fold along them) and ``neutral_tips`` (where the tip is at neutral, for f_SB's
    measured angle below near)."""
    def table(attr: str) -> str:
        return json.dumps({f"{e.limb}/{e.origin}": getattr(e, attr) for e in report.entries},
                          sort_keys=True, separators=(",", ":"))

    return {"dropped": table("dropped"), "unstable": table("unstable"), "short": table("short"),
            "size_rules": table("rule"), "swung": table("swung"), "neutral_tips": table("rest")}


def pulls(entry: VsamEntry) -> list[Direction]:
    """Place-middle is f_SB's neutral pose and never generated."""
    return [d for d in entry.directions if d is not Direction.PLACE_MIDDLE]


def _rows(solver: LimbSolver, sizes: Sizes, balance: Balance, entry: VsamEntry, vsam: Vsam,
          cells: dict[Direction, _Kept]) -> list[PoseRow]:
    """The stored rows: the limb's joints, its support's (a stance leg), and the figures
    measured on the stored values (:mod:`measure`)."""
    out = []
    n = solver.limb_count
    for d, kept in cells.items():
        rest = sizes.neutral(np.array(d.vector))
        for size, pose in zip(vsam.sizes, kept.poses, strict=False):
            values = dict(zip(solver.joints, map(float, pose.values), strict=True))
            tip = balance.fk.offset(entry.limb, entry.origin, values)
            out.append(
                PoseRow(
                    limb=entry.limb,
                    origin=entry.origin,
                    direction=d.slug,
                    size=size,
                    joints={j: values[j] for j in solver.joints[:n]},
                    cosine=rounded(pose.cosine),
                    reach=rounded(_fraction(kept.rule, rest, pose, kept.far)),
                    margin=rounded(solver.margin(pose.values)),
                    support={j: values[j] for j, go in zip(solver.joints[n:], solver.moving[n:],
                                                           strict=True) if go},
                    tip=(rounded(tip[0]), rounded(tip[1]), rounded(tip[2])),
                )
            )
    return out


def _fraction(rule: str, rest: LimbPose, pose: LimbPose, far: LimbPose) -> float:
    """How much of the pull a size is: its tip distance over far's (reach), or the angle its
    bearing turned from neutral over far's (swing); 1 for a limb holding neutral."""
    if rule == REACH:
        return pose.distance / far.distance if far.distance > 0 else 1.0
    whole = _angle(rest.offset, far.offset)
    return _angle(rest.offset, pose.offset) / whole if whole > 1e-6 else 1.0


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na < 1e-12 or nb < 1e-12:
        return 0.0
    return float(np.arccos(np.clip(float(a @ b) / (na * nb), -1.0, 1.0)))


def _direction(solver: LimbSolver, sizes: Sizes, balance: Balance, direction: Direction,
               at_rest: bool) -> _Kept | _Drop:
    """All sizes of one pull that stand, smallest first; or why it is dropped. A pull the
    neutral pose points at (``at_rest``) is never dropped: at worst it holds neutral."""
    d = np.array(direction.vector)
    if solver.span < MIN_SPAN:
        return _Drop(f"its distal end sits on the origin ({solver.span * 100:.1f} cm away)")
    neutral = sizes.neutral(d)
    held = _Kept([neutral] * len(sizes.sizes), neutral, rule=sizes.rule)
    far = _far(solver, sizes, d)
    if far.cosine < COS_FAR:
        return held if at_rest else _Drop(f"far cosine {short_of(far.cosine, COS_FAR)}")
    hit = solver.collides(solver.full_q(far.values))
    if hit is not None:  # the solver keeps poses clean, so this is a safety net
        return held if at_rest else _Drop(f"far pose collides ({hit})")
    found = sizes.chain(far, d, at_rest)
    if isinstance(found, str):
        return held if at_rest else _Drop(found)
    chain, rule = found.poses, found.rule
    if solver.stance:  # a leg: where the body would topple, the stance leg carries it over
        chain = [measure(solver, solver.balanced(p.values), d)  # its sole (a person shifts
                 if balance.check(solver.full_q(p.values)) else p  # weight only then)
                 for p in chain]
    stand: list[LimbPose] = []
    short: str | None = None
    for size, pose in zip(sizes.sizes, chain, strict=True):
        q = solver.full_q(pose.values)
        toppling = solver.collides(q) or balance.check(q)
        if toppling is not None:
            short = f"size {size}: {toppling}"
            break
        stand.append(pose)
    if not stand:
        return _Drop(short or "unstable", unstable=True)
    blocked = sizes.reachable(stand)
    if blocked is not None:
        return held if at_rest else _Drop(blocked)
    return _Kept(stand, far, sizes.path(stand), short, rule)


def _far(solver: LimbSolver, sizes: Sizes, d: np.ndarray) -> LimbPose:
    """The farthest reach toward d: pulled toward a point far out on the ray (via the half-way
    direction if that ends elsewhere); on a ray the floor blocks, a limb that folds takes the
    farthest point of the ray it reaches pointing within FAR_HOLD."""
    world = solver.body_rot @ d
    neutral = solver.neutral[solver.qadr]
    far = _pulled(solver, neutral, d, world)
    if far.cosine < COS_FAR:  # maybe a local optimum: go round via the half-way direction
        via = halfway(solver.neutral_reach().offset, d)
        start = solver.solve(neutral, _ray(solver, solver.span, solver.body_rot @ via),
                             FAR_ITERATIONS)
        detour = _pulled(solver, start, d, world)
        far = detour if detour.cosine > far.cosine else far
    if far.cosine >= COS_FAR or far.cosine < BLOCKED or sizes.rule != REACH:
        return far
    # from the blocked pull (the limb already out that way, e.g. lying on the floor), and,
    # when the floor is what blocks it, from neutral too
    held = _on_ray(solver, d, world, far.values)
    if held is None and solver.reach(solver.full_q(far.values)).tip[2] <= ON_FLOOR:
        held = _on_ray(solver, d, world, neutral)
    return held if held is not None and held.cosine >= COS_FAR else far


def _on_ray(solver: LimbSolver, d: np.ndarray, world: np.ndarray, start: np.ndarray
            ) -> LimbPose | None:
    """The farthest pose with the tip aimed at a point of the ray (a fraction of the span out)
    that points within FAR_HOLD of d and touches nothing; None if no fraction does."""
    def at(fraction: float) -> LimbPose | None:
        pose = measure(solver, solver.solve(start, _ray(solver, fraction * solver.span, world),
                                            FAR_ITERATIONS), d)
        clean = solver.collides(solver.full_q(pose.values)) is None
        return pose if pose.cosine >= FAR_HOLD and clean else None

    for i, fraction in enumerate(HOLD_SCAN):
        best = at(fraction)
        if best is None:
            continue
        lo, hi = fraction, HOLD_SCAN[i - 1] if i else 1.0
        for _ in range(HOLD_REFINE):
            mid = (lo + hi) / 2
            pose = at(mid)
            if pose is not None and pose.distance > best.distance:
                best, lo = pose, mid
            else:
                hi = mid
        return best
    return None


def _pulled(solver: LimbSolver, start: np.ndarray, d: np.ndarray, world: np.ndarray) -> LimbPose:
    """The farthest reach toward d from ``start``: pulled toward a point far out on the ray."""
    target = _ray(solver, FAR_TARGET * solver.span, world)
    return measure(solver, solver.solve(start, target, FAR_ITERATIONS), d)


def _ray(solver: LimbSolver, t: float, world: np.ndarray) -> np.ndarray:
    return np.asarray(solver.origin + t * world)
