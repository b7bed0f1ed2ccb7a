"""Algorithm 1 of the paper, automated: the super-user's manual poses become mink IK solves.

For every VSAM entry (limb l, origin o) and every pull d the limb alone moves (everything else
stays at neutral, the base at the origin) so that its distal end goes from o toward d:

* far (k_smax): the tip is pulled toward a point far out on the ray ``o + t * d`` (4 spans,
  so the pull is nearly parallel to d and the IK maximises the reach along d) with a light
  posture task toward neutral. If that ends pointing elsewhere (a local optimum, e.g. a
  flipper pointing exactly away from d), it is tried once more via the half-way direction.
  If a smaller size later reaches farther than far, far climbs on from that pose, once.
* smaller sizes, from neutral upward, each warm-started from the size below: a limb that can
  shorten (an arm bending its elbow) puts its tip on the ray at evenly spaced projections
  between its nearest comfortable reach (NEAR_FRACTION of far, or the closest it gets) and
  far; a limb that cannot (a head, a forearm turning about its elbow) swings along the arc
  toward far instead, from where it first points honestly toward d (or from neutral).

A direction is kept only if it is honest: the far tip lies within COS_FAR of d (cosine of
d and tip - origin; 0.85 is about 32 degrees), the tip travels toward d from neutral,
projections strictly grow with size, and no pose touches another part of the robot or dips
below the floor. Everything else is dropped and reported. f_SB interpolates straight in joint
space (neutral -> size 1 -> ... -> far), so among candidate chains the first whose segments
stay clear is kept; if none does, the pull is kept and the report names what its path
touches. The same inputs give the same rows: no randomness, no clock, fixed iteration caps,
values rounded to ROUND_DIGITS.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np

from kinesphere.laban import Direction
from kinesphere.robots.mjcf import platform_model
from kinesphere.robots.platform import load_platform
from kinesphere.services.ecl.arcs import along_arc, arc_at, cosine, halfway
from kinesphere.services.ecl.ik import LimbSolver
from kinesphere.services.ecl.store import PoseRow
from kinesphere.services.ecl.vsam import Vsam, VsamEntry, load_vsam

GENERATOR_VERSION = "mink-ik-1"
COS_FAR = 0.85  # the far pose must point within ~32 degrees of d
COS_SIZE = 0.3  # smaller sizes of a limb that can only swing may point less exactly
NEAR_FRACTION = 0.4  # near reach: 40% of the far projection along d
MIN_SPAN = 0.01  # metres: a distal end closer than this to its origin cannot point anywhere
MIN_TRAVEL = 0.05  # the far tip must move toward d by 5% of the limb's span
MIN_GAP = 0.25  # consecutive sizes differ by at least 25% of their nominal spacing
CONTINUE_KEEP = 0.95  # far pushed on from the size below must keep 95% of the first far's reach
SHORTEN = 0.2  # the ray family needs the tip to come back along d by 20% of far
FAR_TARGET = 4.0  # spans out along d: far enough that pulling toward it maximises reach
FAR_ITERATIONS = 200
SIZE_ITERATIONS = 80
ROUND_DIGITS = 6

Progress = Callable[[str, int, int], None]
"""progress(label, done, total): called once per direction."""


@dataclass
class EntryReport:
    """What one (limb, origin) pair got: kept pulls, why the others were dropped, and kept
    pulls whose f_SB interpolation (straight in joint space between sizes) touches something
    on the way although every stored pose is clean."""

    limb: str
    origin: str
    kept: list[str] = field(default_factory=list)
    dropped: dict[str, str] = field(default_factory=dict)
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
class _Pose:
    values: np.ndarray  # limb joints, rounded
    offset: np.ndarray  # tip - origin, body frame
    proj: float
    cosine: float


def generate(
    platform_name: str, progress: Progress | None = None, only: tuple[str, str] | None = None
) -> tuple[list[PoseRow], GenerationReport]:
    """Rows for every pull of every non-core VSAM entry (``only``: one (limb, origin))."""
    start = time.perf_counter()
    platform = load_platform(platform_name)
    vsam = load_vsam(platform)
    pm = platform_model(platform_name)
    entries = [e for e in vsam.entries if not e.is_core]
    if only is not None:
        entries = [e for e in entries if (e.limb, e.origin) == only]
    total = sum(len(_pulls(e)) for e in entries)
    done = 0
    rows: list[PoseRow] = []
    reports: list[EntryReport] = []
    for entry in entries:
        solver = LimbSolver(pm, entry.limb, entry.origin)
        report = EntryReport(entry.limb, entry.origin)
        cells: dict[Direction, list[_Pose]] = {}
        for d in _pulls(entry):
            result = _direction(solver, vsam, d)
            if isinstance(result, str):
                report.dropped[d.slug] = result
            else:
                cells[d], path = result
                report.kept.append(d.slug)
                if path is not None:
                    report.paths[d.slug] = path
            done += 1
            if progress is not None:
                progress(f"{entry.limb}/{entry.origin} {d.slug}", done, total)
        rows.extend(_rows(solver, entry, vsam, cells))
        reports.append(report)
    seconds = time.perf_counter() - start
    return rows, GenerationReport(platform.name, GENERATOR_VERSION, reports, len(rows), seconds)


def _pulls(entry: VsamEntry) -> list[Direction]:
    """Place-middle is f_SB's neutral pose and never generated."""
    return [d for d in entry.directions if d is not Direction.PLACE_MIDDLE]


