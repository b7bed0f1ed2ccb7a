"""The Laban vocabulary: 27 points, their names, and their body-frame vectors."""

import itertools
import math
from collections.abc import Callable

import pytest

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction, Horizontal, Level
from kinesphere.sizes import parse_size


def test_27_points_are_9_horizontals_by_3_levels() -> None:
    assert len(Direction) == 27
    assert {(d.horizontal, d.level) for d in Direction} == set(itertools.product(Horizontal, Level))


def test_pull_vectors_are_unit_distinct_and_pair_into_antipodes() -> None:
    pulls = Direction.pulls()
    assert len(pulls) == 26 and Direction.PLACE_MIDDLE not in pulls
    vectors = [d.vector for d in pulls]
    for v in vectors:
        assert math.isclose(math.hypot(*v), 1.0, rel_tol=1e-12)
    assert len({tuple(round(c, 9) for c in v) for v in vectors}) == 26
    for d in pulls:
        a = d.antipode
        assert a is not d and a.antipode is d
        pairs = zip(d.vector, a.vector, strict=True)
        assert all(math.isclose(x, -y, abs_tol=1e-12) for x, y in pairs)
    assert Direction.PLACE_MIDDLE.vector == (0.0, 0.0, 0.0)


def test_vectors_follow_the_body_frame() -> None:
    assert Direction.FORWARD_MIDDLE.vector == (1.0, 0.0, 0.0)
    assert Direction.LEFT_MIDDLE.vector == (0.0, 1.0, 0.0)
    assert Direction.PLACE_HIGH.vector == (0.0, 0.0, 1.0)
    x, y, z = Direction.LEFT_HIGH.vector
    assert x == 0.0 and y > 0 and z > 0 and math.isclose(y, z)
    x, y, z = Direction.RIGHT_FORWARD_LOW.vector
    assert x > 0 and y < 0 and z < 0 and math.isclose(abs(x), abs(z))


def test_kinds_count_6_dimensional_12_planar_8_diagonal() -> None:
    kinds = [d.kind for d in Direction]
    assert kinds.count("dimensional") == 6
    assert kinds.count("planar") == 12
    assert kinds.count("diagonal") == 8
    assert kinds.count("place") == 1


def test_translations_are_the_8_middle_horizontals() -> None:
    t = Direction.translations()
    assert len(t) == 8
    assert all(d.level is Level.MIDDLE and d.vector[2] == 0.0 for d in t)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("Left-High", Direction.LEFT_HIGH),
        ("Forward-Middle", Direction.FORWARD_MIDDLE),
        ("Right-forward-Low", Direction.RIGHT_FORWARD_LOW),
        ("Place High", Direction.PLACE_HIGH),
        ("place_middle", Direction.PLACE_MIDDLE),
        ("LEFT FORWARD HIGH", Direction.LEFT_FORWARD_HIGH),
        ("forward-left-high", Direction.LEFT_FORWARD_HIGH),
        ("left", Direction.LEFT_MIDDLE),
        ("left-forward-high", Direction.LEFT_FORWARD_HIGH),
    ],
)
def test_parse_accepts_the_papers_spellings(text: str, expected: Direction) -> None:
    assert Direction.parse(text) is expected


def test_canonical_slugs_round_trip() -> None:
    for d in Direction:
        assert Direction.parse(d.slug) is d
        assert d.slug == d.slug.lower() and " " not in d.slug
    assert Direction.LEFT_FORWARD_HIGH.slug == "left-forward-high"
    assert Direction.PLACE_MIDDLE.slug == "place-middle"


@pytest.mark.parametrize("bad", ["up", "left-up", "", "forward-forward", 3])
def test_unknown_direction_lists_valid_names(bad: object) -> None:
    parse: Callable[..., Direction] = Direction.parse  # as an untyped caller calls it
    with pytest.raises(KinesphereError) as err:
        parse(bad)
    assert err.value.code == "unknown_direction"
    if isinstance(bad, str):
        assert "left-forward-high" in err.value.message


@pytest.mark.parametrize(("bad", "near"), [
    ("left-hihg", "left-high"), ("Rigth Forward Low", "right-forward-low"), ("frwd", None),
    ("left-high" * 20, None)])
def test_a_misspelt_direction_is_answered_with_the_nearest(bad: str, near: str | None) -> None:
    """Nearest by spelling, any case; none for garbage or a name far longer than any valid."""
    with pytest.raises(KinesphereError) as err:
        Direction.parse(bad)
    hint = f"(did you mean {near!r}?)"
    assert (hint in err.value.message) if near else ("did you mean" not in err.value.message)


@pytest.mark.parametrize(
    ("text", "value"), [("near", 1.0), ("mid", 2.0), ("far", 3.0), ("2.5", 2.5), (4, 4.0), (0, 0.0)]
)
def test_sizes_parse(text: object, value: float) -> None:
    assert parse_size(text) == value


@pytest.mark.parametrize("bad", ["nan", "-1", "abc", float("inf"), True, None, [3]])
def test_bad_sizes_are_named(bad: object) -> None:
    with pytest.raises(KinesphereError) as err:
        parse_size(bad)
    assert err.value.code == "size_out_of_range"
