"""The generator's distance limit makes, for every pair within reach, the row mink's own
``compute_contact_normal_jacobian`` makes (bit for bit), and the bound mink's
CollisionAvoidanceLimit's rule gives, though it builds all rows at once.

The reference is mink's function called pair by pair, as the limit did before it gathered
the work; the bodies are the shipped platforms' own MuJoCo models, at seeded random poses of a
limb within its limits (some pressing into the body, so both signs of a row are met).
"""

from __future__ import annotations

import mink
import mujoco
import numpy as np
import pytest
from mink.limits.collision_avoidance_limit import compute_contact_normal_jacobian

from kinesphere.platforms.mjcf import platform_model
from kinesphere.services.ecl.constraints import DETECT, LIMIT_GAIN, PairDistanceLimit
from kinesphere.services.ecl.ik import LimbSolver

POSES = 40
DT = 0.1


def reference(limit: PairDistanceLimit, data: mujoco.MjData, dt: float) -> tuple[
        np.ndarray, np.ndarray, int]:
    """Rows and bounds pair by pair with mink's helper; how many pairs were inside."""
    model = limit.model
    fromto, normal = np.zeros(6), np.zeros(3)
    jac1, jac2 = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    rows, bounds, inside = [], [], 0
    for idx, (a, b) in enumerate(limit.pairs.tolist()):
        gap = np.linalg.norm(data.geom_xpos[a] - data.geom_xpos[b]) - limit._rsum[idx]
        if gap > DETECT:
            continue
        dist = mujoco.mj_geomDistance(model, data, a, b, DETECT, fromto)
        if dist >= DETECT - 1e-12:
            continue
        row = compute_contact_normal_jacobian(model, data, a, b, fromto, normal, jac1, jac2)
        rows.append((-1.0 if dist >= 0 else 1.0) * row)
        bounds.append(max(dist - limit._clearance[idx], 0.0) * LIMIT_GAIN / dt)
        inside += dist < 0
    return np.array(rows).reshape(-1, model.nv), np.array(bounds), inside


@pytest.mark.parametrize(("platform", "limb", "origin"), [
    ("baxter", "limb_11", "distal_11"), ("nao", "limb_11", "distal_11"),
    ("packbot", "limb_11", "distal_11"),
])
def test_rows_are_minks_own_for_every_pair_within_reach(platform: str, limb: str,
                                                        origin: str) -> None:
    solver = LimbSolver(platform_model(platform), limb, origin)
    limit = next(lim for lim in solver.limits if isinstance(lim, PairDistanceLimit))
    rng = np.random.default_rng(7)
    config = mink.Configuration(solver.model, solver.neutral.copy())
    rows = inside = 0
    for _ in range(POSES):
        q = solver.neutral.copy()
        q[solver.qadr] = rng.uniform(solver.lower, solver.upper)
        config.update(q)
        got = limit.compute_qp_inequalities(config, DT)
        want_g, want_h, pressed = reference(limit, config.data, DT)
        if len(want_h) == 0:
            assert got.G is None and got.h is None
            continue
        assert got.G is not None and got.h is not None
        assert np.array_equal(got.G, want_g) and np.array_equal(got.h, want_h)
        rows += len(want_h)
        inside += pressed
    assert rows > POSES and inside > 0, (rows, inside)  # not vacuous: both signs met