def _rows(
    solver: LimbSolver, entry: VsamEntry, vsam: Vsam, cells: dict[Direction, list[_Pose]]
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
                    cosine=_r(pose.cosine),
                    reach=_r(pose.proj / best),
                    margin=_r(solver.margin(pose.values)),
                )
            )
    return out


def _r(x: float) -> float:
    return round(float(x), ROUND_DIGITS) + 0.0  # + 0.0 turns -0.0 into 0.0


def _measure(solver: LimbSolver, values: np.ndarray, d: np.ndarray) -> _Pose:
    values = np.array([_r(v) for v in np.clip(values, solver.lower, solver.upper)])
    offset = solver.reach(solver.full_q(values)).offset
    proj = float(offset @ d)
    return _Pose(values, offset, proj, cosine(offset, d))


@dataclass(frozen=True)
class _Beyond:
    """A smaller size overshot far: far was a local optimum, this pose shows a better one."""

    reason: str
    pose: _Pose


def _direction(
    solver: LimbSolver, vsam: Vsam, direction: Direction
) -> tuple[list[_Pose], str | None] | str:
    """All sizes of one pull, smallest first, with what its interpolation path touches (None
    when clear); or the reason it is dropped."""
    d = np.array(direction.vector)
    world = solver.body_rot @ d
    if solver.span < MIN_SPAN:
        return f"its distal end sits on the origin ({solver.span * 100:.1f} cm away)"
    neutral = solver.neutral[solver.qadr]
    far = _far(solver, neutral, d, world)
    if far.cosine < COS_FAR:  # maybe a local optimum: go round via the half-way direction
        via = halfway(solver.neutral_reach().offset, d)
        start = solver.solve(neutral, _ray(solver, solver.span, solver.body_rot @ via),
                             FAR_ITERATIONS)
        detour = _far(solver, start, d, world)
        far = detour if detour.cosine > far.cosine else far
    if far.cosine < COS_FAR:
        return f"far cosine {far.cosine:.2f} < {COS_FAR}"
    hit = solver.collides(solver.full_q(far.values))
    if hit is not None:  # the solver keeps poses clean, so this is a safety net
        return f"far pose collides ({hit})"
    travel = float((far.offset - solver.neutral_reach().offset) @ d)
    if travel < MIN_TRAVEL * solver.span:
        return f"no travel toward it ({travel * 100:.1f} cm from neutral)"
    result = _sizes(solver, far, d, world, vsam.sizes)
    if isinstance(result, _Beyond):  # climb on from the pose that got farther, once
        better = _far(solver, result.pose.values, d, world)
        if better.proj > far.proj and better.cosine >= COS_FAR:
            result = _sizes(solver, better, d, world, vsam.sizes)
    if isinstance(result, _Beyond):
        return result.reason
    if isinstance(result, str):
        return result
    tried: list[tuple[list[_Pose], str]] = []
    for chain in _chains(solver, result, d, world, vsam.sizes):
        why = _paths(solver, chain, vsam.sizes)
        if why is None:
            return chain, None
        tried.append((chain, why))
    return tried[0]  # every pose is clean; only the way between them is not: keep, report


