"""Per-robot counters in arrays: robot time (steps taken) and when each robot last moved.

Why arrays: on a fleet host most robots glide most of the time (``fleet.py``), and after the
physics each of them would count a step of robot time and note that it moved: two Python calls
and a few attribute writes per robot and tick. Kept here, one array operation does it for all
of them. A lone agent has a ledger of its own, of one row.
"""

from __future__ import annotations

import numpy as np


class Ledger:
    """``steps``: control steps each robot has taken (its robot time is ``steps * dt``);
    ``moved``: the step count when its joints or base last moved; ``moved_wall``: the host's
    monotonic clock then (s). One row per robot (its ``slot``)."""

    def __init__(self, robots: int, dt: float) -> None:
        self.dt = dt
        self.steps = np.zeros(robots, dtype=np.int64)
        self.moved = np.zeros(robots, dtype=np.int64)
        self.moved_wall = np.zeros(robots)

    def glided(self, rows: np.ndarray, wall: float) -> None:
        """The robots of ``rows`` (a boolean mask) took a step and moved in it (a glide:
        ``fleet.py``), at ``wall``."""
        steps = self.steps
        steps += rows
        np.copyto(self.moved, steps, where=rows)
        np.copyto(self.moved_wall, wall, where=rows)
