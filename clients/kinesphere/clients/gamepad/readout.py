"""What the operator reads after each tick: the HUD's whole input, made by the streaming loop.

The loop (:mod:`kinesphere.clients.gamepad.teleop`) makes one per tick and the HUD
(:mod:`kinesphere.clients.gamepad.hud`) draws it; neither needs the other to know its shape.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from kinesphere.clients import targets as tg
from kinesphere.clients.gamepad.mapping import Intent
from kinesphere.clients.link import AckAnswer, Seen
from kinesphere.laban import Direction


@dataclass(frozen=True)
class Readout:
    """Everything the HUD shows after a tick: what the robots are about to do and are doing."""

    target: tg.Target
    limb: str
    origin: str
    aliases: dict[str, str]
    intent: Intent
    engaged: bool
    deadman_required: bool
    estopped: bool
    remote_estop: list[str]
    need_fresh_deadman: bool
    connected: bool
    source: str
    robots: dict[str, Seen]
    seq: int
    message: str
    catalogue_errors: dict[str, str] = field(default_factory=dict)
    members: list[str] = field(default_factory=list)
    """The robots heard from that the target reaches."""
    sender: str = ""
    """This operator's sender id (robots name it as their lease holder or e-stop latcher)."""
    answers: dict[str, AckAnswer] = field(default_factory=dict)
    """Each robot's answer to this operator's commands (``report.current_answer``: what it
    does with them now), and when it came."""
    notice: str = ""
    """A standing problem the operator must see (nobody hears the target; robots refusing us
    for another's lease)."""
    unheard: bool = False
    """Nobody the target names is heard: the commands reach nobody."""
    stick_holds: bool = False
    """Engaged with the stick still centred since the deadman was pressed: the limb holds."""
    presses: dict[str, str] = field(default_factory=dict)
    """What the operator presses for an action on the current input (``Start``, ``Enter``)."""
    input_name: str = ""
    """Which device the hands come from."""
    available: frozenset[Direction] | None = None
    """Directions the limb has poses for (None: no catalogue yet)."""
    asked: Direction | None = None
    """The direction the stick asked for, when the nearest available one replaced it."""
    limb_holds: bool = False
    """No targeted body has a pose near the stick's direction: the command carries the drive
    alone and the limb holds (rather than every robot refusing the whole command)."""