def _chains(solver: LimbSolver, first: list[_Pose], d: np.ndarray, world: np.ndarray,
            sizes: tuple[int, ...]) -> Iterator[list[_Pose]]:
    """Candidate pose chains, computed only when asked for: the chain as first found, far
    pushed on from the size below, then the sizes solved from each far downward. f_SB
    interpolates straight between neighbours, so the first chain whose segments are all
    clear wins."""
    yield first
    pushed = _continued(solver, first, d, world)
    if pushed is not first:
        yield pushed
    for far in ([first[-1], pushed[-1]] if pushed is not first else [first[-1]]):
        down = _sizes(solver, far, d, world, sizes, downward=True)
        if isinstance(down, list):
            yield down


def _continued(solver: LimbSolver, poses: list[_Pose], d: np.ndarray,
               world: np.ndarray) -> list[_Pose]:
    """Far solved once more, warm-started from the size below it, as a super-user would keep
    pushing the limb on from there: the chain neutral -> ... -> far then stays in one
    family of postures, so f_SB's straight interpolation between them stays short."""
    if len(poses) < 2:
        return poses
    below, far = poses[-2], poses[-1]
    pushed = _far(solver, below.values, d, world)
    honest = pushed.cosine >= COS_FAR and pushed.proj > below.proj
    clean = solver.collides(solver.full_q(pushed.values)) is None
    if honest and clean and pushed.proj >= CONTINUE_KEEP * far.proj:
        return [*poses[:-1], pushed]
    return poses


def _paths(solver: LimbSolver, poses: list[_Pose], sizes: tuple[int, ...]) -> str | None:
    """Why f_SB's interpolation is unsafe: it moves straight in joint space from neutral to
    size 1 and from each size to the next, so each such segment must stay clear."""
    chain = [solver.neutral[solver.qadr], *(p.values for p in poses)]
    for i, size in enumerate(sizes):
        why = solver.path_touches(chain[i], chain[i + 1])
        if why is not None:
            below = f"size {sizes[i - 1]}" if i else "neutral"
            return f"path from {below} to size {size}: {why}"
    return None


def _far(solver: LimbSolver, start: np.ndarray, d: np.ndarray, world: np.ndarray) -> _Pose:
    """The farthest reach toward d from ``start``: pulled toward a point far out on the ray."""
    target = _ray(solver, FAR_TARGET * solver.span, world)
    return _measure(solver, solver.solve(start, target, FAR_ITERATIONS), d)


