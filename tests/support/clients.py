"""Shared helpers for the client tests: real Zenoh on loopback, posted pygame events.

Nothing is mocked: robots are stood in for by real Zenoh subscribers (or, end to end, by real
agent processes), input comes from events posted into pygame's queue under SDL's dummy video
driver. Waits are on events (a message arriving, a state matching), never on sleeps; to show
that nothing *else* arrives, a sentinel is put behind the traffic on the same publisher and
awaited: Zenoh keeps one publisher's messages in order.
"""

from __future__ import annotations

import ctypes
import itertools
import os
import re
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Self

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import msgspec  # noqa: E402
import pygame  # noqa: E402
import zenoh  # noqa: E402

from kinesphere import zconfig  # noqa: E402
from kinesphere.clients.gamepad.inputs import pad  # noqa: E402
from kinesphere.clients.gamepad.state import ControllerState  # noqa: E402
from kinesphere.clients.link import RobotLink  # noqa: E402
from kinesphere.keyexpr import Keys  # noqa: E402
from kinesphere.protocol import (  # noqa: E402
    Ack,
    AckStage,
    Catalogue,
    Command,
    RobotState,
    Substitution,
    decode,
    encode,
)
from support.network import OWN_KEYS  # noqa: E402
from support.wait import WAIT_S  # noqa: E402
from support.watch import Watch  # noqa: E402

SENTINEL = "sentinel"
MAX = 32767


class _VirtualJoystickDesc(ctypes.Structure):
    """SDL_VirtualJoystickDesc (SDL 2.24+, SDL_VIRTUAL_JOYSTICK_DESC_VERSION 1)."""

    _fields_ = [
        ("version", ctypes.c_uint16), ("type", ctypes.c_uint16), ("naxes", ctypes.c_uint16),
        ("nbuttons", ctypes.c_uint16), ("nhats", ctypes.c_uint16),
        ("vendor_id", ctypes.c_uint16), ("product_id", ctypes.c_uint16),
        ("padding", ctypes.c_uint16), ("button_mask", ctypes.c_uint32),
        ("axis_mask", ctypes.c_uint32), ("name", ctypes.c_char_p), ("userdata", ctypes.c_void_p),
        *((f, ctypes.c_void_p) for f in ("Update", "SetPlayerIndex", "Rumble", "RumbleTriggers",
                                          "SetLED", "SendEffect")),
    ]


def pygames_sdl() -> ctypes.CDLL:
    """The libSDL2 that pygame loaded into this process (not another copy of it)."""
    with open("/proc/self/maps", encoding="utf-8") as maps:
        paths = sorted({m.group(0) for line in maps
                        if (m := re.search(r"/\S*libSDL2-2[^/\s]*\.so[^/\s]*", line))})
    assert paths, "pygame's libSDL2 is not loaded: import pygame and init it first"
    lib = ctypes.CDLL(paths[0])
    lib.SDL_JoystickAttachVirtualEx.argtypes = [ctypes.POINTER(_VirtualJoystickDesc)]
    lib.SDL_JoystickOpen.argtypes = [ctypes.c_int]
    lib.SDL_JoystickOpen.restype = ctypes.c_void_p
    lib.SDL_JoystickSetVirtualAxis.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int16]
    lib.SDL_JoystickSetVirtualButton.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_uint8]
    lib.SDL_JoystickClose.argtypes = [ctypes.c_void_p]
    lib.SDL_JoystickDetachVirtual.argtypes = [ctypes.c_int]
    lib.SDL_GetError.restype = ctypes.c_char_p
    return lib


