"""The eURDF loader: (C, J, L, P) from a labelled URDF, and a clear error for every broken file."""

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from kinesphere.errors import KinesphereError
from kinesphere.eurdf import load_eurdf
from support.paths import TOY_EURDF

TEXT = TOY_EURDF.read_text()


def test_toy_robot_sets() -> None:
    e = load_eurdf(TOY_EURDF)
    assert e.C == ("c_1",)
    assert e.J == ("distal_11", "distal_12", "distal_21")
    assert e.L == ("limb_11", "limb_12", "limb_21")
    assert [p.name for p in e.P] == ["yaw", "elbow", "wrist", "tail_joint"]
    assert e.limits["elbow"].lower == -2.0 and e.limits["elbow"].velocity == 1.5
    assert e.limits["tail_joint"].kind == "continuous"


def test_limbs_overlap_and_resolve_aliases() -> None:
    e = load_eurdf(TOY_EURDF)
    assert set(e.labels_of_link("hand")) == {"limb_11", "limb_12"}
    assert e.limb("arm").name == "limb_11"
    assert e.origin("shoulder").name == "distal_11"
    assert e.limb_joints("limb_12") == ("elbow", "wrist")
    assert e.limb_joints("arm") == ("yaw", "elbow", "wrist")
    assert e.origin_joint("distal_12") == "elbow"
    assert e.tip_link("limb_11") == "tip"
    assert e.root_link == "base"


def test_unknown_labels_list_the_valid_ones() -> None:
    e = load_eurdf(TOY_EURDF)
    with pytest.raises(KinesphereError) as err:
        e.limb("leg")
    assert err.value.code == "unknown_limb" and "limb_11 (arm)" in err.value.message
    with pytest.raises(KinesphereError) as err:
        e.origin("distal_99")
    assert err.value.code == "unknown_origin" and "distal_12" in err.value.message


def test_loader_accepts_text_and_hashes_content() -> None:
    a, b = load_eurdf(TEXT), load_eurdf(TOY_EURDF)
    assert a.sha256 == b.sha256
    assert load_eurdf(TEXT.replace('velocity="3"', 'velocity="4"')).sha256 != a.sha256


LIMB11 = (
    '<body_part name="limb_11" set="L" alias="arm" distal="distal_11"><link name="upper"/>'
    '<link name="lower"/><link name="hand"/><link name="tip"/></body_part>'
)

