"""Zenoh key expressions of kinesphere, built and parsed in one place.

Every key starts with a configurable prefix (default ``kinesphere``) so several deployments can
share one Zenoh network. Names that become key segments are checked here: a ``/`` would shift
the segments, ``* $ ? #`` are Zenoh syntax, and a leading ``@`` makes a verbatim chunk that
wildcards never match (a robot called ``@r1`` would miss ``robot/*/command``). Where a method
documents it, ``"*"`` may stand for a segment to address all of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from kinesphere.errors import KinesphereError
from kinesphere.protocol import MAX_NAME
from kinesphere.sizes import parse_size

DEFAULT_PREFIX = "kinesphere"
WILDCARD = "*"
EXACT = "?exact=true"
"""Selector parameters for a pose query that wants the exact direction, no substitution."""
_FORBIDDEN = frozenset("/*$?#")


def check_segment(text: str, what: str = "name", *, wildcard: bool = False) -> str:
    """``text`` if it is one valid key segment (or ``"*"`` when ``wildcard``) of at most
    :data:`~kinesphere.protocol.MAX_NAME` characters, else malformed (quoting at most 80)."""
    if wildcard and text == WILDCARD:
        return text
    if not isinstance(text, str) or not text:
        raise KinesphereError("malformed", f"{what} must be a non-empty string, got {text!r:.80}")
    if len(text) > MAX_NAME:
        raise KinesphereError(
            "malformed", f"{what} {text[:40]!r}... has {len(text)} characters, at most "
            f"{MAX_NAME} allowed",
        )
    bad = sorted(set(text) & _FORBIDDEN)
    if bad:
        raise KinesphereError(
            "malformed", f"{what} {text!r} may not contain {' '.join(repr(c) for c in bad)}"
        )
    if text.startswith("@"):
        raise KinesphereError("malformed", f"{what} {text!r} may not start with '@'")
    return text


def format_size(size: float) -> str:
    """Compact key text of a size: ``3``, ``2.5``; rejects sizes out of range."""
    value = parse_size(size)
    if value.is_integer():
        return str(int(value))
    return repr(value)


class PoseKey(NamedTuple):
    """The parts of a pose key; ``size`` stays text so the ECL reports its own error code."""

    platform: str
    limb: str
    origin: str
    direction: str
    size: str


@dataclass(frozen=True)
class Keys:
    """Key expressions under ``prefix`` (one or more segments, e.g. ``lab2/kinesphere``)."""

    prefix: str = DEFAULT_PREFIX

    def __post_init__(self) -> None:
        if not isinstance(self.prefix, str) or not self.prefix:
            raise KinesphereError("malformed", "key prefix must be a non-empty string")
        for part in self.prefix.split("/"):
            check_segment(part, "key prefix segment")

    # --- ECL (databank) queryables ---------------------------------------------------------

    def pose(self, platform: str, limb: str, origin: str, direction: str, size: float) -> str:
        """Query key of one pose: ``{p}/ecl/{platform}/pose/{limb}/{origin}/{direction}/{size}``."""
        return "/".join(
            (
                self.prefix,
                "ecl",
                check_segment(platform, "platform"),
                "pose",
                check_segment(limb, "limb"),
                check_segment(origin, "origin"),
                check_segment(direction, "direction"),
                format_size(size),
            )
        )

    def pose_wildcard(self, platform: str) -> str:
        """What a pose queryable declares: ``{p}/ecl/{platform}/pose/**`` (platform may be *)."""
        return f"{self._ecl(platform)}/pose/**"

    def compound(self, platform: str) -> str:
        """Compound query, payload a CompoundRequest: ``{p}/ecl/{platform}/compound``."""
        return f"{self._ecl(platform)}/compound"

    def catalogue(self, platform: str) -> str:
        """Catalogue query: ``{p}/ecl/{platform}/catalogue``; ``*`` lists every platform."""
        return f"{self._ecl(platform)}/catalogue"

    def body(self, platform: str) -> str:
        """Body model query (answer a BodyModel): ``{p}/ecl/{platform}/body``."""
        return f"{self._ecl(platform)}/body"

    def record(self, platform: str) -> str:
        """Super-user write, payload a RecordRequest: ``{p}/ecl/{platform}/record``."""
        return f"{self._ecl(platform)}/record"

    def changed(self, platform: str) -> str:
        """Put by the databank after every successful record: ``{p}/ecl/{platform}/changed``.

        The payload is the recorded Pose; ``*`` watches every platform. Agents drop their
        cached poses on it.
        """
        return f"{self._ecl(platform)}/changed"

    def alive_databank(self, replica: str) -> str:
        """Liveliness token of one databank replica: ``{p}/alive/databank/{replica}``."""
        return f"{self.prefix}/alive/databank/{check_segment(replica, 'replica', wildcard=True)}"

    def alive_databank_all(self) -> str:
        """Every databank replica's token: ``{p}/alive/databank/*``."""
        return self.alive_databank(WILDCARD)

    # --- robots -----------------------------------------------------------------------------

    def command(self, robot_id: str) -> str:
        """Where Commands are put: ``{p}/robot/{id}/command``; ``*`` reaches every robot."""
        return f"{self._robot(robot_id)}/command"

    def state(self, robot_id: str) -> str:
        """Where a robot puts RobotState: ``{p}/robot/{id}/state``; ``*`` to watch all."""
        return f"{self._robot(robot_id)}/state"

    def ack(self, robot_id: str) -> str:
        """Where a robot puts an Ack for every command it receives: ``{p}/robot/{id}/ack``."""
        return f"{self._robot(robot_id)}/ack"

    def alive_robot(self, robot_id: str) -> str:
        """Liveliness token of a robot agent: ``{p}/alive/robot/{id}``; ``*`` for all."""
        return f"{self.prefix}/alive/robot/{check_segment(robot_id, 'robot id', wildcard=True)}"

    def presence(self, robot_id: str) -> str:
        """Where a robot says where it runs (queryable, :class:`Presence`):
        ``{p}/robot/{id}/presence``."""
        return f"{self._robot(robot_id)}/presence"

    def fleet_estops(self, holder: str) -> str:
        """Where a holder (an agent process) answers the fleet e-stops it knows
        (queryable, :class:`FleetEstops`): ``{p}/estop/{holder}``; ``*`` asks them all."""
        return f"{self.prefix}/estop/{check_segment(holder, 'holder', wildcard=True)}"

    def is_fleet_command(self, key: str) -> bool:
        """Whether a command key is every robot's (``{p}/robot/*/command``, signed or not):
        an e-stop put there is a fleet e-stop."""
        rest = str(key).split("/")[self.prefix.count("/") + 1:]
        return len(rest) in (3, 4) and rest[:3] == ["robot", WILDCARD, "command"]

    def group_command(self, group: str) -> str:
        """Commands for a named group: ``{p}/group/{group}/command``.

        Robot ids are free names, so a wildcard cannot pick e.g. "the two arms"; an agent
        started as a member of groups also subscribes here. Same Command message.
        """
        return f"{self.prefix}/group/{check_segment(group, 'group')}/command"

    @staticmethod
    def signed(command_key: str, sender: str) -> str:
        """A command key with its sender's name appended: ``{command key}/{sender}``.

        Clients put every command so; the deploy's access control lets each operator's
        certificate put only under its own name, so the robot takes the sender from the key
        (:meth:`sender_of`), a name the router vouches for, not from the payload."""
        return f"{command_key}/{check_segment(sender, 'sender')}"

    @staticmethod
    def subscribed(command_key: str) -> str:
        """What an agent subscribes to for ``command_key``: the key itself (a command without
        a name in its key) and every signed form, ``{command key}/**``."""
        return f"{command_key}/**"

    def sender_of(self, key: str) -> str:
        """The sender named by a robot or group command key: ``""`` for an unsigned one
        (``{p}/robot/{id}/command``), else its last segment; malformed for anything else."""
        key = str(key)
        n = self.prefix.count("/") + 1
        parts = key.split("/")
        rest = parts[n:]
        if "/".join(parts[:n]) == self.prefix and len(rest) in (3, 4) and \
                rest[0] in ("robot", "group") and rest[2] == "command":
            return check_segment(rest[3], "sender") if len(rest) == 4 else ""
        raise KinesphereError("malformed", f"{key!r:.200} is not a command key under "
                              f"{self.prefix!r} (.../command or .../command/<sender>)")

    # --- parsing ----------------------------------------------------------------------------

    def parse_pose_key(self, key: str) -> PoseKey:
        """Split a concrete pose key into its parts, or raise malformed naming the problem."""
        key = str(key)
        head = f"{self.prefix}/ecl/"
        parts = key[len(head) :].split("/") if key.startswith(head) else []
        if len(parts) != 6 or parts[1] != "pose":
            raise KinesphereError(
                "malformed",
                f"{key!r:.200} is not a pose key "
                f"{head}<platform>/pose/<limb>/<origin>/<direction>/<size>",
            )
        platform, _, limb, origin, direction, size = parts
        for what, text in zip(
            ("platform", "limb", "origin", "direction", "size"),
            (platform, limb, origin, direction, size),
            strict=True,
        ):
            check_segment(text, what)
        return PoseKey(platform, limb, origin, direction, size)

    def robot_id_of(self, key: str) -> str:
        """The robot id in a command, state or robot liveliness key."""
        key = str(key)
        parts = key.split("/")
        n = self.prefix.count("/") + 1
        if "/".join(parts[:n]) == self.prefix:
            rest = parts[n:]
            if len(rest) == 3 and rest[0] == "robot" and rest[2] in ("command", "state", "ack"):
                return check_segment(rest[1], "robot id")
            if len(rest) == 4 and rest[0] == "robot" and rest[2] == "command":  # signed
                return check_segment(rest[1], "robot id")
            if len(rest) == 3 and rest[:2] == ["alive", "robot"]:
                return check_segment(rest[2], "robot id")
        raise KinesphereError("malformed",
                              f"{key!r:.200} is not a robot key under {self.prefix!r}")

    def replica_of(self, key: str) -> str:
        """The replica name in a databank liveliness key."""
        key = str(key)
        head = f"{self.prefix}/alive/databank/"
        if not key.startswith(head) or "/" in key[len(head) :]:
            raise KinesphereError("malformed", f"{key!r:.200} is not a key {head}<replica>")
        return check_segment(key[len(head) :], "replica")

    def _ecl(self, platform: str) -> str:
        return f"{self.prefix}/ecl/{check_segment(platform, 'platform', wildcard=True)}"

    def _robot(self, robot_id: str) -> str:
        return f"{self.prefix}/robot/{check_segment(robot_id, 'robot id', wildcard=True)}"


KEYS = Keys()
"""Keys under the default prefix."""