class Hands:
    """A pad's two sticks and its deadman, however its axes and buttons reach SDL. Each action
    returns the pad, so one step can do several: ``p.deadman().right(0.0, -1.0)``."""

    def axis(self, axis: int, value: float) -> Self:
        raise NotImplementedError

    def button(self, b: int, down: bool = True) -> Self:
        raise NotImplementedError

    def right(self, x: float, y: float) -> Self:
        self.axis(pygame.CONTROLLER_AXIS_RIGHTX, x)
        return self.axis(pygame.CONTROLLER_AXIS_RIGHTY, y)

    def left(self, x: float, y: float) -> Self:
        self.axis(pygame.CONTROLLER_AXIS_LEFTX, x)
        return self.axis(pygame.CONTROLLER_AXIS_LEFTY, y)

    def deadman(self, down: bool = True) -> Self:
        return self.button(pygame.CONTROLLER_BUTTON_LEFTSHOULDER, down)


class VirtualPad(Hands):
    """An SDL virtual GameController: input goes through SDL's real joystick and game
    controller path (device added, mapping, axis and button events), as from a USB pad.

    SDL gives a virtual joystick of type GameController the standard mapping: axes 0..5 are
    leftx, lefty, rightx, righty, lefttrigger, righttrigger, buttons follow
    ``SDL_GameControllerButton``. Values are applied when SDL next updates its joysticks,
    which pygame's event pump does.
    """

    def __init__(self, name: str = "kinesphere virtual pad") -> None:
        self.sdl = pygames_sdl()
        self._name = name.encode()
        desc = _VirtualJoystickDesc(  # type 1: SDL_JOYSTICK_TYPE_GAMECONTROLLER
            version=1, type=1, naxes=6, nbuttons=pygame.CONTROLLER_BUTTON_MAX, name=self._name
        )
        self.index = self.sdl.SDL_JoystickAttachVirtualEx(ctypes.byref(desc))
        assert self.index >= 0, self.sdl.SDL_GetError().decode()
        self.joystick = self.sdl.SDL_JoystickOpen(self.index)
        assert self.joystick, self.sdl.SDL_GetError().decode()

    def axis(self, axis: int, value: float) -> Self:
        """A stick axis in -1..1 (SDL: x right +, y down +) or a trigger in 0..1."""
        if axis in (pygame.CONTROLLER_AXIS_TRIGGERLEFT, pygame.CONTROLLER_AXIS_TRIGGERRIGHT):
            raw = round(-32768 + value * 65535)  # the joystick's full range is the trigger's
        else:
            raw = max(-32768, min(32767, round(value * 32767)))
        assert self.sdl.SDL_JoystickSetVirtualAxis(self.joystick, axis, raw) == 0
        return self

    def button(self, b: int, down: bool = True) -> Self:
        assert self.sdl.SDL_JoystickSetVirtualButton(self.joystick, b, int(down)) == 0
        return self

    def unplug(self) -> None:
        """Detach the device (SDL then reports it removed, like a pulled cable)."""
        if self.joystick:
            self.sdl.SDL_JoystickClose(self.joystick)
            self.joystick = None
            self.sdl.SDL_JoystickDetachVirtual(self.index)


@dataclass(frozen=True)
class Got:
    """A command as a robot received it: ``key`` without the sender a client signs it with
    (``signer``, the last segment of the key it was put on)."""

    at: float
    key: str
    cmd: Command
    signer: str = ""


