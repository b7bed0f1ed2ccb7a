"""Many Ruckig trajectories followed at once, on arrays: a fleet host's joints and bases.

Why: once Ruckig has computed a trajectory, following it is only evaluating its profile. Per
DoF that is at most two brake phases, seven phases of constant jerk and the hold after the end,
each a cubic in time. Done per robot through the binding (``update``, ``pass_to_input`` and
three list conversions) a step costs ~5 us, a third of a body's ``mj_step``; for every robot of
a fleet host at once it is a couple of dozen numpy operations per tick.

Ruckig still computes every trajectory: the step on which a target, a brake or a limit changes
goes through ``update`` as before, and its output is Ruckig's own (``otg.py``). The profile it
computed is then copied here, and the following steps evaluate it with Ruckig's formulas in
Ruckig's order of operations (``Trajectory::at_time`` and ``integrate`` in its headers,
``Ruckig::update``'s clock and its ``Finished``), so they give the numbers its ``update`` would
have given, bit for bit (``tests/robots/test_agent_batch.py`` compares them).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from ruckig import Trajectory

    from kinesphere.robots.agent.otg import Otg

SEGMENTS = 10
"""Per DoF: two brake phases, the profile's seven, and the hold after its end."""
_HOLD = SEGMENTS - 1


class _Rows(NamedTuple):
    """The followed rows' share of the arrays, as :meth:`Followers.advance` reads them."""

    owner: np.ndarray
    duration: np.ndarray
    """Each row's generator's trajectory duration."""
    brake: np.ndarray
    brake_t0: np.ndarray
    t_sum: np.ndarray
    """Per phase end (0 first), the rows: columns, so that a step compares whole rows."""
    ends: np.ndarray
    """``t_sum[1:]``, contiguous: what a step's time is compared with."""
    passed: np.ndarray
    """Room for that comparison (booleans, one per phase end and row)."""
    picked: np.ndarray
    """Room for the five coefficient vectors a step picks."""
    end: np.ndarray
    coef: np.ndarray
    """p0, v0, a0, a0 / 2, jerk, each over every row and segment (flattened): one gather
    makes five contiguous vectors."""
    first: np.ndarray
    """Index in ``coef`` of each row's first profile phase."""
    order: np.ndarray
    """0, 1, 2, ...: each row's place among the followed ones."""
    braking: bool
    """Whether any row has brake phases."""


