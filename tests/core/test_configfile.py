"""Typed config files: msgspec schemas, and errors that name the file, the field and what is
valid. The shipped platform files are the data; each case edits one line of a copy."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Annotated, Literal

import msgspec
import pytest

from kinesphere.configfile import convert, load_toml, read_toml
from kinesphere.errors import KinesphereError
from kinesphere.platforms.platform import PLATFORMS_DIR, load_platform, platform_names


class Leaf(msgspec.Struct, forbid_unknown_fields=True):
    colour: Literal["red", "green"]
    count: Annotated[int, msgspec.Meta(ge=1, le=9)] = 1


class Tree(msgspec.Struct, forbid_unknown_fields=True):
    leaves: dict[str, list[Leaf]]
    height: Annotated[
        float, msgspec.Meta(gt=0, description="a positive height", extra={"code": "conflict"})
    ] = 1.0


@pytest.mark.parametrize(
    ("data", "code", "message"),
    [
        ({"leaves": {"oak": [{"colour": "blue"}]}}, "malformed",
         "tree.toml: leaves.oak[1].colour: 'blue'; valid: green, red"),
        ({"leaves": {"oak": [{"colour": "red", "count": 10}]}}, "malformed",
         "tree.toml: leaves.oak[1].count must be an integer <= 9, got 10"),
        ({"leaves": {"oak": [{"colour": "red", "cout": 2}]}}, "malformed",
         "tree.toml: leaves.oak[1]: unknown cout; valid: colour, count"),
        ({"leaves": {"oak": [{}]}}, "malformed", "tree.toml: leaves.oak[1]: missing colour"),
        ({"leaves": {}, "height": 0}, "conflict",
         "tree.toml: height must be a positive height, got 0"),
        ({"leaves": {}, "height": "tall"}, "conflict",
         "tree.toml: height must be a positive height, got 'tall'"),
        ({"leaves": {}, "extra": 1}, "malformed",
         "tree.toml: unknown extra; valid: height, leaves"),
        ({"leaves": 3}, "malformed", "tree.toml: leaves must be a table, got 3"),
        ({}, "malformed", "tree.toml: missing leaves"),
    ],
)
def test_errors_name_the_file_the_field_and_what_is_valid(
    data: object, code: str, message: str
) -> None:
    with pytest.raises(KinesphereError) as info:
        convert(data, Tree, "tree.toml")
    assert (info.value.code, info.value.message) == (code, message)


def test_name_lists_report_every_unknown_and_missing_key() -> None:
    with pytest.raises(KinesphereError) as info:
        convert({"leaves": {}, "b": 1, "a": 2}, Tree, "t", name_lists=True)
    assert info.value.message == "t: unknown ['a', 'b']; valid: height, leaves"
    with pytest.raises(KinesphereError) as info:
        convert({"leaves": {"x": [{"count": 2}]}}, Tree, "t", name_lists=True)
    assert info.value.message == "t: leaves.x[1]: missing ['colour']"


def test_unreadable_and_invalid_toml_name_the_file(tmp_path: Path) -> None:
    with pytest.raises(KinesphereError) as info:
        read_toml(tmp_path / "nope.toml", "tree file")
    assert info.value.code == "malformed" and f"tree file {tmp_path / 'nope.toml'}" in str(
        info.value.message
    )
    bad = tmp_path / "bad.toml"
    bad.write_text("leaves = [")
    with pytest.raises(KinesphereError) as info:
        load_toml(bad, Tree, "tree file")
    assert info.value.message.startswith(f"tree file {bad} is not TOML")


def test_good_data_decodes_into_the_types() -> None:
    tree = convert({"leaves": {"oak": [{"colour": "red", "count": 2}]}, "height": 3}, Tree, "t")
    assert tree == Tree({"oak": [Leaf("red", 2)]}, 3.0)


# --- platform.toml, decoded by kinesphere.platforms.platform -----------------------------------


def _platform_copy(tmp_path: Path, edit: tuple[str, str]) -> Path:
    folder = tmp_path / "youbot"
    shutil.copytree(PLATFORMS_DIR / "youbot", folder)
    cfg = folder / "platform.toml"
    text = cfg.read_text()
    assert edit[0] in text, edit
    cfg.write_text(text.replace(edit[0], edit[1]))
    return folder


@pytest.mark.parametrize(
    ("edit", "named"),
    [
        (('kind = "omni"', 'kind = "hover"'),
         "base.kind: 'hover'; valid: diff, fixed, legged, omni, skid"),
        (("max_speed = ", "max_sped = "), "base: unknown max_sped; valid: height, kind"),
        (("[motion]", "[motions]"), "unknown motions; valid: base, motion, neutral, platform"),
        (("max_jerk = 5.0 ", "max_jerk = -1 "), "base.max_jerk must be 0..10000 m/s^3, got -1"),
        (("max_jerk = 30.0", "max_jerk = 0"), "motion.max_jerk must be > 0"),
        (("arm_joint_2 = 1.1345", "arm_joint_2 = 'up'"), "neutral.arm_joint_2 must be a number"),
    ],
)
def test_bad_platform_files_are_invalid_and_named(
    tmp_path: Path, edit: tuple[str, str], named: str
) -> None:
    folder = _platform_copy(tmp_path, edit)
    with pytest.raises(KinesphereError) as info:
        load_platform(str(folder))
    assert info.value.code == "invalid_eurdf"
    assert str(folder / "platform.toml") in info.value.message
    assert named in info.value.message


def test_every_shipped_platform_file_decodes_with_its_written_numbers() -> None:
    for name in platform_names():
        text = (PLATFORMS_DIR / name / "platform.toml").read_text()
        p = load_platform(name)
        assert f'kind = "{p.base.kind}"' in text
        for line in text.splitlines():
            key, _, rest = line.partition("=")
            value = rest.split("#")[0].strip()
            if key.strip() == "max_speed":
                assert p.base.max_speed == float(value)
