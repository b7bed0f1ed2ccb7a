"""The ``kinesphere`` command: a dispatcher whose sub-commands the roles register.

Roles plug in through the ``kinesphere.commands`` entry-point group, so this core module
never imports a role; a role that is not installed simply has no commands.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable, Iterable, Sequence
from importlib.metadata import EntryPoint, entry_points, version
from pathlib import Path
from typing import Any

from kinesphere.cliargs import (
    PLATFORMS_ENV,
    Subcommands,
    add_merge_distance,
    add_output,
    add_platforms_argument,
    command,
    use_platform_dirs,
)
from kinesphere.errors import KinesphereError

ROLE_COMMANDS: dict[str, tuple[str, ...]] = {
    "kinesphere-platforms": ("describe", "platform", "platforms"),
    "kinesphere-robots": ("agent", "fleet"),
    "kinesphere-services": ("databank", "ecl", "pose", "query"),
    "kinesphere-clients": ("estop", "gamepad", "lease", "play", "record", "replay", "ros2", "send",
                           "view"),
    "kinesphere-deploy": ("film", "router", "status", "up"),
}
"""Which distribution brings which command, so a host without it can say what to install
(names only: the core imports no role). A test keeps it equal to the registered commands."""


def _register_core(sub: Subcommands) -> None:
    p = command(sub, "label", _label)
    p.add_argument("urdf", type=Path, help="a plain URDF file")
    add_merge_distance(p)
    add_output(p, "the eURDF", default="stdout")


def _label(args: argparse.Namespace) -> int:
    """propose an eURDF (body_part labels) for a plain URDF file

    Derive the paper's hierarchical labels (c_1, limb_ij, distal_ij) from a URDF tree and print the
    eURDF; edit it, then check it with 'kinesphere describe FILE'.
    """
    from kinesphere.labeller import propose_eurdf

    text = propose_eurdf(args.urdf, merge_distance=args.merge_distance)
    if args.output:
        args.output.write_text(text, encoding="utf-8")
        print(f"wrote {args.output}", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


def _root() -> tuple[argparse.ArgumentParser, Subcommands]:
    """The command line with the core's options and commands, and where roles add theirs."""
    parser = argparse.ArgumentParser(
        prog="kinesphere",
        description="Steer any robot with Laban spatial commands: (limb, origin, direction, size).",
    )
    parser.add_argument(
        "--version", action="version", version=f"kinesphere {version('kinesphere')}"
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    add_platforms_argument(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _register_core(sub)
    return parser, sub


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole command line, every installed role's commands registered; with ``command``,
    only the role that brings it (the core's and :data:`ROLE_COMMANDS`' word for it): the
    other roles' modules are then never imported, ~0.1 s of CPU less per process start. An
    unknown ``command``, or one whose role is not installed, registers every role."""
    parser, sub = _root()
    roles = sorted(entry_points(group="kinesphere.commands"), key=lambda e: e.name)
    owner = next((d for d, names in ROLE_COMMANDS.items() if command in names), None)
    if command in sub.choices:
        roles = []
    elif owner is not None and any(_dist_of(ep) == owner for ep in roles):
        roles = [ep for ep in roles if _dist_of(ep) == owner]
    for ep in roles:
        try:
            register: Callable[[Any], None] = ep.load()
        except ModuleNotFoundError as exc:
            if exc.name and ep.module.startswith(exc.name):
                continue  # that role is not part of this installation
            raise
        register(sub)
    _platforms_everywhere(parser)
    return parser


def _dist_of(ep: EntryPoint) -> str | None:
    """The distribution that declares ``ep``, spelt as :data:`ROLE_COMMANDS` spells it."""
    return None if ep.dist is None else str(ep.dist.metadata["Name"])


def _platforms_everywhere(parser: argparse.ArgumentParser) -> None:
    """Every sub-command also takes --platforms DIR after its name."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in dict.fromkeys(action.choices.values()):
                add_platforms_argument(child)
                _platforms_everywhere(child)


def commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The sub-commands ``parser`` offers on this host."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def missing_role(command: str, offered: Iterable[str]) -> str | None:
    """The message for a command whose distribution is not installed here, else None."""
    if command in offered:
        return None
    dist = next((d for d, names in ROLE_COMMANDS.items() if command in names), None)
    if dist is None:
        return None
    return (f"'kinesphere {command}' comes with {dist}, which is not installed on this host "
            f"(pip install {dist}); this host runs: {', '.join(sorted(offered))}")




def _command_word(parser: argparse.ArgumentParser, words: Sequence[str]) -> str | None:
    """The sub-command in ``words``: the first word that is no option nor an option's value."""
    valued = {o for a in parser._actions if a.option_strings and a.nargs != 0
              for o in a.option_strings}
    rest = iter(words)
    for word in rest:
        if word in valued:
            next(rest, None)
        elif not word.startswith("-"):
            return word
    return None


def main(argv: Sequence[str] | None = None,
         parser: argparse.ArgumentParser | None = None) -> int:
    """Run one ``kinesphere`` command line (``sys.argv`` when ``argv`` is None). ``parser``: one
    :func:`build_parser` made, for a program that runs many commands in one process (building
    it costs ~25 ms, as much as refusing a small URDF); parsing leaves it as it was."""
    words = list(sys.argv[1:] if argv is None else argv)
    parser = parser or build_parser(_command_word(_root()[0], words))
    command = _command_word(parser, words)
    message = None if command is None else missing_role(command, commands(parser))
    if message is not None:
        print(f"error: {message} [unavailable]", file=sys.stderr)
        return 2
    args = parser.parse_args(words)
    args.command_line = tuple(words)  # a command that starts copies of itself passes them on
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    func = getattr(args, "func", None)
    if func is None:
        parser.print_help()
        return 2
    saved = os.environ.get(PLATFORMS_ENV)
    use_platform_dirs(getattr(args, "platform_dirs", None) or ())
    try:
        return int(func(args) or 0)
    except KinesphereError as exc:
        print(f"error: {exc.message} [{exc.code}]", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `kinesphere describe --json | head`: the reader had enough
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit
        return 141  # as a process killed by SIGPIPE
    finally:  # main() called in-process (tests, embedding) leaves the environment as it was
        if saved is None:
            os.environ.pop(PLATFORMS_ENV, None)
        else:
            os.environ[PLATFORMS_ENV] = saved


if __name__ == "__main__":
    sys.exit(main())
