"""Who a command is for: one robot, a named group, or every robot.

Groups are lists of robot ids (``[groups] arms = ["baxter-1", "nao-1"]`` in a TOML file). A
group command is put on each member's own key ``{p}/robot/{id}/command``: robot ids are free
names, so no wildcard can pick "the arms" without also reaching robots that merely match it.
Only "all robots" uses the wildcard ``{p}/robot/*/command``, which is exactly what it means.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import WILDCARD, Keys, check_segment

ALL_NAMES = ("all", "*")


@dataclass(frozen=True)
class Target:
    """A robot (``kind="robot"``), a group, or all robots (``members`` empty)."""

    kind: str
    name: str
    members: tuple[str, ...] = ()

    @property
    def is_all(self) -> bool:
        return self.kind == "all"

    def keys(self, keys: Keys) -> list[str]:
        """Command keys to put on: the wildcard for all, else one per member."""
        if self.is_all:
            return [keys.command(WILDCARD)]
        return [keys.command(m) for m in self.members]

    def includes(self, robot_id: str) -> bool:
        return self.is_all or robot_id in self.members

    @property
    def label(self) -> str:
        if self.is_all:
            return "all robots"
        if self.kind == "group":
            return f"group {self.name}: {', '.join(self.members)}"
        return self.name


ALL = Target("all", WILDCARD)


def robot(robot_id: str) -> Target:
    return Target("robot", check_segment(robot_id, "robot id"), (robot_id,))


def parse_target(text: str, groups: Mapping[str, Sequence[str]]) -> Target:
    """``all`` or ``*``, a group name, or a robot id (a group shadows a robot of that name)."""
    if text in ALL_NAMES:
        return ALL
    if text in groups:
        return Target("group", text, tuple(groups[text]))
    try:
        return robot(text)
    except KinesphereError:
        known = ", ".join(sorted(groups)) or "none defined"
        raise KinesphereError(
            "malformed",
            f"target {text!r} is not 'all', a group ({known}) or a robot id "
            "(one key segment, no / * $ ? #)",
        ) from None


def cycle(current: Target, robots: Sequence[str], groups: Mapping[str, Sequence[str]]) -> Target:
    """The next target: each robot, then each group, then all robots, then round again."""
    options = [robot(r) for r in sorted(set(robots))]
    options += [Target("group", g, tuple(m)) for g, m in sorted(groups.items())]
    options.append(ALL)
    for i, t in enumerate(options):
        if (t.kind, t.name) == (current.kind, current.name):
            return options[(i + 1) % len(options)]
    return options[0]