BROKEN = {
    "not xml": (TEXT.replace("</robot>", ""), "not well-formed"),
    "wrong root": ("<robo name='x'/>", "root element must be <robot>"),
    "no name": (TEXT.replace('<robot name="toyarm">', "<robot>"), "no name attribute"),
    "bad set": (TEXT.replace('name="c_1" set="C"', 'name="c_1" set="X"'), "use C, L or J"),
    "bad label name": (
        TEXT.replace('name="limb_21" set="L"', 'name="tail" set="L"'),
        "must be named limb_<i><j>",
    ),
    "missing link": (
        TEXT.replace(
            '<link name="base"/></body_part>', '<link name="base"/><link name="ghost"/></body_part>'
        ),
        "names link 'ghost', which does not exist",
    ),
    "missing joint": (
        TEXT.replace('<joint name="yaw"/></body_part>', '<joint name="nope"/></body_part>'),
        "names joint 'nope', which does not exist",
    ),
    "label twice": (
        TEXT.replace('name="limb_21" set="L" alias="tail"', 'name="limb_21" set="L" alias="arm"'),
        "'arm' is used twice",
    ),
    "no core": (
        TEXT.replace(
            '<body_part name="c_1" set="C" alias="core"><link name="base"/></body_part>', ""
        ),
        "no core label",
    ),
    "limb misses link": (
        TEXT.replace(LIMB11, LIMB11.replace('<link name="tip"/>', "")),
        "misses ['tip']",
    ),
    "limb extra link": (
        TEXT.replace(
            LIMB11, LIMB11.replace('<link name="tip"/>', '<link name="tip"/><link name="tail"/>')
        ),
        "links outside it",
    ),
    "distal index mismatch": (
        TEXT.replace('alias="forearm" distal="distal_12"', 'alias="forearm" distal="distal_11"'),
        "indices must match",
    ),
    "distal attribute missing": (
        TEXT.replace(' distal="distal_21"', ""),
        "needs distal='distal_21'",
    ),
    "fixed joint as origin": (
        TEXT.replace(
            '<joint name="tail_joint"/></body_part>',
            '<joint name="tail_joint"/><joint name="tip_fixed"/></body_part>',
        ),
        "names fixed joint 'tip_fixed'",
    ),
    "joint in two labels": (
        TEXT.replace(
            '<joint name="tail_joint"/></body_part>',
            '<joint name="tail_joint"/><joint name="yaw"/></body_part>',
        ),
        "labelled by both",
    ),
    "parent limb missing": (
        TEXT.replace(LIMB11, "").replace(
            '<body_part name="distal_11" set="J" alias="shoulder"><joint name="yaw"/></body_part>',
            "",
        ),
        "no parent limb limb_11",
    ),
    "core and limb": (
        TEXT.replace(
            '<link name="base"/></body_part>', '<link name="base"/><link name="tail"/></body_part>'
        ),
        "labelled both core and limb",
    ),
    "joint to nowhere": (
        TEXT.replace('<child link="tail"/>', '<child link="tale"/>'),
        "child link 'tale' does not exist",
    ),
    "no limits": (
        TEXT.replace(
            '<limit lower="-2" upper="2" velocity="1.5" effort="10"/></joint>\n'
            '  <joint name="elbow"',
            '</joint>\n  <joint name="elbow"',
        ),
        "needs <limit lower upper>",
    ),
    "lower above upper": (
        TEXT.replace('lower="-1.5" upper="1.5"', 'lower="1.5" upper="-1.5"'),
        "lower limit above upper",
    ),
    "two roots": (
        TEXT.replace(
            '<joint name="tail_joint" type="continuous"><parent link="base"/>'
            '<child link="tail"/><origin xyz="-0.2 0 0"/><axis xyz="1 0 0"/>'
            '<limit velocity="2" effort="1"/></joint>',
            "",
        ),
        "exactly one root link",
    ),
    "distal without limb": (
        TEXT.replace('<joint name="elbow"/><joint name="wrist"/>', '<joint name="elbow"/>').replace(
            "</robot>",
            '<body_part name="distal_31" set="J"><joint name="wrist"/></body_part></robot>',
        ),
        "distal_31'> has no matching limb label",
    ),
    "unlabelled link": (
        TEXT.replace(
            '<body_part name="limb_21" set="L" alias="tail" '
            'distal="distal_21"><link name="tail"/></body_part>',
            "",
        ).replace('<body_part name="distal_21" set="J"><joint name="tail_joint"/></body_part>', ""),
        "link 'tail' has no core or limb label",
    ),
    "J lists links": (
        TEXT.replace(
            '<body_part name="distal_21" set="J"><joint name="tail_joint"/>',
            '<body_part name="distal_21" set="J"><link name="tail"/>',
        ),
        "joint labels list <joint>s",
    ),
    "duplicate link": (
        TEXT.replace('<link name="tip"/>\n', '<link name="tip"/>\n<link name="tip"/>\n'),
        "appears twice",
    ),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_broken_eurdf_gets_a_clear_error(case: str) -> None:
    text, expected = BROKEN[case]
    assert text != TEXT, "the mutation did not apply"
    with pytest.raises(KinesphereError) as err:
        load_eurdf(text)
    assert err.value.code == "invalid_eurdf"
    assert expected in err.value.message, err.value.message


def test_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(KinesphereError, match="not found"):
        load_eurdf(tmp_path / "nope.eurdf")


def test_subtree_limb_must_nest_in_its_parent() -> None:
    text = TEXT.replace(
        'name="limb_12" set="L" alias="forearm" distal="distal_12"',
        'name="limb_13" set="L" alias="forearm" distal="distal_13"',
    ).replace('name="distal_12" set="J"', 'name="distal_13" set="J"')
    with pytest.raises(KinesphereError, match="no parent limb limb_12"):
        load_eurdf(text)


def test_limb_tip_attribute_overrides_the_deepest_link() -> None:
    text = TEXT.replace('alias="forearm" distal="distal_12"',
                        'alias="forearm" distal="distal_12" tip="hand"')
    assert load_eurdf(text).tip_link("limb_12") == "hand"
    with pytest.raises(KinesphereError, match="tip='base' is not one of its links"):
        load_eurdf(text.replace('tip="hand"', 'tip="base"'))


def test_plain_urdf_strips_only_the_labels() -> None:
    from kinesphere.eurdf import plain_urdf
    from kinesphere.platforms.platform import load_platform

    for name in ("baxter", "nao", "youbot"):
        platform = load_platform(name)
        assert platform.eurdf.path is not None
        text = platform.eurdf.path.read_text(encoding="utf-8")
        urdf = plain_urdf(text)
        root = ET.fromstring(urdf)
        assert root.findall("body_part") == [] and "body_part" in text
        assert {j.get("name") for j in root.findall("joint")} >= set(platform.joint_names)
        assert len(root.findall("link")) == len(ET.fromstring(text).findall("link"))
    with pytest.raises(KinesphereError, match="well-formed"):
        plain_urdf("<robot")
