"""VSAM files: defaults, derived core entries, and every mistake named with the right code."""

import shutil
from pathlib import Path

import pytest

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.platform import load_platform
from kinesphere.services.ecl.vsam import load_vsam, vsam_from_dict
from support.paths import TOY

STEPS = {"baxter": None, "nao": 0.1, "youbot": 0.25, "packbot": 0.5, "khepera": 0.05}


def toy_copy(tmp_path: Path, vsam: str, base: str = "omni", name: str = "toy") -> Path:
    """A private toyarm folder with its own vsam.toml (and base kind)."""
    folder = tmp_path / name
    shutil.copytree(TOY, folder)
    cfg = (folder / "platform.toml").read_text().replace('kind = "omni"', f'kind = "{base}"')
    (folder / "platform.toml").write_text(cfg)
    (folder / "vsam.toml").write_text(vsam)
    return folder


GOOD = """
sizes = [1, 2, 3]
directions = "laban-27"
translation_step = 0.1
[[entry]]
limb = "arm"
origin = "shoulder"
"""


def test_toyarm_vsam_has_pairs_restrictions_and_derived_core_entries() -> None:
    v = load_vsam(str(TOY))
    assert v.platform == "toyarm"
    assert v.sizes == (1, 2, 3) and v.k_smax == 3
    assert v.translation_step == 0.1
    assert v.directions == tuple(Direction)
    pairs = [(e.limb, e.origin) for e in v.entries]
    assert pairs == [
        ("limb_11", "distal_11"), ("limb_12", "distal_12"), ("limb_21", "distal_21"),
        ("c_1", "c_1"),
    ]
    tail = v.entry("limb_21", "distal_21")
    assert tail is not None and {d.slug for d in tail.directions} == {
        "place-middle", "left-middle", "right-middle", "place-high", "place-low"
    }
    core = v.entry("c_1", "c_1")
    assert core is not None and core.is_core
    assert core.directions == Direction.translations() and len(core.directions) == 8
    assert v.origins == ("distal_11", "distal_12", "distal_21", "c_1")


def test_aliases_in_the_file_are_stored_as_canonical_labels(tmp_path: Path) -> None:
    v = load_vsam(str(toy_copy(tmp_path, GOOD)))
    assert [(e.limb, e.origin) for e in v.entries if not e.is_core] == [("limb_11", "distal_11")]


def test_to_dict_round_trips_through_validation() -> None:
    plat = load_platform(str(TOY))
    v = load_vsam(plat)
    assert vsam_from_dict(v.to_dict(), plat) == v


@pytest.mark.parametrize("name", sorted(STEPS))
def test_every_shipped_platform_has_a_valid_vsam(name: str) -> None:
    plat = load_platform(name)
    v = load_vsam(plat)
    assert v.sizes == (1, 2, 3) and v.directions == tuple(Direction)
    assert v.translation_step == STEPS[name]
    limbs = [(e.limb, e.origin) for e in v.entries if not e.is_core]
    assert limbs == [(p.name, p.distal) for p in plat.eurdf.limbs]  # k_o = J, limb_ij/distal_ij
    core = [e for e in v.entries if e.is_core]
    if plat.base.mobile:
        assert [(e.limb, e.origin, e.directions) for e in core] == [
            ("c_1", "c_1", Direction.translations())
        ]
    else:
        assert core == [] and not v.can_translate


BAD = [
    ("unknown limb", GOOD.replace('"arm"', '"tentacle"'), "unknown_limb", "tentacle"),
    ("unknown origin", GOOD.replace('"shoulder"', '"hip"'), "unknown_origin", "hip"),
    ("core as origin", GOOD.replace('"shoulder"', '"c_1"'), "unknown_origin", "core label"),
    ("unknown direction", GOOD.replace('"laban-27"', '["left-high", "up-ish"]'),
     "unknown_direction", "up-ish"),
    ("entry direction outside k_d",
     GOOD.replace('"laban-27"', '["left-high"]') + 'directions = ["right-high"]\n',
     "unknown_direction", "right-high"),
    ("duplicate direction", GOOD.replace('"laban-27"', '["left-high", "Left High"]'),
     "malformed", "twice"),
    ("size zero", GOOD.replace("[1, 2, 3]", "[0, 1]"), "size_out_of_range", "positive"),
    ("size text", GOOD.replace("[1, 2, 3]", '["near"]'), "size_out_of_range", "near"),
    ("size float", GOOD.replace("[1, 2, 3]", "[1, 2.5]"), "size_out_of_range", "2.5"),
    ("sizes unordered", GOOD.replace("[1, 2, 3]", "[2, 1]"), "size_out_of_range", "increasing"),
    ("sizes empty", GOOD.replace("[1, 2, 3]", "[]"), "size_out_of_range", "non-empty"),
    ("no step on a mobile base", GOOD.replace("translation_step = 0.1", ""), "malformed",
     "translation_step"),
    ("negative step", GOOD.replace("0.1", "-0.1"), "malformed", "translation_step"),
    ("typo key", GOOD.replace("translation_step", "translation_stepp"), "malformed",
     "translation_stepp"),
    ("entry typo", GOOD + 'orgin = "x"\n', "malformed", "orgin"),
    ("duplicate pair", GOOD + '[[entry]]\nlimb = "limb_11"\norigin = "distal_11"\n',
     "malformed", "twice"),
    ("limb not a string", GOOD.replace('"arm"', "11"), "malformed", "limb"),
    ("not toml", "sizes = [1, 2", "malformed", "TOML"),
]


@pytest.mark.parametrize(("what", "text", "code", "named"), BAD, ids=[b[0] for b in BAD])
def test_bad_vsam_files_fail_with_the_right_code(
    tmp_path: Path, what: str, text: str, code: str, named: str
) -> None:
    folder = toy_copy(tmp_path, text)
    with pytest.raises(KinesphereError) as err:
        load_vsam(str(folder))
    assert err.value.code == code, err.value.message
    assert named in err.value.message
    assert "vsam.toml" in err.value.message  # the file is named


def test_fixed_base_forbids_a_translation_step_and_has_no_core_entries(tmp_path: Path) -> None:
    with pytest.raises(KinesphereError) as err:
        load_vsam(str(toy_copy(tmp_path, GOOD, base="fixed", name="a")))
    assert err.value.code == "malformed" and "fixed base" in err.value.message
    v = load_vsam(str(toy_copy(tmp_path, GOOD.replace("translation_step = 0.1", ""),
                               base="fixed", name="b")))
    assert v.translation_step is None and all(not e.is_core for e in v.entries)


def test_fixed_base_without_entries_is_an_error_but_a_mobile_one_is_not(tmp_path: Path) -> None:
    head = "sizes = [1, 2, 3]\n"
    with pytest.raises(KinesphereError) as err:
        load_vsam(str(toy_copy(tmp_path, head, base="fixed", name="a")))
    assert err.value.code == "malformed" and "entry" in err.value.message
    v = load_vsam(str(toy_copy(tmp_path, head + "translation_step = 0.2\n", name="b")))
    assert [e.limb for e in v.entries] == ["c_1"]


def test_missing_vsam_file_is_unavailable(tmp_path: Path) -> None:
    folder = toy_copy(tmp_path, GOOD)
    (folder / "vsam.toml").unlink()
    with pytest.raises(KinesphereError) as err:
        load_vsam(str(folder))
    assert err.value.code == "unavailable" and "vsam.toml" in err.value.message
