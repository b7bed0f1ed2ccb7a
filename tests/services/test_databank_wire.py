"""A peer written from docs/protocol.md alone, with nothing but ``zenoh`` and ``msgspec``.

The scripts run in a subprocess where importing kinesphere fails, against a real databank
service: the documented example verbatim, then compound, catalogue and error replies as
the document describes them.
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from kinesphere import zconfig
from kinesphere.keyexpr import Keys
from kinesphere.platforms.platform import load_platform
from kinesphere.services.databank.service import DatabankService
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.store import PoseRow, write_databank
from kinesphere.services.ecl.vsam import load_vsam
from support.databank import answered
from support.paths import ROOT

pytestmark = pytest.mark.processes

DOC = ROOT / "docs" / "protocol.md"
NO_KINESPHERE = "import sys\nsys.modules['kinesphere'] = None  # any kinesphere import fails\n"

OTHERS = '''
import json, sys
import msgspec, zenoh

config = zenoh.Config()
config.insert_json5("mode", json.dumps("client"))
config.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
config.insert_json5("scouting/multicast/enabled", "false")

def ask(key, payload=None):
    out = []
    for reply in session.get(key, payload=payload, timeout=2.0,
                             consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is not None:
            out.append(("ok", msgspec.msgpack.decode(reply.ok.payload.to_bytes())))
        else:
            out.append(("err", msgspec.msgpack.decode(reply.err.payload.to_bytes())))
    return out

with zenoh.open(config) as session:
    payload = msgspec.msgpack.encode({
        "parts": [
            {"limb": "limb_11", "origin": "distal_11", "direction": "left-high", "size": 2},
            {"limb": "limb_21", "origin": "distal_21", "direction": "right-high", "size": 2},
        ],
        "last_wins": False,
    })
    (kind, pose), = ask("kinesphere/ecl/baxter/compound", payload)
    print("compound", kind, pose["type"], pose["k_id"], len(pose["joints"]), len(pose["parts"]))
    (kind, cat), = ask("kinesphere/ecl/baxter/catalogue")
    print("catalogue", kind, cat["type"], [e["limb"] for e in cat["limbs"]], cat["version"])
    (kind, err), = ask("kinesphere/ecl/nosuchbot/pose/limb_11/distal_11/left-high/2")
    print("unknown", kind, err["type"], err["code"])
    (kind, err), = ask("kinesphere/ecl/baxter/pose/limb_11/distal_11/left-high/nan")
    print("nan", kind, err["code"])
    (kind, err), = ask("kinesphere/ecl/baxter/record", msgspec.msgpack.encode({
        "limb": "limb_11", "origin": "distal_11", "direction": "left-high", "size": 1,
        "joints": {"right_s0": 0.1}}))
    print("record", kind, err["code"])
'''


def doc_example() -> str:
    """The code block under ``<!-- example:pose-query -->`` in docs/protocol.md."""
    text = DOC.read_text(encoding="utf-8")
    found = re.search(r"<!-- example:pose-query -->\s*```python\n(.*?)```", text, re.S)
    assert found, "docs/protocol.md lost its runnable example"
    return found.group(1)


@pytest.fixture(scope="module")
def endpoint(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A baxter databank (the example's cells) served under the default prefix."""
    plat = load_platform("baxter")
    arm = {"right_s0": 0.2, "right_s1": -0.3, "right_e0": 0.1, "right_e1": 0.5, "right_w0": 0.0,
           "right_w1": 0.4, "right_w2": -0.1}
    rows = [PoseRow("limb_11", "distal_11", "left-high", s, {j: v * s for j, v in arm.items()})
            for s in (1, 2, 3)]
    rows += [PoseRow("limb_21", "distal_21", "right-high", s,
                     {j.replace("right", "left"): v * s for j, v in arm.items()})
             for s in (1, 2, 3)]
    db = tmp_path_factory.mktemp("db") / "baxter.sqlite"
    write_databank(db, plat, load_vsam(plat), rows, "test")
    with zconfig.loopback_hub() as (hub, ep):
        with DatabankService(hub, {"baxter": Ecl.open("baxter", db)}, Keys(), "wire"):
            client = zconfig.open_session(config=zconfig.loopback_config(ep))
            try:
                answered(client, Keys().catalogue("baxter"))
            finally:
                zconfig.close_session(client)
            yield ep


def run(script: str, endpoint: str, tmp_path: Path) -> str:
    path = tmp_path / "peer.py"
    path.write_text(NO_KINESPHERE + script, encoding="utf-8")
    done = subprocess.run([sys.executable, str(path), endpoint], capture_output=True,
                          text=True, timeout=60, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_the_documented_example_runs_without_kinesphere(endpoint: str, tmp_path: Path) -> None:
    out = run(doc_example(), endpoint, tmp_path)
    found = re.fullmatch(r"pose (\d+) 2 \[(.*)\]\n", out)
    assert found, out
    assert "('right_e1', 1.0)" in found.group(2) and "translate" not in out


def test_compound_catalogue_and_errors_from_the_document(endpoint: str, tmp_path: Path) -> None:
    out = run(OTHERS, endpoint, tmp_path).splitlines()
    assert out[0] == "compound ok pose -1 14 2"
    assert out[1].startswith("catalogue ok catalogue ['limb_11', ")
    assert out[2:] == ["unknown err error unknown_platform", "nan err size_out_of_range",
                       "record err forbidden"]
