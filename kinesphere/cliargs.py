"""Command-line options every role's sub-commands share: the ``zenoh`` option group, and one
function per option family more than one role's commands take (output file, JSON, waiting for
answers, the bodies shown side by side, the platform search path, the key prefix, ROS 2 domain
and distribution, joint merging). A family's default comes from its caller's options
dataclass (or a constant here), never repeated in a parser; its help is written once.

One rule for every command (after zenoh-python's ``examples/common/common.py``): the session
starts from ``--zenoh-config FILE`` (or Zenoh's defaults), ``--mode``, ``--connect`` and
``--listen`` override it, and ``--cfg KEY:VALUE`` pairs are applied last. Given none of
``--connect``, ``--listen`` and ``--zenoh-config``, a command uses its :class:`ZenohDefaults`
(a databank listens, agents and clients connect), declared once where its parser is built and
named in its ``--help``. :func:`kinesphere.zconfig.session_from_args` applies the rule.
Importing this module does not load Zenoh, so ``--help`` stays quick.
"""

from __future__ import annotations

import argparse
import inspect
import os
import textwrap
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeAlias

from kinesphere import hints
from kinesphere.endpoints import DEFAULT_ENDPOINT, LOOPBACK_ANY_PORT
from kinesphere.keyexpr import DEFAULT_PREFIX


@dataclass(frozen=True)
class ZenohDefaults:
    """What a command does when given no --connect, --listen or --zenoh-config.

    ``listen=None`` keeps Zenoh's own listen endpoints (all interfaces, a random port); a
    Zenoh client never listens, so in client mode ``listen`` is not used. ``fallback`` is tried
    when a session with these endpoints cannot open (a databank whose port is taken joins the
    one holding it). ``mode`` is also the mode without --mode and without a config file.
    """

    connect: tuple[str, ...] = (DEFAULT_ENDPOINT,)
    listen: tuple[str, ...] | None = None
    mode: str = "peer"
    fallback: ZenohDefaults | None = None
    note: str = ""
    """A sentence the help adds after the rule, e.g. who listens on the endpoint."""

    def describe(self) -> str:
        """The help sentence: what the command does without endpoint options."""

        def where(endpoints: tuple[str, ...]) -> str:
            return ", ".join(
                "loopback, any port" if ep == LOOPBACK_ANY_PORT else ep for ep in endpoints
            )

        def action(d: ZenohDefaults) -> str:
            parts = []
            if d.connect:
                parts.append(f"connect to {where(d.connect)}")
            if d.listen:
                parts.append(f"listen on {where(d.listen)}")
            if d.listen == () and d.mode != "client":
                parts.append("listen nowhere")
            return " and ".join(parts) or "open a session without endpoints"

        text = action(self)
        if self.fallback is not None:
            text += f", or {action(self.fallback)} if that fails"
        if self.mode != "peer":
            text += f" (as a Zenoh {self.mode})"
        return f"{text}.{' ' + self.note if self.note else ''}"


HUB = f"'{hints.router()}' listens there (the hub, which serves nothing else)."
"""Every process joins the router at the well-known endpoint, never a service: a databank or
an agent killed -9 takes nothing down with it."""
AGENT = ZenohDefaults(listen=(LOOPBACK_ANY_PORT,), note=HUB)
"""Robots join the router and accept peers on loopback only."""
OPERATOR = ZenohDefaults(listen=(LOOPBACK_ANY_PORT,), note=HUB)
"""Operator commands join the router."""
SERVICE = ZenohDefaults(listen=(LOOPBACK_ANY_PORT,), note=HUB)
"""A databank joins the router like everyone else (it is no hub: killed, nothing else stops)."""
QUERY = ZenohDefaults(mode="client", note=HUB)
"""A one-shot question joins the router as a client."""
WATCHER = ZenohDefaults(mode="client", note=HUB)
"""A short-lived observer (``status``) joins the router as a client: the router answers for
everyone at once, where a peer would first have to discover the others."""


Subcommands: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"
"""Where a role registers its commands (``kinesphere.commands`` entry points get one)."""


class LaidOutHelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs kept line by line as written, each line wrapped to the
    terminal unless it starts with a space: an example command or a row of a table is laid
    out by hand, a sentence is not (argparse's raw formatter left sentences hundreds of
    characters wide; its default one runs the examples and tables together)."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        lines = [indent + line if not line.strip() or line[0].isspace()
                 else textwrap.fill(line, width, initial_indent=indent, subsequent_indent=indent)
                 for line in text.splitlines()]
        return "\n".join(lines) + ("\n" if text.endswith("\n") else "")


