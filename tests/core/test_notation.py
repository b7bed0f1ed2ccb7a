"""kinesphere's notation writes the cells LabanEditor writes: checked against LabanEditor's own
``labanProcessor.py`` (Microsoft's LabanotationSuite, vendored unchanged with its MIT licence
in ``tests/third_party/labanotationsuite``), its ``to_sphere`` and ``coordinate2laban`` run as the
oracle on many vectors and on every boundary of its sectors and levels.
"""

from __future__ import annotations

import itertools
from types import ModuleType

import numpy as np
import pytest

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.notation import HORIZONTALS, LEVELS, Cell, angle_to, cell_of, notate, spherical


def theirs(laban_editor: ModuleType, v: np.ndarray) -> Cell:
    _, theta, phi = laban_editor.to_sphere(v)
    horizontal, level = laban_editor.coordinate2laban(theta, phi)
    return Cell(horizontal, level)


def test_random_vectors_get_labaneditors_cells(laban_editor: ModuleType) -> None:
    rng = np.random.default_rng(7)
    vectors = np.concatenate([
        rng.normal(size=(20000, 3)),  # every direction
        rng.normal(size=(5000, 3)) * [1.0, 1.0, 0.01],  # near the horizontal plane
        rng.normal(size=(5000, 3)) * [0.01, 0.01, 1.0],  # near the vertical: the caps
        rng.integers(-3, 4, size=(3000, 3)).astype(float),  # on axes, diagonals and planes
    ])
    checked = 0
    for v in vectors:
        if v[1] == 0.0 and v[0] < 0.0 or not v.any():
            continue  # the documented difference (straight back) and the zero vector
        assert notate(v) == theirs(laban_editor, v), v
        checked += 1
    assert checked > 32000


def test_angles_are_labaneditors_to_the_bit(laban_editor: ModuleType) -> None:
    rng = np.random.default_rng(8)
    for v in rng.normal(size=(5000, 3)):
        _, theta, phi = laban_editor.to_sphere(v)
        assert spherical(v) == (theta, phi)


BOUNDARIES = [22.5, 67.5, 112.5, 157.5]


def test_every_sector_and_level_boundary_falls_as_in_labaneditor(laban_editor: ModuleType) -> None:
    eps = 1e-9
    phis = sorted({p for b in BOUNDARIES for s in (1, -1)
                   for p in (s * b, s * b + eps, s * b - eps)} | {0.0, 90.0, -90.0, 180.0})
    thetas = sorted({t for b in BOUNDARIES for t in (b, b + eps, b - eps)} | {0.0, 90.0, 180.0})
    for theta, phi in itertools.product(thetas, phis):
        horizontal, level = laban_editor.coordinate2laban(theta, phi)
        assert cell_of(theta, phi) == Cell(horizontal, level), (theta, phi)


def test_straight_back_is_backward_where_labaneditor_slips_a_quadrant(laban_editor: ModuleType
                                                                    ) -> None:
    v = np.array([-1.0, 0.0, 0.0])
    assert notate(v) == Cell("Backward", "Normal")
    assert theirs(laban_editor, v) == Cell("Forward", "Normal")  # atan(0 / -1) = 0: their slip
    w = np.array([-1.0, 1e-12, 0.0])
    assert notate(w) == theirs(laban_editor, w)


def test_every_cell_direction_is_written_as_its_own_cell(laban_editor: ModuleType) -> None:
    for horizontal, level in itertools.product(HORIZONTALS, LEVELS):
        cell = Cell(horizontal, level)
        v = cell.vector
        if v is None:
            assert (horizontal, level) == ("Place", "Normal")
            assert cell.direction is Direction.PLACE_MIDDLE and not cell.notatable
            continue
        assert theirs(laban_editor, np.array(v)) == cell
        assert angle_to(v, cell) == pytest.approx(0.0, abs=1e-6)
        # the kinesphere direction it is performed with lies in the same cell (straight back,
        # y == 0, is where LabanEditor slips: ours only, there)
        performed = np.array(cell.direction.vector)
        assert notate(performed) == cell
        if not (performed[1] == 0.0 and performed[0] < 0.0):
            assert theirs(laban_editor, performed) == cell
        assert cell.direction.horizontal is HORIZONTALS[horizontal]


def test_a_zero_vector_points_nowhere() -> None:
    assert notate([0.0, 0.0, 0.0]) is None
    assert angle_to([0.0, 0.0, 0.0], Cell("Forward", "High")) is None


@pytest.mark.parametrize(("horizontal", "level", "word"), [
    ("Forwards", "High", "direction"), ("Forward", "Middle", "level"), (3, "High", "direction"),
])
def test_unknown_words_are_named(horizontal: object, level: object, word: str) -> None:
    with pytest.raises(KinesphereError) as err:
        Cell.parse(horizontal, level, "kf 3 head")
    assert err.value.code == "malformed"
    assert err.value.message.startswith(f"kf 3 head: unknown {word}")