class Followers:
    """The generators ``otgs`` (fixed for the lifetime of this object), each followed here
    between the steps on which Ruckig plans (:meth:`load`, :meth:`drop`, :meth:`advance`).

    Every generator's ``position``, ``velocity`` and ``acceleration`` become views of this
    object's arrays, so one assignment per array updates all of them.
    """

    def __init__(self, otgs: Sequence[Otg], dt: float) -> None:
        self.dt = dt
        self._otgs = list(otgs)
        sizes = [otg.n for otg in self._otgs]
        rows = sum(sizes)
        self._start = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.intp) \
            if sizes else np.zeros(0, dtype=np.intp)
        self._owner = np.repeat(np.arange(len(sizes), dtype=np.intp), sizes)
        self.position, self.velocity, self.acceleration = (np.zeros(rows) for _ in range(3))
        self._brake_t0 = np.zeros(rows)
        self._brake = np.zeros(rows)
        """Duration of each DoF's brake phases (0: none)."""
        self._t_sum = np.zeros((rows, 8))
        """0, then the ends of the seven phases (Ruckig's ``t_sum``)."""
        self._end = np.zeros(rows)
        """``brake + t_sum[-1]``: where the hold after the end starts (``at_time``'s ``t_pre``)."""
        self._coef = np.zeros((rows, SEGMENTS, 4))
        """Per DoF and segment: position, velocity, acceleration at its start and its jerk."""
        self._clock = np.zeros(rows)
        """Per row: its generator's time along its trajectory (Ruckig's ``output.time``), the
        same in every row of a generator (each adds the same ``dt``): stepped in place."""
        self._duration = np.zeros(len(sizes))
        self._following = np.zeros(len(sizes), dtype=bool)
        self._slots = np.zeros(0, dtype=np.intp)
        self._rows: slice | np.ndarray = slice(0, 0)
        self._cache: _Rows | None = None
        """What :meth:`advance` reads of the followed rows, gathered once per change."""
        self._dirty = False
        for slot, (otg, start, n) in enumerate(zip(self._otgs, self._start, sizes, strict=True)):
            otg.attach(self, slot, slice(int(start), int(start) + n))

    @property
    def following(self) -> int:
        """Generators followed here now."""
        return int(self._following.sum())

    def load(self, slot: int, trajectory: Trajectory, time: float) -> None:
        """Follow ``trajectory`` (Ruckig's, just computed, its output at ``time`` already
        handed out) for generator ``slot`` from the next :meth:`advance` on."""
        start = int(self._start[slot])
        profiles = trajectory.profiles[0]  # one section: kinesphere sets no waypoints
        brake_t0, brake, t_sum, end, coef = ([] for _ in range(5))
        for profile in profiles:
            b = profile.brake
            bt = b.t
            brake_t0.append(bt[0])
            brake.append(b.duration)
            sums = [0.0]
            total = 0.0
            for i, ti in enumerate(profile.t):  # Ruckig's t_sum: t_sum[i+1] = t_sum[i] + t[i+1]
                total = ti if i == 0 else total + ti
                sums.append(total)
            t_sum.append(sums)
            end.append(b.duration + total)
            coef.append(list(zip([*b.p, *profile.p], [*b.v, *profile.v], [*b.a, *profile.a],
                                 [*b.j, *profile.j, 0.0], strict=True)))
        rows = slice(start, start + len(profiles))
        self._brake_t0[rows] = brake_t0
        self._brake[rows] = brake
        self._t_sum[rows] = t_sum
        self._end[rows] = end
        self._coef[rows] = coef
        self._clock[rows] = time
        self._duration[slot] = trajectory.duration
        self._following[slot] = True
        self._dirty = True

    def left(self, slot: int) -> float:
        """Seconds the trajectory of generator ``slot`` still takes (``Otg.remaining``)."""
        return max(0.0, float(self._duration[slot] - self._clock[self._start[slot]]))

    def drop(self, slot: int) -> None:
        """Generator ``slot`` is no longer followed here (it plans again, or rests)."""
        if self._following[slot]:
            self._following[slot] = False
            self._dirty = True

    def advance(self) -> None:
        """One step along every followed trajectory; a generator whose trajectory ended
        comes to rest as Ruckig's ``Finished`` would have it (``Otg.arrived``)."""
        if self._dirty:
            self._gather()
        slots = self._slots
        if not slots.size:
            return
        assert self._cache is not None
        (owner, duration, brake, brake_t0, t_sum, ends, passed, picked, end, coef, first, order,
         braking) = self._cache
        rows = self._rows
        clock = self._clock
        clock[rows] += self.dt
        t = clock[rows]  # a view when the rows are contiguous
        shifted = t - brake  # at_time's ``t_diff_dof -= p.brake.duration`` (t itself when 0)
        np.less_equal(ends, shifted, out=passed)  # upper_bound over each row's t_sum:
        phase = passed.view(np.uint8).sum(axis=0, dtype=np.uint8)  # phase ends passed
        tau = shifted - t_sum[phase, order]
        segment = phase + first
        if braking:  # the brake phases before the profile (after a retarget mid-motion)
            in_brake = t < brake
            second = t >= brake_t0
            segment = np.where(in_brake, second.astype(np.intp) + first - 2, segment)
            tau = np.where(in_brake, t - brake_t0 * second, tau)
        after = t >= duration
        over = after.any()
        if over:  # Ruckig's ``time >= duration`` branch
            segment = np.where(after, first + _HOLD - 2, segment)
            tau = np.where(after, t - end, tau)
        p0, v0, a0, half, jerk = np.take(coef, segment, axis=1, out=picked)
        tj = tau * jerk
        if isinstance(rows, slice):  # written in place
            np.add(p0, tau * (v0 + tau * (half + tj / 6)), out=self.position[rows])
            np.add(v0, tau * (a0 + tj / 2), out=self.velocity[rows])
            np.add(a0, tj, out=self.acceleration[rows])
        else:
            self.position[rows] = p0 + tau * (v0 + tau * (half + tj / 6))
            self.velocity[rows] = v0 + tau * (a0 + tj / 2)
            self.acceleration[rows] = a0 + tj
        if over:
            for slot in np.unique(owner[t > duration]).tolist():
                self._otgs[slot].arrived()

    def _gather(self) -> None:
        """The followed generators, their rows and what :meth:`advance` reads of them."""
        self._dirty = False
        self._slots = np.flatnonzero(self._following)
        rows = np.flatnonzero(self._following[self._owner])
        contiguous = rows.size and rows[-1] - rows[0] + 1 == rows.size
        self._rows = slice(int(rows[0]), int(rows[-1]) + 1) if contiguous else rows
        owner = self._owner[rows]
        coef = self._coef[rows]
        index = np.arange(rows.size, dtype=np.intp)
        t_sum = np.ascontiguousarray(self._t_sum[rows].T)
        self._cache = _Rows(
            owner, self._duration[owner], self._brake[rows], self._brake_t0[rows], t_sum,
            np.ascontiguousarray(t_sum[1:]), np.zeros((t_sum.shape[0] - 1, rows.size), bool),
            np.zeros((5, rows.size)), self._end[rows],
            # a0 / 2 (exact in binary) beside a0: one division less per step
            np.ascontiguousarray(np.concatenate(
                (coef[:, :, :3], coef[:, :, 2:3] / 2, coef[:, :, 3:]), axis=2).reshape(-1, 5).T),
            index * SEGMENTS + 2, index, bool((self._brake[rows] > 0).any()))
