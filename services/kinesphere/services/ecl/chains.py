"""The sizes of one pull: from neutral through near and mid to far, each a step along d.

A pull's far pose is found first (``generate``); the smaller sizes are what this module adds.
Two candidate chains, tried in order:

* the **IK chain**: each smaller size is an IK solve, warm-started from the size below, that
  puts the tip at an evenly spaced projection on d, on the ray from the origin when the limb
  can shorten (an arm bending its elbow), else on the arc of its swing toward far (a head, a
  forearm turning about its elbow); a posture pull toward the straight joint-space way from
  neutral to far keeps the sizes in one family of postures.
* **segment chains**: the sizes on the straight joint-space segment from neutral to far, near
  where the tip first points at d well enough (one chain per NEAR_COSINES) and the sizes
  evenly spaced along d from there. That is the path f_SB interpolates, so they can neither
  flip nor overshoot far. The chosen chain's smaller sizes are then *nudged* toward the ray,
  each held near its own posture, when that points them better.

A chain is *honest* when the tip advances along d from neutral through every size (near at
least MIN_ADVANCE ahead of neutral, then MIN_GAP of the even spacing up to far apart), every
smaller size points within COS_SIZE of d, no pose touches anything or topples, every size is
reachable from neutral without touching anything (the agent's planner, waypoints allowed), no
joint turns back more than DETOUR_SLACK on its way from neutral through the sizes to far, and
none moves between two successive sizes more than STEP_SLACK beyond its even share of its way
from near to far (no wrist flips between sizes). Deterministic: no randomness, fixed iteration
caps, values rounded.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from kinesphere.platforms.clearance import Clearance, Touch
from kinesphere.services.ecl.arcs import along_arc, arc_at, cosine
from kinesphere.services.ecl.balance import Balance
from kinesphere.services.ecl.ik import LimbSolver

COS_FAR = 0.85  # the far pose must point within ~32 degrees of d
COS_SIZE = 0.3  # smaller sizes of a limb that can only swing may point less exactly
NEAR_FRACTION = 0.4  # a ray's near reach: no closer than 40% of the far projection along d
SHORTEN = 0.2  # the ray family needs the tip to come back along d by 20% of far
MIN_ADVANCE = 0.02  # near is at least 2% of the limb's span ahead of neutral along d
MIN_GAP = 0.25  # consecutive sizes differ by at least 25% of their even spacing near..far
DETOUR_SLACK = 1.5  # rad a joint may turn back, in all, from neutral through the sizes to far
STEP_SLACK = 0.75  # rad a joint may move between two sizes beyond its even share
SIZE_POSTURE = 0.1  # posture weight per radian toward the straight joint-space way
NUDGE_POSTURE = 1.0  # ... and toward a segment pose being nudged onto the ray
SIZE_ITERATIONS = 80
SEGMENT_GRID = 64  # samples of the straight segment before bisection
NEAR_COSINES = (COS_FAR, 0.7, 0.5)  # a segment chain's near: where the tip first points so
ROUND_DIGITS = 6


@dataclass(frozen=True)
class LimbPose:
    """A limb pose and where it puts the tip: offset from the origin (body frame), its
    projection on d and its cosine with d."""

    values: np.ndarray  # limb joints, rounded
    offset: np.ndarray
    proj: float
    cosine: float


@dataclass(frozen=True)
class Beyond:
    """A smaller size reached past far: far was a local optimum and this pose shows better."""

    reason: str
    pose: LimbPose


def rounded(x: float) -> float:
    return round(float(x), ROUND_DIGITS) + 0.0  # + 0.0 turns -0.0 into 0.0


def measure(solver: LimbSolver, values: np.ndarray, d: np.ndarray) -> LimbPose:
    """Round and clip limb values and see where they put the tip."""
    values = np.array([rounded(v) for v in np.clip(values, solver.lower, solver.upper)])
    offset = solver.reach(solver.full_q(values)).offset
    proj = float(offset @ d)
    return LimbPose(values, offset, proj, cosine(offset, d))


def joint_detour(chain: list[np.ndarray]) -> float:
    """Radians the worst joint travels along a chain (neutral, near, ..., far) beyond its
    straight way from the first pose to the last: 0 when every joint moves one way only."""
    q = np.array(chain, dtype=float)
    travelled = np.abs(np.diff(q, axis=0)).sum(axis=0)
    return float(np.max(travelled - np.abs(q[-1] - q[0]), initial=0.0))


def joint_jump(sizes: list[np.ndarray]) -> float:
    """Radians by which the worst step between successive stored sizes (near, ..., far)
    outgrows that joint's even share of its way from near to far: 0 or less for even steps,
    about pi for a wrist that flips over between two sizes."""
    q = np.array(sizes, dtype=float)
    if len(q) < 2:
        return 0.0
    share = np.abs(q[-1] - q[0]) / (len(q) - 1)
    return float(np.max(np.abs(np.diff(q, axis=0)) - share, initial=0.0))


class Sizes:
    """Size chains of one (limb, origin) pair; ``sizes`` are the VSAM's (near ... far)."""

    def __init__(self, solver: LimbSolver, balance: Balance, sizes: tuple[int, ...]) -> None:
        self.solver = solver
        self.balance = balance
        self.sizes = sizes
        self.neutral_values = solver.neutral[solver.qadr]
        self.clearance = Clearance(solver.pm)
        names = solver.pm.platform.joint_names
        self._in_p = np.array([names.index(j) for j in solver.joints], dtype=int)

    def candidates(self, far: LimbPose, d: np.ndarray) -> Iterator[list[LimbPose] | str | Beyond]:
        """The IK chain, then segment chains whose near starts where the tip first points at
        d with each of NEAR_COSINES: each a list of poses near..far, or why not, computed
        only when asked for."""
        yield self._ik_chain(far, d)
        a, b = self.neutral_values, far.values
        grid = [measure(self.solver, a + t * (b - a), d)
                for t in np.linspace(0.0, 1.0, SEGMENT_GRID + 1)]
        for start in NEAR_COSINES:
            yield self._segment_chain(far, d, start, grid)

    def check(self, chain: list[LimbPose], d: np.ndarray) -> str | None:
        """Why a chain (near..far) is not honest, or None; see the module."""
        s = self.solver
        neutral = measure(s, self.neutral_values, d)
        near, far = chain[0], chain[-1]
        if near.proj < neutral.proj + MIN_ADVANCE * s.span:
            return (f"size {self.sizes[0]}: tip {near.proj:.3f} m along d, not ahead of "
                    f"neutral ({neutral.proj:.3f} m)")
        gap = MIN_GAP * (far.proj - near.proj) / max(len(chain) - 1, 1)
        for size, pose, below in zip(self.sizes[1:], chain[1:], chain, strict=False):
            if pose.proj < below.proj + gap:
                return (f"size {size}: tip {pose.proj:.3f} m along d, not {gap:.3f} m ahead "
                        f"of the size below ({below.proj:.3f} m)")
        for size, pose in zip(self.sizes, chain, strict=True):
            if pose is not far and pose.cosine < COS_SIZE:
                return f"size {size}: cosine {pose.cosine:.2f} < {COS_SIZE}"
            q = s.full_q(pose.values)
            why = s.collides(q) or self.balance.check(q)
            if why is not None:
                return f"size {size}: {why}"
        detour = joint_detour([self.neutral_values, *(p.values for p in chain)])
        if detour > DETOUR_SLACK:
            return f"a joint turns back {detour:.2f} rad on the way to far (> {DETOUR_SLACK})"
        jump = joint_jump([p.values for p in chain])
        if jump > STEP_SLACK:
            return (f"a joint jumps {jump:.2f} rad beyond its even step between sizes "
                    f"(> {STEP_SLACK})")
        return None

    def reachable(self, chain: list[LimbPose]) -> str | None:
        """Why a size cannot be reached from neutral without touching anything, or None: the
        agent's own planner (:mod:`kinesphere.platforms.clearance`, waypoints allowed) must find
        a clear way to every stored pose, so no stored pose is blocked from neutral."""
        start = self.clearance.neutral
        for size, pose in zip(self.sizes, chain, strict=True):
            goal = start.copy()
            goal[self._in_p] = pose.values
            route = self.clearance.route(start, goal)
            if isinstance(route, Touch):
                return f"size {size}: no collision-free way from neutral ({route})"
        return None

    def path(self, chain: list[LimbPose]) -> str | None:
        """What f_SB's straight interpolation neutral -> near -> ... -> far touches, or None."""
        values = [self.neutral_values, *(p.values for p in chain)]
        for i, size in enumerate(self.sizes):
            why = self.solver.path_touches(values[i], values[i + 1])
            if why is not None:
                below = f"size {self.sizes[i - 1]}" if i else "neutral"
                return f"path from {below} to size {size}: {why}"
        return None

    # -- the IK chain -----------------------------------------------------------------------
    def _ik_chain(self, far: LimbPose, d: np.ndarray) -> list[LimbPose] | str | Beyond:
        s, n = self.solver, len(self.sizes)
        world = s.body_rot @ d
        neutral = measure(s, self.neutral_values, d)
        probe = measure(s, s.solve(self.neutral_values, _ray(s, NEAR_FRACTION * far.proj, world),
                                   SIZE_ITERATIONS), d)
        lo = max(NEAR_FRACTION * far.proj, probe.proj, neutral.proj)
        ray = probe.cosine >= COS_FAR and lo <= (1.0 - SHORTEN) * far.proj
        arc_start = _honest_start(neutral.offset, far.offset, d)
        p0 = max(float(arc_start @ d), neutral.proj)
        found: list[LimbPose] = []
        for i in range(1, n):
            toward = self.neutral_values + (far.values - self.neutral_values) * i / n
            below = found[-1] if found else neutral
            arc_proj = p0 + (far.proj - p0) * i / n
            targets = [s.origin + s.body_rot @ arc_at(arc_start, far.offset, d, arc_proj)]
            if ray:
                first = neutral.proj + (far.proj - neutral.proj) / n
                near = max(lo, first)
                targets.insert(0, _ray(s, near + (far.proj - near) * (i - 1) / (n - 1), world))
            pose = self._first(below, far, targets, toward, d)
            if isinstance(pose, Beyond):
                return Beyond(f"size {self.sizes[i - 1]}: {pose.reason}", pose.pose)
            if isinstance(pose, str):
                return f"size {self.sizes[i - 1]}: {pose}"
            found.append(pose)
        return [*found, far]

    def _first(self, below: LimbPose, far: LimbPose, targets: list[np.ndarray], toward: np.ndarray,
               d: np.ndarray) -> LimbPose | str | Beyond:
        """The first target whose solve lands ahead of ``below`` and short of far, cleanly."""
        s = self.solver
        why: str | Beyond = "no target"
        for target in targets:
            pose = measure(s, s.solve(below.values, target, SIZE_ITERATIONS, SIZE_POSTURE,
                                      toward), d)
            hit = s.collides(s.full_q(pose.values))
            if pose.proj > far.proj and pose.cosine >= COS_FAR and hit is None:
                why = Beyond(f"reach {pose.proj:.3f} m beyond far {far.proj:.3f} m", pose)
            elif not below.proj < pose.proj < far.proj:
                why = (f"reach {pose.proj:.3f} m not between {below.proj:.3f} and "
                       f"{far.proj:.3f} m")
            elif hit is not None:
                why = hit
            else:
                return pose
        return why

    def nudged(self, chain: list[LimbPose], d: np.ndarray) -> list[LimbPose] | None:
        """The smaller sizes of a chain pulled toward d's ray (or the arc to far) at their
        projections, each held near its own posture: the same smoothness, better pointing.
        None when no size points better that way (or a nudged pose touches something)."""
        s, far = self.solver, chain[-1]
        world = s.body_rot @ d
        neutral = measure(s, self.neutral_values, d)
        arc_start = _honest_start(neutral.offset, far.offset, d)
        out: list[LimbPose] = []
        for pose in chain[:-1]:
            target = _ray(s, pose.proj, world) if pose.proj > 0 else (
                s.origin + s.body_rot @ arc_at(arc_start, far.offset, d, pose.proj))
            moved = measure(s, s.solve(pose.values, target, SIZE_ITERATIONS, NUDGE_POSTURE,
                                       pose.values), d)
            if s.collides(s.full_q(moved.values)) is not None:
                return None
            out.append(moved if moved.cosine > pose.cosine else pose)
        return [*out, far] if any(a is not b for a, b in zip(out, chain, strict=False)) else None

    # -- the segment chain ------------------------------------------------------------------
    def _segment_chain(self, far: LimbPose, d: np.ndarray, start: float, grid: list[LimbPose]
                       ) -> list[LimbPose] | str:
        s, n = self.solver, len(self.sizes)
        a, b = self.neutral_values, far.values
        neutral = measure(s, a, d)

        def at(t: float) -> LimbPose:
            return measure(s, a + t * (b - a), d)

        # near: a step of the even spacing from neutral, or where the tip first points
        # toward d with cosine ``start`` if that comes later (``grid``: the segment sampled)
        pointing = next((p.proj for p in grid if p.cosine >= start), far.proj)
        near = max(neutral.proj + (far.proj - neutral.proj) / n, pointing)
        chain: list[LimbPose] = []
        for i in range(n - 1):
            goal = near + (far.proj - near) * i / (n - 1)
            t = _first_reaching(lambda x: at(x).proj, goal, [p.proj for p in grid])
            if t is None:
                return (f"size {self.sizes[i]}: the straight way to far never reaches "
                        f"{goal:.3f} m")
            chain.append(at(t))
        return [*chain, far]


def _first_reaching(proj: Callable[[float], float], goal: float, sampled: list[float]
                    ) -> float | None:
    """The smallest t in [0, 1] where ``proj(t)`` reaches ``goal``: the first of the evenly
    spaced samples ``sampled`` (proj at SEGMENT_GRID + 1 points) that does, then bisection."""
    grid = np.linspace(0.0, 1.0, SEGMENT_GRID + 1)
    hit = next((float(t) for t, p in zip(grid, sampled, strict=True) if p >= goal), None)
    if hit is None:
        return None
    lo, hi = max(hit - 1.0 / SEGMENT_GRID, 0.0), hit
    for _ in range(30):
        mid = (lo + hi) / 2
        if proj(mid) < goal:
            lo = mid
        else:
            hi = mid
    return hi


def _ray(solver: LimbSolver, t: float, world: np.ndarray) -> np.ndarray:
    return np.asarray(solver.origin + t * world)


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
