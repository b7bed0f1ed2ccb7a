"""Honest fallbacks and bounded sizes: a direction a body lacks is served by the nearest one it
has whose poses point within the limit (and says so) unless asked for exactly; sizes stop at the
platform's max_size; over the wire too, with the shipped databanks."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator

import numpy as np
import pytest
import zenoh

from kinesphere import protocol as pr
from kinesphere.cli import main
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import EXACT
from kinesphere.laban import Direction
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.sizes import MAX_TRANSLATION
from kinesphere.substitution import MAX_ANGLE_DEG, nearest_direction, pointing
from support.databank import error_code, pose_of, raw_get, serving
from support.ecl import gaze
from support.network import OWN_KEYS

ARM = ("limb_11", "distal_11")


@pytest.fixture(scope="module")
def nao() -> Ecl:
    return Ecl.open("nao")


def test_a_missing_direction_is_served_by_the_nearest_and_reported(nao: Ecl) -> None:
    """NAO's right arm cannot fold toward its left-low (across the body): left-forward-low
    serves it, its poses pointing within 45 degrees of left-low."""
    have = nao.directions(*ARM)
    assert Direction.LEFT_LOW not in have and Direction.LEFT_FORWARD_LOW in have
    pose = nao.query("right_arm", "right_shoulder", "left-low", 2)
    served = nao.query(*ARM, "left-forward-low", 2)
    assert pose.direction == "left-forward-low" and pose.joints == served.joints
    assert pose.k_id == served.k_id and pose.p_id == 2
    (sub,) = pose.substitutions
    assert (sub.limb, sub.origin, sub.requested, sub.served) == (*ARM, "left-low",
                                                                 "left-forward-low")
    assert sub.angle == pytest.approx(35.264, abs=1e-3)
    assert served.substitutions == []  # a direction it has: exact, nothing reported
    assert pose.measured_angle is not None and pose.measured_angle <= MAX_ANGLE_DEG
    with pytest.raises(KinesphereError) as err:
        nao.query(*ARM, "left-low", 2, exact=True)
    assert err.value.code == "direction_unavailable" and "exactly" in err.value.message
    assert "left-forward-low" in err.value.message


@pytest.mark.parametrize("platform", ["baxter", "nao", "youbot", "packbot"])
def test_every_substitution_follows_the_shared_rule_within_the_limit(platform: str) -> None:
    ecl = Ecl.open(platform)
    for entry in ecl.catalogue().limbs:
        have = [Direction.parse(d) for d in entry.directions]
        tips = {Direction.parse(d): t for d, t in entry.tips.items()}
        for requested in Direction.pulls():
            choice = nearest_direction(requested, have, MAX_ANGLE_DEG,
                                       pointing([tips], requested))
            if choice is None:
                with pytest.raises(KinesphereError) as err:
                    ecl.query(entry.limb, entry.origin, requested, 3)
                assert err.value.code == "direction_unavailable"
                continue
            pose = ecl.query(entry.limb, entry.origin, requested, 3)
            assert pose.direction == choice.direction.slug
            if choice.angle == 0:
                assert pose.substitutions == []
            else:
                assert pose.substitutions[0].angle <= MAX_ANGLE_DEG
                assert pose.substitutions[0].requested == requested.slug


def test_the_core_and_place_middle_are_never_substituted() -> None:
    youbot = Ecl.open("youbot")
    with pytest.raises(KinesphereError) as err:
        youbot.query("c_1", "c_1", "forward-high", 1)
    assert err.value.code == "direction_unavailable"
    assert youbot.query(*ARM, "place-middle", 3).substitutions == []


def test_compound_parts_substitute_or_stay_exact(nao: Ecl) -> None:
    parts = [pr.SpatialCommand("right_arm", "right_shoulder", "left-low", 3),
             pr.SpatialCommand("head", "neck", "forward-high", 3)]
    head_dirs = {d.slug for d in nao.directions("limb_51", "distal_51")}
    pose = nao.compound(parts)
    requested = {s.requested for s in pose.substitutions}
    assert "left-low" in requested
    assert ("forward-high" in requested) == ("forward-high" not in head_dirs)
    assert pose.parts[0].direction == "left-forward-low"
    exact = [parts[0], pr.SpatialCommand("right_arm", "right_shoulder", "left-low", 3,
                                         exact=True)]
    with pytest.raises(KinesphereError) as err:
        nao.compound(exact, last_wins=True)
    assert err.value.code == "direction_unavailable"


def test_sizes_stop_at_max_size_and_translations_at_ten_metres() -> None:
    youbot = Ecl.open("youbot")
    cat = youbot.catalogue()
    assert cat.max_size == 23 and cat.base_kind == "omni"
    far = youbot.query("c_1", "c_1", "forward-middle", cat.max_size)
    assert far.translation == pytest.approx([23 * 0.25, 0.0, 0.0])
    for size in (23.5, 1.8e19, 1e300):
        with pytest.raises(KinesphereError) as err:
            youbot.query(*ARM, "forward-middle", size)
        assert err.value.code == "size_out_of_range" and "23" in err.value.message
    packbot = Ecl.open("packbot")  # 0.5 m steps: 20 past far is exactly the 10 m cap
    drive = [pr.SpatialCommand("c_1", "c_1", "forward-middle", 20.0),
             pr.SpatialCommand("c_1", "c_1", "left-middle", 20.0)]
    with pytest.raises(KinesphereError) as err:
        packbot.compound(drive, last_wins=True)
    assert err.value.code == "size_out_of_range" and f"{MAX_TRANSLATION:g} m" in err.value.message
    baxter = Ecl.open("baxter")
    assert baxter.catalogue().max_size == 3 and baxter.catalogue().base_kind == "fixed"
    with pytest.raises(KinesphereError) as err:
        baxter.query(*ARM, "left-high", 4)
    assert err.value.code == "cannot_translate"


# -- over the wire ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def net() -> Iterator[tuple[str, zenoh.Session]]:
    """The shipped NAO and PackBot databanks served in-process; the hub's endpoint and a
    querier joined to it."""
    ecls = {"nao": Ecl.open("nao"), "packbot": Ecl.open("packbot")}
    with serving(ecls, "shipped") as (_, client, endpoint):
        yield endpoint, client


def test_query_nao_head_left_middle_looks_left(
    net: tuple[str, zenoh.Session], capsys: pytest.CaptureFixture[str],
) -> None:
    endpoint, _ = net
    zargs = ["--connect", endpoint, "--prefix", OWN_KEYS.prefix, "--timeout", "5"]
    assert main(["query", "nao", "head", "neck", "left-middle", "3", "--json", *zargs]) == 0
    pose = json.loads(capsys.readouterr().out)
    assert (pose["limb"], pose["direction"], pose["substitutions"]) == (
        "limb_51", "left-middle", [])
    looks = gaze("nao", pose["joints"])
    assert looks[1] > 0.95, looks  # +y is the robot's left
    # the neck tilts 38.5 degrees: the nearest pose looks 51 degrees from straight up, too far
    assert main(["query", "nao", "head", "neck", "place-high", "3", *zargs]) == 2
    assert "[direction_unavailable]" in capsys.readouterr().err
    assert main(["query", "nao", "right_arm", "right_shoulder", "left-low", "3", *zargs]) == 0
    out = capsys.readouterr().out
    assert "left-forward-low" in out and "substituted: limb_11 has no left-low" in out
    assert main(["query", "nao", "right_arm", "right_shoulder", "left-low", "3", "--exact",
                 *zargs]) == 2
    assert "[direction_unavailable]" in capsys.readouterr().err


def test_exact_selector_and_substitution_on_the_wire(net: tuple[str, zenoh.Session]) -> None:
    _, client = net
    key = OWN_KEYS.pose("nao", *ARM, "left-low", 3)
    pose = pose_of(raw_get(client, key))
    assert pose.direction == "left-forward-low" and pose.substitutions[0].requested == "left-low"
    assert error_code(raw_get(client, key + EXACT)) == "direction_unavailable"
    assert pose_of(raw_get(client, key)) == pose  # the cached answers stay apart
    assert pose_of(raw_get(client, key + "?other=1")) == pose  # other parameters: ignored
    exact_key = OWN_KEYS.pose("nao", *ARM, "left-forward-low", 3) + EXACT
    exact_hit = pose_of(raw_get(client, exact_key))
    assert exact_hit.joints == pose.joints and exact_hit.substitutions == []
    big = OWN_KEYS.pose("packbot", "c_1", "c_1", "forward-middle", 1.8e19)
    assert error_code(raw_get(client, big)) == "size_out_of_range"
    request = pr.CompoundRequest(parts=[pr.SpatialCommand("right_arm", "right_shoulder",
                                                           "left-low", 3)])
    joined = pose_of(raw_get(client, OWN_KEYS.compound("nao"), pr.encode(request)))
    assert joined.substitutions[0].served == "left-forward-low"
    assert math.isclose(joined.substitutions[0].angle, 35.264, abs_tol=1e-3)
    assert np.isclose(joined.joints["RShoulderPitch"], pose.joints["RShoulderPitch"])
