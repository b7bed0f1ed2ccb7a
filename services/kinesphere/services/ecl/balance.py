"""Static balance: a pose keeps the whole-body centre of mass over what still bears weight.

The paper leaves out the directions that would topple NAO. A pose is *statically stable* when
the ground projection of the whole body's centre of mass lies inside the support polygon (the
convex hull of every robot point within TOUCH of the floor: both soles, the stance sole when a
foot is lifted, a track, a pedestal) at least MARGIN inside its edge. The check is the same
for every mobile platform; on wheels or tracks it rarely bites, on one foot it decides. A fixed
base (``[base] kind = "fixed"``: Baxter's pedestal, an arm bolted to a table) is anchored and
cannot topple, so it is never checked: a Panda reaching forward is no fall. A legged base
(``kind = "legged"``, a brought walker) abstracts walking: the gait that moves the base also
shifts the body over the feet still down when one leg gestures, so its support is what touches
the floor in the pose together with its stance at neutral (a quadruped giving a paw, not a
quadruped toppling because one foot is up); reaching past that stance still topples.
"""

from __future__ import annotations

import numpy as np

from kinesphere.platforms.mjcf import PlatformModel
from kinesphere.services.ecl.measure import TOUCH, Fk, hull, inside

__all__ = ["MARGIN", "TOUCH", "Balance", "hull", "inside"]

MARGIN = 0.01  # metres the centre of mass keeps inside the support polygon's edge


class Balance:
    """Stability checks on one platform's model (its own MjData, so callers' data is untouched);
    the measurement itself is :meth:`kinesphere.services.ecl.measure.Fk.margin`."""

    def __init__(self, pm: PlatformModel) -> None:
        self.fk = Fk(pm)
        self.model = pm.model
        self.anchored = self.fk.anchored

    def margin(self, qpos: np.ndarray) -> tuple[float, tuple[str, ...]]:
        """Metres from the centre of mass to the support polygon's edge (negative: outside),
        and the bodies bearing weight."""
        return self.fk.margin(qpos)

    def check(self, qpos: np.ndarray) -> str | None:
        """Why a pose would topple (centre of mass too near or past the edge), or None; always
        None on an anchored (fixed) base."""
        if self.anchored:
            return None
        margin, names = self.margin(qpos)
        if margin >= MARGIN:
            return None
        where = ", ".join(names) or "nothing"
        if margin < 0:
            return f"unstable: centre of mass {-margin * 100:.1f} cm outside the support of {where}"
        return (f"unstable: centre of mass only {margin * 100:.1f} cm inside the support of "
                f"{where} (needs {MARGIN * 100:.0f} cm)")
