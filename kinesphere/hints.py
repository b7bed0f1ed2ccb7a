"""Every command kinesphere tells a user to run, built in one place so a test runs each one.

A message that says "start it with 'kinesphere router'" is a promise: the command must exist,
take those options and do what the message says. Each function here returns one such
command as a :class:`Hint` (the words after ``kinesphere``, spelled as a user types them);
messages interpolate it (``f"start one with '{hints.router()}'"``). No other module spells a
``kinesphere ...`` command in a message, and ``tests/system/test_hints.py`` runs every hint
below in the situation that prints it (a source scan keeps the first rule).

Placeholders (``FILE``, ``PLATFORM``) are not runnable: a hint names the real file, robot or
platform of the message it ends.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass

from kinesphere.endpoints import DEFAULT_ENDPOINT


@dataclass(frozen=True)
class Hint:
    """A command line: ``argv`` are the words after ``kinesphere``."""

    argv: tuple[str, ...]

    def __str__(self) -> str:
        return shlex.join(("kinesphere", *self.argv))


def _hint(*argv: str) -> Hint:
    return Hint(tuple(argv))


def router(endpoint: str = DEFAULT_ENDPOINT) -> Hint:
    """A router listening where a session tried to connect (plain TCP only: TLS needs its
    deployment's config, see :func:`can_start_router`)."""
    if endpoint == DEFAULT_ENDPOINT:
        return _hint("router")
    return _hint("router", "--listen", endpoint)


def can_start_router(endpoint: str) -> bool:
    """Whether :func:`router` starts a router for ``endpoint`` as it is (TCP or UDP, no TLS)."""
    return endpoint.split("/", 1)[0] in ("tcp", "udp")


def release_estop(target: str, sender: str = "") -> Hint:
    """Release ``sender``'s e-stop latch on ``target`` (a robot id, ``group:NAME`` or ``all``)."""
    words = ["estop", "--release", "--target", target]
    if sender:
        words += ["--sender", sender]
    return _hint(*words)


def take_lease(target: str) -> Hint:
    """Take control of ``target`` from the operator holding it."""
    return _hint("lease", "take", target)


def status() -> Hint:
    """Every live robot and what it last said."""
    return _hint("status")


def describe(platform: str) -> Hint:
    """Check a platform (name or folder)."""
    return _hint("describe", platform)


def build_ecl(platform: str) -> Hint:
    """Build (or rebuild) a platform's databank (a name, or a brought robot's folder)."""
    return _hint("ecl", "build", platform)


def platforms() -> Hint:
    """The platforms this host knows."""
    return _hint("platforms")


def new_platform(name: str, urdf: str) -> Hint:
    """A platform folder proposed from a URDF (how a brought robot's files began)."""
    return _hint("platform", "new", name, "--urdf", urdf)


def serve_databank(platform: str = "", db: str = "", allow_writes: bool = False) -> Hint:
    """A databank serving ``platform`` (every shipped one without it), from its databank
    file ``db`` when given (``PLATFORM=PATH``: the file a running databank serves)."""
    words = ["databank", "serve"]
    if db:
        words += ["--db", f"{platform}={db}" if platform else db]
    elif platform:
        words += ["--platform", platform]
    if allow_writes:
        words.append("--allow-writes")
    return _hint(*words)


def start_agent(platform: str, robot_id: str) -> Hint:
    """A robot of ``platform`` with the id ``robot_id``."""
    return _hint("agent", platform, "--id", robot_id)


def replay(path: str, restamp: bool = False) -> Hint:
    """A ``kinesphere record`` session put back on Zenoh (``--restamp``: as new commands)."""
    return _hint("replay", path, *(["--restamp"] if restamp else []))


def replay_ticks(path: str) -> Hint:
    """A gamepad recording's controller ticks mapped again (no pad needed)."""
    return _hint("gamepad", "--replay", path, "--headless")
