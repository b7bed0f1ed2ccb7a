"""Who a command is for: one robot, a group, or every robot.

Groups are the robots' own: an agent started with ``--group field`` subscribes to
``{p}/group/field/command`` and lists ``field`` in its ``RobotState.groups``. So a client
addresses a group with one put on that key, and learns the members from the live robots'
states; nothing on the operator's side has to list them. Spelled ``group:NAME`` on the
command line (a robot and a group may share a name), ``all`` (or ``*``) for every robot
(``{p}/robot/*/command``), anything else is a robot id.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import WILDCARD, Keys, check_segment

ALL_NAMES = ("all", "*")
GROUP_PREFIX = "group:"


@dataclass(frozen=True)
class Target:
    """A robot (``kind="robot"``), a group (``"group"``) or all robots (``"all"``)."""

    kind: str
    name: str

    @property
    def is_all(self) -> bool:
        return self.kind == "all"

    def keys(self, keys: Keys) -> list[str]:
        """The one key to put on: the robot's, the group's, or the wildcard."""
        if self.kind == "group":
            return [keys.group_command(self.name)]
        return [keys.command(WILDCARD if self.is_all else self.name)]

    def includes(self, robot_id: str, groups: Iterable[str] = ()) -> bool:
        """Whether a robot with this id, obeying ``groups``, receives what is put here."""
        if self.kind == "group":
            return self.name in groups
        return self.is_all or robot_id == self.name

    @property
    def spelling(self) -> str:
        """How ``--target`` spells it."""
        return {"all": "all", "group": f"{GROUP_PREFIX}{self.name}"}.get(self.kind, self.name)

    @property
    def label(self) -> str:
        if self.is_all:
            return "all robots"
        return f"group {self.name}" if self.kind == "group" else self.name


ALL = Target("all", WILDCARD)


def robot(robot_id: str) -> Target:
    return Target("robot", check_segment(robot_id, "robot id"))


def group(name: str) -> Target:
    return Target("group", check_segment(name, "group name"))


def parse_target(text: str) -> Target:
    """``all`` or ``*``, ``group:NAME``, or a robot id."""
    if text in ALL_NAMES:
        return ALL
    try:
        if text.startswith(GROUP_PREFIX):
            return group(text[len(GROUP_PREFIX) :])
        return robot(text)
    except KinesphereError as exc:
        raise KinesphereError(
            "malformed",
            f"target {text!r} is not 'all', 'group:NAME' or a robot id ({exc.message})",
        ) from None


def members(target: Target, robots: Mapping[str, Sequence[str]]) -> list[str]:
    """The robots among ``robots`` (id -> its groups) that ``target`` reaches, sorted."""
    return sorted(rid for rid, groups in robots.items() if target.includes(rid, groups))


def cycle(current: Target, robots: Mapping[str, Sequence[str]]) -> Target:
    """The next target: each robot, then each group the robots report, then all robots."""
    options = [robot(r) for r in sorted(robots)]
    options += [group(g) for g in sorted({g for gs in robots.values() for g in gs})]
    options.append(ALL)
    for i, t in enumerate(options):
        if t == current:
            return options[(i + 1) % len(options)]
    return options[0]
