"""Per-robot access-control rules generated from a fleet file (deploy/robots.toml)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import zenoh

from kinesphere.deploy.acl import add_fleet, fleet_acl, load_fleet
from kinesphere.deploy.router import router_config
from kinesphere.errors import KinesphereError
from support.files import refused
from support.paths import DEPLOY

SHIPPED = DEPLOY / "robots.toml"


def test_the_shipped_fleet_gives_each_robot_its_own_keys_only() -> None:
    fleet = load_fleet(SHIPPED)
    assert set(fleet.robots) == {"baxter-1", "nao-1", "youbot-1"}
    acl = fleet_acl(fleet)
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["robot:youbot-1:put"]["key_exprs"] == [
        "kinesphere/robot/youbot-1/state", "kinesphere/robot/youbot-1/ack"]
    assert rules["robot:youbot-1:liveliness_token"]["key_exprs"] == [
        "kinesphere/alive/robot/youbot-1"]
    assert rules["robot:baxter-1:declare_subscriber"]["key_exprs"] == [
        "kinesphere/robot/baxter-1/command/**", "kinesphere/group/arms/command/**",
        "kinesphere/ecl/*/changed"]
    robots = [k for r in acl["rules"] if r["id"].startswith("robot:") for k in r["key_exprs"]]
    assert not any("robot/*" in k or "alive/robot/*" in k for k in robots)
    assert {"id": "robot:nao-1", "cert_common_names": ["nao-1"]} in acl["subjects"]


def test_the_router_config_admits_the_fleet() -> None:
    config, admitted = router_config(DEPLOY / "router.json5", None, SHIPPED)
    assert admitted == 5  # three robots, two operators
    subjects = json.loads(config.get_json("access_control/subjects"))
    assert {s["id"] for s in subjects} >= {"operator", "robot:baxter-1", "robot:youbot-1"}
    assert not any(s.get("cert_common_names") == ["agent"] for s in subjects)
    assert json.loads(config.get_json("listen/endpoints")) == ["tls/0.0.0.0:7447"]


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ('[robots.operator]\n', "role"),
        ('[robots."a/b"]\n', "'/'"),
        (f'[robots.{"r" * 65}]\n', "at most 64"),
        ('[robots.r1]\ngroups = ["a*"]\n', "'*'"),
        ('[robots.r1]\ncolour = "red"\n', "colour"),
        ("robots = {}\n", "no robots"),
        ("[robots.r1\n", "fleet file"),
    ],
)
def test_bad_fleet_files_are_malformed(tmp_path: Path, text: str, what: str) -> None:
    assert what in refused(load_fleet, tmp_path, text, "robots.toml").message


def test_robots_need_access_control_and_unique_subjects(tmp_path: Path) -> None:
    fleet = load_fleet(SHIPPED)
    with pytest.raises(KinesphereError, match="access_control enabled"):
        add_fleet(zenoh.Config(), fleet)
    config, _ = router_config(DEPLOY / "router.json5", None, SHIPPED)
    with pytest.raises(KinesphereError) as info:
        add_fleet(config, fleet)  # admitted twice
    assert info.value.code == "conflict"


def test_print_acl(capsys: pytest.CaptureFixture[str]) -> None:
    from kinesphere.cli import main

    assert main(["router", "--robots", str(SHIPPED), "--print-acl"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["access_control"]["policies"]) == 5


@pytest.mark.processes
def test_make_certs_refuses_a_robot_named_like_a_role(tmp_path: Path) -> None:
    import os
    import subprocess

    done = subprocess.run([str(DEPLOY / "make-certs.sh"), str(tmp_path / "c")],
                          env=dict(os.environ, ROBOTS="arm-1 operator"), capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 2 and "bad robot id or operator name 'operator'" in done.stderr
    assert not (tmp_path / "c").exists()
