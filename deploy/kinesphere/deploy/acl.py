"""Per-robot and per-operator identity: each certificate speaks only for its own name.

A shared "agent" certificate let any robot put another's state (a spoofed e-stop reached the
operators), declare another's liveliness token and hear every robot's commands; a shared
"operator" certificate let every operator type any other's name into a command (move a robot
someone else leased, release someone else's e-stop). The router instead admits the robots and
operators listed in a fleet file (``deploy/robots.toml``) and gives each one rules naming its
own keys. A robot: put its state and acks, declare its own liveliness token, subscribe to its
own commands, its groups' commands and the ECL's change notices, read the ECL, and ask and
answer the fleet e-stops in force (``{p}/estop/*``: a board's key is its session id, so any
robot may answer any holder's key; a board's records are as trusted as the robots' own
certificates) and who runs its id (``{p}/robot/<id>/presence``). An
operator (certificate CN = the operator's name): put commands only under keys that end with
that name (``{p}/robot/*/command/<name>``, ``{p}/group/*/command/<name>``: clients sign every
command key so, :meth:`~kinesphere.keyexpr.Keys.signed`), read the ECL and watch; robots
take the sender from the key, a name the router vouches for. Zenoh's access control has no
per-certificate key templates (a rule's keys must include the key of each message), so the
rules are generated, one subject and one policy per name, and appended to the router
config's ``access_control`` at start (``kinesphere router --robots FILE``; ``--print-acl``
shows them).
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
"""Certificate common names that name a role: never a robot id or an operator's name."""
RESERVED: Final = ROLES | {"anonymous"}
"""Names no robot or operator may have (``anonymous`` is what a robot calls a command
without a sender)."""
SHARED_RULES: Final = ("ecl-read", "deliver")
"""Rules of the role config every robot also gets (read the ECL, be delivered what it
subscribed to); ``kinesphere router`` checks that the config defines them."""
OPERATOR_RULES: Final = ("ecl-read", "observe", "deliver")
"""Rules of the role config every operator also gets (read the ECL, watch the system)."""


class RobotEntry(msgspec.Struct, forbid_unknown_fields=True):
    """One admitted robot: the groups whose commands it obeys (``agent --group``)."""

    groups: list[str] = []


class OperatorEntry(msgspec.Struct, forbid_unknown_fields=True):
    """One admitted operator (certificate CN = the operator's name, the ``--sender``)."""


class FleetFile(msgspec.Struct, forbid_unknown_fields=True):
    """A fleet file: the key prefix, every robot the router admits by id, every operator by
    name."""

    robots: dict[str, RobotEntry]
    prefix: str = DEFAULT_PREFIX
    operators: dict[str, OperatorEntry] = {}


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
    for what, names in (("robot id", fleet.robots), ("operator", fleet.operators)):
        for name in names:
            check_segment(name, what)
            if name in RESERVED:
                raise KinesphereError(
                    "malformed", f"{where}: {what} {name!r} is a role's certificate name; "
                    f"names may not be {', '.join(sorted(RESERVED))}")
    both = sorted(set(fleet.robots) & set(fleet.operators))
    if both:
        raise KinesphereError("malformed", f"{where}: {both[0]!r} is both a robot and an "
                              "operator (one certificate name, one identity)")
    for rid, entry in fleet.robots.items():
        for group in entry.groups:
            check_segment(group, f"group of {rid}")
    return fleet


def fleet_acl(fleet: FleetFile) -> dict[str, list[dict[str, Any]]]:
    """The ``rules``, ``subjects`` and ``policies`` that admit each robot and operator of
    ``fleet``."""
    keys = Keys(fleet.prefix)
    out: dict[str, list[dict[str, Any]]] = {"rules": [], "subjects": [], "policies": []}

    def admit(kind: str, name: str, own: list[tuple[str, list[str]]],
              shared: tuple[str, ...]) -> None:
        """``own``: (message, key expressions) it may send; ``message:egress``: that the
        router may deliver to it (beyond the shared ``deliver`` rule)."""
        ids = []
        for message, key_exprs in own:
            what, _, flow = message.partition(":")
            ids.append(f"{kind}:{name}:{message}")
            out["rules"].append({"id": ids[-1], "messages": [what],
                                 "flows": [flow or "ingress"], "permission": "allow",
                                 "key_exprs": key_exprs})
        out["subjects"].append({"id": f"{kind}:{name}", "cert_common_names": [name]})
        out["policies"].append({"id": f"{kind}:{name}", "rules": [*ids, *shared],
                                "subjects": [f"{kind}:{name}"]})

    for rid, entry in sorted(fleet.robots.items()):
        commands = [keys.command(rid), *(keys.group_command(g) for g in entry.groups)]
        admit("robot", rid, [
            ("put", [keys.state(rid), keys.ack(rid)]),
            ("liveliness_token", [keys.alive_robot(rid)]),
            # the fleet e-stops in force and who else claims this id: asked, and answered
            # (the holder of a board is a session id, so any holder's key)
            *((message, [keys.fleet_estops("*"), keys.presence(rid)]) for message in (
                "query", "declare_queryable", "reply", "query:egress")),
            ("declare_subscriber", [*(Keys.subscribed(k) for k in commands),
                                    keys.changed("*")]),
        ], SHARED_RULES)
    for name in sorted(fleet.operators):
        admit("operator", name, [
            ("put", [Keys.signed(keys.command("*"), name),
                     Keys.signed(f"{keys.prefix}/group/*/command", name)]),
        ], OPERATOR_RULES)
    return out


def _get(config: zenoh.Config, key: str) -> Any:
    try:
        return json.loads(config.get_json(key))
    except (zenoh.ZError, ValueError):
        return None


def add_fleet(config: zenoh.Config, fleet: FleetFile) -> int:
    """Append ``fleet``'s rules to ``config``'s access control; returns how many robots and
    operators it admits.

    The config must have access control enabled and define the shared rules; a name that
    is already a subject id is refused (it would be admitted twice)."""
    if _get(config, "access_control/enabled") is not True:
        raise KinesphereError("malformed", "--robots needs a config with access_control enabled "
                              "(deploy/router.json5)")
    acl = fleet_acl(fleet)
    current = {part: _get(config, f"access_control/{part}") or [] for part in acl}
    rule_ids = {r.get("id") for r in current["rules"]}
    missing = [r for r in dict.fromkeys((*SHARED_RULES, *OPERATOR_RULES)) if r not in rule_ids]
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
    return len(fleet.robots) + len(fleet.operators)
