"""Bodies over the wire: the databank answers ``{p}/ecl/{platform}/body`` for every platform
it serves, so a viewer draws any robot without local platform files."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import zenoh
from test_databank_support import KEYS, answered, error_code, peer, raw_get

from kinesphere import protocol as pr
from kinesphere import zconfig
from kinesphere.eurdf import load_eurdf
from kinesphere.query import get_one
from kinesphere.robots.platform import load_platform, platform_names
from kinesphere.services.databank.service import DatabankService
from kinesphere.services.ecl.ecl import Ecl


@pytest.fixture(scope="module")
def net() -> Iterator[zenoh.Session]:
    """Every shipped databank served on a hub, and a querier joined to it."""
    with zconfig.loopback_hub() as (hub, endpoint):
        server, client = peer(endpoint), peer(endpoint)
        ecls = {name: Ecl.open(name) for name in platform_names()}
        try:
            with DatabankService(server, ecls, KEYS, "bodies"):
                answered(client, KEYS.body("baxter"))
                yield client
        finally:
            zconfig.close_session(client)
            zconfig.close_session(server)


@pytest.mark.parametrize("name", platform_names())
def test_every_shipped_body_is_served(net: zenoh.Session, name: str) -> None:
    body = get_one(net, KEYS.body(name), pr.BodyModel, timeout=10.0)
    plat = load_platform(name)
    assert body.platform == name and body.base_kind == plat.base.kind
    assert body.neutral == plat.neutral and body.version == plat.eurdf.sha256
    drawn = load_eurdf(body.eurdf)  # the text alone is a valid eURDF, no files needed
    assert drawn.joint_names == plat.joint_names and drawn.sha256 == body.version
    assert len(pr.encode(body)) < 64 * 1024  # primitive shapes only: small


def test_unknown_platform_and_bad_key(net: zenoh.Session) -> None:
    assert error_code(answered(net, KEYS.body("nosuchbot"))) == "unknown_platform"
    (ok, data), = raw_get(net, f"{KEYS.prefix}/ecl/baxter/bodies")
    assert not ok and "body" in pr.decode(data, pr.Error).message