def command(sub: Subcommands, name: str, run: Callable[[argparse.Namespace], int],
            help: str | None = None, description: str | None = None,
            **more: Any) -> argparse.ArgumentParser:
    """Register the sub-command ``name`` that ``run`` handles; ``help`` is its line in the
    list of commands, ``description`` heads its own ``--help`` (``more``: epilog, a
    formatter). The caller adds the options to the parser returned.

    Without ``help``, both come from ``run``'s docstring, as click and typer read one: the
    handler is documented by the text its users read. Given here, they are for a lambda, a
    trampoline into another module, or a description laid out by hand (a raw formatter)."""
    if help is None:
        help, description = handler_texts(run)
    parser: argparse.ArgumentParser = sub.add_parser(name, help=help, description=description,
                                                     **more)
    parser.set_defaults(func=run)
    return parser


def handler_texts(run: Callable[..., object]) -> tuple[str, str | None]:
    """A handler's docstring as a command's texts: the first paragraph is its line in the list
    of commands, the rest its description (argparse wraps them, so each paragraph's line
    breaks are only the source's). ``python -OO`` strips docstrings: then there are none."""
    doc = inspect.getdoc(run) or ""
    paragraphs = [" ".join(p.split()) for p in doc.split("\n\n") if p.strip()]
    return (paragraphs[0] if paragraphs else "", "\n\n".join(paragraphs[1:]) or None)


def command_group(sub: Subcommands, name: str, help: str, description: str | None = None, *,
                  dest: str, metavar: str = "COMMAND", required: bool = True) -> Subcommands:
    """Register ``name`` as a word that takes sub-commands of its own (``kinesphere ecl
    build``), named in ``args.<dest>``; returns where to register them."""
    parser = sub.add_parser(name, help=help, description=description)
    group: Subcommands = parser.add_subparsers(dest=dest, metavar=metavar, required=required)
    return group


def add_zenoh_arguments(
    parser: argparse.ArgumentParser,
    defaults: ZenohDefaults = OPERATOR,
    *,
    listen: bool = True,
    modes: Sequence[str] = ("peer", "client"),
) -> None:
    """Add the ``zenoh`` group: --connect, --listen (unless ``listen=False``: then the
    defaults' listen endpoints always apply without a config file), --zenoh-config, --cfg,
    --mode and --prefix; ``defaults`` go into the parsed arguments for
    :func:`kinesphere.zconfig.session_from_args`."""
    given = "--connect, --listen or --zenoh-config" if listen else "--connect or --zenoh-config"
    group = parser.add_argument_group(
        "zenoh", description=f"Without {given}: {defaults.describe()}"
    )
    group.add_argument(
        "--connect",
        action="append",
        metavar="EP",
        help="endpoint to join, e.g. tcp/10.0.0.5:7447 (repeatable)",
    )
    if listen:
        group.add_argument(
            "--listen",
            action="append",
            metavar="EP",
            help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)",
        )
    group.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help="Zenoh JSON5 config file (access control, TLS...); the options here override it",
    )
    group.add_argument(
        "--cfg",
        action="append",
        default=[],
        metavar="KEY:VALUE",
        help="set one Zenoh config KEY to a JSON5 VALUE, applied last (repeatable), e.g. "
        "--cfg 'transport/link/tx/lease:3000'",
    )
    group.add_argument(
        "--mode",
        choices=tuple(modes),
        default=None,
        help=f"Zenoh session mode (default {defaults.mode}, or the config file's)",
    )
    add_prefix(group)
    parser.set_defaults(zenoh_defaults=defaults)
    if not listen:
        parser.set_defaults(listen=None, zenoh_fixed_listen=True)


def add_prefix(parser: argparse.ArgumentParser | argparse._ArgumentGroup,
               default: str = DEFAULT_PREFIX) -> None:
    """``--prefix``: the key prefix of a deployment."""
    parser.add_argument(
        "--prefix", default=default,
        help=f"key prefix shared by every process of a deployment (default {default})",
    )


def add_output(parser: argparse.ArgumentParser, what: str, *, default: str | None = None,
               metavar: str = "FILE") -> None:
    """``-o/--output FILE``: where a command writes ``what``; required unless the command
    has a ``default`` (named in the help)."""
    parser.add_argument(
        "-o", "--output", type=Path, required=default is None, metavar=metavar,
        help=f"{what} to write" + (f" (default {default})" if default is not None else ""),
    )


def add_json(parser: argparse.ArgumentParser, what: str) -> None:
    """``--json``: print ``what`` as JSON instead of text for people."""
    parser.add_argument("--json", action="store_true", help=f"print {what} as JSON")


def _add_seconds(parser: argparse.ArgumentParser, flag: str, default: float, what: str,
                 then: str = "") -> None:
    parser.add_argument(flag, type=float, default=default, metavar="S",
                        help=f"wait up to S seconds for {what} (default {default:g})"
                        + (f"; {then}" if then else ""))


def add_timeout(parser: argparse.ArgumentParser, default: float, what: str, *,
                then: str = "") -> None:
    """``--timeout S``: how long a command waits for ``what`` (its answers); ``then`` says
    what follows when they do not come."""
    _add_seconds(parser, "--timeout", default, what, then)


