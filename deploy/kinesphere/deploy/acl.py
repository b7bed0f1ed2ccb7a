"""Per-robot identity: each robot's certificate (CN = robot id) speaks only for that robot.

A shared "agent" certificate let any robot put another's state (a spoofed e-stop reached the
operators), declare another's liveliness token and hear every robot's commands. The router
instead admits the robots listed in a fleet file (``deploy/robots.toml``) and gives each one
rules naming its own keys: put its state and acks, declare its own liveliness token, subscribe
to its own commands, its groups' commands and the ECL's change notices, and read the ECL.
Zenoh's access control has no per-certificate key templates, so the rules are generated, one
subject and one policy per robot, and appended to the router config's ``access_control`` at
start (``kinesphere router --robots FILE``; ``--print-acl`` shows them).
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any, Final

import msgspec
import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import DEFAULT_PREFIX, Keys, check_segment

ROLES: Final = frozenset({"router", "databank", "agent", "operator", "superuser"})
"""Certificate common names that name a role: never a robot id."""
SHARED_RULES: Final = ("ecl-read", "deliver")
"""Rules of the role config every robot also gets (read the ECL, be delivered what it
subscribed to); ``kinesphere router`` checks that the config defines them."""


class RobotEntry(msgspec.Struct, forbid_unknown_fields=True):
    """One admitted robot: the groups whose commands it obeys (``agent --group``)."""

    groups: list[str] = []


class FleetFile(msgspec.Struct, forbid_unknown_fields=True):
    """A fleet file: the key prefix and every robot the router admits, by id."""

    robots: dict[str, RobotEntry]
    prefix: str = DEFAULT_PREFIX


def load_fleet(path: Path) -> FleetFile:
    """Read and check a fleet file (TOML); malformed names the problem."""
    try:
        fleet = msgspec.convert(tomllib.loads(path.read_text(encoding="utf-8")), FleetFile)
    except OSError as exc:
        raise KinesphereError("malformed", f"fleet file {path}: {exc.strerror}") from None
    except (tomllib.TOMLDecodeError, msgspec.ValidationError) as exc:
        raise KinesphereError("malformed", f"fleet file {path}: {exc}") from None
    check_fleet(fleet, str(path))
    return fleet


def check_fleet(fleet: FleetFile, where: str = "fleet") -> FleetFile:
    Keys(fleet.prefix)
    if not fleet.robots:
        raise KinesphereError("malformed", f"{where}: no robots")
    for rid, entry in fleet.robots.items():
        check_segment(rid, "robot id")
        if rid in ROLES:
            raise KinesphereError(
                "malformed", f"{where}: robot id {rid!r} is a role's certificate name; "
                f"robot ids may not be {', '.join(sorted(ROLES))}")
        for group in entry.groups:
            check_segment(group, f"group of {rid}")
    return fleet


def robot_acl(fleet: FleetFile) -> dict[str, list[dict[str, Any]]]:
    """The ``rules``, ``subjects`` and ``policies`` that admit each robot of ``fleet``."""
    keys = Keys(fleet.prefix)
    out: dict[str, list[dict[str, Any]]] = {"rules": [], "subjects": [], "policies": []}
    for rid, entry in sorted(fleet.robots.items()):
        own = [
            ("put", [keys.state(rid), keys.ack(rid)]),
            ("liveliness_token", [keys.alive_robot(rid)]),
            ("declare_subscriber", [keys.command(rid), keys.changed("*"),
                                    *(keys.group_command(g) for g in entry.groups)]),
        ]
        ids = []
        for message, key_exprs in own:
            ids.append(f"robot:{rid}:{message}")
            out["rules"].append({"id": ids[-1], "messages": [message], "flows": ["ingress"],
                                 "permission": "allow", "key_exprs": key_exprs})
        out["subjects"].append({"id": f"robot:{rid}", "cert_common_names": [rid]})
        out["policies"].append({"id": f"robot:{rid}", "rules": [*ids, *SHARED_RULES],
                                "subjects": [f"robot:{rid}"]})
    return out


def _get(config: zenoh.Config, key: str) -> Any:
    try:
        return json.loads(config.get_json(key))
    except (zenoh.ZError, ValueError):
        return None


def add_robots(config: zenoh.Config, fleet: FleetFile) -> int:
    """Append ``fleet``'s rules to ``config``'s access control; returns the robot count.

    The config must have access control enabled and define the shared rules; a robot id that
    is already a subject id is refused (it would be admitted twice)."""
    if _get(config, "access_control/enabled") is not True:
        raise KinesphereError("malformed", "--robots needs a config with access_control enabled "
                              "(deploy/router.json5)")
    acl = robot_acl(fleet)
    current = {part: _get(config, f"access_control/{part}") or [] for part in acl}
    rule_ids = {r.get("id") for r in current["rules"]}
    missing = [r for r in SHARED_RULES if r not in rule_ids]
    if missing:
        raise KinesphereError("malformed", f"the router config lacks the rules {missing} that "
                              "every robot is given")
    taken = {s.get("id") for s in current["subjects"]} & {s["id"] for s in acl["subjects"]}
    if taken:
        raise KinesphereError("conflict", f"subjects {sorted(taken)} are defined twice")
    for part, extra in acl.items():
        try:
            config.insert_json5(f"access_control/{part}", json.dumps(current[part] + extra))
        except zenoh.ZError as exc:
            raise KinesphereError("malformed", f"access_control/{part}: {exc}") from None
    return len(fleet.robots)