class CommandInbox(Watch[Got]):
    """Every Command put on ``key`` (may be a wildcard), signed or not, with arrival times."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        super().__init__(session, Keys.subscribed(key), Got)
        self.got = self.heard

    def decoded(self, sample: zenoh.Sample) -> Got:
        key = str(sample.key_expr)
        signer = OWN_KEYS.sender_of(key)
        if signer:
            key = key.rsplit("/", 1)[0]
        return Got(time.monotonic(), key, decode(sample.payload, Command), signer)

    def commands(self, real: bool = True) -> list[Command]:
        with self._cond:
            return [g.cmd for g in self.got if (g.cmd.sender != SENTINEL) == real]


Reply = tuple[AckStage, str, str, list[Substitution]]
"""An ack a stand-in robot sends: stage, code, detail, substitutions."""


def usual(cmd: Command) -> list[Reply]:
    """What an agent answers when all goes well."""
    if cmd.estop:
        return [(AckStage.ESTOPPED, "", "", [])]
    if cmd.release:
        return [(AckStage.RELEASED, "", "", [])]
    if cmd.stop:
        return [(AckStage.STOPPED, "", "", [])]
    if not cmd.deadman:
        return [(AckStage.HOLDING, "", "deadman released", [])]
    if cmd.lease and not cmd.parts and cmd.drive is None:
        return [(AckStage.LEASED, "", f"lease {cmd.lease}", [])]
    return [(AckStage.ACCEPTED, "", "", []), (AckStage.REACHED, "", "", [])]


class StandIn(CommandInbox):
    """A robot as a client sees it, speaking the protocol over real Zenoh: a liveliness token,
    a state with its groups, commands on its own and its groups' keys (and the wildcard), and
    the acks ``answer`` gives for each (none for a robot that has lost its ack publisher)."""

    def __init__(self, session: zenoh.Session, robot_id: str, groups: Sequence[str] = (),
                 answer: Callable[[Command], list[Reply]] | None = usual) -> None:
        super().__init__(session, OWN_KEYS.command(robot_id))
        self.robot_id = robot_id
        self.answer = answer
        self.lease_holder = ""
        self._subs = [session.declare_subscriber(Keys.subscribed(OWN_KEYS.group_command(g)),
                                                 self._on) for g in groups]
        self._acks = session.declare_publisher(OWN_KEYS.ack(robot_id))
        self._state = FakeRobot(session, robot_id, "fakebot", groups, wait=False)
        self._token = session.liveliness().declare_token(OWN_KEYS.alive_robot(robot_id))
        self._closing = threading.Event()
        self._states = threading.Thread(target=self._publish_states, daemon=True)
        self._states.start()

    def _publish_states(self) -> None:
        """A state every 20 ms, as an agent does (its stream is how clients learn its groups)."""
        while not self._closing.wait(0.02):
            self._state.state(lease_holder=self.lease_holder)

    def _on(self, sample: zenoh.Sample) -> None:
        super()._on(sample)
        cmd = decode(sample.payload, Command)
        if self.answer is None or cmd.sender == SENTINEL:
            return
        for stage, code, detail, subs in self.answer(cmd):
            self._acks.put(encode(Ack(
                robot_id=self.robot_id, sender=cmd.sender, session=cmd.session, seq=cmd.seq,
                stage=stage, code=code, detail=detail, stamp_ns=time.time_ns(),
                substitutions=subs, lease_holder=self.lease_holder)))

    def close(self) -> None:
        self._closing.set()
        self._states.join()
        zconfig.undeclare(self._token, self._acks, self._state.pub, *self._subs)
        super().close()


def kind(c: Command) -> str:
    """A command's role: estop, release, lease <action> (lease-only), stop, let go or move."""
    if c.estop:
        return "estop"
    if c.release:
        return "release"
    if c.lease and not c.parts and c.drive is None:
        return f"lease {c.lease}"
    if c.stop:
        return "stop"
    return "move" if c.deadman else "let go"


_marks = itertools.count()


def sentinel(link: RobotLink, keys: Sequence[str], inboxes: Sequence[CommandInbox]) -> None:
    """Put a new sentinel behind everything sent so far and wait until every inbox has it.

    Only messages of the same priority keep their order (an e-stop may overtake).
    """
    n = next(_marks)
    mark = Command(seq=n, sent_ns=time.time_ns(), deadman=False, ttl_ms=0, sender=SENTINEL)
    link.put(keys, mark)
    for box in inboxes:
        box.wait(lambda g: g.cmd.sender == SENTINEL and g.cmd.seq == n, "the sentinel")


@contextmanager
def client_link(endpoint: str, watch: bool = True, sender: str | None = None
                ) -> Iterator[RobotLink]:
    """A client's own session joined to the hub, and its RobotLink (as ``sender``)."""
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        link = RobotLink(s, OWN_KEYS, watch=watch, sender=sender)
        try:
            yield link
        finally:
            link.close()


def post(kind: int, **attrs: object) -> None:
    pygame.event.post(pygame.event.Event(kind, attrs))


