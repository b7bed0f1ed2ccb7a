"""Bodies over the wire: the databank answers ``{p}/ecl/{platform}/body`` for every platform
it serves, so a viewer draws any robot without local platform files."""

from __future__ import annotations

import io
from collections.abc import Iterator

import numpy as np
import pytest
import yourdfpy
import zenoh

from kinesphere import protocol as pr
from kinesphere import zconfig
from kinesphere.clients.view.body import BodyGeometry
from kinesphere.clients.view.scene import Top
from kinesphere.eurdf import load_eurdf
from kinesphere.platforms.platform import load_platform, platform_names
from kinesphere.query import get_one
from kinesphere.services.databank.service import DatabankService
from kinesphere.services.ecl.ecl import Ecl
from support.databank import answered, error_code, raw_get
from support.network import OWN_KEYS, peer


@pytest.fixture(scope="module")
def net() -> Iterator[zenoh.Session]:
    """Every shipped databank served on a hub, and a querier joined to it."""
    with zconfig.loopback_hub() as (hub, endpoint):
        server, client = peer(endpoint), peer(endpoint)
        ecls = {name: Ecl.open(name) for name in platform_names()}
        try:
            with DatabankService(server, ecls, OWN_KEYS, "bodies"):
                answered(client, OWN_KEYS.body("baxter"))
                yield client
        finally:
            zconfig.close_session(client)
            zconfig.close_session(server)


@pytest.mark.parametrize("name", platform_names())
def test_every_shipped_body_is_served(net: zenoh.Session, name: str) -> None:
    body = get_one(net, OWN_KEYS.body(name), pr.BodyModel, timeout=10.0)
    plat = load_platform(name)
    assert body.platform == name and body.base_kind == plat.base.kind
    assert body.neutral == plat.neutral and body.version == plat.eurdf.sha256
    drawn = load_eurdf(body.eurdf)  # the text alone is a valid eURDF, no files needed
    assert drawn.joint_names == plat.joint_names and drawn.sha256 == body.version
    assert len(pr.encode(body)) < 64 * 1024  # primitive shapes only: small


def test_unknown_platform_and_bad_key(net: zenoh.Session) -> None:
    assert error_code(answered(net, OWN_KEYS.body("nosuchbot"))) == "unknown_platform"
    (ok, data), = raw_get(net, f"{OWN_KEYS.prefix}/ecl/baxter/bodies")
    assert not ok and "body" in pr.decode(data, pr.Error).message


@pytest.mark.parametrize("name", platform_names())
def test_drawn_joint_frames_match_yourdfpy(net: zenoh.Session, name: str) -> None:
    """The view's own joint transforms equal yourdfpy's forward kinematics at random poses,
    and the neutral body stands on the floor as the MuJoCo model does."""
    import io

    import numpy as np
    import yourdfpy
    from viser import transforms as tf

    from kinesphere.clients.view.body import BodyGeometry

    model = get_one(net, OWN_KEYS.body(name), pr.BodyModel, timeout=10.0)
    body = BodyGeometry(model)
    urdf = yourdfpy.URDF.load(io.StringIO(model.eurdf), build_scene_graph=True,
                              load_meshes=True)
    plat = load_platform(name)
    assert abs(body.lift - plat.base.height) < 1e-3
    rng = np.random.default_rng(7)
    for _ in range(5):
        lim = [plat.eurdf.limits[j] for j in body.joint_names]
        q = np.array([rng.uniform(max(x.lower, -3.0), min(x.upper, 3.0)) for x in lim])
        urdf.update_cfg(q)
        wxyz, xyz = body.transforms(q)
        for i, joint in enumerate(urdf.joint_map.values()):
            expected = urdf.get_transform(joint.child, joint.parent)
            assert np.allclose(tf.SO3(wxyz[i]).as_matrix(), expected[:3, :3], atol=1e-9)
            assert np.allclose(xyz[i], expected[:3, 3], atol=1e-9)


def test_commands_in_words() -> None:
    from kinesphere.words import command_words, label_names

    names = label_names(load_eurdf(load_platform("baxter").eurdf.path or "").aliases)
    part = pr.SpatialCommand("limb_11", "distal_11", "left-high", 3)
    cmd = pr.Command(seq=1, sent_ns=1, parts=[part], deadman=True, ttl_ms=0)
    assert command_words(cmd, names) == "right_arm ← right_shoulder → left-high, far"
    drive = pr.Drive(direction="forward-middle", speed=0.5)
    both = pr.Command(seq=2, sent_ns=1, parts=[part], drive=drive, deadman=True, ttl_ms=0)
    assert command_words(both).endswith("far + drive forward-middle 0.50")
    assert command_words(pr.Command(seq=3, sent_ns=1, deadman=False, ttl_ms=0, estop=True,
                                    stop=True)) == "E-STOP"
    assert command_words(pr.Command(seq=4, sent_ns=1, deadman=False, ttl_ms=0)) == \
        "let go: hold"


def highest(model: pr.BodyModel, q: np.ndarray, lift: float) -> float:
    """The top of the body at ``q`` by yourdfpy: every vertex of every shape, in the root's
    frame (an independent forward kinematics)."""
    urdf = yourdfpy.URDF.load(io.StringIO(model.eurdf), build_scene_graph=True,
                              load_meshes=True)
    urdf.update_cfg(q)
    base = urdf.scene.graph.base_frame
    top = 0.0
    for name, mesh in urdf.scene.geometry.items():
        world = urdf.get_transform(name, base)
        top = max(top, float((mesh.vertices @ world[:3, :3].T + world[:3, 3])[:, 2].max()))
    return top + lift


def test_the_label_rides_above_a_raised_arm(net: zenoh.Session) -> None:
    """Baxter's right arm raised to Left-High, far: the body's top (where the view puts the
    label) rises with it, never below the body and close above it."""
    model = get_one(net, OWN_KEYS.body("baxter"), pr.BodyModel, timeout=10.0)
    body = BodyGeometry(model)
    top = Top(body)
    neutral = body.vector(body.neutral)
    raised = body.vector(Ecl.open("baxter").query("limb_11", "distal_11", "left-high", 3).joints,
                         body.neutral)
    for q in (neutral, raised):
        exact = highest(model, q, body.lift)
        assert exact - 1e-6 <= top(q) <= exact + 0.25, (top(q), exact)
    assert highest(model, raised, body.lift) > body.height + 0.2, "the arm goes above the head"
    assert top(raised) > top(neutral) + 0.2
