"""The databank's and the ECL's command-line option families, and the defaults they show.

``kinesphere ecl ...``, ``kinesphere pose`` and ``kinesphere query`` name a platform and its
databank file, the words of a spatial command, a cell and ``--exact`` the same way
everywhere. Cheap to import: the parsers are built before any handler runs.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from kinesphere import hints


@dataclass(frozen=True)
class QueryOptions:
    """How long a question over the network waits: ``timeout_s`` for a databank's answer,
    ``capture_timeout_s`` for a robot's next state (``ecl record --from-robot``)."""

    timeout_s: float = 2.0
    capture_timeout_s: float = 5.0


SHEET_SIZE = 3
"""The size a contact sheet (``ecl render``) shows unless told: far."""


def add_platform(parser: argparse.ArgumentParser, *, omit: str | None = None) -> None:
    """``PLATFORM`` and ``--db PATH``: the body whose databank a command reads or writes, and
    a databank file to use instead of its shipped one; ``omit`` says when PLATFORM may be
    left out."""
    parser.add_argument(
        "platform", nargs="?" if omit else None,
        help=f"platform name (see '{hints.platforms()}') or a platform folder"
        + (f" ({omit})" if omit else ""),
    )
    parser.add_argument("--db", type=Path, metavar="PATH",
                        help="databank file to use instead of the shipped databank of the "
                        "platform")


def add_spatial_words(parser: argparse.ArgumentParser) -> None:
    """``LIMB ORIGIN DIRECTION SIZE``: one spatial command, as the paper writes it."""
    parser.add_argument("limb", help="limb label or alias, e.g. limb_11 or right_arm")
    parser.add_argument("origin", help="origin (joint location) label or alias, e.g. distal_11")
    parser.add_argument("direction", help="Laban direction, e.g. left-high or 'Place Low'")
    parser.add_argument("size", help="size: 1 near, 2 mid, 3 far, fractions, past the largest "
                        "stored, or near/mid/far")


def add_exact(parser: argparse.ArgumentParser) -> None:
    """``--exact``: no substitution of a direction the limb lacks."""
    parser.add_argument("--exact", action="store_true",
                        help="this direction only: no substitution by the nearest one the limb "
                        "has")


def add_cell(parser: argparse.ArgumentParser, *, required: bool, direction: bool = True) -> None:
    """``--limb``, ``--origin`` (and ``--direction``): the cells a command works on, each
    ``required``, or else a filter."""
    words = {"limb": "limb label or alias", "origin": "origin label or alias paired with the limb",
             "direction": "Laban direction"}
    for word, what in words.items():
        if word != "direction" or direction:
            parser.add_argument(f"--{word}", required=required,
                                help=what if required else f"only this {word} ({what})")