class Pad(Hands):
    """A gamepad that exists only as events posted into pygame's queue."""

    def __init__(self, iid: int = 3) -> None:
        self.iid = iid

    def plug(self) -> Self:
        post(pygame.CONTROLLERDEVICEADDED, device_index=90 + self.iid, instance_id=self.iid)
        return self

    def unplug(self) -> Self:
        post(pygame.CONTROLLERDEVICEREMOVED, instance_id=self.iid)
        return self

    def axis(self, a: int, value: float) -> Self:
        post(pygame.CONTROLLERAXISMOTION, instance_id=self.iid, axis=a, value=int(value * MAX))
        return self

    def button(self, b: int, down: bool = True) -> Self:
        kind = pygame.CONTROLLERBUTTONDOWN if down else pygame.CONTROLLERBUTTONUP
        post(kind, instance_id=self.iid, button=b)
        return self

    def tap(self, b: int) -> Self:
        self.button(b)
        return self.button(b, down=False)


class Script:
    """A Source that posts scheduled events before each tick, then reads the real queue."""

    def __init__(self, inp: pad.PygameInput, steps: dict[int, Callable[[], object]]) -> None:
        self.inp = inp
        self.steps = steps
        self.tick = 0

    @property
    def finished(self) -> bool:
        return self.tick > max(self.steps, default=0)

    def poll(self) -> ControllerState:
        action = self.steps.get(self.tick)
        if action is not None:
            action()
        self.tick += 1
        return self.inp.poll()


class FakeRobot:
    """Publishes RobotState for one id, as an agent would (status chosen by the test).

    The first state waits until a subscriber (the client under test) is matched, so it is
    not put before the client's subscription has reached the hub.
    """

    def __init__(self, session: zenoh.Session, robot_id: str, platform: str,
                 groups: Sequence[str] = (), wait: bool = True) -> None:
        self.robot_id = robot_id
        self.platform = platform
        self.groups = list(groups)
        self.seq = 0
        self.pub = session.declare_publisher(OWN_KEYS.state(robot_id))
        assert not wait or zconfig.wait_matching(self.pub, WAIT_S), "no state subscriber"

    def state(self, status: str = "idle", **fields: object) -> None:
        """Publish one state; ``fields`` set any other RobotState field (``estop_by``...)."""
        self.seq += 1
        st = RobotState(
            robot_id=self.robot_id, platform=self.platform, seq=self.seq,
            stamp_ns=time.time_ns(), joint_names=[], q=[], qd=[], base_pose=[0.0, 0.0, 0.0],
            status=status, last_command_seq=-1, groups=self.groups,
        )
        self.pub.put(encode(msgspec.structs.replace(st, **fields)))


@contextmanager
def databank_service(session: zenoh.Session, *platforms: str) -> Iterator[None]:
    """The real databank service with the shipped databanks of ``platforms``, on ``session``."""
    from kinesphere.services.databank.service import DatabankService
    from kinesphere.services.ecl.ecl import Ecl

    with DatabankService(session, {p: Ecl.open(p) for p in platforms}, OWN_KEYS, "clients"):
        yield


def await_catalogue(link: RobotLink, platform: str) -> None:
    """Until a catalogue query for ``platform`` from ``link``'s session would reach a server."""
    querier = link.session.declare_querier(OWN_KEYS.catalogue(platform))
    try:
        assert zconfig.wait_matching(querier, WAIT_S), f"no catalogue server for {platform}"
    finally:
        zconfig.undeclare(querier)


@contextmanager
def fake_catalogue(session: zenoh.Session, cat: Catalogue) -> Iterator[None]:
    """A catalogue queryable for ``cat.platform`` (the databank's catalogue key only)."""
    payload = encode(cat)

    def on_query(query: zenoh.Query) -> None:
        with query:
            query.reply(OWN_KEYS.catalogue(cat.platform), payload)

    q = session.declare_queryable(OWN_KEYS.catalogue(cat.platform), on_query)
    try:
        yield
    finally:
        zconfig.undeclare(q)
