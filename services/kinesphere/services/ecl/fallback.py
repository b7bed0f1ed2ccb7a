"""Honest fallbacks: a direction a limb lacks is served by the nearest one it has.

A fleet command reaches bodies with different vocabularies (NAO's head has no place-high, a
PackBot's arm no left-low). Rather than leave them silent, the ECL serves the nearest direction
the limb has by the one rule the gamepad client uses too
(:func:`kinesphere.substitution.nearest_direction`: never from the opposite side, smallest
angle, ties toward the front), within the same :data:`kinesphere.substitution.MAX_ANGLE_DEG`
(45 degrees), and says so in the answer. The label is not enough: the served poses must point
(their tips' measured bearing from the origin, at every stored size) within the same 45
degrees of the request, so a neighbour that points too far off is passed over for the next one
by the rule; the gamepad judges from the same tips, published in the catalogue.
A command that asks for the exact direction gets ``direction_unavailable`` instead.
"""

from __future__ import annotations

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.protocol import Substitution
from kinesphere.services.ecl.cells import Cell
from kinesphere.substitution import MAX_ANGLE_DEG, nearest_direction, pointing


def nearest_cell(limb: str, origin: str, cells: dict[str, Cell], slug: str, exact: bool
                 ) -> tuple[Cell, Substitution]:
    """The cell serving ``slug`` for a pair whose ``cells`` lack it, and the substitution to
    report; ``direction_unavailable`` when ``exact`` or nothing lies within the limit, by
    label or by where its stored poses point (:func:`kinesphere.substitution.pointing`)."""
    have = [d for d in Direction if d.slug in cells]
    valid = ", ".join(d.slug for d in have)
    if exact:
        raise KinesphereError(
            "direction_unavailable", f"({limb}, {origin}) has no direction {slug} and the "
            f"command asked for it exactly; it has: {valid}",
        )
    requested = Direction.parse(slug)
    tips = {d: [t for t in cells[d.slug].tips[1:] if t is not None] for d in have}
    choice = nearest_direction(requested, have, MAX_ANGLE_DEG, pointing([tips], requested))
    if choice is None:
        raise KinesphereError(
            "direction_unavailable", f"({limb}, {origin}) has no direction {slug} nor one "
            f"within {MAX_ANGLE_DEG:g} degrees on the same side whose poses point within "
            f"{MAX_ANGLE_DEG:g} degrees of it; it has: {valid}",
        )
    served = choice.direction.slug
    sub = Substitution(limb=limb, origin=origin, requested=slug, served=served,
                       angle=round(choice.angle, 3))
    return cells[served], sub