def _sizes(
    solver: LimbSolver, far: _Pose, d: np.ndarray, world: np.ndarray, sizes: tuple[int, ...],
    downward: bool = False,
) -> list[_Pose] | str | _Beyond:
    """Sizes 1..smax-1 from neutral upward, each warm-started from the one below (or, with
    ``downward``, from far down, each warm-started from the one above).

    Ray family: if the limb can bring its tip back along the ray (one probe from neutral),
    the sizes are evenly spaced projections from that nearest reach up to far, tip on the ray.
    Swing family (a limb that cannot shorten, or a ray target that fails): the tip follows the
    arc from where it first points honestly toward d (or neutral) to far, evenly spaced.
    """
    n = len(sizes)
    neutral_values = solver.neutral[solver.qadr]
    neutral = solver.neutral_reach().offset
    near_target = _ray(solver, NEAR_FRACTION * far.proj, world)
    probe = _measure(solver, solver.solve(neutral_values, near_target, SIZE_ITERATIONS), d)
    lo = max(NEAR_FRACTION * far.proj, probe.proj)
    ray = probe.cosine >= COS_FAR and lo <= (1.0 - SHORTEN) * far.proj
    arc_start = _honest_start(neutral, far.offset, d)
    p0 = float(arc_start @ d)
    found: dict[int, _Pose] = {n - 1: far}
    for i in (range(n - 2, -1, -1) if downward else range(n - 1)):
        proj = p0 + (far.proj - p0) * (i + 1) / n
        arc = solver.origin + solver.body_rot @ arc_at(arc_start, far.offset, d, proj)
        candidates = [(arc, MIN_GAP * (far.proj - p0) / n)]
        if ray:
            t = lo + (far.proj - lo) * i / (n - 1)
            candidates.insert(0, (_ray(solver, t, world), MIN_GAP * (far.proj - lo) / (n - 1)))
        below = found.get(i - 1)
        above = found[i + 1] if downward else far
        start = above.values if downward else (below.values if below else neutral_values)
        pose = _first_valid(solver, start, below, above, far, candidates, d)
        if isinstance(pose, _Beyond):
            return _Beyond(f"size {sizes[i]}: {pose.reason}", pose.pose)
        if isinstance(pose, str):
            return f"size {sizes[i]}: {pose}"
        found[i] = pose
    return [found[i] for i in range(n)]


def _ray(solver: LimbSolver, t: float, world: np.ndarray) -> np.ndarray:
    return np.asarray(solver.origin + t * world)


def _first_valid(
    solver: LimbSolver,
    start: np.ndarray,
    below: _Pose | None,
    above: _Pose,
    far: _Pose,
    candidates: list[tuple[np.ndarray, float]],
    d: np.ndarray,
) -> _Pose | str | _Beyond:
    """The first (target, gap) whose solve gives an honest pose strictly between its
    neighbours (at least ``gap`` metres of projection from each); a clean pose that reaches
    past far comes back as _Beyond so the caller can improve far."""
    why: str | _Beyond = "no target"
    for target, gap in candidates:
        pose = _measure(solver, solver.solve(start, target, SIZE_ITERATIONS), d)
        floor = below.proj + gap if below is not None else -np.inf
        ceiling = above.proj - gap
        hit = solver.collides(solver.full_q(pose.values))
        if pose.proj > far.proj and pose.cosine >= COS_FAR and hit is None:
            why = _Beyond(f"reach {pose.proj:.3f} m beyond far {far.proj:.3f} m", pose)
        elif not floor <= pose.proj <= ceiling:
            why = (f"reach {pose.proj:.3f} m not between its neighbours "
                   f"({floor:.3f}..{ceiling:.3f} m)")
        elif pose.cosine < COS_SIZE:
            why = f"cosine {pose.cosine:.2f} < {COS_SIZE}"
        elif hit is not None:
            why = hit
        else:
            return pose
    return why


def _honest_start(neutral: np.ndarray, far: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Where the swing from neutral to far starts to point honestly toward d (cosine
    COS_FAR), or neutral itself if it already does: the swing family's size 0."""
    if cosine(neutral, d) >= COS_FAR:
        return neutral
    lo, hi = 0.0, 1.0
    for _ in range(30):
        mid = (lo + hi) / 2
        if cosine(along_arc(neutral, far, mid), d) >= COS_FAR:
            hi = mid
        else:
            lo = mid
    return along_arc(neutral, far, hi)
