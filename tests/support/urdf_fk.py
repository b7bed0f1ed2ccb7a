"""yourdfpy's forward kinematics at exactly the joint values asked for.

yourdfpy's ``update_cfg`` writes each joint's new matrix into trimesh's scene graph, and
trimesh keeps the old matrix when the new one is within 1e-8 of it
(``EnforcedForest.add_edge``): a joint a few nanoradians from its last value (or from 0, on a
fresh load) keeps the last value, an error of that size in every link below it, and a
comparison at 1e-9 fails by chance. Going through values 1 away first changes every edge, so
the values asked for are written.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import yourdfpy


def set_cfg(urdf: yourdfpy.URDF, cfg: Mapping[str, float] | np.ndarray) -> None:
    """``urdf.update_cfg(cfg)``, every joint's matrix written (``cfg``: by name, or one value
    per actuated joint)."""
    if isinstance(cfg, Mapping):
        urdf.update_cfg({name: float(v) + 1.0 for name, v in cfg.items()})
        urdf.update_cfg(dict(cfg))
    else:
        values = np.asarray(cfg, dtype=float)
        urdf.update_cfg(values + 1.0)
        urdf.update_cfg(values)