def add_wait(parser: argparse.ArgumentParser, default: float, what: str) -> None:
    """``--wait S``: how long a command waits for ``what`` before it starts."""
    _add_seconds(parser, "--wait", default, what)


def add_score_options(parser: argparse.ArgumentParser, every: str) -> None:
    """``--gesture NAME`` and ``--speed X``: which gesture of a Labanotation score, how fast
    (``every``: what the command does without ``--gesture``)."""
    parser.add_argument("--gesture", metavar="NAME",
                        help=f"a score: only this gesture (default: {every})")
    parser.add_argument("--speed", type=float, metavar="X",
                        help="a score: X times as fast as its own times (default: 1)")


def platform_list(text: str) -> list[str]:
    """``baxter, nao`` -> ``["baxter", "nao"]`` (empty items dropped)."""
    return [name for name in (n.strip() for n in text.split(",")) if name]


def add_bodies(parser: argparse.ArgumentParser, default: Sequence[str] | None = None) -> None:
    """``--bodies A,B``: the platforms whose bodies a command shows side by side, a list in
    ``args.bodies``; without it ``default``, or None for every platform found. (``--platforms``
    is the folder search path, taken by every command.)"""
    parser.add_argument(
        "--bodies", type=platform_list, metavar="A,B",
        default=None if default is None else list(default),
        help="the platforms' bodies shown side by side, comma-separated (default: "
        + ("every platform found" if default is None else ",".join(default)) + ")",
    )


MERGE_DISTANCE_M = 0.01
"""Joints closer than this (metres) form one joint location when labels are proposed
(:mod:`kinesphere.labeller`); here so that ``--help`` needs no URDF library."""


def add_merge_distance(parser: argparse.ArgumentParser) -> None:
    """``--merge-distance M``: how close joints are to count as one joint location."""
    parser.add_argument(
        "--merge-distance", type=float, default=MERGE_DISTANCE_M, metavar="M",
        help=f"joints closer than M metres form one joint location (default {MERGE_DISTANCE_M})",
    )


def add_ros_distro(parser: argparse.ArgumentParser | argparse._ArgumentGroup, default: str,
                   whose: str, note: str = "") -> None:
    """``--ros-distro``: the ROS 2 distribution of ``whose`` rmw_zenoh (``note``: what it
    changes)."""
    from kinesphere.rmw_zenoh import ROS_DISTROS

    parser.add_argument("--ros-distro", choices=ROS_DISTROS, default=default,
                        help=f"ROS 2 distribution of {whose} rmw_zenoh"
                        + (f"; {note}" if note else "") + f" (default {default})")


def add_ros_domain(parser: argparse.ArgumentParser | argparse._ArgumentGroup, default: int,
                   of: str = "", *, alias: str | None = None) -> None:
    """``--ros2-domain N``: the ROS domain id (``ROS_DOMAIN_ID``) ``of`` what; ``alias`` is a
    second spelling a command took before (``args.ros2_domain`` either way)."""
    flags = ["--ros2-domain"] + ([alias] if alias else [])
    parser.add_argument(*flags, dest="ros2_domain", type=int, default=default, metavar="N",
                        help=f"ROS domain id{' of ' + of if of else ''} (ROS_DOMAIN_ID; default "
                        f"{default})")


PLATFORMS_ENV = "KINESPHERE_PLATFORMS"
"""Folders holding platform folders (os.pathsep-separated), searched after the shipped ones."""


def add_platforms_argument(parser: argparse.ArgumentParser) -> None:
    """``--platforms DIR`` (repeatable): where to find platform folders by name."""
    parser.add_argument(
        "--platforms",
        dest="platform_dirs",
        action="append",
        metavar="DIR",
        default=argparse.SUPPRESS,
        help=f"a folder of platform folders to find platforms in by name (repeatable; also "
        f"${PLATFORMS_ENV}, {os.pathsep}-separated)",
    )


def use_platform_dirs(dirs: Iterable[str | Path]) -> None:
    """Put folders first on the platform search path, for this process and its children
    (``kinesphere up`` starts agents and databanks that must find the same platforms)."""
    new = [str(Path(d).expanduser().resolve()) for d in dirs]
    old = [p for p in os.environ.get(PLATFORMS_ENV, "").split(os.pathsep) if p]
    os.environ[PLATFORMS_ENV] = os.pathsep.join(dict.fromkeys([*new, *old]))


__all__ = [
    "AGENT",
    "DEFAULT_ENDPOINT",
    "OPERATOR",
    "QUERY",
    "SERVICE",
    "WATCHER",
    "ZenohDefaults",
    "Subcommands",
    "command",
    "command_group",
    "add_zenoh_arguments",
    "PLATFORMS_ENV",
    "add_platforms_argument",
    "use_platform_dirs",
    "add_prefix",
    "add_output",
    "add_json",
    "add_timeout",
    "add_wait",
    "platform_list",
    "add_bodies",
    "MERGE_DISTANCE_M",
    "add_merge_distance",
    "add_ros_distro",
    "add_ros_domain",
]
