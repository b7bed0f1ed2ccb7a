"""Command-line options every role's sub-commands share: the ``zenoh`` option group.

Each role keeps its own rule for what happens when no endpoint is given (a databank listens,
agents and clients connect) and says so in ``default_help``; the options themselves are
spelled the same everywhere. Importing this module does not load Zenoh, so ``--help`` stays
quick.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from kinesphere.endpoints import DEFAULT_ENDPOINT
from kinesphere.keyexpr import DEFAULT_PREFIX


def add_zenoh_arguments(
    parser: argparse.ArgumentParser,
    *,
    default_help: str,
    listen: bool = True,
    modes: Sequence[str] = ("peer", "client"),
    default_mode: str = "peer",
) -> None:
    """Add the ``zenoh`` group: --connect, --listen (unless ``listen=False``), --zenoh-config,
    --mode and --prefix.

    ``default_help`` is the sentence describing what the command does without --connect,
    --listen or --zenoh-config; ``default_mode`` is only named in the help (the option's
    value stays None so the role can tell "not given" apart).
    """
    group = parser.add_argument_group("zenoh", description=default_help)
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
        help="Zenoh JSON5 config file (access control, TLS...); the options above override it",
    )
    group.add_argument(
        "--mode",
        choices=tuple(modes),
        default=None,
        help=f"Zenoh session mode (default {default_mode})",
    )
    group.add_argument(
        "--prefix",
        default=DEFAULT_PREFIX,
        help=f"key prefix shared by every process of a deployment (default {DEFAULT_PREFIX})",
    )


__all__ = ["DEFAULT_ENDPOINT", "add_zenoh_arguments"]
