"""The sizes of one pull: near, mid and far, by one of two rules a person would recognise.

A pull's far pose is found first (``generate``: the farthest the tip gets along d with its
bearing held); the smaller sizes are what this module adds, by the limb's **size rule**:

* **reach** (a limb whose extension can change: an arm or a leg with a bending joint):
  each size is the tip on d's ray at an increasing fraction of far's distance from the
  origin, NEAR_FRACTION for near (the elbow bent, the hand close to the body) up to 1 for far,
  the bearing held (cosine >= HONEST) at every size. Each size is an IK solve from the size
  above it, held near that posture, so the limb folds back along the ray the way it came: no
  flips between sizes. A limb that cannot fold that far gets the closest it can (NAO's arm:
  its elbow bends 88 degrees) and the sizes between are spread evenly again.
* **swing** (a limb whose extension cannot change: a head, a wrist, a one-joint segment):
  the size scales the angle of the pull, each size turning the bearing an even share of the
  way from neutral toward far (slerp), so near is a glance and far looks all the way.

A direction the neutral pose already points at (cosine >= HONEST with the neutral bearing) is
answered by neutral at near and by extending along it at the larger sizes; a limb that is
already fully extended that way (NAO's straight leg, place-low) holds neutral at every size.

A chain is *honest* when the tip's distance from the origin grows with the size (reach) or its
bearing turns toward d with the size (swing), every size of a reach chain points within HONEST
of d, no pose touches anything, every size is reachable from neutral without touching anything
(the agent's planner, waypoints allowed), no joint turns back more than DETOUR_SLACK on its way
from near through the sizes to far, and none moves between two successive sizes more than
STEP_SLACK beyond its even share of its way from near to far (no wrist flips between sizes).
Whether each size *stands* (static balance) is decided by the caller: stability removes sizes
from the top, not directions. Deterministic: no randomness, fixed iteration caps, values
rounded.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinesphere.platforms.clearance import Clearance, Touch
from kinesphere.services.ecl.arcs import cosine, swing
from kinesphere.services.ecl.ik import LimbSolver
from kinesphere.services.ecl.measure import HONEST

COS_FAR = HONEST  # the far pose (and every size of a reach chain) points within ~32 degrees
REACH = "reach"
SWING = "swing"
BENDS = 0.85  # a limb whose tip can come this close (fraction of its farthest) can reach
NEAR_FRACTION = 0.5  # a reach chain's near: half of far's distance from the origin
CLOSER_TRIES = 4  # a near the limb cannot fold to is retried this many times, each further out
CLOSER_STEP = 0.05  # ... by this fraction of far's distance
MIN_SPREAD = 0.02  # near must fold the tip at least this fraction of far's distance closer
MIN_GAP = 0.25  # consecutive sizes differ by at least 25% of their even spacing near..far
HELD = 0.02  # a pull along which the limb extends less than this (of its span) holds neutral
DETOUR_SLACK = 1.5  # rad a joint may turn back, in all, from near through the sizes to far
STEP_SLACK = 0.75  # rad a joint may move between two sizes beyond its even share
SIZE_POSTURE = 0.1  # posture weight per radian toward the size above (reach) or the way (swing)
NEAR_POSTURE = 0.02  # ... and toward the family's posture while folding to near: fold fully
SIZE_ITERATIONS = 80
ROUND_DIGITS = 6


def short_of(value: float, bound: float) -> str:
    """``value < bound`` with enough digits to show it (0.8497 is not "0.85 < 0.85")."""
    digits = 2
    while round(value, digits) >= bound and digits < 8:
        digits += 1
    return f"{value:.{digits}f} < {bound}"


@dataclass(frozen=True)
class Chain:
    """An honest pull: its poses near..far and the size rule they follow."""

    poses: list[LimbPose]
    rule: str


@dataclass(frozen=True)
class LimbPose:
    """A limb pose and where it puts the tip: offset from the origin (body frame), its
    projection on d, its distance from the origin and its cosine with d."""

    values: np.ndarray  # the solver's joints, rounded
    offset: np.ndarray
    proj: float
    cosine: float

    @property
    def distance(self) -> float:
        return float(np.linalg.norm(self.offset))


def rounded(x: float) -> float:
    return round(float(x), ROUND_DIGITS) + 0.0  # + 0.0 turns -0.0 into 0.0


def measure(solver: LimbSolver, values: np.ndarray, d: np.ndarray) -> LimbPose:
    """Round and clip joint values and see where they put the tip."""
    values = np.array([rounded(v) for v in np.clip(values, solver.lower, solver.upper)])
    offset = solver.reach(solver.full_q(values)).offset
    proj = float(offset @ d)
    return LimbPose(values, offset, proj, cosine(offset, d))


def joint_detour(chain: list[np.ndarray]) -> float:
    """Radians the worst joint travels along a chain (near, ..., far) beyond its straight way
    from the first pose to the last: 0 when every joint moves one way only."""
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


def size_rule(solver: LimbSolver) -> str:
    """REACH when a joint past the origin's own moves the tip closer to the origin than
    BENDS of its farthest (an elbow, a knee, PackBot's elbows), else SWING (a head, a wrist
    whose axes all meet at the origin, a one-joint segment): each such joint is swept through
    its range with the rest at neutral."""
    own = set(solver.pm.platform.eurdf.origin(solver.origin_label).joints)
    neutral = solver.neutral[solver.qadr]
    distances = [float(np.linalg.norm(solver.neutral_reach().offset))]
    for i, joint in enumerate(solver.joints[: solver.limb_count]):
        if joint in own or not solver.moving[i]:
            continue
        for v in np.linspace(solver.lower[i], solver.upper[i], 17):
            values = neutral.copy()
            values[i] = v
            distances.append(float(np.linalg.norm(solver.reach(solver.full_q(values)).offset)))
    return REACH if min(distances) < BENDS * max(distances) else SWING


class Sizes:
    """Size chains of one (limb, origin) pair; ``sizes`` are the VSAM's (near ... far)."""

    def __init__(self, solver: LimbSolver, sizes: tuple[int, ...], rule: str) -> None:
        self.solver = solver
        self.sizes = sizes
        self.rule = rule
        self.neutral_values = solver.neutral[solver.qadr]
        self.clearance = Clearance(solver.pm)
        names = solver.pm.platform.joint_names
        self._in_p = np.array([names.index(j) for j in solver.joints], dtype=int)

    def neutral(self, d: np.ndarray) -> LimbPose:
        return measure(self.solver, self.neutral_values, d)

    def chain(self, far: LimbPose, d: np.ndarray, at_rest: bool) -> Chain | str:
        """The honest poses near..far (see :meth:`check`) and the rule they follow, or why
        there are none; ``at_rest``: d is a direction the neutral pose already points at,
        answered by neutral at near. A reach chain is tried in three families, near folded
        from neutral's posture, from far's and from half-way between, the first honest one
        kept; a leg (a limb with a stance) that cannot fold along d swings instead, the way a
        dancer's leg gestures (an arm then has no such size: the direction is dropped)."""
        neutral = self.neutral(d)
        if at_rest and far.distance - neutral.distance < HELD * self.solver.span:
            if self.rule == REACH or far.cosine - neutral.cosine < 1e-3:
                return Chain([neutral] * len(self.sizes), self.rule)  # fully extended: hold
        if self.rule != REACH:
            return self._swung(far, d, neutral, at_rest)
        rest = neutral if at_rest and neutral.distance < far.distance else None
        why = ""
        for start in (self.neutral_values, far.values, (far.values + self.neutral_values) / 2):
            found = self._reach(far, d, rest, start)
            if isinstance(found, str):
                why = found
            else:
                why = self.check(found, d, at_rest, REACH) or ""
                if not why:
                    return Chain(found, REACH)
            if rest is not None:
                break  # near is neutral: the families differ only in near
        if self.solver.stance:
            swung = self._swung(far, d, neutral, at_rest)
            return swung if isinstance(swung, Chain) else why
        return why

    def _swung(self, far: LimbPose, d: np.ndarray, neutral: LimbPose, at_rest: bool) -> Chain | str:
        chain = self._swing(far, d, neutral, at_rest)
        return self.check(chain, d, at_rest, SWING) or Chain(chain, SWING)

    # -- reach: the tip on the ray at growing fractions of far's distance --------------------
    def _reach(self, far: LimbPose, d: np.ndarray, rest: LimbPose | None, start: np.ndarray
               ) -> list[LimbPose] | str:
        """Near first (the tip NEAR_FRACTION of far's distance out on the ray, or as close as
        the limb folds, solved from ``start`` and held near it; neutral when it already points
        at d), then the sizes between at evenly spaced distances, each folded back from the
        size above."""
        n = len(self.sizes)
        if n == 1:
            return [far]
        world = self.solver.body_rot @ d
        spread = MIN_SPREAD * far.distance
        held = measure(self.solver, start, d)
        near = rest if rest is not None else self._land(
            start, held, far, d, world, NEAR_FRACTION, far.distance - spread, CLOSER_TRIES,
            NEAR_POSTURE)
        if near is None:
            return (f"size {self.sizes[0]}: the limb does not fold along it (no clean pose on "
                    f"the ray within {1 - MIN_SPREAD:.0%} of far's {far.distance:.3f} m "
                    f"pointing within {COS_FAR})")
        chain = [far]
        for i in range(n - 2, 0, -1):  # the sizes between, from the top down
            aim = near.distance + (far.distance - near.distance) * i / (n - 1)
            above = chain[-1]
            slack = MIN_GAP * (far.distance - near.distance) / (n - 1)
            pose = self._middle(near, above, far, d, world, aim, slack)
            if pose is None:
                return (f"size {self.sizes[i]}: no clean pose on the ray {aim:.3f} m out "
                        f"pointing within {COS_FAR} without a flip")
            chain.append(pose)
        return [near, *chain[::-1]]

    def _middle(self, near: LimbPose, above: LimbPose, far: LimbPose, d: np.ndarray,
                world: np.ndarray, aim: float, slack: float) -> LimbPose | None:
        """A size between near and the one above it, ``aim`` metres out: the first candidate
        at least ``slack`` from both without a flip, of the pose folded back from above
        onto the ray, half-way between the two in joint space, and that half-way posture
        moved onto the ray."""
        def fits(p: LimbPose | None) -> bool:
            return (p is not None
                    and near.distance + slack <= p.distance <= above.distance - slack
                    and joint_jump([near.values, p.values, above.values]) <= STEP_SLACK)

        folded = self._fold(above, far, d, world, aim / far.distance, above.distance - slack, 1)
        if fits(folded):
            return folded
        between = self._between(near, above, d)
        if fits(between):
            return between
        halfway = measure(self.solver, (near.values + above.values) / 2, d)
        moved = self._land(halfway.values, halfway, far, d, world, aim / far.distance,
                           above.distance - slack, 1)
        return moved if fits(moved) else None

    def _between(self, near: LimbPose, above: LimbPose, d: np.ndarray) -> LimbPose | None:
        """Half-way between near and the size above in joint space, when it points within
        COS_FAR and touches nothing (a limb that folds only a little along d: the IK cannot
        land between two poses that close, the straight way can)."""
        s = self.solver
        pose = measure(s, (near.values + above.values) / 2, d)
        clean = pose.cosine >= COS_FAR and s.collides(s.full_q(pose.values)) is None
        return pose if clean and near.distance < pose.distance < above.distance else None

    def _fold(self, above: LimbPose, far: LimbPose, d: np.ndarray, world: np.ndarray,
              fraction: float, at_most: float, tries: int) -> LimbPose | None:
        """A clean pose with the tip on the ray ``fraction`` of far's distance out (further
        out on each retry when the limb cannot fold that far) pointing within COS_FAR, no
        farther than ``at_most``: solved from the size above, held near its posture, and,
        since a stretched limb is singular along its own length, from half-way back to
        neutral and from neutral (its bent posture) when that fails."""
        for start in (above.values, (above.values + self.neutral_values) / 2,
                      self.neutral_values):
            pose = self._land(start, above, far, d, world, fraction, at_most, tries)
            if pose is not None:
                return pose
        return None

    def _land(self, start: np.ndarray, above: LimbPose, far: LimbPose, d: np.ndarray,
              world: np.ndarray, fraction: float, at_most: float, tries: int,
              posture: float = SIZE_POSTURE) -> LimbPose | None:
        s = self.solver
        for _ in range(tries):
            aim = fraction * far.distance
            pose = measure(s, s.solve(start, s.origin + aim * world, SIZE_ITERATIONS,
                                      posture, above.values), d)
            clean = pose.cosine >= COS_FAR and s.collides(s.full_q(pose.values)) is None
            if clean and pose.distance <= at_most:
                return pose
            fraction = max(fraction, pose.distance / far.distance) + CLOSER_STEP
            if fraction * far.distance > at_most:
                return None
        return None

    # -- swing: the bearing turns an even share of the way toward far per size ---------------
    def _swing(self, far: LimbPose, d: np.ndarray, neutral: LimbPose, at_rest: bool
               ) -> list[LimbPose]:
        s = self.solver
        a, b = self.neutral_values, far.values
        chain: list[LimbPose] = [neutral] if at_rest else []
        below = neutral
        for size in self.sizes[len(chain):-1]:
            g, offset = swing(neutral.offset, far.offset, size, self.sizes, at_rest)
            goal = s.origin + s.body_rot @ offset
            toward = a + (b - a) * g
            pose = measure(s, s.solve(below.values, goal, SIZE_ITERATIONS, SIZE_POSTURE, toward),
                           d)
            if s.collides(s.full_q(pose.values)) is not None:
                pose = measure(s, toward, d)  # the straight way itself
            chain.append(pose)
            below = pose
        return [*chain, far]

    # -- checks ------------------------------------------------------------------------------
    def check(self, chain: list[LimbPose], d: np.ndarray, at_rest: bool, rule: str
              ) -> str | None:
        """Why a chain (near..far) is not honest, or None; see the module. A chain from rest
        (near is neutral) need only not shrink: the limb may barely extend further that way."""
        s = self.solver
        far = chain[-1]
        if all(p is chain[0] for p in chain):
            return None  # neutral held at every size
        if rule == REACH:
            gap = -1e-3 if at_rest else (
                MIN_GAP * (far.distance - chain[0].distance) / max(len(chain) - 1, 1))
            for size, pose, below in zip(self.sizes[1:], chain[1:], chain, strict=False):
                if pose.distance < below.distance + gap:
                    return (f"size {size}: tip {pose.distance:.3f} m from the origin, not "
                            f"{gap:.3f} m beyond the size below ({below.distance:.3f} m)")
            for size, pose in zip(self.sizes, chain, strict=True):
                if pose.cosine < COS_FAR:
                    return f"size {size}: cosine {short_of(pose.cosine, COS_FAR)}"
        else:
            neutral = self.neutral(d)
            for size, pose, below in zip(self.sizes, chain, [neutral, *chain], strict=False):
                if pose is not below and pose.cosine <= below.cosine - (1e-3 if at_rest else 0):
                    return (f"size {size}: bearing does not turn toward d (cosine "
                            f"{pose.cosine:.2f} after {below.cosine:.2f})")
        for size, pose in zip(self.sizes, chain, strict=True):
            why = s.collides(s.full_q(pose.values))
            if why is not None:
                return f"size {size}: {why}"
        detour = joint_detour([p.values for p in chain])
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
        for size, pose in zip(self.sizes, chain, strict=False):
            goal = start.copy()
            goal[self._in_p] = pose.values
            route = self.clearance.route(start, goal)
            if isinstance(route, Touch):
                return f"size {size}: no collision-free way from neutral ({route})"
        return None

    def path(self, chain: list[LimbPose]) -> str | None:
        """What f_SB's straight interpolation neutral -> near -> ... -> far touches, or None."""
        values = [self.neutral_values, *(p.values for p in chain)]
        for i, size in enumerate(self.sizes[: len(chain)]):
            why = self.solver.path_touches(values[i], values[i + 1])
            if why is not None:
                below = f"size {self.sizes[i - 1]}" if i else "neutral"
                return f"path from {below} to size {size}: {why}"
        return None
